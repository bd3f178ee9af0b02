"""Compact meshes: quadric decimation to a triangle budget or a geometric error bound,
with the error measured after, not assumed.

Method: Garland & Heckbert 1997 ("Surface simplification using quadric error
metrics", SIGGRAPH '97) through Open3D's ``TriangleMesh.simplify_quadric_decimation``
(edge collapses ordered by the summed squared distances to the planes of the faces
around each vertex; boundary edges held by perpendicular planes of weight
``BOUNDARY_WEIGHT``). The quadric cost is a sum of squared plane distances, not a
distance to the original surface, so the error is measured on the result
(``decimation_error``): the distances from sample points of the original mesh (its
vertices and face centroids) to the decimated mesh, and back from the decimated mesh's
vertices and face centroids to the original, each exact point-to-triangle distances
(the engine's query, ``raytrace.Scene.closest``). The larger of the two maxima is a
sampled symmetric Hausdorff distance.

A geometric bound (``max_error_m``) is met by search: halve the triangle count while the
measured error stays within the bound, then bisect between the last mesh within it and
the first beyond (each step decimates the last mesh within the bound, and each is
measured against the original).

DECISION: Open3D's implementation rather than our own. It is in the ``solid`` extra the
solid route needs anyway and in the test extra; an edge-collapse heap with topology
checks is a large piece of code to own, and the error is measured independently of it
(which is what a user needs to trust). The tunnel route needs no Open3D; its own
budget (``--triangles``: coarser cells) still works without it, and a decimation
asked for on it raises the install hint when Open3D is missing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from survey.errors import ReconstructionError

__all__ = ["BOUNDARY_WEIGHT", "DECIMATION_METHOD", "DecimatedMesh", "decimate_mesh",
           "decimation_error", "point_mesh_distances"]

Floats = NDArray[np.float64]
Ints = NDArray[np.int64]

#: Weight of the boundary-preserving planes (Garland & Heckbert 1997, sec. 5; Open3D's
#: default). An open mesh (portals, trimmed holes) keeps its rim where it was.
BOUNDARY_WEIGHT = 1.0
#: Fewest triangles the error search tries.
MIN_TRIANGLES = 4
#: The error search stops when the last triangle count within the bound and the first
#: beyond it differ by less than this ratio.
SEARCH_RATIO = 1.05
#: What the JSON names as the implementation.
DECIMATION_METHOD = ("quadric edge collapse (Garland & Heckbert 1997), Open3D "
                     "TriangleMesh.simplify_quadric_decimation")


def _open3d() -> Any:
    from raytrace.config import threading_info

    threading_info()            # before Open3D's TBB is loaded (see survey.clouds.solid)
    try:
        import open3d as o3d
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ReconstructionError("Expected the optional package open3d for the quadric "
                                  "decimation (--max-triangles, --max-error), got none; "
                                  "install it with: pip install 'open3d>=0.18' (or use "
                                  "--triangles on the tunnel route).") from exc
    return o3d


def point_mesh_distances(points: ArrayLike, vertices: ArrayLike, faces: ArrayLike
                         ) -> Floats:
    """Exact distance (m) from each point (n, 3) to the nearest triangle of the mesh
    (vertices (v, 3) float, faces (m, 3) int), by the engine's closest-point query
    (``raytrace.Scene.closest``). Returns (n,) float64; empty points give an empty
    array. Zero-area faces are left out (they lie on their neighbours' edges)."""
    import warnings

    from raytrace import MeshError, Scene

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(p) == 0:
        return np.empty(0)
    if len(f) == 0:
        raise ReconstructionError("Expected a mesh with at least one triangle, got none.")
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Dropped .* zero-area",
                                    category=UserWarning)
            scene = Scene(v, f)
    except MeshError as exc:
        raise ReconstructionError(str(exc)) from exc
    return np.asarray(scene.closest(p).distance)


def _samples(v: Floats, f: Ints) -> Floats:
    """The vertices used by faces and the face centroids: (k, 3)."""
    return np.concatenate([v[np.unique(f)], v[f].mean(axis=1)])


def _stats(d: Floats) -> dict[str, float]:
    return {"median_m": float(np.median(d)), "p95_m": float(np.percentile(d, 95)),
            "max_m": float(d.max())}


def decimation_error(vertices: ArrayLike, faces: ArrayLike, decimated_vertices: ArrayLike,
                     decimated_faces: ArrayLike) -> dict[str, Any]:
    """Geometric error of a simplified mesh against the one it came from (m).

    Parameters
    ----------
    vertices : (n, 3) array_like of float; faces : (m, 3) array_like of int
        The original mesh.
    decimated_vertices : (n', 3) array_like of float; decimated_faces : (m', 3) array_like
        of int
        The simplified one.

    Returns
    -------
    dict
        ``original_to_decimated`` and ``decimated_to_original``: {``median_m``, ``p95_m``,
        ``max_m``} of the exact point-to-triangle distances from each mesh's used
        vertices and face centroids to the other mesh; ``hausdorff_m``: the larger
        maximum (a sampled symmetric Hausdorff distance).
    """
    v, f = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    dv = np.asarray(decimated_vertices, dtype=np.float64)
    df = np.asarray(decimated_faces, dtype=np.int64)
    a = point_mesh_distances(_samples(v, f), dv, df)
    b = point_mesh_distances(_samples(dv, df), v, f)
    return {"original_to_decimated": _stats(a), "decimated_to_original": _stats(b),
            "hausdorff_m": float(max(a.max(), b.max()))}


