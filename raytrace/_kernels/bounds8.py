"""Box growing for the BVH builder as one eight-lane float32 operation
(``numba.extending.intrinsic``, LLVM IR through llvmlite), with its scalar twin.

The binned SAH builder (``build.py``, Wald 2007) spends most of its time growing bin
boxes by primitive boxes: per primitive and axis three minima and three maxima. Stored
as eight float32 lanes (min x, min y, min z, max x, max y, max z and two lanes the
builder ignores), one growth is a load of each box, a packed minimum, a packed maximum
and a lane blend: ``vminps``/``vmaxps``/``vblendps`` on AVX (Embree's binning does the
same with SSE/AVX). LLVM splits the 8-lane vectors into SSE halves or scalars on CPUs
without AVX, so the same IR runs everywhere.

Exactness. The primitive boxes are already float32 (rounded outward from float64 by
``build.triangle_setup``), and a minimum or maximum of float32 values is exact, so
growing in float32 gives the very boxes that float64 arithmetic would: the tree does not
change (``tests/raytrace/test_build.py`` compares the two builds bit for bit).

Comparison semantics are those of ``simd.py``: ``select(fcmp olt p, b), p, b`` (a NaN
primitive lane never replaces the running value); builder inputs are finite.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from ..config import CACHE, ERROR_MODEL

#: float32 lanes of a grown box: min x, y, z, max x, y, z, two spare lanes.
BOX_LANES = 8

_F32 = ir.FloatType()
_V8F = ir.VectorType(_F32, BOX_LANES)
#: Lanes taking the minimum (the rest take the maximum).
_MIN_LANES = ir.Constant(ir.VectorType(ir.IntType(1), BOX_LANES),
                         [1, 1, 1, 0, 0, 0, 0, 0])


def _float32_array(ty):
    return isinstance(ty, types.Array) and ty.dtype == types.float32 and ty.layout == "C"


def _vec_ptr(context, builder, arrty, arr, offset):
    """Pointer to the <8 x float> starting at flat element ``offset`` of a C array."""
    data = context.make_array(arrty)(context, builder, arr).data
    return builder.bitcast(builder.gep(data, [offset]), _V8F.as_pointer())


@intrinsic
def grow8(typingctx, dst, dst_off, src, src_off):
    """Grow the box of 8 float32 at flat offset ``dst_off`` of ``dst`` by the 8 float32
    at flat offset ``src_off`` of ``src`` (both C-contiguous float32 arrays of any rank):
    lanes 0-2 take the minimum, lanes 3-7 the maximum. No bounds check: the caller keeps
    ``dst_off + 8 <= dst.size`` and ``src_off + 8 <= src.size``.

    A primitive record of ``build.py`` (box min 0:3, box max 3:6, centroid 6:9) read at
    its first float gives lanes 0-5 = its box (lanes 6, 7: centroid x, y, ignored).

    LLVM IR::

        %b  = load <8 x float>, <8 x float>* %pdst, align 4      ; vmovups
        %p  = load <8 x float>, <8 x float>* %psrc, align 4
        %lt = fcmp olt <8 x float> %p, %b
        %mn = select <8 x i1> %lt, <8 x float> %p, <8 x float> %b  ; vminps
        %gt = fcmp ogt <8 x float> %p, %b
        %mx = select <8 x i1> %gt, <8 x float> %p, <8 x float> %b  ; vmaxps
        %r  = select <8 x i1> <1,1,1,0,0,0,0,0>, %mn, %mx          ; vblendps
        store <8 x float> %r, <8 x float>* %pdst, align 4
    """
    if not (_float32_array(dst) and _float32_array(src)
            and isinstance(dst_off, types.Integer) and isinstance(src_off, types.Integer)):
        return None
    sig = types.void(dst, types.intp, src, types.intp)

    def codegen(context, builder, sig, args):
        pd = _vec_ptr(context, builder, sig.args[0], args[0], args[1])
        ps = _vec_ptr(context, builder, sig.args[2], args[2], args[3])
        b = builder.load(pd, align=4)
        p = builder.load(ps, align=4)
        mn = builder.select(builder.fcmp_ordered("<", p, b), p, b)
        mx = builder.select(builder.fcmp_ordered(">", p, b), p, b)
        builder.store(builder.select(_MIN_LANES, mn, mx), pd, align=4)
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=CACHE, error_model=ERROR_MODEL)
def grow8_scalar(dst, dst_off, src, src_off):
    """Scalar twin of ``grow8`` (the specification the tests hold it to)."""
    d = dst.reshape(dst.size)
    s = src.reshape(src.size)
    for c in range(BOX_LANES):
        p = s[src_off + c]
        b = d[dst_off + c]
        if c < 3:
            d[dst_off + c] = p if p < b else b
        else:
            d[dst_off + c] = p if p > b else b



# Outward rounding steps for float32 box planes. DECISION: bit steps, not
# ``np.nextafter``: Numba lowers that to a libm call, which was most of
# ``build.triangle_setup``'s 49 ns a triangle (six calls per triangle at worst) and of
# packing the node boxes (48 calls a record). IEEE 754 binary32: for finite nonzero x,
# the neighbour away from zero has the integer bit pattern one larger, the neighbour
# towards zero one smaller (the patterns of same-signed floats are ordered like their
# magnitudes); +-0 step to the smallest subnormal; infinities step to the largest
# finite value towards the other side; NaN stays NaN.
_TINY_BITS = 1


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def next_down32(x):
    """``np.nextafter(x, -inf)`` for a float32 x, bit for bit (x == -inf and NaN are
    returned unchanged). The sign picks the step by a select, not a branch (the sign
    of a box plane is as good as random: a branch on it mispredicted half the time)."""
    if x != x or x == np.float32(-np.inf):
        return x
    if x == np.float32(0.0):
        return -np.int32(_TINY_BITS).view(np.float32)
    b = np.float32(x).view(np.int32)
    step = np.int32(-1) if x > np.float32(0.0) else np.int32(1)
    return np.int32(b + step).view(np.float32)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def next_up32(x):
    """``np.nextafter(x, +inf)`` for a float32 x, bit for bit (x == +inf and NaN are
    returned unchanged); see ``next_down32``."""
    if x != x or x == np.float32(np.inf):
        return x
    if x == np.float32(0.0):
        return np.int32(_TINY_BITS).view(np.float32)
    b = np.float32(x).view(np.int32)
    step = np.int32(1) if x > np.float32(0.0) else np.int32(-1)
    return np.int32(b + step).view(np.float32)
