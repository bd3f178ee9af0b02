"""ASTM E57 files through pye57 (libE57Format): one structured TLS scan written, every
scan of a file read.

libE57Format checks a CRC-32C per 1 KiB page, so a cut or altered file is refused as a
whole; its exceptions carry several lines of debug context. The reader turns them into
one ``PointFileError`` line naming the file. A scan with no points (which libE57Format
cannot read) is skipped; a file without any point is the caller's to refuse.

The coordinate reference system is the root's ``coordinateMetadata`` string (E57's
place for it; WKT from ``sensors.io.crs.file_wkt``), written by ``write_e57_scan(...,
crs=)`` and read by ``read_e57_crs``.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sensors.io.errors import PointFileError

__all__ = ["E57_COLOUR", "E57_FIELDS", "E57_MAX_POINTS", "E57Scan", "read_e57",
           "read_e57_colour", "read_e57_crs", "read_e57_scan", "write_e57_scan"]

#: Largest scan read or written: pye57 holds a scan in memory (about 36 bytes a point).
E57_MAX_POINTS = 50_000_000


def _pye57() -> Any:
    try:
        import pye57
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise PointFileError("Expected the optional package pye57 for E57 files; install "
                             "it with: pip install pye57") from exc
    return pye57


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _open_e57(path: Path) -> Any:
    if not path.is_file():
        raise PointFileError(f"Expected an E57 file, got '{path}' which does not exist.")
    if path.stat().st_size == 0:
        raise PointFileError(f"Expected an E57 file, got '{path}' which is empty "
                             "(0 bytes).")
    pye57 = _pye57()
    try:
        return pye57.E57(str(path))
    except Exception as exc:   # libE57Format raises E57Exception; pye57 others
        raise PointFileError(f"Expected a readable E57 file, got '{path}' which libE57 "
                             f"refuses: {_first_line(exc)}; the file is corrupt or cut "
                             "short: copy or export it again.") from exc


def read_e57_crs(path: str | os.PathLike[str]) -> str | None:
    """The root ``coordinateMetadata`` of an E57 file (the CRS as WKT, not parsed), or
    None when it is empty or missing."""
    path = Path(path)
    e57 = _open_e57(path)
    try:
        root = e57.root
        if not root.isDefined("coordinateMetadata"):
            return None
        text = str(root["coordinateMetadata"].value()).strip()
    except Exception as exc:
        raise PointFileError(f"Expected a readable coordinateMetadata in '{path}', got: "
                             f"{_first_line(exc)}.") from exc
    finally:
        with contextlib.suppress(Exception):
            e57.close()
    return text or None


def read_e57(path: str | os.PathLike[str]) -> Iterator[np.ndarray]:
    """World coordinates (n, 3) float64 of each scan of an E57 file (scan pose applied,
    invalid points dropped), one scan at a time.

    Raises ``PointFileError`` for a missing, empty, corrupt (bad checksum, bad header)
    or unreadable file, and for a scan larger than ``E57_MAX_POINTS``.
    """
    for xyz, _ in _scans(Path(path), colour=False):
        yield xyz


def read_e57_colour(path: str | os.PathLike[str]
                    ) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
    """(world coordinates (n, 3) float64, colour (n, 3) float64 or None) of each scan
    of an E57 file, as ``read_e57``; the colour (``colorRed``, ``colorGreen``,
    ``colorBlue``) as stored, mapped to [0, 1] by the scan's ``colorLimits`` (E57
    standard, ASTM E2807 8.4.19: the minimum and maximum the colour can take), or,
    without them, by the limits of the points' colour prototype (an E57
    ``IntegerNode``'s minimum and maximum); None for a scan without colour. Values are
    as the scanner stored them (sRGB-encoded, as cameras store them)."""
    yield from _scans(Path(path), colour=True)


#: The colour fields of an E57 point record (ASTM E2807), red, green, blue.
E57_COLOUR = ("colorRed", "colorGreen", "colorBlue")


def _colour_limits(head: Any, path: Path, i: int) -> tuple[float, float]:
    """(minimum, maximum) of a scan's colour: its ``colorLimits`` (red's), else its
    prototype's integer limits; refused when neither gives a range."""
    try:
        if head.node.isDefined("colorLimits"):
            lim = head.node["colorLimits"]
            lo = float(lim["colorRedMinimum"].value())
            hi = float(lim["colorRedMaximum"].value())
        else:
            from pye57 import libe57

            proto = libe57.StructureNode(head.node["points"].prototype())
            node = libe57.IntegerNode(proto["colorRed"])
            lo, hi = float(node.minimum()), float(node.maximum())
    except Exception as exc:   # libE57Format raises E57Exception; pye57 others
        raise PointFileError(f"Expected colour limits (colorLimits) in scan {i} of "
                             f"'{path}', got none readable ({_first_line(exc)}); pass "
                             "--no-colour to leave its colour out.") from exc
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise PointFileError(f"Expected colour limits with maximum > minimum in scan {i} "
                             f"of '{path}', got {lo:g} to {hi:g}; pass --no-colour to "
                             "leave its colour out.")
    return lo, hi


