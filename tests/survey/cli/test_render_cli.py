"""``tunnelsim render`` and ``tunnelsim cameras`` (issue 35) through the real CLI: the
files a user gets, read back by independent decoders (OpenCV, NumPy, json), every
option changing what it should, the thermal image against Planck's law integrated by
SciPy, and one-line refusals (exit 2) that name the option."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from raytrace.shapes import tunnel_tube
from sensors.appearance import MATERIALS, ROCK_K
from sensors.camera import CAMERA_DIR, load_camera
from sensors.io.meshes import write_mesh
from survey.cli.main import main

cv2 = pytest.importorskip("cv2", reason="OpenCV decodes the PNGs (test extra)")


def _camera(tmp_path, name="realsense_d435_color", w=64, h=48, auto_exposure=False):
    """A shipped camera's file with a small image (fast tests); a colour camera's
    auto-exposure off unless asked (the image then scales with the light)."""
    text = (CAMERA_DIR / f"{name}.toml").read_text()
    if not auto_exposure:
        text = text.replace("auto_exposure = true", "auto_exposure = false")
    full = load_camera(name)
    text = text.replace(f"width = {full.width}", f"width = {w}").replace(
        f"height = {full.height}", f"height = {h}").replace(
        f'name = "{name}"', f'name = "small_{name}"')
    p = tmp_path / f"small_{name}{'_ae' if auto_exposure else ''}.toml"
    p.write_text(text)
    assert load_camera(p).width == w
    assert load_camera(p).auto_exposure == (auto_exposure and load_camera(name).kind
                                            == "color")
    return p


def _tube(tmp_path, **fields):
    """A 20 m tube (horseshoe, along +x); faces with y > 0 labelled 5 (cable), the
    others 0 (lining), as the generator's label indices."""
    v, f = tunnel_tube(3_000, length_m=20.0, seed=1)
    lab = np.where(v[f].mean(axis=1)[:, 1] > 0, 5, 0).astype(np.uint8)
    path = tmp_path / "tube.ply"
    write_mesh(path, v, f, face_fields={"label": lab}, vertex_fields=fields or None)
    return path, v, f


def _render(tmp_path, out, *extra, mesh=None, camera=None):
    mesh = mesh or _tube(tmp_path)[0]
    camera = camera or _camera(tmp_path)
    return main(["render", "--mesh", str(mesh), "--camera", str(camera), "--at",
                 "3,0,1.3", "--heading-deg", "0", "-o", str(tmp_path / out), *extra])


def _rgb_linear(path):
    c = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1] / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def test_render_writes_the_files_of_a_colour_camera(tmp_path, capsys):
    assert _render(tmp_path, "f") == 0
    out = capsys.readouterr().out
    names = sorted(p.name for p in (tmp_path / "f").iterdir())
    assert names == ["camera_info.json", "depth.npy", "depth.png", "rgb.png"]
    assert "appearance: albedo from label, temperature from label" in out
    info = json.loads((tmp_path / "f" / "camera_info.json").read_text())
    assert info["name"] == "small_realsense_d435_color" and info["kind"] == "color"
    W = np.array(info["world_from_camera"])
    np.testing.assert_allclose(W[:3, 3], [3, 0, 1.3])
    np.testing.assert_allclose(W[:3, 2], [1, 0, 0], atol=1e-15)     # looks along +x
    depth = np.load(tmp_path / "f" / "depth.npy")
    png = cv2.imread(str(tmp_path / "f" / "depth.png"), cv2.IMREAD_UNCHANGED)
    ok = np.isfinite(depth)
    np.testing.assert_array_equal(png[ok], np.round(depth[ok].astype(np.float64) * 1000))
    assert np.all(png[~ok] == 0) and 0.9 < ok.mean() < 1.0     # the far portal: no data
    assert (f"small_realsense_d435_color (color, 64x48): {ok.mean():.1%} of pixels hit "
            f"the mesh; depth {np.nanmin(depth):.3f}-{np.nanmax(depth):.3f} m") in out


