"""Retro-reflective surfaces (issue 35): prisms return a lamp's light towards it,
``L = R_A(alpha, beta) E_perp / cos v`` (CIE 54.2) added to the Lambertian term.

References: a square plate facing the camera with a point lamp beside the camera; each
pixel's hit point from the ray-plane intersection computed here, the illuminance
``I / d^2``, the observation, entrance and viewing angles from those points, and
R_A bilinearly interpolated (SciPy's ``RegularGridInterpolator``) in the table of
ASTM D4956 Type III white sheeting written out here; Mitsuba's scenes (no
retro-reflector) through tests/sensors/test_mitsuba_shading.py, and bit-equality of a
scene without retro-reflective faces with the Lambertian shading.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import RegularGridInterpolator

from raytrace import Scene
from sensors.appearance import MATERIALS, Material, mesh_appearance
from sensors.camera import load_camera
from sensors.errors import SimulationError
from sensors.io.meshes import MeshData
from sensors.render import camera_pose
from sensors.shading import Lamp, luminance, radiance_frame, retro_coefficient
from survey.cli.main import main

#: ASTM D4956 Type III white (cd lx^-1 m^-2) at observation 0.1, 0.2, 0.5 deg and
#: entrance -4, +30 deg; the module's 2 and 4 deg rows (ASSUMED there) written again.
OBS_DEG = [0.1, 0.2, 0.5, 2.0, 4.0]
ENT_DEG = [4.0, 30.0]
RA = [[300.0, 180.0], [250.0, 150.0], [95.0, 65.0], [5.0, 2.5], [0.0, 0.0]]
LABELS = ("lining", "prism")
PLATE_X = 3.0
LAMP_CD = 1000.0


def _plate(label: int, half: float = 1.0) -> MeshData:
    v = np.array([[PLATE_X, -half, -half], [PLATE_X, half, -half], [PLATE_X, half, half],
                  [PLATE_X, -half, half]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    return MeshData(v, f, face_fields={"label": np.array([label, label], dtype=np.uint8)})


def _cam():
    """The D435 colour camera scaled to 64 x 48 pixels (its field of view kept)."""
    c = load_camera("realsense_d435_color")
    k = 64 / c.width
    return replace(c, width=64, height=48, fx=c.fx * k, fy=c.fy * k,
                   cx=(c.cx + 0.5) * k - 0.5, cy=(c.cy + 0.5) * k - 0.5)


def _reference(cam, T, lamp_pos, albedo):
    """Per-pixel luminance (h, w) of the plate, NaN off it, computed from the geometry
    alone."""
    h, w = cam.height, cam.width
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    # Undistorted pinhole rays (the test camera has no distortion), then the plane.
    assert not np.any(cam.distortion)
    d_cam = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1)
    d = d_cam @ T[:3, :3].T
    c = T[:3, 3]
    t = (PLATE_X - c[0]) / d[..., 0]
    p = c + t[..., None] * d
    on = (np.abs(p[..., 1]) < 1.0) & (np.abs(p[..., 2]) < 1.0)
    n = np.array([-1.0, 0.0, 0.0])                    # towards the camera
    to_lamp = lamp_pos - p
    dist = np.linalg.norm(to_lamp, axis=-1)
    ell = to_lamp / dist[..., None]
    to_cam = (c - p) / np.linalg.norm(c - p, axis=-1)[..., None]
    cos_i = ell @ n
    e_perp = LAMP_CD / dist ** 2
    alpha = np.degrees(np.arccos(np.clip(np.sum(ell * to_cam, -1), -1, 1)))
    beta = np.degrees(np.arccos(cos_i))
    cos_v = to_cam @ n
    table = RegularGridInterpolator((OBS_DEG, ENT_DEG), np.array(RA), bounds_error=False,
                                    fill_value=0.0)
    ra = table(np.stack([np.clip(alpha, 0.1, None), np.clip(beta, 4.0, 30.0)], -1))
    lam = albedo * e_perp * cos_i / math.pi
    retro = ra * e_perp / cos_v
    return np.where(on, lam, np.nan), np.where(on, retro, np.nan), alpha


def _render(mesh, lamp_pos, cam=None):
    cam = cam or _cam()
    T = camera_pose([0.0, 0.0, 0.0], 0.0)
    app = mesh_appearance(mesh, LABELS, materials={"lining": MATERIALS["lining"],
                                                    "prism": MATERIALS["prism"]})
    lamp = Lamp(lamp_pos, [1.0, 0.0, 0.0], LAMP_CD)
    frame, lum = radiance_frame(Scene(mesh.vertices, mesh.faces), cam, T, [lamp], app)
    return cam, T, frame, lum


def test_plate_in_front_of_a_lamp_beside_the_camera_matches_the_formula():
    """Every pixel of a prism plate 3 m ahead, a point lamp 5 cm above the camera:
    L = rho E cos(i) / pi + R_A(alpha, beta) E_perp / cos v (rel. 1e-9), the same in
    every channel's retro part; off the plate nothing; alpha near 0.95 deg."""
    lamp = np.array([0.0, 0.0, 0.05])
    cam, T, frame, lum = _render(_plate(1), lamp)
    rho = np.array(MATERIALS["prism"].albedo_rgb)
    lam, retro, alpha = _reference(cam, T, lamp, rho[0])
    on = ~np.isnan(lam)
    assert on.sum() > 500 and (~on).sum() > 100
    np.testing.assert_array_equal(frame.hit, on)
    assert 0.8 < alpha[on].min() and alpha[on].max() < 1.0
    for ch in range(3):
        want = rho[ch] * lam[on] / rho[0] + retro[on]
        np.testing.assert_allclose(lum[..., ch][on], want, rtol=1e-9)
    assert np.all(lum[~on] == 0)
    # The retro-reflected part dominates: R_A ~ 40 against rho / pi ~ 0.09.
    assert np.all(retro[on] > 100 * lam[on])


