"""Camera frames along a drive (``sensors.camera_drive``, issue 35).

References: the frame schedule counted by brute force (every start t0 + i / rate whose
readout ends in the drive); the poses composed here from the trajectory, the mount's
roll/pitch/yaw and REP 103's optical axes written out (z forward = x of the link,
x right = -y, y down = -z); OpenCV's ``projectPoints`` for the optical convention; the
rolling-shutter frame against rows rendered one at a time from their own poses.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors.appearance import Appearance, Attribute
from sensors.camera import load_camera
from sensors.camera_drive import (CAMERA_BELOW_LIDAR_M, DEFAULT_LAMP_CD, DriveCamera,
                                  camera_mount, default_camera_mount, drive_lamps,
                                  frame_image, frame_times, readout_s)
from sensors.errors import SimulationError
from sensors.platform_spec import load_platform
from sensors.render import render_depth
from sensors.shading import auto_exposure, expose, headlamp, luminance, platform_lamps
from sensors.trajectory import Mount, Trajectory

_V, _F = tunnel_tube(3_000, length_m=40.0, roughness_m=0.02, seed=5)
_SCENE = Scene(_V, _F)
#: The optical axes in camera_link (REP 103 body: x forward, y left, z up).
_X_RIGHT, _Y_DOWN, _Z_FWD = (0.0, -1.0, 0.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0)
_LINK_FROM_OPTICAL = np.column_stack([_X_RIGHT, _Y_DOWN, _Z_FWD])


def _cam(shutter: str = "rolling", **kw):
    base = replace(load_camera("realsense_d435_color"), width=64, height=48, fx=40.0,
                   fy=40.0, cx=31.5, cy=23.5, distortion=np.zeros(5), frame_rate_hz=20.0,
                   exposure_s=0.005, line_time_s=5e-4 if shutter == "rolling" else 0.0)
    return replace(base, **kw)


def _grey(scene_faces: int) -> Appearance:
    return Appearance(Attribute(np.full((scene_faces, 3), 0.5), "face"),
                      Attribute(np.full(scene_faces, 290.0), "face"),
                      Attribute(np.full(scene_faces, 0.95), "face"),
                      np.asarray(_F, dtype=np.int64))


def _fast_trajectory(speed: float = 20.0, yaw_rate: float = 3.0) -> Trajectory:
    """Along the tube's axis (x), 0.4 s, turning about z: a fast, turning camera."""
    t = np.linspace(0.0, 0.4, 81)
    pos = np.column_stack([5.0 + speed * t, 0.1 + 0 * t, 1.2 + 0 * t])
    return Trajectory(t, pos, Rotation.from_euler("z", (yaw_rate * (t - 0.2))[:, None]))


# ---------------------------------------------------------------------- schedule
@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(0.0, 10.0), st.sampled_from([1.0, 5.0, 15.0, 20.0]),
       st.sampled_from(["rolling", "global"]))
def test_frame_times_are_every_frame_read_out_within_the_drive(duration, start, rate,
                                                                shutter):
    cam = _cam(shutter)
    t = frame_times(cam, (start, start + duration), rate)
    brute = [start + i / rate for i in range(200)
             if start + i / rate + readout_s(cam) <= start + duration + 1e-9]
    np.testing.assert_allclose(t, brute, rtol=0, atol=1e-12)


def test_readout_is_the_rows_and_the_exposure():
    cam = _cam()
    assert readout_s(cam) == pytest.approx(47 * 5e-4 + 0.005, abs=1e-15)
    assert readout_s(_cam("global")) == 0.005


@pytest.mark.parametrize("rate", [0.0, -1.0, 20.5, float("nan")])
def test_a_rate_above_the_cameras_is_refused(rate):
    with pytest.raises(SimulationError, match=r"--camera-rate-hz in \(0, 20\]"):
        frame_times(_cam(), (0.0, 1.0), rate)


