"""LAS and LAZ files (ASPRS LAS 1.0-1.4, LAZ through lazrs), read and written in one
place for the whole project: simulated clouds (``sensors.writers``), processed and
rewritten clouds (``sensors.io.cloudread``, ``sensors.io.cloudmap``).

Reading (``LasSource``) checks what laspy takes on trust, so that a bad file gives one
``PointFileError`` naming the file and the problem, never a library traceback and never
a silently shorter cloud:

- an empty file, a missing ``LASF`` signature, a header of zeros or one whose sizes and
  offsets contradict each other or the file;
- a file shorter than its header promises (LAS: from the file size before any point is
  read; LAZ: while decompressing), with how many points were promised and read;
- coordinate scales or offsets that are zero, NaN or infinite.

Files as other writers leave them (issue 29): every version (1.0-1.4) and point format
(0-10) reads; a rewrite keeps every point record byte but what it is asked to change
and says in one warning line what it cannot keep: a LAS 1.3 "start of waveform data"
that points at no waveform record (zero, the end, the points, padding: a waveform
format without waveform data, as Leica writers leave it), wave packet fields that
index no waveform data, waveform data in an external ``.wdp`` file (not copied), a
LAS 1.0 input (written as 1.1, which laspy writes), and the wave packet fields of
point formats 9 and 10 in a LAZ output (zeros: lazrs 0.8 does not keep varying ones).

COPC files (``.copc.laz``) read as the LAZ 1.4 they are; their octree VLR and EVLR do not
describe a rewritten file and are left out of it (laspy cannot write them).

Writing (``LasWriter``) is a stream of point records into a temporary file renamed into
place on ``close``. ``output_header`` copies an input's header for a rewrite: every
field, VLR and EVLR (LAS 1.3 and 1.4 waveform data included), so that ``tunnelsim
transform`` and ``compare`` keep what they were given.

Coordinate reference system (``sensors.io.crs``): ``set_las_crs`` writes the OGC
Coordinate System WKT VLR (user ``LASF_Projection``, record 2112) and sets the
global-encoding WKT bit, as LAS 1.4 R15 asks for point formats 6-10 (a LAS 1.0-1.3
file gets GeoTIFF keys through laspy); ``las_crs_wkt`` reads the WKT back without
pyproj. A rewrite keeps the input's CRS records unless told otherwise.
"""

from __future__ import annotations

import copy
import logging
import os
import struct
import warnings
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, Self

import numpy as np

from sensors.io.errors import PointFileError
from .fields import field_offset, las_description
from .stream import AtomicStream, deferred_interrupt

__all__ = ["CRS_USER", "LAS_SCALE", "WAVEFORM_FORMATS", "LasRecords", "LasSource",
           "LasWriter", "extra_params", "is_crs_record", "las_crs_wkt", "offsets_near",
           "output_header", "point_records", "quantize", "set_las_crs", "write_las"]

#: Default coordinate scale of the files tunnelsim writes (m): 0.1 mm.
LAS_SCALE = 1e-4
#: VLRs/EVLRs of this user describe a COPC octree and are not copied into a rewrite.
COPC_USER = "copc"
#: VLR user of the CRS records: WKT (2112), WKT math transform (2111), GeoTIFF keys
#: (34735-34737).
CRS_USER = "LASF_Projection"
#: Record id of the OGC Coordinate System WKT VLR (LAS 1.4 R15).
CRS_WKT_RECORD = 2112
#: (user, record) of the EVLR holding waveform data packets.
WAVEFORM_EVLR = ("LASF_Spec", 65535)
#: Point formats with wave packet fields (LAS 1.3: 4, 5; LAS 1.4: 9, 10 too).
WAVEFORM_FORMATS = (4, 5, 9, 10)
#: Point formats whose wave packet fields lazrs does not keep in LAZ (``LasWriter``).
LAZ_WAVE_BROKEN = (9, 10)
#: The wave packet fields of a laspy point record (LAS 1.4 R15, table 14).
WAVE_FIELDS = ("wavepacket_index", "wavepacket_offset", "wavepacket_size",
               "return_point_wave_location", "x_t", "y_t", "z_t")
#: Byte offsets in the public header block (LAS 1.4 R15, table 3).
_HEADER = struct.Struct("<4s20xBB68xHIIBHI")     # signature ... legacy point count
_OFFSET_COUNT_14 = 247                            # uint64 point count (LAS 1.4)
_OFFSET_WAVEFORM = 227                            # uint64 start of waveform data (1.3+)
_EVLR_HEAD = struct.Struct("<H16sHQ32s")          # 60-byte extended VLR header


# DECISION: laspy logs some read failures with ``logger.error`` (a LAZ backend that
# cannot start, fewer points than asked) before raising or returning short; with no
# logging configured, Python prints those on stderr as extra lines. Every such case is
# turned into one PointFileError here, so the library's own log stays silent unless an
# application configures logging (a NullHandler stops only the last-resort printer).
logging.getLogger("laspy").addHandler(logging.NullHandler())


