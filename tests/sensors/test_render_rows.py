"""``render_depth``'s pixel offset (anti-aliasing) and per-row poses (rolling shutter).

References: the pixel-centre frame built here from ``pixel_rays`` and one
``Scene.cast`` (what ``render_depth`` did before it took offsets and rows); a camera
whose principal point is moved by the opposite offset (the pinhole's
u = fx x + cx makes the two the same rays); rows rendered one at a time, each as a
whole frame from its own pose, for the rolling-shutter frame.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors.camera import load_camera, pixel_rays
from sensors.errors import SimulationError
from sensors.render import Frame, camera_pose, render_depth

_V, _F = tunnel_tube(3_000, length_m=20.0, roughness_m=0.02, seed=3)
_SCENE = Scene(_V, _F)


def _cam(**kw):
    """A small pinhole camera, no distortion (64 x 48)."""
    base = replace(load_camera("realsense_d435_color"), width=64, height=48, fx=40.0,
                   fy=40.0, cx=31.5, cy=23.5, distortion=np.zeros(5))
    return replace(base, **kw)


_FIELDS = ("hit", "valid", "range_m", "depth_z_m", "triangle", "normal", "points",
           "bary_u", "bary_v")


def _world_dirs(cam, T):
    """The camera's pixel rays (n, 3) and their world directions turned by the pose's
    rotation in ``render_depth``'s arithmetic order (no BLAS reordering)."""
    d = pixel_rays(cam).reshape(-1, 3)
    R = T[:3, :3]
    return d, np.stack([R[k, 0] * d[:, 0] + R[k, 1] * d[:, 1] + R[k, 2] * d[:, 2]
                        for k in range(3)], 1)


def _assert_frames_equal(a, b, rows=slice(None)):
    for name in _FIELDS:
        np.testing.assert_array_equal(getattr(a, name)[rows], getattr(b, name)[rows],
                                      err_msg=name)


def test_zero_offset_is_the_pixel_centre_frame_bit_for_bit():
    """Offset (0, 0) and the default give the frame of one ray per pixel centre, cast
    here directly: the same t, triangle, barycentrics bit for bit."""
    cam = _cam(distortion=np.array([-0.1, 0.02, 1e-3, -5e-4, 0.0]))
    T = camera_pose([4.0, 0.2, 1.3], np.radians(10.0), np.radians(-5.0), np.radians(2.0))
    fr = render_depth(_SCENE, cam, T, pixel_offset=(0.0, 0.0))
    _assert_frames_equal(fr, render_depth(_SCENE, cam, T))
    d, dirs = _world_dirs(cam, T)
    ref = _SCENE.cast(T[:3, 3], dirs)
    hit = ref.triangle >= 0
    np.testing.assert_array_equal(fr.hit.ravel(), hit)
    np.testing.assert_array_equal(fr.range_m.ravel()[hit], ref.t[hit])
    np.testing.assert_array_equal(fr.triangle.ravel(), np.where(hit, ref.triangle, -1))
    np.testing.assert_array_equal(fr.depth_z_m.ravel()[hit], ref.t[hit] * d[hit, 2])
    np.testing.assert_array_equal(fr.bary_u.ravel()[hit], ref.u[hit])
    assert fr.row_poses is None
    np.testing.assert_array_equal(fr.world_from_camera, T)


@settings(max_examples=15, deadline=None)
@given(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5))
def test_offset_equals_a_shifted_principal_point(dx, dy):
    """A ray through (u + dx, v + dy) of K is the ray through (u, v) of K with
    cx - dx, cy - dy (pinhole, no distortion): the frames agree to 1e-12."""
    cam = _cam()
    T = camera_pose([3.0, -0.3, 1.1], np.radians(-15.0), np.radians(4.0))
    a = render_depth(_SCENE, cam, T, pixel_offset=(dx, dy))
    b = render_depth(_SCENE, replace(cam, cx=cam.cx - dx, cy=cam.cy - dy), T)
    np.testing.assert_allclose(a.rays_cam, b.rays_cam, rtol=0, atol=1e-12)
    # A ray that grazes a triangle edge may pick the neighbour: compare where both
    # frames hit the same face (all but a handful of pixels).
    same = a.hit & b.hit & (a.triangle == b.triangle)
    assert (a.hit != b.hit).sum() <= 2 and same.sum() >= a.hit.sum() - 4
    np.testing.assert_allclose(a.depth_z_m[same], b.depth_z_m[same], rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.points[same], b.points[same], rtol=0, atol=1e-12)


def test_an_offset_moves_the_image():
    """Half a pixel to the right changes the depth of the pixels on the slanted walls
    (an option whose output does not change would be a bug)."""
    cam = _cam()
    T = camera_pose([3.0, 0.0, 1.2], np.radians(20.0))
    a = render_depth(_SCENE, cam, T)
    b = render_depth(_SCENE, cam, T, pixel_offset=(0.5, 0.0))
    both = a.hit & b.hit
    assert np.abs(a.depth_z_m - b.depth_z_m)[both].max() > 1e-3


