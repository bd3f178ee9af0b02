"""Issue 29, routes on meshes users bring: ``tunnelsim drive --along auto`` (and
``tunnelsim gazebo``) on small meshes of each defect class (``tests.sensors.
route_meshes``): a rough 90 degree bend, a rough floor with 10-20 cm steps, a passage
narrowing to just above the robot's width, a steep ramp, a branching mine with dead
ends, an artist's tile with unmerged seams.

Each drive either succeeds or refuses naming a command-line option, and the test runs
that option to show it fixes the drive. What a drive writes is checked on the files the
user gets: the true trajectory (``_true_trajectory.txt``) differentiated by plain
finite differences (speed, acceleration, jerk, yaw rate of the base), its roll and
pitch from the poses' rotations against the platform's traversability, the sensor's
clearance from the mesh by brute force over every triangle (``tests.naive``), and the
room either side of the base against the walls' formulas.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sensors import Trajectory
from sensors.platform_spec import load_platform
from sensors.route import MIN_SENSOR_CLEARANCE_M
from survey.cli.main import main
from tests.naive import naive_cast, naive_point_mesh
from tests.sensors import route_meshes as rm
from tests.sensors.test_route import plan_mesh
from tests.survey.cli.test_drive_platform import SENSOR

ROBOT = load_platform("ground_robot")
WALKER = load_platform("walker")


def _write_mesh(path, v, f):
    import trimesh

    trimesh.Trimesh(v, f, process=False).export(path)
    return str(path)


@pytest.fixture()
def sensor(tmp_path):
    p = tmp_path / "two_beams.toml"
    p.write_text(SENSOR)
    return str(p)


def _drive(tmp_path, mesh, sensor, *extra, code=0, name="d"):
    """Run the CLI; return (exit code, the true trajectory or None, stderr lines)."""
    out = tmp_path / f"{name}.npz"
    got = main(["drive", "--mesh", mesh, "--sensor", sensor, "--quiet", "-o", str(out),
                "--along", "auto", "--speed", "1", *extra])
    assert got == code
    f = tmp_path / f"{name}_true_trajectory.txt"
    return Trajectory.read(f) if got == 0 else None


def _base(traj, spec):
    """The base on the floor: the mast top less the mast along the base's z (wheeled);
    the walker's sensor is level, its base straight below."""
    zb = traj.rotations.as_matrix()[:, :, 2]
    return traj.positions - spec.mast_height_m * zb


def _check_motion(traj, spec, points):
    """Speed, acceleration and jerk of the base's horizontal motion (``points`` (k, 3)),
    and its yaw rate, by plain finite differences of the file's samples, within the
    platform's limits (0.1 % for the file's rounding); from rest to rest."""
    lim = spec.limits
    t = traj.times
    tol = 1.001
    dt = np.diff(t)
    v = np.diff(points[:, :2], axis=0) / dt[:, None]
    a = np.diff(v, axis=0) / (0.5 * (dt[1:] + dt[:-1]))[:, None]
    j = np.diff(a, axis=0) / dt[1:-1, None]
    n = np.linalg.norm
    assert n(v, axis=1).max() <= lim.max_speed_mps * tol
    assert n(a, axis=1).max() <= lim.max_accel_mps2 * tol
    assert n(j, axis=1).max() <= lim.max_jerk_mps3 * tol
    m = traj.rotations.as_matrix()
    yaw = np.unwrap(np.arctan2(m[:, 1, 0], m[:, 0, 0]))
    assert np.abs(np.diff(yaw) / dt).max() <= lim.max_yaw_rate_radps * tol
    assert n(v[[0, -1]], axis=1).max() < 1e-3


def _roll_pitch_deg(traj):
    """Roll and pitch (deg) of each pose from its rotation matrix: pitch the angle of
    the x axis above the horizontal, roll that of the y axis."""
    m = traj.rotations.as_matrix()
    pitch = np.degrees(np.arcsin(np.clip(m[:, 2, 0], -1, 1)))
    roll = np.degrees(np.arcsin(np.clip(m[:, 2, 1], -1, 1)))
    return roll, pitch


