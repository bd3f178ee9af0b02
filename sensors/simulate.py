"""The simulation loop: pattern chunk -> poses at pulse times -> cast -> physics ->
point chunk.

``simulate_station`` (TLS on a tripod) and ``simulate_drive`` (any sensor on a moving
platform) return a ``Run``: iterate it for point chunks (NumPy structured arrays of
``POINT_DTYPE``), or call ``Run.write(path)`` to stream them into a LAS/LAZ, PLY, NPZ or
E57 file. Only returns are output (misses and undetected pulses are dropped).

Output fields (SI, radians):

- ``x, y, z``: the measurement in world coordinates, i.e. the reported sensor-frame
  point placed with the true sensor pose at the pulse's own time. With
  ``Settings.ideal()`` these are exactly the mesh hit points.
- ``sx, sy, sz``: the point in the sensor frame as the device reports it (measured range
  along the nominal beam direction), not corrected for the platform's motion during
  the sweep: transforming one whole frame with a single pose shows the rolling-shutter
  distortion.
- ``range, azimuth, elevation``: measured range and the nominal beam angles in the
  sensor frame (azimuth counter-clockwise from +x, elevation from the x-y plane).
- ``time``: pulse time (s, trajectory time base); ``channel, column, frame`` from the
  pattern; ``intensity`` in [0, 1]; ``incidence`` angle at the surface (rad);
  ``triangle`` input face index (-1 for particles); ``flag`` 1 surface, 2 particle,
  3 mixed (beam-divergence sub-returns disagree by more than 1 cm).
"""

from __future__ import annotations

import time as _time
import warnings

import numpy as np
from scipy.spatial.transform import Rotation

from raytrace import Scene

from . import physics as ph
from ._kernels.pulses import detect_and_noise, fill_points, surface_returns, world_directions
from .errors import SimulationError
from .patterns import CHUNK_PULSES, scan_for
from .spec import SensorSpec, load_sensor
from .trajectory import Mount, Trajectory

#: Pulses per block of random numbers (see ``_Streams``).
RANDOM_BLOCK = 1 << 16

POINT_DTYPE = np.dtype([
    ("x", "f8"), ("y", "f8"), ("z", "f8"), ("sx", "f8"), ("sy", "f8"), ("sz", "f8"),
    ("range", "f8"), ("azimuth", "f4"), ("elevation", "f4"), ("time", "f8"),
    ("channel", "i4"), ("column", "i4"), ("frame", "i4"), ("intensity", "f4"),
    ("incidence", "f4"), ("triangle", "i4"), ("flag", "u1")])


def _reflectivity(scene, reflectivity):
    if reflectivity is None:
        return None
    r = np.asarray(reflectivity, dtype=np.float64)
    if r.ndim == 0:
        return r
    n = getattr(scene, "_n_input_faces", None)
    if r.ndim != 1 or (n is not None and len(r) != n) or not np.isfinite(r).all() or \
            (r < 0).any() or (r > 1).any():
        raise SimulationError(f"Expected `reflectivity` as one value or one per mesh face "
                              f"({n}) in [0, 1], got shape {r.shape}.")
    return r


