"""Issue 33: ``Scene.cast`` leaves (n, 3) directions to the traversal to normalise and
shifts the origins in one fused pass (``checks.prepare_cast``, ``_kernels/rays.py``).
Every answer must be bit for bit that of the previous path: directions normalised by
``prepare_rays`` into a unit array, origins shifted by NumPy, ``traverse.closest_hit``
on unit vectors. The reference below is that path, spelled out with NumPy arithmetic."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import RayError, Scene, config
from raytrace._kernels.rays import count_bad_directions, shift_origins, unit_directions
from raytrace._kernels.traverse import closest_hit
from raytrace.checks import prepare_cast, prepare_rays
from raytrace.shapes import tunnel_tube


def _bits(a):
    """The float64 (or int64) array as raw 64-bit words: equal means bit-identical."""
    return np.ascontiguousarray(a).view(np.uint64)


def _numpy_unit(d):
    """d / |d| with NumPy's arithmetic: length sqrt(x x + y y + z z), one division."""
    length = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])
    return d / length[:, None]


def _reference(scene, o, d, t_min=0.0, t_max=np.inf):
    """The previous path: unit directions written first, NumPy's origin shift, the
    traversal on unit vectors in input order."""
    o = np.atleast_2d(np.asarray(o, dtype=np.float64))
    d = np.asarray(d, dtype=np.float64)
    n = d.shape[0]
    unit = _numpy_unit(d)
    local = np.ascontiguousarray(o - scene.origin_offset)
    tmin = np.broadcast_to(np.asarray(t_min, dtype=np.float64).reshape(-1), (n,)).copy()
    tmax = np.broadcast_to(np.asarray(t_max, dtype=np.float64).reshape(-1), (n,)).copy()
    out = (np.empty(n), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64),
           np.empty(n), np.empty(n))
    closest_hit(scene._nodes, scene._nodes.view(np.int32), scene._tris, scene._ids,
                local, unit, tmin, tmax, scene._stack_size, np.empty(0, dtype=np.int64),
                *out, True, 2, np.zeros(1, dtype=np.int64))
    t, _, tri, u, v = out
    return t, tri, u, v, unit


@pytest.fixture(scope="module")
def tube():
    return Scene(*tunnel_tube(20_000, length_m=40.0, roughness_m=0.01, seed=3))


_coord = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
_comp = st.one_of(st.just(0.0), st.just(-0.0), st.floats(-1.0, 1.0, allow_nan=False))


@settings(max_examples=40, deadline=None)
@given(st.integers(65, 400), st.integers(-150, 150), st.integers(0, 2**32 - 1),
       st.lists(st.tuples(_comp, _comp, _comp), min_size=1, max_size=8))
def test_cast_with_raw_directions_is_bit_identical(tube, n, exp, seed, extra):
    """Random rays (zero components, directions scaled by 10^-150 .. 10^150, origins
    inside and outside the tube) give the reference's t, triangle, u, v, directions
    and points, bit for bit."""
    rng = np.random.default_rng(seed)
    o = np.stack([rng.uniform(-5, 45, n), rng.uniform(-2, 2, n), rng.uniform(-2, 2, n)],
                 axis=1)
    d = rng.standard_normal((n, 3))
    d[rng.random((n, 3)) < 0.15] = 0.0           # axis-parallel rays
    for i, row in enumerate(extra):
        if any(row):
            d[i] = row
    d[(d == 0.0).all(axis=1)] = (0.0, 0.0, 1.0)
    d *= 10.0 ** exp
    if not np.isfinite(np.sqrt((d * d).sum(axis=1))).all() or \
            ((d * d).sum(axis=1) == 0.0).any():
        # The length overflows or underflows: both paths refuse or keep such rows alike;
        # covered by test_bad_direction_counts_agree below.
        return
    _, local, raw, unit, _, _ = prepare_cast(o, d, 0.0, np.inf, tube.origin_offset)
    assert not unit and raw.shape == d.shape
    h = tube.cast(o, d)
    t, tri, u, v, unit_ref = _reference(tube, o, d)
    for got, want in ((h.t, t), (h.triangle, tri), (h.u, u), (h.v, v),
                      (h.directions, unit_ref)):
        np.testing.assert_array_equal(_bits(got), _bits(want))
    with np.errstate(invalid="ignore"):
        p = o + t[:, None] * unit_ref
    p[tri < 0] = np.nan
    np.testing.assert_array_equal(_bits(h.points), _bits(p))
    assert h.hit.any()


