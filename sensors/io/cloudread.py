"""Point clouds read chunk by chunk, whatever wrote them (``sensors.io.cloudmap`` is
the rewriting side).

Reading: ``iter_points`` (LAS/LAZ, binary PLY, XYZ/TXT/CSV text, NPZ, E57),
``read_points``, ``read_reference`` (a mesh or a cloud) and ``cloud_bounds``; the CRS a
file states (``cloud_crs_text``, ``cloud_crs``). The file formats themselves live in
``sensors.io.las``, ``sensors.io.ply`` and ``sensors.io.e57``, shared with the simulation's
writers; field names follow ``sensors.io.fields.FILE_FIELDS`` (files of earlier versions,
with ``sx``/``time`` in PLY and NPZ, read as well: ``ply_time``).

Every problem with a file is a ``PointFileError`` naming the file and the problem: an
empty or corrupt file, a file shorter than its header promises (with the points
promised and read), a valid file without points, a NaN or infinite coordinate (with the
point's index). The helpers ``cloud_errors``, ``existing_cloud``, ``check_finite``,
``check_las_scale``, ``las_xyz``, ``ply_points``, ``ply_xyz`` and ``no_points`` are
shared with ``cloudmap``.

Coordinate reference systems (``sensors.io.crs``): ``cloud_crs`` reports the CRS a cloud
states (LAS/LAZ: the WKT VLR or GeoTIFF keys; E57: ``coordinateMetadata``; PLY, NPZ,
text and mesh files: the sidecar ``<file>.prj``, a text cloud also a ``# crs:``
comment line, a tunnel PLY its JSON's ``crs``).
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from sensors.io.crs import CRSError, parse_crs, read_sidecar, text_file_crs
from sensors.io.e57 import read_e57, read_e57_crs
from sensors.io.errors import PointFileError
from sensors.io.fields import point_field
from sensors.io.las import CRS_USER, LasSource, las_crs_wkt
from sensors.io.ply import ply_element, read_ply_header
from raytrace.errors import TunnelsimError
from sensors.io.errors import PointFileError

__all__ = ["CHUNK", "INFO_USER", "MAX_LAS_SCALE", "SUFFIXES", "TRIMESH_SUFFIXES",
           "check_finite", "check_las_scale", "cloud_bounds", "cloud_crs", "cloud_crs_text",
           "cloud_errors", "existing_cloud", "iter_points", "las_xyz", "no_points",
           "ply_points", "ply_time", "ply_xyz", "read_points", "read_reference"]

CHUNK = 1 << 20
#: Coarsest LAS coordinate scale accepted for tunnel work (m).
MAX_LAS_SCALE = 0.01
#: Suffixes ``iter_points`` reads.
SUFFIXES = (".las", ".laz", ".ply", ".xyz", ".txt", ".csv", ".npz", ".e57")

PathLike = str | os.PathLike[str]
#: User id of the VLR (record 1) and prefix of the PLY comment with a tunnelsim file's
#: simulation info (JSON; ``sensors.writers``).
INFO_USER = "tunnelsim"


@contextlib.contextmanager
def cloud_errors() -> Iterator[None]:
    """File-format errors of ``sensors`` as this package's ``PointFileError``."""
    try:
        yield
    except PointFileError as exc:
        raise PointFileError(str(exc)) from exc


def existing_cloud(path: PathLike) -> Path:
    """``path`` as a Path; ``PointFileError`` when no such file exists."""
    p = Path(path)
    if not p.is_file():
        raise PointFileError(f"Expected a point cloud, got '{p}' which does not exist.")
    return p


def check_las_scale(header: Any, path: Path) -> None:
    """``PointFileError`` for LAS coordinate scales coarser than ``MAX_LAS_SCALE``."""
    sc = np.asarray(header.scales, dtype=np.float64)
    if not (np.isfinite(sc).all() and (sc > 0).all() and (sc <= MAX_LAS_SCALE).all()):
        raise PointFileError(f"Expected LAS coordinate scales between 0 and "
                             f"{MAX_LAS_SCALE} m, got {sc.tolist()} in '{path}'; the "
                             "coordinates are too coarse (or broken) for tunnel work: "
                             "re-export with a scale of 0.001 m or finer.")


def check_finite(xyz: NDArray[np.float64], path: Path, first: int) -> None:
    """Name the first NaN or infinite coordinate (``first``: index of the chunk's first
    point in the file)."""
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        what = "a NaN" if np.isnan(xyz[i]).any() else "an infinite"
        raise PointFileError(f"Expected finite coordinates in '{path}', got point "
                             f"{first + i:,} with {what} coordinate "
                             f"({', '.join(f'{v:g}' for v in xyz[i])}); remove it or "
                             "export the cloud again.")


def las_xyz(rec: Any) -> NDArray[np.float64]:
    """Scaled coordinates (n, 3) float64 of laspy point records."""
    return np.stack([np.asarray(rec.x), np.asarray(rec.y), np.asarray(rec.z)], 1)


def ply_xyz(rec: np.ndarray) -> NDArray[np.float64]:
    """Coordinates (n, 3) float64 of PLY vertex records."""
    return np.stack([rec["x"], rec["y"], rec["z"]], 1).astype(np.float64)


