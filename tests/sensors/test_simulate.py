"""The simulation loop against analytic answers: ranges in a cylinder, angles to a
point target, rolling shutter, noise statistics, detection, particles, mixed pixels,
determinism."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import raytrace
from raytrace import Scene
from raytrace.shapes import sweep_profile
from sensors import (
    Mount,
    Settings,
    SimulationError,
    Trajectory,
    TrajectoryError,
    simulate_drive,
    simulate_station,
)

R, K = 2.0, 512


def _cylinder(length=60.0, k=K, offset=(0.0, 0.0, 0.0)):
    ang = 2 * np.pi * np.arange(k) / k
    v, f = sweep_profile(np.stack([R * np.cos(ang), R * np.sin(ang)], 1), length, 121,
                         closed_ends=True)
    return Scene(v + offset, f), len(f) - 2 * k     # faces before the caps: lining


@pytest.fixture(scope="module")
def cyl():
    return _cylinder()


def _all(run):
    return np.concatenate(list(run))


@pytest.mark.slow
def test_ranges_in_a_cylinder_match_the_analytic_distance(cyl):
    """From a station on the axis, a ray with radial component rho meets the circle at
    R / rho; the inscribed 512-gon lies between R cos(pi/K) / rho and R / rho."""
    scene, n_lining = cyl
    p = _all(simulate_station(scene, "zf_imager_5016", [30.0, 0.0, 0.0], resolution="middle",
                              settings=Settings.ideal()))
    d = np.stack([p["sx"], p["sy"], p["sz"]], 1) / p["range"][:, None]
    rho = np.hypot(d[:, 1], d[:, 2])
    side = (p["triangle"] < n_lining) & (rho > 0.1)
    assert side.sum() > 100_000
    r = p["range"][side]
    assert np.all(r <= R / rho[side] * (1 + 1e-12))
    assert np.all(r >= R * np.cos(np.pi / K) / rho[side] * (1 - 1e-12))
    # world points = station + sensor-frame points (level station, identity attitude)
    np.testing.assert_allclose(p["x"] - 30.0, p["sx"], atol=1e-9)


def test_point_target_angles_with_a_rotated_station():
    """A small square facing the station at a known direction: every return lies on
    it, and the reported angles are the world direction rotated into the station frame."""
    az0, el0, dist = np.deg2rad(50.0), np.deg2rad(12.0), 15.0
    c = dist * np.array([np.cos(el0) * np.cos(az0), np.cos(el0) * np.sin(az0), np.sin(el0)])
    n = c / dist
    u = np.cross(n, [0, 0, 1.0])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    h = 0.05
    v = np.array([c + h * (a * u + b * w) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    scene = Scene(v, [[0, 1, 2], [0, 2, 3]])
    yaw = np.deg2rad(30.0)
    with pytest.warns(UserWarning, match="outside the mesh"):   # a target, not a tunnel
        run = simulate_station(scene, "zf_imager_5016", [0.0, 0.0, 0.0],
                               attitude=Rotation.from_euler("z", yaw), resolution="high",
                               settings=Settings.ideal())
    p = _all(run)
    assert len(p) > 10
    world = np.stack([p["x"], p["y"], p["z"]], 1)
    assert np.abs((world - c) @ n).max() < 1e-9                    # on the target plane
    assert np.abs(world - c).max() < h * 1.5
    np.testing.assert_allclose(np.mean(p["azimuth"]), az0 - yaw, atol=np.deg2rad(0.2))
    np.testing.assert_allclose(np.mean(p["elevation"]), el0, atol=np.deg2rad(0.2))
    waz = np.arctan2(p["y"], p["x"]) - yaw
    np.testing.assert_allclose(p["azimuth"], waz, atol=1e-9)


def test_rolling_shutter_is_speed_times_time(cyl):
    """A lidar moving at v along the tunnel: its sensor-frame points of one sweep, placed
    with the single pose at the sweep's start, differ from the world points by v dt."""
    scene, _ = cyl
    v = 3.0
    traj = Trajectory.along_polyline([[5.0, 0, 0], [55.0, 0, 0]], v)
    p = _all(simulate_drive(scene, "velodyne_vlp16", traj, Mount((0.0, 0.0, 0.3)),
                            settings=Settings.ideal(), t_end=0.25))
    f = p[p["frame"] == 1]
    t_ref = 0.1                                                   # frame 1 starts at 0.1 s
    pos, rot = traj.sensor_poses(np.array([t_ref]), Mount((0.0, 0.0, 0.3)))
    naive = pos[0] + rot[0].apply(np.stack([f["sx"], f["sy"], f["sz"]], 1))
    world = np.stack([f["x"], f["y"], f["z"]], 1)
    expected = np.zeros_like(world)
    expected[:, 0] = v * (f["time"] - t_ref)
    np.testing.assert_allclose(world - naive, expected, atol=1e-3)
    assert np.ptp(world[:, 0] - naive[:, 0]) > 0.25           # the effect is really there


