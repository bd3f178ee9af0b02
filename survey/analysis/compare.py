"""Cloud-to-cloud and cloud-to-mesh distances with CloudCompare's semantics, statistics
per scan (the seed's Table 1), a histogram and the distance as a LAS scalar field.

- ``cloud_to_cloud``: for every compared point the exact nearest reference point
  (scipy ``cKDTree``, no approximation). ``max_distance_m`` clamps: a point with no
  reference point within ``max_distance_m`` gets exactly ``max_distance_m``
  (CloudCompare's "max. distance": farther points are not searched and receive the
  limit). ``split=True`` also returns
  the signed components of (compared - nearest reference) along X, Y and Z (NaN where
  clamped). ``model="plane"``: the distance to the least-squares plane through the
  ``k`` nearest reference points (CloudCompare's local model "least square plane"),
  which removes the reference's sampling from the distance.
- ``cloud_to_mesh``: signed distance to the exact closest point of the mesh (Ericson
  2005, 5.1.5), found by the engine's one closest-point query (``raytrace.Scene.closest``:
  branch and bound over the scene's BVH, ties to the lower triangle index, equal to
  brute force bit for bit). Sign as CloudCompare: positive on the side the closest
  triangle's right-hand normal (b - a) x (c - a) points to.

Two clouds far apart are not compared: ``check_overlap`` refuses bounding boxes more
than ``OVERLAP_TOL_M`` apart (two clouds 2,863 km apart once gave a mean distance of
-2,863,484,478 mm); the references carry their ``bounds``.

Arguments follow one order, the cloud measured first and the reference second
(``cloud_to_cloud(compared, reference)``, ``cloud_to_mesh(compared, vertices, faces)``),
as ``fit_helmert(source, target)`` does. Points may be (n, 3), a single (3,) point or a
structured array with fields x, y, z; results hold one value per point (n = 1 for a
single point).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from raytrace.checks import as_points
from survey.errors import CompareError

__all__ = ["BLOCK", "OVERLAP_TOL_M", "STAT_FIELDS", "Distances", "ReferenceCloud",
           "ReferenceMesh", "box_gap", "check_overlap", "cloud_to_cloud", "cloud_to_mesh",
           "distance_stats"]

#: Points per block in the distance loops (bounds the candidate lists' memory).
BLOCK = 200_000

#: Largest gap (m) between the bounding boxes of a compared cloud and its reference.
#: DECISION: a gap, not "the boxes intersect": a wall that moved 2 cm off a planar
#: reference has a box beside the reference's, and is a comparison. 1 m (ASSUMED) is
#: far above the deformations, overbreak and as-built deviations a comparison measures
#: (mm to dm) and far below the gap of a frame or unit mistake (a local frame against a
#: national grid: km to thousands of km). Every compared point lies at least the gap
#: from the reference.
OVERLAP_TOL_M = 1.0


def _max_distance(value: float | None) -> float | None:
    if value is None:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise CompareError(f"Expected `max_distance_m` as a number of metres, got "
                           f"{value!r}.") from None
    if not v > 0:   # NaN fails too
        raise CompareError(f"Expected a positive max distance `max_distance_m`, got "
                           f"{value!r}; leave it None for no limit.")
    return v


def box_gap(box_a: ArrayLike, box_b: ArrayLike) -> float:
    """The distance (m) between two axis-aligned boxes, 0 when they touch or overlap.

    Parameters
    ----------
    box_a, box_b : (2, 3) array_like of float
        (min, max) rows, as ``Scene.bounds`` and the references' ``bounds``.
    """
    a, b = _box(box_a, "box_a"), _box(box_b, "box_b")
    gap = np.maximum(np.maximum(a[0] - b[1], b[0] - a[1]), 0.0)
    return float(np.linalg.norm(gap))


def _box(box: ArrayLike, name: str) -> NDArray[np.float64]:
    try:
        b = np.asarray(box, dtype=np.float64)
    except (TypeError, ValueError):
        b = np.empty(0)
    if b.shape != (2, 3) or not np.isfinite(b).all() or (b[0] > b[1]).any():
        raise CompareError(f"Expected `{name}` as (2, 3) finite (min, max) rows, got "
                           f"{np.shape(box)}.")
    return b


def _box_text(box: NDArray[np.float64]) -> str:
    return "-".join("(" + ", ".join(f"{round(float(c), 3) + 0.0:.10g}" for c in row) + ")"
                    for row in box)


def _length_text(m: float) -> str:
    return f"{m / 1000:,.1f} km" if m >= 10_000 else f"{m:,.3f} m"


def check_overlap(box: ArrayLike, reference_box: ArrayLike, *,
                  names: tuple[str, str] = ("the compared cloud", "the reference"),
                  tolerance_m: float = OVERLAP_TOL_M) -> float:
    """Refuse a comparison of clouds whose bounding boxes lie more than
    ``tolerance_m`` apart: every distance would be at least that gap, which means
    different frames or units, not a deviation. Returns the gap (m).

    Parameters
    ----------
    box, reference_box : (2, 3) array_like of float
        (min, max) rows of the compared cloud and of the reference, metres.
    names : (str, str)
        What the message calls them (file names).
    tolerance_m : float
        Largest gap accepted, m (``OVERLAP_TOL_M``).

    Raises
    ------
    CompareError
        For boxes more than ``tolerance_m`` apart, naming both boxes.
    """
    a, b = _box(box, "box"), _box(reference_box, "reference_box")
    gap = box_gap(a, b)
    if gap > tolerance_m:
        raise CompareError(f"Expected {names[0]} to overlap {names[1]} (bounding boxes "
                           f"within {tolerance_m:g} m), got {_box_text(a)} and "
                           f"{_box_text(b)}, {_length_text(gap)} apart; are they in "
                           "different coordinate systems or units?")
    return gap


@dataclass(repr=False)
class Distances:
    """Result of a comparison: one value per compared point.

    Attributes
    ----------
    distance : (n,) float64, m (unsigned for C2C, signed for C2M)
    nearest : (n,) int64, index of the nearest reference point or triangle (-1 where
        clamped)
    dx, dy, dz : (n,) float64 or None, split components (C2C with ``split``), m

    Notes
    -----
    A single compared point (3,) gives n = 1.
    """

    distance: NDArray[np.float64]
    nearest: NDArray[np.int64]
    dx: NDArray[np.float64] | None = None
    dy: NDArray[np.float64] | None = None
    dz: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return len(self.distance)

    def __repr__(self) -> str:
        d = self.distance
        if d.size == 0:
            return "Distances(0 points)"
        a = np.abs(d)
        clamped = int((self.nearest < 0).sum())
        return (f"Distances({d.size:,} points, mean {1000 * d.mean():.2f} mm, "
                f"RMS {1000 * np.sqrt(np.mean(d * d)):.2f} mm, max |d| "
                f"{1000 * a.max():.2f} mm" + (f", {clamped:,} clamped" if clamped else "")
                + (", split" if self.dx is not None else "") + ")")


class ReferenceCloud:
    """A reference cloud prepared once (k-d tree) for comparing many clouds or chunks.

    Parameters
    ----------
    reference : (m, 3) array_like of float, or structured array with x, y, z
        Reference points, metres; at least one.
    origin : (3,) array_like of float, optional
        Local origin the tree works about (UTM-sized inputs keep their digits); by
        default the centre of the bounding box rounded to whole metres, so that a tile
        of the reference given the whole cloud's origin gives the same distances bit
        for bit (``survey.cluster``).
    """

    def __init__(self, reference: ArrayLike, *, origin: ArrayLike | None = None) -> None:
        self.points, _ = as_points(reference, "reference", CompareError)
        if len(self.points) == 0:
            raise CompareError("Expected a reference cloud with points, got none.")
        #: (2, 3) float64 (min, max) rows of the reference, m.
        self.bounds = np.stack([self.points.min(axis=0), self.points.max(axis=0)])
        # DECISION: whole metres, so that p - origin is exact for UTM-sized p, and the
        # bounds (not a sum) set it: order-free, the same for any split of the cloud.
        self.origin = (np.round(0.5 * (self.bounds[0] + self.bounds[1]))
                       if origin is None else
                       np.asarray(origin, dtype=np.float64).reshape(3))
        self.tree = cKDTree(self.points - self.origin)

    def __repr__(self) -> str:
        return f"ReferenceCloud({len(self.points):,} points)"

    def distances(self, compared: ArrayLike, *, max_distance_m: float | None = None,
                  split: bool = False, model: Literal["plane"] | None = None,
                  k: int = 6) -> Distances:
        """Distances from each compared point (n, 3) or (3,) to this cloud; see the
        module doc for ``max_distance_m``, ``split``, ``model`` and ``k``."""
        p = as_points(compared, "compared", CompareError)[0] - self.origin
        max_d = _max_distance(max_distance_m)
        if model not in (None, "plane"):
            raise CompareError(f"Expected model None or 'plane', got {model!r}.")
        ub = np.inf if max_d is None else max_d
        d, idx = self.tree.query(p, k=1, distance_upper_bound=ub, workers=-1)
        far = ~np.isfinite(d)
        idx = np.where(far, -1, idx).astype(np.int64)
        if model == "plane":
            kk = min(int(k), len(self.points))
            if kk < 3:
                raise CompareError(f"Expected k >= 3 reference points for a plane, got {kk}.")
            _, nb = self.tree.query(p, k=kk, workers=-1)
            q = self.tree.data[nb]                               # (n, k, 3)
            c = q.mean(axis=1)
            cov = np.einsum("nki,nkj->nij", q - c[:, None], q - c[:, None])
            normal = np.linalg.eigh(cov)[1][:, :, 0]             # smallest eigenvalue
            d = np.where(far, d, np.abs(np.einsum("ni,ni->n", p - c, normal)))
        d = np.where(far, ub, d)
        out = Distances(d, idx)
        if split:
            diff = np.full_like(p, np.nan)
            diff[~far] = p[~far] - self.tree.data[idx[~far]]
            out.dx, out.dy, out.dz = diff[:, 0], diff[:, 1], diff[:, 2]
        return out


def cloud_to_cloud(compared: ArrayLike, reference: ArrayLike, *,
                   max_distance_m: float | None = None, split: bool = False,
                   model: Literal["plane"] | None = None, k: int = 6) -> Distances:
    """Distance from each compared point to the nearest reference point.

    Parameters
    ----------
    compared : (n, 3) or (3,) array_like of float, or structured array with x, y, z
        The cloud measured, metres.
    reference : (m, 3) array_like of float, or structured array with x, y, z
        The cloud it is compared with, metres.
    max_distance_m : float, optional
        Clamp: farther points get exactly this distance and ``nearest`` -1.
    split : bool
        Also return the signed components dx, dy, dz of (compared - nearest).
    model : None or "plane"
        "plane": the distance to the least-squares plane of the ``k`` nearest
        reference points.

    Returns
    -------
    Distances
        (n,) arrays; n = 1 for a single (3,) point.
    """
    return ReferenceCloud(reference).distances(compared, max_distance_m=max_distance_m,
                                               split=split, model=model, k=k)


class ReferenceMesh:
    """A reference triangle mesh prepared once for signed point-to-mesh distances.

    Parameters
    ----------
    vertices : (v, 3) array_like of float, or structured array with x, y, z
    faces : (m, 3) array_like of int, vertex indices

    Attributes
    ----------
    scene : raytrace.Scene
        The engine's scene of the mesh; ``distances`` is its ``closest`` query, signed.
    bounds : (2, 3) float64
        (min, max) rows of the vertices used by a face, m.
    origin : (3,) float64
        The scene's local origin (``Scene.origin_offset``), m.
    """

    def __init__(self, vertices: ArrayLike, faces: ArrayLike) -> None:
        import warnings

        from raytrace import MeshError, Scene

        v, _ = as_points(vertices, "vertices", CompareError)
        f = np.asarray(faces)
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise CompareError(f"Expected `faces` (m, 3) of vertex indices below {len(v)}, "
                               f"got shape {f.shape}.")
        if not np.issubdtype(f.dtype, np.integer):
            whole = np.issubdtype(f.dtype, np.floating) and bool(np.isfinite(f).all()) \
                and bool((f == np.round(f)).all())
            raise CompareError(f"Expected integer `faces` (vertex indices), got dtype "
                               f"{f.dtype}" + ("" if whole else " with non-integer values")
                               + "; pass vertex indices as integers.")
        if f.min() < 0 or f.max() >= len(v):
            raise CompareError(f"Expected `faces` (m, 3) of vertex indices below {len(v)}, "
                               f"got indices from {f.min()} to {f.max()}.")
        #: (2, 3) float64 (min, max) rows of the vertices used by a face, m.
        seen = np.zeros(len(v), dtype=bool)
        seen[f.ravel()] = True
        used = v[seen]
        self.bounds = np.stack([used.min(axis=0), used.max(axis=0)])
        self.vertices = v
        self.faces = f.astype(np.int64, copy=False)
        # The engine's scene (raytrace.Scene): its BVH answers the closest-point query.
        # DECISION: zero-area faces are left out without the Scene's warning: they have
        # no side (no normal) for the sign, and a sliver's points lie on its neighbours'
        # edges; a mesh of nothing but zero-area faces is refused.
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="Dropped .* zero-area",
                                        category=UserWarning)
                self.scene = Scene(self.vertices, self.faces)
        except MeshError as exc:
            raise CompareError(f"Expected a reference mesh with at least one triangle of "
                               f"non-zero area, got {len(f)} degenerate faces; check the "
                               "mesh's faces and units.") from exc
        #: Local origin of the scene's triangles (whole metres), m.
        self.origin = np.asarray(self.scene.origin_offset)

    @property
    def tris(self) -> NDArray[np.float64]:
        """(m, 3, 3) float64: the triangles (vertices of each face) relative to
        ``origin``, m."""
        return np.asarray((self.vertices - self.origin)[self.faces])

    def __repr__(self) -> str:
        return f"ReferenceMesh({len(self.faces):,} triangles)"

    def distances(self, compared: ArrayLike, *,
                  max_distance_m: float | None = None) -> Distances:
        """Signed distances from each compared point (n, 3) or (3,) to this mesh;
        ``max_distance_m`` clamps ``|d|`` keeping the sign."""
        p = as_points(compared, "compared", CompareError)[0]
        max_d = _max_distance(max_distance_m)
        dist = np.empty(len(p))
        tri = np.empty(len(p), dtype=np.int64)
        for b in range(0, len(p), BLOCK):
            near = self.scene.closest(p[b:b + BLOCK])
            dist[b:b + BLOCK] = near.signed_distance
            tri[b:b + BLOCK] = near.triangle
        if max_d is not None:
            far = np.abs(dist) > max_d
            dist[far] = np.sign(dist[far]) * max_d
            tri[far] = -1
        return Distances(dist, tri)


def cloud_to_mesh(compared: ArrayLike, vertices: ArrayLike, faces: ArrayLike, *,
                  max_distance_m: float | None = None) -> Distances:
    """Signed distance from each compared point to a triangle mesh.

    Parameters
    ----------
    compared : (n, 3) or (3,) array_like of float, or structured array with x, y, z
        The points measured, metres.
    vertices : (v, 3) array_like of float; faces : (m, 3) array_like of int
        The reference mesh.
    max_distance_m : float, optional
        Clamp ``|d|`` to this (keeping the sign); clamped points get ``nearest`` -1.

    Returns
    -------
    Distances
        (n,) arrays (n = 1 for a single (3,) point); positive on the side the closest
        triangle's normal (b - a) x (c - a) points to.
    """
    return ReferenceMesh(vertices, faces).distances(compared, max_distance_m=max_distance_m)


# ------------------------------------------------------------------ statistics, outputs
STAT_FIELDS = ("n", "mean", "median", "std", "p95", "rms", "max_abs")


def distance_stats(d: ArrayLike) -> dict[str, float]:
    """n, mean, median, std (ddof 0), p95 of ``|d|``, RMS and max ``|d|`` of distances
    (m)."""
    d = np.asarray(d, dtype=np.float64)
    if d.size == 0:
        return {k: (0 if k == "n" else float("nan")) for k in STAT_FIELDS}
    a = np.abs(d)
    return {"n": int(d.size), "mean": float(d.mean()), "median": float(np.median(d)),
            "std": float(d.std()), "p95": float(np.percentile(a, 95)),
            "rms": float(np.sqrt(np.mean(d * d))), "max_abs": float(a.max())}
