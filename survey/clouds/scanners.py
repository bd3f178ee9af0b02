"""Where the scanner stood for each point of a cloud file: what the solid reconstruction
(``survey.clouds.solid``) orients its normals by.

Sources, tried in this order for each file:

1. ``trajectory`` given (a ``sensors.Trajectory``: the platform's poses, e.g. a drive's
   ``_true_trajectory.txt`` or a SLAM estimate): the sensor's position at each point's
   time (LAS/LAZ ``gps_time``; PLY ``gps_time`` or ``time``; NPZ ``time`` or
   ``gps_time``), through the mount a drive file records in its "tunnelsim" VLR (lever
   arm and boresight; identity without one). An MLS or SLAM cloud.
2. The station pose the file records: a tunnelsim LAS/LAZ file's "tunnelsim" VLR
   (``station_position``), a tunnelsim PLY's ``tunnelsim {...}`` comment, an E57 scan's
   pose (its translation). A TLS station.
3. ``stations`` given ((k, 3) positions, e.g. read by ``read_positions``): the nearest
   to each point (``survey.clouds.solid.nearest_scanner``). A merged cloud whose link
   to the stations was lost.

Otherwise ``PointFileError`` says what to pass. Memory: one chunk at a time (E57: one
scan, as ``iter_points`` reads it).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sensors import Mount, Trajectory
from sensors.errors import TrajectoryError
from sensors.io.las import LasSource
from sensors.io.ply import read_ply_header
from sensors.io.cloudread import (
    CHUNK,
    INFO_USER,
    check_finite,
    check_las_scale,
    cloud_errors,
    existing_cloud,
    iter_points,
    las_xyz,
    ply_points,
    ply_time,
    ply_xyz,
)
from survey.clouds.solid import nearest_scanner
from sensors.io.errors import PointFileError

__all__ = ["file_info", "iter_scanned", "read_positions", "station_position"]

Floats = NDArray[np.float64]
PathLike = str | os.PathLike[str]


def file_info(path: PathLike) -> dict[str, Any]:
    """The simulation info a tunnelsim LAS/LAZ (VLR "tunnelsim", record 1) or PLY
    (``tunnelsim {...}`` comment) file records, or {} (other files, other writers)."""
    path = existing_cloud(path)
    kind = path.suffix.lower()
    text = None
    with cloud_errors():
        if kind in (".las", ".laz"):
            with LasSource(path) as src:
                for v in src.header.vlrs:
                    if str(v.user_id).rstrip("\0") == INFO_USER and v.record_id == 1:
                        text = bytes(v.record_data).decode("utf-8", "replace").rstrip("\0")
        elif kind == ".ply":
            tag = f"comment {INFO_USER} "
            for line in read_ply_header(path).comments:
                if line.startswith(tag):
                    text = line[len(tag):]
    if text is None:
        return {}
    try:
        info = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PointFileError(f"Expected JSON in the {INFO_USER} record of '{path}', got "
                             f"unreadable text ({exc}).") from exc
    return info if isinstance(info, dict) else {}


def station_position(path: PathLike) -> Floats | None:
    """The (3,) position of the station a file records (tunnelsim LAS/LAZ/PLY info,
    E57 scan pose), or None."""
    path = existing_cloud(path)
    if path.suffix.lower() == ".e57":
        from sensors.io.e57 import read_e57_scan

        with cloud_errors():
            return np.asarray(read_e57_scan(path).translation, dtype=np.float64)
    pos = file_info(path).get("station_position")
    if pos is None:
        return None
    try:
        p = np.asarray(pos, dtype=np.float64).reshape(3)
    except (TypeError, ValueError) as exc:
        raise PointFileError(f"Expected station_position (3,) in the {INFO_USER} record "
                             f"of '{path}', got {pos!r}.") from exc
    if not np.isfinite(p).all():
        raise PointFileError(f"Expected a finite station_position in '{path}', got "
                             f"{p.tolist()}.")
    return p


def read_positions(path: PathLike) -> Floats:
    """Scanner positions (k, 3) float64 from a text file: x y z per row (spaces or
    commas, '#' comments); a header line naming x, y and z is read past, and a route
    CSV (``tunnelsim route``: distance_m, x, y, z, ...) or a TUM trajectory (t x y z qx
    qy qz qw) gives its x, y, z columns."""
    p = Path(path)
    if not p.is_file():
        raise PointFileError(f"Expected a file of scanner positions, got '{p}' which does "
                             "not exist.")
    lines = [ln.strip() for ln in p.read_text(errors="replace").splitlines()]
    lines = [ln for ln in lines if ln and not ln.startswith("#")]
    if not lines:
        raise PointFileError(f"Expected scanner positions (x y z per row) in '{p}', got "
                             "none.")
    rows = [ln.replace(",", " ").split() for ln in lines]
    cols = (0, 1, 2)
    try:
        float(rows[0][0])
    except ValueError:
        head = [w.lower() for w in rows.pop(0)]
        if not {"x", "y", "z"} <= set(head):
            raise PointFileError(f"Expected a header naming x, y and z in '{p}', got "
                                 f"{head}.") from None
        cols = (head.index("x"), head.index("y"), head.index("z"))
    else:
        if len(rows[0]) == 8:          # TUM: t x y z qx qy qz qw
            cols = (1, 2, 3)
    try:
        xyz = np.array([[float(r[c]) for c in cols] for r in rows], dtype=np.float64)
    except (ValueError, IndexError) as exc:
        raise PointFileError(f"Expected numeric x y z on every row of '{p}', got a row "
                             f"that is not ({exc}).") from exc
    if len(xyz) == 0 or not np.isfinite(xyz).all():
        raise PointFileError(f"Expected finite scanner positions in '{p}', got "
                             f"{len(xyz)} rows with NaN, inf or none.")
    return xyz


def _mount(path: Path) -> Mount:
    info = file_info(path) if path.suffix.lower() in (".las", ".laz", ".ply") else {}
    lever, quat = info.get("mount_lever_arm_m"), info.get("mount_boresight_xyzw")
    if lever is None or quat is None:
        return Mount()
    from scipy.spatial.transform import Rotation

    return Mount(tuple(lever), Rotation.from_quat(quat))


def _timed_chunks(path: Path, chunk: int) -> Iterator[tuple[Floats, Floats]]:
    """(xyz (n, 3), time (n,)) chunks of a LAS/LAZ, PLY or NPZ cloud with point times."""
    kind = path.suffix.lower()
    n = 0
    with cloud_errors():
        if kind in (".las", ".laz"):
            with LasSource(path) as src:
                check_las_scale(src.header, path)
                if "gps_time" not in set(src.header.point_format.dimension_names):
                    raise _no_times(path)
                for rec in src.chunks(chunk):
                    xyz = las_xyz(rec)
                    check_finite(xyz, path, n)
                    n += len(xyz)
                    yield xyz, np.asarray(rec.gps_time, dtype=np.float64)
            return
        if kind == ".ply":
            data = ply_points(path)
            for i in range(0, len(data), chunk):
                c = data[i:i + chunk]
                t = ply_time(c)
                if t is None:
                    raise _no_times(path)
                xyz = ply_xyz(c)
                check_finite(xyz, path, i)
                yield xyz, t
            return
        if kind == ".npz":
            d = np.load(path, allow_pickle=False)
            name = next((k for k in ("gps_time", "time") if k in d.files), None)
            if name is None:
                raise _no_times(path)
            xyz = np.stack([np.asarray(d[k]).reshape(-1) for k in "xyz"], 1)
            t = np.asarray(d[name], dtype=np.float64).reshape(-1)
            for i in range(0, len(t), chunk):
                check_finite(xyz[i:i + chunk], path, i)
                yield xyz[i:i + chunk].astype(np.float64), t[i:i + chunk]
            return
    raise _no_times(path)


def _no_times(path: Path) -> PointFileError:
    return PointFileError(f"Expected per-point times (gps_time) in '{path}' to place the "
                          "scanner on the trajectory, got a file without them; write the "
                          "drive as LAS/LAZ, PLY or NPZ, or pass --scanners instead.")


def iter_scanned(path: PathLike, *, trajectory: Trajectory | None = None,
                 stations: ArrayLike | None = None, chunk: int = CHUNK
                 ) -> Iterator[tuple[Floats, Floats]]:
    """Chunks (xyz (n, 3) float64, scanner (n, 3) float64) of a cloud file: each point
    and the position of the scanner that measured it (sources: see the module doc).

    Raises
    ------
    PointFileError
        An unreadable file (as ``iter_points``), a file with no scanner source, point
        times outside the trajectory (with the hint ``Trajectory`` gives).
    """
    path = existing_cloud(path)
    if trajectory is not None:
        mount = _mount(path)
        for xyz, t in _timed_chunks(path, chunk):
            try:
                pos, _ = trajectory.sensor_poses(t, mount)
            except TrajectoryError as exc:
                raise PointFileError(f"Expected the point times of '{path}' within the "
                                     f"trajectory, got: {exc}") from exc
            yield xyz, pos
        return
    fixed = station_position(path)
    st = None if stations is None else np.asarray(stations, dtype=np.float64)
    if fixed is None and st is None:
        raise PointFileError(f"Expected scanner positions for '{path}', got a file that "
                             "records no station pose; pass --trajectory (a drive, with "
                             "point times) or --scanners (a file of x y z positions).")
    for xyz in iter_points(path, chunk=chunk):
        if fixed is not None:
            yield xyz, np.broadcast_to(fixed, xyz.shape)
        elif st is not None:
            yield xyz, nearest_scanner(xyz, st)
