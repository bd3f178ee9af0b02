"""Routes found in a mesh: the free space inside it, its floor, and a path along the
middle of the passage at a sensor's height above that floor.

Method, in four steps; steps 1 and 2 (the free space on a voxel grid, and the floor
voxels where a sensor ``height_m`` above keeps ``clearance_m``, joined into a graph)
are ``sensors.freespace``'s.

1. **Free space** (``free_space``) and 2. **Floor** (``FloorGraph``): see
   ``sensors.freespace``.
3. **Path.** The ends are the two drivable voxels farthest apart by walking distance,
   found by a double sweep (Dijkstra from the widest voxel to the farthest, then from
   there to the farthest again; exact on a tree, tight on passages: Magnien, Latapy & Habib 2009, "Fast computation of
   empirically tight bounds for the diameter of massive graphs"), each moved to the
   middle of its end of the passage; at a junction that is the longest branch. The
   route is the cheapest path between the ends, or through the waypoints in order, with
   edge cost ``length / width**p``: a maximum-clearance path as in the clearance-weighted
   planners of Wein, van den Berg & Halperin (2008, "Planning high-quality paths and
   corridors amidst obstacles", IJRR 27) and Geraerts & Overmars (2007, "Creating
   high-quality paths for motion planning", IJRR 26): it keeps to the medial ridge
   rather than cutting bends.
4. **Smoothing and height.** Each leg is smoothed with a Gaussian moving average
   (``smoothing_m``; its ends kept by point reflection), cut where the floor ends under
   an oblique open end, resampled every ``spacing_m``, set on the floor by rays cast
   down (``Scene.cast``) and lifted by ``height_m``. Every point's exact distance to the
   mesh (``Scene.closest``: closest point on a triangle, Ericson 2005, "Real-Time
   Collision Detection" 5.1.5) is measured; where one is below ``clearance_m`` the
   smoothing is halved, then dropped.
5. **The platform** (issue 29, with ``platform``). Where the passage is narrower than
   ``clearance_m`` the route is sought again on the floor where the sensor keeps
   ``MIN_SENSOR_CLEARANCE_M``, and a narrow spot is passed with a warning naming it.
   Along the route the platform is stood on the floor (``_assess``: its contacts by
   rays cast down, every ``ASSESS_STEP_M``) and its ``traversability`` judged: slope
   and roll of the plane through its contacts, steps, ground under its belly, room
   for its footprint between the walls. The floor within its reach of any place it
   cannot cross is taken out of the graph and the route sought again (at most
   ``MAX_DETOURS`` times), or cut back when the trouble lies within ``END_TRIM_M``
   of a free end; where no way is left the route is refused naming the place and
   what is wrong there.

>>> from raytrace.shapes import tunnel_tube
>>> route = find_route(tunnel_tube(1500, length_m=10.0), voxel_m=0.1)
>>> round(route.length_m), round(route.min_clearance_m, 2), route.points.shape[1]
(10, 0.5, 3)
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage, sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from raytrace import Scene
from raytrace.fileio import atomic_writer

from ._checks import as_number
from .errors import RouteError
from .freespace import (FLOOR_OFFSET_VOX, MAX_VOXELS, MIN_VOXEL_M, FloorGraph, FreeSpace,
                        free_space, point_text)
from .platform_spec import PlatformSpec
from .trajectory import Trajectory

__all__ = ["ASSESS_STEP_M", "END_TRIM_M", "MAX_DETOURS", "MIN_SENSOR_CLEARANCE_M", "ROUTE_CSV_COLUMNS", "Route",
           "find_route", "read_waypoints"]

#: A second part of the drivable floor at least this share of it is reported (a
#: warning): the passage is cut by a pinch, not just a pocket behind a boulder or a
#: strip beyond a drain (ASSUMED: a drain beside a wall leaves ~15 %).
SPLIT_WARN_SHARE = 0.25
#: The voxel path is centred between the walls by rays (``_recentre``): from a
#: reference smoothed over ``RECENTRE_REF_M``, middles within ``RECENTRE_MAX_VOX`` voxels
#: of the path, median over ``RECENTRE_MEDIAN_M`` (ASSUMED: over twice a niche's length,
#: 1.5 m in the generator, so that a niche does not pull the route).
RECENTRE_REF_M = 2.0
RECENTRE_MAX_VOX = 1.0
RECENTRE_MEDIAN_M = 4.0
#: With a platform, the least distance the sensor keeps from the mesh at a narrow spot
#: (its footprint's room is judged on its own, ``_assess``). ASSUMED: the radius of a
#: lidar's head (RoboSense Airy ~0.1 m across, a VLP-16 0.103 m).
MIN_SENSOR_CLEARANCE_M = 0.05
#: Spacing of the samples where a platform's ground is judged (m): a step is a rise
#: between two of them (ASSUMED: fine enough that a 45 deg slope rises 5 cm, under any
#: step limit, and coarse enough to be cheap).
ASSESS_STEP_M = 0.05
#: With a platform, trouble within this distance of a free end of the route (no
#: waypoint there) cuts the route back rather than sending it round (m, ASSUMED: the
#: open end of a scanned tile is often ragged; a metre is a robot's length or three).
END_TRIM_M = 1.0
#: Times the route is sought again round the places a platform cannot cross before it
#: is refused (each round blocks the floor within the platform's reach of them).
MAX_DETOURS = 12
#: Rays cast down for the floor under a platform's contacts reach this far below the
#: route's floor (m, ASSUMED): a hole deeper than that is no floor (the contact keeps
#: the route's floor height).
_ASSESS_DROP_M = 0.5
#: Columns of the route CSV (``Route.write_csv``).
ROUTE_CSV_COLUMNS = ("s_m", "x", "y", "z", "floor_z", "clearance_m")


@dataclass(frozen=True, repr=False)
class Route:
    """A route found in a mesh (``find_route``).

    Attributes
    ----------
    points : (n, 3) float64
        Sensor positions (world, m), evenly spaced, ``height_m`` above the floor.
    floor : (n, 3) float64
        The floor under each point (where the ray cast down hit it).
    clearance_m : (n,) float64
        Exact distance of each point to the mesh (m).
    distance_m : (n,) float64
        Distance along the route (m), from 0.
    waypoints : (k, 3) float64
        The ends, or the waypoints, as the route reached them (sensor positions).
    voxel_m, seconds : float
        The voxel used, and the time taken to find the route (s).
    """

    points: NDArray[np.float64]
    floor: NDArray[np.float64]
    clearance_m: NDArray[np.float64]
    distance_m: NDArray[np.float64]
    waypoints: NDArray[np.float64]
    voxel_m: float
    seconds: float

    @property
    def length_m(self) -> float:
        return float(self.distance_m[-1])

    @property
    def min_clearance_m(self) -> float:
        return float(self.clearance_m.min())

    def trajectory(self, speed_mps: float, *, accel_mps2: float | None = None,
                   rate_hz: float = 100.0, follow_grade: bool = False,
                   start_time: float = 0.0) -> Trajectory:
        """The route driven at ``speed_mps`` (``Trajectory.along_polyline``)."""
        return Trajectory.along_polyline(self.points, speed_mps, rate_hz=rate_hz,
                                         start_time=start_time, follow_grade=follow_grade,
                                         accel_mps2=accel_mps2)

    def write_csv(self, path: str | os.PathLike[str]) -> Path:
        """The route as CSV (``ROUTE_CSV_COLUMNS``), atomically; returns the path.
        ``read_waypoints`` reads it back."""
        path = Path(path)
        data = np.column_stack([self.distance_m, self.points, self.floor[:, 2],
                                self.clearance_m])
        with atomic_writer(path, "w") as fh:
            fh.write(",".join(ROUTE_CSV_COLUMNS) + "\n")
            np.savetxt(fh, data, delimiter=",", fmt="%.6f")
        return path

    def __repr__(self) -> str:
        return (f"Route({self.length_m:.1f} m, {len(self.points)} points, smallest "
                f"clearance {self.min_clearance_m:.2f} m, voxel {self.voxel_m:.2f} m)")


def find_route(mesh: Scene | tuple[ArrayLike, ArrayLike], *,
               waypoints: ArrayLike | None = None, start: ArrayLike | None = None,
               height_m: float = 0.5, clearance_m: float = 0.2,
               voxel_m: float | None = None, max_voxels: int = MAX_VOXELS,
               spacing_m: float = 0.25, smoothing_m: float = 0.5,
               clearance_power: float = 2.0, space: FreeSpace | None = None,
               platform: PlatformSpec | None = None,
               min_clearance_m: float | None = None) -> Route:
    """A route along the middle of the passage of a mesh, ``height_m`` above its floor.

    Parameters
    ----------
    mesh : raytrace.Scene, or (vertices (n, 3) float, faces (m, 3) int)
        Any triangle mesh of a passage (tunnel, cave, mine), z up, metres.
    waypoints : (k, 2) or (k, 3) array_like of float, optional
        Points to visit in order (k >= 2); the route starts at the first and ends at the
        last. x, y pick the floor under them; z (NaN: none) picks the floor below z when
        passages lie above one another (without z: the lowest). By default the route
        joins the two ends of the passage that lie farthest apart.
    start : (3,) array_like of float, optional
        A point in the free space to use (``free_space``); by default the largest.
    height_m : float
        Sensor height above the floor (m), > ``clearance_m``.
    clearance_m : float
        Distance the route keeps from the mesh at every point (m) where the passage
        allows it (``--clearance`` of the CLI).
    voxel_m, max_voxels
        The grid (``free_space``).
    spacing_m : float
        Distance between the route's points (m).
    smoothing_m : float
        Standard deviation of the Gaussian moving average along the route (m); halved
        where the smoothed route would come closer than ``clearance_m``.
    clearance_power : float
        p in the edge cost length / width**p (0: the shortest path).
    space : FreeSpace, optional
        A free space already built for this mesh (``voxel_m``, ``max_voxels`` and
        ``start`` are then ignored).
    platform : PlatformSpec, optional
        What drives the route. With its ``traversability`` the route keeps to ground
        it can cross (slope, roll, steps, belly) with room for its footprint, going
        round what it cannot cross (``_assess``).
    min_clearance_m : float, optional
        The least distance from the mesh at which the route still goes through a
        narrow spot, with a warning naming it (default: ``clearance_m``; with a
        platform, ``MIN_SENSOR_CLEARANCE_M``: its footprint's room is then judged by
        ``_assess``).

    Returns
    -------
    Route

    Raises
    ------
    RouteError
        No enclosed free space, ``start`` or a waypoint outside it, waypoints not
        connected, a passage too narrow (or low) for ``min_clearance_m`` at
        ``height_m``, or, with a platform, no way across ground it can cross.

    Warns
    -----
    UserWarning
        A narrow spot passed below ``clearance_m``; a drivable floor cut in two large
        parts (the route runs in the largest).
    """
    t0 = time.perf_counter()
    height_m = as_number(height_m, "height_m", RouteError, unit="m", lo=0, lo_open=True)
    clearance_m = as_number(clearance_m, "clearance_m", RouteError, unit="m", lo=0)
    spacing_m = as_number(spacing_m, "spacing_m", RouteError, unit="m", lo=0,
                          lo_open=True)
    smoothing_m = as_number(smoothing_m, "smoothing_m", RouteError, unit="m", lo=0)
    power = as_number(clearance_power, "clearance_power", RouteError, unit="1", lo=0)
    if height_m <= clearance_m:
        raise RouteError(f"Expected the sensor height above the clearance, got a height "
                         f"of {height_m:g} m and a clearance of {clearance_m:g} m; pass a "
                         "smaller --clearance or a larger --height.")
    if platform is not None and platform.traversability is None:
        platform = None
    if min_clearance_m is None:
        fit = min(clearance_m, MIN_SENSOR_CLEARANCE_M) if platform is not None else \
            clearance_m
    else:
        fit = as_number(min_clearance_m, "min_clearance_m", RouteError, unit="m", lo=0)
        fit = min(fit, clearance_m)
    wp = None if waypoints is None else _waypoint_array(waypoints)
    if space is None:
        space = free_space(mesh, voxel_m=voxel_m, max_voxels=max_voxels, start=start)
    # DECISION: the route is first sought keeping clearance_m (the voxel test), as before
    # issue 29, so that what found a route then finds the same one; only where that
    # fails (no floor, a floor cut in two, waypoints apart) is it sought again with the
    # least clearance the platform needs, and a narrow spot then only warns.
    tries = [clearance_m] if fit >= clearance_m else [clearance_m, fit]
    for k, graph_clear in enumerate(tries):
        try:
            route = _find(space, wp, height_m, clearance_m, graph_clear, fit, spacing_m,
                          smoothing_m, power, platform, final=k == len(tries) - 1)
        except _Retry as exc:
            if k == len(tries) - 1:
                raise RouteError(str(exc)) from None
            continue
        return Route(route.points, route.floor, route.clearance_m, route.distance_m,
                     route.waypoints, route.voxel_m, time.perf_counter() - t0)
    raise AssertionError("unreachable")                          # pragma: no cover


class _Retry(RouteError):
    """Not found at this graph clearance; try the next (internal)."""


def _find(space: FreeSpace, wp: NDArray[np.float64] | None, height_m: float,
          clearance_m: float, graph_clear: float, fit: float, spacing_m: float,
          smoothing_m: float, power: float, platform: PlatformSpec | None, *,
          final: bool) -> Route:
    """``find_route``'s steps 2-4 with the floor graph built at ``graph_clear``: the
    route, smoothed while it keeps ``clearance_m``, accepted down to ``fit`` (with a
    warning), and rerouted round what ``platform`` cannot cross."""
    s = space.voxel_m
    try:
        fl = FloorGraph(space, height_m, graph_clear, None if platform is None else
                        _step_of(platform))
    except RouteError as exc:
        raise _Retry(str(exc)) from None
    g_len, width = fl.g_len, fl.width[fl.nodes]
    n_parts, part = csgraph.connected_components(g_len, directed=False)
    if wp is None:
        sizes = np.bincount(part)
        big = int(np.argmax(sizes))
        if n_parts > 1 and np.sort(sizes)[-2] >= SPLIT_WARN_SHARE * len(part):
            if not final:
                raise _Retry("cut")
            share = 100 * sizes[big] / len(part)
            step, fix = ("", "") if platform is None else (
                f", or by a step over the {platform.name}'s {_step_of(platform):g} m",
                ", or --platform with one that climbs the step")
            warnings.warn(f"The drivable floor is cut where the passage is narrower than "
                          f"2 x {graph_clear:g} m (or lower than {height_m + graph_clear:g} "
                          f"m){step}; the route runs in the largest part, {share:.0f} % of "
                          f"it; pass --waypoints to choose another part{fix}.", UserWarning,
                          stacklevel=3)
        src = int(np.argmax(np.where(part == big, width, -np.inf)))
        a = _far_end(fl.g_sweep, src, width, part == big)
        stops = [a, _far_end(fl.g_sweep, a, width, part == big)]
    else:
        stops = [fl.snap(p, i + 1) for i, p in enumerate(wp)]
        keep = [0] + [i for i in range(1, len(stops)) if stops[i] != stops[i - 1]]
        if len(keep) < 2:
            raise RouteError(f"Expected waypoints apart from one another, got "
                             f"{len(wp)} on the same voxel of {s:.3g} m; pass a smaller "
                             "--voxel or waypoints farther apart.")
        for i in range(1, len(stops)):
            if part[stops[i]] != part[stops[i - 1]]:
                raise _Retry(
                    f"Expected waypoint {i + 1} {point_text(wp[i])} to be reachable from "
                    f"waypoint {i} {point_text(wp[i - 1])}, got no path between them that "
                    f"keeps {graph_clear:g} m from the mesh at {height_m:g} m above the "
                    "floor; the passage between them is closed, too narrow or too low: "
                    "pass a smaller --clearance or --voxel, or other --waypoints.")
        stops, wp = [stops[i] for i in keep], wp[keep]
    cost = fl.cost_graph(power).tocoo()
    blocked = np.zeros(len(fl.nodes), dtype=np.bool_)
    trouble, kind = "", ""
    centres = fl.centres(np.arange(len(fl.nodes)))
    tree = cKDTree(centres[:, :2])
    reach = 0.0
    if platform is not None:
        tv = platform.traversability
        assert tv is not None
        reach = 0.5 * float(np.hypot(tv.footprint_width_m, tv.footprint_length_m)) + s
    for detour in range(MAX_DETOURS + 1):
        ok_edge = ~blocked[cost.row] & ~blocked[cost.col]
        g = sparse.csr_matrix((cost.data[ok_edge], (cost.row[ok_edge], cost.col[ok_edge])),
                              shape=cost.shape)
        legs = _legs(g, stops)
        if legs is None:
            raise RouteError(_no_way(platform, trouble, kind))
        # The smoothest shape that keeps the clearance and that the platform can cross;
        # else the last (unsmoothed: the voxel path itself).
        bad = np.zeros((0, 3))
        # DECISION: after a detour the route is not moved to the middle between the
        # walls (``_recentre``): that pulls it back onto what it had to go round.
        for pts, floor, clr, at in _shapes(space, fl, legs, stops, wp, height_m,
                                           spacing_m, smoothing_m, recentre=not detour):
            if platform is not None:
                bad, trouble, kind = _assess(space.scene, floor, height_m, platform)
                if len(bad) and wp is None:
                    cut = _trim_ends(pts, floor, clr, bad, reach)
                    if cut is not None:
                        pts, floor, clr, at = cut
                        bad = np.zeros((0, 3))
            if clr.min() >= clearance_m and not len(bad):
                break
        if not len(bad):
            break
        # DECISION: block the floor within the platform's reach of every place it
        # cannot cross (not the stops) and seek the route again: the graph has no
        # notion of slope or step finer than its voxels, the floor under the
        # footprint has.
        for p, near in zip(bad, tree.query_ball_point(bad[:, :2], reach)):
            near = np.asarray(near, dtype=np.int64)
            near = near[np.abs(centres[near, 2] - FLOOR_OFFSET_VOX * s - p[2]) < 0.5]
            blocked[near] = True
        blocked[stops] = False
    else:
        raise RouteError(_no_way(platform, trouble, kind))
    i = int(np.argmin(clr))
    if clr[i] < fit:
        raise RouteError(f"Expected a passage where the sensor, {height_m:g} m above the "
                         f"floor, keeps at least {fit:g} m from the mesh, got {clr[i]:.3g} m "
                         f"at {point_text(pts[i])}; pass a smaller --clearance or --voxel "
                         "(a finer grid finds the middle of a narrow passage), or "
                         "--waypoints round it.")
    if clr[i] < clearance_m:
        who = "" if platform is None else \
            f" (the {platform.name} has room for its footprint there)"
        warnings.warn(f"The passage is narrow at {point_text(pts[i])}: the sensor keeps "
                      f"{clr[i]:.3g} m from the mesh there, below the {clearance_m:g} m "
                      f"asked (--clearance){who}; the route goes through.", UserWarning,
                      stacklevel=3)
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return Route(pts, floor, clr, dist, pts[at], s, 0.0)


def _shapes(space: FreeSpace, fl: FloorGraph, legs: list[NDArray[np.int64]],
            stops: list[int], wp: NDArray[np.float64] | None, height_m: float,
            spacing_m: float, smoothing_m: float, recentre: bool = True
            ) -> Iterator[tuple[NDArray[Any], ...]]:
    """Step 4: the legs smoothed by ``smoothing_m``, then a half, a quarter and not at
    all, each (if ``recentre``) moved to the middle between the walls, set on the
    floor and lifted: points (n, 3), floor (n, 3), clearance (n,) and the indices of
    the stops (k,), smoothest first."""
    s = space.voxel_m
    ends = fl.centres(stops)
    if wp is not None:      # a waypoint over drivable floor is passed through exactly
        over = np.linalg.norm(ends[:, :2] - wp[:, :2], axis=1) <= s
        ends[over, :2] = wp[over, :2]
    for sigma in (smoothing_m, smoothing_m / 2, smoothing_m / 4, 0.0):
        if 0 < sigma < s:
            continue
        parts, at = [], [0]
        for k, leg in enumerate(legs):
            c = fl.centres(leg)
            c[0, :2], c[-1, :2] = ends[k, :2], ends[k + 1, :2]
            q = _resample(c, s)
            if sigma > 0:
                q = _smooth(q, sigma / s)
            if sigma > 0 and recentre:
                q = _recentre(space.scene, q, height_m, s, sigma / s,
                              fixed=(wp is not None or k > 0,
                                     wp is not None or k < len(legs) - 1))
            # Voxels straddle an oblique open end: cut the route where the floor ends.
            on = np.flatnonzero(_floor_under(space.scene, q, height_m, s)[1])
            if len(on):
                q = q[on[0] if k == 0 else 0:on[-1] + 1 if k == len(legs) - 1 else None]
            q = _resample(q, spacing_m)
            parts.append(q if k == 0 else q[1:])
            at.append(at[-1] + len(q) - 1)
        floor, hit = _floor_under(space.scene, np.vstack(parts), height_m, s)
        if hit.sum() < 2:
            raise RouteError(f"Expected a floor under the route, got none under "
                             f"{int((~hit).sum())} of its {len(hit)} points; is the mesh "
                             "upside down or open below? Check --mesh.")
        pts = floor + [0.0, 0.0, height_m]
        clear = space.scene.closest(pts).distance
        yield pts, floor, clear, np.asarray(at, dtype=np.int64)


def _trim_ends(pts: NDArray[np.float64], floor: NDArray[np.float64],
               clr: NDArray[np.float64], bad: NDArray[np.float64], reach: float
               ) -> tuple[NDArray[Any], ...] | None:
    """The route (points, floor, clearance, stop indices) cut back from its free ends
    past the places ``bad`` (k, 3) the platform cannot cross, with ``reach`` to spare,
    when all of them lie within ``END_TRIM_M`` of an end; else None."""
    d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(floor, axis=0), axis=1))])
    at = d[cKDTree(floor).query(bad)[1]]
    length = d[-1]
    head, tail = at[at <= END_TRIM_M], at[at >= length - END_TRIM_M]
    if len(head) + len(tail) < len(at):
        return None
    a = head.max() + reach if len(head) else 0.0
    b = tail.min() - reach if len(tail) else length
    keep = np.flatnonzero((d >= a) & (d <= b))
    if b - a < 2 * END_TRIM_M or len(keep) < 2:
        return None
    return (pts[keep], floor[keep], clr[keep], np.array([0, len(keep) - 1]))


def _step_of(platform: PlatformSpec) -> float:
    """The platform's step limit (m)."""
    assert platform.traversability is not None
    return platform.traversability.max_step_m


