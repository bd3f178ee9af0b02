"""Near maps (``raytrace/_kernels/nearmap.py``): a cube map of only the triangles nearest
to a shared origin inside the cone of the rays (a camera frame). The answers are the
BVH's bit for bit and the brute force's; the gathered set is what its radius promises."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from raytrace import Scene, config
from raytrace._kernels.nearmap import gather_near, ray_cone
from raytrace.scene import _turn_to_x
from raytrace.shapes import tunnel_tube
from tests.naive import naive_cast
from tests.raytrace.cpu import cone_rays, near_budget, soup_scene

FIELDS = ("t", "triangle", "u", "v")


def _assert_same(a, b):
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def _camera_rays(width, height, hfov_deg, forward, up=(0.0, 0.0, 1.0)):
    """Pinhole pixel-centre directions, row by row, looking along ``forward``."""
    f = np.asarray(forward, float) / np.linalg.norm(forward)
    right = np.cross(f, up)
    right /= np.linalg.norm(right)
    down = np.cross(f, right)
    t = np.tan(np.deg2rad(hfov_deg) / 2)
    x = (np.arange(width) + 0.5) / width * 2 - 1
    y = ((np.arange(height) + 0.5) / height * 2 - 1) * height / width
    xx, yy = np.meshgrid(x * t, y * t)
    d = f + xx.reshape(-1, 1) * right + yy.reshape(-1, 1) * down
    return d / np.linalg.norm(d, axis=1)[:, None]


@pytest.fixture(scope="module")
def tunnel():
    v, f = tunnel_tube(40_000, length_m=80.0, roughness_m=0.003, seed=5)
    return Scene(v, f), v, f


@pytest.mark.parametrize("per_ray", [0.002, 0.02, 0.5])
def test_camera_frame_matches_bvh(tunnel, monkeypatch, per_ray):
    """A 160 x 120 camera looking down the tunnel: with few gathered triangles most rays
    reach beyond the radius (the BVH answers them), with many most are answered by the
    map; both, and the hits exactly at the radius, equal the BVH's answer."""
    scene = tunnel[0]
    monkeypatch.setattr(config, "NEARMAP_TRIS_PER_RAY", per_ray)
    monkeypatch.setattr(config, "NEARMAP_MIN_TRIS", 16)
    origin = np.array([20.0, 0.3, 1.5])
    d = _camera_rays(160, 120, 69.0, [1.0, 0.05, -0.1])
    ref = scene.cast(origin, d, method="bvh")
    near = scene.cast(origin, d, method="near")
    _assert_same(near, ref)
    # The paths taken: beyond the radius the BVH, nearer the map (both at 0.02).
    radius = scene._near_view((origin - scene.origin_offset)[None], d)[-1]
    if per_ray < 0.5:
        assert (ref.t > radius).any()
    if per_ray > 0.002:
        assert (ref.t < radius).any()
    # Limits per ray, some intervals wholly inside the radius (misses answered there).
    rng = np.random.default_rng(0)
    t_min = rng.uniform(0, 3, len(d))
    t_max = t_min + rng.uniform(0, 6, len(d))
    _assert_same(scene.cast(origin, d, t_min=t_min, t_max=t_max, method="near"),
                 scene.cast(origin, d, t_min=t_min, t_max=t_max, method="bvh"))


@pytest.mark.parametrize("half_angle_deg", [0.01, 10.0, 43.9, 44.1, 80.0, 150.0, 180.0])
def test_cones_of_every_width_match_bvh(tunnel, monkeypatch, half_angle_deg):
    """Narrow cones use one turned face, wide ones all six (the switch at 44 deg): the
    same answers, origin inside the tunnel and outside it."""
    scene = tunnel[0]
    monkeypatch.setattr(config, "NEARMAP_TRIS_PER_RAY", 0.3)
    rng = np.random.default_rng(int(half_angle_deg * 100))
    for origin, axis in (([40.0, 0.0, 1.2], [1.0, 0.2, 0.1]),
                         ([40.0, 0.0, 1.2], [0.0, 0.0, -1.0]),
                         ([40.0, 30.0, 10.0], [0.0, -1.0, -0.2])):
        d = cone_rays(rng, 6000, axis, np.deg2rad(min(half_angle_deg, 179.9)))
        if half_angle_deg == 180.0:
            d = rng.standard_normal((6000, 3))
        _assert_same(scene.cast(origin, d, method="near"),
                     scene.cast(origin, d, method="bvh"))


