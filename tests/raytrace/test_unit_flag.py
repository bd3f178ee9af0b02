"""``Scene.cast(..., unit=True)``: directions the caller has normalised are checked and
cast as given, with no normalised copy (issue 35's depth-frame rate).

References: the default cast of the raw directions r, which normalises them with
x / sqrt(x x + y y + z z): ``unit=True`` with that arithmetic's result must cast the same
rays, so give the same bits, on every path (one origin through a whole map or a near
map, per-ray origins through the BVH); and NumPy's own |d| for the refusals.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import RayError, Scene
from raytrace._kernels.rays import UNIT_TOL, count_not_unit
from raytrace.shapes import tunnel_tube


def _normalised(d):
    """d / |d| by the cast's own arithmetic (``_kernels/rays.unit_directions``)."""
    length = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])
    return d / length[:, None]


def _same(a, b):
    for name in ("t", "triangle", "u", "v"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


@pytest.fixture(scope="module")
def tube():
    return Scene(*tunnel_tube(20_000, length_m=40.0, roughness_m=0.01, seed=5))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 3000),
       method=st.sampled_from(["auto", "bvh", "near", "cubemap"]),
       per_ray=st.booleans())
def test_unit_true_casts_the_same_rays(tube, seed, n, method, per_ray):
    rng = np.random.default_rng(seed)
    raw = rng.normal(size=(n, 3))
    d = _normalised(raw)
    o = np.array([1.0, 0.2, 1.5])
    if per_ray:
        o = o + rng.uniform(-0.3, 0.3, size=(n, 3))
    t_max = rng.uniform(0.5, 20.0, size=n)
    want = tube.cast(o, raw, t_max=t_max, method=method if not per_ray else "bvh")
    got = tube.cast(o, d, t_max=t_max, method=method if not per_ray else "bvh",
                    unit=True)
    _same(got, want)
    # The hits' directions are the caller's, as cast.
    np.testing.assert_array_equal(got.directions, d)


def test_unit_true_on_a_camera_frame_through_the_near_map(tube):
    """A camera-sized batch from one origin (the near map's path, as render_depth
    casts it): the same answers as the default cast."""
    rng = np.random.default_rng(1)
    raw = np.column_stack([np.ones(200_000), rng.uniform(-0.7, 0.7, 200_000),
                           rng.uniform(-0.5, 0.5, 200_000)])
    d = _normalised(raw)
    o = np.array([3.0, 0.0, 1.5])
    got = tube.cast(o, d, unit=True)
    _same(got, tube.cast(o, raw))
    assert got.hit.mean() > 0.99   # the wall, not the open far end: the map's hits


@settings(max_examples=60, deadline=None)
@given(x=st.floats(-2.0, 2.0), y=st.floats(-2.0, 2.0), z=st.floats(-2.0, 2.0))
def test_count_not_unit_matches_numpy(x, y, z):
    d = np.array([[x, y, z], [1.0, 0.0, 0.0]])
    want = int(not abs(x * x + y * y + z * z - 1.0) <= UNIT_TOL)
    assert count_not_unit(d) == want


@pytest.mark.parametrize("scale, what", [(1.0 + 1e-9, "1.000000001"), (1000.0, "1000"),
                                         (0.0, "0")])
def test_unit_true_refuses_directions_that_are_not_unit(tube, scale, what):
    d = np.tile([[0.0, 1.0, 0.0]], (100, 1))
    d[7] *= scale
    d[42] *= scale
    with pytest.raises(RayError) as err:
        tube.cast([1.0, 0.0, 1.5], d, unit=True)
    msg = str(err.value)
    assert "Expected unit-length `directions` with unit=True" in msg
    assert "row(s) 7, 42" in msg and f"length {what}" in msg
    assert "leave unit=False" in msg
    # The default normalises them and casts.
    if scale:
        assert tube.cast([1.0, 0.0, 1.5], d).hit.all()


def test_unit_true_names_nan_rows_as_not_finite(tube):
    d = np.tile([[0.0, 1.0, 0.0]], (100, 1))
    d[3, 2] = np.nan
    with pytest.raises(RayError, match=r"Expected finite `directions`, got NaN/inf at "
                                       r"row\(s\) 3;"):
        tube.cast([1.0, 0.0, 1.5], d, unit=True)
    o = np.tile([1.0, 0.0, 1.5], (100, 1))
    o[9, 0] = np.inf
    with pytest.raises(RayError, match=r"Expected finite `origins`"):
        tube.cast(o, np.tile([[0.0, 1.0, 0.0]], (100, 1)), unit=True)


@pytest.mark.parametrize("bad", ["yes", 1, None])
def test_unit_must_be_a_bool(tube, bad):
    with pytest.raises(RayError, match="Expected `unit` to be True or False"):
        tube.cast([1.0, 0.0, 1.5], [0.0, 1.0, 0.0], unit=bad)
