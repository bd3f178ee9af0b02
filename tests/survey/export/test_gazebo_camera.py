"""The camera in the Gazebo export (issue 35, ``tunnelsim gazebo --camera``): the world
validates with the real SDFormat library (libsdformat-dev; skipped without it), and
what libsdformat parses back (a second compiled checker, sdf/camera_check.cpp) and what
xml.etree reads are the camera's intrinsics: fx recomputed from <horizontal_fov> equals
K's fx to 1e-9, the distortion and principal point round-trip, the image, clip planes,
rate and topic; the optical frame is camera_link turned as REP 103 says; the robot's
lamps are spot lights where the platform file puts them (SciPy's rotations as the
reference)."""

from __future__ import annotations

import math
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sensors import load_sensor
from sensors.bag import camera_topics
from sensors.camera import CAMERA_DIR, load_camera
from sensors.platform_spec import load_platform
from survey.cli.main import main
from survey.errors import GazeboExportError
from survey.export.gazebo import export_gazebo
from survey.export.gazebo_sdf import LIGHT_REF_CD, camera_sdf
from survey.world.alignment import Alignment, straight
from survey.world.generator import make_tunnel
from survey.world.profiles import horseshoe

CHECKER = Path(__file__).parent / "sdf" / "camera_check.cpp"


