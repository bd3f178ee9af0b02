"""A shared task counter for Numba's parallel loops: an atomic fetch-and-add
(``numba.extending.intrinsic``, LLVM ``atomicrmw``), so that worker threads take tasks
one at a time (dynamic scheduling, as a TBB or OpenMP ``schedule(dynamic)`` loop would).

Why. Numba's OpenMP threading layer hands each thread a fixed, contiguous share of a
``prange`` (thread 0 iterations 0..n/2, thread 1 the rest, even under
``numba.parallel_chunksize(1)``: measured with ``numba.np.ufunc.parallel._get_thread_id``).
Tasks of uneven size (the BVH builder's subtrees) then leave one thread idle, and on a
machine shared with other processes a descheduled thread holds up its whole share. A
``prange`` over the workers, each taking the next task from this counter until none is
left, balances both. Which thread builds a task never changes what it writes (each task
owns its output rows), so results stay independent of the thread count.

Usage inside a parallel kernel, ``counter`` a (1,) int64 zero passed in by the caller
(DECISION: not allocated inside the parallel kernel itself: the tasks are still handed
out correctly, but such a counter read after the loop gives back its initial 0, so a
kernel reading it afterwards would be silently wrong; tests/raytrace/test_build.py)::

    for _ in prange(workers):
        while True:
            q = fetch_add(counter, 0, 1)
            if q >= n_tasks:
                break
            ...  # task q
"""

from __future__ import annotations

from numba import types
from numba.extending import intrinsic


@intrinsic
def fetch_add(typingctx, arr, i, value):
    """Atomically add ``value`` to ``arr[i]`` (a C-contiguous int64 array) and return the
    value it held before (sequentially consistent). No bounds check.

    LLVM IR::

        %p = getelementptr i64, i64* %data, i64 %i
        %old = atomicrmw add i64* %p, i64 %value seq_cst     ; lock xadd
    """
    if not (isinstance(arr, types.Array) and arr.dtype == types.int64 and arr.layout == "C"
            and isinstance(i, types.Integer) and isinstance(value, types.Integer)):
        return None
    sig = types.int64(arr, types.intp, types.int64)

    def codegen(context, builder, sig, args):
        data = context.make_array(sig.args[0])(context, builder, args[0]).data
        ptr = builder.gep(data, [args[1]])
        return builder.atomic_rmw("add", ptr, args[2], "seq_cst")

    return sig, codegen


@intrinsic
def atomic_load(typingctx, arr, i):
    """Atomically read ``arr[i]`` (a C-contiguous int64 array; acquire ordering): a
    value another thread publishes with ``fetch_add``, read inside a wait loop (a plain
    load there may be hoisted out of the loop by the compiler). No bounds check.

    LLVM IR::

        %p = getelementptr i64, i64* %data, i64 %i
        %v = load atomic i64, i64* %p acquire, align 8            ; mov
    """
    if not (isinstance(arr, types.Array) and arr.dtype == types.int64 and arr.layout == "C"
            and isinstance(i, types.Integer)):
        return None
    sig = types.int64(arr, types.intp)

    def codegen(context, builder, sig, args):
        data = context.make_array(sig.args[0])(context, builder, args[0]).data
        ptr = builder.gep(data, [args[1]])
        return builder.load_atomic(ptr, "acquire", 8)

    return sig, codegen
