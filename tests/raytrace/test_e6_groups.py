"""Triangle groups (``raytrace/_kernels/intersect.py``: ``mt4``, four Möller–Trumbore tests
as one ``<4 x double>`` computation): each lane equals the scalar test bit for bit on
random input (degenerate triangles, NaN / inf vertices, zero direction components), the
BVH walk that uses them gives the answers of the walk-free cube map and of brute force,
the test compiles to packed instructions, and a generic (no-AVX) CPU agrees."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numba import njit

from raytrace._kernels.intersect import GROUP, moller_trumbore, mt4, mt4_scalar
from tests.raytrace.cpu import generic_and_host_groups, needs_avx2

_SPECIAL = st.sampled_from([0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, np.nan, 1e-300, 1e300])
_COORD = st.one_of(st.floats(-4.0, 4.0, width=64), _SPECIAL)
_DIR = st.one_of(st.floats(-1.0, 1.0, width=64), st.sampled_from([0.0, -0.0]))


@njit(error_model="numpy")
def _mt4(tris, j, n, o, d):
    return mt4(tris, j, n, o[0], o[1], o[2], d[0], d[1], d[2])


def _bits(x):
    """Bit patterns, every NaN as one pattern: which NaN an operation returns (x86 passes
    on its first NaN operand, and LLVM may commute a multiply or an add) is not part of
    the result: a NaN t never passes ``closer`` or a [t0, t1] test."""
    a = np.array(x, dtype=np.float64)
    a[np.isnan(a)] = np.nan
    return a.view(np.int64).tolist()


def _same(a, b):
    assert a[0] == b[0]
    for x, y in zip(a[1:], b[1:]):
        assert _bits(x) == _bits(y)


@settings(max_examples=400, deadline=None)
@given(tris=arrays(np.float64, (7, 9), elements=_COORD), j=st.integers(0, 3),
       n=st.integers(1, GROUP), o=arrays(np.float64, 3, elements=_COORD),
       d=arrays(np.float64, 3, elements=_DIR))
def test_mt4_equals_scalar_twin_on_any_input(tris, j, n, o, d):
    """Any float64 rows, NaN / inf included, and zero direction components: the same
    hit mask and the same t, u, v to the bit as ``moller_trumbore`` lane by lane."""
    _same(_mt4(tris, j, n, o, d), mt4_scalar(tris, j, n, *o, *d))


@st.composite
def _fans(draw):
    """Four triangles sharing edges and a vertex, and a ray aimed at a vertex, an edge
    point or an interior point of one of them: the grazing cases of the tie rule."""
    c = np.array([draw(st.floats(-3.0, 3.0)) for _ in range(3)])
    ring = [c + [np.cos(a), np.sin(a), draw(st.floats(-0.3, 0.3))]
            for a in np.linspace(0.0, 2.0 * np.pi, 5)[:4]]
    tris = np.empty((GROUP, 9))
    for k in range(GROUP):
        p0, p1, p2 = c, ring[k], ring[(k + 1) % GROUP]
        tris[k] = np.concatenate([p0, p1 - p0, p2 - p0])
    k = draw(st.integers(0, GROUP - 1))
    w = draw(st.sampled_from([(1, 0, 0), (0, 1, 0), (0.5, 0.5, 0), (0.25, 0.25, 0.5)]))
    target = w[0] * c + w[1] * ring[k] + w[2] * ring[(k + 1) % GROUP]
    o = target + np.array([draw(st.floats(-2.0, 2.0)) for _ in range(2)] + [2.0])
    d = target - o
    for a in range(2):
        if draw(st.booleans()):
            d[a] = 0.0
            o[a] = target[a]
    return tris, o, d / np.linalg.norm(d)


@settings(max_examples=300, deadline=None)
@given(case=_fans())
def test_mt4_on_grazing_rays_is_the_scalar_test(case):
    """Rays through shared vertices and edges: every lane is ``moller_trumbore`` to the
    bit, and at least one triangle of the fan is hit (the BARY slack at work)."""
    tris, o, d = case
    got = _mt4(tris, 0, GROUP, o, d)
    for k in range(GROUP):
        t, u, v = moller_trumbore(tris, k, *o, *d)
        assert _bits([got[1][k], got[2][k], got[3][k]]) == _bits([t, u, v])
        assert bool((got[0] >> k) & 1) == (not np.isnan(t))
    assert got[0] != 0


@pytest.mark.parametrize("leaf", [1, 2, 3, 5, 8, 16])
def test_walk_with_groups_equals_cube_map_and_brute_force(leaf):
    """Through ``Scene``: leaves of up to ``leaf`` triangles (groups of four plus a rest
    of one to three) cast from inside a closed sphere give, bit for bit, the answers of
    the cube map (which tests each triangle on its own, no BVH walk), hit every ray, and
    pick brute force's triangle (``tests/naive.py``) up to exact ties."""
    from raytrace import Scene
    from raytrace.shapes import icosphere
    from tests.naive import naive_cast

    v, f = icosphere(2, radius=3.0)
    v = v + [0.25, -0.5, 0.125]
    scene = Scene(v, f, max_leaf_size=leaf, c_trav=100.0)  # costly steps: full leaves
    rng = np.random.default_rng(leaf)
    d = rng.standard_normal((3000, 3))
    d = np.vstack([d, v[:12] - [0.5, -0.25, 0.0]])  # at vertices too
    o = np.array([0.5, -0.25, 0.0])
    bvh = scene.cast(o, d, method="bvh")
    ref = scene.cast(o, d, method="cubemap")
    assert bvh.hit.all()
    for a, b in ((bvh.t, ref.t), (bvh.u, ref.u), (bvh.v, ref.v)):
        assert a.view(np.int64).tolist() == b.view(np.int64).tolist()
    assert bvh.triangle.tolist() == ref.triangle.tolist()
    t, tri, _, _, _ = naive_cast(v, f, o, d)
    # Another triangle only at an exact tie (a vertex or edge shared at the same t).
    assert (tri != bvh.triangle).sum() <= 12
    assert np.allclose(t, bvh.t, rtol=1e-12, atol=0.0)
    assert scene.occluded(o, d).all()


@needs_avx2
def test_mt4_compiles_to_packed_double_instructions():
    """A refactor that silently falls back to scalar code fails here: the four tests
    must run as packed float64 multiplies and one packed division on 256-bit (or wider)
    registers."""
    tris = np.ones((4, 9))
    _mt4(tris, 0, 4, np.zeros(3), np.ones(3))
    asm = _mt4.inspect_asm(_mt4.signatures[0])
    assert re.search(r"\bvmulpd\b[^\n]*%[yz]mm", asm), "no packed vmulpd"
    assert re.search(r"\bvdivpd\b[^\n]*%[yz]mm", asm), "no packed vdivpd"
    assert re.search(r"\bvcmp\w*pd\b[^\n]*%[yz]mm", asm), "no packed vcmppd"


def test_generic_cpu_gives_the_same_groups(tmp_path):
    """``NUMBA_CPU_NAME=generic`` (no AVX: LLVM splits the 4-lane vectors) in a
    subprocess with its own Numba cache agrees bit for bit with this process."""
    generic, host = generic_and_host_groups(tmp_path, gather=False)
    assert 0 < sum(m != 0 for m in host["mask"]) < len(host["mask"])  # mixed hits/misses
    assert generic == host
