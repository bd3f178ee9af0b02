"""plan and study fan out on the execution layer (issue 19): the station qualities of a
plan and the configurations of a study run as tasks with the planner or the study sent
once (``Executor.share``); the files equal the in-process run's.

Also the memory-mapped scene the workers load (``Scene.load(mmap=True)``).
"""

from __future__ import annotations

import csv
import io
import pickle
import re

import numpy as np
import pytest

from survey.cli.main import main
from survey.cluster import ClusterError, Executor, Shared, call_shared
from survey.errors import PlanningError


@pytest.fixture(scope="module")
def tunnel(tbm_20k):
    """A 100 m 'tbm' tunnel of ~20k triangles with its JSON (alignment on x)."""
    return tbm_20k


class _Counter:
    def __init__(self, k):
        self.k = k

    def times(self, x):
        return self.k * x


def test_shared_objects_in_process_and_through_a_file(tmp_path):
    obj = _Counter(3)
    held = Executor().share(obj, tmp_path)
    assert held.load() is obj and call_shared((held, "times", (4,))) == 12
    with pytest.raises(ClusterError, match="Executor.share"):
        pickle.dumps(held)
    # What a DaskExecutor hands the workers: a file name; loaded once per process.
    path = tmp_path / "o.pkl"
    path.write_bytes(pickle.dumps(_Counter(5)))
    ref = pickle.loads(pickle.dumps(Shared(str(path))))
    first = ref.load()
    assert first.k == 5 and ref.load() is first
    assert call_shared((ref, "times", (2,))) == 10


def test_planner_remember_refuses_a_count_mismatch(tunnel):
    from sensors import load_sensor
    from survey.analysis.planning import Planner
    from survey.clouds.axis import tunnel_frame

    scene, _, al, hc = tunnel_frame(tunnel)
    pl = Planner(scene, al, hc, load_sensor("zf_imager_5016"), resolution="preview")
    st = pl.stations_at([20.0, 30.0, 20.0])
    need = pl.uncached(st)
    assert len(need) == 2                      # one row per distinct station
    q = [pl.quality(p) for p in need[:1]]
    assert len(pl.uncached(st)) == 1           # the computed one is cached now
    with pytest.raises(PlanningError, match="one quality per station"):
        pl.remember(need, q)


def _rows(path):
    return list(csv.DictReader(io.StringIO(path.read_text())))


@pytest.mark.slow
def test_plan_and_study_on_two_workers_equal_in_process(tunnel, tmp_path, capsys):
    pytest.importorskip("distributed")
    plan = ["plan", "--mesh", str(tunnel), "--spacing", "10,20", "--optimize",
            "--candidate-step", "10", "--resolution", "preview", "--spacing-mm", "50",
            "--quiet"]
    a, b = tmp_path / "pa", tmp_path / "pb"
    assert main(plan + ["-o", str(a)]) == 0
    assert main(plan + ["--workers", "2", "-o", str(b)]) == 0
    # a plan that covers something (not a comparison of two empty plans)
    cov = re.search(r"\| every 10 m \| 10 \| ([\d.]+) %", (a / "plan.md").read_text())
    assert cov and float(cov.group(1)) > 50
    for f in ("plan.csv", "plan.json", "coverage.png"):
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    from tests.iofiles import report_body

    assert report_body(a / "plan.md") == report_body(b / "plan.md")
    assert sorted(p.name for p in b.iterdir()) == sorted(p.name for p in a.iterdir())

    study = ["study", "--mesh", str(tunnel), "--sensor", "velodyne_vlp16", "--speeds",
             "1,3", "--mounts", "level,down", "--strip", "40,42", "--lead", "1", "--quiet"]
    c, d = tmp_path / "sa", tmp_path / "sb"
    assert main(study + ["-o", str(c)]) == 0
    assert main(study + ["--workers", "2", "-o", str(d)]) == 0
    rc, rd = _rows(c / "study.csv"), _rows(d / "study.csv")
    assert len(rc) == 4 and int(rc[0]["points"]) > 1000
    for x, y in zip(rc, rd, strict=True):
        x.pop("seconds"), y.pop("seconds")     # wall time of each simulation
        assert x == y
    # the figure draws the floor rings kept on the workers
    assert (c / "study.png").read_bytes() == (d / "study.png").read_bytes()
    assert sorted(p.name for p in d.iterdir()) == sorted(p.name for p in c.iterdir())


def test_a_memory_mapped_scene_casts_the_same(tunnel, tmp_path):
    from raytrace import Scene
    from sensors.io.meshes import load_mesh

    scene, _ = load_mesh(tunnel)
    path = scene.save(tmp_path / "s.npz")
    mapped = Scene.load(path, mmap=True)
    rng = np.random.default_rng(1)
    o = np.array([30.0, 0.0, 1.0]) + rng.normal(0, 0.5, (5000, 3))
    d = rng.normal(size=(5000, 3))
    a, b = scene.cast(o, d), mapped.cast(o, d)
    for name in ("t", "triangle", "u", "v"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    # pickling (what Executor.share does with a planner) drops the per-process view
    scene.cast(np.array([30.0, 0.0, 1.0]), d)            # builds the cube-map view
    again = pickle.loads(pickle.dumps(scene))
    np.testing.assert_array_equal(again.cast(o, d).t, a.t)


# ---------------------------------------------------------------------------- pipelines
def test_a_pipeline_hands_its_scheduler_only_to_steps_that_fan_out():
    from survey.cli.pipeline import step_argv

    addr = "tcp://10.0.0.5:8786"

    def argv(command, args=(), **options):
        return step_argv({"command": command, "args": list(args), "options": options},
                         scheduler=addr)

    assert argv("scan", mesh="m.ply", chainages="10:30:10", output="o")[-2:] == \
        ["--scheduler", addr]
    assert "--scheduler" not in argv("scan", mesh="m.ply", chainage=20, output="o.laz")
    assert "--scheduler" not in argv("drive", mesh="m.ply", output="d.laz")
    assert argv("drive", mesh="m.ply", output="d.laz", **{"window-s": 5})[-1] == addr
    assert "--scheduler" not in argv("compare", args=["a.laz", "b.laz"], output="c")
    assert argv("study", mesh="m.ply", output="s")[-1] == addr
    assert "--scheduler" not in argv("tunnel", output="t.ply")       # takes none
    # a step's own choice stands
    own = argv("plan", mesh="m.ply", output="p", workers=3)
    assert "--scheduler" not in own and own[own.index("--workers") + 1] == "3"
    assert "--scheduler" not in step_argv({"command": "plan", "options": {
        "mesh": "m.ply", "output": "p"}})                             # no cluster


def test_run_on_two_workers_writes_what_it_writes_here(tunnel, tmp_path):
    pytest.importorskip("distributed")
    pipe = tmp_path / "p.toml"
    pipe.write_text(f'''[pipeline]
name = "two stations and one"
seed = 4

[[steps]]
command = "scan"
[steps.options]
mesh = "{tunnel}"
chainages = "20:30:10"
step-deg = 3
output = "campaign"

[[steps]]
command = "scan"
[steps.options]
mesh = "{tunnel}"
chainage = 25
step-deg = 3
output = "one.laz"
''')
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["run", str(pipe), "-o", str(a), "--quiet"]) == 0
    assert main(["run", str(pipe), "--workers", "2", "-o", str(b), "--quiet"]) == 0
    for f in ("campaign/manifest.json", "one.laz"):
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    report = (b / "report.md").read_text()
    assert report.count("--scheduler tcp://") == 1          # the campaign step only
