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
"""

from __future__ import annotations

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