def _wall(dist=10.0, size=30.0):
    v = np.array([[dist, -size, -size], [dist, size, -size], [dist, size, size],
                  [dist, -size, size]], float)
    return Scene(v, [[0, 1, 2], [0, 2, 3]])


def test_range_noise_has_the_configured_sigma():
    """Profile scanner 10 m in front of a wall: the residuals' spread matches
    sigma(P) of the device model, within 5 standard errors (sigma / sqrt(2 n))."""
    from sensors import load_sensor
    spec = load_sensor("zf_profiler_9012")
    scene = _wall()
    traj = Trajectory.static([0.0, 0.0, 0.0], Rotation.from_euler("y", 90, degrees=True))
    st = Settings(range_noise=True, angle_jitter=False, detection=False, reflectivity=0.3)
    p = _all(simulate_drive(scene, spec, traj, settings=st, t_end=0.05, seed=4))
    dw = np.stack([p["x"], p["y"], p["z"]], 1) / p["range"][:, None]
    true_r = 10.0 / dw[:, 0]
    resid = p["range"] - true_r
    cos = np.cos(p["incidence"])
    ph = spec.physics
    power = 0.3 * cos / true_r ** 2
    sigma = np.sqrt(ph.range_sigma_floor_m ** 2 + ph.range_sigma_m ** 2 *
                    (ph.reference_reflectivity / ph.reference_range_m ** 2) / power)
    z = resid / sigma
    n = len(z)
    assert n > 5000
    assert abs(z.mean()) < 5 / np.sqrt(n)
    assert abs(z.std() - 1.0) < 5 / np.sqrt(2 * n)


def test_same_seed_same_points_any_thread_count(cyl):
    scene, _ = cyl
    traj = Trajectory.along_polyline([[5.0, 0, 0], [55.0, 0, 0]], 2.0)

    def run(seed):
        return _all(simulate_drive(scene, "robosense_airy", traj, Mount.pointing_down(),
                                   seed=seed, t_end=0.05, chunk_pulses=10_000))
    a = run(1)
    old = raytrace.threads()
    try:
        raytrace.set_threads(1)
        b = run(1)
    finally:
        raytrace.set_threads(old)
    assert a.tobytes() == b.tobytes()
    c = run(2)
    assert len(c) != len(a) or not np.array_equal(c["range"], a["range"])


def test_detection_probability_follows_the_lidar_equation():
    """A dark wall near the detection limit: the detected fraction equals the logistic
    probability of its received power (binomial tolerance)."""
    from sensors import load_sensor
    from sensors.physics import detection_probability, power
    spec = load_sensor("velodyne_vlp16")
    ph = spec.physics
    rho = 0.02
    dist = ph.detection_range_m * np.sqrt(rho / ph.detection_reflectivity)   # P = P_min
    scene = _wall(dist, size=2.0)
    traj = Trajectory.static([0.0, 0.0, 0.0])
    st = Settings(range_noise=False, angle_jitter=False, detection=True, reflectivity=rho)
    run = simulate_drive(scene, spec, traj, settings=st, t_end=2.0, seed=3)
    p = _all(run)
    ideal = _all(simulate_drive(scene, spec, traj, settings=Settings.ideal(), t_end=2.0))
    # expected detections: sum of probabilities over the pulses that reach the wall
    cos = np.cos(ideal["incidence"])
    prob = detection_probability(power(rho, cos, ideal["range"], 0.0), ph)
    expected = prob.sum()
    sd = np.sqrt((prob * (1 - prob)).sum())
    assert 0.2 < prob.mean() < 0.8
    assert abs(len(p) - expected) < 5 * sd