def ply_points(path: Path) -> np.ndarray:
    """The vertex records of a point-cloud PLY (memory map)."""
    head = read_ply_header(path)
    v = head.element("vertex")
    if not {"x", "y", "z"} <= set(v.dtype.names or ()):
        raise PointFileError(f"Expected vertex properties x, y, z in '{path}', got "
                             f"{list(v.dtype.names or ())}.")
    return ply_element(path, "vertex", head)


def ply_time(rec: np.ndarray) -> NDArray[np.float64] | None:
    """The per-point time (s) of PLY vertex records: ``gps_time`` (``sensors.io.fields``),
    else ``time`` (tunnelsim files of earlier versions, other writers); None without
    either."""
    for name in rec.dtype.names or ():
        if point_field(name) == "time":
            return np.asarray(rec[name], dtype=np.float64)
    return None


def _raw_chunks(path: Path, kind: str, chunk: int) -> Iterator[NDArray[np.float64]]:
    if kind in (".las", ".laz"):
        with LasSource(path) as src:
            check_las_scale(src.header, path)
            for rec in src.chunks(chunk):
                yield las_xyz(rec)
    elif kind == ".ply":
        data = ply_points(path)
        for i in range(0, len(data), chunk):
            yield ply_xyz(data[i:i + chunk])
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
        raise PointFileError(f"Expected numeric x y z columns, or a header line naming x, "
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
                raise PointFileError(f"Expected numeric x y z columns in '{path}', got "
                                     f"unreadable text ({exc}).") from exc
            if len(a) == 0:
                break
            yield a


def _npz_chunks(path: Path, chunk: int) -> Iterator[NDArray[np.float64]]:
    try:
        d = np.load(path, allow_pickle=False)
        cols = [np.asarray(d[k]).reshape(-1) for k in "xyz"]
    except KeyError as exc:
        raise PointFileError(f"Expected arrays x, y, z in '{path}', got "
                             f"{sorted(getattr(d, 'files', []))}.") from exc
    except Exception as exc:   # zipfile, pickle and format errors of numpy.load
        raise PointFileError(f"Expected an NPZ file numpy can read, got '{path}' which "
                             f"fails with: {exc}.") from exc
    if not len(cols[0]) == len(cols[1]) == len(cols[2]):
        raise PointFileError(f"Expected arrays x, y, z of one length in '{path}', got "
                             f"{[len(c) for c in cols]}.")
    for i in range(0, len(cols[0]), chunk):
        yield np.stack([c[i:i + chunk] for c in cols], 1).astype(np.float64)


def iter_points(path: PathLike, *, chunk: int = CHUNK, allow_empty: bool = False
                ) -> Iterator[NDArray[np.float64]]:
    """Coordinates (n, 3) float64 of a cloud, chunk by chunk: LAS/LAZ (laspy chunks),
    binary PLY (memory map), XYZ/TXT/CSV text (x y z in the first three columns),
    NPZ (tunnelsim's fields x, y, z) and E57 (pye57, whole scans: not chunked).

    Raises ``PointFileError`` for an unreadable, corrupt or cut-short file, a NaN or
    infinite coordinate, and (unless ``allow_empty``) a file without points.
    """
    path = existing_cloud(path)
    kind = path.suffix.lower()
    if kind not in SUFFIXES:
        raise PointFileError(f"Expected a {', '.join(SUFFIXES)} cloud, got '{path}'.")
    n = 0
    with cloud_errors():
        for xyz in _raw_chunks(path, kind, chunk):
            check_finite(xyz, path, n)
            n += len(xyz)
            yield xyz
    if n == 0 and not allow_empty:
        raise PointFileError(f"Expected points in '{path}', got a valid file with 0 "
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

    A PLY with faces is a mesh (read by ``sensors.io.ply``), a PLY without is a cloud;
    OBJ, STL and OFF are meshes (trimesh); every other suffix is a cloud
    (``iter_points``). Raises ``PointFileError`` for an unreadable, cut-short or empty
    file and for a NaN coordinate.
    """
    from .meshes import read_mesh

    path = existing_cloud(path)
    kind = path.suffix.lower()
    mesh_file = kind in TRIMESH_SUFFIXES
    if kind == ".ply":
        with cloud_errors():
            head = read_ply_header(path)
        mesh_file = any(e.name == "face" and e.count > 0 for e in head.elements)
    if mesh_file:
        try:
            mesh = read_mesh(path)
        except TunnelsimError as exc:
            raise PointFileError(str(exc)) from exc
        check_finite(mesh.vertices, path, 0)
        return mesh.vertices, mesh.faces
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
    path = existing_cloud(path)
    if path.suffix.lower() not in (".las", ".laz"):
        return _bounds(iter_points(path, chunk=chunk))
    with cloud_errors(), LasSource(path, xyz_only=True) as src:
        check_las_scale(src.header, path)
        lo, hi, n = _bounds(las_xyz(rec) for rec in src.chunks(chunk))
        h_lo, h_hi = src.header_bounds()
        tol = 2.0 * np.abs(np.asarray(src.header.scales, dtype=np.float64))
    if n == 0:
        raise no_points(path)
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
    path = existing_cloud(path)
    kind = path.suffix.lower()
    with cloud_errors():
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
    from .tunnel_json import FORMAT, read_meta, sidecar

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


def no_points(src: Path) -> PointFileError:
    """The error for a valid cloud without points."""
    return PointFileError(f"Expected points in '{src}', got a valid file with 0 points.")