def test_lamp_intensity_scales_the_image_and_zero_is_dark(tmp_path):
    mesh, camera = _tube(tmp_path)[0], _camera(tmp_path)
    for name, cd in (("a", "2000"), ("b", "8000"), ("c", "0")):
        assert _render(tmp_path, name, "--lamp-cd", cd, "--no-noise", mesh=mesh,
                       camera=camera) == 0
    a, b, c = (_rgb_linear(tmp_path / n / "rgb.png") for n in "abc")
    # Linear in the lamp's intensity (no noise, below full well): 4x, to the 8-bit
    # quantisation of the sRGB values (a half step of the darker image: < 4 % here).
    lit = (a > 0.005) & (b < 0.95)
    assert lit.mean() > 0.3
    np.testing.assert_allclose(b[lit] / a[lit], 4.0, rtol=0.15)
    assert abs(np.median(b[lit] / a[lit]) - 4.0) < 0.05
    assert np.all(c == 0)


def test_auto_exposure_brings_the_image_to_mid_grey_and_is_reported(tmp_path, capsys):
    """The D435's colour file has auto-exposure on: under a weak and a strong lamp the
    noiseless image's mean (decoded from rgb.png) is the 18 % mid grey, the exposure
    time shorter under the strong lamp; camera_info.json and the summary state the
    time and gain. The same camera with auto-exposure off takes another image at its
    fixed 16 ms, gain 1."""
    mesh = _tube(tmp_path)[0]
    ae, fixed = _camera(tmp_path, auto_exposure=True), _camera(tmp_path)
    info = {}
    for name, cam, cd in (("weak", ae, "3000"), ("strong", ae, "300000"),
                          ("fixed", fixed, "3000")):
        capsys.readouterr()
        assert _render(tmp_path, name, "--lamp-cd", cd, "--no-noise", mesh=mesh,
                       camera=cam) == 0
        out = capsys.readouterr().out
        info[name] = json.loads((tmp_path / name / "camera_info.json").read_text())
        t, g = info[name]["exposure_s"], info[name]["gain"]
        assert f"exposure {t * 1e3:.3g} ms at gain {g:.3g}, mean value" in out
    weak, strong, fixed_i = info["weak"], info["strong"], info["fixed"]
    assert weak["auto_exposure"] and strong["auto_exposure"]
    assert not fixed_i["auto_exposure"]
    assert (fixed_i["exposure_s"], fixed_i["gain"]) == (0.016, 1.0)
    assert weak["exposure_s"] == 0.016 and 1.0 < weak["gain"] < 16.0   # time, then gain
    assert strong["exposure_s"] < 0.016 and strong["gain"] == 1.0
    for name in ("weak", "strong"):
        img = _rgb_linear(tmp_path / name / "rgb.png")
        assert (img >= 1.0).mean() < 0.02
        assert img.mean() == pytest.approx(0.18, abs=0.01)     # 8-bit sRGB rounding
    dim = _rgb_linear(tmp_path / "fixed" / "rgb.png")
    assert dim.mean() < 0.18 / 2 and \
        (tmp_path / "fixed" / "rgb.png").read_bytes() != (tmp_path / "weak" / "rgb.png"
                                                          ).read_bytes()


def test_noise_follows_the_seed_and_no_noise_removes_it(tmp_path):
    mesh, camera = _tube(tmp_path)[0], _camera(tmp_path)
    runs = {"s1": ["--seed", "1"], "s1b": ["--seed", "1"], "s2": ["--seed", "2"],
            "n1": ["--seed", "1", "--no-noise"], "n2": ["--seed", "2", "--no-noise"]}
    for name, extra in runs.items():
        assert _render(tmp_path, name, "--lamp-cd", "5000", *extra, mesh=mesh,
                       camera=camera) == 0
    img = {k: (tmp_path / k / "rgb.png").read_bytes() for k in runs}
    assert img["s1"] == img["s1b"] and img["s1"] != img["s2"] and img["n1"] == img["n2"]
    assert img["n1"] != img["s1"]


