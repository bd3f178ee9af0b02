"""One sensor-to-world matrix per firing instant (issue 33): ``Trajectory.
instant_matrices`` gives each pulse the row of its instant, and the matrices picked
through that index are bit for bit the per-pulse ones of ``sensor_matrices``; the
kernels that take the index (``world_directions``, ``fill_points``, ``las_points``)
give the bits they give with the matrices expanded per pulse. Random trajectories,
repeated firing times, and a chunk's worth of Airy-like pulses."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sensors import Mount, Trajectory, TrajectoryError
from sensors._kernels.pulses import fill_points, las_points, world_directions
from sensors.io.fields import POINT_DTYPE
from sensors.simulate import _LAS_EXTRA_FIELDS, NO_ROWS


def _trajectory(seed):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.05, 0.2, 9))
    tr = Trajectory(t, rng.normal(0, 5, (9, 3)) + [451000.0, 5352000.0, 300.0],
                    Rotation.random(9, random_state=seed % 1000))
    return rng, t, tr


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), burst=st.integers(1, 12))
def test_rows_pick_the_per_pulse_matrices_bit_for_bit(seed, burst):
    rng, t, tr = _trajectory(seed)
    mount = Mount.from_degrees((0.1, 0.0, 0.3), roll_deg=3.0, yaw_deg=-20.0)
    q = np.sort(rng.uniform(t[0], t[-1], 300))
    rep = np.repeat(q, rng.integers(1, burst + 1, len(q)))
    pos, mat = tr.sensor_matrices(rep, mount)
    pos_r, mat_r, which = tr.instant_matrices(rep, mount)
    assert len(mat_r) == len(np.unique(rep)) and which.shape == (len(rep),)
    assert np.all(np.diff(which) >= 0) and np.all(rep == np.unique(rep)[which])
    assert pos_r.tobytes() == pos.tobytes()
    assert mat_r[which].tobytes() == mat.tobytes()


def test_the_kernels_give_the_same_bits_through_the_rows():
    rng, t, tr = _trajectory(7)
    n = 20_000
    tt = np.repeat(np.sort(rng.uniform(t[0], t[-1], n // 8)), 8)
    pos, mat, which = tr.instant_matrices(tt, Mount())
    full = np.ascontiguousarray(mat[which])
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    jit = rng.normal(0, 1e-3, (n, 2))
    a, b = np.empty((n, 3)), np.empty((n, 3))
    world_directions(d, jit, mat, which, a)
    world_directions(d, jit, full, NO_ROWS, b)
    assert a.tobytes() == b.tobytes()

    idx = np.flatnonzero(rng.random(n) < 0.9)
    r, p = rng.uniform(1, 30, n), rng.uniform(1e-5, 1e-2, n)
    flag = np.ones(n, np.uint8)
    tri = rng.integers(0, 1000, n).astype(np.int32)
    cos = rng.uniform(0, 1, n)
    ch, col, fr = (rng.integers(0, 96, n).astype(np.int32) for _ in range(3))
    common = (idx, r, p, flag, tri, cos, d, tt, ch, col, fr, pos)
    x, y = np.empty(len(idx), POINT_DTYPE), np.empty(len(idx), POINT_DTYPE)
    fill_points(*common, mat, which, 1e-6, 5.0, *[x[k] for k in POINT_DTYPE.names])
    fill_points(*common, full, NO_ROWS, 1e-6, 5.0, *[y[k] for k in POINT_DTYPE.names])
    assert x.tobytes() == y.tobytes()

    las = np.dtype([("X", "<i4"), ("Y", "<i4"), ("Z", "<i4"), ("intensity", "<u2"),
                    ("bits", "u1"), ("cflags", "u1"), ("cls", "u1"), ("udata", "u1"),
                    ("scan", "<i2"), ("psid", "<u2"), ("gps", "<f8")])
    outs = []
    for m, w in ((mat, which), (full, NO_ROWS)):
        rec = np.zeros(len(idx), las)
        extra = [np.empty(len(idx), POINT_DTYPE[f]) for f in _LAS_EXTRA_FIELDS]
        bad = las_points(*common, m, w, 1e-6, 5.0, pos[0].copy(), np.full(3, 1e-4),
                         *[rec[k] for k in las.names], *extra)
        assert bad == 0
        outs.append(rec.tobytes() + b"".join(e.tobytes() for e in extra))
    assert outs[0] == outs[1]


@pytest.mark.parametrize("bad", [[1e6], [[0.1, 0.2]], [0.1, np.nan], "soon"])
def test_bad_times_get_the_same_clear_error_as_sensor_matrices(bad):
    _, _, tr = _trajectory(1)
    with pytest.raises(TrajectoryError) as a:
        tr.instant_matrices(bad, Mount())
    with pytest.raises(TrajectoryError) as b:
        tr.sensor_matrices(bad, Mount())
    assert str(a.value) == str(b.value) and str(a.value).startswith("Expected")
