"""``sensors._kernels.digest``: the replay cache's test of whether a chunk changed in
place. Checked against a plain-Python evaluation of its definition, and as properties:
any one byte changed always changes the digest (``mix`` is a bijection), the thread
count does not matter."""

from __future__ import annotations

import numba
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sensors._kernels.digest import digest

MASK = (1 << 64) - 1


def _mix(z):
    # SplitMix64's finaliser (Steele, Lea & Flood 2014), in Python integers.
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
    return z ^ (z >> 31)


def _reference(data: bytes) -> int:
    """sum_i mix(w_i xor i PHI) mod 2^64 over little-endian words, last one zero-padded."""
    h = 0
    for i in range(0, len(data), 8):
        w = int.from_bytes(data[i:i + 8].ljust(8, b"\0"), "little")
        h = (h + _mix(w ^ ((i // 8) * 0x9E3779B97F4A7C15 & MASK))) & MASK
    return h


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=0, max_size=300))
def test_equals_its_definition(data):
    assert digest(np.frombuffer(data, dtype=np.uint8).copy()) == _reference(data)


@settings(max_examples=300, deadline=None)
@given(st.binary(min_size=1, max_size=300), st.data())
def test_any_one_byte_changed_changes_it(data, draw):
    a = np.frombuffer(data, dtype=np.uint8).copy()
    i = draw.draw(st.integers(0, len(a) - 1))
    b = a.copy()
    b[i] = draw.draw(st.integers(0, 255).filter(lambda v: v != a[i]))
    assert digest(a) != digest(b)


def test_structured_records_and_threads():
    """A 97-byte record array (the point chunks): its bytes' digest, with any thread
    count, and a swapped pair of records changes it (positions count)."""
    from sensors.io.fields import POINT_DTYPE
    rng = np.random.default_rng(3)
    pts = np.frombuffer(rng.bytes(POINT_DTYPE.itemsize * 5_001), dtype=POINT_DTYPE).copy()
    want = _reference(pts.tobytes())
    before = numba.get_num_threads()
    try:
        for k in range(1, before + 1):
            numba.set_num_threads(k)
            assert digest(pts) == want
    finally:
        numba.set_num_threads(before)
    swapped = pts.copy()
    swapped[[10, 20]] = swapped[[20, 10]]
    assert digest(swapped) != want
