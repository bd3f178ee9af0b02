"""``drive --slam-drift`` writes the drifted cloud (issue 15's bug): tested on the files a
user gets, against the true cloud of the same drive mapped through the SLAM-vs-true
pose difference at each point's own time."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from sensors import Trajectory
from survey.adjust.controlpoints import read_control_points
from survey.adjust.slam import DriftedRun, observe_slam, to_slam_frame
from survey.cli.main import main

#: Half the LAS grid (0.1 mm) on each of the two files compared, per axis; plus 1 µm for
#: the trajectories' 9-decimal text and the float arithmetic.
LAS_TOL_M = 1e-4 + 1e-6


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """The same drive (seed 3, --ideal) with and without --slam-drift."""
    d = tmp_path_factory.mktemp("drift")
    assert main(["tunnel", "-o", str(d / "tbm.ply"), "--preset", "tbm", "--edge-length",
                 "0.3", "--quiet"]) == 0
    common = ["drive", "--mesh", str(d / "tbm.ply"), "--sensor", "velodyne_vlp16",
              "--along", "centreline", "--speed", "15", "--chainage", "2,92", "--ideal",
              "--seed", "3", "--fields", "compact", "--quiet"]
    assert main([*common, "-o", str(d / "plain.laz")]) == 0
    assert main([*common, "--slam-drift", "-o", str(d / "drift.laz")]) == 0
    return d


def _xyzt(path):
    las = laspy.read(path)
    return np.stack([las.x, las.y, las.z], 1), np.asarray(las.gps_time)


def test_slam_drift_cloud_is_the_true_cloud_in_the_slam_frame(drives):
    plain, t_plain = _xyzt(drives / "plain.laz")
    drift, t_drift = _xyzt(drives / "drift.laz")
    # --ideal and the same seed: the same pulses hit the same points in the same order.
    assert len(plain) == len(drift) > 500_000
    np.testing.assert_array_equal(t_plain, t_drift)
    slam = Trajectory.read(drives / "drift_trajectory.txt")
    true = Trajectory.read(drives / "drift_true_trajectory.txt")
    want = to_slam_frame(true, slam, plain, t_plain)
    assert np.abs(drift - want).max() <= LAS_TOL_M
    # ... and the cloud moved where the SLAM drifted (the bug wrote the true cloud).
    moved = np.linalg.norm(want - plain, axis=1)
    assert np.mean(moved > 1e-3) > 0.5 and moved.max() > 0.01
    differs = np.linalg.norm(drift - plain, axis=1)
    big = moved > 1e-3
    assert (differs[big] > moved[big] - 2 * LAS_TOL_M * np.sqrt(3)).all()
    small = moved < 1e-5          # the very start, before any drift
    assert np.abs(drift[small] - plain[small]).max() <= 2 * LAS_TOL_M


def test_slam_drift_control_points_are_consistent(drives):
    """The observed control points are the world ones moved into the SLAM frame at their
    time, within the assumed picking and total-station noise (4 sigma)."""
    from survey.adjust.slam import CONTROL_SIGMA_M, PRISM_SIGMA_MLS_M

    seen = read_control_points(drives / "drift_cp_observed.csv")
    world = read_control_points(drives / "drift_cp_world.csv")
    assert len(seen) >= 3 and seen.time is not None
    slam = Trajectory.read(drives / "drift_trajectory.txt")
    true = Trajectory.read(drives / "drift_true_trajectory.txt")
    idx = [world.ids.index(i) for i in seen.ids]
    want = to_slam_frame(true, slam, world.xyz[idx], seen.time)
    assert np.abs(seen.xyz - want).max() < 4 * (PRISM_SIGMA_MLS_M + CONTROL_SIGMA_M)


def test_drifted_run_writes_what_it_iterates(tmp_path):
    """The wrapper's ``write`` streams the moved chunks in every format (NPZ keeps
    float64, so the match is exact), and iterating it moves every chunk."""
    from raytrace import Scene
    from sensors import Mount, load_sensor, simulate_drive

    # A closed box 10 x 4 x 4 m around a 6 m straight drive.
    v = np.array([[x, y, z] for x in (-2.0, 8.0) for y in (-2.0, 2.0) for z in (-2.0, 2.0)])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    scene = Scene(v, f)
    traj = Trajectory.along_polyline(np.array([[0.0, 0, 0], [6.0, 0, 0]]), 3.0)
    spec = load_sensor("velodyne_vlp16")
    from sensors import Settings

    run = simulate_drive(scene, spec, traj, Mount(), settings=Settings.ideal(), seed=1)
    obs = observe_slam(run, traj, ["A", "B"], [[2.0, 2.0, 0.0], [4.0, -2.0, 0.0]], seed=5,
                       heading_rw=2e-3, pitch_rw=1e-3, roll_rw=1e-3)
    assert isinstance(obs.run, DriftedRun)
    plain = np.concatenate(list(run))
    moved = np.concatenate(list(obs.run))
    want = to_slam_frame(traj, obs.slam, np.stack([plain["x"], plain["y"], plain["z"]], 1),
                         plain["time"])
    np.testing.assert_allclose(np.stack([moved["x"], moved["y"], moved["z"]], 1), want,
                               rtol=0, atol=1e-12)
    assert np.abs(want - np.stack([plain["x"], plain["y"], plain["z"]], 1)).max() > 1e-3
    stats = obs.run.write(tmp_path / "d.npz")
    assert stats["points"] == len(plain)
    back = np.load(tmp_path / "d.npz")
    np.testing.assert_array_equal(np.stack([back["x"], back["y"], back["z"]], 1),
                                  np.stack([moved["x"], moved["y"], moved["z"]], 1))


def test_observe_slam_rejects_mismatched_control_points():
    from survey.errors import DriftError

    traj = Trajectory.along_polyline(np.array([[0.0, 0, 0], [6.0, 0, 0]]), 3.0)
    with pytest.raises(DriftError, match="Expected one id per finite control point"):
        observe_slam(None, traj, ["A"], np.zeros((2, 3)))
    with pytest.raises(DriftError, match="prism_sigma_m"):
        observe_slam(None, traj, ["A"], np.zeros((1, 3)), prism_sigma_m=-1.0)
