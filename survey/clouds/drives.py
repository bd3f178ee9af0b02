"""Simulated drives read back: the scan frames LiDAR odometry consumes, and the drive
re-placed along another trajectory (the cloud a SLAM estimate implies). A drive is a
LAS/LAZ file with full fields, a PLY or NPZ file (every field), or a ROS 2 bag
(``drive -o drive.mcap``: one PointCloud2 per sweep in the sensor frame, the mount in
/tf_static).

Field names follow ``sensors.io.fields.FILE_FIELDS`` in every format (``sensor_x``,
``gps_time``, ...); PLY and NPZ drives of earlier versions (``sx``, ``time``) read as
well. A PLY drive records its sensor and mount in its ``tunnelsim {...}`` comment; an
NPZ drive records none (the mount is then the identity). NPZ columns are loaded whole
(``numpy.load`` reads a member at once); LAS/LAZ and PLY stream.

A drive file is what ``tunnelsim drive --fields full`` writes (LAS/LAZ): per point the
GPS time (the pulse time), the point in the sensor frame (extra bytes ``sensor_x``,
``sensor_y``, ``sensor_z``) and the scan ``frame`` (one turn of a spinning LiDAR, one
profile of a profiler); the "tunnelsim" VLR records the sensor and its mount on the
platform (lever arm and boresight). A real MLS log carries the same things (a
timestamped sensor-frame point stream and the calibrated mount).

Points are written in pulse order, so a frame is a contiguous run of records; the
reader streams chunks and yields each frame once it is complete, so memory stays
bounded by one frame plus one chunk.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from sensors import Mount, Trajectory
from sensors.io.fields import point_field
from sensors.io.las import LasSource
from sensors.io.cloudmap import map_cloud
from sensors.io.cloudread import CHUNK, INFO_USER, cloud_errors, ply_points
from sensors.io.errors import PointFileError

__all__ = ["DRIVE_FIELDS", "TIME_FIELDS", "DriveFile", "ScanFrame", "frames_from_points",
           "iter_frames", "open_drive", "replace_drive"]

#: LAS dimensions a drive file needs for odometry and re-placing.
DRIVE_FIELDS = ("gps_time", "sensor_x", "sensor_y", "sensor_z", "frame")
_SENSOR_XYZ = ("sensor_x", "sensor_y", "sensor_z")


class ScanFrame(NamedTuple):
    """One scan frame: ``frame`` (the file's frame number), ``points`` (m, 3) float64 in
    the sensor frame (m), ``times`` (m,) float64 (s)."""

    frame: int
    points: NDArray[np.float64]
    times: NDArray[np.float64]


@dataclass(frozen=True)
class DriveFile:
    """A checked drive file (``open_drive``).

    Attributes
    ----------
    path : Path
        The file (or rosbag2 folder) opened.
    sensor : str
        The simulated sensor's name (from the tunnelsim VLR; "unknown" without one).
    mount : sensors.Mount
        The sensor's lever arm and boresight on the platform (identity when the file
        records none: then platform poses are sensor poses).
    mount_recorded : bool
        Whether the file recorded the mount.
    n_points : int
        Points in the file.
    time_span_s : (float, float)
        First and last point time (from the points, read once).
    kind : str
        "las" (LAS/LAZ), "ply", "npz" or "bag" (ROS 2 bag: an ``.mcap`` file or a
        rosbag2 folder).
    topic : str
        The PointCloud2 topic read from a bag ("" for LAS).
    """

    path: Path
    sensor: str
    mount: Mount
    mount_recorded: bool
    n_points: int
    time_span_s: tuple[float, float]
    kind: str = "las"
    topic: str = ""


def _info(source: LasSource) -> dict[str, Any]:
    for v in source.header.vlrs:
        if v.user_id == "tunnelsim" and v.record_id == 1:
            try:
                info = json.loads(bytes(v.record_data).decode())
            except (UnicodeDecodeError, json.JSONDecodeError):
                return {}
            return info if isinstance(info, dict) else {}
    return {}


def open_drive(path: str | os.PathLike[str]) -> DriveFile:
    """Check that ``path`` is a drive with what odometry needs; returns a ``DriveFile``.

    Raises
    ------
    PointFileError
        For a file that is not LAS/LAZ, has no points, lacks per-point times or
        sensor-frame fields (``DRIVE_FIELDS``), or whose times do not increase.
    """
    p = Path(path)
    if p.suffix.lower() == ".mcap" or (p.is_dir() and (p / "metadata.yaml").is_file()):
        return _open_bag(p)
    if p.suffix.lower() not in (".las", ".laz", ".ply", ".npz"):
        raise PointFileError(f"Expected a drive as .las/.laz (tunnelsim drive --fields full "
                             f"-o drive.laz), .ply, .npz or a ROS 2 bag (.mcap or a "
                             f"rosbag2 folder), got '{p}'.")
    if not p.is_file():
        raise PointFileError(f"Expected a drive file, got '{p}' which does not exist.")
    if p.suffix.lower() in (".ply", ".npz"):
        return _open_columns(p)
    with LasSource(p) as src:
        names = set(src.header.point_format.dimension_names)
        missing = [f for f in DRIVE_FIELDS if f not in names]
        if missing:
            raise PointFileError(
                f"Expected per-point times and sensor-frame fields {list(DRIVE_FIELDS)} in "
                f"'{p}', got a file without {missing}; simulate the drive with "
                "'tunnelsim drive --fields full'.")
        if src.point_count == 0:
            raise PointFileError(f"Expected points in '{p}', got a valid file with 0 points.")
        info = _info(src)
    lo, hi, last, n = np.inf, -np.inf, -np.inf, 0
    try:
        for t in _las_times(p):
            if len(t) and (t[0] < last or (np.diff(t) < 0).any()):
                raise PointFileError(f"Expected points in time order in '{p}' (as a drive "
                                     "is written), got times that go back.")
            if len(t):
                lo, hi, last = min(lo, t[0]), max(hi, t[-1]), t[-1]
            n += len(t)
    except PointFileError:
        raise
    except Exception as exc:   # lazrs and laspy raise many types for broken data
        raise PointFileError(f"Expected {src.point_count:,} points in '{p}', got data that "
                             f"failed to decompress after {n:,} ({exc}).") from exc
    if n != src.point_count:
        raise PointFileError(f"Expected {src.point_count:,} points in '{p}' (its header), "
                             f"got {n:,}: the file is cut short.")
    lever = info.get("mount_lever_arm_m")
    quat = info.get("mount_boresight_xyzw")
    recorded = lever is not None and quat is not None
    mount = Mount(tuple(lever or ()), Rotation.from_quat(quat)) if recorded else Mount()
    return DriveFile(p, str(info.get("sensor", "unknown")), mount, recorded,
                     int(src.point_count), (float(lo), float(hi)))


def _las_times(p: Path, chunk: int = CHUNK) -> Iterator[NDArray[np.float64]]:
    """The GPS times of a (checked) LAS/LAZ file, chunk by chunk. DECISION: LAZ 1.4
    compresses in layers: decompressing the time layer alone (with x, y, which every
    point record needs) takes a fraction of a full read (a 25M-point Airy drive: see
    RESULTS.md, "SLAM in the loop")."""
    import laspy

    sel = laspy.DecompressionSelection
    with laspy.open(p, decompression_selection=sel.XY_RETURNS_CHANNEL | sel.GPS_TIME) as r:
        for rec in r.chunk_iterator(chunk):
            yield np.asarray(rec.gps_time, dtype=np.float64)


def frames_from_points(chunks: Iterable[np.ndarray]) -> Iterator[ScanFrame]:
    """Scan frames from chunks of ``sensors.POINT_DTYPE`` records in time order (a
    ``Run`` iterated, without a file): fields ``sx``, ``sy``, ``sz``, ``time``,
    ``frame``; a frame split over chunks is joined."""
    return _group(((np.asarray(c["frame"], dtype=np.int64),
                    np.stack([c["sx"], c["sy"], c["sz"]], 1).astype(np.float64),
                    np.asarray(c["time"], dtype=np.float64)) for c in chunks))


def iter_frames(drive: DriveFile, *, chunk: int = CHUNK) -> Iterator[ScanFrame]:
    """The drive file's scan frames in time order (a frame split over chunks is
    joined; in a bag, one PointCloud2 message is one frame)."""
    if drive.kind == "bag":
        yield from _bag_frames(drive)
        return
    if drive.kind in ("ply", "npz"):
        yield from _group(_column_chunks(drive.path, chunk))
        return
    with LasSource(drive.path) as src:
        yield from _group(
            (np.asarray(rec["frame"], dtype=np.int64),
             np.stack([np.asarray(rec[n], dtype=np.float64) for n in _SENSOR_XYZ], 1),
             np.asarray(rec.gps_time, dtype=np.float64)) for rec in src.chunks(chunk))


def _group(parts: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]]
           ) -> Iterator[ScanFrame]:
    """(frame (n,), points (n, 3), times (n,)) chunks -> whole frames."""
    pts: list[np.ndarray] = []
    tms: list[np.ndarray] = []
    current = None
    for fr, xyz, t in parts:
        cuts = np.flatnonzero(np.diff(fr)) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(fr)]):
            if a == b:
                continue
            f = int(fr[a])
            if current is not None and f != current:
                yield ScanFrame(current, np.concatenate(pts), np.concatenate(tms))
                pts, tms = [], []
            current = f
            pts.append(xyz[a:b])
            tms.append(t[a:b])
    if current is not None:
        yield ScanFrame(current, np.concatenate(pts), np.concatenate(tms))


def replace_drive(drive: DriveFile, dst: str | os.PathLike[str], trajectory: Trajectory,
                  *, chunk: int = CHUNK) -> int:
    """Write ``dst``: the drive with every point re-placed from its sensor-frame
    coordinates by the sensor pose of ``trajectory`` (platform poses, e.g. a SLAM
    estimate) at the point's own time, through the drive's mount; every other field is
    kept. Atomic. Returns the point count.

    Raises
    ------
    PointFileError
        When the trajectory does not span the drive's times.
    """
    if drive.kind != "las":
        what = "the ROS 2 bag" if drive.kind == "bag" else f"the {drive.kind.upper()} drive"
        raise PointFileError(f"Expected a LAS/LAZ drive to re-place, got {what} "
                             f"'{drive.path}'; re-place the same drive written as LAZ "
                             "(--fields full).")
    a, b = drive.time_span_s
    if len(trajectory) < 2 or trajectory.start_s > a or trajectory.end_s < b:
        raise PointFileError(f"Expected a trajectory spanning the drive's times [{a:.6f}, "
                             f"{b:.6f}] s, got [{trajectory.start_s:.6f}, "
                             f"{trajectory.end_s:.6f}] s.")

    def place(xyz: NDArray[np.float64], t: NDArray[np.float64] | None,
              extra: dict[str, np.ndarray]) -> NDArray[np.float64]:
        assert t is not None        # DRIVE_FIELDS include gps_time (checked on open)
        s = np.stack([extra[n].astype(np.float64) for n in _SENSOR_XYZ], 1)
        pos, mat = trajectory.sensor_matrices(t, drive.mount)
        return pos + np.einsum("nij,nj->ni", mat, s)

    return map_cloud(drive.path, dst, place, chunk=chunk, fields=_SENSOR_XYZ)


# ------------------------------------------------------------------ PLY and NPZ
#: The POINT_DTYPE fields a PLY/NPZ drive needs (under their file names, or the
#: names of earlier versions: ``sensors.io.fields.point_field``).
_COLUMNS = ("sx", "sy", "sz", "time", "frame")


def _names(have: Iterable[str], p: Path) -> dict[str, str]:
    """{POINT_DTYPE field: the file's name for it} for ``_COLUMNS``."""
    found: dict[str, str] = {}
    for name in have:
        f = point_field(name)
        if f in _COLUMNS and f not in found:
            found[f] = name
    missing = [c for c in _COLUMNS if c not in found]
    if missing:
        raise PointFileError(f"Expected per-point times and sensor-frame fields "
                             f"{list(DRIVE_FIELDS)} in '{p}', got a file without them "
                             f"({sorted(have)}); simulate the drive with 'tunnelsim "
                             "drive'.")
    return found


def _column_chunks(p: Path, chunk: int = CHUNK
                   ) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(frame (n,), sensor-frame points (n, 3), times (n,)) of a PLY/NPZ drive."""
    with cloud_errors():
        if p.suffix.lower() == ".ply":
            rec: Any = ply_points(p)
            names = _names(rec.dtype.names or (), p)
        else:
            try:
                rec = np.load(p, allow_pickle=False)
                files = list(rec.files)
            except Exception as exc:   # zipfile and format errors of numpy.load
                raise PointFileError(f"Expected an NPZ file numpy can read, got '{p}' "
                                     f"which fails with: {exc}.") from exc
            names = _names(files, p)
            rec = {f: np.asarray(rec[n]).reshape(-1) for f, n in names.items()}
            names = {f: f for f in names}
            if len({len(v) for v in rec.values()}) != 1:
                raise PointFileError(f"Expected arrays of one length in '{p}', got "
                                     f"{ {n: len(v) for n, v in rec.items()} }.")
        n = len(rec[names["time"]])
        for i in range(0, n, chunk):
            yield (np.asarray(rec[names["frame"]][i:i + chunk], dtype=np.int64),
                   np.stack([np.asarray(rec[names[a]][i:i + chunk], dtype=np.float64)
                             for a in ("sx", "sy", "sz")], 1),
                   np.asarray(rec[names["time"]][i:i + chunk], dtype=np.float64))


def _ply_info(p: Path) -> dict[str, Any]:
    from sensors.io.ply import read_ply_header

    tag = f"comment {INFO_USER} "
    for line in read_ply_header(p).comments:
        if line.startswith(tag + "{"):
            try:
                info = json.loads(line[len(tag):])
            except json.JSONDecodeError:
                return {}
            return info if isinstance(info, dict) else {}
    return {}


def _open_columns(p: Path) -> DriveFile:
    lo, hi, last, n = np.inf, -np.inf, -np.inf, 0
    for _, _, t in _column_chunks(p):
        if len(t) and (t[0] < last or (np.diff(t) < 0).any()):
            raise PointFileError(f"Expected points in time order in '{p}' (as a drive "
                                 "is written), got times that go back.")
        if len(t):
            lo, hi, last = min(lo, t[0]), max(hi, t[-1]), t[-1]
        n += len(t)
    if n == 0:
        raise PointFileError(f"Expected points in '{p}', got a valid file with 0 points.")
    kind = p.suffix.lower().lstrip(".")
    with cloud_errors():
        info = _ply_info(p) if kind == "ply" else {}
    lever, quat = info.get("mount_lever_arm_m"), info.get("mount_boresight_xyzw")
    recorded = lever is not None and quat is not None
    mount = Mount(tuple(lever or ()), Rotation.from_quat(quat)) if recorded else Mount()
    return DriveFile(p, str(info.get("sensor", "unknown")), mount, recorded, n,
                     (float(lo), float(hi)), kind)


# ------------------------------------------------------------------ ROS 2 bags
#: Per-point time fields of PointCloud2 clouds, as the common drivers write them:
#: name -> (scale to seconds, relative to the message stamp?). velodyne_pointcloud
#: ``time`` (float32 s after the stamp), ouster-ros ``t`` (uint32 ns after the stamp),
#: rslidar_sdk ``timestamp`` (float64 absolute s). sensors.bag writes all three.
TIME_FIELDS = {"time": (1.0, True), "t": (1e-9, True), "timestamp": (1.0, False)}
#: sensor_msgs/msg/PointField datatypes as NumPy types.
_FIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def _reader(p: Path) -> Any:
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise PointFileError("Expected the rosbags package to read a ROS 2 bag, got it "
                             "missing; install it with: pip install 'tunnelsim[ros]'.") \
            from None
    return AnyReader([p])


def _cloud(msg: Any, topic: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(points (n, 3) float64, absolute times (n,) float64) of one PointCloud2."""
    fields = {f.name: f for f in msg.fields}
    tname = next((n for n in TIME_FIELDS if n in fields), None)
    if not {"x", "y", "z"} <= set(fields) or tname is None:
        raise PointFileError(f"Expected x, y, z and a per-point time ({', '.join(TIME_FIELDS)}) "
                             f"in the clouds of '{topic}', got fields {sorted(fields)}.")
    order = ">" if msg.is_bigendian else "<"
    names = ["x", "y", "z", tname]
    dt = np.dtype({"names": names,
                   "formats": [order + _FIELD_TYPES[fields[n].datatype] for n in names],
                   "offsets": [fields[n].offset for n in names],
                   "itemsize": msg.point_step})
    n = int(msg.width) * int(msg.height)
    rec = np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=dt, count=n)
    xyz = np.stack([rec["x"], rec["y"], rec["z"]], 1).astype(np.float64)
    scale, relative = TIME_FIELDS[tname]
    t = rec[tname].astype(np.float64) * scale
    if relative:
        t = t + msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
    # ouster-ros publishes an organised grid with all-zero cells where no return came
    # (sensors.pointcloud2.organise): those are not points at the sensor's origin.
    keep = np.isfinite(xyz).all(axis=1) & (xyz != 0).any(axis=1)
    return xyz[keep], t[keep]


