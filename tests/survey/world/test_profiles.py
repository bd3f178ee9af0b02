"""Cross-section profiles: analytic perimeters and areas, exact sampling, normals,
positions, and rejection of unusable polygons."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from survey.world.profiles import Profile, arched_rectangle, circle, horseshoe
from survey.errors import ProfileError


def test_circle_is_analytic():
    r = 2.5
    p = circle(r)
    assert p.perimeter_m == pytest.approx(2 * np.pi * r, rel=1e-12)
    assert p.area_m2 == pytest.approx(np.pi * r * r, rel=1e-12)
    t = p.sample(0.05)
    pts = p.points(t)
    np.testing.assert_allclose(np.linalg.norm(pts - [0.0, r], axis=1), r, atol=1e-12)
    np.testing.assert_allclose(p.normals(t), (pts - [0.0, r]) / r, atol=1e-12)
    assert pts[:, 1].min() == pytest.approx(0.0, abs=1e-12)


def test_horseshoe_area_matches_width_integral():
    """Area = integral of the width over height, from the horseshoe's definition:
    below the springline h the walls are arcs of radius 2r about the opposite
    springline point, above it a semicircle of radius r."""
    span, h = 2.8, 1.2
    r = span / 2
    p = horseshoe(span, h)

    def width(z):
        if z < h:
            return 2 * (np.sqrt(4 * r * r - (z - h) ** 2) - r)
        return 2 * np.sqrt(max(r * r - (z - h) ** 2, 0.0))

    area = quad(width, 0, h)[0] + quad(width, h, h + r)[0]
    assert p.area_m2 == pytest.approx(area, rel=1e-9)
    left, right, zmin, zmax = p.extent()
    assert left == pytest.approx(r, abs=1e-6) and right == pytest.approx(r, abs=1e-6)
    assert (zmin, zmax) == pytest.approx((0.0, h + r), abs=1e-6)
    t = p.sample(0.1)
    floor = p.is_floor(t[1:-1]) & (p.points(t[1:-1])[:, 1] < 1e-9)
    assert floor.sum() > 5  # the flat floor is labelled floor
    np.testing.assert_allclose(p.normals(t[1:-1][floor]), [[0.0, -1.0]] * floor.sum(),
                               atol=1e-12)


def test_arched_rectangle_area_and_sharp_corners():
    w, hw = 3.0, 1.2
    p = arched_rectangle(w, hw)
    assert p.area_m2 == pytest.approx(w * hw + np.pi * (w / 2) ** 2 / 2, rel=1e-12)
    t = p.sample(0.07)
    pts = p.points(t)
    for corner in ([-1.5, 0.0], [1.5, 0.0], [1.5, 1.2], [-1.5, 1.2]):
        assert np.min(np.linalg.norm(pts - corner, axis=1)) < 1e-12  # kept exactly
    assert np.diff(np.append(t, p.perimeter_m)).max() <= 0.07 + 1e-12
    assert p.distance(pts).max() < 1e-12


def test_segmental_arch_rise():
    p = arched_rectangle(3.0, 1.0, 0.5)
    assert p.extent()[3] == pytest.approx(1.5, abs=1e-6)
    with pytest.raises(ProfileError, match="rise_m"):
        arched_rectangle(3.0, 1.0, 2.0)


def test_positions_on_the_profile():
    p = horseshoe(3.0)
    for side, sgn in (("left", 1), ("right", -1)):
        y, z = p.points(p.t_at_height(side, 1.0))
        assert z == pytest.approx(1.0, abs=1e-6) and sgn * y > 1.0
    y, z = p.points(p.t_at_floor_offset(0.4))
    assert (y, z) == pytest.approx((0.4, 0.0), abs=1e-9)
    for ang in (0.0, 0.7, -1.2, 2.5):
        q = p.points(p.t_at_angle(ang)) - p.centroid
        assert np.arctan2(q[0], q[1]) == pytest.approx(ang, abs=1e-6)
    with pytest.raises(ProfileError, match="height within"):
        p.t_at_height("left", 7.0)
    with pytest.raises(ProfileError, match="side"):
        p.t_at_height("up", 1.0)


def test_polyline_orientation_is_normalised():
    sq = np.array([[0, 0], [0, 2], [2, 2], [2, 0]], float)  # clockwise
    p = Profile.from_polyline(sq)
    assert p.area_m2 == pytest.approx(4.0)
    np.testing.assert_allclose(p.centroid, [1.0, 1.0], atol=1e-9)


@pytest.mark.parametrize("pts, match", [
    ([[0, 0], [1, 1], [1, 0], [0, 1]], "non-self-intersecting"),       # bow tie
    ([[0, 0], [2, 0], [2, 2], [1, 0], [0, 2]], "non-self-intersecting"),  # touches edge
    ([[0, 0], [1, 0], [1, 0], [0, 1]], "distinct consecutive"),
    ([[0, 0], [1, 0]], "at least 3"),
    ([[0, 0], [1, np.nan], [0, 1]], "at least 3 finite"),
])
def test_bad_polylines_are_rejected(pts, match):
    with pytest.raises(ProfileError, match=match):
        Profile.from_polyline(np.array(pts, float))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.5, 3.0), min_size=5, max_size=30), st.integers(0, 2**31))
def test_star_polygons_keep_their_shoelace_area(radii, seed):
    """Random star-shaped polygons (sorted angles, every angular gap below pi, so the
    centre sees every edge from inside) are simple: accepted, and the profile's area
    equals the shoelace formula."""
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, len(radii)))
    gaps = np.diff(np.append(ang, ang[0] + 2 * np.pi))
    assume(gaps.min() > 1e-3 and gaps.max() < np.pi - 1e-3)
    r = np.array(radii)
    pts = np.stack([r * np.cos(ang), 2 + r * np.sin(ang)], 1)
    p = Profile.from_polyline(pts)
    y, z = pts.T
    shoelace = 0.5 * abs(np.sum(y * np.roll(z, -1) - np.roll(y, -1) * z))
    assert p.area_m2 == pytest.approx(shoelace, rel=1e-9)
    assert p.star_shaped_about_centroid() in (True, False)
    # Swapping two non-neighbouring vertices of a convex-enough polygon crosses edges.
    if len(pts) >= 6 and np.ptp(r) < 0.2:
        bad = pts.copy()
        bad[[0, 3]] = bad[[3, 0]]
        with pytest.raises(ProfileError, match="non-self-intersecting"):
            Profile.from_polyline(bad)


@pytest.mark.parametrize("prof", [circle(1.7), horseshoe(2.8, 1.1), arched_rectangle(3, 1, 0.6)])
def test_centroid_matches_dense_polygon(prof):
    """Closed-form moments against the shoelace centroid of a 0.1 mm polygon."""
    t = prof.sample(1e-4)
    y, z = prof.points(t).T
    cross = y * np.roll(z, -1) - np.roll(y, -1) * z
    a = 0.5 * cross.sum()
    c = np.array([((y + np.roll(y, -1)) * cross).sum(), ((z + np.roll(z, -1)) * cross).sum()])
    np.testing.assert_allclose(prof.centroid, c / (6 * a), atol=1e-8)
    assert prof.area_m2 == pytest.approx(a, rel=1e-7)
