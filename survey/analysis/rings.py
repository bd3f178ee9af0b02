"""Rings: best-fit circle and ellipse of a section (TBM linings), geometric fits.

Circle: algebraic start by Kasa's linear least squares (x^2 + y^2 + D x + E y + F = 0;
Kasa 1976, IEEE Trans. Instrum. Meas. 25(1)), then Gauss-Newton with Levenberg-
Marquardt damping on the orthogonal distances r_i = |p_i - c| - R (the geometric fit,
Gander, Golub & Strebel 1994, "Least-squares fitting of circles and ellipses", BIT 34).

Ellipse: algebraic start by the direct ellipse-specific fit of Fitzgibbon, Pilu &
Fisher 1999 (IEEE TPAMI 21(5)) in the numerically stable form of Halir & Flusser 1998
("Numerically stable direct least squares fitting of ellipses"), on centred and scaled
coordinates; then the orthogonal-distance fit of Ahn, Rauh & Warnecke 2001 ("Least-
squares orthogonal distances fitting of circle, sphere, ellipse, hyperbola, and
parabola", Pattern Recognition 34): for each point the orthogonal contact point on the
current ellipse (Newton on the foot-point condition in the ellipse's own frame), then
a Gauss-Newton/LM step on the parameters (centre, semi-axes, angle) with the Jacobian
of the signed distance d_i = n_i . (p_i - x_i) at fixed contact parameters (by the
envelope theorem the contact point's own motion does not enter to first order).

Outliers (cables, brackets, the track bed): points farther than ``REJECT_SIGMA`` robust
standard deviations (1.4826 MAD) from a first fit are dropped and the fit repeated once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.analysis.sections import SectionCut
from survey.errors import CompareError

__all__ = ["FIT_RMS_WARN_M", "REJECT_SIGMA", "CircleFit", "EllipseFit", "RingFit",
           "fit_circle", "fit_ellipse", "fit_rings", "poor_fits"]

Floats = NDArray[np.float64]

#: Points beyond this many robust standard deviations of a first fit are outliers.
REJECT_SIGMA = 3.0
#: A ring whose circle and ellipse both fit worse than this rms (m) is not a ring: the
#: CLI warns (``poor_fits``). DECISION: 25 mm; a segmental lining's fit rms is a few mm
#: (scanner noise, segment steps of up to ~10 mm), a horseshoe's is decimetres (300 mm
#: on a real one, issue 31), which makes its diameters and ovality meaningless.
FIT_RMS_WARN_M = 0.025
#: Iterations and relative step tolerance of the geometric fits.
_MAX_ITER = 100
_STEP_TOL = 1e-12


@dataclass(frozen=True)
class CircleFit:
    """Geometric best-fit circle: ``centre`` (2,) and ``radius_m``; ``residuals_m``
    (n,) orthogonal distances of the points used (> 0 outside), ``rms_m``,
    ``iterations``, ``converged`` and ``algebraic`` (centre y, z and radius of the
    Kasa start); ``sigma_m`` (3,) the formal standard deviations of centre y, z and
    radius (``_formal_sigma``)."""

    centre: Floats
    radius_m: float
    residuals_m: Floats = field(repr=False)
    rms_m: float
    iterations: int
    converged: bool
    algebraic: tuple[float, float, float]
    sigma_m: Floats = field(default_factory=lambda: np.full(3, np.nan), repr=False)

    @property
    def diameter_m(self) -> float:
        return 2.0 * self.radius_m

    @property
    def diameter_sigma_m(self) -> float:
        """Formal standard deviation of the diameter (m), 2 sigma_radius."""
        return 2.0 * float(self.sigma_m[2])


@dataclass(frozen=True)
class EllipseFit:
    """Geometric best-fit ellipse: ``centre`` (2,), semi-axes ``a_m`` >= ``b_m``,
    ``angle_rad`` of the major axis from the +offset axis (in [0, pi)); residuals as
    in ``CircleFit``; ``algebraic`` the (centre y, centre z, a, b, angle) of the
    direct fit; ``sigma`` (5,) the formal standard deviations of centre y, z (m), a, b
    (m) and the angle (rad) (``_formal_sigma``)."""

    centre: Floats
    a_m: float
    b_m: float
    angle_rad: float
    residuals_m: Floats = field(repr=False)
    rms_m: float
    iterations: int
    converged: bool
    algebraic: tuple[float, float, float, float, float]
    sigma: Floats = field(default_factory=lambda: np.full(5, np.nan), repr=False)

    @property
    def diameters_m(self) -> tuple[float, float]:
        """(largest, smallest) diameter (m)."""
        return 2.0 * self.a_m, 2.0 * self.b_m

    @property
    def diameters_sigma_m(self) -> tuple[float, float]:
        """Formal standard deviations of (largest, smallest) diameter (m)."""
        return 2.0 * float(self.sigma[2]), 2.0 * float(self.sigma[3])

    def ovality(self, nominal_diameter_m: float | None = None) -> float:
        """(D_max - D_min) / D_nominal, the usual ovality of a segmental ring (ASSUMED
        definition; D_nominal the mean of the two diameters when not given)."""
        d = self.a_m + self.b_m if nominal_diameter_m is None else float(nominal_diameter_m)
        return 2.0 * (self.a_m - self.b_m) / d


def _as_yz(points: ArrayLike, need: int) -> Floats:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < need or not np.isfinite(p).all():
        raise CompareError(f"Expected at least {need} finite section points of shape "
                           f"(n, 2), got shape {p.shape}.")
    sv = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    if sv[-1] <= 1e-9 * max(sv[0], 1e-300):
        raise CompareError(f"Expected section points around a ring, got {len(p)} "
                           "collinear points.")
    return p


def _kasa(p: Floats) -> tuple[float, float, float]:
    a = np.column_stack([p, np.ones(len(p))])
    sol, *_ = np.linalg.lstsq(a, -(p ** 2).sum(axis=1), rcond=None)
    cy, cz = -0.5 * sol[0], -0.5 * sol[1]
    r2 = cy * cy + cz * cz - sol[2]
    if not np.isfinite(r2) or r2 <= 0:
        raise CompareError("Expected points around a circle, got a degenerate set "
                           "(collinear?).")
    return float(cy), float(cz), float(np.sqrt(r2))


def _lm(residual_jac: Any, x0: Floats, max_iter: int) -> tuple[Floats, int, bool]:
    """Levenberg-Marquardt (Marquardt 1963) on residual_jac(x) -> (r (n,), J (n, k));
    the damping is scaled by the diagonal of J^T J."""
    x = np.asarray(x0, dtype=np.float64).copy()
    r, jac = residual_jac(x)
    cost = float(r @ r)
    lam = 1e-3
    for it in range(1, max_iter + 1):
        jtj = jac.T @ jac
        g = jac.T @ r
        step_ok = False
        while lam < 1e12:
            a = jtj + lam * np.diag(np.maximum(np.diag(jtj), 1e-12))
            try:
                dx = -np.linalg.solve(a, g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            xn = x + dx
            rn, jn = residual_jac(xn)
            cn = float(rn @ rn)
            if np.isfinite(cn) and cn <= cost:
                x, r, jac, cost = xn, rn, jn, cn
                lam = max(lam / 10, 1e-12)
                step_ok = True
                break
            lam *= 10
        if not step_ok or np.linalg.norm(dx) <= _STEP_TOL * (1 + np.linalg.norm(x)):
            return x, it, True
    return x, max_iter, False


def _formal_sigma(r: Floats, jac: Floats) -> Floats:
    """Formal standard deviations of the parameters of a least-squares fit at its
    solution: sqrt(diag(s0^2 (J^T J)^-1)), s0^2 = r^T r / (n - k) (Gauss–Markov; e.g.
    Ghilani 2010, 10.5). NaN where n <= k or J^T J is singular.

    DECISION: formal, from the scatter of the points about the fitted shape, which the
    fit treats as independent; neighbouring scan points are not (shared range and
    angle errors, joints and bolts), so this is a lower bound of the real uncertainty
    and the reports say so."""
    n, k = jac.shape
    if n <= k:
        return np.full(k, np.nan)
    s02 = float(r @ r) / (n - k)
    try:
        cov = s02 * np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        return np.full(k, np.nan)
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def _circle(p: Floats) -> CircleFit:
    alg = _kasa(p)

    def rj(x: Floats) -> tuple[Floats, Floats]:
        d = p - x[:2]
        rho = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-300)
        jac = np.column_stack([-d[:, 0] / rho, -d[:, 1] / rho, -np.ones(len(p))])
        return rho - x[2], jac

    x, it, ok = _lm(rj, np.array(alg), _MAX_ITER)
    res, jac = rj(x)
    return CircleFit(x[:2].copy(), float(abs(x[2])), res, float(np.sqrt(np.mean(res ** 2))),
                     it, ok, alg, _formal_sigma(res, jac))


def fit_circle(points: ArrayLike, *, reject_sigma: float | None = REJECT_SIGMA
               ) -> CircleFit:
    """Geometric best-fit circle of section points (n, 2), n >= 3 (see module doc).
    ``reject_sigma`` None keeps every point."""
    p = _as_yz(points, 3)
    fit = _circle(p)
    if reject_sigma is not None and len(p) > 10:
        keep = _inliers(fit.residuals_m, reject_sigma)
        if not keep.all() and keep.sum() >= 3:
            fit = _circle(p[keep])
    return fit


def _inliers(res: Floats, k: float) -> NDArray[np.bool_]:
    med = np.median(res)
    mad = 1.4826 * np.median(np.abs(res - med))
    return np.abs(res - med) <= k * max(mad, 1e-12)


def _direct_ellipse(p: Floats) -> tuple[float, float, float, float, float]:
    """Halir & Flusser 1998 form of Fitzgibbon et al. 1999 on centred, scaled points;
    returns (cy, cz, a, b, angle)."""
    c = p.mean(axis=0)
    s = max(float(np.abs(p - c).max()), 1e-300)
    q = (p - c) / s
    x, y = q[:, 0], q[:, 1]
    d1 = np.column_stack([x * x, x * y, y * y])
    d2 = np.column_stack([x, y, np.ones(len(q))])
    s1, s2, s3 = d1.T @ d1, d1.T @ d2, d2.T @ d2
    try:
        t = -np.linalg.solve(s3, s2.T)
    except np.linalg.LinAlgError:
        raise CompareError("Expected points around an ellipse, got a degenerate set "
                           "(collinear?).") from None
    m = s1 + s2 @ t
    m = np.array([m[2] / 2, -m[1], m[0] / 2])        # C1^-1 M
    w, v = np.linalg.eig(m)
    v = np.real(v)
    cond = 4 * v[0] * v[2] - v[1] ** 2
    ok = np.flatnonzero(cond > 0)
    if len(ok) == 0:
        raise CompareError("Expected points around an ellipse, got a set with no "
                           "ellipse solution.")
    a1 = v[:, ok[0]]
    A, B, C = a1
    D, E, F = t @ a1
    den = B * B - 4 * A * C
    x0 = (2 * C * D - B * E) / den
    y0 = (2 * A * E - B * D) / den
    # Axes from the conic in centred form: A x^2 + B x y + C y^2 = -F0.
    f0 = A * x0 * x0 + B * x0 * y0 + C * y0 * y0 + D * x0 + E * y0 + F
    lam, vec = np.linalg.eigh(np.array([[A, B / 2], [B / 2, C]]))
    ax = np.sqrt(-f0 / lam)
    i = int(np.argmax(ax))
    ang = float(np.mod(np.arctan2(vec[1, i], vec[0, i]), np.pi))
    return (float(c[0] + s * x0), float(c[1] + s * y0), float(s * ax[i]),
            float(s * ax[1 - i]), ang)


def _foot(u: Floats, v: Floats, a: float, b: float) -> Floats:
    """Parameter phi of the closest ellipse point (a cos phi, b sin phi) to (u, v) in
    the ellipse frame: Newton on (a^2 - b^2) sin cos - a u sin + b v cos = 0 from the
    angle of (u / a, v / b)."""
    phi = np.arctan2(a * v, b * u)
    for _ in range(20):
        s, c = np.sin(phi), np.cos(phi)
        f = (a * a - b * b) * s * c - a * u * s + b * v * c
        df = (a * a - b * b) * (c * c - s * s) - a * u * c - b * v * s
        step = f / np.where(np.abs(df) > 1e-300, df, 1e-300)
        phi = phi - np.clip(step, -0.5, 0.5)
        if np.abs(step).max() < 1e-14:
            break
    return np.asarray(phi, dtype=np.float64)


def _ellipse(p: Floats) -> EllipseFit:
    alg = _direct_ellipse(p)

    def rj(x: Floats) -> tuple[Floats, Floats]:
        cy, cz, a, b, th = x
        ct, st = np.cos(th), np.sin(th)
        dy, dz = p[:, 0] - cy, p[:, 1] - cz
        u, v = ct * dy + st * dz, -st * dy + ct * dz
        phi = _foot(u, v, a, b)
        cp, sp = np.cos(phi), np.sin(phi)
        # Outward normal at the contact point, ellipse frame then world.
        nu, nv = b * cp, a * sp
        nn = np.maximum(np.hypot(nu, nv), 1e-300)
        nu, nv = nu / nn, nv / nn
        ny, nz = ct * nu - st * nv, st * nu + ct * nv
        r = nu * (u - a * cp) + nv * (v - b * sp)
        # d r / d x = -n . d X / d x at fixed phi, X = c + R(th) (a cp, b sp).
        xa, xb = a * cp, b * sp
        dth = np.stack([-st * xa - ct * xb, ct * xa - st * xb], axis=1)
        jac = np.column_stack([-ny, -nz, -(ny * ct * cp + nz * st * cp),
                               -(-ny * st * sp + nz * ct * sp),
                               -(ny * dth[:, 0] + nz * dth[:, 1])])
        return r, jac

    x, it, ok = _lm(rj, np.array(alg), _MAX_ITER)
    cy, cz, a, b, th = x
    a, b = abs(a), abs(b)
    if b > a:
        a, b, th = b, a, th + np.pi / 2
    res, jac = rj(np.array([cy, cz, a, b, th]))
    return EllipseFit(np.array([cy, cz]), float(a), float(b), float(np.mod(th, np.pi)),
                      res, float(np.sqrt(np.mean(res ** 2))), it, ok, alg,
                      _formal_sigma(res, jac))


def fit_ellipse(points: ArrayLike, *, reject_sigma: float | None = REJECT_SIGMA
                ) -> EllipseFit:
    """Geometric best-fit ellipse of section points (n, 2), n >= 6 (see module doc).
    ``reject_sigma`` None keeps every point."""
    p = _as_yz(points, 6)
    fit = _ellipse(p)
    if reject_sigma is not None and len(p) > 20:
        keep = _inliers(fit.residuals_m, reject_sigma)
        if not keep.all() and keep.sum() >= 6:
            fit = _ellipse(p[keep])
    return fit


@dataclass(frozen=True)
class RingFit:
    """Circle and ellipse of one section, and the fitted centre's offset (dy, dz) from
    the reference centre (the design's, m)."""

    chainage_m: float
    n_points: int
    circle: CircleFit
    ellipse: EllipseFit
    centre_offset_m: Floats
    nominal_diameter_m: float | None

    @property
    def ovality(self) -> float:
        """Ellipse ovality (D_max - D_min) / D_nominal."""
        return self.ellipse.ovality(self.nominal_diameter_m)

    def to_dict(self) -> dict[str, Any]:
        dmax, dmin = self.ellipse.diameters_m
        return {"chainage_m": self.chainage_m, "n_points": self.n_points,
                "circle_centre_y_m": float(self.circle.centre[0]),
                "circle_centre_z_m": float(self.circle.centre[1]),
                "circle_diameter_m": self.circle.diameter_m,
                "circle_diameter_sigma_m": self.circle.diameter_sigma_m,
                "circle_rms_m": self.circle.rms_m,
                "ellipse_centre_y_m": float(self.ellipse.centre[0]),
                "ellipse_centre_z_m": float(self.ellipse.centre[1]),
                "diameter_max_m": dmax, "diameter_min_m": dmin,
                "diameter_max_sigma_m": self.ellipse.diameters_sigma_m[0],
                "diameter_min_sigma_m": self.ellipse.diameters_sigma_m[1],
                "major_axis_angle_deg": float(np.rad2deg(self.ellipse.angle_rad)),
                "ellipse_rms_m": self.ellipse.rms_m, "ovality": self.ovality,
                "centre_offset_y_m": float(self.centre_offset_m[0]),
                "centre_offset_z_m": float(self.centre_offset_m[1])}


def fit_rings(cuts: Sequence[SectionCut], *, reference_centre: ArrayLike = (0.0, 0.0),
              nominal_diameter_m: float | None = None,
              reject_sigma: float | None = REJECT_SIGMA) -> list[RingFit]:
    """Circle and ellipse per section; ``reference_centre`` (2,) the design centre in
    the section frame (e.g. (0, R) for ``circle(R)``), ``nominal_diameter_m`` for the
    ovality. Raises ``CompareError`` for a band with fewer than 6 points."""
    ref = np.asarray(reference_centre, dtype=np.float64).reshape(2)
    out = []
    for c in sorted(cuts, key=lambda c: c.chainage_m):
        if len(c.yz) < 6:
            raise CompareError(f"Expected at least 6 points in the section band at "
                               f"chainage {c.chainage_m:g} m for a ring fit, got "
                               f"{len(c.yz)}; widen the band.")
        ci = fit_circle(c.yz, reject_sigma=reject_sigma)
        el = fit_ellipse(c.yz, reject_sigma=reject_sigma)
        out.append(RingFit(c.chainage_m, len(c.yz), ci, el, el.centre - ref,
                           nominal_diameter_m))
    return out


def poor_fits(rings: Sequence[RingFit], rms_m: float = FIT_RMS_WARN_M) -> list[RingFit]:
    """The rings whose best fit (the smaller of the circle's and the ellipse's rms)
    exceeds ``rms_m``: sections that are not circles or ellipses (a horseshoe, a
    rectangle), or bands full of fittings."""
    return [r for r in rings if min(r.circle.rms_m, r.ellipse.rms_m) > rms_m]
