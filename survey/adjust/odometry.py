"""LiDAR odometry in the loop: real SLAM front ends run on simulated scan frames.

Two open-source odometries behind one interface (optional extra ``slam``):

- **KISS-ICP** (Vizzo et al. 2023, "KISS-ICP: In Defense of Point-to-Point ICP", IEEE
  RA-L 8(2)): constant-velocity prediction, per-frame deskewing, point-to-point ICP
  against a voxel-hash local map, adaptive threshold. pip ``kiss-icp``.
- **GenZ-ICP** (Lee et al. 2024, "GenZ-ICP: Generalizable and Degeneracy-Robust LiDAR
  Odometry Using an Adaptive Weighting", IEEE RA-L): point-to-plane and point-to-point
  ICP weighted by the local planarity, built for degenerate corridors. pip ``genz-icp``.

Both are fed each scan frame in the sensor frame with per-point timestamps normalised to
[0, 1] over the frame (their deskewing expects that), and return one sensor pose per
frame relative to the first frame. Which instant of the frame a pose belongs to differs:
KISS-ICP 1.x deskews every point to the frame's *last* timestamp (its C++
``Preprocessor`` maps stamp s by exp((s - 1) log(delta))), GenZ-ICP 0.3 places the pose
at *mid-frame*. Both facts were measured here (tests/survey/adjust/test_odometry.py): in a
feature-rich room an ideal Airy moving at 2 m/s is tracked to about 1-2 cm only with
those stamps; the others are off by 5-10 cm along the motion. ``STAMP`` records them.

DECISION: frames shorter than ``PARTIAL_FRAME`` of a neighbouring frame (the turn the
sensor was in when the drive started or ended) are not registered: a partial turn sees
a sector only, and the deskewing assumes a whole frame. Their points are still placed
by ``odometry_trajectory``, which extrapolates the first and last estimated motion
(the constant-velocity model both odometries use) to the drive's start and end.
"""

from __future__ import annotations

import importlib
import time as _time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from sensors import Mount, Trajectory
from survey.errors import OdometryError

__all__ = ["MIN_FRAMES", "ODOMETRY", "PARTIAL_FRAME", "STAMP", "OdometryResult",
           "odometry_trajectory", "run_odometry"]

#: Odometry backends: name -> (module, install hint).
ODOMETRY = {"kiss-icp": "kiss_icp", "genz-icp": "genz_icp"}
#: Instant of a frame its estimated pose belongs to (0 first point, 1 last point).
STAMP = {"kiss-icp": 1.0, "genz-icp": 0.5}
#: Fewest registered frames a SLAM run needs (a second of a 10 Hz LiDAR, and enough
#: for the adaptive thresholds of both odometries to settle).
MIN_FRAMES = 10
#: A frame lasting less than this fraction of a neighbour's is a partial turn.
PARTIAL_FRAME = 0.9
#: KISS-ICP's map voxel for tunnels (m). DECISION: its default (max range / 100 = 1 m)
#: is a third of a 3 m gallery; 0.5 m tracked a 40 m rock gallery best of 0.25, 0.5
#: and 1 m (benchmarks/RESULTS.md, "SLAM").
TUNNEL_VOXEL_M = {"kiss-icp": 0.5, "genz-icp": 0.3}


class _Frame(Protocol):
    @property
    def frame(self) -> int: ...
    @property
    def points(self) -> NDArray[np.float64]: ...
    @property
    def times(self) -> NDArray[np.float64]: ...


@dataclass(frozen=True, repr=False)
class OdometryResult:
    """Sensor poses estimated by LiDAR odometry.

    Attributes
    ----------
    method : str
        "kiss-icp" or "genz-icp".
    times : (n,) float64
        Time of each pose (s): the frame's first time plus ``STAMP`` of its duration.
    poses : (n, 4, 4) float64
        Sensor-to-odometry-frame transforms; the first frame's sensor pose is the
        identity.
    frames : (n,) int64
        The frame number of each pose.
    skipped : tuple of int
        Frames not registered (partial turns).
    n_points : int
        Points fed to the odometry.
    seconds : float
        Wall time of the odometry itself.
    settings : dict of str to float
        The settings used: ``voxel_size_m`` (the default filled in), ``max_range_m``,
        ``min_range_m`` (m).
    """

    method: str
    times: NDArray[np.float64]
    poses: NDArray[np.float64]
    frames: NDArray[np.int64]
    skipped: tuple[int, ...] = ()
    n_points: int = 0
    seconds: float = 0.0
    settings: dict[str, float] = field(default_factory=dict)

    def __repr__(self) -> str:
        return (f"OdometryResult({self.method}, {len(self.times)} frames, "
                f"{len(self.skipped)} skipped, {self.n_points:,} points, "
                f"{self.seconds:.1f} s)")