def _vlr_list(items):
    from laspy.vlrs.vlrlist import VLRList

    return VLRList(items)


def _bad(path, what: str) -> PointFileError:
    return PointFileError(f"Expected a LAS/LAZ file, got '{path}' {what}.")


def _raw_header(path: Path, size: int) -> dict[str, int]:
    """The fields needed to check a file before laspy reads it."""
    if size == 0:
        raise _bad(path, "which is empty (0 bytes)")
    with open(path, "rb") as fh:
        raw = fh.read(_OFFSET_COUNT_14 + 8)
    if raw[:4] != b"LASF":
        raise _bad(path, "without the 'LASF' signature")
    if len(raw) < _HEADER.size:
        raise _bad(path, f"of {size} bytes, too short for a LAS header (227 bytes at "
                         "least); it is cut short")
    _, major, minor, head_size, offset, _, fmt, rec_len, legacy = _HEADER.unpack_from(raw)
    if major != 1 or minor > 4:
        raise _bad(path, f"whose header says LAS version {major}.{minor} (expected 1.0 to "
                         "1.4): the header is corrupt (zeros after the signature?)")
    if head_size < 227 or offset < head_size:
        raise _bad(path, f"whose header sizes contradict each other (header {head_size} "
                         f"bytes, points from byte {offset}): the header is corrupt")
    if offset > size:
        raise _bad(path, f"which ends at byte {size:,}, before its points (from byte "
                         f"{offset:,}): it is cut short; copy or export it again")
    compressed = bool(fmt & 0xC0)
    fmt &= 0x3F
    if fmt > 10 or rec_len == 0:
        raise _bad(path, f"whose header names point format {fmt} with {rec_len}-byte "
                         "records (expected formats 0 to 10): the header is corrupt")
    # VLR and EVLR counts laspy trusts (a flipped byte made laspy read minutes of
    # "records" from a 79 KB file): each VLR has a 54-byte header before the points,
    # each EVLR a 60-byte one before the end (LAS 1.4 R15, 2.5 and 2.6).
    n_vlrs = struct.unpack_from("<I", raw, 100)[0]
    if n_vlrs * 54 > offset - head_size:
        raise _bad(path, f"whose header counts {n_vlrs:,} VLRs, which cannot fit in the "
                         f"{offset - head_size:,} bytes before its points: the header is "
                         "corrupt")
    if minor >= 4 and len(raw) >= 247:
        evlr_at, n_evlrs = struct.unpack_from("<QI", raw, 235)
        if n_evlrs and evlr_at + n_evlrs * 60 > size:
            raise _bad(path, f"whose header counts {n_evlrs:,} EVLRs from byte "
                             f"{evlr_at:,}, past its end at byte {size:,}: the header is "
                             "corrupt or the file cut short")
    count = legacy
    if minor >= 4 and len(raw) >= _OFFSET_COUNT_14 + 8:
        count = struct.unpack_from("<Q", raw, _OFFSET_COUNT_14)[0] or legacy
    return {"minor": minor, "offset": offset, "record": rec_len, "count": count,
            "compressed": compressed, "format": fmt}


def _warn(text: str) -> None:
    """Say what a read or rewrite leaves out or changes: one line (the CLI prints a
    warning as "tunnelsim: warning: ...")."""
    warnings.warn(text + ".", UserWarning, stacklevel=3)


def _cut_short(path, promised: int, got: int, how: str) -> PointFileError:
    return PointFileError(
        f"Expected {promised:,} points in '{path}' (its header says so), got {got:,} "
        f"{how}: the file is cut short or corrupt (an interrupted copy or download?); "
        "copy or export it again.")


