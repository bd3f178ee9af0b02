"""Eight-lane SIMD building blocks for the 8-wide BVH, written as LLVM IR through
``numba.extending.intrinsic``, each with a plain-Numba scalar twin.

Numba's auto-vectoriser does not turn the per-lane slab test of a wide node into packed
instructions (issue 16), but LLVM lowers explicit ``<8 x float>`` operations to packed
AVX/AVX2 instructions (``vsubps`` or ``vaddps``, ``vmulps``, ``vmaxps``, ``vcmpps``) and
splits them into SSE halves or scalars on CPUs without them, so the same IR runs
everywhere. llvmlite ships with Numba: nothing is compiled at install time.

Every intrinsic has a scalar twin (suffix ``_scalar``) that spells the same arithmetic as
ordinary Numba code; the tests (``tests/raytrace/test_simd.py``) check that the two agree bit
for bit on random input, NaN and infinite planes and zero direction components included.
The twins are the specification; the intrinsics are the fast path.

Comparison semantics. Every minimum/maximum is written as ``a if a > b else b`` (scalar)
and ``select(fcmp ogt a, b), a, b`` (IR): an *ordered* compare is false when either side is
NaN, so a NaN candidate never replaces the running value. That is exactly x86's
``maxps a, b`` (which returns its second operand on NaN), so LLVM emits one ``vmaxps``
per step; and it keeps the test conservative for a ray lying in a slab plane
((plane - o) * inf = 0 * inf = NaN is ignored, Williams et al. 2005).

Planes layout read by ``slab8``: a record of 48 float32 at a flat offset ``base``,
structure of arrays: min x[8], min y[8], min z[8], max x[8], max y[8], max z[8].
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from ..config import CACHE, ERROR_MODEL

#: Lanes of a wide node.
LANES = 8
#: float32 slots of one record's planes: 6 planes x 8 lanes.
PLANES = 6 * LANES

# Ize 2013 ("Robust BVH ray traversal", JCGT 2(2)): with round-to-nearest float32 each of
# (plane - o), 1/d and the product carries a relative error of at most u = 2^-24, so a
# computed slab distance is within gamma(3) = 3u / (1 - 3u) of the exact one (pbrt-v3
# 3.9.2). Scaling the exit distance by 1 + 2 gamma(3) before ``entry <= exit`` therefore
# never rejects a box that the exact ray touches. float32(1 + 2 gamma(3)) rounds up to
# 1 + 4 ulp = 1 + 4.8e-7 (> 1 + 2 gamma(3) = 1 + 3.6e-7, with room for the rounding of the
# product hi * EXIT_SCALE itself).
_U = 2.0 ** -24
_GAMMA3 = 3 * _U / (1 - 3 * _U)
EXIT_SCALE = np.nextafter(np.float32(1.0 + 2.0 * _GAMMA3), np.float32(np.inf))
#: The same allowance in float64, for comparing a float32 entry distance returned by
#: ``slab8`` (which may exceed the exact entry by gamma(3) relative) with a float64 t.
ENTRY_SLACK = float(EXIT_SCALE)

_F32 = ir.FloatType()
_I32 = ir.IntType(32)
_I8 = ir.IntType(8)
_I64 = ir.IntType(64)
_V8F = ir.VectorType(_F32, LANES)
_V8I = ir.VectorType(_I32, LANES)
_V8B = ir.VectorType(ir.IntType(1), LANES)

#: Key of a lane that missed (sorts after every hit: a hit's key is the bit pattern of a
#: distance >= +0, at most 0x7F800007 for +inf).
_MISS_KEY = 0x7FFFFFF8


def _float32_array(ty):
    return isinstance(ty, types.Array) and ty.dtype == types.float32 and ty.layout == "C"


def _vec_ptr(context, builder, arrty, arr, offset, vty):
    """Pointer to the vector ``vty`` starting at element ``offset`` of a C array."""
    data = context.make_array(arrty)(context, builder, arr).data
    return builder.bitcast(builder.gep(data, [offset]), vty.as_pointer())


def _splat(builder, x, vty):
    """<n x T> with every lane equal to the scalar x."""
    v = builder.insert_element(ir.Constant(vty, ir.Undefined), x, ir.Constant(_I32, 0))
    zeros = ir.Constant(ir.VectorType(_I32, vty.count), [0] * vty.count)
    return builder.shuffle_vector(v, ir.Constant(vty, ir.Undefined), zeros)


def _vmax(builder, a, b):
    """a if a > b else b, lane-wise (NaN in a: b; NaN in b: b unless a > b, i.e. b)."""
    return builder.select(builder.fcmp_ordered(">", a, b), a, b)


def _vmin(builder, a, b):
    """a if a < b else b, lane-wise."""
    return builder.select(builder.fcmp_ordered("<", a, b), a, b)


# ---------------------------------------------------------------------------------------
# load8: eight float32 lanes
# ---------------------------------------------------------------------------------------
@intrinsic
def load8(typingctx, arr, offset):
    """Eight consecutive float32 of a C-contiguous float32 array (any rank), starting at
    flat element ``offset``, as a tuple of 8 float32. No bounds check: the caller keeps
    ``offset + 8 <= arr.size``.

    LLVM IR::

        %p = getelementptr float, float* %data, i64 %offset
        %q = bitcast float* %p to <8 x float>*
        %v = load <8 x float>, <8 x float>* %q, align 4     ; unaligned-safe (vmovups)
        ; 8 x extractelement -> { float x 8 }
    """
    if not (_float32_array(arr) and isinstance(offset, types.Integer)):
        return None
    ret = types.UniTuple(types.float32, LANES)
    sig = ret(arr, types.intp)

    def codegen(context, builder, sig, args):
        ptr = _vec_ptr(context, builder, sig.args[0], args[0], args[1], _V8F)
        vec = builder.load(ptr, align=4)
        items = [builder.extract_element(vec, ir.Constant(_I32, k)) for k in range(LANES)]
        return context.make_tuple(builder, sig.return_type, items)

    return sig, codegen


@njit(cache=CACHE, error_model=ERROR_MODEL)
def load8_scalar(arr, offset):
    """Scalar twin of ``load8``."""
    a = arr.reshape(arr.size)
    return (a[offset], a[offset + 1], a[offset + 2], a[offset + 3], a[offset + 4],
            a[offset + 5], a[offset + 6], a[offset + 7])


# ---------------------------------------------------------------------------------------
# slab8: the slab test of eight boxes against one ray
# ---------------------------------------------------------------------------------------
@intrinsic
def slab8(typingctx, planes, base, nx, ny, nz, onx, ony, onz, ofx, ofy, ofz, ix, iy, iz,
          t0, t1, dist):
    """Slab test (Kay & Kajiya 1986) of the eight boxes of the record at flat offset
    ``base`` of ``planes`` (float32, C order) against one ray; returns the 8-bit hit mask
    (int64, bit k = lane k) and writes the entry distances into ``dist[0:8]`` (float32;
    +inf for the lanes that miss).

    ``nx`` is 0 when the ray's x direction is >= 0 (near plane = minimum, far plane =
    maximum at ``24 - nx``) and 24 otherwise; likewise ``ny``, ``nz``. ``onx`` is the
    origin's x used with the near plane and ``ofx`` the one used with the far plane (the
    traversal passes the float64 origin rounded in the direction that can only widen the
    interval, ``axis_setup``); ``ix`` = 1/d_x; [t0, t1] the ray interval. All float32.

    Per lane, in the order of the scalar twin::

        lo = t0;  lo = a if a > lo else lo   for a in (near_x, near_y, near_z)
        hi = t1;  hi = b if b < hi else hi   for b in (far_x, far_y, far_z)
        hit = lo <= hi * EXIT_SCALE;  dist = lo if hit else +inf

    with near_x = (planes[base + nx + lane] - onx) * ix etc.

    LLVM IR (per axis, then the reduction; ``splat`` = insertelement + shufflevector)::

        %pn  = getelementptr float, float* %data, i64 (%base + %nx)
        %vn  = load <8 x float>, <8 x float>* (bitcast %pn), align 4
        %dn  = fsub <8 x float> %vn, splat(%onx)
        %an  = fmul <8 x float> %dn, splat(%ix)                 ; near_x, likewise far_x
        %c   = fcmp ogt <8 x float> %an, %lo
        %lo' = select <8 x i1> %c, <8 x float> %an, <8 x float> %lo     ; -> vmaxps
        ...                                    (fcmp olt + select for hi -> vminps)
        %hs  = fmul <8 x float> %hi, splat(EXIT_SCALE)
        %m   = fcmp ole <8 x float> %lo, %hs                    ; -> vcmpleps
        %d   = select <8 x i1> %m, %lo, splat(+inf)
        store <8 x float> %d, <8 x float>* %dist, align 4
        %mask = zext (bitcast <8 x i1> %m to i8) to i64          ; -> vmovmskps
    """
    if not (_float32_array(planes) and _float32_array(dist)):
        return None
    f32 = types.float32
    sig = types.int64(planes, types.intp, types.intp, types.intp, types.intp,
                      f32, f32, f32, f32, f32, f32, f32, f32, f32, f32, f32, dist)

    def codegen(context, builder, sig, args):
        (planes_v, base_v, nx_v, ny_v, nz_v, onx, ony, onz, ofx, ofy, ofz,
         ixv, iyv, izv, t0v, t1v, dist_v) = args
        far = ir.Constant(_I64, 3 * LANES)
        lo = _splat(builder, t0v, _V8F)
        hi = _splat(builder, t1v, _V8F)
        for axis, (noff, on, of, inv) in enumerate(((nx_v, onx, ofx, ixv),
                                                    (ny_v, ony, ofy, iyv),
                                                    (nz_v, onz, ofz, izv))):
            col = builder.add(base_v, ir.Constant(_I64, axis * LANES))
            near_ptr = _vec_ptr(context, builder, sig.args[0], planes_v,
                                builder.add(col, noff), _V8F)
            far_ptr = _vec_ptr(context, builder, sig.args[0], planes_v,
                               builder.add(col, builder.sub(far, noff)), _V8F)
            vinv = _splat(builder, inv, _V8F)
            a = builder.fmul(builder.fsub(builder.load(near_ptr, align=4),
                                          _splat(builder, on, _V8F)), vinv)
            b = builder.fmul(builder.fsub(builder.load(far_ptr, align=4),
                                          _splat(builder, of, _V8F)), vinv)
            lo = _vmax(builder, a, lo)
            hi = _vmin(builder, b, hi)
        hs = builder.fmul(hi, ir.Constant(_V8F, [float(EXIT_SCALE)] * LANES))
        hit = builder.fcmp_ordered("<=", lo, hs)
        d = builder.select(hit, lo, ir.Constant(_V8F, [float("inf")] * LANES))
        out = _vec_ptr(context, builder, sig.args[-1], dist_v, ir.Constant(_I64, 0), _V8F)
        builder.store(d, out, align=4)
        return builder.zext(builder.bitcast(hit, _I8), _I64)

    return sig, codegen


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def slab8_scalar(planes, base, nx, ny, nz, onx, ony, onz, ofx, ofy, ofz, ix, iy, iz,
                 t0, t1, dist):
    """Scalar twin of ``slab8``: the same float32 arithmetic, one lane at a time."""
    p = planes.reshape(planes.size)
    mask = 0
    for lane in range(LANES):
        b = base + lane
        ax = (p[b + nx] - onx) * ix
        bx = (p[b + 24 - nx] - ofx) * ix
        ay = (p[b + 8 + ny] - ony) * iy
        by = (p[b + 32 - ny] - ofy) * iy
        az = (p[b + 16 + nz] - onz) * iz
        bz = (p[b + 40 - nz] - ofz) * iz
        lo = t0
        lo = ax if ax > lo else lo
        lo = ay if ay > lo else lo
        lo = az if az > lo else lo
        hi = t1
        hi = bx if bx < hi else hi
        hi = by if by < hi else hi
        hi = bz if bz < hi else hi
        if lo <= hi * EXIT_SCALE:
            dist[lane] = lo
            mask |= 1 << lane
        else:
            dist[lane] = np.float32(np.inf)
    return mask


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def round_up32(x):
    """Smallest float32 >= x (float64); inf and NaN pass through."""
    f = np.float32(x)
    if np.float64(f) < x:
        f = np.nextafter(f, np.float32(np.inf))
    return f


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def round_down32(x):
    """Largest float32 <= x (float64); inf and NaN pass through."""
    f = np.float32(x)
    if np.float64(f) > x:
        f = np.nextafter(f, np.float32(-np.inf))
    return f


#: Largest finite float32.
_F32_MAX = np.float32(np.finfo(np.float32).max)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def axis_setup(o, d):
    """Plane column offset, the two float32 origins and the float32 inverse direction of
    one axis for ``slab8``, from the float64 origin ``o`` and direction component ``d``.

    With 1/d >= 0 the near plane is the minimum: the entry distance (min - o) / d may
    only come out smaller, so the near origin is o rounded *up* to float32 and the far
    origin o rounded *down*; with 1/d < 0 the other way round. Exact float32 origins thus
    bracket the float64 one and only the three roundings of Ize 2013 remain (covered by
    ``EXIT_SCALE``). d = +-0 gives an infinite inverse, as in the float64 test.

    A tiny nonzero d whose inverse overflows float32 (|d| < ~2.9e-39) would make a
    finite entry distance infinite and cull a box the ray reaches. DECISION: such an axis
    gets the inverse +-FLT_MAX (an entry distance can then only come out smaller, never
    larger: conservative) and a far origin of -+inf, so that its exit distance is +inf
    (this axis never shortens the interval: conservative, and such rays are rare).

    Returns (near column offset 0 or 24, near origin, far origin, inverse), the offset an
    int and the rest float32.
    """
    inv = 1.0 / d
    inv32 = np.float32(inv)
    if d != 0.0 and abs(inv32) > _F32_MAX:
        if inv > 0.0:
            return 0, round_up32(o), np.float32(-np.inf), _F32_MAX
        return 24, round_down32(o), np.float32(np.inf), -_F32_MAX
    if inv >= 0.0:
        return 0, round_up32(o), round_down32(o), inv32
    return 24, round_down32(o), round_up32(o), inv32


# ---------------------------------------------------------------------------------------
# order8: hit lanes by entry distance, branch-free
# ---------------------------------------------------------------------------------------
def _bitonic_stages(n):
    """Batcher's bitonic sorting network for n (a power of two) lanes, ascending: per
    stage, the partner of each lane and whether the lane keeps the minimum."""
    stages = []
    k = 2
    while k <= n:
        j = k // 2
        while j >= 1:
            partner = [i ^ j for i in range(n)]
            keep_min = [((i & k) == 0) == (i < (i ^ j)) for i in range(n)]
            stages.append((partner, keep_min))
            j //= 2
        k *= 2
    return stages


_STAGES = _bitonic_stages(LANES)


@intrinsic
def order8(typingctx, mask, dist):
    """The hit lanes of ``slab8`` in order of entry distance, branch-free.

    Returns (count, order): ``count`` = popcount(mask & 0xFF); lane ``(order >> 4 q) & 15``
    is the q-th nearest for q < count (lanes that missed follow, in lane order). Both
    int64.

    Sort key per lane: the distance's bit pattern with its low three bits replaced by the
    lane (a non-negative float32 orders like its bits as an int32; distances within
    eight ulps tie and go in lane order: the order only steers the traversal, never the
    result), or 0x7FFFFFF8 | lane for a lane that missed. Keys are distinct, so the
    result is that of any correct sort (the scalar twin uses insertion). Distances must
    be >= +0 for the order to be by distance (``slab8`` gives lo >= t0 >= 0).

    LLVM IR::

        %bits = bitcast <8 x float> (load %dist) to <8 x i32>
        %key  = or (and %bits, splat(-8)), <0, 1, ..., 7>
        %m    = bitcast (trunc i64 %mask to i8) to <8 x i1>
        %key  = select %m, %key, splat(0x7FFFFFF8) | <0..7>
        ; Batcher's bitonic network, 6 stages of:
        %p    = shufflevector %key, undef, <partner lanes>
        %lt   = icmp slt %key, %p
        %mn   = select %lt, %key, %p   ;  %mx = select %lt, %p, %key    (-> vpminsd/vpmaxsd)
        %key  = select <keep-min lanes>, %mn, %mx
        ; pack: ((key & 7) << <0, 4, ..., 28>) reduced by or
        %n    = call i8 @llvm.ctpop.i8(i8 %mask8)
    """
    if not (isinstance(mask, types.Integer) and _float32_array(dist)):
        return None
    sig = types.UniTuple(types.int64, 2)(types.int64, dist)

    def codegen(context, builder, sig, args):
        mask_v, dist_v = args
        lane_ids = ir.Constant(_V8I, list(range(LANES)))
        ptr = _vec_ptr(context, builder, sig.args[1], dist_v, ir.Constant(_I64, 0), _V8F)
        bits = builder.bitcast(builder.load(ptr, align=4), _V8I)
        key = builder.or_(builder.and_(bits, ir.Constant(_V8I, [-8] * LANES)), lane_ids)
        m8 = builder.trunc(mask_v, _I8)
        hit = builder.bitcast(m8, _V8B)
        miss = ir.Constant(_V8I, [_MISS_KEY | k for k in range(LANES)])
        key = builder.select(hit, key, miss)
        undef = ir.Constant(_V8I, ir.Undefined)
        for partner, keep_min in _STAGES:
            other = builder.shuffle_vector(key, undef, ir.Constant(_V8I, partner))
            lt = builder.icmp_signed("<", key, other)
            mn = builder.select(lt, key, other)
            mx = builder.select(lt, other, key)
            key = builder.select(ir.Constant(_V8B, [int(b) for b in keep_min]), mn, mx)
        lanes = builder.and_(key, ir.Constant(_V8I, [LANES - 1] * LANES))
        lanes = builder.shl(lanes, ir.Constant(_V8I, [4 * k for k in range(LANES)]))
        # Or-reduction by halving shuffles (portable; no reduction intrinsic needed).
        width = LANES
        while width > 1:
            width //= 2
            hi_half = builder.shuffle_vector(
                lanes, undef, ir.Constant(_V8I, [width + k if k < width else 0
                                                 for k in range(LANES)]))
            lanes = builder.or_(lanes, hi_half)
        packed = builder.extract_element(lanes, ir.Constant(_I32, 0))
        ctpop = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_I8, [_I8]),
                                               "llvm.ctpop.i8")
        count = builder.zext(builder.call(ctpop, [m8]), _I64)
        # The packed lanes are 32 bits of nibbles: zero-extend, not sign-extend.
        return context.make_tuple(builder, sig.return_type,
                                  [count, builder.zext(packed, _I64)])

    return sig, codegen


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def order8_scalar(mask, dist):
    """Scalar twin of ``order8``: the same keys, sorted by insertion."""
    keys = np.empty(LANES, dtype=np.int32)
    bits = dist[:LANES].view(np.int32)
    count = 0
    for lane in range(LANES):
        if (mask >> lane) & 1:
            keys[lane] = (bits[lane] & -8) | lane
            count += 1
        else:
            keys[lane] = _MISS_KEY | lane
    for i in range(1, LANES):
        k = keys[i]
        j = i
        while j > 0 and keys[j - 1] > k:
            keys[j] = keys[j - 1]
            j -= 1
        keys[j] = k
    packed = 0
    for q in range(LANES):
        packed |= np.int64(keys[q] & (LANES - 1)) << (4 * q)
    return count, packed


# ---------------------------------------------------------------------------------------
# leaf8 and lowest_lane: the leaf/internal split of a visit without per-lane branches
# ---------------------------------------------------------------------------------------
def _int32_array(ty):
    return isinstance(ty, types.Array) and ty.dtype == types.int32 and ty.layout == "C"


@intrinsic
def leaf8(typingctx, arr, offset):
    """Which of eight consecutive int32 of a C-contiguous int32 array (any rank), from
    flat element ``offset``, are > 0, as an 8-bit mask (int64, bit k = element
    ``offset + k``). No bounds check: the caller keeps ``offset + 8 <= arr.size``.

    With ``offset`` at a record's triangle counts (``traverse.COUNT``) this is the
    record's leaf mask: ``mask & leaf`` are the leaf children a visit hits and
    ``mask ^ (mask & leaf)`` the internal ones, with no branch per lane.

    LLVM IR::

        %p = getelementptr i32, i32* %data, i64 %offset
        %v = load <8 x i32>, <8 x i32>* (bitcast %p), align 4
        %c = icmp sgt <8 x i32> %v, zeroinitializer           ; vpcmpgtd (or vpcmpltd)
        %m = zext (bitcast <8 x i1> %c to i8) to i64           ; vmovmskps / kmovb
        %r = call i64 asm "", "=r,0"(i64 %m)                   ; no instruction

    DECISION: the empty ``asm`` (it emits nothing) keeps the mask in a general
    register. Without it LLVM folds ``mask & leaf`` back into ``<8 x i1>`` operations,
    which on AVX-512 live in mask registers that it spilled to the stack and reloaded
    on every visit: bfo, one thread, kernel CPU ns a ray, with / without: drive 166 /
    168, station 149 / 148, random 276 / 285 (issue 33). An empty string with a
    register constraint is valid on every LLVM target.
    """
    if not (_int32_array(arr) and isinstance(offset, types.Integer)):
        return None
    sig = types.int64(arr, types.intp)

    def codegen(context, builder, sig, args):
        ptr = _vec_ptr(context, builder, sig.args[0], args[0], args[1], _V8I)
        vec = builder.load(ptr, align=4)
        pos = builder.icmp_signed(">", vec, ir.Constant(_V8I, [0] * LANES))
        mask = builder.zext(builder.bitcast(pos, _I8), _I64)
        keep = ir.InlineAsm(ir.FunctionType(_I64, [_I64]), "", "=r,0")
        return builder.call(keep, [mask])

    return sig, codegen


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def leaf8_scalar(arr, offset):
    """Scalar twin of ``leaf8``."""
    a = arr.reshape(arr.size)
    mask = 0
    for k in range(LANES):
        if a[offset + k] > 0:
            mask |= 1 << k
    return mask


@intrinsic
def lowest_lane(typingctx, mask):
    """Index of the lowest set bit of ``mask`` (int64), 64 for 0: count trailing zeros,
    one ``tzcnt`` (or ``bsf`` + ``cmov``) instead of a loop whose trip count the branch
    predictor must guess.

    LLVM IR::

        %n = call i64 @llvm.cttz.i64(i64 %mask, i1 false)
    """
    if not isinstance(mask, types.Integer):
        return None
    sig = types.int64(types.int64)

    def codegen(context, builder, sig, args):
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(_I64, [_I64, ir.IntType(1)]), "llvm.cttz.i64")
        return builder.call(fn, [args[0], ir.Constant(ir.IntType(1), 0)])

    return sig, codegen


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def lowest_lane_scalar(mask):
    """Scalar twin of ``lowest_lane``."""
    if mask == 0:
        return 64
    lane = 0
    while (mask >> lane) & 1 == 0:
        lane += 1
    return lane


@intrinsic
def int32_at(typingctx, arr, offset):
    """The int32 at flat element ``offset`` of a C-contiguous int32 array (any rank), as
    int64. No bounds check.

    DECISION: a record's links are read at ``cur * RECORD + CHILD + lane``, the flat
    offset the slab test already computed, instead of ``links[cur, CHILD + lane]``:
    Numba's 2-D index wraps a negative ``cur`` (a shift, an and, an add) and multiplies
    by the row stride read from the array (``imul``), all on the chain from one visit to
    the next (bfo, one thread, kernel CPU ns a ray, flat / 2-D index: drive 166 / 170,
    station 149 / 153, random 276 / 283; issue 33).

    LLVM IR::

        %p = getelementptr i32, i32* %data, i64 %offset
        %x = sext (load i32, i32* %p) to i64
    """
    if not (_int32_array(arr) and isinstance(offset, types.Integer)):
        return None
    sig = types.int64(arr, types.intp)

    def codegen(context, builder, sig, args):
        data = context.make_array(sig.args[0])(context, builder, args[0]).data
        return builder.sext(builder.load(builder.gep(data, [args[1]])), _I64)

    return sig, codegen


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def int32_at_scalar(arr, offset):
    """Scalar twin of ``int32_at``."""
    return np.int64(arr.reshape(arr.size)[offset])


# ---------------------------------------------------------------------------------------
# Outward rounding to float32 without a library call
# ---------------------------------------------------------------------------------------
_F64 = ir.DoubleType()


def _round32(builder, x, up):
    """float32 nearest to the float64 x, moved one float32 step up (``up``) or down
    where that rounding went the wrong way. The step is an integer +-1 on the bit
    pattern: for a float32 f != -0 of sign s the next float32 away from zero has the
    bits of f plus 1, the next towards zero minus 1 (IEEE 754 orders the magnitudes
    of a sign like their bit patterns; +-inf step to +-FLT_MAX)."""
    f = builder.fptrunc(x, _F32)
    wrong = builder.fcmp_ordered("<" if up else ">", builder.fpext(f, _F64), x)
    bits = builder.bitcast(f, _I32)
    one = ir.Constant(_I32, 1)
    minus = ir.Constant(_I32, -1)
    zero = ir.Constant(_I32, 0)
    if up:
        # f < x: f is not +inf and not -0 (x > -0 would round to +0 or above).
        step = builder.select(builder.icmp_signed(">=", bits, zero), one, minus)
    else:
        # f > x: f is not -inf; f = -0 (x a tiny negative) steps to -denormal (+1).
        step = builder.select(builder.icmp_signed(">", bits, zero), minus, one)
    return builder.select(wrong, builder.bitcast(builder.add(bits, step), _F32), f)


@intrinsic
def round_up32_fast(typingctx, x):
    """``round_up32`` (its scalar twin and specification) without ``np.nextafter``.

    DECISION: Numba compiles ``np.nextafter`` on float32 to a call of
    ``numba_nextafterf`` (with a ``vzeroupper`` before it): ~4 calls a ray (the ray's
    origin for three axes, and every closer hit), a fifth to a sixth of a drive ray's
    time. Here it is a compare and an integer step on the bits, branch-free (bfo, one
    thread, kernel CPU ns a ray, HEAD walk with nextafter / with this: drive 220 / 180,
    station 170 / 159, random 328 / 287; issue 33).

    LLVM IR::

        %f    = fptrunc double %x to float
        %bad  = fcmp olt double (fpext float %f to double), %x
        %bits = bitcast float %f to i32
        %step = select (icmp sge i32 %bits, 0), i32 1, i32 -1
        %r    = select %bad, (bitcast (add %bits, %step) to float), %f
    """
    if not isinstance(x, types.Float):
        return None
    sig = types.float32(types.float64)

    def codegen(context, builder, sig, args):
        return _round32(builder, args[0], True)

    return sig, codegen


@intrinsic
def round_down32_fast(typingctx, x):
    """``round_down32`` (its scalar twin and specification) without ``np.nextafter``
    (see ``round_up32_fast``).

    LLVM IR::

        %f    = fptrunc double %x to float
        %bad  = fcmp ogt double (fpext float %f to double), %x
        %bits = bitcast float %f to i32
        %step = select (icmp sgt i32 %bits, 0), i32 -1, i32 1
        %r    = select %bad, (bitcast (add %bits, %step) to float), %f
    """
    if not isinstance(x, types.Float):
        return None
    sig = types.float32(types.float64)

    def codegen(context, builder, sig, args):
        return _round32(builder, args[0], False)

    return sig, codegen


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def axis_setup_fast(o, d):
    """``axis_setup`` (its twin and specification) with ``round_up32_fast`` and
    ``round_down32_fast``: the same four results, bit for bit, without library calls."""
    inv = 1.0 / d
    inv32 = np.float32(inv)
    if d != 0.0 and abs(inv32) > _F32_MAX:
        if inv > 0.0:
            return 0, round_up32_fast(o), np.float32(-np.inf), _F32_MAX
        return 24, round_down32_fast(o), np.float32(np.inf), -_F32_MAX
    if inv >= 0.0:
        return 0, round_up32_fast(o), round_down32_fast(o), inv32
    return 24, round_down32_fast(o), round_up32_fast(o), inv32


__all__ = ["LANES", "PLANES", "EXIT_SCALE", "ENTRY_SLACK", "load8", "load8_scalar",
           "slab8", "slab8_scalar", "axis_setup", "round_up32", "round_down32", "order8",
           "order8_scalar", "leaf8", "leaf8_scalar", "lowest_lane", "lowest_lane_scalar",
           "int32_at", "int32_at_scalar", "round_up32_fast", "round_down32_fast",
           "axis_setup_fast"]
