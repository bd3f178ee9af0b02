"""Point clouds in and out, chunk by chunk, for the survey commands.

Reading: ``iter_points`` (LAS/LAZ, binary PLY, XYZ/TXT/CSV text, NPZ, E57) and
``cloud_bounds``; rewriting with new coordinates (``map_cloud``: Helmert transforms,
drift corrections) or new fields (``annotate_las``: distances); writing
(``write_points_las``). The file formats themselves live in ``sensors.las``,
``sensors.ply`` and ``sensors.e57``, shared with the simulation's writers.

Every problem with a file is a ``CloudFileError`` naming the file and the problem: an
empty or corrupt file, a file shorter than its header promises (with the points
promised and read), a valid file without points, a NaN or infinite coordinate (with the
point's index). A rewrite keeps every field, VLR and EVLR of its input, and is written
atomically: a failure leaves no output file.

Coordinate reference systems (``sensors.crs``): ``cloud_crs`` reports the CRS a cloud
states (LAS/LAZ: the WKT VLR or GeoTIFF keys; E57: ``coordinateMetadata``; PLY, NPZ,
text and mesh files: the sidecar ``<file>.prj``, a text cloud also a ``# crs:``
comment line, a tunnel PLY its JSON's ``crs``). A rewrite keeps the input's CRS unless
``map_cloud(..., crs=)`` states another (or None: the coordinates left it).

Station poses: a tunnelsim LAS/LAZ file records its station's pose in the "tunnelsim"
VLR (JSON ``station_position``, ``station_quaternion_xyzw``; a PLY in its
``tunnelsim {...}`` comment), an E57 scan in its pose. ``map_cloud(..., pose=)``
rewrites them with the coordinates (a drive's ``mount_*`` keys are platform-relative
and stay); an E57 station is rewritten by its pose, its points staying in the scan
frame.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from sensors.crs import CRSError, parse_crs, read_sidecar, text_file_crs, write_sidecar
from sensors.e57 import read_e57, read_e57_crs, read_e57_scan, write_e57_scan
from sensors.errors import PointFileError
from sensors.las import (
    CRS_USER,
    LAS_SCALE,
    LasSource,
    LasWriter,
    is_crs_record,
    las_crs_wkt,
    offsets_near,
    output_header,
    quantize,
    set_las_crs,
    write_las,
)
from sensors.ply import PlyWriter, ply_element, read_ply_header
from survey.errors import CloudFileError, TunnelsimError

__all__ = ["CHUNK", "E57_KEEP_TOL_M", "INFO_USER", "KEEP_CRS", "LAS_SCALE",
           "MAX_LAS_SCALE", "PoseFn", "annotate_las", "cloud_bounds", "cloud_crs",
           "cloud_crs_text", "iter_points", "map_cloud", "read_points", "read_reference",
           "write_points_las"]

CHUNK = 1 << 20
#: Coarsest LAS coordinate scale accepted for tunnel work (m).
MAX_LAS_SCALE = 0.01
#: Suffixes ``iter_points`` reads.
SUFFIXES = (".las", ".laz", ".ply", ".xyz", ".txt", ".csv", ".npz", ".e57")

PathLike = str | os.PathLike[str]
#: ``map_cloud(..., crs=KEEP_CRS)``: the output states the input's CRS (the default).
KEEP_CRS = "keep"
#: User id of the VLR (record 1) and prefix of the PLY comment with a tunnelsim file's
#: simulation info (JSON; ``sensors.writers``).
INFO_USER = "tunnelsim"
#: A rewritten E57 scan keeps its scan-frame coordinates when the recomputed ones
#: differ by less than this (m): rounding of the pose algebra, not a change.
E57_KEEP_TOL_M = 1e-7


@contextlib.contextmanager
def _cloud_errors() -> Iterator[None]:
    """File-format errors of ``sensors`` as this package's ``CloudFileError``."""
    try:
        yield
    except PointFileError as exc:
        raise CloudFileError(str(exc)) from exc


