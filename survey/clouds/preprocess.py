"""Point-cloud preprocessing: streaming voxel-grid downsampling and outlier removal.

Voxel grid (Open3D's ``voxel_down_sample`` semantics): the grid is anchored at the
cloud's minimum bound minus half a voxel, voxel index floor((p - anchor) / size), and a
voxel's output point is the centroid of its input points. Streaming: a first pass finds
the bound (or the LAS header gives it), the second accumulates per-voxel sums in
float64 relative to the anchor (UTM-sized inputs keep their precision) chunk by chunk,
so memory grows with the number of occupied voxels, not with the input. Output order:
by voxel key (Open3D's order is unspecified).

Outlier filters, on an in-memory cloud (run them after the voxel grid):

- statistical (``statistical_outliers``): for each point the mean distance to its
  ``k`` nearest neighbours, the point itself included as Open3D's KNN search returns it
  (so k = 8 means the point and 7 others); a point is an outlier when that mean exceeds
  mean + std_ratio * std over all points (population standard deviation), as in
  Open3D's ``remove_statistical_outlier``.
- radius (``radius_outliers``): a point survives with at least ``n`` other points
  within ``radius`` (the point itself not counted), which is what Open3D's
  ``remove_radius_outlier(nb_points=n)`` does (checked against it in the tests).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from survey.errors import PreprocessError


def _check_points(p, name="points"):
    p = np.asarray(p, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.isfinite(p).all():
        raise PreprocessError(f"Expected finite `{name}` of shape (n, 3), got {p.shape}.")
    if len(p) == 0:
        raise PreprocessError(f"Expected a non-empty cloud, got 0 points in `{name}`.")
    return p


class VoxelGrid:
    """Streaming voxel-grid accumulator.

    ``VoxelGrid(size, min_bound)``, then ``add(points)`` per chunk, then ``result()``
    -> (m, 3) centroids and (m,) counts. ``min_bound`` is the cloud's minimum (the grid
    anchor is min_bound - size / 2).
    """

    #: Bits per axis in the packed voxel key (2 cm voxels: 42 km per axis).
    BITS = 21

    def __init__(self, size: float, min_bound):
        size = float(size)
        if not (np.isfinite(size) and size > 0):
            raise PreprocessError(f"Expected a positive voxel size, got {size}.")
        self.size = size
        self.anchor = np.asarray(min_bound, dtype=np.float64) - size / 2
        self._keys = np.empty(0, dtype=np.int64)
        self._sums = np.empty((0, 3))
        self._counts = np.empty(0, dtype=np.int64)
        self._pending = []
        self._pending_n = 0

    def add(self, points):
        p = np.asarray(points, dtype=np.float64)
        if len(p) == 0:
            return
        local = p - self.anchor
        idx = np.floor(local / self.size).astype(np.int64)
        if (idx < 0).any() or (idx >= 1 << self.BITS).any():
            raise PreprocessError(f"Expected points within the bounds given to the voxel "
                                  f"grid, got one outside; pass the cloud's true minimum "
                                  f"bound (or the extent exceeds {(1 << self.BITS) * self.size:.0f} m).")
        key = (idx[:, 0] << (2 * self.BITS)) | (idx[:, 1] << self.BITS) | idx[:, 2]
        u, inv = np.unique(key, return_inverse=True)
        sums = np.stack([np.bincount(inv, weights=local[:, k], minlength=len(u))
                         for k in range(3)], 1)
        self._pending.append((u, sums, np.bincount(inv, minlength=len(u))))
        self._pending_n += len(u)
        if self._pending_n > max(1 << 22, len(self._keys)):
            self._merge()

    def _merge(self):
        if not self._pending:
            return
        keys = np.concatenate([self._keys] + [k for k, _, _ in self._pending])
        sums = np.concatenate([self._sums] + [s for _, s, _ in self._pending])
        counts = np.concatenate([self._counts] + [c for _, _, c in self._pending])
        u, inv = np.unique(keys, return_inverse=True)
        self._sums = np.stack([np.bincount(inv, weights=sums[:, k], minlength=len(u))
                               for k in range(3)], 1)
        self._counts = np.bincount(inv, weights=counts, minlength=len(u)).astype(np.int64)
        self._keys = u
        self._pending = []
        self._pending_n = 0

    def result(self):
        """(centroids (m, 3) float64 world, counts (m,) int64), ordered by voxel key."""
        self._merge()
        return self._sums / self._counts[:, None] + self.anchor, self._counts.copy()


def voxel_down_sample(points, size: float):
    """Centroid per voxel (Open3D semantics, see module doc); returns (m, 3)."""
    p = _check_points(points)
    g = VoxelGrid(size, p.min(axis=0))
    g.add(p)
    return g.result()[0]


def statistical_outliers(points, k: int = 8, std_ratio: float = 2.0):
    """Boolean mask (n,) of the statistical outliers (see module doc)."""
    p = _check_points(points)
    k = int(k)
    if k < 2:
        raise PreprocessError(f"Expected k >= 2 neighbours (the point included), got {k}.")
    if not (np.isfinite(std_ratio) and std_ratio > 0):
        raise PreprocessError(f"Expected a positive std_ratio, got {std_ratio}.")
    local = p - p.min(axis=0)
    d, _ = cKDTree(local).query(local, k=min(k, len(p)), workers=-1)
    mean = d.mean(axis=1)
    thr = mean.mean() + std_ratio * mean.std()
    return mean > thr


def radius_outliers(points, n: int = 4, radius: float = 0.05):
    """Boolean mask of points with fewer than ``n`` other points within ``radius``."""
    p = _check_points(points)
    if not (np.isfinite(radius) and radius > 0) or int(n) < 1:
        raise PreprocessError(f"Expected n >= 1 and a positive radius, got {n}, {radius}.")
    local = p - p.min(axis=0)
    tree = cKDTree(local)
    counts = tree.query_ball_point(local, radius, return_length=True, workers=-1)
    return counts - 1 < int(n)          # the query point is in its own ball