# ---------------------------------------------------------------------- poses
@pytest.mark.parametrize("shutter", ["rolling", "global"])
def test_row_poses_are_the_trajectory_at_each_rows_time(shutter):
    cam = _cam(shutter)
    traj = _fast_trajectory()
    mount = camera_mount([0.3, -0.1, 0.4, 2.0, -5.0, 10.0])
    dc = DriveCamera(_SCENE, cam, traj, mount, _grey(len(_F)), span_s=(0.0, 0.4))
    i = 3
    t_rows = dc.times[i] + np.arange(cam.height) * cam.line_time_s
    pos, rot = traj.interpolate(t_rows)
    R_link = Rotation.from_euler("xyz", [2.0, -5.0, 10.0], degrees=True).as_matrix()
    want = np.zeros((cam.height, 4, 4))
    want[:, :3, :3] = rot.as_matrix() @ R_link @ _LINK_FROM_OPTICAL
    want[:, :3, 3] = pos + rot.apply([0.3, -0.1, 0.4])
    want[:, 3, 3] = 1.0
    got = dc.poses(i)
    if shutter == "global":
        assert got.shape == (4, 4)
        np.testing.assert_allclose(got, want[0], rtol=0, atol=1e-12)
    else:
        assert got.shape == (cam.height, 4, 4)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert dc.times[i] == pytest.approx(i / 20.0, abs=1e-15)


def test_the_optical_frame_follows_rep_103():
    """A level camera_link looking along +x: a point ahead images at the principal
    point, one to the left (+y) left of it, one above (+z) above it (OpenCV's
    projectPoints of the world points through the inverse pose)."""
    cv2 = pytest.importorskip("cv2")
    cam = _cam()
    traj = Trajectory([0.0], [[0.0, 0.0, 0.0]], Rotation.identity(1))
    dc = DriveCamera(_SCENE, replace(cam, line_time_s=0.0), traj, Mount((0.0, 0.0, 0.0)),
                     _grey(len(_F)), span_s=(0.0, 0.1))
    T = dc.poses(0)
    pts = np.array([[5.0, 0.0, 0.0], [5.0, 1.0, 0.0], [5.0, 0.0, 1.0]])
    Rinv = T[:3, :3].T
    rvec, _ = cv2.Rodrigues(Rinv)
    uv, _ = cv2.projectPoints(pts, rvec, -Rinv @ T[:3, 3], cam.K, np.zeros(5))
    uv = uv.reshape(-1, 2)
    np.testing.assert_allclose(uv[0], [cam.cx, cam.cy], atol=1e-9)
    assert uv[1, 0] < cam.cx - 5 and abs(uv[1, 1] - cam.cy) < 1e-9      # left
    assert uv[2, 1] < cam.cy - 5 and abs(uv[2, 0] - cam.cx) < 1e-9      # up


def test_the_default_mount_is_below_the_lidar_looking_forward():
    m = default_camera_mount(Mount((0.2, 0.05, 0.7), Rotation.from_euler("x", 180,
                                                                          degrees=True)))
    assert m.lever_arm_m == pytest.approx((0.2, 0.05, 0.7 - CAMERA_BELOW_LIDAR_M))
    np.testing.assert_allclose(m.boresight.as_matrix(), np.eye(3), atol=1e-15)


@pytest.mark.parametrize("values", [[1.0, 2.0], [1, 2, 3, 4], [1, 2, float("inf")]])
def test_a_bad_mount_is_refused(values):
    with pytest.raises(SimulationError, match=r"Expected --camera-mount as X,Y,Z"):
        camera_mount(values)


