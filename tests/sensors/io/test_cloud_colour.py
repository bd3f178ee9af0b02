"""Colour and temperature read from cloud files (issue 35): LAS RGB 16-bit and 8-bit
values in 16-bit fields (detected as CloudCompare does), PLY uchar/ushort/float
colour, E57 colour with its colorLimits, temperature in kelvin (LAS extra bytes with
scale, offset and no-data; PLY); files written here by laspy, pye57 and the PLY
writer, the values read back compared with what was written."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sensors.io.cloudfields import MIN_KELVIN, cloud_appearance, iter_appearance
from sensors.io.errors import PointFileError
from sensors.io.ply import write_ply

laspy = pytest.importorskip("laspy")


def _xyz(n, seed=0):
    return np.random.default_rng(seed).uniform(-5, 5, (n, 3))


def _las(path, xyz, rgb=None, fmt=3, temperature=None, no_data=None):
    h = laspy.LasHeader(point_format=fmt, version="1.2" if fmt < 6 else "1.4")
    h.scales, h.offsets = [0.001] * 3, [0.0] * 3
    if temperature is not None:
        h.add_extra_dim(laspy.ExtraBytesParams(
            name="temperature", type=np.int16, scales=np.array([0.01]),
            offsets=np.array([290.0]),
            no_data=None if no_data is None else np.array([no_data])))
    las = laspy.LasData(h)
    las.x, las.y, las.z = xyz.T
    if rgb is not None:
        las.red, las.green, las.blue = np.asarray(rgb, dtype=np.uint16).T
    if temperature is not None:
        las.temperature = temperature
    las.write(str(path))
    return path


def _all(path, **kw):
    parts = list(iter_appearance(path, **kw))
    xyz = np.concatenate([p[0] for p in parts])
    rgb = None if parts[0][1] is None else np.concatenate([p[1] for p in parts])
    t = None if parts[0][2] is None else np.concatenate([p[2] for p in parts])
    return xyz, rgb, t


@pytest.mark.parametrize("fmt", [2, 3, 7, 8])
def test_las_16_bit_colour(tmp_path, fmt):
    xyz = _xyz(500)
    rgb = np.random.default_rng(1).integers(0, 65536, (500, 3))
    rgb[0] = [65535, 300, 0]                  # one value above 255: 16-bit
    p = _las(tmp_path / "c.las", xyz, rgb, fmt=fmt)
    app = cloud_appearance(p)
    assert app.colour is not None and app.colour.how == "LAS RGB, 16-bit"
    got_xyz, got, t = _all(p, chunk=128)
    np.testing.assert_allclose(got_xyz, xyz, atol=5e-4)
    np.testing.assert_array_equal(got, rgb / 65535.0)
    assert t is None


def test_las_8_bit_values_in_16_bit_fields(tmp_path):
    xyz = _xyz(400)
    rgb = np.random.default_rng(2).integers(0, 256, (400, 3))
    rgb[0] = [255, 0, 7]
    p = _las(tmp_path / "c.laz", xyz, rgb)
    app = cloud_appearance(p)
    assert app.colour is not None and "8-bit" in app.colour.how
    _, got, _ = _all(p)
    np.testing.assert_array_equal(got, rgb / 255.0)
    # one value above 255 anywhere in the file (here the last chunk) makes it 16-bit
    rgb[-1] = [256, 0, 0]
    p2 = _las(tmp_path / "d.laz", xyz, rgb)
    _, got2, _ = _all(p2, chunk=100)
    np.testing.assert_array_equal(got2, rgb / 65535.0)


def test_black_everywhere_and_no_colour_fields_are_no_colour(tmp_path):
    xyz = _xyz(50)
    assert cloud_appearance(_las(tmp_path / "z.las", xyz, np.zeros((50, 3)))).colour is None
    assert cloud_appearance(_las(tmp_path / "n.las", xyz, fmt=1)).colour is None
    _, rgb, t = _all(tmp_path / "n.las")
    assert rgb is None and t is None


def _ply(path, xyz, **props):
    dt = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")] + [
        (k, np.asarray(v).dtype.str) for k, v in props.items()]
    rec = np.empty(len(xyz), dtype=dt)
    rec["x"], rec["y"], rec["z"] = xyz.T
    for k, v in props.items():
        rec[k] = v
    write_ply(path, {"vertex": rec})
    return path


@pytest.mark.parametrize("dtype,scale", [(np.uint8, 255.0), (np.uint16, 65535.0),
                                         (np.float32, 1.0)])
def test_ply_colour_types(tmp_path, dtype, scale):
    xyz = _xyz(300)
    rng = np.random.default_rng(3)
    rgb = (rng.uniform(0, 1, (300, 3)) * scale).astype(dtype)
    p = _ply(tmp_path / "c.ply", xyz, red=rgb[:, 0], green=rgb[:, 1], blue=rgb[:, 2])
    _, got, _ = _all(p)
    np.testing.assert_allclose(got, rgb.astype(np.float64) / scale, rtol=1e-12)


def test_ply_float_colour_above_one_is_refused(tmp_path):
    xyz = _xyz(10)
    c = np.full(10, 200.0, dtype=np.float32)
    p = _ply(tmp_path / "c.ply", xyz, red=c, green=c, blue=c)
    with pytest.raises(PointFileError, match=r"\[0, 1\].*--no-colour"):
        cloud_appearance(p)


def test_e57_colour_with_its_limits(tmp_path):
    from sensors.io.e57 import read_e57_colour, write_e57_scan

    local = _xyz(200)
    rgb = np.random.default_rng(4).integers(0, 256, (200, 3)).astype(np.uint8)
    q = Rotation.from_euler("z", 25, degrees=True).as_quat()
    p = write_e57_scan(tmp_path / "s.e57", local, rotation_xyzw=q,
                       translation=[10.0, 20.0, 1.0], name="s",
                       fields={"colorRed": rgb[:, 0], "colorGreen": rgb[:, 1],
                               "colorBlue": rgb[:, 2]})
    app = cloud_appearance(p)
    assert app.colour is not None and "colorLimits" in app.colour.how
    xyz, got, t = _all(p)
    # pye57 writes colorLimits 0-255 (its writer) and float32 coordinates
    np.testing.assert_array_equal(got, rgb / 255.0)
    np.testing.assert_allclose(xyz, Rotation.from_quat(q).apply(local) + [10, 20, 1],
                               atol=2e-5)
    assert t is None
    # the same points as the colourless reader gives
    (plain,) = [c for c, _ in read_e57_colour(p)]
    np.testing.assert_array_equal(plain, xyz)


def test_las_temperature_extra_bytes_scaled_with_no_data(tmp_path):
    xyz = _xyz(200)
    t = np.linspace(280.0, 300.0, 200).round(2)
    raw_nodata = -32768
    p = _las(tmp_path / "t.las", xyz, np.full((200, 3), 1000), temperature=t,
             no_data=raw_nodata)
    # mark two points as "no data" through their stored value
    las = laspy.read(str(p))
    las.points.array["temperature"][[3, 7]] = raw_nodata
    las.write(str(p))
    assert cloud_appearance(p).temperature == "temperature"
    _, _, got = _all(p)
    expect = t.copy()
    expect[[3, 7]] = np.nan
    np.testing.assert_allclose(got, expect, atol=0.006)      # 0.01 K steps
    assert np.isnan(got[[3, 7]]).all()
    _, _, none = _all(p, temperature=False)
    assert none is None


def test_temperature_in_celsius_is_refused(tmp_path):
    xyz = _xyz(20)
    p = _ply(tmp_path / "c.ply", xyz, temperature=np.full(20, 14.0, dtype=np.float32))
    assert MIN_KELVIN > 14.0
    with pytest.raises(PointFileError, match="kelvin.*--no-temperature"):
        _all(p)
    p2 = _ply(tmp_path / "k.ply", xyz, temperature=np.full(20, 287.15, dtype=np.float32))
    np.testing.assert_allclose(_all(p2)[2], 287.15, rtol=1e-7)
