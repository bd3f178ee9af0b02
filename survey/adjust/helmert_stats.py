"""The least-squares machinery of ``survey.adjust.helmert``: rotations, the closed-form
start with its mirror and unit checks, Gauss–Newton, the geodetic statistics and the
geometry behind strong parameter correlations.

``fit_helmert`` is the way in; this module holds the pieces it is made of, public so
that the tests (and a geodesist who wants to look inside) can reach them.

Sources: Umeyama 1991 (closed form); Wolf & Ghilani, "Adjustment Computations" (3-D
conformal transformation by Gauss–Newton); Baarda 1968, "A testing procedure for use in
geodetic networks" (w-tests, data snooping, the critical value 3.29 and delta0 = 4.13);
Pope 1976 (tau-test); Squire & Trapp 1998 (complex-step derivatives).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from survey.errors import HelmertError

__all__ = ["ALPHA", "ARCSEC", "DELTA0", "MAX_SCALE_PPM", "MIRROR_RATIO", "MODELS", "POWER",
           "RANK_DEFICIENT", "RHO_WARN", "STEP_TOL", "STEP_TOL_M", "THIN", "W_CRITICAL",
           "ClosedForm", "SimilarityModel", "Statistics", "angles_of", "closed_form",
           "converged", "correlation_warnings", "gauss_newton", "geometry_reason",
           "parameter_names", "proj_form", "rotation_matrix", "statistics", "tau_critical"]

Floats = NDArray[np.float64]

ARCSEC = np.pi / (180.0 * 3600.0)
#: Significance level alpha0 of Baarda's w-test (one dimension).
ALPHA = 0.001
#: Baarda's critical value for alpha0 = 0.001, two-sided standard normal:
#: Phi^-1(1 - 0.001 / 2) = 3.2905, tabulated as 3.29 (Baarda 1968).
W_CRITICAL = 3.29
#: Power (1 - beta) of the w-test at which the MDB is detected (Baarda 1968: beta0 = 0.20).
POWER = 0.80
#: Non-centrality for alpha0 = 0.001 and power 0.80 (Baarda 1968), for the MDB:
#: Phi^-1(1 - alpha0 / 2) + Phi^-1(POWER) = 3.2905 + 0.8416 = 4.132, tabulated as 4.13.
DELTA0 = 4.13
#: Model name -> number of parameters.
MODELS = {"7": 7, "6": 6, "9": 9}
#: A best-fit scale beyond this (and significant) means different units, not a network
#: scale. ASSUMED: 1,000 ppm = 1 mm/m is far beyond any instrument or projection scale
#: a tunnel survey meets (UTM at its edge is +400 ppm, EDM scale errors a few ppm).
MAX_SCALE_PPM = 1000.0
#: The weakest axis of mirror images must carry this many times the noise variance
#: (``closed_form``). ASSUMED: 100; noise alone gives ~1 (|Z| / (2 sqrt(n))), 14 at most
#: in 20,000 coplanar trials of 4 points; a tunnel network of 5 m height and 2 mm noise
#: gives ~10^5.
MIRROR_RATIO = 100.0
#: Correlations of the parameters above this get a warning naming the geometry.
RHO_WARN = 0.95
#: The Gauss–Newton steps counted as zero: metres (translation), radians and scale.
STEP_TOL_M = 1e-12
STEP_TOL = 1e-14
#: A point set whose second-largest RMS spread is below this fraction of the largest is
#: "nearly collinear"; whose smallest is below it, "nearly coplanar". ASSUMED.
THIN = 0.1


def rotation_matrix(rx: Any, ry: Any, rz: Any) -> NDArray[Any]:
    """R = R_x(rx) R_y(ry) R_z(rz) (radians; works for complex arguments too)."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), \
        np.sin(rz)
    one, zero = cx * 0 + 1, cx * 0
    rxm = np.array([[one, zero, zero], [zero, cx, -sx], [zero, sx, cx]])
    rym = np.array([[cy, zero, sy], [zero, one, zero], [-sy, zero, cy]])
    rzm = np.array([[cz, -sz, zero], [sz, cz, zero], [zero, zero, one]])
    return rxm @ rym @ rzm


def angles_of(r: ArrayLike) -> Floats:
    """(rx, ry, rz) in radians with R = R_x R_y R_z; ry in [-pi/2, pi/2]."""
    r = np.asarray(r, dtype=np.float64)
    ry = np.arcsin(np.clip(r[0, 2], -1.0, 1.0))
    rx = np.arctan2(-r[1, 2], r[2, 2])
    rz = np.arctan2(-r[0, 1], r[0, 0])
    return np.array([rx, ry, rz])