def _check_attitude(traj, spec, tol_deg=0.5):
    roll, pitch = _roll_pitch_deg(traj)
    tv = spec.traversability
    assert np.abs(pitch).max() <= math.degrees(tv.max_slope_rad) + tol_deg
    assert np.abs(roll).max() <= math.degrees(tv.max_roll_rad) + tol_deg
    return roll, pitch


def _clearance(traj, v, f, every=10):
    """Smallest distance of the sensor from the mesh, brute force over every triangle."""
    return float(naive_point_mesh(traj.positions[::every], v, f)[0].min())


def test_rough_bend_drives_within_the_limits(tmp_path, sensor):
    """The rough 90 degree tile that failed with 'a jerk of 14.33 above 1 after 8
    plans': the drive succeeds and the file keeps every limit and the clearance."""
    v, f = rm.rough_bend(seed=3, wall_sigma_m=0.15, floor_sigma_m=0.015)
    mesh = _write_mesh(tmp_path / "bend.ply", v, f)
    traj = _drive(tmp_path, mesh, sensor)
    _check_motion(traj, ROBOT, _base(traj, ROBOT))
    _check_attitude(traj, ROBOT)
    assert _clearance(traj, v, f) >= 0.2 - 0.01
    yaw = np.unwrap(np.arctan2(*traj.rotations.as_matrix()[:, 1::-1, 0].T))
    assert np.ptp(yaw) == pytest.approx(np.pi / 2, abs=0.35)          # round the bend


def test_steps_are_driven_round(tmp_path, sensor):
    """Blocks 10-20 cm high on the left 65 % of the floor: the ground robot (steps up
    to 8 cm) keeps to the level strip on the right; no wheel ever leaves the floor
    (z = 0), checked by rays cast down at its four wheels from every pose."""
    v, f = rm.rough_floor_steps(seed=1)
    mesh = _write_mesh(tmp_path / "steps.ply", v, f)
    traj = _drive(tmp_path, mesh, sensor)
    base = _base(traj, ROBOT)
    _check_motion(traj, ROBOT, base)
    _check_attitude(traj, ROBOT)
    assert base[:, 0].min() < 1.0 and base[:, 0].max() > 11.0         # end to end
    inner = (base[:, 0] > 0.5) & (base[:, 0] < 11.5)         # wheels over the floor
    m = traj.rotations.as_matrix()[inner][::20]
    a, b = 0.5 * ROBOT.wheelbase_m, 0.5 * ROBOT.track_m
    wheels = np.vstack([base[inner][::20] + i * a * m[:, :, 0] + j * b * m[:, :, 1]
                        for i in (1, -1) for j in (1, -1)])
    t = naive_cast(v, f, wheels + [0, 0, 0.4], np.tile([0.0, 0, -1], (len(wheels), 1)))[0]
    assert np.abs(0.4 - t).max() <= 0.01                               # all on z = 0
    assert _clearance(traj, v, f) >= 0.2 - 0.01


def test_a_step_across_the_passage_needs_a_platform_that_climbs_it(tmp_path, sensor,
                                                                   capsys):
    """A 20 cm step across the whole floor: the ground robot drives the larger part
    with a warning naming --platform; --platform walker (steps up to 0.4 m) drives it
    end to end, up the step and down again."""
    v, f = rm.rough_floor_steps(full_width=True)
    mesh = _write_mesh(tmp_path / "step.ply", v, f)
    short = _drive(tmp_path, mesh, sensor, name="robot")
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "warning" in err and "--platform" in err
    assert np.ptp(_base(short, ROBOT)[:, 0]) < 6.0
    walk = _drive(tmp_path, mesh, sensor, "--platform", "walker", name="walker")
    p = walk.positions
    assert p[:, 0].min() < 1.0 and p[:, 0].max() > 11.0
    on_step = (p[:, 0] > 5.5) & (p[:, 0] < 6.5)
    np.testing.assert_allclose(p[on_step, 2], 0.2 + WALKER.mast_height_m, atol=0.05)
    # (the walker's sensor sways with the gait: its limits are the walk's, checked in
    # test_drive_platform; here its speed, which the sway changes by under 0.1 m/s)
    speed = np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1) / np.diff(walk.times)
    assert speed.max() <= 1.0 + 0.1
    assert _clearance(walk, v, f) >= 0.2 - 0.01


