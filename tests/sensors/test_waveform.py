"""Full waveform and multiple returns (``sensors.waveform``) against analytic geometry:
planes behind one another in a beam's footprint, a step edge cast with the real ray
caster, a pulse through dust, the waveform against its defining sum in plain NumPy, and
the return modes against a per-pulse reference written out from the makers' manuals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize_scalar

from raytrace import Scene
from sensors import load_sensor
from sensors import physics as ph
from sensors import waveform as wf
from sensors.errors import SensorSpecError, SimulationError

C = 299_792_458.0
PHYS = load_sensor("velodyne_vlp16").physics
MODEL = wf.WaveformModel(pulse_fwhm_s=4e-9, threshold_power=1e-7)
SIGMA = C * 4e-9 / 2 / (2 * math.sqrt(2 * math.log(2)))   # the pulse's sigma in range
SEP = C * 4e-9 / 2                                        # pulse length x c / 2
OFF, W = ph.subray_offsets(19)


def _beam(direction, divergence):
    """The 19 sub-ray directions (19, 3) of one beam, as the simulation builds them."""
    d = np.asarray(direction, float)[None, :]
    d = d / np.linalg.norm(d)
    u, v = ph.perpendicular_basis(d)
    rays = d + divergence * (OFF[:, :1] * u + OFF[:, 1:] * v)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True), u[0], v[0]


def _two_planes(d, delta, divergence=2e-3, rho=0.5):
    """Beam along +x from the origin; the near plane x = d covers v-offsets below
    0.25 of the divergence (v = the beam's second perpendicular), the far plane
    x = d + delta the rest. Returns per-sub-ray ranges, powers, and the near mask."""
    rays, _, v = _beam([1.0, 0.0, 0.0], divergence)
    near = OFF[:, 1] < 0.25                   # the area split, in the footprint's units
    plane = np.where(near, d, d + delta)
    t = plane / rays[:, 0]                    # ray-plane intersection, normal +x
    p = ph.power(rho, rays[:, 0], t, 0.0)
    return t[None, :], p[None, :], near


def _ref_waveform(x, r, p):
    """The waveform's definition, in plain NumPy: sum_j p_j exp(-(x - r_j)^2 / 2 s^2)."""
    r, p = np.asarray(r), np.asarray(p)
    ok = np.isfinite(r) & (p > 0)
    return (p[ok][None, :] * np.exp(-0.5 * ((np.asarray(x)[:, None] - r[ok][None, :]) /
                                            SIGMA) ** 2)).sum(axis=1)


def _maxima(r, p):
    """Local maxima of the defining sum on a 0.1 mm grid: the echoes a noise-free
    receiver could separate at all (a weak echo on a strong one's flank makes a
    shoulder, not a maximum, until it is about 2.6-3.7 sigma away for 1:2-1:30)."""
    x = np.arange(np.nanmin(r) - 1.0, np.nanmax(r[np.isfinite(r)]) + 1.0, 1e-4)
    y = _ref_waveform(x, r, p)
    return int(np.sum((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:])))


# ---------------------------------------------------------------- the model's numbers
def test_pulse_in_range_units():
    m = wf.WaveformModel(pulse_fwhm_s=4e-9, threshold_power=0.0)
    assert m.sigma_m == pytest.approx(SIGMA, rel=1e-12)
    assert m.bin_m == pytest.approx(C * 0.25e-9 / 2, rel=1e-12)   # 3.75 cm
    assert m.min_separation_m == pytest.approx(0.5996, abs=1e-4)
    # The FWHM in range is the separation: the Gaussian is at half height there.
    assert math.exp(-0.5 * (m.min_separation_m / 2 / m.sigma_m) ** 2) == \
        pytest.approx(0.5, rel=1e-12)


