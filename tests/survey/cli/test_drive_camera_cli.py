"""``tunnelsim drive --camera`` (issue 35) through the real command line: what it prints
and writes beside a point file, and bad input as one line on stderr naming the option,
exit 2, nothing written."""

from __future__ import annotations

import pytest

from survey.cli.main import main
from tests.survey.workflows.test_drive_camera import COLOR
from tests.survey.workflows.test_drive_workflow import SENSOR


@pytest.fixture()
def setup(tmp_path, tbm_20k):
    (tmp_path / "s.toml").write_text(SENSOR)
    (tmp_path / "c.toml").write_text(COLOR)
    traj = tmp_path / "t.txt"
    traj.write_text("# t x y z qx qy qz qw\n" + "".join(
        f"{i / 100:.2f} {20 + 0.02 * i:.4f} 0.3 1.5 0 0 0 1\n" for i in range(51)))
    return tmp_path, tbm_20k


def _drive(tmp_path, mesh, out, *extra):
    return main(["drive", "--mesh", str(mesh), "--sensor", str(tmp_path / "s.toml"),
                 "--trajectory", str(tmp_path / "t.txt"), "--duration", "0.3",
                 "-o", str(tmp_path / out), *extra])


def test_png_folder_beside_a_point_file(setup, capsys):
    tmp_path, mesh = setup
    assert _drive(tmp_path, mesh, "d.laz", "--camera", str(tmp_path / "c.toml"),
                  "--camera-rate-hz", "10", "--lamp-cd", "400") == 0
    out = capsys.readouterr().out
    assert ("camera test_rgb: 3 frames of 64x48 at 10 Hz (rolling shutter, headlamp "
            "400 cd), 0.00922 M rays -> d_cameras/test_rgb/") in out
    folder = tmp_path / "d_cameras" / "test_rgb"
    assert sorted(p.name for p in folder.iterdir()) == ["camera_info.json", "depth",
                                                        "frames.csv", "rgb"]
    assert len(list((folder / "rgb").iterdir())) == 3
    assert not [p for p in tmp_path.rglob("*.part")]


@pytest.mark.parametrize("extra, match", [
    (["--camera", "no_such_camera"], "--camera"),
    (["--camera-rate-hz", "10"], "Expected --camera NAME with --camera-rate-hz"),
    (["--camera", "C", "--camera-rate-hz", "25"], "--camera-rate-hz in (0, 20]"),
    (["--camera", "C", "--camera-mount", "1,2"], "--camera-mount as X,Y,Z"),
    (["--camera", "C", "--camera-mount", "a,b,c"], "--camera-mount"),
    (["--camera", "C", "--camera-samples", "3"], "--camera-samples"),
    (["--camera", "C", "--lamp-cd", "-5"], "--lamp-cd >= 0"),
    (["--camera", "C", "--camera", "C"], "each --camera once"),
])
def test_bad_camera_options_are_refused(setup, capsys, monkeypatch, extra, match):
    tmp_path, mesh = setup
    extra = [str(tmp_path / "c.toml") if x == "C" else x for x in extra]
    monkeypatch.chdir(tmp_path)
    before = set(tmp_path.iterdir())
    assert _drive(tmp_path, mesh, "x.laz", *extra) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and match in err and "Traceback" not in err
    assert set(tmp_path.iterdir()) == before


def test_cameras_in_a_bag_refuse_slam_drift(setup, capsys, monkeypatch):
    tmp_path, mesh = setup
    monkeypatch.chdir(tmp_path)
    assert main(["drive", "--mesh", str(mesh), "--sensor", str(tmp_path / "s.toml"),
                 "--along", "centreline", "--speed", "2", "--duration", "0.3",
                 "--slam-drift", "--camera", str(tmp_path / "c.toml"), "-o", "b.mcap"]) == 2
    err = capsys.readouterr().err
    assert "--camera in a ROS 2 bag without --slam-drift" in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "b.mcap").exists()
