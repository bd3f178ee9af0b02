"""The files of a camera frame (issue 35) read back by independent decoders (OpenCV's
``imread``, NumPy's ``load``, ``json``) and checked against the conventions they claim:
depth.png = round(depth.npy * 1000) where it has data and 0 elsewhere (RealSense Z16),
thermal.png = round(100 * kelvin), rgb.png = IEC 61966-2-1's sRGB of the linear values,
camera_info's K and D reproduce every hit pixel through OpenCV's ``projectPoints`` /
``fisheye.projectPoints``; and the appearance on the mesh (vertex properties
interpolated with the barycentric coordinates, face labels through the table)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors.appearance import (DEFAULT_MATERIAL, MATERIALS, Attribute, mesh_appearance)
from sensors.camera import load_camera
from sensors.camera_io import write_frame
from sensors.errors import SimulationError
from sensors.io.meshes import MeshData
from sensors.render import camera_pose, render_depth
from sensors.shading import srgb_decode, srgb_encode

cv2 = pytest.importorskip("cv2", reason="OpenCV is the projection and PNG reference")


def _cam(name="realsense_d435_color", w=120, h=90, hfov_deg=70.0, model="pinhole", **kw):
    cam = load_camera(name)
    fx = (w / 2) / math.tan(math.radians(hfov_deg) / 2) if model == "pinhole" \
        else (w / 2) / math.radians(hfov_deg / 2)
    return replace(cam, width=w, height=h, fx=fx, fy=fx, cx=(w - 1) / 2, cy=(h - 1) / 2,
                   model=model, **kw)


def _srgb_reference(x):
    """IEC 61966-2-1, section 5.2 (encoding), written out independently."""
    x = np.clip(x, 0, 1)
    out = np.empty_like(x)
    lo = x <= 0.0031308
    out[lo] = 12.92 * x[lo]
    out[~lo] = 1.055 * x[~lo] ** (1 / 2.4) - 0.055
    return out


def _imread(path):
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None, path
    return img


def test_depth_png_is_rounded_millimetres_of_depth_npy_and_zero_without_data(tmp_path):
    # A 100 m tube seen along its axis: near walls, far walls beyond 65.535 m (which
    # depth.png cannot hold) and the open far portal (no data).
    v, f = tunnel_tube(6_000, length_m=100.0, seed=3)
    cam = _cam("realsense_d435_depth", w=96, h=64, hfov_deg=60.0)
    cam = replace(cam, depth_range_m=(0.3, 90.0))
    T = camera_pose([0.5, 0.0, 1.4], 0.0)
    fr = render_depth(Scene(v, f), cam, T)
    files = write_frame(tmp_path, cam, fr)
    png = _imread(files.depth_png)
    npy = np.load(files.depth_npy)
    assert png.dtype == np.uint16 and png.shape == (64, 96)
    assert npy.dtype == np.float32 and npy.shape == (64, 96)
    np.testing.assert_array_equal(np.isnan(npy), ~fr.valid)
    np.testing.assert_array_equal(npy[fr.valid], fr.depth_z_m[fr.valid].astype(np.float32))
    mm = np.round(npy.astype(np.float64) * 1000.0)
    fits = fr.valid & (mm <= 65535)
    np.testing.assert_array_equal(png[fits], mm[fits])
    assert np.all(png[~fits] == 0)
    far = fr.valid & (npy > 65.5355)
    assert far.sum() > 0 and files.depth_clipped == far.sum()
    assert (~fr.valid).sum() > 0          # the open portal: NaN and 0


@pytest.mark.parametrize("model", ["pinhole", "fisheye"])
def test_camera_info_K_D_and_pose_reproduce_every_pixel_through_opencv(tmp_path, model):
    """Hit points projected by OpenCV with camera_info.json's K, D and the inverse of
    world_from_camera land within 0.5 px of the pixel whose ray hit them (distortion
    on)."""
    v, f = tunnel_tube(8_000, length_m=30.0, seed=1)
    if model == "pinhole":
        cam = _cam(distortion=np.array([-0.21, 0.06, 1.2e-3, -0.8e-3, 0.01]))
    else:
        # 140 deg across: the corners stay in front (OpenCV's fisheye model projects
        # only points with z > 0).
        cam = _cam(hfov_deg=140.0, model="fisheye",
                   distortion=np.array([0.02, -0.01, 0.003, -0.0005]))
    T = camera_pose([3.0, -0.3, 1.3], math.radians(-15.0), math.radians(4.0),
                    math.radians(2.0))
    fr = render_depth(Scene(v, f), cam, T)
    info = json.loads(write_frame(tmp_path, cam, fr).camera_info.read_text())
    assert info["model"] == model and info["width"] == 120 and info["height"] == 90
    assert info["distortion_model"] == {"pinhole": "plumb_bob",
                                        "fisheye": "equidistant"}[model]
    K, D = np.array(info["K"]), np.array(info["D"])
    W = np.array(info["world_from_camera"])
    cam_from_world = np.linalg.inv(W)
    rvec, _ = cv2.Rodrigues(cam_from_world[:3, :3])
    tvec = cam_from_world[:3, 3]
    pts = fr.points[fr.hit]
    assert len(pts) > 3000
    if model == "pinhole":
        uv, _ = cv2.projectPoints(pts, rvec, tvec, K, D)
    else:
        uv, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), rvec, tvec, K, D)
    uv = uv.reshape(-1, 2)
    vv, uu = np.nonzero(fr.hit)
    err = np.hypot(uv[:, 0] - uu, uv[:, 1] - vv)
    assert err.max() < 0.5, err.max()


def test_rgb_png_is_the_srgb_encoding_of_the_linear_values(tmp_path):
    cam = _cam(w=40, h=30)
    fr = render_depth(Scene(*tunnel_tube(2_000, length_m=20.0)), cam,
                      camera_pose([2.0, 0.0, 1.4], 0.0))
    lin = np.random.default_rng(5).uniform(0, 1, (30, 40, 3)) ** 3   # dark values too
    files = write_frame(tmp_path, cam, fr, rgb_linear=lin)
    bgr = _imread(files.rgb)
    assert bgr.dtype == np.uint8 and bgr.shape == (30, 40, 3)
    want = np.round(_srgb_reference(lin) * 255.0)
    np.testing.assert_array_equal(bgr[..., ::-1], want)
    assert files.thermal is None


def test_thermal_png_is_centikelvin_and_zero_without_data(tmp_path):
    cam = _cam("lwir_640", w=40, h=30)
    fr = render_depth(Scene(*tunnel_tube(2_000, length_m=20.0)), cam,
                      camera_pose([2.0, 0.0, 1.4], 0.0))
    t = np.random.default_rng(2).uniform(250.0, 330.0, (30, 40))
    t[0, :5] = np.nan
    files = write_frame(tmp_path, cam, fr, thermal_k=t)
    png = _imread(files.thermal)
    assert png.dtype == np.uint16
    ok = np.isfinite(t)
    np.testing.assert_array_equal(png[ok], np.round(t[ok] * 100.0))
    assert np.all(png[~ok] == 0) and files.rgb is None


def test_images_of_the_wrong_shape_are_refused(tmp_path):
    cam = _cam(w=40, h=30)
    fr = render_depth(Scene(*tunnel_tube(2_000, length_m=20.0)), cam,
                      camera_pose([2.0, 0.0, 1.4], 0.0))
    with pytest.raises(SimulationError, match=r"Expected an RGB image of shape \(30, 40, 3\)"):
        write_frame(tmp_path, cam, fr, rgb_linear=np.zeros((30, 40)))
    with pytest.raises(SimulationError, match=r"Expected a thermal image of shape"):
        write_frame(tmp_path, cam, fr, thermal_k=np.zeros((40, 30)))


@settings(max_examples=40, deadline=None)
@given(x=st.floats(0.0, 1.0))
def test_srgb_decode_inverts_encode(x):
    assert float(srgb_decode(srgb_encode(np.array([x])))[0]) == pytest.approx(x, abs=1e-12)


# ------------------------------------------------------------------ appearance
def _frame_of(v, f, cam=None):
    cam = cam or _cam(w=64, h=48)
    return render_depth(Scene(v, f), cam, camera_pose([2.0, 0.1, 1.3], 0.1, -0.05))


@settings(max_examples=15, deadline=None)
@given(a=st.tuples(*[st.floats(-5.0, 5.0)] * 3), b=st.floats(250.0, 320.0))
def test_vertex_temperatures_are_interpolated_exactly_for_a_linear_field(a, b):
    """Barycentric interpolation reproduces a linear function of position exactly: a
    vertex field T = a . p + b gives T(hit point) at every pixel."""
    v, f = tunnel_tube(2_000, length_m=20.0, seed=0)
    m = MeshData(v, f, vertex_fields={"temperature": v @ np.array(a) + b})
    fr = _frame_of(v, f)
    px = mesh_appearance(m).at(fr)
    want = fr.points[fr.hit] @ np.array(a) + b
    np.testing.assert_allclose(px.temperature_k[fr.hit], want, rtol=0, atol=1e-9)
    assert np.isnan(px.temperature_k[~fr.hit]).all()


def test_vertex_colours_are_linearised_srgb_and_override_labels():
    v, f = tunnel_tube(2_000, length_m=20.0, seed=0)
    rgb = np.random.default_rng(1).integers(0, 256, (len(v), 3)).astype(np.uint8)
    m = MeshData(v, f, vertex_fields={"red": rgb[:, 0], "green": rgb[:, 1],
                                      "blue": rgb[:, 2]},
                 face_fields={"label": np.zeros(len(f), np.uint8)})
    app = mesh_appearance(m, label_names=("cable",))
    assert app.source == {"albedo": "vertex", "temperature": "label",
                          "emissivity": "label"}
    c = rgb / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)  # IEC 61966-2-1
    np.testing.assert_allclose(app.albedo.values, lin, rtol=1e-12)
    fr = _frame_of(v, f)
    px = app.at(fr)
    assert np.all(px.temperature_k[fr.hit] == MATERIALS["cable"].temperature_k)
    assert np.all(px.emissivity[fr.hit] == MATERIALS["cable"].emissivity)


def test_labels_pick_the_table_and_unknown_labels_the_default():
    v, f = tunnel_tube(2_000, length_m=20.0, seed=0)
    lab = (np.arange(len(f)) % 3).astype(np.uint8)       # 2 is beyond the names
    m = MeshData(v, f, face_fields={"label": lab})
    app = mesh_appearance(m, label_names=("wet_floor", "no_such_material"))
    fr = _frame_of(v, f)
    px = app.at(fr)
    tri = fr.triangle[fr.hit]
    want = np.array([MATERIALS["wet_floor"].albedo_rgb, DEFAULT_MATERIAL.albedo_rgb,
                     DEFAULT_MATERIAL.albedo_rgb])[lab[tri]]
    np.testing.assert_array_equal(px.albedo[fr.hit], want)
    # Without label names the labels mean nothing: every face is the default.
    plain = mesh_appearance(m).at(fr)
    assert np.all(plain.albedo[fr.hit] == DEFAULT_MATERIAL.albedo_rgb)


def test_the_table_covers_every_label_of_the_generator():
    from survey.world.mesh import LABELS

    assert set(MATERIALS) == set(LABELS)
    for mat in MATERIALS.values():
        assert all(0 < a < 1 for a in mat.albedo_rgb) and 200 < mat.temperature_k < 350
    # Darker when wet (Lekner & Dorf 1988), cables warmer than rock.
    assert sum(MATERIALS["wet_floor"].albedo_rgb) < sum(MATERIALS["floor"].albedo_rgb)
    assert MATERIALS["cable"].temperature_k > MATERIALS["lining"].temperature_k


def test_bad_vertex_temperatures_are_refused():
    v, f = tunnel_tube(500, length_m=5.0)
    t = np.full(len(v), 290.0)
    t[7] = -3.0
    with pytest.raises(SimulationError, match="Expected vertex temperature values in "
                                              "kelvin > 0, got -3.0 at vertex 7"):
        mesh_appearance(MeshData(v, f, vertex_fields={"temperature": t}))


def test_attribute_per_face_is_constant_on_the_face():
    v, f = tunnel_tube(2_000, length_m=20.0, seed=0)
    vals = np.arange(len(f), dtype=np.float64)
    fr = _frame_of(v, f)
    got = Attribute(vals, "face").at(fr, f)
    np.testing.assert_array_equal(got[fr.hit], fr.triangle[fr.hit])


# ------------------------------------------------------------------ the frame itself
def test_frame_fields_agree_with_the_geometry_they_describe():
    """Each pixel's fields against independent arithmetic: the barycentric coordinates
    rebuild the hit point from the triangle's vertices, z is the point's coordinate
    along the optical axis and the depth gate keeps exactly lo <= z <= hi, the normal
    is the face's unit normal turned towards the camera."""
    v, f = tunnel_tube(4_000, length_m=30.0, seed=5)
    cam = replace(_cam("realsense_d435_depth", w=80, h=60), depth_range_m=(1.5, 6.0))
    T = camera_pose([4.0, 0.2, 1.2], math.radians(20.0), math.radians(-5.0))
    fr = render_depth(Scene(v, f), cam, T)
    hit = fr.hit
    tri = f[fr.triangle[hit]]
    u, w_ = fr.bary_u[hit][:, None], fr.bary_v[hit][:, None]
    rebuilt = (1 - u - w_) * v[tri[:, 0]] + u * v[tri[:, 1]] + w_ * v[tri[:, 2]]
    np.testing.assert_allclose(rebuilt, fr.points[hit], atol=1e-9)
    z = (fr.points[hit] - T[:3, 3]) @ T[:3, 2]
    np.testing.assert_allclose(np.linalg.norm(fr.points[hit] - T[:3, 3], axis=1),
                               fr.range_m[hit], rtol=1e-12)
    gate = (z >= 1.5) & (z <= 6.0)
    assert 0 < gate.sum() < hit.sum()
    np.testing.assert_array_equal(fr.valid[hit], gate)
    np.testing.assert_allclose(fr.depth_z_m[hit][gate], z[gate], rtol=1e-12)
    assert np.isnan(fr.depth_z_m[hit][~gate]).all() and np.isnan(fr.depth_z_m[~hit]).all()
    n = np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rays = fr.points[hit] - T[:3, 3]
    n *= -np.sign(np.einsum("ij,ij->i", n, rays))[:, None]
    np.testing.assert_allclose(fr.normal[hit], n, atol=1e-12)
    assert (fr.triangle[~hit] == -1).all() and (fr.normal[~hit] == 0).all()
    assert np.isnan(fr.points[~hit]).all() and (fr.bary_u[~hit] == 0).all()


def test_the_lens_ray_cache_follows_every_lens_parameter():
    """Frames of two cameras that differ only in distortion (or principal point) use
    each its own rays, rendered in any order (a stale cache would reuse the first)."""
    from sensors.camera import pixel_rays

    v, f = tunnel_tube(2_000, length_m=20.0)
    scene = Scene(v, f)
    T = camera_pose([3.0, 0.0, 1.3], 0.0)
    a = _cam(w=40, h=30)
    b = replace(a, distortion=np.array([-0.2, 0.03, 0.0, 0.0, 0.0]))
    c = replace(a, cx=a.cx + 2.0)
    for cam in (a, b, c, a, c, b):
        fr = render_depth(scene, cam, T)
        np.testing.assert_array_equal(fr.rays_cam, pixel_rays(cam))
