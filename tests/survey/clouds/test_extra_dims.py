"""Extra dimensions kept and described (issue 31, item 6).

- The voxel grid carries per-point fields: a floating-point field's voxel value is the
  mean of its points, an integer field's the value of its first point in input order;
  checked against the definition written out (a dict of voxels), and chunking does not
  change it (hypothesis).
- ``preprocess``'s library path keeps a LAS input's extra dimensions (``section``,
  ``chainage``, a scaled one) with their types, scales and descriptions, read back with
  laspy.
- Every extra dimension tunnelsim writes is described with its unit: the 32-byte
  descriptions of the extra-bytes VLR parsed by hand (``tests/sensors/lasbytes.py``'s
  layout, LAS 1.4 R15 table 24), the simulation's fields against ``FIELD_UNITS``, and
  compare's output through the real command line.
"""

from __future__ import annotations

import struct

import laspy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensors.io.fields import FIELD_UNITS, FILE_FIELDS, LAS_DESCRIPTIONS
from sensors.io.las import write_las
from survey.cli.main import main
from survey.clouds.preprocess import (
    VoxelGrid,
    extra_dims,
    iter_points_extra,
    write_preprocessed,
)

UNIT_WORDS = {"m": "[m]", "rad": "[rad]", "s": "[s]"}


def _naive(p, size, fields):
    """{voxel index tuple: (mean point, {field: mean or first value})}, in input order."""
    anchor = p.min(axis=0) - size / 2
    cells: dict = {}
    for i, q in enumerate(p):
        key = tuple(np.floor((q - anchor) / size).astype(int))
        cells.setdefault(key, []).append(i)
    out = {}
    for key, idx in cells.items():
        vals = {k: (np.mean(v[idx].astype(np.float64)) if v.dtype.kind == "f"
                    else v[idx[0]]) for k, v in fields.items()}
        out[key] = (p[idx].mean(axis=0), vals)
    return out


def _grid_by_key(pts, vals, p, size):
    anchor = p.min(axis=0) - size / 2
    keys = [tuple(np.floor((q - anchor) / size).astype(int)) for q in pts]
    return {k: (pts[i], {f: v[i] for f, v in vals.items()}) for i, k in enumerate(keys)}


def _cloud(n, seed):
    rng = np.random.default_rng(seed)
    p = rng.uniform(0, 3, (n, 3))
    fields = {"chainage": rng.uniform(100, 200, n), "section": rng.integers(0, 9, n)
              .astype(np.uint16), "gain": rng.normal(0, 1, n).astype(np.float32)}
    return p, fields


def test_voxel_fields_equal_the_definition():
    p, f = _cloud(4000, 0)
    g = VoxelGrid(0.5, p.min(axis=0))
    g.add(p, f)
    pts, counts = g.result()
    vals = g.fields()
    assert vals["section"].dtype == np.uint16 and vals["chainage"].dtype == np.float64
    want = _naive(p, 0.5, f)
    got = _grid_by_key(pts, vals, p, 0.5)
    assert set(got) == set(want) and counts.sum() == len(p)
    for key, (c, v) in want.items():
        np.testing.assert_allclose(got[key][0], c, atol=1e-12)
        assert got[key][1]["section"] == v["section"]
        np.testing.assert_allclose(got[key][1]["chainage"], v["chainage"], rtol=1e-12)
        np.testing.assert_allclose(got[key][1]["gain"], v["gain"], rtol=1e-6, atol=1e-6)


@settings(max_examples=30, deadline=None)
@given(cuts=st.lists(st.integers(1, 599), max_size=6), peek=st.booleans(),
       seed=st.integers(0, 1000))
