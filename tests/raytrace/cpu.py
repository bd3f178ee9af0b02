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


def generic_and_host(tmp_path, name: str, script_text: str, arg: str = "33"):
    """Run ``script_text`` (a module with ``case(seed) -> dict`` that prints
    ``json.dumps(case(int(sys.argv[1])))`` as a script) once in a subprocess compiled
    for ``NUMBA_CPU_NAME=generic`` (no AVX: LLVM splits the vectors), with its own
    Numba cache, and once imported here, compiled for the host. Returns (generic,
    host): the two dicts, to be compared bit for bit."""
    import json
    import os
    import subprocess
    import sys

    script = tmp_path / f"{name}.py"
    script.write_text(script_text)
    env = dict(os.environ, NUMBA_CPU_NAME="generic", NUMBA_CPU_FEATURES="",
               NUMBA_CACHE_DIR=str(tmp_path / "numba_cache"))
    res = subprocess.run([sys.executable, str(script), arg], capture_output=True,
                         text=True, env=env, check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    generic = json.loads(res.stdout.strip().splitlines()[-1])
    sys.path.insert(0, str(tmp_path))
    try:
        module = __import__(name)          # the same script, compiled for this host
    finally:
        sys.path.remove(str(tmp_path))
    return generic, module.case(int(arg))