class Run:
    """A configured simulation; iterate for point chunks, or ``write`` to a file.

    Attributes: ``n_pulses``, ``duration_s``, ``sensor``, ``stats`` (after a full
    pass: pulses, points, hit ratio, seconds, rays per second).
    """

    def __init__(self, scene, sensor, scan, poses, *, settings, seed, reflectivity,
                 chunk_pulses, station=None, t0=0.0):
        self.scene, self.sensor, self.scan = scene, sensor, scan
        self._poses = poses          # callable(times) -> (positions, matrices (k, 3, 3))
        self.settings, self.seed = settings, int(seed)
        self._rho = _reflectivity(scene, reflectivity)
        self.chunk_pulses = int(chunk_pulses)
        self.station = station       # (position, Rotation) for a TLS station
        self.t0 = float(t0)
        self.stats = {}

    @property
    def n_pulses(self) -> int:
        return self.scan.n_pulses

    @property
    def duration_s(self) -> float:
        return self.scan.duration_s

    def __iter__(self):
        t_start = _time.perf_counter()
        n_pulses = n_points = n_hits = 0
        for pulses in self.scan.chunks(self.chunk_pulses):
            pts, hits = self._chunk(n_pulses, pulses)
            n_pulses += len(pulses)
            n_points += len(pts)
            n_hits += hits
            self.stats = {"pulses": n_pulses, "points": n_points,
                          "hit_ratio": n_hits / max(n_pulses, 1),
                          "seconds": _time.perf_counter() - t_start}
            yield pts
        s = self.stats.get("seconds", 0.0)
        self.stats["rays_per_s"] = n_pulses * self.settings.beam_subrays / s if s else 0.0

    def write(self, path, *, fmt: str | None = None, progress=None, fields=None):
        """Stream every chunk into ``path`` (format from the suffix or ``fmt``:
        las, laz, ply, npz, e57); atomic. ``progress(done_pulses, total)`` is called
        after each chunk; ``fields`` picks the LAS extra bytes (see
        ``sensors.writers``). Returns ``stats``."""
        from .writers import write_points

        return write_points(self, path, fmt=fmt, progress=progress, fields=fields)

    # ------------------------------------------------------------------ one chunk
    def _chunk(self, first, pulses):
        """Simulate one chunk of pulses (``first``: index of its first pulse in the
        run); returns (points, number of pulses that hit)."""
        st, phys = self.settings, self.sensor.physics
        n = len(pulses)
        rng = _Streams(self.seed, first, n)
        t_abs = pulses.time + self.t0
        pos, mats = self._poses(t_abs)
        single = self.station is not None
        mats = np.ascontiguousarray(mats.reshape(-1, 3, 3))
        pos = np.ascontiguousarray(np.asarray(pos, dtype=np.float64).reshape(-1, 3))
        # Random streams, always in this order (see sensors.physics).
        jit = phys.angle_sigma_rad * rng.normal(0, 2) \
            if st.angle_jitter and phys.angle_sigma_rad > 0 else np.empty((0, 2))
        # Scattering closer than the minimum range is invisible; by the exponential
        # law's lack of memory the first visible event is range_min + Exp(rate).
        dpart = phys.range_min_m + rng.exponential(1) / st.particle_rate_per_m \
            if st.particle_rate_per_m > 0 else None
        u_part = rng.uniform(2) if dpart is not None else None
        u_det = rng.uniform(3)
        z = rng.normal(4, 1)
        dw = np.empty((n, 3))
        world_directions(pulses.direction, jit, mats, dw)
        origin = pos[0] if single else pos
        rho_faces = np.empty(0) if self._rho is None or self._rho.ndim == 0 else self._rho
        rho_default = float(self._rho) if self._rho is not None and self._rho.ndim == 0 \
            else st.reflectivity
        method = "cubemap" if single else "auto"
        # A surface nearer than the minimum range blocks the beam without a return.
        if st.beam_subrays == 1:
            hits = self.scene.cast(origin, dw, t_min=0.0, t_max=phys.range_max_m,
                                   method=method)
            r = np.empty(n)
            p = np.empty(n)
            cos = np.empty(n)
            flag = np.empty(n, dtype=np.uint8)
            surface_returns(hits.t, hits.triangle, hits.normals, dw, rho_faces, rho_default,
                            phys.range_min_m, st.attenuation_per_m, r, p, cos, flag)
            tri = hits.triangle.astype(np.int32)
        else:
            r, p, cos, flag, tri = self._subrays(origin, dw, method, rho_faces, rho_default)
        n_hit = int(np.count_nonzero(flag))
        if dpart is not None:
            cand = dpart < np.minimum(r, phys.range_max_m)
            pp = ph.power(st.particle_reflectivity, 1.0, dpart, st.attenuation_per_m)
            won = cand & (u_part < ph.detection_probability(pp, phys)) if st.detection \
                else cand
            r = np.where(won, dpart, r)
            p = np.where(won, pp, p)
            tri = np.where(won, -1, tri).astype(np.int32)
            cos = np.where(won, 1.0, cos)
            flag = np.where(won, ph.FLAG_PARTICLE, flag).astype(np.uint8)
        p_min = phys.detection_reflectivity / phys.detection_range_m ** 2
        p_ref = phys.reference_reflectivity / phys.reference_range_m ** 2
        returned = np.empty(n, dtype=np.bool_)
        detect_and_noise(r, p, flag, u_det, z, st.detection, p_min,
                         1.0 / phys.detection_softness, st.range_noise,
                         phys.range_sigma_floor_m ** 2, phys.range_sigma_m ** 2 * p_ref,
                         returned)
        idx = np.flatnonzero(returned)
        out = np.empty(len(idx), dtype=POINT_DTYPE)
        p_sat = 1.0 / max(phys.range_min_m, 0.1) ** 2
        f = [out[name] for name in POINT_DTYPE.names]
        fill_points(idx, r, p, flag, tri, cos, pulses.direction, t_abs, pulses.channel,
                    pulses.column, pulses.frame, pos, mats, p_min, np.log10(p_sat / p_min),
                    *f)
        return out, n_hit

    def _subrays(self, origin, dw, method, rho_faces, rho_default):
        """Beam divergence: cast the footprint's sub-rays and combine them (NumPy)."""
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
        hits = self.scene.cast(org, rays, t_min=0.0, t_max=phys.range_max_m, method=method)
        t = hits.t.reshape(n, m)
        tri = hits.triangle.reshape(n, m)
        hit = (tri >= 0) & (t >= phys.range_min_m)
        cos = np.abs(np.einsum("ij,ij->i", hits.normals, rays)).reshape(n, m)
        rho = rho_faces[np.maximum(tri, 0)] if len(rho_faces) else np.full((n, m), rho_default)
        e = np.where(hit, ph.power(rho, cos, np.where(hit, t, 1.0), st.attenuation_per_m),
                     0.0)
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


