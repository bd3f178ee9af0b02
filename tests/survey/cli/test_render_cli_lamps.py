"""``tunnelsim render --samples N`` and ``--platform NAME|FILE`` (issue 35) through the
real CLI: supersampling changes rgb.png where the image has edges and leaves the depth
alone; a platform's lamps light the frame from where the platform file puts them
(a lamp placed, in a platform file, exactly where the headlamp is gives the headlamp's
image), the headlamp and the platform's lamps add up as light does, and refusals are
one line, exit 2, naming the option."""

from __future__ import annotations

import re

import numpy as np
import pytest

from sensors.platform_spec import PLATFORM_DIR
from survey.cli.main import main
from tests.survey.cli.test_render_cli import _camera, _rgb_linear, _tube

cv2 = pytest.importorskip("cv2", reason="OpenCV decodes the PNGs (test extra)")

AT = "3,0.2,1.3"


def _render(tmp_path, out, *extra, mesh, camera):
    return main(["render", "--mesh", str(mesh), "--camera", str(camera), "--at", AT,
                 "--heading-deg", "20", "--no-noise", "--quiet", "-o",
                 str(tmp_path / out), *extra])


@pytest.fixture()
def tube(tmp_path):
    return _tube(tmp_path)[0], _camera(tmp_path)


def test_samples_anti_alias_the_edges_and_leave_the_depth(tmp_path, tube):
    mesh, cam = tube
    assert _render(tmp_path, "s1", "--lamp-cd", "20000", mesh=mesh, camera=cam) == 0
    assert _render(tmp_path, "s9", "--lamp-cd", "20000", "--samples", "9", mesh=mesh,
                   camera=cam) == 0
    a, b = ((tmp_path / d / "rgb.png").read_bytes() for d in ("s1", "s9"))
    assert a != b
    for name in ("depth.png", "depth.npy"):
        assert (tmp_path / "s1" / name).read_bytes() == (tmp_path / "s9" / name).read_bytes()
    # The change sits on the image's edges (the lining's facets and creases, the
    # cables' albedo boundary, the lamp's beam): where the one-ray image's gradient is
    # in its top tenth, the mean change is over 5 times that elsewhere (measured 15x).
    one, nine = (_rgb_linear(tmp_path / d / "rgb.png") for d in ("s1", "s9"))
    gy, gx = np.gradient(one.mean(axis=-1))
    grad = np.hypot(gx, gy)
    edge = grad > np.quantile(grad, 0.9)
    diff = np.abs(nine - one).mean(axis=-1)
    assert diff[edge].mean() > 5 * diff[~edge].mean()


def _platform(tmp_path, base, mast_m, lamp_xyz):
    """A platform file: the shipped ``base`` with its lamps replaced by one spot at
    ``lamp_xyz`` along base_link's +x (30/45 deg, 30000 cd) and its mast ``mast_m``."""
    text = re.sub(r"^\[\[lamps\]\]\n(?:(?!\[).*\n?)*", "",
                  (PLATFORM_DIR / f"{base}.toml").read_text(), flags=re.M)
    text = re.sub(r"mast_height_m = [0-9.]+", f"mast_height_m = {mast_m}", text)
    text = text.replace(f'name = "{base}"', f'name = "my_{base}"') + f"""
[[lamps]]
kind = "spot"
xyz_m = [{lamp_xyz[0]}, {lamp_xyz[1]}, {lamp_xyz[2]}]
rpy_deg = [0.0, 0.0, 0.0]
intensity_cd = 30000.0
beam_deg = 30.0
cutoff_deg = 45.0
"""
    path = tmp_path / f"my_{base}_{len(list(tmp_path.glob('my_*')))}.toml"
    path.write_text(text)
    return path


def _enc(lin):
    """8-bit sRGB codes of linear values (IEC 61966-2-1)."""
    return np.round(255 * np.where(lin <= 0.0031308, 12.92 * lin,
                                   1.055 * lin ** (1 / 2.4) - 0.055))


def test_samples_anti_alias_a_thermal_frame_too(tmp_path):
    """The tube's cables (25 C) beside the lining (13 C): with 4 rays per pixel the
    pixels on their boundary read between the two, the depth stays."""
    mesh = _tube(tmp_path)[0]
    cam = _camera(tmp_path, "lwir_640")
    for n in ("1", "4"):
        assert _render(tmp_path, f"t{n}", "--samples", n, mesh=mesh, camera=cam) == 0
    one, four = (cv2.imread(str(tmp_path / d / "thermal.png"), cv2.IMREAD_UNCHANGED)
                 .astype(np.float64) / 100 for d in ("t1", "t4"))
    for name in ("depth.png", "depth.npy"):
        assert (tmp_path / "t1" / name).read_bytes() == (tmp_path / "t4" / name).read_bytes()
    hot, cold = one.max(), one[one > 0].min()
    assert hot - cold > 5
    between = (four > cold + 1) & (four < hot - 1)
    assert between.sum() > between[(one > cold + 1) & (one < hot - 1)].sum() + 5