def test_waveform_is_the_sum_of_pulse_shapes():
    rng = np.random.default_rng(1)
    r = rng.uniform(2, 30, (5, 7))
    r[1, 3] = np.inf
    p = rng.uniform(0, 1e-3, (5, 7))
    start, s = wf.waveforms(r, p, MODEL)
    for i in range(5):
        x = start[i] + MODEL.bin_m * np.arange(s.shape[1])
        ref = _ref_waveform(x, r[i], p[i])
        # Each pulse shape is cut at REACH_SIGMA (6) sigma: exp(-18) of its peak.
        np.testing.assert_allclose(s[i], ref, rtol=1e-9,
                                   atol=math.exp(-18) * p[i][np.isfinite(r[i])].sum())
        # The grid is anchored at range 0: sample ranges are whole bins.
        np.testing.assert_allclose(x / MODEL.bin_m, np.round(x / MODEL.bin_m), atol=1e-6)


# ------------------------------------------------------------- two planes in a beam
@pytest.mark.parametrize("factor,expected", [(0.3, 1), (0.9, 1), (1.2, 2), (2.0, 2),
                                             (8.0, 2)])
def test_two_planes_two_echoes_iff_beyond_separation(factor, expected):
    d, delta = 12.0, factor * SEP
    t, p, near = _two_planes(d, delta)
    e = wf.pulse_echoes(t, p, W, MODEL)
    assert e.count[0] == expected
    # Beyond the separation, the waveform itself has two maxima here (area split
    # about 2:1), so the dead time is what decides.
    assert (_maxima(t[0], (p * W)[0]) == 2) == (factor > 1.1)
    if expected == 2:
        assert e.range_m[0, 0] == pytest.approx(d, abs=1e-3)
        assert e.range_m[0, 1] == pytest.approx(d + delta, abs=1e-3)
        # Amplitude ratio from the area split of the footprint and 1/R^2.
        f_near = W[near].sum()
        ratio = (f_near / d ** 2) / ((1 - f_near) / (d + delta) ** 2)
        assert e.amplitude[0, 0] / e.amplitude[0, 1] == pytest.approx(ratio, rel=1e-4)
        # Each echo of a plane facing the beam is the emitted pulse: width = sigma.
        np.testing.assert_allclose(e.width_m[0, :2], SIGMA, rtol=1e-4)
    else:
        # One echo, between the planes (a mixed pixel of the waveform).
        assert d < e.range_m[0, 0] < d + delta


@settings(max_examples=40, deadline=None)
@given(d=st.floats(1.0, 80.0), factor=st.one_of(st.floats(0.05, 0.95),
                                                st.floats(1.3, 20.0)))
def test_two_planes_property(d, factor):
    """Two echoes iff the planes are more than the separation apart and the waveform
    has two maxima (always so from 1.6 separations on, for these splits)."""
    t, p, _ = _two_planes(d, factor * SEP)
    e = wf.pulse_echoes(t, p, W, MODEL)
    two = factor > 1 and _maxima(t[0], (p * W)[0]) == 2
    # Not at the edge of resolvability (a dip too shallow for 3.75 cm bins to show):
    # the planes 5 cm nearer must give the same answer.
    t2, p2, _ = _two_planes(d, factor * SEP - 0.05)
    assume(factor <= 1 or two == (_maxima(t2[0], (p2 * W)[0]) == 2))
    assert e.count[0] == (2 if two else 1)
    assert two or factor < 1.6
    if two:
        np.testing.assert_allclose(e.range_m[0, :2], [d, d + factor * SEP], atol=1e-3)