def test_particles_return_early_at_the_beer_lambert_rate(cyl):
    scene, n_lining = cyl
    beta = 0.3
    st = Settings(range_noise=False, angle_jitter=False, detection=False,
                  particle_rate_per_m=beta)
    p = _all(simulate_station(scene, "zf_imager_5016", [30.0, 0.0, 0.0], resolution="preview",
                              settings=st, seed=5))
    ideal = _all(simulate_station(scene, "zf_imager_5016", [30.0, 0.0, 0.0],
                                  resolution="preview", settings=Settings.ideal()))
    q = np.clip(1 - np.exp(-beta * (ideal["range"] - 0.3)), 0, 1)  # min range 0.3 m
    frac = np.mean(p["flag"] == 2)
    sd = np.sqrt((q * (1 - q)).sum()) / len(q)
    assert abs(frac - q.mean()) < 5 * sd
    assert np.all(p["triangle"][p["flag"] == 2] == -1)


def test_beam_divergence_mixes_returns_at_an_edge():
    """Two walls at 10 m and 12 m meeting at y = 0: sub-rays that straddle the step
    give mixed returns between the two ranges ("average") or at one of them
    ("strongest")."""
    v = np.array([[10, -5, -5], [10, 0, -5], [10, 0, 5], [10, -5, 5],
                  [12, 0, -5], [12, 5, -5], [12, 5, 5], [12, 0, 5]], float)
    scene = Scene(v, [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    base = dict(range_noise=False, angle_jitter=False, detection=False, beam_subrays=19)
    for mode in ("average", "strongest"):
        with pytest.warns(UserWarning, match="outside the mesh"):
            run = simulate_station(scene, "zf_imager_5016", [0.0, 0.0, 0.0],
                                   step_rad=np.deg2rad(0.01),
                                   window_rad=np.deg2rad([-1.0, 1.0, -5.0, 5.0]),
                                   settings=Settings(mixed=mode, **base))
        p = _all(run)
        assert np.all(np.abs(p["azimuth"]) <= np.deg2rad(1) + 1e-12)
        mixed = p[p["flag"] == 3]
        assert len(mixed) > 0
        x = mixed["x"]
        if mode == "average":
            assert np.any((x > 10.05) & (x < 11.95))           # between the walls
        else:
            assert np.all((np.abs(x - 10) < 0.01) | (np.abs(x - 12) < 0.01))
        # Off the edge the footprint lies on one wall: "average" is the centre's range
        # to second order in the divergence; "strongest" is one sub-ray's, off by up to
        # R tan(incidence) x half-angle (12 m x tan 5 deg x 0.3 mrad = 0.3 mm).
        clean = p[p["flag"] == 1]
        tol = 1e-5 if mode == "average" else 12 * np.tan(np.deg2rad(5.1)) * 0.3e-3
        assert np.all((np.abs(clean["x"] - 10) < tol) | (np.abs(clean["x"] - 12) < tol))


def test_station_outside_the_mesh_warns(cyl):
    scene, _ = cyl
    with pytest.warns(UserWarning, match="outside the mesh bounds"):
        simulate_station(scene, "zf_imager_5016", [500.0, 0.0, 0.0], resolution="preview")


def test_bad_simulation_input(cyl):
    scene, _ = cyl
    with pytest.raises(SimulationError, match="resolution"):
        simulate_station(scene, "zf_imager_5016", [30, 0, 0], resolution="insane")
    with pytest.raises(SimulationError, match="TLS sensor"):
        simulate_station(scene, "velodyne_vlp16", [30, 0, 0])
    with pytest.raises(SimulationError, match="raytrace.Scene"):
        simulate_station("mesh.ply", "zf_imager_5016", [30, 0, 0])
    with pytest.raises(SimulationError, match="beam_subrays"):
        Settings(beam_subrays=4)
    with pytest.raises(SimulationError, match="end > start"):
        simulate_drive(scene, "velodyne_vlp16", Trajectory.static([30, 0, 0]))


def test_trajectory_interpolation_files_and_errors(tmp_path):
    rots = Rotation.from_euler("z", [[0.0], [90.0]], degrees=True)
    tr = Trajectory([0.0, 1.0], [[451000.0, 5352000.0, 300.0], [451010.0, 5352000.0, 301.0]],
                    rots)
    pos, rot = tr.interpolate(np.array([0.5]))
    np.testing.assert_allclose(pos[0], [451005.0, 5352000.0, 300.5], atol=1e-9)
    assert rot[0].as_euler("zyx", degrees=True)[0] == pytest.approx(45.0)
    for name in ("t.txt", "t.csv"):
        tr.write(tmp_path / name)
        back = Trajectory.read(tmp_path / name)
        np.testing.assert_allclose(back.positions, tr.positions, atol=1e-9)
        np.testing.assert_allclose(back.rotations.as_quat(), tr.rotations.as_quat(), atol=1e-9)
    with pytest.raises(TrajectoryError, match="strictly increasing"):
        Trajectory([0.0, 1.0, 1.0], np.zeros((3, 3)), np.tile([0, 0, 0, 1.0], (3, 1)))
    with pytest.raises(TrajectoryError, match="within the trajectory"):
        tr.interpolate(np.array([2.0]))
    (tmp_path / "bad.txt").write_text("0 1 2\n")
    with pytest.raises(TrajectoryError, match="8 columns"):
        Trajectory.read(tmp_path / "bad.txt")


def test_fast_pose_path_equals_scipy_slerp():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.05, 0.2, 12))
    tr = Trajectory(t, rng.normal(0, 10, (12, 3)) + [451000.0, 5352000.0, 300.0],
                    Rotation.random(12, random_state=1))
    mount = Mount.from_degrees((0.1, -0.2, 0.5), roll_deg=10.0, pitch_deg=-5.0, yaw_deg=90.0)
    q = np.linspace(t[0], t[-1], 1001)
    pos_a, rot_a = tr.sensor_poses(q, mount)
    pos_b, mat_b = tr.sensor_matrices(q, mount)
    np.testing.assert_allclose(pos_b, pos_a, atol=1e-9)
    np.testing.assert_allclose(mat_b, rot_a.as_matrix(), atol=1e-12)