def _no_way(platform: PlatformSpec | None, trouble: str, kind: str) -> str:
    """The refusal when no route joins the stops round what the platform cannot
    cross: the place and what it is, and the options that change it."""
    who = "the platform" if platform is None else f"the {platform.name}"
    what = f": {trouble}" if trouble else ""
    if kind == "room":
        fix = "--platform with a narrower one, or --waypoints to drive another part"
    elif platform is not None and platform.name != "walker":
        fix = ("--platform with one that crosses it (walker: steps up to 0.4 m, slopes "
               "up to 35 deg), or --waypoints to drive another part")
    else:
        fix = "--waypoints to drive another part"
    return (f"Expected a route {who} can drive between the route's ends, got none{what} "
            f"and no way round it; pass {fix}.")


def _assess(scene: Scene, floor: NDArray[np.float64], height_m: float,
            platform: PlatformSpec) -> tuple[NDArray[np.float64], str, str]:
    """Where the platform cannot go along a route on the floor ``floor`` (n, 3): the
    floor points (k, 3) (every ``ASSESS_STEP_M``) where it breaks a limit of its
    ``traversability``, the first of them in words ('' if none) and its kind ('slope',
    'roll', 'step', 'belly' or 'room').

    At each point the base stands on the floor under its contacts (a wheeled base's
    wheels: wheelbase x track; else the footprint's corners), found by rays cast down
    from the sensor's height; the least-squares plane through them gives its pitch
    (along the heading: ``max_slope_rad``) and roll (across: ``max_roll_rad``), as
    ``sensors.platform`` poses it. A step is a contact's rise or fall between two
    samples ``ASSESS_STEP_M`` apart over ``max_step_m``; the belly is grounded where the
    floor under the middle of the base (its centre and half-way to each axle) rises
    above the plane by more than ``ground_clearance_m``; the footprint has room where
    rays cast left and right along the base's y, from its ground clearance and from
    half-way to the sensor, run at least half its width before they hit."""
    tv = platform.traversability
    assert tv is not None
    q = _resample(floor, ASSESS_STEP_M)
    if len(q) < 3:
        return np.zeros((0, 3)), "", ""
    d = np.gradient(q[:, :2], axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]
    fwd = np.column_stack([d, np.zeros(len(q))])
    left = np.column_stack([-d[:, 1], d[:, 0], np.zeros(len(q))])
    if platform.motion == "wheeled":
        a, b = 0.5 * platform.wheelbase_m, 0.5 * platform.track_m
    else:
        a, b = 0.5 * tv.footprint_length_m, 0.5 * tv.footprint_width_m
    reach = height_m + _ASSESS_DROP_M
    # One cast for every ray down: the four contacts, then the belly's three points.
    sign = ((1, 1), (1, -1), (-1, 1), (-1, -1))
    xy = [q[:, :2] + i * a * fwd[:, :2] + j * b * left[:, :2] for i, j in sign]
    xy += [q[:, :2] + k * a * fwd[:, :2] for k in (-0.5, 0.0, 0.5)]
    org = np.column_stack([np.vstack(xy), np.tile(q[:, 2] + height_m, len(xy))])
    t = scene.cast(org, [0.0, 0.0, -1.0], t_max=reach).t
    zall = np.where(np.isfinite(t), org[:, 2] - t, np.tile(q[:, 2], len(xy)))
    zall = zall.reshape(len(xy), len(q)).T
    zc, zmid = zall[:, :4], zall[:, 4:]
    # The plane through the four contacts (a rectangle), as sensors.platform does.
    z0 = zc.mean(axis=1)
    g_fwd = ((zc[:, 0] + zc[:, 1]) - (zc[:, 2] + zc[:, 3])) / (4 * a)
    g_left = ((zc[:, 0] + zc[:, 2]) - (zc[:, 1] + zc[:, 3])) / (4 * b)
    checks: list[tuple[str, NDArray[np.bool_], NDArray[np.float64], str]] = []
    pitch, roll = np.arctan(np.abs(g_fwd)), np.arctan(np.abs(g_left))
    checks.append(("slope", pitch > tv.max_slope_rad, np.degrees(pitch),
                   f"a slope of {{:.3g}} deg (its limit {np.degrees(tv.max_slope_rad):g})"))
    checks.append(("roll", roll > tv.max_roll_rad, np.degrees(roll),
                   f"a cross slope (roll) of {{:.3g}} deg (its limit "
                   f"{np.degrees(tv.max_roll_rad):g})"))
    rise = np.abs(np.diff(zc, axis=0)).max(axis=1)
    step = np.maximum(np.append(rise, 0.0), np.insert(rise, 0, 0.0))
    checks.append(("step", step > tv.max_step_m, step,
                   f"a step of {{:.3g}} m (its limit {tv.max_step_m:g} m)"))
    belly = np.max([zmid[:, i] - (z0 + k * a * g_fwd)
                    for i, k in enumerate((-0.5, 0.0, 0.5))], axis=0)
    checks.append(("belly", belly > tv.ground_clearance_m, belly,
                   f"ground {{:.3g}} m up under its belly (its ground clearance "
                   f"{tv.ground_clearance_m:g} m)"))
    # The base's axes (sensors.platform._wheeled): z the plane's normal, y across.
    zb = np.column_stack([-(g_fwd[:, None] * fwd + g_left[:, None] * left)[:, :2],
                          np.ones(len(q))])
    zb /= np.linalg.norm(zb, axis=1)[:, None]
    xb = fwd - np.einsum("ij,ij->i", fwd, zb)[:, None] * zb
    xb /= np.linalg.norm(xb, axis=1)[:, None]
    yb = np.cross(zb, xb)
    base = np.column_stack([q[:, :2], z0])
    hs = (tv.ground_clearance_m, 0.5 * (tv.ground_clearance_m + height_m))
    org = np.vstack([base + h * zb for h in hs for _ in (1, -1)])
    dirs = np.vstack([sgn * yb for _ in hs for sgn in (1.0, -1.0)])
    room = scene.cast(org, dirs).t.reshape(4, len(q)).min(axis=0)
    half = 0.5 * tv.footprint_width_m
    checks.append(("room", room < half, 2 * room,
                   f"room for {{:.3g}} m of its {tv.footprint_width_m:g} m width "
                   "(twice the nearer wall)"))
    bad = np.zeros(len(q), dtype=np.bool_)
    first, text, kind = len(q), "", ""
    for name, mask, value, what in checks:
        bad |= mask
        hit = np.flatnonzero(mask)
        if len(hit) and hit[0] < first:
            first = int(hit[0])
            # the worst of the first run of trouble: the largest value, the least room
            gaps = np.flatnonzero(np.diff(hit) > 1)
            run = hit[:gaps[0] + 1] if len(gaps) else hit
            sgn = -1.0 if name == "room" else 1.0
            worst = run[np.argmax(sgn * value[run])]
            text = what.format(float(value[worst])) + \
                f" at {point_text(np.round(q[worst], 3) + 0.0)}"
            kind = name
    return q[bad], text, kind


