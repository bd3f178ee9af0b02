"""Ray ordering for scattered batches: sort rays by a Morton code of their origin so that
consecutive rays start close together and walk the same part of the tree (the same
records and leaves stay in cache). Results do not depend on the order; only speed does.

Morton (Z-order) codes interleave the bits of quantised coordinates (Morton 1966; used
for BVH construction by Lauterbach et al. 2009, "Fast BVH construction on GPUs"). Here a
coarse grid (``bits`` per axis over the scene's box; origins outside are clamped) and a
stable counting sort, O(n) with 2^(3 bits) buckets.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import CACHE, ERROR_MODEL


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _spread3(x):
    """Insert two zero bits between each of the low 10 bits of x."""
    x &= 0x3FF
    x = (x | (x << 16)) & 0x030000FF
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    x = (x | (x << 2)) & 0x09249249
    return x


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def morton_keys(org, lo, hi, bits, keys):
    """keys[i] = Morton code of org[i] on a grid of cubic cells: the box [lo, hi]'s
    largest extent split into 2^bits. DECISION: cubic cells, not 2^bits per axis: on a
    300 m x 3 m x 3 m tunnel per-axis cells make the Z-curve split first by height and
    gave no speed-up at all; cubic cells order rays along the tunnel (1.7x)."""
    cells = 1 << bits
    ext = max(hi[0] - lo[0], max(hi[1] - lo[1], hi[2] - lo[2]))
    scale = cells / ext if ext > 0.0 else 0.0
    for i in prange(org.shape[0]):
        code = 0
        for a in range(3):
            q = int((org[i, a] - lo[a]) * scale)
            q = min(cells - 1, max(0, q))
            code |= _spread3(q) << a
        keys[i] = code


@njit(cache=CACHE, error_model=ERROR_MODEL)
def counting_sort(keys, n_buckets):
    """Stable permutation that sorts ``keys`` (all in [0, n_buckets))."""
    count = np.zeros(n_buckets + 1, dtype=np.int64)
    for i in range(keys.shape[0]):
        count[keys[i] + 1] += 1
    for b in range(n_buckets):
        count[b + 1] += count[b]
    perm = np.empty(keys.shape[0], dtype=np.int64)
    for i in range(keys.shape[0]):
        k = keys[i]
        perm[count[k]] = i
        count[k] += 1
    return perm
