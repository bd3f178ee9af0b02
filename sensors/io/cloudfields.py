"""Per-point fields of a cloud file, streamed with the coordinates: what a developed
view or another per-point analysis reads (an M3C2 ``distance``, the ``intensity``,
``iter_field``), and the surface's appearance a mesh takes from the cloud: colour and
temperature (``cloud_appearance``, ``iter_appearance``; issue 35)."""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sensors.io.errors import PointFileError

__all__ = ["COLOUR_NAMES", "LAS_INTENSITY_SCALE", "MIN_KELVIN", "TEMPERATURE_NAMES",
           "CloudAppearance", "ColourEncoding", "cloud_appearance", "iter_appearance",
           "iter_field"]

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


# ------------------------------------------------------------------ appearance
#: Per-point colour property names a cloud file may use, in order of preference: the
#: common ``red green blue`` (LAS, PLY, NPZ) and MeshLab's ``diffuse_*`` (PLY).
COLOUR_NAMES = (("red", "green", "blue"), ("diffuse_red", "diffuse_green", "diffuse_blue"))
#: Per-point temperature field names (kelvin): a LAS/LAZ extra-bytes dimension, a PLY
#: vertex property or an NPZ array; matched case-insensitively.
TEMPERATURE_NAMES = ("temperature", "temperature_k")
#: Below this a ``temperature`` is refused as not kelvin (K). DECISION: no surface a
#: scanner or a thermal camera meets underground is colder than -123 degC, and every
#: value in degrees Celsius of such a surface is below 150, so a value under 150 K is
#: taken for degrees Celsius (or another unit) and refused rather than guessed at.
MIN_KELVIN = 150.0


@dataclass(frozen=True)
class ColourEncoding:
    """How a cloud file stores colour.

    Attributes
    ----------
    names : (str, str, str), the file's red, green and blue field names
    low, high : float, the stored values of 0 and full intensity
    how : str, a description for the summary ("LAS RGB, 16-bit", ...)
    """

    names: tuple[str, str, str]
    low: float
    high: float
    how: str

    def unit(self, raw: NDArray[Any]) -> Floats:
        """Stored values (n, 3) as sRGB-encoded colour in [0, 1] (n, 3) float64."""
        x = (np.asarray(raw, dtype=np.float64) - self.low) / (self.high - self.low)
        return np.clip(x, 0.0, 1.0)


@dataclass(frozen=True)
class CloudAppearance:
    """What a cloud file carries of a surface's appearance (``cloud_appearance``).

    Attributes
    ----------
    path : Path
    colour : ColourEncoding or None, None when the file carries no colour
    temperature : str or None, the name of its temperature field (kelvin)
    """

    path: Path
    colour: ColourEncoding | None
    temperature: str | None


def _colour_names(names: Iterable[str]) -> tuple[str, str, str] | None:
    for trio in COLOUR_NAMES:
        found = [_named(names, k) for k in trio]
        if all(f is not None for f in found):
            return (str(found[0]), str(found[1]), str(found[2]))
    return None


def _temperature_name(names: Iterable[str]) -> str | None:
    names = list(names)
    for k in TEMPERATURE_NAMES:
        found = _named(names, k)
        if found is not None:
            return found
    return None


def _typed_encoding(names: tuple[str, str, str], dtype: np.dtype, peak: float,
                    fmt: str) -> ColourEncoding | None:
    """The encoding of PLY/NPZ colour of ``dtype`` whose largest value is ``peak``;
    None for colour that is 0 everywhere.

    DECISION: ``uchar`` is 0-255 and ``ushort`` 0-65535 (their full range, as PLY
    writers use them); a floating-point colour is 0-1 (Open3D, PCL); another integer
    type is 8-bit when no value exceeds 255, else 16-bit (the rule for LAS)."""
    if peak <= 0:
        return None
    if dtype.kind == "f":
        if peak > 1.0:
            raise PointFileError(f"Expected floating-point colours in [0, 1], got values "
                                 f"up to {peak:g}; store them as uchar 0-255, or pass "
                                 "--no-colour to leave them out.")
        return ColourEncoding(names, 0.0, 1.0, f"{fmt} float colour 0-1")
    if dtype.itemsize == 1 or (dtype != np.uint16 and peak <= 255):
        return ColourEncoding(names, 0.0, 255.0, f"{fmt} 8-bit colour")
    return ColourEncoding(names, 0.0, 65535.0, f"{fmt} 16-bit colour")


