"""LAS 1.0-1.4 files as other writers leave them (issue 29), through ``tunnelsim
transform`` and ``tunnelsim compare`` on the real command line.

Every input is written byte by byte from the ASPRS specifications
(``tests/sensors/lasbytes.py``, no laspy), and every output is checked against those
bytes: each point record of a transform holds the input's bytes after X, Y, Z (every
standard field, wave packet field and extra byte; the wave packet's direction
x(t), y(t), z(t) turned by the Helmert's (1 + s) R), and X, Y, Z hold the input's
coordinates through the Helmert (x' = t + (1 + s) R x, built here from the JSON's
matrix); each record of a compare holds the input's bytes followed by the distance to a
reference shifted by a known 10 mm. LAZ outputs are decompressed by laspy. What a
rewrite cannot keep is one warning line on stderr, checked word by word.
"""

from __future__ import annotations

import json
import struct

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from survey.adjust.helmert import from_parameters
from survey.cli.main import main
from tests.sensors import lasbytes as B

N = 40
SHIFT_M = 0.01                    # the reference of compare: every point 10 mm higher
EXTRA = [("section", "<u2", "tunnel section [index]"), ("chainage", "<f8", "chainage [m]")]
CASES = [(m, f) for m, fs in B.LEGAL_FORMATS.items() for f in fs]


@pytest.fixture(scope="module")
def helmert(tmp_path_factory):
    d = tmp_path_factory.mktemp("helmert")
    res = from_parameters(np.array([120.5, -40.25, 3.0]), np.array([20.0, -15.0, 900.0]),
                          30.0)
    (d / "h.json").write_text(json.dumps(res.to_dict()))
    return d / "h.json", res


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out = capsys.readouterr()
    return rc, out.err


def _file(path, minor, fmt, seed=0, *, vlrs=(), pad=0, **kw):
    """A hand-made LAS with extra bytes (section, chainage) and ``vlrs``; returns the
    raw records."""
    rng = np.random.default_rng(seed)
    rec = B.random_records(fmt, N, rng, [(n, t) for n, t, _ in EXTRA], pad)
    vlrs = [("LASF_Spec", 4, "extra bytes", B.extra_bytes_vlr(EXTRA)), *vlrs]
    path.write_bytes(B.las_bytes(minor, fmt, rec, vlrs=vlrs, **kw))
    return rec


def _xyz(head, raw):
    """World coordinates (n, 3) of raw records (X, Y, Z int32 first)."""
    b = np.frombuffer(raw.tobytes(), np.uint8).reshape(len(raw), -1)[:, :12]
    q = np.ascontiguousarray(b).view("<i4")
    return q * head["scales"] + head["offsets"]


def _tail(raw, start=12):
    """Every record's bytes after X, Y, Z, (n, k) uint8."""
    return np.frombuffer(raw.tobytes(), np.uint8).reshape(len(raw), -1)[:, start:]


def _reference(path, xyz):
    np.savetxt(path, xyz + [0.0, 0.0, SHIFT_M], fmt="%.4f")


def _extra_descriptors(vlrs):
    """(name, type code, description) of the extra bytes VLR, parsed by hand."""
    data = [d for u, rid, _, d in vlrs if (u, rid) == ("LASF_Spec", 4)]
    assert len(data) == 1
    out = []
    for i in range(0, len(data[0]), 192):
        _, code, _, name = struct.unpack_from("<2sBB32s", data[0], i)
        desc = struct.unpack_from("<32s", data[0], i + 160)[0]
        out.append((name.rstrip(b"\0").decode(), code, desc.rstrip(b"\0").decode()))
    return out


def _warnings(err):
    lines = err.strip().splitlines()
    assert all(ln.startswith("tunnelsim: warning: ") for ln in lines), err
    return lines


