"""The demo end to end (--quick), pipelines, and what every command shares."""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from survey.cli.main import build_parser, main
from survey.cli.pipeline import demo_text, load_pipeline, step_argv

#: Commands that draw random numbers (they take --seed).
SEEDED = {"tunnel", "scan", "drive", "slam", "study", "demo", "run"}
#: Commands that only print (no --quiet, no --threads).
PRINTING = {"info", "sensors"}


def _commands():
    return build_parser()[1]


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "d"
    assert main(["demo", "--quick", "-o", str(out), "--quiet"]) == 0
    return out


def test_demo_quick_key_numbers_are_sane(demo):
    s = json.loads((demo / "summary.json").read_text())
    # MLS: the correction removes the drift to below 1 cm between the control points,
    # and the leave-one-out check points agree within 1 cm RMS.
    assert s["corrected_drift_max_m"] < 0.01
    assert s["corrected_check_rms_m"] < 0.01
    assert s["corrected_drift_max_m"] < s["raw_drift_max_m"]
    # ... and on the cloud's own points (issue 15: a cloud written without its drift
    # showed none of it): C2M RMS against the true mesh shrinks with the correction.
    before, after = s["cloud_c2m_rms_before_m"], s["cloud_c2m_rms_after_m"]
    assert np.isfinite([before, after]).all() and after < before
    # Reconstruction: millimetre-level median fit.
    assert s["reconstruction"]["median_m"] < 0.005
    # Table 1: stations on the reconstruction agree with the truth at the cm level.
    assert set(s["table1"]) == {"station25_reconstructed", "station50_reconstructed"}
    for row in s["table1"].values():
        assert row["n"] > 100_000 and 0 < row["median_m"] < 0.02
    # Planning: 5 m beats 10 m, the optimised plan reaches the quick target (95 %).
    p = s["plan"]
    assert p["every 5 m"]["coverage"] > p["every 10 m"]["coverage"]
    assert p["optimised"]["coverage"] >= 0.95 - 1e-9
    assert p["optimised"]["stations"] <= p["greedy"]["stations"]
    # Study: density per pass ~ 1/v; distortion max ~ v/f.
    rows = {r["speed_mps"]: r for r in s["study"]}
    assert rows[1.0]["density_floor"] / rows[3.0]["density_floor"] == pytest.approx(3, rel=0.05)
    assert rows[3.0]["distortion_max_m"] == pytest.approx(0.3, rel=0.02)
    assert s["gazebo_world"] and (demo / "gazebo" / "models" / "tunnel" / "model.sdf").is_file()


