"""``tunnelsim mesh`` carries colour and temperature from coloured clouds onto the
mesh's vertices (issue 35), through the real CLI, on a tunnel tube cloud made here
with a colour pattern (left wall red, floor dark, the rest light grey):

- the PLY's vertex colours equal, vertex by vertex, a brute-force computation over
  every point of the file (laspy reads it back): the nearest ``NEIGHBOURS`` points
  within half the mesh's median edge, averaged in linear light (IEC 61966-2-1
  written out here), the nearest point where none is within;
- every method (tunnel, poisson, solid, auto, and ``--max-triangles``) writes the
  pattern's colours on vertices away from its edges; LAS 8-bit values in 16-bit
  fields, E57 colour and PLY colour with temperature too;
- ``--no-colour`` / ``--no-temperature`` change the file; a temperature in degrees
  Celsius is refused in one line naming the option;
- ``sensors.appearance.mesh_appearance`` reads the colour as the vertex albedo, and
  ``tunnelsim render`` of the coloured mesh shows the red wall red.
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from sensors.appearance import mesh_appearance
from sensors.io.meshes import read_mesh
from survey.cli.main import main
from survey.clouds.colour import NEIGHBOURS

laspy = pytest.importorskip("laspy")
pytest.importorskip("open3d", reason="the poisson and solid routes need Open3D")

#: The tube: along +x, radius and profile centre height (m).
LENGTH_M, RADIUS_M, HC = 40.0, 3.0, 1.5
#: 8-bit sRGB colours of the pattern.
RED, DARK, GREY = (255, 0, 0), (30, 30, 30), (180, 180, 180)
N_POINTS = 30_000


def _pattern(xyz):
    """8-bit colour (n, 3) of each point: left wall (y > 1 m) red, floor (z below the
    centre by more than 2 m) dark, the rest grey."""
    y, z = xyz[:, 1], xyz[:, 2]
    rgb = np.tile(np.array(GREY), (len(xyz), 1))
    rgb[z < HC - 2.0] = DARK
    rgb[y > 1.0] = RED
    return rgb


def _tube_points(n=N_POINTS, seed=0):
    rng = np.random.default_rng(seed)
    s = rng.uniform(0.0, LENGTH_M, n)
    a = rng.uniform(-np.pi, np.pi, n)
    r = RADIUS_M + rng.normal(0.0, 0.002, n)
    return np.column_stack([s, r * np.sin(a), HC + r * np.cos(a)])


def _write_las(path, xyz, rgb16, fmt=3):
    h = laspy.LasHeader(point_format=fmt, version="1.2" if fmt < 6 else "1.4")
    h.scales, h.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(h)
    las.x, las.y, las.z = xyz.T
    las.red, las.green, las.blue = np.asarray(rgb16, dtype=np.uint16).T
    las.write(str(path))
    return path


def _run(argv):
    """(exit status, stdout, stderr) of ``tunnelsim`` in-process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


def _decode(c):
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _encode(x):
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def _brute_force(points, rgb01, vertices, radius, k=NEIGHBOURS):
    """uint8 colour of each vertex: every point's distance, in blocks of vertices."""
    lin = _decode(rgb01)
    out = np.empty((len(vertices), 3), dtype=np.uint8)
    for a in range(0, len(vertices), 64):
        v = vertices[a:a + 64]
        d = np.sqrt(((v[:, None, :] - points[None, :, :]) ** 2).sum(axis=2))
        part = np.argpartition(d, k, axis=1)[:, :k]          # the k nearest, unsorted
        rows = np.arange(len(v))[:, None]
        order = np.take_along_axis(part, np.argsort(d[rows, part], axis=1), axis=1)
        for j in range(len(v)):
            o = order[j]
            near = o[d[j, o] <= radius]
            near = near if len(near) else o[:1]
            out[a + j] = np.rint(_encode(lin[near].mean(axis=0)) * 255)
    return out


def _median_edge(vertices, faces):
    e = np.concatenate([vertices[faces[:, i]] - vertices[faces[:, (i + 1) % 3]]
                        for i in range(3)])
    return float(np.median(np.linalg.norm(e, axis=1)))


