"""Preprocessing: voxel grid against a naive reference and Open3D, streaming equals
one pass, UTM precision; outlier filters against Open3D."""

from __future__ import annotations

import numpy as np
import pytest

from survey.errors import PreprocessError
from survey.clouds.preprocess import (VoxelGrid, radius_outliers, statistical_outliers, voxel_down_sample)


def _cloud(n=20_000, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(0, 1, (n, 3))
    p[:50] *= 8                                  # a few far outliers
    return p


def _naive_voxel(p, size):
    """Dictionary of voxel -> points, the definition written out."""
    anchor = p.min(axis=0) - size / 2
    cells = {}
    for q in p:
        key = tuple(np.floor((q - anchor) / size).astype(int))
        cells.setdefault(key, []).append(q)
    return np.array([np.mean(v, axis=0) for v in cells.values()])


def _sorted(a):
    return a[np.lexsort(a.T)]


def test_voxel_grid_equals_the_naive_definition():
    p = _cloud(3000)
    np.testing.assert_allclose(_sorted(voxel_down_sample(p, 0.3)),
                               _sorted(_naive_voxel(p, 0.3)), atol=1e-12)


def test_streaming_chunks_give_the_same_voxels_and_keep_utm_precision():
    p = _cloud(50_000, seed=1) * 20 + [451_000.0, 5_352_000.0, 600.0]
    one = voxel_down_sample(p, 0.5)
    g = VoxelGrid(0.5, p.min(axis=0))
    for i in range(0, len(p), 7_777):
        g.add(p[i:i + 7_777])
    pts, counts = g.result()
    assert counts.sum() == len(p)
    np.testing.assert_allclose(pts, one, atol=1e-9, rtol=0)
    # A voxel holding one point returns that point exactly (to float64 rounding).
    single = counts == 1
    d, _ = __import__("scipy.spatial", fromlist=["cKDTree"]).cKDTree(p).query(pts[single])
    assert d.max() < 1e-9


def test_voxel_grid_matches_open3d():
    o3d = pytest.importorskip("open3d", reason="Open3D is an optional cross-check")
    p = _cloud()
    ref = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
                     .voxel_down_sample(0.1).points)
    np.testing.assert_allclose(_sorted(voxel_down_sample(p, 0.1)), _sorted(ref), atol=1e-12)


@pytest.mark.parametrize("k, ratio", [(8, 2.0), (20, 1.0)])
def test_statistical_filter_matches_open3d(k, ratio):
    o3d = pytest.importorskip("open3d", reason="Open3D is an optional cross-check")
    p = _cloud()
    _, ind = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).remove_statistical_outlier(
        nb_neighbors=k, std_ratio=ratio)
    keep = np.zeros(len(p), bool)
    keep[ind] = True
    np.testing.assert_array_equal(~statistical_outliers(p, k=k, std_ratio=ratio), keep)


@pytest.mark.parametrize("n, r", [(2, 0.2), (5, 0.2), (9, 0.3)])
def test_radius_filter_matches_open3d(n, r):
    o3d = pytest.importorskip("open3d", reason="Open3D is an optional cross-check")
    p = _cloud()
    _, ind = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).remove_radius_outlier(
        nb_points=n, radius=r)
    keep = np.zeros(len(p), bool)
    keep[ind] = True
    np.testing.assert_array_equal(~radius_outliers(p, min_neighbours=n, radius_m=r), keep)


def test_filters_against_brute_force():
    """Without Open3D: the definitions by brute force on a small cloud."""
    p = _cloud(400, seed=3)
    d = np.linalg.norm(p[:, None] - p[None], axis=2)
    srt = np.sort(d, axis=1)
    mean = srt[:, :8].mean(axis=1)                       # itself (0) + 7 others
    np.testing.assert_array_equal(statistical_outliers(p, k=8, std_ratio=2.0),
                                  mean > mean.mean() + 2.0 * mean.std())
    np.testing.assert_array_equal(radius_outliers(p, min_neighbours=3, radius_m=0.5), (d <= 0.5).sum(axis=1) - 1 < 3)


def test_bad_input():
    with pytest.raises(PreprocessError, match="non-empty"):
        voxel_down_sample(np.empty((0, 3)), 0.1)
    with pytest.raises(PreprocessError, match="positive voxel size"):
        voxel_down_sample(_cloud(10), 0.0)
    with pytest.raises(PreprocessError, match="shape"):
        statistical_outliers(np.zeros((5, 2)))
    g = VoxelGrid(0.1, [0.0, 0.0, 0.0])
    with pytest.raises(PreprocessError, match="bounds"):
        g.add(np.array([[-5.0, 0.0, 0.0]]))
