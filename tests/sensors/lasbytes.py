"""LAS files written byte by byte with ``struct``, from the ASPRS specifications
(LAS 1.0 1.1, 1.2, 1.3 R11, 1.4 R15), not through laspy: the independent reference the
LAS tests read other writers' files against.

Public header block (LAS 1.4 R15, table 3): 227 bytes up to LAS 1.2, 235 in LAS 1.3
(+ start of waveform data packet record, uint64), 375 in LAS 1.4 (+ start of first
EVLR, EVLR count, uint64 point count, 15 uint64 counts by return). VLR header 54
bytes, EVLR header 60 bytes. Point record layouts (tables 7-17 of R15; formats 0-1 from
LAS 1.0, 2-3 from 1.2, 4-5 from 1.3, 6-10 from 1.4) are the NumPy dtypes below.
"""

from __future__ import annotations

import struct

import numpy as np

#: Public header size by minor version.
HEADER_SIZE = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}
#: The point formats each minor version defines.
LEGAL_FORMATS = {0: (0, 1), 1: (0, 1), 2: (0, 1, 2, 3), 3: (0, 1, 2, 3, 4, 5),
                 4: tuple(range(11))}

_LEGACY = [("X", "<i4"), ("Y", "<i4"), ("Z", "<i4"), ("intensity", "<u2"),
           ("bits", "u1"), ("classification", "u1"), ("scan_angle_rank", "i1"),
           ("user_data", "u1"), ("point_source_id", "<u2")]
_NEW = [("X", "<i4"), ("Y", "<i4"), ("Z", "<i4"), ("intensity", "<u2"),
        ("returns", "u1"), ("flags", "u1"), ("classification", "u1"), ("user_data", "u1"),
        ("scan_angle", "<i2"), ("point_source_id", "<u2"), ("gps_time", "<f8")]
_GPS = [("gps_time", "<f8")]
_RGB = [("red", "<u2"), ("green", "<u2"), ("blue", "<u2")]
_WAVE = [("wavepacket_index", "u1"), ("wavepacket_offset", "<u8"),
         ("wavepacket_size", "<u4"), ("return_point_wave_location", "<f4"),
         ("x_t", "<f4"), ("y_t", "<f4"), ("z_t", "<f4")]
#: Point record layout of every format (R15 tables 7-17).
POINT_LAYOUT = {0: _LEGACY, 1: _LEGACY + _GPS, 2: _LEGACY + _RGB,
                3: _LEGACY + _GPS + _RGB, 4: _LEGACY + _GPS + _WAVE,
                5: _LEGACY + _GPS + _RGB + _WAVE, 6: _NEW, 7: _NEW + _RGB,
                8: _NEW + _RGB + [("nir", "<u2")], 9: _NEW + _WAVE,
                10: _NEW + _RGB + [("nir", "<u2")] + _WAVE}
#: Record lengths the specification gives (checked against the layouts on import).
RECORD_LENGTH = {0: 20, 1: 28, 2: 26, 3: 34, 4: 57, 5: 63, 6: 30, 7: 36, 8: 38,
                 9: 59, 10: 67}
for _f, _lay in POINT_LAYOUT.items():
    assert np.dtype(_lay).itemsize == RECORD_LENGTH[_f], _f

#: Extra-bytes data types (R15 table 24): type code -> NumPy type.
EXTRA_TYPES = {1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8",
               8: "<i8", 9: "<f4", 10: "<f8"}


def record_dtype(fmt: int, extra: list[tuple[str, str]] = (), pad: int = 0) -> np.dtype:
    """The record of point format ``fmt`` followed by the ``extra`` (name, type) fields
    and ``pad`` undescribed bytes."""
    lay = POINT_LAYOUT[fmt] + [(n, t) for n, t in extra]
    if pad:
        lay = lay + [("_pad", f"V{pad}")]
    return np.dtype(lay)


def random_records(fmt: int, n: int, rng, extra=(), pad: int = 0) -> np.ndarray:
    """(n,) records of ``record_dtype`` with every field random (legal bit fields)."""
    dt = record_dtype(fmt, list(extra), pad)
    raw = rng.integers(0, 256, n * dt.itemsize, dtype=np.uint8)
    rec = raw.view(dt).copy()
    rec["X"] = rng.integers(-500_000, 500_000, n)
    rec["Y"] = rng.integers(-500_000, 500_000, n)
    rec["Z"] = rng.integers(-50_000, 50_000, n)
    for name, t in [(k, dt[k]) for k in dt.names]:
        if t.kind == "f":
            rec[name] = rng.uniform(-1e3, 1e3, n).astype(t)
    if fmt < 6:
        # return number 1..5 of 1..5 returns (3 + 3 bits), scan direction, edge
        nret = rng.integers(1, 6, n)
        ret = np.minimum(rng.integers(1, 6, n), nret)
        rec["bits"] = ret | (nret << 3) | (rng.integers(0, 4, n) << 6)
        rec["scan_angle_rank"] = rng.integers(-90, 91, n)
    else:
        nret = rng.integers(1, 16, n)
        ret = np.minimum(rng.integers(1, 16, n), nret)
        rec["returns"] = ret | (nret << 4)
        rec["scan_angle"] = rng.integers(-30_000, 30_001, n)
    return rec


