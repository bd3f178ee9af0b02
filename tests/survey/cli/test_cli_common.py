"""What every command shares: negative numbers in X,Y,Z options, one-line errors, no
outputs left behind by a failed command, a light start, and pipelines run through the
command registry."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest

from survey.cli.common import removed_on_failure
from survey.cli.main import build_parser, main
from survey.cli.pipeline import load_pipeline, run_pipeline, step_about
from survey.errors import PipelineError, TunnelsimCLIError

ROOT = Path(__file__).resolve().parents[3]

#: A valid command line for each X,Y,Z option, the option's value left to the test.
XYZ_LINES = {
    ("scan", "at"): ["scan", "--mesh", "m.ply", "-o", "s.laz", "--at"],
    ("drive", "lever"): ["drive", "--mesh", "m.ply", "-o", "d.laz", "--lever"],
    ("tunnel", "origin"): ["tunnel", "-o", "t.ply", "--origin"],
    ("render", "at"): ["render", "--mesh", "m.ply", "--camera", "lwir_640", "-o", "f",
                       "--heading-deg", "0", "--at"],
}


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tunnelsim: error: "), err
    assert "Traceback" not in err[0]
    return err[0]


@pytest.fixture(scope="module")
def tbm(tbm_mesh):
    return tbm_mesh(0.5)


# ---------------------------------------------------------------------------- numbers
def test_every_xyz_option_is_covered():
    """Every option whose value is X,Y,Z (or E,N,H) has a line below: a new one fails
    here until it is tested for negative numbers too."""
    found = {(name, o.name) for name, c in build_parser()[1].items()
             for o in c.options.values() if o.metavar in ("X,Y,Z", "E,N,H")}
    assert found == set(XYZ_LINES)


@pytest.mark.parametrize("key", sorted(XYZ_LINES))
@pytest.mark.parametrize("value", ["-3.2,10,1.5", "-3,-10,-1.5", "1,-2,-3", "-.5:2:1e-3"])
def test_every_xyz_option_takes_negative_numbers(key, value):
    parser, commands = build_parser()
    args = parser.parse_args([*XYZ_LINES[key], value])
    assert getattr(args, commands[key[0]].options[key[1]].dest) == value
    # The same with "=", and an option after it still parsed as one.
    args = parser.parse_args([*XYZ_LINES[key][:-1], f"--{key[1]}={value}", "--quiet"])
    assert getattr(args, commands[key[0]].options[key[1]].dest) == value and args.quiet


@pytest.mark.parametrize("argv, dest, value", [
    (["drive", "--mesh", "m", "-o", "d.laz", "--chainage", "-5,10"], "chainage", "-5,10"),
    (["preprocess", "c.laz", "-o", "o.laz", "--crop", "-2,3"], "crop", "-2,3"),
    (["tunnel", "-o", "t.ply", "--heading-deg", "-30"], "heading_deg", -30.0),
    (["tunnel", "-o", "t.ply", "--convergence", "-5:10:3"], "convergence", ["-5:10:3"]),
])
def test_other_number_options_take_negative_values(argv, dest, value):
    assert getattr(build_parser()[0].parse_args(argv), dest) == value


def test_a_negative_value_is_not_taken_for_a_flag(capsys):
    # --quiet takes no value: "-3,1,2" after it stays an (unknown) argument.
    assert main(["tunnel", "-o", "t.ply", "--quiet", "-3,1,2"]) == 2
    assert "unrecognized arguments: -3,1,2" in _one_line_error(capsys)


def test_negative_origin_and_station_end_to_end(tmp_path):
    """A tunnel whose first portal is at negative local coordinates, and a station in it
    placed with a negative --at: the station is where --at says (each point minus its
    sensor-frame coordinates; heading 0, so the frames are parallel)."""
    t = tmp_path / "t.ply"
    assert main(["tunnel", "-o", str(t), "--preset", "tbm", "--edge-length", "0.5",
                 "--origin", "-100,-50,-10", "--quiet"]) == 0
    from survey.world.mesh import read_axis

    al, _ = read_axis(t.with_suffix(".json"))
    first = al.to_world(np.array([al.chainage_range[0]]), np.zeros(1), np.zeros(1))
    np.testing.assert_allclose(np.reshape(first, 3), [-100.0, -50.0, -10.0], atol=1e-9)
    out = tmp_path / "s.laz"
    assert main(["scan", "--mesh", str(t), "--at", "-50,-50,-8.5", "--resolution",
                 "preview", "--ideal", "--fields", "full", "-o", str(out), "--quiet"]) == 0
    las = laspy.read(out)
    world = np.stack([las.x, las.y, las.z], 1)
    local = np.stack([las["sensor_x"], las["sensor_y"], las["sensor_z"]], 1)
    assert len(world) > 100_000
    np.testing.assert_allclose(world - local, np.broadcast_to([-50.0, -50.0, -8.5],
                                                               world.shape), atol=1e-4)


def test_negative_lever_arm_end_to_end(tbm, tmp_path):
    """A drive with a negative lever arm on a level platform with identity attitude:
    every point minus its sensor-frame coordinates is the platform position at the
    point's time plus the lever arm."""
    from scipy.spatial.transform import Rotation

    from sensors import Trajectory

    Trajectory([0.0, 0.2], [[10.0, 0.0, 1.5], [10.4, 0.0, 1.5]],
               Rotation.identity(2)).write(tmp_path / "traj.txt")
    out = tmp_path / "d.laz"
    assert main(["drive", "--mesh", str(tbm), "--sensor", "velodyne_vlp16", "--trajectory",
                 str(tmp_path / "traj.txt"), "--lever", "-0.2,0.1,-0.3", "--ideal",
                 "--fields", "full", "-o", str(out), "--quiet"]) == 0
    las = laspy.read(out)
    t = np.asarray(las.gps_time)
    base = np.stack([10.0 + 2.0 * t, 0 * t, 0 * t + 1.5], 1)
    got = np.stack([las.x, las.y, las.z], 1) - \
        np.stack([las["sensor_x"], las["sensor_y"], las["sensor_z"]], 1) - base
    assert len(t) > 10_000
    np.testing.assert_allclose(got, np.broadcast_to([-0.2, 0.1, -0.3], got.shape),
                               atol=1e-4)


