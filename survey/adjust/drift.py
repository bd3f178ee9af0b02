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

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline, Slerp


from survey.adjust.helmert import fit_helmert
from survey.errors import DriftError


#: Standard-deviation factor for control points of neighbouring sections (per section).
NEIGHBOUR_SIGMA = 2.0


@dataclass
class DriftCorrection:
    """A time-dependent correction from the MLS frame to the world frame.

    times (k,), rotations (Rotation of k), source_centres (k, 3), target_centres (k, 3)
    for the piecewise model; or ``helmert`` for the global one. ``residuals`` (n, 3):
    corrected control points minus their world coordinates (fit residuals).
    """

    model: str
    times: np.ndarray
    rotations: Rotation | None
    source_centres: np.ndarray
    target_centres: np.ndarray
    helmert: object = None
    residuals: np.ndarray | None = None
    ids: list | None = None
    interpolation: str = "cubic"

    def apply(self, points, times):
        """Corrected points (n, 3) for MLS-frame points observed at ``times`` (n,)."""
        p = np.asarray(points, dtype=np.float64)
        if self.model == "global":
            return self.helmert.apply(p)
        t = np.asarray(times, dtype=np.float64)
        rot, mc, gc = self._at(t)
        return gc + rot.apply(p - mc)

    def _at(self, t):
        tk = self.times
        if len(tk) == 1:
            n = len(t)
            return (Rotation.from_quat(np.tile(self.rotations.as_quat()[0], (n, 1))),
                    np.tile(self.source_centres[0], (n, 1)),
                    np.tile(self.target_centres[0], (n, 1)))
        tc = np.clip(t, tk[0], tk[-1])
        if self.interpolation == "linear" or len(tk) < 3:
            rot = Slerp(tk, self.rotations)(tc)
            mc = np.stack([np.interp(tc, tk, self.source_centres[:, i]) for i in range(3)], 1)
            gc = np.stack([np.interp(tc, tk, self.target_centres[:, i]) for i in range(3)], 1)
            return rot, mc, gc
        # Cubic: C2 rotation spline (scipy RotationSpline) and natural cubic splines of
        # the centres - drift is smooth over several control sections.
        rot = RotationSpline(tk, self.rotations)(tc)
        mc = CubicSpline(tk, self.source_centres, bc_type="natural")(tc)
        gc = CubicSpline(tk, self.target_centres, bc_type="natural")(tc)
        return rot, mc, gc

    def apply_trajectory(self, traj):
        """A corrected copy of a ``sensors.Trajectory``."""
        from sensors import Trajectory

        pos = self.apply(traj.positions, traj.times)
        if self.model == "global":
            r = Rotation.from_matrix(self.helmert.rotation_matrix)
            rots = r * traj.rotations
        else:
            rots = self._at(traj.times)[0] * traj.rotations
        return Trajectory(traj.times, pos, rots)

    def magnitude(self, points, times):
        """Length (n,) of the correction at MLS points and times."""
        return np.linalg.norm(self.apply(points, times) - np.asarray(points), axis=1)


def _sections(times, gap):
    order = np.argsort(times, kind="stable")
    sec = np.zeros(len(times), dtype=np.int64)
    sec[order] = np.concatenate([[0], np.cumsum(np.diff(times[order]) > gap)])
    return sec


def fit_drift(mls_xyz, mls_times, world_xyz, *, model: str = "piecewise",
              sigma_world=None, window: int = 1, section_gap_s: float = 2.0,
              interpolation: str = "cubic", ids=None) -> DriftCorrection:
    """Fit a drift correction from control points seen in the MLS frame.

    mls_xyz (n, 3), mls_times (n,), world_xyz (n, 3): the same points (matched).
    """
    m = np.asarray(mls_xyz, dtype=np.float64)
    g = np.asarray(world_xyz, dtype=np.float64)
    t = np.asarray(mls_times, dtype=np.float64)
    if m.shape != g.shape or m.ndim != 2 or m.shape[1] != 3 or t.shape != (len(m),) or \
            not (np.isfinite(m).all() and np.isfinite(g).all() and np.isfinite(t).all()):
        raise DriftError(f"Expected matched MLS points (n, 3), times (n,) and world points "
                         f"(n, 3), got {m.shape}, {t.shape}, {g.shape}.")
    if len(m) < 3:
        raise DriftError(f"Expected at least 3 control points, got {len(m)}.")
    ids = [str(i) for i in range(len(m))] if ids is None else [str(i) for i in ids]
    if model == "global":
        h = fit_helmert(m, g, "7", sigma_target=sigma_world, ids=ids)
        corr = DriftCorrection("global", np.array([t.min()]), None, np.zeros((1, 3)),
                               np.zeros((1, 3)), helmert=h, ids=ids)
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
            base = 1.0 if sigma_world is None else sigma_world
            sw = np.asarray(base)[use] if np.ndim(base) else np.full(use.sum(), base)
            # Neighbouring sections inform the pose (they fix pitch and heading, which
            # one cross-section cannot) but see a slightly different drift: they count
            # with NEIGHBOUR_SIGMA x the sigma per section of distance.
            far = np.abs(sec[use] - k).astype(np.float64)
            sw = sw * (1.0 + (NEIGHBOUR_SIGMA - 1.0) * far)
            h = fit_helmert(m[use], g[use], "6", sigma_target=sw)
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
                               np.array(mcs)[order], np.array(gcs)[order], ids=ids,
                               interpolation=interpolation)
    else:
        raise DriftError(f"Expected model 'piecewise' or 'global', got {model!r}.")
    corr.residuals = corr.apply(m, t) - g
    return corr


def leave_one_out(mls_xyz, mls_times, world_xyz, **kwargs) -> np.ndarray:
    """Check-point residuals (n, 3): each control point predicted by the correction
    fitted without it, minus its world coordinates."""
    m = np.asarray(mls_xyz, dtype=np.float64)
    g = np.asarray(world_xyz, dtype=np.float64)
    t = np.asarray(mls_times, dtype=np.float64)
    sw = kwargs.pop("sigma_world", None)
    out = np.empty_like(m)
    for i in range(len(m)):
        keep = np.arange(len(m)) != i
        swi = sw[keep] if sw is not None and np.ndim(sw) else sw
        c = fit_drift(m[keep], t[keep], g[keep], sigma_world=swi, **kwargs)
        out[i] = c.apply(m[i:i + 1], t[i:i + 1])[0] - g[i]
    return out
