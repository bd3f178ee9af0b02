"""Streaming point-cloud writers: LAS 1.4 / LAZ, PLY, NPZ and E57.

Each writer takes chunks of ``POINT_DTYPE`` records one at a time, so memory stays
bounded by one chunk (E57 excepted, see below), and writes under a temporary name that
is renamed into place only after the last chunk: an interrupted run leaves no file that
looks complete.

- **LAS 1.4 / LAZ** (laspy; LAZ through lazrs): point format 6 with GPS time (the pulse
  time), intensity (``intensity`` x 65535), return 1 of 1, scan angle (the beam's
  elevation in the sensor frame, in the format's 0.006 deg units), user data
  (channel mod 256), point source ID (frame mod 65536) and classification 7 (noise)
  for particle returns, else 0. The other fields go into extra bytes: all of them
  ("full": sensor_x, sensor_y, sensor_z, range, azimuth, elevation, channel, column,
  frame, incidence, triangle, flag; the default for moving platforms) or the four a
  station cannot recompute ("compact": channel, column, triangle, flag; the default
  for TLS stations, 3x faster to compress). A VLR (user "tunnelsim", record 1) holds
  the sensor, seed and station pose as JSON. Coordinates: scale 0.1 mm, offset = the
  first point rounded to a kilometre, so UTM coordinates keep 0.1 mm.
- **PLY** (binary little endian): every field as a vertex property; the vertex count in
  the header is patched at the end.
- **NPZ**: one array per field, as ``numpy.load`` returns them; chunks go to temporary
  raw files and are zipped at the end.
- **E57** (pye57, TLS stations only): one structured scan with row/column indices
  (channel = row along the vertical sweep, column = line), sensor-frame Cartesian
  coordinates and the station pose (rotation, translation). pye57 writes a scan in one
  call, so the scan is gathered in memory first; ``E57_MAX_POINTS`` guards the machine.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from raytrace.fileio import atomic_writer

from .errors import PointFileError

FORMATS = ("las", "laz", "ply", "npz", "e57")
#: LAS coordinate scale (m): 0.1 mm.
LAS_SCALE = 1e-4
#: Largest scan the E57 writer gathers in memory (about 36 bytes a point).
E57_MAX_POINTS = 50_000_000

#: Extra bytes of the "compact" LAS layout (the default for TLS stations, whose
#: sensor-frame coordinates, range and angles follow from the world point and the
#: station pose stored in the tunnelsim VLR).
_COMPACT = ("channel", "column", "triangle", "flag")

_EXTRA = [("sensor_x", "sx", "f8"), ("sensor_y", "sy", "f8"), ("sensor_z", "sz", "f8"),
          ("range", "range", "f8"), ("azimuth", "azimuth", "f4"),
          ("elevation", "elevation", "f4"), ("channel", "channel", "u4"),
          ("column", "column", "u4"), ("frame", "frame", "u4"),
          ("incidence", "incidence", "f4"), ("triangle", "triangle", "i4"),
          ("flag", "flag", "u1")]


def format_of(path, fmt=None) -> str:
    f = (fmt or Path(path).suffix.lstrip(".")).lower()
    if f not in FORMATS:
        raise PointFileError(f"Expected an output format in {FORMATS} (from the suffix or "
                             f"`fmt`), got {f!r} for '{path}'.")
    return f


def write_points(run, path, *, fmt=None, progress=None, fields=None):
    """Stream a ``Run`` into ``path``; returns the run's stats plus the path.

    ``fields`` (LAS/LAZ): "full" (every output field as extra bytes) or "compact"
    (channel, column, triangle, flag); default compact for TLS stations, full for
    moving platforms.
    """
    path = Path(path)
    f = format_of(path, fmt)
    if not path.parent.exists():
        raise PointFileError(f"Expected an existing output folder, got '{path.parent}'; "
                             "create it first.")
    writer = {"las": _write_las, "laz": _write_las, "ply": _write_ply, "npz": _write_npz,
              "e57": _write_e57}[f]
    done = [0]

    def chunks():
        for c in run:
            yield c
            done[0] = run.stats["pulses"]
            if progress is not None:
                progress(done[0], run.n_pulses)

    if fields is None:
        fields = "compact" if run.station is not None else "full"
    if fields not in ("full", "compact"):
        raise PointFileError(f"Expected fields 'full' or 'compact', got {fields!r}.")
    if f in ("las", "laz"):
        _write_las(run, chunks(), path, compress=(f == "laz"), fields=fields)
    else:
        writer(run, chunks(), path)
    return dict(run.stats, path=str(path))


# ---------------------------------------------------------------------- LAS / LAZ
def _las_header(run, extra):
    import json

    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.full(3, LAS_SCALE)
    header.add_extra_dims([laspy.ExtraBytesParams(name=n, type=np.dtype(t))
                           for n, _, t in extra])
    header.system_identifier = f"tunnelsim {run.sensor.name}"[:32]
    header.generating_software = "tunnelsim"
    info = {"sensor": run.sensor.name, "seed": run.seed}
    if run.station is not None:
        pos, rot = run.station
        info["station_position"] = [float(v) for v in pos]
        info["station_quaternion_xyzw"] = [float(v) for v in rot.as_quat()]
    header.vlrs.append(laspy.VLR(user_id="tunnelsim", record_id=1,
                                 description="simulation info (JSON)",
                                 record_data=json.dumps(info).encode()))
    return header


def _write_las(run, chunks, path, compress=False, fields="full"):
    import laspy

    extra = _EXTRA if fields == "full" else [e for e in _EXTRA if e[0] in _COMPACT]
    header = None
    with atomic_writer(path) as fh:
        writer = None
        try:
            for c in chunks:
                if writer is None:
                    header = _las_header(run, extra)
                    first = np.array([c["x"][0], c["y"][0], c["z"][0]]) if len(c) else \
                        np.zeros(3)
                    header.offsets = np.round(first / 1000.0) * 1000.0
                    writer = laspy.open(fh, mode="w", header=header, closefd=False,
                                        do_compress=compress)
                writer.write_points(_las_record(c, header, extra))
            if writer is None:  # an empty run still gives a valid, empty file
                writer = laspy.open(fh, mode="w", header=_las_header(run, extra),
                                    closefd=False, do_compress=compress)
        finally:
            if writer is not None:
                writer.close()


def _las_record(c, header, extra):
    """Point records filled straight into laspy's structured array (its per-field
    setters cost more than the compression)."""
    import laspy

    rec = laspy.ScaleAwarePointRecord.zeros(len(c), header=header)
    a = rec.array
    lo = header.offsets
    for axis, name in enumerate("xyz"):
        q = np.round((c[name] - lo[axis]) / LAS_SCALE)
        if len(q) and (np.abs(q).max() >= 2**31 - 1):
            raise PointFileError(f"Expected coordinates within 214 km of the LAS offset "
                                 f"{lo.tolist()}, got {name} up to {np.abs(c[name]).max()}; "
                                 "split the output.")
        a[name.upper()] = q
    a["gps_time"] = c["time"]
    a["intensity"] = np.round(c["intensity"] * 65535)
    a["bit_fields"] = 0x11                      # return 1 of 1 (4 + 4 bits)
    a["scan_angle"] = np.round(np.rad2deg(c["elevation"]) / 0.006)
    a["user_data"] = c["channel"] % 256
    a["point_source_id"] = c["frame"] % 65536
    a["classification"] = np.where(c["flag"] == 2, 7, 0)
    for name, field, _ in extra:
        a[name] = c[field]
    return rec


# ---------------------------------------------------------------------- PLY
_PLY_TYPE = {"f8": "double", "f4": "float", "i4": "int", "u1": "uchar", "u4": "uint"}


def _write_ply(run, chunks, path):
    from .simulate import POINT_DTYPE

    props = [f"property {_PLY_TYPE[POINT_DTYPE[n].str[1:]]} {n}" for n in POINT_DTYPE.names]
    count_field = " " * 20
    head = "\n".join(["ply", "format binary_little_endian 1.0",
                      f"comment tunnelsim {run.sensor.name}",
                      f"element vertex {count_field}", *props, "end_header"]) + "\n"
    n = 0
    with atomic_writer(path) as fh:
        fh.write(head.encode("ascii"))
        for c in chunks:
            fh.write(np.ascontiguousarray(c).astype(POINT_DTYPE.newbyteorder("<")).tobytes())
            n += len(c)
        fh.seek(head.index("element vertex ") + len("element vertex "))
        fh.write(str(n).ljust(20).encode("ascii"))


# ---------------------------------------------------------------------- NPZ
def _write_npz(run, chunks, path):
    from .simulate import POINT_DTYPE

    with tempfile.TemporaryDirectory(dir=path.parent, prefix="." + path.name + ".") as tmp:
        files = {name: open(os.path.join(tmp, name), "wb") for name in POINT_DTYPE.names}
        n = 0
        try:
            for c in chunks:
                for name, fh in files.items():
                    fh.write(np.ascontiguousarray(c[name]).tobytes())
                n += len(c)
        finally:
            for fh in files.values():
                fh.close()
        with atomic_writer(path) as out, zipfile.ZipFile(out, "w", zipfile.ZIP_STORED,
                                                         allowZip64=True) as zf:
            for name in POINT_DTYPE.names:
                dt = POINT_DTYPE[name]
                with zf.open(name + ".npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array_header_1_0(
                        member, {"descr": np.lib.format.dtype_to_descr(dt),
                                 "fortran_order": False, "shape": (n,)})
                    with open(os.path.join(tmp, name), "rb") as src:
                        while True:
                            block = src.read(1 << 24)
                            if not block:
                                break
                            member.write(block)


# ---------------------------------------------------------------------- E57
def _write_e57(run, chunks, path):
    if run.station is None:
        raise PointFileError("Expected a TLS station for E57 output (a structured scan "
                             "with one pose), got a moving platform; write LAS/LAZ instead.")
    if run.n_pulses > E57_MAX_POINTS:
        raise PointFileError(f"Expected at most {E57_MAX_POINTS:,} pulses for E57 (pye57 "
                             f"writes a scan from memory), got {run.n_pulses:,}; use a "
                             "coarser resolution or LAZ.")
    try:
        import pye57
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise PointFileError("Expected the optional package pye57 for E57 output; install "
                             "it with: pip install pye57") from exc
    from .simulate import POINT_DTYPE

    parts = list(chunks)
    c = np.concatenate(parts) if parts else np.empty(0, dtype=POINT_DTYPE)
    pos, rot = run.station
    q = rot.as_quat()  # x, y, z, w
    data = {"cartesianX": c["sx"].astype(np.float64), "cartesianY": c["sy"].astype(np.float64),
            "cartesianZ": c["sz"].astype(np.float64),
            "intensity": c["intensity"].astype(np.float32),
            "rowIndex": c["channel"].astype(np.int32),
            "columnIndex": c["column"].astype(np.int32)}
    # pye57 writes to a path: write beside the target and rename when complete.
    tmp = path.with_name("." + path.name + ".part")
    try:
        e57 = pye57.E57(str(tmp), mode="w")
        try:
            e57.write_scan_raw(data, name=f"tunnelsim {run.sensor.name}",
                               rotation=np.array([q[3], q[0], q[1], q[2]]),
                               translation=np.asarray(pos, dtype=np.float64))
        finally:
            e57.close()
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
