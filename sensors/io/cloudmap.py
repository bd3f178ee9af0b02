"""Point clouds rewritten chunk by chunk (``sensors.io.cloudread`` is the reading
side): new coordinates
(``map_cloud``: Helmert transforms, drift corrections, a drive re-placed), new fields
(``annotate_las``: distances), new files (``write_points_las``).

A rewrite keeps every field, VLR and EVLR of its input, and is written atomically: a
failure leaves no output file. It keeps the input's CRS unless ``map_cloud(...,
crs=)`` states another (or None: the coordinates left it).

Station poses: a tunnelsim LAS/LAZ file records its station's pose in the "tunnelsim"
VLR (JSON ``station_position``, ``station_quaternion_xyzw``; a PLY in its
``tunnelsim {...}`` comment), an E57 scan in its pose. ``map_cloud(..., pose=)``
rewrites them with the coordinates (a drive's ``mount_*`` keys are platform-relative
and stay); an E57 station is rewritten by its pose, its points staying in the scan
frame.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensors.io.crs import parse_crs, read_sidecar, write_sidecar
from sensors.io.e57 import read_e57_scan, write_e57_scan
from sensors.io.las import (
    LAS_SCALE,
    LasSource,
    LasWriter,
    is_crs_record,
    offsets_near,
    output_header,
    quantize,
    set_las_crs,
    write_las,
)
from sensors.io.ply import PlyWriter, read_ply_header
from sensors.io.cloudread import (
    CHUNK,
    INFO_USER,
    PathLike,
    check_finite,
    check_las_scale,
    cloud_errors,
    existing_cloud,
    las_xyz,
    no_points,
    ply_points,
    ply_time,
    ply_xyz,
)
from sensors.io.errors import PointFileError

__all__ = ["E57_KEEP_TOL_M", "KEEP_CRS", "PoseFn", "XyzFn", "annotate_las",
           "map_cloud", "write_points_las"]

#: ``map_cloud(..., crs=KEEP_CRS)``: the output states the input's CRS (the default).
KEEP_CRS = "keep"
#: A rewritten E57 scan keeps its scan-frame coordinates when the recomputed ones
#: differ by less than this (m): rounding of the pose algebra, not a change.
E57_KEEP_TOL_M = 1e-7


#: fn(xyz (n, 3), time (n,) or None[, fields]) -> new xyz (n, 3).
XyzFn = Callable[..., Any]


def _new_xyz(fn: XyzFn, xyz: NDArray[np.float64], t: NDArray[np.float64] | None,
             src: Path) -> NDArray[np.float64]:
    new = np.asarray(fn(xyz, t), dtype=np.float64)
    if new.shape != xyz.shape:
        raise PointFileError(f"Expected new coordinates of shape {xyz.shape} for '{src}', "
                             f"got {new.shape}.")
    return new


#: pose(position (3,), quaternion_xyzw (4,)) -> (position (3,), quaternion_xyzw (4,)),
#: a station's pose (sensor to world) in the new coordinates.
PoseFn = Callable[[NDArray[np.float64], NDArray[np.float64]], tuple[Any, Any]]


def map_cloud(src: PathLike, dst: PathLike, fn: XyzFn, *, chunk: int = CHUNK,
              fields: tuple[str, ...] = (), crs: Any = KEEP_CRS,
              pose: PoseFn | None = None) -> int:
    """Write ``dst`` = ``src`` with x, y, z replaced by ``fn(xyz (n, 3), time (n,) or
    None)``; every other field, VLR and EVLR is kept (a COPC file becomes a plain LAZ).
    LAS/LAZ (by suffix) or binary PLY. Atomic. Returns the point count.

    With ``fields`` (LAS/LAZ dimension names, e.g. extra bytes ``sensor_x``), ``fn`` is
    called as ``fn(xyz, time, {name: (n,) array})``; a file without one of them is a
    ``PointFileError``.

    ``crs``: the CRS ``dst`` states: ``KEEP_CRS`` (default) the input's (its LAS
    records, its PLY sidecar), None none (the new coordinates are in another system
    whose CRS is unknown), or a CRS (EPSG:n, WKT, PROJJSON; needs pyproj), which
    replaces the input's.

    ``pose``: the station pose in the new coordinates (``PoseFn``); the station pose
    that a tunnelsim file records (LAS/LAZ VLR, PLY comment) is rewritten through it
    (without ``pose`` it is copied as it is). An E57 file (one scan, as a tunnelsim
    station; output .e57) needs ``pose``: its pose becomes ``pose(...)`` and its
    scan-frame points ``R_new^T (fn(world) - p_new)``, which are the input's when
    ``fn`` and ``pose`` agree on a rigid motion (a scale changes them; see
    ``_map_e57``)."""
    src, dst = existing_cloud(src), Path(dst)
    if not dst.parent.exists():
        raise PointFileError(f"Expected an existing output folder, got '{dst.parent}'.")
    kind = src.suffix.lower()
    with cloud_errors():
        if kind in (".las", ".laz"):
            if dst.suffix.lower() not in (".las", ".laz"):
                raise PointFileError(f"Expected a .las/.laz output for '{src}', got '{dst}'.")
            n = _map_las(src, dst, fn, chunk, fields, crs, pose)
        elif kind == ".ply" and not fields:
            if dst.suffix.lower() != ".ply":
                raise PointFileError(f"Expected a .ply output for '{src}', got '{dst}'.")
            if crs is not KEEP_CRS and crs is not None:
                crs = parse_crs(crs, what="the output CRS")   # before any point is read
            n = _map_ply(src, dst, fn, chunk, pose)
            write_sidecar(dst, read_sidecar(src) if crs is KEEP_CRS else crs)
        elif kind == ".e57" and not fields:
            if dst.suffix.lower() != ".e57":
                raise PointFileError(f"Expected a .e57 output for '{src}', got '{dst}'.")
            if pose is None:
                raise PointFileError(f"Expected a pose function for the E57 scan '{src}' "
                                     "(its points are stored in the scan frame), got none.")
            n = _map_e57(src, dst, fn, pose, crs)
        else:
            raise PointFileError(f"Expected a .las, .laz, .ply or .e57 cloud, got '{src}'.")
    return n


#: step(records, index of their first point) -> (``output_header`` options, a function
#: from the output header to the records to write).
LasStep = Callable[[Any, int], tuple[dict[str, Any], Callable[[Any], Any]]]


def _rewrite_las(source: LasSource, dst: Path, chunk: int, step: LasStep,
                 crs: Any = KEEP_CRS, pose: PoseFn | None = None) -> int:
    """Write ``dst`` from ``source`` chunk by chunk through ``step``; the options it
    gives for the first chunk make the output header (they may depend on the data:
    offsets near the new coordinates, dtypes of new fields). Every VLR and EVLR is
    carried, the CRS records as ``map_cloud``'s ``crs`` says; a failure leaves no
    ``dst``; with ``pose`` the station pose of the tunnelsim VLR is rewritten. Returns
    the point count."""
    if source.point_count == 0:
        raise no_points(source.path)
    if crs is not KEEP_CRS and crs is not None:
        crs = parse_crs(crs, what="the output CRS")     # before any point is read
    evlrs = source.evlrs()
    if crs is not KEEP_CRS:
        evlrs = [e for e in evlrs if not is_crs_record(e)]
    n = 0
    with contextlib.ExitStack() as stack:     # closes the writer, or drops its file
        w: LasWriter | None = None
        for rec in source.chunks(chunk):
            options, records = step(rec, n)
            if w is None:
                head = output_header(source, **options)
                if pose is not None:
                    _move_info_vlr(head, pose, source.path)
                if crs is not KEEP_CRS:
                    set_las_crs(head, crs)
                w = stack.enter_context(LasWriter(dst, head, evlrs=evlrs))
            w.write_points(records(w.header))
            n += len(rec)
    return n


def _map_las(src: Path, dst: Path, fn: XyzFn, chunk: int, fields: tuple[str, ...] = (),
             crs: Any = KEEP_CRS, pose: PoseFn | None = None) -> int:
    import laspy

    with LasSource(src) as source:
        names = set(source.header.point_format.dimension_names)
        has_time = "gps_time" in names
        missing = [f for f in fields if f not in names]
        if missing:
            raise PointFileError(f"Expected the fields {list(fields)} in '{src}', got a "
                                 f"file without {missing}.")
        # A finer scale never loses what the input held; 0.1 mm at most.
        scales = np.minimum(LAS_SCALE, np.asarray(source.header.scales, dtype=np.float64))

        wave = {"x_t", "y_t", "z_t"} <= names

        def step(rec: Any, first: int) -> tuple[dict[str, Any], Callable[[Any], Any]]:
            t = np.asarray(rec.gps_time) if has_time else None
            if fields:
                extra = {f: np.asarray(rec[f]) for f in fields}
                f1: XyzFn = lambda xyz, tt: fn(xyz, tt, extra)  # noqa: E731
            else:
                f1 = fn
            xyz = las_xyz(rec)
            new = _new_xyz(f1, xyz, t, src)
            check_finite(new, dst, first)
            d_new = None
            if wave:
                # The wave packet's direction (x(t), y(t), z(t): coordinate units per
                # picosecond, LAS 1.4 R15 table 17) turns with the points: mapped as
                # the difference of two mapped points ~1 m apart along it, exact for
                # a Helmert transform and the local linearisation of any other.
                d = np.stack([np.asarray(rec[k], dtype=np.float64)
                              for k in ("x_t", "y_t", "z_t")], 1)
                tau = 1.0 / np.maximum(np.abs(d).max(axis=1), 1e-12)
                d_new = (_new_xyz(f1, xyz + d * tau[:, None], t, src) - new) \
                    / tau[:, None]

            def records(head: Any) -> Any:
                out = laspy.ScaleAwarePointRecord(rec.array.copy(), head.point_format,
                                                  head.scales, head.offsets)
                q = quantize(new, head.scales, head.offsets)
                out.array["X"], out.array["Y"], out.array["Z"] = q.T
                if d_new is not None:
                    for k, col in zip(("x_t", "y_t", "z_t"), d_new.T):
                        out[k] = col.astype(np.float32)
                return out
            return {"scales": scales, "offsets": offsets_near(new)}, records

        return _rewrite_las(source, dst, chunk, step, crs, pose)


def _map_ply(src: Path, dst: Path, fn: XyzFn, chunk: int, pose: PoseFn | None = None
             ) -> int:
    head = read_ply_header(src)
    if [e.name for e in head.elements] != ["vertex"]:
        raise PointFileError(f"Expected a point-cloud PLY (vertex element only), got "
                             f"'{src}'; transform meshes with their own tools.")
    data = ply_points(src)
    n = len(data)
    if n == 0:
        raise no_points(src)
    names = [f for f in data.dtype.names or () if not f.startswith("__n_")]
    native = np.dtype([(f, data.dtype[f].base.newbyteorder("="), data.dtype[f].shape)
                       for f in names])
    # A damaged header can hold bytes that decode to U+FFFD; PLY headers are ASCII.
    comments = [c.encode("ascii", "replace").decode("ascii") for c in head.comments]
    if pose is not None:
        tag = f"comment {INFO_USER} "           # comments as read_ply_header gives them
        for i, line in enumerate(comments):
            if line.startswith(tag + "{"):
                comments[i] = tag + _moved_info(line[len(tag):], pose, src)
    with PlyWriter(dst, [("vertex", native, n)], comments=comments) as w:
        for i in range(0, n, chunk):
            c = np.array(data[i:i + chunk]).astype(native)
            xyz = ply_xyz(c)
            check_finite(xyz, src, i)
            new = _new_xyz(fn, xyz, ply_time(c), src)
            check_finite(new, dst, i)
            c["x"], c["y"], c["z"] = new.T
            w.write("vertex", c)
    del data
    return n


def _moved_info(text: str, pose: PoseFn, src: Path) -> str:
    """The simulation info JSON ``text`` with its station pose moved by ``pose``."""
    import json

    try:
        info = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PointFileError(f"Expected JSON in the {INFO_USER} record of '{src}', got "
                             f"unreadable text ({exc}).") from exc
    if not isinstance(info, dict) or "station_position" not in info:
        return text           # a drive: its mount is platform-relative and stays
    try:
        p = np.asarray(info["station_position"], dtype=np.float64).reshape(3)
        q = np.asarray(info["station_quaternion_xyzw"], dtype=np.float64).reshape(4)
    except (KeyError, TypeError, ValueError) as exc:
        got = {k: info.get(k) for k in ("station_position", "station_quaternion_xyzw")}
        raise PointFileError(f"Expected station_position (3,) and station_quaternion_xyzw "
                             f"(4,) in the {INFO_USER} record of '{src}', got {got}."
                             ) from exc
    p2, q2 = pose(p, q)
    info["station_position"] = np.asarray(p2, dtype=np.float64).reshape(3).tolist()
    info["station_quaternion_xyzw"] = np.asarray(q2, dtype=np.float64).reshape(4).tolist()
    return json.dumps(info)


def _move_info_vlr(head: Any, pose: PoseFn, src: Path) -> None:
    """Rewrite the station pose in a header's tunnelsim VLR (record 1), in place."""
    import laspy

    for i, v in enumerate(head.vlrs):
        if str(v.user_id).rstrip("\0") == INFO_USER and v.record_id == 1:
            text = bytes(v.record_data).decode("utf-8", "replace").rstrip("\0")
            head.vlrs[i] = laspy.VLR(user_id=INFO_USER, record_id=1,
                                     description=v.description,
                                     record_data=_moved_info(text, pose, src).encode())


