"""What the host CPU offers, for the tests that read the emitted assembly."""

from __future__ import annotations

import pytest


def has_avx2() -> bool:
    """AVX2 on the host, and Numba left to target it (NUMBA_CPU_NAME/FEATURES unset)."""
    import llvmlite.binding as llvm
    from numba.core import config as nconfig

    if nconfig.CPU_NAME or nconfig.CPU_FEATURES:
        return False
    return bool(llvm.get_host_cpu_features().get("avx2", False))


#: Skip a test that checks for packed 8-lane instructions where they cannot appear.
needs_avx2 = pytest.mark.skipif(not has_avx2(), reason="packed 8-lane float instructions "
                                "need AVX2 on the host and NUMBA_CPU_NAME/NUMBA_CPU_FEATURES "
                                "unset")