def test_beam_across_a_step_edge():
    """Two walls facing the beam, 1 m apart, their edge inside the footprint: the ray
    caster's sub-ray hits give an echo on each wall, where the single-return blend
    (footprint-weighted mean range) gives a point in the air between them."""
    d, step, half = 10.0, 1.0, 5.0
    div = 3e-3
    rays, u, v = _beam([1.0, 0.0, 0.0], div)
    e_v = 0.25 * div * d                       # the edge, 1/4 of the footprint off axis
    # Near wall x = d on v-coordinate < e_v, far wall x = d + step beyond it (a quad
    # each, in the plane spanned by u and v, facing -x).
    def quad(x, v0, v1):
        return np.array([[x, 0, 0] + a * u + b * v for a, b in
                         [(-half, v0), (half, v0), (half, v1), (-half, v1)]])
    verts = np.concatenate([quad(d, -half, e_v), quad(d + step, e_v, half)])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    hits = Scene(verts, faces).cast(np.zeros(3), rays)
    assert np.all(hits.triangle >= 0)
    cos = np.abs(np.einsum("ij,ij->i", hits.normals, rays))
    p = ph.power(0.5, cos, hits.t, 0.0)
    e = wf.pulse_echoes(hits.t[None], p[None], W, MODEL)
    assert e.count[0] == 2
    np.testing.assert_allclose(e.range_m[0, :2], [d, d + step], atol=1e-3)
    near = OFF[:, 1] * div * d < e_v
    assert np.array_equal(hits.t < d + step / 2, near)
    blend = (p * W * hits.t).sum() / (p * W).sum()     # sensors.simulate "average"
    assert d + 0.05 < blend < d + step - 0.05
    # Dual (strongest + last) reports both walls, nearer first.
    ret = wf.select_returns(e, "dual", dual="strongest_last")
    np.testing.assert_allclose(ret.take(e.range_m), [d, d + step], atol=1e-3)
    assert list(ret.return_number) == [1, 2] and list(ret.number_of_returns) == [2, 2]


def test_dust_echo_first_wall_last_in_dual():
    d_wall, d_dust = 20.0, 6.0
    rays, _, _ = _beam([1.0, 0.0, 0.0], 2e-3)
    t = d_wall / rays[:, 0]
    p = ph.power(0.5, rays[:, 0], t, 0.0)
    pp = ph.power(0.1, 1.0, d_dust, 0.0)               # as sensors.simulate does
    e = wf.pulse_echoes(t[None], p[None], W, MODEL, particle_range_m=[d_dust],
                        particle_power=[pp])
    assert e.count[0] == 2
    np.testing.assert_allclose(e.range_m[0, :2], [d_dust, d_wall], atol=1e-3)
    assert e.power[0, 0] == pytest.approx(pp, rel=1e-6)
    for kind in ("first_last", "strongest_last", "strongest_second"):
        ret = wf.select_returns(e, "dual", dual=kind)
        np.testing.assert_allclose(ret.take(e.range_m), [d_dust, d_wall], atol=1e-3)
        assert list(ret.return_number) == [1, 2]
    # The single modes pick one each: the wall is the strongest and the last.
    wall = e.power[0, 1] > e.power[0, 0]
    got = {m: wf.select_returns(e, m).take(e.range_m)[0] for m in ("first", "last",
                                                                 "strongest")}
    assert got["first"] == e.range_m[0, 0] and got["last"] == e.range_m[0, 1]
    assert got["strongest"] == e.range_m[0, 1 if wall else 0]
    # No particle (inf): one echo, the wall.
    e1 = wf.pulse_echoes(t[None], p[None], W, MODEL, particle_range_m=[np.inf],
                         particle_power=[pp])
    assert e1.count[0] == 1 and e1.range_m[0, 0] == pytest.approx(d_wall, abs=1e-3)


# ------------------------------------------------------------------ one plane, any way
@settings(max_examples=60, deadline=None)
@given(r=st.floats(1.0, 80.0), inc_deg=st.floats(0.0, 60.0),
       div=st.sampled_from([3e-4, 1.125e-3, 3e-3]))
def test_one_plane_one_echo_at_the_waveform_peak(r, inc_deg, div):
    """A tilted plane across the footprint: exactly one echo, at the maximum of the
    continuous waveform (found by scipy on the defining sum, no grid), with the
    power of the single-return model (its footprint-weighted power)."""
    inc = math.radians(inc_deg)
    rays, _, _ = _beam([1.0, 0.0, 0.0], div)
    n = np.array([-math.cos(inc), math.sin(inc), 0.0])          # plane through (r, 0, 0)
    t = (r * -n[0]) / -(rays @ n)
    cos = np.abs(rays @ n)
    p = ph.power(0.5, cos, t, 0.0)
    e = wf.pulse_echoes(t[None], p[None], W, MODEL)
    assert e.count[0] == 1
    spread = t.max() - t.min()
    peak = minimize_scalar(lambda x: -_ref_waveform([x], t, p * W)[0],
                           bounds=(t.min() - SIGMA, t.max() + SIGMA), method="bounded",
                           options={"xatol": 1e-7}).x
    assert e.range_m[0, 0] == pytest.approx(peak, abs=1e-3)
    assert abs(e.range_m[0, 0] - r) <= spread / 2 + 1e-3
    assert e.power[0, 0] == pytest.approx((p * W).sum(), rel=0.02)