def test_pulses_fired_together_share_one_pose_bit_for_bit():
    """Poses are interpolated once per run of equal times (the Airy fires 8 channels at
    once) and written to each pulse of the run: every row equals the pose of its own
    time computed alone, and scipy's SLERP to rounding."""
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.05, 0.2, 9))
    tr = Trajectory(t, rng.normal(0, 5, (9, 3)) + [451000.0, 5352000.0, 300.0],
                    Rotation.random(9, random_state=2))
    mount = Mount.from_degrees((0.1, 0.0, 0.3), roll_deg=3.0, yaw_deg=-20.0)
    q = np.linspace(t[0], t[-1], 257)
    rep = np.repeat(q, rng.integers(1, 9, len(q)))
    pos, mat = tr.sensor_matrices(rep, mount)
    for i in rng.choice(len(rep), 40, replace=False):
        p1, m1 = tr.sensor_matrices(rep[i:i + 1], mount)
        assert p1.tobytes() == pos[i:i + 1].tobytes() and m1.tobytes() == mat[i:i + 1].tobytes()
    pos_s, rot_s = tr.sensor_poses(rep, mount)
    np.testing.assert_allclose(pos, pos_s, atol=1e-9)
    np.testing.assert_allclose(mat, rot_s.as_matrix(), atol=1e-12)


def test_large_chunks_on_the_thread_pool_equal_small_chunks(cyl):
    """Chunks of 1M pulses draw their random blocks and pattern columns on a thread pool;
    chunks of 10,000 do it in one thread: the points must be the same bytes."""
    scene, _ = cyl
    traj = Trajectory.along_polyline([[5.0, 0, 0], [55.0, 0, 0]], 2.0)

    def run(chunk):
        return _all(simulate_drive(scene, "robosense_airy", traj, Mount(), seed=5,
                                   t_end=0.35, chunk_pulses=chunk))
    big, small = run(1 << 20), run(10_000)
    assert len(big) > 200_000        # several random blocks of 65,536 in one chunk
    assert big.tobytes() == small.tobytes()
