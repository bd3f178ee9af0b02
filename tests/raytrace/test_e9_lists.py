"""Cube-map and near-map lists tested four entries at a time (``intersect.mt4_gather``),
and the BVH walk of a ray beyond a near map's radius starting at that radius
(``cubemap._view_block``). Every answer must stay the BVH's bit for bit (t, triangle, u,
v), ties to the lower input index included."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numba import njit

from raytrace import Scene
from raytrace._kernels.intersect import GROUP as LIST_GROUP
from raytrace._kernels.intersect import moller_trumbore, mt4_gather, mt4_gather_scalar
from raytrace.scene import _turn_to_x
from raytrace.shapes import icosphere
from tests.naive import naive_cast
from tests.raytrace.cpu import (cone_rays, generic_and_host_groups, near_budget, needs_avx2,
                                soup_scene)

FIELDS = ("t", "triangle", "u", "v")

_SPECIAL = st.sampled_from([0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, np.nan, 1e-300, 1e300])
_COORD = st.one_of(st.floats(-4.0, 4.0, width=64), _SPECIAL)
_DIR = st.one_of(st.floats(-1.0, 1.0, width=64), st.sampled_from([0.0, -0.0]))


@njit(error_model="numpy")
def _gather(tris, slots, e, n, o, d):
    return mt4_gather(tris, slots, e, n, o[0], o[1], o[2], d[0], d[1], d[2])


def _bits(x):
    """Bit patterns, every NaN as one pattern (which NaN comes out is not part of the
    result: a NaN t never passes ``closer``)."""
    a = np.array(x, dtype=np.float64)
    a[np.isnan(a)] = np.nan
    return a.view(np.int64).tolist()


def _assert_same(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if x.dtype.kind == "f":
            assert _bits(x) == _bits(y), name
        else:
            np.testing.assert_array_equal(x, y, err_msg=name)


@settings(max_examples=400, deadline=None)
@given(tris=arrays(np.float64, (6, 9), elements=_COORD),
       slots=arrays(np.int32, 9, elements=st.integers(0, 5)), e=st.integers(0, 5),
       n=st.integers(1, LIST_GROUP), o=arrays(np.float64, 3, elements=_COORD),
       d=arrays(np.float64, 3, elements=_DIR))
def test_mt4_gather_is_moller_trumbore_lane_by_lane(tris, slots, e, n, o, d):
    """Any float64 rows (NaN, inf, 1e+-300), any slot order with repeats, zero direction
    components: lane l < n is ``moller_trumbore`` of slots[e + l] to the bit, the mask
    says which lanes hit, lanes >= n report a miss; the scalar twin agrees."""
    n = min(n, slots.shape[0] - e)
    got = _gather(tris, slots, e, n, o, d)
    mask = 0
    for lane in range(LIST_GROUP):
        if lane < n:
            t, u, v = moller_trumbore(tris, slots[e + lane], *o, *d)
            if not np.isnan(t):
                mask |= 1 << lane
        else:
            t, u, v = np.nan, 0.0, 0.0
        assert _bits([got[1][lane], got[2][lane], got[3][lane]]) == _bits([t, u, v])
    assert got[0] == mask
    twin = mt4_gather_scalar(tris, slots, e, n, *o, *d)
    assert twin[0] == got[0]
    for x, y in zip(twin[1:], got[1:]):
        assert _bits(x) == _bits(y)


@needs_avx2
def test_mt4_gather_compiles_to_packed_double_instructions():
    """The four list entries must be tested as packed float64 arithmetic on 256-bit (or
    wider) registers, not lane by lane."""
    tris = np.ones((4, 9))
    slots = np.array([3, 0, 2, 1], dtype=np.int32)
    _gather(tris, slots, 0, 4, np.zeros(3), np.ones(3))
    asm = _gather.inspect_asm(_gather.signatures[0])
    assert re.search(r"\bvmulpd\b[^\n]*%[yz]mm", asm), "no packed vmulpd"
    assert re.search(r"\bvdivpd\b[^\n]*%[yz]mm", asm), "no packed vdivpd"
    assert re.search(r"\bvcmp\w*pd\b[^\n]*%[yz]mm", asm), "no packed vcmppd"


def test_generic_cpu_gives_the_same_list_groups(tmp_path):
    """``NUMBA_CPU_NAME=generic`` (no AVX: LLVM splits the vectors) in a subprocess
    agrees bit for bit with this process."""
    generic, host = generic_and_host_groups(tmp_path, gather=True)
    assert 0 < sum(m != 0 for m in host["mask"]) < len(host["mask"])  # mixed hits/misses
    assert generic == host


def _camera_rays(width, height, hfov_deg, forward):
    """Pinhole pixel-centre directions in image (row-major) order along ``forward``."""
    rot = _turn_to_x(*(np.asarray(forward, float) / np.linalg.norm(forward)))
    t = np.tan(np.deg2rad(hfov_deg) / 2)
    x = ((np.arange(width) + 0.5) / width * 2 - 1) * t
    y = ((np.arange(height) + 0.5) / height * 2 - 1) * t * height / width
    xx, yy = np.meshgrid(x, y)
    d = np.stack([np.ones(xx.size), xx.ravel(), yy.ravel()], axis=1) @ rot
    return d / np.linalg.norm(d, axis=1)[:, None]


def _assert_brute_force(got, v, f, o, d, t_min=0.0, t_max=np.inf):
    """``got`` agrees with ``tests/naive.py`` (world frame, its own rounding) on every ray
    that does not graze an edge: the same triangle (ties: the lower index), t to 1e-9."""
    t_min = np.broadcast_to(np.asarray(t_min, float), (len(d),))
    t_max = np.broadcast_to(np.asarray(t_max, float), (len(d),))
    for lo, hi in set(zip(t_min.tolist(), t_max.tolist())):
        rows = np.flatnonzero((t_min == lo) & (t_max == hi))
        t, tri, _, _, margin = naive_cast(v, f, o[None], d[rows], lo, hi)
        clear = margin > 1e-6
        np.testing.assert_array_equal(got.triangle[rows][clear], tri[clear])
        np.testing.assert_allclose(got.t[rows][clear], t[clear], rtol=1e-9, atol=1e-12)


def _near(scene, o, d, k, **limits):
    """``method="near"`` with k triangles gathered (a finite radius below the mesh's)."""
    with near_budget(k):
        return scene.cast(o, d, method="near", **limits)


coord = st.floats(-6.0, 6.0, allow_nan=False, allow_infinity=False, width=64)


@st.composite
def soups(draw):
    """A triangle soup with some triangles repeated (exact ties at equal t; the copy
    gets the higher input index), an origin, and a bundle of directions: a camera-like
    cone (one turned face), a wide cone or the full sphere."""
    n_tri = draw(st.integers(1, 50))
    v = draw(arrays(np.float64, (3 * n_tri, 3), elements=coord))
    f = np.arange(3 * n_tri).reshape(n_tri, 3)
    dup = draw(st.lists(st.integers(0, n_tri - 1), max_size=n_tri))
    f = np.concatenate([f, f[dup]]) if dup else f
    if draw(st.booleans()):  # copies first: a lower input index for the copy's twin
        f = f[::-1].copy()
    o = draw(arrays(np.float64, (3,), elements=coord))
    axis = draw(arrays(np.float64, (3,), elements=st.floats(-1, 1, width=64)))
    half = draw(st.sampled_from([0.0, 0.2, 0.6, 0.76, 1.2, np.pi]))
    k = draw(st.integers(0, f.shape[0]))
    limits = draw(st.sampled_from(["none", "scalar", "per_ray"]))
    seed = draw(st.integers(0, 2**31))
    return v, f, o, axis, half, k, limits, seed


_TINY = 5.16714748e-123
#: Found by hypothesis in CI: the rays leave the shared vertex (~1e-123) of a face, so
#: brute force sees it at t = -1e-122 (a miss) where the engine sees +1e-122; a graze
#: at t_min, which ``naive_cast``'s margin now counts.
_VERTEX_ORIGIN = (np.array([[-2.0, _TINY, _TINY], [_TINY] * 3, [_TINY] * 3,
                            [_TINY, 1.0, _TINY], [_TINY] * 3, [_TINY, _TINY, 1.0]]),
                  np.array([[0, 1, 2], [3, 4, 5]]), np.zeros(3), np.ones(3), 0.0, 0,
                  "none", 0)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(soups())
@example(_VERTEX_ORIGIN)
def test_near_and_whole_maps_equal_the_bvh(case):
    """Near maps (any number of gathered triangles, so rays on both sides of the
    radius) and the whole cube map give the BVH's answers bit for bit, with and without
    [t_min, t_max] limits, duplicated triangles included; brute force agrees on t."""
    v, f, o, axis, half, k, limits, seed = case
    if np.linalg.norm(axis) < 1e-3:
        return
    rng = np.random.default_rng(seed)
    n = 60
    if half >= np.pi:
        d = rng.standard_normal((n, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
    else:
        d = cone_rays(rng, n, axis, half)
    # Some rays aimed at vertices: hits on shared vertices and edges, exact ties.
    d[:10] = v[rng.integers(0, len(v), 10)] - o
    keep = np.linalg.norm(d, axis=1) > 1e-9
    d = d[keep]
    kw = {}
    if limits == "scalar":
        kw = dict(t_min=float(rng.uniform(0, 3)), t_max=float(rng.uniform(3, 12)))
    elif limits == "per_ray":
        t_min = rng.uniform(0, 4, len(d))
        kw = dict(t_min=t_min, t_max=t_min + rng.uniform(0, 8, len(d)))
    scene = soup_scene(v, f)
    if scene is None:
        return
    ref = scene.cast(o, d, method="bvh", **kw)
    _assert_same(_near(scene, o, d, k, **kw), ref)
    _assert_same(scene.cast(o, d, method="cubemap", **kw), ref)
    _assert_brute_force(ref, v, f, o, d, **kw)


@pytest.mark.parametrize("k", [16, 200, 100_000])
def test_closed_mesh_has_no_misses(k):
    """From inside a closed, shifted icosphere: a 64 x 48 camera frame (one turned face)
    and the full sphere (six faces), with few or all triangles
    gathered, and the whole map: every ray hits, and the answers are the BVH's."""
    v, f = icosphere(3, radius=2.0)
    v = v + [0.3, -0.2, 0.1]
    scene = Scene(v, f)
    o = np.array([0.5, 0.1, -0.3])
    rng = np.random.default_rng(k)
    for d in (_camera_rays(64, 48, 69.0, [1.0, 0.3, -0.2]), rng.standard_normal((3000, 3))):
        ref = scene.cast(o, d, method="bvh")
        assert ref.hit.all()
        near = _near(scene, o, d, k)
        assert near.hit.all()
        _assert_same(near, ref)
        _assert_same(scene.cast(o, d, method="cubemap"), ref)


def _wall_of_twins(rng, n_side=12):
    """A wall of triangles at x = 3 in front of the origin, every triangle twice:
    slot order (the lists' order) is the BVH's leaf order, the input order shuffled."""
    side = np.linspace(-1.5, 1.5, n_side + 1)
    ys, zs = np.meshgrid(side, side)
    pts = np.stack([np.full(ys.size, 3.0), ys.ravel(), zs.ravel()], axis=1)
    idx = np.arange(pts.shape[0]).reshape(n_side + 1, n_side + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, e = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, e], 1), np.stack([a, e, c], 1)])
    faces = np.concatenate([faces, faces])
    return pts, faces[rng.permutation(len(faces))]