@settings(max_examples=50, deadline=None)
@given(k=st.integers(1, 5), data=st.data())
def test_separated_echoes_found_in_range_order(k, data):
    """k targets filling the beam one after another (each a Gaussian), at least 1.5
    separations apart, powers within 1:10: k echoes, sorted, each within 1 mm."""
    gaps = data.draw(st.lists(st.floats(1.5 * SEP, 6 * SEP), min_size=k, max_size=k))
    r = 1.0 + np.cumsum(gaps)
    p = np.array(data.draw(st.lists(st.floats(1e-4, 1e-3), min_size=k, max_size=k)))
    perm = np.array(data.draw(st.permutations(range(k))))
    e = wf.detect_echoes(r[perm][None], p[perm][None], MODEL)
    assert e.count[0] == k
    np.testing.assert_allclose(e.range_m[0, :k], r, atol=1e-3)
    np.testing.assert_allclose(e.amplitude[0, :k], p, rtol=1e-3)
    assert np.all(np.diff(e.range_m[0, :k]) > SEP)
    assert np.all(np.isinf(e.range_m[0, k:]))


# ------------------------------------------------------------- threshold, chunking
def test_noise_threshold():
    r = np.array([[10.0], [10.0]])
    p = np.array([[0.99e-3], [1.01e-3]])
    e = wf.detect_echoes(r, p, wf.WaveformModel(pulse_fwhm_s=4e-9, threshold_power=1e-3))
    assert list(e.count) == [0, 1]
    # The device threshold: where its detection probability is 1 / (1 + e^4).
    th = wf.detection_threshold(PHYS)
    assert ph.detection_probability(th, PHYS) == pytest.approx(1 / (1 + math.e ** 4),
                                                               rel=1e-9)


def test_chunks_do_not_change_echoes():
    rng = np.random.default_rng(7)
    n = 3 * wf.PULSE_BLOCK + 17
    r = rng.uniform(1, 40, (n, 4))
    r[rng.random((n, 4)) < 0.2] = np.inf
    p = rng.uniform(1e-6, 1e-3, (n, 4))
    whole = wf.detect_echoes(r, p, MODEL)
    parts = [wf.detect_echoes(r[a:b], p[a:b], MODEL) for a, b in [(0, 5), (5, 600),
                                                                  (600, n)]]
    for name in ("range_m", "amplitude", "width_m", "count"):
        got = np.concatenate([getattr(x, name) for x in parts])
        assert np.array_equal(got, getattr(whole, name)), name
    assert np.all(whole.count[np.all(np.isinf(r), axis=1)] == 0)
    # One thread gives the same bits (each pulse is computed alone).
    from raytrace.config import max_threads, set_threads
    set_threads(1)
    try:
        one = wf.detect_echoes(r, p, MODEL)
    finally:
        set_threads(max_threads())
    assert np.array_equal(one.range_m, whole.range_m)


def test_empty_and_bad_input():
    e = wf.detect_echoes(np.empty((0, 3)), np.empty((0, 3)), MODEL)
    assert e.range_m.shape == (0, MODEL.max_echoes) and len(e) == 0
    assert len(wf.select_returns(e, "dual")) == 0
    with pytest.raises(SimulationError, match="Expected `ranges` and `powers`"):
        wf.detect_echoes(np.ones((2, 3)), np.ones((2, 2)), MODEL)
    with pytest.raises(SimulationError, match="powers >= 0"):
        wf.detect_echoes(np.ones((1, 1)), -np.ones((1, 1)), MODEL)
    with pytest.raises(SimulationError, match="pass --returns"):
        wf.select_returns(e, "second")
    with pytest.raises(SimulationError, match="`pulse_fwhm_s`"):
        wf.WaveformModel(pulse_fwhm_s=0.0, threshold_power=0.0)
    with pytest.raises(SimulationError, match="more than one bin"):
        wf.WaveformModel(pulse_fwhm_s=0.2e-9, threshold_power=0.0)


