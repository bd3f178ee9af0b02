"""Point-cloud writers as streams, in laspy's shape::

    with open_writer("scan.laz", sensor="zf_imager_5016", seed=7, pose=(position, rot)) as w:
        for chunk in run:            # POINT_DTYPE records
            w.write_points(chunk)

A writer is given what it stores (the sensor's name, the seed, a TLS station's pose),
not the object that produces the points; ``Run.write`` is a loop over a run's chunks
into one. Memory stays bounded by one chunk (E57 excepted, see below), and the file is
written under a temporary name renamed into place on a clean close: an interrupted run
(an exception, Ctrl-C) leaves no file that looks complete.

- **LAS 1.4 / LAZ** (``sensors.io.las``): point format 6 with GPS time (the pulse time),
  intensity (``intensity`` x 65535), return 1 of 1 (or the chunk's
  ``return_number``/``number_of_returns`` where it has them: multiple returns,
  ``sensors.waveform``, whose ``echo_width``/``echo_amplitude`` then go into extra
  bytes too), scan angle (the beam's elevation in
  the sensor frame, in the format's 0.006 deg units), user data (channel mod 256),
  point source ID (frame mod 65536) and classification 7 (noise) for particle returns,
  else 0. The other fields go into extra bytes: all of them (``fields="full"``:
  sensor_x, sensor_y, sensor_z, range, azimuth, elevation, channel, column, frame,
  incidence, triangle, flag; the default for moving platforms; sensor_x, sensor_y,
  sensor_z and range as float32 since issue 30, which rounds them by at most 31 um below
  512 m, see ``sensors.io.fields``; NPZ and PLY keep float64) or the four a station
  cannot recompute (``"compact"``: channel, column, triangle, flag; the default for TLS
  stations, 3x faster to compress). A VLR (user "tunnelsim", record 1) holds the
  sensor, seed and station pose (or the platform mount of a drive) as JSON. Coordinates: scale 0.1 mm, offset = the first
  point rounded to a kilometre, so UTM coordinates keep 0.1 mm.
  **Full waveform** (chunks of ``WAVEFORM_POINT_DTYPE``, ``Settings(waveform=True)``,
  ``open_writer(waveform=True)``): LAS 1.4 point format 9 in a .las, 4 in a .laz (the
  same fields as format 6 but 3-bit return numbers and a whole-degree scan angle:
  lazrs changes varying wave packet fields of format 9 in LAZ), one wave packet
  descriptor (``LASF_Spec`` 100: 16 bits, uncompressed, ``WAVE_SAMPLES`` samples, the
  bin in ps, gain = the device's waveform threshold per count, offset 0) and each
  point's packet index, offset, size, return point location and x(t), y(t), z(t). The
  packets (each distinct window once) are spilled to a file beside the output while
  the points stream, then become the .las's waveform data packet record (EVLR
  ``LASF_Spec`` 65535, global encoding bit 1) or ``NAME.wdp`` (bit 2; always for
  .laz, for .las with ``waveform_data="external"``).
- **PLY** (``sensors.io.ply``, binary little endian): every field as a vertex property;
  the vertex count in the header is patched at the end.
- **NPZ**: one array per field, as ``numpy.load`` returns them; chunks go to temporary
  raw files and are zipped at the end.

Every format names a field as ``sensors.io.fields.FILE_FIELDS`` says (issue 22): the LAS
names (``sensor_x``, ``sensor_y``, ``sensor_z``, ``gps_time``, the rest as in
``POINT_DTYPE``) in LAS extra bytes, PLY properties and NPZ arrays alike.

``PointWriter.write_returned`` takes a single-return chunk as its returned pulses (what
``Run.write`` hands over for a run larger than its replay cache): the LAS/LAZ writer
makes its records straight from them (one kernel, ``sensors._kernels.pulses.las_points``,
into a reused record buffer; issue 33), every other format stores their point records;
the bytes are those of ``write_points``.

LAS/LAZ, PLY and NPZ are stored by a writer thread (``sensors.io.stream.Background``,
``open_writer(thread=True)``, the default): ``write_points`` queues the chunk (two at
most wait) and the simulation goes on while it is turned into records and compressed
(lazrs and file writes release the GIL). An error on the thread is raised by the next
``write_points`` or by ``close``; an exception or Ctrl-C in the caller stops the thread
before the file is dropped. The bytes are those of the unthreaded writer.
- **E57** (``sensors.io.e57``, TLS stations only): one structured scan with row/column
  indices (channel = row along the vertical sweep, column = line), sensor-frame
  Cartesian coordinates and the station pose. pye57 writes a scan in one call, so the
  scan is gathered in memory first; ``E57_MAX_POINTS`` guards the machine.
- **ROS 2 bags** (``sensors.bag``, moving platforms only; needs ``rosbags``): ``.mcap``
  is one MCAP file, a path without a suffix a rosbag2 folder (format "rosbag2", as
  ``ros2 bag record -o NAME`` makes): one PointCloud2 per whole sweep in the sensor's
  ROS 2 driver layout, /tf_static, and with ``trajectory`` /tf, ground-truth odometry
  and an IMU. Memory stays bounded by one sweep and one chunk.

With ``crs`` (``sensors.io.crs``: EPSG:n, WKT or PROJJSON; needs pyproj) the file states
the world coordinates' coordinate reference system: LAS/LAZ in the OGC WKT VLR (and
the WKT bit), E57 in ``coordinateMetadata``, PLY and NPZ in a sidecar ``<file>.prj``
(an older sidecar of the same name is removed when a file is written without a CRS),
a ROS 2 bag in its ``tunnelsim`` metadata (``crs``: the WKT of the ``map`` frame).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import struct
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from raytrace.fileio import atomic_writer

from .bag import RosbagStream
from .io.copc import CopcWriter
from .io.crs import file_wkt, parse_crs, write_sidecar
from .io.e57 import E57_MAX_POINTS, write_e57_scan
from .io.errors import PointFileError
from .io.fields import (
    FIELD_NAMES,
    FILE_DTYPE,
    FILE_FIELDS,
    LAS_COMPACT,
    LAS_EXTRA,
    POINT_DTYPE,
    WAVE_SAMPLES,
    WAVEFORM_FIELDS,
    file_records,
)
from .io.las import (
    LAS_SCALE,
    LasRecords,
    LasWriter,
    extra_params,
    offsets_near,
    set_las_crs,
)
from .io.ply import PlyWriter
from .spec import SensorSpec, load_sensor
from .io.stream import Background, Stream, deferred_interrupt
from .trajectory import Trajectory
from .waveform import BIN_S, WAVE_BITS

__all__ = ["FORMATS", "PointWriter", "format_of",
           "open_writer"]

FORMATS = ("las", "laz", "copc", "ply", "npz", "e57", "mcap", "rosbag2")

def format_of(path: str | os.PathLike[str], fmt: str | None = None) -> str:
    """The output format: ``fmt``, else the path's suffix; one of ``FORMATS``. A path
    without a suffix is a rosbag2 folder ("rosbag2")."""
    # DECISION: no suffix means a bag folder, as `ros2 bag record -o NAME` names one.
    f = (fmt or Path(path).suffix.lstrip(".") or "rosbag2").lower()
    if fmt is None and Path(path).name.lower().endswith(".copc.laz"):
        f = "copc"     # COPC is LAZ: the double suffix names it, as PDAL and QGIS read it
    if f not in FORMATS:
        raise PointFileError(f"Expected an output format in {FORMATS} (from the suffix or "
                             f"`fmt`), got {f!r} for '{path}'.")
    return f


def _quaternion(rotation: Any) -> np.ndarray:
    q = rotation.as_quat() if hasattr(rotation, "as_quat") else rotation
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (4,) or not np.isfinite(q).all():
        raise PointFileError(f"Expected a station rotation (scipy Rotation or quaternion "
                             f"x, y, z, w), got shape {q.shape}.")
    return q


class PointWriter(Stream):
    """A stream of ``POINT_DTYPE`` chunks into one file (made by ``open_writer``).

    Attributes: ``path``, ``sensor`` (name), ``seed``, ``position`` (3,) and
    ``quaternion_xyzw`` (4,) of a TLS station (None for a moving platform), ``mount``
    (the sensor's ``Mount`` on a moving platform, or None), ``crs`` (the WKT the file
    states, or None), ``n_points`` written so far, ``threaded`` (whether the chunks are
    stored by a writer thread).

    With a writer thread (``Background``), ``write_points`` queues the chunk and
    returns: the caller must not change a chunk it has handed over. The file's bytes
    are the same with and without the thread (the chunks are stored in order by one
    thread either way).
    """

    def __init__(self, path: Path, *, sensor: str | SensorSpec, seed: int, pose: Any,
                 mount: Any = None, crs: Any = None, threaded: bool = False) -> None:
        name = sensor.name if isinstance(sensor, SensorSpec) else str(sensor)
        self.path, self.sensor, self.seed = path, name, int(seed)
        # Parsed here, before any point is simulated: a bad CRS fails at once.
        self.crs: str | None = None if crs is None else file_wkt(
            parse_crs(crs, metric=True, what="the output CRS"))
        self.position = self.quaternion_xyzw = None
        if pose is not None:
            pos, rot = pose
            self.position = np.asarray(pos, dtype=np.float64).reshape(3)
            self.quaternion_xyzw = _quaternion(rot)
        self.mount = mount
        self.n_points = 0
        self._open = True
        self.threaded = bool(threaded)
        self._worker: Background | None = None

    def info(self) -> dict[str, Any]:
        """What the file records about its origin (JSON-ready)."""
        out: dict[str, Any] = {"sensor": self.sensor, "seed": self.seed}
        if self.position is not None and self.quaternion_xyzw is not None:
            out["station_position"] = self.position.tolist()
            out["station_quaternion_xyzw"] = self.quaternion_xyzw.tolist()
        if self.mount is not None:
            out["mount_lever_arm_m"] = list(self.mount.lever_arm_m)
            out["mount_boresight_xyzw"] = _quaternion(self.mount.boresight).tolist()
        return out

    def write_points(self, points: np.ndarray) -> None:
        """Append a chunk of ``POINT_DTYPE`` records (n,)."""
        if not self._open:
            raise PointFileError(f"Expected an open writer for '{self.path}', got a "
                                 "closed one.")
        pts = np.asarray(points)
        missing = [n for n in FIELD_NAMES if n not in (pts.dtype.names or ())]
        if pts.ndim != 1 or missing:
            raise PointFileError(f"Expected (n,) records with the fields of POINT_DTYPE, "
                                 f"got shape {pts.shape} without {missing}.")
        if self.threaded:
            if self._worker is None:
                self._worker = Background(self._write)
            self._worker.put(pts)
        else:
            self._write(pts)
        self.n_points += len(pts)

    def write_returned(self, returned: Any) -> None:
        """Append a chunk of a single-return simulation as its returned pulses (the
        ``sensors.simulate`` object with ``points()`` and ``fill_las(...)``): a LAS/LAZ
        writer makes its records straight from them (``_LasPoints``), every other
        format stores ``returned.points()``. The file's bytes are those of
        ``write_points(returned.points())``."""
        if not self._takes_returned:
            self.write_points(returned.points())
            return
        if not self._open:
            raise PointFileError(f"Expected an open writer for '{self.path}', got a "
                                 "closed one.")
        if self.threaded:
            if self._worker is None:
                self._worker = Background(self._write)
            self._worker.put(returned)
        else:
            self._write(returned)
        self.n_points += len(returned)

    #: Whether ``_write`` takes returned pulses as well as point records.
    _takes_returned = False

    def close(self) -> Path:
        """Store the queued chunks, finish the file and move it into place; returns
        its path."""
        if self._open and self._worker is not None:
            try:
                self._worker.finish()
            except BaseException as exc:
                self._open = False
                self._discard(exc)
                raise
        return super().close()

    def _cancel(self) -> None:
        """Stop the writer thread (before the file is discarded)."""
        if self._worker is not None:
            with deferred_interrupt():   # a second Ctrl-C must not skip the clean-up
                self._worker.cancel()

    def abort(self) -> None:
        """Drop the file being written (nothing appears at ``path``)."""
        if self._open:
            self._cancel()
        super().abort()

    def __exit__(self, kind: object, exc: BaseException | None, tb: object) -> None:
        if exc is not None and self._open:
            self._cancel()
        super().__exit__(kind, exc, tb)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}('{self.path}', sensor={self.sensor!r}, "
                f"{self.n_points:,} points{'' if self._open else ', closed'})")

    def _write(self, pts: np.ndarray) -> None:   # one per format, as _finish, _discard
        raise NotImplementedError


#: Echo fields of multiple returns (``sensors.waveform.RETURN_FIELDS``) stored as LAS
#: extra bytes where a chunk has them: (name, POINT field, type, description).
LAS_ECHO_EXTRA: tuple[tuple[str, str, str, str], ...] = (
    ("echo_width", "echo_width", "f4", "echo Gaussian sigma [m]"),
    ("echo_amplitude", "echo_amplitude", "f4", "echo peak [relative power]"))
#: The return-number fields a chunk of multiple returns has (``RETURN_FIELDS``).
_RETURN_BITS = ("return_number", "number_of_returns")


#: LAS 1.4 R15 wave packet descriptor payload (user ``LASF_Spec``, record 99 + index, 26
#: bytes): bits per sample, compression type, number of samples, temporal sample
#: spacing (ps), digitizer gain, digitizer offset.
WAVE_DESCRIPTOR = struct.Struct("<BBIIdd")
#: Bytes of the waveform data packet record's header (an EVLR header; a ``.wdp`` file
#: starts with one too): packet offsets count from its first byte.
WAVE_RECORD_HEADER = 60
#: Point formats of full-waveform output: 9 in .las (format 6 plus wave packets, what
#: every other LAS output of the simulation is), 4 in .laz (see ``_LasPoints``).
WAVE_FORMAT_LAS, WAVE_FORMAT_LAZ = 9, 4
#: Where waveform packets go (``open_writer(waveform_data=...)``).
WAVEFORM_DATA = ("internal", "external")


class _LasPoints(PointWriter):
    def __init__(self, path, *, compress: bool, fields: str, copc: bool = False,
                 waveform: bool = False, wdp: bool = False, **kw) -> None:
        super().__init__(path, **kw)
        self._compress = compress
        self._copc = copc
        # Full waveform (WAVEFORM_POINT_DTYPE chunks): packets are spilled to a file
        # beside the target as they come (memory stays bounded by a chunk), then
        # appended to the .las as its waveform EVLR or copied into NAME.wdp.
        self._waveform = bool(waveform)
        self._wdp = bool(wdp)
        self._wave = False
        self._spill: Any = None
        self._n_packets = 0
        self._packet_bytes = 0
        self._last_key: tuple[float, int, int, float] | None = None
        self._wave_desc: tuple[int, float] | None = None
        self._extra = LAS_EXTRA if fields == "full" else \
            tuple(e for e in LAS_EXTRA if e[0] in LAS_COMPACT)
        self._echo: tuple[tuple[str, str, str, str], ...] = ()
        self._returns = False
        self._w: LasWriter | CopcWriter | None = None
        self._records: LasRecords | None = None

    def _header(self, first_xyz, wave_samples: int = 0):
        import laspy

        fmt = 6 if not self._wave else (WAVE_FORMAT_LAZ if self._compress else
                                         WAVE_FORMAT_LAS)
        header = laspy.LasHeader(point_format=fmt, version="1.4")
        header.scales = np.full(3, LAS_SCALE)
        header.offsets = offsets_near(first_xyz)
        # Each extra dimension described with its unit (sensors.io.fields.FILE_FIELDS).
        header.add_extra_dims(extra_params({n: np.dtype(t) for n, _, t in self._extra}))
        if self._echo:   # multiple returns: the echo's width and amplitude
            header.add_extra_dims([laspy.ExtraBytesParams(name=n, type=np.dtype(t),
                                                          description=txt)
                                   for n, _, t, txt in self._echo])
        header.system_identifier = f"tunnelsim {self.sensor}"[:32]
        header.generating_software = "tunnelsim"
        header.vlrs.append(laspy.VLR(user_id="tunnelsim", record_id=1,
                                     description="simulation info (JSON)",
                                     record_data=json.dumps(self.info()).encode()))
        if self.crs is not None:
            set_las_crs(header, self.crs)
        if self._wave:
            assert self._wave_desc is not None
            spacing_ps, gain = self._wave_desc
            # One descriptor, index 1: every packet is one fixed window.
            header.vlrs.append(laspy.VLR(
                user_id="LASF_Spec", record_id=100, description="wave packet descriptor",
                record_data=WAVE_DESCRIPTOR.pack(WAVE_BITS, 0, wave_samples, spacing_ps,
                                                 gain, 0.0)))
            if self._wdp:
                header.global_encoding.waveform_data_packets_external = True
        return header

    #: Returned pulses (``write_returned``) become LAS records in one kernel.
    _takes_returned = True

    def _write(self, c):
        if self._w is None:
            # The file's layout follows its first chunk (its first record for
            # returned pulses, which are single-return POINT_DTYPE records).
            head = c if isinstance(c, np.ndarray) else c.points(limit=1)
            if not len(head):
                return
            first = np.array([head["x"][0], head["y"][0], head["z"][0]],
                             dtype=np.float64)
            # Chunks of multiple returns (sensors.waveform) carry return numbers and
            # echo fields.
            names = head.dtype.names or ()
            self._returns = all(n in names for n in _RETURN_BITS)
            self._echo = tuple(e for e in LAS_ECHO_EXTRA if e[1] in names)
            self._start_waves(head)
            self._w = self._open_file(self._header(
                first, head.dtype["wave"].shape[0] if self._wave else 0))
            self._records = LasRecords(self._w.header)
        assert self._records is not None
        if not isinstance(c, np.ndarray):
            if self._fill_returned(c):
                return
            c = c.points()   # a layout the kernel does not make
        if self._wave:
            self._write_wave(c)
            return
        # Record fields as LAS point format 6 holds them (LAS 1.4 R15, table 21);
        # every expression is evaluated in the field's own dtype, as since the first
        # writer (files stay byte-identical); the extra bytes are copied as they are.
        fields = {"gps_time": c["time"], "intensity": np.round(c["intensity"] * 65535),
                  "bit_fields": 0x11,                    # return 1 of 1 (4 + 4 bits)
                  "scan_angle": np.round(np.rad2deg(c["elevation"]) / 0.006),
                  "user_data": c["channel"] % 256, "point_source_id": c["frame"] % 65536,
                  "classification": np.where(c["flag"] == 2, 7, 0)}
        copies = {name: field for name, field, _ in self._extra}
        if self._returns:   # LAS 1.4 R15 table 21: return number bits 0-3, count 4-7
            fields["bit_fields"] = (c["return_number"].astype(np.uint8) & 0x0F) | \
                (c["number_of_returns"].astype(np.uint8) << 4)
        copies.update({name: field for name, field, _, _ in self._echo})
        self._w.write_points(self._records.fill(
            (c["x"], c["y"], c["z"]), fields, records=c, copies=copies))

    def _fill_returned(self, ret) -> bool:
        """Store returned pulses (``write_returned``) as LAS records made straight from
        them, into the reused record buffer; False where the file's layout is one the
        kernel does not make (full waveform, multiple returns: then ``points()``)."""
        assert self._records is not None and self._w is not None
        if self._wave or self._returns or self._echo:
            return False
        rec = self._records.buffer(len(ret))
        if not ret.fill_las(rec, self._records.offsets, self._records.scales,
                            {name: field for name, field, _ in self._extra}):
            return False
        self._w.write_points(self._records.wrap(rec))
        return True

    # ---------------------------------------------------------------- full waveform
    def _start_waves(self, c) -> None:
        """Open the packet spill file if the first chunk has waveforms (or refuse)."""
        names = c.dtype.names or ()
        self._wave = all(n in names for n, *_ in WAVEFORM_FIELDS)
        if self._waveform and not self._wave:
            raise PointFileError(f"Expected full-waveform records "
                                 f"(sensors.io.fields.WAVEFORM_POINT_DTYPE) for "
                                 f"'{self.path}', got records without them; simulate "
                                 "with --waveform (Settings(waveform=True)).")
        if not self._wave:
            return
        if self._copc:
            raise PointFileError(f"Expected a .las or .laz output for --waveform, got "
                                 f"'{self.path}' (copc): COPC holds no wave packets; "
                                 "write -o NAME.las or NAME.laz.")
        self._wave_desc = (int(c["wave_spacing_ps"][0]), float(c["wave_gain"][0]))
        self._packet_bytes = int(c.dtype["wave"].itemsize)
        self._spill = tempfile.NamedTemporaryFile(  # noqa: SIM115 (closed on finish)
            dir=self.path.parent, prefix="." + self.path.name + ".", suffix=".packets",
            delete=False)

    def _write_wave(self, c) -> None:
        """Store a chunk of full-waveform records: each distinct window once in the
        spill file (consecutive returns of a pulse with the same window share it),
        the points with their wave packet fields (LAS 1.4 R15, table 14)."""
        assert self._records is not None and self._w is not None
        assert self._wave_desc is not None and self._spill is not None
        n = len(c)
        if not n:
            return
        t, ch, co, ws = c["time"], c["channel"], c["column"], c["wave_start_m"]
        if (np.any(c["wave_spacing_ps"] != self._wave_desc[0]) or
                np.any(c["wave_gain"] != self._wave_desc[1])):
            raise PointFileError(f"Expected one waveform bin and gain in '{self.path}' "
                                 f"(its wave packet descriptor), got chunks with "
                                 "others; write one run per file.")
        same = np.zeros(n, dtype=np.bool_)
        same[1:] = ((t[1:] == t[:-1]) & (ch[1:] == ch[:-1]) & (co[1:] == co[:-1]) &
                    (ws[1:] == ws[:-1]))
        same[0] = self._last_key == (float(t[0]), int(ch[0]), int(co[0]), float(ws[0]))
        self._last_key = (float(t[-1]), int(ch[-1]), int(co[-1]), float(ws[-1]))
        new = ~same
        number = self._n_packets + np.cumsum(new) - 1
        self._spill.write(np.ascontiguousarray(c["wave"][new], dtype="<u2").data)
        self._n_packets += int(np.count_nonzero(new))
        fields: dict[str, Any] = {
            "gps_time": c["time"], "intensity": np.round(c["intensity"] * 65535),
            "user_data": c["channel"] % 256, "point_source_id": c["frame"] % 65536,
            "wavepacket_index": 1,
            "wavepacket_offset": WAVE_RECORD_HEADER + number * self._packet_bytes,
            "wavepacket_size": self._packet_bytes,
            "return_point_wave_location": c["wave_location_ps"],
            "x_t": c["wave_dx"], "y_t": c["wave_dy"], "z_t": c["wave_dz"]}
        cls = np.where(c["flag"] == 2, 7, 0)
        rn = c["return_number"].astype(np.uint8)
        nr = c["number_of_returns"].astype(np.uint8)
        if self._w.header.point_format.id == WAVE_FORMAT_LAZ:
            # Point format 4 (LAS 1.4 R15, formats 1 and 4): 3 + 3 return bits, the
            # class in the low 5 bits, the scan angle in whole degrees.
            if nr.max() > 7:
                raise PointFileError(f"Expected at most 7 returns per pulse in a .laz "
                                     f"with --waveform (point format 4), got "
                                     f"{int(nr.max())}; write -o NAME.las (point "
                                     "format 9).")
            fields.update(bit_fields=(rn & 0x07) | ((nr & 0x07) << 3),
                          raw_classification=cls,
                          scan_angle_rank=np.clip(np.round(np.rad2deg(c["elevation"])),
                                                  -90, 90))
        else:
            fields.update(bit_fields=(rn & 0x0F) | (nr << 4), classification=cls,
                          scan_angle=np.round(np.rad2deg(c["elevation"]) / 0.006))
        copies = {name: field for name, field, _ in self._extra}
        copies.update({name: field for name, field, _, _ in self._echo})
        self._w.write_points(self._records.fill(
            (c["x"], c["y"], c["z"]), fields, records=c, copies=copies))

    def _write_wdp(self) -> None:
        """NAME.wdp beside the output (LAS 1.4 R15, global encoding bit 2): the
        waveform data packet record's header, then the packets (offsets count from
        the file's first byte, as in the EVLR)."""
        assert self._spill is not None
        size = os.path.getsize(self._spill.name)
        with atomic_writer(self.path.with_suffix(".wdp")) as out:
            out.write(struct.pack("<H16sHQ32s", 0, b"LASF_Spec", 65535, size,
                                  b"waveform data packets"))
            with open(self._spill.name, "rb") as src:
                shutil.copyfileobj(src, out, 1 << 24)

    def _drop_spill(self) -> None:
        if self._spill is not None:
            self._spill.close()
            with contextlib.suppress(OSError):
                os.unlink(self._spill.name)
            self._spill = None

    def _finish(self):
        if self._w is None:   # an empty run still gives a valid, empty file
            if self._waveform:   # an empty full-waveform file: its layout, no packet
                self._wave = True
                self._wave_desc = (int(round(BIN_S * 1e12)), 1.0)
                self._packet_bytes = 2 * WAVE_SAMPLES
                self._spill = tempfile.NamedTemporaryFile(  # noqa: SIM115
                    dir=self.path.parent, prefix="." + self.path.name + ".",
                    suffix=".packets", delete=False)
            self._w = self._open_file(self._header(np.zeros((0, 3)),
                                                   WAVE_SAMPLES if self._wave else 0))
        wdp = None
        try:
            if self._spill is not None:
                self._spill.flush()
                if self._wdp:   # before the LAS appears, so that it never lacks it
                    self._write_wdp()
                    wdp = self.path.with_suffix(".wdp")
            self._w.close()
        except BaseException:
            if wdp is not None:
                with contextlib.suppress(OSError):
                    wdp.unlink()
            raise
        finally:
            self._drop_spill()

    def _open_file(self, header):
        if self._copc:   # the octree is built on close (sensors.io.copc: bounded memory)
            return CopcWriter(self.path, header)
        internal = self._spill.name if self._spill is not None and not self._wdp else None
        return LasWriter(self.path, header, compress=self._compress,
                         waveform_packets=internal)

    def _discard(self, exc):
        if self._w is not None:
            self._w.abort()
        self._drop_spill()


