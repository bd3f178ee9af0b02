"""Plan and study on any mesh (issue 20): no tunnel JSON, a U-shaped tube that has no
straight axis. Coverage on the mesh's own triangles against a brute-force count
(every sample, every station, every triangle: ``tests/naive.py``), the sub-triangle
index and the route frame as properties, and the files the user gets."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import Settings, load_sensor
from sensors.route import find_route
from survey.analysis.planning import OCCLUSION_EPS_M, RoutePlanner, Thresholds
from survey.analysis.surface import FLOOR_NORMAL_Z, RouteFrame, mesh_surface, sub_index
from survey.analysis.study import Study
from survey.cli.main import main
from tests.iofiles import ply_mesh
from tests.naive import naive_cast


def bent_tube(n_triangles: int, length_m: float, turn_rad: float):
    """``tunnel_tube`` (straight along +x, floor at z = 0) bent left on a circular arc
    through ``turn_rad``: a passage with no straight axis."""
    v, f = tunnel_tube(n_triangles, length_m=length_m, roughness_m=0.0)
    r = length_m / turn_rad
    th = v[:, 0] / r
    return np.stack([(r - v[:, 1]) * np.sin(th), r - (r - v[:, 1]) * np.cos(th),
                     v[:, 2]], axis=1), f


@pytest.fixture(scope="module")
def u_tube():
    return bent_tube(1500, 20.0, np.pi)


@pytest.fixture(scope="module")
def small_planner():
    v, f = bent_tube(400, 12.0, np.pi / 2)
    return RoutePlanner(Scene(v, f), load_sensor("zf_imager_5016"), resolution="high",
                        thresholds=Thresholds(spacing_m=0.004, range_m=7.0),
                        sample_m=0.8)


# ------------------------------------------------------------------ brute force
def _naive_samples(v, f, sample_m):
    """Centroid, area and triangle of every sub-triangle, by explicit loops: triangle
    (a, b, c) cut n x n, n = ceil(longest edge / sample_m)."""
    out = []
    for k, (ia, ib, ic) in enumerate(f):
        a, b, c = v[ia], v[ib], v[ic]
        n = max(1, int(np.ceil(max(np.linalg.norm(b - a), np.linalg.norm(c - b),
                                   np.linalg.norm(a - c)) / sample_m - 1e-9)))
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a)) / n ** 2
        p = lambda i, j: a + (i * (b - a) + j * (c - a)) / n  # noqa: E731
        for i in range(n):
            for j in range(n - i):
                out.append(((p(i, j) + p(i + 1, j) + p(i, j + 1)) / 3, area, k))
                if i + j <= n - 2:
                    out.append(((p(i + 1, j) + p(i + 1, j + 1) + p(i, j + 1)) / 3, area, k))
    return (np.array([o[0] for o in out]), np.array([o[1] for o in out]),
            np.array([o[2] for o in out]))


def _floor(v, f, tri, pts):
    """Floor samples of the tubes here: facing up (|n_z| > FLOOR_NORMAL_Z) and below
    1 m (their roof is above 2 m)."""
    n = np.cross(v[f[tri, 1]] - v[f[tri, 0]], v[f[tri, 2]] - v[f[tri, 0]])
    return (np.abs(n[:, 2]) / np.linalg.norm(n, axis=1) > FLOOR_NORMAL_Z) & (pts[:, 2] < 1.0)


def _naive_served(v, f, pts, tri, station, step_rad, th, range_max_m, blind_el_rad):
    """Per sample: seen from ``station`` within every threshold. Visibility: the first
    hit of every triangle (``naive_cast``) lies no nearer than the sample less
    ``OCCLUSION_EPS_M``; incidence from the triangle's normal, either side."""
    d = pts - station
    r = np.linalg.norm(d, axis=1)
    el = np.arcsin(d[:, 2] / r)
    cand = (r <= min(range_max_m, th.range_m)) & (el >= blind_el_rad)
    idx = np.flatnonzero(cand)
    t, *_ = naive_cast(v, f, station, d[idx], t_max=np.inf)
    vis = np.zeros(len(pts), dtype=bool)
    vis[idx] = t >= r[idx] - OCCLUSION_EPS_M
    a, b, c = v[f[tri, 0]], v[f[tri, 1]], v[f[tri, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1)[:, None]
    cosi = np.abs(np.einsum("ni,ni->n", d, n)) / r
    return vis & (np.arccos(np.clip(cosi, 0, 1)) <= th.incidence_rad) & \
        (r * step_rad / cosi <= th.spacing_m)


def test_coverage_equals_brute_force(small_planner):
    pl = small_planner
    v = np.asarray(pl.scene.vertices)
    f = np.asarray(pl.scene.faces)
    pts, area, tri = _naive_samples(v, f, 0.8)
    floor = _floor(v, f, tri, pts)
    pts, area, tri = pts[~floor], area[~floor], tri[~floor]
    assert pl.cells.total_area == pytest.approx(area.sum(), rel=1e-12)
    plan = pl.evaluate([2.0, 9.0], "two")
    fov = pl.sensor.pattern.vertical_fov_rad
    served = np.zeros(len(pts), dtype=bool)
    for p in plan.stations:
        served |= _naive_served(v, f, pts, tri, p, pl.step_rad, pl.th,
                                pl.sensor.physics.range_max_m, -(np.pi / 2 - (2 * np.pi - fov) / 2))
    # Same samples in another order: match them by position.
    order = np.lexsort(np.round(pts, 9).T)
    mine = np.lexsort(np.round(pl.cells.points, 9).T)
    np.testing.assert_allclose(pl.cells.points[mine], pts[order], atol=1e-12)
    np.testing.assert_array_equal(plan.served[mine] > 0, served[order])
    assert 0.2 < plan.coverage < 0.95                  # the case is not trivial
    assert plan.coverage == pytest.approx(area[served].sum() / area.sum(), rel=1e-12)
    # The gaps hold every uncovered sample's area.
    assert sum(g["area_m2"] for g in plan.gaps) == pytest.approx(area[~served].sum())


def test_surface_partitions_the_mesh(u_tube):
    v, f = u_tube
    sc = Scene(v, f)
    frame = RouteFrame(find_route(sc, height_m=0.5).floor)
    s = mesh_surface(sc, frame, sample_m=0.3, height_m=0.5, keep_floor=True)
    tri_area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]),
                                    axis=1)
    np.testing.assert_allclose(np.bincount(s.triangle, s.area, len(f)), tri_area, rtol=1e-12)
    edges = np.linalg.norm(s.corners[:, [1, 2, 0]] - s.corners, axis=2)
    assert edges.max() <= 0.3 + 1e-9
    # The floor (facing up, low) is what is marked floor.
    np.testing.assert_array_equal(s.is_floor, _floor(v, f, s.triangle, s.points))


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 9), u=st.floats(0, 1), v=st.floats(0, 1))
def test_sub_index_finds_the_sub_triangle(n, u, v):
    # Brute force: the sub-triangle whose lattice corners contain (u, v).
    if u + v > 1:
        u, v = 1 - u, 1 - v
    k = int(sub_index(u, v, n))
    tris = []
    for i in range(n):
        for j in range(n - i):
            tris.append(((i, j), (i + 1, j), (i, j + 1)))
    for i in range(n - 1):
        for j in range(n - 1 - i):
            tris.append(((i + 1, j), (i + 1, j + 1), (i, j + 1)))
    c = np.array(tris[k], dtype=float) / n
    m = np.array([c[1] - c[0], c[2] - c[0]]).T
    w = np.linalg.solve(m, np.array([u, v]) - c[0])
    assert w.min() >= -1e-9 and w.sum() <= 1 + 1e-9