# ---------------------------------------------------------------------------- errors
def test_usage_errors_are_one_line_and_name_the_command(capsys):
    assert main(["scan", "--mesh", "m.ply", "--at", "1,2,3", "-o", "s.laz", "--nope"]) == 2
    line = _one_line_error(capsys)
    assert "unrecognized arguments: --nope" in line and "'tunnelsim scan --help'" in line
    assert main(["scan", "--mesh", "m.ply", "-o", "s.laz"]) == 2
    assert "one of the arguments --at --chainage --chainages --plan is required" in _one_line_error(capsys)
    assert main(["frobnicate"]) == 2
    assert "invalid choice: 'frobnicate'" in _one_line_error(capsys)


def test_debug_shows_the_traceback(tmp_path):
    with pytest.raises(TunnelsimCLIError, match="ending in .ply"):
        main(["tunnel", "-o", str(tmp_path / "x.obj"), "--debug"])


def test_failed_tunnel_leaves_no_mesh(tmp_path, capsys):
    """The first epoch is written, then the second fails (no such folder): neither the
    PLY nor its JSON stays."""
    assert main(["tunnel", "-o", str(tmp_path / "t.ply"), "--preset", "tbm",
                 "--edge-length", "0.5", "--epoch2", str(tmp_path / "no" / "e.ply")]) == 2
    assert "existing output folder" in _one_line_error(capsys)
    assert list(tmp_path.iterdir()) == []