# -------------------------------------------------------------------- return modes
def _reference_pick(r, pw, mode, dual, n_max):
    """The makers' definitions, one pulse at a time (indices of reported echoes)."""
    k = len(r)
    if k == 0:
        return []
    strong = sorted(range(k), key=lambda i: -pw[i])
    if mode == "strongest":
        return [strong[0]]
    if mode == "first":
        return [0]
    if mode == "last":
        return [k - 1]
    if mode == "all":
        return list(range(min(k, n_max)))
    if dual == "first_last":
        return sorted({0, k - 1})
    if dual == "strongest_second":
        return sorted(strong[:2])
    # Velodyne/Hesai: last and strongest; second strongest if the strongest is last.
    if k == 1:
        return [0]
    s = strong[0] if strong[0] != k - 1 else strong[1]
    return sorted({s, k - 1})


@settings(max_examples=60, deadline=None)
@given(data=st.data(), mode=st.sampled_from(wf.RETURN_MODES),
       dual=st.sampled_from(wf.DUAL_KINDS), n_max=st.integers(1, 4))
def test_select_returns_matches_the_definitions(data, mode, dual, n_max):
    n, e = 6, 5
    counts = data.draw(st.lists(st.integers(0, e), min_size=n, max_size=n))
    rng = np.random.default_rng(data.draw(st.integers(0, 2 ** 32 - 1)))
    r = np.sort(rng.uniform(1, 50, (n, e)), axis=1)
    amp = rng.permutation(np.arange(1, n * e + 1, dtype=float)).reshape(n, e)  # no ties
    live = np.arange(e)[None, :] < np.array(counts)[:, None]
    ech = wf.Echoes(np.where(live, r, np.inf), np.where(live, amp, 0.0),
                    np.where(live, MODEL.sigma_m, 0.0), np.array(counts, np.int64),
                    MODEL.sigma_m)
    ret = wf.select_returns(ech, mode, dual=dual, max_returns=n_max)
    row = 0
    for i in range(n):
        want = _reference_pick(r[i, :counts[i]], amp[i, :counts[i]], mode, dual, n_max)
        got = ret.echo[ret.pulse == i]
        assert list(got) == want
        assert list(ret.return_number[ret.pulse == i]) == list(range(1, len(want) + 1))
        assert np.all(ret.number_of_returns[ret.pulse == i] == len(want))
        row += len(want)
    assert len(ret) == row
    assert np.all(np.diff(ret.pulse) >= 0)


# --------------------------------------------------------------- the [returns] table
def test_returns_table():
    spec = wf.ReturnsSpec.from_table({"modes": ["strongest", "last", "dual"],
                                      "dual": "strongest_last", "max_returns": 2,
                                      "pulse_fwhm_ns": 6.0, "pulse_source": "ASSUMED"})
    assert spec.modes == ("strongest", "last", "dual")
    m = spec.model(PHYS)
    assert m.pulse_fwhm_s == pytest.approx(6e-9)
    assert m.threshold_power == pytest.approx(wf.detection_threshold(PHYS))
    assert wf.DEFAULT_RETURNS.modes == ("strongest",)
    with pytest.raises(SensorSpecError, match=r"vlp.toml: Expected \[returns\] keys"):
        wf.ReturnsSpec.from_table({"mode": ["dual"]}, "vlp.toml")
    with pytest.raises(SensorSpecError, match="modes"):
        wf.ReturnsSpec.from_table({"modes": ["dual", "second"], "max_returns": 2})
    with pytest.raises(SensorSpecError, match="max_returns >= 2"):
        wf.ReturnsSpec.from_table({"modes": ["strongest", "dual"]})
    with pytest.raises(SensorSpecError, match="dual in"):
        wf.ReturnsSpec.from_table({"dual": "last_first"})
    with pytest.raises(SensorSpecError, match="pulse_fwhm_ns"):
        wf.ReturnsSpec.from_table({"pulse_fwhm_ns": -1})


