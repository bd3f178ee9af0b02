"""The sensors API as a NumPy user meets it: arguments checked at the call (not five
chunks later), points taken as (3,), (n, 3) or x/y/z records alike, keyword-only
options where order could be confused, one-line reprs, and ``Run.stats`` that a
partial pass does not overwrite."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from raytrace import Scene
from raytrace.shapes import sweep_profile
from sensors import (
    Mount,
    Settings,
    SimulationError,
    TLSScan,
    Trajectory,
    TrajectoryError,
    load_sensor,
    simulate_drive,
    simulate_station,
)

XYZ = np.dtype([("x", "f8"), ("y", "f8"), ("z", "f8")])


@pytest.fixture(scope="module")
def tube():
    k = 48
    ang = 2 * np.pi * np.arange(k) / k
    v, f = sweep_profile(np.stack([2.0 * np.cos(ang), 2.0 * np.sin(ang)], 1), 20.0, 11,
                         closed_ends=True)
    return Scene(v, f)


@pytest.fixture(scope="module")
def two_seconds():
    return Trajectory.along_polyline([[5.0, 0, 0], [9.0, 0, 0]], 2.0)   # 0 to 2 s


# ---------------------------------------------------------------- checked at the call
def test_a_window_past_the_trajectory_fails_at_the_call(tube, two_seconds):
    with pytest.raises(SimulationError, match=r"within the trajectory's \[0, 2\] s, got "
                                              r"\[0, 6\] s"):
        simulate_drive(tube, "velodyne_vlp16", two_seconds, t_end=6)
    with pytest.raises(SimulationError, match=r"got \[-1, 1\] s"):
        simulate_drive(tube, "velodyne_vlp16", two_seconds, t_start=-1, t_end=1)
    with pytest.raises(SimulationError, match="t_end.*finite number"):
        simulate_drive(tube, "velodyne_vlp16", two_seconds, t_end=float("nan"))
    # A TLS pattern lasts minutes: longer than this trajectory.
    with pytest.raises(SimulationError, match="zf_imager_5016 station pattern"):
        simulate_drive(tube, "zf_imager_5016", two_seconds)
    # Inside the span it runs to the end (every pulse has a pose).
    run = simulate_drive(tube, "velodyne_vlp16", two_seconds, t_start=1.9, t_end=2.0)
    assert sum(len(c) for c in run) > 0


IN_ZERO_ONE = r"`reflectivity` to be a finite number within \[0, 1\]"


@pytest.mark.parametrize("value", [50.0, -1.0, float("nan")])
def test_reflectivity_outside_zero_one_is_refused(tube, two_seconds, value):
    with pytest.raises(SimulationError, match=IN_ZERO_ONE):
        simulate_drive(tube, "velodyne_vlp16", two_seconds, reflectivity=value)
    with pytest.raises(SimulationError, match=IN_ZERO_ONE):
        simulate_station(tube, "zf_imager_5016", [10.0, 0, 0], reflectivity=value)
    with pytest.raises(SimulationError, match=IN_ZERO_ONE):
        Settings(reflectivity=value)


def test_per_face_reflectivity_is_checked(tube, two_seconds):
    m = len(tube.faces)
    with pytest.raises(SimulationError, match=rf"one per mesh face \({m},\), got shape"):
        simulate_drive(tube, "velodyne_vlp16", two_seconds, reflectivity=np.ones(m - 1))
    bad = np.full(m, 0.5)
    bad[7] = 1.5
    with pytest.raises(SimulationError, match=r"within \[0, 1\], got 1.5 at face 7"):
        simulate_drive(tube, "velodyne_vlp16", two_seconds, reflectivity=bad)


@pytest.mark.parametrize("call, match", [
    (lambda s, t: simulate_drive(s, "velodyne_vlp16", t, seed=-1), "seed.*>= 0"),
    (lambda s, t: simulate_drive(s, "velodyne_vlp16", t, seed=1.5), "seed.*whole number"),
    (lambda s, t: simulate_drive(s, "velodyne_vlp16", t, chunk_pulses=0), "chunk_pulses"),
    (lambda s, t: simulate_drive(s, "velodyne_vlp16", t, settings="ideal"),
     "sensors.Settings"),
    (lambda s, t: simulate_drive(s, "velodyne_vlp16", t, "down"), "sensors.Mount"),
    (lambda s, t: simulate_drive(s, "velodyne_vlp16", [0, 1]), "Expected a Trajectory"),
    (lambda s, t: simulate_station(s, "zf_imager_5016", [10, 0, 0], attitude=30.0),
     "attitude.*Rotation"),
    (lambda s, t: simulate_station(s, "zf_imager_5016", [10, 0], resolution="high"),
     r"`position` to have shape \(n, 3\) or \(3,\), got \(2,\)"),
    (lambda s, t: simulate_station(s, "zf_imager_5016", np.zeros((2, 3))),
     "one station `position`"),
    (lambda s, t: simulate_station(s, "zf_imager_5016", [10, np.nan, 0]), "finite"),
    (lambda s, t: simulate_station(s, "zf_imager_5016", [10, 0, 0], step_rad="fine"),
     "step_rad.*number"),
    (lambda s, t: Settings(range_noise="no"), "range_noise.*True or False"),
    (lambda s, t: Settings(beam_subrays=7.0), "beam_subrays"),
    (lambda s, t: Settings(attenuation_per_m=-0.1), "attenuation_per_m.*>= 0"),
    (lambda s, t: Trajectory.along_polyline([[0, 0, 0], [1, 0, 0]], 1.0, rate_hz=0),
     "rate_hz.*> 0"),
    (lambda s, t: Mount(lever_arm_m=(0, 0)), "lever arm of 3"),
])
def test_bad_arguments_fail_at_the_call_with_the_house_message(tube, two_seconds, call,
                                                               match):
    with pytest.raises((SimulationError, TrajectoryError), match=match) as exc:
        call(tube, two_seconds)
    assert str(exc.value).startswith("Expected ")
    assert isinstance(exc.value, ValueError)


# ---------------------------------------------------------------- points, any shape
def test_positions_as_a_row_a_matrix_or_records(tube):
    settings = Settings.ideal()
    window = np.deg2rad([0.0, 20.0, -10.0, 10.0])
    rec = np.array((10.0, 0.2, -0.1), dtype=XYZ)
    runs = [simulate_station(tube, "zf_imager_5016", p, resolution="preview",
                             window_rad=window, settings=settings)
            for p in ([10.0, 0.2, -0.1], [[10.0, 0.2, -0.1]], rec, rec[None])]
    clouds = [np.concatenate(list(r)) for r in runs]
    assert len(clouds[0]) > 100
    for c in clouds[1:]:
        assert c.tobytes() == clouds[0].tobytes()

    a = Trajectory.static([1.0, 2.0, 3.0])
    b = Trajectory.static(np.array([(1.0, 2.0, 3.0)], dtype=XYZ))
    np.testing.assert_array_equal(a.positions, b.positions)
    line = np.array([(0.0, 0.0, 0.0), (4.0, 3.0, 0.0)], dtype=XYZ)
    t1 = Trajectory.along_polyline(line, 1.0)
    t2 = Trajectory.along_polyline([[0.0, 0, 0], [4.0, 3.0, 0]], 1.0)
    np.testing.assert_array_equal(t1.positions, t2.positions)
    tr = Trajectory([0.0, 1.0], line, np.tile([0, 0, 0, 1.0], (2, 1)))
    np.testing.assert_array_equal(tr.positions, [[0, 0, 0], [4, 3, 0]])
    with pytest.raises(TrajectoryError, match="fields x, y, z"):
        Trajectory.static(np.zeros(1, dtype=[("a", "f8"), ("b", "f8"), ("c", "f8")]))


def test_options_that_could_be_swapped_are_keyword_only():
    spec = load_sensor("zf_imager_5016")
    with pytest.raises(TypeError):
        Mount.from_degrees((0.0, 0.0, 0.0), 10.0, 5.0)          # roll? pitch? yaw?
    with pytest.raises(TypeError):
        Settings(False, False)                                   # which switches?
    with pytest.raises(TypeError):
        Trajectory.static([0.0, 0, 0], None, 5.0)                 # a time, not a pose
    with pytest.raises(TypeError):
        TLSScan(spec, None, 1e-3)                                 # step? window?
    m = Mount.from_degrees((0.0, 0.0, 0.0), roll_deg=10.0, pitch_deg=5.0)
    np.testing.assert_allclose(m.boresight.as_euler("xyz", degrees=True), [10, 5, 0],
                               atol=1e-12)


# ---------------------------------------------------------------- reprs and stats
def test_reprs_are_one_short_line(tube, two_seconds):
    traj = Trajectory.along_polyline([[0.0, 0, 0], [11.9, 0, 0]], 1.0, rate_hz=10)
    assert repr(traj) == "Trajectory(120 poses, 0.0-11.9 s, 11.9 m path)"
    assert repr(Trajectory.static([1.0, 2, 3], t=4.0)) == \
        "Trajectory(static at (1, 2, 3), t = 4 s)"
    assert repr(Mount((0.0, 0.0, 0.3))) == "Mount(lever_arm_m=(0.0, 0.0, 0.3))"
    assert repr(Mount.from_degrees(yaw_deg=90.0)) == \
        "Mount(lever_arm_m=(0.0, 0.0, 0.0), roll/pitch/yaw 0, 0, 90 deg)"
    assert repr(Settings()) == "Settings()"
    s = Settings(detection=False, reflectivity=0.3)
    assert repr(s) == "Settings(detection=False, reflectivity=0.3)"
    assert eval(repr(s), {"Settings": Settings}) == s
    run = simulate_drive(tube, "velodyne_vlp16", two_seconds, t_end=0.01, seed=3)
    # 181 whole columns of 16 lasers: the last fires at 180 x 55.296 us + 15 x 2.304 us.
    assert repr(run) == ("Run(velodyne_vlp16 drive from t = 0 s, 2,896 pulses, 0.01 s, "
                         "seed 3; not run yet)")
    n = sum(len(c) for c in run)
    assert repr(run).endswith(f"seed 3; {n:,} points in the last pass)")
    st = simulate_station(tube, "zf_imager_5016", [10.0, 0, 0], resolution="preview")
    assert repr(st).startswith("Run(zf_imager_5016 station at (10, 0, 0), 695,000 pulses")
    for obj in (traj, run, st, st.scan, run.scan, load_sensor("velodyne_vlp16")):
        assert "\n" not in repr(obj) and len(repr(obj)) < 120 and " at 0x" not in repr(obj)


def test_a_partial_pass_keeps_the_stats_of_the_last_complete_one(tube, two_seconds):
    run = simulate_drive(tube, "velodyne_vlp16", two_seconds, t_end=0.05,
                         chunk_pulses=2000)
    first = iter(run)
    next(first)                                     # a fresh run, stopped early
    first.close()
    assert run.stats == {} and 0 < run.pass_stats["pulses"] < run.n_pulses
    n_points = sum(len(c) for c in run)
    full = dict(run.stats)
    assert full["pulses"] == run.n_pulses and full["points"] == n_points
    assert set(full) == {"pulses", "points", "hit_ratio", "seconds", "rays_per_s"}
    for _ in zip(range(2), run):                    # a preview of two chunks
        pass
    assert run.stats == full                        # not replaced by the partial pass
    assert run.pass_stats["pulses"] < full["pulses"]


def test_the_attitude_and_a_static_drive_agree_with_a_station(tube):
    """One TLS station, through either entry point: the same points."""
    rot = Rotation.from_euler("z", 20.0, degrees=True)
    window = np.deg2rad([0.0, 10.0, -5.0, 5.0])
    a = np.concatenate(list(simulate_station(
        tube, "zf_imager_5016", [10.0, 0, 0], attitude=rot, resolution="preview",
        window_rad=window, settings=Settings.ideal())))
    assert len(a) > 10
    assert np.all(np.abs(np.arctan2(a["sy"], a["sx"])) <= np.deg2rad(10) + 1e-9)