class LasSource:
    """An open, checked LAS/LAZ file; use as a context manager.

    Attributes
    ----------
    path : Path
    header : laspy.LasHeader
        As read (``point_count``: the points the header promises).
    compressed : bool

    With ``xyz_only``, a LAZ file's other dimensions are not decompressed (zeros).
    """

    def __init__(self, path: str | os.PathLike[str], *, xyz_only: bool = False) -> None:
        import laspy

        self.path = Path(path)
        if not self.path.is_file():
            raise PointFileError(f"Expected a LAS/LAZ file, got '{self.path}' which does "
                                 "not exist.")
        self.size = self.path.stat().st_size
        raw = _raw_header(self.path, self.size)
        self.compressed = raw["compressed"]
        if not self.compressed and self.size < raw["offset"] + raw["count"] * raw["record"]:
            whole = (self.size - raw["offset"]) // raw["record"]
            raise _cut_short(self.path, raw["count"], whole, "whole point records")
        try:
            # Point formats 6-10 compress in layers: x, y, z alone decompress faster.
            sel = laspy.DecompressionSelection
            self._reader = laspy.open(self.path, decompression_selection=(
                sel.XY_RETURNS_CHANNEL | sel.Z if xyz_only else sel.all()))
        except Exception as exc:   # laspy and lazrs raise many types for broken headers
            raise _bad(self.path, f"whose header laspy cannot read ({exc}): it is "
                                  "corrupt") from exc
        self.header = self._reader.header
        sc = np.asarray(self.header.scales, dtype=np.float64)
        off = np.asarray(self.header.offsets, dtype=np.float64)
        if not (np.isfinite(sc).all() and (sc != 0).all() and np.isfinite(off).all()):
            self.close()
            raise _bad(self.path, f"whose coordinate scales {sc.tolist()} or offsets "
                                  f"{off.tolist()} are zero, NaN or infinite: every "
                                  "coordinate would be NaN; fix the header")

    @property
    def point_count(self) -> int:
        return int(self.header.point_count)

    def chunks(self, size: int) -> Iterator[Any]:
        """laspy ``ScaleAwarePointRecord`` chunks of at most ``size`` points; raises
        ``PointFileError`` when the data end before the header's point count."""
        n = self.point_count
        done = 0
        while done < n:
            try:
                with deferred_interrupt():
                    rec = self._reader.read_points(min(size, n - done))
            except Exception as exc:   # lazrs.LazrsError, ValueError from numpy, ...
                raise _cut_short(self.path, n, done,
                                 f"points before the data failed to decompress ({exc})") from exc
            if len(rec) == 0:
                break
            done += len(rec)
            yield rec
        if done != n:
            raise _cut_short(self.path, n, done, "points")

    def header_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(mins (3,), maxs (3,)) as the header states them (not checked)."""
        return (np.asarray(self.header.mins, dtype=np.float64),
                np.asarray(self.header.maxs, dtype=np.float64))

    def evlrs(self) -> list[Any]:
        """The EVLRs to carry into a rewrite of this file (COPC octree pages left out);
        for a LAS 1.3 file, its waveform data record, which laspy does not read.

        Files as other writers leave them (issue 29) are taken as they are: a LAS 1.3
        header whose "start of waveform data packet record" points at no waveform
        record (zero, the end of the file, the points, padding) gives no record. What
        a rewrite cannot keep is said in one warning line each (``warnings.warn``): a
        waveform pointer to nothing, waveform data kept in an external ``.wdp`` file
        (not copied), wave packet fields of points (formats 4, 5, 9, 10) without the
        waveform data they index (kept as they are, pointing nowhere)."""
        why = None
        if self.header.version.minor >= 4:
            out = [v for v in (self.header.evlrs or []) if v.user_id != COPC_USER]
        else:
            out, why = self._waveform_record_13()
        self._say_waveform_state(out, why)
        return out

    def _waveform_record_13(self) -> tuple[list[Any], str | None]:
        """([the LAS 1.3 waveform data record], None) when the header points at one,
        else ([], None) or ([], why the pointer leads to none)."""
        import laspy

        if self.header.version.minor < 3:
            return [], None
        start = int(self.header.start_of_waveform_data_packet_record)
        if start == 0:
            return [], None
        points_end = self._points_end()
        head = b""
        if points_end <= start <= self.size - _EVLR_HEAD.size:
            with open(self.path, "rb") as fh:
                fh.seek(start)
                head = fh.read(_EVLR_HEAD.size)
        if len(head) < _EVLR_HEAD.size:
            return [], (f"its header's waveform data start, byte {start:,}, is where "
                        f"no waveform data record can lie (points end at byte "
                        f"{points_end:,}, the file at {self.size:,})")
        _, user, rid, length, desc = _EVLR_HEAD.unpack(head)
        user_s = user.split(b"\0", 1)[0].decode("ascii", "replace")
        if (user_s, rid) != WAVEFORM_EVLR:
            return [], (f"its header's waveform data start, byte {start:,}, holds no "
                        f"waveform data record (user {WAVEFORM_EVLR[0]!r} record "
                        f"{WAVEFORM_EVLR[1]}), but {user_s[:16]!r} record {rid}")
        if length > self.size - start - _EVLR_HEAD.size:
            raise _bad(self.path, f"whose waveform data record promises {length:,} bytes "
                                  f"and holds {self.size - start - _EVLR_HEAD.size:,}: it "
                                  "is cut short")
        with open(self.path, "rb") as fh:
            fh.seek(start + _EVLR_HEAD.size)
            data = fh.read(length)
        return [laspy.VLR(user_s, rid, desc.rstrip(b"\0").decode("ascii", "replace"),
                          data)], None

    def _points_end(self) -> int:
        """The byte after the point records (LAS; for LAZ, the header's offset: the
        compressed size is unknown before reading)."""
        offset = int(self.header.offset_to_point_data)
        if self.compressed:
            return offset
        return offset + self.point_count * int(self.header.point_format.size)

    def waveform_file(self) -> Path | None:
        """The external waveform data file beside this one (same name, ``.wdp``, as
        LAS 1.3 R11 names it), or None when there is none."""
        for suffix in (".wdp", ".WDP"):
            p = self.path.with_suffix(suffix)
            if p.is_file():
                return p
        return None

    def _say_waveform_state(self, evlrs: list[Any], why: str | None) -> None:
        """Warn, in one line, about waveform data a rewrite does not carry (see
        ``evlrs``); ``why``: how the header's waveform pointer leads nowhere."""
        if any((str(v.user_id).rstrip("\0"), v.record_id) == WAVEFORM_EVLR
               for v in evlrs):
            return
        wdp = self.waveform_file()
        pointer = "" if why is None else f"; {why}, which is not carried"
        if self.header.global_encoding.waveform_data_packets_external and wdp is not None:
            _warn(f"'{self.path}' keeps its waveform data in '{wdp.name}' (external), "
                  "which a rewrite does not copy: the wave packet fields are kept; copy "
                  "that file beside the output, named as the output with .wdp, to use "
                  f"them{pointer}")
        elif self.header.point_format.id in WAVEFORM_FORMATS:
            _warn(f"'{self.path}' has wave packet fields (point format "
                  f"{self.header.point_format.id}) but no waveform data (none in the "
                  "file, no .wdp beside it): they are kept as they are and point "
                  f"nowhere{pointer}")
        elif why is not None:
            _warn(f"'{self.path}' (LAS {self.header.version}): {why}; no waveform data "
                  "carried")

    def close(self) -> None:
        self._reader.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def output_header(source: Any, *, scales: np.ndarray | None = None,
                  offsets: np.ndarray | None = None,
                  extra: Mapping[str, np.dtype] | None = None) -> Any:
    """A header for rewriting the file ``source`` (a ``LasSource``): its version, point
    format (extra bytes included, with their descriptions), global encoding,
    identifiers, dates and VLRs, with the COPC octree VLR left out and the ``extra``
    dimensions {name: dtype} added, each described with its unit
    (``sensors.io.fields.las_description``; an input extra dimension of the same name is
    replaced). EVLRs are passed to ``LasWriter`` separately (``source.evlrs()``).

    A LAS 1.0 input gives a LAS 1.1 header (laspy writes 1.1 and later; the point
    records of formats 0 and 1 are the same bytes), with a warning."""
    import laspy

    head = copy.deepcopy(source.header)
    head.vlrs = _vlr_list([v for v in head.vlrs if v.user_id != COPC_USER and
                               type(v).__name__ != "LasZipVlr"])
    head.evlrs = None
    head.start_of_waveform_data_packet_record = 0
    if head.version.minor == 0:
        # DECISION: 1.1, the nearest version laspy writes: LAS 1.1 turned the
        # header's reserved bytes 4-5 into the file source ID (zero in a 1.0 file,
        # zero here) and dropped the 0xCCDD point data start signature; the public
        # header keeps its 227 bytes and the point records of formats 0 and 1 are byte
        # for byte the same.
        head.version = laspy.header.Version(1, 1)
        _warn(f"'{source.path}' is LAS 1.0, which laspy does not write: the output is "
              "LAS 1.1, with the same point records")
    if scales is not None:
        head.scales = np.asarray(scales, dtype=np.float64)
    if offsets is not None:
        head.offsets = np.asarray(offsets, dtype=np.float64)
    if extra:
        old = [e for e in head.point_format.extra_dimension_names if e in extra]
        if old:
            head.remove_extra_dims(old)
        head.add_extra_dims(extra_params(extra))
    return head


