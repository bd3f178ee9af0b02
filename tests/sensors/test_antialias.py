"""Anti-aliasing (issue 35): ``sensors.shading.radiance_frame`` averages the linear
radiance of a stratified grid of rays per pixel, ``thermal_frame`` the band radiance.
Checked against closed forms (a lit plate whose edges cut pixels, every sub-pixel ray
intersected with the plane by hand; a warm plate over a cool floor, Planck's law
integrated and inverted by SciPy), against Mitsuba 3's box filter (which integrates
over the pixel: more samples must come closer than one), and the strata themselves
(hypothesis)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors.camera import load_camera
from sensors.errors import SimulationError
from sensors.render import camera_pose, render_depth
from sensors.appearance import Appearance, Attribute
from sensors.shading import (Lamp, apparent_temperature, headlamp, luminance,
                             radiance_frame, stratified_offsets, thermal_frame)


def _pinhole(w, h, f):
    return replace(load_camera("realsense_d435_color"), width=w, height=h, fx=f, fy=f,
                   cx=(w - 1) / 2, cy=(h - 1) / 2, distortion=np.zeros(5))


@given(st.integers(1, 12))
def test_offsets_are_one_per_stratum(k):
    off = stratified_offsets(k * k)
    assert off.shape == (k * k, 2)
    # Each of the k x k strata of the pixel (-0.5..0.5)^2 holds exactly one sample, at
    # its centre: the mean is the pixel centre.
    cell = np.floor((off + 0.5) * k).astype(int)
    assert len({tuple(c) for c in cell}) == k * k
    np.testing.assert_allclose((off + 0.5) * k - cell, 0.5, atol=1e-12)
    np.testing.assert_allclose(off.mean(axis=0), 0.0, atol=1e-15)


@pytest.mark.parametrize("n", [0, 2, 3, 15, -4, 2.0])
def test_a_non_square_count_is_refused_naming_the_option(n):
    with pytest.raises(SimulationError, match=r"Expected --samples to be a square number"):
        stratified_offsets(n)


def _plate_scene():
    """A 2 x 1.4 m plate on z = 0, turned 17 deg so that its edges cut pixels at all
    sub-pixel positions, inside a 40 m floor 1 m lower (rays off the plate hit it)."""
    a = math.radians(17.0)
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    corners = np.array([[-1.0, -0.7], [1.0, -0.7], [1.0, 0.7], [-1.0, 0.7]]) @ R.T
    v = np.vstack([np.column_stack([corners, np.zeros(4)]),
                   [[-20, -20, -1.0], [20, -20, -1.0], [20, 20, -1.0], [-20, 20, -1.0]]])
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    return v, f, R


def _closed_form(cam, T, lamp, rho, R, offsets):
    """Each sub-pixel ray through (u + dx, v + dy) met with z = 0 (the plate, where the
    point lies inside the turned rectangle) or z = -1 (the floor) by hand, its
    Lambertian radiance rho I cos / (pi d^2) (0 in the plate's shadow), averaged over
    the offsets."""
    v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    total = np.zeros(u.shape)
    for dx, dy in offsets:
        d_cam = np.stack([(u + dx - cam.cx) / cam.fx, (v + dy - cam.cy) / cam.fy,
                          np.ones_like(u)], -1)
        d = d_cam @ T[:3, :3].T
        o = T[:3, 3]
        t0 = (0.0 - o[2]) / d[..., 2]
        p = o + t0[..., None] * d
        local = p[..., :2] @ R                 # back into the plate's axes
        on_plate = (np.abs(local[..., 0]) < 1.0) & (np.abs(local[..., 1]) < 0.7)
        t1 = (-1.0 - o[2]) / d[..., 2]
        p = np.where(on_plate[..., None], p, o + t1[..., None] * d)
        to = lamp.position - p
        dist = np.linalg.norm(to, axis=-1)
        # A floor point is in the plate's shadow where its ray to the lamp crosses
        # z = 0 inside the plate.
        s = (0.0 - p[..., 2]) / to[..., 2]
        cross = (p + s[..., None] * to)[..., :2] @ R
        shadow = ~on_plate & (np.abs(cross[..., 0]) < 1.0) & (np.abs(cross[..., 1]) < 0.7)
        total += np.where(shadow, 0.0, rho * lamp.intensity_cd * (to[..., 2] / dist)
                          / (math.pi * dist ** 2))
    return total / len(offsets)


@pytest.mark.parametrize("n", [4, 9, 16])
def test_supersampled_radiance_equals_the_closed_form_over_the_strata(n):
    v, f, R = _plate_scene()
    scene = Scene(v, f)
    cam = _pinhole(64, 48, 40.0)
    T = camera_pose([0.3, -0.2, 2.5], 0.4, -math.pi / 2 + 0.1)
    lamp = Lamp([0.5, 0.4, 3.0], [0.0, 0.0, -1.0], 700.0)
    fr, lum = radiance_frame(scene, cam, T, [lamp], np.array([0.4]), n)
    ref = _closed_form(cam, T, lamp, 0.4, R, stratified_offsets(n))
    np.testing.assert_allclose(lum[..., 0], ref, rtol=1e-9)
    # The plate's edges are anti-aliased: pixels between the plate's and the floor's
    # radiance, which one ray per pixel never gives.
    one = _closed_form(cam, T, lamp, 0.4, R, stratified_offsets(1))
    assert np.sum(np.abs(lum[..., 0] - one) > 0.05 * one.max()) > 20
    # Depth stays the pixel centre's (a depth camera does not average).
    centre = render_depth(scene, cam, T)
    np.testing.assert_array_equal(fr.depth_z_m, centre.depth_z_m)


def test_one_sample_is_the_pixel_centre_exactly():
    v, f = tunnel_tube(2_000, length_m=10.0, seed=3)
    scene = Scene(v, f)
    cam = _pinhole(40, 30, 20.0)
    T = camera_pose([2.0, 0.1, 1.2], 0.1)
    lamps = [headlamp(T, 500.0)]
    fr, lum = radiance_frame(scene, cam, T, lamps, np.array([0.3, 0.2, 0.1]), 1)
    ref = luminance(scene, render_depth(scene, cam, T), lamps, np.array([0.3, 0.2, 0.1]))
    np.testing.assert_array_equal(lum, ref)


def _thermal_cam(w=64, h=48, f=40.0):
    return replace(load_camera("lwir_640"), width=w, height=h, fx=f, fy=f,
                   cx=(w - 1) / 2, cy=(h - 1) / 2, distortion=np.zeros(5))


def _plate_appearance(f, t_plate, t_floor):
    """Per face: the plate (faces 0, 1) at ``t_plate``, the floor at ``t_floor``, both
    black bodies (emissivity 1: no reflected surroundings)."""
    per_face = lambda a: Attribute(np.asarray(a, dtype=np.float64), "face")  # noqa: E731
    return Appearance(per_face(np.full((4, 3), 0.3)),
                      per_face([t_plate, t_plate, t_floor, t_floor]), per_face(np.ones(4)),
                      np.asarray(f, dtype=np.int64))


def _planck_band(T, band_m):
    """Black-body radiance in the band (W m^-2 sr^-1), Planck's law by SciPy's quad."""
    from scipy.integrate import quad

    h, c, k = 6.62607015e-34, 299_792_458.0, 1.380649e-23
    return quad(lambda lam: 2 * h * c ** 2 / lam ** 5 / math.expm1(h * c / (lam * k * T)),
                *band_m, epsabs=0, epsrel=1e-12)[0]


@pytest.mark.parametrize("n", [4, 9])
def test_thermal_supersampling_averages_band_radiance(n):
    """A pixel whose strata see the 320 K plate on a fraction p of its rays and the
    280 K floor on the rest reads the black body's temperature of p B(320) + (1 - p)
    B(280): not the mean temperature (Planck's law is not linear)."""
    from scipy.optimize import brentq

    v, f, R = _plate_scene()
    scene = Scene(v, f)
    cam = _thermal_cam()
    T = camera_pose([0.3, -0.2, 2.5], 0.4, -math.pi / 2 + 0.1)
    fr, got = thermal_frame(scene, cam, T, _plate_appearance(f, 320.0, 280.0), 290.0, n,
                            noise=False)
    # The fraction of each pixel's rays that meet the plate, by hand (as _closed_form).
    frac = np.zeros((cam.height, cam.width))
    v_, u_ = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    for dx, dy in stratified_offsets(n):
        d = np.stack([(u_ + dx - cam.cx) / cam.fx, (v_ + dy - cam.cy) / cam.fy,
                      np.ones_like(u_)], -1) @ T[:3, :3].T
        p = T[:3, 3] + ((0.0 - T[2, 3]) / d[..., 2])[..., None] * d
        local = p[..., :2] @ R
        frac += (np.abs(local[..., 0]) < 1.0) & (np.abs(local[..., 1]) < 0.7)
    frac /= n
    assert fr.hit.all() and 0 < np.mean((frac > 0) & (frac < 1)) < 0.5
    b1, b0 = _planck_band(320.0, cam.band_m), _planck_band(280.0, cam.band_m)
    ref = {}
    for p in np.unique(frac):
        L = p * b1 + (1 - p) * b0
        ref[p] = brentq(lambda t: _planck_band(t, cam.band_m) - L, 270.0, 330.0,
                        xtol=1e-9)
    want = np.vectorize(ref.get)(frac)
    np.testing.assert_allclose(got, want, atol=1e-4)
    edge = (frac > 0.3) & (frac < 0.7)
    assert edge.any() and np.all(np.abs(got[edge] - (280 + 40 * frac[edge])) > 0.1)


def test_one_thermal_sample_is_the_pixel_centres_apparent_temperature():
    v, f, _ = _plate_scene()
    scene = Scene(v, f)
    cam = _thermal_cam()
    T = camera_pose([0.3, -0.2, 2.5], 0.4, -math.pi / 2 + 0.1)
    app = _plate_appearance(f, 320.0, 280.0)
    fr, got = thermal_frame(scene, cam, T, app, 290.0, 1, seed=5)
    px = app.at(fr)
    want = apparent_temperature(cam, px.temperature_k[fr.hit], px.emissivity[fr.hit],
                                290.0, seed=5)
    np.testing.assert_array_equal(got[fr.hit], want)
    with pytest.raises(SimulationError, match="thermal camera"):
        thermal_frame(scene, _pinhole(8, 6, 4.0), T, app, 290.0)


mi = None
try:    # Mitsuba is optional: only the convergence test needs it
    import mitsuba as mi  # type: ignore[no-redef]
except ImportError:  # pragma: no cover
    pass


@pytest.mark.skipif(mi is None, reason="Mitsuba 3 is the box-filter reference (pip "
                                       "install mitsuba)")
@pytest.mark.parametrize("kind", ["point", "headlamp"])
def test_supersampling_converges_to_mitsubas_box_filter(tmp_path, kind):
    """Mitsuba's ``box`` filter averages the radiance over each pixel's square; ours
    at one ray per pixel samples its centre (55-59 dB, tests/sensors/
    test_mitsuba_shading.py). Measured (2026-11-27, 1024 Mitsuba samples per pixel):
    1, 4, 16 rays per pixel give 59.3, 68.8, 76.5 dB (point lamp) and 55.3, 63.6,
    69.0 dB (headlamp); the floor is Mitsuba's Monte-Carlo noise."""
    from tests.sensors import test_mitsuba_shading as tm

    W, H = tm.W, tm.H
    v, f = tunnel_tube(3_000, length_m=12.0, seed=2)
    fx = (W / 2) / math.tan(math.radians(100.0) / 2)
    cam = _pinhole(W, H, fx)
    T = camera_pose([2.0, 0.2, 1.3], math.radians(5.0), math.radians(-3.0))
    scene = Scene(v, f)
    rho = (0.6, 0.45, 0.3)
    lamp = Lamp([3.0, -0.5, 1.8], [1.0, 0.0, 0.0], 50.0) if kind == "point" else \
        headlamp(T, 50.0)
    old = tm.SPP
    tm.SPP = 1024
    try:
        ref = tm._mitsuba_image(v, f, tmp_path / "tube.obj", T, fx, lamp, rho)
    finally:
        tm.SPP = old

    def psnr(n):
        _, ours = radiance_frame(scene, cam, T, [lamp], np.array(rho), n)
        return 10 * math.log10(ref.max() ** 2 / float(((ours - ref) ** 2).mean()))

    p1, p4, p16 = psnr(1), psnr(4), psnr(16)
    assert p1 < p4 < p16, (p1, p4, p16)
    assert p16 > p1 + 10.0, (p1, p16)
