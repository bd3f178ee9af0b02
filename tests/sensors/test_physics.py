"""Return physics against its documented model (``sensors.physics``), written out here
in plain NumPy float64: the formulas, the one-source rule (Numba kernels and NumPy
paths run the same compiled formula), and a seeded run whose every returned point is
predicted from the documented formulas and the documented random streams."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import sweep_profile
from sensors import ProfileScan, Settings, Trajectory, load_sensor, simulate_drive
from sensors import physics as ph
from sensors._kernels import pulses as kern
from sensors.simulate import RANDOM_BLOCK

PROFILER = load_sensor("zf_profiler_9012")
PHYS = PROFILER.physics


# ---------------------------------------------------------------- the model, by hand
def _power(rho, cos, r, alpha):
    return rho * cos / r ** 2 * np.exp(-2.0 * alpha * r)


def _p_min(phys):
    return phys.detection_reflectivity / phys.detection_range_m ** 2


def _probability(p, phys):
    return 1.0 / (1.0 + (p / _p_min(phys)) ** (-1.0 / phys.detection_softness))


def _sigma(p, phys):
    p_ref = phys.reference_reflectivity / phys.reference_range_m ** 2
    return np.sqrt(phys.range_sigma_floor_m ** 2 + phys.range_sigma_m ** 2 * p_ref / p)


def _intensity(p, phys):
    p_sat = 1.0 / max(phys.range_min_m, 0.1) ** 2
    x = np.log10(p / _p_min(phys)) / np.log10(p_sat / _p_min(phys))
    return np.clip(x, 0.0, 1.0)


def test_formulas_follow_the_documented_model():
    rng = np.random.default_rng(0)
    rho, cos = rng.uniform(0.01, 1, 5000), rng.uniform(0.05, 1, 5000)
    r, alpha = 10 ** rng.uniform(-1.5, 2.1, 5000), rng.uniform(0, 0.01, 5000)
    p = ph.power(rho, cos, r, alpha)
    # A few ulp: NumPy's SIMD exp and pow (the reference) and libm's (the formula, in
    # Numba) round differently in the last bit for a few per cent of inputs.
    np.testing.assert_array_max_ulp(p, _power(rho, cos, r, alpha), maxulp=2)
    np.testing.assert_array_max_ulp(ph.detection_probability(p, PHYS), _probability(p, PHYS),
                                    maxulp=4)
    np.testing.assert_array_max_ulp(ph.range_sigma(p, PHYS), _sigma(p, PHYS), maxulp=1)
    got = ph.intensity(p, PHYS)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, _intensity(p, PHYS), rtol=0, atol=2e-7)
    assert np.mean(got == 0) > 0.01 and np.mean(got == 1) > 0.01   # both clips, and
    assert np.mean((got > 0.1) & (got < 0.9)) > 0.3                # the scale between


def test_edge_values():
    assert ph.power(0.5, 1.0, 0.0, 0.0) == np.inf         # R = 0, no warning raised
    assert ph.detection_probability(0.0, PHYS) == 0.0      # a miss is never detected
    assert ph.detection_probability(_p_min(PHYS), PHYS) == pytest.approx(0.5, abs=1e-15)
    assert ph.detection_probability(1e300, PHYS) == 1.0
    assert ph.intensity(0.0, PHYS) == 0.0 and ph.intensity(1e9, PHYS) == 1.0
    assert np.isfinite(ph.range_sigma(0.0, PHYS))         # floored power, not inf


@settings(max_examples=200, deadline=None)
@given(rho=st.floats(0.0, 1.0), cos=st.floats(0.0, 1.0), r=st.floats(1e-3, 1e4),
       alpha=st.floats(0.0, 1.0), soft=st.floats(0.01, 2.0))
def test_kernels_and_numpy_paths_share_one_formula(rho, cos, r, alpha, soft):
    """The scalar functions the kernels call and the ufuncs sensors.physics calls are
    compiled from the same source: equal to the last bit."""
    p = kern.received_power(rho, cos, r, alpha)
    assert p == ph.power(rho, cos, r, alpha) or (np.isnan(p) and np.isnan(
        ph.power(rho, cos, r, alpha)))
    p_min, inv = 1e-4, 1.0 / soft
    with np.errstate(over="ignore", divide="ignore"):     # (P / P_min)^-k may overflow
        assert kern.detection_probability(p, p_min, inv) == \
            kern.detection_probability_ufunc(p, p_min, inv)
        assert kern.range_sigma(p, 1e-8, 3e-9) == kern.range_sigma_ufunc(p, 1e-8, 3e-9)
        assert kern.intensity(p, p_min, 5.0) == kern.intensity_ufunc(p, p_min, 5.0)


# ---------------------------------------------------------------- a seeded run, predicted
@pytest.fixture(scope="module")
def tube():
    """A closed 64-gon tube along x (radius 2 m): a profiler on its axis, scanning the
    y-z plane, hits the lining with every pulse."""
    k = 64
    ang = 2 * np.pi * np.arange(k) / k
    v, f = sweep_profile(np.stack([2.0 * np.cos(ang), 2.0 * np.sin(ang)], 1), 60.0, 31,
                         closed_ends=True)
    return Scene(v, f)


def test_a_seeded_run_is_the_documented_model(tube):
    """Every point of a seeded profiler run (detection, range noise, attenuation and a
    reflectivity per face; no angular jitter) follows from the geometry, the formulas
    above and the random streams of the physics doc: detection uses stream 3 (uniform),
    range noise stream 4 (standard normal), each drawn in blocks of RANDOM_BLOCK pulses
    from default_rng([seed, stream, block])."""
    seed, alpha, t_end = 11, 0.05, 0.01
    # Reflectivities from 1e-5 to 1e-3: detection probabilities across (0, 1) at 2 m.
    rho = 10 ** np.random.default_rng(1).uniform(-5.0, -3.0, len(tube.faces))
    traj = Trajectory.static([30.0, 0.0, 0.0])
    ideal = np.concatenate(list(simulate_drive(
        tube, PROFILER, traj, settings=Settings(range_noise=False, angle_jitter=False,
                                                detection=False, attenuation_per_m=alpha),
        reflectivity=rho, t_end=t_end)))
    scan = ProfileScan(PROFILER, t_end)
    n = scan.n_pulses
    assert len(ideal) == n < RANDOM_BLOCK                  # every pulse hits, one block
    d = np.concatenate([c.direction for c in scan.chunks()])
    v, f = tube.vertices, tube.faces[ideal["triangle"]]
    nrm = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    cos = np.abs(np.einsum("ij,ij->i", nrm, d))
    r0 = ideal["range"]
    p = _power(rho[ideal["triangle"]], cos, r0, alpha)

    run = simulate_drive(tube, PROFILER, traj, seed=seed, reflectivity=rho, t_end=t_end,
                         settings=Settings(angle_jitter=False, attenuation_per_m=alpha))
    got = np.concatenate(list(run))
    u = np.random.default_rng([seed, 3, 0]).random((RANDOM_BLOCK, 1))[:n, 0]
    z = np.random.default_rng([seed, 4, 0]).standard_normal((RANDOM_BLOCK, 1))[:n, 0]
    prob = _probability(p, PHYS)
    assert 0.2 < prob.mean() < 0.8
    detected = np.flatnonzero(u < prob)
    i = np.searchsorted(ideal["time"], got["time"])        # pulse of each point
    np.testing.assert_array_equal(i, detected)
    np.testing.assert_allclose(got["range"], r0[i] + z[i] * _sigma(p[i], PHYS), rtol=0,
                               atol=1e-12)
    assert np.std(got["range"] - r0[i]) > 1e-3             # the noise is really there
    want = _intensity(p[i], PHYS).astype(np.float32)
    np.testing.assert_array_max_ulp(got["intensity"], want, maxulp=1)
    np.testing.assert_allclose(got["incidence"], np.arccos(cos[i]), atol=1e-6)
