"""Issue 32: ``tunnelsim plan`` and ``tunnelsim study`` as library calls
(``survey.workflows.planning``).

Notebook-style: the command (in-process) and ``plan_stations`` / ``run_study`` on the
same 100 m tunnel into two folders write the same files byte for byte, except the
report header's ``computed (UTC)`` line and the study's ``seconds`` column (the wall
time of each simulation). The results' numbers are checked against the files and
against what the stations must be (a regular spacing from the tunnel's axis).
"""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from survey.cli.main import main
from survey.errors import PlanningError, StudyError
from survey.workflows.planning import PlanResult, StudyResult, plan_stations, run_study

from .test_compare_workflow import same_files

PLAN = ["--spacing", "10,20", "--optimize", "--candidate-step", "10", "--resolution",
        "preview", "--spacing-mm", "50"]
PLAN_KW = dict(spacings_m=[10.0, 20.0], optimize=True, candidate_step_m=10.0,
               resolution="preview", spacing_threshold_m=0.05)


def test_plan_command_and_library_write_the_same_files(tbm_20k, tmp_path, capsys):
    cli, lib = tmp_path / "cli", tmp_path / "lib"
    assert main(["plan", "--mesh", str(tbm_20k), *PLAN, "-o", str(cli)]) == 0
    printed = capsys.readouterr().out
    r = plan_stations(tbm_20k, lib, **PLAN_KW)
    assert same_files(cli, lib) == ["coverage.png", "plan.csv", "plan.html", "plan.json",
                                    "plan.md"]
    assert isinstance(r, PlanResult) and r.along == "centreline" and r.route_file is None
    assert sorted(p.name for p in r.files) == sorted(p.name for p in lib.iterdir())
    assert printed == r.markdown.split("\n## Largest")[0].rstrip() + \
        f"\n-> {cli}/ (plan.csv, plan.md, plan.json, coverage.png)\n"
    # The numbers: plan.json is the result's summary; the spaced plans stand every 10
    # and 20 m along the axis (x) at the instrument height, the denser covering more.
    assert json.loads((lib / "plan.json").read_text()) == json.loads(json.dumps(r.summary))
    ten, twenty, best, greedy = r.plans
    for p, step in ((ten, 10.0), (twenty, 20.0)):
        assert np.allclose(np.diff(p.chainages), step)
        assert np.allclose(np.diff(p.stations[:, 0]), step, atol=1e-6)
    assert ten.coverage >= twenty.coverage > 0
    assert len(best.chainages) <= len(greedy.chainages)
    rows = list(csv.DictReader(io.StringIO((lib / "plan.csv").read_text())))
    assert len(rows) == sum(len(p.chainages) for p in r.plans)


def test_study_command_and_library_write_the_same_files(tbm_20k, tmp_path):
    argv = ["study", "--mesh", str(tbm_20k), "--sensor", "velodyne_vlp16", "--speeds",
            "1,3", "--rates", "10", "--mounts", "down", "--strip", "40,42",
            "--lead", "1", "--quiet"]
    cli, lib = tmp_path / "cli", tmp_path / "lib"
    assert main(argv + ["-o", str(cli)]) == 0
    r = run_study(tbm_20k, lib, sensor="velodyne_vlp16", speeds_mps=[1, 3],
                  rates_hz=[10], mounts=["down"], strip_m=(40.0, 42.0),
                  lead_m=1.0)
    assert isinstance(r, StudyResult) and r.strip_m == (40.0, 42.0) and r.lead_m == 1.0

    def rows(path):
        got = list(csv.DictReader(io.StringIO(path.read_text())))
        for x in got:
            x.pop("seconds")             # wall time of each simulation
        return got

    written = rows(lib / "study.csv")
    assert rows(cli / "study.csv") == written
    assert sorted((row.speed_mps, row.mount) for row in r.rows) == [(1.0, "down"),
                                                                     (3.0, "down")]
    # The result's rows are the CSV's (6 significant digits there).
    for row, w in zip(r.rows, written, strict=True):
        assert int(w["points"]) == row.points and w["mount"] == row.mount
        assert float(w["density_lining"]) == pytest.approx(row.density_lining, rel=1e-5)
    (cli / "study.csv").unlink()
    (lib / "study.csv").unlink()
    assert same_files(cli, lib) == ["study.html", "study.md", "study.png"]
    slow, fast = sorted(r.rows, key=lambda row: row.speed_mps)
    assert slow.points > 1000
    # Three times the speed, the same rate: the sweeps lie three times as far apart.
    assert fast.line_spacing_analytic_m == pytest.approx(3 * slow.line_spacing_analytic_m)


def test_plan_and_study_refuse_waypoints_on_the_centreline(tbm_20k, tmp_path):
    (tmp_path / "w.csv").write_text("0,0\n50,0\n")
    with pytest.raises(PlanningError, match="--waypoints with --along auto"):
        plan_stations(tbm_20k, tmp_path / "p", waypoints=tmp_path / "w.csv",
                      along="centreline")
    with pytest.raises(StudyError, match="--waypoints with --along auto"):
        run_study(tbm_20k, tmp_path / "s", waypoints=tmp_path / "w.csv")
    assert not (tmp_path / "p").exists() and not (tmp_path / "s").exists()
