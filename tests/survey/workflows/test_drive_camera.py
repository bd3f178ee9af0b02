"""Cameras along a drive (issue 35): ``tunnelsim drive --camera`` into a ROS 2 bag and
into PNG folders beside a point file, on the files the user gets.

References: ``rosbags`` (a third-party reader) decodes the bag; every image is
compared with the frame rendered here directly (``render_depth`` / ``radiance_frame``
at poses composed in this file from the trajectory file, the ``--camera-mount`` given
and REP 103's optical axes, lit by the headlamp ``render`` uses, exposed without noise);
CameraInfo against the camera's K and D; the frame count against a brute-force count;
the rolling-shutter frame against rows rendered one at a time from their own poses.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from raytrace import Scene
from sensors.appearance import mesh_appearance
from sensors.camera import load_camera
from sensors.camera_io import depth_counts, rgb8
from sensors.io.meshes import read_mesh
from sensors.pointcloud2 import GENERIC_DRIVER
from sensors.render import render_depth
from sensors.shading import auto_exposure, expose, headlamp, luminance, radiance_frame
from sensors.trajectory import Trajectory
from survey.cli.main import main
from survey.workflows.drive import drive_to_file
from tests.survey.workflows.test_drive_workflow import SENSOR

rosbags = pytest.importorskip("rosbags", reason="rosbags is in the test extra")
from rosbags.highlevel import AnyReader  # noqa: E402

COLOR = """
[device]
name = "test_rgb"
vendor = "Intel"
model = "RealSense test colour"
kind = "color"
sources = ["test camera: 64 x 48, rolling shutter"]
[image]
width = 64
height = 48
frame_rate_hz = 20.0
[lens]
model = "pinhole"
hfov_deg = 80.0
distortion = [0.01, -0.002, 0.0005, -0.0003, 0.0]
[sensor]
shutter = "rolling"
line_time_us = 500.0
exposure_ms = 5.0
read_noise_e = 2.0
full_well_e = 4500.0
pixel_um = 3.0
f_number = 2.0
quantum_efficiency = 0.5
bit_depth = 8
"""
DEPTH = """
[device]
name = "test_depth"
vendor = "Intel"
model = "RealSense test depth"
kind = "depth"
sources = ["test camera: 32 x 24, global shutter"]
[image]
width = 32
height = 24
frame_rate_hz = 20.0
[lens]
model = "pinhole"
hfov_deg = 87.0
distortion = [0.0, 0.0, 0.0, 0.0, 0.0]
[sensor]
shutter = "global"
line_time_us = 0.0
exposure_ms = 2.0
read_noise_e = 2.0
full_well_e = 4500.0
pixel_um = 3.0
f_number = 2.0
quantum_efficiency = 0.5
bit_depth = 16
[depth]
min_m = 0.2
max_m = 10.0
"""
MOUNT = (0.1, 0.0, -0.1, 0.0, 5.0, 2.0)        # X,Y,Z m, roll, pitch, yaw deg
#: REP 103: the optical axes (x right, y down, z forward) in camera_link.
LINK_FROM_OPTICAL = np.column_stack([(0.0, -1.0, 0.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0)])


@pytest.fixture()
def files(tmp_path):
    out = {}
    for name, text in (("sensor", SENSOR), ("color", COLOR), ("depth", DEPTH)):
        p = tmp_path / f"{name}.toml"
        p.write_text(text)
        out[name] = p
    return out


def _trajectory(path: Path, speed: float, yaw_rate: float = 0.0) -> Path:
    """TUM file: 0.5 s along the tbm tunnel's axis (x) at 1.5 m, turning at
    ``yaw_rate``."""
    t = np.round(np.arange(51) * 0.01, 2)
    yaw = yaw_rate * (t - 0.25)
    q = Rotation.from_euler("z", yaw[:, None]).as_quat()
    rows = [f"{ti:.2f} {20 + speed * ti:.6f} 0.3 1.5 {a:.12f} {b:.12f} {c:.12f} {d:.12f}"
            for ti, (a, b, c, d) in zip(t, q)]
    path.write_text("# t x y z qx qy qz qw\n" + "\n".join(rows) + "\n")
    return path


def _row_poses(traj: Trajectory, times: np.ndarray, mount=MOUNT) -> np.ndarray:
    """world_from_optical at ``times``: base_link from the trajectory, camera_link by
    the mount, the optical frame by REP 103."""
    pos, rot = traj.interpolate(times)
    R_link = Rotation.from_euler("xyz", mount[3:], degrees=True).as_matrix()
    T = np.zeros((len(times), 4, 4))
    T[:, :3, :3] = rot.as_matrix() @ R_link @ LINK_FROM_OPTICAL
    T[:, :3, 3] = pos + rot.apply(mount[:3])
    T[:, 3, 3] = 1.0
    return T


def _expected_starts(cam, duration: float, rate: float) -> list[float]:
    readout = (cam.height - 1) * cam.line_time_s + cam.exposure_s
    return [i / rate for i in range(100) if i / rate + readout <= duration + 1e-12]


def _scene_and_look(mesh: Path):
    m = read_mesh(mesh)
    labels = json.loads(mesh.with_suffix(".json").read_text())["labels"]
    names = [labels[str(i)] for i in range(len(labels))]
    return Scene(m.vertices, m.faces), mesh_appearance(m, names)


def test_bag_holds_lidar_camera_and_imu_in_time_order(tbm_20k, files, tmp_path, capsys):
    """Acceptance: a drive bag with lidar + colour + depth camera + IMU, through the
    CLI, read back by rosbags: the images decode and equal frames rendered directly at
    their poses; CameraInfo is the camera's; image stamps fall between the clouds';
    /tf_static holds the mount and REP 103's optical frame."""
    traj_path = _trajectory(tmp_path / "traj.txt", speed=2.0)
    bag = tmp_path / "d.mcap"
    argv = ["drive", "--mesh", str(tbm_20k), "--sensor", str(files["sensor"]),
            "--trajectory", str(traj_path), "--duration", "0.3", "--camera",
            str(files["color"]), "--camera", str(files["depth"]), "--camera-mount",
            ",".join(map(str, MOUNT)), "--no-noise", "-o", str(bag)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    color, depth = load_camera(files["color"]), load_camera(files["depth"])
    starts = {"test_rgb": _expected_starts(color, 0.3, 20.0),
              "test_depth": _expected_starts(depth, 0.3, 20.0)}
    assert len(starts["test_rgb"]) == 6 and len(starts["test_depth"]) == 6
    assert "camera test_rgb: 6 frames of 64x48 at 20 Hz (rolling shutter" in printed
    assert "/camera/color/image_raw and /camera/color/camera_info" in printed

    msgs: dict[str, list] = {}
    order = []
    with AnyReader([bag]) as r:
        for con, log, raw in r.messages():
            m = r.deserialize(raw, con.msgtype)
            msgs.setdefault(con.topic, []).append((log, m))
            order.append((log, con.topic))
    for topic in (GENERIC_DRIVER.topic, "/imu/data_raw", "/camera/color/image_raw",
                  "/camera/color/camera_info", "/camera/depth/image_rect_raw",
                  "/camera/depth/camera_info"):
        assert topic in msgs, topic
    assert len(msgs["/imu/data_raw"]) > 20
    assert [t for t, _ in order] == sorted(t for t, _ in order)

    def ns(stamp):
        return stamp.sec * 10 ** 9 + stamp.nanosec

    scene, look = _scene_and_look(tbm_20k)
    traj = Trajectory.read(traj_path)
    for topic, cam in (("/camera/color/image_raw", color),
                       ("/camera/depth/image_rect_raw", depth)):
        images = msgs[topic]
        assert [ns(m.header.stamp) for _, m in images] == \
            [round(t * 1e9) for t in starts[cam.name]]
        readout = (cam.height - 1) * cam.line_time_s + cam.exposure_s
        for (log, m), t0 in zip(images, starts[cam.name]):
            assert log == round((t0 + readout) * 1e9)      # logged at its readout end
            assert m.header.frame_id == f"camera_{cam.kind}_optical_frame"
            assert (m.height, m.width) == (cam.height, cam.width)
            assert len(m.data) == m.height * m.step
            rows = t0 + np.arange(cam.height) * cam.line_time_s if \
                cam.line_time_s else np.array([t0])
            T = _row_poses(traj, rows)
            pose = T if len(T) > 1 else T[0]
            if cam.kind == "color":
                assert m.encoding == "rgb8" and m.step == 3 * cam.width
                lamp = headlamp(T[0], 1000.0)
                _fr, lum = radiance_frame(scene, cam, pose, [lamp], look, 1)
                want = rgb8(expose(cam, lum, noise=False) / 255.0)
                got = np.frombuffer(m.data, np.uint8).reshape(cam.height, cam.width, 3)
                assert got.mean() > 5                         # lit, not black
            else:
                assert m.encoding == "16UC1" and m.step == 2 * cam.width
                want = depth_counts(render_depth(scene, cam, pose).depth_z_m)[0]
                got = np.frombuffer(m.data, "<u2").reshape(cam.height, cam.width)
                assert (got > 0).mean() > 0.9
            np.testing.assert_array_equal(got, want)
    # CameraInfo: the camera's K and D, R = I, P = [K | 0], stamped as its image.
    for topic, cam in (("/camera/color/camera_info", color),
                       ("/camera/depth/camera_info", depth)):
        infos = msgs[topic]
        assert len(infos) == 6
        for _, m in infos:
            assert m.distortion_model == "plumb_bob"
            np.testing.assert_array_equal(np.reshape(m.k, (3, 3)), cam.K)
            np.testing.assert_array_equal(m.d, cam.distortion)
            np.testing.assert_array_equal(np.reshape(m.r, (3, 3)), np.eye(3))
            np.testing.assert_array_equal(np.reshape(m.p, (3, 4)),
                                          np.hstack([cam.K, np.zeros((3, 1))]))
            assert (m.width, m.height) == (cam.width, cam.height)
    # Interleaving: the clouds are stamped 0, 0.1, 0.2 s; images at 0.05, 0.15 s lie
    # between them, and the bag's log order mixes the topics.
    clouds = [ns(m.header.stamp) for _, m in msgs[GENERIC_DRIVER.topic]]
    assert clouds == [0, 100_000_000, 200_000_000]
    img = [ns(m.header.stamp) for _, m in msgs["/camera/color/image_raw"]]
    between = [s for s in img if any(a < s < b for a, b in zip(clouds, clouds[1:]))]
    assert len(between) >= 2
    seq = [tp for _, tp in order if tp in (GENERIC_DRIVER.topic, "/camera/color/image_raw")]
    first_cloud = seq.index(GENERIC_DRIVER.topic)
    assert "/camera/color/image_raw" in seq[:first_cloud] and \
        "/camera/color/image_raw" in seq[first_cloud + 1:]
    # /tf_static: base_link -> camera_link is the mount; -> optical frames are REP 103.
    (static,) = [m for _, m in msgs["/tf_static"]]
    tf = {(x.header.frame_id, x.child_frame_id): x.transform for x in static.transforms}
    link = tf[("base_link", "camera_link")]
    np.testing.assert_allclose([link.translation.x, link.translation.y, link.translation.z],
                               MOUNT[:3], atol=1e-12)
    q = link.rotation
    np.testing.assert_allclose(
        Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(),
        Rotation.from_euler("xyz", MOUNT[3:], degrees=True).as_matrix(), atol=1e-12)
    for kind in ("color", "depth"):
        q = tf[("camera_link", f"camera_{kind}_optical_frame")].rotation
        np.testing.assert_allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(),
                                   LINK_FROM_OPTICAL, atol=1e-12)


