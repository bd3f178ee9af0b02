"""TLS station planning: which stations cover the lining well enough (seed Figure 6).

The lining is sampled as surface cells on an unrolled (chainage x angle) grid: a ray
from the tunnel axis at each cell centre finds the visible surface, its normal and the
cell's area. A station "sees" a cell when the segment station -> cell is free, the cell
lies within range and outside the scanner's blind cone. Its quality there follows from
geometry alone, so one ray per cell and station is enough at any resolution preset:

- range r, incidence alpha (between the beam and the surface normal),
- point spacing r * step / cos(alpha): the angular step of the chosen preset projected
  on the inclined surface (Soudarissanane et al. 2011, "Scanning geometry: influencing
  factor on the quality of terrestrial laser scanning points", ISPRS J. 66(4)).

A cell *meets the thresholds* from a station when range, incidence and spacing are all
within the user's limits; the plan's coverage is the area share of cells that at least
one station serves so. The floor (cells below the axis whose surface faces up) is not
lining and is left out.

Minimum station sets: exact set cover as a mixed-integer programme (``scipy.optimize.milp``,
HiGHS) on cells merged by identical candidate signature, with the greedy set (Chvátal
1979) as the fallback and as a bound; the optimality gap is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.analysis.surface import FLOOR_NORMAL_Z, RouteFrame, Surface, mesh_surface
from survey.errors import PlanningError
from survey.world.alignment import Alignment

if TYPE_CHECKING:
    from raytrace import Scene
    from sensors.route import Route
    from sensors.spec_types import SensorSpec

__all__ = ["OCCLUSION_EPS_M", "TRIPOD_HEIGHT_M", "Cells", "Plan", "Planner", "RoutePlanner",
           "StationQuality", "Thresholds", "axis_stations", "lining_cells",
           "station_quality"]

Floats = NDArray[np.float64]
Ints = NDArray[np.int64]

#: Tripod height above the floor (m) for stations on the axis.
TRIPOD_HEIGHT_M = 1.5
#: Station-to-cell rays stop this far short of the cell (m) so that the cell's own
#: surface does not occlude it.
OCCLUSION_EPS_M = 2e-3


@dataclass(repr=False)
class Thresholds:
    """Quality limits for a cell served by a station: point spacing (m), incidence
    angle between beam and surface normal (radians) and range (m)."""

    spacing_m: float = 0.005
    incidence_rad: float = float(np.deg2rad(70.0))
    range_m: float = 30.0

    def __repr__(self) -> str:
        return (f"Thresholds(spacing_m={self.spacing_m:g}, incidence_rad="
                f"{self.incidence_rad:.4f} ({np.degrees(self.incidence_rad):.1f} deg), "
                f"range_m={self.range_m:g})")

    def __post_init__(self) -> None:
        for k in ("spacing_m", "incidence_rad", "range_m"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v > 0):
                raise PlanningError(f"Expected a positive threshold `{k}`, got {v}.")


@dataclass(repr=False)
class Cells:
    """Lining cells on an unrolled grid of ``shape`` (rings, around).

    chainage, angle : (k,) float64, cell centre: chainage (m) and angle from the crown
        (radians, positive left)
    points, normals : (k, 3) float64, surface point (m) and unit normal facing the axis
    area : (k,) float64, m^2
    ring, col : (k,) int64, grid indices
    s_edges : (rings + 1,) float64, m; a_edges : (around + 1,) float64, radians
    is_floor : (k,) bool, floor cells (kept only by ``keep_floor``)
    """

    chainage: Floats
    angle: Floats
    points: Floats
    normals: Floats
    area: Floats
    ring: Ints
    col: Ints
    shape: tuple[int, int]
    s_edges: Floats
    a_edges: Floats
    is_floor: NDArray[np.bool_]

    def __repr__(self) -> str:
        return (f"Cells({len(self.area):,} cells on a {self.shape[0]} x {self.shape[1]} "
                f"grid, {self.total_area:.1f} m^2)")

    @property
    def total_area(self) -> float:
        """Sum of the cell areas (m^2)."""
        return float(self.area.sum())


def lining_cells(scene: Scene, alignment: Alignment, centre_height_m: float, *,
                 chainage_range_m: tuple[float, float] | None = None, cell_m: float = 0.25,
                 cell_rad: float = float(np.deg2rad(2.0)), keep_floor: bool = False
                 ) -> Cells:
    """Sample the visible surface around the axis in cells of ``cell_m`` (m) x
    ``cell_rad`` (radians) between the chainages ``chainage_range_m`` (default: the
    whole alignment); floor cells dropped unless ``keep_floor`` (``Cells.is_floor``
    marks them)."""
    c0, c1 = alignment.chainage_range if chainage_range_m is None else chainage_range_m
    if not (cell_m > 0 and cell_rad > 0 and c1 > c0):
        raise PlanningError(f"Expected positive cell sizes and a chainage range with end > "
                            f"start, got {cell_m} m, {cell_rad} rad, [{c0}, {c1}].")
    n_s = max(1, int(np.floor((c1 - c0) / cell_m)))
    n_a = max(4, int(round(2 * np.pi / cell_rad)))
    s_edges = np.asarray(c0 + np.arange(n_s + 1) * cell_m, dtype=np.float64)
    a_edges = np.asarray(-np.pi + np.arange(n_a + 1) * (2 * np.pi / n_a), dtype=np.float64)
    s = 0.5 * (s_edges[1:] + s_edges[:-1])
    a = 0.5 * (a_edges[1:] + a_edges[:-1])
    S, A = np.meshgrid(s, a, indexing="ij")
    origin = alignment.to_world(S, 0.0, centre_height_m).reshape(-1, 3)
    tip = alignment.to_world(S, np.sin(A), centre_height_m + np.cos(A)).reshape(-1, 3)
    d = tip - origin
    hits = scene.cast(origin, d)
    ok = hits.hit
    n = hits.normals
    # Orient the normals towards the axis (the side the scanner looks from).
    n = np.where((np.einsum("ni,ni->n", n, d) > 0)[:, None], -n, n)
    floor = (A.ravel() > np.pi / 2) | (A.ravel() < -np.pi / 2)
    floor &= n[:, 2] > FLOOR_NORMAL_Z
    keep = ok & ~floor if not keep_floor else ok
    rho = hits.t
    area = cell_m * np.where(ok, rho, 0) * (2 * np.pi / n_a)
    ring, col = np.divmod(np.arange(n_s * n_a), n_a)
    return Cells(S.ravel()[keep], A.ravel()[keep], hits.points[keep], n[keep],
                 area[keep], ring[keep], col[keep], (n_s, n_a), s_edges, a_edges,
                 floor[keep])


@dataclass(repr=False)
class StationQuality:
    """Per-cell view of one station, each (k,): visible (bool), range (m), incidence
    (radians), point spacing (m)."""

    visible: NDArray[np.bool_]
    range_m: Floats
    incidence_rad: Floats
    spacing_m: Floats

    def __repr__(self) -> str:
        return f"StationQuality({int(self.visible.sum()):,} of {len(self.visible):,} cells seen)"

    def meets(self, th: Thresholds) -> NDArray[np.bool_]:
        """Cells (k,) seen within every threshold."""
        return self.visible & (self.range_m <= th.range_m) & \
            (self.incidence_rad <= th.incidence_rad) & (self.spacing_m <= th.spacing_m)


def station_quality(scene: Scene, cells: Cells | Surface, station: ArrayLike, step_rad: float, *,
                    range_max_m: float, vertical_fov_rad: float = 2 * np.pi
                    ) -> StationQuality:
    """Quality of every cell seen from ``station`` (3,) by a level scanner with angular
    step ``step_rad`` (see module doc); cells beyond ``range_max_m`` are not cast."""
    st = np.asarray(station, dtype=np.float64)
    d = cells.points - st
    r = np.linalg.norm(d, axis=1)
    k = len(r)
    vis = np.zeros(k, dtype=bool)
    blind_el = -(np.pi / 2 - (2 * np.pi - vertical_fov_rad) / 2)
    el = np.arcsin(np.clip(d[:, 2] / np.maximum(r, 1e-12), -1, 1))
    cand = (r <= range_max_m) & (r > OCCLUSION_EPS_M) & (el >= blind_el)
    idx = np.flatnonzero(cand)
    if len(idx):
        vis[idx] = ~scene.occluded(st, d[idx], t_max=r[idx] - OCCLUSION_EPS_M)
    cosi = np.clip(-np.einsum("ni,ni->n", d, cells.normals) / np.maximum(r, 1e-12), 0, 1)
    inc = np.arccos(cosi)
    spacing = r * step_rad / np.maximum(cosi, 1e-9)
    return StationQuality(vis, r, inc, spacing)


def axis_stations(scene: Scene, alignment: Alignment, centre_height_m: float,
                  chainages: ArrayLike, *, height_m: float = TRIPOD_HEIGHT_M) -> Floats:
    """Stations (k, 3) on the axis at ``height_m`` above the floor found straight below
    the axis at each chainage (k,) (m)."""
    s = np.asarray(chainages, dtype=np.float64).reshape(-1)
    top = alignment.to_world(s, 0.0, centre_height_m)
    hits = scene.cast(top, np.broadcast_to([0.0, 0.0, -1.0], top.shape))
    if not hits.hit.all():
        bad = s[~hits.hit]
        raise PlanningError(f"Expected a floor below the axis at every station, got none "
                            f"at chainage {bad[:5].tolist()} m; is the axis inside the "
                            "tunnel?")
    out = hits.points.copy()
    out[:, 2] += height_m
    return out


@dataclass(repr=False)
class Plan:
    """Stations and what they achieve.

    Attributes
    ----------
    name : str, the plan's name
    stations : (k, 3) float64, station positions, m
    chainages : (k,) float64, station chainages, m
    served : (k_cells,) int, stations meeting the thresholds per cell
    seen : (k_cells,) int, stations seeing the cell within the range threshold
    coverage : float, area share of cells served by at least one station
    per_station : (k,) float64, area share each station serves alone
    overlap : (k - 1,) float64, share of station i's seen area also seen by station i + 1
    gaps : list of dicts (chainage_from, chainage_to, angle_from_deg, angle_to_deg,
        area_m2), the uncovered regions, largest first
    note : str, a remark shown in the ``repr`` ("" for none)
    offsets_m : (k,) float64, lateral offsets (m, left positive) of route stations;
        zeros on the axis
    """

    name: str
    stations: Floats
    chainages: Floats
    served: Ints
    seen: Ints
    coverage: float
    per_station: Floats
    overlap: Floats
    gaps: list[dict[str, float]] = field(default_factory=list)
    note: str = ""
    #: (k,) lateral offsets (m, left positive) of route stations; zeros on the axis.
    offsets_m: Floats = field(default_factory=lambda: np.zeros(0))

    def __repr__(self) -> str:
        return (f"Plan({self.name!r}, {len(self.chainages)} stations, coverage "
                f"{100 * self.coverage:.2f} %, {len(self.gaps)} gaps"
                + (f", {self.note}" if self.note else "") + ")")


class Planner:
    """Coverage of candidate stations on one tunnel, computed once and reused."""

    def __init__(self, scene: Scene, alignment: Alignment, centre_height_m: float,
                 sensor: SensorSpec, *, resolution: str | None = None,
                 thresholds: Thresholds | None = None, cell_m: float = 0.25,
                 cell_rad: float = float(np.deg2rad(2.0)),
                 chainage_range_m: tuple[float, float] | None = None,
                 height_m: float = TRIPOD_HEIGHT_M) -> None:
        self._setup(scene, sensor, resolution, thresholds, height_m)
        self.alignment, self.hc = alignment, float(centre_height_m)
        self.cells: Cells | Surface = lining_cells(
            scene, alignment, self.hc, chainage_range_m=chainage_range_m, cell_m=cell_m,
            cell_rad=cell_rad)
        if len(self.cells.area) == 0:
            raise PlanningError("Expected lining cells around the axis, got none; does "
                                "the axis run inside the mesh?")

    def _setup(self, scene: Scene, sensor: SensorSpec, resolution: str | None,
               thresholds: Thresholds | None, height_m: float) -> None:
        """The sensor, its angular step and the thresholds (shared by both planners)."""
        if sensor.kind != "tls":
            raise PlanningError(f"Expected a TLS sensor for station planning, got "
                                f"{sensor.name} ({sensor.kind}).")
        pattern: Any = sensor.pattern          # a TLSPattern (checked above)
        res = resolution or pattern.default_resolution
        steps = pattern.resolutions_rad
        if res not in steps:
            raise PlanningError(f"Expected a resolution of {sensor.name} "
                                f"({', '.join(steps)}), got {res!r}.")
        self.scene = scene
        self.sensor, self.resolution, self.step_rad = sensor, res, float(steps[res])
        self.th = thresholds or Thresholds()
        self.height_m = height_m
        self._cache: dict[tuple[float, ...], StationQuality] = {}

    def __repr__(self) -> str:
        return (f"Planner({self.sensor.name} at {self.resolution}, "
                f"{len(self.cells.area):,} cells, {self.th!r})")

    @staticmethod
    def _key(station: ArrayLike) -> tuple[float, ...]:
        return tuple(np.round(np.asarray(station, dtype=np.float64), 6))

    def uncached(self, stations: ArrayLike) -> Floats:
        """The rows of ``stations`` (k, 3) whose quality is not computed yet, once each
        (for computing them elsewhere: ``remember``)."""
        seen: set[tuple[float, ...]] = set()
        rows = []
        for p in np.asarray(stations, dtype=np.float64).reshape(-1, 3):
            k = self._key(p)
            if k not in self._cache and k not in seen:
                seen.add(k)
                rows.append(p)
        return np.array(rows).reshape(-1, 3)

    def remember(self, stations: ArrayLike, qualities: list[StationQuality]) -> None:
        """Keep qualities computed elsewhere (by ``quality`` in another process) for
        ``stations`` (k, 3)."""
        st = np.asarray(stations, dtype=np.float64).reshape(-1, 3)
        if len(st) != len(qualities):
            raise PlanningError(f"Expected one quality per station ({len(st)}), got "
                                f"{len(qualities)}.")
        for p, q in zip(st, qualities, strict=True):
            self._cache[self._key(p)] = q

    def quality(self, station: ArrayLike) -> StationQuality:
        """Quality of every cell from ``station`` (3,) (cached per station)."""
        key = self._key(station)
        if key not in self._cache:
            rmax = min(self.sensor.physics.range_max_m, self.th.range_m)
            pattern: Any = self.sensor.pattern
            self._cache[key] = station_quality(
                self.scene, self.cells, station, self.step_rad, range_max_m=rmax,
                vertical_fov_rad=pattern.vertical_fov_rad)
        return self._cache[key]

    @property
    def span_m(self) -> tuple[float, float]:
        """(first, last) chainage (m) the stations may take."""
        c = self.cells
        assert isinstance(c, Cells)
        return float(c.s_edges[0]), float(c.s_edges[-1])

    def _where(self, chainages: ArrayLike) -> Floats:
        """Station places in plan order: chainages (k,) sorted."""
        return np.sort(np.asarray(chainages, dtype=np.float64).reshape(-1))

    def stations_at(self, chainages: ArrayLike) -> Floats:
        """Stations (k, 3) on the axis at chainages (k,) (m)."""
        return axis_stations(self.scene, self.alignment, self.hc, chainages,
                             height_m=self.height_m)

    def spaced(self, spacing_m: float, *, start_m: float | None = None) -> Floats:
        """Chainages every ``spacing_m`` (first at half a spacing from the start)."""
        c0, c1 = self.span_m
        if not spacing_m > 0:
            raise PlanningError(f"Expected a positive station spacing, got {spacing_m} m.")
        first = c0 + spacing_m / 2 if start_m is None else start_m
        return np.arange(first, c1, spacing_m)

    def evaluate(self, chainages: ArrayLike, name: str = "plan", note: str = "") -> Plan:
        """The plan of stations at ``chainages`` (k,) (m)."""
        s = self._where(chainages)
        st = self.stations_at(s) if len(s) else np.zeros((0, 3))
        a = self.cells.area
        served = np.zeros(len(a), dtype=np.int64)
        seen = np.zeros(len(a), dtype=np.int64)
        per, vis = [], []
        for p in st:
            q = self.quality(p)
            m = q.meets(self.th)
            v = q.visible & (q.range_m <= self.th.range_m)
            served += m
            seen += v
            per.append(a[m].sum() / a.sum())
            vis.append(v)
        overlap = np.array([a[vis[i] & vis[i + 1]].sum() / max(a[vis[i]].sum(), 1e-12)
                            for i in range(len(vis) - 1)])
        cov = float(a[served > 0].sum() / a.sum())
        off = s[:, 1] if s.ndim == 2 else np.zeros(len(s))
        return Plan(name, st, s[:, 0] if s.ndim == 2 else s, served, seen, cov,
                    np.array(per), overlap, self.gaps(served > 0), note, off)

    def gaps(self, covered: NDArray[np.bool_]) -> list[dict[str, float]]:
        """Connected uncovered regions of the unrolled grid, largest first."""
        from scipy import ndimage

        c = self.cells
        assert isinstance(c, Cells)
        grid = np.zeros(c.shape, dtype=bool)
        grid[c.ring[~covered], c.col[~covered]] = True
        area = np.zeros(c.shape)
        area[c.ring, c.col] = c.area
        lab, n = ndimage.label(grid)
        out = []
        for k in range(1, n + 1):
            r, q = np.nonzero(lab == k)
            out.append({"chainage_from": float(c.s_edges[r.min()]),
                        "chainage_to": float(c.s_edges[r.max() + 1]),
                        "angle_from_deg": float(np.degrees(c.a_edges[q.min()])),
                        "angle_to_deg": float(np.degrees(c.a_edges[q.max() + 1])),
                        "area_m2": float(area[r, q].sum())})
        return sorted(out, key=lambda g: -g["area_m2"])

    # ------------------------------------------------------------------ optimisation
    def optimize(self, candidates: ArrayLike, *, target: float = 0.99,
                 time_limit_s: float = 60.0) -> tuple[Plan, Plan, dict[str, Any]]:
        """Smallest set of candidate chainages whose stations serve ``target`` of the
        lining area. Returns (Plan of the optimum (or best found), Plan of the greedy set,
        info dict with the MILP status, bound and gap)."""
        from scipy.optimize import Bounds, LinearConstraint, milp
        from scipy.sparse import csr_matrix

        if not 0 < target <= 1:
            raise PlanningError(f"Expected a target coverage in (0, 1], got {target}.")
        cand = self._where(candidates)
        if len(cand) == 0:
            raise PlanningError("Expected at least one candidate station, got none.")
        st = self.stations_at(cand)
        M = np.stack([self.quality(p).meets(self.th) for p in st], axis=1)   # cells x k
        a = self.cells.area
        total = a.sum()
        reach = a[M.any(axis=1)].sum() / total
        info: dict[str, Any] = {"candidates": len(cand), "target": target, "reachable": float(reach)}
        goal = target
        if reach < target:
            goal = reach
            info["note"] = (f"the target {100 * target:.1f} % is not reachable with these "
                            f"candidates (all of them serve {100 * reach:.2f} %); planned "
                            "for the reachable coverage instead")
        # Merge cells with the same candidate signature: exact, and far fewer rows.
        sig, inv = np.unique(M, axis=0, return_inverse=True)
        w = np.bincount(inv.ravel(), weights=a) / total
        useful = sig.any(axis=1)
        sig, w = sig[useful], w[useful]
        greedy = self._greedy(sig, w, goal)
        info["greedy"] = len(greedy)
        k, g = len(cand), len(w)
        # Variables: x (k, binary stations), y (g, continuous cell-group covered).
        c = np.concatenate([np.ones(k), np.zeros(g)])
        rows = [np.concatenate([np.zeros(k), w])]                 # sum w y >= goal
        A1 = csr_matrix(np.hstack([-sig.astype(float), np.eye(g)]))  # y - sum x <= 0
        cons = [LinearConstraint(np.array(rows), goal - 1e-9, np.inf),
                LinearConstraint(A1, -np.inf, 0.0)]
        integrality = np.concatenate([np.ones(k), np.zeros(g)])
        res = milp(c, constraints=cons, integrality=integrality,
                   bounds=Bounds(np.zeros(k + g), np.ones(k + g)),
                   options={"time_limit": time_limit_s})
        if res.x is not None:
            chosen = np.flatnonzero(res.x[:k] > 0.5)
            bound = float(getattr(res, "mip_dual_bound", np.nan))
            info.update(milp_status=res.message, milp=len(chosen),
                        lower_bound=float(np.ceil(bound - 1e-6)) if np.isfinite(bound)
                        else float("nan"), optimal=res.status == 0)
            if len(chosen) > len(greedy):          # time limit hit with a poor incumbent
                chosen = np.array(greedy)
        else:
            chosen = np.array(greedy)
            info.update(milp_status=res.message, milp=None, lower_bound=float("nan"),
                        optimal=False)
        lb = info["lower_bound"]
        info["gap"] = (float(len(chosen) - lb) / len(chosen)) if np.isfinite(lb) and \
            len(chosen) else float("nan")
        best = self.evaluate(cand[chosen], "optimised",
                             "optimal (MILP)" if info["optimal"] else "best found")
        gr = self.evaluate(cand[np.array(greedy, dtype=int)], "greedy")
        return best, gr, info

    @staticmethod
    def _greedy(sig: NDArray[np.bool_], w: Floats, goal: float) -> list[int]:
        covered = np.zeros(len(w), dtype=bool)
        chosen = []
        while w[covered].sum() < goal - 1e-9:
            gain = (sig & ~covered[:, None]).T.astype(float) @ w
            j = int(np.argmax(gain))
            if gain[j] <= 0:
                break
            chosen.append(j)
            covered |= sig[:, j]
        return sorted(chosen)


class RoutePlanner(Planner):
    """Station planning on any mesh: candidate stations along the route found in it
    (``sensors.route.find_route``) and offset across it, ``height_m`` above the floor
    under them; coverage measured on the mesh's own triangles (``mesh_surface``), by
    the rule of the grid path (``station_quality``, ``StationQuality.meets``).

    Stations are placed by (distance along the route, left offset) in m; ``evaluate``
    and ``optimize`` take (k,) distances or (k, 2) (distance, offset) rows.
    """

    def __init__(self, scene: Scene, sensor: SensorSpec, *, route: Route | None = None,
                 waypoints: ArrayLike | None = None, resolution: str | None = None,
                 thresholds: Thresholds | None = None, sample_m: float = 0.25,
                 height_m: float = TRIPOD_HEIGHT_M, clearance_m: float = 0.2,
                 keep_floor: bool = False) -> None:
        from sensors.route import find_route
        from sensors.freespace import free_space

        self._setup(scene, sensor, resolution, thresholds, height_m)
        if route is None:
            self.space = free_space(scene)
            route = find_route(scene, waypoints=waypoints, height_m=height_m,
                               clearance_m=clearance_m, space=self.space)
        else:
            self.space = free_space(scene, voxel_m=route.voxel_m,
                                    start=route.points[len(route.points) // 2])
        self.route, self.clearance_m = route, float(clearance_m)
        # DECISION: the frame runs through the floor under the route, so that stations
        # at any height_m are placed from the floor and the unrolled angle is seen from
        # the instrument's height.
        self.frame = RouteFrame(route.floor)
        self.surface = mesh_surface(scene, self.frame, sample_m=sample_m,
                                    height_m=height_m, keep_floor=keep_floor)
        self.cells = self.surface
        if len(self.cells.area) == 0:
            raise PlanningError("Expected triangles to cover, got none (every one is "
                                "floor or has no area).")
        tri = np.unique(np.round(np.asarray(scene.vertices) / 1e-6), axis=0,
                        return_inverse=True)[1].reshape(-1)
        self._faces = tri[np.asarray(scene.faces)]        # faces on merged vertices

    def __repr__(self) -> str:
        return (f"RoutePlanner({self.sensor.name} at {self.resolution}, route "
                f"{self.frame.length_m:.1f} m, {len(self.cells.area):,} samples, "
                f"{self.th!r})")

    @property
    def span_m(self) -> tuple[float, float]:
        """(0, route length) in m."""
        return self.frame.chainage_range

    def _where(self, chainages: ArrayLike) -> Floats:
        """(k, 2) (distance, offset) rows in plan order; (k,) distances get offset 0."""
        w = np.asarray(chainages, dtype=np.float64)
        w = np.column_stack([w.reshape(-1), np.zeros(w.size)]) if w.ndim < 2 else w
        if w.shape[1] != 2:
            raise PlanningError(f"Expected stations as (k,) distances or (k, 2) "
                                f"(distance, offset) rows, got shape {w.shape}.")
        return w[np.lexsort((w[:, 1], w[:, 0]))]

    def _place(self, where: ArrayLike) -> tuple[Floats, NDArray[np.bool_]]:
        """Stations (k, 3) and whether each fits: a floor under it, in sight of the
        route and at least ``clearance_m`` from the mesh."""
        w = self._where(where)
        s, off = w[:, 0], w[:, 1]
        L = self.frame.length_m
        if ((s < -1e-9) | (s > L + 1e-9)).any():
            raise PlanningError(f"Expected distances along the route within [0, {L:.3f}] "
                                f"m, got {s[(s < 0) | (s > L)][:5].tolist()}.")
        # From the route point at the instrument height across to the offset, then down.
        top = self.frame.to_world(s, off, self.height_m)
        mid = self.frame.to_world(s, 0.0, self.height_m)
        ok = np.ones(len(s), dtype=bool)
        side = np.flatnonzero(off != 0)
        if len(side):
            ok[side] = ~self.scene.occluded(mid[side], top[side] - mid[side],
                                            t_max=np.abs(off[side]))
        hits = self.scene.cast(top, np.broadcast_to([0.0, 0.0, -1.0], top.shape))
        st = np.where(hits.hit[:, None], hits.points, top - [0.0, 0.0, self.height_m])
        st = st + [0.0, 0.0, self.height_m]
        ok &= hits.hit & (self.space.distance(st) >= self.clearance_m - 1e-9)
        return st, ok

    def stations_at(self, chainages: ArrayLike) -> Floats:
        """Stations (k, 3) at (k,) distances along the route or (k, 2) (distance,
        offset) rows (m), ``height_m`` above the floor under them."""
        st, ok = self._place(chainages)
        w = self._where(chainages)
        if not ok.all():
            bad = w[~ok][:3].round(2).tolist()
            raise PlanningError(f"Expected every station {self.clearance_m:g} m or more "
                                f"from the mesh with a floor under it, got {int((~ok).sum())}"
                                f" that do not fit at (distance, offset) {bad} m; lower "
                                "the height or the offsets.")
        return st

    def candidates(self, step_m: float, offsets_m: ArrayLike = (0.0,)) -> Floats:
        """(k, 2) (distance, offset) rows every ``step_m`` along the route at each of
        ``offsets_m`` (m, left positive) that fit (``stations_at``); the rest dropped."""
        d = self.spaced(step_m)
        off = np.unique(np.append(np.asarray(offsets_m, dtype=np.float64).reshape(-1), 0.0))
        w = np.array([(a, b) for a in d for b in off], dtype=np.float64).reshape(-1, 2)
        return w[self._place(w)[1]] if len(w) else w

    def gaps(self, covered: NDArray[np.bool_]) -> list[dict[str, float]]:
        """Uncovered regions of the mesh, largest first: triangles holding an uncovered
        sample, joined where they share a vertex; per region its distance and angle
        span along the route, its uncovered area (m^2) and its area-weighted centre
        (x, y, z)."""
        from scipy import sparse
        from scipy.sparse import csgraph

        c = self.surface
        gap_faces = np.unique(c.triangle[~covered])
        if len(gap_faces) == 0:
            return []
        fv = self._faces[gap_faces]
        m = sparse.csr_matrix((np.ones(fv.size), (np.repeat(np.arange(len(fv)), 3),
                                                   fv.ravel())))
        n, lab = csgraph.connected_components(m @ m.T, directed=False)
        comp = lab[np.searchsorted(gap_faces, c.triangle[~covered])]
        a, s, ang, p = c.area[~covered], c.chainage[~covered], c.angle[~covered], \
            c.points[~covered]
        out = []
        for k in range(n):
            q = comp == k
            w = a[q]
            x, y, z = (w[:, None] * p[q]).sum(axis=0) / w.sum()
            out.append({"chainage_from": float(s[q].min()), "chainage_to": float(s[q].max()),
                        "angle_from_deg": float(np.degrees(ang[q].min())),
                        "angle_to_deg": float(np.degrees(ang[q].max())),
                        "area_m2": float(w.sum()), "x": float(x), "y": float(y),
                        "z": float(z)})
        return sorted(out, key=lambda g: -g["area_m2"])
