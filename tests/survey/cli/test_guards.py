"""Guards with a reason (issue 21), tested on what a user gets: the exit status, the one
stderr line, no output left behind, and the files written where the behaviour is
"trims" or "reads by header".

compare refuses clouds far apart (and shows progress); scan refuses a station outside
the mesh or one that returns nothing; drive refuses a trajectory out of reach of the
mesh, a drive returning almost nothing, ns/us stamps and a --duration past the end
(before the mesh is loaded), and trims every output to --duration; a degree option
that looks like radians warns; --azimuth-deg gives the station --heading-deg gives.
"""

from __future__ import annotations

import io
import json
import math
import sys

import laspy
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sensors import Trajectory
from survey.analysis.compare import OVERLAP_TOL_M, box_gap, check_overlap
from survey.workflows.drive import MIN_DRIVE_RETURN
from survey.cli.common import radian_like
from survey.cli.main import main
from sensors.io.cloudmap import write_points_las
from survey.errors import CompareError


@pytest.fixture(scope="module")
def tbm(tbm_mesh):
    """The 100 m tbm tunnel, 0.5 m edges: x from 0 to 100 along the axis, |y| < 2.51,
    z from 0 to 5.01."""
    return tbm_mesh(0.5)


def _fails(capsys, *words) -> str:
    """The one stderr line of a refused command, holding every word."""
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tunnelsim: error: "), err
    for w in words:
        assert w in err[0], (w, err[0])
    return err[0]


def _warnings(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.startswith("tunnelsim: warning: ")]


def _boom(*a, **k):
    raise AssertionError("called, but the guard should have refused before")


def _traj_file(path, xyz0, *, n=201, step_m=0.05, rate_hz=100.0, rot=None, scale=1.0):
    """A TUM file: a straight drive along +x from ``xyz0`` (``scale`` multiplies the
    stamps, e.g. 1e9 for nanoseconds)."""
    t = np.arange(n) / rate_hz
    pos = np.asarray(xyz0, dtype=float) + np.c_[step_m * np.arange(n), 0 * t, 0 * t]
    q = (rot or Rotation.identity()).as_quat()
    np.savetxt(path, np.c_[t * scale, pos, np.tile(q, (n, 1))], fmt="%.17g")
    return path


# ---------------------------------------------------------------------------- compare
def test_box_gap_and_overlap():
    a = [[0, 0, 0], [1, 1, 1]]
    assert box_gap(a, [[0.5, 0.5, 0.5], [3, 3, 3]]) == 0.0           # overlap
    assert box_gap(a, [[1, 0, 0], [2, 1, 1]]) == 0.0                 # touching
    assert box_gap(a, [[4, 0, 0], [5, 1, 1]]) == 3.0                 # along x
    assert box_gap(a, [[4, 5, -2], [5, 6, -1]]) == pytest.approx(math.sqrt(9 + 16 + 1))
    assert box_gap([[4, 5, -2], [5, 6, -1]], a) == box_gap(a, [[4, 5, -2], [5, 6, -1]])
    assert check_overlap(a, [[1.9, 0, 0], [2, 1, 1]]) == pytest.approx(0.9)
    with pytest.raises(CompareError, match=r"within 1 m\), got \(0, 0, 0\)-\(1, 1, 1\) and "
                                           r"\(2.5, 0, 0\)-\(3, 1, 1\), 1.500 m apart"):
        check_overlap(a, [[2.5, 0, 0], [3, 1, 1]])
    with pytest.raises(CompareError, match="box"):
        box_gap([[1, 0, 0], [0, 1, 1]], a)                          # min > max
    assert OVERLAP_TOL_M == 1.0


@pytest.fixture(scope="module")
def far_clouds(tmp_path_factory):
    """A cloud in a Swiss-grid-like frame, one 4,675 km away in a UTM-like frame, and
    one 2 cm off the first (a moved wall: boxes apart, but a comparison)."""
    d = tmp_path_factory.mktemp("far")
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 10, (3000, 3)) + [2600000, 1200000, 500]
    write_points_las(d / "a.laz", a)
    write_points_las(d / "b.laz", rng.uniform(0, 10, (3000, 3)) + [451000, 5352000, 600])
    flat = np.c_[rng.uniform(0, 10, (3000, 2)), np.zeros(3000)] + [2600000, 1200000, 500]
    write_points_las(d / "wall0.laz", flat)
    write_points_las(d / "wall1.laz", flat + [0, 0, 0.02])
    return d