def extra_params(extra: Mapping[str, Any]) -> list[Any]:
    """laspy ``ExtraBytesParams`` of dimensions {name: dtype (or array)}, each described
    with its unit where tunnelsim writes it (``sensors.io.fields.LAS_DESCRIPTIONS``)."""
    import laspy

    return [laspy.ExtraBytesParams(name=k, type=np.dtype(getattr(t, "dtype", t)),
                                   description=las_description(k))
            for k, t in extra.items()]


def is_crs_record(vlr: Any) -> bool:
    """Whether a VLR/EVLR describes the CRS (user ``LASF_Projection``)."""
    return str(vlr.user_id).rstrip("\0") == CRS_USER


def las_crs_wkt(header: Any) -> str | None:
    """The WKT of a LAS header's OGC Coordinate System WKT record (VLR, else EVLR),
    without pyproj; None when it has none (GeoTIFF keys need ``header.parse_crs()``)."""
    for v in list(header.vlrs) + list(header.evlrs or []):
        if is_crs_record(v) and v.record_id == CRS_WKT_RECORD:
            text = getattr(v, "string", None)
            if text is None:
                text = bytes(v.record_data).decode("utf-8", "replace")
            text = text.rstrip("\0").strip()
            if text:
                return text
    return None


def set_las_crs(header: Any, crs: Any) -> None:
    """Replace a header's CRS records with ``crs`` (as ``sensors.io.crs.parse_crs`` takes
    it), or remove them (``crs`` None; the WKT bit is cleared). LAS 1.4: the WKT VLR
    (``sensors.io.crs.file_wkt``) and the global-encoding WKT bit; LAS 1.0-1.3 with point
    formats 0-5: GeoTIFF keys (laspy ``add_crs``; a CRS without an EPSG code may not
    fit them). EVLRs are the caller's to filter (``is_crs_record``)."""
    from laspy.vlrs.known import WktCoordinateSystemVlr

    from .crs import CRSError, file_wkt, parse_crs

    header.vlrs = _vlr_list([v for v in header.vlrs if not is_crs_record(v)])
    if crs is None:
        if header.version.minor >= 4:
            header.global_encoding.wkt = False
        return
    if header.version.minor >= 4 or header.point_format.id >= 6:
        header.vlrs.append(WktCoordinateSystemVlr(file_wkt(crs)))
        header.global_encoding.wkt = True
        return
    try:
        header.add_crs(parse_crs(crs, metric=False))
    except Exception as exc:   # laspy/pyproj raise several types for CRSs GeoTIFF lacks
        raise CRSError(f"Expected a CRS that GeoTIFF keys can hold for a LAS "
                       f"{header.version} file, got one they cannot ({exc}); write LAS "
                       "1.4.") from exc


