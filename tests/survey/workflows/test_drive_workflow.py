"""``drive_to_file`` (survey.workflows.drive) against ``tunnelsim drive``: a notebook
that calls the library gets the same files as the command line, byte for byte, and the
numbers the command prints are the result's.

References: the files the CLI writes (run in-process through ``survey.cli.main.main``)
in a second folder; for the bag, the messages decoded by ``rosbags`` (a third-party
reader), and the lever arm the command line was given (for a trajectory file base_link
is the trajectory's frame, so /tf_static base_link -> sensor must be that lever arm);
laspy's own count of the points in the LAZ.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.cli.main import main
from survey.workflows.drive import drive_to_file

# A two-beam spinning test sensor: 2,000 pulses a second keep each drive at a few
# thousand pulses (tests/survey/cli/test_drive_platform.py uses the same device).
SENSOR = """
[device]
name = "test_two_beams"
vendor = "test"
model = "two beams"
kind = "spinning"
wavelength_nm = 905
sources = ["test sensor: 2 channels, 1 kHz columns"]
[range]
min_m = 0.1
max_m = 50.0
[detection]
range_m = 50.0
reflectivity = 0.8
softness = 0.1
[noise]
range_sigma_m = 0.01
reference_range_m = 10.0
reference_reflectivity = 0.5
range_sigma_floor_m = 0.0
angle_sigma_arcsec = 0.0
[beam]
divergence_half_mrad = 0.0
exit_diameter_mm = 0.0
[spinning]
rotation_hz = 10.0
column_period_us = 1000.0
elevations_deg = [-30.0, 10.0]
azimuth_offset_deg = 0.0
firing_group_size = 1
firing_group_step_us = 1.0
clockwise = true
"""
LEVER = (0.2, 0.05, 0.3)


@pytest.fixture()
def sensor(tmp_path):
    p = tmp_path / "two_beams.toml"
    p.write_text(SENSOR)
    return str(p)


def _files(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _both(tmp_path, argv, **kwargs):
    """(CLI folder, library folder, library result, CLI stdout) of the same drive."""
    a, b = tmp_path / "cli", tmp_path / "lib"
    a.mkdir()
    b.mkdir()
    assert main(["drive", *argv, "-o", str(a / kwargs["name"])]) == 0
    name = kwargs.pop("name")
    res = drive_to_file(output=b / name, **kwargs)
    return a, b, res


def test_drive_laz_is_the_clis_byte_for_byte(tbm_20k, sensor, tmp_path, capsys):
    """Centreline drive of 0.35 s (cut back to its 3 whole sweeps), down-looking mount,
    a lever arm, noise on: the LAZ, the true and base_link trajectories, the URDF and
    the launch file are the CLI's, byte for byte; the lines the CLI printed are those
    made from the result (but the summary's timing)."""
    argv = ["--mesh", str(tbm_20k), "--sensor", sensor, "--along", "centreline",
            "--speed", "2", "--duration", "0.35", "--mount", "down", "--lever",
            ",".join(map(str, LEVER)), "--seed", "7", "--fields", "full",
            "--chainage", "20,40"]
    a, b, res = _both(tmp_path, argv, name="d.laz", mesh=tbm_20k, sensor=sensor,
                      along="centreline", speed_mps=2.0, duration_s=0.35, mount="down",
                      lever_arm_m=LEVER, seed=7, fields="full", chainage_m=(20.0, 40.0))
    printed = capsys.readouterr().out.splitlines()
    cli, lib = _files(a), _files(b)
    # The trolley rides the centreline: base_link is its frame, no base_link file.
    assert sorted(cli) == sorted(lib) == ["d.laz", "d_robot.launch.py", "d_robot.urdf",
                                          "d_true_trajectory.txt"]
    for name in cli:
        assert cli[name] == lib[name], name

    import laspy

    las = laspy.read(b / "d.laz")
    # 3 sweeps of 0.1 s at 2,000 pulses a second; nearly all hit the tube around it.
    assert res.output.pulses == 600
    assert res.output.points == len(las.points) > 0.9 * 600
    # Cut back to whole sweeps: 3 revolutions of 0.1 s, no point after them.
    assert res.sweeps is not None and res.sweeps.sweeps == 3
    t = np.asarray(las.gps_time)
    assert t.max() <= res.sweeps.end_s + 1e-9 and res.duration_s == pytest.approx(0.3)
    poses = (b / "d_true_trajectory.txt").read_text().splitlines()
    assert res.poses == len([p for p in poses if p and not p.startswith("#")])
    from survey.cli.commands.driving import drive_lines

    mine = drive_lines(res, a / "d.laz")
    label = f"{res.label}: "
    assert len(printed) == len(mine)
    for got, want in zip(printed, mine):
        if got.startswith(label):       # seconds and rays per second differ run to run
            assert got.split(" (hit ratio")[0] == want.split(" (hit ratio")[0]
        else:
            assert got == want


def _bag_messages(path):
    """Every message of a bag: (topic, log time ns, raw bytes), via rosbags."""
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def test_drive_bag_holds_the_clis_messages_and_the_robot_frames(tbm_20k, sensor,
                                                                   tmp_path):
    """A bag of a drive along a trajectory file: the library's MCAP is the CLI's, byte
    for byte and message for message (decoded by rosbags), with /tf_static and /odom,
    which ``Run.write`` alone does not write; its base_link -> sensor transform is the
    lever arm given."""
    traj = tmp_path / "traj.txt"
    # TUM rows along the tunnel's axis (x), 1.5 m up, 1 m/s for 0.4 s.
    t = np.linspace(0.0, 0.4, 9)
    rows = np.column_stack([t, 30.0 + t, np.zeros_like(t), np.full_like(t, 1.5),
                            np.zeros((len(t), 3)), np.ones_like(t)])
    np.savetxt(traj, rows, fmt="%.9f")
    argv = ["--mesh", str(tbm_20k), "--sensor", sensor, "--trajectory", str(traj),
            "--lever", ",".join(map(str, LEVER)), "--seed", "3", "--start-time",
            "1700000000.5"]
    a, b, res = _both(tmp_path, argv, name="d.mcap", mesh=tbm_20k, sensor=sensor,
                      trajectory=traj, lever_arm_m=LEVER, seed=3,
                      start_time="1700000000.5")
    # The MCAP holds no wall-clock time (its times are the drive's, from --start-time):
    # the files are the same byte for byte, and so are the decoded messages.
    assert (a / "d.mcap").read_bytes() == (b / "d.mcap").read_bytes()
    cli, lib = _bag_messages(a / "d.mcap"), _bag_messages(b / "d.mcap")
    assert len(cli) == len(lib) > 10 and cli == lib
    assert _files(a) == _files(b)
    topics = {m[0] for m in lib}
    assert {"/tf_static", "/odom"} <= topics
    # Decoded /tf_static: base_link -> the sensor's frame is the lever arm.
    from rosbags.highlevel import AnyReader

    with AnyReader([b / "d.mcap"]) as reader:
        conns = [c for c in reader.connections if c.topic == "/tf_static"]
        found = {}
        for c, _t, raw in reader.messages(connections=conns):
            for tf in reader.deserialize(raw, c.msgtype).transforms:
                tr = tf.transform.translation
                found[(tf.header.frame_id, tf.child_frame_id)] = (tr.x, tr.y, tr.z)
    sensor_tf = [v for (parent, child), v in found.items()
                 if parent == "base_link" and child != "imu_link"]
    assert len(sensor_tf) == 1 and sensor_tf[0] == pytest.approx(LEVER, abs=1e-12)
    assert res.output.points > 0 and res.robot.mast_height_m == 0.0
    # The bag Run.write makes from the same run has no robot: no /odom.
    from sensors import Mount, Trajectory, simulate_drive
    from sensors.io.meshes import load_mesh

    scene, refl = load_mesh(tbm_20k)
    run = simulate_drive(scene, sensor, Trajectory.read(traj), Mount(LEVER), seed=3,
                         reflectivity=refl)
    run.write(tmp_path / "plain.mcap")
    assert "/odom" not in {m[0] for m in _bag_messages(tmp_path / "plain.mcap")}


def test_cli_and_library_refuse_alike(tbm_20k, sensor, tmp_path, capsys):
    """A duration past the trajectory's end: the library raises the message the CLI
    prints (one line, exit 2), naming --duration; neither leaves a file behind."""
    from sensors.errors import SimulationError

    traj = tmp_path / "traj.txt"
    np.savetxt(traj, [[0, 30, 0, 1.5, 0, 0, 0, 1], [1, 31, 0, 1.5, 0, 0, 0, 1]])
    out = tmp_path / "x.laz"
    assert main(["drive", "--mesh", str(tbm_20k), "--sensor", sensor, "--trajectory",
                 str(traj), "--duration", "2", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    with pytest.raises(SimulationError) as exc:
        drive_to_file(tbm_20k, out, sensor=sensor, trajectory=traj, duration_s=2.0)
    assert err == f"tunnelsim: error: {exc.value}" and "--duration" in err
    assert not out.exists()


@settings(max_examples=200, deadline=None)
@given(start=st.floats(-1e3, 1e3), dur=st.floats(0.01, 20.0),
       rate=st.sampled_from([5.0, 10.0, 12.5, 20.0]),
       part=st.one_of(st.none(), st.floats(0.01, 1.0)))
def test_a_drive_is_cut_at_its_last_whole_sweep(start, dur, rate, part):
    """``whole_sweeps_end``: the end is the start plus a whole number of sweeps
    (counted one by one here), the last that fits the time driven; what is left out is
    less than one sweep; a drive ending on a whole sweep (or shorter than one) is not
    cut."""
    from scipy.spatial.transform import Rotation

    from sensors import Trajectory, load_sensor
    from sensors.spec import with_rate
    from survey.workflows.drive import whole_sweeps_end

    spec = with_rate(load_sensor("velodyne_vlp16"), rate)
    traj = Trajectory([start, start + dur], np.zeros((2, 3)), Rotation.identity(2))
    t_end = None if part is None else start + part * dur
    end = start + dur if t_end is None else t_end
    n = 0                               # whole sweeps that fit, counted one by one
    while start + (n + 1) / rate <= end + 1e-9 / rate:
        n += 1
    got, cut = whole_sweeps_end(spec, traj, t_end)
    if n < 1 or start + n / rate >= end - 1e-9:
        assert cut is None and got == t_end
    else:
        assert cut is not None and cut.sweeps == n and got == start + n / rate
        assert 0 < cut.left_out_s < 1 / rate + 1e-9 and cut.period_s == 1 / rate
        assert got <= end


def test_a_terrestrial_scanner_is_not_cut():
    """A TLS has no sweeps (``sweep_rate_hz`` None): its end is left as it is."""
    from scipy.spatial.transform import Rotation

    from sensors import Trajectory, load_sensor
    from survey.workflows.drive import sweep_rate_hz, whole_sweeps_end

    spec = load_sensor("zf_imager_5016")
    traj = Trajectory([0.0, 1.05], np.zeros((2, 3)), Rotation.identity(2))
    assert sweep_rate_hz(spec) is None and whole_sweeps_end(spec, traj, None) == (None, None)
    assert sweep_rate_hz(load_sensor("zf_profiler_9012")) == \
        load_sensor("zf_profiler_9012").pattern.profile_rate_hz


def test_drive_waveform_changes_the_output_and_refuses_a_bag(tbm_20k, tmp_path, capsys):
    """drive --waveform (a survey profiler): the LAZ differs from the drive without it
    and its wave packets go to NAME.wdp beside it; into a bag it is one line naming
    --waveform, nothing left behind."""
    common = ["drive", "--mesh", str(tbm_20k), "--sensor", "zf_profiler_9012", "--along",
              "centreline", "--speed", "1", "--duration", "0.02", "--quiet"]
    assert main([*common, "-o", str(tmp_path / "p.laz")]) == 0
    assert main([*common, "--waveform", "-o", str(tmp_path / "w.laz")]) == 0
    assert (tmp_path / "w.wdp").stat().st_size > 0 and not (tmp_path / "p.wdp").exists()
    assert (tmp_path / "p.laz").read_bytes() != (tmp_path / "w.laz").read_bytes()
    capsys.readouterr()
    assert main([*common, "--waveform", "-o", str(tmp_path / "b.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--waveform" in err[0]
    assert not list(tmp_path.glob("b*"))