class _Streams:
    """Random numbers for pulses [first, first + n) of a run, independent of how the
    run is chunked: stream s of block b (``RANDOM_BLOCK`` pulses) comes from
    ``default_rng([seed, s, b])``, and a chunk takes the slices it covers."""

    def __init__(self, seed, first, n):
        self.seed, self.first, self.n = seed, first, n

    def _take(self, stream, draw, width):
        b0 = self.first // RANDOM_BLOCK
        b1 = (self.first + max(self.n, 1) - 1) // RANDOM_BLOCK
        parts = [draw(np.random.default_rng([self.seed, stream, b]), (RANDOM_BLOCK, width))
                 for b in range(b0, b1 + 1)]
        off = self.first - b0 * RANDOM_BLOCK
        out = np.concatenate(parts)[off:off + self.n]
        return out[:, 0] if width == 1 else out

    def normal(self, stream, width=2):
        return self._take(stream, lambda g, s: g.standard_normal(s), width)

    def uniform(self, stream):
        return self._take(stream, lambda g, s: g.random(s), 1)

    def exponential(self, stream):
        return self._take(stream, lambda g, s: g.standard_exponential(s), 1)


def _as_sensor(sensor) -> SensorSpec:
    return sensor if isinstance(sensor, SensorSpec) else load_sensor(sensor)


def _check_scene(scene):
    if not isinstance(scene, Scene):
        raise SimulationError(f"Expected a raytrace.Scene, got {type(scene).__name__}; "
                              "build one with Scene.from_file(path).")


def simulate_station(scene, sensor, position, *, attitude: Rotation | None = None,
                     resolution: str | None = None, step_rad: float | None = None,
                     window_rad=None, settings: ph.Settings | None = None, seed: int = 0,
                     reflectivity=None, chunk_pulses: int = CHUNK_PULSES) -> Run:
    """A TLS station at ``position`` (3,) world, level unless ``attitude`` is given.

    ``resolution`` names a preset of the sensor (e.g. "superhigh"), or ``step_rad``
    gives the angular step; ``window_rad`` (az_min, az_max, el_min, el_max) limits the
    scan to a section, as the instrument allows. ``reflectivity``: one value or one per input face (e.g.
    the PLY face property); else ``settings.reflectivity``. A position outside the
    mesh's bounding box gives a warning (the station sees the mesh from outside).
    """
    _check_scene(scene)
    spec = _as_sensor(sensor)
    if spec.kind != "tls":
        raise SimulationError(f"Expected a TLS sensor for a station, got {spec.name} "
                              f"({spec.kind}); use simulate_drive with a static trajectory.")
    scan = scan_for(spec, resolution=resolution, step_rad=step_rad, window_rad=window_rad)
    pos = np.asarray(position, dtype=np.float64)
    if pos.shape != (3,) or not np.isfinite(pos).all():
        raise SimulationError(f"Expected a station position of 3 finite coordinates, got "
                              f"{np.shape(position)}.")
    lo, hi = scene.bounds
    if ((pos < lo) | (pos > hi)).any():
        warnings.warn(f"Station {pos.tolist()} lies outside the mesh bounds "
                      f"{lo.tolist()} - {hi.tolist()}; it will see the mesh from outside.",
                      UserWarning, stacklevel=2)
    rot = Rotation.identity() if attitude is None else attitude
    mat = rot.as_matrix()[None]

    def poses(t):
        return pos[None, :], mat

    return Run(scene, spec, scan, poses, settings=settings or ph.Settings(), seed=seed,
               reflectivity=reflectivity, chunk_pulses=chunk_pulses, station=(pos, rot))


def simulate_drive(scene, sensor, trajectory: Trajectory, mount: Mount | None = None, *,
                   settings: ph.Settings | None = None, seed: int = 0, reflectivity=None,
                   chunk_pulses: int = CHUNK_PULSES, t_start: float | None = None,
                   t_end: float | None = None) -> Run:
    """Any sensor on a platform following ``trajectory``; each pulse is cast from the
    sensor pose at its own time. A TLS sensor scans one full station pattern."""
    _check_scene(scene)
    spec = _as_sensor(sensor)
    if not isinstance(trajectory, Trajectory):
        raise SimulationError(f"Expected a Trajectory, got {type(trajectory).__name__}.")
    mount = mount or Mount()
    a = trajectory.start_s if t_start is None else float(t_start)
    b = trajectory.end_s if t_end is None else float(t_end)
    if not b > a:
        raise SimulationError(f"Expected a time window with end > start, got [{a}, {b}] s "
                              "(a static trajectory needs t_end).")
    scan = scan_for(spec, duration_s=b - a)

    def poses(t):
        return trajectory.sensor_matrices(t, mount)

    return Run(scene, spec, scan, poses, settings=settings or ph.Settings(), seed=seed,
               reflectivity=reflectivity, chunk_pulses=chunk_pulses, t0=a)
