"""Point-cloud preprocessing: streaming voxel-grid downsampling and outlier removal.

Voxel grid (Open3D's ``voxel_down_sample`` semantics): the grid is anchored at the
cloud's minimum bound minus half a voxel, voxel index floor((p - anchor) /
voxel_size_m), and a
voxel's output point is the centroid of its input points. Streaming: a first pass finds
the bound (or the LAS header gives it), the second accumulates per-voxel sums in
float64 relative to the anchor (UTM-sized inputs keep their precision) chunk by chunk,
so memory grows with the number of occupied voxels, not with the input: 40 bytes a
voxel (packed key, three sums, count) held, about three times that while chunks merge
(the sort of the keys), plus one chunk's points. Output order: by voxel key (Open3D's
order is unspecified).

Outlier filters, on an in-memory cloud (run them after the voxel grid):

- statistical (``statistical_outliers``): for each point the mean distance to its
  ``k`` nearest neighbours, the point itself included as Open3D's KNN search returns it
  (so k = 8 means the point and 7 others); a point is an outlier when that mean exceeds
  mean + std_ratio * std over all points (population standard deviation), as in
  Open3D's ``remove_statistical_outlier``.
- radius (``radius_outliers``): a point survives with at least ``min_neighbours``
  other points within ``radius_m`` (the point itself not counted), which is what
  Open3D's ``remove_radius_outlier(nb_points=min_neighbours)`` does (checked against it
  in the tests).

Points may be (n, 3), a single (3,) point or a structured array with fields x, y, z.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from raytrace.checks import as_points
from survey.errors import PreprocessError

__all__ = ["VoxelGrid", "radius_outliers", "statistical_outliers", "voxel_down_sample"]


def _check_points(p: ArrayLike, name: str = "points") -> NDArray[np.float64]:
    pts, _ = as_points(p, name, PreprocessError)
    if len(pts) == 0:
        raise PreprocessError(f"Expected a non-empty cloud, got 0 points in `{name}`.")
    return pts


class VoxelGrid:
    """Streaming voxel-grid accumulator.

    ``VoxelGrid(voxel_size_m, min_bound)``, then ``add(points)`` per chunk, then
    ``result()`` -> (m, 3) centroids and (m,) counts. ``min_bound`` (3,) is the cloud's
    minimum, metres (the grid anchor is min_bound - voxel_size_m / 2).
    """

    #: Bits per axis in the packed voxel key (2 cm voxels: 42 km per axis).
    BITS = 21

    def __init__(self, voxel_size_m: float, min_bound: ArrayLike) -> None:
        try:
            size = float(voxel_size_m)
        except (TypeError, ValueError):
            size = float("nan")
        if not (np.isfinite(size) and size > 0):
            raise PreprocessError(f"Expected a positive voxel size `voxel_size_m` (m), got "
                                  f"{voxel_size_m!r}.")
        self.voxel_size_m = size
        lo = np.asarray(min_bound, dtype=np.float64)
        if lo.shape != (3,) or not np.isfinite(lo).all():
            raise PreprocessError(f"Expected a finite `min_bound` of shape (3,), got "
                                  f"{lo.shape}; pass the cloud's minimum x, y, z.")
        self.anchor = lo - size / 2
        self._keys = np.empty(0, dtype=np.int64)
        self._sums = np.empty((0, 3))
        self._counts = np.empty(0, dtype=np.int64)
        self._pending: list[tuple[NDArray[Any], NDArray[Any], NDArray[Any]]] = []
        self._pending_n = 0

    def __repr__(self) -> str:
        return (f"VoxelGrid({self.voxel_size_m:g} m, "
                f"{len(self._keys) + self._pending_n:,} voxels so far)")

    def add(self, points: ArrayLike) -> None:
        """Accumulate a chunk of points (n, 3) or (3,), or a structured array."""
        p, _ = as_points(points, "points", PreprocessError, finite=False)
        if len(p) == 0:
            return
        local = p - self.anchor
        idx = np.floor(local / self.voxel_size_m).astype(np.int64)
        if (idx < 0).any() or (idx >= 1 << self.BITS).any():
            raise PreprocessError(f"Expected points within the bounds given to the voxel "
                                  f"grid, got one outside; pass the cloud's true minimum "
                                  f"bound (or the extent exceeds "
                                  f"{(1 << self.BITS) * self.voxel_size_m:.0f} m).")
        key = (idx[:, 0] << (2 * self.BITS)) | (idx[:, 1] << self.BITS) | idx[:, 2]
        u, inv = np.unique(key, return_inverse=True)
        sums = np.stack([np.bincount(inv, weights=local[:, k], minlength=len(u))
                         for k in range(3)], 1)
        self._pending.append((u, sums, np.bincount(inv, minlength=len(u))))
        self._pending_n += len(u)
        if self._pending_n > max(1 << 22, len(self._keys)):
            self._merge()

    def _merge(self) -> None:
        if not self._pending:
            return
        # The grid's arrays and the pending chunks go once concatenated: the merge's
        # peak is the concatenation and the sort's arrays, not those beside them too.
        parts = [(self._keys, self._sums, self._counts)] + self._pending
        self._pending, self._pending_n = [], 0
        del self._keys, self._sums, self._counts
        keys = np.concatenate([k for k, _, _ in parts])
        counts = np.concatenate([c for _, _, c in parts])
        sums = np.concatenate([s for _, s, _ in parts])
        del parts
        u, inv = np.unique(keys, return_inverse=True)
        del keys
        self._sums = np.stack([np.bincount(inv, weights=sums[:, k], minlength=len(u))
                               for k in range(3)], 1)
        del sums
        self._counts = np.bincount(inv, weights=counts, minlength=len(u)).astype(np.int64)
        self._keys = u

    def result(self) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """(centroids (m, 3) float64 world, counts (m,) int64), ordered by voxel key."""
        self._merge()
        return self._sums / self._counts[:, None] + self.anchor, self._counts.copy()


def voxel_down_sample(points: ArrayLike, voxel_size_m: float) -> NDArray[np.float64]:
    """Centroid per voxel of ``voxel_size_m`` (Open3D semantics, see module doc).

    points : (n, 3) or (3,) array_like of float, or structured array with x, y, z.
    Returns (m, 3) float64.
    """
    p = _check_points(points)
    g = VoxelGrid(voxel_size_m, p.min(axis=0))
    g.add(p)
    return g.result()[0]


def statistical_outliers(points: ArrayLike, *, k: int = 8,
                         std_ratio: float = 2.0) -> NDArray[np.bool_]:
    """Boolean mask (n,) of the statistical outliers (see module doc): ``k`` nearest
    neighbours (the point included), threshold mean + ``std_ratio`` x std."""
    p = _check_points(points)
    k = int(k)
    if k < 2:
        raise PreprocessError(f"Expected k >= 2 neighbours (the point included), got {k}.")
    if not (np.isfinite(std_ratio) and std_ratio > 0):
        raise PreprocessError(f"Expected a positive std_ratio, got {std_ratio}.")
    local = p - p.min(axis=0)
    d, _ = cKDTree(local).query(local, k=min(k, len(p)), workers=-1)
    d = d.reshape(len(p), -1)           # one point: query returns (n,) for k = 1
    mean = d.mean(axis=1)
    thr = mean.mean() + std_ratio * mean.std()
    return mean > thr


def radius_outliers(points: ArrayLike, *, min_neighbours: int = 4,
                    radius_m: float = 0.05) -> NDArray[np.bool_]:
    """Boolean mask (n,) of points with fewer than ``min_neighbours`` other points
    within ``radius_m``."""
    p = _check_points(points)
    if not (np.isfinite(radius_m) and radius_m > 0) or int(min_neighbours) < 1:
        raise PreprocessError(f"Expected min_neighbours >= 1 and a positive radius_m, got "
                              f"{min_neighbours}, {radius_m}.")
    local = p - p.min(axis=0)
    tree = cKDTree(local)
    counts = tree.query_ball_point(local, radius_m, return_length=True, workers=-1)
    return counts - 1 < int(min_neighbours)          # the query point is in its own ball
