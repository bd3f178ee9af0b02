"""The execution layer and the campaigns it runs (survey.cluster, issue 19): the same
bytes in this process and on a LocalCluster of 1 or 2 workers, a killed worker changes
nothing, and bad schedulers and plan files are one-line errors.

Stations are tiny (1-2 degree steps, ~15-60k pulses) on a small generated tunnel; each
LocalCluster start costs a few seconds, so the cluster tests share what they can.
"""

from __future__ import annotations

import json
import os
import re
import signal
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.cli.main import main
from survey.cluster import (
    ClusterError,
    Executor,
    Station,
    open_executor,
    read_plan,
    scan_stations,
    sha256_of,
    station_seed,
)
from survey.errors import PlanningError

STEP_RAD = np.deg2rad(2.0)


@pytest.fixture(scope="module")
def tunnel(tbm_20k):
    """A 100 m 'tbm' tunnel of ~20k triangles with its JSON (alignment on x)."""
    return tbm_20k


@pytest.fixture(scope="module")
def scene(tunnel):
    from sensors.io.meshes import load_mesh

    return load_mesh(tunnel)


def _stations(n):
    return [Station((10.0 + 8.0 * i, 0.1 * i, 1.5), 0.3 * i, 10.0 + 8.0 * i)
            for i in range(n)]


def _campaign(scene, folder, n, executor=None, progress=None):
    from sensors import load_sensor

    folder.mkdir()
    sc, refl = scene
    return scan_stations(sc, load_sensor("zf_imager_5016"), _stations(n), folder,
                         executor=executor, step_rad=STEP_RAD, seed=7, reflectivity=refl,
                         progress=progress)


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory):
    """The in-process campaign of 6 stations: what every cluster run must equal."""
    return _campaign(scene, tmp_path_factory.mktemp("ref") / "c", 6)


# ---------------------------------------------------------------------------- seeds
@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32), st.lists(st.integers(0, 10**6), min_size=2, max_size=20,
                                       unique=True))
def test_station_seeds_are_valid_distinct_and_reproducible(base, indices):
    seeds = [station_seed(base, i) for i in indices]
    assert all(0 <= s < 2**63 for s in seeds)
    assert len(set(seeds)) == len(seeds)      # 64-bit words: a collision is ~1e-17
    assert seeds == [station_seed(base, i) for i in indices]
    assert station_seed(base + 1, indices[0]) != seeds[0]


@pytest.mark.parametrize("bad", [(-1, 0), (0, -1), (0.5, 0), (True, 0)])
def test_station_seed_refuses_bad_input(bad):
    with pytest.raises(ClusterError, match="Expected `(base_seed|index)` as a whole"):
        station_seed(*bad)


# ---------------------------------------------------------------------------- in-process
def test_a_campaign_station_is_the_single_station_with_its_seed(scene, reference,
                                                                 tmp_path):
    """Each file equals the one simulate_station writes alone with the manifest's seed
    and pose (an independent path through sensors), and the manifest is complete."""
    from scipy.spatial.transform import Rotation

    from sensors import load_sensor, simulate_station

    sc, refl = scene
    rows = reference.manifest["stations"]
    assert [r["station"] for r in rows] == list(range(6))
    for r, s in zip(rows[:2], _stations(2)):
        assert r["seed"] == station_seed(7, r["station"])
        run = simulate_station(sc, load_sensor("zf_imager_5016"), s.position,
                               attitude=Rotation.from_euler("z", s.heading_rad),
                               step_rad=STEP_RAD, seed=r["seed"], reflectivity=refl)
        single = tmp_path / f"alone{r['station']}.laz"
        stats = run.write(single)
        assert sha256_of(single) == r["sha256"] == sha256_of(reference.folder / r["file"])
        assert (r["points"], r["pulses"]) == (stats["points"], stats["pulses"])
        assert r["pose"]["position_m"] == list(s.position)
        assert np.allclose(Rotation.from_quat(r["pose"]["quaternion_xyzw"]).as_euler(
            "xyz")[2], s.heading_rad)
    assert reference.manifest["totals"]["points"] == sum(r["points"] for r in rows) > 0
    on_disk = json.loads(reference.manifest_path.read_text())
    assert on_disk["stations"] == rows and "seconds" not in rows[0]
    assert sorted(p.name for p in reference.folder.iterdir()) == \
        ["manifest.json"] + [f"station_{i:03d}.laz" for i in range(6)]


