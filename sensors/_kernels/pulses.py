"""Per-pulse kernels of the simulation loop: beam directions in the world, surface
returns, detection and noise, and the output record. Flat arrays in, flat arrays out;
``prange`` over pulses; random numbers are drawn by the caller (NumPy Generator) so the
result never depends on the thread count.

The return physics (``sensors.physics`` documents the model) is written once, here, as
four scalar functions: received power, detection probability, range sigma and
intensity. Each is compiled twice from the same source: ``@njit`` for the kernels below,
and as a NumPy ufunc (``numba.vectorize``, suffix ``_ufunc``) for the NumPy paths
(``sensors.physics``, the beam-divergence and particle code of ``sensors.simulate``),
in the manner of tinybvh's one ``IntersectTri`` shared by every layout.

DECISION: the formulas live in this file, beside the kernels that call them, not in a
module of their own: Numba's cache checks only a kernel's own source file, so a
formula edited in another file would leave the cached kernels running the old one.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, vectorize

from raytrace.config import CACHE, ERROR_MODEL

#: Powers are floored here before a division or a logarithm (a miss has power 0).
POWER_FLOOR = 1e-300

_F8x4 = ["float64(float64, float64, float64, float64)"]
_F8x3 = ["float64(float64, float64, float64)"]


def _received_power(rho, cos_inc, r, alpha):
    """P = rho cos(theta) / R^2 exp(-2 alpha R): lidar equation for an extended
    Lambertian target with two-way Beer-Lambert extinction (Jelalian 1992)."""
    return rho * cos_inc / (r * r) * np.exp(-2.0 * alpha * r)


def _detection_probability(p, p_min, inv_softness):
    """1 / (1 + (P / P_min)^(-1/softness)): a logistic in ln P, 1/2 at P = P_min."""
    return 1.0 / (1.0 + (max(p, POWER_FLOOR) / p_min) ** (-inv_softness))


def _range_sigma(p, floor2, ref2):
    """sqrt(floor^2 + sigma_ref^2 P_ref / P), ref2 = sigma_ref^2 P_ref: shot-noise-limited
    ranging, sigma ~ 1 / sqrt(SNR), above a floor."""
    return np.sqrt(floor2 + ref2 / max(p, POWER_FLOOR))


def _intensity(p, p_min, log_span):
    """log10(P / P_min) / log10(P_sat / P_min) (log_span = the denominator), clipped to
    [0, 1]: the logarithmic compression of a receiver's dynamic range."""
    v = np.log10(max(p, POWER_FLOOR) / p_min) / log_span
    return min(1.0, max(0.0, v))


received_power = njit(cache=CACHE, error_model=ERROR_MODEL)(_received_power)
detection_probability = njit(cache=CACHE, error_model=ERROR_MODEL)(_detection_probability)
range_sigma = njit(cache=CACHE, error_model=ERROR_MODEL)(_range_sigma)
intensity = njit(cache=CACHE, error_model=ERROR_MODEL)(_intensity)