# ------------------------------------------------ the simulation loop's entry point
def test_chunk_returns_step_edge_and_dust():
    """Pulse 0 straddles a step (walls 1 m apart, each a pair of faces), pulse 1 meets
    one wall whole, pulse 2 a wall behind dust: the triangles, flags, incidence and
    return numbers of each reported return, from the real ray caster's hits."""
    d, step, half, div = 10.0, 1.0, 5.0, 3e-3
    rays, u, v = _beam([1.0, 0.0, 0.0], div)
    e_v = 0.25 * div * d

    def quad(x, v0, v1):
        return np.array([[x, 0, 0] + a * u + b * v for a, b in
                         [(-half, v0), (half, v0), (half, v1), (-half, v1)]])
    verts = np.concatenate([quad(d, -half, e_v), quad(d + step, e_v, half)])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    scene = Scene(verts, faces)
    # Pulse 1 and 2 aim 1 m off the edge (whole footprint on one wall; the sub-rays'
    # ranges spread 6 mm, under the 1 cm of a mixed return).
    dirs = [np.array([d, 0, 0]), np.array([d, 0, 0]) - 1.0 * v,
            np.array([d, 0, 0]) + 1.0 * v]
    rr, cc, tt, pp = [], [], [], []
    for di in dirs:
        ry, _, _ = _beam(di, div)
        h = scene.cast(np.zeros(3), ry)
        rr.append(h.t)
        cc.append(np.abs(np.einsum("ij,ij->i", h.normals, ry)))
        tt.append(h.triangle)
        pp.append(ph.power(0.5, cc[-1], h.t, 0.0))
    r, cos, tri, p = map(np.array, (rr, cc, tt, pp))
    dust = np.array([np.inf, np.inf, 4.0])
    pdust = ph.power(0.1, 1.0, 4.0, 0.0) * np.ones(3)
    out = wf.chunk_returns(r, p, cos, tri, W, MODEL, "dual", dual="first_last",
                           particle_range_m=dust, particle_power=pdust)
    assert list(out.pulse) == [0, 0, 1, 2, 2]
    assert list(out.return_number) == [1, 2, 1, 1, 2]
    assert list(out.number_of_returns) == [2, 2, 1, 2, 2]
    far = (d + step) * np.hypot(d, 1.0) / d        # along (d, 1) to the plane x = d + step
    np.testing.assert_allclose(out.range_m, [d, d + step, np.hypot(d, 1.0), 4.0, far],
                               atol=2e-3)
    assert set(out.triangle[:1]) <= {0, 1} and set(out.triangle[1:2]) <= {2, 3}
    assert out.triangle[2] in (0, 1) and out.triangle[3] == -1 and out.triangle[4] in (2, 3)
    # Part of the beam on each wall: mixed; the whole beam on one wall: a surface.
    assert list(out.flag) == [ph.FLAG_MIXED, ph.FLAG_MIXED, ph.FLAG_SURFACE,
                              ph.FLAG_PARTICLE, ph.FLAG_SURFACE]
    np.testing.assert_allclose(out.cos[[0, 1, 3]], 1.0, atol=1e-5)
    assert out.cos[2] == pytest.approx(d / np.hypot(d, 1.0), abs=1e-3)
    # The whole-footprint echo has the single-return model's power (sensors.simulate:
    # the footprint-weighted sum over sub-rays); the particle the whole beam's.
    assert out.power[2] == pytest.approx((p[1] * W).sum(), rel=2e-3)
    assert out.power[3] == pytest.approx(pdust[2], rel=1e-6)
    np.testing.assert_allclose(out.width_m[[0, 1, 3]], SIGMA, rtol=1e-3)
    # Strongest mode: one per pulse; the dust-free pulses report what dual did last.
    one = wf.chunk_returns(r, p, cos, tri, W, MODEL, "strongest",
                           particle_range_m=dust, particle_power=pdust)
    assert list(one.pulse) == [0, 1, 2] and np.all(one.number_of_returns == 1)
    assert one.range_m[0] == pytest.approx(d, abs=2e-3)      # 2/3 of the beam is near


