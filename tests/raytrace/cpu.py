"""Helpers shared by the raytrace kernel tests: what the host CPU offers (for the tests
that read the emitted assembly), the generic-CPU subprocess check and its group script,
compiled callers of kernels, and the near-map setup (cone rays, soups that may be wholly
degenerate, the gathered-triangle budget)."""

from __future__ import annotations

import warnings
from contextlib import contextmanager

import numpy as np
import pytest
from numba import njit

from raytrace import MeshError, Scene, config
from raytrace.scene import _turn_to_x


def has_avx2() -> bool:
    """AVX2 on the host, and Numba left to target it (NUMBA_CPU_NAME/FEATURES unset)."""
    import llvmlite.binding as llvm
    from numba.core import config as nconfig

    if getattr(nconfig, "CPU_NAME", None) or getattr(nconfig, "CPU_FEATURES", None):
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


#: A ``generic_and_host`` script: ``intersect.mt4`` (``GATHER = False``: rows j .. j + n
#: - 1) or ``mt4_gather`` (``True``: rows slots[e .. e + n - 1]) on random rows, 2 % of
#: their coordinates NaN, and random rays, 10 % of direction components zero; n = 1 .. 4
#: in turn. ``case`` returns the masks and the t, u, v bit patterns.
GROUP_SCRIPT = r"""
import json, sys
import numpy as np
from numba import njit
from raytrace._kernels.intersect import mt4, mt4_gather

GATHER = {gather}

@njit(error_model="numpy")
def run(tris, slots, o, d, out_mask, out):
    for r in range(d.shape[0]):
        e = r % (slots.shape[0] - 3)
        n = 1 + r % 4
        if GATHER:
            m, t, u, v = mt4_gather(tris, slots, e, n, o[r, 0], o[r, 1], o[r, 2],
                                    d[r, 0], d[r, 1], d[r, 2])
        else:
            m, t, u, v = mt4(tris, e, n, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1],
                             d[r, 2])
        out_mask[r] = m
        for k in range(4):
            out[r, k] = t[k]
            out[r, 4 + k] = u[k]
            out[r, 8 + k] = v[k]

def case(seed, n=2000):
    rng = np.random.default_rng(seed)
    tris = rng.standard_normal((40, 9))
    tris[rng.random(tris.shape) < 0.02] = np.nan
    # mt4's rows j .. j + n - 1 (j < 37): an identity list of 40 slots walks the same j.
    slots = (rng.integers(0, 40, 64) if GATHER else np.arange(40)).astype(np.int32)
    o = 0.3 * rng.standard_normal((n, 3))
    d = rng.standard_normal((n, 3))
    d[rng.random((n, 3)) < 0.1] = 0.0
    mask = np.empty(n, dtype=np.int64)
    out = np.empty((n, 12))
    run(tris, slots, o, d, mask, out)
    return dict(mask=mask.tolist(), out=out.view(np.int64).ravel().tolist())

if __name__ == "__main__":
    print(json.dumps(case(int(sys.argv[1]))))
"""


def generic_and_host_groups(tmp_path, gather: bool):
    """``generic_and_host`` of ``GROUP_SCRIPT``: (generic, host) answers of ``mt4``
    (``gather`` False) or ``mt4_gather`` (True), to be compared bit for bit."""
    name = "generic_mt4_gather" if gather else "generic_mt4"
    return generic_and_host(tmp_path, name, GROUP_SCRIPT.format(gather=gather))


def jit_call(kernel, arity, **options):
    """A Numba-compiled function of ``arity`` (1 or 2) arguments returning
    ``kernel(*args)``, so that a test calls an intrinsic or an ``inline="always"``
    kernel (neither callable from Python) and can read the caller's assembly
    (``inspect_asm``). ``options`` go to ``njit``.

    DECISION: a fixed arity, not ``*args``: Numba refuses a closure that passes
    ``*args`` on to an ``inline="always"`` function."""

    def call1(a):
        return kernel(a)

    def call2(a, b):
        return kernel(a, b)

    calls = {1: call1, 2: call2}
    if arity not in calls:
        raise ValueError(f"Expected arity 1 or 2, got {arity}; add the case here")
    return njit(**options)(calls[arity])


def cone_rays(rng, n, axis, half_angle_rad):
    """n unit directions within ``half_angle_rad`` of ``axis`` (uniform in tan)."""
    rot = _turn_to_x(*(np.asarray(axis, float) / np.linalg.norm(axis)))
    r = np.tan(half_angle_rad) * np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    local = np.stack([np.ones(n), r * np.cos(phi), r * np.sin(phi)], axis=1)
    d = local @ rot  # rows of rot are the turned frame's axes in the world
    return d / np.linalg.norm(d, axis=1)[:, None]


def soup_scene(v, f):
    """``Scene(v, f)`` of a random soup, its warnings (dropped degenerate triangles)
    silenced; None where every triangle is degenerate (``MeshError``)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            return Scene(v, f)
    except MeshError:
        return None


@contextmanager
def near_budget(k):
    """Within the block a near map gathers k triangles (``config.NEARMAP_MIN_TRIS`` = k,
    none a ray), so a radius below the mesh's is chosen at will; restored after."""
    old = config.NEARMAP_MIN_TRIS, config.NEARMAP_TRIS_PER_RAY
    try:
        config.NEARMAP_MIN_TRIS, config.NEARMAP_TRIS_PER_RAY = k, 0.0
        yield
    finally:
        config.NEARMAP_MIN_TRIS, config.NEARMAP_TRIS_PER_RAY = old
