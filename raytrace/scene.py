"""``Scene``: a triangle mesh with a BVH, answering closest-hit and any-hit ray queries.

Precision: the mesh is stored relative to a local origin (the centre of its bounding
box) in float64, and every ray origin is shifted into that frame in float64 before
casting. A tunnel in UTM coordinates (eastings ~4.5e5, northings ~5.4e6) therefore hits
exactly like the same tunnel near (0, 0, 0): the intersection arithmetic only ever sees
numbers of the size of the tunnel itself.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from . import config
from ._kernels.build import build_bvh, slot_triangles, to_quad_layout, triangle_setup
from ._kernels.cubemap import closest_hit_view, count_entries, fill_entries, footprints
from ._kernels.normals import hit_normals
from ._kernels.order import counting_sort, morton_keys
from ._kernels.traverse import any_hit, closest_hit
from .errors import MeshError, RayError, SceneFileError
from .fileio import atomic_writer

_NO_ORDER = np.empty(0, dtype=np.int64)

#: Version of the ``Scene.save`` file layout; ``Scene.load`` refuses other versions.
FILE_FORMAT = 4


def _shape(a) -> str:
    return str(tuple(np.shape(a)))


def _first(idx, k: int = 10) -> str:
    idx = np.asarray(idx).ravel()
    s = ", ".join(str(int(i)) for i in idx[:k])
    return s + (f", ... ({idx.size} in all)" if idx.size > k else "")


@dataclass
class Hits:
    """Result of ``Scene.cast`` for n rays.

    Attributes
    ----------
    t : (n,) float64
        Distance along the normalised direction; ``inf`` on a miss.
    triangle : (n,) int64
        Index of the hit face in the ``faces`` array given to the scene; -1 on a miss.
    u, v : (n,) float64
        Barycentric coordinates: the hit is (1 - u - v) p0 + u p1 + v p2 of the face's
        vertices in their given order (Embree's convention); 0 on a miss.
    points : (n, 3) float64
        World coordinates of the hits (computed on first access); NaN on a miss.
    normals : (n, 3) float64
        Unit geometric normals, (p1 - p0) x (p2 - p0) normalised, so they follow the
        faces' winding, not the ray (computed on first access); NaN on a miss.
    """

    t: np.ndarray
    triangle: np.ndarray
    u: np.ndarray
    v: np.ndarray
    _origins: np.ndarray = field(repr=False)
    _directions: np.ndarray = field(repr=False)
    _slot: np.ndarray = field(repr=False)
    _scene: "Scene" = field(repr=False)
    _points: np.ndarray | None = field(default=None, repr=False)
    _normals: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return self.t.shape[0]

    @property
    def hit(self) -> np.ndarray:
        """(n,) bool: True where the ray hit a triangle."""
        return self.triangle >= 0

    @property
    def points(self) -> np.ndarray:
        if self._points is None:
            with np.errstate(invalid="ignore"):
                p = self._origins + self.t[:, None] * self._directions
            p[~self.hit] = np.nan
            self._points = p
        return self._points

    @property
    def normals(self) -> np.ndarray:
        if self._normals is None:
            nrm = np.empty((len(self), 3))
            hit_normals(self._scene._tris, self._slot, nrm)
            self._normals = nrm
        return self._normals


class Scene:
    """A triangle mesh with a binned-SAH BVH for exact ray casting.

    Parameters
    ----------
    vertices : (n_v, 3) array_like of float
        Vertex coordinates in metres (any frame; large offsets such as UTM are fine).
    faces : (n_f, 3) array_like of int
        Vertex indices per triangle.
    sah_bins, max_leaf_size, c_trav, c_isect : optional
        Build constants; defaults from ``raytrace.config``.

    Raises
    ------
    MeshError
        Empty mesh, wrong shapes, non-finite vertices, non-integer or out-of-range face
        indices, or a mesh whose triangles are all degenerate.

    Notes
    -----
    Zero-area triangles are dropped with a ``UserWarning`` that counts them; the other
    triangles keep their input indices in ``Hits.triangle``.
    """

    def __init__(self, vertices, faces, *, sah_bins: int = config.SAH_BINS,
                 max_leaf_size: int = config.MAX_LEAF_SIZE,
                 c_trav: float = config.SAH_C_TRAV, c_isect: float = config.SAH_C_ISECT):
        t_start = time.perf_counter()
        if not (2 <= int(sah_bins) <= 256 and 1 <= int(max_leaf_size) <= 255
                and float(c_trav) > 0 and float(c_isect) > 0):
            raise ValueError(
                f"Expected 2 <= sah_bins <= 256, 1 <= max_leaf_size <= 255 and positive "
                f"costs, got sah_bins={sah_bins}, max_leaf_size={max_leaf_size}, "
                f"c_trav={c_trav}, c_isect={c_isect}; the defaults are in raytrace.config.")
        v, f = _validate_mesh(vertices, faces)
        lo = v.min(axis=0)
        hi = v.max(axis=0)
        # Local origin: the box centre rounded to a whole metre, so that it is a short,
        # exactly representable number a user can read back and reason about.
        self.origin_offset = np.round(0.5 * (lo + hi))
        local = v - self.origin_offset
        m = f.shape[0]
        prim = np.empty((m, 9), dtype=np.float32)
        good = np.empty(m, dtype=np.bool_)
        triangle_setup(local, f, config.AREA_REL, prim, good)
        n_bad = m - int(good.sum())
        if n_bad == m:
            raise MeshError(
                f"Expected a mesh with at least one triangle of non-zero area, got "
                f"{n_bad} degenerate triangles; check the face indices and units."
            )
        keep = np.arange(m)
        if n_bad:
            warnings.warn(
                f"Dropped {n_bad} zero-area triangle(s) of {m} "
                f"(first: {_first(np.flatnonzero(~good))}); they cannot be hit.",
                UserWarning, stacklevel=2,
            )
            keep = np.flatnonzero(good)
            prim = prim[keep]
        stop = max(config.BUILD_TASK_MIN, len(keep) // config.BUILD_TASKS)
        with numba.parallel_chunksize(1):
            node_box, node_meta = build_bvh(
                prim, keep, int(sah_bins), bool(config.SAH_ALL_AXES), float(c_trav),
                float(c_isect),
                int(max_leaf_size), int(config.MAX_LEAF_SIZE_FORCED), int(stop))
        del prim
        quad_box, quad_link, (n_nodes, n_leaves, max_depth, in_leaves, cost, depth4) = \
            to_quad_layout(node_box, node_meta, float(c_trav), float(c_isect))
        del node_box, node_meta
        # DECISION: per slot v0, e1, e2 in float64 (72 B a triangle, a leaf is one
        # contiguous run) rather than shared vertices + indices (~24 B): with shared
        # vertices every triangle of a leaf gathers three vertices from different cache
        # lines, which made incoherent rays ~1.5x slower on the 1M-triangle benchmark
        # tunnel; the scene stays within 1.5x of Open3D's memory (benchmarks/RESULTS.md).
        self._tris = np.empty((len(keep), 9))
        slot_triangles(local, f, keep, self._tris)
        self._ids = keep.astype(np.int32)
        self._nodes = _pack_nodes(quad_box, quad_link, hi - lo)
        self._max_depth = int(max_depth)
        # A visit pushes at most 3 records: 3 per 4-wide level, plus slack.
        self._stack_size = 3 * int(depth4) + 4
        self._n_input_faces = int(m)
        self._build = dict(sah_bins=int(sah_bins), max_leaf_size=int(max_leaf_size),
                           c_trav=float(c_trav), c_isect=float(c_isect))
        self._tree = dict(nodes=int(n_nodes), leaves=int(n_leaves),
                          mean_leaf_size=float(in_leaves) / n_leaves, sah_cost=float(cost))
        self._stats = self._compute_stats(time.perf_counter() - t_start)
        _release_freed_memory()

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_file(cls, path, **kwargs) -> "Scene":
        """Load any mesh trimesh reads (PLY, OBJ, STL, OFF, GLB, DAE) and build a scene.

        Multi-part files (scenes) are concatenated in their world placement. Collada
        (.dae) needs the optional ``pycollada`` (``pip install 'tunnelsim[collada]'``).
        """
        import trimesh

        path = Path(path)
        if not path.is_file():
            raise MeshError(f"Expected a mesh file, got no file at '{path}'; check the path.")
        if path.suffix.lower() == ".dae":
            try:
                import collada  # noqa: F401  (trimesh reads Collada through pycollada)
            except ImportError:
                raise MeshError(f"Expected pycollada to read the Collada file '{path}', "
                                "got it missing; pip install 'tunnelsim[collada]'.") from None
        try:
            mesh = trimesh.load(str(path), force="mesh", process=False)
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise MeshError(
                f"Expected a mesh file trimesh can read, got '{path}' which failed with "
                f"{type(exc).__name__}: {exc}; convert it to PLY or OBJ."
            ) from exc
        if not hasattr(mesh, "faces") or len(mesh.faces) == 0:
            raise MeshError(f"Expected triangles in '{path}', got none; is it a point cloud?")
        return cls(np.asarray(mesh.vertices, dtype=np.float64),
                   np.asarray(mesh.faces, dtype=np.int64), **kwargs)

    @classmethod
    def _from_arrays(cls, nodes, tris, ids, offset, max_depth, stack_size, n_faces,
                     build, stats):
        self = cls.__new__(cls)
        self._stack_size = int(stack_size)
        self._nodes = nodes
        self._tris = tris
        self._ids = ids
        self.origin_offset = offset
        self._max_depth = int(max_depth)
        self._n_input_faces = int(n_faces)
        self._build = build
        self._stats = stats
        return self

    # ------------------------------------------------------------------ queries
    def cast(self, origins, directions, t_min=0.0, t_max=np.inf, *,
             method: str = "auto") -> Hits:
        """Closest hit of each ray.

        Parameters
        ----------
        origins : (n, 3) or (3,) array_like of float
            Ray origins in world coordinates; a single origin is shared by all rays.
        directions : (n, 3) array_like of float
            Ray directions; need not be unit length, must not be zero.
        t_min, t_max : float or (n,) array_like of float
            Accepted hit interval [t_min, t_max] along the normalised direction (both
            ends included, as in Embree).
        method : {"auto", "bvh", "cubemap"}
            "cubemap" builds (and keeps, for the next call from the same origin) a cube
            map of candidate triangles around a single shared origin — a TLS station —
            and tests each ray against its cell's list only. "auto" does so for a single
            origin with at least ``config.CUBEMAP_MIN_RAYS_PER_TRI`` rays per triangle.
            The answer is identical either way; only the speed differs.

        Returns
        -------
        Hits
        """
        if method not in ("auto", "bvh", "cubemap"):
            raise RayError(f"Expected `method` to be 'auto', 'bvh' or 'cubemap', got "
                           f"{method!r}.")
        org, dirs, tmin, tmax = self._prepare(origins, directions, t_min, t_max)
        n = dirs.shape[0]
        out_t = np.empty(n)
        out_slot = np.empty(n, dtype=np.int64)
        out_u = np.empty(n)
        out_v = np.empty(n)
        local = org - self.origin_offset
        view = None
        if n and org.shape[0] == 1 and (method == "cubemap" or (
                method == "auto" and n >= config.CUBEMAP_MIN_RAYS_PER_TRI * self.n_triangles)):
            view = self._view(local)
        if n and view is not None:
            start, slots, counts, g = view
            with numba.parallel_chunksize(config.PRANGE_CHUNK):
                closest_hit_view(start, slots, counts, g, config.CUBEMAP_HOT, self._nodes,
                                 self._nodes.view(np.int32), self._tris, self._ids, local,
                                 dirs, tmin, tmax, self._stack_size, config.RAY_BLOCK,
                                 out_t, out_slot, out_u, out_v)
        elif n:
            with numba.parallel_chunksize(config.PRANGE_CHUNK):
                closest_hit(self._nodes, self._nodes.view(np.int32), self._tris, self._ids,
                            local, dirs, tmin, tmax, self._stack_size,
                            self._ray_order(local), out_t, out_slot, out_u, out_v)
        tri = np.where(out_slot >= 0, self._ids[np.maximum(out_slot, 0)], -1)
        return Hits(out_t, tri.astype(np.int64), out_u, out_v, org, dirs, out_slot, self)

    def occluded(self, origins, directions, t_max=np.inf, t_min=0.0) -> np.ndarray:
        """Whether each ray hits anything within [t_min, t_max] (any-hit, early exit).

        Shapes as in ``cast``. Returns (n,) bool.
        """
        org, dirs, tmin, tmax = self._prepare(origins, directions, t_min, t_max)
        out = np.zeros(dirs.shape[0], dtype=np.bool_)
        if dirs.shape[0]:
            local = org - self.origin_offset
            with numba.parallel_chunksize(config.PRANGE_CHUNK):
                any_hit(self._nodes, self._nodes.view(np.int32), self._tris, local, dirs,
                        tmin, tmax, self._stack_size, self._ray_order(local), out)
        return out

    def _ray_order(self, local_origins):
        """Processing order for a batch: Morton order of the origins for large batches
        of scattered origins, else empty (input order). Speed only; see order.py."""
        n = local_origins.shape[0]
        if n < config.ORDER_MIN_RAYS:
            return _NO_ORDER
        box = self.bounds - self.origin_offset
        keys = np.empty(n, dtype=np.int64)
        morton_keys(local_origins, box[0], box[1], config.ORDER_BITS, keys)
        return counting_sort(keys, 1 << (3 * config.ORDER_BITS))

    def _view(self, local_origin):
        """Cube map around one origin (local frame), cached for the last origin used.
        Returns (start, slots, counts, g), or None when it would be too large."""
        key = local_origin.tobytes()
        cached = getattr(self, "_view_cache", None)
        if cached is not None and cached[0] == key:  # same origin: reuse
            return cached[1]
        m = self.n_triangles
        g = int(np.sqrt(config.CUBEMAP_CELLS_PER_TRI * m / 6.0))
        g = min(config.CUBEMAP_MAX_G, max(config.CUBEMAP_MIN_G, g))
        fp = np.empty((m, 6, 4), dtype=np.int32)
        o = local_origin[0]
        footprints(self._tris, float(o[0]), float(o[1]), float(o[2]), g, fp)
        counts = count_entries(fp, g)
        kept = int(counts[counts <= config.CUBEMAP_HOT].sum())
        view = None
        if kept <= config.CUBEMAP_MAX_ENTRIES:
            start, slots = fill_entries(fp, g, counts, config.CUBEMAP_HOT)
            view = (start, slots, counts, g)
        self._view_cache = (key, view)
        return view

    def _prepare(self, origins, directions, t_min, t_max):
        d = np.asarray(directions, dtype=np.float64)
        if d.ndim == 1 and d.shape == (3,):
            d = d[None, :]
        if d.ndim != 2 or d.shape[1] != 3:
            raise RayError(f"Expected `directions` to have shape (n, 3), got {_shape(d)}; "
                           "pass one row per ray.")
        n = d.shape[0]
        o = np.asarray(origins, dtype=np.float64)
        if o.shape == (3,):
            o = o[None, :]
        if o.ndim != 2 or o.shape[1] != 3 or o.shape[0] not in (1, n):
            raise RayError(f"Expected `origins` to have shape ({n}, 3) or (3,), got "
                           f"{_shape(o)}; pass one origin per ray or a single one.")
        bad = np.flatnonzero(~np.isfinite(o).all(axis=1))
        if bad.size:
            raise RayError(f"Expected finite `origins`, got NaN/inf at row(s) {_first(bad)}.")
        bad = np.flatnonzero(~np.isfinite(d).all(axis=1))
        if bad.size:
            raise RayError(f"Expected finite `directions`, got NaN/inf at row(s) {_first(bad)}.")
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        bad = np.flatnonzero(length == 0.0)
        if bad.size:
            raise RayError(f"Expected non-zero `directions`, got zero length at row(s) "
                           f"{_first(bad)}; drop those rays.")
        d = d / length[:, None]
        o = np.ascontiguousarray(o)
        lims = []
        for name, val in (("t_min", t_min), ("t_max", t_max)):
            a = np.asarray(val, dtype=np.float64)
            if a.ndim == 0:
                a = a.reshape(1)
            if a.ndim != 1 or a.shape[0] not in (1, n):
                raise RayError(f"Expected `{name}` to be a scalar or shape ({n},), got "
                               f"{_shape(a)}.")
            if np.isnan(a).any():
                raise RayError(f"Expected `{name}` without NaN, got NaN at "
                               f"{_first(np.flatnonzero(np.isnan(a)))}.")
            lims.append(np.ascontiguousarray(a))
        tmin, tmax = lims
        if (tmin < 0).any():
            raise RayError("Expected `t_min` >= 0, got a negative value; rays start at "
                           "their origin.")
        if tmin.shape[0] != tmax.shape[0]:
            tmin = np.broadcast_to(tmin, (n,)).copy()
            tmax = np.broadcast_to(tmax, (n,)).copy()
        return o, np.ascontiguousarray(d), tmin, tmax

    # ------------------------------------------------------------------ persistence
    def save(self, path) -> Path:
        """Write the built scene to ``path`` (NumPy .npz) atomically; returns the path."""
        path = Path(path)
        meta = dict(format=FILE_FORMAT, max_depth=self._max_depth, stack_size=self._stack_size,
                    n_input_faces=self._n_input_faces, build=self._build, stats=self._stats)
        with atomic_writer(path) as fh:
            np.savez(fh, nodes=self._nodes, tris=self._tris, ids=self._ids,
                     origin_offset=self.origin_offset,
                     info=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8))
        return path

    @classmethod
    def load(cls, path) -> "Scene":
        """Read a scene written by ``save`` (no rebuild)."""
        path = Path(path)
        if not path.is_file():
            raise SceneFileError(f"Expected a saved scene file, got no file at '{path}'.")
        try:
            with np.load(path, allow_pickle=False) as z:
                info = json.loads(z["info"].tobytes().decode())
                arrays = {k: z[k] for k in ("nodes", "tris", "ids", "origin_offset")}
        except SceneFileError:
            raise
        except Exception as exc:
            raise SceneFileError(
                f"Expected a scene file written by Scene.save, got '{path}' which could "
                f"not be read ({type(exc).__name__}: {exc}); rebuild it from the mesh."
            ) from exc
        if info.get("format") != FILE_FORMAT:
            raise SceneFileError(f"Expected scene file format {FILE_FORMAT}, got "
                                 f"{info.get('format')} in '{path}'; rebuild it from the mesh.")
        return cls._from_arrays(arrays["nodes"], arrays["tris"], arrays["ids"],
                                arrays["origin_offset"], info["max_depth"],
                                info["stack_size"],
                                info["n_input_faces"], info["build"], info["stats"])

    # ------------------------------------------------------------------ diagnostics
    @property
    def stats(self) -> dict:
        """Build statistics: triangles, nodes, leaves, max depth, mean leaf size, SAH
        cost, build seconds, memory bytes."""
        return dict(self._stats)

    @property
    def n_triangles(self) -> int:
        """Number of triangles in the BVH (degenerate ones dropped)."""
        return int(self._tris.shape[0])

    @property
    def nbytes(self) -> int:
        """Bytes held by the scene's arrays (tree and triangles)."""
        return int(self._nodes.nbytes + self._tris.nbytes + self._ids.nbytes)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64 world-coordinate box of the mesh (as stored, padded)."""
        b = self._nodes[0, :24].astype(np.float64).reshape(6, 4)  # SoA lanes
        lo = b[:3].min(axis=1)
        hi = b[3:].max(axis=1)
        return np.stack([lo, hi]) + self.origin_offset

    def _compute_stats(self, seconds) -> dict:
        return dict(triangles=int(self._tris.shape[0]), input_faces=self._n_input_faces,
                    max_depth=self._max_depth, **self._tree, build_seconds=float(seconds),
                    nbytes=self.nbytes)

    def __repr__(self) -> str:
        s = self._stats
        return (f"Scene(triangles={s['triangles']}, nodes={s['nodes']}, "
                f"max_depth={s['max_depth']}, origin_offset={self.origin_offset.tolist()})")


def _validate_mesh(vertices, faces):
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MeshError(f"Expected numeric `vertices`, got {type(vertices).__name__}: {exc}.")
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"Expected `vertices` to have shape (n, 3), got {_shape(v)}.")
    if v.shape[0] == 0:
        raise MeshError("Expected at least 3 `vertices`, got an empty array; the mesh is empty.")
    bad = np.flatnonzero(~np.isfinite(v).all(axis=1))
    if bad.size:
        raise MeshError(f"Expected finite `vertices`, got NaN/inf at vertex index(es) "
                        f"{_first(bad)}; remove or repair them.")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3:
        raise MeshError(f"Expected `faces` to have shape (m, 3), got {_shape(f)}; only "
                        "triangles are supported (triangulate polygons first).")
    if f.shape[0] == 0:
        raise MeshError("Expected at least one face, got an empty `faces` array; the mesh "
                        "is empty.")
    if not np.issubdtype(f.dtype, np.integer):
        if np.issubdtype(f.dtype, np.floating) and np.isfinite(f).all() and \
                (f == np.round(f)).all():
            f = f.astype(np.int64)
        else:
            raise MeshError(f"Expected integer `faces`, got dtype {f.dtype}.")
    f = f.astype(np.int64, copy=False)
    bad = np.flatnonzero(((f < 0) | (f >= v.shape[0])).any(axis=1))
    if bad.size:
        raise MeshError(f"Expected face indices in [0, {v.shape[0] - 1}], got out-of-range "
                        f"indices in face(s) {_first(bad)}; the faces refer to missing "
                        "vertices.")
    return v, f


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


def _pack_nodes(quad_box, quad_link, extent):
    """Pack the 4-wide layout into one (n4, 32) float32 array (128-byte records).

    Boxes (columns 0:12 minima, 12:24 maxima) are rounded outward to float32 and padded
    by ``config.BOX_PAD_REL`` times the scene extent; links are stored as int32 bits in
    columns 24-31.
    """
    pad = config.BOX_PAD_REL * float(max(np.max(extent), 1e-12))
    nodes = np.empty((quad_box.shape[0], 32), dtype=np.float32)
    with np.errstate(invalid="ignore", over="ignore"):
        lo = (quad_box[:, :12].astype(np.float64) - pad).astype(np.float32)
        hi = (quad_box[:, 12:24].astype(np.float64) + pad).astype(np.float32)
    nodes[:, :12] = np.nextafter(lo, np.float32(-np.inf))
    nodes[:, 12:24] = np.nextafter(hi, np.float32(np.inf))
    if quad_link.max() >= 2 ** 31:
        raise MeshError("Expected fewer than 2**31 triangles, got more; split the mesh.")
    nodes.view(np.int32)[:, 24:32] = quad_link.astype(np.int32)
    return nodes