def extra_bytes_vlr(fields: list[tuple[str, str, str]]) -> bytes:
    """The payload of an extra bytes VLR (LASF_Spec 4; R15 table 24): one 192-byte
    descriptor per (name, NumPy type, description)."""
    codes = {np.dtype(v).str: k for k, v in EXTRA_TYPES.items()}
    out = b""
    for name, t, desc in fields:
        code = codes[np.dtype(t).newbyteorder("<").str]
        out += struct.pack("<2sBB32s4s24s24s24s24s24s32s", b"\0\0", code, 0,
                           name.encode(), b"", b"", b"", b"", b"", b"", desc.encode())
    assert len(out) == 192 * len(fields)
    return out


def waveform_descriptor(bits: int = 8, samples: int = 64, spacing_ps: int = 1000
                        ) -> bytes:
    """The payload of a waveform packet descriptor VLR (LASF_Spec 100-354; 26 bytes):
    bits per sample, compression type, samples, temporal spacing (ps), gain, offset."""
    return struct.pack("<BBIIdd", bits, 0, samples, spacing_ps, 1.0, 0.0)


def las_bytes(minor: int, fmt: int, records: np.ndarray, *, vlrs=(), evlrs=(),
              scales=(0.001, 0.001, 0.001), offsets=(0.0, 0.0, 0.0),
              global_encoding: int = 0, waveform_start: int | str = 0,
              legacy_signature: bool = False, trailing: bytes = b"",
              system: str = "other writer", software: str = "hand made") -> bytes:
    """A whole LAS 1.``minor`` file of point format ``fmt`` with ``records``.

    ``vlrs``/``evlrs``: (user, record id, description, payload) each. ``waveform_start``
    (LAS 1.3+): the header's start of waveform data packet record, an int or "first
    evlr" (the first EVLR's offset). ``legacy_signature``: the LAS 1.0 point data start
    signature 0xCCDD between the VLRs and the points. ``trailing``: bytes after
    everything (padding some writers leave)."""
    head_size = HEADER_SIZE[minor]
    vlr_bytes = b"".join(struct.pack("<H16sHH32s", 0, u.encode(), rid, len(d),
                                     desc.encode()) + d for u, rid, desc, d in vlrs)
    sig = struct.pack("<H", 0xCCDD) if legacy_signature else b""
    offset = head_size + len(vlr_bytes) + len(sig)
    points = records.tobytes()
    n = len(records)
    evlr_at = offset + len(points)
    evlr_bytes = b"".join(struct.pack("<H16sHQ32s", 0, u.encode(), rid, len(d),
                                      desc.encode()) + d for u, rid, desc, d in evlrs)
    sc, off = np.asarray(scales, float), np.asarray(offsets, float)
    if n:
        xyz = np.stack([records["X"], records["Y"], records["Z"]], 1) * sc + off
        lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    else:
        lo = hi = np.zeros(3)
    ret_field = "bits" if fmt < 6 else "returns"
    rn = (records[ret_field] & (0x07 if fmt < 6 else 0x0F)).astype(int)
    by_return = [int((rn == k).sum()) for k in range(1, 16)]
    h = bytearray(head_size)
    struct.pack_into("<4sHH16sBB32s32sHHHIIBHI5I3d3d6d", h, 0, b"LASF", 0,
                     global_encoding, b"\0" * 16, 1, minor, system.encode(),
                     software.encode(), 100, 2020, head_size, offset, len(vlrs), fmt,
                     records.dtype.itemsize, n if fmt < 6 or minor < 4 else 0,
                     *by_return[:5], *sc, *off, hi[0], lo[0], hi[1], lo[1], hi[2], lo[2])
    if minor >= 3:
        start = evlr_at if waveform_start == "first evlr" else int(waveform_start)
        struct.pack_into("<Q", h, 227, start)
    if minor >= 4:
        struct.pack_into("<QIQ15Q", h, 235, evlr_at if evlrs else 0, len(evlrs), n,
                         *by_return)
    elif evlrs and minor < 3:
        raise ValueError("EVLRs need LAS 1.3 or 1.4")
    return bytes(h) + vlr_bytes + sig + points + evlr_bytes + trailing


def read_records(data: bytes) -> tuple[dict, np.ndarray]:
    """(header fields, raw records (n,) as void of the record length) of LAS bytes:
    what the file holds, read without laspy."""
    (sig, _src, ge, _g, major, minor, _sys, _sw, _d, _y, head_size, offset, n_vlrs, fmt,
     rec_len, legacy) = struct.unpack_from("<4sHH16sBB32s32sHHHIIBHI", data, 0)
    sc = struct.unpack_from("<3d", data, 131)
    off = struct.unpack_from("<3d", data, 155)
    n = legacy
    if minor >= 4:
        n = struct.unpack_from("<Q", data, 247)[0] or legacy
    vlrs = []
    pos = head_size
    for _ in range(n_vlrs):
        _, user, rid, length, desc = struct.unpack_from("<H16sHH32s", data, pos)
        vlrs.append((user.rstrip(b"\0").decode(), rid, desc.rstrip(b"\0").decode(),
                     data[pos + 54:pos + 54 + length]))
        pos += 54 + length
    head = {"minor": minor, "format": fmt & 0x3F, "record_length": rec_len, "count": n,
            "scales": np.array(sc), "offsets": np.array(off), "global_encoding": ge,
            "offset": offset, "vlrs": vlrs,
            "waveform_start": struct.unpack_from("<Q", data, 227)[0] if minor >= 3 else 0}
    raw = np.frombuffer(data, dtype=f"V{rec_len}", count=n, offset=offset)
    return head, raw
