"""``Scene``: a triangle mesh with a BVH, answering closest-hit and any-hit ray queries.

Precision: the mesh is stored relative to a local origin (the centre of its bounding
box) in float64, and every ray origin is shifted into that frame in float64 before
casting. A tunnel in UTM coordinates (eastings ~4.5e5, northings ~5.4e6) therefore hits
exactly like the same tunnel near (0, 0, 0): the intersection arithmetic only ever sees
numbers of the size of the tunnel itself.

>>> from raytrace import Scene
>>> scene = Scene([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
>>> scene
Scene(1 triangles, BVH 0.0 MB, bounds (0, 0, 0) .. (1, 1, 0) m)
>>> scene.cast([0.25, 0.25, 1.0], [0, 0, -1]).t
array([1.])
>>> bool(scene.occluded([0.25, 0.25, 1.0], [0, 0, -1], t_max=0.5)[0])
False
"""

from __future__ import annotations

import json
import operator
import os
import time
import warnings
from pathlib import Path
from typing import Any, Literal

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import config
from .aligned import as_aligned, empty_aligned
from .checks import as_points, first_rows, prepare_cast, prepare_rays, validate_mesh
from .closest import ClosestPoints
from ._kernels.build import build_bvh, slot_triangles, triangle_setup, vertex_bounds
from ._kernels.closest import closest_points
from ._kernels.collapse import pack_records, to_wide_layout
from ._kernels.cubemap import (closest_hit_view, count_part, entry_offsets, fill_entries,
                               fill_part, footprints, footprints_counted)
from ._kernels.nearmap import gather_near, ray_cone
from ._kernels.order import counting_sort, is_coherent, morton_keys, origin_runs
from ._kernels.rays import unit_directions
from ._kernels.simd import LANES
from ._kernels.traverse import CHILD, RECORD, any_hit, closest_hit
from .errors import ConfigError, MeshError, RayError, SceneFileError
from .fileio import atomic_writer, npz_memmap, savez_aligned
from .hits import Hits

__all__ = ["FILE_FORMAT", "Scene"]

_NO_ORDER = np.empty(0, dtype=np.int64)
#: Largest half-angle of a ray cone mapped on one turned face (a near map): 44 deg, one
#: degree inside the face's 45, so that rounding never puts a ray on another face (if
#: it did, that ray would walk the BVH: still exact).
_ONE_FACE_RAD = np.deg2rad(44.0)


def _turn_to_x(ax: float, ay: float, az: float) -> NDArray[np.float64]:
    """(3, 3) float64 rotation whose first row is the unit vector a: it turns a onto +x."""
    a = np.array([ax, ay, az], dtype=np.float64)
    helper = np.zeros(3)
    helper[int(np.argmin(np.abs(a)))] = 1.0
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    return np.stack([a, e1, e2])

#: Version of the ``Scene.save`` file layout; ``Scene.load`` refuses other versions.
#: 5: the input vertices and faces are stored too (``Scene.vertices``, ``Scene.faces``).
#: 6: 8-wide node records (256 bytes) instead of 4-wide ones.
FILE_FORMAT = 6

Method = Literal["auto", "bvh", "cubemap", "near"]


def _read_only(a: NDArray[Any]) -> NDArray[Any]:
    """A read-only view of ``a`` (``a`` itself stays as writeable as it was)."""
    view = a.view()
    view.flags.writeable = False
    return view


def _build_constants(sah_bins: int, max_leaf_size: int, c_trav: float,
                     c_isect: float) -> dict[str, Any]:
    """The BVH build constants, checked; ``ConfigError`` when out of range."""
    try:
        build = dict(sah_bins=operator.index(sah_bins),
                     max_leaf_size=operator.index(max_leaf_size),
                     c_trav=float(c_trav), c_isect=float(c_isect))
        ok = (2 <= build["sah_bins"] <= 256 and 1 <= build["max_leaf_size"] <= 255
              and build["c_trav"] > 0 and build["c_isect"] > 0
              and np.isfinite([build["c_trav"], build["c_isect"]]).all())
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ConfigError(
            f"Expected integers 2 <= sah_bins <= 256, 1 <= max_leaf_size <= 255 and "
            f"finite positive costs, got sah_bins={sah_bins!r}, max_leaf_size="
            f"{max_leaf_size!r}, c_trav={c_trav!r}, c_isect={c_isect!r}; the defaults "
            "are in raytrace.config.")
    return build