@settings(max_examples=60, deadline=None)
@given(s=st.floats(0.5, 19.5), off=st.floats(-1.0, 1.0), h=st.floats(-1.0, 2.0))
def test_route_frame_round_trip(u_tube, s, off, h):
    # A U-bend of radius 20 / pi m: within 1 m of it a point's nearest route point is
    # unique, so to_local undoes to_world.
    th = np.linspace(0, np.pi, 200)
    r = 20.0 / np.pi
    frame = RouteFrame(np.stack([r * np.sin(th), r - r * np.cos(th), 0.1 * th], 1))
    got = frame.to_local(frame.to_world(s, off, h).reshape(1, 3))
    np.testing.assert_allclose([g[0] for g in got], [s, off, h], atol=2e-3)


# ------------------------------------------------------------------ study
def test_study_along_route_counts_like_brute_force(u_tube):
    from scipy.spatial.transform import Rotation

    from sensors import Trajectory, simulate_drive

    v, f = u_tube
    sc = Scene(v, f)
    route = find_route(sc, height_m=0.5)
    spec = load_sensor("velodyne_vlp16")
    study = Study.along_route(sc, route, spec, strip_m=(8.0, 11.0), lead_m=2.0,
                              sample_m=0.25, settings=Settings.ideal())
    row = study.run(0.0, 10.0, "level")
    # The same sweep, simulated here: standing at the path's middle, heading along it.
    mid = len(study.path) // 2
    d = study.path[mid + 1] - study.path[mid - 1]
    traj = Trajectory.static(study.path[mid], Rotation.from_euler("z", np.arctan2(d[1], d[0])))
    pts = np.concatenate(list(simulate_drive(sc, spec, traj, settings=Settings.ideal(),
                                             t_start=0.0, t_end=0.1 + 1e-6)))
    c = study.cells
    counts = np.zeros(len(c.area), dtype=np.int64)
    for p in pts[pts["triangle"] >= 0]:
        x = np.array([p["x"], p["y"], p["z"]])
        for k in np.flatnonzero(c.triangle == p["triangle"]):
            a, b, cc = c.corners[k]
            m = np.array([b - a, cc - a]).T
            w = np.linalg.lstsq(m, x - a, rcond=None)[0]
            if w.min() >= -1e-9 and w.sum() <= 1 + 1e-9:
                counts[k] += 1
                break
    lin = ~c.is_floor
    assert row.points == counts.sum() > 1000
    assert row.density_lining == pytest.approx(counts[lin].sum() / c.area[lin].sum())
    assert row.empty_lining_share == pytest.approx(
        c.area[lin & (counts == 0)].sum() / c.area[lin].sum())