@pytest.mark.parametrize("method", ["near", "cubemap"])
def test_equal_t_goes_to_the_lower_index_listed_later(method):
    """Two copies of a triangle in one cell, the copy with the LOWER input index listed
    after the other (checked below on the map itself): the ray through the triangle
    takes the lower index, as brute force and the BVH do (a test that kept the first
    of equal t fails here)."""
    rng = np.random.default_rng(7)
    v, f = _wall_of_twins(rng)
    scene = Scene(v, f)
    o = np.zeros(3)
    centroids = v[f].mean(axis=1)
    d = centroids - o
    local = (o - scene.origin_offset)[None]
    unit = d / np.linalg.norm(d, axis=1)[:, None]
    if method == "near":
        view = scene._near_view(local, unit)
    else:
        view = scene._map(local, None, scene._map_side())
    start, slots, counts = view[0], view[1], view[2]
    ids = scene._ids
    # The precondition: some cell lists twins with the higher input index first.
    twin_of = {}
    for i, row in enumerate(map(tuple, np.sort(f, axis=1))):
        twin_of.setdefault(row, []).append(i)
    lower = {max(p): min(p) for p in twin_of.values() if len(p) == 2}
    tripped = 0
    for c in range(len(counts)):
        listed = ids[slots[start[c]:start[c + 1]]].tolist()
        for pos, tri in enumerate(listed):
            if tri in lower and lower[tri] in listed[pos + 1:]:
                tripped += 1
    assert tripped > 0
    got = scene.cast(o, d, method=method) if method == "cubemap" else _near(
        scene, o, d, 100_000)
    ref = scene.cast(o, d, method="bvh")
    _assert_same(got, ref)
    _assert_brute_force(got, v, f, o, d)
    key = np.sort(f[got.triangle], axis=1)
    assert all(got.triangle[i] == min(twin_of[tuple(key[i])]) for i in range(len(d)))