def _check_transform(src, dst, res, err, expect_warn=()):
    head0, raw0 = B.read_records(src.read_bytes())
    head1, raw1 = B.read_records(dst.read_bytes())
    lines = _warnings(err)
    assert len(lines) == len(expect_warn), err
    for ln, words in zip(lines, expect_warn):
        assert all(w in ln for w in words), (ln, words)
    assert head1["format"] == head0["format"] and head1["count"] == N
    assert head1["record_length"] == head0["record_length"]
    assert head1["minor"] == max(head0["minor"], 1)
    fmt = head0["format"]
    t0, t1 = _tail(raw0), _tail(raw1)
    sr = (1.0 + res.scale_ppm * 1e-6) * np.asarray(res.rotation_matrix)
    if fmt in (4, 5, 9, 10):
        # The wave packet's direction x(t), y(t), z(t) (the format's last 12 bytes,
        # float32) turns with the points: (1 + s) R d, to float32 rounding.
        w = B.RECORD_LENGTH[fmt] - 12 - 12
        d0 = np.ascontiguousarray(t0[:, w:w + 12]).view("<f4").astype(np.float64)
        d1 = np.ascontiguousarray(t1[:, w:w + 12]).view("<f4").astype(np.float64)
        np.testing.assert_allclose(d1, d0 @ sr.T, rtol=0,
                                   atol=4e-7 * np.abs(d0).max() + 1e-30)
        t0, t1 = np.delete(t0, np.s_[w:w + 12], 1), np.delete(t1, np.s_[w:w + 12], 1)
    np.testing.assert_array_equal(t1, t0)                        # every other byte kept
    want = (res.translation_m + (1.0 + res.scale_ppm * 1e-6) *
            _xyz(head0, raw0) @ np.asarray(res.rotation_matrix).T)
    assert np.abs(_xyz(head1, raw1) - want).max() <= 0.5e-4 + 1e-9
    # laspy describes undescribed extra bytes as "ExtraBytes" (bytes kept, above).
    got = [e for e in _extra_descriptors(head1["vlrs"]) if e[0] != "ExtraBytes"]
    assert got == [(n, 3 if t == "<u2" else 10, d) for n, t, d in EXTRA]
    return head0, head1


def _check_compare(src, out_laz, err, n_warn):
    """The compare output: the input's record bytes, then the distance; formats 9
    and 10 with wave packet fields zero and one more warning line (LAZ, lazrs)."""
    head0, raw0 = B.read_records(src.read_bytes())
    fmt = head0["format"]
    lines = _warnings(err)
    assert len(lines) == n_warn + (fmt in (9, 10)), err
    las = laspy.read(out_laz)
    got = las.points.array
    assert got.dtype.itemsize == head0["record_length"] + 4     # + distance, float32
    tail = np.frombuffer(got.tobytes(), np.uint8).reshape(N, -1)[:, 12:-4]
    want = _tail(raw0).copy()
    if fmt in (9, 10):
        assert "written as zeros" in lines[-1] and "write .las" in lines[-1]
        wave = B.RECORD_LENGTH[fmt] - 29 - 12        # 29 bytes of wave packet fields
        want[:, wave:wave + 29] = 0
    np.testing.assert_array_equal(tail, want)
    np.testing.assert_array_equal(np.stack([las.x, las.y, las.z], 1), _xyz(head0, raw0))
    np.testing.assert_allclose(np.asarray(las["distance"]), SHIFT_M, atol=2e-6)
    desc = {e.name: e.description for e in las.point_format.extra_dimensions}
    assert desc == {**{n: d for n, _, d in EXTRA}, "distance": "distance to reference [m]"}


@pytest.mark.parametrize("minor,fmt", CASES)
def test_every_version_and_format_through_transform_and_compare(tmp_path, helmert, capsys,
                                                                  minor, fmt):
    """LAS 1.0-1.4 x every format each defines, with extra bytes: transform keeps every
    byte but the coordinates, which move by the Helmert; compare keeps every byte and
    adds the distance. Waveform formats without waveform data and LAS 1.0 (written as
    1.1) are one warning line each."""
    h, res = helmert
    src = tmp_path / "in.las"
    _file(src, minor, fmt, seed=minor * 11 + fmt)
    warn = []
    if minor == 0:
        warn.append(("LAS 1.0", "LAS 1.1", "same point records"))
    if fmt in (4, 5, 9, 10):
        warn.append(("wave packet fields", f"point format {fmt}", "point nowhere"))
    rc, err = _run(["transform", src, "--helmert", h, "-o", tmp_path / "t.las", "--quiet"],
                   capsys)
    assert rc == 0, err
    _check_transform(src, tmp_path / "t.las", res, err, warn)
    _, raw = B.read_records(src.read_bytes())
    _reference(tmp_path / "ref.xyz", _xyz(B.read_records(src.read_bytes())[0], raw))
    rc, err = _run(["compare", src, tmp_path / "ref.xyz", "-o", tmp_path / "cmp",
                    "--quiet"], capsys)
    assert rc == 0, err
    _check_compare(src, tmp_path / "cmp" / "in_distance.laz", err, len(warn))