def test_a_narrow_passage_the_robot_fits_is_driven_with_a_warning(tmp_path, sensor,
                                                                  capsys):
    """A 3 m passage narrowing to 0.32 m (the robot is 0.22 m wide): the drive goes
    through with a one-line warning naming the place and --clearance; the base keeps
    its half width from the walls (their formula) at every pose and the sensor its
    least clearance (brute force). --clearance 0.15 asks no more than the passage
    gives: no warning, the same route."""
    v, f = rm.narrowing(0.32)
    mesh = _write_mesh(tmp_path / "narrow.ply", v, f)
    traj = _drive(tmp_path, mesh, sensor, "--quiet")
    err = capsys.readouterr().err
    assert "narrow at (6" in err and "--clearance" in err
    base = _base(traj, ROBOT)
    assert base[:, 0].min() < 1.0 and base[:, 0].max() > 11.0
    _check_motion(traj, ROBOT, base)
    hw = 0.16 + np.clip((np.abs(base[:, 0] - 6.0) - 0.5) / 2.0, 0, 1) * (1.5 - 0.16)
    m = traj.rotations.as_matrix()
    half = 0.5 * ROBOT.traversability.footprint_width_m
    for k in (-1, 1):                         # the footprint's corners, left and right
        for i in (-1, 1):
            c = base + i * 0.5 * ROBOT.traversability.footprint_length_m * m[:, :, 0] \
                + k * half * m[:, :, 1]
            w = 0.16 + np.clip((np.abs(c[:, 0] - 6.0) - 0.5) / 2.0, 0, 1) * (1.5 - 0.16)
            assert (np.abs(c[:, 1]) <= w + 1e-3).all()
    assert (np.abs(base[:, 1]) + half <= hw + 0.03).all()
    assert _clearance(traj, v, f, every=5) >= MIN_SENSOR_CLEARANCE_M
    again = _drive(tmp_path, mesh, sensor, "--clearance", "0.15", name="c15")
    assert "narrow" not in capsys.readouterr().err
    assert _clearance(again, v, f, every=5) >= 0.15 - 0.01


def test_too_narrow_for_the_walker_is_refused_naming_the_place(tmp_path, sensor,
                                                               capsys):
    """The same 0.32 m pinch is too narrow for the walker's 0.5 m shoulders: refused
    in one line naming the place and --platform; --platform ground_robot fixes it."""
    v, f = rm.narrowing(0.32)
    mesh = _write_mesh(tmp_path / "narrow.ply", v, f)
    _drive(tmp_path, mesh, sensor, "--platform", "walker", code=2)
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "room for 0.32 m of its 0.5 m width" in err and "--platform" in err
    x = float(err.split(" at (")[1].split(",")[0])
    assert 4.5 <= x <= 7.5                                   # where it narrows
    assert not list(tmp_path.glob("d*"))
    _drive(tmp_path, mesh, sensor, "--platform", "ground_robot")


def test_a_steep_ramp_is_refused_for_the_robot_and_walked(tmp_path, sensor, capsys):
    """A 30 degree ramp is over the ground robot's 25: refused in one line naming the
    slope, the place and --platform; --platform walker (35) walks it. A 15 degree ramp
    is driven, pitched with the floor (its pitch from the poses 15 deg, within 25)."""
    v, f = rm.ramp(30)
    mesh = _write_mesh(tmp_path / "ramp30.ply", v, f)
    _drive(tmp_path, mesh, sensor, code=2)
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "a slope of 30 deg" in err and "--platform" in err
    x = float(err.split(" at (")[1].split(",")[0])
    assert 4.0 <= x <= 10.0
    walk = _drive(tmp_path, mesh, sensor, "--platform", "walker", name="w")
    p = walk.positions
    floor = np.tan(np.radians(30)) * np.clip(p[:, 0] - 4.0, 0.0, 6.0)
    # away from the kinks (the walker's floor is smoothed over 0.3 s), the gait's bob
    away = (np.abs(p[:, 0] - 4.0) > 0.6) & (np.abs(p[:, 0] - 10.0) > 0.6)
    assert np.abs(p[away, 2] - WALKER.mast_height_m - floor[away]).max() <= \
        0.5 * WALKER.gait.bob_m + 0.01
    assert np.ptp(p[:, 0]) > 11.0
    v, f = rm.ramp(15)
    mesh = _write_mesh(tmp_path / "ramp15.ply", v, f)
    traj = _drive(tmp_path, mesh, sensor, name="r15")
    _, pitch = _check_attitude(traj, ROBOT)
    base = _base(traj, ROBOT)
    on = (base[:, 0] > 5.0) & (base[:, 0] < 9.0)
    np.testing.assert_allclose(np.abs(pitch[on]), 15.0, atol=0.5)     # up or down
    _check_motion(traj, ROBOT, base)