def _map_e57(src: Path, dst: Path, fn: XyzFn, pose: PoseFn, crs: Any) -> int:
    """Rewrite an E57 station: new pose ``pose(t, q)``; scan-frame points recomputed
    from ``fn`` of the world points, so that the output's world points are ``fn``'s.

    DECISION: an E57 pose is rigid, so a scale (a similarity's 1 + s, model 9's scale
    per axis) cannot go into it; it goes into the scan-frame coordinates (x (1 + s) for
    a similarity), which keeps the world coordinates exactly ``fn``'s, as for LAS and
    PLY. Refusing a scale instead would refuse every fitted 7-parameter Helmert (its
    scale is never exactly 0). Spherical coordinates cannot follow such a change; a
    scan that has them is refused then. Recomputed coordinates within
    ``E57_KEEP_TOL_M`` of the input's are the input's (rounding, not a change)."""
    from scipy.spatial.transform import Rotation

    if crs is not KEEP_CRS and crs is not None:
        crs = parse_crs(crs, what="the output CRS")     # before any point is read
    scan = read_e57_scan(src)
    n = len(scan.local_xyz)
    if n == 0:
        raise no_points(src)
    world = scan.world_xyz()
    check_finite(world, src, 0)
    new = _new_xyz(fn, world, None, src)
    check_finite(new, dst, 0)
    p2, q2 = pose(scan.translation, scan.rotation_xyzw)
    p2 = np.asarray(p2, dtype=np.float64).reshape(3)
    q2 = np.asarray(q2, dtype=np.float64).reshape(4)
    local = Rotation.from_quat(q2).inv().apply(new - p2)
    if np.max(np.abs(local - scan.local_xyz)) <= E57_KEEP_TOL_M:
        local = scan.local_xyz
    elif any(k.startswith("spherical") for k in scan.fields):
        moved = float(np.max(np.abs(local - scan.local_xyz)))
        raise PointFileError(f"Expected a rigid transform for '{src}', whose scan has "
                             "spherical coordinates, got one that changes the scan-frame "
                             f"coordinates by up to {moved:.3g} m (a scale); drop the "
                             "spherical fields or write LAS/LAZ.")
    write_e57_scan(dst, local, rotation_xyzw=q2, translation=p2, name=scan.name,
                   fields=scan.fields, crs=scan.crs if crs is KEEP_CRS else crs)
    return n


