"""LAS/LAZ records made straight from the pulse kernels (issue 33): a run too large for
its replay cache writes its LAS/LAZ without the ``POINT_DTYPE`` record in between. The
reference is the writer's own path from point records (``Run.write(points=...)``, the
packing every earlier file went through): the files must be the same bytes, for
stations and drives, every field layout, particles and mixed returns, any chunking.
The random streams, now drawn straight into the chunk and only as far as it needs, are
checked against whole blocks drawn as the module documents them."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import sensors.simulate as simulate
import sensors.writers
from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import PointFileError, Settings, Trajectory, simulate_drive, simulate_station
from sensors.io.fields import LAS_EXTRA, LAS_EXTRA_F8


@pytest.fixture(scope="module")
def scene():
    v, f = tunnel_tube(4_000, length_m=30.0, seed=2)
    return Scene(v, f)


@pytest.fixture(scope="module")
def traj():
    return Trajectory.along_polyline([[5.0, 0.0, 1.4], [20.0, 0.0, 1.4]], 2.0, rate_hz=50)


@pytest.fixture
def direct(monkeypatch):
    """Counts the chunks whose LAS records the kernel made (``las_points`` calls)."""
    count = {"n": 0}
    kernel = simulate.las_points

    def counting(*a):
        count["n"] += 1
        return kernel(*a)

    monkeypatch.setattr(simulate, "las_points", counting)
    return count


def _station(scene, **kw):
    return simulate_station(scene, "zf_imager_5016", [10.0, 0.0, 1.4],
                            resolution="preview", seed=3, chunk_pulses=20_000, **kw)


def _drive(scene, traj, **kw):
    return simulate_drive(scene, "velodyne_vlp16", traj, seed=4, t_end=0.2,
                          chunk_pulses=16_000, **kw)


def _both(make, path, **write):
    """(bytes written straight from the kernels, bytes written from point records)."""
    direct = path.with_name("direct" + path.suffix)
    ref = path.with_name("ref" + path.suffix)
    stats = make(cache_bytes=0).write(direct, **write)
    chunks = list(make())
    make().write(ref, points=chunks, **write)
    assert stats["points"] == sum(len(c) for c in chunks) > 0
    return direct.read_bytes(), ref.read_bytes()


@pytest.mark.parametrize("suffix", ["las", "laz"])
@pytest.mark.parametrize("fields", ["compact", "full"])
@pytest.mark.parametrize("kind", ["station", "drive"])
def test_direct_records_are_the_same_bytes(scene, traj, tmp_path, direct, suffix, fields,
                                           kind):
    def make(**kw):
        return _station(scene, **kw) if kind == "station" else _drive(scene, traj, **kw)
    got, want = _both(make, tmp_path / f"p.{suffix}", fields=fields)
    assert direct["n"] > 1                       # the kernel made them, chunk by chunk
    assert got == want


@pytest.mark.parametrize("phys", [
    Settings(particle_rate_per_m=0.2, attenuation_per_m=0.02),   # class 7, flag 2
    Settings(beam_subrays=7),                                    # flag 3 (mixed)
    Settings.ideal(),
], ids=["particles", "subrays", "ideal"])
def test_direct_records_of_every_flag(scene, traj, tmp_path, direct, phys):
    got, want = _both(lambda **kw: _drive(scene, traj, settings=phys, **kw),
                      tmp_path / "p.las", fields="full")
    assert direct["n"] > 0 and got == want


def test_the_float64_layout_of_earlier_files_too(scene, tmp_path, direct, monkeypatch):
    """The benchmarks' ``LAS_EXTRA_F8`` (sensor_x .. range as float64) is made by the
    kernel as well, as the writer packs it."""
    monkeypatch.setattr(sensors.writers, "LAS_EXTRA", LAS_EXTRA_F8)
    got, want = _both(lambda **kw: _station(scene, **kw), tmp_path / "p.las",
                      fields="full")
    assert LAS_EXTRA_F8 != LAS_EXTRA and direct["n"] > 0 and got == want


@settings(max_examples=6, deadline=None)
@given(chunk=st.integers(1_000, 40_000), seed=st.integers(0, 2**32))
def test_direct_records_for_any_chunking(scene, traj, tmp_path_factory, chunk, seed):
    """Property: whatever the chunk size and seed, the kernel's file is the writer's."""
    path = tmp_path_factory.mktemp("c") / "p.las"

    def make(**kw):
        return simulate_drive(scene, "velodyne_vlp16", traj, seed=seed, t_end=0.1,
                              chunk_pulses=chunk, **kw)
    got, want = _both(make, path, fields="compact")
    assert got == want


def test_a_direct_write_keeps_no_cache_and_the_same_stats(scene, traj, tmp_path, direct):
    run = _drive(scene, traj, cache_bytes=0)
    stats = run.write(tmp_path / "d.laz")
    ref = _drive(scene, traj)
    n = sum(len(c) for c in ref)
    assert direct["n"] > 0 and not run.cached
    assert stats["points"] == n == ref.stats["points"]
    assert stats["pulses"] == ref.stats["pulses"]
    assert stats["hit_ratio"] == ref.stats["hit_ratio"]


def test_a_run_within_its_cache_still_writes_from_records(scene, traj, tmp_path, direct):
    """A run whose records fit the cache keeps "simulates once": the write fills the
    cache and a later pass replays it (no kernel-made records)."""
    run = _drive(scene, traj)
    run.write(tmp_path / "d.las")
    assert direct["n"] == 0 and run.cached


def test_coordinates_beyond_the_int32_range_are_refused_alike(tmp_path):
    """Two rooms 300 km apart scanned by one drive: the LAS offset is near the first
    point, the second room's points do not fit 0.1 mm int32 coordinates; the kernel's
    path raises the writer's own error, naming the point."""
    v, f = tunnel_tube(2_000, length_m=10.0, seed=1)
    far = v + [300_000.0, 0.0, 0.0]
    scene = Scene(np.vstack([v, far]), np.vstack([f, f + len(v)]))
    traj = Trajectory([0.0, 0.1, 0.101, 0.2], [[5.0, 0, 1.4], [5.0, 0, 1.4],
                                              [300_005.0, 0, 1.4], [300_005.0, 0, 1.4]],
                      Rotation.identity(4))
    messages = []
    for kw, points in (({"cache_bytes": 0}, None), ({}, "ref")):
        run = simulate_drive(scene, "velodyne_vlp16", traj, seed=1, chunk_pulses=50_000,
                             **kw)
        with pytest.raises(PointFileError, match="Expected coordinates within") as err:
            run.write(tmp_path / "far.las",
                      points=None if points is None else list(run))
        messages.append(str(err.value))
        assert not (tmp_path / "far.las").exists()
    assert messages[0] == messages[1]