def parameter_names(model: str) -> list[str]:
    """Names of the parameters in the order of the covariance: tx ty tz rx ry rz, then
    s (model 7) or sx sy sz (model 9)."""
    base = ["tx", "ty", "tz", "rx", "ry", "rz"]
    return base + {"7": ["s"], "6": [], "9": ["sx", "sy", "sz"]}[model]


# ------------------------------------------------------------------------ closed form
@dataclass
class ClosedForm:
    """The weighted closed-form similarity of centred point sets (Umeyama 1991).

    rotation : (3, 3) float64, a proper rotation (det +1) even for mirror images
    factor : float, the scale factor (1 for a rigid fit)
    translation : (3,) float64
    mirrored : bool, the best orthogonal fit is a reflection, significantly (see
        ``closed_form``)
    mirror_ratio : float, d2 over the noise variance (see ``closed_form``; 0 without
        a reflection)
    scale_ppm, scale_sigma_ppm : float, the similarity scale of the data and its
        standard deviation (estimated from the closed-form residuals), also for a rigid
        fit: the unit check
    """

    rotation: Floats
    factor: float
    translation: Floats
    mirrored: bool
    mirror_ratio: float
    scale_ppm: float
    scale_sigma_ppm: float


def closed_form(src: Floats, dst: Floats, w: Floats, scale: bool) -> ClosedForm:
    """Closed-form similarity ``dst ~ t + c R src`` (Umeyama 1991: SVD of the weighted
    cross-covariance) with the reflection fix, the mirror test and the data's scale.

    Parameters
    ----------
    src, dst : (n, 3) float64, the same points in both systems
    w : (n,) float64, positive weights
    scale : bool, estimate c (False: c = 1)

    Notes
    -----
    With the singular values d0 >= d1 >= d2 of the cross-covariance and det(U V^T) = -1
    the best orthogonal map is a reflection; the best rotation flips the weakest axis
    and pays 4 c d2 in the weighted mean square residual. For true mirror images d2 is
    the variance of the points along their weakest axis (a tunnel's height: ~1 m^2);
    for (nearly) coplanar points it is a product of noise, of either sign, about
    sigma^2 / sqrt(n).

    DECISION: the sign of the determinant alone is not enough (it is random for
    coplanar points, and an F test on the 4 c d2 misfit fires on them too, because
    that misfit is linear in the noise, not quadratic). A reflection counts when d2
    exceeds ``MIRROR_RATIO`` times the misclosure variance of the mirror fit (noise:
    below ~1 even for n = 3) and rounding (1e-12 d0).
    """
    ws = w / w.sum()
    cs, cd = ws @ src, ws @ dst
    a, b = src - cs, dst - cd
    cov = (b * ws[:, None]).T @ a
    u, d, vt = np.linalg.svd(cov)
    e = np.ones(3)
    reflection = np.linalg.det(u) * np.linalg.det(vt) < 0
    if reflection:        # the best rotation flips the weakest axis
        e[2] = -1.0
    r = u @ np.diag(e) @ vt
    var_a = float(np.sum(ws * np.sum(a * a, axis=1)))
    var_b = float(np.sum(ws * np.sum(b * b, axis=1)))
    sum_rot, sum_mir = float((d * e).sum()), float(d.sum())
    # Weighted mean squares of the best similarity with a rotation / a reflection.
    ss_rot = max(var_b - sum_rot ** 2 / var_a, 0.0)
    ss_mir = max(var_b - sum_mir ** 2 / var_a, 0.0)
    n = len(src)
    dof = 3 * n - 7
    # Misclosure variance per coordinate of the mirror fit (weights normalised).
    noise = n * ss_mir / max(dof, 1)
    ratio = float(d[2] / noise) if noise > 0 else float(np.inf)
    mirrored = bool(reflection and d[2] > 1e-12 * d[0] and ratio > MIRROR_RATIO)
    c_sim = sum_rot / var_a
    # Least-squares scale: var(c) = sigma^2 / sum(w |a|^2), sigma^2 from the residuals.
    c_sd = np.sqrt(ss_rot / max(dof, 1) / var_a)
    c = c_sim if scale else 1.0
    return ClosedForm(r, c, cd - c * r @ cs, mirrored, ratio if reflection else 0.0,
                      (c_sim - 1.0) * 1e6, float(c_sd) * 1e6)


