"""Per-point fields of a cloud file, streamed with the coordinates: what a developed
view or another per-point analysis reads (an M3C2 ``distance``, the ``intensity``)."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sensors.io.errors import PointFileError

__all__ = ["LAS_INTENSITY_SCALE", "iter_field"]

Floats = NDArray[np.float64]

#: LAS stores intensity as uint16; divided by this it is a fraction in [0, 1], as the
#: PLY and NPZ files of ``sensors.io.fields`` store it.
LAS_INTENSITY_SCALE = 65535.0


def _named(names: Iterable[str], field: str) -> str | None:
    """The column of ``names`` that holds ``field`` (case-insensitive)."""
    low = {n.lower(): n for n in names}
    return low.get(field.lower())


def iter_field(path: str | os.PathLike[str], field: str, *, chunk: int = 1 << 20
               ) -> Iterator[tuple[Floats, Floats]]:
    """(xyz (m, 3) float64, values (m,) float64) of a cloud's per-point ``field``,
    chunk by chunk: LAS/LAZ (a standard dimension or extra bytes; ``intensity`` divided
    by 65535 into [0, 1]), PLY (a vertex property), NPZ (an array) and CSV/TXT/XYZ with a
    header line naming x, y, z and the field.

    Raises ``PointFileError`` for a missing file, an unknown format (E57) or a file
    without that field (naming the fields it has)."""
    from sensors.io.cloudread import (check_finite, check_las_scale, cloud_errors,
                                         existing_cloud, las_xyz, ply_points, ply_xyz)

    p = existing_cloud(path)
    kind = p.suffix.lower()
    n = 0

    def missing(have: Iterable[str]) -> PointFileError:
        return PointFileError(f"Expected a per-point field {field!r} in '{p}', got "
                              f"{sorted(have)}; choose one of them.")

    with cloud_errors():
        if kind in (".las", ".laz"):
            from sensors.io.las import LasSource

            with LasSource(p) as src:
                check_las_scale(src.header, p)
                dims = list(src.header.point_format.dimension_names)
                name = _named(dims, field)
                if name is None:
                    raise missing(dims)
                scale = LAS_INTENSITY_SCALE if name == "intensity" else 1.0
                for rec in src.chunks(chunk):
                    xyz = las_xyz(rec)
                    check_finite(xyz, p, n)
                    n += len(xyz)
                    yield xyz, np.asarray(rec[name], dtype=np.float64) / scale
        elif kind == ".ply":
            data = ply_points(p)
            name = _named(data.dtype.names or (), field)
            if name is None:
                raise missing(data.dtype.names or ())
            for a in range(0, len(data), chunk):
                rec = data[a:a + chunk]
                xyz = ply_xyz(rec)
                check_finite(xyz, p, n)
                n += len(xyz)
                yield xyz, np.asarray(rec[name], dtype=np.float64)
        elif kind == ".npz":
            with np.load(p, allow_pickle=False) as d:
                name = _named(d.files, field)
                if name is None or not {"x", "y", "z"} <= set(d.files):
                    raise missing(d.files)
                cols = [np.asarray(d[k]).reshape(-1) for k in ("x", "y", "z", name)]
            for a in range(0, len(cols[0]), chunk):
                xyz = np.stack([c[a:a + chunk] for c in cols[:3]], 1).astype(np.float64)
                check_finite(xyz, p, n)
                n += len(xyz)
                yield xyz, cols[3][a:a + chunk].astype(np.float64)
        elif kind in (".csv", ".txt", ".xyz"):
            yield from _text_field(p, field, chunk)
        else:
            raise PointFileError(f"Expected a LAS/LAZ, PLY, NPZ or CSV/TXT cloud for the "
                                 f"field {field!r}, got '{p}'.")


def _text_field(p: Path, field: str, chunk: int) -> Iterator[tuple[Floats, Floats]]:
    delim = "," if p.suffix.lower() == ".csv" else None
    with open(p, errors="replace") as fh:
        head = ""
        while not head:
            line = fh.readline()
            if not line:
                raise PointFileError(f"Expected a header line naming x, y, z and "
                                     f"{field!r} in '{p}', got an empty file.")
            head = line.strip() if not line.lstrip().startswith("#") else ""
        words = [w.strip().lstrip("/").strip()
                 for w in (head.split(delim) if delim else head.split())]
        cols = [_named(words, k) for k in ("x", "y", "z", field)]
        if any(c is None for c in cols):
            raise PointFileError(f"Expected a header line naming x, y, z and {field!r} in "
                                 f"'{p}', got {words[:12]}.")
        use = [words.index(str(c)) for c in cols]
        while True:
            try:
                a = np.loadtxt(fh, delimiter=delim, max_rows=chunk, ndmin=2, usecols=use,
                               comments="#")
            except (ValueError, IndexError) as exc:
                raise PointFileError(f"Expected numeric columns in '{p}', got unreadable "
                                     f"text ({exc}).") from exc
            if len(a) == 0:
                break
            yield a[:, :3].astype(np.float64), a[:, 3].astype(np.float64)
