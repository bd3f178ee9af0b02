"""A ``Run`` simulates once (issue 30): a second pass replays the first, counted by the
casts on the scene (no timing); a bound, a partial pass, a changed seed and a consumer
that changes its chunks are handled; the replay equals a fresh simulation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import Trajectory, simulate_drive, simulate_station
from sensors.io.fields import POINT_DTYPE


@pytest.fixture(scope="module")
def scene():
    v, f = tunnel_tube(4_000, length_m=30.0, seed=2)
    return Scene(v, f)


@pytest.fixture(scope="module")
def traj():
    return Trajectory.along_polyline([[5.0, 0.0, 1.4], [20.0, 0.0, 1.4]], 2.0, rate_hz=50)


@pytest.fixture
def casts(monkeypatch):
    """Counts the calls of ``Scene.cast`` (every simulated chunk casts once)."""
    count = {"n": 0}
    original = Scene.cast

    def counting(self, *a, **kw):
        count["n"] += 1
        return original(self, *a, **kw)

    monkeypatch.setattr(Scene, "cast", counting)
    return count


def _drive(scene, traj, **kw):
    return simulate_drive(scene, "velodyne_vlp16", traj, seed=4, t_end=0.2,
                          chunk_pulses=16_000, **kw)


def test_a_run_iterated_twice_casts_once(scene, traj, casts, tmp_path):
    run = _drive(scene, traj)
    first = list(run)
    n = casts["n"]
    assert n == len(first) > 1                     # one cast per chunk of the pass
    second = list(run)
    stats = run.write(tmp_path / "d.npz")          # a third pass, into a file
    assert casts["n"] == n                         # nothing cast again
    assert run.pass_stats["replayed"] and run.cached
    np.testing.assert_array_equal(np.concatenate(second), np.concatenate(first))
    with np.load(tmp_path / "d.npz") as z:
        np.testing.assert_array_equal(z["sensor_x"], np.concatenate(first)["sx"])
    assert stats["points"] == sum(len(c) for c in first)


def test_a_station_is_cached_too(scene, casts):
    run = simulate_station(scene, "zf_imager_5016", [10.0, 0.0, 1.4], resolution="preview",
                           window_rad=[0.0, 0.3, -0.2, 0.2], chunk_pulses=20_000)
    a = np.concatenate(list(run))
    n = casts["n"]
    b = np.concatenate(list(run))
    assert casts["n"] == n > 0
    np.testing.assert_array_equal(a, b)


def test_replayed_chunks_are_copies(scene, traj):
    run = _drive(scene, traj)
    ref = np.concatenate(list(run))
    for chunk in run:                              # a consumer that moves its points
        chunk["x"] += 1000.0
    np.testing.assert_array_equal(np.concatenate(list(run)), ref)


def test_the_cache_holds_the_chunks_handed_out_not_copies(scene, traj):
    """list(run) holds its points once: the cache keeps the very arrays of the pass."""
    run = _drive(scene, traj)
    first = list(run)
    assert run._cache is not None and len(run._cache) == len(first)
    assert all(e.points is c for e, c in zip(run._cache, first))


@pytest.mark.parametrize("change", ["value", "dtype", "shape"])
def test_a_chunk_changed_in_place_is_simulated_again_on_replay(scene, traj, casts,
                                                               change):
    """A consumer that changes a chunk it was handed (in place: a value, or the array's
    dtype or shape) gets the true points on replay: that chunk, and only it, is
    simulated again; the reference is a run without a cache."""
    run = _drive(scene, traj)
    first = list(run)
    truth = np.concatenate(list(_drive(scene, traj, cache_bytes=0)))
    k = 1
    if change == "value":
        first[k]["range"][3] += 1e-9          # one value, by far less than noise
    elif change == "dtype":
        first[k].dtype = np.dtype([("raw", "V%d" % POINT_DTYPE.itemsize)])
    else:
        first[k].shape = (len(first[k]), 1)
    n = casts["n"]
    again = list(run)
    assert casts["n"] == n + 1                 # only the changed chunk is cast again
    assert np.concatenate(again).tobytes() == truth.tobytes()
    assert run.pass_stats["replayed"]
    third = list(run)                          # the repaired chunk is kept
    assert casts["n"] == n + 1
    assert np.concatenate(third).tobytes() == truth.tobytes()


def test_a_partial_pass_is_not_kept(scene, traj, casts):
    run = _drive(scene, traj)
    for _chunk in run:
        break
    assert casts["n"] == 1 and not run.cached
    whole = list(run)
    assert casts["n"] == 1 + len(whole)
    assert run.cached


def test_a_changed_seed_simulates_again(scene, traj, casts):
    run = _drive(scene, traj)
    a = np.concatenate(list(run))
    n = casts["n"]
    run.seed = 5
    b = np.concatenate(list(run))
    assert casts["n"] == 2 * n
    assert not np.array_equal(a["range"], b["range"])    # the other seed's noise


def test_beyond_the_bound_a_run_simulates_again_and_says_so(scene, traj, casts):
    run = _drive(scene, traj, cache_bytes=POINT_DTYPE.itemsize * 10)
    a = np.concatenate(list(run))
    n = casts["n"]
    with pytest.warns(UserWarning, match="again.*cache"):
        b = np.concatenate(list(run))
    assert casts["n"] == 2 * n and not run.cached
    np.testing.assert_array_equal(a, b)               # the same points, cast twice
    off = _drive(scene, traj, cache_bytes=0)           # switched off: no warning
    list(off)
    list(off)
    assert not off.cached


def test_bad_cache_bound_is_refused(scene, traj):
    with pytest.raises(Exception, match="cache_bytes"):
        _drive(scene, traj, cache_bytes=-1)


@settings(max_examples=4, deadline=None)
@given(st.integers(2_000, 20_000))
def test_replay_equals_a_fresh_simulation(scene, traj, chunk):
    """Whatever the chunking, the replayed pass is the simulated one, and both equal an
    uncached run's (the reference: simulated anew)."""
    run = simulate_drive(scene, "velodyne_vlp16", traj, seed=1, t_end=0.05,
                         chunk_pulses=chunk)
    first = np.concatenate(list(run))
    replay = np.concatenate(list(run))
    fresh = np.concatenate(list(simulate_drive(scene, "velodyne_vlp16", traj, seed=1,
                                               t_end=0.05, cache_bytes=0)))
    np.testing.assert_array_equal(replay, first)
    np.testing.assert_array_equal(replay, fresh)