def _far_end(g: sparse.csr_matrix, src: int, width: NDArray[np.float64],
             keep: NDArray[np.bool_]) -> int:
    """The end of the passage farthest (walking) from ``src`` among the drivable voxels
    ``keep``, in its middle: the largest walking distance + 2 x width. A step sideways
    off the ridge loses two units for at most one gained, so the farthest voxel, at a
    wall, gives way to the middle of its end; a ledge or alcove that runs back from the
    end is no longer the farthest for its few metres."""
    dist = csgraph.dijkstra(g, directed=False, indices=src)
    return int(np.argmax(np.where(np.isfinite(dist) & keep, dist + 2.0 * width, -np.inf)))


def _legs(g: sparse.csr_matrix, stops: list[int]) -> list[NDArray[np.int64]] | None:
    """The cheapest paths between consecutive ``stops``, as node indices (each leg from
    one stop to the next, both included); None where two are not connected."""
    dist, pred = csgraph.dijkstra(g, directed=False, indices=stops[:-1],
                                  return_predecessors=True)
    out = []
    for i in range(1, len(stops)):
        if not np.isfinite(dist[i - 1, stops[i]]):
            return None
        leg = [stops[i]]
        while leg[-1] != stops[i - 1]:
            leg.append(int(pred[i - 1, leg[-1]]))
        out.append(np.array(leg[::-1], dtype=np.int64))
    return out


