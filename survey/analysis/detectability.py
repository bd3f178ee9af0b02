"""Detectability study (issue 17, item 6): the smallest lining deformation a survey
detects, and its false alarms, for a sensor x speed (or station spacing) x noise grid.

A stretch of a generated tunnel is laid out with known deformations
(``DetectLayout``): undeformed reference lining, a zone of uniform radial convergence,
undeformed lining, a ring of local bulges. Each configuration scans the stretch as
built (epoch 1) and, with the same sensor, poses and noise seed, deformed at each
magnitude (one epoch 2 per magnitude, ``TunnelMesh.deformed``), so every magnitude is
seen from the same places. M3C2 (``M3C2``, Lague et al. 2013) at core points of epoch 1
with normals towards the tunnel axis gives distances (positive: convergence), LoD95 and
significance.

Definitions (per configuration and deformation kind):

- Target region of a target: the core points where the deformation is (nearly) at its
  magnitude m: for a convergence zone its plateau (full value) shrunk by the cylinder
  radius at both ends, so that every point of every cylinder there moved by m; for a
  bulge of amplitude m the lining within ``BULGE_CORE_FRACTION`` x radius of its
  centre (developed distance; true displacement >= 0.75 m).
- Detection share of a target: the share of its target-region core points flagged
  significant (|d| > LoD95) with d > 0 (the right direction).
- Detected with 95 % probability: detection share >= ``POD_TARGET`` = 0.95.
  ``detectable_m`` is the smallest magnitude of the grid from which on every larger
  magnitude is detected so (NaN: none). This is the hit/miss probability of detection
  evaluated at each tested size, without a model (MIL-HDBK-1823A, 2009, hit/miss
  data: POD(a) as the share of detected targets of size a).
- ``a95_m``: the same threshold from the "a-hat versus a" model of MIL-HDBK-1823A
  (2009; Berens 1989, ASM Metals Handbook vol. 17): the measured distance d is
  regressed on the true displacement a at the target-region and reference core points,
  d = b0 + b1 a + e, e ~ N(0, tau^2); a point is detected when d > LoD (the median
  LoD95 of the target-region points), so POD(a) = Phi((b0 + b1 a - LoD) / tau) and
  a95 = (LoD + 1.645 tau - b0) / b1. Continuous between the tested magnitudes.
- False-alarm rate: the share of reference core points (undeformed lining, at least
  ``margin`` from every deformation's support along the axis) flagged significant (either
  sign). With LoD95 = 1.96 sigma_d it is 5 % for Gaussian distances; more where the
  spreads are estimated from few points (Student's t), less where the two epochs sample
  the same roughness (identical poses: the roughness cancels in d but not in the spreads).
  ``reference_sd_m``, the observed spread of d there, shows which: at a Z+F's own noise
  the lining's shape inside a cylinder dominates the spreads, LoD95 / 1.96 exceeds the
  observed spread ~1.5x and the rate is ~0 % (benchmarks/RESULTS.md, 2026-11-27).

DECISION: common random numbers (Law & Kelton, Simulation Modeling and Analysis, 4th
ed., chapter 11): every configuration draws epoch 1 and epoch 2 with the same two
seeds (and a noise factor scales the same draws), so that differences between
configurations come from the configurations, not from the draw. The two epochs use
different seeds: their noise is independent, as in two surveys.

DECISION: the epochs are registered perfectly (they share the simulation frame);
``registration_error_m`` of the M3C2 parameters adds a real survey's registration error
to the LoD95.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from raytrace.checks import positive
from survey.errors import StudyError
from survey.world.deformation import total_field

# The layout and the POD statistics live in modules of their own; their public names
# are re-exported here, where users have always imported them from.
from .detect_layout import (BULGE_ANGLES_RAD, BULGE_CORE_FRACTION, KINDS, DetectLayout,
                            DetectTarget)
from .detect_stats import POD_TARGET, ahat_a95, detection_limit

if TYPE_CHECKING:
    from raytrace import Scene
    from sensors.physics import Settings
    from sensors.spec_types import SensorSpec
    from survey.analysis.m3c2 import M3C2Params
    from survey.world.mesh import TunnelMesh

__all__ = ["CUT_M", "LINING_LABELS",
           "DetectRow", "Detectability",
           "TargetScore", "with_noise"]

Floats = NDArray[np.float64]


def _pos(value: Any, name: str, zero: bool = False) -> float:
    return positive(value, name, StudyError, zero=zero, what="a number")


@dataclass
class TargetScore:
    """One target in one configuration: ``points`` target-region core points with a
    distance, the share detected, the median distance and LoD95 there (m)."""

    kind: str
    magnitude_m: float
    points: int
    detected_share: float
    median_distance_m: float
    median_lod_m: float

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class DetectRow:
    """One configuration's result (SI units; module doc for the definitions).

    speed_mps is NaN for a TLS, spacing_m NaN for a moving sensor; noise is the factor
    on the sensor's range and angle noise. detectable_m and a95_m map each kind to m.
    """

    sensor: str
    sensor_kind: str
    speed_mps: float
    spacing_m: float
    noise: float
    points1: int
    points2: int
    core_points: int
    reference_points: int
    false_alarm_rate: float
    median_lod_m: float          # on the reference lining
    detectable_m: dict[str, float]
    a95_m: dict[str, float]
    targets: list[TargetScore] = field(default_factory=list)
    #: Standard deviation of the M3C2 distance on the reference lining (m): against
    #: ``median_lod_m`` / 1.96 it shows how conservative LoD95 is for this survey.
    reference_sd_m: float = float("nan")

    def to_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["targets"] = [t.to_dict() for t in self.targets]
        return d


def with_noise(spec: SensorSpec, factor: float) -> SensorSpec:
    """The spec with its range noise (reference and floor) and angular noise times
    ``factor`` (>= 0)."""
    k = _pos(factor, "noise factor", zero=True)
    p = spec.physics
    return replace(spec, physics=replace(
        p, range_sigma_m=k * p.range_sigma_m, range_sigma_floor_m=k * p.range_sigma_floor_m,
        angle_sigma_rad=k * p.angle_sigma_rad))




#: Face labels of the lining, where core points stand (``survey.world.mesh.LABELS``).
LINING_LABELS = ("lining", "floor", "wet_floor")
#: Lining kept in the scanned scenes beyond the layout's lead at each end, m. ASSUMED:
#: TLS stations stand within one spacing of the layout, and 25 m covers spacings up
#: to 20 m; lining farther off adds pulses, never core points.
CUT_M = 25.0


class Detectability:
    """One tunnel, one deformation layout; ``run`` scores a configuration.

    Parameters
    ----------
    tunnel : TunnelMesh
        A generated tunnel (``survey.world``: ``preset`` or ``read_tunnel``); its
        alignment must hold the layout with ``lead_m`` on both sides.
    layout : DetectLayout
    params : M3C2Params, optional
        M3C2 parameters; by default cylinder radius 0.1 m, half-length 0.1 m, normal
        radius 0.25 m (ASSUMED: a 0.2 m projection scale holds tens of points at
        centimetre spacing; normals over 0.5 m average the roughness of a lining).
    core_spacing_m : float
        Core points: epoch 1 subsampled to one point per cube of this edge (m).
    lead_m : float
        Scanned lining beyond the layout at each end (a moving sensor also starts and
        stops this far out), m.
    settings : Settings, optional
        Physics switches of the simulation (default ``Settings()``: noise, jitter,
        detection on).
    seed : int >= 0
        Seed of the study (epoch 1 and epoch 2 draw from two seeds spawned from it).
    margin_m : float, optional
        Reference lining keeps this far (m) from every deformation's support along the
        axis; default twice the cylinder radius.

    Raises
    ------
    StudyError
        Not a generated tunnel, a layout outside it, bad parameters.
    """

    def __init__(self, tunnel: TunnelMesh, layout: DetectLayout, *,
                 params: M3C2Params | None = None, core_spacing_m: float = 0.1,
                 lead_m: float = 2.0, settings: Settings | None = None, seed: int = 0,
                 margin_m: float | None = None) -> None:
        from raytrace import Scene
        from survey.analysis.m3c2 import M3C2Params
        from survey.world.mesh import LABEL, TunnelMesh

        if not isinstance(tunnel, TunnelMesh):
            raise StudyError(f"Expected a generated TunnelMesh, got "
                             f"{type(tunnel).__name__}; read one with read_tunnel.")
        if not isinstance(layout, DetectLayout):
            raise StudyError(f"Expected a DetectLayout, got {type(layout).__name__}; "
                             "build one with DetectLayout.build.")
        self.tunnel, self.layout = tunnel, layout
        self.params = params if params is not None else M3C2Params(0.1, 0.1, (0.25,))
        if not isinstance(self.params, M3C2Params) or not self.params.normal_radii_m:
            raise StudyError("Expected M3C2Params with `normal_radii_m` (normals are "
                             f"computed from epoch 1), got {self.params!r}.")
        self.core_spacing_m = _pos(core_spacing_m, "core_spacing_m")
        self.lead_m = _pos(lead_m, "lead_m", zero=True)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise StudyError(f"Expected a seed >= 0, got {seed!r}.")
        self.seed, self.settings = int(seed), settings
        self.margin_m = 2 * self.params.cyl_radius_m if margin_m is None else \
            _pos(margin_m, "margin_m", zero=True)
        al, prof = tunnel.alignment, tunnel.profile
        c0, c1 = al.chainage_range
        lo, hi = layout.start_m - self.lead_m, layout.end_m + self.lead_m
        if not (c0 <= lo and hi <= c1):
            raise StudyError(f"Expected the layout [{layout.start_m:g}, "
                             f"{layout.end_m:g}] m with {self.lead_m:g} m lead inside the "
                             f"tunnel [{c0:g}, {c1:g}] m, got it outside; move the start "
                             "or shorten the layout.")
        self.hc = float(prof.centroid[1])
        self.alignment = al
        self._t_centres = np.array([prof.t_at_angle(a) for a in BULGE_ANGLES_RAD])
        # DECISION: scan a cut of the tunnel (module constant CUT_M): the tube far off
        # only costs BVH memory and build time, once per epoch-2 scene.
        s = tunnel.vertex_chainage
        self.cut_m = (max(c0, lo - CUT_M), min(c1, hi + CUT_M))
        inside = np.isfinite(s) & (s >= self.cut_m[0]) & (s <= self.cut_m[1])
        keep = inside[tunnel.faces].all(axis=1)
        self.faces = tunnel.faces[keep]
        self.reflectivity = np.asarray(tunnel.reflectivity)[keep]
        # Truth per vertex: chainage, profile parameter, displacement at unit magnitude.
        self._vs, self._vt = s, tunnel.vertex_param
        self._unit = total_field(layout.deformations(1.0), s, self._vt, prof)
        scenes = [Scene(tunnel.vertices, self.faces)]
        for m in layout.magnitudes_m:
            scenes.append(Scene(tunnel.deformed(layout.deformations(m)).vertices,
                                self.faces))
        #: Epoch 1, then epoch 2 at each magnitude of the layout.
        self.scenes: tuple[Scene, ...] = tuple(scenes)
        self.keep_m = (lo, hi)
        # World box of the kept lining (+0.5 m): most points of a scan fall outside it
        # and skip the exact chainage (``Alignment.to_local``).
        vk = np.isfinite(s) & (s >= lo - 0.5) & (s <= hi + 0.5)
        self._box = np.stack([tunnel.vertices[vk].min(axis=0) - 0.5,
                              tunnel.vertices[vk].max(axis=0) + 0.5])
        # Core points stand on the lining itself (cables, bolts, prisms excluded).
        lining = [LABEL[n] for n in LINING_LABELS]
        self._on_lining = np.isin(tunnel.labels[keep], lining)
        ss = np.random.SeedSequence(self.seed).spawn(2)
        self.epoch_seeds = tuple(int(q.generate_state(1, np.uint32)[0]) for q in ss)

    def __repr__(self) -> str:
        return (f"Detectability({len(self.layout.magnitudes_m)} magnitudes over "
                f"{self.layout.start_m:g}-{self.layout.end_m:g} m, core spacing "
                f"{self.core_spacing_m:g} m)")

    # ------------------------------------------------------------------ scanning
    def stations(self, spacing_m: float) -> Floats:
        """TLS station chainages (k,) for ``spacing_m``: every spacing from the start of
        the convergence plateau, within one spacing of the layout and inside the cut."""
        sp = _pos(spacing_m, "spacing_m")
        s0 = self.layout.targets[0].plateau_m[0]
        a = max(self.layout.start_m - sp, self.cut_m[0] + 1.0)
        b = min(self.layout.end_m + sp, self.cut_m[1] - 1.0)
        k = np.arange(np.ceil((a - s0) / sp - 1e-9), np.floor((b - s0) / sp + 1e-9) + 1)
        return s0 + k * sp

    def _scan(self, scene: Scene, seed: int, spec: SensorSpec, speed_mps: float,
              spacing_m: float, resolution: str | None, height_m: float
              ) -> tuple[Floats, NDArray[np.int64]]:
        """Points (n, 3) of one epoch within the kept chainages and their triangles
        (indices into the cut faces)."""
        from sensors import Mount, Trajectory, simulate_drive, simulate_station
        from survey.analysis.planning import axis_stations

        a, b = self.layout.start_m, self.layout.end_m
        runs = []
        if spec.kind == "tls":
            pos = axis_stations(self.scenes[0], self.alignment, self.hc,
                                self.stations(spacing_m), height_m=height_m)
            for k, p in enumerate(pos):
                # Each run is read once: no replay cache (the runs are kept in a list).
                runs.append(simulate_station(scene, spec, p, resolution=resolution,
                                             settings=self.settings, seed=seed + k,
                                             reflectivity=self.reflectivity,
                                             cache_bytes=0))
        else:
            s = np.arange(a - self.lead_m, b + self.lead_m + 1e-9, 0.25)
            path = axis_stations(self.scenes[0], self.alignment, self.hc, s,
                                 height_m=height_m)
            traj = Trajectory.along_polyline(path, speed_mps)
            runs.append(simulate_drive(scene, spec, traj, Mount(), settings=self.settings,
                                       seed=seed, reflectivity=self.reflectivity,
                                       cache_bytes=0))
        xyz, tri = [], []
        lo, hi = self.keep_m
        for run in runs:
            for pts in run:
                if not len(pts):
                    continue
                p = np.stack([pts["x"], pts["y"], pts["z"]], 1)
                tr = pts["triangle"].astype(np.int64)
                near = np.all((p >= self._box[0]) & (p <= self._box[1]), axis=1) & \
                    (tr >= 0)
                p, tr = p[near], tr[near]
                s_, _, _ = self.alignment.to_local(p)
                ok = (s_ >= lo) & (s_ <= hi)
                xyz.append(p[ok])
                tri.append(tr[ok])
        if not xyz:
            return np.empty((0, 3)), np.empty(0, np.int64)
        return np.concatenate(xyz), np.concatenate(tri)

    def _truth(self, xyz: Floats, tri: NDArray[np.int64]) -> tuple[Floats, Floats, Floats]:
        """(chainage, profile parameter, displacement at unit magnitude) at points on
        their triangles, interpolated barycentrically from the vertices."""
        per = self.tunnel.profile.perimeter_m
        fv = self.faces[tri]
        v = self.tunnel.vertices
        a = v[fv[:, 0]]
        e1, e2, w = v[fv[:, 1]] - a, v[fv[:, 2]] - a, xyz - a
        g11, g12, g22 = (np.einsum("ni,ni->n", x, y) for x, y in
                         ((e1, e1), (e1, e2), (e2, e2)))
        r1, r2 = np.einsum("ni,ni->n", w, e1), np.einsum("ni,ni->n", w, e2)
        det = np.maximum(g11 * g22 - g12 * g12, 1e-300)
        u = (g22 * r1 - g12 * r2) / det
        vv = (g11 * r2 - g12 * r1) / det
        wts = np.stack([1 - u - vv, u, vv], 1)
        s = np.einsum("nk,nk->n", wts, self._vs[fv])
        t = self._vt[fv]
        t = t[:, :1] + np.mod(t - t[:, :1] + per / 2, per) - per / 2   # unwrap
        t = np.mod(np.einsum("nk,nk->n", wts, t), per)
        f = np.einsum("nk,nk->n", wts, self._unit[fv])
        return s, t, f

    # ------------------------------------------------------------------ scoring
    def run(self, sensor: SensorSpec, *, speed_mps: float | None = None,
            spacing_m: float | None = None, noise: float = 1.0,
            resolution: str | None = None, rate_hz: float | None = None,
            height_m: float | None = None) -> DetectRow:
        """Scan epoch 1 and epoch 2 at every magnitude with one configuration; score it.

        Parameters
        ----------
        sensor : SensorSpec
        speed_mps : float > 0
            A moving sensor's speed along the axis (spinning lidar, profiler).
        spacing_m : float > 0
            A TLS's station spacing on the axis (``stations``).
        noise : float >= 0
            Factor on the sensor's range and angular noise (``with_noise``).
        resolution : str, optional
            A TLS resolution preset (default: the sensor's).
        rate_hz : float, optional
            A moving sensor's rotation / profile rate (default: the sensor's).
        height_m : float, optional
            Sensor height above the floor (default 1.5 m for a TLS, 1.0 m moving).

        Returns
        -------
        DetectRow
        """
        from sensors.spec_types import SensorSpec
        from sensors.spec import with_rate
        from survey.analysis.m3c2 import M3C2, towards_axis

        if not isinstance(sensor, SensorSpec):
            raise StudyError(f"Expected a SensorSpec (load_sensor), got "
                             f"{type(sensor).__name__}.")
        spec = with_noise(sensor, noise)
        if spec.kind == "tls":
            spacing_m = _pos(spacing_m, "spacing_m")
            speed_mps = float("nan")
            height_m = 1.5 if height_m is None else height_m
        else:
            speed_mps = _pos(speed_mps, "speed_mps")
            spacing_m = float("nan")
            height_m = 1.0 if height_m is None else height_m
            if rate_hz is not None:
                spec = with_rate(spec, rate_hz)
        height_m = _pos(height_m, "height_m")
        scan = (spec, speed_mps, spacing_m, resolution, height_m)
        e1, tri = self._scan(self.scenes[0], self.epoch_seeds[0], *scan)
        if len(e1) < 3:
            raise StudyError(f"Expected points of {sensor.name} on the layout, got "
                             f"{len(e1)}.")
        # Core points: the first epoch-1 point of each cube (as m3c2.subsample), within
        # the layout's chainages.
        cell = np.floor((e1 - e1.min(axis=0)) / self.core_spacing_m).astype(np.int64)
        dims = cell.max(axis=0) + 1
        key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
        _, first = np.unique(key, return_index=True)
        idx = np.sort(first)
        idx = idx[self._on_lining[tri[idx]]]
        s, t, f1 = self._truth(e1[idx], tri[idx])
        inl = (s >= self.layout.start_m) & (s <= self.layout.end_m)
        core, s, t, f1 = e1[idx[inl]], s[inl], t[inl], f1[inl]
        per = self.tunnel.profile.perimeter_m
        regions = {tg.kind: tg.region(s, t, per, self._t_centres, self.params.cyl_radius_m)
                   for tg in self.layout.targets}
        ref0 = np.ones(len(core), dtype=bool)
        for tg in self.layout.targets:
            ref0 &= (s < tg.lo_m - self.margin_m) | (s > tg.hi_m + self.margin_m)
        centre = (float(self.tunnel.profile.centroid[0]), self.hc)
        towards = towards_axis(self.alignment, core, centre)
        normals = None
        n2 = 0
        scores: list[TargetScore] = []
        fit: dict[str, list[tuple[Floats, Floats, Floats]]] = {k: [] for k in KINDS}
        fa, nref, lod_ref, sd_ref = float("nan"), 0, float("nan"), float("nan")
        for j, m in enumerate(self.layout.magnitudes_m):
            e2, _ = self._scan(self.scenes[1 + j], self.epoch_seeds[1], *scan)
            if len(e2) < 3:
                raise StudyError(f"Expected points of {sensor.name} on the layout in "
                                 f"epoch 2, got {len(e2)}.")
            n2 = max(n2, len(e2))
            job = M3C2(e1, e2, self.params)
            if normals is None:
                normals, _ = job.normals(core, towards=towards)
            res = job.compute(core, normals=normals)
            d, lod = res.distance, res.lod
            ok = np.isfinite(d) & np.isfinite(lod)
            hit = res.significant & (d > 0)
            ref = ref0 & ok
            if j == 0:
                # The reference lining is the same in every epoch 2 (same seed, same
                # undeformed triangles): its false alarms are counted once.
                nref = int(ref.sum())
                fa = float(res.significant[ref].mean()) if nref else float("nan")
                lod_ref = float(np.median(lod[ref])) if nref else float("nan")
                sd_ref = float(np.std(d[ref])) if nref > 1 else float("nan")
            for kind in KINDS:
                reg = regions[kind] & ok
                n = int(reg.sum())
                scores.append(TargetScore(
                    kind, m, n, float(hit[reg].mean()) if n else float("nan"),
                    float(np.median(d[reg])) if n else float("nan"),
                    float(np.median(lod[reg])) if n else float("nan")))
                sel = reg | ref
                fit[kind].append((np.where(reg[sel], m * f1[sel], 0.0), d[sel], lod[reg]))
        detectable, a95 = {}, {}
        for kind in KINDS:
            sc = [x for x in scores if x.kind == kind]
            detectable[kind] = detection_limit([x.magnitude_m for x in sc],
                                               [x.detected_share for x in sc])
            a, dd, ll = (np.concatenate(x) for x in zip(*fit[kind]))
            a95[kind] = ahat_a95(a, dd, ll)["a_pod"]
        return DetectRow(
            sensor.name, sensor.kind, float(speed_mps), float(spacing_m), float(noise),
            len(e1), n2, len(core), nref, fa, lod_ref, detectable, a95, scores,
            reference_sd_m=sd_ref)

    def grid(self, sensors: Sequence[SensorSpec], *, speeds_mps: Iterable[float] = (),
             spacings_m: Iterable[float] = (), noises: Iterable[float] = (1.0,),
             progress: Callable[[int, int], object] | None = None,
             **kwargs: Any) -> list[DetectRow]:
        """``run`` for every sensor x (speed for a moving sensor, spacing for a TLS) x
        noise factor, noise varying fastest; ``kwargs`` as for ``run``;
        ``progress(done, total)`` after each."""
        speeds, spacings, noises = list(speeds_mps), list(spacings_m), list(noises)
        combos: list[tuple[SensorSpec, str, float, float]] = []
        for spec in sensors:
            tls = spec.kind == "tls"
            passes = spacings if tls else speeds
            if not passes:
                raise StudyError(f"Expected {'station spacings' if tls else 'speeds'} for "
                                 f"{spec.name} ({spec.kind}), got none.")
            for v in passes:
                for k in noises:
                    combos.append((spec, "spacing_m" if tls else "speed_mps", v, k))
        if not combos:
            raise StudyError("Expected at least one sensor, got none.")
        if not noises:
            raise StudyError("Expected at least one noise factor, got none.")
        rows = []
        for i, (spec, key, v, k) in enumerate(combos):
            if key == "spacing_m":
                rows.append(self.run(spec, spacing_m=v, noise=k, **kwargs))
            else:
                rows.append(self.run(spec, speed_mps=v, noise=k, **kwargs))
            if progress:
                progress(i + 1, len(combos))
        return rows
