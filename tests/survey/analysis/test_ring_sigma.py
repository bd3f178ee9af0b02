"""Formal standard deviations of ring diameters (issue 31, item 5: "ring diameters
without σ"): against the closed form 2 σ / sqrt(n) of a full circle with evenly spread
points, and against the Monte Carlo spread of repeated fits to noisy rings (seeded;
tolerances from the spread of a standard deviation estimated from N samples,
about 1 / sqrt(2 N): 4 % for N = 300, taken 4x)."""

from __future__ import annotations

import numpy as np
import pytest

from survey.analysis.rings import fit_circle, fit_ellipse


def _ring(a, b, n, sigma, rng, angle=0.3):
    t = rng.uniform(0, 2 * np.pi, n)
    u, v = a * np.cos(t), b * np.sin(t)
    c, s = np.cos(angle), np.sin(angle)
    p = np.column_stack([c * u - s * v + 0.5, s * u + c * v + 3.0])
    # noise along the normal of the true shape (orthogonal distance)
    nrm = np.column_stack([b * np.cos(t), a * np.sin(t)])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm = np.column_stack([c * nrm[:, 0] - s * nrm[:, 1], s * nrm[:, 0] + c * nrm[:, 1]])
    return p + nrm * rng.normal(0, sigma, (n, 1))


def test_circle_diameter_sigma_matches_the_closed_form():
    rng = np.random.default_rng(5)
    n, sigma = 400, 0.002
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 3.0 + rng.normal(0, sigma, n)
    fit = fit_circle(np.column_stack([r * np.cos(t), r * np.sin(t)]), reject_sigma=None)
    # full circle, even angles: Var(r) = sigma^2 / n, D = 2 r
    assert fit.diameter_sigma_m == pytest.approx(2 * sigma / np.sqrt(n), rel=0.15)


def test_diameter_sigmas_match_the_monte_carlo_spread():
    rng = np.random.default_rng(11)
    dc, sc, dmax, smax, dmin, smin = [], [], [], [], [], []
    for _ in range(300):
        p = _ring(3.2, 2.9, 150, 0.003, rng)
        ci = fit_circle(_ring(3.0, 3.0, 150, 0.003, rng), reject_sigma=None)
        el = fit_ellipse(p, reject_sigma=None)
        dc.append(ci.diameter_m)
        sc.append(ci.diameter_sigma_m)
        dmax.append(el.diameters_m[0])
        dmin.append(el.diameters_m[1])
        smax.append(el.diameters_sigma_m[0])
        smin.append(el.diameters_sigma_m[1])
    assert np.std(dc, ddof=1) == pytest.approx(np.mean(sc), rel=0.16)
    assert np.std(dmax, ddof=1) == pytest.approx(np.mean(smax), rel=0.16)
    assert np.std(dmin, ddof=1) == pytest.approx(np.mean(smin), rel=0.16)