def _farthest_cells(plan, cell_m=0.5):
    """The two free cells of a plan farthest apart by walking (8-neighbour moves,
    diagonals only between free cells), brute force: Floyd-Warshall on the cells."""
    cells = np.argwhere(plan)
    n = len(cells)
    d = np.full((n, n), np.inf)
    np.fill_diagonal(d, 0.0)
    index = {tuple(c): i for i, c in enumerate(cells)}
    for i, (x, y) in enumerate(cells):
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                j = index.get((x + dx, y + dy))
                if j is None or (dx, dy) == (0, 0):
                    continue
                if dx and dy and not (plan[x + dx, y] and plan[x, y + dy]):
                    continue
                d[i, j] = math.hypot(dx, dy)
    for k in range(n):
        d = np.minimum(d, d[:, k:k + 1] + d[k:k + 1, :])
    i, j = np.unravel_index(np.argmax(d), d.shape)
    return (cells[[i, j]] + 0.5) * cell_m


def test_branching_mine_routes_between_its_farthest_ends(tmp_path, sensor):
    """A mine drive with two dead ends and a stub: the route joins the two ends
    farthest apart by walking (a brute-force search over the plan's cells: here the
    +y dead end and the far portal), within the ends' half width; with --waypoints
    at the two portals it keeps to the main drive and enters no side drive."""
    plan = rm.branching_mine()
    v, f = plan_mesh(plan, portals=("x-", "x+"))
    mesh = _write_mesh(tmp_path / "mine.ply", v, f)
    traj = _drive(tmp_path, mesh, sensor)
    base = _base(traj, ROBOT)
    _check_motion(traj, ROBOT, base)
    assert _clearance(traj, v, f) >= 0.2 - 0.01
    ends = _farthest_cells(plan)
    got = base[[0, -1], :2]
    gap = min(np.linalg.norm(got - ends, axis=1).max(),
              np.linalg.norm(got - ends[::-1], axis=1).max())
    assert gap <= 1.0
    (tmp_path / "wp.csv").write_text("x,y\n0.3,3.75\n11.7,3.75\n")
    traj = _drive(tmp_path, mesh, sensor, "--waypoints", str(tmp_path / "wp.csv"),
                  name="wp")
    base = _base(traj, ROBOT)
    assert base[:, 0].min() < 1.0 and base[:, 0].max() > 11.0
    assert (base[:, 1] > 3.0).all() and (base[:, 1] < 4.5).all()      # main drive y 3-4.5
    _check_motion(traj, ROBOT, base)


def test_unmerged_tiles_drive_as_the_merged_mesh(tmp_path, sensor):
    """The rough bend cut into three tiles with their own vertices, 2 mm slits at the
    seams and shuffled faces: the drive succeeds, within the limits, and its path lies
    within 5 cm of the merged mesh's."""
    v, f = rm.rough_bend(seed=1)
    merged = _drive(tmp_path, _write_mesh(tmp_path / "m.ply", v, f), sensor, name="m")
    tv, tf = rm.unmerged_tiles(v, f)
    tiles = _drive(tmp_path, _write_mesh(tmp_path / "t.ply", tv, tf), sensor, name="t")
    _check_motion(tiles, ROBOT, _base(tiles, ROBOT))
    from scipy.spatial import cKDTree

    gap = cKDTree(merged.positions[:, :2]).query(tiles.positions[:, :2])[0]
    assert gap.max() <= 0.05
    assert _clearance(tiles, tv, tf) >= 0.2 - 0.01