def test_study_along_route_density_is_one_over_speed(u_tube):
    v, f = u_tube
    sc = Scene(v, f)
    study = Study.along_route(sc, find_route(sc, height_m=0.5), load_sensor("velodyne_vlp16"),
                              strip_m=(9.0, 11.0), lead_m=2.0, sample_m=0.25,
                              settings=Settings.ideal())
    r2, r4 = study.run(2.0, 10.0), study.run(4.0, 10.0)
    # Same positions, half the pulses per metre (see test_study.py).
    assert r2.density_lining / r4.density_lining == pytest.approx(2.0, rel=0.03)
    assert r2.line_spacing_m == pytest.approx(0.2, rel=0.05)


# ------------------------------------------------------------------ the files
@pytest.fixture(scope="module")
def u_ply(tmp_path_factory, u_tube):
    path = tmp_path_factory.mktemp("anymesh") / "u.ply"
    ply_mesh(path, *u_tube)
    assert not path.with_suffix(".json").exists()
    return path


def _plan(u_ply, out, *extra):
    assert main(["plan", "--mesh", str(u_ply), "--resolution", "high", "--cell", "0.5,4",
                 "-o", str(out), "--quiet", *extra]) == 0
    rows = [r.split(",") for r in (out / "plan.csv").read_text().splitlines()]
    return rows[0], rows[1:], json.loads((out / "plan.json").read_text())


def test_cli_plan_on_any_mesh_follows_the_options(tmp_path, u_ply):
    head, rows, js = _plan(u_ply, tmp_path / "a", "--spacing", "5", "--optimize",
                           "--target", "0.9", "--candidate-step", "2.5")
    assert js["along"] == "route" and js["route"]["length_m"] > 17
    assert {r[0] for r in rows} == {"every 5 m", "optimised", "greedy"}
    assert len([r for r in rows if r[0] == "every 5 m"]) == 4        # 2.5 .. 17.5 m
    best = next(p for p in js["plans"] if p["name"] == "optimised")
    assert best["coverage"] >= 0.9
    i = head.index("z")
    assert all(float(r[i]) == pytest.approx(1.5, abs=1e-6) for r in rows)  # floor z = 0
    png = (tmp_path / "a" / "coverage.png").read_bytes()
    assert png[:4] == b"\x89PNG"
    assert (tmp_path / "a" / "route.csv").is_file()
    md = (tmp_path / "a" / "plan.md").read_text()
    assert "route found in the mesh" in md and "| every 5 m | 4 |" in md
    # Other options, other files: fewer stations, another height, another figure.
    head2, rows2, js2 = _plan(u_ply, tmp_path / "b", "--spacing", "10", "--height", "1.2")
    assert len(rows2) == 2 and js2["plans"][0]["stations"] == 2
    assert all(float(r[head2.index("z")]) == pytest.approx(1.2, abs=1e-6) for r in rows2)
    assert js2["plans"][0]["coverage"] < js["plans"][0]["coverage"]
    assert (tmp_path / "b" / "coverage.png").read_bytes() != png
    # Offsets: candidates across the route appear in the optimised set's CSV column.
    _, rows3, js3 = _plan(u_ply, tmp_path / "c", "--spacing", "5", "--optimize",
                          "--candidate-step", "5", "--offsets", "0.8", "--target", "0.99")
    offs = {float(r[head.index("offset_m")]) for r in rows3 if r[0] == "greedy"}
    assert offs <= {-0.8, 0.0, 0.8} and js3["optimisation"]["candidates"] == 12


