"""``sensors._kernels.spinning``: a spinning lidar's columns in one fused pass give the
bits of the NumPy formulation it replaced (written out here as the reference, one
NumPy pass per quantity), for any first column, any chunking, either sense of
rotation, and whatever the firing offsets; and the pulses of ``SpinningScan`` match
the pattern's definition (times, channels, frames) independently of both."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sensors import load_sensor
from sensors._kernels.spinning import spinning_columns
from sensors.patterns import SpinningScan


def _numpy_columns(k0, m, T, off, sgn, f, az_off, cpr, el):
    """The pulses of columns k0 .. k0 + m - 1, one NumPy pass per quantity."""
    k = np.arange(k0, k0 + m, dtype=np.int64)
    start = k * T
    t = start[:, None] + off[None, :]
    az = t * (sgn * 2 * np.pi * f)
    az += az_off[None, :]
    frame = np.floor(start * f + 1e-9).astype(np.int64)
    first = np.ceil(frame * cpr - 1e-9).astype(np.int64)
    ce, se = np.cos(el), np.sin(el)
    d = np.stack([ce[None, :] * np.cos(az), ce[None, :] * np.sin(az),
                  np.broadcast_to(se[None, :], az.shape)], axis=-1)
    ch = np.broadcast_to(np.arange(len(off), dtype=np.int32)[None, :], az.shape)
    col = np.broadcast_to((k - first).astype(np.int32)[:, None], az.shape)
    fr = np.broadcast_to(frame.astype(np.int32)[:, None], az.shape)
    return t, d, ch, col, fr


@settings(max_examples=60, deadline=None)
@given(k0=st.integers(0, 50_000_000), m=st.integers(1, 300), nch=st.integers(1, 40),
       clockwise=st.booleans(), f=st.floats(5.0, 25.0), cols=st.integers(300, 4096),
       seed=st.integers(0, 2**32 - 1))
def test_the_fused_pass_gives_the_numpy_bits(k0, m, nch, clockwise, f, cols, seed):
    rng = np.random.default_rng(seed)
    T = 1.0 / (f * cols)
    off = np.sort(rng.uniform(0, T, nch))
    az_off = rng.uniform(-0.1, 0.1, nch)
    el = rng.uniform(-0.5, 1.5, nch)
    cpr = 1.0 / (f * T)
    sgn = -1.0 if clockwise else 1.0
    want = _numpy_columns(k0, m, T, off, sgn, f, az_off, cpr, el)
    t = np.empty((m, nch))
    d = np.empty((m, nch, 3))
    ch, col, fr = (np.empty((m, nch), dtype=np.int32) for _ in range(3))
    spinning_columns(k0, T, off, sgn * 2 * np.pi * f, az_off, f, cpr, np.cos(el),
                     np.sin(el), t, d, ch, col, fr)
    for got, ref in zip((t, d, ch, col, fr), want):
        assert got.dtype == ref.dtype
        assert got.tobytes() == np.ascontiguousarray(ref).tobytes()


def test_the_scan_follows_its_definition_in_any_chunking():
    """VLP-16 for 0.25 s: pulse times k T + offset_c, channel c, frame = the revolution
    of the column start, column = index within it (checked with exact rationals where
    they decide), the same pulses for any chunk size."""
    spec = load_sensor("velodyne_vlp16")
    scan = SpinningScan(spec, 0.25)
    whole = list(scan.chunks(1 << 20))
    assert len(whole) == 1
    p = whole[0]
    nch = spec.channels
    k = np.arange(scan.n_columns).repeat(nch)
    c = np.tile(np.arange(nch), scan.n_columns)
    np.testing.assert_array_equal(p.channel, c)
    np.testing.assert_allclose(p.time, k * scan.T + scan.pattern.firing_offsets_s[c],
                               rtol=0, atol=1e-12)
    frame = np.floor(k * scan.T * scan.rotation_hz + 1e-9).astype(int)
    np.testing.assert_array_equal(p.frame, frame)
    assert p.column.min() == 0 and np.all(np.diff(p.column[::nch])[
        np.diff(frame[::nch]) == 0] == 1)
    np.testing.assert_allclose(np.linalg.norm(p.direction, axis=1), 1.0, atol=1e-15)
    for step in (16, 1000, 7 * 16 + 3):
        parts = list(scan.chunks(step))
        assert len(parts) > 1
        for name in ("time", "direction", "channel", "column", "frame"):
            joined = np.concatenate([getattr(q, name) for q in parts])
            assert joined.tobytes() == getattr(p, name).tobytes()
