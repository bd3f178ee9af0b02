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

>>> traj = Trajectory.along_polyline([[0.0, 0, 0], [12.0, 0, 0]], 1.0, rate_hz=10)
>>> traj
Trajectory(121 poses, 0.0-12.0 s, 12.0 m path)
>>> Mount.pointing_down((0.0, 0.0, 0.3))
Mount(lever_arm_m=(0.0, 0.0, 0.3), roll/pitch/yaw 180, 0, 0 deg)
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation, Slerp

from raytrace.fileio import atomic_writer

from ._checks import as_number, as_points
from .errors import TrajectoryError

__all__ = ["Mount", "Trajectory"]


@dataclass(frozen=True)
class Mount:
    """Lever arm and boresight from the platform to the sensor.

    Parameters
    ----------
    lever_arm_m : (3,) array_like of float
        Sensor origin in the platform frame (m); stored as a tuple.
    boresight : scipy Rotation
        One rotation, platform axes -> sensor axes; identity by default.
    """

    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    boresight: Rotation = field(default_factory=Rotation.identity)

    def __post_init__(self) -> None:
        try:
            la = np.asarray(self.lever_arm_m, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            la = np.empty(0)
        if la.shape != (3,) or not np.isfinite(la).all():
            raise TrajectoryError(f"Expected a lever arm of 3 finite numbers (m), got "
                                  f"{self.lever_arm_m!r}.")
        object.__setattr__(self, "lever_arm_m", tuple(la.tolist()))
        if not isinstance(self.boresight, Rotation) or not self.boresight.single:
            raise TrajectoryError(f"Expected the boresight as one scipy Rotation, got "
                                  f"{type(self.boresight).__name__}; use "
                                  "Mount.from_degrees(...) for angles.")

    @classmethod
    def from_degrees(cls, lever_arm_m: ArrayLike = (0.0, 0.0, 0.0), *,
                     roll_deg: float = 0.0, pitch_deg: float = 0.0,
                     yaw_deg: float = 0.0) -> Mount:
        """Boresight from roll, pitch, yaw in degrees (extrinsic x, y, z); the angles
        are keyword-only."""
        angles = [as_number(v, n, TrajectoryError, unit="deg")
                  for v, n in ((roll_deg, "roll_deg"), (pitch_deg, "pitch_deg"),
                               (yaw_deg, "yaw_deg"))]
        return cls(lever_arm_m,  # type: ignore[arg-type]
                   Rotation.from_euler("xyz", angles, degrees=True))

    @classmethod
    def pointing_down(cls, lever_arm_m: ArrayLike = (0.0, 0.0, 0.0)) -> Mount:
        """Sensor z axis along the platform's -z (rolled 180 deg about x): a
        hemispherical lidar such as the Airy looking at the floor."""
        return cls.from_degrees(lever_arm_m, roll_deg=180.0)

    def __repr__(self) -> str:
        arm = f"lever_arm_m={self.lever_arm_m!r}"
        if np.allclose(self.boresight.as_quat(canonical=True), [0, 0, 0, 1], atol=1e-15):
            return f"Mount({arm})"
        rpy = self.boresight.as_euler("xyz", degrees=True)
        rpy = [round(float(a), 9) + 0.0 for a in rpy]      # no -0 or 1e-15 in the text
        return f"Mount({arm}, roll/pitch/yaw {', '.join(f'{a:.6g}' for a in rpy)} deg)"


class Trajectory:
    """Timed platform poses.

    Parameters
    ----------
    times : (n,) array_like of float
        Strictly increasing, seconds.
    positions : (n, 3) array_like of float, or records with fields x, y, z
        World coordinates (m); a single (3,) row for a single pose.
    rotations : scipy Rotation of length n (body -> world), or (n, 4) quaternions
        Scalar-last; a single pose (n = 1) is a static platform.

    Raises
    ------
    TrajectoryError
        For shapes that disagree, non-finite values, or times that do not increase.
    """

    def __init__(self, times: ArrayLike, positions: ArrayLike,
                 rotations: Rotation | ArrayLike) -> None:
        try:
            t = np.atleast_1d(np.asarray(times, dtype=np.float64))
        except (TypeError, ValueError):
            raise TrajectoryError(f"Expected `times` as numbers (s), got "
                                  f"{type(times).__name__}.") from None
        if t.ndim != 1 or len(t) == 0 or not np.isfinite(t).all():
            raise TrajectoryError(f"Expected finite `times` of shape (n,), got shape "
                                  f"{t.shape}.")
        p = as_points(positions, "positions", TrajectoryError)
        if p.shape != (len(t), 3):
            raise TrajectoryError(f"Expected `positions` of shape ({len(t)}, 3), one per "
                                  f"time, got {p.shape}.")
        if len(t) > 1 and (np.diff(t) <= 0).any():
            i = int(np.argmax(np.diff(t) <= 0))
            raise TrajectoryError(f"Expected strictly increasing times, got t[{i}] = {t[i]} "
                                  f"followed by t[{i + 1}] = {t[i + 1]}; sort the poses and "
                                  "drop duplicates.")
        rot = self._rotations(rotations, len(t))
        self.times = t
        self.origin = np.round(p[0])
        self._local = p - self.origin
        self.rotations = rot
        self._slerp = Slerp(t, rot) if len(t) > 1 else None
        self._quat: NDArray[np.float64] | None = None

    @staticmethod
    def _rotations(rotations: Rotation | ArrayLike, n: int) -> Rotation:
        if not isinstance(rotations, Rotation):
            try:
                q = np.asarray(rotations, dtype=np.float64).reshape(-1, 4)
            except (TypeError, ValueError):
                q = np.empty((0, 4))
            if q.shape != (n, 4) or not np.isfinite(q).all() or \
                    (np.linalg.norm(q, axis=1) < 1e-9).any():
                raise TrajectoryError(f"Expected ({n}, 4) non-zero quaternions "
                                      f"(qx, qy, qz, qw), got shape {np.shape(rotations)}.")
            rotations = Rotation.from_quat(q)
        if rotations.single:
            rotations = Rotation.concatenate([rotations])
        if len(rotations) != n:
            raise TrajectoryError(f"Expected {n} rotations, one per time, got "
                                  f"{len(rotations)}.")
        return rotations

    # ------------------------------------------------------------------ builders
    @classmethod
    def static(cls, position: ArrayLike, rotation: Rotation | None = None, *,
               t: float = 0.0) -> Trajectory:
        """One pose at ``position`` (3,), level unless ``rotation`` is given, at time
        ``t`` (keyword-only): a static platform (give the scan's ``t_end``)."""
        rot = Rotation.identity() if rotation is None else rotation
        return cls([as_number(t, "t", TrajectoryError, unit="s")],
                   as_points(position, "position", TrajectoryError), rot)

    @classmethod
    def along_polyline(cls, points: ArrayLike, speed_mps: float, *, rate_hz: float = 100.0,
                       start_time: float = 0.0, follow_grade: bool = False) -> Trajectory:
        """Constant speed along a polyline (n, 3), heading along it (x forward, z up;
        level unless ``follow_grade``), sampled at ``rate_hz``."""
        pts = as_points(points, "points", TrajectoryError)
        if len(pts) < 2:
            raise TrajectoryError(f"Expected at least 2 polyline points of shape (n, 3), "
                                  f"got {len(pts)}.")
        speed_mps = as_number(speed_mps, "speed_mps", TrajectoryError, unit="m/s", lo=0,
                              lo_open=True)
        rate_hz = as_number(rate_hz, "rate_hz", TrajectoryError, unit="Hz", lo=0,
                            lo_open=True)
        start_time = as_number(start_time, "start_time", TrajectoryError, unit="s")
        origin = np.round(pts[0])
        q = pts - origin
        seg = np.linalg.norm(np.diff(q, axis=0), axis=1)
        if (seg <= 0).any():
            raise TrajectoryError("Expected distinct consecutive polyline points, got a "
                                  f"repeated point at row {int(np.argmax(seg <= 0)) + 1}.")
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

    def with_standstill(self, before_s: float = 0.0, after_s: float = 0.0) -> Trajectory:
        """The same path with the platform standing still for ``before_s`` at its first
        pose (the path's times shift by ``before_s``) and ``after_s`` at its last, as a
        real MLS run starts and ends: SLAM initialises on a still sensor."""
        before_s = as_number(before_s, "before_s", TrajectoryError, unit="s", lo=0)
        after_s = as_number(after_s, "after_s", TrajectoryError, unit="s", lo=0)
        if len(self) < 2:
            raise TrajectoryError("Expected a moving trajectory (2 poses or more), got a "
                                  "static one; give a static platform a duration instead.")
        t, p, q = self.times + before_s, self.positions, self.rotations.as_quat()
        if before_s > 0:
            t, p, q = np.r_[self.times[0], t], np.vstack([p[:1], p]), np.vstack([q[:1], q])
        if after_s > 0:
            t, p, q = np.r_[t, t[-1] + after_s], np.vstack([p, p[-1:]]), np.vstack([q, q[-1:]])
        return Trajectory(t, p, q)

    # ------------------------------------------------------------------ access
    def __len__(self) -> int:
        return len(self.times)

    def __repr__(self) -> str:
        if len(self) == 1:
            at = ", ".join(f"{c:.6g}" for c in self.positions[0])
            return f"Trajectory(static at ({at}), t = {self.start_s:.6g} s)"
        path = float(np.linalg.norm(np.diff(self._local, axis=0), axis=1).sum())
        return (f"Trajectory({len(self)} poses, {self.start_s:.1f}-{self.end_s:.1f} s, "
                f"{path:.1f} m path)")

    @property
    def positions(self) -> NDArray[np.float64]:
        """(n, 3) float64 world coordinates of the poses."""
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

    def _query_times(self, t: ArrayLike) -> NDArray[np.float64]:
        """``t`` as contiguous (n,) float64, within the trajectory's span (to rounding)
        unless it is static."""
        try:
            q = np.ascontiguousarray(np.atleast_1d(np.asarray(t, dtype=np.float64)))
        except (TypeError, ValueError):
            raise TrajectoryError(f"Expected times as numbers (s), got "
                                  f"{type(t).__name__}.") from None
        if q.ndim != 1:
            raise TrajectoryError(f"Expected times of shape (n,), got {q.shape}.")
        lo, hi = self.times[0], self.times[-1]
        eps = 1e-9 * max(1.0, abs(hi))
        if len(self) > 1 and len(q) and not (q.min() >= lo - eps and q.max() <= hi + eps):
            raise TrajectoryError(f"Expected times within the trajectory [{lo}, {hi}] s, "
                                  f"got [{np.min(q)}, {np.max(q)}].")
        return q

    def interpolate(self, t: ArrayLike, *, local: bool = False
                    ) -> tuple[NDArray[np.float64], Rotation]:
        """Poses at times t (n,): positions (n, 3) (world, or relative to ``origin``
        with ``local``) and a Rotation of length n."""
        t = self._query_times(t)
        if self._slerp is None:
            pos = np.broadcast_to(self._local[0], (len(t), 3)).copy()
            rot = Rotation.from_quat(np.tile(self.rotations.as_quat()[0], (len(t), 1)))
        else:
            tc = np.clip(t, self.times[0], self.times[-1])
            pos = np.stack([np.interp(tc, self.times, self._local[:, k]) for k in range(3)],
                           1)
            rot = self._slerp(tc)
        return (pos if local else pos + self.origin), rot

    def sensor_matrices(self, t: ArrayLike, mount: Mount
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Sensor positions (n, 3) (world) and sensor-to-world matrices (n, 3, 3) at
        times t: the fast path of the simulation loop. Quaternion SLERP (Shoemake 1985)
        in Numba, equal to ``sensor_poses`` (scipy's Slerp) to rounding."""
        from ._kernels.poses import interpolate_poses

        t = self._query_times(t)
        if self._quat is None:
            self._quat = np.ascontiguousarray(self.rotations.as_quat())
        pos = np.empty((len(t), 3))
        mat = np.empty((len(t), 3, 3))
        interpolate_poses(self.times, self._local, self._quat, t,
                          np.asarray(mount.lever_arm_m, dtype=np.float64),
                          np.ascontiguousarray(mount.boresight.as_matrix()), pos, mat)
        pos += self.origin
        return pos, mat

    def sensor_poses(self, t: ArrayLike, mount: Mount, *, local: bool = False
                     ) -> tuple[NDArray[np.float64], Rotation]:
        """Sensor positions (n, 3) and sensor-to-world rotations at times t."""
        pos, rot = self.interpolate(t, local=local)
        return pos + rot.apply(np.asarray(mount.lever_arm_m)), rot * mount.boresight

    # ------------------------------------------------------------------ files
    def write(self, path: str | os.PathLike[str]) -> Path:
        """TUM text (``.txt``/``.tum``) or CSV (``.csv``), chosen by the suffix; atomic.
        Returns the path."""
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
    def read(cls, path: str | os.PathLike[str]) -> Trajectory:
        """Read TUM text or CSV (by suffix).

        Raises
        ------
        TrajectoryError
            For a missing or unreadable file, or rows that are not 8 numbers.
        """
        path = Path(path)
        if not path.is_file():
            raise TrajectoryError(f"Expected a trajectory file, got '{path}' which does not "
                                  "exist.")
        try:
            if path.suffix.lower() == ".csv":
                data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
            else:
                data = np.loadtxt(path, comments="#", ndmin=2)
        except (ValueError, UnicodeDecodeError) as exc:
            raise TrajectoryError(f"Expected rows of 8 numbers (t x y z qx qy qz qw) in "
                                  f"'{path}', got unreadable text ({exc}).") from exc
        if data.shape[1] != 8:
            raise TrajectoryError(f"Expected 8 columns (t x y z qx qy qz qw) in '{path}', got "
                                  f"{data.shape[1]}.")
        return cls(data[:, 0], data[:, 1:4], data[:, 4:8])
