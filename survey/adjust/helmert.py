"""Helmert (similarity) transformations by least squares, with geodetic statistics.

Model, in PROJ's form and its position-vector convention (EPSG method 1033 / 1037):

    x_target = t + (1 + s 1e-6) R x_source,   R = R_x(rx) R_y(ry) R_z(rz) exactly,

with R_x(a) = [[1, 0, 0], [0, cos a, -sin a], [0, sin a, cos a]] (and alike), which is
what PROJ's ``+proj=helmert +convention=position_vector +exact`` computes (checked
numerically against pyproj in the tests). The coordinate-frame convention (EPSG 1032)
has the opposite rotation signs; ``HelmertResult.rotation_arcsec_cf`` gives them.
Models: "7" (t, R, s), "6" (rigid: s = 0), "9" (a scale per source axis:
x_t = t + R diag(1 + s_i 1e-6) x_s; not an EPSG method).

Estimation (Wolf & Ghilani, "Adjustment Computations", ch. on 3-D conformal
transformations; Niemeier, "Ausgleichungsrechnung"):

1. Closed-form start: Umeyama 1991 (SVD of the weighted cross-covariance, with the
   reflection fix det(U V^T) = -1 -> flip the last singular vector).
2. Gauss–Newton on (t, rx, ry, rz, s) with exact rotations, coordinates reduced to the
   weighted centroids for conditioning; the Jacobian of R by complex-step
   differentiation (exact to rounding; Squire & Trapp 1998).
3. Errors in the target only: weights 1/sigma_target^2. Errors in both systems
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

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from survey.errors import HelmertError

ARCSEC = np.pi / (180.0 * 3600.0)
#: Baarda's critical value for alpha = 0.001 (two-sided, one dimension) and the
#: non-centrality for power 0.80.
W_CRITICAL = 3.29
DELTA0 = 4.13
ALPHA = 0.001
MODELS = {"7": 7, "6": 6, "9": 9}


def rotation_matrix(rx, ry, rz):
    """R = R_x(rx) R_y(ry) R_z(rz) (radians; works for complex arguments too)."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), \
        np.sin(rz)
    one, zero = cx * 0 + 1, cx * 0
    rxm = np.array([[one, zero, zero], [zero, cx, -sx], [zero, sx, cx]])
    rym = np.array([[cy, zero, sy], [zero, one, zero], [-sy, zero, cy]])
    rzm = np.array([[cz, -sz, zero], [sz, cz, zero], [zero, zero, one]])
    return rxm @ rym @ rzm


def angles_of(r):
    """(rx, ry, rz) with R = R_x R_y R_z; ry in [-pi/2, pi/2]."""
    ry = np.arcsin(np.clip(r[0, 2], -1.0, 1.0))
    rx = np.arctan2(-r[1, 2], r[2, 2])
    rz = np.arctan2(-r[0, 1], r[0, 0])
    return np.array([rx, ry, rz])


def _sigmas(sig, n, name):
    if sig is None:
        return None
    s = np.asarray(sig, dtype=np.float64)
    if s.ndim == 0:
        s = np.full((n, 3), float(s))
    elif s.shape == (n,):
        s = np.repeat(s[:, None], 3, axis=1)
    if s.shape != (n, 3) or not np.isfinite(s).all() or (s <= 0).any():
        raise HelmertError(f"Expected `{name}` as one positive value, (n,) or (n, 3) "
                           f"positive values for n = {n}, got shape {np.shape(sig)}.")
    return s