def _backend(method: str, voxel_size_m: float, max_range_m: float, min_range_m: float
             ) -> Any:
    """A configured odometry object with ``register_frame(points, stamps)`` and
    ``last_pose``."""
    if method not in ODOMETRY:
        raise OdometryError(f"Expected an odometry in {sorted(ODOMETRY)}, got {method!r}.")
    try:
        importlib.import_module(ODOMETRY[method])
    except ImportError as exc:
        raise OdometryError(f"Expected the {method} package for SLAM, got it missing "
                            f"({exc}); install it with: pip install 'tunnelsim[slam]'.") \
            from None
    if method == "kiss-icp":
        from kiss_icp.config import load_config as kiss_config
        from kiss_icp.kiss_icp import KissICP

        cfg = kiss_config(None)
        cfg.data.deskew = True
        cfg.data.max_range, cfg.data.min_range = max_range_m, min_range_m
        cfg.mapping.voxel_size = voxel_size_m
        return KissICP(cfg)
    from genz_icp.config import load_config as genz_config
    from genz_icp.genz_icp import GenZICP

    gcfg = genz_config(None)
    gcfg.data.deskew = True
    gcfg.data.max_range, gcfg.data.min_range = max_range_m, min_range_m
    gcfg.mapping.voxel_size = voxel_size_m
    return GenZICP(gcfg)


def _whole_frames(frames: Iterable[_Frame], skipped: list[int]) -> Iterator[_Frame]:
    """The frames that are whole turns: a frame is judged against its neighbours (one
    frame of look-ahead), see ``PARTIAL_FRAME``."""
    def span(f: _Frame) -> float:
        return float(f.times.max() - f.times.min()) if len(f.times) > 1 else 0.0

    prev_span = None
    held: _Frame | None = None
    for f in frames:
        if held is not None:
            ref = max(span(f), prev_span or 0.0)
            if span(held) >= PARTIAL_FRAME * ref:
                yield held
            else:
                skipped.append(int(held.frame))
            prev_span = span(held)
        held = f
    if held is not None:
        if prev_span is not None and span(held) >= PARTIAL_FRAME * prev_span:
            yield held
        else:
            skipped.append(int(held.frame))


def run_odometry(frames: Iterable[_Frame], *, method: str = "kiss-icp",
                 voxel_size_m: float | None = None, max_range_m: float = 100.0,
                 min_range_m: float = 0.3,
                 progress: Callable[[int], object] | None = None) -> OdometryResult:
    """Run LiDAR odometry over scan frames.

    Parameters
    ----------
    frames : iterable of frames
        Each with ``frame`` (int), ``points`` (m, 3) float64 in the sensor frame (m) and
        ``times`` (m,) float64 (s), in time order (``survey.clouds.drives.iter_frames``).
    method : {"kiss-icp", "genz-icp"}
    voxel_size_m : float, optional
        Map voxel; ``TUNNEL_VOXEL_M`` of the method by default.
    max_range_m, min_range_m : float
        Points outside this range are ignored by the odometry.
    progress : callable, optional
        Called with the number of frames registered so far.

    Returns
    -------
    OdometryResult

    Raises
    ------
    OdometryError
        For a missing backend, bad settings, or fewer than ``MIN_FRAMES`` whole frames.
    """
    vox = TUNNEL_VOXEL_M.get(method, 0.5) if voxel_size_m is None else float(voxel_size_m)
    for name, v in (("voxel_size_m", vox), ("max_range_m", max_range_m)):
        if not (np.isfinite(v) and v > 0):
            raise OdometryError(f"Expected a positive `{name}`, got {v}.")
    if not (np.isfinite(min_range_m) and 0 <= min_range_m < max_range_m):
        raise OdometryError(f"Expected 0 <= `min_range_m` < `max_range_m`, got "
                            f"{min_range_m} and {max_range_m}.")
    odo = _backend(method, vox, float(max_range_m), float(min_range_m))
    stamp = STAMP[method]
    skipped: list[int] = []
    times, poses, ids = [], [], []
    n_points = 0
    spent = 0.0
    for f in _whole_frames(frames, skipped):
        t = np.asarray(f.times, dtype=np.float64)
        lo, hi = float(t.min()), float(t.max())
        norm = (t - lo) / (hi - lo) if hi > lo else np.zeros_like(t)
        pts = np.ascontiguousarray(f.points, dtype=np.float64)
        t0 = _time.perf_counter()
        odo.register_frame(pts, norm)
        spent += _time.perf_counter() - t0
        poses.append(np.array(odo.last_pose, dtype=np.float64))
        times.append(lo + stamp * (hi - lo))
        ids.append(int(f.frame))
        n_points += len(pts)
        if progress is not None:
            progress(len(poses))
    if len(poses) < MIN_FRAMES:
        raise OdometryError(f"Expected at least {MIN_FRAMES} whole scan frames for SLAM, got "
                            f"{len(poses)} ({len(skipped)} partial); simulate a longer "
                            "drive.")
    p = np.asarray(poses)
    p = np.einsum("ij,njk->nik", np.linalg.inv(p[0]), p)   # first frame = identity
    return OdometryResult(method, np.asarray(times), p, np.asarray(ids, dtype=np.int64),
                          tuple(skipped), n_points, spent,
                          {"voxel_size_m": vox, "max_range_m": float(max_range_m),
                           "min_range_m": float(min_range_m)})


