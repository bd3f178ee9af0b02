"""``tunnelsim render`` and ``cameras`` against their library functions (issue 32's
design, issue 35's commands): the CLI in-process and ``survey.workflows.render`` on the
same inputs in two folders write the same files byte for byte (no file of a frame
embeds a time stamp or the command line), the CLI prints the result's numbers, and
both refuse alike."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace.shapes import tunnel_tube
from sensors.camera import CAMERA_DIR, list_cameras, load_camera
from sensors.errors import CameraSpecError, SimulationError
from sensors.io.meshes import write_mesh
from survey.cli.main import main
from survey.workflows.render import camera_models, render_frame


def _files(root):
    return {p.name: p.read_bytes() for p in sorted(root.iterdir())}


@pytest.fixture()
def scene(tmp_path):
    v, f = tunnel_tube(3_000, length_m=20.0, seed=1)
    mesh = tmp_path / "tube.ply"
    write_mesh(mesh, v, f, face_fields={"label": (np.arange(len(f)) % 9).astype(np.uint8)})
    cams = {}
    for name in ("realsense_d435_color", "lwir_640", "realsense_d435_depth"):
        full = load_camera(name)
        text = (CAMERA_DIR / f"{name}.toml").read_text().replace(
            f"width = {full.width}", "width = 48").replace(
            f"height = {full.height}", "height = 36")
        cams[name] = tmp_path / f"{name}.toml"
        cams[name].write_text(text)
    return mesh, cams


@pytest.mark.parametrize("kind", ["realsense_d435_color", "lwir_640",
                                  "realsense_d435_depth"])
def test_render_cli_and_library_write_the_same_files(tmp_path, capsys, scene, kind):
    mesh, cams = scene
    assert main(["render", "--mesh", str(mesh), "--camera", str(cams[kind]), "--at",
                 "4,0.2,1.2", "--heading-deg", "10", "--pitch-deg", "-5", "--roll-deg",
                 "3", "--lamp-cd", "3000", "--seed", "7", "-o",
                 str(tmp_path / "cli")]) == 0
    said = capsys.readouterr().out.splitlines()
    r = render_frame(mesh, cams[kind], [4.0, 0.2, 1.2], tmp_path / "lib",
                     heading_deg=10.0, pitch_deg=-5.0, roll_deg=3.0, lamp_cd=3000.0,
                     seed=7)
    a, b = _files(tmp_path / "cli"), _files(tmp_path / "lib")
    assert a == b and sorted(a) == sorted(p.name for p in r.files)
    assert said[0] == (f"{r.camera} ({r.kind}, 48x36): {r.hit_fraction:.1%} of pixels "
                       f"hit the mesh; depth {r.depth_min_m:.3f}-{r.depth_max_m:.3f} m "
                       f"(median {r.depth_median_m:.3f} m) on {r.valid_fraction:.1%}")
    assert said[-len(r.files):] == [f"wrote {tmp_path / 'cli' / p.name}" for p in r.files]
    depth = np.load(tmp_path / "lib" / "depth.npy")
    assert r.depth_min_m == pytest.approx(float(np.nanmin(depth)), abs=1e-6)
    assert r.valid_fraction == np.isfinite(depth).mean()


def test_render_refuses_alike(tmp_path, capsys, scene):
    mesh, _ = scene
    with pytest.raises(CameraSpecError, match="--camera: Expected a camera name"):
        render_frame(mesh, "nope", [4, 0, 1.2], tmp_path / "x", heading_deg=0.0)
    with pytest.raises(SimulationError, match="pass --at inside the mesh"), \
            pytest.warns(UserWarning, match="outside the mesh's bounding box"):
        render_frame(mesh, "lwir_640", [-30, 0, 1.2], tmp_path / "x", heading_deg=180.0)
    for args, text in ((["--camera", "nope"], "--camera: Expected a camera name"),
                       (["--camera", "lwir_640", "--at", "-30,0,1.2", "--heading-deg",
                         "180"], "pass --at inside the mesh")):
        argv = ["render", "--mesh", str(mesh), "--at", "4,0,1.2", "--heading-deg", "0",
                "-o", str(tmp_path / "y"), *args]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert text in err and len(err.strip().splitlines()) <= 2


def test_camera_models_are_the_shipped_files(capsys):
    models = camera_models()
    assert [m.name for m in models] == list_cameras()
    assert main(["cameras"]) == 0
    lines = capsys.readouterr().out.splitlines()
    for m, line in zip(models, lines):
        c = load_camera(m.name)
        assert line.startswith(f"{m.name} ") and f"{m.width}x{m.height}" in line
        # Field of view through the image's edges, from K: 2 atan(w / 2 / fx).
        assert m.hfov_deg == pytest.approx(np.degrees(2 * np.arctan(c.width / 2 / c.fx)))
        assert m.vfov_deg == pytest.approx(np.degrees(2 * np.arctan(c.height / 2 / c.fy)))