def _recentre(scene: Scene, q: NDArray[np.float64], height_m: float, s: float,
              sigma: float, fixed: tuple[bool, bool]) -> NDArray[np.float64]:
    """The path q (n, 3) (floor voxels' height, a point every ``s``) moved sideways to
    the middle between the walls at the sensor's height: the voxel path is only centred
    to about a voxel. The middle is found by rays cast left and right from a reference,
    the path smoothed over ``RECENTRE_REF_M``, where the walls are nearly parallel to
    it; a middle over ``RECENTRE_MAX_VOX`` voxels off the path (a side passage, a
    corner) is replaced by its neighbours', and a median over ``RECENTRE_MEDIAN_M``
    removes the pull of a niche. The offsets are smoothed (``sigma`` samples) and, at a
    ``fixed`` (start, end) waypoint, blended back into the path over ``RECENTRE_REF_M``."""
    if len(q) < 3:
        return q
    r = _smooth(q, RECENTRE_REF_M / s)
    t = np.gradient(r[:, :2], axis=0)
    n = np.column_stack([-t[:, 1], t[:, 0], np.zeros(len(q))])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]
    org = r + [0.0, 0.0, height_m - FLOOR_OFFSET_VOX * s]
    with np.errstate(invalid="ignore"):                          # inf - inf: no walls
        mid = 0.5 * (scene.cast(org, n).t - scene.cast(org, -n).t)
    dev = np.einsum("ij,ij->i", q - r, n)                        # the path, off r
    ok = np.flatnonzero(np.abs(mid - dev) <= RECENTRE_MAX_VOX * s)
    if not len(ok):
        return q
    i = np.arange(len(q))
    mid = ndimage.median_filter(np.interp(i, ok, mid[ok]), int(RECENTRE_MEDIAN_M / s) | 1,
                                mode="nearest")
    mid = ndimage.gaussian_filter1d(mid, max(sigma, 1e-9), mode="nearest")
    ramp = np.minimum(1.0, i * s / RECENTRE_REF_M)
    w = (ramp if fixed[0] else 1.0) * (ramp[::-1] if fixed[1] else 1.0)
    return q + ((w * mid + (1 - w) * dev) - dev)[:, None] * n


