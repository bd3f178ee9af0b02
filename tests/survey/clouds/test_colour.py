"""``survey.clouds.colour`` (issue 35): the colour and temperature of a mesh vertex
against a brute-force reference (every point's distance, sorted: the nearest
``NEIGHBOURS`` within the radius, averaged in linear light by the IEC 61966-2-1
formulas written out here; the nearest point where none is within), the voxel grid's
point-weighted mean against the plain mean of the points, and a hypothesis property:
the transfer does not change under a rigid motion plus a UTM-sized offset."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from survey.clouds.colour import (NEIGHBOURS, AppearanceCloud, AppearanceGrid,
                                  appearance_fields, appearance_radius,
                                  transfer_appearance)
from survey.errors import ReconstructionError


def _decode(c):
    """IEC 61966-2-1 sRGB -> linear, written out independently of the package."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _encode(x):
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def brute_force(points, rgb, temp, vertices, radius, k=NEIGHBOURS):
    """(uint8 colour (n, 3), temperature (n,), fallbacks) of each vertex by brute force."""
    out_rgb = np.empty((len(vertices), 3), dtype=np.uint8)
    out_t = np.empty(len(vertices))
    fallbacks = 0
    lin = _decode(rgb)
    for i, v in enumerate(vertices):
        d = np.sqrt(((points - v) ** 2).sum(axis=1))
        order = np.argsort(d, kind="stable")[:k]
        near = order[d[order] <= radius]
        if len(near) == 0:
            near = order[:1]
            fallbacks += 1
        out_rgb[i] = np.rint(_encode(lin[near].mean(axis=0)) * 255)
        out_t[i] = temp[near].mean()
    return out_rgb, out_t, fallbacks


def _cloud(points, rgb, temp):
    f = appearance_fields(rgb, temp, len(points), True, True)
    return AppearanceCloud.from_means(points, f, None, {})