def _existing(path: PathLike) -> Path:
    p = Path(path)
    if not p.is_file():
        raise CloudFileError(f"Expected a point cloud, got '{p}' which does not exist.")
    return p


def _check_las_scale(header: Any, path: Path) -> None:
    sc = np.asarray(header.scales, dtype=np.float64)
    if not (np.isfinite(sc).all() and (sc > 0).all() and (sc <= MAX_LAS_SCALE).all()):
        raise CloudFileError(f"Expected LAS coordinate scales between 0 and "
                             f"{MAX_LAS_SCALE} m, got {sc.tolist()} in '{path}'; the "
                             "coordinates are too coarse (or broken) for tunnel work: "
                             "re-export with a scale of 0.001 m or finer.")


def _check_finite(xyz: NDArray[np.float64], path: Path, first: int) -> None:
    """Name the first NaN or infinite coordinate (``first``: index of the chunk's first
    point in the file)."""
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        what = "a NaN" if np.isnan(xyz[i]).any() else "an infinite"
        raise CloudFileError(f"Expected finite coordinates in '{path}', got point "
                             f"{first + i:,} with {what} coordinate "
                             f"({', '.join(f'{v:g}' for v in xyz[i])}); remove it or "
                             "export the cloud again.")


def _las_xyz(rec: Any) -> NDArray[np.float64]:
    return np.stack([np.asarray(rec.x), np.asarray(rec.y), np.asarray(rec.z)], 1)


def _ply_xyz(rec: np.ndarray) -> NDArray[np.float64]:
    return np.stack([rec["x"], rec["y"], rec["z"]], 1).astype(np.float64)


def _ply_points(path: Path) -> np.ndarray:
    """The vertex records of a point-cloud PLY (memory map)."""
    head = read_ply_header(path)
    v = head.element("vertex")
    if not {"x", "y", "z"} <= set(v.dtype.names or ()):
        raise CloudFileError(f"Expected vertex properties x, y, z in '{path}', got "
                             f"{list(v.dtype.names or ())}.")
    return ply_element(path, "vertex", head)


def _raw_chunks(path: Path, kind: str, chunk: int) -> Iterator[NDArray[np.float64]]:
    if kind in (".las", ".laz"):
        with LasSource(path) as src:
            _check_las_scale(src.header, path)
            for rec in src.chunks(chunk):
                yield _las_xyz(rec)
    elif kind == ".ply":
        data = _ply_points(path)
        for i in range(0, len(data), chunk):
            yield _ply_xyz(data[i:i + chunk])
    elif kind in (".xyz", ".txt", ".csv"):
        yield from _text_chunks(path, "," if kind == ".csv" else None, chunk)
    elif kind == ".npz":
        yield from _npz_chunks(path, chunk)
    else:
        yield from read_e57(path)


def _text_columns(path: Path, fh: TextIO, delim: str | None) -> tuple[int, int, int]:
    """Columns of x, y, z in a text cloud, reading past a header line if it has one
    (``x,y,z,...``, CloudCompare's ``//X,Y,Z,...``); the file is left at the first data
    line."""
    while True:
        pos = fh.tell()
        line = fh.readline()
        if not line:
            return (0, 1, 2)
        text = line.strip()
        if text and not text.startswith("#"):
            break
    words = [w.strip().lstrip("/").strip().lower()
             for w in (text.split(delim) if delim else text.split())]
    try:
        [float(w) for w in words[:3]]
    except ValueError:
        if {"x", "y", "z"} <= set(words):
            return (words.index("x"), words.index("y"), words.index("z"))
        raise CloudFileError(f"Expected numeric x y z columns, or a header line naming x, "
                             f"y and z, in '{path}', got the line {text[:60]!r}; name the "
                             "coordinate columns x, y, z or remove the header.") from None
    fh.seek(pos)
    return (0, 1, 2)


