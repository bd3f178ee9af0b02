"""Simulated SLAM drift for mobile-mapping studies.

A SLAM trajectory drifts because small errors of its attitude integrate into position
error (no GNSS underground). Model, per axis (roll, pitch, heading), in the distance
travelled s: an attitude error e(s) = angle random walk (white noise on the angle,
``*_rw`` rad per sqrt(m)) + the integral of a bias that itself walks randomly
(``*_bias_rw`` rad per m per sqrt(m)) - the two terms of the usual gyro/odometry error
model (IEEE Std 952 names them angle random walk and rate random walk). The SLAM
position integrates the true displacement rotated by the current attitude error:

    R_slam(t) = R_e(t) R_true(t),  p_slam[k+1] = p_slam[k] + R_e[k] (p_true[k+1] - p_true[k])

With the defaults the drift reaches ~0.3-1 m over 300 m and is smooth over tens of
metres, as SLAM drift in a feature-poor gallery is. The map the SLAM system builds
places a world point x seen at time t at x_slam = p_slam(t) + R_e(t) (x - p_true(t)).
ASSUMED values: no published drift spectrum for the seed study's sensors was at hand.

``observe_slam`` puts a simulated drive through such a SLAM: the cloud in the drifting
map frame (``DriftedRun``, streamed chunk by chunk), the SLAM and true trajectories, and
the control points a surveyor would have (total-station coordinates, and the same
prisms picked in the drifting cloud with the time they were passed).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from sensors import Trajectory
from sensors.trajectory import Mount
from survey.adjust.controlpoints import ControlPoints
from survey.errors import DriftError

if TYPE_CHECKING:
    from sensors.simulate import Run

#: Prism centres picked from an MLS cloud, per axis (m): ASSUMED, typical of fitting a
#: sphere/prism target in a dense profiler cloud.
PRISM_SIGMA_MLS_M = 0.003
#: Total-station control points, per axis (m): ASSUMED (a monitoring network).
CONTROL_SIGMA_M = 0.0015


def slam_trajectory(true: Trajectory, *, heading_rw: float = 2e-5, pitch_rw: float = 1e-5,
                    roll_rw: float = 1e-5, heading_bias_rw: float = 1.5e-6,
                    pitch_bias_rw: float = 0.5e-6, roll_bias_rw: float = 0.3e-6,
                    seed: int = 0) -> Trajectory:
    """The drifting SLAM estimate of a true trajectory (same times)."""
    rng = np.random.default_rng(seed)
    p = true.positions
    ds = np.linalg.norm(np.diff(p, axis=0), axis=1)
    sq = np.sqrt(ds)[:, None]
    arw = rng.standard_normal((len(ds), 3)) * sq * np.array([roll_rw, pitch_rw, heading_rw])
    bias = np.cumsum(rng.standard_normal((len(ds), 3)) * sq *
                     np.array([roll_bias_rw, pitch_bias_rw, heading_bias_rw]), axis=0)
    steps = arw + bias * ds[:, None]
    e = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
    # Error rotation in world axes: roll about x, pitch about y, heading about z.
    re = Rotation.from_rotvec(e)
    inc = np.diff(p - p[0], axis=0)
    ps = np.vstack([np.zeros(3), np.cumsum(re[:-1].apply(inc), axis=0)]) + p[0]
    return Trajectory(true.times, ps, re * true.rotations)


def to_slam_frame(true: Trajectory, slam: Trajectory, xyz: ArrayLike,
                  times: ArrayLike) -> NDArray[np.float64]:
    """World points (n, 3) seen at ``times`` (n,) placed in the SLAM map frame."""
    t = np.asarray(times, dtype=np.float64)
    pt, mt = true.sensor_matrices(t, Mount())
    ps, ms = slam.sensor_matrices(t, Mount())
    re = np.einsum("nij,nkj->nik", ms, mt)          # R_slam R_true^T
    d = np.asarray(xyz, dtype=np.float64) - pt
    return ps + np.einsum("nij,nj->ni", re, d)


class DriftedRun:
    """A simulation ``Run`` seen through a drifting SLAM: every chunk's points are moved
    into the SLAM map frame at their own time (``to_slam_frame``), whether the run is
    iterated or written.

    DECISION: no attribute is forwarded to the run implicitly. A wrapper that forwarded
    unknown attributes reached the run's own ``write``, which iterates the run itself and
    wrote the true cloud (issue 15's bug); here ``write`` streams the moved chunks and
    the run's descriptive attributes are named one by one.
    """

    def __init__(self, run: Run, true: Trajectory, slam: Trajectory) -> None:
        self.run, self.true, self.slam = run, true, slam

    def __repr__(self) -> str:
        return f"DriftedRun({self.run!r}, {len(self.slam.times)} SLAM poses)"

    # The run's description, unchanged by the drift.
    sensor = property(lambda self: self.run.sensor)
    seed = property(lambda self: self.run.seed)
    station = property(lambda self: self.run.station)
    n_pulses = property(lambda self: self.run.n_pulses)
    duration_s = property(lambda self: self.run.duration_s)
    stats = property(lambda self: self.run.stats, doc="The run's stats after a full pass.")

    def to_map(self, points: np.ndarray) -> np.ndarray:
        """A copy of a chunk of ``POINT_DTYPE`` records with x, y, z in the SLAM map
        frame at each point's ``time``; the other fields unchanged."""
        if not len(points):
            return points
        xyz = to_slam_frame(self.true, self.slam,
                            np.stack([points["x"], points["y"], points["z"]], 1),
                            points["time"])
        out = points.copy()
        out["x"], out["y"], out["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        return out

    def __iter__(self) -> Iterator[np.ndarray]:
        for pts in self.run:
            yield self.to_map(pts)

    def write(self, path: str | os.PathLike[str], *, fmt: str | None = None,
              progress: Callable[[int, int], object] | None = None,
              fields: str | None = None) -> dict[str, Any]:
        """Stream the drifted chunks into ``path``, as ``Run.write`` does for the true
        ones (same formats and options: ``sensors.writers.open_writer``); returns the
        run's stats plus the path."""
        return self.run.write(path, fmt=fmt, progress=progress, fields=fields, points=self)


@dataclass(frozen=True, repr=False)
class SlamObservation:
    """A drive through a drifting SLAM, as a surveyor receives it.

    Attributes
    ----------
    run : DriftedRun
        The cloud in the SLAM map frame (iterate it or ``write`` it).
    true, slam : Trajectory
        The platform's true trajectory and the drifting SLAM estimate (same times).
    observed : ControlPoints
        The control points seen in the drifting cloud: SLAM-frame coordinates (with
        ``prism_sigma_m`` picking noise) and the time each was passed (``time``); only
        the points passed strictly inside the trajectory's time span.
    world : ControlPoints
        The same points by total station: world coordinates with ``control_sigma_m``
        noise and that ``sigma``.
    """

    run: DriftedRun
    true: Trajectory
    slam: Trajectory
    observed: ControlPoints
    world: ControlPoints

    def __repr__(self) -> str:
        return (f"SlamObservation({len(self.slam.times)} poses, {len(self.observed)} of "
                f"{len(self.world)} control points observed)")


def observe_slam(run: Run, trajectory: Trajectory, control_ids: Iterable[str],
                 control_xyz: ArrayLike, *,
                 seed: int = 0, prism_sigma_m: float = PRISM_SIGMA_MLS_M,
                 control_sigma_m: float = CONTROL_SIGMA_M, **drift: float
                 ) -> SlamObservation:
    """Observe a simulated drive through a drifting SLAM.

    Parameters
    ----------
    run : sensors.Run
        The drive (``simulate_drive``) along ``trajectory``.
    trajectory : Trajectory
        The platform's true trajectory.
    control_ids : sequence of str, (k,)
    control_xyz : (k, 3) float64
        The control points (prisms) in world coordinates, m.
    seed : int
        The SLAM drift uses ``seed + 1`` and the prism/total-station noise ``seed + 2``.
    prism_sigma_m, control_sigma_m : float
        Noise per axis (m) of the prism centres picked in the cloud and of the total
        station (module constants, ASSUMED).
    **drift
        Drift parameters of ``slam_trajectory`` (``heading_rw``...).

    Returns
    -------
    SlamObservation

    Notes
    -----
    A control point is observed when the platform passes nearest to it (horizontal
    distance to the trajectory); DECISION: the seeds are offset from the drive's so the
    same ``seed`` for both does not replay the drive's random stream (and the demo's
    numbers stay those of earlier versions).
    """
    slam = slam_trajectory(trajectory, seed=seed + 1, **drift)
    observed, world = observe_control(trajectory, slam, control_ids, control_xyz, seed=seed,
                                      prism_sigma_m=prism_sigma_m,
                                      control_sigma_m=control_sigma_m)
    return SlamObservation(DriftedRun(run, trajectory, slam), trajectory, slam, observed,
                           world)


def observe_control(true: Trajectory, slam: Trajectory, control_ids: Iterable[str],
                    control_xyz: ArrayLike, *, seed: int = 0,
                    prism_sigma_m: float = PRISM_SIGMA_MLS_M,
                    control_sigma_m: float = CONTROL_SIGMA_M
                    ) -> tuple[ControlPoints, ControlPoints]:
    """The control points a surveyor has for a cloud mapped with ``slam`` (a drifting
    model or a real odometry's estimate): (observed, world).

    Parameters
    ----------
    true : Trajectory
        The platform's true trajectory.
    slam : Trajectory
        The SLAM estimate the cloud was mapped with.
    control_ids : iterable of str
        One id per control point.
    control_xyz : (k, 3) array_like of float
        The control points' true world coordinates, metres.
    seed : int
        Noise from ``seed + 2`` (the offset ``observe_slam`` has always used).
    prism_sigma_m : float
        Picking noise of a prism in the cloud, per axis (m), >= 0.
    control_sigma_m : float
        Total-station noise of a control point, per axis (m), >= 0.

    Returns
    -------
    observed : ControlPoints
        The prisms picked in the SLAM cloud: each point mapped into the SLAM frame at
        the time the platform passed nearest to it (horizontal distance), plus
        ``prism_sigma_m`` noise per axis, with that ``time``; only points the path
        passes (nearest to neither of its ends) strictly inside both trajectories'
        common time span.
    world : ControlPoints
        Every point by total station, ``control_sigma_m`` noise and that ``sigma``.

    Raises
    ------
    DriftError
        Not one id per finite control point, or a negative or non-finite sigma.
    """
    g = np.asarray(control_xyz, dtype=np.float64).reshape(-1, 3)
    ids = [str(i) for i in control_ids]
    if len(ids) != len(g) or not np.isfinite(g).all():
        raise DriftError(f"Expected one id per finite control point, got {len(ids)} ids "
                         f"for {len(g)} points.")
    for name, v in (("prism_sigma_m", prism_sigma_m), ("control_sigma_m", control_sigma_m)):
        if not (np.isfinite(v) and v >= 0):
            raise DriftError(f"Expected `{name}` >= 0, got {v}.")
    t, p = true.times, true.positions
    near = np.argmin(np.linalg.norm(p[None, :, :2] - g[:, None, :2],
                                    axis=2), axis=1) if len(g) else np.zeros(0, dtype=int)
    tau = t[near]
    lo, hi = max(t[0], slam.start_s), min(t[-1], slam.end_s)
    # Passed: nearest to a point of the path other than its two ends (a platform
    # standing still at an end must not "pass" every prism beyond it).
    ends = np.minimum(np.linalg.norm(p[near] - p[0], axis=1),
                      np.linalg.norm(p[near] - p[-1], axis=1))
    inside = (tau > lo) & (tau < hi) & (ends > 1e-6)
    rng = np.random.default_rng(seed + 2)
    seen = to_slam_frame(true, slam, g[inside], tau[inside]) + \
        rng.normal(0, prism_sigma_m, (int(inside.sum()), 3))
    observed = ControlPoints([i for i, k in zip(ids, inside) if k], seen, time=tau[inside])
    world = ControlPoints(ids, g + rng.normal(0, control_sigma_m, g.shape),
                          sigma=np.full(g.shape, float(control_sigma_m)))
    return observed, world


__all__ = ["CONTROL_SIGMA_M", "PRISM_SIGMA_MLS_M", "DriftedRun", "SlamObservation",
           "observe_control", "observe_slam", "slam_trajectory", "to_slam_frame"]