def offsets_near(xyz: np.ndarray) -> np.ndarray:
    """LAS offsets for coordinates ``xyz`` (n, 3): the first point rounded to a
    kilometre, so that a 0.1 mm scale reaches 214 km around it (UTM keeps 0.1 mm)."""
    first = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)[:1]
    return np.round(first[0] / 1000.0) * 1000.0 if len(first) else np.zeros(3)


def quantize(xyz: np.ndarray, scales: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(n, 3) int32 LAS integer coordinates of ``xyz`` (n, 3) float64; raises
    ``PointFileError`` for NaN or for coordinates beyond the int32 range."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    q = np.round((xyz - offsets) / scales)
    bad = ~(np.abs(q) < 2**31 - 1).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise PointFileError(f"Expected coordinates within {float(np.min(scales)) * 2**31:,.0f}"
                             f" m of the LAS offset {np.asarray(offsets).tolist()}, got point "
                             f"{i} at {xyz[i].tolist()}; split the output or remove it.")
    return q.astype(np.int32)


def point_records(header: Any, xyz: np.ndarray,
                  fields: Mapping[str, np.ndarray] | None = None) -> Any:
    """A laspy ``ScaleAwarePointRecord`` for ``header`` with coordinates ``xyz`` (n, 3)
    and the other dimensions from ``fields`` {name: (n,) array} (zero elsewhere; raw
    array names such as ``bit_fields`` are accepted)."""
    import laspy

    q = quantize(xyz, header.scales, header.offsets)
    rec = laspy.ScaleAwarePointRecord.zeros(len(q), header=header)
    a = rec.array
    a["X"], a["Y"], a["Z"] = q.T
    for name, v in (fields or {}).items():
        a[name] = v
    return rec


class LasRecords:
    """Point records for ``header`` built into one reused buffer (a stream of chunks
    would otherwise allocate, and page in, a new record array per chunk).

    ``fill`` returns a laspy ``ScaleAwarePointRecord`` that views the buffer: it is
    valid until the next ``fill`` (hand it to a writer before then). The coordinates
    are quantised as ``quantize`` does it, column by column with the same arithmetic
    (same integers); every other dimension holds what NumPy's assignment would put
    there (files are byte-identical to ``point_records``'s).

    DECISION: not field by field. The computed dimensions go into a small packed
    array first; it and the ``copies`` from the caller's records are then moved into
    the LAS records as runs of adjacent bytes (a NumPy void-field copy per run, a
    memcpy per record): a full Airy record is 2 runs from the packed array and 5 from
    the POINT_DTYPE records, not 23 typed field assignments, each of which reads
    every cache line of both arrays. Measured per 860k points (2-core VM): typed
    assignment 0.27 s, a byte-copy Numba kernel 0.10 s CPU, void runs 0.036 s CPU.
    """

    def __init__(self, header: Any) -> None:
        self.header = header
        self.dtype = header.point_format.dtype()
        self._buf = np.empty(0, dtype=self.dtype)
        self._aux = np.empty(0, dtype=np.uint8)
        self._scales = np.asarray(header.scales, dtype=np.float64)
        self._offsets = np.asarray(header.offsets, dtype=np.float64)

    @property
    def scales(self) -> np.ndarray:
        """(3,) float64: the header's coordinate scales."""
        return self._scales

    @property
    def offsets(self) -> np.ndarray:
        """(3,) float64: the header's coordinate offsets."""
        return self._offsets

    def buffer(self, n: int) -> np.ndarray:
        """(n,) records of the header's point dtype, from the reused buffer (valid until
        the next ``fill`` or ``buffer``), for a caller that fills every byte itself and
        hands the result to ``wrap``."""
        if len(self._buf) < n:
            self._buf = np.empty(n, dtype=self.dtype)
        return self._buf[:n]

    def wrap(self, records: np.ndarray) -> Any:
        """A laspy ``ScaleAwarePointRecord`` viewing ``records`` (from ``buffer``)."""
        import laspy

        return laspy.ScaleAwarePointRecord(records, self.header.point_format,
                                           self._scales, self._offsets)

    def _bytes_alike(self, name: str, src: np.dtype) -> bool:
        dst = self.dtype[name]
        if src.shape or dst.shape or src.itemsize != dst.itemsize or \
                not (src.isnative and dst.isnative):
            return False
        return src == dst or (src.kind in "iu" and dst.kind in "iu")

    def fill(self, xyz: tuple[np.ndarray, np.ndarray, np.ndarray] | np.ndarray,
             fields: Mapping[str, Any] | None = None, *, records: np.ndarray | None = None,
             copies: Mapping[str, str] | None = None) -> Any:
        """Records with coordinates ``xyz`` (three (n,) columns, or (n, 3)), the
        dimensions ``fields`` {name: (n,) array or scalar} (raw names such as
        ``bit_fields`` accepted) and ``copies`` {dimension: field of ``records``}
        (a structured (n,) array; an integer field goes to an integer dimension of its
        size as NumPy casts it); zero elsewhere. Raises ``PointFileError`` for NaN or
        for coordinates beyond the int32 range, and for an unknown dimension."""
        import laspy

        cols = [np.asarray(v, dtype=np.float64) for v in
                (xyz.T if isinstance(xyz, np.ndarray) else xyz)]
        n = len(cols[0])
        fields = dict(fields or {})
        copies = dict(copies or {})
        names = self.dtype.names or ()
        unknown = sorted((set(fields) | set(copies)) - set(names[3:]))
        if unknown:
            raise PointFileError(f"Expected dimensions of point format "
                                 f"{self.header.point_format.id} with its extra bytes "
                                 f"(X, Y, Z from `xyz`), got {unknown}.")
        if copies and records is None:
            raise PointFileError("Expected the `records` that `copies` names fields of, "
                                 "got none.")
        for name in [k for k, f in copies.items()
                     if not self._bytes_alike(k, records.dtype[f])]:   # type: ignore[union-attr]
            fields[name] = records[copies.pop(name)]                   # type: ignore[index]
        # The dimensions computed here, packed in record order (X, Y, Z first).
        own = [k for k in names if k not in copies]
        aux_dt = np.dtype([(k, self.dtype[k]) for k in own])
        if len(self._buf) < n:
            self._buf = np.empty(n, dtype=self.dtype)
        if len(self._aux) < n * aux_dt.itemsize:
            self._aux = np.empty(n * aux_dt.itemsize, dtype=np.uint8)
        a = self._buf[:n]
        aux = self._aux[:n * aux_dt.itemsize].view(aux_dt)
        for k, name in enumerate("XYZ"):
            q = np.round((cols[k] - self._offsets[k]) / self._scales[k])
            if not (np.abs(q) < 2**31 - 1).all():
                quantize(np.stack(cols, 1), self._scales, self._offsets)   # raises
            aux[name] = q
        for name in own[3:]:
            aux[name] = fields.get(name, 0)
        if n:
            _copy_runs(aux, a, [(field_offset(aux_dt, k), field_offset(self.dtype, k),
                                 aux_dt[k].itemsize) for k in own])
            if copies and records is not None:
                _copy_runs(records, a, [(field_offset(records.dtype, f),
                                         field_offset(self.dtype, k),
                                         self.dtype[k].itemsize)
                                        for k, f in copies.items()])
        return laspy.ScaleAwarePointRecord(a, self.header.point_format, self._scales,
                                           self._offsets)


def _copy_runs(src: np.ndarray, dst: np.ndarray, moves: list[tuple[int, int, int]]
               ) -> None:
    """Copy the bytes (source offset, target offset, count) of every record of ``src``
    (n,) into those of ``dst`` (n,), adjacent moves merged into one run each."""
    runs: list[list[int]] = []
    for s, d, k in sorted(moves):
        if runs and runs[-1][0] + runs[-1][2] == s and runs[-1][1] + runs[-1][2] == d:
            runs[-1][2] += k
        else:
            runs.append([s, d, k])
    names = [f"r{j}" for j in range(len(runs))]
    src_v = src.view(np.dtype({"names": names, "formats": [f"V{r[2]}" for r in runs],
                               "offsets": [r[0] for r in runs],
                               "itemsize": src.dtype.itemsize}))
    dst_v = dst.view(np.dtype({"names": names, "formats": [f"V{r[2]}" for r in runs],
                               "offsets": [r[1] for r in runs],
                               "itemsize": dst.dtype.itemsize}))
    for name in names:
        dst_v[name] = src_v[name]


class LasWriter(AtomicStream):
    """A LAS/LAZ file written as a stream of point records, atomically.

    Parameters
    ----------
    path : path-like
        The file; LAZ when ``compress`` is True (default: from the ``.laz`` suffix).
    header : laspy.LasHeader
        Scales and offsets must be final: records are stored in them.
    evlrs : iterable of laspy VLRs
        Written after the points (LAS 1.3: only a waveform data record).
    waveform_packets : path-like, optional
        LAS 1.4: a file holding the waveform data packets back to back, as the points'
        ``wavepacket_offset`` index them (the first at byte 60, after the record's
        header): appended on ``close`` as the waveform data packet record (EVLR
        ``LASF_Spec`` 65535) after the other EVLRs, streamed (never whole in memory);
        the header's start of waveform data, EVLR count and (where it has no other
        EVLR) start of the first EVLR point at it, and the global encoding says
        "internal" (bit 1). The file is the caller's to remove.

    ``write_points`` takes laspy point records of the header's point format; ``close``
    writes the EVLRs, points the header at the waveform data (if any) and moves the
    file into place; an exception inside ``with`` leaves nothing at ``path``.
    """

    def __init__(self, path: str | os.PathLike[str], header: Any, *,
                 compress: bool | None = None, evlrs: Iterable[Any] = (),
                 waveform_packets: str | os.PathLike[str] | None = None) -> None:
        import laspy

        path = Path(path)
        self._evlrs = list(evlrs)
        self._packets = None if waveform_packets is None else Path(waveform_packets)
        if self._packets is not None:
            if header.version.minor < 4 or any(
                    (v.user_id, v.record_id) == WAVEFORM_EVLR for v in self._evlrs):
                raise PointFileError(f"Expected a LAS 1.4 header without another waveform "
                                     f"record for waveform packets, got LAS "
                                     f"{header.version} for '{path}'.")
            header.global_encoding.waveform_data_packets_internal = True
            header.global_encoding.waveform_data_packets_external = False
        if header.version.minor < 4 and [v for v in self._evlrs
                                         if (v.user_id, v.record_id) != WAVEFORM_EVLR]:
            raise PointFileError(f"Expected EVLRs only in LAS 1.4 (or a waveform record in "
                                 f"1.3), got others for '{path}' (LAS {header.version}).")
        compress = path.suffix.lower() == ".laz" if compress is None else compress
        super().__init__(path)
        try:
            # "replace": a header copied from another writer may hold non-ASCII text
            # (a VLR description, a system identifier) that laspy refuses to encode.
            self._writer = laspy.open(self._fh, mode="w", header=header, closefd=False,
                                      do_compress=compress, encoding_errors="replace")
        except BaseException as exc:
            self._discard(exc)
            if isinstance(exc, Exception):   # laspy raises several types for these
                raise PointFileError(f"Expected a LAS header laspy can write for "
                                     f"'{path}', got one it refuses: {exc}.") from exc
            raise
        self.header = self._writer.header
        self.n_points = 0
        # DECISION: lazrs 0.8 (laspy's LAZ codec) changes varying wave packet fields of
        # point formats 9 and 10 in a LAZ round trip (found by
        # tests/sensors/io/test_las_versions.py: offsets, sizes and x(t) of a third of
        # the points differ; constant fields survive). Silently wrong values are
        # worse than none: a LAZ output of those formats gets them as zeros, said
        # once; a .las output keeps them.
        self._zero_wave = compress and header.point_format.id in LAZ_WAVE_BROKEN
        self._said_wave = False

    def write_points(self, records: Any) -> None:
        """Append laspy point records (``point_records`` makes them)."""
        if self._zero_wave:
            records = self._without_wave(records)
        with deferred_interrupt():
            self._writer.write_points(records)
        self.n_points += len(records)

    def _without_wave(self, records: Any) -> Any:
        """``records`` with their wave packet fields zero (see ``__init__``)."""
        import laspy

        a = records.array
        if not any(np.any(a[k]) for k in WAVE_FIELDS):
            return records
        if not self._said_wave:
            self._said_wave = True
            _warn(f"'{self.path}': LAZ (lazrs) does not keep varying wave packet fields "
                  f"of point format {self.header.point_format.id}, so they are written "
                  "as zeros (every other field is kept); write .las to keep them")
        a = a.copy()
        for k in WAVE_FIELDS:
            a[k] = 0
        return laspy.ScaleAwarePointRecord(a, records.point_format, records.scales,
                                           records.offsets)

    def _finish(self) -> None:
        with deferred_interrupt():
            if self.header.version.minor >= 4 and self._evlrs:
                self._writer.write_evlrs(_vlr_list(self._evlrs))
            self._writer.close()
        if self._evlrs:
            self._place_evlrs()
        if self._packets is not None:
            self._append_packets(self._packets)
        super()._finish()

    def _append_packets(self, packets: Path) -> None:
        """Append the waveform data packet record (LAS 1.4 R15, 2.6: an EVLR of user
        ``LASF_Spec``, record 65535) holding ``packets``' bytes, and point the header
        at it: start of waveform data packet record (byte 227), start of the first
        EVLR and EVLR count (bytes 235 and 243)."""
        import shutil

        fh = self._fh
        pos = fh.seek(0, os.SEEK_END)
        size = packets.stat().st_size
        with deferred_interrupt():
            fh.write(_EVLR_HEAD.pack(0, WAVEFORM_EVLR[0].encode(), WAVEFORM_EVLR[1], size,
                                     b"waveform data packets"))
            with open(packets, "rb") as src:
                shutil.copyfileobj(src, fh, 1 << 24)
            before = len(self._evlrs)
            first = int(self.header.start_of_first_evlr) if before else pos
            fh.seek(_OFFSET_WAVEFORM)
            fh.write(struct.pack("<Q", pos))
            fh.seek(_OFFSET_WAVEFORM + 8)
            fh.write(struct.pack("<QI", first, before + 1))
            fh.seek(0, os.SEEK_END)

    def _place_evlrs(self) -> None:
        """LAS 1.3: append the waveform record laspy does not write. Both versions:
        point the header's waveform field at that record's new place."""
        fh = self._fh
        if self.header.version.minor >= 4:
            pos = int(self.header.start_of_first_evlr)
        else:
            pos = fh.seek(0, os.SEEK_END)
            _vlr_list(self._evlrs).write_to(fh, as_extended=True)
        for v in self._evlrs:
            if (v.user_id, v.record_id) == WAVEFORM_EVLR:
                fh.seek(_OFFSET_WAVEFORM)
                fh.write(struct.pack("<Q", pos))
                break
            pos += _EVLR_HEAD.size + len(v.record_data_bytes())
        fh.seek(0, os.SEEK_END)


#: Points per record chunk when whole arrays are written.
WRITE_CHUNK = 1 << 20


def write_las(path: str | os.PathLike[str], xyz: np.ndarray, *,
              fields: Mapping[str, np.ndarray] | None = None,
              extra: Mapping[str, np.ndarray] | None = None,
              point_format: int = 6, scale: float = LAS_SCALE,
              vlrs: Iterable[Any] = (), system_identifier: str = "",
              compress: bool | None = None, crs: Any = None,
              extra_dims: Mapping[str, Any] | None = None) -> Path:
    """Write points ``xyz`` (n, 3) float64 as LAS 1.4 (default point format 6, scale
    ``scale`` m, offsets near the data), atomically, in chunks.

    ``fields`` fills standard dimensions {name: (n,) array} (e.g. ``classification``,
    ``intensity``, ``gps_time``); ``extra`` adds extra-bytes dimensions of the arrays'
    dtypes, each described with its unit where tunnelsim knows the name
    (``sensors.io.fields.LAS_DESCRIPTIONS``); ``extra_dims`` {name: laspy
    ``ExtraBytesParams``} describes an ``extra`` array as another file had it (type,
    description, scale and offset: the array holds the stored values); ``crs`` (as
    ``sensors.io.crs.parse_crs`` takes it) writes the WKT VLR. Every point is "return 1
    of 1". Returns the path.
    """
    import laspy

    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    head = laspy.LasHeader(point_format=point_format, version="1.4")
    head.scales = np.full(3, scale)
    head.offsets = offsets_near(xyz)
    head.generating_software = "tunnelsim"
    if system_identifier:
        head.system_identifier = system_identifier[:32]
    extra = {k: np.asarray(v) for k, v in (extra or {}).items()}
    given = dict(extra_dims or {})
    head.add_extra_dims([given[k] if k in given else extra_params({k: v})[0]
                         for k, v in extra.items()])
    head.vlrs.extend(vlrs)
    if crs is not None:
        set_las_crs(head, crs)
    every = dict(fields or {}, **extra)
    with LasWriter(path, head, compress=compress) as w:
        for i in range(0, len(xyz), WRITE_CHUNK):
            part: dict[str, Any] = {k: np.asarray(v)[i:i + WRITE_CHUNK]
                                    for k, v in every.items()}
            # return 1 of 1: 4 + 4 bits from format 6 on, 3 + 3 bits before it
            part.setdefault("bit_fields", 0x11 if point_format >= 6 else 0x09)
            w.write_points(point_records(w.header, xyz[i:i + WRITE_CHUNK], part))
    return Path(path)