# ------------------------------------------------------------------------ the model
class SimilarityModel:
    """The observation model in centroid-reduced coordinates ``a`` (source) for the
    parameters p = (t, rx, ry, rz[, s | s_x, s_y, s_z]): predictions, their Jacobian and
    the weights of the misclosures.

    Parameters
    ----------
    model : "6", "7" or "9"
    a : (n, 3) float64, centroid-reduced source points
    var_t : (n, 3) float64, variances of the target coordinates (m^2)
    var_s : (n, 3) float64 or None, variances of the source coordinates (Gauss–Helmert)
    """

    def __init__(self, model: str, a: Floats, var_t: Floats, var_s: Floats | None):
        self.model, self.a, self.var_t, self.var_s = model, a, var_t, var_s
        self.n, self.u = len(a), MODELS[model]

    def start(self, r0: Floats, c0: float, t0: Floats) -> Floats:
        """Parameters of a closed-form start (rotation, scale factor, translation)."""
        ang = angles_of(r0)
        if self.model == "7":
            return np.concatenate([t0, ang, [c0 - 1.0]])
        if self.model == "6":
            return np.concatenate([t0, ang])
        return np.concatenate([t0, ang, np.full(3, c0 - 1.0)])

    def predict(self, p: NDArray[Any]) -> NDArray[Any]:
        """Transformed source points (n, 3) (real or complex parameters)."""
        r = rotation_matrix(p[3], p[4], p[5])
        if self.model == "7":
            return p[:3] + (1 + p[6]) * (self.a @ r.T)
        if self.model == "6":
            return p[:3] + self.a @ r.T
        return p[:3] + (self.a * (1 + p[6:9])) @ r.T

    def jacobian(self, p: Floats) -> Floats:
        """d predict / d p (3n, u), by complex-step differentiation."""
        j = np.empty((3 * self.n, self.u))
        h = 1e-20
        for k in range(self.u):
            pc = p.astype(complex)
            pc[k] += 1j * h
            j[:, k] = (self.predict(pc).imag / h).ravel()
        return j

    def weights(self, p: Floats) -> NDArray[Any]:
        """Per-point 3x3 weight blocks (inverse misclosure covariance): Sigma_t,i +
        R S Sigma_s,i S R^T with S the scale (Gauss–Helmert)."""
        cov = np.zeros((self.n, 3, 3))
        cov[:, [0, 1, 2], [0, 1, 2]] = self.var_t
        if self.var_s is not None:
            r = rotation_matrix(p[3], p[4], p[5])
            sc = (1 + p[6]) if self.model == "7" else \
                (1 + p[6:9] if self.model == "9" else 1.0)
            m = r * sc   # R diag(sc) for model 9, sc R otherwise
            cov += np.einsum("ij,nj,kj->nik", m, self.var_s, m)
        return np.linalg.inv(cov)

    def normals(self, p: Floats) -> tuple[NDArray[Any], Floats, Floats]:
        """(weights (n, 3, 3), Jacobian (3n, u), P J (3n, u)) at p."""
        pw = self.weights(p)
        j = self.jacobian(p)
        pj = np.einsum("nij,njk->nik", pw, j.reshape(self.n, 3, self.u)).reshape(
            3 * self.n, self.u)
        return pw, j, pj


RANK_DEFICIENT = ("Expected a point configuration that determines every parameter, got "
                  "a rank-deficient one; add points that are not collinear.")


def gauss_newton(m: SimilarityModel, b: Floats, x: Floats, max_iter: int
                 ) -> tuple[Floats, int, Floats]:
    """Gauss–Newton from x until the steps vanish (below ``STEP_TOL_M`` in translation
    and ``STEP_TOL`` in rotation and scale).

    Returns
    -------
    (parameters (u,), iterations, the last step (u,)); the caller decides whether a
    last step above the tolerances (no convergence within ``max_iter``) is an error.
    """
    it = 0
    dx = np.full(m.u, np.inf)
    for it in range(1, max_iter + 1):
        _, j, pj = m.normals(x)
        v = (b - m.predict(x)).ravel()
        try:
            dx = np.linalg.solve(j.T @ pj, pj.T @ v)
        except np.linalg.LinAlgError as exc:
            raise HelmertError(RANK_DEFICIENT) from exc
        x = x + dx
        if converged(dx):
            break
    return x, it, dx


