"""ASTM E57 files through pye57 (libE57Format): one structured TLS scan written, every
scan of a file read.

libE57Format checks a CRC-32C per 1 KiB page, so a cut or altered file is refused as a
whole; its exceptions carry several lines of debug context. The reader turns them into
one ``PointFileError`` line naming the file. A scan with no points (which libE57Format
cannot read) is skipped; a file without any point is the caller's to refuse.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .errors import PointFileError

__all__ = ["E57_MAX_POINTS", "read_e57", "write_e57_scan"]

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


def read_e57(path: str | os.PathLike[str]) -> Iterator[np.ndarray]:
    """World coordinates (n, 3) float64 of each scan of an E57 file (scan pose applied,
    invalid points dropped), one scan at a time.

    Raises ``PointFileError`` for a missing, empty, corrupt (bad checksum, bad header)
    or unreadable file, and for a scan larger than ``E57_MAX_POINTS``.
    """
    path = Path(path)
    if not path.is_file():
        raise PointFileError(f"Expected an E57 file, got '{path}' which does not exist.")
    if path.stat().st_size == 0:
        raise PointFileError(f"Expected an E57 file, got '{path}' which is empty (0 bytes).")
    pye57 = _pye57()
    try:
        e57 = pye57.E57(str(path))
        count = e57.scan_count
    except Exception as exc:   # libE57Format raises E57Exception; pye57 others
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
            try:
                d = e57.read_scan(i, ignore_missing_fields=True)
            except Exception as exc:
                raise PointFileError(f"Expected the {n:,} points of scan {i} of '{path}', "
                                     f"got an error reading them: {_first_line(exc)}; the "
                                     "file is corrupt.") from exc
            yield np.stack([d["cartesianX"], d["cartesianY"], d["cartesianZ"]],
                           1).astype(np.float64)
    finally:
        with contextlib.suppress(Exception):
            e57.close()


def write_e57_scan(path: str | os.PathLike[str], local_xyz: np.ndarray, *,
                   rotation_xyzw: np.ndarray, translation: np.ndarray, name: str,
                   intensity: np.ndarray | None = None, row: np.ndarray | None = None,
                   column: np.ndarray | None = None) -> Path:
    """Write one structured scan: sensor-frame Cartesian coordinates ``local_xyz``
    (n, 3), the pose (quaternion x, y, z, w and translation (3,), sensor to world),
    optional ``intensity`` (n,) and ``row``/``column`` indices (n,). Written beside the
    target and renamed when complete (pye57 writes to a path, not a stream)."""
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
    if row is not None and column is not None:
        data["rowIndex"] = np.asarray(row, dtype=np.int32)
        data["columnIndex"] = np.asarray(column, dtype=np.int32)
    q = np.asarray(rotation_xyzw, dtype=np.float64)
    tmp = path.with_name("." + path.name + ".part")
    try:
        e57 = pye57.E57(str(tmp), mode="w")
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
