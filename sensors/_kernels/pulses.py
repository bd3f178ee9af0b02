"""Per-pulse kernels of the simulation loop: beam directions in the world, surface
returns, detection and noise, and the output record (``POINT_DTYPE``, or LAS records
straight from the same values: ``las_points``). Flat arrays in, flat arrays out;
``prange`` over pulses (``las_points``: serial, for the writer thread); random numbers
are drawn by the caller (NumPy Generator) so the result never depends on the thread
count.

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
def world_directions(d, jit, rot, which, out):
    """out[i] = R_i (d[i] tilted by jit[i]) for unit d (n, 3); jit (n, 2) radians or
    (0, 2) for no jitter; rot (1, 3, 3) shared or (n, 3, 3) per pulse, or (m, 3, 3)
    with ``which`` (n,) int64 giving each pulse's row (``which`` empty otherwise)."""
    n = d.shape[0]
    per = rot.shape[0] == n and n > 1
    by_row = which.shape[0] > 0
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
        if by_row:
            q = which[i]
        elif not per:
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
                which, p_min, log_span, ox, oy, oz, sx, sy, sz, rng, az, el, tt, ch, co,
                fr, inten, inc, otri, oflag):
    """Output records of the returned pulses idx: sensor-frame point r d, world point
    pos + R (r d), angles (rad), time, indices, intensity, incidence angle (rad).
    pos and rot: one (shape (1, ...)) or one per pulse; with ``which`` (n,) int64 not
    empty, pulse i's matrix is rot[which[i]]."""
    per = pos.shape[0] > 1
    by_row = which.shape[0] > 0
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
        m = which[i] if by_row else q
        ox[j] = pos[q, 0] + rot[m, 0, 0] * x + rot[m, 0, 1] * y + rot[m, 0, 2] * z
        oy[j] = pos[q, 1] + rot[m, 1, 0] * x + rot[m, 1, 1] * y + rot[m, 1, 2] * z
        oz[j] = pos[q, 2] + rot[m, 2, 0] * x + rot[m, 2, 1] * y + rot[m, 2, 2] * z
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


#: float32 degrees per radian as NumPy's float32 ``rad2deg`` takes it (180 / pi, both
#: rounded to float32 first): ``las_points`` gives the scan angle of the LAS writer's
#: ``np.round(np.rad2deg(elevation) / 0.006)`` bit for bit.
DEG_PER_RAD_F4 = np.float32(180.0) / np.float32(np.pi)
#: LAS 1.4 scan angle unit (degrees), as float32 (R15, point data record format 6:
#: 0.006 deg, as the LAS writer divides by it).
SCAN_ANGLE_UNIT_F4 = np.float32(0.006)
#: Largest magnitude of a LAS integer coordinate (int32, as ``sensors.io.las.quantize``).
INT32_LIMIT = 2.0 ** 31 - 1


# DECISION: serial and nogil: it runs on the writer thread (sensors.io.stream.Background)
# beside the simulation's parallel kernels, which must not wait for the GIL meanwhile (a
# 1M-point chunk takes ~50 ms in it, time the main thread would otherwise stand still).
@njit(cache=CACHE, error_model=ERROR_MODEL, nogil=True)
def las_points(idx, r, p, flag, tri, cos, d, t, channel, column, frame, pos, rot, which,
               p_min, log_span, offsets, scales, X, Y, Z, inten, bits, cflags, cls, udata,
               scan, psid, gps, sx, sy, sz, rng, az, el, ch, co, fr, inc, otri, oflag):
    """LAS point format 6 records (with tunnelsim's extra bytes) of the returned pulses
    ``idx``, written straight into the strided fields of a record buffer (X ... gps:
    the dimensions of format 6 in record order; sx ... oflag: extra bytes, named as
    the ``POINT_DTYPE`` fields they hold): what
    ``fill_points`` followed by the LAS writer's packing gives, bit for bit, without the
    ``POINT_DTYPE`` record in between (issue 33).

    Every value is first rounded to its ``POINT_DTYPE`` type (as ``fill_points`` stores
    it), then to the LAS field's type (as NumPy's assignment casts it). Extra-bytes
    outputs of length 0 are not in the file's layout and are skipped. Coordinates:
    ``round((x - offset) / scale)`` (round half to even, as ``np.round``). Returns the
    number of records whose coordinates are NaN or beyond the int32 range (their X, Y,
    Z are then meaningless: the caller raises).
    """
    per = pos.shape[0] > 1
    by_row = which.shape[0] > 0
    has_s = sx.shape[0] > 0
    has_r = rng.shape[0] > 0
    has_az = az.shape[0] > 0
    has_el = el.shape[0] > 0
    has_ch = ch.shape[0] > 0
    has_co = co.shape[0] > 0
    has_fr = fr.shape[0] > 0
    has_inc = inc.shape[0] > 0
    has_tri = otri.shape[0] > 0
    has_flag = oflag.shape[0] > 0
    bad = 0
    for j in range(idx.shape[0]):
        i = idx[j]
        ri = r[i]
        x, y, z = d[i, 0] * ri, d[i, 1] * ri, d[i, 2] * ri
        q = np.int64(i)
        if not per:
            q = np.int64(0)
        m = which[i] if by_row else q
        # The world point exactly as fill_points computes it.
        wx = pos[q, 0] + rot[m, 0, 0] * x + rot[m, 0, 1] * y + rot[m, 0, 2] * z
        wy = pos[q, 1] + rot[m, 1, 0] * x + rot[m, 1, 1] * y + rot[m, 1, 2] * z
        wz = pos[q, 2] + rot[m, 2, 0] * x + rot[m, 2, 1] * y + rot[m, 2, 2] * z
        qx = np.rint((wx - offsets[0]) / scales[0])
        qy = np.rint((wy - offsets[1]) / scales[1])
        qz = np.rint((wz - offsets[2]) / scales[2])
        if not (abs(qx) < INT32_LIMIT and abs(qy) < INT32_LIMIT and abs(qz) < INT32_LIMIT):
            bad += 1
            qx = qy = qz = 0.0
        X[j] = np.int32(qx)
        Y[j] = np.int32(qy)
        Z[j] = np.int32(qz)
        gps[j] = t[i]
        # Intensity: float32 in [0, 1] in the point record, x 65535 in float32, rounded.
        f = np.float32(intensity(p[i], p_min, log_span))
        inten[j] = np.uint16(np.rint(f * np.float32(65535.0)))
        bits[j] = 0x11                       # return 1 of 1 (4 + 4 bits)
        cflags[j] = 0
        cls[j] = 7 if flag[i] == 2 else 0    # particles are noise (class 7)
        e = np.float32(np.arcsin(min(1.0, max(-1.0, d[i, 2]))))
        scan[j] = np.int16(np.rint((e * DEG_PER_RAD_F4) / SCAN_ANGLE_UNIT_F4))
        udata[j] = channel[i] % 256
        psid[j] = frame[i] % 65536
        if has_s:
            sx[j] = x
            sy[j] = y
            sz[j] = z
        if has_r:
            rng[j] = ri
        if has_az:
            az[j] = np.float32(np.arctan2(d[i, 1], d[i, 0]))
        if has_el:
            el[j] = e
        if has_ch:
            ch[j] = channel[i]
        if has_co:
            co[j] = column[i]
        if has_fr:
            fr[j] = frame[i]
        if has_inc:
            inc[j] = np.float32(np.arccos(min(1.0, max(0.0, cos[i]))))
        if has_tri:
            otri[j] = np.int32(tri[i])
        if has_flag:
            oflag[j] = flag[i]
    return bad