def _scans(path: Path, colour: bool
           ) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
    e57 = _open_e57(path)
    try:
        count = e57.scan_count
    except Exception as exc:   # libE57Format raises E57Exception; pye57 others
        with contextlib.suppress(Exception):
            e57.close()
        raise PointFileError(f"Expected a readable E57 file, got '{path}' which libE57 "
                             f"refuses: {_first_line(exc)}; the file is corrupt or cut "
                             "short: copy or export it again.") from exc
    try:
        for i in range(count):
            try:
                head = e57.get_header(i)
                n = int(head.point_count)
            except Exception as exc:
                raise PointFileError(f"Expected a readable header for scan {i} of '{path}', "
                                     f"got: {_first_line(exc)}.") from exc
            if n == 0:
                continue
            if n > E57_MAX_POINTS:
                raise PointFileError(f"Expected at most {E57_MAX_POINTS:,} points in scan {i}"
                                     f" of '{path}' (pye57 reads a scan into memory), got "
                                     f"{n:,}; split or subsample it first.")
            fields = head.point_fields
            if not ({"cartesianX", "cartesianY", "cartesianZ"} <= set(fields) or
                    {"sphericalRange", "sphericalAzimuth", "sphericalElevation"} <=
                    set(fields)):
                raise PointFileError(f"Expected Cartesian or spherical coordinates in scan "
                                     f"{i} of '{path}', got fields {sorted(fields)}.")
            coloured = colour and set(E57_COLOUR) <= set(fields)
            limits = _colour_limits(head, path, i) if coloured else None
            try:
                d = e57.read_scan(i, ignore_missing_fields=True, colors=coloured)
            except Exception as exc:
                raise PointFileError(f"Expected the {n:,} points of scan {i} of '{path}', "
                                     f"got an error reading them: {_first_line(exc)}; the "
                                     "file is corrupt.") from exc
            xyz = np.stack([d["cartesianX"], d["cartesianY"], d["cartesianZ"]],
                           1).astype(np.float64)
            rgb = None
            if limits is not None:
                lo, hi = limits
                rgb = np.clip((np.stack([d[k] for k in E57_COLOUR], 1).astype(np.float64)
                               - lo) / (hi - lo), 0.0, 1.0)
            yield xyz, rgb
    finally:
        with contextlib.suppress(Exception):
            e57.close()


