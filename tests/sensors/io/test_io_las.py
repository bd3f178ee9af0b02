"""sensors.io.las: files from other writers read whole; damaged files refused with the
points promised and read; rewrites keep every field, VLR and EVLR (checked with laspy
and raw bytes, not with the module's own reader)."""

from __future__ import annotations

import struct

import laspy
import numpy as np
import pytest

from sensors.io.errors import PointFileError
from sensors.io.las import LasSource, LasWriter, output_header, point_records, write_las
from tests import iofiles as F


def _read_all(path):
    with LasSource(path) as src:
        return np.concatenate([np.stack([r.x, r.y, r.z], 1) for r in src.chunks(97)])


@pytest.mark.parametrize("version,fmt", [("1.1", 1), ("1.2", 3), ("1.3", 5), ("1.4", 0),
                                         ("1.4", 8), ("1.4", 10)])
@pytest.mark.parametrize("suffix", ["las", "laz"])
def test_every_version_and_format_reads_whole(tmp_path, version, fmt, suffix):
    las = F.las_file(tmp_path / f"a.{suffix}", version=version, point_format=fmt,
                     extra=True)
    got = _read_all(tmp_path / f"a.{suffix}")
    np.testing.assert_array_equal(got, np.stack([las.x, las.y, las.z], 1))


@pytest.mark.parametrize("damage,match", [
    (lambda p: p.write_bytes(b""), r"empty \(0 bytes\)"),
    (lambda p: F.zeros_after_signature(p), r"version 0\.0 .*corrupt"),
    (lambda p: p.write_bytes(b"PK\x03\x04" + bytes(500)), "without the 'LASF' signature"),
    (lambda p: F.truncate(p, 100), "too short for a LAS header"),
    (lambda p: F.truncate(p, 150), "ends at byte 150, before its points"),
    (lambda p: F.truncate(p, 300), "cut short"),
])
def test_broken_headers_give_one_clear_error(tmp_path, damage, match):
    p = tmp_path / "a.las"
    F.las_file(p)
    damage(p)
    with pytest.raises(PointFileError, match=match):
        LasSource(p)


@pytest.mark.parametrize("suffix", ["las", "laz"])
def test_a_cut_short_file_says_how_many_points_it_promised_and_held(tmp_path, suffix):
    p = tmp_path / f"a.{suffix}"
    F.las_file(p)                                          # 600 points
    F.truncate(p, 0.6)
    with pytest.raises(PointFileError, match=r"Expected 600 points .* got \d+"):
        _read_all(p)


@pytest.mark.parametrize("suffix,match", [
    ("las", r"Expected 695,000 points .* got 600 whole point records"),
    ("laz", r"Expected 695,000 points .* got \d+ points before")])
def test_a_header_claiming_more_points_than_held_is_an_error(tmp_path, suffix, match):
    """The silent data loss of issue 14: 695,000 promised, 600 held."""
    p = tmp_path / f"a.{suffix}"
    F.las_file(p)
    F.set_las_count(p, 695_000)
    with pytest.raises(PointFileError, match=match):
        _read_all(p)


def test_nan_offsets_are_refused(tmp_path):
    p = tmp_path / "a.las"
    F.las_file(p)
    F.set_las_offset_nan(p)
    with pytest.raises(PointFileError, match="NaN"):
        LasSource(p)


def test_copc_is_read_and_rewritten_as_plain_laz(tmp_path):
    las = F.copc_file(tmp_path / "c.copc.laz")
    with LasSource(tmp_path / "c.copc.laz") as src:
        head = output_header(src)
        with LasWriter(tmp_path / "o.laz", head, evlrs=src.evlrs()) as w:
            for rec in src.chunks(200):
                w.write_points(rec)
    out = laspy.read(tmp_path / "o.laz")
    assert not [v for v in out.header.vlrs if v.user_id == "copc"]
    assert not [v for v in (out.header.evlrs or []) if v.user_id == "copc"]
    np.testing.assert_array_equal(out.X, las.X)
    np.testing.assert_array_equal(out.gps_time, las.gps_time)


def test_rewrite_keeps_fields_vlrs_and_evlrs(tmp_path):
    src_las = F.las_file(tmp_path / "a.las", point_format=7, extra=True, vlr=True,
                         evlr=True)
    with LasSource(tmp_path / "a.las") as src:
        head = output_header(src, extra={"distance": np.dtype("f4")})
        with LasWriter(tmp_path / "o.laz", head, evlrs=src.evlrs()) as w:
            for rec in src.chunks(250):
                out = laspy.ScaleAwarePointRecord.zeros(len(rec), header=w.header)
                for name in rec.array.dtype.names:
                    out.array[name] = rec.array[name]
                out.array["distance"] = 1.5
                w.write_points(out)
    out = laspy.read(tmp_path / "o.laz")
    for dim in src_las.point_format.dimension_names:
        np.testing.assert_array_equal(np.asarray(out[dim]), np.asarray(src_las[dim]))
    assert np.all(out["distance"] == np.float32(1.5))
    assert out.header.system_identifier == "other writer"
    vl = [(v.user_id, v.record_id, v.record_data) for v in out.header.vlrs
          if v.user_id == "OtherWriter"]
    assert vl == [("OtherWriter", 42, b"keep me, please")]
    ev = [(v.user_id, v.record_id, v.record_data) for v in out.header.evlrs]
    assert ev == [("OtherWriter", 7, bytes(range(256)) * 300)]