def test_equal_row_poses_give_the_single_pose_frame_bit_for_bit():
    cam = _cam()
    T = camera_pose([5.0, 0.1, 1.2], np.radians(170.0), np.radians(3.0), np.radians(-1.0))
    one = render_depth(_SCENE, cam, T)
    rows = render_depth(_SCENE, cam, np.broadcast_to(T, (cam.height, 4, 4)))
    _assert_frames_equal(one, rows)
    np.testing.assert_array_equal(rows.world_from_camera, T)
    assert rows.row_poses is not None and rows.row_poses.shape == (cam.height, 4, 4)


def _moving_poses(h: int, speed_m_per_row: float, yaw_rad_per_row: float):
    return np.stack([camera_pose([2.0 + speed_m_per_row * r, 0.1, 1.2],
                                 np.radians(5.0) + yaw_rad_per_row * r) for r in range(h)])


@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.25, -0.25)])
def test_rolling_shutter_frame_equals_rows_rendered_one_by_one(offset):
    """Each row of a frame with per-row poses is that row of the frame rendered whole
    from the row's own pose (moving and turning camera), bit for bit."""
    cam = _cam()
    poses = _moving_poses(cam.height, 0.05, 0.01)
    rs = render_depth(_SCENE, cam, poses, pixel_offset=offset)
    for r in range(cam.height):
        ref = render_depth(_SCENE, cam, poses[r], pixel_offset=offset)
        _assert_frames_equal(rs, ref, rows=r)
    np.testing.assert_array_equal(rs.world_from_camera, poses[0])
    np.testing.assert_array_equal(rs.row_poses, poses)
    # And the motion shows: the frame differs from the global-shutter one at row 0's pose.
    glob = render_depth(_SCENE, cam, poses[0], pixel_offset=offset)
    assert np.nanmax(np.abs(rs.depth_z_m - glob.depth_z_m)) > 0.1


@pytest.mark.parametrize("pose, match", [
    (np.eye(4)[:3], r"4x4 matrix or one per image row \(48, 4, 4\), got shape \(3, 4\)"),
    (np.broadcast_to(np.eye(4), (47, 4, 4)), r"got shape \(47, 4, 4\)"),
    (np.diag([1.0, 1.0, -1.0, 1.0]), "proper rotation"),
])
def test_bad_poses_are_refused(pose, match):
    with pytest.raises(SimulationError, match=match):
        render_depth(_SCENE, _cam(), pose)


@pytest.mark.parametrize("offset", [(0.5,), (0.0, float("nan")), (1.0, 2.0, 3.0)])
def test_bad_offsets_are_refused(offset):
    with pytest.raises(SimulationError, match=r"Expected pixel_offset as 2 finite numbers"):
        render_depth(_SCENE, _cam(), np.eye(4), pixel_offset=offset)


def test_surface_fields_computed_on_first_use_equal_the_cast_and_frames_are_read_only():
    """A depth frame's normal, points and barycentrics are made on first use (a depth
    camera reads none of them): they equal the cast's own, the normal turned towards
    the camera, the point o + t d; 0 / NaN on a miss. A frame made by hand without them
    says so, and no field can be reassigned."""
    cam = _cam()
    T = camera_pose([3.0, -0.4, 1.2], np.radians(-20.0), np.radians(8.0))
    fr = render_depth(_SCENE, cam, T)
    _d, dirs = _world_dirs(cam, T)
    ref = _SCENE.cast(T[:3, 3], dirs)
    hit = ref.triangle >= 0
    assert 0 < hit.sum() < hit.size          # rays out of the tube's open ends miss
    n_ref = ref.normals * np.where(np.einsum("ij,ij->i", ref.normals, dirs) > 0,
                                   -1.0, 1.0)[:, None]
    np.testing.assert_array_equal(fr.normal.reshape(-1, 3)[hit], n_ref[hit])
    np.testing.assert_array_equal(fr.normal.reshape(-1, 3)[~hit], 0.0)
    # o + t d along the unit direction as cast (t is measured along it).
    np.testing.assert_array_equal(fr.points.reshape(-1, 3)[hit],
                                  T[:3, 3] + ref.directions[hit] * ref.t[hit, None])
    assert np.isnan(fr.points.reshape(-1, 3)[~hit]).all()
    np.testing.assert_array_equal(fr.bary_v.ravel()[hit], ref.v[hit])
    np.testing.assert_array_equal(fr.bary_u.ravel()[~hit], 0.0)
    assert fr.normal is fr.normal                      # computed once, kept
    bare = Frame(fr.hit, fr.valid, fr.range_m, fr.depth_z_m, fr.triangle, None, None,
                 fr.rays_cam, T, None, None)
    np.testing.assert_array_equal(bare.depth_z_m, fr.depth_z_m)
    with pytest.raises(AttributeError, match="made without them; pass all four"):
        bare.points
    with pytest.raises(AttributeError, match="read-only"):
        fr.depth_z_m = fr.range_m