def test_all_mode_keeps_up_to_n_echoes():
    """Ten thin targets one behind another (each filling the beam): "all" with N = 10
    reports all ten in range order (more than the waveform's default of 8), N = 3 the
    nearest three."""
    r = 2.0 + 1.5 * np.arange(10)
    ranges = r[None, :]
    p = np.full((1, 10), 1e-3)
    w = np.ones(10)                                 # one "sub-ray" per target, weight 1
    args = (ranges, p, np.ones((1, 10)), np.arange(10, dtype=np.int32)[None], w, MODEL)
    ten = wf.chunk_returns(*args, "all", max_returns=10)
    np.testing.assert_allclose(ten.range_m, r, atol=1e-3)
    assert list(ten.triangle) == list(range(10))
    assert list(ten.return_number) == list(range(1, 11))
    three = wf.chunk_returns(*args, "all", max_returns=3)
    np.testing.assert_allclose(three.range_m, r[:3], atol=1e-3)
    assert np.all(three.number_of_returns == 3)


@settings(max_examples=80, deadline=None)
@given(data=st.data(), m=st.integers(1, 12))
def test_echo_invariants_for_any_contributions(data, m):
    """Whatever the contributions (overlapping, tiny, missing): at most max_echoes
    echoes, sorted by range, each a separation apart (to a bin: the rule is applied to
    the sampled peaks), within a sigma of the contributions, with finite positive
    amplitude and width, and none where the waveform never exceeds the threshold."""
    r = np.array(data.draw(st.lists(st.one_of(st.floats(0.5, 30.0), st.just(np.inf)),
                                    min_size=m, max_size=m)))
    p = np.array(data.draw(st.lists(st.floats(0.0, 1e-2), min_size=m, max_size=m)))
    model = wf.WaveformModel(pulse_fwhm_s=4e-9, threshold_power=1e-5, max_echoes=3)
    e = wf.detect_echoes(r[None], p[None], model)
    k = int(e.count[0])
    assert 0 <= k <= 3
    x = e.range_m[0, :k]
    assert np.all(np.diff(x) >= SEP - MODEL.bin_m)
    live = np.isfinite(r) & (p > 0)
    if k:
        # Where pulses overlap, the decomposition may model a shoulder by a Gaussian
        # centred a little outside the contributions (0.18 m at worst in 1.5 million
        # random pulses): within one sigma.
        assert np.all((x >= r[live].min() - SIGMA) & (x <= r[live].max() + SIGMA))
        assert np.all(np.isfinite(e.amplitude[0, :k]) & (e.amplitude[0, :k] > 0))
        assert np.all(np.isfinite(e.width_m[0, :k]) & (e.width_m[0, :k] > 0))
    if not live.any() or p[live].sum() <= 1e-5:    # the waveform's peak <= sum of powers
        assert k == 0


@settings(max_examples=50, deadline=None)
@given(sizes=st.lists(st.integers(1, 4), min_size=0, max_size=8), data=st.data())
def test_renumber_returns_after_detection(sizes, data):
    """Dropping undetected returns renumbers the rest of each pulse 1..k (reference:
    a loop over pulses)."""
    pulse = np.repeat(np.arange(len(sizes)), sizes)
    keep = np.array(data.draw(st.lists(st.booleans(), min_size=len(pulse),
                                       max_size=len(pulse))), dtype=bool)
    rn, nr = wf.renumber_returns(pulse, keep)
    want_rn, want_nr = [], []
    for i in range(len(sizes)):
        k = int(keep[pulse == i].sum())
        want_rn += list(range(1, k + 1))
        want_nr += [k] * k
    assert list(rn) == want_rn and list(nr) == want_nr
    assert rn.dtype == np.uint8 and nr.dtype == np.uint8