def test_auto_takes_the_near_map_for_a_frame(tunnel, monkeypatch):
    """``auto`` maps a single-origin batch below the whole-map threshold (0.5 rays a
    triangle) but above NEARMAP_MIN_RUN with a near map; below it, the BVH; and a
    short batch from the origin whose whole map is kept uses that map."""
    scene = tunnel[0]
    monkeypatch.setattr(config, "NEARMAP_MIN_RUN", 4096)
    calls = []
    original = Scene._near_view

    def spy(self, *args):
        calls.append(len(args[1]))
        return original(self, *args)

    monkeypatch.setattr(Scene, "_near_view", spy)
    d = _camera_rays(128, 96, 69.0, [1.0, 0.0, 0.0])  # 12,288 rays, 0.3 a triangle
    origin = [30.0, 0.0, 1.5]
    _assert_same(scene.cast(origin, d), scene.cast(origin, d, method="bvh"))
    assert calls == [len(d)]
    scene.cast(origin, d[:config.NEARMAP_MIN_RUN - 1])
    assert calls == [len(d)]
    # An (n, 3) array of equal rows is the same batch.
    scene.cast(np.repeat(np.asarray(origin, float)[None], len(d), axis=0), d)
    assert calls == [len(d), len(d)]
    # Once the whole map of this origin is kept, a short batch from it uses that map.
    scene._view_cache = None
    scene.cast(origin, _camera_rays(256, 96, 69.0, [1.0, 0.0, 0.0]))  # 0.6 a triangle
    assert scene._has_view((np.asarray(origin, float) - scene.origin_offset)[None])
    _assert_same(scene.cast(origin, d), scene.cast(origin, d, method="bvh"))
    assert calls == [len(d), len(d)]


coord = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False, width=64)


@st.composite
def soup_and_cone(draw):
    n_tri = draw(st.integers(1, 60))
    v = draw(arrays(np.float64, (3 * n_tri, 3), elements=coord))
    f = np.arange(3 * n_tri).reshape(n_tri, 3)
    o = draw(arrays(np.float64, (3,), elements=coord))
    axis = draw(arrays(np.float64, (3,), elements=st.floats(-1, 1, width=64)))
    half = draw(st.sampled_from([0.0, 1e-3, 0.3, 0.76, 1.2, 3.0]))
    k = draw(st.integers(0, 3 * n_tri))
    seed = draw(st.integers(0, 2**31))
    return v, f, o, axis, half, k, seed


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(soup_and_cone())
def test_near_map_matches_brute_force(case):
    """Random soups, cones of every width, any number of gathered triangles: the near
    map's answer is the BVH's, and no triangle left out of the gathered set has a
    brute-force hit nearer than the radius."""
    v, f, o, axis, half, k, seed = case
    if np.linalg.norm(axis) < 1e-3:
        return
    rng = np.random.default_rng(seed)
    d = cone_rays(rng, 40, axis, half)
    scene = soup_scene(v, f)
    if scene is None:
        return
    with near_budget(k):
        near = scene.cast(o, d, method="near")
    # Bit for bit the BVH's answer (which tests/raytrace/test_against_naive.py holds to
    # the brute force, rounding-level ties and grazing rays aside).
    _assert_same(near, scene.cast(o, d, method="bvh"))
    # The gathered set keeps its promise, by brute force over the triangles left out.
    local = (o - scene.origin_offset)
    ax, ay, az, c = ray_cone(d)
    sel = np.empty(scene.n_triangles, dtype=np.int32)
    count, radius = gather_near(scene._nodes, scene._nodes.view(np.int32), *local,
                                ax, ay, az, c, k, sel)
    assert count >= min(k, 1) or radius == np.inf
    left_out = np.setdiff1d(np.arange(scene.n_triangles), sel[:count])
    if left_out.size:
        tri = scene._tris[left_out]
        v0 = tri[:, 0:3] + scene.origin_offset
        vv = np.concatenate([v0, v0 + tri[:, 3:6], v0 + tri[:, 6:9]], axis=1).reshape(-1, 3)
        t, hit_tri, *_ = naive_cast(vv, np.arange(len(vv)).reshape(-1, 3), o[None], d)
        assert (t[hit_tri >= 0] >= radius).all()


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, (25, 3), elements=st.floats(-1, 1, width=64)))
def test_ray_cone_holds_every_direction(d):
    """Every direction lies within the returned cone (axis unit, half-angle's cosine)."""
    norm = np.linalg.norm(d, axis=1)
    d = d[norm > 1e-3] / norm[norm > 1e-3, None]
    if len(d) == 0:
        return
    ax, ay, az, c = ray_cone(d)
    a = np.array([ax, ay, az])
    assert abs(np.linalg.norm(a) - 1.0) < 1e-12
    assert (d @ a >= c - 1e-12).all()
    rot = _turn_to_x(ax, ay, az)
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rot @ a, [1.0, 0.0, 0.0], atol=1e-12)
    assert np.linalg.det(rot) > 0