class Scene:
    """A triangle mesh with a binned-SAH BVH for exact ray casting.

    Parameters
    ----------
    vertices : (n_v, 3) array_like of float
        Vertex coordinates in metres (any frame; large offsets such as UTM are fine). A
        structured array with fields ``x``, ``y``, ``z`` is read as (n_v, 3).
    faces : (n_f, 3) array_like of int
        Vertex indices per triangle (rows of ``vertices``).
    copy_data : bool, default False
        Copy ``vertices`` and ``faces`` even when they are already float64 / int64. By
        default the scene keeps (read-only views of) the arrays it was given, as
        ``scipy.spatial.cKDTree`` does: changing them afterwards makes ``Scene.vertices``
        disagree with what the BVH was built from.
    sah_bins, max_leaf_size, c_trav, c_isect : int, int, float, float, optional
        BVH build constants (Wald 2007 binned SAH); defaults from ``raytrace.config``.

    Attributes
    ----------
    origin_offset : (3,) float64
        Local origin of the stored triangles (read-only): the centre of the mesh's box,
        rounded to whole metres.

    Raises
    ------
    MeshError
        Empty mesh, wrong shapes, non-finite vertices, non-integer or out-of-range face
        indices, or a mesh whose triangles are all degenerate.
    ConfigError
        A build constant out of range.

    Notes
    -----
    Zero-area triangles are dropped with a ``UserWarning`` that counts them; the other
    triangles keep their input indices in ``Hits.triangle``.
    """

    def __init__(self, vertices: ArrayLike, faces: ArrayLike, *, copy_data: bool = False,
                 sah_bins: int = config.SAH_BINS, max_leaf_size: int = config.MAX_LEAF_SIZE,
                 c_trav: float = config.SAH_C_TRAV, c_isect: float = config.SAH_C_ISECT
                 ) -> None:
        t_start = time.perf_counter()
        build = _build_constants(sah_bins, max_leaf_size, c_trav, c_isect)
        v, f = validate_mesh(vertices, faces)
        # DECISION: keep the given arrays, not copies (cKDTree's copy_data=False): a copy
        # costs 36 B a triangle, +40 % of the scene's own memory, for arrays the caller
        # almost always keeps anyway (a TunnelMesh, a file just read).
        if copy_data:
            v, f = v.copy(), f.copy()
        self._vertices = _read_only(v)
        self._faces = _read_only(f)
        lo, hi = vertex_bounds(v)
        # Local origin: the box centre rounded to a whole metre, so that it is a short,
        # exactly representable number a user can read back and reason about.
        self.origin_offset = _read_only(np.round(0.5 * (lo + hi)))
        m = f.shape[0]
        prim = np.empty((m, 9), dtype=np.float32)
        good = np.empty(m, dtype=np.bool_)
        triangle_setup(v, self.origin_offset, f, config.AREA_REL, prim, good)
        n_bad = m - int(good.sum())
        if n_bad == m:
            raise MeshError(
                f"Expected a mesh with at least one triangle of non-zero area, got "
                f"{n_bad} degenerate triangles; check the face indices and units."
            )
        if m >= 2 ** 31:
            raise MeshError("Expected fewer than 2**31 triangles, got more; split the mesh.")
        # int32 row indices: 4 bytes less to move per row and partition, and already the
        # dtype of the scene's slot -> triangle map.
        keep = np.arange(m, dtype=np.int32)
        if n_bad:
            warnings.warn(
                f"Dropped {n_bad} zero-area triangle(s) of {m} "
                f"(first: {first_rows(np.flatnonzero(~good))}); they cannot be hit.",
                UserWarning, stacklevel=2,
            )
            keep = np.flatnonzero(good).astype(np.int32)
            prim = prim[keep]
        stop = max(config.BUILD_TASK_MIN, len(keep) // config.BUILD_TASKS)
        with numba.parallel_chunksize(1):
            node_box, node_meta = build_bvh(
                prim, keep, build["sah_bins"], bool(config.SAH_ALL_AXES), build["c_trav"],
                build["c_isect"], build["max_leaf_size"], int(config.MAX_LEAF_SIZE_FORCED),
                int(stop))
        del prim
        wide_box, wide_link, (n_nodes, n_leaves, max_depth, in_leaves, cost, depth_w) = \
            to_wide_layout(node_box, node_meta, build["c_trav"], build["c_isect"], LANES)
        del node_box, node_meta
        # DECISION: per slot v0, e1, e2 in float64 (72 B a triangle, a leaf is one
        # contiguous run) rather than shared vertices + indices (~24 B): with shared
        # vertices every triangle of a leaf gathers three vertices from different cache
        # lines, which made incoherent rays ~1.5x slower on the 1M-triangle benchmark
        # tunnel; the scene stays within 1.5x of Open3D's memory (benchmarks/RESULTS.md).
        self._tris = np.empty((len(keep), 9))
        slot_triangles(v, self.origin_offset, f, keep, self._tris)
        self._ids = keep
        self._nodes = _pack_nodes(wide_box, wide_link, hi - lo)
        self._max_depth = int(max_depth)
        # A visit pushes at most 7 records: 7 per 8-wide level, plus slack.
        self._stack_size = (LANES - 1) * int(depth_w) + LANES
        self._n_input_faces = int(m)
        self._build = build
        self._view_cache: tuple[bytes, Any] | None = None
        self._tree = dict(nodes=int(n_nodes), leaves=int(n_leaves),
                          mean_leaf_size=float(in_leaves) / n_leaves, sah_cost=float(cost))
        self._stats = self._compute_stats(time.perf_counter() - t_start)
        _release_freed_memory()

    # ------------------------------------------------------------------ construction
    # ------------------------------------------------------------------ queries
    def cast(self, origins: ArrayLike, directions: ArrayLike, *, t_min: ArrayLike = 0.0,
             t_max: ArrayLike = np.inf, method: Method = "auto", unit: bool = False
             ) -> Hits:
        """Closest hit of each ray within [t_min, t_max].

        Parameters
        ----------
        origins : (n, 3) or (3,) array_like of float
            Ray origins in world coordinates, metres; a single row is shared by all rays.
        directions : (n, 3) or (3,) array_like of float
            Ray directions; need not be unit length, must not be zero. A single row is
            shared by all origins.
        t_min, t_max : float or (n,) array_like of float, keyword-only
            Accepted hit interval along the normalised direction, metres, both ends
            included (as in Embree): 0 <= t_min <= t_max, t_min finite, t_max finite or
            ``inf``.
        method : {"auto", "bvh", "cubemap", "near"}, keyword-only
            "cubemap" builds (and keeps, for the next call from the same origin) a cube
            map of candidate triangles around a single shared origin — a TLS station,
            given as a (3,) row or as (n, 3) rows that are all equal — and tests each ray
            against its cell's list only. "auto" does so for every run of equal
            consecutive origin rows (a single origin included) with at least
            ``config.CUBEMAP_MIN_RAYS_PER_TRI`` rays per triangle, and so does
            "cubemap" when the origins are not all equal. "near" maps only the
            triangles nearest to the origin within the cone of the rays' directions
            (about ``config.NEARMAP_TRIS_PER_RAY`` per ray; not kept between calls);
            rays whose hit may lie beyond them walk the BVH. "auto" does so for runs
            shorter than a whole map repays but at least ``config.NEARMAP_MIN_RUN``
            long (a camera frame). The answer is identical either way; only the speed
            differs.
        unit : bool, keyword-only
            True: the directions are unit vectors already (``abs(|d|^2 - 1) <=
            1e-12``, checked) and are cast exactly as given, without the normalised
            copy the default makes (24 bytes a ray). False: they are normalised here
            (x / sqrt(x x + y y + z z)); normalising them so yourself and passing
            True casts the same rays, bit for bit.

        Returns
        -------
        Hits
            Per ray: ``t`` (n,) float64, ``triangle`` (n,) int64, ``u``, ``v``, and the
            derived ``hit``, ``points``, ``normals``, ``incidence_rad``.

        Raises
        ------
        RayError
            Shapes that do not broadcast to n rays, NaN/inf origins or directions, a zero
            direction (with ``unit``: one not of unit length), or limits that break
            0 <= t_min <= t_max.
        """
        if not isinstance(unit, (bool, np.bool_)):
            raise RayError(f"Expected `unit` to be True or False, got {unit!r}; pass "
                           "unit=True only for directions already of unit length.")
        if not isinstance(method, str) or method not in ("auto", "bvh", "cubemap", "near"):
            raise RayError(f"Expected `method` to be 'auto', 'bvh', 'cubemap' or 'near', "
                           f"got {method!r}; leave it at 'auto' unless timing the paths.")
        org, local, dirs, unit, tmin, tmax = prepare_cast(origins, directions, t_min,
                                                          t_max, self.origin_offset,
                                                          bool(unit))
        n = dirs.shape[0]
        # t, slot, input triangle, u, v
        out = (np.empty(n), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64),
               np.empty(n), np.empty(n))
        # Rays sharing one origin go to that origin's cube map. DECISION: shared origins
        # are also found in an (n, 3) array (runs of bit-identical consecutive rows, one
        # O(n) pass): a station's rays passed with one row per ray were 3x slower than
        # the same rays with a (3,) origin (issue 16).
        # DECISION: per triangle or per cell of the whole map, whichever is more: on a
        # small artist-made mesh (3,776 large triangles, a 64-cell floor per face side)
        # every 1920-ray row of a rolling-shutter frame passed the per-triangle rule and
        # built a whole map of its own (its own origin): 13 s a frame instead of 3.
        min_run = max(config.CUBEMAP_MIN_RUN,
                      int(np.ceil(config.CUBEMAP_MIN_RAYS_PER_TRI *
                                  max(self.n_triangles, 6 * self._map_side() ** 2))))
        # Shortest run worth a map: a whole map ("cubemap") or a near map.
        shortest = min_run if method == "cubemap" else min(min_run, config.NEARMAP_MIN_RUN)
        runs = np.empty((0, 2), dtype=np.int64)
        if n and method != "bvh":
            if local.shape[0] == 1:  # one origin, or n equal rows (prepare_cast)
                runs = np.array([[0, n]], dtype=np.int64)
            else:
                # "cubemap"/"near": at least a run that is the whole batch (one origin);
                # "auto" (and the others) also every run long enough to repay its map.
                runs = origin_runs(local.view(np.int64), min(shortest, n))
            if method == "auto" or (runs.shape[0] and runs[0, 1] - runs[0, 0] < n):
                runs = runs[runs[:, 1] - runs[:, 0] >= shortest]
        rest = None
        if runs.shape[0] and not unit:  # the maps' kernels take unit directions
            dirs = _unit(dirs)
            unit = True
        for a, b in runs:
            # A run too short for a whole map takes a near map, unless the whole map of
            # its origin is already kept (the last, short chunk of a station).
            if method == "near" or (method == "auto" and b - a < min_run
                                    and not self._has_view(local[a:a + 1])):
                view = self._near_view(local[a:a + 1], dirs[a:b])
            else:
                view = self._view(local[a:a + 1])
            if view is None:  # too many cube-map entries: the BVH does these rays
                continue
            part = slice(a, b)
            self._cast_view(view, local[a:a + 1], dirs[part], _part(tmin, part),
                            _part(tmax, part), [o[part] for o in out])
            if rest is None:
                rest = np.ones(n, dtype=np.bool_)
            rest[part] = False
        if rest is None:
            if n:
                self._cast_bvh(local, dirs, unit, tmin, tmax, out)
        elif rest.any():
            idx = np.flatnonzero(rest)
            sub = (np.empty(idx.size), np.empty(idx.size, dtype=np.int64),
                   np.empty(idx.size, dtype=np.int64), np.empty(idx.size),
                   np.empty(idx.size))
            self._cast_bvh(local[idx] if local.shape[0] > 1 else local, dirs[idx], unit,
                           _part(tmin, idx), _part(tmax, idx), sub)
            for o, so in zip(out, sub):
                o[idx] = so
        out_t, out_slot, tri, out_u, out_v = out
        return Hits(out_t, tri, out_u, out_v, origins=org, directions=dirs,
                    slots=out_slot, records=self._tris, unit=unit)

    def _cast_view(self, view: Any, local1: NDArray[np.float64], dirs: NDArray[np.float64],
                   tmin: NDArray[np.float64], tmax: NDArray[np.float64],
                   out: Any) -> None:
        """Closest hits of rays from the one origin ``local1`` (1, 3) through its cube
        map or near map ``view``, written into ``out`` (t, slot, triangle, u, v)."""
        start, slots, counts, g, n_faces, rot, scale, radius = view
        # DECISION: an infinite radius (a whole map, or a near map that holds every
        # triangle of its cone) and a scale of 1 are passed as None: the kernel is then
        # compiled without the radius test, the warm start of its BVH walks and the
        # divisions by the scale, as whole maps were before near maps existed
        # (cubemap._view_block). Same cells, same answers.
        with numba.parallel_chunksize(config.PRANGE_CHUNK):
            closest_hit_view(start, slots, counts, g, n_faces, rot,
                             None if scale == 1.0 else scale, config.CUBEMAP_HOT,
                             radius if radius < np.inf else None, self._nodes,
                             self._nodes.view(np.int32), self._tris, self._ids, local1,
                             dirs, tmin, tmax, self._stack_size, config.RAY_BLOCK, *out)

    def _cast_bvh(self, local: NDArray[np.float64], dirs: NDArray[np.float64],
                  unit: bool, tmin: NDArray[np.float64], tmax: NDArray[np.float64],
                  out: Any) -> None:
        """Closest hits through the BVH, written into ``out`` (t, slot, triangle, u,
        v); ``unit`` False: ``dirs`` are normalised per ray by the kernel."""
        order = self._ray_order(local, config.CAST_ORDER_BITS)
        # One prange iteration a worker; the workers share out the blocks themselves.
        with numba.parallel_chunksize(1):
            closest_hit(self._nodes, self._nodes.view(np.int32), self._tris, self._ids,
                        local, dirs, tmin, tmax, self._stack_size, order, *out, bool(unit),
                        numba.get_num_threads(), np.zeros(1, dtype=np.int64))

    def occluded(self, origins: ArrayLike, directions: ArrayLike, *,
                 t_min: ArrayLike = 0.0, t_max: ArrayLike = np.inf) -> NDArray[np.bool_]:
        """Whether each ray hits anything within [t_min, t_max] (any hit, early exit).

        ``occluded(o, d, t_min=a, t_max=b)`` equals ``cast(o, d, t_min=a, t_max=b).hit``,
        faster: a shadow or line-of-sight test.

        Parameters
        ----------
        origins, directions : (n, 3) or (3,) array_like of float
            As in ``cast``.
        t_min, t_max : float or (n,) array_like of float, keyword-only
            As in ``cast``: 0 <= t_min <= t_max, metres along the normalised direction.

        Returns
        -------
        (n,) bool
            True where some triangle lies within the interval.

        Raises
        ------
        RayError
            As in ``cast``.
        """
        org, dirs, tmin, tmax = prepare_rays(origins, directions, t_min, t_max)
        out = np.zeros(dirs.shape[0], dtype=np.bool_)
        if dirs.shape[0]:
            local = org - self.origin_offset
            with numba.parallel_chunksize(config.PRANGE_CHUNK):
                any_hit(self._nodes, self._nodes.view(np.int32), self._tris, local, dirs,
                        tmin, tmax, self._stack_size, self._ray_order(local), out)
        return out

    def closest(self, points: ArrayLike) -> ClosestPoints:
        """Nearest triangle of each point, and the closest point on it (exact).

        Branch and bound over the scene's BVH; the point–triangle test is Ericson 2005,
        *Real-Time Collision Detection*, 5.1.5, in float64 in the scene's local frame.
        The answer is the minimum of (distance, face row) over all triangles: bit for
        bit what trying every triangle gives, whatever the thread count or batch split.

        Parameters
        ----------
        points : (n, 3) or (3,) array_like of float
            Query points in world coordinates, metres (or a structured array with
            fields x, y, z). A single (3,) point gives (1,)-shaped results.

        Returns
        -------
        ClosestPoints
            Per point: ``distance`` (n,) float64, ``triangle`` (n,) int64 (ties to the
            lowest face row), ``points`` (n, 3) float64, ``offset`` (n, 3) float64
            (point minus closest point), ``side`` (n,) float64 (+1/-1 against the face
            normal (b - a) x (c - a)) and ``signed_distance``.

        Raises
        ------
        RayError
            Points that are not (n, 3) or (3,) numbers, or hold NaN or inf.

        Notes
        -----
        Zero-area faces are not in the BVH (see ``Scene``) and are never the answer.
        """
        pts, _ = as_points(points, "points", RayError)
        n = pts.shape[0]
        dist = np.empty(n)
        tri = np.empty(n, dtype=np.int64)
        off = np.empty((n, 3))
        side = np.empty(n)
        if n:
            local = pts - self.origin_offset
            with numba.parallel_chunksize(config.PRANGE_CHUNK):
                closest_points(self._nodes, self._nodes.view(np.int32), self._tris,
                               self._ids, local, self._stack_size, self._ray_order(local),
                               dist, tri, off, side)
        return ClosestPoints(dist, tri, pts - off, off, side)

    def _ray_order(self, local_origins: NDArray[np.float64], bits: int | None = None
                   ) -> NDArray[np.int64]:
        """Processing order for a batch: Morton order of the origins on a grid of 2^bits
        cells an axis (default ``config.ORDER_BITS``) for large batches of scattered
        origins, else empty (input order: small batches, and batches whose consecutive
        origins are already within a cell of each other). Speed only; see order.py."""
        n = local_origins.shape[0]
        if n < config.ORDER_MIN_RAYS:
            return _NO_ORDER
        bits = config.ORDER_BITS if bits is None else int(bits)
        box = self.bounds - self.origin_offset
        step = float(np.max(box[1] - box[0])) / (1 << bits)
        if is_coherent(local_origins, step, n // config.ORDER_RUN):
            return _NO_ORDER
        keys = np.empty(n, dtype=np.int64)
        morton_keys(local_origins, box[0], box[1], bits, keys)
        return counting_sort(keys, 1 << (3 * bits))

    def _has_view(self, local_origin: NDArray[np.float64]) -> bool:
        """Whether the cube map kept from the last call is that of ``local_origin``."""
        cached = self._view_cache
        return cached is not None and cached[0] == local_origin.tobytes() \
            and cached[1] is not None

    def _view(self, local_origin: NDArray[np.float64]) -> Any:
        """Cube map around one origin (local frame), cached for the last origin used.
        Returns the view (``_map``), or None when it would be too large."""
        key = local_origin.tobytes()
        cached = self._view_cache
        if cached is not None and cached[0] == key:  # same origin: reuse
            return cached[1]
        view = self._map(local_origin, None, self._map_side())
        self._view_cache = (key, view)
        return view

    def _map_side(self) -> int:
        """Cells along a side of each face of the whole mesh's cube map: about
        ``config.CUBEMAP_CELLS_PER_TRI`` cells a triangle, clamped."""
        g = int(np.sqrt(config.CUBEMAP_CELLS_PER_TRI * self.n_triangles / 6.0))
        return min(config.CUBEMAP_MAX_G, max(config.CUBEMAP_MIN_G, g))

    def _map(self, local_origin: NDArray[np.float64], sel: NDArray[np.int32] | None,
             g: int, radius: float = np.inf, rot: NDArray[np.float64] | None = None,
             scale: float = 1.0, n_faces: int = 6) -> Any:
        """Cube map of the triangles ``sel`` (None: all) around one origin (local
        frame), in the frame turned by ``rot`` (None: not turned), each face's grid
        spanning [-scale, scale]^2, the first ``n_faces`` faces kept. Returns (start,
        slots, counts, g, n_faces, rot, scale, radius), or None when it would be too
        large."""
        # int16 cell ranges: g <= CUBEMAP_MAX_G (2048) < 2^15 (cubemap.footprints).
        fp = np.empty((self.n_triangles if sel is None else sel.shape[0], 6, 4),
                      dtype=np.int16 if g < 2**15 else np.int32)
        o = local_origin[0]
        ox, oy, oz = float(o[0]), float(o[1]), float(o[2])
        # The footprints in one part a thread, each part counted (as its footprints are
        # written) and listed by its own task (the lists do not depend on the split).
        # DECISION: the lists serially below config.CUBEMAP_PARALLEL_MIN_TRIS
        # footprints: on a loaded 2-core machine each parallel region can wait
        # milliseconds for its second thread.
        m = fp.shape[0]
        n_parts = numba.get_num_threads() if m >= config.CUBEMAP_PARALLEL_MIN_TRIS else 1
        parts = np.zeros((n_parts, n_faces * g * g), dtype=np.int32)
        if n_parts == 1:
            footprints(self._tris, sel, ox, oy, oz, rot, float(scale), g, fp)
            count_part(fp, g, n_faces, 0, m, parts[0])
        else:
            footprints_counted(self._tris, sel, ox, oy, oz, rot, float(scale), g, fp,
                               n_faces, parts)
        counts, start, kept = entry_offsets(parts, config.CUBEMAP_HOT)
        if kept > config.CUBEMAP_MAX_ENTRIES:
            return None
        slots = np.empty(kept, dtype=np.int32)
        if n_parts == 1:
            fill_part(fp, sel, g, n_faces, 0, m, counts, config.CUBEMAP_HOT, parts[0],
                      slots)
        else:
            fill_entries(fp, sel, g, n_faces, parts, counts, config.CUBEMAP_HOT, slots)
        return (start, slots, counts, g, n_faces, rot, float(scale), float(radius))

    def _near_view(self, local_origin: NDArray[np.float64],
                   dirs: NDArray[np.float64]) -> Any:
        """Near map around one origin (local frame) for the rays ``dirs`` (unit vectors):
        the cube map of the triangles nearest to it inside the cone of ``dirs``
        (``nearmap.py``). Returns the view of ``_map`` (its radius last), or None when
        it would be too large."""
        m = self.n_triangles
        ax, ay, az, cos_cone = ray_cone(dirs)
        k_max = max(config.NEARMAP_MIN_TRIS,
                    int(config.NEARMAP_TRIS_PER_RAY * dirs.shape[0]))
        sel = np.empty(m, dtype=np.int32)
        o = local_origin[0]
        count, radius = gather_near(self._nodes, self._nodes.view(np.int32), float(o[0]),
                                    float(o[1]), float(o[2]), ax, ay, az, cos_cone,
                                    k_max, sel)
        half_angle = float(np.arccos(np.clip(cos_cone, -1.0, 1.0)))
        cells_in = config.NEARMAP_CELLS_PER_TRI * max(count, 1)
        cells_max = config.NEARMAP_MAX_CELLS_PER_TRI * max(count, 1)
        if half_angle <= _ONE_FACE_RAD:
            # DECISION: a narrow cone (a camera) is turned onto +x and mapped on that
            # face alone, its grid spanning just the cone (|tan| <= tan(half-angle)):
            # a cube map's six faces would need ~40 times the cells for the same cell
            # size inside a 69 x 52 deg field of view.
            rot = _turn_to_x(ax, ay, az)
            scale = max(np.tan(half_angle) * (1.0 + 1e-6), 1e-3)
            # The cone's disc covers pi / 4 of the square grid.
            cells = min(cells_in * 4.0 / np.pi, cells_max)
            g = min(config.CUBEMAP_MAX_G, max(config.CUBEMAP_MIN_G, int(np.sqrt(cells))))
            return self._map(local_origin, sel[:count], g, radius, rot, scale, 1)
        # A wide cone: all six faces, about NEARMAP_CELLS_PER_TRI cells a collected
        # triangle inside the cone (solid angle 2 pi (1 - cos), of the sphere's 4 pi).
        cells = min(cells_in / max(0.5 * (1.0 - cos_cone), 1e-6), cells_max)
        g = min(config.CUBEMAP_MAX_G, max(config.CUBEMAP_MIN_G, int(np.sqrt(cells / 6.0))))
        return self._map(local_origin, sel[:count], g, radius)

    # ------------------------------------------------------------------ persistence
    def __getstate__(self) -> dict[str, Any]:
        # The cube-map view is a per-process cache (rebuilt on first use), not state.
        state = dict(self.__dict__)
        state["_view_cache"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        # Unpickled arrays are fresh allocations: the records go back on a cache line.
        self.__dict__.update(state)
        self._nodes = as_aligned(self._nodes)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the built scene, with its vertices and faces, to ``path`` (NumPy .npz)
        atomically; returns the path. ``Scene.load`` reads it back without a rebuild."""
        path = Path(path)
        meta = dict(format=FILE_FORMAT, max_depth=self._max_depth, stack_size=self._stack_size,
                    n_input_faces=self._n_input_faces, build=self._build, stats=self._stats)
        # Members aligned to a cache line (fileio.savez_aligned): a mapped load's
        # records then start on one, as a built scene's do (aligned.py).
        with atomic_writer(path) as fh:
            savez_aligned(fh, dict(nodes=self._nodes, tris=self._tris, ids=self._ids,
                                   origin_offset=self.origin_offset,
                                   vertices=self._vertices, faces=self._faces,
                                   info=np.frombuffer(json.dumps(meta).encode(),
                                                      dtype=np.uint8)))
        return path

    @classmethod
    def load(cls, path: str | os.PathLike[str], *, mmap: bool = False) -> Scene:
        """Read a scene written by ``save`` (no rebuild).

        ``mmap=True`` maps the arrays from the file instead of reading them
        (``fileio.npz_memmap``): loading costs no time or memory up front, and processes on
        one machine that map the same file share its pages (the cluster's workers do).

        Raises
        ------
        SceneFileError
            No such file, a file ``save`` did not write, or one of another format
            version (``FILE_FORMAT``).
        """
        path = Path(path)
        if not path.is_file():
            raise SceneFileError(f"Expected a saved scene file, got no file at '{path}'; "
                                 "check the path.")
        try:
            with np.load(path, allow_pickle=False) as z:
                info = json.loads(z["info"].tobytes().decode())
                version = info.get("format")
                names = ("nodes", "tris", "ids", "origin_offset", "vertices", "faces")
                arrays = {} if version != FILE_FORMAT else \
                    npz_memmap(path, names) if mmap else {k: z[k] for k in names}
        except Exception as exc:
            raise SceneFileError(
                f"Expected a scene file written by Scene.save, got '{path}' which could "
                f"not be read ({type(exc).__name__}: {exc}); rebuild it from the mesh."
            ) from exc
        if version != FILE_FORMAT:
            raise SceneFileError(f"Expected scene file format {FILE_FORMAT}, got "
                                 f"{version} in '{path}'; rebuild it from the mesh.")
        self = cls.__new__(cls)
        # A file ``save`` wrote has its records on a cache line; one from before
        # (or another writer) gets an aligned copy of them (256 bytes a record, about
        # a sixth of the scene), the rest stays mapped.
        self._nodes = as_aligned(arrays["nodes"])
        self._tris = arrays["tris"]
        self._ids = arrays["ids"]
        self.origin_offset = _read_only(arrays["origin_offset"])
        self._vertices = _read_only(arrays["vertices"])
        self._faces = _read_only(arrays["faces"])
        self._max_depth = int(info["max_depth"])
        self._stack_size = int(info["stack_size"])
        self._n_input_faces = int(info["n_input_faces"])
        self._build = info["build"]
        self._stats = info["stats"]
        self._view_cache = None
        return self

    # ------------------------------------------------------------------ the mesh
    @property
    def vertices(self) -> NDArray[np.float64]:
        """(n_v, 3) float64: the vertices given to the scene, world frame (read-only)."""
        return self._vertices

    @property
    def faces(self) -> NDArray[np.int64]:
        """(n_f, 3) int64: the faces given to the scene, zero-area ones included
        (read-only); ``Hits.triangle`` indexes its rows."""
        return self._faces

    @property
    def n_triangles(self) -> int:
        """Number of triangles in the BVH: ``len(faces)`` less the zero-area ones."""
        return int(self._tris.shape[0])

    @property
    def bounds(self) -> NDArray[np.float64]:
        """(2, 3) float64: world-coordinate box of the mesh, (min, max) rows, padded
        outward by the BVH's float32 rounding (~1e-6 of the extent)."""
        b = self._nodes[0, :6 * LANES].astype(np.float64).reshape(6, LANES)  # SoA lanes
        lo = b[:3].min(axis=1)
        hi = b[3:].max(axis=1)
        return np.stack([lo, hi]) + self.origin_offset

    # ------------------------------------------------------------------ diagnostics
    @property
    def stats(self) -> dict[str, Any]:
        """Build statistics: triangles, input_faces, nodes, leaves, max_depth,
        mean_leaf_size, sah_cost, build_seconds, nbytes."""
        return dict(self._stats)

    @property
    def nbytes(self) -> int:
        """Bytes held by the BVH (tree and triangle records; not ``vertices`` and
        ``faces``, which may be the caller's arrays)."""
        return int(self._nodes.nbytes + self._tris.nbytes + self._ids.nbytes)

    def _compute_stats(self, seconds: float) -> dict[str, Any]:
        return dict(triangles=int(self._tris.shape[0]), input_faces=self._n_input_faces,
                    max_depth=self._max_depth, **self._tree, build_seconds=float(seconds),
                    nbytes=self.nbytes)

    def __repr__(self) -> str:
        # The vertices' own box: ``bounds`` is padded and would print as -1e-06.
        box = (self._vertices.min(axis=0), self._vertices.max(axis=0))
        lo, hi = (", ".join(f"{x:.6g}" for x in row) for row in box)
        return (f"Scene({self.n_triangles:,} triangles, BVH {self.nbytes / 1e6:.1f} MB, "
                f"bounds ({lo}) .. ({hi}) m)")


def _unit(d: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 3) unit vectors of the checked (non-zero, finite) directions ``d``, as
    ``checks.prepare_rays`` normalises them."""
    u = np.empty_like(d)
    unit_directions(d, u)
    return u


def _part(limit: NDArray[np.float64], part: Any) -> NDArray[np.float64]:
    """The rays ``part`` (slice or indices) of a ray limit stored as (1,) or (n,)."""
    return limit if limit.shape[0] == 1 else limit[part]


def _release_freed_memory():
    """Hand the build's freed temporaries back to the OS (glibc ``malloc_trim``).

    The build allocates ~2.5x the final scene in temporaries (primitive records, the
    binary tree); glibc keeps much of that freed memory in its heap, which showed as
    ~50 MB of extra resident memory per 1M triangles. Best effort: other C libraries
    (or none found) are simply skipped.
    """
    global _MALLOC_TRIM
    if _MALLOC_TRIM is None:
        try:
            import ctypes

            _MALLOC_TRIM = ctypes.CDLL("libc.so.6").malloc_trim
        except (OSError, AttributeError):
            _MALLOC_TRIM = False
    if _MALLOC_TRIM:
        _MALLOC_TRIM(0)


_MALLOC_TRIM = None


def _pack_nodes(wide_box, wide_link, extent):
    """Pack the 8-wide layout into one (n8, 64) float32 array (256-byte records, the
    layout ``_kernels/traverse.py`` documents).

    Boxes (columns 0:24 minima, 24:48 maxima) are padded by ``config.BOX_PAD_REL`` times
    the scene extent and rounded outward to float32 (minima down, maxima up, then one
    more float32 step): a float32 box must contain the float64 box of its triangles, or
    a ray grazing a triangle's extreme vertex or edge could miss the box and the triangle
    with it (the watertight guarantee). Links are stored as int32 bits in columns 48:64.
    """
    pad = config.BOX_PAD_REL * float(max(np.max(extent), 1e-12))
    if wide_link.max() >= 2 ** 31:
        raise MeshError("Expected fewer than 2**31 triangles, got more; split the mesh.")
    assert wide_box.shape[1] == 6 * LANES and CHILD == 6 * LANES
    # 64-byte aligned: a record is then four whole cache lines (aligned.py). Measured
    # on bfo (1M rays a set, one thread, CPU ns a ray, median of eight alternations,
    # 16 bytes past a line / aligned): drive 271 / 255, station 195 / 179, random
    # 398 / 393 (issue 33).
    nodes = empty_aligned((wide_box.shape[0], RECORD), np.float32)
    # DECISION: one parallel kernel (collapse.pack_records), not NumPy: the same float64
    # arithmetic and float32 rounding per value, without the five temporaries of a
    # serial NumPy pass (~18 ms at 0.8M triangles).
    pack_records(wide_box, wide_link, pad, nodes, nodes.view(np.int32))
    return nodes
