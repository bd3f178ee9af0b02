"""Shading and exposure (issue 35) against closed forms: a floor under a point lamp
(inverse square and cosine laws), a shadow cast by a square plate (its projection),
the spot profile, Stefan-Boltzmann for the band radiance, and the noise statistics of
the exposure."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from sensors.camera import load_camera
from sensors.errors import SimulationError
from sensors.render import camera_pose, render_depth
from sensors.shading import (AE_MIN_EXPOSURE_S, AE_TARGET, K_V, Lamp, _band_radiance,
                             apparent_temperature, auto_exposure, expose, luminance)


def _floor(half=20.0, z=0.0):
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def _small(cam_name="realsense_d435_color"):
    cam = load_camera(cam_name)
    return replace(cam, width=160, height=120, fx=100.0, fy=100.0, cx=79.5, cy=59.5)


def test_a_point_lamp_over_a_floor_is_inverse_square_and_cosine():
    v, f = _floor()
    scene = Scene(v, f)
    cam = _small()
    T = camera_pose([0.0, 0.0, 3.0], 0.0, -math.pi / 2)     # looking straight down
    fr = render_depth(scene, cam, T)
    lamp = Lamp([0.5, -0.3, 2.0], [0, 0, -1], 800.0)
    L = luminance(scene, fr, [lamp], np.array([0.4, 0.5, 0.6]))
    p = fr.points[fr.hit]
    d = np.linalg.norm(lamp.position - p, axis=1)
    E = 800.0 * (2.0 / d) / d ** 2                          # cos = h / d
    for c, rho in enumerate((0.4, 0.5, 0.6)):
        np.testing.assert_allclose(L[fr.hit][:, c], rho * E / math.pi, rtol=1e-12)


def test_a_plate_casts_its_projected_shadow():
    v, f = _floor()
    # A 1 m square plate 1 m above the floor, under a lamp 2 m up: its shadow is the
    # plate scaled by 2 about the lamp's foot.
    pv = np.array([[-0.5, -0.5, 1.0], [0.5, -0.5, 1.0], [0.5, 0.5, 1.0], [-0.5, 0.5, 1.0]])
    scene = Scene(np.vstack([v, pv]), np.vstack([f, np.array([[4, 5, 6], [4, 6, 7]])]))
    cam = _small()
    T = camera_pose([3.0, 0.0, 3.0], math.pi, -math.radians(50))
    fr = render_depth(scene, cam, T)
    L = luminance(scene, fr, [Lamp([0, 0, 2.0], [0, 0, -1], 500.0)], np.array([1.0]))
    on_floor = fr.hit & (np.abs(fr.points[..., 2]) < 1e-9)
    x, y = fr.points[..., 0], fr.points[..., 1]
    inside = on_floor & (np.abs(x) < 0.99) & (np.abs(y) < 0.99)
    outside = on_floor & ((np.abs(x) > 1.01) | (np.abs(y) > 1.01))
    assert inside.sum() > 50 and outside.sum() > 50
    assert np.all(L[inside] == 0.0) and np.all(L[outside] > 0.0)


def test_spot_profile_is_full_inside_and_zero_outside():
    lamp = Lamp([0, 0, 0], [0, 0, -1], 1.0, math.radians(20), math.radians(30))
    cos = np.cos(np.radians([0, 19.9, 25, 30.1, 90]))
    f = lamp.profile(cos)
    assert f[0] == f[1] == 1.0 and 0 < f[2] < 1 and f[3] == f[4] == 0.0


def test_band_radiance_over_all_wavelengths_is_stefan_boltzmann():
    """Planck integrated over 0.5 um - 2 mm (in octaves, each by the production
    quadrature) is sigma T^4 / pi: the band radiance's units and constants."""
    sigma = 5.670374419e-8
    edges = 0.5e-6 * 2.0 ** np.arange(13)                       # 0.5 um ... 2.048 mm
    for T in (250.0, 300.0, 400.0):
        got = sum(_band_radiance(np.array([T]), (a, b))[0] for a, b in zip(edges[:-1],
                                                                            edges[1:]))
        assert got == pytest.approx(sigma * T ** 4 / math.pi, rel=2e-3)