def _waveform_start(kind, size, points_end, offset):
    return {"zero": 0, "end of points": points_end, "inside points": offset + 5,
            "past the end": size + 1000, "padding": points_end}[kind]


@pytest.mark.parametrize("kind", ["zero", "end of points", "inside points",
                                  "past the end", "padding"])
def test_leica_las13_format4_without_waveform_data(tmp_path, helmert, capsys, kind):
    """Issue 29's file: LAS 1.3, point format 4, a waveform packet descriptor VLR, no
    waveform data record, and a "start of waveform data" that points at nothing (zero,
    the end of the points, into the points, past the end, into trailing padding):
    read, transform and compare keep every field and say in one line that the wave
    packet fields point nowhere."""
    from sensors.io.cloudread import read_points

    h, res = helmert
    src = tmp_path / "leica.las"
    desc = ("LASF_Spec", 100, "waveform packet descriptor", B.waveform_descriptor())
    trailing = bytes(range(200)) if kind == "padding" else b""
    _file(src, 3, 4, vlrs=[desc], trailing=trailing)
    head, raw = B.read_records(src.read_bytes())
    points_end = head["offset"] + N * head["record_length"]
    start = _waveform_start(kind, src.stat().st_size, points_end, head["offset"])
    _file(src, 3, 4, vlrs=[desc], trailing=trailing, waveform_start=start,
          global_encoding=2 if kind != "zero" else 0)
    np.testing.assert_array_equal(read_points(src), _xyz(head, raw))
    rc, err = _run(["transform", src, "--helmert", h, "-o", tmp_path / "t.las", "--quiet"],
                   capsys)
    assert rc == 0, err
    pointer = () if kind == "zero" else (f"byte {start:,}", "not carried")
    _, h1 = _check_transform(src, tmp_path / "t.las", res, err,
                             [("wave packet fields", "point nowhere", *pointer)])
    assert h1["waveform_start"] == 0
    assert [v for v in h1["vlrs"] if v[1] == 100] == [desc]      # the descriptor kept
    _reference(tmp_path / "ref.xyz", _xyz(head, raw))
    rc, err = _run(["compare", src, tmp_path / "ref.xyz", "-o", tmp_path / "cmp",
                    "--quiet"], capsys)
    assert rc == 0, err
    _check_compare(src, tmp_path / "cmp" / "leica_distance.laz", err, 1)


def test_internal_waveform_data_is_carried_and_pointed_at(tmp_path, helmert, capsys):
    """A hand-made LAS 1.3 with its waveform data record after the points: the output
    holds the same record, and its header points at it; no warning."""
    h, res = helmert
    src = tmp_path / "w.las"
    packets = bytes((7 * i) % 251 for i in range(N * 64))
    _file(src, 3, 5, global_encoding=2, waveform_start="first evlr",
          vlrs=[("LASF_Spec", 101, "descriptor", B.waveform_descriptor())],
          evlrs=[("LASF_Spec", 65535, "waveform packets", packets)])
    rc, err = _run(["transform", src, "--helmert", h, "-o", tmp_path / "t.las", "--quiet"],
                   capsys)
    assert rc == 0, err
    _, h1 = _check_transform(src, tmp_path / "t.las", res, err, [])
    data = (tmp_path / "t.las").read_bytes()
    _, user, rid, length, _ = struct.unpack_from("<H16sHQ32s", data, h1["waveform_start"])
    assert (user.rstrip(b"\0"), rid, length) == (b"LASF_Spec", 65535, len(packets))
    assert data[h1["waveform_start"] + 60:][:length] == packets
    head, raw = B.read_records(src.read_bytes())
    _reference(tmp_path / "ref.xyz", _xyz(head, raw))
    rc, err = _run(["compare", src, tmp_path / "ref.xyz", "-o", tmp_path / "cmp",
                    "--quiet"], capsys)
    assert rc == 0, err
    _check_compare(src, tmp_path / "cmp" / "w_distance.laz", err, 0)
    data = (tmp_path / "cmp" / "w_distance.laz").read_bytes()
    start = struct.unpack_from("<Q", data, 227)[0]
    assert data[start + 60:start + 60 + len(packets)] == packets


