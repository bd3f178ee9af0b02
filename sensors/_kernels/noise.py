"""Shot and read noise of a camera frame in one parallel pass (``sensors.shading.expose``).

Each value i of the frame gets its own stream of random numbers: outputs i * 2^20 + 1,
i * 2^20 + 2, ... of one SplitMix64 sequence seeded by the frame's key (Steele, Lea &
Flood 2014, "Fast splittable pseudorandom number generators", OOPSLA: state += the
golden gamma 0x9E3779B97F4A7C15, then the variant-13 mix). Since the gamma is odd, the
states of different values never meet, so a value depends only on (key, i): the frame
is the same for any thread count and any split of the work.

- Shot noise, Poisson(lam): inversion by sequential search below ``PTRS_MIN_LAMBDA``
  (Devroye 1986, *Non-Uniform Random Variate Generation*, X.3.3), Hörmann's
  transformed rejection with squeeze (PTRS) at and above it (W. Hörmann 1993, "The
  transformed rejection method for generating Poisson random variables", Insurance:
  Mathematics and Economics 12, 39-45: the constants below are the paper's). Exact
  for every lam: no normal approximation.
- Read noise, N(0, sigma): Box-Muller (Box & Muller 1958), the cosine branch.

DECISION: a parallel kernel instead of NumPy's ``Generator.poisson`` + ``normal``,
which run on one core: for a 1920x1080 colour frame (6.2M values) both take ~0.3 s of
CPU (kernel 0.33, NumPy 0.29 on the 2-core VM), so the frame's wall time gains what
the other cores take (half on two cores, more on a workstation). The noise is the same
distribution, not the same numbers.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL

#: SplitMix64's increment (the golden gamma) and its mix multipliers (Steele et al.
#: 2014; the mix is Stafford's variant 13).
_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
#: Outputs reserved for each value (2^20: PTRS needs ~1.1 pairs of uniforms a value on
#: average; a value that would need more than half a million draws does not occur).
STREAM_STRIDE = np.uint64(1 << 20)
#: Below this mean, inversion (a short search); at and above, PTRS (valid for >= 10).
PTRS_MIN_LAMBDA = 10.0
_TWO_PI = 2.0 * math.pi


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _mix(z):
    """SplitMix64's output function of a state (uint64)."""
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _uniform(state):
    """(next state, u) with u uniform in the open interval (0, 1): the top 53 bits of
    the next output, plus half a step."""
    state = state + _GAMMA
    u = (np.float64(_mix(state) >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
    return state, u


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _poisson(lam, state):
    """(next state, k): a Poisson(lam) draw, lam >= 0 finite."""
    if lam < PTRS_MIN_LAMBDA:
        # Sequential search of the cumulative distribution (Devroye X.3.3).
        state, u = _uniform(state)
        k = 0.0
        p = math.exp(-lam)
        s = p
        while u > s and p > 0.0:
            k += 1.0
            p *= lam / k
            s += p
        return state, k
    # PTRS (Hörmann 1993, algorithm PTRS with its constants).
    slam = math.sqrt(lam)
    loglam = math.log(lam)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    inv_alpha = 1.1239 + 1.1328 / (b - 3.4)
    vr = 0.9277 - 3.6224 / (b - 2.0)
    while True:
        state, u = _uniform(state)
        state, v = _uniform(state)
        u -= 0.5
        us = 0.5 - abs(u)
        k = np.floor((2.0 * a / us + b) * u + lam + 0.43)
        if us >= 0.07 and v <= vr:
            return state, k
        if k < 0.0 or (us < 0.013 and v > us):
            continue
        if math.log(v) + math.log(inv_alpha) - math.log(a / (us * us) + b) <= \
                -lam + k * loglam - math.lgamma(k + 1.0):
            return state, k


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def shot_and_read(e, key, read_sigma, out):  # pragma: no cover (Numba)
    """out[i] = Poisson(e[i]) + N(0, read_sigma) for the flat electron counts ``e``
    (float64), value i drawn from its own stream of the sequence seeded by ``key``
    (uint64). Returns how many ``e`` were not finite or negative (their ``out`` is
    NaN): the caller refuses those."""
    bad = 0
    for i in prange(e.shape[0]):
        lam = e[i]
        state = key + np.uint64(i) * STREAM_STRIDE * _GAMMA
        if not (lam >= 0.0 and lam < np.inf):
            out[i] = np.nan
            bad += 1
            continue
        state, k = _poisson(lam, state)
        state, u1 = _uniform(state)
        state, u2 = _uniform(state)
        out[i] = k + read_sigma * math.sqrt(-2.0 * math.log(u1)) * math.cos(_TWO_PI * u2)
    return bad


__all__ = ["PTRS_MIN_LAMBDA", "STREAM_STRIDE", "shot_and_read"]