def _text_chunks(path: Path, delim: str | None, chunk: int) -> Iterator[NDArray[np.float64]]:
    with open(path, errors="replace") as fh:
        cols = _text_columns(path, fh, delim)
        while True:
            try:
                with warnings.catch_warnings():
                    # The read after the last row finds no data: the loop's end, not news.
                    warnings.filterwarnings("ignore", "loadtxt: input contained no data")
                    a = np.loadtxt(fh, delimiter=delim, max_rows=chunk, ndmin=2,
                                   usecols=cols, comments="#")
            except (ValueError, IndexError) as exc:
                raise CloudFileError(f"Expected numeric x y z columns in '{path}', got "
                                     f"unreadable text ({exc}).") from exc
            if len(a) == 0:
                break
            yield a


def _npz_chunks(path: Path, chunk: int) -> Iterator[NDArray[np.float64]]:
    try:
        d = np.load(path, allow_pickle=False)
        cols = [np.asarray(d[k]).reshape(-1) for k in "xyz"]
    except KeyError as exc:
        raise CloudFileError(f"Expected arrays x, y, z in '{path}', got "
                             f"{sorted(getattr(d, 'files', []))}.") from exc
    except Exception as exc:   # zipfile, pickle and format errors of numpy.load
        raise CloudFileError(f"Expected an NPZ file numpy can read, got '{path}' which "
                             f"fails with: {exc}.") from exc
    if not len(cols[0]) == len(cols[1]) == len(cols[2]):
        raise CloudFileError(f"Expected arrays x, y, z of one length in '{path}', got "
                             f"{[len(c) for c in cols]}.")
    for i in range(0, len(cols[0]), chunk):
        yield np.stack([c[i:i + chunk] for c in cols], 1).astype(np.float64)


def iter_points(path: PathLike, *, chunk: int = CHUNK, allow_empty: bool = False
                ) -> Iterator[NDArray[np.float64]]:
    """Coordinates (n, 3) float64 of a cloud, chunk by chunk: LAS/LAZ (laspy chunks),
    binary PLY (memory map), XYZ/TXT/CSV text (x y z in the first three columns),
    NPZ (tunnelsim's fields x, y, z) and E57 (pye57, whole scans: not chunked).

    Raises ``CloudFileError`` for an unreadable, corrupt or cut-short file, a NaN or
    infinite coordinate, and (unless ``allow_empty``) a file without points.
    """
    path = _existing(path)
    kind = path.suffix.lower()
    if kind not in SUFFIXES:
        raise CloudFileError(f"Expected a {', '.join(SUFFIXES)} cloud, got '{path}'.")
    n = 0
    with _cloud_errors():
        for xyz in _raw_chunks(path, kind, chunk):
            _check_finite(xyz, path, n)
            n += len(xyz)
            yield xyz
    if n == 0 and not allow_empty:
        raise CloudFileError(f"Expected points in '{path}', got a valid file with 0 "
                             "points.")


def read_points(path: PathLike, *, allow_empty: bool = False) -> NDArray[np.float64]:
    """All coordinates (n, 3) float64 of a cloud (see ``iter_points``)."""
    parts = list(iter_points(path, allow_empty=allow_empty))
    return np.concatenate(parts) if parts else np.empty((0, 3))


#: Mesh formats ``read_reference`` reads through trimesh.
TRIMESH_SUFFIXES = (".obj", ".stl", ".off")