def write_points_las(path: PathLike, xyz: NDArray[np.float64],
                     extra: Mapping[str, np.ndarray] | None = None,
                     classification: np.ndarray | None = None, *, crs: Any = None) -> Path:
    """Write points (n, 3) as LAS/LAZ 1.4 (format 6, 0.1 mm scale, offset near the data)
    with optional extra dimensions {name: (n,) array}, classification codes (n,) and
    the CRS ``crs`` (EPSG:n, WKT or PROJJSON; needs pyproj); atomic."""
    fields = {} if classification is None else {"classification": classification}
    with cloud_errors():
        return write_las(path, xyz, fields=fields, extra=extra, crs=crs)


def annotate_las(src: PathLike, dst: PathLike,
                 fn: Callable[[NDArray[np.float64]], Mapping[str, np.ndarray]], *,
                 chunk: int = CHUNK) -> int:
    """Write ``dst`` = LAS/LAZ ``src`` with every point record kept (coordinates,
    intensity, GPS time, classification, extra bytes), every VLR and EVLR, plus the
    extra dimensions that ``fn(xyz (n, 3))`` returns as {name: (n,) array}, chunk by
    chunk; an input extra dimension of the same name is replaced. Atomic. Returns the
    point count."""
    import laspy

    src, dst = existing_cloud(src), Path(dst)
    if src.suffix.lower() not in (".las", ".laz") or dst.suffix.lower() not in (".las",
                                                                                 ".laz"):
        raise PointFileError(f"Expected .las/.laz input and output, got '{src}' -> '{dst}'.")
    with cloud_errors(), LasSource(src) as source:
        check_las_scale(source.header, src)

        def step(rec: Any, first: int) -> tuple[dict[str, Any], Callable[[Any], Any]]:
            extra = {k: np.asarray(v) for k, v in fn(las_xyz(rec)).items()}

            def records(head: Any) -> Any:
                out = laspy.ScaleAwarePointRecord.zeros(len(rec), header=head)
                for name in out.array.dtype.names or ():
                    if name in extra:
                        out.array[name] = extra[name]
                    elif name in (rec.array.dtype.names or ()):
                        out.array[name] = rec.array[name]
                return out
            return {"extra": {k: v.dtype for k, v in extra.items()}}, records

        return _rewrite_las(source, dst, chunk, step)
