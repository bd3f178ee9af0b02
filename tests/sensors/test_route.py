"""Routes found in a mesh (``sensors.route``): on generated passages whose middle is known
- a straight horseshoe tube, a bent one, a 90 degree turn, a T junction, a change of
grade - the route keeps its clearance (exact brute-force distance, ``tests.naive``),
rides at the sensor height above the floor under it (brute-force ray cast), covers the
passage end to end, lies on the known centreline, follows waypoints in order, is
deterministic and moves with the mesh under a rigid motion; bad input is refused.

The tunnel generator (``survey.world``) sweeps one profile along one alignment: it makes
no junctions, and sensors' tests must not depend on survey. The turn and the junction
are therefore extruded here from a floor plan (``plan_mesh``: a rectangular section,
unmerged quads as artist-made meshes have), and the bend is a swept horseshoe tube
wrapped onto an arc (``bent_tube``).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from raytrace.shapes import horseshoe_profile, icosphere, sweep_profile, tunnel_tube
from sensors import TrajectoryError, find_route, free_space, read_waypoints
from tests.naive import naive_cast, naive_point_mesh

VOXEL = 0.1
HEIGHT = 0.5
CLEAR = 0.2


def plan_mesh(plan, cell_m=0.5, height_m=2.5, portals=()):
    """A passage of rectangular section from a floor plan (nx, ny) bool of free cells:
    floor at z = 0, roof at ``height_m``, walls between free cells and solid ones or the
    plan's border, except on the border sides named in ``portals`` ("x-", "x+", "y-",
    "y+"), which are left open (portals)."""
    plan = np.asarray(plan, dtype=bool)
    c, h = cell_m, height_m
    quads = []
    for i, j in np.argwhere(plan):
        x0, x1, y0, y1 = i * c, (i + 1) * c, j * c, (j + 1) * c
        quads += [[[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]],
                  [[x0, y0, h], [x0, y1, h], [x1, y1, h], [x1, y0, h]]]
        for di, dj, side in ((1, 0, "x+"), (-1, 0, "x-"), (0, 1, "y+"), (0, -1, "y-")):
            a, b = i + di, j + dj
            inside = 0 <= a < plan.shape[0] and 0 <= b < plan.shape[1]
            if (inside and plan[a, b]) or (not inside and side in portals):
                continue
            if di:
                x = x1 if di > 0 else x0
                quads.append([[x, y0, 0], [x, y1, 0], [x, y1, h], [x, y0, h]])
            else:
                y = y1 if dj > 0 else y0
                quads.append([[x0, y, 0], [x1, y, 0], [x1, y, h], [x0, y, h]])
    q = np.array(quads, dtype=np.float64)
    k = np.arange(len(q))[:, None] * 4
    return q.reshape(-1, 3), np.concatenate([k + [0, 1, 2], k + [0, 2, 3]]).astype(np.int64)


def bent_tube(length_m=16.0, radius_m=10.0):
    """A 3 m horseshoe tube along an arc of ``radius_m`` turning left from (0, 0) along
    +x; its centreline is the arc (the floor's middle)."""
    v, f = sweep_profile(horseshoe_profile(3.0, 1.2, 40), length_m, int(length_m * 4) + 1)
    x, y, z = v.T
    th = x / radius_m
    return np.column_stack([(radius_m - y) * np.sin(th),
                            radius_m - (radius_m - y) * np.cos(th), z]), f


def _tube(length_m=10.0):
    return tunnel_tube(1600, length_m=length_m, roughness_m=0.0)


def _check_route(route, v, f, *, height_m=HEIGHT, clear_m=CLEAR):
    """Clearance by brute force (and the route's own figures agree), height above the
    floor under each point by a brute-force ray cast, even spacing."""
    d, _ = naive_point_mesh(route.points, v, f)
    assert d.min() >= clear_m
    np.testing.assert_allclose(route.clearance_m, d, atol=1e-9)
    t = naive_cast(v, f, route.points, np.tile([0.0, 0, -1], (len(route.points), 1)))[0]
    np.testing.assert_allclose(t, height_m, atol=0.02)
    step = np.linalg.norm(np.diff(route.points[:, :2], axis=0), axis=1)
    assert step.max() < 0.3 and step.min() > 0.1


@pytest.fixture(scope="module")
def tube_route():
    v, f = _tube()
    return v, f, find_route((v, f), voxel_m=VOXEL)


def test_straight_tube_end_to_end_on_the_centreline(tube_route):
    v, f, route = tube_route
    _check_route(route, v, f)
    x = np.sort(route.points[[0, -1], 0])
    assert x[0] <= 3 * VOXEL and x[1] >= 10.0 - 3 * VOXEL          # portal to portal
    assert np.abs(route.points[:, 1]).max() <= 0.1                  # the middle
    assert route.length_m == pytest.approx(10.0, abs=0.3)
    assert route.min_clearance_m == pytest.approx(route.clearance_m.min())


def test_bend_follows_the_arc():
    v, f = bent_tube()
    route = find_route((v, f), voxel_m=VOXEL)
    _check_route(route, v, f)
    lateral = np.hypot(route.points[:, 0], route.points[:, 1] - 10.0) - 10.0
    assert np.abs(lateral).max() <= 0.1
    ang = np.sort(np.arctan2(route.points[[0, -1], 0], 10.0 - route.points[[0, -1], 1]))
    assert ang[0] <= 3 * VOXEL / 10 and ang[1] >= 1.6 - 3 * VOXEL / 10


def test_ninety_degree_turn():
    plan = np.zeros((24, 24), bool)
    plan[:, :6] = True                 # 12 m along x, 3 m wide, open at x = 12
    plan[:6, :] = True                 # 12 m along y, open at y = 12
    v, f = plan_mesh(plan, portals=("x+", "y+"))
    route = find_route((v, f), voxel_m=VOXEL)
    _check_route(route, v, f)
    p = route.points
    e = p[[0, -1], :2]
    at_x, at_y = e[:, 0] >= 12.0 - 3 * VOXEL, e[:, 1] >= 12.0 - 3 * VOXEL   # the portals
    assert at_x.sum() == 1 and at_y.sum() == 1 and not (at_x & at_y).any()
    arm_x, arm_y = p[:, 0] > 5.0, p[:, 1] > 5.0                     # 2 m past the corner
    assert np.abs(p[arm_x, 1] - 1.5).max() <= 0.1 and np.abs(p[arm_y, 0] - 1.5).max() <= 0.1
    assert arm_x.any() and arm_y.any()


def _t_junction():
    plan = np.zeros((40, 24), bool)
    plan[:, 9:15] = True               # cross-bar: 20 m along x, y in [4.5, 7.5]
    plan[17:23, 15:] = True            # stem: x in [8.5, 11.5], up to y = 12
    return plan_mesh(plan, portals=("x-", "x+", "y+"))


def test_t_junction_takes_the_longest_branch():
    v, f = _t_junction()
    route = find_route((v, f), voxel_m=VOXEL)
    _check_route(route, v, f)
    assert sorted(np.round(route.points[[0, -1], 0])) == [0.0, 20.0]
    far = np.abs(route.points[:, 0] - 10.0) > 2.0                     # 2 m off the junction
    assert np.abs(route.points[far, 1] - 6.0).max() <= 0.1


def test_waypoints_are_visited_in_order():
    v, f = _t_junction()
    wp = np.array([[10.0, 11.5], [1.0, 6.0], [19.0, 6.0]])         # stem, west, east
    route = find_route((v, f), voxel_m=VOXEL, waypoints=wp)
    _check_route(route, v, f)
    np.testing.assert_allclose(route.waypoints[:, :2], wp, atol=1e-9)
    hits = [int(np.argmin(np.linalg.norm(route.points[:, :2] - w, axis=1))) for w in wp]
    assert hits[0] == 0 and hits[0] < hits[1] < hits[2] == len(route.points) - 1
    # west then east: the route crosses the junction twice
    assert route.length_m > (11.5 - 6.0) + 9.0 + 18.0 - 1.0


def test_waypoints_with_heights():
    v, f = _tube()
    route = find_route((v, f), voxel_m=VOXEL, waypoints=[[1.0, 0.3, 0.0], [9.0, -0.3, 2.0]])
    _check_route(route, v, f)
    np.testing.assert_allclose(route.waypoints[:, :2], [[1.0, 0.3], [9.0, -0.3]], atol=1e-9)


def test_change_of_grade():
    v, f = tunnel_tube(2400, length_m=12.0, roughness_m=0.0)
    v = v.copy()
    v[:, 2] += 0.10 * np.maximum(v[:, 0] - 4.0, 0.0)                   # level, then 10 %
    route = find_route((v, f), voxel_m=VOXEL)
    _check_route(route, v, f)
    assert np.ptp(route.points[:, 2]) == pytest.approx(0.8, abs=0.05)


def test_deterministic(tube_route):
    v, f, route = tube_route
    again = find_route((v, f), voxel_m=VOXEL)
    np.testing.assert_array_equal(again.points, route.points)
    np.testing.assert_array_equal(again.clearance_m, route.clearance_m)


def _polyline_gap(a, b):
    """Largest distance from a point of a to the polyline b (dense sampling of b)."""
    t = np.linspace(0, 1, 21)[:, None, None]
    dense = (b[:-1] + t * (b[1:] - b[:-1])).reshape(-1, 3)
    return max(np.min(np.linalg.norm(dense - p, axis=1)) for p in a)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(angle=st.floats(0, 2 * np.pi), shift=st.tuples(*[st.floats(-1e4, 1e4)] * 3))
def test_route_moves_with_the_mesh(tube_route, angle, shift):
    """A rigid motion of the mesh (a turn about z and a shift, up to UTM-like offsets)
    moves the route with it: to within a voxel along the passage and 1.5 voxels at its
    ends (the grid stays axis-aligned, so an end voxel straddles an oblique portal)."""
    v, f, route = tube_route
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    moved = find_route((v @ rot.T + shift, f), voxel_m=VOXEL)
    back = (moved.points - shift) @ rot
    ref = route.points
    for a, b in ((back, ref), (ref, back)):
        inner = np.minimum(a[:, 0], 10.0 - a[:, 0]) > 0.5
        assert _polyline_gap(a[inner], b) <= VOXEL
    ends = np.linalg.norm(np.sort(back[[0, -1]], axis=0) - np.sort(ref[[0, -1]], axis=0),
                          axis=1)
    assert ends.max() <= 1.5 * VOXEL
    assert moved.length_m == pytest.approx(route.length_m, abs=2 * VOXEL)
    assert moved.min_clearance_m >= CLEAR


def test_trajectory_keeps_the_clearance(tube_route):
    v, f, route = tube_route
    traj = route.trajectory(1.0, accel_mps2=0.5, rate_hz=20)
    p = traj.positions
    assert np.linalg.norm(p[1] - p[0]) < 0.01 and np.linalg.norm(p[-1] - p[-2]) < 0.01
    assert naive_point_mesh(p[::5], v, f)[0].min() >= CLEAR


def test_free_space_from_a_start_point():
    v, f = _tube()
    space = free_space((v, f), voxel_m=VOXEL, start=[5.0, 0.0, 1.0])
    assert space.free[tuple(space.index([[5.0, 0.0, 1.0]])[0])]
    d = space.distance([[5.0, 0.0, 1.0]])
    assert d[0] == pytest.approx(naive_point_mesh([[5.0, 0.0, 1.0]], v, f)[0][0], abs=1e-12)


def test_route_csv_reads_back_as_waypoints(tube_route, tmp_path):
    _, _, route = tube_route
    path = route.write_csv(tmp_path / "r.csv")
    np.testing.assert_allclose(read_waypoints(path), route.points, atol=1e-6)
    (tmp_path / "w.csv").write_text("# west to east\n1,0\n9,0.5,1.2\n")
    with pytest.raises(TrajectoryError, match="unreadable rows"):
        read_waypoints(tmp_path / "w.csv")
    (tmp_path / "w.csv").write_text("1,0\n9,0.5\n")
    np.testing.assert_array_equal(read_waypoints(tmp_path / "w.csv")[:, :2],
                                  [[1, 0], [9, 0.5]])
    assert np.isnan(read_waypoints(tmp_path / "w.csv")[:, 2]).all()
    (tmp_path / "w.csv").write_text("east,north\n1,0\n9,0.5\n")
    with pytest.raises(TrajectoryError, match="header naming x, y"):
        read_waypoints(tmp_path / "w.csv")
    (tmp_path / "w.csv").write_text("x,y\n1,0\n")
    with pytest.raises(TrajectoryError, match="at least 2 waypoints"):
        read_waypoints(tmp_path / "w.csv")
    with pytest.raises(TrajectoryError, match="does not exist"):
        read_waypoints(tmp_path / "none.csv")


def _pinched():
    plan = np.zeros((40, 6), bool)
    plan[:, :] = True
    plan[18:22, :] = False
    plan[18:22, 2] = True              # 2 m of a 0.5 m slot between two 3 m wide halves
    return plan_mesh(plan, portals=("x-", "x+"))


def test_bad_input():
    plane = (np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0.0]]),
             np.array([[0, 1, 2], [1, 3, 2]]))
    with pytest.raises(TrajectoryError, match="encloses free space"):
        find_route(plane, voxel_m=VOXEL)
    v, f = icosphere(3, 5.0)
    bowl = f[(v[f][:, :, 2] <= 1e-9).all(axis=1)]                  # the lower half
    with pytest.raises(TrajectoryError, match="encloses free space"):
        find_route((v, bowl), voxel_m=VOXEL)
    v, f = _tube()
    with pytest.raises(TrajectoryError, match="`start` inside"):
        find_route((v, f), voxel_m=VOXEL, start=[5.0, 0.0, 10.0])
    with pytest.raises(TrajectoryError, match="waypoint 2 .* inside the passage"):
        find_route((v, f), voxel_m=VOXEL, waypoints=[[1.0, 0.0], [9.0, 4.0]])
    with pytest.raises(TrajectoryError, match="waypoint 2 .* inside the passage"):
        find_route((v, f), voxel_m=VOXEL, waypoints=[[1.0, 0.0, 0.5], [9.0, 0.0, 10.0]])
    with pytest.raises(TrajectoryError, match="sensor height above the clearance"):
        find_route((v, f), voxel_m=VOXEL, height_m=0.1)
    with pytest.raises(TrajectoryError, match="at most 2,000,000 voxels"):
        find_route((v, f), voxel_m=0.01)
    with pytest.raises(TrajectoryError, match="at least 2 waypoints"):
        find_route((v, f), voxel_m=VOXEL, waypoints=[[1.0, 0.0]])
    narrow = np.zeros((30, 1), bool)
    narrow[:] = True                                                   # 0.5 m wide
    with pytest.raises(TrajectoryError, match=r"at least 2 x 0.2 m wide"):
        find_route(plan_mesh(narrow, portals=("x-", "x+")), voxel_m=VOXEL)
    v, f = _pinched()
    with pytest.raises(TrajectoryError, match="waypoint 2 .* reachable from waypoint 1"):
        find_route((v, f), voxel_m=VOXEL, waypoints=[[2.0, 1.5], [18.0, 1.5]])
    with pytest.raises(TrajectoryError, match="waypoint 2 .* where the passage keeps"):
        find_route((v, f), voxel_m=VOXEL, waypoints=[[2.0, 1.5], [10.0, 1.25]])


