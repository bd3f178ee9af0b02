"""MLS speed and scan-rate study (seed Figure 7): how point density, line spacing, gaps
and rolling-shutter distortion depend on the platform speed, the rotation rate and the
mounting of a moving lidar.

Each configuration drives the sensor along the axis at constant speed through an
evaluation strip [s_a, s_b] with ``lead_m`` before and after it, and counts the points
that land in the strip while the sensor is in that window. Because the set of sensor
positions is the same for every speed, the count scales as 1/v for a constant pulse
rate: density per pass ~ pulse rate x (window length / v) x (share landing in the
strip). At v = 0 the sensor stands at the strip's centre for one sweep and the
densities are per sweep (marked as such).

Metrics per configuration:

- density on lining and floor (points/m^2): points in the strip's lining/floor cells
  (``planning.lining_cells``) over the cells' area;
- empty lining share: lining cells (``cell_m`` x ``cell_rad``) without a point;
- along-track line spacing: for the forward-looking beams (|azimuth| < 2 deg) on the
  floor, the median shift in chainage of each channel's footprint between consecutive
  sweeps (analytic: v / f);
- rolling-shutter distortion: each point's device-frame coordinates placed with the
  pose at its sweep's start (what a driver does that assembles a sweep with one pose),
  minus the true point; max and RMS (analytic for straight, level motion: v x time
  since the sweep started, at most v / f).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from survey.errors import StudyError
from survey.world.alignment import Alignment

if TYPE_CHECKING:
    from raytrace import Scene
    from sensors.route import Route
    from survey.analysis.surface import RouteFrame, Surface
    from sensors.physics import Settings
    from sensors.spec_types import SensorSpec
    from sensors.trajectory import Mount, Trajectory

__all__ = ["FORWARD_AZ_RAD", "MOUNTS", "Study", "StudyRow"]

#: Forward beams used for the along-track line spacing (|azimuth| below this, rad).
FORWARD_AZ_RAD = np.deg2rad(2.0)
MOUNTS = ("level", "down")

Floats = NDArray[np.float64]


@dataclass
class StudyRow:
    """One configuration's metrics (SI units; see the module doc)."""

    speed_mps: float
    rate_hz: float
    mount: str
    points: int
    density_lining: float        # points / m^2 (per pass; per sweep at v = 0)
    density_floor: float
    empty_lining_share: float
    line_spacing_m: float        # measured (NaN where no forward floor beams)
    line_spacing_analytic_m: float
    distortion_max_m: float
    distortion_rms_m: float
    distortion_analytic_max_m: float
    pulses: int
    seconds: float

    def to_dict(self) -> dict[str, Any]:
        """The fields by name (JSON-ready)."""
        return dict(self.__dict__)


def _with_rate(spec: SensorSpec, rate_hz: float) -> SensorSpec:
    from sensors.spec import with_rate

    if spec.kind in ("spinning", "profiler"):
        return with_rate(spec, rate_hz)
    raise StudyError(f"Expected a moving sensor (spinning or profiler), got {spec.name} "
                     f"({spec.kind}); plan TLS stations with 'tunnelsim plan'.")


def _line_spacing(fwd: dict[tuple[int, int], list[float]]) -> float:
    """Median along-track shift (m) of each channel's mean forward-floor footprint
    chainage between consecutive sweeps; NaN without consecutive sweeps."""
    by_ch: dict[int, list[tuple[int, float]]] = {}
    for (ch, frm), (tot, n) in fwd.items():
        by_ch.setdefault(ch, []).append((frm, tot / n))
    diffs: list[float] = []
    for v in by_ch.values():
        v.sort()
        fr_, ss_ = np.array(v).T
        ok = np.diff(fr_) == 1
        diffs.extend(np.abs(np.diff(ss_))[ok].tolist())
    return float(np.median(diffs)) if diffs else float("nan")


@dataclass
class _Tally:
    """Per-run accumulators over the simulated chunks."""

    counts: NDArray[np.int64]
    fwd: dict[tuple[int, int], list[float]] = field(default_factory=dict)
    dmax: float = 0.0
    dsq: float = 0.0
    nd: int = 0
    keep: list[Floats] = field(default_factory=list)