def test_failed_drive_leaves_no_trajectories(tbm, tmp_path, capsys):
    """--slam-drift writes its trajectories and control points first; the cloud then
    fails (E57 is for stations only): none of the five files stays."""
    (tmp_path / "mine.txt").write_text("a user's file\n")
    assert main(["drive", "--mesh", str(tbm), "--sensor", "velodyne_vlp16", "--along",
                 "centreline", "--speed", "20", "--slam-drift", "-o",
                 str(tmp_path / "d.e57")]) == 2
    assert "E57" in _one_line_error(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"]


def test_failed_mesh_leaves_no_ply(tbm, tmp_path, capsys):
    from sensors.io.cloudmap import write_points_las
    from survey.world.mesh import LABEL, read_tunnel

    tun = read_tunnel(tbm)
    rng = np.random.default_rng(0)
    lin = tun.faces[np.isin(tun.labels, [LABEL["lining"], LABEL["floor"]])]
    tri = tun.vertices[lin[rng.integers(0, len(lin), 50_000)]]
    write_points_las(tmp_path / "c.laz", np.einsum("nk,nkj->nj",
                                                   rng.dirichlet([1, 1, 1], len(tri)), tri))
    before = set(tmp_path.iterdir())
    assert main(["mesh", str(tmp_path / "c.laz"), "-o", str(tmp_path / "m.ply"), "--cell",
                 "0.5,4", "--tunnel-json", str(tbm.with_suffix(".json")), "--json",
                 str(tmp_path / "no" / "q.json")]) == 2
    assert "existing folder" in _one_line_error(capsys)
    assert set(tmp_path.iterdir()) == before


@pytest.mark.parametrize("force", [False, True])
def test_failed_compare_leaves_no_folder(tmp_path, capsys, force):
    """The compared cloud is unreadable; the output folder (new, or existing with the
    user's file and --force) ends as it was."""
    from sensors.io.cloudmap import write_points_las

    write_points_las(tmp_path / "ref.laz", np.random.default_rng(1).normal(size=(500, 3)))
    (tmp_path / "bad.xyz").write_text("1 2 3\n4 5 x\n")
    out = tmp_path / "cmp"
    if force:
        out.mkdir()
        (out / "keep.md").write_text("mine\n")
    argv = ["compare", str(tmp_path / "bad.xyz"), str(tmp_path / "ref.laz"), "-o", str(out)]
    assert main(argv + (["--force"] if force else [])) == 2
    _one_line_error(capsys)
    if force:
        assert [p.name for p in out.iterdir()] == ["keep.md"]
    else:
        assert not out.exists()


def test_removed_on_failure_keeps_what_existed(tmp_path):
    (tmp_path / "a_old.txt").write_text("old")
    (tmp_path / "a.laz").write_text("old")
    with pytest.raises(KeyboardInterrupt), removed_on_failure([tmp_path / "a.laz"]):
        (tmp_path / "a_new.txt").write_text("new")
        (tmp_path / "b.txt").write_text("other command's")
        (tmp_path / "a.laz").write_text("replaced")
        raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.laz", "a_old.txt", "b.txt"]
    with removed_on_failure([tmp_path / "c.laz"]):      # success: everything stays
        (tmp_path / "c.laz").write_text("new")
    assert (tmp_path / "c.laz").is_file()


def test_failed_pipeline_leaves_no_folder(tmp_path, capsys):
    (tmp_path / "p.toml").write_text(
        "[[steps]]\ncommand = 'tunnel'\n[steps.options]\noutput = 't.ply'\npreset = 'tbm'\n"
        "edge-length = 0.5\n\n[[steps]]\ncommand = 'tunnel'\n[steps.options]\n"
        "output = 'x.obj'\n")
    assert main(["run", str(tmp_path / "p.toml"), "-o", str(tmp_path / "o"), "--quiet"]) == 2
    assert "step 2 'tunnel'" in _one_line_error(capsys)
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------- start-up
def test_start_up_imports_no_heavy_module():
    """--version and a command's --help load neither NumPy nor any heavy library (the
    commands import them where they run)."""
    code = ("import sys\nfrom survey.cli.main import main\n"
            "for argv in (['--version'], ['scan', '--help'], ['demo', '--help']):\n"
            "    try:\n        main(argv)\n    except SystemExit:\n        pass\n"
            "heavy = ('numpy', 'scipy', 'numba', 'matplotlib', 'trimesh', 'laspy', "
            "'sensors.simulate', 'survey.world.mesh')\n"
            "print(sorted(m for m in heavy if m in sys.modules))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert res.stdout.strip().splitlines()[-1] == "[]"


# ---------------------------------------------------------------------------- pipelines
SMALL = """
[pipeline]
name = "small"

[[steps]]
command = "tunnel"
about = "A {preset} tunnel with {edge-length:cm} edges."
[steps.options]
output = "t.ply"
preset = "tbm"
edge-length = 0.5
[steps.quick]
edge-length = 0.75

[[steps]]
command = "plan"
about = "Stations every {spacing:list} m, {cell[0]:cm} x {cell[1]:g} deg cells, {target:%}."
[steps.options]
mesh = "t.ply"
spacing = "10,20"
cell = "0.5,6"
output = "plan"
"""


def test_pipeline_paths_are_the_output_folders_without_chdir(tmp_path, monkeypatch):
    """Steps run with their paths resolved against the output folder; the working
    directory is never changed and nothing lands in it."""
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)

    def no_chdir(path):
        raise AssertionError(f"os.chdir({path!r}) called")

    monkeypatch.setattr(os, "chdir", no_chdir)
    done = run_pipeline(load_pipeline(SMALL), tmp_path / "out", quiet=True)
    assert [argv[0] for _, argv, _ in done] == ["tunnel", "plan"]
    assert "--output t.ply" in " ".join(done[0][1])          # the report shows it as written
    assert (tmp_path / "out" / "t.ply").is_file() and (tmp_path / "out" / "t.json").is_file()
    assert (tmp_path / "out" / "plan" / "plan.json").is_file()
    assert list(cwd.iterdir()) == []
    # The about texts come from the options run (the plan's target is its default).
    assert done[0][0]["about"] == "A tbm tunnel with 50 cm edges."
    assert done[1][0]["about"] == "Stations every 10 and 20 m, 50 cm x 6 deg cells, 99 %."


def test_a_failing_step_raises_with_the_command_error(tmp_path):
    pipe = load_pipeline(SMALL.replace('output = "t.ply"', 'output = "t.obj"'))
    with pytest.raises(PipelineError, match=r"step 1 'tunnel' to succeed, got: Expected an "
                                            r"output file ending in \.ply") as exc:
        run_pipeline(pipe, tmp_path / "out", quiet=True)
    assert isinstance(exc.value.__cause__, TunnelsimCLIError)


@pytest.mark.parametrize("key", ["help", "h", "version", "nope"])
def test_step_options_are_the_registered_ones(key):
    """Only options the command registered: not argparse's own --help."""
    with pytest.raises(PipelineError, match=f"got '--{key}'"):
        load_pipeline(SMALL.replace("preset = \"tbm\"", f"preset = \"tbm\"\n{key} = true"))


def test_a_positional_is_not_an_option():
    with pytest.raises(PipelineError, match="got '--cloud'"):
        load_pipeline("[[steps]]\ncommand = 'mesh'\n[steps.options]\ncloud = 'c.laz'\n"
                      "output = 'm.ply'\n")


def test_about_follows_the_options():
    pipe = load_pipeline(SMALL)
    st = pipe["steps"][0]
    assert step_about(st) == "A tbm tunnel with 50 cm edges."
    assert step_about(st, quick=True) == "A tbm tunnel with 75 cm edges."
    st["options"]["edge-length"] = 0.3
    assert step_about(st) == "A tbm tunnel with 30 cm edges."
    with pytest.raises(PipelineError, match="'about' of step 'tunnel'"):
        load_pipeline(SMALL.replace("{preset}", "{nonsense}"))


def test_demo_about_texts_are_what_the_steps_run():
    """The shipped demo's texts say the numbers its steps run, in both modes."""
    from survey.cli.pipeline import demo_text

    steps = {s["name"]: s for s in load_pipeline(demo_text())["steps"]}
    mls, plan = steps["mls"], steps["station planning"]
    assert "3 m/s, 50 profiles/s, chainage 5-60 m" in step_about(mls)
    assert "3 m/s, 25 profiles/s, chainage 8-44 m" in step_about(mls, quick=True)
    assert "99 % coverage" in step_about(plan)
    assert "95 % coverage" in step_about(plan, quick=True)
    assert "10 and 20 Hz" in step_about(steps["MLS study"])
    assert "10 Hz" in step_about(steps["MLS study"], quick=True)
    assert "resolution preview" in step_about(steps["station 25 m on the true tunnel"],
                                              quick=True)



def test_a_pipeline_reruns_into_its_folder_with_force(tmp_path):
    """--force reaches the steps with output folders (plan here), so a rerun into the
    same folder replaces them instead of failing on the first one."""
    pipe = load_pipeline(SMALL)
    run_pipeline(pipe, tmp_path / "out", quiet=True)
    with pytest.raises(TunnelsimCLIError, match="pass --force"):
        run_pipeline(pipe, tmp_path / "out", quiet=True)
    (tmp_path / "out" / "plan" / "plan.md").write_text("old\n")
    done = run_pipeline(pipe, tmp_path / "out", quiet=True, force=True)
    assert "--force" in done[1][1] and "--force" not in done[0][1]   # tunnel has none
    assert (tmp_path / "out" / "plan" / "plan.md").read_text().startswith("# Station plan")