def test_a_plate_that_is_not_retroreflective_is_lambertian():
    """The same plate of lining: the Lambertian term alone (rel. 1e-9)."""
    lamp = np.array([0.0, 0.0, 0.05])
    cam, T, frame, lum = _render(_plate(0), lamp)
    rho = np.array(MATERIALS["lining"].albedo_rgb)
    lam, _, _ = _reference(cam, T, lamp, 1.0)
    on = frame.hit
    for ch in range(3):
        np.testing.assert_allclose(lum[..., ch][on], rho[ch] * lam[on], rtol=1e-9)


def test_retroreflection_falls_off_as_the_lamp_moves_away_from_the_camera():
    """The centre pixel's retro-reflected luminance (the frame's minus the plain
    plate's) falls strictly as the lamp moves 1, 2, 5, 10, 20 cm from the camera
    (observation angle 0.19-3.8 deg at 3 m) and vanishes at 40 cm (7.6 deg > 4 deg)."""
    cam = _cam()
    centre = (cam.height // 2, cam.width // 2)
    retro = []
    for off in (0.01, 0.02, 0.05, 0.10, 0.20, 0.40):
        lamp = np.array([0.0, off, 0.0])
        _, _, _, lum = _render(_plate(1), lamp, cam)
        _, _, _, plain = _render(_plate(0), lamp, cam)
        rho_p, rho_l = MATERIALS["prism"].albedo_rgb[0], MATERIALS["lining"].albedo_rgb[0]
        retro.append(lum[centre][0] - plain[centre][0] * rho_p / rho_l)
    assert all(a > b > 0 for a, b in zip(retro[:-1], retro[1:-1]))
    assert retro[-1] == pytest.approx(0.0, abs=1e-9)


def test_a_scene_without_retroreflectors_is_shaded_bit_for_bit_as_before(tmp_path):
    """No retro-reflective face: the appearance carries no flag, and ``luminance`` with
    an all-False mask equals it without one, bit for bit (the Mitsuba scenes of
    tests/sensors/test_mitsuba_shading.py have none)."""
    mesh = _plate(0)
    app = mesh_appearance(mesh, LABELS)
    assert app.retroreflective is None
    cam = _cam()
    T = camera_pose([0.0, 0.0, 0.0], 0.0)
    lamp = Lamp([0.0, 0.0, 0.05], [1.0, 0.0, 0.0], LAMP_CD)
    scene = Scene(mesh.vertices, mesh.faces)
    frame, lum = radiance_frame(scene, cam, T, [lamp], app)
    alb = app.at(frame).albedo
    a = luminance(scene, frame, [lamp], np.nan_to_num(alb))
    b = luminance(scene, frame, [lamp], np.nan_to_num(alb), np.zeros(frame.hit.shape, bool))
    np.testing.assert_array_equal(a, lum)
    np.testing.assert_array_equal(b, lum)
    with pytest.raises(SimulationError, match="retroreflective as true or false"):
        Material((0.3, 0.3, 0.3), 290.0, 0.9,
                 retroreflective="yes")  # type: ignore[arg-type]


def test_a_shadowed_retroreflector_returns_nothing():
    """A blocker between the lamp and the plate (not between the plate and the
    camera): the shadowed pixels' luminance is 0, retro-reflection included."""
    plate = _plate(1)
    # A strip at x 1.5 (z 0.40-0.45) between a lamp 0.6 m above the camera and the
    # plate's upper half.
    lamp = np.array([0.0, 0.0, 0.6])
    bv = np.array([[1.5, -2.0, 0.40], [1.5, 2.0, 0.40], [1.5, 2.0, 0.45],
                   [1.5, -2.0, 0.45]])
    v = np.vstack([plate.vertices, bv])
    f = np.vstack([plate.faces, np.array([[4, 5, 6], [4, 6, 7]])])
    mesh = MeshData(v, f, face_fields={"label": np.array([1, 1, 0, 0], dtype=np.uint8)})
    cam, T, frame, lum = _render(mesh, lamp)
    on_plate = frame.triangle <= 1
    on_plate &= frame.hit
    dark = on_plate & (lum[..., 0] == 0)
    # The line from the lamp (z 0.6) through the strip (z 0.40-0.45 at x 1.5) reaches
    # the plate (x 3) at z 0.20-0.30.
    z = frame.points[..., 2]
    band = on_plate & (z > 0.21) & (z < 0.29)
    assert band.sum() > 0 and np.all(lum[band] == 0)
    assert np.all(dark <= on_plate & (z >= 0.19) & (z <= 0.31))


@given(a1=st.floats(0.0, 6.0), a2=st.floats(0.0, 6.0), b=st.floats(0.0, 89.0))
@settings(max_examples=200, deadline=None)
def test_coefficient_is_monotone_and_bounded(a1, a2, b):
    """R_A never rises with the observation angle, lies within the table's range, is
    0 from 4 deg and equals the table at its nodes."""
    lo, hi = sorted((a1, a2))
    ra_lo, ra_hi = retro_coefficient(np.radians([lo, hi]), np.radians([b, b]))
    assert ra_lo >= ra_hi >= 0.0 and ra_lo <= 300.0
    if hi >= 4.0:
        assert ra_hi == 0.0
    for i, a in enumerate(OBS_DEG):
        for j, e in enumerate(ENT_DEG):
            assert retro_coefficient(math.radians(a), math.radians(e)) == \
                pytest.approx(RA[i][j], rel=1e-12)


def test_render_cli_prism_is_bright_under_the_headlamp(tmp_path):
    """``tunnelsim render`` on a plate labelled prism (the generator's label index,
    ``survey.world.mesh.LABELS``) against the same plate labelled lining: in the
    rgb.png the user gets, the prism's pixels are far brighter (noise off; the D435's
    auto-exposure off, so that both plates are exposed alike)."""
    from PIL import Image

    from sensors.camera import CAMERA_DIR
    from sensors.io.meshes import write_mesh
    from survey.world.mesh import LABEL

    cam = tmp_path / "d435_fixed.toml"
    text = (CAMERA_DIR / "realsense_d435_color.toml").read_text()
    assert "auto_exposure = true" in text
    cam.write_text(text.replace("auto_exposure = true", "auto_exposure = false"))
    images = {}
    for name in ("prism", "lining"):
        mesh = _plate(LABEL[name], half=0.5)
        path = tmp_path / f"{name}.ply"
        write_mesh(path, mesh.vertices, mesh.faces, face_fields=dict(mesh.face_fields))
        # (The camera outside the plate's bounding box gets a warning on stderr.)
        assert main(["render", "--mesh", str(path), "--camera", str(cam),
                     "--at", "0,0,0", "--heading-deg", "0", "--no-noise", "--lamp-cd",
                     "100", "-o", str(tmp_path / name), "--quiet"]) == 0
        images[name] = np.asarray(Image.open(tmp_path / name / "rgb.png"), dtype=float)
    hit = np.load(tmp_path / "lining" / "depth.npy") > 0
    assert 0.05 < hit.mean() < 0.5
    assert images["lining"][hit].mean() > 0
    assert images["prism"][hit].mean() > 5 * images["lining"][hit].mean()
    assert np.all(images["prism"][~hit] == 0)
