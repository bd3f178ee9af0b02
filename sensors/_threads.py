"""A process-wide pool of threads for NumPy work that releases the GIL (random draws,
element-wise ufuncs over large arrays): the simulation loop's serial NumPy stages run
on both cores this way without changing a bit of their results, since every task
fills its own slice."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor

from raytrace import threads

_POOL: dict[int, ThreadPoolExecutor] = {}


def pool() -> ThreadPoolExecutor:
    """The pool: as many threads as the kernels use, made on first use; one per process
    (a forked child makes its own: the parent's threads are not in it)."""
    pid = os.getpid()
    if pid not in _POOL:
        _POOL.clear()
        _POOL[pid] = ThreadPoolExecutor(threads(), thread_name_prefix="tunnelsim")
    return _POOL[pid]


def run_parts(task: Callable[[int, int], None], n: int, min_part: int = 1 << 16) -> None:
    """Call ``task(a, b)`` for consecutive parts [a, b) of range(n), on the pool when n
    is at least two parts of ``min_part``; the caller's tasks write disjoint slices."""
    k = min(threads(), n // min_part) if n >= 2 * min_part else 1
    if k <= 1:
        task(0, n)
        return
    edges = [n * i // k for i in range(k + 1)]
    _wait(pool().map(lambda i: task(edges[i], edges[i + 1]), range(k)))


def run_each(task: Callable[[int], None], items: Iterable[int]) -> None:
    """Call ``task(i)`` for each item on the pool (tasks write disjoint slices)."""
    _wait(pool().map(task, items))


def _wait(results: Iterable[None]) -> None:
    for _ in results:  # re-raises a task's exception here
        pass