def test_compare_refuses_clouds_far_apart(far_clouds, tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["compare", str(far_clouds / "a.laz"), str(far_clouds / "b.laz"), "-o",
                 str(out)]) == 2
    _fails(capsys, "overlap", "(2600000", "(451000", "km apart", "coordinate systems",
           "--allow-disjoint")
    assert not out.exists()
    # The user says so: compared, and every distance is at least the gap.
    assert main(["compare", str(far_clouds / "a.laz"), str(far_clouds / "b.laz"), "-o",
                 str(out), "--allow-disjoint", "--quiet"]) == 0
    d = np.asarray(laspy.read(out / "a_distance.laz")["distance"])
    gap = box_gap([[2600000, 1200000, 500], [2600010, 1200010, 510]],
                  [[451000, 5352000, 600], [451010, 5352010, 610]])
    assert d.min() > 0.999 * gap


def test_compare_refuses_a_cloud_far_from_a_mesh(far_clouds, tbm, tmp_path, capsys):
    assert main(["compare", str(far_clouds / "a.laz"), str(tbm), "-o",
                 str(tmp_path / "c")]) == 2
    _fails(capsys, "overlap", "tbm.ply", "(0, -2.5", "km apart")
    assert not (tmp_path / "c").exists()


def test_compare_takes_a_moved_wall(far_clouds, tmp_path):
    """Boxes 2 cm apart (a wall that moved): within the 1 m tolerance, compared."""
    out = tmp_path / "w"
    assert main(["compare", str(far_clouds / "wall1.laz"), str(far_clouds / "wall0.laz"),
                 "-o", str(out), "--quiet"]) == 0
    d = np.asarray(laspy.read(out / "wall1_distance.laz")["distance"])
    assert np.abs(d - 0.02).max() < 1e-3


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_compare_shows_progress_unless_quiet(far_clouds, tmp_path, monkeypatch):
    term = _Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    assert main(["compare", str(far_clouds / "wall1.laz"), str(far_clouds / "wall0.laz"),
                 str(far_clouds / "wall0.laz"), "-o", str(tmp_path / "p")]) == 0
    bar = term.getvalue()
    assert "100.0 %" in bar and "0.0M/0.0M points" in bar and bar.endswith("\n")
    assert bar.count("\r") == 2            # one block per cloud (3,000 points each)
    term = _Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    assert main(["compare", str(far_clouds / "wall1.laz"), str(far_clouds / "wall0.laz"),
                 "-o", str(tmp_path / "q"), "--quiet"]) == 0
    assert term.getvalue() == ""


# ---------------------------------------------------------------------------- scan
SCAN = ["scan", "--sensor", "zf_imager_5016", "--step-deg", "2", "--ideal", "--quiet"]


def test_scan_refuses_a_station_outside_the_mesh(tbm, tmp_path, capsys):
    out = tmp_path / "s.laz"
    assert main([*SCAN, "--mesh", str(tbm), "--at", "50,40,1.5", "-o", str(out)]) == 2
    _fails(capsys, "inside the mesh's bounding box", "(0, -2.5", "got (50, 40, 1.5)",
           "--allow-outside")
    assert not list(tmp_path.iterdir())


def test_scan_outside_allowed_still_needs_points(tbm, tmp_path, capsys):
    # 5 m before the open portal, looking in: points, and no warning (the user said so).
    out = tmp_path / "portal.laz"
    assert main([*SCAN, "--mesh", str(tbm), "--at", "-5,0,2.5", "--allow-outside", "-o",
                 str(out)]) == 0
    assert capsys.readouterr().err == ""
    assert len(laspy.read(out).points) > 100
    # 1 km off: beyond the scanner's 365 m range, nothing returns; no file is left.
    out = tmp_path / "far.laz"
    assert main([*SCAN, "--mesh", str(tbm), "--at", "1000,0,1.5", "--allow-outside", "-o",
                 str(out)]) == 2
    _fails(capsys, "see the mesh", "got 0 points from", "at (1000, 0, 1.5)")
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["portal.laz"]