def _vertex_rgb(mesh):
    return np.column_stack([mesh.vertex_fields[k] for k in ("red", "green", "blue")])


def _check_pattern(mesh, tol=3):
    """Vertices away from the pattern's edges carry its colours."""
    v, rgb = mesh.vertices, _vertex_rgb(mesh)
    red = (v[:, 1] > 1.8) & (v[:, 0] > 2) & (v[:, 0] < LENGTH_M - 2)
    dark = (v[:, 2] < HC - 2.8) & (np.abs(v[:, 1]) < 0.5) & (v[:, 0] > 2) & \
        (v[:, 0] < LENGTH_M - 2)
    grey = (v[:, 1] < -1.8) & (v[:, 2] > HC) & (v[:, 0] > 2) & (v[:, 0] < LENGTH_M - 2)
    assert red.sum() > 10 and dark.sum() > 3 and grey.sum() > 10
    for sel, want in ((red, RED), (dark, DARK), (grey, GREY)):
        assert np.abs(rgb[sel].astype(int) - want).max() <= tol, (want, rgb[sel][:5])


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    """(folder, LAS 16-bit, LAS 8-bit in 16-bit fields, its points, its colour 8-bit)."""
    d = tmp_path_factory.mktemp("colour")
    xyz = _tube_points()
    rgb8 = _pattern(xyz)
    las16 = _write_las(d / "c16.las", xyz, rgb8 * 257)
    las8 = _write_las(d / "c8.laz", xyz, rgb8, fmt=7)
    return d, las16, las8


@pytest.fixture(scope="module")
def tunnel_mesh(clouds):
    """The tunnel mesh of the 16-bit cloud, every point (--voxel 0), and its output."""
    d, las16, _ = clouds
    out = d / "tunnel.ply"
    rc, printed, err = _run(["mesh", las16, "-o", out, "--method", "tunnel", "--voxel",
                             "0", "--cell", "0.5,6", "--json", d / "tunnel.json"])
    assert rc == 0, err
    return out, printed


def test_vertex_colours_equal_a_brute_force_over_every_point(clouds, tunnel_mesh):
    _, las16, _ = clouds
    out, printed = tunnel_mesh
    mesh = read_mesh(out)
    las = laspy.read(str(las16))
    pts = np.column_stack([las.x, las.y, las.z])
    rgb01 = np.column_stack([las.red, las.green, las.blue]) / 65535.0
    radius = 0.5 * _median_edge(mesh.vertices, mesh.faces)
    ref = _brute_force(pts, rgb01, mesh.vertices, radius)
    got = _vertex_rgb(mesh)
    assert got.dtype == np.uint8 and len(got) == len(mesh.vertices)
    diff = np.abs(got.astype(int) - ref.astype(int))
    assert diff.max() <= 1 and (diff == 0).mean() > 0.99       # rounding ties only
    _check_pattern(mesh)
    assert "support" in mesh.vertex_fields                       # kept beside colour
    assert (f"colour: vertex red green blue from c16.las: LAS RGB, 16-bit; mean of the "
            f"points within {radius * 1000:.0f} mm") in printed
    block = json.loads((out.parent / "tunnel.json").read_text())["appearance"]
    assert block["colour"]["written"] and block["radius_m"] == pytest.approx(radius)
    assert block["temperature"] == {"written": False, "why": "the clouds carry none"}


def test_mesh_appearance_reads_the_colour_as_vertex_albedo(tunnel_mesh):
    mesh = read_mesh(tunnel_mesh[0])
    app = mesh_appearance(mesh)
    assert app.source["albedo"] == "vertex" and app.albedo.per == "vertex"
    np.testing.assert_allclose(app.albedo.values, _decode(_vertex_rgb(mesh) / 255.0))
    assert app.source["temperature"] == "default"


