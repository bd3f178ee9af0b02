"""Alignment: analytic element geometry, round trips, frame, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import fresnel

from survey.world.alignment import Alignment, arc, clothoid, curve, straight
from survey.errors import AlignmentError


@pytest.fixture(scope="module")
def curved():
    """Straight, clothoid into R = 400 m, arc, clothoid out, straight; 1.5 % grade."""
    elems = [straight(60.0), clothoid(40.0, np.inf, 400.0), arc(80.0, 400.0),
             clothoid(40.0, 400.0, np.inf), straight(80.0)]
    return Alignment(elems, start_xy=(451_000.0, 5_352_000.0), heading_rad=0.3,
                     profile=[(1000.0, 300.0), (1150.0, 302.25), (1300.0, 301.0)],
                     start_chainage_m=1000.0)


def test_arc_chord_is_analytic():
    r, length = 250.0, 120.0
    al = Alignment([arc(length, r)], heading_rad=0.0)
    xy, th, k = al.plan(np.array([0.0, length]))
    chord = np.linalg.norm(xy[1] - xy[0])
    assert chord == pytest.approx(2 * r * np.sin(length / (2 * r)), abs=1e-10)
    assert th[1] == pytest.approx(length / r, abs=1e-14) and k[0] == 1 / r


def test_clothoid_matches_fresnel_integrals():
    """A clothoid from a straight to radius R over L: x = a C(L/a), y = a S(L/a) with
    a = sqrt(pi R L) (scipy's Fresnel integrals, an independent evaluation)."""
    r, length = 300.0, 70.0
    al = Alignment([clothoid(length, np.inf, r)], heading_rad=0.0)
    s = np.linspace(0, length, 8)
    xy, th, k = al.plan(s)
    a = np.sqrt(np.pi * r * length)
    fs, fc = fresnel(s / a)
    np.testing.assert_allclose(xy[:, 0], a * fc, atol=1e-9)
    np.testing.assert_allclose(xy[:, 1], a * fs, atol=1e-9)
    np.testing.assert_allclose(th, s ** 2 / (2 * r * length), atol=1e-14)
    np.testing.assert_allclose(k, s / (r * length), atol=1e-15)


def test_length_and_chainage(curved):
    assert curved.length_m == pytest.approx(300.0)
    assert curved.chainage_range == (1000.0, 1300.0)
    # Arc length along the curve equals the chainage difference (fine polyline).
    s = np.linspace(1000.0, 1300.0, 300_001)
    pts = curved.plan(s)[0]
    assert np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() == pytest.approx(300.0,
                                                                               abs=1e-6)


def test_continuity_at_element_joints(curved):
    joints = 1000.0 + np.cumsum([60.0, 40.0, 80.0, 40.0])
    eps = 1e-7
    before, th_b, k_b = curved.plan(joints - eps)
    after, th_a, k_a = curved.plan(joints + eps)
    np.testing.assert_allclose(before, after, atol=1e-6)
    np.testing.assert_allclose(th_b, th_a, atol=1e-8)
    np.testing.assert_allclose(k_b, k_a, atol=1e-9)  # clothoids make curvature continuous


def test_round_trips_in_utm(curved):
    rng = np.random.default_rng(0)
    n = 5000
    s = rng.uniform(1000.0, 1300.0, n)
    off = rng.uniform(-3.0, 3.0, n)
    h = rng.uniform(-1.0, 4.0, n)
    world = curved.to_world(s, off, h)
    s2, off2, h2 = curved.to_local(world)
    np.testing.assert_allclose(s2, s, atol=1e-9)
    np.testing.assert_allclose(off2, off, atol=1e-9)
    np.testing.assert_allclose(h2, h, atol=1e-9)
    back = curved.to_world(s2, off2, h2)
    np.testing.assert_allclose(back, world, rtol=0, atol=1e-9)


def test_frame_matches_finite_differences(curved):
    s = np.linspace(1001.0, 1299.0, 50)
    t, n, up = curved.frame(s)
    # Central differences at UTM magnitudes (5.35e6 m): a 1e-2 m step keeps rounding
    # (~5e6 * 1e-16 / 1e-2 = 5e-8) and truncation (kappa h^2 / 6 ~ 4e-8) below 1e-6.
    eps = 1e-2
    d = (curved.plan(s + eps)[0] - curved.plan(s - eps)[0]) / (2 * eps)
    np.testing.assert_allclose(t[:, :2], d, atol=1e-6)
    np.testing.assert_allclose(np.einsum("ij,ij->i", t, n), 0.0, atol=1e-15)
    np.testing.assert_allclose(np.cross(t, n), up, atol=1e-15)  # right-handed
    g = curved.grade(np.array([1010.0, 1200.0]))
    np.testing.assert_allclose(g, [2.25 / 150, -1.25 / 150])
    np.testing.assert_allclose(curved.elevation([1000.0, 1075.0, 1300.0]),
                               [300.0, 301.125, 301.0])


@pytest.mark.parametrize("make, match", [
    (lambda: Alignment([]), "at least one"),
    (lambda: Alignment([straight(0.0)]), "positive element length"),
    (lambda: Alignment([straight(-5.0)]), "positive element length"),
    (lambda: arc(10.0, 0.0), "non-zero arc radius"),
    (lambda: Alignment([straight(10.0)], profile=[(5.0, 1.0), (5.0, 2.0)]), "increasing"),
    (lambda: Alignment([straight(10.0)], profile=[1.0, 2.0]), r"\(k, 2\)"),
    (lambda: Alignment(["straight"]), "Element objects"),
])
def test_bad_definitions(make, match):
    with pytest.raises(AlignmentError, match=match):
        make()


def test_bad_queries(curved):
    with pytest.raises(AlignmentError, match="within"):
        curved.plan(np.array([999.0]))
    with pytest.raises(AlignmentError, match=r"shape \(n, 3\)"):
        curved.to_local(np.zeros((4, 2)))


def test_fit_recovers_a_noisy_arc():
    """Noisy points (5 mm) of a known 150 m arc of R = 200 m in UTM coordinates: the
    fitted alignment's curvature gives the radius within 1 %, and the true arc lies
    within 5 mm of the fitted centreline except in the last 5 m at either end, where a
    least-squares spline is least constrained (measured: 7 mm at the very first point,
    <= 1.6 mm inside)."""
    r, length = 200.0, 150.0
    truth = Alignment([arc(length, r)], start_xy=(452_000.0, 5_351_000.0),
                      heading_rad=1.0, profile=[(0.0, 280.0), (150.0, 281.5)])
    s = np.arange(0.0, length + 1e-9, 0.5)
    pts = truth.point(s)
    rng = np.random.default_rng(3)
    noisy = pts + rng.normal(0.0, 0.005, pts.shape)
    fitted = Alignment.fit(noisy)
    assert fitted.length_m == pytest.approx(length, abs=0.05)
    mid = np.linspace(20.0, fitted.length_m - 20.0, 50)
    _, _, k = fitted.plan(mid)
    assert 1.0 / k.mean() == pytest.approx(r, rel=0.01)
    _, off, h = fitted.to_local(pts[10:-10])
    assert np.abs(off).max() < 0.005 and np.abs(h).max() < 0.005


def test_fit_rejects_bad_points():
    with pytest.raises(AlignmentError, match="at least 5"):
        Alignment.fit(np.zeros((3, 3)))
    with pytest.raises(AlignmentError, match="repeated"):
        Alignment.fit(np.repeat(np.arange(6.0)[:, None], 3, axis=1).repeat(2, axis=0))


def test_curve_turns_by_its_deflection_with_analytic_element_lengths():
    """Clothoid-arc-clothoid: each clothoid turns L/(2R), the arc the rest; the end
    heading is the deflection and the arc's own length is R (deflection - L/R)."""
    d, r, ln = -0.4, 250.0, 30.0
    els = curve(d, r, ln)
    assert [e.length_m for e in els] == pytest.approx([ln, r * (abs(d) - ln / r), ln])
    al = Alignment(els, heading_rad=0.2)
    _, th, k = al.plan(np.array([0.0, ln, al.length_m]))
    assert th[2] - th[0] == pytest.approx(d, abs=1e-13)
    assert th[1] - th[0] == pytest.approx(-ln / (2 * r), abs=1e-13)
    assert k[1] == pytest.approx(-1 / r)
    assert al.min_radius() == (np.inf, pytest.approx(r))


def test_alignment_dict_round_trip(curved):
    back = Alignment.from_dict(curved.to_dict())
    s = np.linspace(*curved.chainage_range, 57)
    np.testing.assert_array_equal(back.point(s), curved.point(s))
    with pytest.raises(AlignmentError, match="alignment dictionary"):
        Alignment.from_dict({"elements": []})


def test_short_clothoids_use_8_nodes_without_losing_precision(monkeypatch):
    """Chains of short clothoids (as Alignment.fit makes) take the 8-node rule; it
    agrees with the 24-node rule to 1e-12 m."""
    import survey.world.alignment as A
    rng = np.random.default_rng(0)
    k = np.concatenate([[0.0], np.cumsum(rng.normal(0, 0.002, 150))])
    al = Alignment([A.Element(2.0, k[i], k[i + 1]) for i in range(150)])
    s = np.linspace(0, al.length_m, 997)
    fast = al.point(s)
    monkeypatch.setattr(A, "_SHORT_PANEL_M", 0.0)
    slow = Alignment(list(al.elements)).point(s)
    np.testing.assert_allclose(fast, slow, atol=1e-12, rtol=0)