class Study:
    """One tunnel, one sensor; ``run`` evaluates a configuration.

    Parameters
    ----------
    scene : raytrace.Scene
    alignment : Alignment
    centre_height_m : float, profile-centre height (m)
    sensor : SensorSpec, a spinning lidar or a profiler
    strip_m : (start, end) float, optional, chainages (m) of the evaluation strip
        (default: 5 m in the middle of the tunnel)
    lead_m : float, the sensor's run-in and run-out on each side of the strip (m)
    height_m : float, sensor height above the floor (m)
    cell_m, cell_rad : float, lining cell size along (m) and around (rad) the axis
    settings : sensors.physics.Settings, optional, passed to ``simulate_drive``
    seed : int, seed of the simulated drives
    reflectivity : float or (m,) array_like, optional, passed to ``simulate_drive``
        (one value or one per mesh face)
    keep_points : int, floor points kept per configuration for the figure (0: none)

    Notes
    -----
    ``Study.along_route`` makes one on any mesh.
    """

    # Sample lookup of the mesh path (``along_route``): sorted (triangle, sub) keys.
    _kmax: int
    _keys: NDArray[np.int64]
    _order: NDArray[np.int64]

    def __init__(self, scene: Scene, alignment: Alignment, centre_height_m: float,
                 sensor: SensorSpec, *, strip_m: tuple[float, float] | None = None,
                 lead_m: float = 5.0, height_m: float = 0.5, cell_m: float = 0.1,
                 cell_rad: float = np.deg2rad(2.0), settings: Settings | None = None,
                 seed: int = 0, reflectivity: Any = None, keep_points: int = 0) -> None:
        from survey.analysis.planning import axis_stations, lining_cells

        self.scene, self.hc = scene, float(centre_height_m)
        self.sensor = sensor
        _with_rate(sensor, 1.0)                        # kind check
        c0, c1 = alignment.chainage_range
        if strip_m is None:
            mid = 0.5 * (c0 + c1)
            strip_m = (mid - 2.5, mid + 2.5)
        try:
            sa, sb = (float(v) for v in strip_m)
        except (TypeError, ValueError):
            raise StudyError(f"Expected `strip_m` as (start, end) chainages in m, got "
                             f"{strip_m!r}.") from None
        if not (c0 <= sa - lead_m and sb + lead_m <= c1 and sb > sa):
            raise StudyError(f"Expected the strip [{sa}, {sb}] m with {lead_m} m lead on "
                             f"both sides inside the tunnel [{c0}, {c1}] m, got it outside; "
                             "shorten the strip or the lead.")
        self.strip_m, self.lead_m = (sa, sb), float(lead_m)
        self.cells: Any = lining_cells(
            scene, alignment, self.hc, chainage_range_m=(sa, sb), cell_m=cell_m,
            cell_rad=cell_rad, keep_floor=True)
        self.frame: Alignment | RouteFrame = alignment
        self.cell_m, self.n_a = cell_m, self.cells.shape[1]
        # Cell index of each (ring, column) of the grid, -1 where there is no cell.
        self._lookup = np.full(self.cells.shape, -1, dtype=np.int64)
        self._lookup[self.cells.ring, self.cells.col] = np.arange(len(self.cells.area))
        # Sensor path: height_m above the floor below the axis, sampled every 0.25 m.
        s = np.arange(sa - lead_m, sb + lead_m + 1e-9, 0.25)
        self.path = axis_stations(scene, alignment, self.hc, s, height_m=height_m)
        self._finish(height_m, settings, seed, reflectivity, keep_points, s,
                     alignment.to_world(0.5 * (sa + sb), 0.0, self.hc))

    def _finish(self, height_m: float, settings: Settings | None, seed: int,
                reflectivity: Any, keep_points: int, path_s: Floats,
                centre: Floats) -> None:
        """The state both paths share: settings, the ball holding the strip (points
        outside it skip the exact, slow, chainage) and the figure's footprints."""
        self.height_m = height_m
        self.settings, self.seed, self.refl = settings, seed, reflectivity
        self.keep_points = int(keep_points)
        self.path_s = path_s
        self._ball_c = np.asarray(centre, dtype=np.float64)
        self._ball_r = float(np.linalg.norm(self.cells.points - self._ball_c, axis=1).max()
                             + 2 * self.cell_m)
        #: Floor footprints per (speed, rate, mount): (k, 4) chainage, offset, height,
        #: time since the strip centre.
        self.kept: dict[tuple[float, float, str], Floats] = {}

    @classmethod
    def along_route(cls, scene: Scene, route: Route, sensor: SensorSpec, *,
                    strip_m: tuple[float, float] | None = None, lead_m: float = 5.0,
                    sample_m: float = 0.1, settings: Settings | None = None,
                    seed: int = 0, reflectivity: Any = None, keep_points: int = 0
                    ) -> Study:
        """The study on any mesh: the sensor drives along ``route``
        (``sensors.route.find_route``, found at the sensor's height) and the strip is
        measured on the mesh's own triangles (``planning.mesh_surface``, samples no
        larger than ``sample_m``), a point counted in the sample of its triangle it
        lands in. Chainages are distances along the route (m)."""
        from survey.analysis.surface import RouteFrame, mesh_surface

        self = cls.__new__(cls)
        self.scene, self.sensor = scene, sensor
        _with_rate(sensor, 1.0)                        # kind check
        self.frame = frame = RouteFrame(route.floor)
        height_m = float(np.median(route.points[:, 2] - route.floor[:, 2]))
        L = frame.length_m
        if strip_m is None:
            strip_m = (0.5 * L - 2.5, 0.5 * L + 2.5)
        sa, sb = (float(v) for v in strip_m)
        if not (0 <= sa - lead_m and sb + lead_m <= L and sb > sa):
            raise StudyError(f"Expected the strip [{sa}, {sb}] m with {lead_m} m lead on "
                             f"both sides inside the route [0, {L:.2f}] m, got it outside; "
                             "shorten the strip or the lead.")
        self.strip_m, self.lead_m = (sa, sb), float(lead_m)
        self.cells = c = mesh_surface(scene, frame, sample_m=sample_m, height_m=height_m,
                                      keep_floor=True, chainage_range_m=(sa, sb))
        if len(c.area) == 0:
            raise StudyError(f"Expected triangles along the strip [{sa}, {sb}] m, got none.")
        self.cell_m = float(sample_m)
        # Sample index by (triangle, sub-triangle) key, for the points' triangles.
        self._kmax = int(c.split.max()) ** 2
        key = c.triangle * self._kmax + c.sub
        self._order = np.argsort(key)
        self._keys = key[self._order]
        s = np.arange(sa - lead_m, sb + lead_m + 1e-9, 0.25)
        self.path = frame.to_world(s, 0.0, height_m)
        self._finish(height_m, settings, seed, reflectivity, keep_points, s,
                     frame.to_world(0.5 * (sa + sb), 0.0, height_m))
        return self

    def _cells_of(self, p: NDArray[Any], xyz: Floats, s: Floats, off: Floats,
                  h: Floats) -> NDArray[np.int64]:
        """Cell index (m,) of each point, -1 outside every cell of the strip."""
        from survey.analysis.planning import Cells
        from survey.analysis.surface import sub_index

        if isinstance(self.cells, Cells):
            c = self.cells
            sa = self.strip_m[0]
            phi = np.arctan2(off, h - self.hc)
            ring = ((s - sa) / self.cell_m).astype(np.int64)
            col = np.clip(((phi + np.pi) / (2 * np.pi) * self.n_a).astype(np.int64), 0,
                          self.n_a - 1)
            inside = (s >= sa) & (s < self.strip_m[1])
            ring = np.clip(ring, 0, c.shape[0] - 1)
            return np.where(inside, self._lookup[ring, col], -1)
        # The mesh path: barycentric coordinates of each point in its own triangle.
        tri = p["triangle"].astype(np.int64)
        ok = tri >= 0
        t = np.asarray(self.scene.faces)[np.maximum(tri, 0)]
        v = np.asarray(self.scene.vertices, dtype=np.float64)
        a = v[t[:, 0]]
        e1, e2, w = v[t[:, 1]] - a, v[t[:, 2]] - a, xyz - a
        g11, g12, g22 = (np.einsum("ni,ni->n", x, y) for x, y in
                         ((e1, e1), (e1, e2), (e2, e2)))
        r1, r2 = np.einsum("ni,ni->n", w, e1), np.einsum("ni,ni->n", w, e2)
        det = np.maximum(g11 * g22 - g12 * g12, 1e-300)
        sub = sub_index((g22 * r1 - g12 * r2) / det, (g11 * r2 - g12 * r1) / det,
                        self.cells.split[np.maximum(tri, 0)])
        key = np.maximum(tri, 0) * self._kmax + sub
        j = np.clip(np.searchsorted(self._keys, key), 0, len(self._keys) - 1)
        return np.where(ok & (self._keys[j] == key), self._order[j], -1)

    def __repr__(self) -> str:
        return (f"Study({self.sensor.name}, strip {self.strip_m[0]:g}-{self.strip_m[1]:g} "
                f"m, lead {self.lead_m:g} m, {len(self.cells.area):,} cells)")

    def _trajectory(self, speed_mps: float, rate_hz: float
                    ) -> tuple[Trajectory, float, float]:
        """(trajectory, t0, t1): along the path at constant speed, or standing at the
        strip's centre for one sweep at v = 0."""
        from scipy.spatial.transform import Rotation

        from sensors import Trajectory

        if speed_mps > 0:
            traj = Trajectory.along_polyline(self.path, speed_mps)
            return traj, traj.start_s, traj.end_s
        mid = len(self.path) // 2
        d = self.path[mid + 1] - self.path[mid - 1]
        rot = Rotation.from_euler("z", np.arctan2(d[1], d[0]))
        return Trajectory.static(self.path[mid], rot), 0.0, 1.0 / rate_hz + 1e-6

    def _tally_chunk(self, tally: _Tally, pts: NDArray[Any], traj: Trajectory,
                     mnt: Mount, t0: float, t1: float, speed_mps: float,
                     rate_hz: float) -> None:
        """Add one simulated chunk: cell counts, rolling-shutter distortion, forward
        floor footprints and (with ``keep_points``) the figure's floor points."""
        c = self.cells
        sa, sb = self.strip_m
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], 1)
        near = np.einsum("ni,ni->n", xyz - self._ball_c, xyz - self._ball_c) <= \
            self._ball_r ** 2
        pts, xyz = pts[near], xyz[near]
        s, off, h = self.frame.to_local(xyz)
        cell = self._cells_of(pts, xyz, s, off, h)
        ins = cell >= 0
        if not ins.any():
            return
        p, cell = pts[ins], cell[ins]
        s, off, h = s[ins], off[ins], h[ins]
        np.add.at(tally.counts, cell, 1)
        # Rolling shutter: the sweep assembled with the pose at its start.
        fr = p["frame"].astype(np.int64)
        tf = t0 + fr / rate_hz
        pos, mats = traj.sensor_matrices(np.minimum(tf, t1), mnt)
        sxyz = np.stack([p["sx"], p["sy"], p["sz"]], 1)
        ref = np.einsum("nij,nj->ni", mats, sxyz) + pos
        dd = np.linalg.norm(ref - np.stack([p["x"], p["y"], p["z"]], 1), axis=1)
        tally.dmax = max(tally.dmax, float(dd.max()))
        tally.dsq += float((dd * dd).sum())
        tally.nd += len(dd)
        # Forward floor beams for the line spacing.
        floor = c.is_floor[cell]
        f = floor & (np.abs(p["azimuth"]) < FORWARD_AZ_RAD)
        for ch, frm, ss in zip(p["channel"][f], fr[f], s[f]):
            a = tally.fwd.setdefault((int(ch), int(frm)), [0.0, 0])
            a[0] += ss
            a[1] += 1
        if self.keep_points:
            # Floor footprint of three sweeps from when the sensor passes the strip
            # centre (the rings of the seed's Figure 7).
            tc = t0 + (self.lead_m + 0.5 * (sb - sa)) / speed_mps if speed_mps > 0 else t0
            k = floor & (p["time"] >= tc) & (p["time"] < tc + 3.0 / rate_hz) & \
                (p["channel"] % 6 == 0)
            tally.keep.append(np.stack([s, off, h, p["time"] - tc], 1)[k])

    def run(self, speed_mps: float, rate_hz: float, mount: str = "level") -> StudyRow:
        """Drive the sensor through the strip at ``speed_mps`` with its rotation or
        profile rate set to ``rate_hz``, mounted "level" or "down"; the metrics."""
        from sensors import Mount, simulate_drive

        if not (np.isfinite(speed_mps) and speed_mps >= 0):
            raise StudyError(f"Expected a speed >= 0 m/s, got {speed_mps}.")
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise StudyError(f"Expected a positive rotation/profile rate, got {rate_hz} Hz.")
        if mount not in MOUNTS:
            raise StudyError(f"Expected a mount in {MOUNTS}, got {mount!r}.")
        spec = _with_rate(self.sensor, rate_hz)
        mnt = Mount.pointing_down() if mount == "down" else Mount()
        traj, t0, t1 = self._trajectory(speed_mps, rate_hz)
        run = simulate_drive(self.scene, spec, traj, mnt, settings=self.settings,
                             seed=self.seed, reflectivity=self.refl, t_start=t0, t_end=t1)
        c = self.cells
        tally = _Tally(np.zeros(len(c.area), dtype=np.int64))
        for pts in run:
            if len(pts):
                self._tally_chunk(tally, pts, traj, mnt, t0, t1, speed_mps, rate_hz)
        if self.keep_points:
            kp = np.concatenate(tally.keep) if tally.keep else np.zeros((0, 4))
            if len(kp) > self.keep_points:
                kp = kp[np.random.default_rng(0).choice(len(kp), self.keep_points,
                                                        replace=False)]
            self.kept[(float(speed_mps), float(rate_hz), mount)] = kp
        got = tally.counts
        lin, flo = ~c.is_floor, c.is_floor
        dens_l = got[lin].sum() / max(c.area[lin].sum(), 1e-12)
        dens_f = got[flo].sum() / max(c.area[flo].sum(), 1e-12)
        empty = float(c.area[lin & (got == 0)].sum() / max(c.area[lin].sum(), 1e-12))
        st = run.stats
        return StudyRow(float(speed_mps), float(rate_hz), mount, int(got.sum()),
                        float(dens_l), float(dens_f), empty, _line_spacing(tally.fwd),
                        float(speed_mps / rate_hz), tally.dmax,
                        float(np.sqrt(tally.dsq / tally.nd)) if tally.nd else 0.0,
                        float(speed_mps / rate_hz), int(st.get("pulses", 0)),
                        float(st.get("seconds", 0.0)))

    def run_kept(self, speed_mps: float, rate_hz: float, mount: str = "level"
                 ) -> tuple[StudyRow, NDArray[np.float64] | None]:
        """``run``, and the points it kept for the figures (``kept``; None without
        ``keep_points``): for runs in another process, whose ``kept`` is not this one's."""
        row = self.run(speed_mps, rate_hz, mount)
        return row, self.kept.get((float(speed_mps), float(rate_hz), mount))

    @staticmethod
    def configurations(speeds: Iterable[float], rates: Iterable[float],
                       mounts: Iterable[str] = ("level",)) -> list[tuple[float, float, str]]:
        """The (speed, rate, mount) triples ``grid`` runs, in its order (speeds varying
        fastest): each is one ``run``, independent of the others."""
        speeds, rates, mounts = list(speeds), list(rates), list(mounts)
        return [(v, f, m) for m in mounts for f in rates for v in speeds]

    def grid(self, speeds: Iterable[float], rates: Iterable[float],
             mounts: Iterable[str] = ("level",),
             progress: Callable[[int, int], object] | None = None) -> list[StudyRow]:
        """``run`` for every (speed, rate, mount), speeds varying fastest;
        ``progress(done, total)`` after each."""
        rows = []
        combos = self.configurations(speeds, rates, mounts)
        for i, (v, f, m) in enumerate(combos):
            rows.append(self.run(v, f, m))
            if progress:
                progress(i + 1, len(combos))
        return rows