# ---------------------------------------------------------------------------- angles
@pytest.mark.parametrize("value, deg", [
    (0.5236, 30), (0.524, 30), (-0.7854, -45), (1.5708, 90), (3.1416, 180),
    (3.14159, 180), (4.7124, 270), (6.2832, 360), (1.0472, 60),
    (30.0, None), (0.52, None), (0.0, None), (1.0, None), (0.35, None), (3.14, None),
    (7.0, None), (12.5664, None), (0.1, None),
])
def test_radian_like(value, deg):
    assert radian_like(value) == deg


def test_radian_like_never_fires_on_whole_degrees_and_always_on_typed_radians():
    assert all(radian_like(float(d)) is None for d in range(-720, 721))
    for k in [k for k in range(-24, 25) if k]:
        for decimals in (3, 4, 6):
            assert radian_like(round(k * math.pi / 12, decimals)) == 15 * k


def test_heading_in_radians_warns_once(tbm, tmp_path, capsys):
    assert main([*SCAN, "--mesh", str(tbm), "--at", "50,0,1.5", "--heading-deg", "0.5236",
                 "-o", str(tmp_path / "r.laz")]) == 0
    err = capsys.readouterr().err
    warned = _warnings(err)
    assert len(warned) == 1 and len(err.strip().splitlines()) == 1
    assert "--heading-deg 0.5236 looks like radians (30 deg)" in warned[0]
    assert "--heading-deg 30" in warned[0]
    assert main([*SCAN, "--mesh", str(tbm), "--at", "50,0,1.5", "--heading-deg", "30",
                 "-o", str(tmp_path / "d.laz")]) == 0
    assert capsys.readouterr().err == ""


def _station(path):
    las = laspy.read(path)
    info = json.loads(las.header.vlrs.get_by_id("tunnelsim", [1])[0].record_data)
    return (np.array(info["station_position"]), Rotation.from_quat(
        info["station_quaternion_xyzw"]), np.stack([las.X, las.Y, las.Z], 1))


def test_azimuth_and_heading_give_the_same_station(tbm, tmp_path, capsys):
    """Azimuth 60 (clockwise from north) is heading 30 (counter-clockwise from east):
    the same pose in the file, the same points; azimuth 0 turns the station's x axis
    to grid north (+y)."""
    base = [*SCAN, "--mesh", str(tbm), "--at", "50,0,1.5"]
    assert main([*base, "--azimuth-deg", "60", "-o", str(tmp_path / "a.laz")]) == 0
    assert main([*base, "--heading-deg", "30", "-o", str(tmp_path / "h.laz")]) == 0
    assert main([*base, "--azimuth-deg", "0", "-o", str(tmp_path / "n.laz")]) == 0
    pa, ra, xa = _station(tmp_path / "a.laz")
    ph, rh, xh = _station(tmp_path / "h.laz")
    np.testing.assert_array_equal(pa, ph)
    assert ra.approx_equal(rh, atol=1e-12)
    assert ra.approx_equal(Rotation.from_euler("z", 30, degrees=True), atol=1e-12)
    np.testing.assert_array_equal(xa, xh)
    _, rn, _ = _station(tmp_path / "n.laz")
    np.testing.assert_allclose(rn.apply([1.0, 0, 0]), [0, 1, 0], atol=1e-12)
    # Both at once is a usage error.
    assert main([*base, "--azimuth-deg", "60", "--heading-deg", "30", "-o",
                 str(tmp_path / "x.laz")]) == 2
    _fails(capsys, "--azimuth-deg", "not allowed with", "--heading-deg")
    assert not (tmp_path / "x.laz").exists()


# ---------------------------------------------------------------------------- drive
DRIVE = ["drive", "--sensor", "velodyne_vlp16", "--ideal", "--quiet"]


def test_drive_out_of_reach_is_refused_before_simulating(tbm, tmp_path, capsys,
                                                          monkeypatch):
    """1 km off the tunnel: beyond the VLP-16's 100 m range of the mesh's box, so no
    pulse can return; refused before any simulation."""
    import sensors

    monkeypatch.setattr(sensors, "simulate_drive", _boom)
    traj = _traj_file(tmp_path / "t.txt", (10.0, 1000.0, 1.5))
    out = tmp_path / "d.laz"
    assert main([*DRIVE, "--mesh", str(tbm), "--trajectory", str(traj), "-o",
                 str(out)]) == 2
    _fails(capsys, "within the velodyne_vlp16's 100 m range", "(0, -2.5",
           "(10, 1000, 1.5)", "997.495 m from it", "--allow-outside")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.txt"]


