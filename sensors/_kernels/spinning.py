"""The pulses of a spinning multi-beam lidar's columns (``patterns.SpinningScan``): one
fused pass per column instead of a NumPy pass per quantity.

Column k starts at k T; channel c fires at k T + offset_c, azimuth w t + az_c (w = +-2 pi
f_rot, its sign the sense of rotation) and elevation el_c: direction (cos el_c cos az,
cos el_c sin az, sin el_c). Frame = floor(k T f_rot + 1e-9), the revolution of the
column's start; column = k - ceil(frame columns_per_rev - 1e-9), its index within the
revolution. The operations, and their order, are those of the NumPy code this replaced
(the same bits: tests/sensors/test_spinning_kernel.py checks them against it).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def spinning_columns(k0, period_s, offsets_s, w, az_offsets, rotation_hz, columns_per_rev,
                     cos_el, sin_el, t, d, ch, col, fr):
    """Columns k0 .. k0 + m - 1 into rows 0 .. m - 1 of t (m, c) float64, d (m, c, 3)
    float64, ch, col, fr (m, c) int32; offsets_s, az_offsets, cos_el, sin_el (c,)
    float64 per channel; w the signed angular rate (rad/s)."""
    nch = offsets_s.shape[0]
    for r in prange(t.shape[0]):
        k = np.int64(k0) + np.int64(r)
        start = np.float64(k) * period_s
        frame = np.int64(np.floor(start * rotation_hz + 1e-9))
        first = np.int64(np.ceil(np.float64(frame) * columns_per_rev - 1e-9))
        cj = np.int32(k - first)
        fj = np.int32(frame)
        for c in range(nch):
            tc = start + offsets_s[c]
            t[r, c] = tc
            az = tc * w
            az += az_offsets[c]
            d[r, c, 0] = cos_el[c] * np.cos(az)
            d[r, c, 1] = cos_el[c] * np.sin(az)
            d[r, c, 2] = sin_el[c]
            ch[r, c] = c
            col[r, c] = cj
            fr[r, c] = fj