def _blocks(seed, stream, first, n, kind, width):
    """The documented streams drawn the plain way: whole blocks of ``RANDOM_BLOCK``
    numbers from ``default_rng([seed, stream, block])``, concatenated, sliced."""
    b = simulate.RANDOM_BLOCK
    b0, b1 = first // b, (first + max(n, 1) - 1) // b
    parts = []
    for k in range(b0, b1 + 1):
        g = np.random.default_rng([seed, stream, k])
        draw = {"normal": g.standard_normal, "uniform": g.random,
                "exponential": g.standard_exponential}[kind]
        parts.append(draw((b, width)))
    whole = np.concatenate(parts)[first - b0 * b:first - b0 * b + n]
    return whole[:, 0] if width == 1 else whole


@settings(max_examples=25, deadline=None)
@given(first=st.integers(0, 6 * simulate.RANDOM_BLOCK),
       n=st.integers(0, 3 * simulate.RANDOM_BLOCK), seed=st.integers(0, 2**32))
def test_streams_are_the_whole_blocks_sliced(first, n, seed):
    s = simulate._Streams(seed, first, n)
    for got, want in ((s.normal(0, 2), _blocks(seed, 0, first, n, "normal", 2)),
                      (s.normal(4, 1), _blocks(seed, 4, first, n, "normal", 1)),
                      (s.uniform(3), _blocks(seed, 3, first, n, "uniform", 1)),
                      (s.exponential(1), _blocks(seed, 1, first, n, "exponential", 1)),
                      (s.uniform_columns(5, 3), _blocks(seed, 5, first, n, "uniform", 3))):
        assert got.shape == want.shape
        assert got.tobytes() == want.tobytes()


def test_progress_is_reported_alike(scene, traj, tmp_path, direct):
    """``progress(done, total)`` is called after each chunk on both paths, with the
    same counts."""
    calls: dict[str, list[tuple[int, int]]] = {"direct": [], "ref": []}
    _drive(scene, traj, cache_bytes=0).write(
        tmp_path / "a.laz", progress=lambda d, n: calls["direct"].append((d, n)))
    _drive(scene, traj).write(
        tmp_path / "b.laz", progress=lambda d, n: calls["ref"].append((d, n)))
    assert direct["n"] > 1 and len(calls["direct"]) > 1
    assert calls["direct"] == calls["ref"]
    assert calls["direct"][-1][0] == calls["direct"][-1][1]