def test_directions_match_prepare_rays_and_shared_paths(tube):
    """The lazily normalised directions are ``prepare_rays``' unit array, bit for bit;
    a (3,) direction, a short batch and the cube-map path still get unit vectors."""
    rng = np.random.default_rng(1)
    n = 5000
    o = np.tile([20.0, 0.1, 0.2], (n, 1)) + rng.uniform(-0.3, 0.3, (n, 3))
    d = rng.standard_normal((n, 3)) * 7.0
    _, unit, _, _ = prepare_rays(o, d, 0.0, np.inf)
    h = tube.cast(o, d)
    np.testing.assert_array_equal(_bits(h.directions), _bits(unit))
    nrm = h.normals
    cos = np.abs(np.einsum("ij,ij->i", unit, nrm))
    sin = np.linalg.norm(np.cross(unit, nrm), axis=1)
    np.testing.assert_array_equal(_bits(h.incidence_rad), _bits(np.arctan2(sin, cos)))
    # One origin repeated (the cube-map path) and a single shared origin agree.
    same = np.tile([20.0, 0.1, 0.2], (n, 1))
    a = tube.cast(same, d, method="cubemap")
    b = tube.cast(same[0], d, method="bvh")
    for name in ("t", "triangle", "u", "v"):
        np.testing.assert_array_equal(_bits(getattr(a, name)), _bits(getattr(b, name)))
    np.testing.assert_array_equal(_bits(a.directions), _bits(unit))


def test_shift_origins_is_numpy_subtraction():
    """The fused shift writes NumPy's o - offset bit for bit and counts bad rows."""
    rng = np.random.default_rng(2)
    o = rng.standard_normal((1000, 3)) * np.array([1e6, 1e-3, 5e6]) + 4.5e5
    o[3, 1] = np.nan
    o[10, 2] = -np.inf
    o[11] = (1e308, -1e308, 0.0)
    offset = np.array([450123.0, -7.0, 5.4e6])
    out = np.empty_like(o)
    assert shift_origins(o, offset, out) == 2
    np.testing.assert_array_equal(_bits(out), _bits(o - offset))


def test_bad_direction_counts_agree():
    """``count_bad_directions`` counts exactly the rows ``unit_directions`` counts:
    NaN, inf, zero, and lengths that underflow to zero (1e-200); a length that
    overflows (1e200) is finite input and is not refused by either."""
    d = np.ones((200, 3))
    d[0] = (0.0, 0.0, 0.0)
    d[1] = (np.nan, 1.0, 0.0)
    d[2] = (0.0, np.inf, 0.0)
    d[3] = (1e-200, 0.0, 0.0)
    d[4] = (1e200, 1e200, 0.0)
    d[5] = (-0.0, 0.0, 1e-300)
    d[6] = (5e-324, 0.0, 0.0)
    out = np.empty_like(d)
    assert count_bad_directions(d) == unit_directions(d, out) == 6


@pytest.mark.parametrize("row, message", [
    ((0.0, 0.0, 0.0), "zero length at row(s) 70"),
    ((np.nan, 0.0, 1.0), "finite `directions`, got NaN/inf at row(s) 70"),
])
def test_errors_unchanged_for_long_batches(tube, row, message):
    """A bad direction in a batch the fused check handles names the same row."""
    d = np.ones((100, 3))
    d[70] = row
    with pytest.raises(RayError, match=message.replace("(", r"\(").replace(")", r"\)")):
        tube.cast(np.full((100, 3), 20.0), d)


def test_cast_order_grid_orders_only_scattered_batches(tube):
    """The cast's Morton grid (``config.CAST_ORDER_BITS``) sorts origins scattered along
    the whole tube and keeps a creeping batch as it is; the answers are those of the
    reference, cast in input order, either way."""
    rng = np.random.default_rng(6)
    n = config.ORDER_MIN_RAYS + 100
    o = np.stack([rng.uniform(0, 40, n), rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)], 1)
    d = rng.standard_normal((n, 3))
    local = o - tube.origin_offset
    order = tube._ray_order(local, config.CAST_ORDER_BITS)
    assert sorted(order.tolist()) == list(range(n))
    creep = o[np.argsort(o[:, 0])]
    creep[:, 1:] = 0.3   # creeping along the axis, as a drive's origins do
    assert len(tube._ray_order(creep - tube.origin_offset, config.CAST_ORDER_BITS)) == 0
    for batch in (o, creep):
        h = tube.cast(batch, d)
        t, tri, u, v, _ = _reference(tube, batch, d)
        for got, want in ((h.t, t), (h.triangle, tri), (h.u, u), (h.v, v)):
            np.testing.assert_array_equal(_bits(got), _bits(want))