def test_external_waveform_file_is_named_not_copied(tmp_path, helmert, capsys):
    h, res = helmert
    src = tmp_path / "ext.las"
    _file(src, 3, 4, global_encoding=4)
    (tmp_path / "ext.wdp").write_bytes(bytes(N * 64))
    rc, err = _run(["transform", src, "--helmert", h, "-o", tmp_path / "t.las", "--quiet"],
                   capsys)
    assert rc == 0, err
    _check_transform(src, tmp_path / "t.las", res, err,
                     [("'ext.wdp' (external)", "does not copy", "wave packet fields")])
    assert not (tmp_path / "t.wdp").exists()


@pytest.mark.parametrize("variant", ["legacy signature", "padding", "undescribed bytes"])
def test_odd_layouts_keep_every_byte(tmp_path, helmert, capsys, variant):
    """A LAS 1.0 file with the 0xCCDD point data start signature; a LAS 1.2 file with
    200 bytes of padding after its points; a LAS 1.4 file whose records hold 3 bytes
    that no extra bytes descriptor names."""
    h, res = helmert
    src = tmp_path / "odd.las"
    minor, fmt = {"legacy signature": (0, 1), "padding": (2, 3),
                  "undescribed bytes": (4, 7)}[variant]
    _file(src, minor, fmt, legacy_signature=variant == "legacy signature",
          trailing=bytes(200) if variant == "padding" else b"",
          pad=3 if variant == "undescribed bytes" else 0)
    rc, err = _run(["transform", src, "--helmert", h, "-o", tmp_path / "t.las", "--quiet"],
                   capsys)
    assert rc == 0, err
    warn = [("LAS 1.0",)] if minor == 0 else []
    _check_transform(src, tmp_path / "t.las", res, err, warn)


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=st.sampled_from(CASES), n=st.integers(1, 60), seed=st.integers(0, 2**16))
def test_a_rewrite_keeps_every_byte_but_the_coordinates(tmp_path, case, n, seed):
    """Property: ``map_cloud`` with the identity keeps every record byte after X, Y, Z
    and the coordinates to the output scale, whatever the version, format and count."""
    import warnings

    from sensors.io.cloudmap import map_cloud

    minor, fmt = case
    rng = np.random.default_rng(seed)
    rec = B.random_records(fmt, n, rng)
    src, dst = tmp_path / f"p{seed}.las", tmp_path / f"q{seed}.las"
    src.write_bytes(B.las_bytes(minor, fmt, rec))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")           # LAS 1.0 and waveform formats say so
        assert map_cloud(src, dst, lambda xyz, t: xyz) == n
    h0, r0 = B.read_records(src.read_bytes())
    h1, r1 = B.read_records(dst.read_bytes())
    np.testing.assert_array_equal(_tail(r1), _tail(r0))
    assert np.abs(_xyz(h1, r1) - _xyz(h0, r0)).max() <= 0.5e-4 + 1e-9


@pytest.mark.parametrize("fmt", [4, 5, 9, 10])
def test_lazrs_keeps_wave_packets_of_formats_4_and_5_only(fmt):
    """The reason for ``sensors.io.las.LAZ_WAVE_BROKEN``: a laspy/lazrs LAZ round trip of
    hand-made records keeps every byte of formats 4 and 5 and changes varying wave
    packet fields of 9 and 10. When this fails for 9 or 10, lazrs was fixed: drop the
    zeroing in ``LasWriter``."""
    import io

    from sensors.io.las import LAZ_WAVE_BROKEN

    rec = B.random_records(fmt, 300, np.random.default_rng(fmt))
    rec["wavepacket_offset"] = np.arange(300) * 64 + 60         # as a writer fills it
    las = laspy.read(io.BytesIO(B.las_bytes(3 if fmt < 6 else 4, fmt, rec)))
    buf = io.BytesIO()
    las.write(buf, do_compress=True)
    buf.seek(0)
    back = laspy.read(buf).points.array
    same = back.tobytes() == las.points.array.tobytes()
    assert same == (fmt not in LAZ_WAVE_BROKEN)
