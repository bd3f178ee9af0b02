"""``tunnelsim preprocess`` keeps a cloud's colour (issue 35), through the real CLI:
a voxel's colour is the linear-light mean of its points' colour, written as LAS RGB
16-bit, compared with a voxel-by-voxel computation here (the voxel index from Open3D's
anchoring, written out; IEC 61966-2-1 written out); without a grid every point keeps
its colour; ``preprocess`` then ``mesh`` gives the mesh the cloud's colours."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest

from survey.cli.main import main

laspy = pytest.importorskip("laspy")


def _decode(c):
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _encode(x):
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def _las(path, xyz, rgb, fmt=3):
    h = laspy.LasHeader(point_format=fmt, version="1.2")
    h.scales, h.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(h)
    las.x, las.y, las.z = xyz.T
    las.red, las.green, las.blue = np.asarray(rgb, dtype=np.uint16).T
    las.write(str(path))
    return path


def _run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


def _read(path):
    las = laspy.read(str(path))
    return (np.column_stack([las.x, las.y, las.z]),
            np.column_stack([las.red, las.green, las.blue]), las)


def test_voxel_colour_is_the_linear_mean_of_its_points(tmp_path):
    rng = np.random.default_rng(0)
    xyz = rng.uniform(0, 3, (4000, 3))
    rgb8 = rng.integers(0, 256, (4000, 3))                 # 8-bit in 16-bit fields
    src = _las(tmp_path / "in.las", xyz, rgb8)
    rc, _, err = _run(["preprocess", src, "-o", tmp_path / "out.las", "--voxel", "0.5"])
    assert rc == 0, err
    pts_in, _, _ = _read(src)
    out_xyz, out_rgb, las = _read(tmp_path / "out.las")
    assert las.header.point_format.id == 7
    # voxel of every input point: anchor = min - voxel / 2 (Open3D)
    v = 0.5
    key = np.floor((pts_in - (pts_in.min(axis=0) - v / 2)) / v).astype(int)
    out_key = np.floor((out_xyz - (pts_in.min(axis=0) - v / 2)) / v).astype(int)
    lin = _decode(rgb8 / 255.0)
    assert len(out_xyz) == len(np.unique(key, axis=0))
    for k, c in zip(out_key, out_rgb):
        sel = (key == k).all(axis=1)
        want = np.rint(_encode(lin[sel].mean(axis=0)) * 65535)
        np.testing.assert_allclose(c, want, atol=1)


def test_without_a_grid_each_point_keeps_its_colour(tmp_path):
    rng = np.random.default_rng(1)
    xyz = rng.uniform(0, 3, (500, 3))
    rgb16 = rng.integers(0, 65536, (500, 3))
    src = _las(tmp_path / "in.laz", xyz, rgb16)
    assert _run(["preprocess", src, "-o", tmp_path / "out.laz"])[0] == 0
    p_in, c_in, _ = _read(src)
    p_out, c_out, _ = _read(tmp_path / "out.laz")
    o_in, o_out = np.lexsort(p_in.T), np.lexsort(p_out.T)
    np.testing.assert_allclose(p_out[o_out], p_in[o_in], atol=1e-6)
    np.testing.assert_array_equal(c_out[o_out], c_in[o_in])


def test_an_uncoloured_cloud_stays_format_6(tmp_path):
    xyz = np.random.default_rng(2).uniform(0, 3, (200, 3))
    src = _las(tmp_path / "in.las", xyz, np.zeros((200, 3)))       # black: no colour
    assert _run(["preprocess", src, "-o", tmp_path / "out.las", "--voxel", "0.5"])[0] == 0
    assert laspy.read(str(tmp_path / "out.las")).header.point_format.id == 6


def test_preprocess_then_mesh_keeps_the_colour(tmp_path):
    pytest.importorskip("open3d")
    rng = np.random.default_rng(3)
    n = 30_000
    s, a = rng.uniform(0, 40, n), rng.uniform(-np.pi, np.pi, n)
    xyz = np.column_stack([s, 3 * np.sin(a), 1.5 + 3 * np.cos(a)])
    rgb8 = np.where((xyz[:, 1] > 1.0)[:, None], [255, 0, 0], [180, 180, 180])
    src = _las(tmp_path / "in.las", xyz, rgb8)
    assert _run(["preprocess", src, "-o", tmp_path / "clean.laz", "--voxel", "0.1"])[0] == 0
    rc, printed, err = _run(["mesh", tmp_path / "clean.laz", "-o", tmp_path / "m.ply",
                             "--method", "tunnel", "--cell", "1,8"])
    assert rc == 0, err
    from sensors.io.meshes import read_mesh

    m = read_mesh(tmp_path / "m.ply")
    rgb = np.column_stack([m.vertex_fields[k] for k in ("red", "green", "blue")])
    red = m.vertices[:, 1] > 1.8
    grey = m.vertices[:, 1] < 0.2
    assert np.abs(rgb[red].astype(int) - [255, 0, 0]).max() <= 2
    assert np.abs(rgb[grey].astype(int) - [180, 180, 180]).max() <= 2
    assert "clean.laz: LAS RGB, 16-bit" in printed