def _max_of(arrays: Iterable[NDArray[Any]]) -> float:
    peak = -np.inf
    for a in arrays:
        if len(a):
            peak = max(peak, float(np.nanmax(np.asarray(a, dtype=np.float64))))
    return peak


def cloud_appearance(path: str | os.PathLike[str], *, colour: bool = True,
                     chunk: int = 1 << 20) -> CloudAppearance:
    """Which colour and temperature a cloud file carries, and how its colour is stored.

    - LAS/LAZ: ``red green blue`` (point formats 2, 3, 5, 7, 8, 10), 16-bit by the
      specification (LAS 1.4 R15, table 7: "the Red, Green, Blue values should
      always be normalized to 16 bit values"). DECISION: many writers store 0-255 in
      them, so, as CloudCompare's LAS reader does (it switches to 16-bit at the first
      value above 255), a file whose colour never exceeds 255 is read as 8-bit; this
      takes one pass over the file's colour. A temperature is an extra-bytes dimension
      named as ``TEMPERATURE_NAMES`` (its scale and offset applied; its no-data value
      is no temperature).
    - PLY: vertex properties ``red green blue`` (or ``diffuse_*``): uchar 0-255,
      ushort 0-65535, float 0-1 (see ``_typed_encoding``); ``temperature``.
    - NPZ: arrays ``red green blue`` and ``temperature``, typed as for PLY.
    - E57: ``colorRed colorGreen colorBlue`` with the scan's ``colorLimits``
      (``sensors.io.e57.read_e57_colour``); E57 has no temperature field.
    - Text clouds (XYZ/TXT/CSV): neither (not read).

    DECISION: colour that is 0 (black) at every point is no colour: writers fill the
    fields with zeros when they have none (CloudCompare reads LAS colour so too).

    ``colour`` False: the colour is not looked for (``colour`` None; no pass).

    Raises ``PointFileError`` for an unreadable file, and for floating-point colours
    above 1.
    """
    from sensors.io.cloudread import check_las_scale, cloud_errors, existing_cloud, \
        ply_points

    p = existing_cloud(path)
    kind = p.suffix.lower()
    enc: ColourEncoding | None = None
    temp: str | None = None
    with cloud_errors():
        if kind in (".las", ".laz"):
            from sensors.io.las import LasSource

            with LasSource(p) as src:
                check_las_scale(src.header, p)
                dims = list(src.header.point_format.dimension_names)
                names = _colour_names(dims) if colour else None
                temp = _temperature_name(
                    d.name for d in src.header.point_format.extra_dimensions)
                if names is not None:
                    peak = _max_of(np.asarray(rec[k]) for rec in src.chunks(chunk)
                                   for k in names)
                    if peak > 255:
                        enc = ColourEncoding(names, 0.0, 65535.0, "LAS RGB, 16-bit")
                    elif peak > 0:
                        enc = ColourEncoding(names, 0.0, 255.0,
                                             "LAS RGB, 8-bit values in its 16-bit "
                                             "fields (none above 255)")
        elif kind == ".ply":
            data = ply_points(p)
            fields = data.dtype.names or ()
            names = _colour_names(fields) if colour else None
            temp = _temperature_name(fields)
            if names is not None:
                peak = _max_of(data[k][a:a + chunk] for a in range(0, len(data), chunk)
                               for k in names)
                enc = _typed_encoding(names, data.dtype[names[0]].base, peak, "PLY")
        elif kind == ".npz":
            with np.load(p, allow_pickle=False) as d:
                names = _colour_names(d.files) if colour else None
                temp = _temperature_name(d.files)
                if names is not None:
                    arrays = [np.asarray(d[k]) for k in names]
                    enc = _typed_encoding(names, arrays[0].dtype, _max_of(arrays),
                                          "NPZ")
        elif kind == ".e57" and colour:
            from sensors.io.e57 import E57_COLOUR, read_e57_colour

            peak = _max_of(rgb for _, rgb in read_e57_colour(p) if rgb is not None)
            if peak > 0:
                enc = ColourEncoding(E57_COLOUR, 0.0, 1.0,
                                     "E57 colour, scaled by its colorLimits")
    return CloudAppearance(p, enc, temp)


def _las_no_data(header: Any, name: str) -> float | None:
    """The no-data value of a LAS extra-bytes dimension (its descriptor's ``no_data``
    when option bit 0 is set, LAS 1.4 R15 table 24), as stored (before scale and
    offset), or None. Read from the descriptor VLR: laspy 2.7 does not return it."""
    for v in header.vlrs:
        if v.record_id != 4 or not str(v.user_id).startswith("LASF_Spec"):
            continue
        for st in getattr(v, "extra_bytes_structs", ()):
            if st.format_name() == name and st.options & 1:
                return float(st.no_data[0])
    return None


