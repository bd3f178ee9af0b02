"""The simulation loop: pattern chunk -> poses at pulse times -> cast -> physics ->
point chunk.

``simulate_station`` (TLS on a tripod) and ``simulate_drive`` (any sensor on a moving
platform) return a ``Run``: iterate it for point chunks (NumPy structured arrays of
``POINT_DTYPE``), or call ``Run.write(path)`` to stream them into a LAS/LAZ, PLY, NPZ or
E57 file. Only returns are output (misses and undetected pulses are dropped).

A run simulates once: the chunks of its first complete pass are kept (up to
``cache_bytes``, ``CACHE_BYTES`` by default) and later passes replay them, so that
``list(run)`` followed by ``run.write(...)`` casts every ray once. A run whose points
exceed the bound is simulated again on each pass (same points; a warning says so).
``Run.write`` of a single-return run whose pulses could exceed the bound (pulses x 97
bytes > ``cache_bytes``: a SUPERHIGH station, a minute's drive) keeps no cache and hands
the writer each chunk's returned pulses instead of point records: a LAS/LAZ writer
makes its records from them in one kernel (``sensors._kernels.pulses.las_points``,
issue 33), the same bytes as from the point records, without the 97-byte record and
its two strided passes in between.

Output fields (SI, radians):

- ``x, y, z``: the measurement in world coordinates, i.e. the reported sensor-frame
  point placed with the true sensor pose at the pulse's own time. With
  ``Settings.ideal()`` these are exactly the mesh hit points.
- ``sx, sy, sz``: the point in the sensor frame as the device reports it (measured range
  along the nominal beam direction), not corrected for the platform's motion during
  the sweep: transforming one whole frame with a single pose shows the rolling-shutter
  distortion.
- ``range, azimuth, elevation``: measured range (m) and the nominal beam angles in the
  sensor frame, in radians (azimuth counter-clockwise from +x, elevation from the x-y
  plane).
- ``time``: pulse time (s, trajectory time base); ``channel, column, frame`` from the
  pattern; ``intensity`` in [0, 1]; ``incidence`` angle at the surface (rad);
  ``triangle`` input face index (-1 for particles); ``flag`` 1 surface, 2 particle,
  3 mixed (beam-divergence sub-returns disagree by more than 1 cm).

Multiple returns (``Settings(returns=mode)``, one of the sensor's ``[returns]``
modes): each pulse's footprint sub-rays and its dust particle make a waveform
(``sensors.waveform.chunk_returns``), the mode picks the echoes the device reports,
and each is detected and noised as a single return is. The chunks then hold
``RETURN_POINT_DTYPE`` records: one per detected echo, grouped by pulse and in range
order, with ``return_number`` (1 = nearest), ``number_of_returns`` (among the detected
ones), ``echo_width`` (sigma, m) and ``echo_amplitude`` (relative power). With
``returns=None`` (the default) none of this runs: the points are those of the
single-return model, bit for bit.

Full waveform (``Settings(waveform=True)``, devices with ``[returns] waveform =
true``): the multiple-return model runs (in the device's default mode unless
``returns`` names one) and each record (``WAVEFORM_POINT_DTYPE``) also carries a
``WAVE_SAMPLES``-bin window of the summed waveform its echo was detected in
(``sensors.waveform.wave_windows``: shared by a pulse's returns where their echoes fit
in one), quantised to 16 bits, with the LAS wave packet geometry (return point location,
x(t), y(t), z(t)); chunks are cut at ``WAVE_CHUNK_PULSES`` pulses at most.
"""

from __future__ import annotations

import os
import time as _time
import warnings
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Final, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from raytrace import Scene

from . import physics as ph
from . import waveform
from ._threads import run_each
from ._checks import as_number, as_points, as_whole
from ._pages import held_heap, transient_pages
from ._kernels.digest import digest
from ._kernels.pulses import (
    detect_and_noise,
    fill_points,
    las_points,
    surface_returns,
    world_directions,
)
from .errors import SimulationError
from .io.fields import POINT_DTYPE, RETURN_POINT_DTYPE, WAVEFORM_POINT_DTYPE
from .io.las import quantize
from .patterns import CHUNK_PULSES, Pulses, Scan, TLSScan, chunk_size, scan_for
from .spec import SensorSpec, list_sensors, load_sensor
from .trajectory import Mount, Trajectory

__all__ = ["CACHE_BYTES", "RANDOM_BLOCK", "Run", "WAVE_CHUNK_PULSES", "simulate_drive",
           "simulate_station"]

#: An empty row index: the kernels' "one matrix for each pulse, or one for all".
NO_ROWS: Final = np.empty(0, dtype=np.int64)
#: Pulses per block of random numbers (see ``_Streams``).
RANDOM_BLOCK: Final = 1 << 16
#: Default bound of a run's replay cache (bytes of point records): 1 GiB holds about
#: 11 million points (97 bytes each), a 10 s drive of any shipped spinning lidar.
CACHE_BYTES: Final = 1 << 30
#: Most pulses per chunk of a full-waveform run (``Settings(waveform=True)``): its records
#: carry a waveform window each (~650 bytes), so chunks are cut smaller than
#: ``chunk_pulses`` (64k pulses, one random-number block: ~43 MB of records per return
#: per pulse). Results do not depend on it (random streams are keyed by pulse index).
WAVE_CHUNK_PULSES: Final = 1 << 16

#: poses(times (n,)) -> sensor positions (n or 1, 3), sensor-to-world matrices (m, 3, 3)
#: and each pulse's matrix row (n,) int64, or ``NO_ROWS`` when the matrices are one
#: per pulse or one for all.
PoseFn = Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64],
                                               NDArray[np.int64]]]
#: Per pulse: range (m), power, cosine of incidence, flag, triangle.
_Returns = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                 NDArray[np.uint8], NDArray[np.int32]]


def _reflectivity(scene: Scene, reflectivity: ArrayLike | None, settings: ph.Settings
                  ) -> tuple[NDArray[np.float64], float]:
    """(per-face reflectivity (m,) or an empty array, the value used without one)."""
    if reflectivity is None:
        return np.empty(0), settings.reflectivity
    try:
        r = np.asarray(reflectivity, dtype=np.float64)
    except (TypeError, ValueError):
        raise SimulationError(f"Expected `reflectivity` as a number within [0, 1] or one "
                              f"per mesh face, got {type(reflectivity).__name__}.") from None
    if r.ndim == 0:
        return np.empty(0), as_number(float(r), "reflectivity", SimulationError,
                                      unit="a fraction, not a percentage", lo=0, hi=1)
    n = len(scene.faces)
    if r.shape != (n,):
        raise SimulationError(f"Expected `reflectivity` as one value or one per mesh face "
                              f"({n},), got shape {r.shape}; pass a number or the mesh's "
                              "face property.")
    bad = np.flatnonzero(~(np.isfinite(r) & (r >= 0.0) & (r <= 1.0)))
    if bad.size:
        raise SimulationError(f"Expected every face's `reflectivity` within [0, 1], got "
                              f"{float(r[bad[0]])!r} at face {int(bad[0])} ({bad.size} "
                              "outside).")
    return r, settings.reflectivity


