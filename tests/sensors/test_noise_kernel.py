"""The camera's shot and read noise kernel (``sensors._kernels.noise``), against SciPy's
distributions: Poisson draws pass a chi-square test against ``scipy.stats.poisson``
on both sides of the inversion/PTRS switch, the read noise a Kolmogorov-Smirnov test
against the normal; values are independent of their neighbours, of the thread count
and of how the frame is split, and ``expose`` refuses luminance it cannot expose.
Fixed seeds: each test is deterministic (no flaky p-values)."""

from __future__ import annotations

from dataclasses import replace

import numba
import numpy as np
import pytest
from scipy import stats

from sensors._kernels.noise import PTRS_MIN_LAMBDA, shot_and_read
from sensors.camera import load_camera
from sensors.errors import SimulationError
from sensors.shading import expose

_KEY = np.uint64(0x5EED)


def _draw(lam, n=200_000, sigma=0.0, key=_KEY):
    e = np.full(n, float(lam))
    out = np.empty(n)
    assert shot_and_read(e, key, sigma, out) == 0
    return out


def _chi2_pvalue(k, lam):
    """Chi-square goodness of fit of integer draws k against Poisson(lam): bins of
    single values where the expected count is >= 20, the tails pooled."""
    lo, hi = stats.poisson.ppf([1e-6, 1 - 1e-6], lam).astype(int)
    edges = np.arange(lo, hi + 2)
    cdf = stats.poisson.cdf(edges - 1, lam)
    expected = np.diff(np.concatenate([[0.0], cdf[1:-1], [1.0]])) * k.size
    observed = np.histogram(np.clip(k, lo, hi), bins=np.append(edges[:-1], hi + 1))[0]
    # Pool neighbouring bins until each expects >= 20 draws.
    obs_p, exp_p, o_acc, e_acc = [], [], 0.0, 0.0
    for o, e in zip(observed, expected):
        o_acc += o
        e_acc += e
        if e_acc >= 20.0:
            obs_p.append(o_acc)
            exp_p.append(e_acc)
            o_acc = e_acc = 0.0
    obs_p[-1] += o_acc
    exp_p[-1] += e_acc
    exp_p = np.array(exp_p) * (sum(obs_p) / sum(exp_p))
    return stats.chisquare(obs_p, exp_p).pvalue


@pytest.mark.parametrize("lam", [0.02, 0.7, 3.0, 9.999, PTRS_MIN_LAMBDA, 10.5, 37.2,
                                 400.0, 2.5e4])
def test_shot_noise_is_poisson(lam):
    k = _draw(lam)
    assert np.array_equal(k, np.round(k)) and k.min() >= 0
    n = k.size
    assert abs(k.mean() - lam) <= 5 * np.sqrt(lam / n)
    # Var of the sample variance of a Poisson: (lam + 2 lam^2 (n/(n-1))) / n ~ 2 lam^2/n
    assert abs(k.var() - lam) <= 5 * np.sqrt((lam + 2 * lam * lam) / n)
    assert _chi2_pvalue(k, lam) > 1e-4


def test_zero_electrons_give_zero_shot_noise():
    assert np.array_equal(_draw(0.0, 1000), np.zeros(1000))


def test_read_noise_is_normal_with_its_sigma():
    x = _draw(0.0, sigma=3.5)
    assert stats.kstest(x, stats.norm(0.0, 3.5).cdf).pvalue > 1e-4
    assert abs(x.std() - 3.5) < 5 * 3.5 / np.sqrt(2 * x.size)


def test_neighbouring_values_and_keys_are_independent():
    a = _draw(50.0, 400_000)
    r = np.corrcoef(a[:-1], a[1:])[0, 1]
    assert abs(r) < 5 / np.sqrt(a.size)
    b = _draw(50.0, 400_000, key=_KEY + np.uint64(1))
    assert abs(np.corrcoef(a, b)[0, 1]) < 5 / np.sqrt(a.size)
    assert not np.array_equal(a, b)


def test_the_same_values_for_any_thread_count_and_split():
    e = np.random.default_rng(2).uniform(0.0, 200.0, 300_001)
    outs = []
    before = numba.get_num_threads()
    try:
        for threads in (1, numba.config.NUMBA_NUM_THREADS):
            numba.set_num_threads(threads)
            out = np.empty_like(e)
            shot_and_read(e, _KEY, 2.0, out)
            outs.append(out)
    finally:
        numba.set_num_threads(before)
    np.testing.assert_array_equal(outs[0], outs[1])
    # Value i depends on (key, i) only: a frame's every value, drawn alone, is the same.
    for i in (0, 7, 150_000, 300_000):
        one = np.empty(i + 1)
        shot_and_read(np.where(np.arange(i + 1) == i, e[i], 0.0), _KEY, 2.0, one)
        assert one[i] == outs[0][i]


def test_expose_draws_with_its_seed_and_refuses_bad_luminance():
    cam = replace(load_camera("realsense_d435_color"), auto_exposure=False)
    lum = np.full((40, 60, 3), 0.5)
    a, b = expose(cam, lum, seed=11), expose(cam, lum, seed=11)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, expose(cam, lum, seed=12))
    for bad in (np.nan, -1.0, np.inf):
        lum2 = lum.copy()
        lum2[3, 4, 1] = bad
        with pytest.raises(SimulationError, match="Expected finite, non-negative"):
            expose(cam, lum2, seed=1)