def converged(dx: Floats) -> bool:
    """Whether a Gauss–Newton step counts as zero (``STEP_TOL_M``, ``STEP_TOL``)."""
    return bool(np.abs(dx[:3]).max() < STEP_TOL_M and np.abs(dx[3:]).max() < STEP_TOL)


# ------------------------------------------------------------------------ statistics
@dataclass
class Statistics:
    """Statistics of a converged fit (see ``statistics``).

    v : (n, 3) misclosures (m); ninv : (u, u) cofactors of the parameters; sigma0 :
    a posteriori; dof : 3n - u; redundancy : (n, 3); w_tests : (n,) the largest |w| or
    |tau| of each point; test : "w" or "tau"; critical : its critical value; mdb_m :
    (n,); global_test : dict.
    """

    v: Floats
    ninv: NDArray[Any]
    sigma0: float
    dof: int
    redundancy: Floats
    w_tests: Floats
    test: str
    critical: float
    mdb_m: Floats
    global_test: dict[str, Any]


def tau_critical(dof: int, alpha: float = ALPHA) -> float:
    """Pope's tau critical value for ``dof`` degrees of freedom (Pope 1976): the
    Student t quantile t(1 - alpha / 2, dof - 1) transformed to the tau distribution;
    inf for dof <= 1."""
    if dof <= 1:
        return float(np.inf)
    tq = stats.t.ppf(1 - alpha / 2, dof - 1)
    return float(np.sqrt(dof) * tq / np.sqrt(dof - 1 + tq * tq))


def statistics(m: SimilarityModel, b: Floats, x: Floats, known: bool) -> Statistics:
    """Misclosures, sigma0, redundancy numbers, w/tau tests, MDBs and the global test.

    Redundancy r = 3n - u, sigma0^2 = v^T P v / r, Q_vv = Q_ll - A N^-1 A^T, redundancy
    numbers diag(Q_vv P); with a priori sigmas (``known``) Baarda's w = v / sqrt(q_vv)
    against ``W_CRITICAL`` and a chi^2 global test, otherwise Pope's tau = v / (sigma0
    sqrt(q_vv)) against ``tau_critical``. MDB = sigma delta0 / sqrt(r_i).
    """
    n, u = m.n, m.u
    pw, j, pj = m.normals(x)
    v = b - m.predict(x)                             # (n, 3) misclosures
    nmat = j.T @ pj
    if np.linalg.cond(nmat) > 1e14:
        raise HelmertError(RANK_DEFICIENT)
    ninv = np.linalg.inv(nmat)
    pv = np.einsum("nij,nj->ni", pw, v).ravel()
    omega = float(v.ravel() @ pv)
    dof = 3 * n - u
    s0 = np.sqrt(omega / dof) if dof > 0 else np.nan
    qll = np.linalg.inv(pw)                          # (n, 3, 3) blocks
    jr = j.reshape(n, 3, u)
    qvv_diag = np.einsum("nii->ni", qll) - np.einsum("nik,kl,nil->ni", jr, ninv, jr)
    qvv_diag = np.maximum(qvv_diag, 0.0)
    redundancy = qvv_diag * np.einsum("nii->ni", pw)
    if known:
        test, crit, scale = "w", W_CRITICAL, 1.0
        chi_lo, chi_hi = stats.chi2.ppf([0.025, 0.975], dof) if dof > 0 else (np.nan, np.nan)
        global_test = {"statistic": omega, "dof": dof, "alpha": 0.05,
                       "interval": [float(chi_lo), float(chi_hi)],
                       "passed": bool(chi_lo <= omega <= chi_hi)}
    else:
        test, crit, scale = "tau", tau_critical(dof), s0
        global_test = {"statistic": omega, "dof": dof, "alpha": 0.05, "interval": None,
                       "passed": None, "note": "no a priori sigmas: sigma0 estimated"}
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.abs(v) / (scale * np.sqrt(qvv_diag))
    w = np.where(np.isfinite(w), w, 0.0)
    sig_for_mdb = np.sqrt(np.einsum("nii->ni", qll)) * scale
    with np.errstate(divide="ignore"):
        mdb = (sig_for_mdb * DELTA0 / np.sqrt(np.maximum(redundancy, 1e-300))).max(axis=1)
    return Statistics(v, ninv, float(s0), dof, redundancy, w.max(axis=1), test,
                      float(crit), mdb, global_test)