class Run:
    """A configured simulation: iterate it for point chunks, or ``write`` it to a file.

    Built by ``simulate_station`` and ``simulate_drive``. Every pass over a run gives
    the same points (the random streams depend on the seed and the pulse index only).
    Each chunk is a structured array of ``sensors.POINT_DTYPE``: x, y, z, sx, sy, sz and
    range in metres, time in seconds, azimuth, elevation and incidence in radians
    (``sensors.io.fields`` documents every field; ``FIELD_UNITS`` holds the units).

    Attributes
    ----------
    scene : raytrace.Scene
    sensor : SensorSpec
    scan : TLSScan, SpinningScan or ProfileScan
        The pattern; ``n_pulses`` and ``duration_s`` are its.
    settings : Settings
    seed : int
    station : (position (3,) float64, scipy Rotation) or None
        The pose of a TLS station; None on a moving platform.
    mount : Mount or None
        Lever arm and boresight of the sensor on a moving platform (recorded in the
        files it writes, so that LiDAR odometry can turn sensor poses into platform
        poses); None for a station.
    trajectory : Trajectory or None
        The platform's trajectory of a drive (a ROS 2 bag writes its /tf, ground-truth
        odometry and IMU from it); None for a station.
    t0 : float
        Trajectory time of the scan's start (s).
    stats : dict
        Statistics of the last *complete* pass that simulated: ``pulses``,
        ``points``, ``hit_ratio``, ``seconds``, ``rays_per_s``; empty before one. A
        pass stopped early, or one replayed from the cache, leaves it as it was.
    pass_stats : dict
        The same for the pass under way (or the last one, complete or not), updated
        after every chunk: ``pulses``, ``points``, ``hit_ratio``, ``seconds``, and
        ``replayed`` (whether the pass came from the cache).
    cache_bytes : int
        Bound of the replay cache (see the module notes); 0 switches it off.
    cached : bool
        Whether the next pass replays the cache.
    """

    def __init__(self, scene: Scene, sensor: SensorSpec, scan: Scan, poses: PoseFn, *,
                 settings: ph.Settings, seed: int, reflectivity: ArrayLike | None,
                 chunk_pulses: int, station: tuple[NDArray[np.float64], Rotation] | None
                 = None, t0: float = 0.0, mount: Mount | None = None,
                 trajectory: Trajectory | None = None, cache_bytes: int = CACHE_BYTES
                 ) -> None:
        self.scene, self.sensor, self.scan = scene, sensor, scan
        self.mount, self.trajectory = mount, trajectory
        self._poses = poses
        self.settings, self.seed = settings, _seed(seed)
        _check_returns(sensor, settings)
        self._rho_faces, self._rho_default = _reflectivity(scene, reflectivity, settings)
        self.chunk_pulses = chunk_size(chunk_pulses)
        self.station = station
        self.t0 = float(t0)
        self.stats: dict[str, float] = {}
        self.pass_stats: dict[str, float] = {}
        self.cache_bytes = as_whole(cache_bytes, "cache_bytes", SimulationError, lo=0)
        # Chunks of the last complete pass (``_Cached``) and what they were simulated
        # with; None when there is none to replay.
        self._cache: list[_Cached] | None = None
        self._cache_key: tuple[object, ...] | None = None
        self._overflowed = False

    def _key(self) -> tuple[object, ...]:
        """What a cached pass depends on among the attributes a user may reassign."""
        return (self.seed, self.settings, self.chunk_pulses, self.t0, id(self.scene),
                id(self.sensor), id(self.scan), id(self._poses), self._rho_default,
                id(self._rho_faces))

    @property
    def cached(self) -> bool:
        """Whether the next pass replays the chunks of a complete one."""
        return self._cache is not None and self._cache_key == self._key()

    def _chunk_step(self) -> int:
        """Pulses per simulated chunk: ``chunk_pulses``, at most ``WAVE_CHUNK_PULSES``
        in a full-waveform run."""
        if self.settings.waveform:
            return min(self.chunk_pulses, WAVE_CHUNK_PULSES)
        return self.chunk_pulses

    def clear_cache(self) -> None:
        """Drop the cached chunks (the next pass simulates again)."""
        self._cache, self._cache_key = None, None

    @property
    def n_pulses(self) -> int:
        """Pulses of the whole run (a windowed TLS station counts them once, lazily)."""
        return self.scan.n_pulses

    @property
    def duration_s(self) -> float:
        """Duration of the scan pattern (s)."""
        return self.scan.duration_s

    def __repr__(self) -> str:
        if self.station is not None:
            where = "station at (" + ", ".join(f"{c:.6g}" for c in self.station[0]) + ")"
        else:
            where = f"drive from t = {self.t0:.6g} s"
        windowed = isinstance(self.scan, TLSScan) and self.scan.window is not None
        pulses = "windowed" if windowed else f"{self.scan.n_pulses:,} pulses"
        done = (f"{int(self.stats['points']):,} points in the last pass" if self.stats
                else "not run yet")
        return (f"Run({self.sensor.name} {where}, {pulses}, {self.duration_s:.6g} s, "
                f"seed {self.seed}; {done})")

    def __iter__(self) -> Iterator[NDArray[np.void]]:
        """Point chunks (structured arrays of ``POINT_DTYPE``), in pulse order: simulated
        on the first complete pass, replayed from the cache after it (each chunk a
        fresh copy: a consumer may change what it is given).

        The cache holds the first pass's chunks themselves, not copies: a chunk a
        consumer changed in place since (its bytes, dtype or shape) is simulated again
        when it is replayed (the same points: a run is deterministic)."""
        t_start = _time.perf_counter()
        n_pulses = n_points = n_hits = 0
        self.pass_stats = {}
        if self.cached:
            assert self._cache is not None
            for j, entry in enumerate(self._cache):
                if not entry.intact():
                    entry = _Cached.of(entry.first, entry.pulses, entry.hits, next(
                        self._range_chunks(entry.first, entry.first + entry.pulses)))
                    self._cache[j] = entry
                pulses_n, hits, pts = entry.pulses, entry.hits, entry.points
                n_pulses += pulses_n
                n_points += len(pts)
                n_hits += hits
                self.pass_stats = {"pulses": n_pulses, "points": n_points,
                                   "hit_ratio": n_hits / max(n_pulses, 1),
                                   "seconds": _time.perf_counter() - t_start,
                                   "replayed": True}
                yield pts.copy()
            return
        self.clear_cache()
        self._warn_again()
        yield from self._simulate(returned_only=False)

    def _warn_again(self) -> None:
        if self._overflowed:
            warnings.warn(f"Simulating {self.sensor.name} again: its points exceeded the "
                          f"replay cache ({self.cache_bytes:,} bytes) on the last pass; "
                          "consume the run once (e.g. write it and read the file), or "
                          "raise cache_bytes.", UserWarning, stacklevel=3)

    def _simulate(self, returned_only: bool) -> Iterator[Any]:
        """One simulated pass: point chunks (kept in the replay cache within its bound),
        or with ``returned_only`` the chunks' ``_Returned`` pulses (kept nowhere); both
        update ``pass_stats``, and ``stats`` at the end of a complete pass."""
        t_start = _time.perf_counter()
        n_pulses = n_points = n_hits = 0
        # DECISION: a bounded in-memory cache rather than a one-shot iterator: a run
        # is iterated more than once by callers that exist (list(run) then write, a
        # preview then the file), and each pass gave the same points; a bound keeps a
        # long drive (a 2 min OS1 drive is ~6 GB of records) from filling the memory.
        store: list[_Cached] | None = \
            [] if self.cache_bytes > 0 and not returned_only else None
        size = 0
        pattern = iter(self.scan.chunks(self._chunk_step()))
        # The chunks' freed arrays are reused by the next chunk instead of faulted in
        # again (``_pages.held_heap``: a fifth of a drive's CPU time).
        with held_heap():
            while True:
                # A chunk's arrays are written once and dropped: ordinary pages, not
                # NumPy's huge-page hint (``_pages.py``: a third of the drive's CPU time
                # was page faults). The caller's code between chunks is left alone.
                with transient_pages():
                    pulses = next(pattern, None)
                    if pulses is None:
                        break
                    got = self._chunk(n_pulses, pulses, returned_only)
                    if returned_only:
                        k, hits = len(got), got.n_hit
                        size += k * POINT_DTYPE.itemsize
                    else:
                        pts, hits = got
                        k = len(pts)
                        size += pts.nbytes
                if store is not None:
                    if size > self.cache_bytes:
                        store = None
                    else:
                        # DECISION: the chunk itself, with a digest of its bytes, not
                        # a copy (issue 33: the copy was 3-4 % of a drive's time, and
                        # list(run) held every point twice); a consumer's change in
                        # place is caught on replay (``__iter__``).
                        store.append(_Cached.of(n_pulses, len(pulses), hits, pts))
                n_pulses += len(pulses)
                n_points += k
                n_hits += hits
                self.pass_stats = {"pulses": n_pulses, "points": n_points,
                                   "hit_ratio": n_hits / max(n_pulses, 1),
                                   "seconds": _time.perf_counter() - t_start,
                                   "replayed": False}
                yield got if returned_only else pts
        # Only a complete pass is kept (a consumer that stopped early never gets here).
        self._overflowed = self.cache_bytes > 0 and size > self.cache_bytes
        if store is not None:
            self._cache, self._cache_key = store, self._key()
        s = self.pass_stats.get("seconds", 0.0)
        # DECISION: ``stats`` changes only here, at the end of a complete pass: a
        # consumer that stops early (a preview, a ``break``) must not leave the counts
        # of a partial pass where a complete one's were.
        self.stats = {"pulses": n_pulses, "points": n_points,
                      "hit_ratio": n_hits / max(n_pulses, 1), "seconds": s,
                      "rays_per_s": n_pulses * self.settings.beam_subrays / s if s else 0.0}

    def chunks(self, start: int = 0, stop: int | None = None
               ) -> Iterator[NDArray[np.void]]:
        """Point chunks of pulses ``start`` to ``stop`` - 1 (indices in pattern order;
        ``stop`` None: to the end): exactly the points a whole pass gives for them, in
        the same order, since each pulse's random numbers are keyed by its index
        (``_Streams``), not by the chunk it falls in. Chunks are cut where a whole pass
        cuts them (and at ``start`` and ``stop``); the pattern before ``start`` is
        generated but not simulated. ``stats`` and ``pass_stats`` are left alone, and
        the replay cache is neither used nor filled.

        A drive split into pulse ranges [0, i1), [i1, i2), ... and run anywhere gives,
        concatenated, the points of the whole run (``survey.cluster.windows``)."""
        a = as_whole(start, "start", SimulationError, lo=0)
        b = self.n_pulses if stop is None else as_whole(stop, "stop", SimulationError,
                                                        lo=0)
        with held_heap():
            yield from self._range_chunks(a, b)

    def _range_chunks(self, a: int, b: int) -> Iterator[NDArray[np.void]]:
        """``chunks`` of pulses ``a`` to ``b`` - 1."""
        first = 0
        for pulses in self.scan.chunks(self._chunk_step()):
            if first >= b:
                break
            n = len(pulses)
            lo, hi = max(a, first), min(b, first + n)
            if lo < hi:
                if hi - lo < n:
                    cut = slice(lo - first, hi - first)
                    pulses = Pulses(pulses.time[cut], pulses.direction[cut],
                                    pulses.channel[cut], pulses.column[cut],
                                    pulses.frame[cut])
                with transient_pages():
                    pts = self._chunk(lo, pulses)[0]
                yield pts
            first += n

    def write(self, path, *, fmt: str | None = None, progress=None, fields=None,
              points: Iterable[NDArray[np.void]] | None = None, crs=None,
              start_time_ns: int | None = None, ros_distro: str | None = None,
              waveform_data: str | None = None):
        """Stream every chunk into ``path`` (format from the suffix or ``fmt``:
        las, laz, ply, npz, e57); atomic. ``progress(done_pulses, total)`` is called
        after each chunk; ``fields`` picks the LAS extra bytes (see
        ``sensors.writers``). ``points``: chunks to write instead of the run's own, made
        from them while it runs (e.g. moved into a drifting SLAM frame). ``crs``: the
        coordinate reference system of the scene's coordinates (EPSG:n, WKT or
        PROJJSON; needs pyproj), stated in the file (``sensors.writers``).
        ``start_time_ns`` and ``ros_distro``: a ROS 2 bag's epoch at the scan's start
        and metadata layout (``sensors.bag.RosbagStream``); only passed on when given.
        A full-waveform run (``Settings(waveform=True)``) writes LAS/LAZ wave packets
        and refuses other formats before simulating; ``waveform_data`` (None,
        "internal" or "external") says where its packets go (``sensors.writers.
        open_writer``). Returns ``stats`` plus the path."""
        from .writers import open_writer

        span = None if self.station is not None else (self.t0, self.t0 + self.duration_s)
        bag: dict[str, Any] = {}
        if start_time_ns is not None:
            bag["start_time_ns"] = start_time_ns
        if ros_distro is not None:
            bag["ros_distro"] = ros_distro
        with open_writer(path, sensor=self.sensor, seed=self.seed, pose=self.station,
                         fields=fields, fmt=fmt, expected_points=self.n_pulses,
                         mount=self.mount, trajectory=self.trajectory, span_s=span,
                         crs=crs, returns=self.settings.returns,
                         waveform=self.settings.waveform, waveform_data=waveform_data,
                         **bag) as w:
            if points is None and self._writes_returned():
                # Straight from the kernels: the writer makes its records from each
                # chunk's returned pulses (a LAS/LAZ writer without the POINT_DTYPE
                # record in between), and no replay cache is kept.
                self.pass_stats = {}
                self.clear_cache()
                self._warn_again()
                for ret in self._simulate(returned_only=True):
                    w.write_returned(ret)
                    if progress is not None:
                        progress(self.pass_stats["pulses"], self.n_pulses)
            else:
                for chunk in (self if points is None else points):
                    w.write_points(chunk)
                    if progress is not None:
                        progress(self.pass_stats["pulses"], self.n_pulses)
        return dict(self.stats, path=str(path))

    def _writes_returned(self) -> bool:
        """Whether ``write`` streams the chunks' returned pulses to the writer instead of
        point records: a single-return run that is not cached and whose pulses could
        exceed the replay cache (as records; a bound of 0 included)."""
        # DECISION: only where the cache could not be relied on anyway: a run whose
        # records may fit keeps the documented "simulates once" (write, then iterate
        # from the cache); a larger one (a SUPERHIGH station, a minute's drive) would
        # overflow the cache, so writing it straight from the kernels loses nothing.
        st = self.settings
        return (st.returns is None and not st.waveform and not self.cached and
                (self.cache_bytes == 0 or
                 self.n_pulses * POINT_DTYPE.itemsize > self.cache_bytes))

    # ------------------------------------------------------------------ one chunk
    def _chunk(self, first: int, pulses: Pulses, returned_only: bool = False
               ) -> Any:
        """Simulate one chunk of pulses (``first``: index of its first pulse in the
        run); returns (points, number of pulses that hit a surface), or with
        ``returned_only`` (single-return runs only) the ``_Returned`` pulses whose
        records are not made yet."""
        st, phys = self.settings, self.sensor.physics
        n = len(pulses)
        rng = _Streams(self.seed, first, n)
        t_abs = pulses.time + self.t0
        # One matrix per firing instant and each pulse's row in ``which`` (a drive), or
        # one matrix for every pulse (a station; ``which`` empty).
        pos, mats, which = self._poses(t_abs)
        single = self.station is not None
        mats = np.ascontiguousarray(mats.reshape(-1, 3, 3))
        pos = np.ascontiguousarray(np.asarray(pos, dtype=np.float64).reshape(-1, 3))
        # Random streams, always in this order (see sensors.physics).
        jit = np.empty((0, 2))
        if st.angle_jitter and phys.angle_sigma_rad > 0:
            jit = rng.normal(0, 2)
            jit *= phys.angle_sigma_rad     # in place: the same products, no copy
        # Scattering closer than the minimum range is invisible; by the exponential
        # law's lack of memory the first visible event is range_min + Exp(rate).
        dpart = phys.range_min_m + rng.exponential(1) / st.particle_rate_per_m \
            if st.particle_rate_per_m > 0 else None
        u_part = rng.uniform(2) if dpart is not None else None
        u_det = rng.uniform(3)
        z = rng.normal(4, 1)
        dw = np.empty((n, 3))
        world_directions(pulses.direction, jit, mats, which, dw)
        if st.returns is not None or st.waveform:   # the waveform model
            per_pulse = mats[which] if len(which) else mats
            return self._chunk_returns(rng, pulses, t_abs, pos, per_pulse, dw, dpart,
                                       u_det, z)
        ret = self._surface(pos[0] if single else pos, dw, "cubemap" if single else "auto")
        n_hit = int(np.count_nonzero(ret[3]))
        if dpart is not None and u_part is not None:
            ret = self._particles(dpart, u_part, *ret)
        r, p, cos, flag, tri = ret
        p_min, log_span = ph.intensity_constants(phys)
        floor2, ref2 = ph.noise_constants(phys)
        returned = np.empty(n, dtype=np.bool_)
        detect_and_noise(r, p, flag, u_det, z, st.detection, p_min,
                         1.0 / phys.detection_softness, st.range_noise, floor2, ref2,
                         returned)
        got = _Returned(np.flatnonzero(returned), r, p, flag, tri, cos, pulses, t_abs, pos,
                        mats, which, p_min, log_span, n_hit)
        return got if returned_only else (got.points(), n_hit)

    def _chunk_returns(self, rng: _Streams, pulses: Pulses, t_abs: NDArray[np.float64],
                       pos: NDArray[np.float64], mats: NDArray[np.float64],
                       dw: NDArray[np.float64], dpart: NDArray[np.float64] | None,
                       u_det: NDArray[np.float64], z: NDArray[np.float64]
                       ) -> tuple[NDArray[np.void], int]:
        """``_chunk`` in a multiple-return mode (``Settings.returns``): each pulse's
        sub-rays and particle make a waveform (``sensors.waveform.chunk_returns``), the
        device's mode picks its echoes, each is detected and noised as a single return
        is; records of ``RETURN_POINT_DTYPE``, one per detected return."""
        st, phys, spec = self.settings, self.sensor.physics, self.sensor
        mode = _mode(spec, st)
        n = len(dw)
        single = self.station is not None
        t, tri, hit, cos, e, w = self._cast_subrays(pos[0] if single else pos, dw,
                                                    "cubemap" if single else "auto")
        n_hit = int(np.count_nonzero(hit.any(axis=1)))
        pr = pp = None
        if dpart is not None:
            # A particle echoes where it lies before the farthest surface the footprint
            # reaches (the beam ends there) and within range.
            far = np.where(hit, t, -np.inf).max(axis=1)
            far = np.where(np.isfinite(far), far, phys.range_max_m)
            pr = np.where(dpart < np.minimum(far, phys.range_max_m), dpart, np.inf)
            pp = ph.power(st.particle_reflectivity, 1.0, pr, st.attenuation_per_m)
        rs = spec.returns
        model = rs.model(phys)
        cr = waveform.chunk_returns(np.where(hit, t, np.inf), e, cos, tri, w,
                                    model, mode, dual=rs.dual,
                                    max_returns=rs.max_returns, particle_range_m=pr,
                                    particle_power=pp)
        k = len(cr)
        # DECISION: the first reported return of a pulse draws from streams 3 and 4,
        # as the single return does; returns 2, 3, ... from streams 5 and 6, one
        # column each, so adding a mode changes no draw of the default path.
        later = cr.return_number.astype(np.int64) - 2
        u, zz = u_det[cr.pulse], z[cr.pulse]
        if (later >= 0).any():
            width = max(rs.max_returns - 1, 1)
            u2 = rng.uniform_columns(5, width)
            z2 = rng.normal(6, width).reshape(-1, width)
            more = later >= 0
            u[more] = u2[cr.pulse[more], later[more]]
            zz[more] = z2[cr.pulse[more], later[more]]
        r = cr.range_m.copy()
        p_min, log_span = ph.intensity_constants(phys)
        floor2, ref2 = ph.noise_constants(phys)
        returned = np.empty(k, dtype=np.bool_)
        detect_and_noise(r, cr.power, cr.flag, u, zz, st.detection, p_min,
                         1.0 / phys.detection_softness, st.range_noise, floor2, ref2,
                         returned)
        idx = np.flatnonzero(returned)
        out = np.empty(len(idx), dtype=WAVEFORM_POINT_DTYPE if st.waveform else
                       RETURN_POINT_DTYPE)
        f = [out[name] for name in POINT_DTYPE.names or ()]
        q = cr.pulse
        per_pos = pos[q] if pos.shape[0] == n and n > 1 else pos
        per_rot = mats[q] if mats.shape[0] == n and n > 1 else mats
        fill_points(idx, r, cr.power, cr.flag, cr.triangle, cr.cos,
                    np.ascontiguousarray(pulses.direction[q]), t_abs[q], pulses.channel[q],
                    pulses.column[q], pulses.frame[q], np.ascontiguousarray(per_pos),
                    np.ascontiguousarray(per_rot), NO_ROWS, p_min, log_span, *f)
        out["return_number"], out["number_of_returns"] = \
            waveform.renumber_returns(q, returned)
        out["echo_width"] = cr.width_m[idx]
        out["echo_amplitude"] = cr.amplitude[idx]
        if st.waveform:
            self._fill_waves(out, cr, idx, r, model, pulses.direction[q[idx]],
                             per_rot if per_rot.shape[0] == 1 else per_rot[idx])
        return out, n_hit

    def _fill_waves(self, out: NDArray[np.void], cr: waveform.ChunkReturns,
                    idx: NDArray[np.int64], r: NDArray[np.float64],
                    model: waveform.WaveformModel, d_sensor: NDArray[np.float64],
                    rot: NDArray[np.float64]) -> None:
        """The waveform fields of the detected returns ``idx`` of ``cr`` (measured
        ranges ``r``; nominal beam directions ``d_sensor`` (k, 3) in the sensor frame,
        sensor-to-world rotations ``rot`` (1 or k, 3, 3)): each return's window
        (``sensors.waveform.wave_windows``) and its LAS wave packet geometry."""
        assert cr.contrib_range_m is not None and cr.contrib_power is not None
        # The windows of the detected returns (a pulse's window spans the echoes it
        # reports), sampled straight into the records.
        ww = waveform.wave_windows(cr.contrib_range_m, cr.contrib_power, model,
                                   return_pulse=cr.pulse[idx], echo_range_m=cr.range_m[idx],
                                   gain=waveform.waveform_gain(self.sensor.physics),
                                   out=out["wave"])
        # The world point is pos + R (r d) (fill_points): its beam is R d, unit.
        d_world = np.einsum("kij,kj->ki", np.broadcast_to(rot, (len(idx), 3, 3)), d_sensor)
        out["wave_start_m"] = ww.start_m
        # LAS "return point waveform location": the measured return's time after the
        # window's first sample (ps), so that the sample grid sits where the point is.
        out["wave_location_ps"] = (r[idx] - ww.start_m) / waveform.RANGE_PER_PS_M
        # DECISION: x(t), y(t), z(t) point back along the beam, towards the scanner:
        # LASlib (laswaveform13reader) and CloudCompare (ccWaveform::getSamplePos) place
        # sample k at point + (location - k spacing) (x(t), y(t), z(t)), which puts the
        # first sample nearest the scanner only with this sense. The anchor (sample 0)
        # is then point + location (x(t), y(t), z(t)).
        back = -d_world * waveform.RANGE_PER_PS_M
        out["wave_dx"], out["wave_dy"], out["wave_dz"] = back.T
        out["wave_gain"] = ww.gain
        out["wave_spacing_ps"] = ww.spacing_ps

    def _surface(self, origin: NDArray[np.float64], dw: NDArray[np.float64], method: str
                 ) -> _Returns:
        """Surface returns of a chunk's beams ``dw`` (n, 3) (world frame): range (inf
        for none), power, cosine of incidence, flag, triangle."""
        st, phys = self.settings, self.sensor.physics
        if st.beam_subrays > 1:
            return self._subrays(origin, dw, method)
        n = len(dw)
        # A surface nearer than the minimum range blocks the beam without a return.
        hits = self.scene.cast(origin, dw, t_min=0.0, t_max=phys.range_max_m,
                               method=method)  # type: ignore[arg-type]
        r, p, cos = np.empty(n), np.empty(n), np.empty(n)
        flag = np.empty(n, dtype=np.uint8)
        surface_returns(hits.t, hits.triangle, hits.normals, dw, self._rho_faces,
                        self._rho_default, phys.range_min_m, st.attenuation_per_m, r, p, cos,
                        flag)
        return r, p, cos, flag, hits.triangle.astype(np.int32)

    def _particles(self, dpart: NDArray[np.float64], u_part: NDArray[np.float64],
                   r: NDArray[np.float64], p: NDArray[np.float64], cos: NDArray[np.float64],
                   flag: NDArray[np.uint8], tri: NDArray[np.int32]) -> _Returns:
        """Airborne particles: a particle return at ``dpart`` replaces the surface's
        where it comes first and is detected (``u_part`` < its detection probability)."""
        st, phys = self.settings, self.sensor.physics
        cand = dpart < np.minimum(r, phys.range_max_m)
        pp = ph.power(st.particle_reflectivity, 1.0, dpart, st.attenuation_per_m)
        won = cand & (u_part < ph.detection_probability(pp, phys)) if st.detection \
            else cand
        return (np.where(won, dpart, r), np.where(won, pp, p), np.where(won, 1.0, cos),
                np.where(won, ph.FLAG_PARTICLE, flag).astype(np.uint8),
                np.where(won, -1, tri).astype(np.int32))

    def _cast_subrays(self, origin: NDArray[np.float64], dw: NDArray[np.float64],
                      method: str) -> tuple[NDArray[np.float64], NDArray[np.int64],
                                            NDArray[np.bool_], NDArray[np.float64],
                                            NDArray[np.float64], NDArray[np.float64]]:
        """Beam divergence: cast the footprint's sub-rays of the beams ``dw`` (n, 3).
        Returns, (n, m) each: range t, triangle, hit (a face beyond the minimum range),
        cosine of incidence, power e (0 where no hit); and the weights w (m,)."""
        st, phys = self.settings, self.sensor.physics
        n = len(dw)
        off, w = ph.subray_offsets(st.beam_subrays)
        m = len(w)
        u, v = ph.perpendicular_basis(dw)
        g = phys.beam_divergence_rad
        rays = (dw[:, None, :] + g * (off[None, :, :1] * u[:, None, :] +
                                      off[None, :, 1:] * v[:, None, :])).reshape(-1, 3)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        org = origin if origin.ndim == 1 else np.repeat(origin, m, axis=0)
        hits = self.scene.cast(org, rays, t_min=0.0, t_max=phys.range_max_m,
                               method=method)  # type: ignore[arg-type]
        t = hits.t.reshape(n, m)
        tri = hits.triangle.reshape(n, m)
        hit = (tri >= 0) & (t >= phys.range_min_m)
        cos = np.abs(np.einsum("ij,ij->i", hits.normals, rays)).reshape(n, m)
        rho = self._rho_faces[np.maximum(tri, 0)] if len(self._rho_faces) else \
            np.full((n, m), self._rho_default)
        e = np.where(hit, ph.power(rho, cos, np.where(hit, t, 1.0), st.attenuation_per_m),
                     0.0)
        return t, tri, hit, cos, e, w

    def _subrays(self, origin: NDArray[np.float64], dw: NDArray[np.float64], method: str
                 ) -> _Returns:
        """Beam divergence: cast the footprint's sub-rays and combine them (NumPy)."""
        st = self.settings
        t, tri, hit, cos, e, w = self._cast_subrays(origin, dw, method)
        n, m = t.shape
        any_hit = hit.any(axis=1)
        j = np.argmax(e, axis=1)
        rows = np.arange(n)
        p = (e * w).sum(axis=1)            # footprint-weighted power
        if st.mixed == "strongest":
            r = t[rows, j]
        else:
            with np.errstate(invalid="ignore", divide="ignore"):
                r = np.where(hit, e * t, 0.0).sum(axis=1) / e.sum(axis=1)
        tt = np.where(hit, t, np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            spread = np.nanmax(tt, axis=1) - np.nanmin(tt, axis=1)
        mixed = any_hit & ((spread > ph.MIXED_SPREAD_M) | (hit.sum(axis=1) < m))
        flag = np.where(mixed, ph.FLAG_MIXED, np.where(any_hit, ph.FLAG_SURFACE, 0))
        r = np.where(any_hit, r, np.inf)
        return (r, p, cos[rows, j], flag.astype(np.uint8),
                np.where(any_hit, tri[rows, j], -1).astype(np.int32))


#: LAS dimensions ``las_points`` fills itself (point format 6), and the POINT_DTYPE fields
#: it can put into extra bytes (in its argument order).
_LAS_STANDARD = ("X", "Y", "Z", "intensity", "bit_fields", "classification_flags",
                 "classification", "user_data", "scan_angle", "point_source_id",
                 "gps_time")
_LAS_EXTRA_FIELDS = ("sx", "sy", "sz", "range", "azimuth", "elevation", "channel",
                     "column", "frame", "incidence", "triangle", "flag")


class _Returned:
    """The returned pulses of a single-return chunk, before their records are made:
    the per-pulse state the records are computed from, and the indices of the pulses
    that gave a return. ``points`` makes the ``POINT_DTYPE`` records; ``fill_las``
    writes LAS records straight from the same values, bit for bit what the LAS writer
    makes of ``points`` (issue 33: a LAS/LAZ output skips the 97-byte record and two
    strided passes). A writer thread may hold it: nothing in it changes once made.
    """

    def __init__(self, idx: NDArray[np.int64], r: NDArray[np.float64],
                 p: NDArray[np.float64], flag: NDArray[np.uint8], tri: NDArray[np.int32],
                 cos: NDArray[np.float64], pulses: Pulses, t_abs: NDArray[np.float64],
                 pos: NDArray[np.float64], mats: NDArray[np.float64],
                 which: NDArray[np.int64], p_min: float, log_span: float, n_hit: int
                 ) -> None:
        self.idx, self.r, self.p, self.flag, self.tri, self.cos = idx, r, p, flag, tri, cos
        self.pulses, self.t_abs, self.pos, self.mats = pulses, t_abs, pos, mats
        self.which = which
        self.p_min, self.log_span, self.n_hit = p_min, log_span, n_hit

    def __len__(self) -> int:
        return len(self.idx)

    def _args(self, idx: NDArray[np.int64]) -> tuple[Any, ...]:
        q = self.pulses
        return (idx, self.r, self.p, self.flag, self.tri, self.cos, q.direction,
                self.t_abs, q.channel, q.column, q.frame, self.pos, self.mats, self.which,
                self.p_min, self.log_span)

    def points(self, limit: int | None = None) -> NDArray[np.void]:
        """The ``POINT_DTYPE`` records (of the first ``limit`` returns only, if given)."""
        idx = self.idx if limit is None else self.idx[:limit]
        out = np.empty(len(idx), dtype=POINT_DTYPE)
        fill_points(*self._args(idx), *[out[name] for name in POINT_DTYPE.names or ()])
        return out

    def fill_las(self, records: NDArray[np.void], offsets: NDArray[np.float64],
                 scales: NDArray[np.float64], extra: dict[str, str]) -> bool:
        """Write the LAS point format 6 records ``records`` (len(self),) (a laspy point
        dtype: the standard dimensions, then extra bytes ``extra`` {dimension:
        POINT_DTYPE field}) for coordinate ``offsets`` and ``scales`` (3,). Returns False,
        writing nothing, for a layout it does not know (other dimensions); raises the
        LAS writer's ``PointFileError`` for coordinates beyond the int32 range."""
        names = records.dtype.names or ()
        if len(records) != len(self) or names[:len(_LAS_STANDARD)] != _LAS_STANDARD or \
                set(names[len(_LAS_STANDARD):]) != set(extra) or \
                not set(extra.values()) <= set(_LAS_EXTRA_FIELDS):
            return False
        by_field = {f: records[k] for k, f in extra.items()}
        outs = [by_field[f] if f in by_field else np.empty(0, POINT_DTYPE[f])
                for f in _LAS_EXTRA_FIELDS]
        bad = las_points(*self._args(self.idx), np.asarray(offsets, dtype=np.float64),
                         np.asarray(scales, dtype=np.float64),
                         *[records[k] for k in _LAS_STANDARD], *outs)
        if bad:   # the LAS writer's own check names the point
            pts = self.points()
            quantize(np.stack([pts["x"], pts["y"], pts["z"]], 1), scales, offsets)
        return True


class _Cached(NamedTuple):
    """A chunk of the replay cache: its first pulse's index and pulse count in the
    pass, the pulses that hit a surface, its points (the very array the pass handed
    out), their record type and length, and the digest of their bytes then
    (``sensors._kernels.digest``)."""
    first: int
    pulses: int
    hits: int
    points: NDArray[np.void]
    dtype: np.dtype
    length: int
    digest: int

    @classmethod
    def of(cls, first: int, pulses: int, hits: int, pts: NDArray[np.void]) -> _Cached:
        return cls(first, pulses, hits, pts, pts.dtype, len(pts), digest(pts))

    def intact(self) -> bool:
        """Whether the chunk is as the pass handed it out (a consumer may have changed
        its values, or its dtype or shape in place)."""
        p = self.points
        return (p.dtype == self.dtype and p.shape == (self.length,) and
                p.flags.c_contiguous and digest(p) == self.digest)


class _Streams:
    """Random numbers for pulses [first, first + n) of a run, independent of how the
    run is chunked: stream s of block b (``RANDOM_BLOCK`` pulses) comes from
    ``default_rng([seed, s, b])``, and a chunk takes the slices it covers."""

    def __init__(self, seed: int, first: int, n: int) -> None:
        self.seed, self.first, self.n = seed, first, n

    def _take(self, stream: int, draw: Callable[[np.random.Generator, NDArray[np.float64]],
                                                object],
              width: int, skip: bool = False) -> NDArray[np.float64]:
        """Rows [first, first + n) of stream ``stream`` ((n, width), or (n,) for width
        1): ``draw(generator, out)`` fills ``out`` with the generator's next numbers.
        ``skip``: each number is one 64-bit draw (uniforms), so the rows of a block
        before the chunk are skipped by advancing its generator instead of drawn."""
        b0 = self.first // RANDOM_BLOCK
        b1 = (self.first + max(self.n, 1) - 1) // RANDOM_BLOCK
        end = self.first + self.n
        # The rows drawn: from the chunk's first row (skip) or its first block's start.
        lo = self.first if skip else b0 * RANDOM_BLOCK
        whole = np.empty((end - lo, width))

        def fill(b: int) -> None:
            a, e = max(b * RANDOM_BLOCK, lo), min((b + 1) * RANDOM_BLOCK, end)
            if e <= a:
                return
            g = np.random.default_rng([self.seed, stream, b])
            if a > b * RANDOM_BLOCK:
                bits = g.bit_generator
                assert isinstance(bits, np.random.PCG64)   # default_rng's, with advance
                bits.advance((a - b * RANDOM_BLOCK) * width)
            draw(g, whole[a - lo:e - lo])
        # DECISION: the blocks are drawn on a small thread pool (NumPy's generators
        # release the GIL while they fill): each block has its own generator, so the
        # numbers are the same bits in any order; 2x faster on 2 cores (issue 16).
        # Each block is drawn straight into the chunk's array (``out=``), and only as
        # far as the chunk needs: a generator's first k numbers are the same whether it
        # draws k or a whole block (issue 33: a quarter of the draws and a copy less).
        run_each(fill, range(b0, b1 + 1))
        out = whole[self.first - lo:]
        return out[:, 0] if width == 1 else out

    def normal(self, stream: int, width: int = 2) -> NDArray[np.float64]:
        return self._take(stream, lambda g, o: g.standard_normal(out=o), width)

    def uniform(self, stream: int) -> NDArray[np.float64]:
        return self._take(stream, lambda g, o: g.random(out=o), 1, skip=True)

    def uniform_columns(self, stream: int, width: int) -> NDArray[np.float64]:
        """(n, width) uniforms (``uniform`` is the (n,) of width 1)."""
        return self._take(stream, lambda g, o: g.random(out=o), width,
                          skip=True).reshape(-1, width)

    def exponential(self, stream: int) -> NDArray[np.float64]:
        return self._take(stream, lambda g, o: g.standard_exponential(out=o), 1)


# ---------------------------------------------------------------------- checks at the call
def _seed(seed: object) -> int:
    return as_whole(seed, "seed", SimulationError, lo=0)


def _as_sensor(sensor: str | os.PathLike[str] | SensorSpec) -> SensorSpec:
    return sensor if isinstance(sensor, SensorSpec) else load_sensor(sensor)


def _check_scene(scene: object) -> None:
    if not isinstance(scene, Scene):
        raise SimulationError(f"Expected a raytrace.Scene, got {type(scene).__name__}; "
                              "build one with Scene.from_file(path).")


def _settings(settings: ph.Settings | None) -> ph.Settings:
    if settings is None:
        return ph.Settings()
    if not isinstance(settings, ph.Settings):
        raise SimulationError(f"Expected `settings` as a sensors.Settings, got "
                              f"{type(settings).__name__}; build one with Settings(...).")
    return settings


def _mode(spec: SensorSpec, settings: ph.Settings) -> str:
    """The return mode a multiple-return run simulates: ``settings.returns``, or the
    device's default (first) mode for a full-waveform run without one."""
    return settings.returns if settings.returns is not None else spec.returns.modes[0]


def _check_returns(spec: SensorSpec, settings: ph.Settings) -> None:
    """A return mode must be one the device records (its spec's ``[returns] modes``);
    full-waveform output needs a device that records the waveform."""
    if settings.waveform and not spec.returns.waveform:
        able = [n for n in list_sensors() if load_sensor(n).returns.waveform]
        raise SimulationError(f"Expected a sensor that records the full waveform for "
                              f"--waveform ([returns] waveform = true: {able}), got "
                              f"{spec.name}; pick one of those, or leave --waveform "
                              "out (--returns gives its multiple returns).")
    mode = settings.returns
    if mode is not None and mode not in spec.returns.modes:
        raise SimulationError(f"Expected --returns in {list(spec.returns.modes)} for "
                              f"{spec.name} (its [returns] modes), got {mode!r}; pass "
                              "--returns with one of them, or leave it out for one "
                              "return per pulse.")


def _station_position(position: ArrayLike) -> NDArray[np.float64]:
    rows = as_points(position, "position", SimulationError)
    if len(rows) != 1:
        raise SimulationError(f"Expected one station `position` (3,) or (1, 3), got "
                              f"{len(rows)} rows; simulate one station per call.")
    return rows[0]


def _drive_window(trajectory: Trajectory, t_start: float | None, t_end: float | None
                  ) -> tuple[float, float]:
    """[a, b], the part of the trajectory to scan, checked against its time span (a
    static trajectory has none: any window is fine, but t_end must be given)."""
    a = trajectory.start_s if t_start is None else \
        as_number(t_start, "t_start", SimulationError, unit="s")
    b = trajectory.end_s if t_end is None else \
        as_number(t_end, "t_end", SimulationError, unit="s")
    if not b > a:
        raise SimulationError(f"Expected a time window with end > start, got [{a:g}, {b:g}] "
                              "s (a static trajectory needs t_end).")
    lo, hi = trajectory.start_s, trajectory.end_s
    eps = 1e-9 * max(1.0, abs(hi))
    if len(trajectory) > 1 and (a < lo - eps or b > hi + eps):
        raise SimulationError(f"Expected `t_start` and `t_end` within the trajectory's "
                              f"[{lo:g}, {hi:g}] s, got [{a:g}, {b:g}] s; shorten the window "
                              "or extend the trajectory.")
    return a, b


# ---------------------------------------------------------------------- public API
def simulate_station(scene: Scene, sensor: str | os.PathLike[str] | SensorSpec,
                     position: ArrayLike, *, attitude: Rotation | None = None,
                     resolution: str | None = None, step_rad: float | None = None,
                     window_rad: ArrayLike | None = None,
                     settings: ph.Settings | None = None, seed: int = 0,
                     reflectivity: ArrayLike | None = None,
                     chunk_pulses: int = CHUNK_PULSES, cache_bytes: int = CACHE_BYTES
                     ) -> Run:
    """A TLS station at ``position``, level unless ``attitude`` is given.

    Parameters
    ----------
    scene : raytrace.Scene
    sensor : str, path or SensorSpec
        A TLS sensor: a name from ``list_sensors()``, a TOML file, or a loaded spec.
    position : (3,) or (1, 3) array_like of float, or a record with fields x, y, z
        Station position in world coordinates (m).
    attitude : scipy Rotation, optional, keyword-only (as are all that follow)
        Sensor-to-world rotation; level (identity) by default.
    resolution : str, optional
        A resolution preset of the sensor (e.g. "superhigh"); its default if neither
        this nor ``step_rad`` is given.
    step_rad : float, optional
        Angular step (rad) instead of a preset.
    window_rad : (4,) array_like of float, optional
        (az_min, az_max, el_min, el_max) in radians, sensor frame: scan only this
        section, as the instrument allows.
    settings : Settings, optional
        Physics switches; ``Settings()`` by default.
    seed : int >= 0
        Seed of every random stream.
    reflectivity : float in [0, 1] or (n_faces,) array_like, optional
        One value, or one per input face (e.g. the PLY face property); else
        ``settings.reflectivity``.
    chunk_pulses : int >= 1
        Pulses simulated at a time (memory, not results, depends on it).
    cache_bytes : int >= 0
        Bound of the run's replay cache (bytes of point records; 0: none): a second
        pass over a run within it replays the first instead of simulating again.

    Returns
    -------
    Run

    Raises
    ------
    SimulationError, SensorSpecError
        For an argument that is out of range or of the wrong kind.

    Warns
    -----
    UserWarning
        For a position outside the mesh's bounding box (the station sees the mesh
        from outside).
    """
    _check_scene(scene)
    spec = _as_sensor(sensor)
    if spec.kind != "tls":
        raise SimulationError(f"Expected a TLS sensor for a station, got {spec.name} "
                              f"({spec.kind}); use simulate_drive with a static trajectory.")
    pos = _station_position(position)
    if attitude is not None and not (isinstance(attitude, Rotation) and attitude.single):
        raise SimulationError(f"Expected `attitude` as one scipy Rotation, got "
                              f"{type(attitude).__name__}; use Rotation.from_euler(...).")
    st = _settings(settings)
    scan = scan_for(spec, resolution=resolution, step_rad=step_rad, window_rad=window_rad)
    lo, hi = scene.bounds
    if ((pos < lo) | (pos > hi)).any():
        warnings.warn(f"Station {pos.tolist()} lies outside the mesh bounds "
                      f"{lo.tolist()} - {hi.tolist()}; it will see the mesh from outside.",
                      UserWarning, stacklevel=2)
    rot = Rotation.identity() if attitude is None else attitude
    mat = rot.as_matrix()[None]

    def poses(t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                               NDArray[np.int64]]:
        return pos[None, :], mat, NO_ROWS

    return Run(scene, spec, scan, poses, settings=st, seed=seed, reflectivity=reflectivity,
               chunk_pulses=chunk_pulses, station=(pos, rot), cache_bytes=cache_bytes)


def simulate_drive(scene: Scene, sensor: str | os.PathLike[str] | SensorSpec,
                   trajectory: Trajectory, mount: Mount | None = None, *,
                   settings: ph.Settings | None = None, seed: int = 0,
                   reflectivity: ArrayLike | None = None, chunk_pulses: int = CHUNK_PULSES,
                   t_start: float | None = None, t_end: float | None = None,
                   cache_bytes: int = CACHE_BYTES) -> Run:
    """Any sensor on a platform following ``trajectory``; each pulse is cast from the
    sensor pose at its own time. A TLS sensor scans one full station pattern.

    Parameters
    ----------
    scene : raytrace.Scene
    sensor : str, path or SensorSpec
    trajectory : Trajectory
        Platform poses; one pose is a static platform (then ``t_end`` is needed).
    mount : Mount, optional
        Lever arm and boresight from the platform to the sensor; none by default.
    settings, seed, reflectivity, chunk_pulses, cache_bytes : keyword-only
        As for ``simulate_station``.
    t_start, t_end : float, optional, keyword-only
        The part of the trajectory to scan (s, trajectory time base); the whole of it
        by default. Checked here against the trajectory's span.

    Returns
    -------
    Run
        The configured drive: iterate it for point chunks or ``write`` it.

    Raises
    ------
    SimulationError, SensorSpecError
        For an argument out of range, a window outside the trajectory, or a TLS
        station pattern longer than the trajectory.
    """
    _check_scene(scene)
    spec = _as_sensor(sensor)
    if not isinstance(trajectory, Trajectory):
        raise SimulationError(f"Expected a Trajectory, got {type(trajectory).__name__}; "
                              "build one with Trajectory(...) or Trajectory.read(path).")
    mnt = Mount() if mount is None else mount
    if not isinstance(mnt, Mount):
        raise SimulationError(f"Expected `mount` as a sensors.Mount, got "
                              f"{type(mnt).__name__}; e.g. Mount(lever_arm_m=(0, 0, 0.3)).")
    st = _settings(settings)
    a, b = _drive_window(trajectory, t_start, t_end)
    scan = scan_for(spec, duration_s=b - a)
    if len(trajectory) > 1 and a + scan.duration_s > trajectory.end_s + 1e-9 * max(
            1.0, abs(trajectory.end_s)):
        raise SimulationError(f"Expected the trajectory to last the {spec.name} station "
                              f"pattern's {scan.duration_s:g} s from t = {a:g} s, got it "
                              f"ending at {trajectory.end_s:g} s; use a longer trajectory "
                              "or a static one.")

    def poses(t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                               NDArray[np.int64]]:
        return trajectory.instant_matrices(t, mnt)

    return Run(scene, spec, scan, poses, settings=st, seed=seed, reflectivity=reflectivity,
               chunk_pulses=chunk_pulses, t0=a, mount=mnt, trajectory=trajectory,
               cache_bytes=cache_bytes)
