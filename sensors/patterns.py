"""Scan patterns with per-pulse timing, generated in chunks.

Every pattern yields ``Pulses`` chunks: the time of each pulse, its unit direction in
the sensor frame (x forward, y left, z up), and its channel (row), column and frame
indices. Nothing is materialised beyond one chunk, so a 225-million-ray TLS station
streams in bounded memory.

- ``TLSScan`` (Z+F IMAGER-type): a mirror rotating about the horizontal axis sweeps a
  vertical great circle at ``measurement_rate_hz / n_slots`` revolutions per second,
  n_slots = round(2 pi / step) (the effective step is 2 pi / n_slots); the head turns continuously by one step per mirror
  revolution through ``head_sweep`` (180 deg: each vertical circle covers both sides).
  Slot i of revolution j sits at mirror angle beta = (i + 1/2) step from the zenith and
  head azimuth phi = (j + i / n_slots) step; slots within the blind cone around nadir
  (outside the vertical field) are skipped but take their time. Pulse time
  (j n_slots + i) / measurement_rate. Channel = row along the vertical sweep (0 at the
  lower edge behind), column = j.
- ``SpinningScan`` (Airy, VLP-16, Ouster): column k starts at k T_col; channel c fires
  at k T_col + offset_c with elevation el_c and azimuth +-2 pi f_rot t + az_c (clockwise
  sensors turn negatively about z). Frame = revolution index of the column start,
  column = index of the column within its revolution.
- ``ProfileScan`` (Z+F PROFILER-type): one plane, the sensor's y-z plane; profile p at
  p / rate, point i at angle gamma = 2 pi (i + 1/2) / N from +z towards +y, at time
  (p + i / N) / rate; points inside the blind sector are skipped. Channel = i,
  column = frame = p.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Final, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._checks import as_number, as_whole
from ._kernels.spinning import spinning_columns
from ._threads import run_parts
from .errors import SimulationError
from .spec import ProfilerPattern, SensorSpec, SpinningPattern, TLSPattern

__all__ = ["CHUNK_PULSES", "ProfileScan", "Pulses", "Scan", "SpinningScan", "TLSScan",
           "chunk_size", "scan_for"]

_P = TypeVar("_P", TLSPattern, SpinningPattern, ProfilerPattern)

#: Default number of pulses per chunk (about 100 MB of simulation state per chunk).
CHUNK_PULSES: Final = 1 << 20


@dataclass
class Pulses:
    """One chunk of pulses.

    Attributes
    ----------
    time : (n,) float64
        Seconds from the start of the scan.
    direction : (n, 3) float64
        Unit vectors in the sensor frame (x forward, y left, z up).
    channel, column, frame : (n,) int32
    """

    time: NDArray[np.float64]
    direction: NDArray[np.float64]
    channel: NDArray[np.int32]
    column: NDArray[np.int32]
    frame: NDArray[np.int32]

    def __len__(self) -> int:
        return len(self.time)

    def __repr__(self) -> str:
        if not len(self):
            return "Pulses(0 pulses)"
        return (f"Pulses({len(self):,} pulses, {self.time[0]:.6g}-{self.time[-1]:.6g} s)")


def chunk_size(chunk_pulses: object) -> int:
    """``chunk_pulses`` as an int >= 1, or a ``SimulationError``."""
    return as_whole(chunk_pulses, "chunk_pulses", SimulationError, lo=1)


def _pattern(spec: SensorSpec, kind: type[_P], what: str) -> _P:
    """The spec's pattern if it is of ``kind``, else the error naming the sensor."""
    if not isinstance(spec, SensorSpec):
        raise SimulationError(f"Expected a SensorSpec, got {type(spec).__name__}; load one "
                              "with load_sensor(name).")
    if not isinstance(spec.pattern, kind):
        raise SimulationError(f"Expected {what}, got {spec.name} ({spec.kind}).")
    return spec.pattern


def _positive_duration(duration_s: object) -> float:
    return as_number(duration_s, "duration_s", SimulationError, unit="s", lo=0, lo_open=True)


