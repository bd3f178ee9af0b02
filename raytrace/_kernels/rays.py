"""Per-ray passes at the public boundary, fused and parallel: checking and normalising
directions, checking origins. (Hit slots are mapped to input triangle indices inside
the casting kernels.)

Each replaces a chain of NumPy passes (``isfinite``/``all``, ``einsum``, a division, a
``where``) that together cost about as much as casting the rays through a cube map
(measured: ~0.15 s for a 4M-ray station on the 2-core VM, against ~0.16 s of casting).
The arithmetic is that of the NumPy formulas they replace (length sqrt(x x + y y + z z),
then one division per component), so results do not change.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import CACHE, ERROR_MODEL


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _bad_direction(x, y, z, length):
    """A direction that cannot be cast: not finite, or of zero length."""
    return not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z) and length != 0.0)


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def unit_directions(d, out):
    """out[i] = d[i] / |d[i]| for d (n, 3) float64; returns how many rows are not
    finite or have zero length (their ``out`` rows are then meaningless)."""
    bad = 0
    for i in prange(d.shape[0]):
        x = d[i, 0]
        y = d[i, 1]
        z = d[i, 2]
        length = np.sqrt(x * x + y * y + z * z)
        out[i, 0] = x / length
        out[i, 1] = y / length
        out[i, 2] = z / length
        if _bad_direction(x, y, z, length):
            bad += 1
    return bad


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def count_nonfinite(a):
    """Number of rows of a (n, 3) float64 with a NaN or inf."""
    bad = 0
    for i in prange(a.shape[0]):
        if not (np.isfinite(a[i, 0]) and np.isfinite(a[i, 1]) and np.isfinite(a[i, 2])):
            bad += 1
    return bad


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def count_bad_directions(d):
    """How many rows of d (n, 3) float64 ``unit_directions`` would count as bad (not
    finite, or zero length), without writing anything: the check of a cast whose
    directions the traversal normalises itself (``traverse.closest_hit``)."""
    bad = 0
    for i in prange(d.shape[0]):
        x = d[i, 0]
        y = d[i, 1]
        z = d[i, 2]
        if _bad_direction(x, y, z, np.sqrt(x * x + y * y + z * z)):
            bad += 1
    return bad


#: Largest | |d|^2 - 1 | of a direction that ``count_not_unit`` accepts as unit length.
#: DECISION: 1e-12, about 4,500 ulps of 1: a vector normalised by any usual float64
#: arithmetic (x / sqrt(x x + y y + z z), a rotation of a unit vector, cos/sin of
#: angles) is within a few ulps; a direction in the wrong unit or never normalised
#: (|d|^2 - 1 of 1e-6 and more) is refused.
UNIT_TOL = 1e-12


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def count_not_unit(d):
    """How many rows of d (n, 3) float64 are not unit vectors: | |d|^2 - 1 | above
    ``UNIT_TOL``, or not finite (NaN fails the comparison). Reads only: the check of a
    cast whose caller says its directions are unit length already (``Scene.cast(...,
    unit=True)``), instead of writing a normalised copy."""
    bad = 0
    for i in prange(d.shape[0]):
        x = d[i, 0]
        y = d[i, 1]
        z = d[i, 2]
        if not abs(x * x + y * y + z * z - 1.0) <= UNIT_TOL:
            bad += 1
    return bad


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def shift_origins(o, offset, out):
    """out[i] = o[i] - offset for o (n, 3) float64 (NumPy's ``o - offset``, the same
    float64 subtraction, in one parallel pass); returns how many rows of ``o`` hold a
    NaN or inf (``count_nonfinite`` fused in)."""
    bad = 0
    for i in prange(o.shape[0]):
        x = o[i, 0]
        y = o[i, 1]
        z = o[i, 2]
        out[i, 0] = x - offset[0]
        out[i, 1] = y - offset[1]
        out[i, 2] = z - offset[2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            bad += 1
    return bad


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def rows_unlike_first(bits):
    """How many rows of bits (n, 3) int64 (float64 origins viewed as int64) differ from
    the first row, bit for bit (0: one origin given once per ray, a station as an
    (n, 3) array). Bitwise, as ``order.origin_runs`` compares origins: -0.0 differs
    from 0.0, and a NaN equals only the same NaN."""
    differ = 0
    b0 = bits[0, 0]
    b1 = bits[0, 1]
    b2 = bits[0, 2]
    for i in prange(bits.shape[0]):
        if bits[i, 0] != b0 or bits[i, 1] != b1 or bits[i, 2] != b2:
            differ += 1
    return differ