@pytest.mark.parametrize("base, mast, z", [("ground_robot", 0.7, 0.75),
                                           ("tripod", 0.7, 0.05)])
def test_a_platform_lamp_where_the_headlamp_is_gives_the_headlamps_image(tmp_path, tube,
                                                                        base, mast, z):
    """The camera at --at is the platform's camera mount (its platform frame), the
    platform level facing --heading-deg; base_link is ``mast_height_m`` below the
    mount for a wheeled base, at the mount otherwise (sensors.robot). A spot 5 cm above
    the mount along base_link's +x, 30/45 deg, is the headlamp
    (sensors.shading.headlamp) of the same intensity: the images agree to the PNG's
    rounding."""
    mesh, cam = tube
    assert _render(tmp_path, "head", "--lamp-cd", "30000", mesh=mesh, camera=cam) == 0
    plat = _platform(tmp_path, base, mast, (0.0, 0.0, z))
    assert _render(tmp_path, "plat", "--platform", str(plat), mesh=mesh, camera=cam) == 0
    head = _rgb_linear(tmp_path / "head" / "rgb.png")
    assert head.max() > 0.1
    assert np.abs(_enc(head) - _enc(_rgb_linear(tmp_path / "plat" / "rgb.png"))).max() <= 1
    # Moved 0.3 m to the left in the file, the lamp lights another image.
    moved = _platform(tmp_path, base, mast, (0.0, 0.3, z))
    assert _render(tmp_path, "moved", "--platform", str(moved), mesh=mesh, camera=cam) == 0
    assert np.abs(_enc(_rgb_linear(tmp_path / "moved" / "rgb.png")) - _enc(head)).max() > 10


def _half_step(lin):
    """Half an 8-bit sRGB step, in linear units, at linear values ``lin``: the most a
    PNG's rounding moves a value (IEC 61966-2-1's decoding slope times 0.5 / 255)."""
    c = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    slope = np.where(c <= 0.04045, 1 / 12.92, 2.4 / 1.055 * ((c + 0.055) / 1.055) ** 1.4)
    return 0.5 / 255 * slope


def test_platform_lamps_change_the_image_and_add_to_the_headlamp(tmp_path, tube):
    mesh, cam = tube
    assert _render(tmp_path, "head", "--lamp-cd", "3000", mesh=mesh, camera=cam) == 0
    assert _render(tmp_path, "robot", "--platform", "ground_robot", mesh=mesh,
                   camera=cam) == 0
    assert _render(tmp_path, "both", "--platform", "ground_robot", "--lamp-cd", "3000",
                   mesh=mesh, camera=cam) == 0
    head, robot, both = (_rgb_linear(tmp_path / d / "rgb.png")
                         for d in ("head", "robot", "both"))
    # The robot's two headlights (0.2 m above base_link, the camera 0.5 m above it on
    # the mast) light the floor ahead, where the headlamp 5 cm above the camera does
    # not light alike.
    assert robot.max() > 0.01 and np.abs(robot - head).max() > 0.01
    # Light adds (no noise, below full well): both = headlamp + the robot's lamps, to
    # the PNGs' rounding.
    assert both.max() < 0.99
    tol = _half_step(both) + _half_step(head) + _half_step(robot) + 1e-12
    assert np.all(np.abs(both - (head + robot)) <= tol)
    assert np.abs(both - head).max() > 0.01 and np.abs(both - robot).max() > 0.01


@pytest.mark.parametrize("extra, camera, option", [
    (["--samples", "3"], "realsense_d435_color", "--samples"),
    (["--samples", "0"], "realsense_d435_color", "--samples"),
    (["--samples", "4"], "realsense_d435_depth", "--samples"),
    (["--samples", "5"], "lwir_640", "--samples"),
    (["--platform", "ground_robot"], "lwir_640", "--platform"),
    (["--platform", "hovercraft"], "realsense_d435_color", "--platform"),
    (["--platform", "missing.toml"], "realsense_d435_color", "--platform"),
])
def test_bad_options_are_one_line_exit_2_naming_the_option(tmp_path, capsys, extra,
                                                            camera, option):
    mesh = _tube(tmp_path)[0]
    cam = _camera(tmp_path, camera)
    capsys.readouterr()
    assert _render(tmp_path, "out", *extra, mesh=mesh, camera=cam) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tunnelsim: error: "), err
    assert option in lines[0] and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_the_summary_names_the_lights_and_samples(tmp_path, tube, capsys):
    mesh, cam = tube
    capsys.readouterr()
    assert main(["render", "--mesh", str(mesh), "--camera", str(cam), "--at", AT,
                 "--heading-deg", "20", "--platform", "walker", "--samples", "4", "-o",
                 str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "walker's 1 lamp, 4 samples per pixel: exposure 16 ms at gain 1, mean value" \
        in out
    assert "headlamp" not in out