class _PlyPoints(PointWriter):
    """Every field as a vertex property, under its file name (``FILE_DTYPE``): a chunk
    is written as it lies in memory."""

    def __init__(self, path, **kw) -> None:
        super().__init__(path, **kw)
        self._w = PlyWriter(path, [("vertex", FILE_DTYPE, None)],
                            comments=[f"tunnelsim {self.sensor}",
                                      "tunnelsim " + json.dumps(self.info())])

    def _write(self, c):
        self._w.write("vertex", file_records(c))

    def _finish(self):
        self._w.close()
        write_sidecar(self.path, self.crs)

    def _discard(self, exc):
        self._w.abort()


class _NpzPoints(PointWriter):
    """Chunks go to one raw file per field in a temporary folder beside the target,
    zipped (stored, not compressed) into ``numpy.load``'s layout on close; arrays are
    named by their file names (``sensors.io.fields.FILE_FIELDS``)."""

    def __init__(self, path, **kw) -> None:
        super().__init__(path, **kw)
        self._tmp = tempfile.mkdtemp(dir=path.parent, prefix="." + path.name + ".")
        # Open across write_points calls; closed by _finish or _discard.
        self._files = {f.field: open(os.path.join(self._tmp, f.name), "wb")  # noqa: SIM115
                       for f in FILE_FIELDS}

    def _write(self, c):
        # DECISION: one NumPy gather per field, written from its buffer (no tobytes
        # copy). A one-pass Numba kernel splitting the records into columns was tried:
        # 1.41 s CPU against 0.56 s for 3.4M Airy points (it moves bytes one by one,
        # a field gather whole values).
        for field, fh in self._files.items():
            fh.write(np.ascontiguousarray(c[field], dtype=POINT_DTYPE[field]).data)

    def _finish(self):
        for fh in self._files.values():
            fh.close()
        try:
            with atomic_writer(self.path) as out, zipfile.ZipFile(
                    out, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
                for f in FILE_FIELDS:
                    dt = POINT_DTYPE[f.field]
                    with zf.open(f.name + ".npy", "w", force_zip64=True) as member:
                        np.lib.format.write_array_header_1_0(
                            member, {"descr": np.lib.format.dtype_to_descr(dt),
                                     "fortran_order": False, "shape": (self.n_points,)})
                        with open(os.path.join(self._tmp, f.name), "rb") as src:
                            shutil.copyfileobj(src, member, 1 << 24)
        finally:
            shutil.rmtree(self._tmp, ignore_errors=True)
        write_sidecar(self.path, self.crs)

    def _discard(self, exc):
        for fh in self._files.values():
            fh.close()
        shutil.rmtree(self._tmp, ignore_errors=True)


#: What the E57 writer gathers of each point.
_E57_PART = np.dtype([("sx", "f8"), ("sy", "f8"), ("sz", "f8"), ("intensity", "f4"),
                      ("channel", "i4"), ("column", "i4")])


class _E57Points(PointWriter):
    def __init__(self, path, *, expected_points: int | None, **kw) -> None:
        super().__init__(path, **kw)
        if self.position is None:
            raise PointFileError("Expected a TLS station for E57 output (a structured scan "
                                 "with one pose), got a moving platform; write LAS/LAZ "
                                 "instead.")
        if expected_points is not None and expected_points > E57_MAX_POINTS:
            raise PointFileError(f"Expected at most {E57_MAX_POINTS:,} pulses for E57 "
                                 f"(pye57 writes a scan from memory), got "
                                 f"{expected_points:,}; use a coarser resolution or LAZ.")
        self._parts: list[np.ndarray] = []

    def _write(self, c):
        if self.n_points + len(c) > E57_MAX_POINTS:
            raise PointFileError(f"Expected at most {E57_MAX_POINTS:,} points for E57, got "
                                 "more; use a coarser resolution or LAZ.")
        part = np.empty(len(c), dtype=_E57_PART)
        for name in _E57_PART.names:
            part[name] = c[name]
        self._parts.append(part)

    def _finish(self):
        c = np.concatenate(self._parts) if self._parts else np.empty(0, _E57_PART)
        self._parts = []
        write_e57_scan(self.path, np.stack([c["sx"], c["sy"], c["sz"]], 1),
                       rotation_xyzw=self.quaternion_xyzw, translation=self.position,
                       name=f"tunnelsim {self.sensor}", intensity=c["intensity"],
                       row=c["channel"], column=c["column"], crs=self.crs)

    def _discard(self, exc):
        self._parts = []


class _BagPoints(PointWriter):
    """A ROS 2 bag: the chunks go to ``sensors.bag.RosbagStream``."""

    def __init__(self, path, *, spec: SensorSpec, single_file: bool,
                 trajectory: Trajectory | None, span_s, start_time_ns: int | None = None,
                 ros_distro: str | None = None, returns: str | None = None,
                 **kw) -> None:
        super().__init__(path, **kw)
        if self.position is not None:
            raise PointFileError("Expected a moving platform for a ROS 2 bag, got a TLS "
                                 "station; write LAZ or E57 instead.")
        info = self.info() if self.crs is None else dict(self.info(), crs=self.crs)
        self._w = RosbagStream(path, spec, single_file=single_file, seed=self.seed,
                               mount=self.mount, trajectory=trajectory, span_s=span_s,
                               info=info, start_time_ns=start_time_ns,
                               ros_distro=ros_distro or "jazzy", returns=returns)

    def _write(self, c):
        self._w.write_points(c)

    def _finish(self):
        self._w.close()

    def _discard(self, exc):
        self._w.abort()


def open_writer(path: str | os.PathLike[str], *, sensor: str | SensorSpec, seed: int = 0,
                pose: Any = None, fields: str | None = None, fmt: str | None = None,
                expected_points: int | None = None, mount: Any = None,
                trajectory: Trajectory | None = None,
                span_s: tuple[float, float] | None = None, crs: Any = None,
                thread: bool = True, start_time_ns: int | None = None,
                ros_distro: str | None = None, returns: str | None = None,
                waveform: bool = False, waveform_data: str | None = None) -> PointWriter:
    """A ``PointWriter`` for ``path`` (format from the suffix or ``fmt``: las, laz,
    ply, npz, e57, mcap; no suffix: a rosbag2 folder).

    Parameters
    ----------
    sensor : str or SensorSpec
        The sensor (its name is recorded in the file). A ROS 2 bag needs the spec (a
        name is loaded with ``load_sensor``) for its driver conventions and sweep rate.
    seed : int
        The simulation seed, recorded in LAS/LAZ and PLY.
    pose : (position (3,), rotation) or None
        A TLS station's pose (rotation: scipy ``Rotation`` or quaternion x, y, z, w);
        None for a moving platform. E57 needs one.
    fields : "full", "compact" or None
        LAS/LAZ extra bytes (see the module notes); default compact with a pose, full
        without.
    expected_points : int, optional
        The most points the stream may bring (E57 refuses a scan too large to gather
        before any is simulated).
    mount : sensors.Mount, optional
        The sensor's lever arm and boresight on a moving platform, recorded (LAS/LAZ
        VLR: ``mount_lever_arm_m``, ``mount_boresight_xyzw``) so that sensor poses
        estimated from the file (LiDAR odometry) can be turned into platform poses.
    trajectory : Trajectory, optional
        The platform's true poses: a ROS 2 bag writes /tf, ground-truth odometry and
        an IMU from them (other formats ignore it).
    span_s : (float, float), optional
        The scan's time window (trajectory time base): a ROS 2 bag stamps sweep k at
        ``span_s[0] + k / rate`` and drops a last sweep that ends after ``span_s[1]``.
    crs : str, dict or pyproj.CRS, optional
        The coordinate reference system of the world coordinates (EPSG:n, WKT or
        PROJJSON; metre axes), stated in the file (see the module notes). Needs pyproj;
        checked before the writer opens (``sensors.io.crs.CRSError``).
    thread : bool
        LAS/LAZ, PLY and NPZ: store the chunks on a writer thread
        (``sensors.io.stream.Background``; default), so that the caller simulates the
        next chunk while this one is compressed and written; the file's bytes are the
        same either way. The caller must then not change a chunk it has handed over.
    start_time_ns : int, optional
        A ROS 2 bag's ROS time at the scan's start (``span_s[0]``), ns since 1970
        (``sensors.bag.RosbagStream``); other formats refuse it.
    ros_distro : {"jazzy", "humble"}, optional
        A ROS 2 bag folder's metadata layout (default jazzy); other formats refuse it.
    returns : str, optional
        A ROS 2 bag's return mode (``Settings.returns``): a single-echo mode keeps one
        topic, ``dual`` opens the driver's second-return topic where it has one.
    waveform : bool
        Full-waveform records (``Settings(waveform=True)``, ``WAVEFORM_POINT_DTYPE``):
        only LAS and LAZ hold them (other formats are refused here, before any point
        is simulated). A .las gets LAS 1.4 point format 9, a .laz point format 4
        (lazrs changes varying wave packet fields of format 9 in LAZ,
        ``sensors.io.las.LAZ_WAVE_BROKEN``; format 4's LAZ codec keeps them), each
        point's packet a fixed ``WAVE_SAMPLES``-sample window of 16-bit samples (one
        wave packet descriptor, index 1), stored once per distinct window.
    waveform_data : {None, "internal", "external"}
        Where the packets go: "internal", the .las's waveform data packet record (an
        EVLR, global encoding bit 1); "external", NAME.wdp beside the output (bit 2).
        None: internal for .las, external for .laz (refused: "internal" with .laz).
    """
    path = Path(path)
    f = format_of(path, fmt)
    if not path.parent.exists():
        raise PointFileError(f"Expected an existing output folder, got '{path.parent}'; "
                             "create it first.")
    if waveform_data is not None and waveform_data not in WAVEFORM_DATA:
        raise PointFileError(f"Expected --waveform {' or '.join(WAVEFORM_DATA)} (or no "
                             f"value), got {waveform_data!r}.")
    if waveform_data is not None and not waveform:
        raise PointFileError(f"Expected --waveform {waveform_data} only for a "
                             f"full-waveform run, got it without one; simulate with "
                             "--waveform.")
    if waveform and f not in ("las", "laz"):
        raise PointFileError(f"Expected a .las or .laz output for --waveform, got "
                             f"'{path}' ({f}): only LAS 1.4 wave packets hold the "
                             "waveform; write -o NAME.las or NAME.laz, or leave "
                             "--waveform out.")
    if waveform and f == "laz" and waveform_data == "internal":
        raise PointFileError(f"Expected --waveform external (or no value) for a .laz "
                             f"output, got --waveform internal for '{path}': a LAZ keeps "
                             "its packets in NAME.wdp; write -o NAME.las for packets "
                             "inside the file.")
    if f in ("mcap", "rosbag2"):
        spec = sensor if isinstance(sensor, SensorSpec) else load_sensor(sensor)
        return _BagPoints(path, spec=spec, single_file=f == "mcap", trajectory=trajectory,
                          span_s=span_s, sensor=spec, seed=seed, pose=pose, mount=mount,
                          crs=crs, start_time_ns=start_time_ns, ros_distro=ros_distro,
                          returns=returns)
    if start_time_ns is not None or ros_distro is not None:
        raise PointFileError(f"Expected --start-time and --ros-distro only with a ROS 2 "
                             f"bag (-o NAME.mcap or a folder), got them for '{path}' ({f}).")
    if fields is None:
        fields = "compact" if pose is not None else "full"
    if fields not in ("full", "compact"):
        raise PointFileError(f"Expected fields 'full' or 'compact', got {fields!r}.")
    kw: dict[str, Any] = {"sensor": sensor, "seed": seed, "pose": pose, "mount": mount,
                          "crs": crs}
    # DECISION: no thread for E57 (it gathers the scan; pye57 writes it at the end).
    streamed = dict(kw, threaded=bool(thread))
    if f in ("las", "laz", "copc"):
        return _LasPoints(path, compress=f != "las", fields=fields, copc=f == "copc",
                          waveform=waveform,
                          wdp=f == "laz" or waveform_data == "external", **streamed)
    if f == "ply":
        return _PlyPoints(path, **streamed)
    if f == "npz":
        return _NpzPoints(path, **streamed)
    return _E57Points(path, expected_points=expected_points, **kw)