def test_in_process_executor_keeps_order_and_reports_progress():
    seen = []
    assert Executor().map(abs, [-3, 1, -2], progress=lambda d, t: seen.append((d, t))) \
        == [3, 1, 2]
    assert seen == [(1, 3), (2, 3), (3, 3)]


# ---------------------------------------------------------------------------- cluster
def _same(a, b):
    assert a.manifest == b.manifest
    assert a.manifest_path.read_bytes() == b.manifest_path.read_bytes()
    for r in a.manifest["stations"]:
        assert (a.folder / r["file"]).read_bytes() == (b.folder / r["file"]).read_bytes()


def test_one_worker_gives_the_same_bytes(scene, reference, tmp_path):
    pytest.importorskip("distributed")
    with open_executor(workers=1) as ex:
        assert ex.workers == 1 and ex.kind == "local cluster"
        # Its one worker gets every core of this machine as Numba threads.
        info = next(iter(ex.client.run(_threads).values()))
        assert info == (os.cpu_count() or 1)
        got = _campaign(scene, tmp_path / "c", 6, executor=ex)
        _windows_on(ex, scene, tmp_path)
    _same(got, reference)
    # the shared scene went with the executor; no temporaries stay
    assert not [p for p in got.folder.iterdir() if p.name.startswith(".")]


def _windows_on(ex, scene, tmp_path):
    """A drive in 0.3 s windows on the cluster, merged: the bytes of the drive written
    whole in this process (where sensors has the pulse-range API)."""
    from sensors.simulate import Run
    from survey.cluster import simulate_windows

    if not hasattr(Run, "chunks"):
        return
    run = _drive(scene)
    run.write(tmp_path / "whole.npz")
    m = simulate_windows(run, 0.3, tmp_path / "w.npz", reflectivity=scene[1], executor=ex)
    assert len(m["windows"]) == 4
    assert (tmp_path / "w.npz").read_bytes() == (tmp_path / "whole.npz").read_bytes()


def _threads():
    from raytrace import max_threads

    return max_threads()


def test_a_killed_worker_changes_nothing(scene, reference, tmp_path):
    """Two workers; when the first station is done, the worker that is simulating
    another one is killed (SIGKILL): its task reruns, every file is whole and equal to
    the in-process run's, and no temporary file is left."""
    pytest.importorskip("distributed")
    killed = []

    with open_executor(workers=2) as ex:
        pids = ex.client.run(os.getpid)

        def kill_one(done, total):
            if killed:
                return
            busy = [w for w, keys in ex.client.processing().items() if keys]
            if busy:
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(busy[0])

        got = _campaign(scene, tmp_path / "c", 6, executor=ex, progress=kill_one)
        after = ex.client.run(os.getpid)
        _windows_on(ex, scene, tmp_path)
    assert killed, "no worker was busy when the first station finished"
    assert set(after.values()) != set(pids.values())     # the nanny started a new one
    _same(got, reference)
    assert not list(got.folder.glob(".*"))


# ---------------------------------------------------------------------------- errors
def test_without_dask_the_error_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)     # import fails
    with pytest.raises(ClusterError, match=r"pip install 'tunnelsim\[cluster\]'"):
        open_executor(workers=2)


@pytest.mark.parametrize("kw, match", [
    (dict(workers=0), "positive whole number of workers"),
    (dict(workers=2, scheduler="tcp://x:1"), "got both"),
])
def test_bad_executor_arguments(kw, match):
    with pytest.raises(ClusterError, match=match):
        open_executor(**kw)