def _resample(p: NDArray[np.float64], step: float) -> NDArray[np.float64]:
    """The polyline p (n, 3) at even arc-length steps of about ``step`` (ends kept)."""
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    p = np.vstack([p[:1], p[1:][seg > 0]])
    s = np.concatenate([[0.0], np.cumsum(seg[seg > 0])])
    if s[-1] == 0:
        return np.vstack([p[:1], p[:1]])
    t = np.linspace(0.0, s[-1], max(2, int(np.ceil(s[-1] / step - 1e-9)) + 1))
    return np.column_stack([np.interp(t, s, p[:, k]) for k in range(3)])


def _smooth(p: NDArray[np.float64], sigma: float) -> NDArray[np.float64]:
    """Gaussian moving average of an evenly spaced polyline (sigma in samples), padded by
    point reflection through each end so that the ends and straight runs stay put."""
    if sigma <= 0 or len(p) < 3:
        return p
    pad = min(len(p) - 1, int(4 * sigma) + 1)
    ext = np.vstack([2 * p[0] - p[pad:0:-1], p, 2 * p[-1] - p[-2:-pad - 2:-1]])
    out = ndimage.gaussian_filter1d(ext, sigma, axis=0, mode="nearest")[pad:pad + len(p)]
    out[0], out[-1] = p[0], p[-1]
    return out