def _open_bag(p: Path) -> DriveFile:
    """A bag's drive: its PointCloud2 topic (the one with most messages), the mount
    from /tf_static (base_link -> the clouds' frame), points and time span."""
    if not p.exists():
        raise PointFileError(f"Expected a ROS 2 bag, got '{p}' which does not exist.")
    with _reader(p) as bag:
        clouds = [c for c in bag.connections if c.msgtype == "sensor_msgs/msg/PointCloud2"]
        if not clouds:
            raise PointFileError(f"Expected a sensor_msgs/msg/PointCloud2 topic in '{p}', "
                                 "got none.")
        best = max(clouds, key=lambda c: c.msgcount)
        n, lo, hi, frame = 0, np.inf, -np.inf, ""
        for con, _, raw in bag.messages(connections=[best]):
            msg = bag.deserialize(raw, con.msgtype)
            xyz, t = _cloud(msg, best.topic)
            frame = frame or msg.header.frame_id
            n += len(t)
            if len(t):
                lo, hi = min(lo, float(t.min())), max(hi, float(t.max()))
        mount, recorded = Mount(), False
        static = [c for c in bag.connections if c.topic == "/tf_static"]
        for con, _, raw in bag.messages(connections=static):
            for tf in bag.deserialize(raw, con.msgtype).transforms:
                if tf.child_frame_id == frame:
                    tr, q = tf.transform.translation, tf.transform.rotation
                    mount = Mount((tr.x, tr.y, tr.z), Rotation.from_quat([q.x, q.y, q.z, q.w]))
                    recorded = True
    if n == 0:
        raise PointFileError(f"Expected points in the clouds of '{best.topic}' in '{p}', "
                             "got none.")
    return DriveFile(p, frame or "unknown", mount, recorded, n, (lo, hi), "bag", best.topic)


def _bag_frames(drive: DriveFile) -> Iterator[ScanFrame]:
    with _reader(drive.path) as bag:
        cons = [c for c in bag.connections if c.topic == drive.topic]
        for k, (con, _, raw) in enumerate(bag.messages(connections=cons)):
            xyz, t = _cloud(bag.deserialize(raw, con.msgtype), drive.topic)
            if len(t):
                order = np.argsort(t, kind="stable")
                yield ScanFrame(k, xyz[order], t[order])