def test_las13_waveform_record_is_carried_and_pointed_at(tmp_path):
    packets = F.waveform_las13(tmp_path / "w.las")
    with LasSource(tmp_path / "w.las") as src:
        assert src.evlrs()[0].record_data == packets
        with LasWriter(tmp_path / "o.las", output_header(src), evlrs=src.evlrs()) as w:
            for rec in src.chunks(1000):
                w.write_points(rec)
    raw = (tmp_path / "o.las").read_bytes()
    start = struct.unpack_from("<Q", raw, 227)[0]
    _, user, rid, length, _ = struct.unpack_from("<H16sHQ32s", raw, start)
    assert (user.rstrip(b"\0"), rid, length) == (b"LASF_Spec", 65535, len(packets))
    assert raw[start + 60:start + 60 + length] == packets
    out = laspy.read(tmp_path / "o.las")
    np.testing.assert_array_equal(out.wavepacket_offset, 60 + np.arange(50) * 16)


def test_write_las_round_trip_and_atomic_failure(tmp_path):
    xyz = F.tunnel_points(seed=5)
    write_las(tmp_path / "o.laz", xyz, fields={"classification": np.full(600, 2)},
              extra={"d": np.arange(600, dtype=np.float32)})
    out = laspy.read(tmp_path / "o.laz")
    assert np.abs(np.stack([out.x, out.y, out.z], 1) - xyz).max() <= 0.5e-4 + 1e-9
    assert set(np.asarray(out.classification)) == {2}
    np.testing.assert_array_equal(out.d, np.arange(600))
    assert np.all(out.return_number == 1) and np.all(out.number_of_returns == 1)
    bad = xyz.copy()
    bad[17, 1] = np.nan
    with pytest.raises(PointFileError, match="point 17"):
        write_las(tmp_path / "n.laz", bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.laz"]


def test_point_records_refuse_coordinates_beyond_int32(tmp_path):
    head = laspy.LasHeader(point_format=6, version="1.4")
    head.scales, head.offsets = np.full(3, 1e-4), np.zeros(3)
    with pytest.raises(PointFileError, match="within 214,748 m"):
        point_records(head, np.array([[0.0, 0.0, 0.0], [3e5, 0.0, 0.0]]))


def test_ctrl_c_during_compression_stays_a_ctrl_c(tmp_path):
    """lazrs turns a KeyboardInterrupt inside its file callbacks into an IoError; the
    writer holds SIGINT until laspy's write returns, then raises KeyboardInterrupt."""
    import os
    import signal

    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        pytest.skip("SIGINT has a custom handler in this process")
    xyz = F.tunnel_points(2000)
    head = laspy.LasHeader(point_format=6, version="1.4")
    head.scales, head.offsets = np.full(3, 1e-3), np.round(xyz[0])
    finished = []
    with pytest.raises(KeyboardInterrupt), LasWriter(tmp_path / "a.laz", head) as w:
        laspy_write = w._writer.write_points

        def write_in_rust(records):       # stands for lazrs calling back into Python
            os.kill(os.getpid(), signal.SIGINT)
            laspy_write(records)
            finished.append(len(records))

        w._writer.write_points = write_in_rust
        w.write_points(point_records(w.header, xyz))
    assert finished == [2000]             # the write was not torn in the middle
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("field, at, fmt", [("VLR", 100, "<I"), ("EVLR", 243, "<I")])
def test_vlr_counts_that_cannot_fit_are_refused(tmp_path, field, at, fmt):
    """A flipped byte in a VLR or EVLR count (found by the fuzz property: laspy then
    read 'records' for minutes from a 79 KB file, and a rewrite wrote 711 MB) is one
    clear error before laspy reads anything."""
    import struct

    import laspy

    from sensors.io.errors import PointFileError
    from sensors.io.las import LasSource

    h = laspy.LasHeader(point_format=6, version="1.4")
    las = laspy.LasData(h)
    las.x, las.y, las.z = np.arange(5.0), np.zeros(5), np.ones(5)
    path = tmp_path / "a.las"
    las.write(path)
    with LasSource(path) as src:                 # the valid file opens
        assert src.point_count == 5
    data = bytearray(path.read_bytes())
    struct.pack_into(fmt, data, at, 11_862_017)
    path.write_bytes(bytes(data))
    with pytest.raises(PointFileError, match=f"counts 11,862,017 {field}s"):
        LasSource(path)