@pytest.fixture(scope="module")
def camera_check(tmp_path_factory):
    """sdf/camera_check.cpp compiled against libsdformat (skipped, with the reason,
    when the library or a compiler is missing), as tests/survey/conftest.py builds the
    world checker."""
    if not shutil.which("g++") or not shutil.which("pkg-config"):
        pytest.skip("g++ or pkg-config not found: cannot build the SDFormat checker")
    flags = subprocess.run(["pkg-config", "--cflags", "--libs", "sdformat12"],
                           capture_output=True, text=True)
    if flags.returncode != 0:
        pytest.skip("libsdformat-dev (SDFormat 12) not installed: apt-get install "
                    "libsdformat-dev (.ci/run does)")
    exe = tmp_path_factory.mktemp("camcheck") / "camera_check"
    r = subprocess.run(["g++", "-std=c++17", "-O1", str(CHECKER), "-o", str(exe),
                        *flags.stdout.split()], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return exe


@pytest.fixture(scope="module")
def tunnel_ply(tmp_path_factory):
    t = make_tunnel(Alignment([straight(12.0)]), horseshoe(5.0), edge_length_m=0.5,
                    roughness_rms_m=0.0)
    path = tmp_path_factory.mktemp("gzcam") / "t.ply"
    t.write(path)
    return path


def _camera_file(tmp_path, name, **edits):
    """A shipped camera's file with ``edits`` (old text -> new text) applied."""
    text = (CAMERA_DIR / f"{name}.toml").read_text()
    for old, new in edits.items():
        assert old in text, old
        text = text.replace(old, new)
    p = tmp_path / f"{name}_edited.toml"
    p.write_text(text.replace(f'name = "{name}"', f'name = "{name}_edited"'))
    return load_camera(p)


DISTORTED = {"distortion = [0.0, 0.0, 0.0, 0.0, 0.0]":
             "distortion = [-0.1234567890123, 0.0456, 0.00123, -0.00078, 0.0021]",
             "width = 1920": "width = 1921"}     # an odd width: cx not a half-integer
FISHEYE = {'model = "pinhole"': 'model = "fisheye"', "hfov_deg = 69.0": "hfov_deg = 190.0",
           "distortion = [0.0, 0.0, 0.0, 0.0, 0.0]": "distortion = [0.01, -0.002, 0.0, 0.0]"}


def _cams(tmp_path):
    return {"color": load_camera("realsense_d435_color"),
            "depth": load_camera("realsense_d435_depth"),
            "thermal": load_camera("lwir_640"),
            "distorted": _camera_file(tmp_path, "realsense_d435_color", **DISTORTED),
            "fisheye": _camera_file(tmp_path, "realsense_d435_color", **FISHEYE)}


def _lines(out, head):
    return [dict(kv.split("=", 1) for kv in ln.split()[1:]) for ln in out.splitlines()
            if ln.startswith(head + " ")]


def _rot(d):
    return Rotation.from_quat([float(d["qx"]), float(d["qy"]), float(d["qz"]),
                               float(d["qw"])]).as_matrix()


@pytest.mark.parametrize("which", ["color", "depth", "thermal", "distorted", "fisheye"])
def test_camera_world_validates_and_reads_back_as_the_spec(sdf_check, camera_check,
                                                          tunnel_ply, tmp_path, which):
    cam = _cams(tmp_path)[which]
    info = export_gazebo(tunnel_ply, load_sensor("robosense_airy"), tmp_path / "w",
                         camera=cam)
    world = tmp_path / "w" / "world.sdf"
    # The world checker the other Gazebo tests use: no error, no unknown element.
    r = subprocess.run([str(sdf_check), str(world), str(tmp_path / "w" / "models")],
                       capture_output=True, text=True)
    assert r.returncode == 0 and "error" not in r.stdout, r.stdout + r.stderr
    r = subprocess.run([str(camera_check), str(world), str(tmp_path / "w" / "models")],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    (c,) = _lines(r.stdout, "camera")
    w, h = cam.width, cam.height
    topics = camera_topics(cam)
    assert (c["name"], c["topic"]) == (cam.name, topics.image)
    assert info["camera"]["info_topic"] == topics.info
    assert (int(c["width"]), int(c["height"])) == (w, h)
    assert float(c["update_rate"]) == cam.frame_rate_hz
    hfov = float(c["hfov"])
    if cam.model == "pinhole":
        assert c["type"] == {"color": "camera", "depth": "depth_camera",
                             "thermal": "thermal_camera"}[cam.kind]
        # fx from the field of view, as a Gazebo camera's projection makes it.
        assert w / (2 * math.tan(hfov / 2)) == pytest.approx(cam.fx, rel=1e-9)
        k1, k2, p1, p2, k3 = cam.distortion
        assert [float(c[k]) for k in ("k1", "k2", "k3", "p1", "p2")] == [k1, k2, k3, p1, p2]
        # SDF's image coordinates start at the top-left pixel's corner, ours at its
        # centre: half a pixel.
        assert float(c["center_x"]) * w - 0.5 == pytest.approx(cam.cx, abs=1e-9)
        assert float(c["center_y"]) * h - 0.5 == pytest.approx(cam.cy, abs=1e-9)
        assert (float(c["fx"]), float(c["fy"])) == (cam.fx, cam.fy)
        assert (float(c["cx"]) - 0.5, float(c["cy"]) - 0.5) == (cam.cx, cam.cy)
        assert c["lens"] == "gnomonical"
    else:
        # Equidistant: r = f theta, so the width spans w / fx radians.
        # libsdformat's name for the type ``wideanglecamera`` written.
        assert c["type"] == "wide_angle_camera" and c["lens"] == "equidistant"
        assert w / hfov == pytest.approx(cam.fx, rel=1e-9)
        assert float(c["cutoff"]) == pytest.approx(min(math.hypot(w, h) / 2 / cam.fx,
                                                       math.pi))
        assert any("Kannala-Brandt" in x for x in info["camera"]["limitations"])
    fmt = {"color": "RGB_INT8", "depth": "R_FLOAT32", "thermal": "L_INT16"}[cam.kind]
    assert c["format"] == fmt
    near, far = (float(c["near"]), float(c["far"]))
    if cam.kind == "depth":
        assert (near, far) == cam.depth_range_m
        assert (float(c["depth_near"]), float(c["depth_far"])) == cam.depth_range_m
    else:
        assert 0 < near < 0.1 and far >= 500
    # The sensor (camera_link: x forward, z up) 10 cm below the lidar, level; the
    # optical frame at the same point, z along camera_link's x, x along -y, y along -z.
    lidar = _lines(subprocess.run([str(sdf_check), str(world),
                                   str(tmp_path / "w" / "models")], capture_output=True,
                                  text=True).stdout, "sensor_pose")
    lid = next(d for d in lidar if d["name"] == "robosense_airy")
    pos = np.array([float(c[k]) for k in "xyz"])
    np.testing.assert_allclose(pos, [float(lid[k]) for k in "xyz"] - np.array([0, 0, 0.1]),
                               atol=1e-12)
    R_link = _rot(c)
    np.testing.assert_allclose(R_link, np.eye(3), atol=1e-12)
    (fr,) = _lines(r.stdout, "frame")
    assert fr["name"] == topics.frame_id and fr["attached_to"] == "chassis"
    np.testing.assert_allclose([float(fr[k]) for k in "xyz"], pos, atol=1e-12)
    R_opt = _rot(fr)
    np.testing.assert_allclose(R_opt[:, 2], R_link[:, 0], atol=1e-12)
    np.testing.assert_allclose(R_opt[:, 0], -R_link[:, 1], atol=1e-12)
    np.testing.assert_allclose(R_opt[:, 1], -R_link[:, 2], atol=1e-12)
    # The robot's lamps (ground_robot's [[lamps]]), in the model frame (base_link).
    lights = _lines(r.stdout, "light")
    lamps = load_platform("ground_robot").lamps
    assert len(lights) == len(lamps) == info["camera"]["lamps"] == 2
    for lt, lp in zip(lights, lamps):
        assert lt["link"] == "chassis" and lt["type"] == "2"       # sdf::LightType::SPOT
        np.testing.assert_allclose([float(lt[k]) for k in "xyz"], lp.xyz_m, atol=1e-12)
        beam = Rotation.from_euler("xyz", lp.rpy_rad).apply([1.0, 0.0, 0.0])
        np.testing.assert_allclose([float(lt[k]) for k in ("dx", "dy", "dz")], beam,
                                   atol=1e-12)
        assert float(lt["inner"]) == pytest.approx(2 * lp.beam_half_angle_rad)
        assert float(lt["outer"]) == pytest.approx(2 * lp.cutoff_half_angle_rad)
        assert (float(lt["constant"]), float(lt["linear"]), float(lt["quadratic"])) == \
            (0.0, 0.0, 1.0)
        assert float(lt["intensity"]) == pytest.approx(lp.intensity_cd / LIGHT_REF_CD)
        # The range ends where the axis illuminance I / d^2 falls to 0.1 lux.
        assert float(lt["range"]) == pytest.approx(math.sqrt(lp.intensity_cd / 0.1))


@pytest.mark.parametrize("which", ["color", "distorted", "depth"])
def test_xml_round_trip_of_the_intrinsics(tmp_path, which):
    cam = _cams(tmp_path)[which]
    xml, limits = camera_sdf(cam, topic="/cam/image_raw")
    s = ET.fromstring(xml.strip())
    g = lambda path: s.find(path).text      # noqa: E731
    hfov = float(g("camera/horizontal_fov"))
    assert cam.width / (2 * math.tan(hfov / 2)) == pytest.approx(cam.fx, rel=1e-9)
    k1, k2, p1, p2, k3 = cam.distortion
    got = [float(g(f"camera/distortion/{k}")) for k in ("k1", "k2", "k3", "p1", "p2")]
    assert got == [k1, k2, k3, p1, p2]                     # exactly: 17 digits written
    ux, uy = (float(x) for x in g("camera/distortion/center").split())
    assert (ux * cam.width - 0.5, uy * cam.height - 0.5) == pytest.approx((cam.cx, cam.cy),
                                                                          abs=1e-12)
    assert float(g("update_rate")) == cam.frame_rate_hz
    assert int(g("camera/image/width")) == cam.width
    assert any("noise" in x for x in limits)
    assert any("rolling shutter" in x for x in limits) == (not cam.global_shutter)


def test_a_fisheye_depth_camera_is_refused(tmp_path):
    cam = _camera_file(tmp_path, "realsense_d435_depth", **{
        'model = "pinhole"': 'model = "fisheye"',
        "distortion = [0.0, 0.0, 0.0, 0.0, 0.0]": "distortion = [0.0, 0.0, 0.0, 0.0]"})
    with pytest.raises(GazeboExportError, match="pinhole lens for a depth camera.*--camera"):
        camera_sdf(cam, topic="/d")


def test_cli_camera_adds_the_sensor_bridge_and_lights(tunnel_ply, tmp_path, capsys):
    assert main(["gazebo", "--mesh", str(tunnel_ply), "-o", str(tmp_path / "plain"),
                 "--quiet"]) == 0
    assert main(["gazebo", "--mesh", str(tunnel_ply), "--camera", "realsense_d435_color",
                 "-o", str(tmp_path / "cam")]) == 0
    out = capsys.readouterr().out
    assert "realsense_d435_color on /camera/color/image_raw (camera_info beside it)" in out
    plain = ET.parse(tmp_path / "plain" / "world.sdf").getroot()
    world = ET.parse(tmp_path / "cam" / "world.sdf").getroot()
    chassis = ".//model[@name='robot']/link[@name='chassis']"
    assert plain.findall(f"{chassis}/sensor[@type='camera']") == []
    assert plain.findall(f"{chassis}/light") == []
    (sensor,) = world.findall(f"{chassis}/sensor[@type='camera']")
    hfov = float(sensor.find("camera/horizontal_fov").text)
    cam = load_camera("realsense_d435_color")
    assert cam.width / (2 * math.tan(hfov / 2)) == pytest.approx(cam.fx, rel=1e-9)
    assert len(world.findall(f"{chassis}/light[@type='spot']")) == 2
    bridge = (tmp_path / "cam" / "bridge.yaml").read_text()
    assert 'ros_topic_name: "/camera/color/image_raw"' in bridge
    assert 'gz_type_name: "gz.msgs.CameraInfo"' in bridge
    assert "image_raw" not in (tmp_path / "plain" / "bridge.yaml").read_text()
    readme = (tmp_path / "cam" / "README.txt").read_text()
    assert "Camera: realsense_d435_color (color) on robot::chassis, " \
           "/camera/color/image_raw and /camera/color/camera_info" in readme
    assert "Camera:" not in (tmp_path / "plain" / "README.txt").read_text()


def test_cli_refuses_an_unknown_camera_naming_the_option(tunnel_ply, tmp_path, capsys):
    assert main(["gazebo", "--mesh", str(tunnel_ply), "--camera", "no_such_cam", "-o",
                 str(tmp_path / "w")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tunnelsim: error: --camera") and \
        "tunnelsim cameras" in err[0]
    assert not (tmp_path / "w").exists()
