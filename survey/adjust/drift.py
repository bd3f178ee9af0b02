"""Drift correction of a mobile (SLAM) run with control points.

Inputs: control points with their total-station (world) coordinates g_k, and where
they appear in the MLS frame: coordinates m_k picked from the cloud and the time tau_k
when they were observed. Two models:

- ``"global"``: one 7-parameter Helmert transform for the whole run (``fit_helmert``).
- ``"piecewise"`` (default): the run is split into sections (control points observed
  within ``section_gap_s`` of each other, e.g. the prisms of one monitoring cross-
  section). At each section k a rigid transform x_w = g_c,k + R_k (x_s - m_c,k) is
  fitted by least squares to the control points of sections k - window .. k + window
  (centroids m_c, g_c of those points). Between section times the transform is blended:
  R(t) by a C2 rotation spline (scipy ``RotationSpline``; or SLERP, Shoemake 1985, with
  ``interpolation="linear"``) and the centroids by natural cubic splines (or linearly),
  so the correction is smooth and exact at the anchors; before the first and after the
  last section it is held constant. This is the usual "piecewise rigid with smooth blending"
  treatment of SLAM drift between ground control (cf. trajectory adjustment with
  control points in commercial MLS software).

``DriftCorrection.apply(points, times)`` corrects cloud points by their time;
``apply_trajectory`` corrects poses. ``leave_one_out`` refits without each control
point in turn and predicts it: the honest check-point accuracy.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline, Slerp

from raytrace.checks import as_points
from survey.adjust.helmert import HelmertResult, fit_helmert
from survey.errors import DriftError

if TYPE_CHECKING:
    from sensors.trajectory import Trajectory

__all__ = ["NEIGHBOUR_SIGMA", "DriftCorrection", "fit_drift", "leave_one_out"]

Floats = NDArray[np.float64]

#: Standard-deviation factor for control points of neighbouring sections (per section).
NEIGHBOUR_SIGMA = 2.0


@dataclass(repr=False)
class DriftCorrection:
    """A time-dependent correction from the MLS frame to the world frame.

    Attributes
    ----------
    model : "piecewise" or "global"
    times : (k,) float64, s, the control sections' times (piecewise)
    rotations : scipy Rotation of k, or None (global)
    source_centres, target_centres : (k, 3) float64, m
    helmert : HelmertResult or None, the global model's transform
    residuals : (n, 3) float64, m, corrected control points minus their world
        coordinates (fit residuals)
    ids : list of point ids; interpolation : "cubic" or "linear"
    """

    model: str
    times: Floats
    rotations: Rotation | None
    source_centres: Floats
    target_centres: Floats
    helmert: HelmertResult | None = None
    residuals: Floats | None = None
    ids: list[str] | None = None
    interpolation: str = "cubic"

    def __repr__(self) -> str:
        n = "?" if self.residuals is None else len(self.residuals)
        rms = "" if self.residuals is None or len(self.residuals) == 0 else \
            f", fit RMS {1000 * np.sqrt(np.mean(np.sum(self.residuals ** 2, 1))):.1f} mm"
        kind = (f"piecewise, {len(self.times)} sections, {self.interpolation}"
                if self.model == "piecewise" else "global Helmert")
        return f"DriftCorrection({kind}, {n} control points{rms})"

    def apply(self, points: ArrayLike, times: ArrayLike) -> Floats:
        """Corrected points for MLS-frame points observed at ``times``.

        Parameters
        ----------
        points : (n, 3) or (3,) array_like of float, or structured array with x, y, z
        times : (n,) array_like of float, s (a single value for a single point)

        Returns
        -------
        (n, 3) float64, or (3,) for a single (3,) point (the shape given).
        """
        p, single = as_points(points, "points", DriftError, finite=False)
        if self.model == "global":
            assert self.helmert is not None
            out = self.helmert.apply(p)
        else:
            t = np.asarray(times, dtype=np.float64).reshape(-1)
            if t.shape != (len(p),):
                raise DriftError(f"Expected one time per point ({len(p)}), got shape "
                                 f"{np.shape(times)}.")
            rot, mc, gc = self._at(t)
            out = gc + rot.apply(p - mc)
        return out[0] if single else out

    def _at(self, t: Floats) -> tuple[Rotation, Floats, Floats]:
        tk = self.times
        rots = self.rotations
        assert rots is not None
        if len(tk) == 1:
            n = len(t)
            return (Rotation.from_quat(np.tile(rots.as_quat()[0], (n, 1))),
                    np.tile(self.source_centres[0], (n, 1)),
                    np.tile(self.target_centres[0], (n, 1)))
        tc = np.clip(t, tk[0], tk[-1])
        if self.interpolation == "linear" or len(tk) < 3:
            rot = Slerp(tk, rots)(tc)
            mc = np.stack([np.interp(tc, tk, self.source_centres[:, i]) for i in range(3)], 1)
            gc = np.stack([np.interp(tc, tk, self.target_centres[:, i]) for i in range(3)], 1)
            return rot, mc, gc
        # Cubic: C2 rotation spline (scipy RotationSpline) and natural cubic splines of
        # the centres - drift is smooth over several control sections.
        rot = RotationSpline(tk, rots)(tc)
        mc = CubicSpline(tk, self.source_centres, bc_type="natural")(tc)
        gc = CubicSpline(tk, self.target_centres, bc_type="natural")(tc)
        return rot, mc, gc

    def apply_trajectory(self, traj: Trajectory) -> Trajectory:
        """A corrected copy of a ``sensors.Trajectory``."""
        from sensors import Trajectory

        pos = self.apply(traj.positions, traj.times)
        if self.model == "global":
            assert self.helmert is not None
            r = Rotation.from_matrix(self.helmert.rotation_matrix)
            rots = r * traj.rotations
        else:
            rots = self._at(traj.times)[0] * traj.rotations
        return Trajectory(traj.times, pos, rots)

    def magnitude(self, points: ArrayLike, times: ArrayLike) -> Floats:
        """Length (n,) of the correction (m) at MLS points (n, 3) and times (n,)."""
        p, _ = as_points(points, "points", DriftError, finite=False)
        return np.linalg.norm(self.apply(p, np.asarray(times).reshape(-1)) - p, axis=1)


def _sections(times: Floats, gap: float) -> NDArray[np.int64]:
    order = np.argsort(times, kind="stable")
    sec = np.zeros(len(times), dtype=np.int64)
    sec[order] = np.concatenate([[0], np.cumsum(np.diff(times[order]) > gap)])
    return sec


def fit_drift(mls_xyz: ArrayLike, mls_times: ArrayLike, world_xyz: ArrayLike, *,
              model: Literal["piecewise", "global"] = "piecewise",
              sigma_world_m: ArrayLike | None = None, window: int = 1,
              section_gap_s: float = 2.0,
              interpolation: Literal["cubic", "linear"] = "cubic",
              ids: Iterable[object] | None = None) -> DriftCorrection:
    """Fit a drift correction from control points seen in the MLS frame.

    Parameters
    ----------
    mls_xyz : (n, 3) array_like of float, or structured array with x, y, z
        Control points picked in the MLS cloud (m).
    mls_times : (n,) array_like of float
        When each was observed (s).
    world_xyz : (n, 3) array_like of float, or structured array with x, y, z
        The same points' world coordinates (m), matched row by row.
    sigma_world_m : None, a value or (n,) array_like
        Standard deviations of the world coordinates (m).
    window : int
        Neighbouring sections on each side that inform a section's pose.
    section_gap_s : float
        Control points observed within this time of each other form one section.
    ids : (n,) sequence, optional
        Point names.
    """
    m, _ = as_points(mls_xyz, "mls_xyz", DriftError, finite=False)
    g, _ = as_points(world_xyz, "world_xyz", DriftError, finite=False)
    t = np.asarray(mls_times, dtype=np.float64)
    if m.shape != g.shape or m.ndim != 2 or m.shape[1] != 3 or t.shape != (len(m),) or \
            not (np.isfinite(m).all() and np.isfinite(g).all() and np.isfinite(t).all()):
        raise DriftError(f"Expected matched MLS points (n, 3), times (n,) and world points "
                         f"(n, 3), got {m.shape}, {t.shape}, {g.shape}.")
    if len(m) < 3:
        raise DriftError(f"Expected at least 3 control points, got {len(m)}.")
    id_list = [str(i) for i in range(len(m))] if ids is None else [str(i) for i in ids]
    if model == "global":
        # DECISION: SLAM scale drift in a tunnel can exceed the unit guard's 1,000 ppm;
        # here both systems are metres by construction.
        h = fit_helmert(m, g, model=7, sigma_target_m=sigma_world_m, ids=id_list,
                        allow_scale=True)
        corr = DriftCorrection("global", np.array([t.min()]), None, np.zeros((1, 3)),
                               np.zeros((1, 3)), helmert=h, ids=id_list)
    elif model == "piecewise":
        sec = _sections(t, section_gap_s)
        n_sec = sec.max() + 1
        times, rots, mcs, gcs = [], [], [], []
        for k in range(n_sec):
            use = (sec >= k - window) & (sec <= k + window)
            w = max(window, 1)
            while use.sum() < 3 or np.linalg.matrix_rank(m[use] - m[use].mean(0),
                                                         tol=1e-6) < 2:
                w += 1                      # widen until the points determine a pose
                use = (sec >= k - w) & (sec <= k + w)
                if w > n_sec:
                    raise DriftError("Expected control points that determine a pose "
                                     "(3 or more, not on one line), got too few.")
            base = 1.0 if sigma_world_m is None else sigma_world_m
            sw = np.asarray(base)[use] if np.ndim(base) else np.full(use.sum(), base)
            # Neighbouring sections inform the pose (they fix pitch and heading, which
            # one cross-section cannot) but see a slightly different drift: they count
            # with NEIGHBOUR_SIGMA x the sigma per section of distance.
            far = np.abs(sec[use] - k).astype(np.float64)
            sw = sw * (1.0 + (NEIGHBOUR_SIGMA - 1.0) * far)
            h = fit_helmert(m[use], g[use], model=6, sigma_target_m=sw, allow_scale=True)
            mc = m[use].mean(axis=0)
            times.append(t[sec == k].mean())
            rots.append(h.rotation_matrix)
            mcs.append(mc)
            gcs.append(h.apply(mc[None])[0])
        order = np.argsort(times)
        if interpolation not in ("cubic", "linear"):
            raise DriftError(f"Expected interpolation 'cubic' or 'linear', got "
                             f"{interpolation!r}.")
        corr = DriftCorrection("piecewise", np.array(times)[order],
                               Rotation.from_matrix(np.array(rots)[order]),
                               np.array(mcs)[order], np.array(gcs)[order], ids=id_list,
                               interpolation=interpolation)
    else:
        raise DriftError(f"Expected model 'piecewise' or 'global', got {model!r}.")
    corr.residuals = corr.apply(m, t) - g
    return corr


def leave_one_out(mls_xyz: ArrayLike, mls_times: ArrayLike, world_xyz: ArrayLike,
                  **kwargs: Any) -> Floats:
    """Check-point residuals (n, 3), m: each control point predicted by the correction
    fitted without it, minus its world coordinates. ``kwargs`` as ``fit_drift``."""
    m, _ = as_points(mls_xyz, "mls_xyz", DriftError, finite=False)
    g, _ = as_points(world_xyz, "world_xyz", DriftError, finite=False)
    t = np.asarray(mls_times, dtype=np.float64)
    sw = kwargs.pop("sigma_world_m", None)
    out = np.empty_like(m)
    for i in range(len(m)):
        keep = np.arange(len(m)) != i
        swi = sw[keep] if sw is not None and np.ndim(sw) else sw
        c = fit_drift(m[keep], t[keep], g[keep], sigma_world_m=swi, **kwargs)
        out[i] = c.apply(m[i:i + 1], t[i:i + 1])[0] - g[i]
    return out