def read_reference(path: PathLike
                   ) -> tuple[NDArray[np.float64], NDArray[np.int64] | None]:
    """A comparison reference: (vertices (n, 3), faces (m, 3) int64) of a mesh, or
    (points (n, 3), None) of a cloud.

    A PLY with faces is a mesh (read by ``sensors.ply``), a PLY without is a cloud;
    OBJ, STL and OFF are meshes (trimesh); every other suffix is a cloud
    (``iter_points``). Raises ``CloudFileError`` for an unreadable, cut-short or empty
    file and for a NaN coordinate.
    """
    from survey.world.mesh import read_ply

    path = _existing(path)
    kind = path.suffix.lower()
    if kind == ".ply":
        with _cloud_errors():
            head = read_ply_header(path)
        if any(e.name == "face" and e.count > 0 for e in head.elements):
            try:
                mesh = read_ply(path)
            except TunnelsimError as exc:
                raise CloudFileError(str(exc)) from exc
            _check_finite(mesh["vertices"], path, 0)
            return mesh["vertices"], mesh["faces"]
    elif kind in TRIMESH_SUFFIXES:
        import trimesh

        try:
            m: Any = trimesh.load(str(path), force="mesh", process=False)
            v, f = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, np.int64)
        except Exception as exc:   # trimesh raises many types for unreadable files
            raise CloudFileError(f"Expected a mesh trimesh can read, got '{path}' which "
                                 f"fails with: {exc}") from exc
        if len(f) == 0:
            raise CloudFileError(f"Expected triangles in '{path}', got none.")
        _check_finite(v, path, 0)
        return v, f
    return read_points(path), None


