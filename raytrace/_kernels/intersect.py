"""The ray-triangle test: a small pure function, inlined into the traversal kernels, and
the same test of four triangle slots as one ``<4 x double>`` computation (LLVM IR
through ``numba.extending.intrinsic``): four consecutive slots (``mt4``, a BVH leaf) or
four slots gathered from a list (``mt4_gather``, a cube-map cell), each with its scalar
twin.

No ``fastmath`` here (see ``config.BUILD_FASTMATH``): the results must be the IEEE
float64 results of the formulas as written. ``mt4`` performs, lane by lane, exactly the
operations of ``moller_trumbore`` in the same order (``fmul``/``fsub``/``fadd``/``fdiv``
without fast-math flags, so LLVM neither contracts them into FMAs nor reassociates), so
every lane is bit for bit the scalar test: watertightness and the tie-break stay.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from ..config import BARY, CACHE, ERROR_MODEL

#: Triangle slots tested at once by ``mt4``.
GROUP = 4
#: Leaves with at least this many triangles are tested in groups of ``GROUP``; smaller
#: ones one triangle at a time. DECISION: 2. Measured on bfo (one thread, CPU ns a ray,
#: three passes of a prototype): scalar / groups from 1 / from 2 / from 3 triangles:
#: drive 244-255 / 230-234 / 226-230 / 223-232, station 210-217 / 190-196 / 188-194 /
#: 188-193, random 389-422 / 356-361 / 344-360 / 343-357. A last single slot tested on
#: its own instead of as a one-lane group: no difference (issue 33).
GROUP_MIN = 2


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def moller_trumbore(tris, k, ox, oy, oz, dx, dy, dz):
    """Möller & Trumbore 1997 ray-triangle test, both faces, float64.

    ``tris[k]`` holds v0 (0:3), e1 = v1 - v0 (3:6), e2 = v2 - v0 (6:9), local frame.
    The ray is o + t d. Returns (t, u, v) with the hit at (1 - u - v) v0 + u v1 + v v2, or
    (NaN, 0, 0) when the ray misses the triangle's (slightly enlarged) interior (a NaN t
    fails every comparison, so ``closer`` and [t0, t1] tests reject it).

    Edges and vertices: the barycentric test uses the slack ``config.BARY`` on all three
    constraints, so a ray through a shared edge or vertex hits every triangle sharing it
    (the caller breaks the tie: smaller t, then smaller input index). A ray parallel to
    the triangle's plane (det == 0 exactly) misses it.
    """
    v0x = tris[k, 0]
    v0y = tris[k, 1]
    v0z = tris[k, 2]
    e1x = tris[k, 3]
    e1y = tris[k, 4]
    e1z = tris[k, 5]
    e2x = tris[k, 6]
    e2y = tris[k, 7]
    e2z = tris[k, 8]
    # p = d x e2, det = e1 . p
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return (np.nan, 0.0, 0.0)
    inv = 1.0 / det
    sx = ox - v0x
    sy = oy - v0y
    sz = oz - v0z
    u = (sx * px + sy * py + sz * pz) * inv
    if u < -BARY or u > 1.0 + BARY:
        return (np.nan, 0.0, 0.0)
    # q = s x e1
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < -BARY or u + v > 1.0 + BARY:
        return (np.nan, 0.0, 0.0)
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return (t, u, v)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def closer(t, ids, k, t0, best_t, best_id):
    """Whether a hit at t on slot k beats the best so far (input index best_id, -1 for
    none): t must lie in [t0, best_t]; a smaller t wins, an equal t goes to the smaller
    input index (``ids[k]``). The one place the tie rule lives: it makes the closest hit
    a total order, independent of traversal order and thread count."""
    return t >= t0 and t <= best_t and (t < best_t or best_id < 0 or ids[k] < best_id)


_F64 = ir.DoubleType()
_I32 = ir.IntType(32)
_I64 = ir.IntType(64)
_V4D = ir.VectorType(_F64, GROUP)


def _splat4(builder, x):
    """<4 x double> with every lane equal to the scalar x."""
    v = builder.insert_element(ir.Constant(_V4D, ir.Undefined), x, ir.Constant(_I32, 0))
    return builder.shuffle_vector(v, ir.Constant(_V4D, ir.Undefined),
                                  ir.Constant(ir.VectorType(_I32, GROUP), [0] * GROUP))


def _mt4_body(context, builder, data, rows, nv, ray, ret, quad):
    """The IR shared by ``mt4`` and ``mt4_gather``: load the nine float64 columns of the
    four rows ``rows`` (i64 values, row indices of ``data``, a (m, 9) float64 array's
    data pointer) into <4 x double> columns, run ``moller_trumbore``'s formulas on them
    in its order of operations, mask the misses and the lanes >= ``nv``, and return
    (mask, t, u, v) as ``ret``."""
    ox, oy, oz, dx, dy, dz = ray
    cols = [ir.Constant(_V4D, ir.Undefined) for _ in range(9)]
    for lane, r in enumerate(rows):
        row = builder.mul(r, ir.Constant(_I64, 9))
        for c in range(9):
            x = builder.load(builder.gep(data, [builder.add(row, ir.Constant(_I64, c))]))
            cols[c] = builder.insert_element(cols[c], x, ir.Constant(_I32, lane))
    v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z = cols
    vdx, vdy, vdz, vox, voy, voz = (_splat4(builder, a) for a in (dx, dy, dz, ox, oy, oz))
    mul, sub, add = builder.fmul, builder.fsub, builder.fadd
    # Möller & Trumbore 1997, in moller_trumbore's order of operations.
    px = sub(mul(vdy, e2z), mul(vdz, e2y))
    py = sub(mul(vdz, e2x), mul(vdx, e2z))
    pz = sub(mul(vdx, e2y), mul(vdy, e2x))
    det = add(add(mul(e1x, px), mul(e1y, py)), mul(e1z, pz))
    inv = builder.fdiv(ir.Constant(_V4D, [1.0] * GROUP), det)
    sx = sub(vox, v0x)
    sy = sub(voy, v0y)
    sz = sub(voz, v0z)
    u = mul(add(add(mul(sx, px), mul(sy, py)), mul(sz, pz)), inv)
    qx = sub(mul(sy, e1z), mul(sz, e1y))
    qy = sub(mul(sz, e1x), mul(sx, e1z))
    qz = sub(mul(sx, e1y), mul(sy, e1x))
    v = mul(add(add(mul(vdx, qx), mul(vdy, qy)), mul(vdz, qz)), inv)
    t = mul(add(add(mul(e2x, qx), mul(e2y, qy)), mul(e2z, qz)), inv)
    lo = ir.Constant(_V4D, [-BARY] * GROUP)
    hi = ir.Constant(_V4D, [1.0 + BARY] * GROUP)
    zero = ir.Constant(_V4D, [0.0] * GROUP)
    bad = builder.fcmp_ordered("==", det, zero)
    bad = builder.or_(bad, builder.fcmp_ordered("<", u, lo))
    bad = builder.or_(bad, builder.fcmp_ordered(">", u, hi))
    bad = builder.or_(bad, builder.fcmp_ordered("<", v, lo))
    bad = builder.or_(bad, builder.fcmp_ordered(">", add(u, v), hi))
    v4i = ir.VectorType(_I64, GROUP)
    nvec = builder.shuffle_vector(
        builder.insert_element(ir.Constant(v4i, ir.Undefined), nv, ir.Constant(_I32, 0)),
        ir.Constant(v4i, ir.Undefined), ir.Constant(ir.VectorType(_I32, GROUP), [0] * GROUP))
    beyond = builder.icmp_signed(">=", ir.Constant(v4i, list(range(GROUP))), nvec)
    bad = builder.or_(bad, beyond)
    t = builder.select(bad, ir.Constant(_V4D, [float("nan")] * GROUP), t)
    u = builder.select(bad, zero, u)
    v = builder.select(bad, zero, v)
    mask = builder.zext(builder.bitcast(builder.fcmp_ordered("ord", t, t),
                                        ir.IntType(GROUP)), _I64)
    quads = []
    for vec in (t, u, v):
        items = [builder.extract_element(vec, ir.Constant(_I32, k)) for k in range(GROUP)]
        quads.append(context.make_tuple(builder, quad, items))
    return context.make_tuple(builder, ret, [mask] + quads)


def _lane_offsets(builder, nv):
    """min(l, n - 1) for the four lanes l (i64 values): lanes beyond n repeat the last."""
    last = builder.sub(nv, ir.Constant(_I64, 1))
    out = []
    for lane in range(GROUP):
        lv = ir.Constant(_I64, lane)
        out.append(builder.select(builder.icmp_signed("<", lv, nv), lv, last))
    return out


@intrinsic
def mt4(typingctx, tris, j, n, ox, oy, oz, dx, dy, dz):
    """``moller_trumbore`` of the slots j .. j + n - 1 (1 <= n <= 4) at once.

    ``tris`` (m, 9) float64, C order, as in ``moller_trumbore``; the caller keeps
    j + n <= m (lanes n..3 compute slot j + n - 1 again and report NaN, 0, 0). Returns
    (mask, t, u, v): ``mask`` (int64) has bit l set where lane l < n returned a non-NaN
    t; t, u, v are 4-tuples of float64, lane l < n being ``moller_trumbore(tris, j + l,
    ...)`` bit for bit (NaN, 0, 0 on a miss). A lane whose bit is clear can never pass
    ``closer`` or a [t0, t1] test (its t is NaN), so a caller may skip it.

    LLVM IR (per lane l: the row r = j + min(l, n - 1); then ``moller_trumbore``'s
    formulas on <4 x double>, the branches turned into one miss mask)::

        %x   = load double, double* (getelementptr %data, 9 r + c)     ; 9 columns
        %col = insertelement <4 x double> %col, double %x, i32 l
        %px  = fsub (fmul splat(%dy), %e2z), (fmul splat(%dz), %e2y)    ; -> vmulpd ymm
        ...
        %inv = fdiv <4 x double> <1.0, ...>, %det                       ; -> vdivpd ymm
        %bad = or (fcmp oeq %det, 0), (fcmp olt %u, -BARY), (fcmp ogt %u, 1 + BARY),
                  (fcmp olt %v, -BARY), (fcmp ogt (fadd %u, %v), 1 + BARY)
        %bad = or %bad, (icmp sge <0, 1, 2, 3>, splat(%n))             ; lanes >= n
        %t   = select %bad, splat(NaN), %t ;  %u, %v: select %bad, 0, ...
        %m   = zext (bitcast (fcmp ord %t, %t) to i4) to i64
    """
    if not (isinstance(tris, types.Array) and tris.dtype == types.float64
            and tris.layout == "C" and isinstance(j, types.Integer)
            and isinstance(n, types.Integer)):
        return None
    f64 = types.float64
    quad = types.UniTuple(f64, GROUP)
    ret = types.Tuple((types.int64, quad, quad, quad))
    sig = ret(tris, types.intp, types.intp, f64, f64, f64, f64, f64, f64)

    def codegen(context, builder, sig, args):
        tr, jv, nv, ox, oy, oz, dx, dy, dz = args
        data = context.make_array(sig.args[0])(context, builder, tr).data
        rows = [builder.add(jv, off) for off in _lane_offsets(builder, nv)]
        return _mt4_body(context, builder, data, rows, nv, (ox, oy, oz, dx, dy, dz),
                         ret, quad)

    return sig, codegen


@intrinsic
def mt4_gather(typingctx, tris, slots, e, n, ox, oy, oz, dx, dy, dz):
    """``moller_trumbore`` of the triangles ``slots[e]`` .. ``slots[e + n - 1]`` (1 <= n
    <= 4) at once: ``mt4`` for rows that are not consecutive (a cube-map cell's list).

    ``tris`` (m, 9) float64, C order; ``slots`` (k,) int32, C order, e + n <= k (lanes
    n..3 test ``slots[e + n - 1]`` again and report NaN, 0, 0). Returns (mask, t, u, v)
    as ``mt4`` does, lane l < n being ``moller_trumbore(tris, slots[e + l], ...)`` bit
    for bit. ``mt4_gather_scalar`` is its specification.

    LLVM IR: per lane l, s = sext(load slots[e + min(l, n - 1)]) to i64, then ``mt4``'s
    IR on the rows s (``_mt4_body``)::

        %s   = sext i32 (load i32* (getelementptr %slots, %e + min(l, %n - 1))) to i64
        %x   = load double, double* (getelementptr %tris, 9 %s + c)    ; c = 0..8
        ...                                                            ; as mt4

    DECISION: a gather of rows instead of a copy of the triangles in list order: a
    camera's near map has ~18 entries a triangle (~40 MB of rows a frame to copy).
    """
    if not (isinstance(tris, types.Array) and tris.dtype == types.float64
            and tris.layout == "C" and isinstance(slots, types.Array)
            and slots.dtype == types.int32 and slots.layout == "C"
            and isinstance(e, types.Integer) and isinstance(n, types.Integer)):
        return None
    f64 = types.float64
    quad = types.UniTuple(f64, GROUP)
    ret = types.Tuple((types.int64, quad, quad, quad))
    sig = ret(tris, slots, types.intp, types.intp, f64, f64, f64, f64, f64, f64)

    def codegen(context, builder, sig, args):
        tr, sl, ev, nv, ox, oy, oz, dx, dy, dz = args
        data = context.make_array(sig.args[0])(context, builder, tr).data
        sdata = context.make_array(sig.args[1])(context, builder, sl).data
        rows = [builder.sext(builder.load(builder.gep(sdata, [builder.add(ev, off)])), _I64)
                for off in _lane_offsets(builder, nv)]
        return _mt4_body(context, builder, data, rows, nv, (ox, oy, oz, dx, dy, dz),
                         ret, quad)

    return sig, codegen


@njit(cache=CACHE, error_model=ERROR_MODEL)
def mt4_scalar(tris, j, n, ox, oy, oz, dx, dy, dz):
    """Scalar twin of ``mt4`` (its specification): ``moller_trumbore`` lane by lane."""
    return _twin(tris, (j, j + min(1, n - 1), j + min(2, n - 1), j + min(3, n - 1)), n,
                 ox, oy, oz, dx, dy, dz)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def mt4_gather_scalar(tris, slots, e, n, ox, oy, oz, dx, dy, dz):
    """Scalar twin of ``mt4_gather`` (its specification): ``moller_trumbore`` lane by
    lane on ``slots[e + min(l, n - 1)]``, lanes l >= n reported as (NaN, 0, 0)."""
    rows = (np.int64(slots[e]), np.int64(slots[e + min(1, n - 1)]),
            np.int64(slots[e + min(2, n - 1)]), np.int64(slots[e + min(3, n - 1)]))
    return _twin(tris, rows, n, ox, oy, oz, dx, dy, dz)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _twin(tris, rows, n, ox, oy, oz, dx, dy, dz):
    """The scalar twins' lanes: ``moller_trumbore`` on the four ``rows``, lanes l >= n
    reported as (NaN, 0, 0), and the mask of non-NaN t."""
    t = np.full(GROUP, np.nan)
    u = np.zeros(GROUP)
    v = np.zeros(GROUP)
    mask = 0
    for lane in range(GROUP):
        a, b, c = moller_trumbore(tris, rows[lane], ox, oy, oz, dx, dy, dz)
        if lane < n:
            t[lane] = a
            u[lane] = b
            v[lane] = c
            if not np.isnan(a):
                mask |= 1 << lane
    return mask, (t[0], t[1], t[2], t[3]), (u[0], u[1], u[2], u[3]), (v[0], v[1], v[2], v[3])
