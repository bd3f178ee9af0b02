"""Camera models (issue 35): the shipped files load, the lens models equal OpenCV's
``projectPoints`` / ``fisheye.projectPoints`` (opencv-python-headless, a test
reference), unprojection inverts projection, and bad files are refused by key."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensors.camera import (CAMERA_DIR, list_cameras, load_camera, pixel_rays, project,
                            unproject)
from sensors.errors import CameraSpecError

cv2 = pytest.importorskip("cv2", reason="OpenCV (opencv-python-headless) is the "
                                        "projection reference; it is in the test extra")

#: Distortions of real calibrations (OpenCV's sample values' order of magnitude).
PINHOLE_D = np.array([-0.28, 0.07, 1e-3, -5e-4, -0.01])
FISHEYE_D = np.array([0.02, -0.005, 0.001, -0.0002])


def _camera(model: str, dist) -> object:
    cam = load_camera("realsense_d435_color")
    return replace(cam, model=model, distortion=np.asarray(dist, dtype=np.float64),
                   fy=cam.fx * 1.01, cx=cam.cx + 3.2, cy=cam.cy - 2.1)


def _points(n: int, seed: int, half_angle_rad: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0, half_angle_rad, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(0.3, 40.0, n)
    return np.stack([r * np.sin(theta) * np.cos(phi), r * np.sin(theta) * np.sin(phi),
                     r * np.cos(theta)], 1)


def test_the_shipped_cameras_load():
    names = list_cameras()
    assert {"realsense_d435_depth", "realsense_d435_color", "lwir_640"} <= set(names)
    depth = load_camera("realsense_d435_depth")
    assert (depth.kind, depth.width, depth.height) == ("depth", 1280, 720)
    # fx from the datasheet's 87 deg horizontal field of view (square pixels).
    assert depth.fx == pytest.approx(640 / np.tan(np.radians(43.5)))
    assert depth.global_shutter and not load_camera("realsense_d435_color").global_shutter


def test_pinhole_equals_opencv():
    cam = _camera("pinhole", PINHOLE_D)
    p = _points(5000, 1, np.radians(40))
    ref, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), cam.K, cam.distortion)
    np.testing.assert_allclose(project(cam, p), ref.reshape(-1, 2), rtol=0, atol=1e-6)


def test_fisheye_equals_opencv():
    cam = _camera("fisheye", FISHEYE_D)
    p = _points(5000, 2, np.radians(85))
    ref, _ = cv2.fisheye.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                       cam.K, cam.distortion)
    np.testing.assert_allclose(project(cam, p), ref.reshape(-1, 2), rtol=0, atol=1e-6)


@pytest.mark.parametrize("model, dist", [("pinhole", PINHOLE_D), ("fisheye", FISHEYE_D)])
def test_unprojection_matches_opencv_undistort(model, dist):
    """Our pixel -> ray equals OpenCV's undistortPoints (pinhole, fisheye) on the
    normalised coordinates, where OpenCV's iteration converges."""
    cam = _camera(model, dist)
    rng = np.random.default_rng(3)
    uv = np.stack([rng.uniform(200, 1700, 2000), rng.uniform(150, 930, 2000)], 1)
    ray = unproject(cam, uv)
    if model == "pinhole":
        ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.distortion,
                                  criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                                            200, 1e-14))
    else:
        ref = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.distortion,
                                          criteria=(cv2.TERM_CRITERIA_COUNT |
                                                    cv2.TERM_CRITERIA_EPS, 200, 1e-14))
    np.testing.assert_allclose(ray[:, :2] / ray[:, 2:], ref.reshape(-1, 2), atol=1e-7)


@settings(max_examples=40, deadline=None)
@given(model=st.sampled_from(["pinhole", "fisheye"]), seed=st.integers(0, 2**31 - 1),
       scale=st.floats(0.0, 1.0))
def test_unproject_inverts_project(model, seed, scale):
    """project(unproject(uv)) == uv and unproject(project(p)) is p's direction, for
    distortions scaled from none to the calibration's."""
    cam = _camera(model, (PINHOLE_D if model == "pinhole" else FISHEYE_D) * scale)
    p = _points(300, seed, np.radians(35 if model == "pinhole" else 80))
    uv = project(cam, p)
    ray = unproject(cam, uv)
    np.testing.assert_allclose(ray, p / np.linalg.norm(p, axis=1, keepdims=True),
                               atol=1e-9)
    np.testing.assert_allclose(project(cam, ray), uv, atol=1e-6)


def test_pixel_rays_are_unit_and_centred():
    cam = load_camera("realsense_d435_depth")
    rays = pixel_rays(cam)
    assert rays.shape == (720, 1280, 3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=2), 1.0, atol=1e-12)
    # The four centre pixels straddle the optical axis symmetrically.
    c = rays[359:361, 639:641].reshape(-1, 3)
    np.testing.assert_allclose(c[:, 0].sum(), 0, atol=1e-12)
    # The left and right edges' pixel centres sit half a pixel inside the 87 deg field.
    half = np.degrees(np.arctan2(-rays[360, 0, 0], rays[360, 0, 2]))
    assert 43.4 < half < 43.5


def test_points_behind_a_pinhole_do_not_project():
    cam = load_camera("realsense_d435_depth")
    assert np.isnan(project(cam, [[0.1, 0.0, -1.0]])).all()


@pytest.mark.parametrize("old, new, match", [
    ("hfov_deg = 87.0", "hfov_dg = 87.0", r"unknown key `hfov_dg` \(did you mean `hfov_deg`"),
    ('kind = "depth"', 'kind = "lidar"', r"`device.kind` .* one of"),
    ('model = "pinhole"', 'model = "orthographic"', r"`lens.model` .* one of"),
    ("distortion = [0.0, 0.0, 0.0, 0.0, 0.0]", "distortion = [0.0, 0.0]",
     r"`lens.distortion` .* a list of 5 finite numbers"),
    ("line_time_us = 0.0", "line_time_us = 10.0", r"`sensor.line_time_us` .* 0 for a "
                                                   "global shutter"),
    ("min_m = 0.28", "min_m = 20.0", r"`depth.max_m` > `depth.min_m`"),
    ("bit_depth = 16", "bit_depth = 16\nauto_exposure = true",
     r"`sensor.auto_exposure` .* false \(auto-exposure is for colour cameras\)"),
    ("bit_depth = 16", "bit_depth = 16\nauto_exposure = 1",
     r"`sensor.auto_exposure` .* true or false"),
    ("bit_depth = 16", "bit_depth = 16\ngain_max = 0.5", r"`sensor.gain_max` .* within \[1.0"),
])
def test_bad_camera_files_are_refused(old, new, match, tmp_path):
    text = (CAMERA_DIR / "realsense_d435_depth.toml").read_text()
    assert old in text
    path = tmp_path / "cam.toml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(CameraSpecError, match=match):
        load_camera(path)


def test_auto_exposure_keys_are_read_and_default_off():
    """The D435's colour file turns auto-exposure on (gain up to 16x); a file without
    the keys has it off at gain 1 (the depth camera's)."""
    color, depth = load_camera("realsense_d435_color"), load_camera("realsense_d435_depth")
    assert color.auto_exposure and color.gain_max == 16.0
    assert "auto_exposure" not in (CAMERA_DIR / "realsense_d435_depth.toml").read_text()
    assert not depth.auto_exposure and depth.gain_max == 1.0
