"""Platform motion: timed poses, interpolation, mounting, TUM/CSV files.

A ``Trajectory`` holds poses of the platform body frame (x forward, y left, z up) in
world coordinates at strictly increasing times. Positions are interpolated linearly,
attitudes by spherical linear interpolation (``scipy.spatial.transform.Slerp``;
Shoemake 1985). Positions are kept relative to a local origin (the first position
rounded to a metre) so that UTM-sized coordinates keep their precision through the
arithmetic; ``positions`` returns world coordinates.

A ``Mount`` is the lever arm (platform frame, metres) and boresight rotation from the
platform to the sensor frame: sensor-to-world = platform-to-world * mount.

File formats: TUM (``t x y z qx qy qz qw``, space separated, '#' comments; Sturm et al.
2012) and CSV with the header ``t,x,y,z,qx,qy,qz,qw``. Quaternions are scalar-last,
as in scipy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from raytrace.fileio import atomic_writer

from .errors import TrajectoryError


@dataclass(frozen=True)
class Mount:
    """Lever arm ``lever_arm_m`` (3,) in the platform frame and boresight rotation
    (platform -> sensor axes)."""

    lever_arm_m: tuple = (0.0, 0.0, 0.0)
    boresight: Rotation = field(default_factory=Rotation.identity)

    def __post_init__(self):
        la = np.asarray(self.lever_arm_m, dtype=np.float64)
        if la.shape != (3,) or not np.isfinite(la).all():
            raise TrajectoryError(f"Expected a lever arm of 3 finite numbers (m), got "
                                  f"{self.lever_arm_m!r}.")
        object.__setattr__(self, "lever_arm_m", tuple(la.tolist()))
        if not isinstance(self.boresight, Rotation) or not self.boresight.single:
            raise TrajectoryError("Expected the boresight as one scipy Rotation.")

    @classmethod
    def from_degrees(cls, lever_arm_m=(0.0, 0.0, 0.0), roll_deg=0.0, pitch_deg=0.0,
                     yaw_deg=0.0) -> "Mount":
        """Boresight from roll, pitch, yaw in degrees (extrinsic x, y, z)."""
        return cls(lever_arm_m, Rotation.from_euler("xyz", [roll_deg, pitch_deg, yaw_deg],
                                                    degrees=True))

    @classmethod
    def pointing_down(cls, lever_arm_m=(0.0, 0.0, 0.0)) -> "Mount":
        """Sensor z axis along the platform's -z (rolled 180 deg about x): a
        hemispherical lidar such as the Airy looking at the floor."""
        return cls.from_degrees(lever_arm_m, roll_deg=180.0)


class Trajectory:
    """Timed platform poses.

    Parameters
    ----------
    times : (n,) float64, strictly increasing, seconds
    positions : (n, 3) float64 world coordinates
    rotations : scipy Rotation of length n (body -> world), or (n, 4) quaternions
        scalar-last; a single pose (n = 1) is a static platform.
    """

    def __init__(self, times, positions, rotations):
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        p = np.asarray(positions, dtype=np.float64)
        if t.ndim != 1 or len(t) == 0 or not np.isfinite(t).all():
            raise TrajectoryError(f"Expected finite `times` of shape (n,), got shape "
                                  f"{t.shape}.")
        if p.shape != (len(t), 3) or not np.isfinite(p).all():
            raise TrajectoryError(f"Expected `positions` of shape ({len(t)}, 3) and finite, "
                                  f"got {np.shape(positions)}.")
        if len(t) > 1 and (np.diff(t) <= 0).any():
            i = int(np.argmax(np.diff(t) <= 0))
            raise TrajectoryError(f"Expected strictly increasing times, got t[{i}] = {t[i]} "
                                  f"followed by t[{i + 1}] = {t[i + 1]}; sort the poses and "
                                  "drop duplicates.")
        if not isinstance(rotations, Rotation):
            q = np.asarray(rotations, dtype=np.float64).reshape(-1, 4)
            if q.shape != (len(t), 4) or not np.isfinite(q).all() or \
                    (np.linalg.norm(q, axis=1) < 1e-9).any():
                raise TrajectoryError(f"Expected ({len(t)}, 4) non-zero quaternions "
                                      f"(qx, qy, qz, qw), got shape {np.shape(rotations)}.")
            rotations = Rotation.from_quat(q)
        if rotations.single:
            rotations = Rotation.concatenate([rotations])
        if len(rotations) != len(t):
            raise TrajectoryError(f"Expected {len(t)} rotations, got {len(rotations)}.")
        self.times = t
        self.origin = np.round(p[0])
        self._local = p - self.origin
        self.rotations = rotations
        self._slerp = Slerp(t, rotations) if len(t) > 1 else None
        self._quat = None

    # ------------------------------------------------------------------ builders
    @classmethod
    def static(cls, position, rotation: Rotation | None = None, t: float = 0.0):
        rot = Rotation.identity() if rotation is None else rotation
        return cls([t], np.asarray(position, dtype=np.float64).reshape(1, 3), rot)

    @classmethod
    def along_polyline(cls, points, speed_mps: float, *, rate_hz: float = 100.0,
                       start_time: float = 0.0, follow_grade: bool = False):
        """Constant speed along a polyline (n, 3), heading along it (x forward, z up;
        level unless ``follow_grade``), sampled at ``rate_hz``."""
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2 or not np.isfinite(pts).all():
            raise TrajectoryError(f"Expected at least 2 finite points of shape (n, 3), got "
                                  f"{pts.shape}.")
        if not (np.isfinite(speed_mps) and speed_mps > 0):
            raise TrajectoryError(f"Expected a positive speed, got {speed_mps} m/s.")
        origin = np.round(pts[0])
        q = pts - origin
        seg = np.linalg.norm(np.diff(q, axis=0), axis=1)
        if (seg <= 0).any():
            raise TrajectoryError("Expected distinct consecutive polyline points, got a "
                                  "repeated point.")
        s = np.concatenate([[0.0], np.cumsum(seg)])
        n = max(2, int(np.ceil(s[-1] / speed_mps * rate_hz)) + 1)
        ss = np.linspace(0.0, s[-1], n)
        pos = np.stack([np.interp(ss, s, q[:, k]) for k in range(3)], 1) + origin
        # Heading from the segment each sample lies on.
        iseg = np.clip(np.searchsorted(s, ss, side="right") - 1, 0, len(seg) - 1)
        d = np.diff(q, axis=0)[iseg]
        yaw = np.arctan2(d[:, 1], d[:, 0])
        pitch = -np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])) if follow_grade else 0 * yaw
        rot = Rotation.from_euler("ZYX", np.stack([yaw, pitch, 0 * yaw], 1))
        return cls(start_time + ss / speed_mps, pos, rot)

    # ------------------------------------------------------------------ access
    @property
    def positions(self) -> np.ndarray:
        return self._local + self.origin

    @property
    def start_s(self) -> float:
        return float(self.times[0])

    @property
    def end_s(self) -> float:
        return float(self.times[-1])

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def interpolate(self, t, *, local: bool = False):
        """Poses at times t (n,): positions (n, 3) (world, or relative to ``origin``
        with ``local``) and a Rotation of length n."""
        t = np.asarray(t, dtype=np.float64)
        if len(self.times) == 1:
            pos = np.broadcast_to(self._local[0], (len(t), 3)).copy()
            rot = Rotation.from_quat(np.tile(self.rotations.as_quat()[0], (len(t), 1)))
        else:
            lo, hi = self.times[0], self.times[-1]
            eps = 1e-9 * max(1.0, abs(hi))
            if len(t) and (t.min() < lo - eps or t.max() > hi + eps):
                raise TrajectoryError(f"Expected times within the trajectory [{lo}, {hi}] s, "
                                      f"got [{t.min()}, {t.max()}].")
            tc = np.clip(t, lo, hi)
            pos = np.stack([np.interp(tc, self.times, self._local[:, k]) for k in range(3)],
                           1)
            rot = self._slerp(tc)
        return (pos if local else pos + self.origin), rot

    def sensor_matrices(self, t, mount: Mount):
        """Sensor positions (n, 3) (world) and sensor-to-world matrices (n, 3, 3) at
        times t: the fast path of the simulation loop. Quaternion SLERP (Shoemake 1985)
        in NumPy, equal to ``sensor_poses`` (scipy's Slerp) to rounding."""
        from ._kernels.poses import interpolate_poses

        t = np.ascontiguousarray(t, dtype=np.float64)
        lo, hi = self.times[0], self.times[-1]
        eps = 1e-9 * max(1.0, abs(hi))
        if len(self.times) > 1 and len(t) and (t.min() < lo - eps or t.max() > hi + eps):
            raise TrajectoryError(f"Expected times within the trajectory [{lo}, {hi}] s, "
                                  f"got [{t.min()}, {t.max()}].")
        if self._quat is None:
            self._quat = np.ascontiguousarray(self.rotations.as_quat())
        pos = np.empty((len(t), 3))
        mat = np.empty((len(t), 3, 3))
        interpolate_poses(self.times, self._local, self._quat, t,
                          np.asarray(mount.lever_arm_m, dtype=np.float64),
                          np.ascontiguousarray(mount.boresight.as_matrix()), pos, mat)
        pos += self.origin
        return pos, mat

    def sensor_poses(self, t, mount: Mount, *, local: bool = False):
        """Sensor positions (n, 3) and sensor-to-world rotations at times t."""
        pos, rot = self.interpolate(t, local=local)
        return pos + rot.apply(np.asarray(mount.lever_arm_m)), rot * mount.boresight

    # ------------------------------------------------------------------ files
    def write(self, path):
        """TUM text (``.txt``/``.tum``) or CSV (``.csv``), chosen by the suffix; atomic."""
        path = Path(path)
        q = self.rotations.as_quat()
        data = np.column_stack([self.times, self.positions, q])
        with atomic_writer(path, "w") as fh:
            if path.suffix.lower() == ".csv":
                fh.write("t,x,y,z,qx,qy,qz,qw\n")
                np.savetxt(fh, data, delimiter=",", fmt="%.9f")
            else:
                fh.write("# t x y z qx qy qz qw (TUM)\n")
                np.savetxt(fh, data, fmt="%.9f")
        return path

    @classmethod
    def read(cls, path) -> "Trajectory":
        """Read TUM text or CSV (by suffix)."""
        path = Path(path)
        if not path.is_file():
            raise TrajectoryError(f"Expected a trajectory file, got '{path}' which does not "
                                  "exist.")
        try:
            if path.suffix.lower() == ".csv":
                data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
            else:
                data = np.loadtxt(path, comments="#", ndmin=2)
        except ValueError as exc:
            raise TrajectoryError(f"Expected rows of 8 numbers (t x y z qx qy qz qw) in "
                                  f"'{path}', got unreadable text ({exc}).") from exc
        if data.shape[1] != 8:
            raise TrajectoryError(f"Expected 8 columns (t x y z qx qy qz qw) in '{path}', got "
                                  f"{data.shape[1]}.")
        return cls(data[:, 0], data[:, 1:4], data[:, 4:8])