@dataclass
class DecimatedMesh:
    """A decimated mesh (``decimate_mesh``).

    Attributes
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    nearest_original : (n,) int64
        The original vertex nearest to each vertex (to carry per-vertex properties such
        as ``support`` over).
    quality : dict
        ``method``, ``triangles_before``, ``triangles``, ``max_triangles``,
        ``max_error_m`` (the request, None where not given), ``tries`` (decimations
        run) and the measured ``error`` (``decimation_error``).
    """

    vertices: Floats
    faces: Ints
    nearest_original: Ints
    quality: dict[str, Any] = field(default_factory=dict)


def _simplify(o3d: Any, v: Floats, f: Ints, target: int) -> tuple[Floats, Ints]:
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v),
                                     o3d.utility.Vector3iVector(f.astype(np.int32)))
    out = mesh.simplify_quadric_decimation(int(target), boundary_weight=BOUNDARY_WEIGHT)
    out.remove_unreferenced_vertices()
    out.remove_degenerate_triangles()
    out.remove_unreferenced_vertices()
    return (np.asarray(out.vertices, dtype=np.float64),
            np.asarray(out.triangles, dtype=np.int64))


def decimate_mesh(vertices: ArrayLike, faces: ArrayLike, *, max_triangles: int | None = None,
                  max_error_m: float | None = None) -> DecimatedMesh:
    """Quadric decimation to at most ``max_triangles`` faces and/or a measured
    symmetric error (``decimation_error``'s ``hausdorff_m``) of at most ``max_error_m``
    (see the module doc).

    Parameters
    ----------
    vertices : (n, 3) array_like of float
    faces : (m, 3) array_like of int
    max_triangles : int > 0, optional
        Triangle budget. A mesh within it already is returned unchanged (error 0).
    max_error_m : float > 0, optional
        With it, the fewest triangles (within ``max_triangles`` if given too) whose
        measured error stays within the bound, to ``SEARCH_RATIO``.

    Returns
    -------
    DecimatedMesh

    Raises
    ------
    ReconstructionError
        Neither bound given, bad bounds, Open3D missing, or a budget whose decimation
        exceeds ``max_error_m`` (the two cannot both hold: the message says which to
        raise).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ReconstructionError(f"Expected a mesh of vertices (n, 3) and faces (m, 3), "
                                  f"got {v.shape} and {f.shape}.")
    if max_triangles is None and max_error_m is None:
        raise ReconstructionError("Expected a triangle budget or an error bound, got "
                                  "neither; pass --max-triangles or --max-error.")
    if max_triangles is not None and not (isinstance(max_triangles, (int, np.integer))
                                          and max_triangles >= MIN_TRIANGLES):
        raise ReconstructionError(f"Expected --max-triangles as an integer >= "
                                  f"{MIN_TRIANGLES}, got {max_triangles!r}.")
    if max_error_m is not None and not (np.isfinite(max_error_m) and max_error_m > 0):
        raise ReconstructionError(f"Expected a positive --max-error (m), got "
                                  f"{max_error_m!r}.")
    # Open3D keeps vertices in float64 but sums quadrics about the origin: centre UTM-sized
    # coordinates first.
    origin = np.round(v.mean(axis=0))
    v0 = v - origin
    n0 = len(f)
    cap = n0 if max_triangles is None else min(n0, int(max_triangles))
    tries = 0

    o3d = _open3d() if cap < n0 or max_error_m is not None else None
    best_v, best_f = v0, f
    if cap < n0:
        best_v, best_f = _simplify(o3d, v0, f, cap)
        tries += 1
    if cap < n0:
        err = decimation_error(v0, f, best_v, best_f)
    else:
        zero = {"median_m": 0.0, "p95_m": 0.0, "max_m": 0.0}
        err = {"original_to_decimated": zero, "decimated_to_original": dict(zero),
               "hausdorff_m": 0.0}
    if max_error_m is not None:
        if err["hausdorff_m"] > max_error_m:
            raise ReconstructionError(
                f"Expected a decimation within --max-error {max_error_m:g} m under "
                f"--max-triangles {max_triangles}, got {err['hausdorff_m']:.4g} m at "
                f"{len(best_f):,} triangles; raise --max-triangles or --max-error.")
        # Halve while within the bound, then bisect (module doc).
        lo_n = MIN_TRIANGLES - 1           # a count known (or taken) to exceed the bound
        while len(best_f) > MIN_TRIANGLES:
            target = max(MIN_TRIANGLES, len(best_f) // 2)
            cv, cf = _simplify(o3d, best_v, best_f, target)
            tries += 1
            ce = decimation_error(v0, f, cv, cf) if len(cf) else None
            if ce is None or ce["hausdorff_m"] > max_error_m:
                lo_n = target
                break
            best_v, best_f, err = cv, cf, ce
        while len(best_f) > SEARCH_RATIO * max(lo_n, 1) and len(best_f) - lo_n > 1:
            target = int(np.sqrt(max(lo_n, 1) * len(best_f)))
            if target >= len(best_f) or target <= lo_n:
                break
            cv, cf = _simplify(o3d, best_v, best_f, target)
            tries += 1
            ce = decimation_error(v0, f, cv, cf) if len(cf) else None
            if ce is None or ce["hausdorff_m"] > max_error_m:
                lo_n = target
            else:
                best_v, best_f, err = cv, cf, ce
    # DECISION: per-vertex properties follow the nearest original vertex: a collapse
    # puts the new vertex on (or within the measured error of) the surface it replaced.
    _, near = cKDTree(v0).query(best_v, workers=-1)
    quality = {"method": DECIMATION_METHOD, "triangles_before": int(n0),
               "triangles": int(len(best_f)), "max_triangles": max_triangles,
               "max_error_m": max_error_m, "tries": tries, "error": err}
    return DecimatedMesh(best_v + origin, best_f, np.asarray(near, dtype=np.int64), quality)