def test_chunks_and_merges_do_not_change_the_fields(cuts, peek, seed):
    """Property: any split of the input into chunks, with a merge (``fields()``)
    between them or not, gives the one-pass values (first value in input order
    included)."""
    p, f = _cloud(600, seed)
    one = VoxelGrid(0.4, p.min(axis=0))
    one.add(p, f)
    g = VoxelGrid(0.4, p.min(axis=0))
    bounds = [0, *sorted(set(cuts)), len(p)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        g.add(p[a:b], {k: v[a:b] for k, v in f.items()})
        if peek:
            g.fields()
    np.testing.assert_array_equal(g.result()[1], one.result()[1])
    for k, v in one.fields().items():
        np.testing.assert_allclose(g.fields()[k], v, rtol=1e-12, atol=1e-12)


def _las_with_extra(path, n=3000, seed=1):
    """A LAS 1.4 (format 6) with extra dimensions section (u2), chainage (f8) and a
    scaled temperature (i4, 0.01 degC steps), each described."""
    rng = np.random.default_rng(seed)
    head = laspy.LasHeader(point_format=6, version="1.4")
    head.scales, head.offsets = np.full(3, 1e-4), np.array([2_600_000.0, 1_200_000.0, 0])
    head.add_extra_dims([
        laspy.ExtraBytesParams("section", np.uint16, description="tunnel section [index]"),
        laspy.ExtraBytesParams("chainage", np.float64, description="chainage [m]"),
        laspy.ExtraBytesParams("temp", np.int32, description="rock temperature [degC]",
                               scales=np.array([0.01]), offsets=np.array([0.0]))])
    las = laspy.LasData(head, points=laspy.ScaleAwarePointRecord.zeros(n, header=head))
    xyz = head.offsets + rng.uniform(0, 4, (n, 3))
    las.x, las.y, las.z = xyz.T
    las.section = rng.integers(1, 30, n)
    las.chainage = rng.uniform(1000, 1010, n)
    las.temp = np.round(rng.uniform(5, 25, n), 2)
    las.write(path)
    return laspy.read(path)


@pytest.mark.parametrize("voxel", [None, 0.5])
def test_preprocess_keeps_extra_dimensions(tmp_path, voxel):
    """The steps ``tunnelsim preprocess`` runs (reader, voxel grid, writer): every
    extra dimension arrives with its type, scale and description; with a grid its
    values are the definition's (mean chainage, first section and temperature), without
    one they are the input's."""
    src = _las_with_extra(tmp_path / "in.las")
    dims = extra_dims(tmp_path / "in.las")
    assert list(dims) == ["section", "chainage", "temp"]
    parts = list(iter_points_extra(tmp_path / "in.las", chunk=700))
    xyz = np.concatenate([p for p, _ in parts])
    f = {k: np.concatenate([v[k] for _, v in parts]) for k in dims}
    if voxel is None:
        pts, counts, vals = xyz, np.ones(len(xyz), np.int64), f
    else:
        g = VoxelGrid(voxel, xyz.min(axis=0))
        for p, v in parts:
            g.add(p, v)
        pts, counts = g.result()
        vals = g.fields()
    write_preprocessed(tmp_path / "out.laz", pts, counts, vals, dims)
    _check_preprocessed(src, tmp_path / "out.laz", voxel)


def _check_preprocessed(src, path, voxel):
    """The output keeps every extra dimension of ``src`` (type, scale, description);
    its values are the input's (no grid) or the definition's per voxel."""
    out = laspy.read(path)
    info = {e.name: (e.dtype, e.description, None if e.scales is None else
                     float(e.scales[0])) for e in out.point_format.extra_dimensions}
    assert info == {"voxel_count": (np.dtype("u4"), "input points in voxel [count]", None),
                    "section": (np.dtype("u2"), "tunnel section [index]", None),
                    "chainage": (np.dtype("f8"), "chainage [m]", None),
                    "temp": (np.dtype("i4"), "rock temperature [degC]", 0.01)}
    oxyz = np.stack([out.x, out.y, out.z], 1)
    sxyz = np.stack([src.x, src.y, src.z], 1)
    if voxel is None:
        np.testing.assert_array_equal(out.section, src.section)
        np.testing.assert_array_equal(out.chainage, src.chainage)
        np.testing.assert_allclose(out.temp, src.temp, atol=1e-9)
        assert np.all(out.voxel_count == 1)
        return
    want = _naive(sxyz, voxel, {"section": np.asarray(src.section),
                                "chainage": np.asarray(src.chainage),
                                "temp": np.asarray(src.points.array["temp"])})
    got = _grid_by_key(oxyz, {"section": np.asarray(out.section),
                              "chainage": np.asarray(out.chainage),
                              "temp": np.asarray(out.points.array["temp"]),
                              "n": np.asarray(out.voxel_count)}, sxyz, voxel)
    assert set(got) == set(want)
    assert sum(v[1]["n"] for v in got.values()) == len(sxyz)
    for key, (c, v) in want.items():
        assert np.abs(got[key][0] - c).max() <= 0.5e-4 + 1e-9
        assert got[key][1]["section"] == v["section"]
        assert got[key][1]["temp"] == v["temp"]          # stored integers: first
        assert got[key][1]["chainage"] == pytest.approx(v["chainage"], rel=1e-12)


@pytest.mark.parametrize("voxel", [None, 0.5])
def test_preprocess_cli_keeps_extra_dimensions(tmp_path, capsys, voxel):
    """The file ``tunnelsim preprocess`` gives the user (issue 31's acceptance)."""
    src = _las_with_extra(tmp_path / "in.las")
    rc = main(["preprocess", str(tmp_path / "in.las"), "-o", str(tmp_path / "out.laz"),
               "--quiet", *([] if voxel is None else ["--voxel", str(voxel)])])
    assert rc == 0, capsys.readouterr().err
    _check_preprocessed(src, tmp_path / "out.laz", voxel)


def _raw_descriptions(path):
    """{name: description} of a LAS file's extra-bytes VLR, parsed by hand."""
    from tests.sensors.lasbytes import read_records

    head, _ = read_records(path.read_bytes())
    data = [d for u, rid, _, d in head["vlrs"] if (u, rid) == ("LASF_Spec", 4)][0]
    out = {}
    for i in range(0, len(data), 192):
        name = struct.unpack_from("<32s", data, i + 4)[0].rstrip(b"\0").decode()
        out[name] = struct.unpack_from("<32s", data, i + 160)[0].rstrip(b"\0").decode()
    return out


def test_every_field_tunnelsim_writes_is_described_with_its_unit(tmp_path):
    xyz = np.random.default_rng(2).uniform(0, 5, (50, 3))
    write_las(tmp_path / "all.las", xyz,
              extra={k: np.zeros(50, np.float32) for k in LAS_DESCRIPTIONS})
    assert _raw_descriptions(tmp_path / "all.las") == LAS_DESCRIPTIONS
    for f in FILE_FIELDS:            # the simulation's units, as sensors.io.fields has them
        if f.name in LAS_DESCRIPTIONS and FIELD_UNITS[f.field] in UNIT_WORDS:
            assert LAS_DESCRIPTIONS[f.name].endswith(UNIT_WORDS[FIELD_UNITS[f.field]])
    from survey.analysis.m3c2 import M3C2Result

    res = M3C2Result(*(np.zeros(3) if k != "normal" else np.zeros((3, 3))
                       for k in ("distance", "lod", "significant", "spread1", "spread2",
                                 "n1", "n2", "normal", "normal_radius")))
    assert set(res.fields()) <= set(LAS_DESCRIPTIONS)


def test_simulated_las_fields_are_described(tmp_path):
    from sensors.io.fields import POINT_DTYPE
    from sensors.writers import open_writer

    pts = np.zeros(20, POINT_DTYPE)
    pts["x"] = np.arange(20.0)
    with open_writer(tmp_path / "sim.las", sensor="velodyne_vlp16", fields="full") as w:
        w.write_points(pts)
    got = _raw_descriptions(tmp_path / "sim.las")
    assert got == {f.name: f.description for f in FILE_FIELDS
                   if f.las not in ("xyz", "standard")}
    assert got["range"] == "measured range [m]" and got["azimuth"].endswith("[rad]")


def test_compare_output_fields_are_described(tmp_path, capsys):
    xyz = np.random.default_rng(3).uniform(0, 5, (200, 3))
    write_las(tmp_path / "a.las", xyz)
    a = laspy.read(tmp_path / "a.las")
    np.savetxt(tmp_path / "ref.xyz", np.stack([a.x, a.y, a.z], 1) + [0.0, 0.0, 0.01])
    rc = main(["compare", str(tmp_path / "a.las"), str(tmp_path / "ref.xyz"), "-o",
               str(tmp_path / "cmp"), "--split", "--quiet"])
    assert rc == 0, capsys.readouterr().err
    out = laspy.read(tmp_path / "cmp" / "a_distance.laz")
    desc = {e.name: e.description for e in out.point_format.extra_dimensions}
    assert desc == {"distance": "distance to reference [m]",
                    "dx": "x of distance vector [m]", "dy": "y of distance vector [m]",
                    "dz": "z of distance vector [m]"}
    np.testing.assert_allclose(out.distance, 0.01, atol=1e-6)