def test_a_pinch_is_reported():
    v, f = _pinched()
    with pytest.warns(UserWarning, match="the route runs in the largest part, 50 %"):
        route = find_route((v, f), voxel_m=VOXEL)
    # one 9 m half, to where the medial axis of its closed end begins (half a width)
    assert 9.0 - 1.5 <= route.length_m <= 9.0
    x = route.points[:, 0]
    assert (x < 9.0).all() or (x > 11.0).all()


# ---------------------------------------------------------------------- command line
def _write_mesh(path, v, f):
    import trimesh

    trimesh.Trimesh(v, f, process=False).export(path)
    return str(path)


def test_drive_along_auto_writes_the_cloud_truth_and_route(tmp_path, capsys):
    import laspy

    from survey.cli.main import main
    from sensors import Trajectory

    v, f = _tube(8.0)
    mesh = _write_mesh(tmp_path / "tube.ply", v, f)
    out = tmp_path / "dr.laz"
    assert main(["drive", "--mesh", mesh, "--sensor", "velodyne_vlp16", "--along", "auto",
                 "--platform", "trolley", "--speed", "4", "--height", "0.6",
                 "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "route: 8.0 m, smallest clearance 0.60 m" in text
    assert len(laspy.read(out).points) > 10_000
    truth = Trajectory.read(tmp_path / "dr_true_trajectory.txt")
    assert truth.duration_s == pytest.approx(2.0, abs=0.05)
    p = truth.positions[::10]
    assert naive_point_mesh(p, v, f)[0].min() >= CLEAR
    t = naive_cast(v, f, p, np.tile([0.0, 0, -1], (len(p), 1)))[0]
    np.testing.assert_allclose(t, 0.6, atol=0.02)                   # over the floor
    table = np.loadtxt(tmp_path / "dr_route.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 3] - table[:, 4], 0.6, atol=1e-6)


@pytest.mark.parametrize("extra, match", [
    (["--along", "centreline", "--waypoints", "WP"], "--waypoints with --along auto"),
    (["--along", "auto", "--offset", "0.5"], "--offset with --along centreline"),
    (["--along", "auto", "--waypoints", "WP"], "waypoint 2 (9, 4) inside the passage"),
])
def test_drive_along_auto_bad_input(extra, match, tmp_path, capsys, monkeypatch):
    from survey.cli.main import main

    monkeypatch.chdir(tmp_path)
    mesh = _write_mesh(tmp_path / "tube.ply", *_tube(8.0))
    (tmp_path / "wp.csv").write_text("x,y\n1,0\n9,4\n")
    before = set(tmp_path.iterdir())
    argv = ["drive", "--mesh", mesh, "--sensor", "velodyne_vlp16", "--speed", "4",
            *[str(tmp_path / "wp.csv") if a == "WP" else a for a in extra], "-o", "x.laz"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and match in err
    assert set(tmp_path.iterdir()) == before
