"""Per-pulse kernels of the simulation loop: beam directions in the world, surface
returns, detection and noise, and the output record. Flat arrays in, flat arrays out;
``prange`` over pulses; random numbers are drawn by the caller (NumPy Generator) so the
result never depends on the thread count. Formulas: see ``sensors.physics``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL


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
    """Single-ray pulses: range, relative power rho cos / R^2 exp(-2 alpha R), cosine
    of incidence and flag (1 surface, 0 none) from the cast."""
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
        p_out[i] = rho * c / (r * r) * np.exp(-2.0 * alpha * r)
        flag_out[i] = 1


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def detect_and_noise(r, p, flag, u, z, detect, p_min, inv_soft, noise, floor2, ref2,
                     returned):
    """returned[i]: a return that is detected (u < logistic(ln P/P_min)); r[i] gets
    Gaussian noise z sigma(P), sigma^2 = floor^2 + ref2 / P (ref2 = sigma_ref^2 P_ref)."""
    for i in prange(r.shape[0]):
        ok = flag[i] > 0
        pi = max(p[i], 1e-300)
        if ok and detect:
            ok = u[i] < 1.0 / (1.0 + (pi / p_min) ** (-inv_soft))
        returned[i] = ok
        if ok and noise:
            r[i] += z[i] * np.sqrt(floor2 + ref2 / pi)


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def fill_points(idx, r, p, flag, tri, cos, d, t, channel, column, frame, pos, rot,
                p_min, log_span, ox, oy, oz, sx, sy, sz, rng, az, el, tt, ch, co, fr,
                inten, inc, otri, oflag):
    """Output records of the returned pulses idx: sensor-frame point r d, world point
    pos + R (r d), angles, time, indices, intensity log10(P/P_min)/log_span in [0, 1],
    incidence angle."""
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
        v = np.log10(max(p[i], 1e-300) / p_min) / log_span
        inten[j] = min(1.0, max(0.0, v))
        inc[j] = np.arccos(min(1.0, max(0.0, cos[i])))
        otri[j] = tri[i]
        oflag[j] = flag[i]