# ---------------------------------------------------------------------- frames
def test_rolling_shutter_frame_equals_rows_rendered_one_by_one():
    """A camera at 20 m/s turning at 3 rad/s: each row of its frame is that row of a
    frame rendered whole from the row's own pose, shaded under the lamps of the frame's
    start; the global-shutter frame at the start differs."""
    cam = _cam()
    traj = _fast_trajectory()
    app = _grey(len(_F))
    dc = DriveCamera(_SCENE, cam, traj, Mount((0.0, 0.0, 0.0)), app, span_s=(0.0, 0.4),
                     noise=False)
    i = 2
    got = dc.render(i)
    t_rows = dc.times[i] + np.arange(cam.height) * cam.line_time_s
    pos, rot = traj.interpolate(t_rows)
    lamp = None
    ref_depth = np.empty((cam.height, cam.width))
    ref_lum = np.empty((cam.height, cam.width, 3))
    for r in range(cam.height):
        T = np.eye(4)
        T[:3, :3] = rot[r].as_matrix() @ _LINK_FROM_OPTICAL
        T[:3, 3] = pos[r]
        if lamp is None:
            lamp = headlamp(T, DEFAULT_LAMP_CD)        # the frame's start
        fr = render_depth(_SCENE, cam, T)
        ref_depth[r] = fr.depth_z_m[r]
        ref_lum[r] = luminance(_SCENE, fr, [lamp], np.full(3, 0.5))[r]
    np.testing.assert_allclose(got.frame.depth_z_m, ref_depth, rtol=0, atol=1e-9)
    # Auto-exposure (the D435's) metered on the whole frame's light, as taken.
    t_exp, gain = auto_exposure(cam, ref_lum)
    assert (got.exposure_s, got.gain) == (t_exp, gain) and gain > 1.0
    ref_rgb = expose(cam, ref_lum, noise=False, exposure_s=t_exp, gain=gain) / 255.0
    np.testing.assert_allclose(got.rgb_linear, ref_rgb, rtol=1e-12, atol=1e-15)
    assert got.stamp_s == dc.times[i] and got.readout_end_s == dc.times[i] + readout_s(cam)
    # The global shutter sees another image.
    glob = DriveCamera(_SCENE, _cam("global"), traj, Mount((0.0, 0.0, 0.0)), app,
                       span_s=(0.0, 0.4), noise=False).render(i)
    both = np.isfinite(glob.frame.depth_z_m) & np.isfinite(got.frame.depth_z_m)
    assert np.abs(glob.frame.depth_z_m - got.frame.depth_z_m)[both].max() > 0.2


def test_frames_have_their_own_noise_and_reproduce():
    cam = _cam("global")
    traj = Trajectory([0.0, 1.0], [[5.0, 0.0, 1.2], [6.0, 0.0, 1.2]], Rotation.identity(2))
    mk = lambda seed: DriveCamera(_SCENE, cam, traj, Mount((0.0, 0.0, 0.0)),  # noqa: E731
                                  _grey(len(_F)), span_s=(0.0, 1.0), seed=seed)
    a, b = mk(1), mk(1)
    np.testing.assert_array_equal(a.render(0).rgb_linear, b.render(0).rgb_linear)
    assert not np.array_equal(a.render(0).rgb_linear, mk(2).render(0).rgb_linear)
    # Noise on: frame 0 and frame 1 differ beyond their (tiny) motion's change.
    quiet = DriveCamera(_SCENE, cam, traj, Mount((0.0, 0.0, 0.0)), _grey(len(_F)),
                        span_s=(0.0, 1.0), noise=False)
    assert not np.array_equal(a.render(0).rgb_linear, quiet.render(0).rgb_linear)


def test_depth_and_thermal_frames():
    T = np.eye(4)
    T[:3, :3] = _LINK_FROM_OPTICAL
    T[:3, 3] = [5.0, 0.0, 1.2]
    app = _grey(len(_F))
    depth_cam = replace(load_camera("realsense_d435_depth"), width=32, height=24, fx=20.0,
                        fy=20.0, cx=15.5, cy=11.5)
    fr, rgb, th, t_exp, gain = frame_image(_SCENE, depth_cam, T, app, [])
    assert rgb is None and th is None and (t_exp, gain) == (depth_cam.exposure_s, 1.0)
    np.testing.assert_array_equal(fr.depth_z_m, render_depth(_SCENE, depth_cam, T).depth_z_m)
    lwir = replace(load_camera("lwir_640"), width=32, height=24, fx=20.0, fy=20.0,
                   cx=15.5, cy=11.5)
    fr, rgb, th, _, _ = frame_image(_SCENE, lwir, T, app, [], noise=False, ambient_k=290.0)
    assert rgb is None
    # Walls at 290 K reflecting 290 K surroundings read 290 K (to the table's 1e-6 K).
    np.testing.assert_allclose(th[fr.hit], 290.0, atol=1e-5)