def test_demo_report_links_every_figure(demo):
    md = (demo / "report.md").read_text()
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md)
    assert links and all((demo / link).is_file() for link in links)
    pngs = {str(p.relative_to(demo)) for p in demo.rglob("*.png")}
    assert pngs == set(links)
    for png in pngs:
        data = (demo / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    s = json.loads((demo / "summary.json").read_text())
    assert f"{1000 * s['corrected_check_rms_m']:.1f}" in md
    assert f"{1000 * s['cloud_c2m_rms_before_m']:.1f} / " \
        f"{1000 * s['cloud_c2m_rms_after_m']:.1f} mm" in md
    assert md.count("```\ntunnelsim ") == len(load_pipeline(demo_text())["steps"])


def _refuse(name):
    raise ValueError(f"non-standard JSON constant {name}")


def test_every_json_of_the_demo_is_strict(demo):
    """Every JSON the demo wrote parses with a strict reader (NaN, Infinity refused):
    jq and JavaScript read them. The study's line spacing at 0 m/s is undefined: null."""
    files = sorted(demo.rglob("*.json"))
    assert {"summary.json", "tunnel.json", "mls_corrected.json", "reconstructed.json",
            "plan.json"} <= {p.name for p in files}
    for p in files:
        json.loads(p.read_text(), parse_constant=_refuse)
    s = json.loads((demo / "summary.json").read_text())
    still = [r for r in s["study"] if r["speed_mps"] == 0]
    assert still and all(r["line_spacing_m"] is None for r in still)


def test_demo_report_says_what_quick_ran(demo):
    """--quick's numbers in the step texts, above the commands that ran them."""
    md = (demo / "report.md").read_text()
    block = md.split("## 2. mls")[1].split("## 3.")[0]
    assert "3 m/s, 25 profiles/s, chainage 5-60 m" in block
    assert "--speed 3.0" in block and "--rate 25" in block and "--chainage 5,60" in block
    plan = md.split("station planning")[1]
    assert "95 % coverage" in plan.split("```")[0] and "--target 0.95" in plan
    assert "99 %" not in md.split("## 12. station planning")[1].split("```")[0]


def test_print_config_is_the_shipped_pipeline(capsys):
    assert main(["demo", "--print-config"]) == 0
    text = capsys.readouterr().out
    assert text == demo_text()
    pipe = load_pipeline(text)
    assert [s["command"] for s in pipe["steps"]][:3] == ["tunnel", "drive", "correct"]
    for st in pipe["steps"]:           # every step's options exist on its command
        step_argv(st, quick=True)
        step_argv(st)


def test_run_a_small_pipeline(tmp_path):
    (tmp_path / "p.toml").write_text('''
[pipeline]
name = "two steps"
seed = 3

[[steps]]
command = "tunnel"
[steps.options]
output = "t.ply"
preset = "tbm"
edge-length = 0.5

[[steps]]
command = "plan"
tables = ["plan/plan.md"]
figures = ["plan/coverage.png"]
[steps.options]
mesh = "t.ply"
spacing = "10,20"
cell = "0.5,6"
output = "plan"
''')
    out = tmp_path / "o"
    assert main(["run", str(tmp_path / "p.toml"), "-o", str(out), "--quiet"]) == 0
    md = (out / "report.md").read_text()
    assert "tunnelsim tunnel --output t.ply --preset tbm --edge-length 0.5 --seed 3" in md
    assert "![coverage](plan/coverage.png)" in md and "| every 10 m |" in md
    meta = json.loads((out / "t.json").read_text())
    assert meta["parameters"]["seed"] == 3


@pytest.mark.parametrize("body, match", [
    ("[[steps]]\ncommand = 'frobnicate'\n", "Expected a tunnelsim command"),
    ("[[steps]]\ncommand = 'tunnel'\n[steps.options]\nbogus = 1\n", "'--bogus'"),
    ("[[steps]]\ncommand = 'tunnel'\nwhat = 1\n", "Expected only"),
    ("[pipeline\n", "syntax error"),
    ("[pipeline]\nname = 'x'\n", "Expected \\[\\[steps\\]\\]"),
    ("[[steps]]\ncommand = 'tunnel'\n[steps.options]\noutput = 'x.obj'\n",
     "Expected step 1 'tunnel' to succeed"),
])
def test_bad_pipelines_are_one_line(tmp_path, capsys, body, match):
    (tmp_path / "p.toml").write_text(body)
    assert main(["run", str(tmp_path / "p.toml"), "-o", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert re.search(match, err[-1]) and err[-1].startswith("tunnelsim: error:")


def test_run_missing_file(tmp_path, capsys):
    assert main(["run", str(tmp_path / "none.toml"), "-o", str(tmp_path / "o")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_every_command_shares_the_common_options():
    cmds = _commands()
    assert {"tunnel", "scan", "drive", "adjust", "transform", "correct", "preprocess",
            "mesh", "compare", "plan", "study", "gazebo", "sensors", "demo", "info",
            "run"} <= set(cmds)
    assert {n for n, c in cmds.items() if c.seeded} == SEEDED
    assert {n for n, c in cmds.items() if c.printing} == PRINTING
    for name, c in cmds.items():
        # What the parser itself offers (its help), not only what the registry recorded.
        text = c.parser.format_help()
        have = {f for f in ("--debug", "--quiet", "--threads", "--seed") if f in text}
        assert "--debug" in have, name
        assert ("Example: tunnelsim " + name) in (c.parser.epilog or ""), name
        if name not in PRINTING:
            assert {"--quiet", "--threads"} <= have, name
        if name in SEEDED:
            assert "--seed" in have, name


@pytest.mark.parametrize("name", sorted(_commands()))
def test_every_command_rejects_a_bad_option_in_one_line(name, capsys):
    assert main([name, "--no-such-option"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ("unrecognized arguments" in err[0] or "required" in err[0])


def test_bad_thread_count_is_one_line(tmp_path, capsys):
    assert main(["tunnel", "-o", str(tmp_path / "t.ply"), "--threads", "999"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--threads" in err[0]


def test_pipeline_toml_is_valid_toml():
    data = tomllib.loads(demo_text())
    assert data["pipeline"]["seed"] == 0 and len(data["steps"]) >= 10
    assert np.isfinite([s.get("expect_s", 1) for s in data["steps"]]).all()


def test_ctrl_c_leaves_no_partial_output(tmp_path):
    """SIGINT while a drive is being written: exit 130, one line, no output file and no
    temporary left behind."""
    import os
    import signal
    import subprocess
    import sys
    import time

    assert main(["tunnel", "-o", str(tmp_path / "t.ply"), "--preset", "tbm",
                 "--edge-length", "0.5", "--quiet"]) == 0
    out = tmp_path / "drive.laz"
    proc = subprocess.Popen(
        [sys.executable, "-m", "survey.cli", "drive", "--mesh", str(tmp_path / "t.ply"),
         "--sensor", "robosense_airy", "--along", "centreline", "--speed", "0.5",
         "-o", str(out), "--quiet"], stderr=subprocess.PIPE, text=True,
        env=dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[2])))
    deadline = time.time() + 120
    while not list(tmp_path.glob(".drive.laz.*.part")):
        assert proc.poll() is None and time.time() < deadline, "writing never started"
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    err = proc.communicate(timeout=60)[1].strip().splitlines()
    assert proc.returncode == 130
    assert err == ["tunnelsim: interrupted"]
    assert not out.exists() and not list(tmp_path.glob(".drive.laz.*"))