def test_drive_returning_almost_nothing_is_refused(tbm, tmp_path, capsys):
    """100 m off (within range of the box's edge): simulated, but fewer than 1 % of the
    pulses return; refused and nothing left. --allow-outside writes it."""
    traj = _traj_file(tmp_path / "t.txt", (10.0, 100.0, 1.5), n=51)
    out = tmp_path / "d.laz"
    assert main([*DRIVE, "--mesh", str(tbm), "--trajectory", str(traj), "-o",
                 str(out)]) == 2
    _fails(capsys, "to see the mesh", "% returned, below 1 %", "(10, 100, 1.5)",
           "--allow-outside")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.txt"]
    assert main([*DRIVE, "--mesh", str(tbm), "--trajectory", str(traj), "--allow-outside",
                 "-o", str(out)]) == 0
    n = len(laspy.read(out).points)
    assert 0 < n < MIN_DRIVE_RETURN * 0.5 * 300_000     # VLP-16: ~300k pulses/s


def test_drive_inside_returns_most_pulses(tbm, tmp_path, capsys):
    traj = _traj_file(tmp_path / "t.txt", (10.0, 0.0, 1.5), n=51)
    assert main(["drive", "--sensor", "velodyne_vlp16", "--ideal", "--mesh", str(tbm),
                 "--trajectory", str(traj), "-o", str(tmp_path / "d.laz")]) == 0
    summary = capsys.readouterr().out
    ratio = float(summary.split("hit ratio ")[1].split(" %")[0]) / 100
    assert ratio > 0.9 > MIN_DRIVE_RETURN


def test_drive_with_nanosecond_stamps_is_refused(tbm, tmp_path, capsys, monkeypatch):
    import sensors.io.meshes

    monkeypatch.setattr(sensors.io.meshes, "load_mesh", _boom)
    traj = _traj_file(tmp_path / "ns.txt", (10.0, 0.0, 1.5), scale=1e9)
    out = tmp_path / "d.laz"
    assert main([*DRIVE, "--mesh", str(tbm), "--trajectory", str(traj), "-o",
                 str(out)]) == 2
    _fails(capsys, "look like nanoseconds", "divide it by 1e9")
    assert not out.exists()


def test_drive_reads_a_csv_by_its_header(tbm, tmp_path):
    """The issue's header (qw before qx): the drive is the one of the TUM file, point
    for point; reading by position would tilt the sensor and change every point."""
    rot = Rotation.from_euler("xz", [35.0, 20.0], degrees=True)
    tum = _traj_file(tmp_path / "t.txt", (20.0, 0.0, 1.5), n=31, rot=rot)
    rows = np.loadtxt(tum)
    csv = tmp_path / "t.csv"
    with open(csv, "w") as fh:
        fh.write("timestamp,px,py,pz,qw,qx,qy,qz\n")
        np.savetxt(fh, rows[:, [0, 1, 2, 3, 7, 4, 5, 6]], delimiter=",", fmt="%.17g")
    for src, name in ((tum, "a.laz"), (csv, "b.laz")):
        assert main([*DRIVE, "--mesh", str(tbm), "--trajectory", str(src), "-o",
                     str(tmp_path / name)]) == 0
    a, b = laspy.read(tmp_path / "a.laz"), laspy.read(tmp_path / "b.laz")
    assert len(a.points) > 10_000
    for f in ("X", "Y", "Z", "gps_time"):
        np.testing.assert_array_equal(np.asarray(a[f]), np.asarray(b[f]))


