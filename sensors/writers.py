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
- **PLY** (``sensors.io.ply``, binary little endian): every field as a vertex property;
  the vertex count in the header is patched at the end.
- **NPZ**: one array per field, as ``numpy.load`` returns them; chunks go to temporary
  raw files and are zipped at the end.

Every format names a field as ``sensors.io.fields.FILE_FIELDS`` says (issue 22): the LAS
names (``sensor_x``, ``sensor_y``, ``sensor_z``, ``gps_time``, the rest as in
``POINT_DTYPE``) in LAS extra bytes, PLY properties and NPZ arrays alike.

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

import json
import os
import shutil
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

__all__ = ["E57_MAX_POINTS", "FORMATS", "LAS_SCALE", "PointWriter", "format_of",
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


class _LasPoints(PointWriter):
    def __init__(self, path, *, compress: bool, fields: str, copc: bool = False,
                 **kw) -> None:
        super().__init__(path, **kw)
        self._compress = compress
        self._copc = copc
        self._extra = LAS_EXTRA if fields == "full" else \
            tuple(e for e in LAS_EXTRA if e[0] in LAS_COMPACT)
        self._echo: tuple[tuple[str, str, str, str], ...] = ()
        self._returns = False
        self._w: LasWriter | CopcWriter | None = None
        self._records: LasRecords | None = None

    def _header(self, first_xyz):
        import laspy

        header = laspy.LasHeader(point_format=6, version="1.4")
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
        return header

    def _write(self, c):
        if self._w is None:
            if not len(c):
                return
            first = np.array([c["x"][0], c["y"][0], c["z"][0]], dtype=np.float64)
            # Chunks of multiple returns (sensors.waveform) carry return numbers and
            # echo fields; the file's layout follows its first chunk.
            names = c.dtype.names or ()
            self._returns = all(n in names for n in _RETURN_BITS)
            self._echo = tuple(e for e in LAS_ECHO_EXTRA if e[1] in names)
            self._w = self._open_file(self._header(first))
            self._records = LasRecords(self._w.header)
        assert self._records is not None
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

    def _finish(self):
        if self._w is None:   # an empty run still gives a valid, empty file
            self._w = self._open_file(self._header(np.zeros((0, 3))))
        self._w.close()

    def _open_file(self, header):
        if self._copc:   # the octree is built on close (sensors.io.copc: bounded memory)
            return CopcWriter(self.path, header)
        return LasWriter(self.path, header, compress=self._compress)

    def _discard(self, exc):
        if self._w is not None:
            self._w.abort()


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
                ros_distro: str | None = None, returns: str | None = None) -> PointWriter:
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
    """
    path = Path(path)
    f = format_of(path, fmt)
    if not path.parent.exists():
        raise PointFileError(f"Expected an existing output folder, got '{path.parent}'; "
                             "create it first.")
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
                          **streamed)
    if f == "ply":
        return _PlyPoints(path, **streamed)
    if f == "npz":
        return _NpzPoints(path, **streamed)
    return _E57Points(path, expected_points=expected_points, **kw)
