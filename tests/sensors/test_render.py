"""Depth frames (issue 35) equal Open3D's pinhole ray casting (Embree) on the same mesh
and K: to 1e-4 m on every pixel both hit, the same pixels hit.

Open3D's ``create_rays_pinhole`` puts pixel (u, v)'s ray through (u + 0.5, v + 0.5) of
its K (pixel corners at integers); OpenCV, ROS ``camera_info`` and tunnelsim put pixel
centres at integers. The same rays therefore come from Open3D's K with cx + 0.5 and
cy + 0.5; its direction has z = 1 in the camera frame, so its ``t_hit`` is z-depth.

The floor of the comparison is Open3D's float32 (rays, vertices and Embree's
arithmetic): a ray grazing the wall (cos incidence 0.003-0.03) 20-35 m away moves by
up to 0.8 mm when its direction is rounded to float32 (measured: 40 of 0.92 M pixels
of the D435 frame). Every pixel is within 1e-4 m or within that float32 bound,
8 * 2**-24 * range / cos(incidence); the bound is what a pixel needs beyond 1e-4 m.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors.camera import load_camera, project
from sensors.errors import SimulationError
from sensors.render import camera_pose, render_depth

o3d = pytest.importorskip("open3d", reason="Open3D is the depth reference (test extra)")


def _open3d_depth(v, f, cam, T):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)),
                        o3d.core.Tensor(f.astype(np.uint32)))
    K = cam.K.copy()
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        o3d.core.Tensor(K), o3d.core.Tensor(np.linalg.inv(T)), cam.width, cam.height)
    t = scene.cast_rays(rays)["t_hit"].numpy().astype(np.float64)
    return np.where(np.isfinite(t), t, np.nan)


@pytest.mark.parametrize("name", ["realsense_d435_depth", "lwir_640"])
def test_depth_equals_open3d(name):
    v, f = tunnel_tube(20_000, length_m=40.0, roughness_m=0.01, seed=4)
    cam = load_camera(name)
    if cam.depth_range_m is not None:   # compare geometry, not the device's range gate
        cam = replace(cam, depth_range_m=None)
    T = camera_pose([5.0, 0.3, 1.4], np.radians(12.0), np.radians(-8.0), np.radians(3.0))
    ours = render_depth(Scene(v, f), cam, T)
    ref = _open3d_depth(v, f, cam, T)
    both = ours.hit & np.isfinite(ref)
    # Same pixels hit (a grazing ray at a silhouette may differ in float32: none here).
    np.testing.assert_array_equal(ours.hit, np.isfinite(ref))
    d = np.abs(ours.depth_z_m - ref)[both]
    cos_inc = np.abs(np.einsum("hwk,hwk->hw", ours.normal,
                               ours.rays_cam @ T[:3, :3].T))[both]
    float32_bound = 8 * 2.0**-24 * ours.range_m[both] / np.maximum(cos_inc, 1e-9)
    assert np.all((d <= 1e-4) | (d <= float32_bound)), d.max()
    # Beyond 1e-4 m only where the ray grazes the wall (the float32 floor), and rarely.
    assert np.all(cos_inc[d > 1e-4] < 0.05) and (d > 1e-4).mean() < 1e-4


def test_hit_points_project_back_to_their_pixels():
    """Every hit point, projected by the lens model, lands on its own pixel (the ray
    through a pixel centre and the projection agree)."""
    v, f = tunnel_tube(8_000, length_m=30.0, seed=1)
    cam = replace(load_camera("realsense_d435_color"), width=320, height=180, fx=233.0,
                  fy=233.0, cx=159.5, cy=89.5,
                  distortion=np.array([-0.2, 0.05, 1e-3, -1e-3, 0.0]))
    T = camera_pose([3.0, -0.4, 1.2], np.radians(-20.0))
    fr = render_depth(Scene(v, f), cam, T)
    pts = fr.points[fr.hit]
    cam_pts = (pts - T[:3, 3]) @ T[:3, :3]
    uv = project(cam, cam_pts)
    vv, uu = np.nonzero(fr.hit)
    np.testing.assert_allclose(uv, np.stack([uu, vv], 1), atol=1e-6)


@settings(max_examples=20, deadline=None)
@given(h=st.floats(-np.pi, np.pi), p=st.floats(-1.4, 1.4), r=st.floats(-np.pi, np.pi))
def test_camera_pose_is_a_proper_optical_frame(h, p, r):
    T = camera_pose([1.0, 2.0, 3.0], h, p, r)
    R = T[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    # The optical axis (z) points along heading and pitch; roll leaves it alone.
    np.testing.assert_allclose(R[:, 2], [np.cos(h) * np.cos(p), np.sin(h) * np.cos(p),
                                         np.sin(p)], atol=1e-12)


def test_a_bad_pose_is_refused():
    v, f = tunnel_tube(2_000, length_m=10.0)
    T = np.eye(4)
    T[0, 0] = 2.0
    with pytest.raises(SimulationError, match="proper rotation"):
        render_depth(Scene(v, f), load_camera("lwir_640"), T)
