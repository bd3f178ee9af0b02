"""Pose interpolation per pulse: linear position, quaternion SLERP (Shoemake 1985),
then the mount (lever arm and boresight). One pass, no temporaries."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def interpolate_poses(times, pos, quat, t, rows, lever, bore, origin, out_pos, out_mat,
                      out_which):
    """times (k,) increasing; pos (k, 3) local; quat (k, 4) x, y, z, w; t (n,) within
    [times[0], times[-1]]; rows (n + 1,) increasing offsets; lever (3,); bore (3, 3);
    origin (3,) added to the positions last. Writes the pose at t[j] into rows rows[j]
    to rows[j + 1] - 1 of out_pos (sensor positions, local + origin, (rows[n], 3)), and
    its sensor-to-world matrix either into the same rows of out_mat ((rows[n], 3, 3),
    out_which of length 0) or into row j of out_mat ((n, 3, 3)) with out_which[q] = j
    for each of its rows q (out_which (rows[n],) int64): pulses fired at one instant
    share one interpolation, and with out_which one matrix."""
    per_instant = out_which.shape[0] > 0
    k = times.shape[0]
    for j in prange(t.shape[0]):
        tj = min(max(t[j], times[0]), times[k - 1])
        # Binary search for the segment [times[i], times[i + 1]] holding tj.
        lo = 0
        hi = k - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if times[mid] <= tj:
                lo = mid
            else:
                hi = mid
        i = lo
        f = 0.0
        if k > 1:
            f = (tj - times[i]) / (times[i + 1] - times[i])
        i1 = min(i + 1, k - 1)
        ax, ay, az, aw = quat[i, 0], quat[i, 1], quat[i, 2], quat[i, 3]
        bx, by, bz, bw = quat[i1, 0], quat[i1, 1], quat[i1, 2], quat[i1, 3]
        d = ax * bx + ay * by + az * bz + aw * bw
        if d < 0.0:  # the shorter arc
            bx, by, bz, bw, d = -bx, -by, -bz, -bw, -d
        th = np.arccos(min(d, 1.0))
        s = np.sin(th)
        if s < 1e-9:
            wa, wb = 1.0 - f, f
        else:
            wa, wb = np.sin((1.0 - f) * th) / s, np.sin(f * th) / s
        x = wa * ax + wb * bx
        y = wa * ay + wb * by
        z = wa * az + wb * bz
        w = wa * aw + wb * bw
        nrm = 1.0 / np.sqrt(x * x + y * y + z * z + w * w)
        x *= nrm
        y *= nrm
        z *= nrm
        w *= nrm
        r00 = 1 - 2 * (y * y + z * z)
        r01 = 2 * (x * y - z * w)
        r02 = 2 * (x * z + y * w)
        r10 = 2 * (x * y + z * w)
        r11 = 1 - 2 * (x * x + z * z)
        r12 = 2 * (y * z - x * w)
        r20 = 2 * (x * z - y * w)
        r21 = 2 * (y * z + x * w)
        r22 = 1 - 2 * (x * x + y * y)
        px = pos[i, 0] + f * (pos[i1, 0] - pos[i, 0])
        py = pos[i, 1] + f * (pos[i1, 1] - pos[i, 1])
        pz = pos[i, 2] + f * (pos[i1, 2] - pos[i, 2])
        px += r00 * lever[0] + r01 * lever[1] + r02 * lever[2]
        py += r10 * lever[0] + r11 * lever[1] + r12 * lever[2]
        pz += r20 * lever[0] + r21 * lever[1] + r22 * lever[2]
        q0 = rows[j]
        out_pos[q0, 0] = px + origin[0]
        out_pos[q0, 1] = py + origin[1]
        out_pos[q0, 2] = pz + origin[2]
        qm = np.int64(j) if per_instant else q0
        for c in range(3):
            out_mat[qm, 0, c] = r00 * bore[0, c] + r01 * bore[1, c] + r02 * bore[2, c]
            out_mat[qm, 1, c] = r10 * bore[0, c] + r11 * bore[1, c] + r12 * bore[2, c]
            out_mat[qm, 2, c] = r20 * bore[0, c] + r21 * bore[1, c] + r22 * bore[2, c]
        if per_instant:
            for q in range(q0, rows[j + 1]):
                out_which[q] = j
        # The other pulses of the run copy the first one's pose.
        for q in range(q0 + 1, rows[j + 1]):
            for c in range(3):
                out_pos[q, c] = out_pos[q0, c]
                if not per_instant:
                    for a in range(3):
                        out_mat[q, a, c] = out_mat[q0, a, c]
