"""M3C2 kernels (Lague, Brodu & Leroux 2013, ISPRS J. 82:10-26): a uniform grid over
an epoch's points, multiscale normals, and the cylinder statistics per core point.

Grid layout (one per epoch; built by ``survey.analysis.m3c2.EpochGrid``):

    pts   (n, 3) float64   points in local coordinates, sorted by cell key (24 B/point)
    keys  (n,)   int64     cell key of each sorted point, ascending        (8 B/point)
    lo    (3,)   float64   corner of cell (0, 0, 0)
    dims  (3,)   int64     cells per axis (nx, ny, nz)
    h            float64   cell edge

A cell (ix, iy, iz) has key (ix * ny + iy) * nz + iz, so the cells of one (ix, iy)
column from iz0 to iz1 hold one contiguous run of ``pts``: a box query costs one pair
of binary searches per column, and the points come in memory order.

Every query visits the cells of a box and tests each point exactly; the box only
bounds the work. Kernels run over core points in blocks of ``CORE_BLOCK`` (fixed, so
results never depend on the thread count); each block owns one scratch buffer.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL

#: Core points one worker handles in sequence (one scratch buffer per block).
CORE_BLOCK = 64
#: Initial length of a block's buffer of projections; it doubles when a cylinder holds
#: more points.
BUFFER0 = 1024
#: Cyclic Jacobi sweeps for a 3 x 3 symmetric eigenproblem (converges in ~5; the
#: off-diagonal test ends it earlier).
JACOBI_SWEEPS = 32


@njit(cache=CACHE, error_model=ERROR_MODEL)
def cell_keys(points, lo, inv_h, dims, out):
    """Cell key of each point (n, 3) into out (n,) int64; cells clipped to the grid."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    for i in range(points.shape[0]):
        ix = min(max(np.int64(np.floor((points[i, 0] - lo[0]) * inv_h)), 0), nx - 1)
        iy = min(max(np.int64(np.floor((points[i, 1] - lo[1]) * inv_h)), 0), ny - 1)
        iz = min(max(np.int64(np.floor((points[i, 2] - lo[2]) * inv_h)), 0), nz - 1)
        out[i] = (ix * ny + iy) * nz + iz


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _cell_range(x0, x1, lo, h, n):
    """First and last cell index along one axis covering [x0, x1], clipped."""
    a = np.int64(np.floor((x0 - lo) / h))
    b = np.int64(np.floor((x1 - lo) / h))
    return max(a, 0), min(b, n - 1)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def sym3_eigen(a, vals, vecs):
    """Eigenvalues (ascending, into vals (3,)) and unit eigenvectors (columns of vecs
    (3, 3)) of the symmetric 3 x 3 matrix a (not changed); cyclic Jacobi rotations
    (Golub & Van Loan 2013, 8.5.2)."""
    m = a.copy()
    v = np.eye(3)
    for _ in range(JACOBI_SWEEPS):
        off = m[0, 1] ** 2 + m[0, 2] ** 2 + m[1, 2] ** 2
        scale = m[0, 0] ** 2 + m[1, 1] ** 2 + m[2, 2] ** 2
        if off <= 1e-32 * scale or off == 0.0:
            break
        for p in range(2):
            for q in range(p + 1, 3):
                if m[p, q] == 0.0:
                    continue
                # Symmetric Schur 2 x 2 (G&VL Algorithm 8.5.1): c, s zeroing m[p, q].
                tau = (m[q, q] - m[p, p]) / (2.0 * m[p, q])
                t = (1.0 if tau >= 0.0 else -1.0) / (abs(tau) + np.sqrt(1.0 + tau * tau))
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = t * c
                for k in range(3):                      # m <- J^T m J
                    mkp, mkq = m[k, p], m[k, q]
                    m[k, p] = c * mkp - s * mkq
                    m[k, q] = s * mkp + c * mkq
                for k in range(3):
                    mpk, mqk = m[p, k], m[q, k]
                    m[p, k] = c * mpk - s * mqk
                    m[q, k] = s * mpk + c * mqk
                for k in range(3):                      # v <- v J
                    vkp, vkq = v[k, p], v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq
    d0, d1, d2 = m[0, 0], m[1, 1], m[2, 2]
    i0, i1, i2 = 0, 1, 2                                # sort ascending
    if d0 > d1:
        d0, d1, i0, i1 = d1, d0, i1, i0
    if d1 > d2:
        d1, d2, i1, i2 = d2, d1, i2, i1
    if d0 > d1:
        d0, d1, i0, i1 = d1, d0, i1, i0
    vals[0], vals[1], vals[2] = d0, d1, d2
    for k in range(3):
        vecs[k, 0], vecs[k, 1], vecs[k, 2] = v[k, i0], v[k, i1], v[k, i2]


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _ball_cov(pts, keys, lo, h, dims, cx, cy, cz, radius, cov):
    """Sample covariance (ddof 1) of the points within ``radius`` of c into cov (3, 3),
    about the core point to keep the sums small; returns the count."""
    ny, nz = dims[1], dims[2]
    ax0, ax1 = _cell_range(cx - radius, cx + radius, lo[0], h, dims[0])
    ay0, ay1 = _cell_range(cy - radius, cy + radius, lo[1], h, dims[1])
    az0, az1 = _cell_range(cz - radius, cz + radius, lo[2], h, dims[2])
    r2 = radius * radius
    m = 0
    sx = sy = sz = sxx = sxy = sxz = syy = syz = szz = 0.0
    for ix in range(ax0, ax1 + 1):
        for iy in range(ay0, ay1 + 1):
            base = (ix * ny + iy) * nz
            a = np.searchsorted(keys, base + az0)
            b = np.searchsorted(keys, base + az1, side="right")
            for j in range(a, b):
                x, y, z = pts[j, 0] - cx, pts[j, 1] - cy, pts[j, 2] - cz
                if x * x + y * y + z * z <= r2:
                    m += 1
                    sx += x
                    sy += y
                    sz += z
                    sxx += x * x
                    sxy += x * y
                    sxz += x * z
                    syy += y * y
                    syz += y * z
                    szz += z * z
    if m < 2:
        return m
    f = 1.0 / (m - 1)
    mx, my, mz = sx / m, sy / m, sz / m
    cov[0, 0] = (sxx - m * mx * mx) * f
    cov[0, 1] = cov[1, 0] = (sxy - m * mx * my) * f
    cov[0, 2] = cov[2, 0] = (sxz - m * mx * mz) * f
    cov[1, 1] = (syy - m * my * my) * f
    cov[1, 2] = cov[2, 1] = (syz - m * my * mz) * f
    cov[2, 2] = (szz - m * mz * mz) * f
    return m


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def multiscale_normals(pts, keys, lo, h, dims, cores, radii, orient, out_n, out_r):
    """M3C2 normals (Lague et al. 2013, 3.2): at each core point (n, 3) and each radius
    of ``radii`` (k,), the eigenvector of the smallest eigenvalue of the neighbours'
    covariance; the radius with the highest planarity (l1 - l0) / l2 wins (the first
    on ties; py4dgeo's rule). The normal is flipped so that its dot product with
    ``orient`` (row i, or row 0 when it has one row) is >= 0. Writes out_n (n, 3) and
    the radius used out_r (n,); NaN where no radius gave a planarity above 0 (fewer
    than three points, or collinear ones)."""
    n = cores.shape[0]
    nblocks = (n + CORE_BLOCK - 1) // CORE_BLOCK
    for blk in prange(nblocks):
        cov = np.zeros((3, 3))
        vals = np.empty(3)
        vecs = np.empty((3, 3))
        for i in range(blk * CORE_BLOCK, min(n, (blk + 1) * CORE_BLOCK)):
            o = i if orient.shape[0] > 1 else 0
            best = 0.0
            out_n[i, 0] = out_n[i, 1] = out_n[i, 2] = np.nan
            out_r[i] = np.nan
            for r in radii:
                m = _ball_cov(pts, keys, lo, h, dims, cores[i, 0], cores[i, 1],
                              cores[i, 2], r, cov)
                if m < 3:
                    continue
                sym3_eigen(cov, vals, vecs)
                plan = (vals[1] - vals[0]) / vals[2]
                if plan > best:
                    best = plan
                    dot = (vecs[0, 0] * orient[o, 0] + vecs[1, 0] * orient[o, 1]
                           + vecs[2, 0] * orient[o, 2])
                    sgn = -1.0 if dot < 0.0 else 1.0
                    out_n[i, 0] = sgn * vecs[0, 0]
                    out_n[i, 1] = sgn * vecs[1, 0]
                    out_n[i, 2] = sgn * vecs[2, 0]
                    out_r[i] = r


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _cylinder(pts, keys, lo, h, dims, c, nv, radius, half_len, n_slabs, buf):
    """Projections t = (p - c) . nv of the points in the cylinder of axis nv through c,
    |t| <= half_len and distance to the axis <= radius, into buf. Returns the count;
    when it exceeds len(buf), only the count is right (the caller grows buf and asks
    again).

    The cylinder is cut into ``n_slabs`` slabs along the axis (as py4dgeo cuts it:
    ceil(half_len / radius)); each slab visits the cells of its own bounding box, so
    a long oblique cylinder does not visit its whole box. A point is taken by the slab
    its t falls in only, so it counts once."""
    ny, nz = dims[1], dims[2]
    r2 = radius * radius
    slab = 2.0 * half_len / n_slabs
    m = 0
    for k in range(n_slabs):
        t0 = -half_len + k * slab                      # this slab: t in [t0, t0 + slab]
        tm = t0 + 0.5 * slab
        qx, qy, qz = c[0] + tm * nv[0], c[1] + tm * nv[1], c[2] + tm * nv[2]
        # Box of a cylinder of half-length slab/2 and radius r with unit axis nv:
        # extent along axis j is (slab/2)|nv_j| + r sqrt(1 - nv_j^2).
        ex = 0.5 * slab * abs(nv[0]) + radius * np.sqrt(max(0.0, 1.0 - nv[0] * nv[0]))
        ey = 0.5 * slab * abs(nv[1]) + radius * np.sqrt(max(0.0, 1.0 - nv[1] * nv[1]))
        ez = 0.5 * slab * abs(nv[2]) + radius * np.sqrt(max(0.0, 1.0 - nv[2] * nv[2]))
        ax0, ax1 = _cell_range(qx - ex, qx + ex, lo[0], h, dims[0])
        ay0, ay1 = _cell_range(qy - ey, qy + ey, lo[1], h, dims[1])
        az0, az1 = _cell_range(qz - ez, qz + ez, lo[2], h, dims[2])
        for ix in range(ax0, ax1 + 1):
            for iy in range(ay0, ay1 + 1):
                base = (ix * ny + iy) * nz
                a = np.searchsorted(keys, base + az0)
                b = np.searchsorted(keys, base + az1, side="right")
                for j in range(a, b):
                    x, y, z = pts[j, 0] - c[0], pts[j, 1] - c[1], pts[j, 2] - c[2]
                    t = x * nv[0] + y * nv[1] + z * nv[2]
                    if abs(t) > half_len:
                        continue
                    kk = min(np.int64(np.floor((t + half_len) / slab)), n_slabs - 1)
                    if kk != k:
                        continue
                    px, py, pz = x - t * nv[0], y - t * nv[1], z - t * nv[2]
                    if px * px + py * py + pz * pz <= r2:
                        if m < buf.shape[0]:
                            buf[m] = t
                        m += 1
    return m


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _quartile(a, m, pos, average):
    """a[pos], or the mean of a[pos - 1] and a[pos] (a sorted; py4dgeo's rule)."""
    return 0.5 * (a[pos - 1] + a[pos]) if average and pos > 0 else a[pos]


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _summary(buf, m, robust, out):
    """(centre, spread) of buf[:m] into out (2,): mean and standard deviation (ddof 1),
    or with ``robust`` the median and interquartile range as py4dgeo takes them
    (sorted a: q at n/4, n/2, 3n/4, each averaged with its left neighbour when n is
    divisible by 4, 2, 4). NaN for m = 0 (and a NaN spread for m = 1, mean)."""
    if m == 0:
        out[0] = out[1] = np.nan
        return
    if robust:
        a = buf[:m]
        a.sort()
        q1 = _quartile(a, m, m // 4, m % 4 == 0)
        q2 = _quartile(a, m, m // 2, m % 2 == 0)
        q3 = _quartile(a, m, (3 * m) // 4, m % 4 == 0)
        out[0] = q2
        out[1] = q3 - q1
        return
    s = 0.0
    for j in range(m):
        s += buf[j]
    mean = s / m
    ss = 0.0
    for j in range(m):
        d = buf[j] - mean
        ss += d * d
    out[0] = mean
    out[1] = np.sqrt(ss / (m - 1)) if m > 1 else np.nan


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def cylinder_stats(g1_pts, g1_keys, g1_lo, g1_h, g1_dims, g2_pts, g2_keys, g2_lo, g2_h,
                   g2_dims, cores, normals, radius, half_len, n_slabs, robust,
                   out_c1, out_s1, out_n1, out_c2, out_s2, out_n2):
    """Per core point i (cores (n, 3), normals (n, 3)): centre (mean or median of the
    projections t) out_c*, spread (std or IQR) out_s* and count out_n* of epoch 1 and
    2 in the cylinder (see ``_cylinder``). A NaN normal gives NaN and count 0."""
    n = cores.shape[0]
    nblocks = (n + CORE_BLOCK - 1) // CORE_BLOCK
    for blk in prange(nblocks):
        buf = np.empty(BUFFER0)
        res = np.empty(2)
        for i in range(blk * CORE_BLOCK, min(n, (blk + 1) * CORE_BLOCK)):
            nv = normals[i]
            if not (np.isfinite(nv[0]) and np.isfinite(nv[1]) and np.isfinite(nv[2])):
                out_c1[i] = out_s1[i] = out_c2[i] = out_s2[i] = np.nan
                out_n1[i] = out_n2[i] = 0
                continue
            for e in range(2):
                if e == 0:
                    m = _cylinder(g1_pts, g1_keys, g1_lo, g1_h, g1_dims, cores[i], nv,
                                  radius, half_len, n_slabs, buf)
                else:
                    m = _cylinder(g2_pts, g2_keys, g2_lo, g2_h, g2_dims, cores[i], nv,
                                  radius, half_len, n_slabs, buf)
                if m > buf.shape[0]:                   # grow, then collect again
                    buf = np.empty(2 * m)
                    if e == 0:
                        m = _cylinder(g1_pts, g1_keys, g1_lo, g1_h, g1_dims, cores[i], nv,
                                      radius, half_len, n_slabs, buf)
                    else:
                        m = _cylinder(g2_pts, g2_keys, g2_lo, g2_h, g2_dims, cores[i], nv,
                                      radius, half_len, n_slabs, buf)
                _summary(buf, m, robust, res)
                if e == 0:
                    out_c1[i], out_s1[i], out_n1[i] = res[0], res[1], m
                else:
                    out_c2[i], out_s2[i], out_n2[i] = res[0], res[1], m