def write_e57_scan(path: str | os.PathLike[str], local_xyz: np.ndarray, *,
                   rotation_xyzw: np.ndarray, translation: np.ndarray, name: str,
                   intensity: np.ndarray | None = None, row: np.ndarray | None = None,
                   column: np.ndarray | None = None, crs: Any = None,
                   fields: Mapping[str, np.ndarray] | None = None) -> Path:
    """Write one structured scan: sensor-frame Cartesian coordinates ``local_xyz``
    (n, 3), the pose (quaternion x, y, z, w and translation (3,), sensor to world),
    optional ``intensity`` (n,) and ``row``/``column`` indices (n,), and the world
    frame's CRS ``crs`` (as ``sensors.io.crs.parse_crs`` takes it) in the root's
    ``coordinateMetadata``. ``fields``: other per-point fields {E57 name: (n,) array}
    that pye57 writes (colour, invalid states; what ``read_e57_scan`` returns), kept
    as given. Written beside the target and renamed when complete (pye57 writes to a
    path, not a stream)."""
    local_xyz = np.asarray(local_xyz, dtype=np.float64).reshape(-1, 3)
    path = Path(path)
    if len(local_xyz) == 0:
        raise PointFileError(f"Expected at least one point for the E57 scan '{path}', got "
                             "none (libE57 cannot read an empty scan); write LAS/LAZ.")
    if len(local_xyz) > E57_MAX_POINTS:
        raise PointFileError(f"Expected at most {E57_MAX_POINTS:,} points for E57 (pye57 "
                             f"writes a scan from memory), got {len(local_xyz):,}; use a "
                             "coarser resolution or LAZ.")
    pye57 = _pye57()
    data = {"cartesianX": local_xyz[:, 0].copy(), "cartesianY": local_xyz[:, 1].copy(),
            "cartesianZ": local_xyz[:, 2].copy()}
    if intensity is not None:
        data["intensity"] = np.asarray(intensity, dtype=np.float32)
    for key, value in (fields or {}).items():
        if key in data or key in ("cartesianX", "cartesianY", "cartesianZ"):
            continue
        data[key] = np.asarray(value).reshape(-1)
    if row is not None and column is not None:
        data["rowIndex"] = np.asarray(row, dtype=np.int32)
        data["columnIndex"] = np.asarray(column, dtype=np.int32)
    q = np.asarray(rotation_xyzw, dtype=np.float64)
    meta = ""
    if crs is not None:
        from .crs import file_wkt

        meta = file_wkt(crs)
    tmp = path.with_name("." + path.name + ".part")
    try:
        e57 = _writer(pye57, tmp, meta)
        try:
            e57.write_scan_raw(data, name=name, rotation=np.array([q[3], q[0], q[1], q[2]]),
                               translation=np.asarray(translation, dtype=np.float64))
        finally:
            e57.close()
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return path


#: Per-point fields ``read_e57_scan`` carries (pye57 reads and writes them).
E57_FIELDS = ("cartesianX", "cartesianY", "cartesianZ", "sphericalRange",
              "sphericalAzimuth", "sphericalElevation", "intensity", "colorRed",
              "colorGreen", "colorBlue", "rowIndex", "columnIndex",
              "cartesianInvalidState", "sphericalInvalidState")


