"""`tunnelsim drive --start-time --ros-distro` (issue 30): the bag a user gets, read
back with rosbags; bad input is one line on stderr, exit 2, nothing written."""

from __future__ import annotations

from pathlib import Path

import pytest

from survey.cli.main import main

pytest.importorskip("rosbags", reason="rosbags is in the test extra")
from rosbags.highlevel import AnyReader  # noqa: E402
from ruamel.yaml import YAML  # noqa: E402

EPOCH_NS = 1_714_564_800 * 10 ** 9           # 2024-05-01T12:00:00Z


@pytest.fixture(scope="module")
def tbm(tbm_mesh):
    return tbm_mesh(0.3)


def _drive(tbm, out, *extra):
    return main(["drive", "--mesh", str(tbm), "--sensor", "velodyne_vlp16", "--along",
                 "centreline", "--speed", "2", "--duration", "0.3", "-o", str(out),
                 "--quiet", *extra])


def _stamps(path):
    with AnyReader([Path(path)]) as r:
        c = [x for x in r.connections if x.topic == "/velodyne_points"]
        return [(t, r.deserialize(raw, x.msgtype).header.stamp)
                for x, t, raw in r.messages(connections=c)]


def test_start_time_moves_every_stamp_to_the_epoch(tbm, tmp_path):
    assert _drive(tbm, tmp_path / "a.mcap") == 0
    assert _drive(tbm, tmp_path / "b.mcap", "--start-time", "2024-05-01T12:00:00Z") == 0
    a, b = _stamps(tmp_path / "a.mcap"), _stamps(tmp_path / "b.mcap")
    assert len(a) == len(b) == 3
    assert a[0][1].sec == 0                         # the trajectory's own time base
    for k, (log, stamp) in enumerate(b):
        assert stamp.sec * 10 ** 9 + stamp.nanosec == EPOCH_NS + k * 100_000_000
        assert log == EPOCH_NS + (k + 1) * 100_000_000


def test_ros_distro_picks_the_metadata_version(tbm, tmp_path):
    for distro, version in (("humble", 5), ("jazzy", 9)):
        assert _drive(tbm, tmp_path / distro, "--ros-distro", distro) == 0
        meta = YAML(typ="safe").load((tmp_path / distro / "metadata.yaml").read_text())
        assert meta["rosbag2_bagfile_information"]["version"] == version
        assert len(_stamps(tmp_path / distro)) == 3


@pytest.mark.parametrize("extra, out, match", [
    (["--start-time", "noon"], "x.mcap", "--start-time"),
    (["--start-time", "2024-05-01T12:00:00"], "x.mcap", "--start-time"),
    (["--start-time", "1714564800"], "x.laz", "ROS 2 bag"),
    (["--ros-distro", "humble"], "x.laz", "ROS 2 bag"),
])
def test_bad_bag_options_are_refused(tbm, tmp_path, capsys, monkeypatch, extra, out, match):
    monkeypatch.chdir(tmp_path)
    assert _drive(tbm, out, *extra) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and match in err and "Traceback" not in err
    assert not list(tmp_path.iterdir())