def _patch(n, seed):
    """Points on a wavy 4 m x 4 m surface with random colours and temperatures."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 4, (n, 2))
    pts = np.column_stack([xy, 0.1 * np.sin(xy[:, 0])])
    return pts, rng.uniform(0, 1, (n, 3)), rng.uniform(280, 300, n)


def test_transfer_matches_brute_force():
    pts, rgb, temp = _patch(3000, 0)
    rng = np.random.default_rng(1)
    verts = np.column_stack([rng.uniform(0, 4, (400, 2)), rng.normal(0, 0.05, 400)])
    verts[:5] += [0, 0, 3.0]                         # far from every point: fallback
    for radius in (0.05, 0.15, 0.4):                 # few, many (> NEIGHBOURS) points
        app = transfer_appearance(_cloud(pts, rgb, temp), verts, radius)
        ref_rgb, ref_t, fb = brute_force(pts, rgb, temp, verts, radius)
        diff = np.abs(app.rgb.astype(int) - ref_rgb.astype(int))
        assert diff.max() <= 1 and (diff == 0).mean() > 0.99     # rounding ties only
        np.testing.assert_allclose(app.temperature_k, ref_t, rtol=1e-6)
        assert app.fallback == {"colour": fb, "temperature": fb} and fb >= 5
        fields = app.vertex_fields()
        assert [fields[k].dtype for k in ("red", "green", "blue", "temperature")] == \
            [np.uint8] * 3 + [np.float32]


def test_points_without_a_value_do_not_count():
    """NaN colour / temperature (a cloud without them beside one with) weigh nothing."""
    pts, rgb, temp = _patch(2000, 2)
    rgb2, temp2 = rgb.copy(), temp.copy()
    rgb2[::3] = np.nan
    temp2[1::4] = np.nan
    verts = pts[:200] + [0, 0, 0.01]
    app = transfer_appearance(_cloud(pts, rgb2, temp2), verts, 0.2)
    keep_c, keep_t = np.isfinite(rgb2).all(axis=1), np.isfinite(temp2)
    ref_rgb, _, _ = brute_force(pts[keep_c], rgb[keep_c], temp[keep_c], verts, 0.2)
    _, ref_t, _ = brute_force(pts[keep_t], rgb[keep_t], temp[keep_t], verts, 0.2)
    assert np.abs(app.rgb.astype(int) - ref_rgb.astype(int)).max() <= 1
    np.testing.assert_allclose(app.temperature_k, ref_t, rtol=1e-6)


def test_voxel_grid_weights_each_voxel_by_its_points():
    """Through the grid, a neighbourhood holding every voxel gives the mean of every
    point (in linear light), however the points fall into voxels and chunks."""
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 0.3, (5000, 3))
    rgb = rng.uniform(0, 1, (5000, 3)) ** 3
    temp = rng.uniform(270, 310, 5000)
    g = AppearanceGrid(0.07, pts.min(axis=0), colour=True, temperature=True, sources={})
    for a in range(0, 5000, 1234):
        g.add(pts[a:a + 1234], rgb[a:a + 1234], temp[a:a + 1234])
    vox, counts, cloud = g.result()
    assert counts.sum() == 5000 and len(vox) < 200
    app = transfer_appearance(cloud, [[0.15, 0.15, 0.15]], 1.0, neighbours=1000)
    np.testing.assert_array_equal(app.rgb[0], np.rint(_encode(_decode(rgb).mean(0)) * 255))
    np.testing.assert_allclose(app.temperature_k[0], temp.mean(), rtol=1e-6)
    # the mean of the sRGB values (the wrong average) is darker and would differ
    assert (np.rint(rgb.mean(0) * 255) < app.rgb[0]).all()


def test_radius_is_half_the_median_edge_at_least_a_voxel():
    v = np.array([[0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [1, 1, 0]])
    f = np.array([[0, 1, 2], [1, 3, 2]])
    edges = [1, 1, np.sqrt(2), 1, 1, np.sqrt(2)]
    assert appearance_radius(v, f, 0.02) == pytest.approx(0.5 * np.median(edges))
    assert appearance_radius(v, f, 2.0) == 2.0
    with pytest.raises(ReconstructionError, match="positive radius"):
        transfer_appearance(_cloud(v, np.zeros((4, 3)), np.full(4, 290.0)), v, 0.0)


def test_an_attribute_no_point_has_is_none():
    pts, rgb, _ = _patch(100, 4)
    cloud = AppearanceCloud.from_means(
        pts, appearance_fields(rgb, None, 100, True, False), None, {})
    app = transfer_appearance(cloud, pts[:3], 0.1)
    assert app.temperature_k is None and "temperature" not in app.vertex_fields()


@settings(max_examples=25, deadline=None)
@given(angles=st.tuples(*[st.floats(-np.pi, np.pi)] * 3),
       offset=st.tuples(st.floats(-5e5, 5e5), st.floats(4e6, 6e6), st.floats(-100, 3000)),
       seed=st.integers(0, 1000))
def test_transfer_invariant_under_rigid_motion_and_utm_offset(angles, offset, seed):
    pts, rgb, temp = _patch(800, seed)
    rng = np.random.default_rng(seed + 1)
    verts = pts[rng.choice(800, 60, replace=False)] + rng.normal(0, 0.03, (60, 3))
    rot = Rotation.from_euler("xyz", angles)
    moved = rot.apply(pts) + offset
    moved_v = rot.apply(verts) + offset
    a = transfer_appearance(_cloud(pts, rgb, temp), verts, 0.2)
    b = transfer_appearance(_cloud(moved, rgb, temp), moved_v, 0.2)
    # distances at UTM size are exact to ~1e-9 m: a tie at the radius could flip one
    # neighbour, the rounding to uint8 one step
    assert np.abs(a.rgb.astype(int) - b.rgb.astype(int)).max() <= 1
    np.testing.assert_allclose(a.temperature_k, b.temperature_k, rtol=1e-5)
    assert a.fallback == b.fallback