@dataclass
class E57Scan:
    """One scan of an E57 file, as stored: pose and scan-frame points.

    Attributes
    ----------
    local_xyz : (n, 3) float64, Cartesian coordinates in the scan frame (m)
    rotation_xyzw : (4,) float64, quaternion x, y, z, w (scan to world)
    translation : (3,) float64, scan origin in world coordinates (m)
    name : str, the scan's name
    fields : dict {E57 name: (n,) array}, the other per-point fields (intensity,
        rowIndex, columnIndex, colour, invalid states, spherical coordinates)
    crs : str or None, the file's ``coordinateMetadata`` (WKT, not parsed)
    """

    local_xyz: np.ndarray
    rotation_xyzw: np.ndarray
    translation: np.ndarray
    name: str
    fields: dict[str, np.ndarray]
    crs: str | None

    def world_xyz(self) -> np.ndarray:
        """(n, 3) float64 world coordinates: the pose applied to ``local_xyz``."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(self.rotation_xyzw).apply(self.local_xyz) + \
            self.translation


def read_e57_scan(path: str | os.PathLike[str]) -> E57Scan:
    """The single scan of an E57 file (a TLS station, as ``write_e57_scan`` writes it)
    with its pose, its scan-frame Cartesian points and every other field.

    Raises ``PointFileError`` for a file that ``read_e57`` refuses, a file with more or
    fewer than one scan, a scan without Cartesian coordinates, and a scan with fields
    pye57 cannot carry (a rewrite would drop them).
    """
    path = Path(path)
    crs = read_e57_crs(path)
    e57 = _open_e57(path)
    try:
        try:
            count = e57.scan_count
            head = e57.get_header(0) if count == 1 else None
            names = set(head.point_fields) if head is not None else set()
        except Exception as exc:   # libE57Format raises E57Exception; pye57 others
            raise PointFileError(f"Expected a readable E57 file, got '{path}' which libE57 "
                                 f"refuses: {_first_line(exc)}.") from exc
        if head is None:
            raise PointFileError(f"Expected one scan (a station) in '{path}', got {count}; "
                                 "split the file into one file per scan.")
        if not {"cartesianX", "cartesianY", "cartesianZ"} <= names:
            raise PointFileError(f"Expected Cartesian coordinates in the scan of '{path}', "
                                 f"got fields {sorted(names)}; convert it to Cartesian "
                                 "first.")
        other = sorted(names - set(E57_FIELDS))
        if other:
            raise PointFileError(f"Expected only the fields {list(E57_FIELDS)} in '{path}', "
                                 f"got also {other}, which a rewrite would drop.")
        n = int(head.point_count)
        if n > E57_MAX_POINTS:
            raise PointFileError(f"Expected at most {E57_MAX_POINTS:,} points in '{path}' "
                                 f"(pye57 reads a scan into memory), got {n:,}.")
        try:
            d = e57.read_scan_raw(0) if n else {k: np.zeros(0) for k in names}
            q_wxyz = np.asarray(head.rotation, dtype=np.float64)
            t = np.asarray(head.translation, dtype=np.float64).reshape(3)
            name = str(head["name"].value()) if head.node.isDefined("name") else "scan"
        except Exception as exc:
            raise PointFileError(f"Expected the {n:,} points of the scan of '{path}', got "
                                 f"an error reading them: {_first_line(exc)}; the file "
                                 "is corrupt.") from exc
    finally:
        with contextlib.suppress(Exception):
            e57.close()
    xyz = np.stack([d.pop("cartesianX"), d.pop("cartesianY"), d.pop("cartesianZ")],
                   1).astype(np.float64)
    q = np.array([q_wxyz[1], q_wxyz[2], q_wxyz[3], q_wxyz[0]])
    return E57Scan(xyz, q, t, name, dict(d), crs)


def _writer(pye57: Any, path: Path, coordinate_metadata: str) -> Any:
    """A pye57 writer whose root ``coordinateMetadata`` holds ``coordinate_metadata``.

    DECISION: pye57 sets the root's ``coordinateMetadata`` to "" while it writes the
    default header in its constructor, and libE57 refuses to set a node twice; the
    subclass hands that one ``set`` the text instead (the rest of pye57's header is
    kept as it writes it), and the result is checked so that a pye57 that changes its
    header cannot drop the CRS silently."""
    from pye57 import libe57

    class Root:      # the root node, with the coordinateMetadata set redirected
        def __init__(self, node: Any, imf: Any) -> None:
            self._node, self._imf = node, imf

        def set(self, name: str, value: Any) -> None:
            if name == "coordinateMetadata":
                value = libe57.StringNode(self._imf, coordinate_metadata)
            self._node.set(name, value)

        def __getattr__(self, name: str) -> Any:
            return getattr(self._node, name)

        def __getitem__(self, key: Any) -> Any:
            return self._node[key]

    class Writer(pye57.E57):
        _in_header = False

        def write_default_header(self) -> None:
            self._in_header = True
            try:
                super().write_default_header()
            finally:
                self._in_header = False

        @property
        def root(self) -> Any:
            node = self.image_file.root()
            return Root(node, self.image_file) if self._in_header else node

    e57 = Writer(str(path), mode="w")
    root = e57.image_file.root()
    if not root.isDefined("coordinateMetadata"):
        root.set("coordinateMetadata", libe57.StringNode(e57.image_file,
                                                         coordinate_metadata))
    if str(root["coordinateMetadata"].value()) != coordinate_metadata:
        e57.close()
        raise PointFileError(f"Expected pye57 to write the CRS into '{path}', got a "
                             "coordinateMetadata it set otherwise; update tunnelsim or "
                             "write LAS/LAZ.")
    return e57
