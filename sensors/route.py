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
   mesh (closest point on a triangle, Ericson 2005, "Real-Time Collision Detection"
   5.1.5) is measured; where one is below ``clearance_m`` the smoothing is halved, then
   dropped.

>>> from raytrace.shapes import tunnel_tube
>>> route = find_route(tunnel_tube(1500, length_m=10.0), voxel_m=0.1)
>>> round(route.length_m), round(route.min_clearance_m, 2), route.points.shape[1]
(10, 0.5, 3)
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from raytrace import Scene
from raytrace.fileio import atomic_writer

from ._checks import as_number
from .errors import RouteError
from .freespace import (FLOOR_OFFSET_VOX, MAX_VOXELS, MIN_VOXEL_M, FloorGraph, FreeSpace,
                        free_space, point_text)
from .trajectory import Trajectory

__all__ = ["FreeSpace", "MAX_VOXELS", "MIN_VOXEL_M", "ROUTE_CSV_COLUMNS", "Route",
           "find_route", "free_space", "read_waypoints"]

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
               clearance_power: float = 2.0, space: FreeSpace | None = None) -> Route:
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
        Smallest distance kept from the mesh at every point (m).
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

    Returns
    -------
    Route

    Raises
    ------
    RouteError
        No enclosed free space, ``start`` or a waypoint outside it, waypoints not
        connected, or a passage too narrow (or low) for ``clearance_m`` at ``height_m``.
    """
    t0 = time.perf_counter()
    height_m = as_number(height_m, "height_m", RouteError, unit="m", lo=0, lo_open=True)
    clearance_m = as_number(clearance_m, "clearance_m", RouteError, unit="m", lo=0)
    spacing_m = as_number(spacing_m, "spacing_m", RouteError, unit="m", lo=0,
                          lo_open=True)
    smoothing_m = as_number(smoothing_m, "smoothing_m", RouteError, unit="m", lo=0)
    power = as_number(clearance_power, "clearance_power", RouteError, unit="1", lo=0)
    if height_m <= clearance_m:
        raise RouteError(f"Expected height_m above clearance_m, got height_m="
                              f"{height_m:g} m and clearance_m={clearance_m:g} m.")
    wp = None if waypoints is None else _waypoint_array(waypoints)
    if space is None:
        space = free_space(mesh, voxel_m=voxel_m, max_voxels=max_voxels, start=start)
    s = space.voxel_m
    fl = FloorGraph(space, height_m, clearance_m)
    g_len, width = fl.g_len, fl.width[fl.nodes]
    n_parts, part = csgraph.connected_components(g_len, directed=False)
    if wp is None:
        sizes = np.bincount(part)
        big = int(np.argmax(sizes))
        if n_parts > 1 and np.sort(sizes)[-2] >= SPLIT_WARN_SHARE * len(part):
            share = 100 * sizes[big] / len(part)
            warnings.warn(f"The drivable floor is cut where the passage is narrower than "
                          f"2 x {clearance_m:g} m (or lower than {height_m + clearance_m:g} "
                          f"m); the route runs in the largest part, {share:.0f} % of it; "
                          "pass waypoints to choose another.", UserWarning, stacklevel=2)
        src = int(np.argmax(np.where(part == big, width, -np.inf)))
        a = _far_end(fl.g_sweep, src, width, part == big)
        stops = [a, _far_end(fl.g_sweep, a, width, part == big)]
    else:
        stops = [fl.snap(p, i + 1) for i, p in enumerate(wp)]
        keep = [0] + [i for i in range(1, len(stops)) if stops[i] != stops[i - 1]]
        if len(keep) < 2:
            raise RouteError(f"Expected waypoints apart from one another, got "
                                  f"{len(wp)} on the same voxel of {s:.3g} m.")
        for i in range(1, len(stops)):
            if part[stops[i]] != part[stops[i - 1]]:
                raise RouteError(
                    f"Expected waypoint {i + 1} {point_text(wp[i])} to be reachable from "
                    f"waypoint {i} {point_text(wp[i - 1])}, got no path between them that keeps "
                    f"{clearance_m:g} m from the mesh at {height_m:g} m above the floor; "
                    "the passage between them is closed, too narrow or too low.")
        stops, wp = [stops[i] for i in keep], wp[keep]
    legs = _legs(fl.cost_graph(power), stops)
    ends = fl.centres(stops)
    if wp is not None:      # a waypoint over drivable floor is passed through exactly
        over = np.linalg.norm(ends[:, :2] - wp[:, :2], axis=1) <= s
        ends[over, :2] = wp[over, :2]
    ok = False
    for sigma in (smoothing_m, smoothing_m / 2, smoothing_m / 4, 0.0):
        if 0 < sigma < s:
            continue
        parts, at = [], [0]
        for k, leg in enumerate(legs):
            c = fl.centres(leg)
            c[0, :2], c[-1, :2] = ends[k, :2], ends[k + 1, :2]
            q = _resample(c, s)
            if sigma > 0:
                q = _recentre(space.scene, _smooth(q, sigma / s), height_m, s, sigma / s,
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
                                  f"{int((~hit).sum())} of its {len(hit)} points.")
        pts = floor + [0.0, 0.0, height_m]
        clr = space.distance(pts)
        ok = bool(clr.min() >= clearance_m)
        if ok:
            break
    if not ok:
        i = int(np.argmin(clr))
        raise RouteError(f"Expected a passage at least 2 x {clearance_m:g} m wide at "
                              f"{height_m:g} m above its floor, got {clr[i]:.3g} m of "
                              f"clearance at {point_text(pts[i])}; lower clearance_m or "
                              "voxel_m.")
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return Route(pts, floor, clr, dist, pts[at], s, time.perf_counter() - t0)


def _far_end(g: sparse.csr_matrix, src: int, width: NDArray[np.float64],
             keep: NDArray[np.bool_]) -> int:
    """The end of the passage farthest (walking) from ``src`` among the drivable voxels
    ``keep``, in its middle: the largest walking distance + 2 x width. A step sideways
    off the ridge loses two units for at most one gained, so the farthest voxel, at a
    wall, gives way to the middle of its end; a ledge or alcove that runs back from the
    end is no longer the farthest for its few metres."""
    dist = csgraph.dijkstra(g, directed=False, indices=src)
    return int(np.argmax(np.where(np.isfinite(dist) & keep, dist + 2.0 * width, -np.inf)))


def _legs(g: sparse.csr_matrix, stops: list[int]) -> list[NDArray[np.int64]]:
    """The cheapest paths between consecutive ``stops``, as node indices (each leg from
    one stop to the next, both included)."""
    _, pred = csgraph.dijkstra(g, directed=False, indices=stops[:-1],
                               return_predecessors=True)
    out = []
    for i in range(1, len(stops)):
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
