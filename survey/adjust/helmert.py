"""Helmert (similarity) transformations by least squares, with geodetic statistics.

Model, in PROJ's form and its position-vector convention (EPSG method 1033 / 1037):

    x_target = t + (1 + s 1e-6) R x_source,   R = R_x(rx) R_y(ry) R_z(rz) exactly,

with R_x(a) = [[1, 0, 0], [0, cos a, -sin a], [0, sin a, cos a]] (and alike), which is
what PROJ's ``+proj=helmert +convention=position_vector +exact`` computes (checked
numerically against pyproj in the tests). The coordinate-frame convention (EPSG 1032)
has the opposite rotation signs; ``HelmertResult.rotation_arcsec_cf`` gives them.
Models: 7 (t, R, s), 6 (rigid: s = 0), 9 (a scale per source axis:
x_t = t + R diag(1 + s_i 1e-6) x_s; not an EPSG method); given as the int or the string.

Units: translations in metres, rotations in arcseconds (radians inside), scale in ppm.
Argument order as everywhere in ``survey``: the points you have first (``source``, the
role of ``compared`` in ``cloud_to_cloud``), the reference second (``target``).

Estimation (Wolf & Ghilani, "Adjustment Computations", ch. on 3-D conformal
transformations; Niemeier, "Ausgleichungsrechnung"):

1. Closed-form start: Umeyama 1991 (SVD of the weighted cross-covariance, with the
   reflection fix det(U V^T) = -1 -> flip the last singular vector).
2. Gauss–Newton on (t, rx, ry, rz, s) with exact rotations, coordinates reduced to the
   weighted centroids for conditioning; the Jacobian of R by complex-step
   differentiation (exact to rounding; Squire & Trapp 1998).
3. Errors in the target only: weights 1/sigma_target_m^2. Errors in both systems
   (Gauss–Helmert model): the misclosure of point i has covariance
   Sigma_t,i + (1 + s)^2 R Sigma_s,i R^T, and the normal equations use its inverse.

Statistics (Baarda 1968; Pope 1976; Teunissen, "Testing theory"): redundancy
r = 3n - u, sigma0^2 = v^T P v / r, covariance of the parameters sigma0^2 (A^T P A)^-1
(a posteriori; a priori when sigmas are given and ``use_apriori``), cofactors of the
residuals Q_vv = Q_ll - A N^-1 A^T, redundancy numbers diag(Q_vv P), a global chi^2
test of v^T P v against r (with a priori sigmas), per-coordinate w-tests
w = v / (sigma_0 sqrt(q_vv)) against 3.29 (alpha = 0.001) when sigmas are known, and
Pope's tau-test (estimated sigma0) otherwise; a point's test value is the largest of
its three. Minimal detectable bias sigma delta0 / sqrt(r_i) with delta0 = 4.13
(alpha = 0.001, power 0.80). Data snooping flags the worst point above the critical
value; nothing is dropped.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from raytrace.checks import as_points
from survey.errors import HelmertError

if TYPE_CHECKING:
    from sensors.trajectory import Trajectory

__all__ = ["ALPHA", "ARCSEC", "DELTA0", "MODELS", "W_CRITICAL", "HelmertModel",
           "HelmertResult", "angles_of", "fit_helmert", "from_parameters", "model_name",
           "rotation_matrix"]

ARCSEC = np.pi / (180.0 * 3600.0)
#: Baarda's critical value for alpha = 0.001 (two-sided, one dimension) and the
#: non-centrality for power 0.80.
W_CRITICAL = 3.29
DELTA0 = 4.13
ALPHA = 0.001
#: Model name -> number of parameters.
MODELS = {"7": 7, "6": 6, "9": 9}
#: What ``model`` accepts: the parameter count as an int or a string.
HelmertModel = Literal[6, 7, 9, "6", "7", "9"]

Floats = NDArray[np.float64]


def model_name(model: object) -> str:
    """The model as its canonical name "6", "7" or "9" (from 6, 7, 9 or their strings).

    Raises
    ------
    HelmertError
        For anything else (5, "7p", 7.5, True).
    """
    name = None
    if isinstance(model, str):
        name = model.strip()
    elif isinstance(model, (int, np.integer)) and not isinstance(model, (bool, np.bool_)):
        name = str(int(model))
    if name not in MODELS:
        raise HelmertError(f"Expected model 7, 6 or 9 (an int or a string), got "
                           f"{model!r}.")
    return name


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


def _sigmas(sig: ArrayLike | None, n: int, name: str) -> Floats | None:
    if sig is None:
        return None
    try:
        s = np.asarray(sig, dtype=np.float64)
    except (TypeError, ValueError):
        raise HelmertError(f"Expected `{name}` as numbers (m), got "
                           f"{type(sig).__name__}.") from None
    if s.ndim == 0:
        s = np.full((n, 3), float(s))
    elif s.shape == (n,):
        s = np.repeat(s[:, None], 3, axis=1)
    if s.shape != (n, 3) or not np.isfinite(s).all() or (s <= 0).any():
        raise HelmertError(f"Expected `{name}` as one positive value, (n,) or (n, 3) "
                           f"positive values for n = {n}, got shape {np.shape(sig)}.")
    return s


def _nan_to_none(v: Any) -> Any:
    """A JSON-ready value: arrays as lists, NaN and inf as None."""
    if isinstance(v, np.ndarray):
        if v.dtype.kind != "f":
            return v.tolist()
        out = v.astype(object)
        out[~np.isfinite(v)] = None
        return out.tolist()
    if isinstance(v, float) and not np.isfinite(v):
        return None
    return v


@dataclass(repr=False)
class HelmertResult:
    """Parameters (PROJ form, position-vector convention) and statistics.

    Attributes
    ----------
    model : str, "6", "7" or "9"
    translation_m : (3,) float64, metres
    rotation_arcsec : (3,) float64, arcseconds (position-vector convention)
    rotation_matrix : (3, 3) float64
    scale_ppm : float, or (3,) float64 for model "9", ppm
    translation_sigma_m, rotation_sigma_arcsec, scale_sigma_ppm : their standard
        deviations, in the same units
    correlation : (u, u) float64, correlations of (t, r, s)
    sigma0 : float, a posteriori standard deviation of unit weight
    residuals : (n, 3) float64, m, target - transformed source
    redundancy : (n, 3) float64, redundancy numbers
    w_tests : (n,) float64, largest |w| or |tau| of each point
    test : "w", "tau" or "none"; critical : float, its critical value
    mdb_m : (n,) float64, minimal detectable bias, metres
    outliers : list of ids flagged; global_test : dict; ids : list of point ids
    dof : int, redundancy 3n - u; iterations : int

    ``repr`` is two lines; the full report (parameters, tests, residuals per point) is
    ``survey.report.helmert_report(result)``.
    """

    model: str
    translation_m: Floats
    rotation_arcsec: Floats
    rotation_matrix: Floats
    scale_ppm: float | Floats
    translation_sigma_m: Floats
    rotation_sigma_arcsec: Floats
    scale_sigma_ppm: float | Floats
    correlation: Floats
    sigma0: float
    residuals: Floats
    redundancy: Floats
    w_tests: Floats
    test: str
    critical: float
    mdb_m: Floats
    outliers: list[str]
    global_test: dict[str, Any]
    ids: list[str]
    dof: int
    iterations: int
    extra: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        t = ", ".join(f"{v:.4f}" for v in self.translation_m)
        r = ", ".join(f"{v:.4f}" for v in self.rotation_arcsec)
        s = ", ".join(f"{v:.3f}" for v in np.atleast_1d(self.scale_ppm))
        head = (f"HelmertResult(model {self.model}, t [{t}] m, r [{r}] arcsec, "
                f"s {s} ppm")
        if self.test == "none":
            return head + ", from parameters)"
        found = ", ".join(self.outliers) if self.outliers else "none"
        return (head + f",\n              {len(self.ids)} points, sigma0 {self.sigma0:.4g}, "
                f"{self.test}-test outliers: {found})")

    @property
    def rotation_arcsec_cf(self) -> Floats:
        """Rotations in the coordinate-frame convention (EPSG 1032): R_cf = R^T, and
        for the exact form the angles of R^T's decomposition (arcsec)."""
        return angles_of(self.rotation_matrix.T) / ARCSEC

    def _scales(self) -> Any:
        return 1.0 + np.asarray(self.scale_ppm, dtype=np.float64) * 1e-6

    def apply(self, points: ArrayLike, *, exact: bool = True) -> Floats:
        """Transform points.

        Parameters
        ----------
        points : (n, 3) or (3,) array_like of float, or structured array with x, y, z
        exact : bool
            False uses PROJ's linearised rotation matrix (small angles), for
            comparison with PROJ without ``+exact``.

        Returns
        -------
        (n, 3) float64, or (3,) for a single (3,) point (the shape given).
        """
        p, single = as_points(points, "points", HelmertError, finite=False)
        r = self.rotation_matrix
        if not exact:
            cf = self.extra.get("convention") == "coordinate_frame"
            rx, ry, rz = (self.extra["input_arcsec"] if cf else self.rotation_arcsec) * ARCSEC
            r = np.array([[1.0, -rz, ry], [rz, 1.0, -rx], [-ry, rx, 1.0]])
            if cf:   # PROJ's coordinate-frame matrix is the transpose, same angles
                r = r.T
        sc = self._scales()
        if np.ndim(sc) == 0:
            out = self.translation_m + sc * (p @ r.T)
        else:
            out = self.translation_m + (p * sc) @ r.T
        return out[0] if single else out

    def apply_trajectory(self, traj: Trajectory) -> Trajectory:
        """A transformed copy of a ``sensors.Trajectory`` (positions and attitudes;
        the scale does not change attitudes)."""
        from scipy.spatial.transform import Rotation

        from sensors import Trajectory

        r = Rotation.from_matrix(self.rotation_matrix)
        return Trajectory(traj.times, self.apply(traj.positions), r * traj.rotations)

    def to_proj(self, *, exact: bool = True) -> str:
        """The PROJ pipeline string of this transform (models 6 and 7)."""
        if self.model == "9":
            raise HelmertError("Expected model 6 or 7 for a PROJ string, got 9 (PROJ has "
                               "no per-axis scale).")
        t, r = self.translation_m, self.rotation_arcsec
        s = (f"+proj=helmert +x={t[0]:.12g} +y={t[1]:.12g} +z={t[2]:.12g} "
             f"+rx={r[0]:.15g} +ry={r[1]:.15g} +rz={r[2]:.15g} "
             f"+s={float(self.scale_ppm):.15g} +convention=position_vector")
        return s + (" +exact" if exact else "")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with every field (the CLI's ``--json``)."""
        out = {k: _nan_to_none(v) for k, v in self.__dict__.items() if k != "extra"}
        out["convention"] = "position_vector"
        out["form"] = "x_target = t + (1 + s 1e-6) R x_source, R = Rx(rx) Ry(ry) Rz(rz)"
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> HelmertResult:
        """The transform back from ``to_dict`` output (parameters; statistics as
        stored)."""
        try:
            model = model_name(str(d["model"]))
            t = np.asarray(d["translation_m"], dtype=np.float64)
            r = np.asarray(d["rotation_arcsec"], dtype=np.float64)
            s = d["scale_ppm"]
        except (KeyError, TypeError) as exc:
            raise HelmertError("Expected a Helmert JSON with model, translation_m, "
                               "rotation_arcsec and scale_ppm (as written by "
                               "'tunnelsim adjust --json').") from exc
        res = from_parameters(t, r, 0.0)
        res.model = model
        res.scale_ppm = np.asarray(s, dtype=np.float64) if model == "9" else float(s)
        return res


def from_parameters(translation_m: ArrayLike, rotation_arcsec: ArrayLike,
                    scale_ppm: float = 0.0, *,
                    convention: Literal["position_vector", "coordinate_frame"] =
                    "position_vector") -> HelmertResult:
    """A transform from known parameters (PROJ form), without statistics.

    translation_m : (3,) metres; rotation_arcsec : (3,) arcseconds, in the given
    ``convention`` (exact form); scale_ppm : ppm.
    """
    try:
        t = np.asarray(translation_m, dtype=np.float64).reshape(3)
        r = np.asarray(rotation_arcsec, dtype=np.float64).reshape(3)
        s = float(scale_ppm)
    except (TypeError, ValueError) as exc:
        raise HelmertError(f"Expected translation_m (3,) in m, rotation_arcsec (3,) in "
                           f"arcsec and a number scale_ppm, got {exc}.") from None
    r_in = r.copy()
    if convention == "coordinate_frame":
        mat = rotation_matrix(*(r * ARCSEC)).T
        r = angles_of(mat) / ARCSEC
    elif convention != "position_vector":
        raise HelmertError(f"Expected convention 'position_vector' or 'coordinate_frame', "
                           f"got {convention!r}.")
    nan3 = np.full(3, np.nan)
    return HelmertResult("7", t, r, rotation_matrix(*(r * ARCSEC)), s, nan3,
                         nan3, np.nan, np.full((7, 7), np.nan), np.nan, np.zeros((0, 3)),
                         np.zeros((0, 3)), np.zeros(0), "none", np.nan, np.zeros(0), [], {},
                         [], 0, 0, {"convention": convention, "input_arcsec": r_in})


# ---------------------------------------------------------------------------- the fit
def _umeyama(src: Floats, dst: Floats, w: Floats, scale: bool
             ) -> tuple[Floats, float, Floats]:
    """Weighted closed-form similarity (Umeyama 1991) with the reflection fix."""
    ws = w / w.sum()
    cs = ws @ src
    cd = ws @ dst
    a, b = src - cs, dst - cd
    cov = (b * ws[:, None]).T @ a
    u, d, vt = np.linalg.svd(cov)
    e = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:  # reflection: flip the weakest axis
        e[2] = -1.0
    r = u @ np.diag(e) @ vt
    var = np.sum(ws * np.sum(a * a, axis=1))
    c = (d * e).sum() / var if scale else 1.0
    return r, c, cd - c * r @ cs


def _check_points(source: ArrayLike, target: ArrayLike, model: str
                  ) -> tuple[Floats, Floats]:
    """Source and target (n, 3): same shape, finite, enough points, not collinear."""
    src, _ = as_points(source, "source", HelmertError, finite=False)
    dst, _ = as_points(target, "target", HelmertError, finite=False)
    if src.shape != dst.shape or not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise HelmertError(f"Expected finite source and target points of the same shape "
                           f"(n, 3), got {src.shape} and {dst.shape}.")
    n, u = len(src), MODELS[model]
    if n < 3 or 3 * n < u:
        raise HelmertError(f"Expected at least 3 common points for a {u}-parameter "
                           f"Helmert transform, got {n}.")
    for name, pts in (("source", src), ("target", dst)):
        c = pts - pts.mean(axis=0)
        sv = np.linalg.svd(c, compute_uv=False)
        if sv[1] <= 1e-9 * max(sv[0], 1e-300):
            raise HelmertError(f"Expected non-collinear {name} points, got points on one "
                               "line (the rotation about it is undetermined); add a point "
                               "off the line.")
    return src, dst


class _Similarity:
    """The observation model in centroid-reduced coordinates ``a`` (source) for the
    parameters p = (t, rx, ry, rz[, s | s_x, s_y, s_z]): predictions, their Jacobian and
    the weights of the misclosures."""

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
        """Per-point 3x3 weight blocks (inverse misclosure covariance)."""
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


_RANK_DEFICIENT = ("Expected a point configuration that determines every parameter, got "
                   "a rank-deficient one; add points that are not collinear.")


def _gauss_newton(m: _Similarity, b: Floats, x: Floats, max_iter: int
                  ) -> tuple[Floats, int]:
    """Gauss–Newton from x until the steps vanish; (parameters, iterations)."""
    it = 0
    for it in range(1, max_iter + 1):
        _, j, pj = m.normals(x)
        v = (b - m.predict(x)).ravel()
        nmat = j.T @ pj
        rhs = pj.T @ v
        try:
            dx = np.linalg.solve(nmat, rhs)
        except np.linalg.LinAlgError as exc:
            raise HelmertError(_RANK_DEFICIENT) from exc
        x = x + dx
        if np.abs(dx[:3]).max() < 1e-12 and np.abs(dx[3:]).max() < 1e-14:
            break
    return x, it


@dataclass
class _Tests:
    """Statistics of a converged fit (see the module doc)."""

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


def _statistics(m: _Similarity, b: Floats, x: Floats, known: bool) -> _Tests:
    """Misclosures, sigma0, redundancy numbers, w/tau tests, MDBs and the global test."""
    n, u = m.n, m.u
    pw, j, pj = m.normals(x)
    v = b - m.predict(x)                             # (n, 3) misclosures
    nmat = j.T @ pj
    if np.linalg.cond(nmat) > 1e14:
        raise HelmertError(_RANK_DEFICIENT)
    ninv = np.linalg.inv(nmat)
    vv = v.ravel()
    pv = np.einsum("nij,nj->ni", pw, v).ravel()
    omega = float(vv @ pv)
    dof = 3 * n - u
    s0 = np.sqrt(omega / dof) if dof > 0 else np.nan
    # Cofactors of the misclosures and redundancy numbers.
    qll = np.linalg.inv(pw)                          # (n, 3, 3) blocks
    jr = j.reshape(n, 3, u)
    qvv_diag = np.einsum("nii->ni", qll) - np.einsum("nik,kl,nil->ni", jr, ninv, jr)
    qvv_diag = np.maximum(qvv_diag, 0.0)
    pdiag = np.einsum("nii->ni", pw)
    redundancy = qvv_diag * pdiag
    sig_apriori = 1.0
    if known:
        test = "w"
        crit = W_CRITICAL
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.abs(v) / (sig_apriori * np.sqrt(qvv_diag))
        chi_lo, chi_hi = stats.chi2.ppf([0.025, 0.975], dof) if dof > 0 else (np.nan, np.nan)
        global_test = {"statistic": omega, "dof": dof, "alpha": 0.05,
                       "interval": [float(chi_lo), float(chi_hi)],
                       "passed": bool(chi_lo <= omega <= chi_hi)}
    else:
        test = "tau"
        tq = stats.t.ppf(1 - ALPHA / 2, max(dof - 1, 1))
        crit = float(np.sqrt(dof) * tq / np.sqrt(dof - 1 + tq * tq)) if dof > 1 else np.inf
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.abs(v) / (s0 * np.sqrt(qvv_diag))
        global_test = {"statistic": omega, "dof": dof, "alpha": 0.05, "interval": None,
                       "passed": None, "note": "no a priori sigmas: sigma0 estimated"}
    w = np.where(np.isfinite(w), w, 0.0)
    wpt = w.max(axis=1)
    sig_for_mdb = np.sqrt(np.einsum("nii->ni", qll)) * (sig_apriori if known else s0)
    with np.errstate(divide="ignore"):
        mdb = (sig_for_mdb * DELTA0 / np.sqrt(np.maximum(redundancy, 1e-300))).max(axis=1)
    return _Tests(v, ninv, float(s0), dof, redundancy, wpt, test, float(crit), mdb,
                  global_test)


def _proj_form(model: str, x: Floats, cov: Floats, cs: Floats, ct: Floats
               ) -> tuple[Floats, Floats, Any, Any]:
    """Centroid-reduced parameters back to PROJ form, x_t = ct + t' + S R (x_s - cs):
    (translation, its standard deviations, scale_ppm, its standard deviation)."""
    sd = np.sqrt(np.diag(cov))
    r = rotation_matrix(*x[3:6])
    scale_ppm: Any
    scale_sd: Any
    if model == "7":
        sc = 1 + x[6]
        t = ct + x[:3] - sc * r @ cs
        scale_ppm, scale_sd = x[6] * 1e6, sd[6] * 1e6
    elif model == "6":
        t = ct + x[:3] - r @ cs
        scale_ppm, scale_sd = 0.0, 0.0
    else:
        t = ct + x[:3] - r @ ((1 + x[6:9]) * cs)
        scale_ppm, scale_sd = x[6:9] * 1e6, sd[6:9] * 1e6
    # Covariance of t: t = ct + t' - d/dp [S R cs]; propagate with the Jacobian.
    u = len(x)
    jt = np.zeros((3, u))
    jt[:, :3] = np.eye(3)

    def tfun(p: NDArray[Any]) -> NDArray[Any]:
        rr = rotation_matrix(p[3], p[4], p[5])
        if model == "7":
            return p[:3] - (1 + p[6]) * rr @ cs
        if model == "6":
            return p[:3] - rr @ cs
        return p[:3] - rr @ ((1 + p[6:9]) * cs)

    for k in range(3, u):
        pc = x.astype(complex)
        pc[k] += 1e-20j
        jt[:, k] = tfun(pc).imag / 1e-20
    t_sd = np.sqrt(np.diag(jt @ cov @ jt.T))
    return t, t_sd, scale_ppm, scale_sd


def fit_helmert(source: ArrayLike, target: ArrayLike, *, model: HelmertModel = 7,
                sigma_source_m: ArrayLike | None = None,
                sigma_target_m: ArrayLike | None = None, ids: Iterable[object] | None = None,
                use_apriori: bool | None = None, max_iter: int = 50) -> HelmertResult:
    """Least-squares Helmert transform from ``source`` to ``target``.

    Parameters
    ----------
    source, target : (n, 3) array_like of float, or structured arrays with x, y, z
        The same n points in both systems (m), n >= 3, not collinear.
    model : 7, 6 or 9 (int or str)
        7 parameters (similarity), 6 (rigid) or 9 (a scale per source axis).
    sigma_source_m, sigma_target_m : None, a value, (n,) or (n, 3) array_like
        Standard deviations (m). Target sigmas alone: errors in the target. Both:
        Gauss–Helmert. None: unit weights and an estimated sigma0 (Pope's tau-test).
    ids : (n,) sequence, optional
        Point names for the outlier list (default "0", "1", ...).
    use_apriori : bool
        Scale the parameter covariance with the a priori sigma0 = 1 instead of the
        estimated one (default: True when sigmas are given).
    max_iter : int
        Gauss–Newton iterations at most.

    Returns
    -------
    HelmertResult
    """
    name = model_name(model)
    src, dst = _check_points(source, target, name)
    n = len(src)
    id_list = [str(i) for i in range(n)] if ids is None else [str(i) for i in ids]
    if len(id_list) != n:
        raise HelmertError(f"Expected one id per point ({n}), got {len(id_list)} ids.")
    if int(max_iter) < 1:
        raise HelmertError(f"Expected max_iter >= 1, got {max_iter}.")
    st = _sigmas(sigma_target_m, n, "sigma_target_m")
    ss = _sigmas(sigma_source_m, n, "sigma_source_m")
    known = st is not None or ss is not None
    use_apriori = known if use_apriori is None else use_apriori
    var_t = np.ones((n, 3)) if st is None else st ** 2
    var_s = None if ss is None else ss ** 2
    # Reduce to centroids (conditioning with UTM-sized numbers).
    w0 = 1.0 / var_t.mean(axis=1)
    cs = (w0 @ src) / w0.sum()
    ct = (w0 @ dst) / w0.sum()
    a, b = src - cs, dst - ct
    m = _Similarity(name, a, var_t, var_s)
    x = m.start(*_umeyama(a, b, w0, scale=(name != "6")))
    x, it = _gauss_newton(m, b, x, int(max_iter))
    tests = _statistics(m, b, x, known)
    worst = int(np.argmax(tests.w_tests))
    outliers = [id_list[worst]] if tests.w_tests[worst] > tests.critical else []
    scale_cov = 1.0 if use_apriori else tests.sigma0 ** 2
    cov = tests.ninv * scale_cov
    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd)
    t, t_sd, scale_ppm, scale_sd = _proj_form(name, x, cov, cs, ct)
    return HelmertResult(
        model=name, translation_m=t, rotation_arcsec=x[3:6] / ARCSEC,
        rotation_matrix=rotation_matrix(*x[3:6]), scale_ppm=scale_ppm,
        translation_sigma_m=t_sd, rotation_sigma_arcsec=sd[3:6] / ARCSEC,
        scale_sigma_ppm=scale_sd, correlation=corr, sigma0=tests.sigma0,
        residuals=tests.v, redundancy=tests.redundancy, w_tests=tests.w_tests,
        test=tests.test, critical=tests.critical, mdb_m=tests.mdb_m, outliers=outliers,
        global_test=tests.global_test, ids=id_list, dof=tests.dof, iterations=it)