@dataclass
class HelmertResult:
    """Parameters (PROJ form, position-vector convention) and statistics.

    translation_m (3,), rotation_arcsec (3,), rotation_matrix (3, 3), scale_ppm (float,
    or (3,) for model "9"), their standard deviations (``*_sigma``), ``correlation``
    (u, u) of (t, r, s), ``sigma0`` (a posteriori), ``residuals`` (n, 3) = target -
    transformed source, ``redundancy`` (n, 3), ``w_tests`` (n,) (largest |w| or |tau|
    of each point), ``test`` ("w" or "tau"), ``critical``, ``mdb_m`` (n,), ``outliers``
    (ids), ``global_test`` (dict), ``ids``.
    """

    model: str
    translation_m: np.ndarray
    rotation_arcsec: np.ndarray
    rotation_matrix: np.ndarray
    scale_ppm: object
    translation_sigma_m: np.ndarray
    rotation_sigma_arcsec: np.ndarray
    scale_sigma_ppm: object
    correlation: np.ndarray
    sigma0: float
    residuals: np.ndarray
    redundancy: np.ndarray
    w_tests: np.ndarray
    test: str
    critical: float
    mdb_m: np.ndarray
    outliers: list
    global_test: dict
    ids: list
    dof: int
    iterations: int
    extra: dict = field(default_factory=dict)

    @property
    def rotation_arcsec_cf(self) -> np.ndarray:
        """Rotations in the coordinate-frame convention (EPSG 1032): R_cf = R^T, and
        for the exact form the angles of R^T's decomposition."""
        return angles_of(self.rotation_matrix.T) / ARCSEC

    def _scales(self):
        return 1.0 + np.asarray(self.scale_ppm, dtype=np.float64) * 1e-6

    def apply(self, points, *, exact: bool = True):
        """Transform points (n, 3). ``exact=False`` uses PROJ's linearised rotation
        matrix (small angles), for comparison with PROJ without ``+exact``."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise HelmertError(f"Expected points of shape (n, 3), got {p.shape}.")
        r = self.rotation_matrix
        if not exact:
            cf = self.extra.get("convention") == "coordinate_frame"
            rx, ry, rz = (self.extra["input_arcsec"] if cf else self.rotation_arcsec) * ARCSEC
            r = np.array([[1.0, -rz, ry], [rz, 1.0, -rx], [-ry, rx, 1.0]])
            if cf:   # PROJ's coordinate-frame matrix is the transpose, same angles
                r = r.T
        sc = self._scales()
        if np.ndim(sc) == 0:
            return self.translation_m + sc * (p @ r.T)
        return self.translation_m + (p * sc) @ r.T

    def apply_trajectory(self, traj):
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
             f"+rx={r[0]:.15g} +ry={r[1]:.15g} +rz={r[2]:.15g} +s={float(self.scale_ppm):.15g} "
             "+convention=position_vector")
        return s + (" +exact" if exact else "")

    def to_dict(self) -> dict:
        """JSON-ready dict with every field (the CLI's ``--json``)."""
        def f(v):
            if isinstance(v, np.ndarray):
                return np.where(np.isfinite(v), v, None).tolist() if v.dtype.kind == "f" \
                    else v.tolist()
            if isinstance(v, float) and not np.isfinite(v):
                return None
            return v
        out = {k: f(v) for k, v in self.__dict__.items() if k != "extra"}
        out["convention"] = "position_vector"
        out["form"] = "x_target = t + (1 + s 1e-6) R x_source, R = Rx(rx) Ry(ry) Rz(rz)"
        return out

    @classmethod
    def from_dict(cls, d) -> "HelmertResult":
        """The transform back from ``to_dict`` output (parameters; statistics as
        stored)."""
        try:
            model = str(d["model"])
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


def from_parameters(translation_m, rotation_arcsec, scale_ppm=0.0, *,
                    convention: str = "position_vector") -> HelmertResult:
    """A transform from known parameters (PROJ form), without statistics; rotations in
    the given convention ("position_vector" or "coordinate_frame", exact form)."""
    t = np.asarray(translation_m, dtype=np.float64).reshape(3)
    r = np.asarray(rotation_arcsec, dtype=np.float64).reshape(3)
    if convention == "coordinate_frame":
        mat = rotation_matrix(*(r * ARCSEC)).T
        r = angles_of(mat) / ARCSEC
    elif convention != "position_vector":
        raise HelmertError(f"Expected convention 'position_vector' or 'coordinate_frame', "
                           f"got {convention!r}.")
    nan3 = np.full(3, np.nan)
    r_in = np.asarray(rotation_arcsec, dtype=np.float64).reshape(3)
    return HelmertResult("7", t, r, rotation_matrix(*(r * ARCSEC)), float(scale_ppm), nan3,
                         nan3, np.nan, np.full((7, 7), np.nan), np.nan, np.zeros((0, 3)),
                         np.zeros((0, 3)), np.zeros(0), "none", np.nan, np.zeros(0), [], {},
                         [], 0, 0, {"convention": convention, "input_arcsec": r_in})


def _umeyama(src, dst, w, scale):
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


def fit_helmert(source, target, model: str = "7", sigma_source=None, sigma_target=None,
                *, ids=None, use_apriori: bool | None = None, max_iter: int = 50
                ) -> HelmertResult:
    """Least-squares Helmert transform from ``source`` (n, 3) to ``target`` (n, 3).

    sigma_source, sigma_target : None, a value, (n,) or (n, 3) standard deviations (m).
        Target sigmas alone: errors in the target. Both: Gauss–Helmert. None: unit
        weights and an estimated sigma0 (Pope's tau-test).
    use_apriori : bool
        Scale the parameter covariance with the a priori sigma0 = 1 instead of the
        estimated one (default: True when sigmas are given).
    """
    if model not in MODELS:
        raise HelmertError(f"Expected model '7', '6' or '9', got {model!r}.")
    src = np.asarray(source, dtype=np.float64)
    dst = np.asarray(target, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape or \
            not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise HelmertError(f"Expected finite source and target points of the same shape "
                           f"(n, 3), got {src.shape} and {dst.shape}.")
    n = len(src)
    ids = [str(i) for i in range(n)] if ids is None else [str(i) for i in ids]
    u = MODELS[model]
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
    st = _sigmas(sigma_target, n, "sigma_target")
    ss = _sigmas(sigma_source, n, "sigma_source")
    known = st is not None or ss is not None
    use_apriori = known if use_apriori is None else use_apriori
    var_t = np.ones((n, 3)) if st is None else st ** 2
    var_s = None if ss is None else ss ** 2
    # Reduce to centroids (conditioning with UTM-sized numbers).
    w0 = 1.0 / var_t.mean(axis=1)
    cs = (w0 @ src) / w0.sum()
    ct = (w0 @ dst) / w0.sum()
    a, b = src - cs, dst - ct
    r0, c0, t0 = _umeyama(a, b, w0, scale=(model != "6"))
    ang = angles_of(r0)
    if model == "7":
        x = np.concatenate([t0, ang, [c0 - 1.0]])
    elif model == "6":
        x = np.concatenate([t0, ang])
    else:
        x = np.concatenate([t0, ang, np.full(3, c0 - 1.0)])

    def predict(p):
        r = rotation_matrix(p[3], p[4], p[5])
        if model == "7":
            return p[:3] + (1 + p[6]) * (a @ r.T)
        if model == "6":
            return p[:3] + a @ r.T
        return p[:3] + (a * (1 + p[6:9])) @ r.T

    def jacobian(p):
        j = np.empty((3 * n, u))
        h = 1e-20
        for k in range(u):
            pc = p.astype(complex)
            pc[k] += 1j * h
            j[:, k] = (predict(pc).imag / h).ravel()
        return j

    def weights(p):
        """Per-point 3x3 weight blocks (inverse misclosure covariance)."""
        cov = np.zeros((n, 3, 3))
        cov[:, [0, 1, 2], [0, 1, 2]] = var_t
        if var_s is not None:
            r = rotation_matrix(p[3], p[4], p[5])
            sc = (1 + p[6]) if model == "7" else (1 + p[6:9] if model == "9" else 1.0)
            m = r * sc if np.ndim(sc) else r * sc   # R diag(sc) or sc R
            cov += np.einsum("ij,nj,kj->nik", m, var_s, m)
        return np.linalg.inv(cov)

    it = 0
    for it in range(1, max_iter + 1):
        pw = weights(x)
        v = (b - predict(x)).ravel()
        j = jacobian(x)
        pj = np.einsum("nij,njk->nik", pw, j.reshape(n, 3, u)).reshape(3 * n, u)
        nmat = j.T @ pj
        rhs = pj.T @ v
        try:
            dx = np.linalg.solve(nmat, rhs)
        except np.linalg.LinAlgError as exc:
            raise HelmertError("Expected a point configuration that determines every "
                               "parameter, got a rank-deficient one; add points that are "
                               "not collinear.") from exc
        x = x + dx
        if np.abs(dx[:3]).max() < 1e-12 and np.abs(dx[3:]).max() < 1e-14:
            break
    pw = weights(x)
    j = jacobian(x)
    v = b - predict(x)                               # (n, 3) misclosures
    pj = np.einsum("nij,njk->nik", pw, j.reshape(n, 3, u)).reshape(3 * n, u)
    nmat = j.T @ pj
    if np.linalg.cond(nmat) > 1e14:
        raise HelmertError("Expected a point configuration that determines every "
                           "parameter, got a rank-deficient one; add points that are not "
                           "collinear.")
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
    worst = int(np.argmax(wpt))
    outliers = [ids[worst]] if wpt[worst] > crit else []
    scale_cov = sig_apriori ** 2 if use_apriori else s0 ** 2
    cov = ninv * scale_cov
    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd)
    # Back from centroid-reduced to PROJ form: x_t = ct + t' + S R (x_s - cs).
    r = rotation_matrix(*x[3:6])
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
    jt = np.zeros((3, u))
    jt[:, :3] = np.eye(3)

    def tfun(p):
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
    return HelmertResult(
        model=model, translation_m=t, rotation_arcsec=x[3:6] / ARCSEC, rotation_matrix=r,
        scale_ppm=scale_ppm, translation_sigma_m=t_sd, rotation_sigma_arcsec=sd[3:6] / ARCSEC,
        scale_sigma_ppm=scale_sd, correlation=corr, sigma0=float(s0), residuals=v,
        redundancy=redundancy, w_tests=wpt, test=test, critical=float(crit), mdb_m=mdb,
        outliers=outliers, global_test=global_test, ids=ids, dof=dof, iterations=it)