def cloud_bounds(path: PathLike, *, chunk: int = CHUNK
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """(min (3,), max (3,), count) of a cloud's points.

    DECISION: computed from the points, one pass over the file, never taken from a
    LAS header alone: real writers store bounds wrong (by 1000x, or stale after an
    edit), and a grid built on them refuses the points. The pass over a LAZ file
    decompresses x, y, z only. When a LAS header disagrees with its points by more
    than two scale steps, a one-line warning says so.
    """
    path = _existing(path)
    if path.suffix.lower() not in (".las", ".laz"):
        return _bounds(iter_points(path, chunk=chunk))
    with _cloud_errors(), LasSource(path, xyz_only=True) as src:
        _check_las_scale(src.header, path)
        lo, hi, n = _bounds(_las_xyz(rec) for rec in src.chunks(chunk))
        h_lo, h_hi = src.header_bounds()
        tol = 2.0 * np.abs(np.asarray(src.header.scales, dtype=np.float64))
    if n == 0:
        raise _no_points(path)
    if not (np.all(np.abs(h_lo - lo) <= tol) and np.all(np.abs(h_hi - hi) <= tol)):
        warnings.warn(f"'{path}' states bounds {h_lo.tolist()} - {h_hi.tolist()} in its "
                      f"header, but its points span {lo.tolist()} - {hi.tolist()}; using "
                      "the points' bounds.", UserWarning, stacklevel=2)
    return lo, hi, n


def _bounds(chunks: Iterable[NDArray[np.float64]]
            ) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    lo, hi, n = np.full(3, np.inf), np.full(3, -np.inf), 0
    for xyz in chunks:
        if len(xyz):
            lo = np.minimum(lo, xyz.min(axis=0))
            hi = np.maximum(hi, xyz.max(axis=0))
            n += len(xyz)
    return lo, hi, n


# ---------------------------------------------------------------------- CRS
def cloud_crs_text(path: PathLike) -> str | None:
    """The CRS a cloud or mesh file states, as text (WKT, or what a sidecar or ``# crs:``
    line holds), or None; see the module notes. No pyproj needed, except for a LAS file
    with GeoTIFF keys only (turned into WKT)."""
    path = _existing(path)
    kind = path.suffix.lower()
    with _cloud_errors():
        if kind in (".las", ".laz"):
            with LasSource(path) as src:
                text = las_crs_wkt(src.header)
                if text is None and any(v.user_id == CRS_USER for v in src.header.vlrs):
                    text = _geotiff_wkt(src.header, path)
            return text
        if kind == ".e57":
            return read_e57_crs(path)
    text = text_file_crs(path) if kind in (".xyz", ".txt", ".csv") else read_sidecar(path)
    if text is None and kind == ".ply":
        text = _tunnel_crs(path)
    return text


def _geotiff_wkt(header: Any, path: Path) -> str | None:
    """The WKT of a LAS header's GeoTIFF keys (laspy and pyproj read them)."""
    try:
        crs = header.parse_crs()
    except ImportError as exc:
        raise CRSError(f"Expected the optional package pyproj to read the CRS of '{path}' "
                       "(GeoTIFF keys); install it with: pip install 'tunnelsim[crs]'."
                       ) from exc
    except Exception as exc:   # pyproj and laspy raise several types for bad keys
        raise CRSError(f"Expected GeoTIFF CRS keys pyproj can read in '{path}', got keys "
                       f"it refuses ({exc}).") from exc
    return None if crs is None else str(crs.to_wkt())


def _tunnel_crs(path: Path) -> str | None:
    """The ``crs`` of a tunnel PLY's JSON (when the JSON beside it is a tunnel's)."""
    from survey.world.mesh import FORMAT, read_meta, sidecar

    js = sidecar(path)
    if not js.is_file():
        return None
    try:
        meta = read_meta(js)
    except TunnelsimError:
        return None
    crs = meta.get("crs") if meta.get("format") == FORMAT else None
    return crs if isinstance(crs, str) and crs.strip() else None


def cloud_crs(path: PathLike) -> Any:
    """The ``pyproj.CRS`` a cloud or mesh file states (``cloud_crs_text`` parsed), or
    None. Needs pyproj only when the file states one."""
    text = cloud_crs_text(path)
    return None if text is None else parse_crs(text, metric=False,
                                               what=f"the CRS of '{path}'")


# ---------------------------------------------------------------------- rewriting
#: fn(xyz (n, 3), time (n,) or None[, fields]) -> new xyz (n, 3).
XyzFn = Callable[..., Any]


def _new_xyz(fn: XyzFn, xyz: NDArray[np.float64], t: NDArray[np.float64] | None,
             src: Path) -> NDArray[np.float64]:
    new = np.asarray(fn(xyz, t), dtype=np.float64)
    if new.shape != xyz.shape:
        raise CloudFileError(f"Expected new coordinates of shape {xyz.shape} for '{src}', "
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
    ``CloudFileError``.

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
    src, dst = _existing(src), Path(dst)
    if not dst.parent.exists():
        raise CloudFileError(f"Expected an existing output folder, got '{dst.parent}'.")
    kind = src.suffix.lower()
    with _cloud_errors():
        if kind in (".las", ".laz"):
            if dst.suffix.lower() not in (".las", ".laz"):
                raise CloudFileError(f"Expected a .las/.laz output for '{src}', got '{dst}'.")
            n = _map_las(src, dst, fn, chunk, fields, crs, pose)
        elif kind == ".ply" and not fields:
            if dst.suffix.lower() != ".ply":
                raise CloudFileError(f"Expected a .ply output for '{src}', got '{dst}'.")
            if crs is not KEEP_CRS and crs is not None:
                crs = parse_crs(crs, what="the output CRS")   # before any point is read
            n = _map_ply(src, dst, fn, chunk, pose)
            write_sidecar(dst, read_sidecar(src) if crs is KEEP_CRS else crs)
        elif kind == ".e57" and not fields:
            if dst.suffix.lower() != ".e57":
                raise CloudFileError(f"Expected a .e57 output for '{src}', got '{dst}'.")
            if pose is None:
                raise CloudFileError(f"Expected a pose function for the E57 scan '{src}' "
                                     "(its points are stored in the scan frame), got none.")
            n = _map_e57(src, dst, fn, pose, crs)
        else:
            raise CloudFileError(f"Expected a .las, .laz, .ply or .e57 cloud, got '{src}'.")
    return n


def _no_points(src: Path) -> CloudFileError:
    return CloudFileError(f"Expected points in '{src}', got a valid file with 0 points.")


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
        raise _no_points(source.path)
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
            raise CloudFileError(f"Expected the fields {list(fields)} in '{src}', got a "
                                 f"file without {missing}.")
        # A finer scale never loses what the input held; 0.1 mm at most.
        scales = np.minimum(LAS_SCALE, np.asarray(source.header.scales, dtype=np.float64))

        def step(rec: Any, first: int) -> tuple[dict[str, Any], Callable[[Any], Any]]:
            t = np.asarray(rec.gps_time) if has_time else None
            if fields:
                extra = {f: np.asarray(rec[f]) for f in fields}
                new = _new_xyz(lambda xyz, tt: fn(xyz, tt, extra), _las_xyz(rec), t, src)
            else:
                new = _new_xyz(fn, _las_xyz(rec), t, src)
            _check_finite(new, dst, first)

            def records(head: Any) -> Any:
                out = laspy.ScaleAwarePointRecord(rec.array.copy(), head.point_format,
                                                  head.scales, head.offsets)
                q = quantize(new, head.scales, head.offsets)
                out.array["X"], out.array["Y"], out.array["Z"] = q.T
                return out
            return {"scales": scales, "offsets": offsets_near(new)}, records

        return _rewrite_las(source, dst, chunk, step, crs, pose)


def _map_ply(src: Path, dst: Path, fn: XyzFn, chunk: int, pose: PoseFn | None = None
             ) -> int:
    head = read_ply_header(src)
    if [e.name for e in head.elements] != ["vertex"]:
        raise CloudFileError(f"Expected a point-cloud PLY (vertex element only), got "
                             f"'{src}'; transform meshes with their own tools.")
    data = _ply_points(src)
    n = len(data)
    if n == 0:
        raise _no_points(src)
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
            xyz = _ply_xyz(c)
            _check_finite(xyz, src, i)
            new = _new_xyz(fn, xyz, c["time"] if "time" in names else None, src)
            _check_finite(new, dst, i)
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
        raise CloudFileError(f"Expected JSON in the {INFO_USER} record of '{src}', got "
                             f"unreadable text ({exc}).") from exc
    if not isinstance(info, dict) or "station_position" not in info:
        return text           # a drive: its mount is platform-relative and stays
    try:
        p = np.asarray(info["station_position"], dtype=np.float64).reshape(3)
        q = np.asarray(info["station_quaternion_xyzw"], dtype=np.float64).reshape(4)
    except (KeyError, TypeError, ValueError) as exc:
        got = {k: info.get(k) for k in ("station_position", "station_quaternion_xyzw")}
        raise CloudFileError(f"Expected station_position (3,) and station_quaternion_xyzw "
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
        raise _no_points(src)
    world = scan.world_xyz()
    _check_finite(world, src, 0)
    new = _new_xyz(fn, world, None, src)
    _check_finite(new, dst, 0)
    p2, q2 = pose(scan.translation, scan.rotation_xyzw)
    p2 = np.asarray(p2, dtype=np.float64).reshape(3)
    q2 = np.asarray(q2, dtype=np.float64).reshape(4)
    local = Rotation.from_quat(q2).inv().apply(new - p2)
    if np.max(np.abs(local - scan.local_xyz)) <= E57_KEEP_TOL_M:
        local = scan.local_xyz
    elif any(k.startswith("spherical") for k in scan.fields):
        moved = float(np.max(np.abs(local - scan.local_xyz)))
        raise CloudFileError(f"Expected a rigid transform for '{src}', whose scan has "
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
    with _cloud_errors():
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

    src, dst = _existing(src), Path(dst)
    if src.suffix.lower() not in (".las", ".laz") or dst.suffix.lower() not in (".las",
                                                                                 ".laz"):
        raise CloudFileError(f"Expected .las/.laz input and output, got '{src}' -> '{dst}'.")
    with _cloud_errors(), LasSource(src) as source:
        _check_las_scale(source.header, src)

        def step(rec: Any, first: int) -> tuple[dict[str, Any], Callable[[Any], Any]]:
            extra = {k: np.asarray(v) for k, v in fn(_las_xyz(rec)).items()}

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