def proj_form(model: str, x: Floats, cov: Floats, cs: Floats, ct: Floats
              ) -> tuple[Floats, Floats, Any, Any]:
    """Centroid-reduced parameters back to PROJ form, x_t = ct + t' + S R (x_s - cs):
    (translation, its standard deviations, scale_ppm, its standard deviation)."""
    sd = np.sqrt(np.diag(cov))
    r = rotation_matrix(*x[3:6])
    scale_ppm: Any
    scale_sd: Any
    if model == "7":
        t = ct + x[:3] - (1 + x[6]) * r @ cs
        scale_ppm, scale_sd = x[6] * 1e6, sd[6] * 1e6
    elif model == "6":
        t = ct + x[:3] - r @ cs
        scale_ppm, scale_sd = 0.0, 0.0
    else:
        t = ct + x[:3] - r @ ((1 + x[6:9]) * cs)
        scale_ppm, scale_sd = x[6:9] * 1e6, sd[6:9] * 1e6

    def tfun(p: NDArray[Any]) -> NDArray[Any]:
        rr = rotation_matrix(p[3], p[4], p[5])
        if model == "7":
            return p[:3] - (1 + p[6]) * rr @ cs
        if model == "6":
            return p[:3] - rr @ cs
        return p[:3] - rr @ ((1 + p[6:9]) * cs)

    # Covariance of t = ct + t' - S R cs by the Jacobian (complex step).
    jt = np.zeros((3, len(x)))
    jt[:, :3] = np.eye(3)
    for k in range(3, len(x)):
        pc = x.astype(complex)
        pc[k] += 1e-20j
        jt[:, k] = tfun(pc).imag / 1e-20
    t_sd = np.sqrt(np.diag(jt @ cov @ jt.T))
    return t, t_sd, scale_ppm, scale_sd


# ------------------------------------------------------------------------ geometry
def _direction(v: Floats) -> str:
    """A unit vector as text, with its azimuth (clockwise from +y, grid north) when it
    is nearly horizontal."""
    v = v if v[np.argmax(np.abs(v))] > 0 else -v
    text = f"({v[0]:.3f}, {v[1]:.3f}, {v[2]:.3f})"
    if abs(v[2]) < 0.5:
        az = np.degrees(np.arctan2(v[0], v[1])) % 180.0
        text += f", azimuth {az:.1f}°"
    return text


def geometry_reason(points: ArrayLike, first: str, second: str) -> str:
    """Why two parameters of a fit on ``points`` ((n, 3), the source points) cannot be
    told apart, from the shape of the point set (its principal RMS spreads)."""
    p = np.asarray(points, dtype=np.float64)
    c = p - p.mean(axis=0)
    _, sv, vt = np.linalg.svd(c, full_matrices=False)
    sv = sv / np.sqrt(len(p))                       # RMS spread along each principal axis
    rotations = first.startswith("r") and second.startswith("r")
    if sv[1] < THIN * sv[0]:
        why = (f"control points nearly collinear along {_direction(vt[0])} (the tunnel "
               f"axis?): {sv[1]:.3g} m RMS across against {sv[0]:.3g} m along it")
        return why + (", so the rotation about that line is weakly determined"
                      if rotations else "")
    if sv[2] < THIN * sv[0]:
        return (f"control points nearly coplanar (normal {_direction(vt[2])}): "
                f"{sv[2]:.3g} m RMS off the plane against {sv[0]:.3g} m in it")
    return ("the point geometry does not separate them (RMS spreads "
            f"{sv[0]:.3g}, {sv[1]:.3g}, {sv[2]:.3g} m); add points spread in all three "
            "directions")


def correlation_warnings(corr: ArrayLike, model: str, points: ArrayLike,
                         limit: float = RHO_WARN) -> list[str]:
    """One line per pair of parameters with |rho| > ``limit``: the pair, rho and the
    geometry reason (``geometry_reason``); largest |rho| first.

    Parameters
    ----------
    corr : (u, u) float64, correlations in the order of ``parameter_names(model)``
    model : "6", "7" or "9"
    points : (n, 3) float64, the source points of the fit
    """
    c = np.asarray(corr, dtype=np.float64)
    names = parameter_names(model)
    pairs = [(abs(c[i, k]), i, k) for i in range(len(names)) for k in range(i + 1, len(names))
             if np.isfinite(c[i, k]) and abs(c[i, k]) > limit]
    return [f"{names[i]}-{names[k]} correlation {c[i, k]:.4f}: "
            f"{geometry_reason(points, names[i], names[k])}"
            for _, i, k in sorted(pairs, reverse=True)]