# Ufuncs: broadcasting, IEEE division (1/0 = inf, with NumPy's warning, which callers
# silence with np.errstate where a zero is expected).
received_power_ufunc = vectorize(_F8x4, cache=CACHE)(_received_power)
detection_probability_ufunc = vectorize(_F8x3, cache=CACHE)(_detection_probability)
range_sigma_ufunc = vectorize(_F8x3, cache=CACHE)(_range_sigma)
intensity_ufunc = vectorize(_F8x3, cache=CACHE)(_intensity)


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def world_directions(d, jit, rot, out):
    """out[i] = R_i (d[i] tilted by jit[i]) for unit d (n, 3); jit (n, 2) radians or
    (0, 2) for no jitter; rot (1, 3, 3) shared or (n, 3, 3) per pulse."""
    n = d.shape[0]
    per = rot.shape[0] == n and n > 1
    tilt = jit.shape[0] == n
    for i in prange(n):
        x, y, z = d[i, 0], d[i, 1], d[i, 2]
        if tilt:
            # Perpendicular basis u = d x a, v = d x u (a = z, or x near the poles).
            if abs(z) < 0.9:
                ux, uy, uz = y, -x, 0.0
            else:
                ux, uy, uz = 0.0, z, -y
            s = 1.0 / np.sqrt(ux * ux + uy * uy + uz * uz)
            ux *= s
            uy *= s
            uz *= s
            vx = y * uz - z * uy
            vy = z * ux - x * uz
            vz = x * uy - y * ux
            a = np.tan(jit[i, 0])
            b = np.tan(jit[i, 1])
            x, y, z = x + a * ux + b * vx, y + a * uy + b * vy, z + a * uz + b * vz
            s = 1.0 / np.sqrt(x * x + y * y + z * z)
            x *= s
            y *= s
            z *= s
        q = np.int64(i)  # prange indices are unsigned: keep q an int64
        if not per:
            q = np.int64(0)
        for k in range(3):
            out[i, k] = rot[q, k, 0] * x + rot[q, k, 1] * y + rot[q, k, 2] * z


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def surface_returns(t, tri, nrm, dw, rho_faces, rho_default, range_min, alpha,
                    r_out, p_out, cos_out, flag_out):
    """Single-ray pulses: range, received power, cosine of incidence and flag
    (1 surface, 0 none) from the cast."""
    use_faces = rho_faces.shape[0] > 0
    for i in prange(t.shape[0]):
        if tri[i] < 0 or t[i] < range_min:
            r_out[i] = np.inf
            p_out[i] = 0.0
            cos_out[i] = 0.0
            flag_out[i] = 0
            continue
        c = abs(nrm[i, 0] * dw[i, 0] + nrm[i, 1] * dw[i, 1] + nrm[i, 2] * dw[i, 2])
        rho = rho_faces[tri[i]] if use_faces else rho_default
        r = t[i]
        r_out[i] = r
        cos_out[i] = c
        p_out[i] = received_power(rho, c, r, alpha)
        flag_out[i] = 1


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def detect_and_noise(r, p, flag, u, z, detect, p_min, inv_soft, noise, floor2, ref2,
                     returned):
    """returned[i]: a return that is detected (u < detection_probability(P)); r[i] gets
    Gaussian noise z range_sigma(P)."""
    for i in prange(r.shape[0]):
        ok = flag[i] > 0
        if ok and detect:
            ok = u[i] < detection_probability(p[i], p_min, inv_soft)
        returned[i] = ok
        if ok and noise:
            r[i] += z[i] * range_sigma(p[i], floor2, ref2)


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def fill_points(idx, r, p, flag, tri, cos, d, t, channel, column, frame, pos, rot,
                p_min, log_span, ox, oy, oz, sx, sy, sz, rng, az, el, tt, ch, co, fr,
                inten, inc, otri, oflag):
    """Output records of the returned pulses idx: sensor-frame point r d, world point
    pos + R (r d), angles (rad), time, indices, intensity, incidence angle (rad)."""
    per = pos.shape[0] > 1
    for j in prange(idx.shape[0]):
        i = idx[j]
        ri = r[i]
        x, y, z = d[i, 0] * ri, d[i, 1] * ri, d[i, 2] * ri
        sx[j] = x
        sy[j] = y
        sz[j] = z
        q = np.int64(i)  # prange indices are unsigned: keep q an int64
        if not per:
            q = np.int64(0)
        ox[j] = pos[q, 0] + rot[q, 0, 0] * x + rot[q, 0, 1] * y + rot[q, 0, 2] * z
        oy[j] = pos[q, 1] + rot[q, 1, 0] * x + rot[q, 1, 1] * y + rot[q, 1, 2] * z
        oz[j] = pos[q, 2] + rot[q, 2, 0] * x + rot[q, 2, 1] * y + rot[q, 2, 2] * z
        rng[j] = ri
        az[j] = np.arctan2(d[i, 1], d[i, 0])
        el[j] = np.arcsin(min(1.0, max(-1.0, d[i, 2])))
        tt[j] = t[i]
        ch[j] = channel[i]
        co[j] = column[i]
        fr[j] = frame[i]
        inten[j] = intensity(p[i], p_min, log_span)
        inc[j] = np.arccos(min(1.0, max(0.0, cos[i])))
        otri[j] = tri[i]
        oflag[j] = flag[i]