# ---------------------------------------------------------------------- lamps
def test_drive_lamps_follow_renders_rule():
    robot = load_platform("ground_robot")
    assert robot.lamps, "the ground robot ships with headlights (issue 35)"
    base = np.eye(4)
    base[:3, 3] = [3.0, 0.2, 0.0]
    cam_T = np.eye(4)
    cam_T[:3, 3] = [3.1, 0.2, 0.4]
    fn, said = drive_lamps(robot)            # the platform's lamps alone
    want = platform_lamps(robot, base)
    got = fn(base, cam_T)
    assert len(got) == len(want) and "lamps of the ground_robot" in said
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g.position, w.position)
    fn, said = drive_lamps(robot, 500.0)     # and a headlamp
    got = fn(base, cam_T)
    assert len(got) == len(want) + 1 and got[0].intensity_cd == 500.0
    np.testing.assert_array_equal(got[0].position, headlamp(cam_T, 500.0).position)
    fn, said = drive_lamps(None)             # no platform: the default headlamp
    assert [x.intensity_cd for x in fn(base, cam_T)] == [DEFAULT_LAMP_CD]
    assert drive_lamps(None, 0.0)[0](base, cam_T) == []
    with pytest.raises(SimulationError, match="--lamp-cd"):
        drive_lamps(None, -1.0)


def test_supersampling_for_colour_and_thermal_not_depth():
    """A thermal camera averages its band radiance over the samples
    (``sensors.shading.thermal_frame``, the reference here): on the tube's edges the
    4-sample frame differs from the 1-sample one; a depth camera refuses samples."""
    from sensors.shading import thermal_frame

    lwir = replace(load_camera("lwir_640"), width=16, height=12, fx=10.0, fy=10.0,
                   cx=7.5, cy=5.5)
    traj = Trajectory([0.0], [[5.0, 0.0, 1.2]], Rotation.identity(1))
    # A face temperature that varies: the samples see several.
    temps = 280.0 + 20.0 * (np.arange(len(_F)) % 7)
    app = Appearance(Attribute(np.full((len(_F), 3), 0.5), "face"),
                     Attribute(temps, "face"), Attribute(np.full(len(_F), 0.95), "face"),
                     np.asarray(_F, dtype=np.int64))
    four = DriveCamera(_SCENE, lwir, traj, Mount(), app, span_s=(0.0, 1.0), noise=False,
                       samples_per_pixel=4, ambient_k=290.0).render(0)
    one = DriveCamera(_SCENE, lwir, traj, Mount(), app, span_s=(0.0, 1.0), noise=False,
                      ambient_k=290.0).render(0)
    T = DriveCamera(_SCENE, lwir, traj, Mount(), app, span_s=(0.0, 1.0)).poses(0)
    _fr, ref = thermal_frame(_SCENE, lwir, T, app, 290.0, 4, noise=False)
    np.testing.assert_array_equal(four.thermal_k, ref)
    assert np.nanmax(np.abs(four.thermal_k - one.thermal_k)) > 1.0
    depth = replace(load_camera("realsense_d435_depth"), width=8, height=6)
    with pytest.raises(SimulationError, match="--camera-samples 1 for the depth camera"):
        DriveCamera(_SCENE, depth, traj, Mount(), app, span_s=(0.0, 1.0),
                    samples_per_pixel=4)