@settings(max_examples=30, deadline=None)
@given(T=st.floats(200.0, 600.0), eps=st.floats(0.05, 1.0), amb=st.floats(200.0, 400.0))
def test_apparent_temperature_lies_between_surface_and_surroundings(T, eps, amb):
    cam = load_camera("lwir_640")
    got = apparent_temperature(cam, np.array([T]), eps, amb, noise=False)[0]
    lo, hi = min(T, amb), max(T, amb)
    assert lo - 1e-6 <= got <= hi + 1e-6
    if eps == 1.0:
        assert got == pytest.approx(T, abs=1e-6)


def test_a_colour_camera_gives_no_temperature():
    with pytest.raises(SimulationError, match="thermal camera"):
        apparent_temperature(load_camera("realsense_d435_color"), np.array([300.0]))


def test_exposure_is_the_formula_and_its_noise_poisson_plus_read():
    cam = replace(load_camera("realsense_d435_color"), full_well_e=1e9, bit_depth=16)
    lum = np.full((200, 200, 1), 30.0)
    e_mean = cam.quantum_efficiency * K_V * cam.pixel_area_m2 * 30.0 * cam.exposure_s * \
        math.pi / (4 * cam.f_number ** 2)
    scale = (2 ** 16 - 1) / cam.full_well_e
    np.testing.assert_allclose(expose(cam, lum, noise=False), e_mean * scale, rtol=1e-12)
    noisy = expose(cam, lum, seed=3) / scale
    assert noisy.mean() == pytest.approx(e_mean, rel=0.01)
    assert noisy.var() == pytest.approx(e_mean + cam.read_noise_e ** 2, rel=0.05)


def _electrons(cam, lum, t):
    """Noiseless electrons of luminance ``lum`` (cd/m^2) over ``t`` seconds (the
    module's formula, written out)."""
    return cam.quantum_efficiency * K_V * cam.pixel_area_m2 * lum * t * math.pi / \
        (4 * cam.f_number ** 2)


@settings(max_examples=60, deadline=None)
@given(st.floats(-6.0, 6.0), st.floats(1.0, 64.0))
def test_auto_exposure_brings_a_frame_to_mid_grey_time_first_then_gain(log_lum, gain_max):
    """A uniform frame of luminance L: auto-exposure's noiseless image has the mean
    AE_TARGET of full scale wherever the time (AE_MIN_EXPOSURE_S .. exposure_s) and the
    gain (1 .. gain_max) reach it; else the nearest end, the longest time and largest
    gain for a dark frame, the shortest time for a bright one (then clipped at full
    scale). The gain rises only once the time is at its longest."""
    cam = replace(load_camera("realsense_d435_color"), gain_max=gain_max, bit_depth=16)
    L = 10.0 ** log_lum
    lum = np.full((4, 5, 3), L)
    t, g = auto_exposure(cam, lum)
    assert AE_MIN_EXPOSURE_S <= t <= cam.exposure_s and 1.0 <= g <= gain_max
    assert g == 1.0 or t == cam.exposure_s
    frac_max = _electrons(cam, L, cam.exposure_s) / cam.full_well_e * gain_max
    frac_min = _electrons(cam, L, AE_MIN_EXPOSURE_S) / cam.full_well_e
    want = min(max(AE_TARGET, frac_min), frac_max, 1.0)
    got = expose(cam, lum, noise=False, exposure_s=t, gain=g) / (2 ** 16 - 1)
    np.testing.assert_allclose(got, want, rtol=1e-9)