def test_cli_plan_and_study_refuse_bad_route_options(tmp_path, u_ply, capsys):
    from survey.world.alignment import Alignment, straight
    from survey.world.generator import make_tunnel
    from survey.world.profiles import horseshoe

    (tmp_path / "w.csv").write_text("0,0\n1,1\n")
    t = make_tunnel(Alignment([straight(12.0)]), horseshoe(5.0), edge_length_m=0.5,
                    roughness_rms_m=0.0)
    t.write(tmp_path / "t.ply")
    assert main(["plan", "--mesh", str(tmp_path / "t.ply"), "--waypoints",
                 str(tmp_path / "w.csv"), "-o", str(tmp_path / "p")]) == 2
    assert "--along auto" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()
    (tmp_path / "far.csv").write_text("100,100\n120,100\n")
    assert main(["study", "--mesh", str(u_ply), "--waypoints", str(tmp_path / "far.csv"),
                 "-o", str(tmp_path / "s")]) == 2
    assert "waypoint" in capsys.readouterr().err.lower()
    assert not (tmp_path / "s").exists()


def test_cli_study_on_any_mesh(tmp_path, u_ply):
    out = tmp_path / "st"
    assert main(["study", "--mesh", str(u_ply), "--sensor", "velodyne_vlp16", "--speeds",
                 "0,2", "--rates", "10", "--mounts", "level", "--strip", "9,11", "--lead",
                 "2", "--cell", "0.25", "--ideal", "-o", str(out), "--quiet"]) == 0
    rows = (out / "study.csv").read_text().splitlines()
    assert len(rows) == 3 and rows[0].startswith("speed_mps,rate_hz,mount")
    assert "route found in the mesh" in (out / "study.md").read_text()
    assert (out / "route.csv").is_file() and (out / "study.png").read_bytes()[:4] == b"\x89PNG"


def test_route_objects_print_one_line(small_planner):
    pl = small_planner
    plan = pl.evaluate([[2.0, 0.0], [9.0, 0.5]], "two")
    assert plan.offsets_m.tolist() == [0.0, 0.5]
    for obj, start in ((pl, "RoutePlanner(zf_imager_5016 at high, route 12.0 m, "),
                       (pl.cells, f"Surface({len(pl.cells.area):,} samples of "),
                       (pl.frame, "RouteFrame(12.0 m)"),
                       (plan, "Plan('two', 2 stations, coverage ")):
        text = repr(obj)
        assert text.startswith(start) and "\n" not in text and len(text) < 200, text


def test_route_planner_bad_inputs(small_planner):
    from survey.errors import PlanningError

    pl = small_planner
    with pytest.raises(PlanningError, match="along the route within"):
        pl.stations_at([50.0])
    with pytest.raises(PlanningError, match="do not fit"):
        pl.stations_at([[6.0, 5.0]])                     # 5 m left: outside the tube
    with pytest.raises(PlanningError, match="shape"):
        pl.evaluate(np.zeros((2, 3)))
    with pytest.raises(PlanningError, match="sample size"):
        mesh_surface(pl.scene, pl.frame, sample_m=0.0)
    with pytest.raises(PlanningError, match="route of shape"):
        RouteFrame(np.zeros((1, 3)))
    assert len(pl.candidates(3.0, [5.0])) == len(pl.spaced(3.0))   # 5 m dropped