def test_no_colour_leaves_the_colour_out(clouds, tunnel_mesh):
    d, las16, _ = clouds
    out = d / "plain.ply"
    rc, printed, _ = _run(["mesh", las16, "-o", out, "--method", "tunnel", "--voxel",
                           "0", "--cell", "0.5,6", "--no-colour"])
    assert rc == 0
    plain, coloured = read_mesh(out), read_mesh(tunnel_mesh[0])
    assert out.read_bytes() != tunnel_mesh[0].read_bytes()
    assert set(plain.vertex_fields) == {"support"}
    np.testing.assert_array_equal(plain.vertices, coloured.vertices)   # geometry same
    np.testing.assert_array_equal(plain.faces, coloured.faces)
    assert "colour: none (left out by --no-colour)" in printed


@pytest.mark.parametrize("args", [
    ["--method", "poisson", "--depth", "7", "--voxel", "0.05"],
    ["--method", "auto", "--voxel", "0.05", "--cell", "0.5,6"],
    ["--method", "tunnel", "--cell", "0.5,6", "--max-triangles", "3000"],
    ["--method", "solid", "--voxel", "0.1", "--scanners", "STATIONS"],
], ids=["poisson", "auto", "decimated", "solid"])
def test_every_method_writes_the_pattern(clouds, args):
    """The 8-bit-in-16-bit LAZ: detected as 8-bit (read as 16-bit the colours would be
    about 1/257 as bright: black)."""
    d, _, las8 = clouds
    stations = d / "stations.txt"
    stations.write_text("".join(f"{x} 0 {HC}\n" for x in range(2, 40, 4)))
    args = [str(stations) if a == "STATIONS" else a for a in args]
    out = d / f"m_{args[1]}_{len(args)}.ply"
    rc, printed, err = _run(["mesh", las8, "-o", out, *args])
    assert rc == 0, err
    mesh = read_mesh(out)
    _check_pattern(mesh)
    assert "c8.laz: LAS RGB, 8-bit values in its 16-bit fields" in printed
    if "--max-triangles" in args:
        assert len(mesh.faces) <= 3000


def test_e57_colour_through_mesh(tmp_path):
    from sensors.io.e57 import write_e57_scan

    xyz = _tube_points(20_000, seed=5)
    rgb = _pattern(xyz).astype(np.uint8)
    origin = np.array([2_600_000.0, 1_200_000.0, 450.0])     # UTM-sized pose
    p = write_e57_scan(tmp_path / "s.e57", xyz - [20, 0, HC],
                       rotation_xyzw=[0, 0, 0, 1], translation=origin + [20, 0, HC],
                       name="s", fields={"colorRed": rgb[:, 0], "colorGreen": rgb[:, 1],
                                         "colorBlue": rgb[:, 2]})
    out = tmp_path / "e.ply"
    rc, printed, err = _run(["mesh", p, "-o", out, "--method", "tunnel", "--cell", "1,8"])
    assert rc == 0, err
    mesh = read_mesh(out)
    mesh = type(mesh)(mesh.vertices - origin, mesh.faces, mesh.vertex_fields)
    _check_pattern(mesh)
    assert "s.e57: E57 colour, scaled by its colorLimits" in printed


def _ply_cloud(path, xyz, rgb8, temperature):
    from sensors.io.ply import write_ply

    rec = np.empty(len(xyz), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"),
                                    ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                                    ("temperature", "<f4")])
    rec["x"], rec["y"], rec["z"] = xyz.T
    rec["red"], rec["green"], rec["blue"] = rgb8.T
    rec["temperature"] = temperature
    write_ply(path, {"vertex": rec})
    return path