def test_auto_exposure_in_the_dark_and_on_a_real_frame():
    """No light: the longest time at the largest gain. A frame lit by a lamp over a
    floor: its noiseless mean lands on AE_TARGET (the mean includes the dark pixels)."""
    cam = _small()
    assert auto_exposure(cam, np.zeros((3, 3, 3))) == (cam.exposure_s, cam.gain_max)
    v, f = _floor()
    scene = Scene(v, f)
    T = camera_pose([0.0, 0.0, 3.0], 0.0, -math.pi / 2)
    fr = render_depth(scene, cam, T)
    lum = luminance(scene, fr, [Lamp([0.5, -0.3, 2.0], [0, 0, -1], 800.0)], np.full(3, 0.4))
    t, g = auto_exposure(cam, lum)
    img = expose(cam, lum, noise=False, exposure_s=t, gain=g) / 255.0
    assert (img >= 1.0).mean() < 0.01          # mid grey: almost nothing clipped here
    assert img.mean() == pytest.approx(AE_TARGET, rel=0.02)
    # A fixed exposure (the camera's, gain 1) is another image.
    assert abs(expose(cam, lum, noise=False).mean() / 255.0 - AE_TARGET) > 0.02


@pytest.mark.parametrize("t, g, msg", [(0.0, 1.0, "positive exposure"),
                                       (float("nan"), 1.0, "positive exposure"),
                                       (0.01, 0.5, "gain >= 1")])
def test_expose_refuses_bad_exposure_or_gain(t, g, msg):
    with pytest.raises(SimulationError, match=msg):
        expose(_small(), np.ones((2, 2, 3)), exposure_s=t, gain=g)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["point", "hard", "ramp"]))
def test_the_lamp_kernel_is_the_formula(seed, kind):
    """``_kernels.lamps.lamp_light`` (one pass a lamp) equals the module's formula in
    NumPy with ``Lamp.profile``: E = I f(alpha) cos(theta_i) / d^2 facing the lamp, else
    0; and its directions, distances and cosines."""
    from sensors._kernels.lamps import lamp_light
    from sensors.shading import _profile_kind

    rng = np.random.default_rng(seed)
    m = 500
    p = rng.uniform(-5, 5, (m, 3))
    n = rng.normal(size=(m, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    pos = rng.uniform(-1, 1, 3)
    axis = p[0] - pos                        # aimed at point 0, which faces the lamp
    axis /= np.linalg.norm(axis)
    n[0] = -axis
    beam = rng.uniform(0.3, 1.0)
    cut = {"point": math.pi, "hard": beam, "ramp": beam + rng.uniform(0.05, 0.8)}[kind]
    lamp = Lamp(pos, axis, 1234.5, beam, cut)
    ell, d, ci, ca, e = np.empty((m, 3)), np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    lamp_light(p, n, lamp.position, lamp.direction, lamp.intensity_cd,
               *_profile_kind(lamp), ell, d, ci, ca, e)
    to = lamp.position - p
    d_ref = np.linalg.norm(to, axis=1)
    ell_ref = to / d_ref[:, None]
    ci_ref = np.einsum("ij,ij->i", n, ell_ref)
    ca_ref = -(ell_ref @ lamp.direction)
    e_ref = np.where(ci_ref > 0, 1234.5 * lamp.profile(ca_ref) * ci_ref / d_ref ** 2, 0.0)
    np.testing.assert_allclose(d, d_ref, rtol=1e-14)
    np.testing.assert_allclose(ell, ell_ref, rtol=0, atol=1e-14)
    np.testing.assert_allclose(ci, ci_ref, rtol=0, atol=1e-14)
    np.testing.assert_allclose(ca, ca_ref, rtol=0, atol=1e-14)
    # A hard beam's edge: a cosine within rounding of it may fall either side.
    edge = np.abs(np.arccos(np.clip(ca_ref, -1, 1)) - beam) < 1e-9 if kind == "hard" \
        else np.zeros(m, bool)
    np.testing.assert_allclose(e[~edge], e_ref[~edge], rtol=1e-12, atol=1e-12)
    assert (e_ref > 0).sum() > 0 and ((e > 0) == (e_ref > 0))[~edge].all()