def iter_appearance(path: str | os.PathLike[str], appearance: CloudAppearance | None
                    = None, *, colour: bool = True, temperature: bool = True,
                    chunk: int = 1 << 20
                    ) -> Iterator[tuple[Floats, Floats | None, Floats | None]]:
    """(xyz (n, 3) float64, colour (n, 3) float64 sRGB-encoded in [0, 1] or None,
    temperature (n,) float64 kelvin or None) of a cloud, chunk by chunk (E57: scan by
    scan), as ``cloud_appearance`` found them (``appearance``, found here when not
    given). ``colour`` / ``temperature`` False leave that out (None). A temperature of
    NaN (or the LAS no-data value) is no temperature for that point (NaN).

    Raises ``PointFileError`` as ``sensors.io.cloudread.iter_points`` does, and for a
    finite temperature below ``MIN_KELVIN``.
    """
    from sensors.io.cloudread import (check_finite, check_las_scale, cloud_errors,
                                         iter_points, las_xyz, no_points, ply_points,
                                         ply_xyz)

    app = cloud_appearance(path, chunk=chunk) if appearance is None else appearance
    p = app.path
    enc = app.colour if colour else None
    tname = app.temperature if temperature else None
    kind = p.suffix.lower()
    n = 0

    def kelvin(t: NDArray[Any]) -> Floats:
        t = np.asarray(t, dtype=np.float64)
        bad = np.isfinite(t) & (t < MIN_KELVIN)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise PointFileError(f"Expected the {tname!r} of '{p}' in kelvin (at least "
                                 f"{MIN_KELVIN:g} K), got {t[i]:g} at point {n + i:,}: "
                                 "degrees Celsius? Store kelvin (K = degC + 273.15), or "
                                 "pass --no-temperature to leave it out.")
        return t

    if enc is None and tname is None:
        for xyz in iter_points(p, chunk=chunk):
            yield xyz, None, None
        return
    with cloud_errors():
        if kind in (".las", ".laz"):
            from sensors.io.las import LasSource

            with LasSource(p) as src:
                check_las_scale(src.header, p)
                nodata = None if tname is None else _las_no_data(src.header, tname)
                for rec in src.chunks(chunk):
                    xyz = las_xyz(rec)
                    check_finite(xyz, p, n)
                    rgb = None if enc is None else enc.unit(
                        np.stack([np.asarray(rec[k]) for k in enc.names], 1))
                    t = None
                    if tname is not None:
                        t = np.asarray(rec[tname], dtype=np.float64)
                        if nodata is not None:
                            t = np.where(np.asarray(rec.array[tname]) == nodata, np.nan, t)
                        t = kelvin(t)
                    n += len(xyz)
                    yield xyz, rgb, t
        elif kind == ".ply":
            data = ply_points(p)
            for a in range(0, len(data), chunk):
                rec = data[a:a + chunk]
                xyz = ply_xyz(rec)
                check_finite(xyz, p, n)
                rgb = None if enc is None else enc.unit(
                    np.stack([rec[k] for k in enc.names], 1))
                t = None if tname is None else kelvin(rec[tname])
                n += len(xyz)
                yield xyz, rgb, t
        elif kind == ".npz":
            with np.load(p, allow_pickle=False) as d:
                cols = [np.asarray(d[k]).reshape(-1) for k in ("x", "y", "z")]
                rgb_all = None if enc is None else enc.unit(
                    np.stack([np.asarray(d[k]).reshape(-1) for k in enc.names], 1))
                t_all = None if tname is None else np.asarray(d[tname]).reshape(-1)
            for a in range(0, len(cols[0]), chunk):
                xyz = np.stack([c[a:a + chunk] for c in cols], 1).astype(np.float64)
                check_finite(xyz, p, n)
                t = None if t_all is None else kelvin(t_all[a:a + chunk])
                n += len(xyz)
                yield xyz, None if rgb_all is None else rgb_all[a:a + chunk], t
        else:                          # .e57 (the only other format with colour)
            from sensors.io.e57 import read_e57_colour

            for xyz, rgb in read_e57_colour(p):
                check_finite(xyz, p, n)
                n += len(xyz)
                if enc is not None and rgb is None:
                    rgb = np.full((len(xyz), 3), np.nan)     # a scan without colour
                yield xyz, rgb, None
    if n == 0:
        raise no_points(p)