def _floor_under(scene: Scene, q: NDArray[np.float64], height_m: float, s: float
                 ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The floor (n, 3) under each route point q (n, 3) (z: a floor voxel's centre), by
    a ray cast down from half the sensor height above it, and whether it was found
    (n,) bool; a miss (a hole in the floor) takes the floor height interpolated from the
    points that found it."""
    lift = 0.5 * height_m
    org = q + [0.0, 0.0, lift]
    t = scene.cast(org, [0.0, 0.0, -1.0], t_max=lift + (FLOOR_OFFSET_VOX + 4) * s).t
    hit = np.isfinite(t)
    i = np.flatnonzero(hit)
    z = np.interp(np.arange(len(q)), i, org[i, 2] - t[i]) if len(i) else q[:, 2]
    return np.column_stack([q[:, :2], z]), hit


def _waypoint_array(waypoints: ArrayLike) -> NDArray[np.float64]:
    """Waypoints as (k, 3) float64, z NaN where not given; k >= 2."""
    try:
        w = np.asarray(waypoints, dtype=np.float64)
    except (TypeError, ValueError):
        w = np.empty((0, 0))
    if w.ndim != 2 or w.shape[1] not in (2, 3) or len(w) < 2 or \
            not np.isfinite(w[:, :2]).all():
        raise RouteError(f"Expected at least 2 waypoints of finite x, y[, z] (shape "
                              f"(k, 2) or (k, 3)), got shape {np.shape(waypoints)}.")
    return w if w.shape[1] == 3 else np.column_stack([w, np.full(len(w), np.nan)])


def read_waypoints(path: str | os.PathLike[str]) -> NDArray[np.float64]:
    """Waypoints (k, 3) float64 from a CSV file of ``x,y`` or ``x,y,z`` rows ('#'
    comments; z NaN where not given), with an optional header naming x, y[, z] (a route
    CSV's other ``ROUTE_CSV_COLUMNS`` are read past). ``RouteError`` for a missing
    file, an unknown header name, rows that are not 2 or 3 numbers, or fewer than 2."""
    path = Path(path)
    if not path.is_file():
        raise RouteError(f"Expected a waypoints file, got '{path}' which does not "
                              "exist.")
    rows = [ln.split("#")[0].strip() for ln in path.read_text().splitlines()]
    rows = [r for r in rows if r]
    names = ["x", "y", "z"]
    try:
        np.array(rows[0].split(",") if rows else [], dtype=np.float64)
    except ValueError:                                           # a header
        names = [x.strip().lower() for x in rows.pop(0).split(",")]
        if not {"x", "y"} <= set(names) <= set(ROUTE_CSV_COLUMNS):
            raise RouteError(f"Expected a waypoints header naming x, y[, z], got "
                                  f"'{','.join(names)}' in '{path}'.") from None
    try:
        w = np.array([r.split(",") for r in rows], dtype=np.float64).reshape(len(rows), -1)
    except ValueError:
        w = np.empty((len(rows), 0))
    if rows and w.shape[1] not in ((2, 3) if len(names) == 3 else (len(names),)):
        raise RouteError(f"Expected rows of 2 or 3 numbers x,y[,z] (as many as the "
                              f"header names) in '{path}', got unreadable rows or rows of "
                              "different lengths.")
    cols = [names.index(c) for c in ("x", "y", "z") if c in names[:w.shape[1]]]
    try:
        return _waypoint_array(w[:, cols])
    except RouteError as exc:
        raise RouteError(f"{exc} (in '{path}')") from None