def test_temperature_round_trip_and_no_temperature(tmp_path):
    xyz = _tube_points(20_000, seed=7)
    warm = xyz[:, 1] > 1.0                      # the red wall 10 K warmer
    temp = np.where(warm, 295.0, 285.0).astype(np.float32)
    p = _ply_cloud(tmp_path / "t.ply", xyz, _pattern(xyz).astype(np.uint8), temp)
    out = tmp_path / "t_mesh.ply"
    rc, printed, err = _run(["mesh", p, "-o", out, "--method", "tunnel", "--cell", "1,8"])
    assert rc == 0, err
    mesh = read_mesh(out)
    _check_pattern(mesh)
    t = mesh.vertex_fields["temperature"]
    v = mesh.vertices
    assert t.dtype == np.float32
    hot, cold = v[:, 1] > 1.8, v[:, 1] < 0.2
    np.testing.assert_allclose(t[hot], 295.0, atol=1e-3)
    np.testing.assert_allclose(t[cold], 285.0, atol=1e-3)
    between = (v[:, 1] > 0.2) & (v[:, 1] < 1.8)
    assert ((t[between] >= 285.0 - 1e-3) & (t[between] <= 295.0 + 1e-3)).all()
    app = mesh_appearance(mesh)
    assert app.source == {"albedo": "vertex", "temperature": "vertex",
                          "emissivity": "default"}
    np.testing.assert_array_equal(app.temperature_k.values, t)
    assert "temperature: vertex temperature from t.ply: field 'temperature' (K)" in printed

    out2 = tmp_path / "t_none.ply"
    rc, printed2, _ = _run(["mesh", p, "-o", out2, "--method", "tunnel", "--cell", "1,8",
                            "--no-temperature"])
    assert rc == 0 and out2.read_bytes() != out.read_bytes()
    m2 = read_mesh(out2)
    assert "temperature" not in m2.vertex_fields and "red" in m2.vertex_fields
    assert "temperature: none (left out by --no-temperature)" in printed2


def test_temperature_in_celsius_is_refused_in_one_line(tmp_path):
    xyz = _tube_points(5_000, seed=8)
    p = _ply_cloud(tmp_path / "c.ply", xyz, _pattern(xyz).astype(np.uint8),
                   np.full(len(xyz), 12.5, dtype=np.float32))
    rc, _, err = _run(["mesh", p, "-o", tmp_path / "x.ply", "--method", "tunnel",
                       "--cell", "1,8"])
    assert rc == 2 and not (tmp_path / "x.ply").exists()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "kelvin" in lines[0] and "--no-temperature" in lines[0]
    rc, _, err = _run(["mesh", p, "-o", tmp_path / "x.ply", "--method", "tunnel",
                       "--cell", "1,8", "--no-temperature"])
    assert rc == 0, err


def _camera(tmp_path, name="realsense_d435_color", w=64, h=48):
    from sensors.camera import CAMERA_DIR, load_camera

    text = (CAMERA_DIR / f"{name}.toml").read_text()
    full = load_camera(name)
    text = text.replace(f"width = {full.width}", f"width = {w}").replace(
        f"height = {full.height}", f"height = {h}").replace(
        f'name = "{name}"', f'name = "small_{name}"')
    p = tmp_path / f"small_{name}.toml"
    p.write_text(text)
    return p


def test_render_shows_the_red_wall_red(tmp_path, tunnel_mesh, clouds):
    cv2 = pytest.importorskip("cv2", reason="OpenCV decodes the PNGs (test extra)")
    d, las16, _ = clouds
    plain = d / "plain_render.ply"
    assert _run(["mesh", las16, "-o", plain, "--method", "tunnel", "--voxel", "0",
                 "--cell", "0.5,6", "--no-colour"])[0] == 0
    cam = _camera(tmp_path)
    means = {}
    for name, mesh in (("coloured", tunnel_mesh[0]), ("plain", plain)):
        rc, printed, err = _run(["render", "--mesh", mesh, "--camera", cam, "--at",
                                 f"3,0,{HC}", "--heading-deg", "0", "--no-noise",
                                 "-o", tmp_path / name])
        assert rc == 0, err
        img = cv2.imread(str(tmp_path / name / "rgb.png"), cv2.IMREAD_UNCHANGED)
        rgb = img[..., ::-1].astype(float)
        left = rgb[:, : rgb.shape[1] // 2]          # looking along +x: y > 0 is left
        means[name] = left.reshape(-1, 3).mean(axis=0)
        if name == "coloured":
            assert "albedo from vertex" in printed
    r, g, b = means["coloured"]
    assert r > 3 * g and r > 3 * b and r > 5          # a dark image (default lamp)
    pr, pg, _ = means["plain"]                      # grey default: no red cast
    assert abs(pr - pg) < 0.05 * max(pr, 1.0)
