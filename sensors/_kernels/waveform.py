"""Full-waveform kernels: a pulse's received waveform on a time grid and its echoes.

Flat arrays in, flat arrays out; ``prange`` over fixed blocks of pulses, each block with
its own preallocated scratch row (no allocation in the per-pulse loop), so the result
never depends on the thread count (every pulse is computed alone, in the same order of
operations, whichever thread takes its block).

Model (``sensors.waveform`` documents it): pulse i has contributions j at range r[i, j]
(m) with received power p[i, j] (relative units, footprint weight included); each adds
the emitted pulse shape, a Gaussian of standard deviation sigma (m, in range), sampled
at the bin centres (start + b) * bin_m. Echoes are the local maxima above a threshold,
at least a separation apart (the strongest wins), each refined by a Gaussian
decomposition (Wagner et al. 2006): three-point Gaussian fits (Fisher & Naidu 1996) on
the waveform minus the other echoes' fitted Gaussians, repeated a few times.
``attribute_returns`` finds which contribution (face, incidence) an echo stands for.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL

#: Contributions are evaluated out to this many sigma either side (exp(-18) ~ 1.5e-8 of
#: the peak beyond it: below any threshold, as a device's dynamic range is ~1e5).
REACH_SIGMA = 6.0


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _build(r, p, i, start, nb, bin_m, sigma_m, buf):
    """buf[:nb] = the waveform of pulse i: sum_j p[i, j] exp(-(x - r[i, j])^2 / 2 s^2)
    at x = (start + b) bin_m. Non-finite ranges and powers <= 0 add nothing."""
    for b in range(nb):
        buf[b] = 0.0
    s_b = sigma_m / bin_m
    inv2 = 0.5 / (s_b * s_b)
    reach = REACH_SIGMA * s_b
    step4 = np.exp(-32.0 * inv2)
    for j in range(r.shape[1]):
        rj = r[i, j]
        pj = p[i, j]
        if not np.isfinite(rj) or not (pj > 0.0):
            continue
        c = rj / bin_m - start           # the contribution's centre, in bins of the row
        lo = max(0, int(np.ceil(c - reach)))
        hi = min(nb - 1, int(np.floor(c + reach)))
        # exp(-x^2 k) bin by bin without an exp per bin: from x to x + 4 the value is
        # multiplied by q = exp(-(8x + 16) k), and q itself by exp(-32 k) (a rounding
        # of ~1e-16 per step); four interleaved chains (bins lo + s + 4t) keep the
        # multiplications independent, so they pipeline.
        x0 = lo - c
        g0 = pj * np.exp(-x0 * x0 * inv2)
        g1 = pj * np.exp(-(x0 + 1.0) * (x0 + 1.0) * inv2)
        g2 = pj * np.exp(-(x0 + 2.0) * (x0 + 2.0) * inv2)
        g3 = pj * np.exp(-(x0 + 3.0) * (x0 + 3.0) * inv2)
        q0 = np.exp(-(8.0 * x0 + 16.0) * inv2)
        q1 = np.exp(-(8.0 * x0 + 24.0) * inv2)
        q2 = np.exp(-(8.0 * x0 + 32.0) * inv2)
        q3 = np.exp(-(8.0 * x0 + 40.0) * inv2)
        b = lo
        while b + 3 <= hi:
            buf[b] += g0
            buf[b + 1] += g1
            buf[b + 2] += g2
            buf[b + 3] += g3
            g0 *= q0
            g1 *= q1
            g2 *= q2
            g3 *= q3
            q0 *= step4
            q1 *= step4
            q2 *= step4
            q3 *= step4
            b += 4
        if b <= hi:
            buf[b] += g0
        if b + 1 <= hi:
            buf[b + 1] += g1
        if b + 2 <= hi:
            buf[b + 2] += g2


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _gauss3(y0, y1, y2):
    """Three-point Gaussian fit (Fisher & Naidu 1996; Wagner et al. 2006 use Gaussians
    for echoes): the parabola through (-1, ln y0), (0, ln y1), (1, ln y2) is
    ln A - (x - d)^2 / 2 s^2. Returns (ok, d, A, s) in bins; ok False where the three
    values are not positive or not peaked (no maximum)."""
    if not (y0 > 0.0 and y1 > 0.0 and y2 > 0.0):
        return False, 0.0, 0.0, 0.0
    l0 = np.log(y0)
    l1 = np.log(y1)
    l2 = np.log(y2)
    den = l0 - 2.0 * l1 + l2               # 2c: negative at a maximum
    if not (den < 0.0):
        return False, 0.0, 0.0, 0.0
    d = 0.5 * (l0 - l2) / den
    if abs(d) > 1.5:                       # the maximum is too far from the samples
        return False, 0.0, 0.0, 0.0
    s = np.sqrt(-1.0 / den)
    a = np.exp(l1 - 0.125 * (l2 - l0) * (l2 - l0) / den)
    return True, d, a, s


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _others(x, k, n, mu, amp, sig):
    """Sum of the fitted Gaussians of echoes 0..n-1 other than k, at x (bins)."""
    v = 0.0
    for q in range(n):
        if q == k:
            continue
        z = (x - mu[q]) / sig[q]
        v += amp[q] * np.exp(-0.5 * z * z)
    return v


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def detect_echoes(r, p, start, nbins, bin_m, sigma_m, threshold, sep_m, iterations,
                  scratch, cand_b, cand_a, acc, out_r, out_a, out_s, out_count):
    """Echoes of each pulse's waveform.

    r, p : (n, m) float64 contribution ranges (m) and powers; start (n,) int64 first
    bin of each pulse's row ((start + b) bin_m is bin b's range); nbins (n,) int64 its
    length (<= scratch.shape[1]; 0 for no contribution). scratch (k, w) float64 and
    cand_b (k, c) int64, cand_a (k, c) float64, acc (k, 4, e) float64 are one row per
    block of pulses (k blocks). Outputs (n, e): echo range (m, inf where none),
    amplitude, width (sigma, m), sorted by range; out_count (n,) echoes found.
    """
    n = r.shape[0]
    nblk = scratch.shape[0]
    per = (n + nblk - 1) // nblk
    cmax = cand_b.shape[1]
    emax = out_r.shape[1]
    sep_b = sep_m / bin_m
    for k in prange(nblk):
        buf = scratch[k]
        cb = cand_b[k]
        ca = cand_a[k]
        pos = acc[k, 0]
        mu = acc[k, 1]
        amp = acc[k, 2]
        sig = acc[k, 3]
        i0 = k * per
        i1 = min(n, i0 + per)
        for i in range(i0, i1):
            for e in range(emax):
                out_r[i, e] = np.inf
                out_a[i, e] = 0.0
                out_s[i, e] = 0.0
            out_count[i] = 0
            nb = nbins[i]
            if nb < 3:
                continue
            _build(r, p, i, start[i], nb, bin_m, sigma_m, buf)
            # Candidates: local maxima above the noise threshold (a plateau counts
            # once, at its first sample); past cmax the weakest is replaced.
            nc = 0
            for b in range(1, nb - 1):
                y = buf[b]
                if y > threshold and y > buf[b - 1] and y >= buf[b + 1]:
                    if nc < cmax:
                        cb[nc] = b
                        ca[nc] = y
                        nc += 1
                    else:
                        w = 0
                        for q in range(1, cmax):
                            if ca[q] < ca[w]:
                                w = q
                        if y > ca[w]:
                            cb[w] = b
                            ca[w] = y
            # Minimum separation (the receiver's dead time after an echo, about the
            # pulse length x c / 2): strongest first, closer ones dropped.
            ne = 0
            while ne < emax:
                best = -1
                for q in range(nc):
                    if ca[q] > 0.0 and (best < 0 or ca[q] > ca[best]):
                        best = q
                if best < 0:
                    break
                bb = cb[best]
                pos[ne] = bb
                ne += 1
                ca[best] = 0.0
                for q in range(nc):
                    if ca[q] > 0.0 and abs(cb[q] - bb) < sep_b:
                        ca[q] = 0.0
            # First guess: a Gaussian through each peak's three samples.
            for e in range(ne):
                b = int(pos[e])
                ok, d, a, s = _gauss3(buf[b - 1], buf[b], buf[b + 1])
                if ok:
                    mu[e], amp[e], sig[e] = b + d, a, s
                else:
                    mu[e], amp[e], sig[e] = float(b), buf[b], sigma_m / bin_m
            # Gaussian decomposition (Wagner et al. 2006), Gauss-Seidel style: refit
            # each echo on the waveform less the others' Gaussians.
            if ne > 1:
                for _ in range(iterations):
                    for e in range(ne):
                        # The window follows the echo's current centre (its sample
                        # peak sits off-centre where a neighbour's tail leans on it).
                        b = min(nb - 2, max(1, int(np.floor(mu[e] + 0.5))))
                        y0 = buf[b - 1] - _others(b - 1.0, e, ne, mu, amp, sig)
                        y1 = buf[b] - _others(float(b), e, ne, mu, amp, sig)
                        y2 = buf[b + 1] - _others(b + 1.0, e, ne, mu, amp, sig)
                        ok, d, a, s = _gauss3(y0, y1, y2)
                        if ok:
                            mu[e], amp[e], sig[e] = b + d, a, s
            # Out, by range (insertion sort: a handful of echoes).
            for e in range(ne):
                x = (start[i] + mu[e]) * bin_m
                a = amp[e]
                s = sig[e] * bin_m
                q = e
                while q > 0 and out_r[i, q - 1] > x:
                    out_r[i, q] = out_r[i, q - 1]
                    out_a[i, q] = out_a[i, q - 1]
                    out_s[i, q] = out_s[i, q - 1]
                    q -= 1
                out_r[i, q] = x
                out_a[i, q] = a
                out_s[i, q] = s
            out_count[i] = ne


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def sample_waveforms(r, p, start, nbins, bin_m, sigma_m, out):
    """out[i, :nbins[i]] = pulse i's waveform (as in ``detect_echoes``), zeros after."""
    for i in prange(r.shape[0]):
        row = out[i]
        nb = min(nbins[i], row.shape[0])
        _build(r, p, i, start[i], nb, bin_m, sigma_m, row)
        for b in range(nb, row.shape[0]):
            row[b] = 0.0


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def attribute_returns(pulse, x, r, p, n_sub, half_sep, mixed_spread, j_out, mixed_out):
    """For return q (pulse[q], echo range x[q]): j_out[q] = the strongest contribution
    of r, p (n, m) within half_sep of x[q] (the nearest one if none is), and
    mixed_out[q] = its sub-rays (columns < n_sub) within half_sep spread more than
    mixed_spread, or are not all n_sub of them."""
    for q in prange(pulse.shape[0]):
        i = pulse[q]
        best = -1
        best_p = -1.0
        nearest = -1
        nearest_d = np.inf
        lo = np.inf
        hi = -np.inf
        n_in = 0
        for j in range(r.shape[1]):
            rj = r[i, j]
            pj = p[i, j]
            if not (pj > 0.0) or not np.isfinite(rj):
                continue
            dd = abs(rj - x[q])
            if dd < nearest_d:
                nearest_d = dd
                nearest = j
            if dd <= half_sep:
                if pj > best_p:
                    best_p = pj
                    best = j
                if j < n_sub:
                    lo = min(lo, rj)
                    hi = max(hi, rj)
                    n_in += 1
        j_out[q] = best if best >= 0 else nearest
        mixed_out[q] = (hi - lo > mixed_spread) or n_in < n_sub


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def sample_quantised(r, p, src, start, bin_m, sigma_m, inv_gain, top, scratch, out):
    """out[q, b] = min(floor(w(b) inv_gain + 0.5), top) for the waveform w of pulse
    src[q] (as in ``detect_echoes``) on bins start[q] + b, b < out.shape[1]: digitiser
    counts (out an unsigned integer array, rows may be strided; w >= 0, so this rounds
    half up). scratch (k, out.shape[1]) float64: one row per block of rows (k blocks)."""
    n = src.shape[0]
    w = out.shape[1]
    nblk = scratch.shape[0]
    per = (n + nblk - 1) // nblk
    for k in prange(nblk):
        buf = scratch[k]
        for q in range(k * per, min(n, (k + 1) * per)):
            _build(r, p, src[q], start[q], w, bin_m, sigma_m, buf)
            for b in range(w):
                v = np.floor(buf[b] * inv_gain + 0.5)
                out[q, b] = top if v > top else v