@pytest.mark.parametrize("extra, match", [
    (["--clearance", "0.3"], "--clearance with --along auto"),
    (["--voxel", "0"], "positive --voxel"),
])
def test_route_options_bad_input(extra, match, tmp_path, sensor, capsys):
    v, f = rm.ramp(5)
    mesh = _write_mesh(tmp_path / "r.ply", v, f)
    args = ["drive", "--mesh", mesh, "--sensor", sensor, "-o", str(tmp_path / "x.npz"),
            "--speed", "1", *extra]
    if "--voxel" in extra:
        args += ["--along", "auto"]
    else:
        Trajectory.along_polyline([[1.0, 0, 0.5], [7.0, 0, 0.5]], 1.0).write(
            tmp_path / "t.txt")
        args += ["--trajectory", str(tmp_path / "t.txt")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err, err


def test_voxel_option_sets_the_grid(tmp_path, sensor, capsys):
    """--voxel is the route's grid: the drive reports it, and a coarser one gives
    another route file."""
    v, f = rm.rough_bend(seed=2)
    mesh = _write_mesh(tmp_path / "b.ply", v, f)
    out = {}
    for vox in ("0.05", "0.12"):
        assert main(["drive", "--mesh", mesh, "--sensor", sensor, "-o",
                     str(tmp_path / f"v{vox}.npz"), "--along", "auto", "--speed", "1",
                     "--voxel", vox]) == 0
        assert f"voxel {float(vox):.2f} m" in capsys.readouterr().out
        out[vox] = np.loadtxt(tmp_path / f"v{vox}_route.csv", delimiter=",", skiprows=1)
    assert out["0.05"].shape != out["0.12"].shape or \
        np.abs(out["0.05"] - out["0.12"]).max() > 1e-3


def test_gazebo_route_keeps_to_what_the_robot_crosses(tmp_path, capsys):
    """gazebo plans the ground robot's route on a mesh without its JSON: on the steps
    mesh the robot starts on the level floor; on the 30 degree ramp it is refused
    naming --waypoints (gazebo has no --platform); --clearance is refused for a
    generated tunnel's axis."""
    v, f = rm.ramp(30)
    mesh = _write_mesh(tmp_path / "ramp.ply", v, f)
    assert main(["gazebo", "--mesh", mesh, "-o", str(tmp_path / "w1"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "a slope of 30 deg" in err and "--waypoints" in err and "--platform" not in err
    v, f = rm.rough_floor_steps(seed=1)
    mesh = _write_mesh(tmp_path / "steps.ply", v, f)
    (tmp_path / "wp.csv").write_text("x,y\n0.5,-1.0\n11.5,-1.0\n")
    assert main(["gazebo", "--mesh", mesh, "-o", str(tmp_path / "w2"),
                 "--waypoints", str(tmp_path / "wp.csv"), "--clearance", "0.25"]) == 0
    line = [x for x in capsys.readouterr().out.splitlines() if x.startswith("robot at")][0]
    x, y, z = (float(t) for t in line.split(": ")[1].split()[:3])
    import xml.etree.ElementTree as ET
    frame = ET.parse(tmp_path / "w2" / "world.sdf").getroot().find(
        "world/frame[@name='map_origin']/pose").text.split()
    origin = -np.array(frame[:3], dtype=float)          # world = local + origin
    assert (x + origin[0], y + origin[1], z + origin[2]) == pytest.approx(
        (0.5, -1.0, 0.0), abs=0.06)
    tun = str(tmp_path / "bfo.ply")
    assert main(["tunnel", "-o", tun, "--preset", "bfo", "--edge-length", "1.0",
                 "--relief", "none", "--quiet"]) == 0
    assert main(["gazebo", "--mesh", tun, "-o", str(tmp_path / "w3"), "--quiet",
                 "--clearance", "0.3"]) == 2
    assert "--clearance" in capsys.readouterr().err