class TLSScan:
    """A full TLS station at one angular step (see module doc).

    Parameters
    ----------
    spec : SensorSpec
        A TLS sensor.
    resolution : str, optional
        A preset of the sensor; its default if neither this nor ``step_rad`` is given.
    step_rad : float, optional, keyword-only
        Angular step (rad) instead of a preset, 1e-6 rad to 10 degrees.
    window_rad : (4,) array_like of float, optional, keyword-only
        (az_min, az_max, el_min, el_max), radians, sensor frame.
    """

    def __init__(self, spec: SensorSpec, resolution: str | None = None, *,
                 step_rad: float | None = None, window_rad: ArrayLike | None = None) -> None:
        p = _pattern(spec, TLSPattern, "a TLS sensor for a station scan")
        if step_rad is None:
            resolution = resolution or p.default_resolution
            if resolution not in p.resolutions_rad:
                raise SimulationError(f"Expected a resolution of {spec.name} in "
                                      f"{sorted(p.resolutions_rad)}, got {resolution!r}.")
            step_rad = p.resolutions_rad[resolution]
        step_rad = as_number(step_rad, "step_rad", SimulationError, unit="rad")
        if not 1e-6 <= step_rad <= np.deg2rad(10):
            raise SimulationError(f"Expected an angular step between 1e-6 rad and 10 deg, "
                                  f"got {step_rad} rad; note that the step is in radians.")
        self.spec, self.resolution = spec, resolution
        # The mirror revolution is divided evenly (pixels per 360 deg, as vendors name
        # their resolutions): the effective step is 2 pi / n_slots.
        self.n_slots = round(2 * np.pi / step_rad)
        self.step_rad = step_rad = 2 * np.pi / self.n_slots
        self.n_lines = round(p.head_sweep_rad / step_rad)
        beta = (np.arange(self.n_slots) + 0.5) * step_rad
        alpha = np.where(beta <= np.pi, beta, beta - 2 * np.pi)   # signed, from zenith
        half = p.vertical_fov_rad / 2
        valid = np.abs(alpha) <= half
        self._slot = np.nonzero(valid)[0]
        self._alpha = alpha[valid]
        order = np.argsort(self._alpha, kind="stable")
        self._row = np.empty(len(order), dtype=np.int32)
        self._row[order] = np.arange(len(order), dtype=np.int32)
        self.rate_hz = p.measurement_rate_hz
        # Scan window (azimuth min/max, elevation min/max in the sensor frame), as the
        # instrument's "scan section": only lines that can reach it are generated, and
        # pulses outside it are dropped (their time slots stay).
        self.window: NDArray[np.float64] | None = None
        self._lines = np.arange(self.n_lines)
        if window_rad is not None:
            try:
                w = np.asarray(window_rad, dtype=np.float64)
            except (TypeError, ValueError):
                w = np.empty(0)
            if w.shape != (4,) or not np.isfinite(w).all() or w[1] <= w[0] or w[3] <= w[2]:
                raise SimulationError(f"Expected a window (az_min, az_max, el_min, el_max) "
                                      f"in radians with min < max, got {window_rad!r}.")
            self.window = w
            phi = self._lines * step_rad
            keep = np.zeros(self.n_lines, dtype=bool)
            for side in (0.0, np.pi):
                a = np.mod(phi + side - w[0], 2 * np.pi)
                keep |= a <= (w[1] - w[0]) + 2 * step_rad
            self._lines = self._lines[keep]
        self._n_pulses: int | None = None

    def __repr__(self) -> str:
        what = self.resolution or f"step {np.rad2deg(self.step_rad):.4g} deg"
        pulses = "windowed" if self.window is not None else f"{self.n_pulses:,} pulses"
        return (f"TLSScan({self.spec.name} {what}, {self.n_lines:,} lines x "
                f"{self.points_per_line:,} points, {pulses}, {self.duration_s:.6g} s)")

    @property
    def points_per_line(self) -> int:
        """Pulses per vertical line (the mirror slots outside the blind cone)."""
        return len(self._slot)

    @property
    def n_pulses(self) -> int:
        """Pulses of the station (with a window: counted once, by a pass over it)."""
        if self.window is None:
            return self.points_per_line * self.n_lines
        if self._n_pulses is None:
            self._n_pulses = sum(len(c) for c in self.chunks())
        return self._n_pulses

    def _in_window(self, d: NDArray[np.float64]) -> NDArray[np.bool_]:
        w = self.window
        assert w is not None
        az = np.mod(np.arctan2(d[:, 1], d[:, 0]) - w[0], 2 * np.pi)
        el = np.arcsin(np.clip(d[:, 2], -1.0, 1.0))
        return (az <= w[1] - w[0]) & (el >= w[2]) & (el <= w[3])

    @property
    def duration_s(self) -> float:
        """Time of the whole station (s), blind slots included."""
        return self.n_lines * self.n_slots / self.rate_hz

    def chunks(self, chunk_pulses: int = CHUNK_PULSES) -> Iterator[Pulses]:
        """The pulses in time order, about ``chunk_pulses`` at a time (whole lines)."""
        per = self.points_per_line
        lines_per = max(1, chunk_size(chunk_pulses) // per)
        slot = self._slot.astype(np.float64)
        sa, ca = np.sin(self._alpha), np.cos(self._alpha)
        for j0 in range(0, len(self._lines), lines_per):
            lines = self._lines[j0:j0 + lines_per]
            m = len(lines)
            t = np.empty((m, per))
            d = np.empty((m, per, 3))
            row = np.empty((m, per), dtype=np.int32)
            col = np.empty((m, per), dtype=np.int32)

            def rows(a: int, b: int, lines: NDArray[np.int64] = lines,
                     t: NDArray[np.float64] = t, d: NDArray[np.float64] = d,
                     row: NDArray[np.int32] = row, col: NDArray[np.int32] = col) -> None:
                # Lines [a, b) of the chunk: element-wise, so any split gives the same
                # bits (run on the thread pool; issue 16).
                # The same operations in the same order as ever (same bits), each
                # written into its destination (issue 33: no temporaries, one pass less
                # per output).
                j = lines[a:b].astype(np.float64)
                tt = t[a:b]
                np.multiply(j[:, None], self.n_slots, out=tt)
                tt += slot[None, :]
                tt /= self.rate_hz
                phi = np.add(j[:, None], slot[None, :] / self.n_slots)
                phi *= self.step_rad
                trig = np.empty_like(phi)
                np.multiply(sa[None, :], np.cos(phi, out=trig), out=d[a:b, :, 0])
                np.multiply(sa[None, :], np.sin(phi, out=trig), out=d[a:b, :, 1])
                d[a:b, :, 2] = ca[None, :]
                row[a:b] = self._row[None, :]
                col[a:b] = j.astype(np.int32)[:, None]
            run_parts(rows, m, max(1, (1 << 16) // max(per, 1)))
            out = Pulses(t.reshape(-1), d.reshape(-1, 3), row.reshape(-1), col.reshape(-1),
                         np.zeros(m * per, dtype=np.int32))
            if self.window is not None:
                keep = self._in_window(out.direction)
                out = Pulses(out.time[keep], out.direction[keep], out.channel[keep],
                             out.column[keep], out.frame[keep])
            yield out


class SpinningScan:
    """A spinning multi-beam lidar running for ``duration_s`` (see module doc)."""

    def __init__(self, spec: SensorSpec, duration_s: float) -> None:
        p = _pattern(spec, SpinningPattern, "a spinning lidar")
        self.spec, self.pattern = spec, p
        self.rotation_hz = p.rotation_hz
        self.duration_s = _positive_duration(duration_s)
        self.T = p.column_period_s
        # Whole columns within the duration (last pulse at k T + max offset <= duration),
        # so that every pulse has a pose on a trajectory of that length.
        last = float(p.firing_offsets_s.max())
        self.n_columns = max(0, int(np.floor((self.duration_s - last) / self.T + 1e-9)) + 1)
        self.columns_per_rev = 1.0 / (self.rotation_hz * self.T)

    def __repr__(self) -> str:
        return (f"SpinningScan({self.spec.name}, {self.n_columns:,} columns x "
                f"{self.spec.channels} channels, {self.duration_s:.6g} s at "
                f"{self.rotation_hz:g} Hz)")

    @property
    def n_pulses(self) -> int:
        """Pulses of the scan: whole columns x channels."""
        return self.n_columns * self.spec.channels

    def chunks(self, chunk_pulses: int = CHUNK_PULSES) -> Iterator[Pulses]:
        """The pulses in time order, about ``chunk_pulses`` at a time (whole columns)."""
        p = self.pattern
        nch = self.spec.channels
        cols_per = max(1, chunk_size(chunk_pulses) // nch)
        sgn = -1.0 if p.clockwise else 1.0
        w = sgn * 2 * np.pi * self.rotation_hz      # as ever: (sgn 2) pi, then x f
        ce, se = np.cos(p.elevations_rad), np.sin(p.elevations_rad)
        for k0 in range(0, self.n_columns, cols_per):
            m = min(self.n_columns, k0 + cols_per) - k0
            t = np.empty((m, nch))
            d = np.empty((m, nch, 3))
            ch = np.empty((m, nch), dtype=np.int32)
            col = np.empty((m, nch), dtype=np.int32)
            fr = np.empty((m, nch), dtype=np.int32)
            # One fused parallel pass (issue 33: ten NumPy passes over the chunk were
            # 7 % of a drive's CPU); the same operations in the same order, same bits.
            spinning_columns(k0, self.T, p.firing_offsets_s, w, p.azimuth_offsets_rad,
                             self.rotation_hz, self.columns_per_rev, ce, se, t, d, ch,
                             col, fr)
            yield Pulses(t.reshape(-1), d.reshape(-1, 3), ch.reshape(-1), col.reshape(-1),
                         fr.reshape(-1))


class ProfileScan:
    """A 2-D profile scanner running for ``duration_s`` (see module doc)."""

    def __init__(self, spec: SensorSpec, duration_s: float) -> None:
        p = _pattern(spec, ProfilerPattern, "a profile scanner")
        self.spec, self.pattern = spec, p
        self.duration_s = _positive_duration(duration_s)
        # Whole profiles within the duration.
        self.n_profiles = int(np.floor(self.duration_s * p.profile_rate_hz + 1e-9))
        n = p.points_per_profile
        gamma = 2 * np.pi * (np.arange(n) + 0.5) / n
        b0, b1 = (np.mod(b, 2 * np.pi) for b in p.blind_sector_rad)
        blind = (gamma >= b0) & (gamma <= b1) if b0 <= b1 else (gamma >= b0) | (gamma <= b1)
        self._idx = np.nonzero(~blind)[0]
        self._gamma = gamma[~blind]

    def __repr__(self) -> str:
        return (f"ProfileScan({self.spec.name}, {self.n_profiles:,} profiles x "
                f"{self.points_per_profile:,} points, {self.duration_s:.6g} s)")

    @property
    def points_per_profile(self) -> int:
        """Pulses per profile (the slots outside the blind sector)."""
        return len(self._idx)

    @property
    def n_pulses(self) -> int:
        """Pulses of the scan: whole profiles x points per profile."""
        return self.n_profiles * self.points_per_profile

    def chunks(self, chunk_pulses: int = CHUNK_PULSES) -> Iterator[Pulses]:
        """The pulses in time order, about ``chunk_pulses`` at a time (whole profiles)."""
        p = self.pattern
        per = self.points_per_profile
        prof_per = max(1, chunk_size(chunk_pulses) // per)
        n = p.points_per_profile
        sg, cg = np.sin(self._gamma), np.cos(self._gamma)
        for p0 in range(0, self.n_profiles, prof_per):
            q = np.arange(p0, min(self.n_profiles, p0 + prof_per))
            t = (q[:, None] + self._idx[None, :] / n) / p.profile_rate_hz
            d = np.zeros((len(q), per, 3))
            d[..., 1] = sg
            d[..., 2] = cg
            yield Pulses(t.ravel(), d.reshape(-1, 3),
                         np.tile(self._idx.astype(np.int32), len(q)),
                         np.repeat(q.astype(np.int32), per),
                         np.repeat(q.astype(np.int32), per))


#: Any of the three patterns: ``n_pulses``, ``duration_s``, ``chunks(chunk_pulses)``.
Scan = TLSScan | SpinningScan | ProfileScan


def scan_for(spec: SensorSpec, *, duration_s: float | None = None,
             resolution: str | None = None, step_rad: float | None = None,
             window_rad: ArrayLike | None = None) -> Scan:
    """The pattern of a sensor: a station (TLS; ``duration_s`` is ignored, the pattern
    sets it) or a run of ``duration_s`` seconds (the others)."""
    if not isinstance(spec, SensorSpec):
        raise SimulationError(f"Expected a SensorSpec, got {type(spec).__name__}; load one "
                              "with load_sensor(name).")
    if spec.kind == "tls":
        return TLSScan(spec, resolution, step_rad=step_rad, window_rad=window_rad)
    if duration_s is None:
        raise SimulationError(f"Expected a duration for {spec.name} ({spec.kind}), got none.")
    if spec.kind == "spinning":
        return SpinningScan(spec, duration_s)
    return ProfileScan(spec, duration_s)