def test_walk_beyond_the_radius_starts_there_and_keeps_ties():
    """Rays whose hit lies beyond the near map's radius walk the BVH over [max(t_min,
    radius), t_max]: with twins behind the radius (ties) and t_min below and above the
    radius, the answers are the BVH's and brute force's (a walk started beyond the
    radius fails here)."""
    rng = np.random.default_rng(3)
    near_v, near_f = _wall_of_twins(rng, 6)
    near_v = near_v * [1.0, 0.3, 0.3]  # a small wall at x = 3 in the middle of the view
    far_v, far_f = _wall_of_twins(rng, 10)
    far_v = far_v * [3.0, 2.0, 2.0]  # a wide wall at x = 9 behind it
    v = np.concatenate([near_v, far_v])
    f = np.concatenate([near_f, far_f + len(near_v)])
    f = f[rng.permutation(len(f))]
    scene = Scene(v, f)
    o = np.zeros(3)
    d = _camera_rays(80, 60, 90.0, [1.0, 0.0, 0.0])
    k = 2 * len(near_f)
    local = (o - scene.origin_offset)[None]
    with near_budget(k):
        radius = scene._near_view(local, d)[-1]
    assert np.isfinite(radius)
    t_min = np.where(np.arange(len(d)) % 3 == 0, rng.uniform(radius, 10.0, len(d)),
                     rng.uniform(0.0, radius, len(d)))
    for kw in ({}, dict(t_min=t_min, t_max=t_min + rng.uniform(0, 6, len(d)))):
        ref = scene.cast(o, d, method="bvh", **kw)
        assert (ref.t[ref.hit] > radius).any() and (ref.t[ref.hit] < radius).any()
        got = _near(scene, o, d, k, **kw)
        _assert_same(got, ref)
        _assert_brute_force(got, v, f, o, d, **kw)
