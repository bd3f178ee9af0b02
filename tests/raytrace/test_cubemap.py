"""The cube-map path for single-origin batches gives bit-identical results to the BVH."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace import RayError, Scene, config
from raytrace.shapes import icosphere, tunnel_tube


def _assert_same(a, b):
    for name in ("t", "triangle", "u", "v"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def _directions(rng, n):
    d = rng.standard_normal((n, 3))
    # Directions on cube-face borders and axes, where the face choice is a tie.
    special = np.array([[1, 1, 0], [1, -1, 0], [0, 1, 1], [1, 0, -1], [1, 1, 1], [-1, -1, -1],
                        [1, 0, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [-1, 1, 1e-17]], float)
    return np.concatenate([d, special])


@pytest.fixture(scope="module")
def tunnel():
    v, f = tunnel_tube(30_000, length_m=80.0, roughness_m=0.003, seed=2)
    return Scene(v, f), v, f


@pytest.mark.parametrize("origin", [[40.0, 0.1, 1.5], [1.0, -1.2, 0.2], [79.9, 0.0, 2.8]])
def test_station_matches_bvh(tunnel, origin):
    scene = tunnel[0]
    rng = np.random.default_rng(1)
    d = _directions(rng, 60_000)
    _assert_same(scene.cast(origin, d, method="cubemap"), scene.cast(origin, d, method="bvh"))


def test_intervals_match_bvh(tunnel):
    scene = tunnel[0]
    rng = np.random.default_rng(2)
    d = _directions(rng, 20_000)
    t_min = rng.uniform(0, 2, len(d))
    t_max = t_min + rng.uniform(0, 3, len(d))
    o = [40.0, 0.0, 1.2]
    _assert_same(scene.cast(o, d, t_min=t_min, t_max=t_max, method="cubemap"),
                 scene.cast(o, d, t_min=t_min, t_max=t_max, method="bvh"))


def test_origin_on_vertex_and_outside(tunnel):
    scene, v, _ = tunnel
    rng = np.random.default_rng(3)
    d = _directions(rng, 20_000)
    for origin in (v[1234], v[5], np.array([40.0, 30.0, 10.0]), np.array([-50.0, 0.0, 1.5])):
        _assert_same(scene.cast(origin, d, method="cubemap"),
                     scene.cast(origin, d, method="bvh"))


def test_hot_cells_fall_back_to_bvh(monkeypatch):
    """With a tiny hot-cell limit most cells use the BVH; results still agree."""
    v, f = icosphere(4)
    scene = Scene(v, f)
    d = _directions(np.random.default_rng(4), 20_000)
    ref = scene.cast([0.1, 0.2, 0.0], d, method="bvh")
    monkeypatch.setattr(config, "CUBEMAP_HOT", 1)
    scene._view_cache = None
    _assert_same(scene.cast([0.1, 0.2, 0.0], d, method="cubemap"), ref)


def test_auto_uses_cubemap_for_dense_single_origin(tunnel):
    scene = tunnel[0]
    scene._view_cache = None
    d = _directions(np.random.default_rng(5), 40_000)  # > 0.5 rays per triangle
    scene.cast([40.0, 0.0, 1.5], d)
    assert scene._view_cache is not None and scene._view_cache[1] is not None


def test_bad_method(tunnel):
    with pytest.raises(RayError, match="`method`"):
        tunnel[0].cast(np.zeros(3), np.ones((2, 3)), method="embree")
