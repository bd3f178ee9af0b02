"""A drive ends at its last whole sweep (issue 22: a 2 s OS1 drive used to end with a
21st sweep of 53 points), unless --keep-partial-sweep; the files the user gets (the
cloud's frames, the truth's last pose) agree."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from survey.cli.main import main


@pytest.fixture(scope="module")
def tube(tmp_path_factory):
    d = tmp_path_factory.mktemp("ws")
    assert main(["tunnel", "--preset", "tbm", "--edge-length", "0.5", "-o",
                 str(d / "t.ply"), "--quiet"]) == 0
    return d / "t.ply"


@pytest.mark.parametrize("keep", [False, True])
def test_drive_ends_at_the_last_whole_sweep(tube, tmp_path, keep):
    out = tmp_path / "d.las"
    args = ["drive", "--mesh", str(tube), "--sensor", "velodyne_vlp16", "--along",
            "centreline", "--speed", "1", "--duration", "0.25", "--fields", "full",
            "-o", str(out), "--quiet"] + (["--keep-partial-sweep"] if keep else [])
    assert main(args) == 0
    las = laspy.read(out)
    frames, counts = np.unique(np.asarray(las["frame"]), return_counts=True)
    truth = np.loadtxt(tmp_path / "d_true_trajectory.txt")
    # VLP-16 at 10 Hz: 0.25 s is two whole revolutions and half of a third.
    if keep:
        assert frames.tolist() == [0, 1, 2]
        assert counts[2] < 0.6 * counts[1]
        assert truth[-1, 0] - truth[0, 0] == pytest.approx(0.25, abs=1e-9)
    else:
        assert frames.tolist() == [0, 1]
        assert abs(counts[1] - counts[0]) < 0.05 * counts[0]     # both whole
        assert truth[-1, 0] - truth[0, 0] == pytest.approx(0.2, abs=1e-9)
        assert np.asarray(las.gps_time).max() <= truth[-1, 0] + 1e-9


def test_files_beside_a_copc_drive_take_its_stem(tube, tmp_path):
    """``d.copc.laz``'s truth is ``d_true_trajectory.txt`` (not ``d.copc_...``)."""
    out = tmp_path / "d.copc.laz"
    assert main(["drive", "--mesh", str(tube), "--sensor", "velodyne_vlp16", "--along",
                 "centreline", "--speed", "1", "--duration", "0.2", "-o", str(out),
                 "--quiet"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "d.copc.laz", "d_robot.launch.py", "d_robot.urdf", "d_true_trajectory.txt"]


@pytest.mark.parametrize("suffix", ["npz", "las"])
def test_drive_in_windows_writes_the_one_piece_points(tube, tmp_path, suffix):
    """drive --window-s (issue 19), in this process: the file holds the points of the
    drive run in one piece; NPZ byte for byte (LAS: the points; laspy's extra-bytes
    statistics in the header depend on the chunking)."""
    base = ["drive", "--mesh", str(tube), "--sensor", "velodyne_vlp16", "--along",
            "centreline", "--speed", "1", "--duration", "0.5", "--fields", "full",
            "--quiet", "--seed", "3"]
    one, win = tmp_path / f"one.{suffix}", tmp_path / f"win.{suffix}"
    assert main(base + ["-o", str(one)]) == 0
    assert main(base + ["-o", str(win), "--window-s", "0.2"]) == 0
    if suffix == "npz":
        a, b = np.load(one), np.load(win)
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k])
    else:
        a, b = laspy.read(one), laspy.read(win)
        assert a.header.point_count == b.header.point_count > 0
        np.testing.assert_array_equal(np.asarray(a.points.array), np.asarray(b.points.array))


def test_cluster_options_need_windows(tube, tmp_path, capsys):
    code = main(["drive", "--mesh", str(tube), "--sensor", "velodyne_vlp16", "--along",
                 "centreline", "--speed", "1", "--duration", "0.2", "--workers", "2",
                 "-o", str(tmp_path / "d.laz")])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert "--window-s" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "d.laz").exists()


def test_drive_in_windows_on_a_local_cluster(tube, tmp_path, capsys):
    """The same command on a LocalCluster of 2 workers: the same points, the cluster
    named in the summary line."""
    pytest.importorskip("distributed")
    base = ["drive", "--mesh", str(tube), "--sensor", "velodyne_vlp16", "--along",
            "centreline", "--speed", "1", "--duration", "0.4", "--seed", "5"]
    assert main(base + ["-o", str(tmp_path / "one.npz"), "--quiet"]) == 0
    assert main(base + ["-o", str(tmp_path / "win.npz"), "--window-s", "0.1",
                        "--workers", "2"]) == 0
    assert "local cluster" in capsys.readouterr().out
    a, b = np.load(tmp_path / "one.npz"), np.load(tmp_path / "win.npz")
    for k in a.files:
        np.testing.assert_array_equal(a[k], b[k])