def _matrix(pos: ArrayLike, rot: Rotation) -> NDArray[np.float64]:
    m = np.eye(4)
    m[:3, :3] = rot.as_matrix()
    m[:3, 3] = np.asarray(pos, dtype=np.float64)
    return m


def _extrapolate(a: NDArray[np.float64], b: NDArray[np.float64], f: float
                 ) -> NDArray[np.float64]:
    """The pose reached from ``a`` by ``f`` times the motion a -> b (constant velocity:
    rotation vector and translation scaled alike)."""
    d = np.linalg.inv(a) @ b
    step = np.eye(4)
    step[:3, :3] = Rotation.from_rotvec(f * Rotation.from_matrix(d[:3, :3]).as_rotvec()
                                        ).as_matrix()
    step[:3, 3] = f * d[:3, 3]
    return a @ step


def odometry_trajectory(result: OdometryResult, mount: Mount | None = None, *,
                        start: tuple[ArrayLike, Rotation] | None = None,
                        span_s: tuple[float, float] | None = None) -> Trajectory:
    """The platform trajectory the odometry implies.

    (Named apart from ``sensors.platform.platform_trajectory``, which drives a
    platform along a path: this one turns estimated sensor poses into platform poses.)

    Parameters
    ----------
    result : OdometryResult
    mount : Mount, optional
        The sensor's mount on the platform (identity: platform = sensor).
    start : (position (3,), Rotation), optional
        The platform's pose at the first estimated time (a known start point, as a
        surveyor sets up an MLS run on a control point); the odometry frame's origin
        otherwise.
    span_s : (float, float), optional
        Extend the trajectory to these times with the first and last estimated motion
        (constant velocity), e.g. to the drive's first and last point.

    Returns
    -------
    Trajectory
        Platform poses at ``result.times`` (plus the two ends of ``span_s``).
    """
    mnt = Mount() if mount is None else mount
    m = _matrix(mnt.lever_arm_m, mnt.boresight)
    anchor = np.eye(4) if start is None else _matrix(start[0], start[1])
    # P_k = A M S_k M^-1 (S_0 = I: the first platform pose is the anchor).
    world = np.einsum("ij,njk,kl->nil", anchor @ m, result.poses, np.linalg.inv(m))
    t = np.asarray(result.times, dtype=np.float64)
    if span_s is not None:
        a, b = float(span_s[0]), float(span_s[1])
        if a < t[0] - 1e-9:
            world = np.concatenate([_extrapolate(world[0], world[1],
                                                 (a - t[0]) / (t[1] - t[0]))[None], world])
            t = np.r_[a, t]
        if b > t[-1] + 1e-9:
            world = np.concatenate([world, _extrapolate(world[-2], world[-1],
                                                        (b - t[-2]) / (t[-1] - t[-2]))[None]])
            t = np.r_[t, b]
    return Trajectory(t, world[:, :3, 3], Rotation.from_matrix(world[:, :3, :3]))
