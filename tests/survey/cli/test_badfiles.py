"""Bad and foreign files through the real command line (issue 14, item 9).

Every command that reads a cloud gets an empty file, a file cut short (LAS, LAZ, PLY),
a corrupt header, a header that promises more points than the file holds, a valid file
without points and one with a NaN coordinate: each answers with ONE line on stderr that
names the problem, exit status 2, no traceback, and leaves no output behind.

Files from other writers (LAS 1.1-1.4, formats 0-10, extra bytes, VLRs, EVLRs, LAS 1.3
waveform data, COPC, a header with bounds 1000x wrong) go through preprocess, compare
and transform, which keep every field, VLR and EVLR of their input.

All files are made here (``tests/iofiles.py``), with laspy, pye57 and plain bytes.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import laspy
import numpy as np
import pytest

from survey.cli.main import main
from sensors.io.errors import PointFileError
from tests import iofiles as F

N = 600                                     # points of every good input (iofiles)
SHIFT = np.array([10.0, 20.0, 3.0])         # the Helmert transform used: a translation


# ---------------------------------------------------------------------- inputs
def _good_las(p):
    F.las_file(p)


def _cut(frac):
    def make(p):
        (_good_ply if p.suffix == ".ply" else _good_las)(p)
        F.truncate(p, frac)
    return make


def _good_ply(p):
    F.ply_cloud(p, F.tunnel_points(), extra={"time": np.linspace(1e5, 1e5 + 60, N)})


def _overcount(p):
    if p.suffix == ".ply":
        _good_ply(p)
        F.set_ply_count(p, 695_000)
    else:
        _good_las(p)
        F.set_las_count(p, 695_000)


def _zero_points(p):
    if p.suffix == ".ply":
        F.ply_cloud(p, np.empty((0, 3)))
    else:
        F.las_file(p, np.empty((0, 3)))


def _nan(p):
    xyz = F.tunnel_points()
    xyz[17, 1] = np.nan
    if p.suffix == ".ply":
        F.ply_cloud(p, xyz, extra={"time": np.linspace(1e5, 1e5 + 60, N)})
    elif p.suffix == ".xyz":
        np.savetxt(p, xyz)
    else:
        _good_las(p)
        F.set_las_offset_nan(p)


def _bad_ply_header(p):
    p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex lots\n"
                  b"property double x\nend_header\n" + bytes(64))


#: (case, suffix, builder, what the one line must say)
BAD = [
    ("empty", ".las", lambda p: p.write_bytes(b""), r"empty \(0 bytes\)"),
    ("empty", ".ply", lambda p: p.write_bytes(b""), r"empty \(0 bytes\)"),
    ("zeros-header", ".las", F.zeros_after_signature, r"LAS version 0\.0 .*corrupt"),
    ("bad-header", ".ply", _bad_ply_header, "malformed line 'element vertex lots'"),
    ("cut-short", ".las", _cut(0.6), r"Expected 600 points .* got \d+ whole point records"),
    ("cut-short", ".laz", _cut(0.6), r"Expected 600 points .* got \d+ points before"),
    ("cut-short", ".ply", _cut(0.6), r"Expected 600 vertex records .* got \d+ whole ones"),
    ("overcount", ".las", _overcount, r"Expected 695,000 points .* got 600 whole"),
    ("overcount", ".laz", _overcount, r"Expected 695,000 points .* got \d+ points"),
    ("overcount", ".ply", _overcount, r"Expected 695,000 vertex records .* got 600"),
    ("zero-points", ".las", _zero_points, "got a valid file with 0 points"),
    ("zero-points", ".ply", _zero_points, "got a valid file with 0 points"),
    ("nan", ".ply", _nan, r"point 17 with a NaN coordinate"),
    ("nan", ".xyz", _nan, r"point 17 with a NaN coordinate"),
    ("nan-offset", ".las", _nan, r"offsets .* NaN"),
    ("e57-empty-scan", ".e57", F.e57_empty_scan, "got a valid file with 0 points"),
    ("e57-checksum", ".e57",
     lambda p: (F.e57_file(p, [F.tunnel_points()]), _flip(p, 1500)), "checksum mismatch"),
    ("e57-empty", ".e57", lambda p: p.write_bytes(b""), r"empty \(0 bytes\)"),
]


def _flip(p, at):
    b = bytearray(p.read_bytes())
    b[at] ^= 0xFF
    p.write_bytes(bytes(b))


# ---------------------------------------------------------------------- commands
@pytest.fixture(scope="module")
def aux(tmp_path_factory):
    """The good inputs a command needs beside the cloud under test."""
    d = tmp_path_factory.mktemp("aux")
    F.las_file(d / "ref.laz", seed=1)
    (d / "helmert.json").write_text(json.dumps(
        {"model": "6", "translation_m": SHIFT.tolist(), "rotation_arcsec": [0, 0, 0],
         "scale_ppm": 0.0}))
    t = np.linspace(1e5 - 1, 1e5 + 61, 63)
    o = np.asarray(F.tunnel_points(1))[0]
    (d / "traj.txt").write_text("".join(f"{ti} {o[0] + ti - 1e5} {o[1]} {o[2]} 0 0 0 1\n"
                                        for ti in t))
    cp = F.tunnel_points(8, seed=9)
    (d / "cp.csv").write_text("id,x,y,z\n" + "".join(
        f"C{i},{x},{y},{z}\n" for i, (x, y, z) in enumerate(cp)))
    (d / "cp_mls.csv").write_text("id,x,y,z,time\n" + "".join(
        f"C{i},{x},{y},{z},{1e5 + 7 * i}\n" for i, (x, y, z) in enumerate(cp)))
    return d


def _argv(command, cloud: Path, out: Path, aux: Path) -> list[str]:
    suffix = cloud.suffix if cloud.suffix in (".las", ".laz", ".ply") else ".laz"
    return {
        "preprocess": ["preprocess", str(cloud), "-o", str(out / "o.laz"), "--voxel",
                       "0.05"],
        "mesh": ["mesh", str(cloud), "-o", str(out / "m.ply")],
        "compare": ["compare", str(cloud), str(aux / "ref.laz"), "-o", str(out / "cmp")],
        "compare-reference": ["compare", str(aux / "ref.laz"), str(cloud), "-o",
                              str(out / "cmp")],
        "transform": ["transform", str(cloud), "--helmert", str(aux / "helmert.json"),
                      "-o", str(out / f"t{suffix}")],
        "correct": ["correct", "--trajectory", str(aux / "traj.txt"), "--cloud",
                    str(cloud), "--control", str(aux / "cp.csv"), "--observed",
                    str(aux / "cp_mls.csv"), "--model", "global", "-o",
                    str(out / f"c{suffix}")],
    }[command] + ["--quiet"]


#: Commands and the suffixes they read.
READERS = {"preprocess": (".las", ".laz", ".ply", ".xyz", ".e57"),
           "mesh": (".las", ".laz", ".ply", ".xyz", ".e57"),
           "compare": (".las", ".laz", ".ply", ".xyz", ".e57"),
           "compare-reference": (".las", ".laz", ".ply", ".xyz", ".e57"),
           "transform": (".las", ".laz", ".ply"),
           "correct": (".las", ".laz", ".ply")}

CASES = [pytest.param(cmd, case, suffix, make, match, id=f"{cmd}-{case}{suffix}")
         for cmd, suffixes in READERS.items()
         for case, suffix, make, match in BAD if suffix in suffixes]


def _run(argv, capsys):
    rc = main(argv)
    cap = capsys.readouterr()
    return rc, cap.err


@pytest.mark.parametrize("command,case,suffix,make,match", CASES)
def test_bad_file_gives_one_line_exit_2_and_no_output(tmp_path, aux, capsys, command,
                                                      case, suffix, make, match):
    cloud = tmp_path / f"in_{case}{suffix}"
    make(cloud)
    out = tmp_path / "out"
    out.mkdir()
    rc, err = _run(_argv(command, cloud, out, aux), capsys)
    lines = err.strip().splitlines()
    assert "Traceback" not in err
    assert len(lines) == 1, err
    assert lines[0].startswith("tunnelsim: error: ")
    assert rc == 2
    import re
    assert re.search(match, lines[0]), lines[0]
    assert cloud.name in lines[0]
    assert sorted(p.name for p in out.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([cloud.name, "out"])


def test_a_console_run_on_a_cut_file_is_one_line(tmp_path):
    """The same through a real process: what a user sees in a terminal."""
    import subprocess
    import sys

    cloud = tmp_path / "cut.laz"
    _cut(0.5)(cloud)
    res = subprocess.run([sys.executable, "-m", "survey.cli", "preprocess", str(cloud),
                          "-o", str(tmp_path / "o.laz")], capture_output=True, text=True,
                         check=False, cwd=Path(__file__).resolve().parents[3])
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and "Expected 600 points" in res.stderr
    assert not (tmp_path / "o.laz").exists()


# ---------------------------------------------------------------------- foreign files
def _transform(cloud, out, aux, capsys):
    rc, err = _run(["transform", str(cloud), "--helmert", str(aux / "helmert.json"), "-o",
                    str(out), "--quiet"], capsys)
    assert rc == 0, err
    return laspy.read(out)


def _vlrs(header):
    return sorted((v.user_id, v.record_id, bytes(v.record_data_bytes()))
                  for v in header.vlrs
                  if type(v).__name__ not in ("ExtraBytesVlr", "LasZipVlr"))


def _evlrs(header):
    return sorted((v.user_id, v.record_id, bytes(v.record_data_bytes()))
                  for v in (header.evlrs or []))


@pytest.mark.parametrize("version,fmt", [("1.1", 1), ("1.2", 3), ("1.3", 5), ("1.4", 6),
                                         ("1.4", 7), ("1.4", 8), ("1.4", 10)])
def test_transform_and_compare_keep_every_field_vlr_and_evlr(tmp_path, aux, capsys,
                                                             version, fmt):
    src = F.las_file(tmp_path / "in.las", version=version, point_format=fmt, extra=True,
                     vlr=True, evlr=version == "1.4")
    out = _transform(tmp_path / "in.las", tmp_path / "t.laz", aux, capsys)
    assert (out.header.version, out.header.point_format.id) == (src.header.version, fmt)
    np.testing.assert_allclose(np.stack([out.x, out.y, out.z], 1),
                               np.stack([src.x, src.y, src.z], 1) + SHIFT, atol=1e-9)
    for dim in src.point_format.dimension_names:
        if dim not in ("X", "Y", "Z"):
            np.testing.assert_array_equal(np.asarray(out[dim]), np.asarray(src[dim]),
                                          err_msg=dim)
    assert _vlrs(out.header) == _vlrs(src.header)
    assert _evlrs(out.header) == _evlrs(src.header)
    assert out.header.system_identifier == src.header.system_identifier
    assert out.header.global_encoding.value == src.header.global_encoding.value

    rc, err = _run(["compare", str(tmp_path / "in.las"), str(aux / "ref.laz"), "-o",
                    str(tmp_path / "cmp"), "--quiet"], capsys)
    assert rc == 0, err
    cmp_ = laspy.read(tmp_path / "cmp" / "in_distance.laz")
    for dim in src.point_format.dimension_names:
        np.testing.assert_array_equal(np.asarray(cmp_[dim]), np.asarray(src[dim]),
                                      err_msg=dim)
    assert "distance" in cmp_.point_format.extra_dimension_names
    assert _vlrs(cmp_.header) == _vlrs(src.header)
    assert _evlrs(cmp_.header) == _evlrs(src.header)


def test_transform_keeps_las13_waveform_data(tmp_path, aux, capsys):
    packets = F.waveform_las13(tmp_path / "w.las")
    out = _transform(tmp_path / "w.las", tmp_path / "t.las", aux, capsys)
    raw = (tmp_path / "t.las").read_bytes()
    start = struct.unpack_from("<Q", raw, 227)[0]
    assert raw[start + 60:start + 60 + len(packets)] == packets
    np.testing.assert_array_equal(out.wavepacket_offset, 60 + np.arange(50) * 16)


def test_copc_input_through_preprocess_compare_transform(tmp_path, aux, capsys):
    src = F.copc_file(tmp_path / "c.copc.laz")
    out = _transform(tmp_path / "c.copc.laz", tmp_path / "t.laz", aux, capsys)
    np.testing.assert_allclose(out.x, src.x + SHIFT[0], atol=1e-9)
    assert not [v for v in out.header.vlrs if v.user_id == "copc"]
    assert not [v for v in (out.header.evlrs or []) if v.user_id == "copc"]
    rc, err = _run(["compare", str(tmp_path / "c.copc.laz"), str(aux / "ref.laz"), "-o",
                    str(tmp_path / "cmp"), "--quiet"], capsys)
    assert rc == 0, err
    cmp_ = laspy.read(tmp_path / "cmp" / "c.copc_distance.laz")
    np.testing.assert_array_equal(cmp_.X, src.X)
    rc, err = _run(["preprocess", str(tmp_path / "c.copc.laz"), "-o",
                    str(tmp_path / "p.laz"), "--quiet"], capsys)
    assert rc == 0, err
    assert len(laspy.read(tmp_path / "p.laz").points) == N


def test_header_bounds_1000x_wrong_use_the_points_and_warn(tmp_path, aux, capsys):
    """A LAS 1.3 whose stored bounds are wrong by 1000x (real writers do this): the
    voxel grid takes the points' own bounds, with a warning; compare and transform
    never rely on them."""
    src = F.las_file(tmp_path / "b.las", version="1.3", point_format=1)
    F.scale_las_bounds(tmp_path / "b.las", 1000.0)
    rc, err = _run(["preprocess", str(tmp_path / "b.las"), "-o",
                    str(tmp_path / "p.laz"), "--voxel", "0.01", "--quiet"], capsys)
    assert rc == 0, err
    # The warning reaches the user as one line, without a Python source path.
    warned = [ln for ln in err.splitlines() if "using the points' bounds" in ln]
    assert len(warned) == 1 and warned[0].startswith("tunnelsim: warning: "), err
    assert ".py" not in err
    p = laspy.read(tmp_path / "p.laz")
    assert len(p.points) > 0.9 * N
    assert np.all(np.asarray(p.x) >= np.min(src.x) - 1e-3)
    out = _transform(tmp_path / "b.las", tmp_path / "t.las", aux, capsys)
    np.testing.assert_allclose(out.header.mins, np.min(np.stack([src.x, src.y, src.z], 1),
                                                       axis=0) + SHIFT, atol=1e-3)
    rc, err = _run(["compare", str(tmp_path / "b.las"), str(aux / "ref.laz"), "-o",
                    str(tmp_path / "cmp"), "--quiet"], capsys)
    assert rc == 0, err


# ---------------------------------------------------------------------- the library
def test_read_reference_tells_meshes_from_clouds(tmp_path):
    from sensors.io.cloudread import read_reference

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    f = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    F.ply_mesh(tmp_path / "m.ply", v, f)
    got_v, got_f = read_reference(tmp_path / "m.ply")
    np.testing.assert_array_equal(got_v, v)
    np.testing.assert_array_equal(got_f, f)
    import trimesh
    trimesh.Trimesh(v, f, process=False).export(tmp_path / "m.obj")
    got_v, got_f = read_reference(tmp_path / "m.obj")
    np.testing.assert_array_equal(got_f, f)
    xyz = F.tunnel_points(50)
    F.ply_cloud(tmp_path / "c.ply", xyz)
    got_v, got_f = read_reference(tmp_path / "c.ply")
    assert got_f is None
    np.testing.assert_array_equal(got_v, xyz)


@pytest.mark.parametrize("suffix", [".npz", ".csv", ".txt"])
def test_text_and_npz_clouds_name_their_nan(tmp_path, suffix):
    from sensors.io.cloudread import read_points
    from sensors.io.errors import PointFileError

    xyz = F.tunnel_points(40)
    p = tmp_path / f"c{suffix}"

    def write(a):
        if suffix == ".npz":
            np.savez(p, x=a[:, 0], y=a[:, 1], z=a[:, 2])
        else:
            np.savetxt(p, a, delimiter="," if suffix == ".csv" else " ")
    write(xyz)
    np.testing.assert_allclose(read_points(p), xyz, rtol=0, atol=1e-6)
    xyz[33, 2] = np.inf
    write(xyz)
    with pytest.raises(PointFileError, match="point 33 with an infinite coordinate"):
        read_points(p)
    write(xyz[:0])
    with pytest.raises(PointFileError, match="0 points"):
        read_points(p)
    assert read_points(p, allow_empty=True).shape == (0, 3)


def test_ply_transform_keeps_fields_comments_and_byte_values(tmp_path, aux, capsys):
    xyz = F.tunnel_points(80)
    t = np.linspace(1e5, 1e5 + 8, 80)
    F.ply_cloud(tmp_path / "b.ply", xyz, big_endian=True, extra={"time": t})
    rc, err = _run(["transform", str(tmp_path / "b.ply"), "--helmert",
                    str(aux / "helmert.json"), "-o", str(tmp_path / "t.ply"), "--quiet"],
                   capsys)
    assert rc == 0, err
    import trimesh
    out = trimesh.load(tmp_path / "t.ply")
    np.testing.assert_allclose(out.vertices, xyz + SHIFT, rtol=0, atol=1e-9)
    raw = (tmp_path / "t.ply").read_bytes()
    assert b"comment other writer" in raw and b"property float time" in raw
    from sensors.io.ply import read_ply
    np.testing.assert_array_equal(read_ply(tmp_path / "t.ply")["vertex"]["time"],
                                  t.astype(np.float32))


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_cloud_bounds_are_the_points_own(tmp_path, suffix):
    import warnings

    from sensors.io.cloudread import cloud_bounds

    src = F.las_file(tmp_path / f"a{suffix}", point_format=7, extra=True)
    xyz = np.stack([src.x, src.y, src.z], 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                  # a true header: no warning
        lo, hi, n = cloud_bounds(tmp_path / f"a{suffix}", chunk=97)
    np.testing.assert_array_equal(lo, xyz.min(axis=0))
    np.testing.assert_array_equal(hi, xyz.max(axis=0))
    assert n == N
    F.scale_las_bounds(tmp_path / f"a{suffix}", 1e-3)
    with pytest.warns(UserWarning, match="states bounds .* using the points' bounds"):
        lo, hi, n = cloud_bounds(tmp_path / f"a{suffix}", chunk=97)
    np.testing.assert_array_equal(lo, xyz.min(axis=0))


@pytest.mark.parametrize("header", ["x,y,z,intensity", "//X,Y,Z,Intensity", "z,x,y,i"])
def test_text_cloud_with_a_header_reads_its_named_columns(tmp_path, header):
    """A CSV cloud with a header line (CloudCompare writes '//X,Y,Z,...') is read by the
    names in it, whatever the column order; without x, y and z it is refused by name."""
    from sensors.io.cloudread import read_points

    xyz = np.random.default_rng(3).uniform(-5, 5, (50, 3))
    names = [w.lstrip("/").lower() for w in header.split(",")]
    cols = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "intensity": np.ones(50),
            "i": np.ones(50)}
    rows = np.stack([cols[n] for n in names], 1)
    path = tmp_path / "c.csv"
    path.write_text("# a comment\n" + header + "\n" +
                    "\n".join(",".join(f"{v:.6f}" for v in r) for r in rows) + "\n")
    np.testing.assert_allclose(read_points(path), xyz, atol=1e-6)
    (tmp_path / "bad.csv").write_text("east,north,height\n1,2,3\n")
    with pytest.raises(PointFileError, match="header line naming x, y and z"):
        read_points(tmp_path / "bad.csv")