def test_heading_pitch_and_roll_set_the_optical_frame(tmp_path):
    mesh, camera = _tube(tmp_path)[0], _camera(tmp_path)
    assert _render(tmp_path, "p", "--heading-deg", "30", "--pitch-deg", "10",
                   "--roll-deg", "20", mesh=mesh, camera=camera) == 0
    W = np.array(json.loads((tmp_path / "p" / "camera_info.json").read_text())
                 ["world_from_camera"])
    h, p, r = np.radians([30.0, 10.0, 20.0])
    # Independent construction: an aircraft-style yaw (about +z, from +x), pitch up
    # (about the lateral axis) and roll about the axis, applied to the optical frame
    # (x right, y down, z forward) of a camera looking along +x.
    from scipy.spatial.transform import Rotation

    base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])   # cols x,y,z
    R = Rotation.from_euler("ZYX", [h, -p, r]).as_matrix() @ base
    np.testing.assert_allclose(W[:3, :3], R, atol=1e-12)


def test_thermal_png_is_the_apparent_temperature_of_the_label_table(tmp_path):
    """Cable faces (y > 0, the image's left half) and lining faces (right half): each
    pixel's centikelvin equal the black-body temperature of eps B(T) + (1 - eps)
    B(T_rock) in the camera's 7.5-13.5 um band, Planck's law integrated by SciPy."""
    from scipy.integrate import quad
    from scipy.optimize import brentq

    h_, c_, k_ = 6.62607015e-34, 299_792_458.0, 1.380649e-23

    def band(T):
        return quad(lambda lam: 2 * h_ * c_ ** 2 / lam ** 5 / math.expm1(
            h_ * c_ / (lam * k_ * T)), 7.5e-6, 13.5e-6, epsabs=0, epsrel=1e-12)[0]

    def apparent(mat):
        L = mat.emissivity * band(mat.temperature_k) + (1 - mat.emissivity) * band(ROCK_K)
        return brentq(lambda T: band(T) - L, 200.0, 400.0, xtol=1e-9)

    mesh = _tube(tmp_path)[0]
    camera = _camera(tmp_path, "lwir_640", 64, 48)
    assert _render(tmp_path, "t", "--no-noise", mesh=mesh, camera=camera) == 0
    names = sorted(p.name for p in (tmp_path / "t").iterdir())
    assert names == ["camera_info.json", "depth.npy", "depth.png", "thermal.png"]
    png = cv2.imread(str(tmp_path / "t" / "thermal.png"), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16
    cable, lining = (round(100 * apparent(MATERIALS[k])) for k in ("cable", "lining"))
    assert cable != lining
    hit = np.isfinite(np.load(tmp_path / "t" / "depth.npy"))
    assert np.all(png[~hit] == 0) and hit[:, :28].mean() > 0.9
    assert set(np.unique(png[:, :28][hit[:, :28]]).tolist()) == {cable}
    assert set(np.unique(png[:, 36:][hit[:, 36:]]).tolist()) == {lining}
    # The noise is the camera's NETD (50 mK): with it, values scatter by ~5 counts.
    assert _render(tmp_path, "tn", mesh=mesh, camera=camera) == 0
    noisy = cv2.imread(str(tmp_path / "tn" / "thermal.png"), cv2.IMREAD_UNCHANGED)
    diff = (noisy.astype(float) - png)[hit]
    assert 3.5 < diff.std() < 6.5


def test_vertex_colours_and_temperatures_of_the_mesh_file_are_used(tmp_path, capsys):
    v = tunnel_tube(3_000, length_m=20.0, seed=1)[0]
    red = np.full(len(v), 200, np.uint8)
    green = np.full(len(v), 100, np.uint8)
    blue = np.full(len(v), 50, np.uint8)
    temp = 280.0 + v[:, 0]              # warmer along the tunnel
    mesh = _tube(tmp_path, red=red, green=green, blue=blue, temperature=temp)[0]
    assert _render(tmp_path, "c", "--lamp-cd", "8000", "--no-noise", mesh=mesh) == 0
    assert "appearance: albedo from vertex, temperature from vertex" in \
        capsys.readouterr().out
    rgb = _rgb_linear(tmp_path / "c" / "rgb.png")
    lit = (rgb[..., 1] > 0.01) & (rgb[..., 0] < 0.95)
    assert lit.mean() > 0.2
    want = [(x / 255 + 0.055) / 1.055 for x in (200, 100, 50)]
    want = [w ** 2.4 for w in want]
    np.testing.assert_allclose(np.median(rgb[lit][:, 0] / rgb[lit][:, 1]),
                               want[0] / want[1], rtol=0.03)
    camera = _camera(tmp_path, "lwir_640", 64, 48)
    assert _render(tmp_path, "t", "--no-noise", mesh=mesh, camera=camera) == 0
    th = cv2.imread(str(tmp_path / "t" / "thermal.png"), cv2.IMREAD_UNCHANGED) / 100.0
    depth = np.load(tmp_path / "t" / "depth.npy")
    # Further along the axis (larger depth at the image's centre row) is warmer.
    row = 24
    ok = np.isfinite(depth[row])
    assert np.corrcoef(depth[row][ok], th[row][ok])[0, 1] > 0.9


def test_cameras_lists_every_camera_file(capsys):
    assert main(["cameras"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = sorted(tomllib.loads(p.read_text())["device"]["name"]
                   for p in CAMERA_DIR.glob("*.toml"))
    assert sorted(line.split()[0] for line in lines) == names and len(names) >= 3
    d435 = next(line for line in lines if line.startswith("realsense_d435_depth "))
    assert "depth" in d435 and "1280x720" in d435 and "30 Hz" in d435 and \
        "FOV 87.0x" in d435 and "pinhole, global shutter" in d435 and "337029" in d435


@pytest.mark.parametrize("args, option", [
    (["--camera", "no_such_camera"], "--camera"),
    (["--at", "1,2"], "--at"),
    (["--at", "500,0,1.3"], "--at"),            # far beyond the tube's open end
    (["--lamp-cd", "-5"], "--lamp-cd"),
    (["--mesh", "CLOUD"], "--mesh"),
])
def test_bad_input_is_one_line_exit_2_naming_the_option(tmp_path, capsys, args, option):
    mesh, camera = _tube(tmp_path)[0], _camera(tmp_path)
    cloud = tmp_path / "cloud.ply"
    cloud.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
                      b"property double x\nproperty double y\nproperty double z\n"
                      b"end_header\n" + np.zeros(3).tobytes())
    argv = {"--mesh": str(mesh), "--camera": str(camera), "--at": "3,0,1.3",
            "--heading-deg": "0", "-o": str(tmp_path / "out")}
    for k, val in zip(args[::2], args[1::2]):
        argv[k] = str(cloud) if val == "CLOUD" else val
    if "--at" in args and args[1] == "500,0,1.3":
        argv["--heading-deg"] = "0"
    flat = [x for kv in argv.items() for x in kv]
    capsys.readouterr()
    assert main(["render", *flat]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert lines[-1].startswith("tunnelsim: error: ") and option in lines[-1], err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()       # nothing left behind


def test_a_camera_outside_the_mesh_that_sees_it_is_warned_about(tmp_path, capsys):
    mesh = _tube(tmp_path)[0]
    assert main(["render", "--mesh", str(mesh), "--camera", str(_camera(tmp_path)),
                 "--at", "-3,0,1.3", "--heading-deg", "0", "-o",
                 str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "warning: --at -3,0,1.3 lies outside the mesh's bounding box" in err
    assert Path(tmp_path / "o" / "rgb.png").is_file()
