"""Arrays that start on a cache-line boundary.

NumPy places a large array's data 16 bytes past the start of the pages glibc maps for
it (the allocator's chunk header), so a 256-byte BVH record (``_kernels/traverse.py``)
spans five 64-byte cache lines instead of four, and every other 32-byte
``<8 x float>`` plane load of the node test straddles two lines. The scene's records
are therefore allocated here, 64-byte aligned (the cache line of x86-64 and of
Arm Neoverse cores; Intel 64 and IA-32 Optimization Reference Manual, "Alignment").
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["CACHE_LINE", "as_aligned", "empty_aligned"]

#: Bytes: one cache line.
CACHE_LINE = 64


def empty_aligned(shape: tuple[int, ...], dtype: Any, align: int = CACHE_LINE
                  ) -> NDArray[Any]:
    """``np.empty(shape, dtype)`` whose data starts at a multiple of ``align`` bytes (a
    power of two). The array is a view into a slightly larger byte buffer, which it
    keeps alive (``.base``); it is C-contiguous and writeable. (A zero-size array has no
    data to align.)"""
    if align <= 0 or align & (align - 1):
        raise ValueError(f"Expected `align` to be a power of two, got {align}; "
                         "use 64 (a cache line).")
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    buf = np.empty(nbytes + align, dtype=np.uint8)
    start = (-buf.ctypes.data) % align
    return buf[start:start + nbytes].view(dtype).reshape(shape)


def as_aligned(a: NDArray[Any], align: int = CACHE_LINE) -> NDArray[Any]:
    """``a`` itself when its data starts at a multiple of ``align`` bytes and it is
    C-contiguous, else an aligned copy."""
    if a.flags.c_contiguous and a.ctypes.data % align == 0:
        return a
    out = empty_aligned(a.shape, a.dtype, align)
    out[...] = a
    return out
