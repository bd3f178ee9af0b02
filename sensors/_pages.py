"""Memory pages of the simulation loop's transient arrays.

NumPy asks Linux for transparent huge pages (``madvise(MADV_HUGEPAGE)``) on every
array of 4 MiB or more. Measured on the project's 2-core VM (kernel THP mode
"madvise", no compaction stalls): a 5 s RoboSense Airy drive into memory (4.3M pulses,
five 1M-pulse chunks, each allocating and dropping a few hundred MB of per-pulse
arrays) spent 1.8-2.2 s in the kernel with the hint and 0.6-0.7 s without, 968-991
against 621-636 CPU ns a pulse (issue 33's "Airy into memory" row). The long-lived
scene arrays gain from huge pages instead (BVH walks 5-8 % slower without them, fewer
TLB misses), so the hint is turned off only while a chunk is simulated.

NumPy's switch (``numpy._core.multiarray._set_madvise_hugepage``, the function behind
its documented ``NUMPY_MADVISE_HUGEPAGE`` environment variable) is process-wide and not
public API: it is looked up once, and where it is missing ``transient_pages`` does
nothing. Pages never change a result, only the time.

The heap (``held_heap``). glibc's ``malloc`` serves an array above its mmap threshold
(128 KiB, rising with each freed array up to 32 MiB) with a fresh ``mmap`` and gives
it back on ``free``; a smaller one comes from the heap, whose top is given back once
more than the trim threshold (twice the mmap threshold) is free. A chunk allocates a
few hundred MB of per-pulse arrays (the 1M-pulse records alone are 97 MB) and frees
them all at its end, so every chunk faulted its pages in again: 1.0-1.2 s of kernel
time in a 10 s Airy drive into memory (8.6M pulses, ~3.7 GB first-touched), 0.17-0.22 s
with the freed memory held for the next chunk (4.1-4.2 -> 4.6-4.8x real time on the
2-core VM, 2026-11-27). ``held_heap`` raises both thresholds for the length of a pass
(``mallopt``, glibc's documented interface) and, when the outermost pass ends, puts
them at the values glibc's dynamic thresholds reach once a program has freed a 32 MiB
array (``DEFAULT_MMAP_THRESHOLD_MAX``) and gives the free memory back
(``malloc_trim``). Elsewhere than glibc, and where the user tuned ``malloc``
themselves (``MALLOC_*_`` or ``GLIBC_TUNABLES`` in the environment), it does nothing.
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np


def _switch() -> Any:
    """NumPy's huge-page switch (returns the previous setting), or None."""
    for name in ("_core", "core"):
        module = getattr(np, name, None)
        multiarray = getattr(module, "multiarray", None)
        fn = getattr(multiarray, "_set_madvise_hugepage", None)
        if callable(fn):
            return fn
    return None


_SWITCH = _switch()


@contextmanager
def transient_pages() -> Iterator[None]:
    """Arrays made inside the block get ordinary pages, not huge-page hints; the
    previous setting is restored on leaving (also after an exception).

    DECISION: the user's setting (``NUMPY_MADVISE_HUGEPAGE``) is left as it is outside
    the block: inside it, the hint is off whatever it was, since the block's arrays
    are written once and dropped."""
    if _SWITCH is None:
        yield
        return
    previous = _SWITCH(False)
    try:
        yield
    finally:
        _SWITCH(bool(previous))


# glibc's mallopt parameters (malloc.h).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
#: Thresholds while a pass runs: arrays up to 1 GiB from the heap, and up to 2 GiB - 1
#: (mallopt takes a C int) of free heap kept for the next chunk.
HELD_MMAP_BYTES = 1 << 30
HELD_TRIM_BYTES = (1 << 31) - 1
#: Thresholds after the outermost pass: where glibc's dynamic thresholds end up once
#: a 32 MiB array was freed (DEFAULT_MMAP_THRESHOLD_MAX on 64-bit; trim = 2 x mmap).
AFTER_MMAP_BYTES = 32 << 20
AFTER_TRIM_BYTES = 64 << 20
#: Environment variables by which a user tunes glibc's malloc (then left alone).
USER_TUNING = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_MAX_",
               "MALLOC_TOP_PAD_", "MALLOC_ARENA_MAX", "GLIBC_TUNABLES")


def _glibc() -> Any:
    """The C library when it is glibc (it has ``mallopt`` and ``malloc_trim``), or None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None)
        libc.gnu_get_libc_version
        mallopt, trim = libc.mallopt, libc.malloc_trim
    except (OSError, AttributeError):
        return None
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return libc


_LIBC = _glibc()
_LOCK = threading.Lock()
_DEPTH = [0]


def _user_tuned() -> bool:
    return any(name in os.environ for name in USER_TUNING)


@contextmanager
def held_heap() -> Iterator[None]:
    """Memory freed inside the block stays in the heap for the next allocation instead
    of going back to the kernel (see the module notes); the outermost block sets the
    thresholds on entry and after it, and gives the free memory back on leaving (also
    after an exception). Blocks may nest and overlap (two runs iterated in turn).

    DECISION: for the length of a whole pass, not a chunk: the consumer frees the
    chunk it was given between chunks, and a trim there would give the heap back.
    Peak memory stays what the pass had live at once (plus fragmentation): the heap
    only keeps what was allocated before."""
    libc = None if _LIBC is None or _user_tuned() else _LIBC
    if libc is not None:
        with _LOCK:
            _DEPTH[0] += 1
            if _DEPTH[0] == 1:
                libc.mallopt(M_MMAP_THRESHOLD, HELD_MMAP_BYTES)
                libc.mallopt(M_TRIM_THRESHOLD, HELD_TRIM_BYTES)
    try:
        yield
    finally:
        if libc is not None:
            with _LOCK:
                _DEPTH[0] -= 1
                if _DEPTH[0] == 0:
                    libc.mallopt(M_MMAP_THRESHOLD, AFTER_MMAP_BYTES)
                    libc.mallopt(M_TRIM_THRESHOLD, AFTER_TRIM_BYTES)
                    libc.malloc_trim(0)
