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
2012) and CSV, written with the header ``t,x,y,z,qx,qy,qz,qw`` and read by its header
names in any order (``CSV_COLUMNS``; a headerless CSV is 8 numbers a row in TUM order).
Quaternions are scalar-last, as in scipy. Times are seconds: stamps that can only be
nanoseconds, microseconds or milliseconds are refused on reading
(``looks_like_time_unit``).

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

__all__ = ["CSV_COLUMNS", "MAX_SPAN_S", "MAX_STAMP_S", "MAX_STEP_S", "Mount", "Trajectory",
           "csv_column_order", "looks_like_time_unit", "time_base_hint"]


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


def _trapezoid(length_m: float, speed_mps: float, accel_mps2: float, rate_hz: float
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(times, distances) sampled at ``rate_hz`` of a trip of ``length_m`` from rest to
    rest: accelerate at ``accel_mps2`` to ``speed_mps``, cruise, brake alike."""
    v = min(speed_mps, float(np.sqrt(accel_mps2 * length_m)))   # peak (triangular)
    ta = v / accel_mps2
    da = 0.5 * v * ta
    tc = (length_m - 2 * da) / v
    total = 2 * ta + tc
    t = np.linspace(0.0, total, max(3, int(np.ceil(total * rate_hz)) + 1))
    d = np.where(t < ta, 0.5 * accel_mps2 * t ** 2,
                 np.where(t < ta + tc, da + v * (t - ta),
                          length_m - 0.5 * accel_mps2 * np.maximum(total - t, 0.0) ** 2))
    d[-1] = length_m
    return t, np.maximum.accumulate(np.clip(d, 0.0, length_m))


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
                       start_time: float = 0.0, follow_grade: bool = False,
                       accel_mps2: float | None = None) -> Trajectory:
        """Constant speed along a polyline (n, 3), heading along it (x forward, z up;
        level unless ``follow_grade``), sampled at ``rate_hz``. With ``accel_mps2`` the
        platform starts and ends at rest, accelerating and braking at that rate
        (trapezoidal speed profile; triangular when the path is too short to reach
        ``speed_mps``); otherwise it moves at ``speed_mps`` from the first instant."""
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
        if accel_mps2 is None:
            n = max(2, int(np.ceil(s[-1] / speed_mps * rate_hz)) + 1)
            ss = np.linspace(0.0, s[-1], n)
            tt = ss / speed_mps
        else:
            accel_mps2 = as_number(accel_mps2, "accel_mps2", TrajectoryError, unit="m/s^2",
                                   lo=0, lo_open=True)
            tt, ss = _trapezoid(s[-1], speed_mps, accel_mps2, rate_hz)
        pos = np.stack([np.interp(ss, s, q[:, k]) for k in range(3)], 1) + origin
        # Heading from the segment each sample lies on.
        iseg = np.clip(np.searchsorted(s, ss, side="right") - 1, 0, len(seg) - 1)
        d = np.diff(q, axis=0)[iseg]
        yaw = np.arctan2(d[:, 1], d[:, 0])
        pitch = -np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])) if follow_grade else 0 * yaw
        rot = Rotation.from_euler("ZYX", np.stack([yaw, pitch, 0 * yaw], 1))
        return cls(start_time + tt, pos, rot)

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
                                  f"got [{np.min(q)}, {np.max(q)}]"
                                  f"{time_base_hint(self.times, q)}.")
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
        pos, mat, _ = self._matrices(t, mount, per_instant=False)
        return pos, mat

    def instant_matrices(self, t: ArrayLike, mount: Mount
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                    NDArray[np.int64]]:
        """``sensor_matrices`` with one matrix per firing instant: positions (n, 3),
        matrices (r, 3, 3) for the r runs of equal times in t, and each time's row
        (n,) int64, so that ``matrices[rows]`` is ``sensor_matrices``' (n, 3, 3) bit
        for bit (the simulation loop's form: the Airy fires eight channels at once)."""
        return self._matrices(t, mount, per_instant=True)

    def _matrices(self, t: ArrayLike, mount: Mount, per_instant: bool
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
        """``sensor_matrices`` or, with ``per_instant``, ``instant_matrices`` (the third
        array empty without it)."""
        from ._kernels.poses import interpolate_poses

        t = self._query_times(t)
        if self._quat is None:
            self._quat = np.ascontiguousarray(self.rotations.as_quat())
        # DECISION: pulses fired at one instant (the Airy fires 8 channels at a time)
        # share one pose: it is interpolated once per run of equal times and written to
        # each pulse of the run, the same bits at an eighth of the work (poses were 7 %
        # of a drive; issue 16). The simulation loop keeps one matrix per run and an
        # index per pulse (72 bytes a pulse written and read twice less; issue 33).
        first = np.ones(len(t), dtype=np.bool_)
        np.not_equal(t[1:], t[:-1], out=first[1:])
        rows = np.append(np.flatnonzero(first), len(t))
        pos = np.empty((len(t), 3))
        mat = np.empty((len(rows) - 1 if per_instant else len(t), 3, 3))
        which = np.empty(len(t) if per_instant else 0, dtype=np.int64)
        interpolate_poses(self.times, self._local, self._quat, t[rows[:-1]], rows,
                          np.asarray(mount.lever_arm_m, dtype=np.float64),
                          np.ascontiguousarray(mount.boresight.as_matrix()),
                          np.asarray(self.origin, dtype=np.float64), pos, mat, which)
        return pos, mat, which

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
        """Read a TUM text file or a CSV file (``.csv``), chosen by the suffix.

        TUM: ``t x y z qx qy qz qw`` separated by spaces, '#' comments (Sturm et al.
        2012). CSV: see ``CSV_COLUMNS`` for the header names and the headerless rule.
        Times must be seconds: stamps that look like nanoseconds, microseconds or
        milliseconds (``looks_like_time_unit``) are refused with the factor to divide by.

        Raises
        ------
        TrajectoryError
            For a missing or unreadable file, rows that are not 8 numbers, an unknown,
            missing or repeated CSV column, or stamps that are not seconds.
        """
        path = Path(path)
        if not path.is_file():
            raise TrajectoryError(f"Expected a trajectory file, got '{path}' which does not "
                                  "exist.")
        try:
            if path.suffix.lower() == ".csv":
                data = _read_csv(path)
            else:
                data = np.loadtxt(path, comments="#", ndmin=2)
        except (ValueError, UnicodeDecodeError) as exc:
            if isinstance(exc, TrajectoryError):
                raise
            raise TrajectoryError(f"Expected rows of 8 numbers (t x y z qx qy qz qw) in "
                                  f"'{path}', got unreadable text ({exc}).") from exc
        if data.shape[1] != 8:
            raise TrajectoryError(f"Expected 8 columns (t x y z qx qy qz qw) in '{path}', got "
                                  f"{data.shape[1]}.")
        if len(data) and np.isfinite(data[:, 0]).all():
            _check_seconds(data[:, 0], path)
        return cls(data[:, 0], data[:, 1:4], data[:, 4:8])


# ---------------------------------------------------------------------- reading files
#: The fields of a pose in TUM order, and the CSV header names each may go by
#: (case-insensitive, in any column order; a leading '#' on the header is dropped, as
#: EuRoC writes "#timestamp"). ``tx, ty, tz`` are translations (ROS, evo), not times.
#: DECISION: a CSV header is required to name all 8 columns and nothing else: a column
#: read by its position would put ``qw`` where ``qx`` is meant without a word (a
#: ``timestamp,px,py,pz,qw,qx,qy,qz`` file turned the spin axis horizontal).
#: Headerless rule: when every field of the first line is a number, the file has no
#: header and each row is 8 numbers in TUM order ``t, x, y, z, qx, qy, qz, qw``; the
#: first line is then the first pose.
CSV_COLUMNS: dict[str, tuple[str, ...]] = {
    "t": ("t", "timestamp", "time"), "x": ("x", "px", "tx"), "y": ("y", "py", "ty"),
    "z": ("z", "pz", "tz"), "qx": ("qx",), "qy": ("qy",), "qz": ("qz",), "qw": ("qw",)}

_ALIAS = {name: field for field, names in CSV_COLUMNS.items() for name in names}


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def csv_column_order(header: list[str]) -> list[int]:
    """The column of each pose field (TUM order) in a CSV header's names.

    Parameters
    ----------
    header : list of str
        The header's names, in file order.

    Returns
    -------
    list of int, (8,)
        The file's column index of t, x, y, z, qx, qy, qz, qw.

    Raises
    ------
    TrajectoryError
        For a name not in ``CSV_COLUMNS``, a field named twice or a field missing.
    """
    names = [h.strip().strip("'\"").strip().lower() for h in header]
    if names:
        names[0] = names[0].lstrip("#").strip()
    unknown = [h.strip() for h, n in zip(header, names) if n not in _ALIAS]
    if unknown:
        known = ", ".join("|".join(v) for v in CSV_COLUMNS.values())
        raise TrajectoryError(f"Expected CSV trajectory columns named {known} (any order), "
                              f"got unknown {', '.join(repr(u) for u in unknown)}; rename "
                              "or remove those columns.")
    where: dict[str, list[int]] = {}
    for i, n in enumerate(names):
        where.setdefault(_ALIAS[n], []).append(i)
    twice = {f: cols for f, cols in where.items() if len(cols) > 1}
    if twice:
        f, cols = next(iter(twice.items()))
        raise TrajectoryError(f"Expected one column for {f}, got "
                              f"{' and '.join(repr(header[i].strip()) for i in cols)}; "
                              "keep one of them.")
    missing = [f for f in CSV_COLUMNS if f not in where]
    if missing:
        raise TrajectoryError(f"Expected the 8 columns t, x, y, z, qx, qy, qz, qw in a CSV "
                              f"trajectory header, got none for {', '.join(missing)}.")
    return [where[f][0] for f in CSV_COLUMNS]


def _read_csv(path: Path) -> NDArray[np.float64]:
    """(n, 8) float64 rows in TUM order from a CSV trajectory (``CSV_COLUMNS``), its
    dialect sniffed as for control points (``sensors.io.tables``: delimiter, decimal comma,
    encoding; a '#' header as EuRoC writes it). A header names the 8 columns and nothing
    else; a headerless file is 8 numbers a row in TUM order."""
    from sensors.io.tables import map_columns, numeric_columns, read_table

    fields = tuple(CSV_COLUMNS)
    tab = read_table(path, what="CSV trajectory", error=TrajectoryError, hash_header=True)
    if not tab.rows:
        raise TrajectoryError(f"Expected poses in the CSV trajectory '{path}'"
                              + (" below its header" if tab.names else "")
                              + ", got none.")
    col = map_columns(tab, CSV_COLUMNS, fields, headerless=fields, unknown="error",
                      what="CSV trajectory", flag="", error=TrajectoryError)
    return numeric_columns(tab, col, fields, what="CSV trajectory", flag="",
                           error=TrajectoryError)


#: Stamps read as seconds must stay within these (ASSUMED, generous): a trajectory of a
#: survey spans less than a day, has a pose at least every hour, and has no stamp above
#: 1e11 s (the year 5138 as Unix time). Nanoseconds (ROS ``stamp.to_nsec()``, 1.7e18
#: since 1970), microseconds and milliseconds break at least one of them for any drive
#: longer than a few seconds.
MAX_SPAN_S = 86_400.0
MAX_STEP_S = 3_600.0
MAX_STAMP_S = 1e11
#: Units a stamp might be in instead of seconds, with their factor to seconds.
_TIME_UNITS = (("nanoseconds", 1e-9), ("microseconds", 1e-6), ("milliseconds", 1e-3))
#: Unix times (s) of plausible survey dates, 1973 to 2286, to recognise epoch stamps.
_EPOCH_S = (1e8, 1e10)
#: The pose interval (s) a unit is judged by: the geometric middle of 1 Hz and 1 kHz,
#: so that each unit is named right for any pose rate between the two.
_TYPICAL_STEP_S = 10 ** -1.5


def looks_like_time_unit(times: ArrayLike) -> tuple[str, float] | None:
    """The unit that stamps (n,) float64 seem to be in when they cannot be seconds:
    (name, factor to seconds), or None when they can be seconds.

    Seconds are ruled out by ``MAX_SPAN_S``, ``MAX_STEP_S`` or ``MAX_STAMP_S``. The unit
    named is the one that turns the first stamp into a Unix time of 1973-2286 when the
    stamps are that large (epoch stamps), else the one that puts the median step
    nearest (in ratio) 32 ms, the middle of pose rates from 1 Hz to 1 kHz.

    >>> looks_like_time_unit([1.7e18, 1.7e18 + 1e7])
    ('nanoseconds', 1e-09)
    >>> looks_like_time_unit([0.0, 1e4, 2e4]) is None, looks_like_time_unit([0.0, 0.01])
    (False, None)
    """
    t = np.atleast_1d(np.asarray(times, dtype=np.float64))
    step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    big = float(np.abs(t).max()) > MAX_STAMP_S
    if not (big or t[-1] - t[0] > MAX_SPAN_S or step > MAX_STEP_S):
        return None
    if big:
        for name, f in _TIME_UNITS:
            if _EPOCH_S[0] <= abs(t[0]) * f <= _EPOCH_S[1]:
                return name, f
    if step <= 0:
        return _TIME_UNITS[0]
    return min(_TIME_UNITS, key=lambda u: abs(np.log10(step * u[1] / _TYPICAL_STEP_S)))


def _check_seconds(t: NDArray[np.float64], path: Path) -> None:
    unit = looks_like_time_unit(t)
    if unit is None:
        return
    name, f = unit
    if len(t) > 1:
        step = float(np.median(np.diff(t)))
        got = (f"stamps from {t[0]:.6g} spanning {t[-1] - t[0]:.6g} with a median step of "
               f"{step:.6g}, which look like {name} (a pose every {1e3 * f * step:.3g} ms)")
    else:
        got = f"the stamp {t[0]:.6g}, which looks like {name}"
    raise TrajectoryError(f"Expected trajectory times in seconds in '{path}', got {got}; "
                          "convert the time column to seconds (divide it by "
                          f"1e{round(-np.log10(f))}).")


def time_base_hint(times_s: ArrayLike, other_s: ArrayLike) -> str:
    """A hint for two sets of times (s) that do not meet: '' unless one starts like an
    epoch time (``_EPOCH_S``: Unix time, or GPS time less 1e9 as LAS 1.4 stores it)
    and the other like seconds from a start (below ``_EPOCH_S[0]``); then the clause
    that says so and how to give both one time base."""
    a = float(np.min(times_s)) if np.size(times_s) else 0.0
    b = float(np.min(other_s)) if np.size(other_s) else 0.0
    if (a >= _EPOCH_S[0]) == (b >= _EPOCH_S[0]):
        return ""
    epoch, rel = ("the trajectory's", "the others") if a >= b else \
        ("the others", "the trajectory's")
    return (f"; {epoch} look like epoch seconds (from {max(a, b):.10g}) and {rel} like "
            f"seconds from a start (from {min(a, b):.6g}): give both one time base, e.g. "
            f"subtract {max(a, b) - min(a, b):.10g} s from the epoch ones")