def _png(path: Path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(path.read_bytes())))


def test_png_folder_rolling_shutter_equals_rows_rendered_one_by_one(tbm_20k, files,
                                                                    tmp_path):
    """A fast, turning drive into LAZ: the frames beside it (<stem>_cameras/<camera>/)
    are as many as the drive holds at the rate asked; each row of a rolling-shutter
    frame is the frame rendered whole from that row's pose; the global-shutter camera's
    frame differs."""
    traj_path = _trajectory(tmp_path / "fast.txt", speed=15.0, yaw_rate=2.0)
    res = drive_to_file(tbm_20k, tmp_path / "d.laz", sensor=files["sensor"],
                        trajectory=traj_path, duration_s=0.3, cameras=[files["color"]],
                        camera_rate_hz=10.0, camera_mount=MOUNT, camera_noise=False)
    color = load_camera(files["color"])
    folder = tmp_path / "d_cameras" / "test_rgb"
    (run,) = res.cameras
    assert run.folder == folder and run.frames == 3 and run.rate_hz == 10.0
    starts = _expected_starts(color, 0.3, 10.0)
    pngs = sorted((folder / "rgb").iterdir())
    assert [p.name for p in pngs] == [f"{i:06d}_{round(t * 1e9)}.png"
                                      for i, t in enumerate(starts)]
    assert len(list((folder / "depth").iterdir())) == 3
    with open(folder / "frames.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["stamp_ns"]) for r in rows] == [round(t * 1e9) for t in starts]
    info = json.loads((folder / "camera_info.json").read_text())
    np.testing.assert_array_equal(info["K"], color.K)
    assert info["frames"] == 3 and info["distortion_model"] == "plumb_bob"
    assert info["shutter"] == "rolling" and info["rate_hz"] == 10.0

    scene, look = _scene_and_look(tbm_20k)
    traj = Trajectory.read(traj_path)
    i, t0 = 1, starts[1]
    T = _row_poses(traj, t0 + np.arange(color.height) * color.line_time_s)
    # frames.csv's pose is row 0's.
    np.testing.assert_allclose([float(rows[i][k]) for k in "xyz"], T[0, :3, 3], atol=1e-8)
    lamp = headlamp(T[0], 1000.0)
    lum = np.empty((color.height, color.width, 3))
    depth = np.empty((color.height, color.width))
    for r in range(color.height):
        fr = render_depth(scene, color, T[r])
        px = look.at(fr)
        lum[r] = luminance(scene, fr, [lamp], np.nan_to_num(px.albedo, nan=0.0))[r]
        depth[r] = fr.depth_z_m[r]
    want = rgb8(expose(color, lum, noise=False) / 255.0)
    got = _png(pngs[i])
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(_png(sorted((folder / "depth").iterdir())[i]),
                                  depth_counts(depth)[0])
    # The same camera with a global shutter sees another frame.
    glob = tmp_path / "color_global.toml"
    glob.write_text(COLOR.replace('"rolling"', '"global"').replace("500.0", "0.0")
                    .replace('"test_rgb"', '"test_rgb_global"'))
    drive_to_file(tbm_20k, tmp_path / "g.laz", sensor=files["sensor"], trajectory=traj_path,
                  duration_s=0.3, cameras=[glob], camera_rate_hz=10.0, camera_mount=MOUNT,
                  camera_noise=False)
    other = _png(sorted((tmp_path / "g_cameras" / "test_rgb_global" / "rgb").iterdir())[i])
    assert np.abs(other.astype(int) - got.astype(int)).mean() > 1.0


def test_camera_rate_and_samples_change_the_output(tbm_20k, files, tmp_path):
    """--camera-rate-hz decimates (6 frames at the camera's 20 Hz, 2 at 5 Hz);
    --camera-samples 4 changes the pixels on edges (anti-aliasing)."""
    traj_path = _trajectory(tmp_path / "t.txt", speed=2.0)
    kw = dict(sensor=files["sensor"], trajectory=traj_path, duration_s=0.3,
              cameras=[files["color"]], camera_noise=False)
    a = drive_to_file(tbm_20k, tmp_path / "a.laz", **kw)
    b = drive_to_file(tbm_20k, tmp_path / "b.laz", camera_rate_hz=5.0, **kw)
    c = drive_to_file(tbm_20k, tmp_path / "c.laz", camera_samples=4, **kw)
    assert (a.cameras[0].frames, b.cameras[0].frames) == (6, 2)
    assert c.cameras[0].rays == 4 * a.cameras[0].rays
    pa = _png(sorted((tmp_path / "a_cameras" / "test_rgb" / "rgb").iterdir())[0])
    pc = _png(sorted((tmp_path / "c_cameras" / "test_rgb" / "rgb").iterdir())[0])
    assert not np.array_equal(pa, pc)
    # The default mount: 0.1 m below the lidar (at the trajectory's frame here).
    info = json.loads((tmp_path / "a_cameras" / "test_rgb" / "camera_info.json").read_text())
    np.testing.assert_allclose(np.asarray(info["base_from_optical"])[:3, 3], [0, 0, -0.1])
    np.testing.assert_allclose(np.asarray(info["base_from_optical"])[:3, :3],
                               LINK_FROM_OPTICAL, atol=1e-15)


def test_a_bag_without_cameras_is_unchanged(tbm_20k, files, tmp_path):
    """No --camera: the bag holds no camera topic and the same messages as before the
    cameras existed (the clouds, poses and IMU of the drive)."""
    traj_path = _trajectory(tmp_path / "t.txt", speed=2.0)
    drive_to_file(tbm_20k, tmp_path / "n.mcap", sensor=files["sensor"],
                  trajectory=traj_path, duration_s=0.3)
    with AnyReader([tmp_path / "n.mcap"]) as r:
        topics = {c.topic for c in r.connections}
    assert not any("camera" in t for t in topics) and "/imu/data_raw" in topics


def test_depth_camera_is_not_supersampled(tbm_20k, files, tmp_path):
    """With a colour and a depth camera, --camera-samples changes the colour frames
    only; a depth camera alone refuses it."""
    traj_path = _trajectory(tmp_path / "t.txt", speed=2.0)
    from sensors.errors import SimulationError

    kw = dict(sensor=files["sensor"], trajectory=traj_path, duration_s=0.3,
              cameras=[files["color"], files["depth"]], camera_noise=False,
              camera_rate_hz=5.0)
    drive_to_file(tbm_20k, tmp_path / "a.laz", **kw)
    drive_to_file(tbm_20k, tmp_path / "b.laz", camera_samples=9, **kw)

    def pngs(stem, cam, sub):
        return [p.read_bytes() for p in
                sorted((tmp_path / f"{stem}_cameras" / cam / sub).iterdir())]
    assert pngs("a", "test_depth", "depth") == pngs("b", "test_depth", "depth")
    assert pngs("a", "test_rgb", "rgb") != pngs("b", "test_rgb", "rgb")

    with pytest.raises(SimulationError, match="--camera-samples 1 for the depth camera"):
        drive_to_file(tbm_20k, tmp_path / "x.laz", sensor=files["sensor"],
                      trajectory=traj_path, duration_s=0.3, cameras=[files["depth"]],
                      camera_samples=4)
    assert not list(tmp_path.glob("x*"))



#: What one camera frame costs on the ``frame_clock`` (s): far above all the rest of a
#: drive there (microseconds), so a frame counted in the lidar's time cannot hide.
FRAME_S = 10.0


@pytest.fixture()
def frame_clock(monkeypatch):
    """``time.perf_counter`` (which the run's clock and the workflow's both read) as a
    clock that ticks 1 µs a reading and FRAME_S more for each frame a camera renders:
    the cameras' true time is then known (frames x FRAME_S), and the lidar's is the
    microseconds left. Drives are simulated in chunks of 50 pulses, so that a bag's
    frames are fed between the lidar's chunks, as on a long drive. Returns the runs
    simulated."""
    import time

    import sensors
    from sensors.camera_drive import DriveCamera

    now = [0.0]

    def clock():
        now[0] += 1e-6
        return now[0]

    render = DriveCamera.render

    def costly_render(self, i):
        now[0] += FRAME_S
        return render(self, i)

    runs = []
    simulate_drive = sensors.simulate_drive

    def in_small_chunks(*args, **kwargs):
        runs.append(simulate_drive(*args, chunk_pulses=50, **kwargs))
        return runs[-1]

    monkeypatch.setattr(time, "perf_counter", clock)
    monkeypatch.setattr(DriveCamera, "render", costly_render)
    monkeypatch.setattr(sensors, "simulate_drive", in_small_chunks)
    return runs


@pytest.mark.parametrize("out", ["d.mcap", "d.laz"])
def test_camera_time_is_not_the_lidars(tbm_20k, files, tmp_path, frame_clock, out):
    """The drive's summary counted the frames rendered among the points (a bag) in the
    lidar's time and rate. On the frame clock: each camera's seconds are its frames x
    FRAME_S; the lidar's are the run's clock less the frames it counted, below one
    frame's; its rate is its rays over its own seconds. In a bag the run's clock did
    count frames (the case the split repairs): lidar + those frames = the run's clock."""
    traj_path = _trajectory(tmp_path / "t.txt", speed=2.0)
    res = drive_to_file(tbm_20k, tmp_path / out, sensor=files["sensor"],
                        trajectory=traj_path, duration_s=0.3,
                        cameras=[files["color"], files["depth"]], camera_rate_hz=10.0)
    (run,) = frame_clock
    assert [c.name for c in res.cameras] == ["test_rgb", "test_depth"]
    for c in res.cameras:
        assert c.frames >= 2
        assert c.seconds == pytest.approx(c.frames * FRAME_S, abs=0.01)
    o = res.output
    assert 0 < o.seconds < 0.01 * FRAME_S
    assert o.rays_per_s == pytest.approx(o.pulses * run.settings.beam_subrays / o.seconds,
                                         rel=1e-9)
    counted = run.stats["seconds"] - o.seconds
    if out == "d.mcap":
        frames = round(counted / FRAME_S)
        assert 1 <= frames <= sum(c.frames for c in res.cameras)
        assert counted == pytest.approx(frames * FRAME_S, abs=0.01)
    else:                       # the frames are rendered into folders after the points
        assert counted == 0.0


def test_without_a_camera_the_lidar_keeps_the_runs_time(tbm_20k, files, tmp_path,
                                                         frame_clock):
    """No camera: the bag's lidar time and rate are the run's own, as before."""
    traj_path = _trajectory(tmp_path / "t.txt", speed=2.0)
    res = drive_to_file(tbm_20k, tmp_path / "n.mcap", sensor=files["sensor"],
                        trajectory=traj_path, duration_s=0.3)
    (run,) = frame_clock
    assert res.cameras == ()
    assert (res.output.seconds, res.output.rays_per_s) == \
        (run.stats["seconds"], run.stats["rays_per_s"])


def test_the_command_prints_each_cameras_time_apart(tbm_20k, files, tmp_path, capsys,
                                                    frame_clock):
    """``tunnelsim drive -o d.mcap --camera ...``: the lidar's line gives its own time
    (0.0 s on the frame clock, not the frames' tens of seconds) and each camera's line
    its frames' time (3 frames x FRAME_S = 30.0 s)."""
    traj_path = _trajectory(tmp_path / "t.txt", speed=2.0)
    assert main(["drive", "--mesh", str(tbm_20k), "--sensor", str(files["sensor"]),
                 "--trajectory", str(traj_path), "--duration", "0.3", "--camera",
                 str(files["color"]), "--camera-rate-hz", "10", "-o",
                 str(tmp_path / "d.mcap")]) == 0
    printed = capsys.readouterr().out.splitlines()
    (lidar,) = [ln for ln in printed if ln.startswith("test_two_beams drive 0.3 s: ")]
    assert "), 0.0 s, " in lidar
    (camera,) = [ln for ln in printed if ln.startswith("camera test_rgb: ")]
    assert camera.startswith("camera test_rgb: 3 frames of 64x48 at 10 Hz")
    assert camera.endswith("-> /camera/color/image_raw and /camera/color/camera_info "
                           "(rendered and written in 30.0 s)")


def test_auto_exposure_frames_state_their_time_and_gain(tbm_20k, files, tmp_path):
    """A colour camera with auto-exposure along a drive: frames.csv gives each frame's
    exposure time and gain, and the noiseless PNG of frame 0 is the frame exposed with
    exactly those (its luminance re-rendered here row by row); the camera without
    auto-exposure states its fixed 5 ms at gain 1 and writes another image."""
    ae = tmp_path / "color_ae.toml"
    ae.write_text(COLOR.replace("bit_depth = 8\n", "bit_depth = 8\nauto_exposure = true\n"
                                "gain_max = 64.0\n").replace('"test_rgb"', '"test_ae"'))
    traj_path = _trajectory(tmp_path / "t.txt", speed=2.0)
    kw = dict(sensor=files["sensor"], trajectory=traj_path, duration_s=0.2,
              camera_rate_hz=10.0, camera_mount=MOUNT, camera_noise=False)
    drive_to_file(tbm_20k, tmp_path / "a.laz", cameras=[ae], **kw)
    drive_to_file(tbm_20k, tmp_path / "f.laz", cameras=[files["color"]], **kw)

    def rows(folder):
        with open(folder / "frames.csv", newline="") as fh:
            return list(csv.DictReader(fh))

    a_dir, f_dir = tmp_path / "a_cameras" / "test_ae", tmp_path / "f_cameras" / "test_rgb"
    fixed = rows(f_dir)
    assert all((float(r["exposure_s"]), float(r["gain"])) == (0.005, 1.0) for r in fixed)
    got = rows(a_dir)
    assert len(got) == len(fixed) == 2
    cam = load_camera(ae)
    assert json.loads((a_dir / "camera_info.json").read_text())["auto_exposure"] is True
    scene, look = _scene_and_look(tbm_20k)
    t0 = _expected_starts(cam, 0.2, 10.0)[0]
    T = _row_poses(Trajectory.read(traj_path), t0 + np.arange(cam.height) * cam.line_time_s)
    lamp = headlamp(T[0], 1000.0)
    lum = np.empty((cam.height, cam.width, 3))
    for r in range(cam.height):
        fr = render_depth(scene, cam, T[r])
        lum[r] = luminance(scene, fr, [lamp], np.nan_to_num(look.at(fr).albedo, nan=0.0))[r]
    t_exp, gain = auto_exposure(cam, lum)
    assert float(got[0]["exposure_s"]) == pytest.approx(t_exp, rel=1e-8)
    assert float(got[0]["gain"]) == pytest.approx(gain, rel=1e-5)
    want = rgb8(expose(cam, lum, noise=False, exposure_s=t_exp, gain=gain) / 255.0)
    png = _png(sorted((a_dir / "rgb").iterdir())[0])
    np.testing.assert_array_equal(png, want)
    assert not np.array_equal(png, _png(sorted((f_dir / "rgb").iterdir())[0]))