def test_duration_past_the_end_is_refused_before_loading_the_mesh(tbm, tmp_path, capsys,
                                                                 monkeypatch):
    import sensors.io.meshes

    monkeypatch.setattr(sensors.io.meshes, "load_mesh", _boom)
    traj = _traj_file(tmp_path / "t.txt", (10.0, 0.0, 1.5))          # 2 s
    out = tmp_path / "d.laz"
    for dur, words in (("15", ("at most the trajectory's 2 s", "got 15 s")),
                       ("0", ("positive --duration",)), ("-1", ("positive --duration",))):
        assert main([*DRIVE, "--mesh", str(tbm), "--trajectory", str(traj), "--duration",
                     dur, "-o", str(out)]) == 2
        _fails(capsys, *words)
    # The centreline too: 98 m at 15 m/s is 6.53 s.
    assert main([*DRIVE, "--mesh", str(tbm), "--along", "centreline", "--speed", "15",
                 "--duration", "50", "--slam-drift", "-o", str(out)]) == 2
    _fails(capsys, "at most the trajectory's 6.53333 s", "got 50 s")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.txt"]


def test_duration_trims_every_output(tbm, tmp_path):
    """--duration 1.5 at 30 m/s from chainage 1: the cloud, the true and SLAM
    trajectories and the control points all end at t = 1.5 s (x = 46 m); the world
    control points are the tunnel's prisms up to there (10 and 30 m), not all ten."""
    out = tmp_path / "d.laz"
    assert main([*DRIVE, "--mesh", str(tbm), "--along", "centreline", "--speed", "30",
                 "--duration", "1.5", "--slam-drift", "-o", str(out)]) == 0
    assert np.asarray(laspy.read(out).gps_time).max() <= 1.5
    true = Trajectory.read(tmp_path / "d_true_trajectory.txt")
    slam = Trajectory.read(tmp_path / "d_trajectory.txt")
    assert true.start_s == slam.start_s == 0.0 and true.end_s == slam.end_s == 1.5
    np.testing.assert_allclose(true.positions[-1], [46.0, 0.0, 0.5], atol=1e-9)
    meta = json.loads(tbm.with_suffix(".json").read_text())
    want = {c["id"] for c in meta["control_points"] if c["xyz"][0] <= 46.0}
    assert len(want) == 4 and len(meta["control_points"]) == 10

    def ids(name):
        return {ln.split(",")[0] for ln in (tmp_path / name).read_text().splitlines()[1:]}

    assert ids("d_cp_world.csv") == want
    assert ids("d_cp_observed.csv") <= want
    times = np.loadtxt(tmp_path / "d_cp_observed.csv", delimiter=",", skiprows=1,
                       usecols=4, ndmin=1)
    assert len(times) and times.max() <= 1.5
    # Without --slam-drift, the true trajectory alone is trimmed alike.
    assert main([*DRIVE, "--mesh", str(tbm), "--along", "centreline", "--speed", "30",
                 "--duration", "0.2", "-o", str(tmp_path / "p.laz")]) == 0
    plain = Trajectory.read(tmp_path / "p_true_trajectory.txt")
    assert plain.end_s == 0.2
    np.testing.assert_allclose(plain.positions[-1], [7.0, 0.0, 0.5], atol=1e-9)


def test_correct_refuses_control_times_outside_the_trajectory(tmp_path, capsys):
    """A trajectory stamped in epoch seconds against control points timed from 0:
    refused in one line naming both time bases, and nothing written (it used to fit
    on the control points and apply the correction 1.7e9 s away, exit 0)."""
    from sensors import Trajectory
    from sensors.io.cloudmap import write_points_las

    t = np.linspace(0.0, 10.0, 11)
    traj = Trajectory(t + 1.7e9, np.stack([t, 0 * t, 0 * t], 1), np.tile([0, 0, 0, 1.0], (11, 1)))
    traj.write(tmp_path / "traj.txt")
    write_points_las(tmp_path / "c.laz", np.stack([t, 0 * t, 0 * t + 1], 1))
    (tmp_path / "w.csv").write_text("id,x,y,z\nA,1,1,1\nB,5,1,1\nC,9,1,1\n")
    (tmp_path / "o.csv").write_text("id,x,y,z,time\nA,1,1,1,1\nB,5,1,1,5\nC,9,1,1,9\n")
    before = set(tmp_path.iterdir())
    assert main(["correct", "--trajectory", str(tmp_path / "traj.txt"), "--cloud",
                 str(tmp_path / "c.laz"), "--control", str(tmp_path / "w.csv"),
                 "--observed", str(tmp_path / "o.csv"), "-o", str(tmp_path / "x.laz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "within the trajectory" in err[0] and "epoch" in err[0]
    assert set(tmp_path.iterdir()) == before
