"""Helmert (similarity) transformations by least squares, with geodetic statistics.

Model, in PROJ's form and its position-vector convention (EPSG method 1033 / 1037):

    x_target = t + (1 + s 1e-6) R x_source,   R = R_x(rx) R_y(ry) R_z(rz) exactly,

with R_x(a) = [[1, 0, 0], [0, cos a, -sin a], [0, sin a, cos a]] (and alike), which is
what PROJ's ``+proj=helmert +convention=position_vector +exact`` computes (checked
numerically against pyproj in the tests). The coordinate-frame convention (EPSG 1032)
has the opposite rotation signs; ``HelmertResult.rotation_arcsec_cf`` gives them.
Models (``FORMS``): 7 (t, R, s), 6 (rigid: s = 0), 9 (a scale per source axis:
x_t = t + R diag(1 + s_i 1e-6) x_s; not an EPSG method, written for PROJ as
``+proj=affine``); given as the int or the string.

Units: translations in metres, rotations in arcseconds (radians inside; degrees and gon
as properties), scale in ppm. Argument order as everywhere in ``survey``: the points
you have first (``source``), the reference second (``target``).

Estimation (Wolf & Ghilani, "Adjustment Computations", ch. on 3-D conformal
transformations; Niemeier, "Ausgleichungsrechnung"), in ``helmert_stats``:

1. Closed-form start: Umeyama 1991 (SVD of the weighted cross-covariance).
2. Gauss–Newton on (t, rx, ry, rz, s) with exact rotations, coordinates reduced to the
   weighted centroids for conditioning; Jacobian by complex-step differentiation.
3. Errors in the target only: weights 1/sigma_target_m^2. Errors in both systems
   (Gauss–Helmert model): the misclosure of point i has covariance
   Sigma_t,i + (1 + s)^2 R Sigma_s,i R^T.

Guards: input that gives confident nonsense is refused with a ``HelmertError`` naming
the likely cause, unless the caller says it is meant: mirror images (the best
orthogonal map is a reflection: swapped axes; ``allow_reflection``), a scale beyond
1,000 ppm (different units; ``allow_scale``), and a Gauss–Newton iteration that does
not converge within ``max_iter``.

Statistics (Baarda 1968, "A testing procedure for use in geodetic networks"; Pope
1976): sigma0, the parameter covariance labelled a priori or a posteriori, redundancy
numbers, a global chi^2 test, w-tests (critical value 3.29: alpha0 = 0.001, two-sided
standard normal) with known sigmas or tau-tests otherwise, MDBs. Every point above the
critical value is listed, largest first; nothing is dropped here (data snooping, one
point at a time: ``survey.adjust.snooping``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points
from survey.adjust.helmert_stats import (
    ALPHA,
    ARCSEC,
    DELTA0,
    MAX_SCALE_PPM,
    MODELS,
    W_CRITICAL,
    SimilarityModel,
    angles_of,
    closed_form,
    converged,
    correlation_warnings,
    gauss_newton,
    parameter_names,
    proj_form,
    rotation_matrix,
    statistics,
)
from survey.errors import HelmertError

if TYPE_CHECKING:
    from sensors.trajectory import Trajectory

__all__ = ["FORMS", "HelmertModel", "HelmertResult", "fit_helmert", "from_parameters",
           "model_name"]

#: What ``model`` accepts: the parameter count as an int or a string.
HelmertModel = Literal[6, 7, 9, "6", "7", "9"]
#: The formula of each model (the report's and the JSON's ``form``).
FORMS = {
    "7": "x_target = t + (1 + s 1e-6) R x_source, R = Rx(rx) Ry(ry) Rz(rz)",
    "6": "x_target = t + R x_source, R = Rx(rx) Ry(ry) Rz(rz)",
    "9": "x_target = t + R diag(1 + sx 1e-6, 1 + sy 1e-6, 1 + sz 1e-6) x_source, "
         "R = Rx(rx) Ry(ry) Rz(rz)",
}
#: Arcseconds -> degrees and gon (400 gon = 360 degrees).
ARCSEC_DEG = 1.0 / 3600.0
ARCSEC_GON = 400.0 / (360.0 * 3600.0)

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


def _g17(v: Any) -> str:
    """A float as PROJ reads it back to the last bit."""
    return format(float(v), ".17g")


@dataclass(repr=False)
class HelmertResult:
    """Parameters (PROJ form, position-vector convention) and statistics.

    Attributes
    ----------
    model : str, "6", "7" or "9"
    translation_m : (3,) float64, metres
    rotation_arcsec : (3,) float64, arcseconds (position-vector convention);
        ``rotation_deg`` and ``rotation_gon`` give them in degrees and gon
    rotation_matrix : (3, 3) float64
    scale_ppm : float, or (3,) float64 for model "9", ppm
    translation_sigma_m, rotation_sigma_arcsec, scale_sigma_ppm : their standard
        deviations, in the same units, a priori or a posteriori (``sigma_basis``)
    correlation : (u, u) float64, correlations of the parameters in the order of
        ``parameter_names`` (translations at the centroid of the points)
    sigma0 : float, a posteriori standard deviation of unit weight
    residuals : (n, 3) float64, m, target - transformed source
    redundancy : (n, 3) float64, redundancy numbers
    w_tests : (n,) float64, largest ``|w|`` or ``|tau|`` of each point
    test : "w", "tau" or "none"
    critical : float, the critical value of ``test``
    mdb_m : (n,) float64, minimal detectable bias, metres
    outliers : list of the ids whose test exceeds ``critical``, largest first
    global_test : dict, the chi-square test of the weighted residual sum ("statistic",
        "dof", "alpha", "interval", "passed"; "interval" and "passed" None without a
        priori sigmas)
    ids : list of point ids
    dof : int, redundancy 3n - u
    iterations : int
    sigma_basis : "a priori" (from the given sigmas, sigma0 = 1), "a posteriori"
        (scaled by the estimated sigma0) or "none" (no statistics)
    correlation_warnings : list of str, pairs with ``|rho|`` > 0.95 and the geometry
        reason
    extra : dict, internal: the rotation and convention ``from_parameters`` was given
        (``apply(..., exact=False)`` linearises that rotation; not in ``to_dict``)

    Notes
    -----
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
    sigma_basis: str = "a posteriori"
    correlation_warnings: list[str] = field(default_factory=list)
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
    def parameter_names(self) -> list[str]:
        """Names of the parameters, the rows of ``correlation``."""
        return parameter_names(self.model)

    @property
    def formula(self) -> str:
        """The formula of this model (``FORMS``)."""
        return FORMS[self.model]

    @property
    def rotation_deg(self) -> Floats:
        """(3,) rotations in degrees (position-vector convention)."""
        return np.asarray(self.rotation_arcsec) * ARCSEC_DEG

    @property
    def rotation_gon(self) -> Floats:
        """(3,) rotations in gon (400 gon a full turn)."""
        return np.asarray(self.rotation_arcsec) * ARCSEC_GON

    @property
    def rotation_arcsec_cf(self) -> Floats:
        """Rotations in the coordinate-frame convention (EPSG 1032): R_cf = R^T, and
        for the exact form the angles of R^T's decomposition (arcsec)."""
        return angles_of(self.rotation_matrix.T) / ARCSEC

    @property
    def outlier_tests(self) -> list[dict[str, Any]]:
        """Every point above the critical value, largest test first:
        [{"id", "statistic", "critical", "test"}]."""
        at = {k: i for i, k in enumerate(self.ids)}
        return [{"id": k, "statistic": float(self.w_tests[at[k]]),
                 "critical": float(self.critical), "test": self.test}
                for k in self.outliers]

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

    def apply_inverse(self, points: ArrayLike) -> Floats:
        """Transform target points back to the source system (the exact inverse:
        x_s = diag(1 + s 1e-6)^-1 R^T (x_t - t), for every model).

        Parameters
        ----------
        points : (n, 3) or (3,) array_like of float, or structured array with x, y, z

        Returns
        -------
        (n, 3) float64, or (3,) for a single (3,) point.
        """
        p, single = as_points(points, "points", HelmertError, finite=False)
        out = ((p - self.translation_m) @ self.rotation_matrix) / self._scales()
        return out[0] if single else out

    def apply_trajectory(self, traj: Trajectory) -> Trajectory:
        """A transformed copy of a ``sensors.Trajectory`` (positions and attitudes;
        the scale does not change attitudes)."""
        from scipy.spatial.transform import Rotation

        from sensors import Trajectory

        r = Rotation.from_matrix(self.rotation_matrix)
        return Trajectory(traj.times, self.apply(traj.positions), r * traj.rotations)

    def to_proj(self, *, exact: bool = True) -> str:
        """The PROJ string of this transform: ``+proj=helmert ...
        +convention=position_vector`` (models 6 and 7; ``+exact`` unless ``exact`` is
        False), or for model 9, which PROJ's Helmert cannot express,
        ``+proj=affine`` with the matrix R diag(1 + s 1e-6). Full float precision."""
        t = self.translation_m
        if self.model == "9":
            m = self.rotation_matrix * self._scales()
            cells = " ".join(f"+s{i + 1}{k + 1}={_g17(m[i, k])}" for i in range(3)
                             for k in range(3))
            return (f"+proj=affine +xoff={_g17(t[0])} +yoff={_g17(t[1])} "
                    f"+zoff={_g17(t[2])} {cells}")
        r = self.rotation_arcsec
        s = (f"+proj=helmert +x={_g17(t[0])} +y={_g17(t[1])} +z={_g17(t[2])} "
             f"+rx={_g17(r[0])} +ry={_g17(r[1])} +rz={_g17(r[2])} "
             f"+s={_g17(self.scale_ppm)} +convention=position_vector")
        return s + (" +exact" if exact else "")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with every field (the CLI's ``--json``), the formula
        (``form``), the PROJ string (``proj``), rotations in degrees and gon, the
        points above the critical value (``outlier_tests``, largest first), the unit of
        ``sigma0`` (``sigma0_unit``: "m" with unit weights, "1" with given standard
        deviations) and the ``variance_factor`` sigma0² (given deviations only)."""
        out = {k: _nan_to_none(v) for k, v in self.__dict__.items() if k != "extra"}
        out["convention"] = "position_vector"
        out["form"] = self.formula
        out["proj"] = self.to_proj()
        out["parameter_names"] = self.parameter_names
        sd = np.asarray(self.rotation_sigma_arcsec, dtype=np.float64)
        out["rotation_deg"] = _nan_to_none(self.rotation_deg)
        out["rotation_sigma_deg"] = _nan_to_none(sd * ARCSEC_DEG)
        out["rotation_gon"] = _nan_to_none(self.rotation_gon)
        out["rotation_sigma_gon"] = _nan_to_none(sd * ARCSEC_GON)
        out["outlier_tests"] = self.outlier_tests
        # sigma0 is metres with unit weights, a unitless ratio with given sigmas
        # (``survey.report.adjustment.sigma0_lines``); the variance factor only then.
        known = self.test == "w"
        out["sigma0_unit"] = None if self.test == "none" else ("1" if known else "m")
        out["variance_factor"] = _nan_to_none(self.sigma0 ** 2) if known else None
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

    Parameters
    ----------
    translation_m : (3,) array_like of float
        Translation, metres.
    rotation_arcsec : (3,) array_like of float
        Rotations about x, y, z, arcseconds, in the given ``convention`` (exact form).
    scale_ppm : float
        Scale change, ppm.
    convention : "position_vector" or "coordinate_frame"
        PROJ's ``+convention`` of ``rotation_arcsec``.

    Returns
    -------
    HelmertResult
        Model "7" in the position-vector convention, with NaN statistics
        (``sigma_basis`` "none").
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
                         [], 0, 0, sigma_basis="none",
                         extra={"convention": convention, "input_arcsec": r_in})


# ---------------------------------------------------------------------------- the fit
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


def _scale_refused(scale_ppm: Any, sigma_ppm: Any) -> bool:
    """A scale beyond ``MAX_SCALE_PPM`` that is also significant (|s| > 3.29 sigma).

    DECISION: significance too, so that a noisy scale of a tiny network (2 mm noise on
    points 3 m apart gives several hundred ppm of pure noise) is not taken for a unit
    error; a unit error is both huge and exact."""
    s = np.abs(np.atleast_1d(np.asarray(scale_ppm, dtype=np.float64)))
    sd = np.atleast_1d(np.asarray(sigma_ppm, dtype=np.float64))
    # No redundancy (sigma NaN): nothing can be told from noise; not refused here (the
    # closed-form check before the fit always has redundancy).
    return bool(np.any((s > MAX_SCALE_PPM) & (s > W_CRITICAL * sd)))


def _scale_message(scale_ppm: Any, sigma_ppm: Any) -> str:
    s = ", ".join(f"{v:+,.1f}" for v in np.atleast_1d(scale_ppm))
    sd = ", ".join(f"{v:,.1f}" for v in np.atleast_1d(sigma_ppm))
    return (f"Expected source and target in the same unit (a scale within ±"
            f"{MAX_SCALE_PPM:,.0f} ppm), got a best-fit scale of {s} ppm (± {sd}): "
            "different units? mm against m gives -999,000 ppm; convert one file, or give "
            "--allow-scale (allow_scale=True in Python) if the scale is real.")


MIRROR = ("Expected source and target of the same handedness, got a best-fit rotation "
          "that is a reflection (det = -1 for the centred points, weakest axis {f:.3g} "
          "times the noise): the systems are mirror images: are x and y swapped? Check "
          "the column order of both files (--columns), or give --allow-reflection "
          "(allow_reflection=True in Python) to fit the best proper rotation anyway.")


def fit_helmert(source: ArrayLike, target: ArrayLike, *, model: HelmertModel = 7,
                sigma_source_m: ArrayLike | None = None,
                sigma_target_m: ArrayLike | None = None, ids: Iterable[object] | None = None,
                use_apriori: bool | None = None, max_iter: int = 50,
                allow_reflection: bool = False, allow_scale: bool = False
                ) -> HelmertResult:
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
        estimated one (default: True when sigmas are given); ``sigma_basis`` says which.
    max_iter : int
        Gauss–Newton iterations at most; not converging within them is an error.
    allow_reflection : bool
        Fit the best proper rotation even when the two point sets are mirror images.
    allow_scale : bool
        Accept a scale beyond ±1,000 ppm (``MAX_SCALE_PPM``; for model 6 the scale the
        data imply).

    Returns
    -------
    HelmertResult

    Raises
    ------
    HelmertError
        Bad input; mirror images; a scale beyond ±1,000 ppm; no convergence.
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
    start = closed_form(a, b, w0, scale=(name != "6"))
    if start.mirrored and not allow_reflection:
        raise HelmertError(MIRROR.format(f=start.mirror_ratio))
    if not allow_scale and _scale_refused(start.scale_ppm, start.scale_sigma_ppm):
        raise HelmertError(_scale_message(start.scale_ppm, start.scale_sigma_ppm))
    m = SimilarityModel(name, a, var_t, var_s)
    x = m.start(start.rotation, start.factor, start.translation)
    x, it, dx = gauss_newton(m, b, x, int(max_iter))
    if not converged(dx):
        raise HelmertError(
            f"Expected the Gauss–Newton iteration to converge within max_iter = "
            f"{int(max_iter)} iterations, got a last step of {np.abs(dx[:3]).max():.3g} m and "
            f"{np.abs(dx[3:6]).max() / ARCSEC:.3g} arcsec; check that the ids pair the same "
            "points and both files use the same axes and units, or allow more iterations "
            "(max_iter, --max-iter).")
    tests = statistics(m, b, x, known)
    order = np.argsort(-tests.w_tests, kind="stable")
    outliers = [id_list[i] for i in order if tests.w_tests[i] > tests.critical]
    cov = tests.ninv * (1.0 if use_apriori else tests.sigma0 ** 2)
    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd)
    t, t_sd, scale_ppm, scale_sd = proj_form(name, x, cov, cs, ct)
    if name == "9" and not allow_scale:
        sd_post = np.sqrt(np.diag(tests.ninv))[6:9] * tests.sigma0 * 1e6
        if _scale_refused(scale_ppm, sd_post):
            raise HelmertError(_scale_message(scale_ppm, sd_post))
    return HelmertResult(
        model=name, translation_m=t, rotation_arcsec=x[3:6] / ARCSEC,
        rotation_matrix=rotation_matrix(*x[3:6]), scale_ppm=scale_ppm,
        translation_sigma_m=t_sd, rotation_sigma_arcsec=sd[3:6] / ARCSEC,
        scale_sigma_ppm=scale_sd, correlation=corr, sigma0=tests.sigma0,
        residuals=tests.v, redundancy=tests.redundancy, w_tests=tests.w_tests,
        test=tests.test, critical=tests.critical, mdb_m=tests.mdb_m, outliers=outliers,
        global_test=tests.global_test, ids=id_list, dof=tests.dof, iterations=it,
        sigma_basis="a priori" if use_apriori else "a posteriori",
        correlation_warnings=correlation_warnings(corr, name, src))