def test_an_unreachable_scheduler_is_one_line(tunnel, tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")
    import survey.cluster.execution as execution

    monkeypatch.setattr(execution, "CONNECT_TIMEOUT_S", 1.0)
    out = tmp_path / "camp"
    assert main(["scan", "--mesh", str(tunnel), "--chainages", "10:20:10", "--step-deg",
                 "2", "--scheduler", "tcp://127.0.0.1:1", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Expected a dask scheduler at 'tcp://127.0.0.1:1'" in err[0]
    assert not out.exists()


def _plan_file(path, plans, optimised=None):
    data = {"sensor": "zf_imager_5016", "resolution": "high", "along": "centreline",
            "plans": plans, "optimisation": optimised}
    path.write_text(json.dumps(data))
    return path


PLAN = {"name": "every 10 m", "stations": 2, "coverage": 0.9, "gaps": 0,
        "chainages_m": [10.0, 20.0], "offsets_m": [0.0, 0.0],
        "stations_xyz": [[10.0, 0.0, 1.5], [20.0, 0.0, 1.5]]}


def test_read_plan_takes_the_optimised_or_the_named_plan(tmp_path):
    opt = dict(PLAN, name="optimised (MILP)", chainages_m=[15.0],
               stations_xyz=[[15.0, 0.2, 1.4]])
    f = _plan_file(tmp_path / "plan.json", [PLAN, opt], {"status": "optimal"})
    name, st = read_plan(f)
    assert name == "optimised (MILP)" and st == [Station((15.0, 0.2, 1.4), 0.0, 15.0)]
    name, st = read_plan(f, "every 10 m")
    assert [s.chainage_m for s in st] == [10.0, 20.0]
    assert [s.position for s in st] == [(10.0, 0.0, 1.5), (20.0, 0.0, 1.5)]


@pytest.mark.parametrize("content, name, match", [
    (None, None, "does not exist"),
    ("{not json", None, "Expected JSON"),
    ({"plans": []}, None, "Expected a 'plans' list"),
    ({"plans": [PLAN, dict(PLAN, name="every 5 m")]}, None, "--plan-name to choose"),
    ({"plans": [PLAN]}, "every 3 m", "Expected a plan named one of"),
    ({"plans": [dict(PLAN, stations_xyz="x")]}, None, "'stations_xyz' as"),
    ({"plans": [dict(PLAN, chainages_m=[1.0])]}, None, "one chainage each"),
])
def test_bad_plan_files(tmp_path, content, name, match):
    f = tmp_path / "plan.json"
    if content is not None:
        f.write_text(content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(PlanningError, match=match):
        read_plan(f, name)


@pytest.mark.parametrize("extra, match", [
    (["--at", "10,0,1.5", "--workers", "2"], "--workers with --chainages or --plan"),
    (["--chainages", "10:20:10", "--plan-name", "x"], "--plan-name with --plan"),
    (["--chainages", "20:10:5"], "STOP >= START"),
    (["--chainages", "10:20"], "START:STOP:STEP"),
    (["--chainages", "10:900:10"], r"--chainages within \[0, 100\] m"),
    (["--plan", "PLAN"], "Expected a 'plans' list"),
    (["--chainages", "10:20:10", "--workers", "0"], "positive whole number"),
])
def test_campaign_cli_errors_are_one_line(tunnel, tmp_path, capsys, extra, match):
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    argv = ["scan", "--mesh", str(tunnel), "--step-deg", "2", "-o", str(tmp_path / "o")]
    assert main(argv + [str(bad) if a == "PLAN" else a for a in extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(match, err[0]), err
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------- the command
def test_scan_chainages_and_plan_on_two_workers_equal_in_process(tunnel, tmp_path,
                                                                 capsys):
    """tunnelsim scan --chainages: the same manifest and files in-process and on two
    workers; --plan with the same stations gives the same files too."""
    pytest.importorskip("distributed")
    base = ["scan", "--mesh", str(tunnel), "--step-deg", "2", "--seed", "3"]
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    assert main(base + ["--chainages", "10:40:10", "-o", str(a)]) == 0
    assert main(base + ["--chainages", "10:40:10", "--workers", "2", "-o", str(b)]) == 0
    out = capsys.readouterr().out
    assert "dashboard http://" in out and "4 stations" in out
    ma = json.loads((a / "manifest.json").read_text())
    assert (a / "manifest.json").read_bytes() == (b / "manifest.json").read_bytes()
    assert [s["chainage_m"] for s in ma["stations"]] == [10.0, 20.0, 30.0, 40.0]
    for s in ma["stations"]:
        assert sha256_of(a / s["file"]) == sha256_of(b / s["file"]) == s["sha256"]
    # the same stations from a plan file
    xyz = [s["pose"]["position_m"] for s in ma["stations"]]
    plan = _plan_file(tmp_path / "plan.json", [dict(PLAN, chainages_m=[10, 20, 30, 40],
                                                     stations_xyz=xyz)])
    assert main(base + ["--plan", str(plan), "-o", str(c), "--quiet"]) == 0
    mc = json.loads((c / "manifest.json").read_text())
    assert [s["sha256"] for s in mc["stations"]] == [s["sha256"] for s in ma["stations"]]
    assert mc["plan_name"] == "every 10 m"


# ---------------------------------------------------------------------------- drive windows
def _needs_pulse_ranges():
    from sensors.simulate import Run

    if not hasattr(Run, "chunks"):
        pytest.skip("needs sensors.Run.chunks(start, stop) (the pulse-range API)")


def _drive(scene, duration_s=1.0, sensor="velodyne_vlp16"):
    from scipy.spatial.transform import Rotation

    from sensors import Trajectory, load_sensor, simulate_drive

    sc, refl = scene
    traj = Trajectory(np.array([0.0, 2.0]), np.array([[20.0, 0.0, 1.5], [26.0, 0.3, 1.6]]),
                      Rotation.from_euler("z", [[0.0], [0.2]]))
    return simulate_drive(sc, load_sensor(sensor), traj, seed=5, reflectivity=refl,
                          t_end=duration_s, chunk_pulses=40_000)


@settings(max_examples=40, deadline=None)
@given(st.floats(0.003, 1.5), st.sampled_from(["velodyne_vlp16", "zf_profiler_9012"]))
def test_windows_partition_the_pulses_at_their_times(scene, window_s, sensor):
    """Windows are contiguous pulse ranges covering every pulse once; each starts at
    the first pulse whose column (profile) starts at or after its start time, checked
    against the pattern's own pulse times."""
    from survey.cluster import drive_windows

    run = _drive(scene, 0.5, sensor)
    wins = drive_windows(run, window_s)
    assert wins[0].first_pulse == 0 and wins[-1].stop_pulse == run.n_pulses
    assert all(a.stop_pulse == b.first_pulse for a, b in zip(wins, wins[1:]))
    assert all(w.stop_pulse > w.first_pulse and w.end_s > w.start_s for w in wins)
    t = np.concatenate([p.time for p in run.scan.chunks()]) + run.t0
    unit = run.sensor.channels if sensor == "velodyne_vlp16" else \
        run.scan.points_per_profile
    starts = t[::unit]          # the first pulse of each column fires at its start
    for w in wins:
        k = w.first_pulse // unit
        assert w.first_pulse % unit == 0
        assert starts[k] >= w.start_s - 1e-9
        assert k == 0 or starts[k - 1] < w.start_s + 1e-9


def test_a_windowed_drive_is_the_whole_drive(scene, tmp_path):
    """Merged windows of any length: the same bytes as the drive written whole (NPZ,
    PLY), the same points in LAZ; tiled windows: the same points in order, no pulse
    lost or doubled at the edges."""
    _needs_pulse_ranges()
    import laspy

    from survey.cluster import simulate_windows

    run = _drive(scene)
    _, refl = scene
    whole = {ext: run.write(tmp_path / f"whole.{ext}") for ext in ("npz", "ply", "laz")}
    ref = np.load(tmp_path / "whole.npz")
    for window_s in (0.07, 0.3333, 5.0):
        for ext in ("npz", "ply"):
            out = tmp_path / f"w{window_s}.{ext}"
            m = simulate_windows(run, window_s, out, reflectivity=refl)
            assert out.read_bytes() == (tmp_path / f"whole.{ext}").read_bytes()
            assert m["points"] == whole[ext]["points"]
        tiles = tmp_path / f"tiles{window_s}"
        m = simulate_windows(run, window_s, tiles, reflectivity=refl, tiled=True, fmt="npz")
        got = [np.load(tiles / w["file"]) for w in m["windows"]]
        for name in ("x", "gps_time", "range", "channel", "intensity"):
            assert np.array_equal(np.concatenate([g[name] for g in got]), ref[name])
        assert [p.name for p in sorted(tiles.iterdir())][-1] == "window_" + \
            f"{len(m['windows']) - 1:03d}.npz"
    simulate_windows(run, 0.25, tmp_path / "w.laz", reflectivity=refl)
    a, b = laspy.read(tmp_path / "w.laz"), laspy.read(tmp_path / "whole.laz")
    for name in ("X", "Y", "Z", "gps_time", "intensity", "range"):
        assert np.array_equal(np.asarray(a[name]), np.asarray(b[name]))
    assert not list(tmp_path.glob(".*"))


def test_bad_window_length(scene):
    from survey.cluster import drive_windows

    with pytest.raises(ClusterError, match="positive window length"):
        drive_windows(_drive(scene), 0.0)
