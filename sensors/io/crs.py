"""Coordinate reference systems (CRS) of the files tunnelsim makes and reads.

A CRS is given as ``EPSG:n`` (any ``AUTHORITY:CODE`` PROJ knows: ``EPSG:2056``,
``ESRI:102100``, ``EPSG:2056+5728`` for a projected + vertical compound), as OGC WKT
(WKT1 or WKT2) or as PROJJSON; ``parse_crs`` turns each into a ``pyproj.CRS``. pyproj is
an optional extra (``pip install 'tunnelsim[crs]'``), imported only where a CRS is
given or found in a file: files without one never need it.

Where each format keeps it:

- **LAS/LAZ 1.4** (``sensors.io.las``): the OGC Coordinate System WKT VLR (user
  ``LASF_Projection``, record 2112) and the global-encoding WKT bit, as LAS 1.4 R15
  asks for point formats 6-10; ``laspy``'s ``header.parse_crs()`` reads it.
- **E57** (``sensors.io.e57``): the root's ``coordinateMetadata`` string (WKT).
- **PLY, NPZ and text clouds**, which have no place for it: a sidecar beside the file,
  ``<file>.prj`` (``scan.ply.prj``) holding the WKT. Text clouds and control-point CSVs
  may instead state it in a leading comment line, ``# crs: EPSG:2056``.
- **Tunnel JSON** (``survey.world.mesh``): ``crs`` (WKT2) and ``crs_name``.

The WKT written into files (``file_wkt``) is WKT1 (OGC 12-063r5, GDAL's flavour: what
LAS 1.4 names and what LAStools, PDAL and CloudCompare read) when the CRS survives the
round trip through it (``pyproj.CRS.equals``), else WKT2:2019 (OGC 18-010r7). Two CRSs
are the same when PROJ finds them equivalent (``same_crs``): EPSG:2056 and the WKT1 of
it are; EPSG:2056 and EPSG:2056+5728 are not.

tunnelsim's coordinates are metres, so a CRS given for them must have metre axes
(``parse_crs(..., metric=True)``): a geographic CRS (degrees) or one in US survey feet
is refused.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from raytrace.errors import TunnelsimError
from raytrace.fileio import atomic_writer

__all__ = ["AREA_MARGIN_DEG", "CRSError", "CRS_FORMS", "SIDECAR_SUFFIX", "area_warning",
           "comment_crs", "crs_comment", "crs_label", "crs_mismatch", "crs_wkt", "file_wkt",
           "mismatch_message", "parse_crs", "read_sidecar", "same_crs", "sidecar_path",
           "text_file_crs", "write_sidecar"]

#: How a CRS may be written, for messages.
CRS_FORMS = "EPSG:n (or another AUTHORITY:CODE), WKT or PROJJSON"
#: Suffix appended to a PLY/NPZ/text cloud's name for its CRS sidecar (WKT).
SIDECAR_SUFFIX = ".prj"
#: A position this far (degrees) outside a CRS's area of use is reported (ASSUMED: half
#: a degree, ~50 km, lets a site near a border pass and catches a forgotten origin).
AREA_MARGIN_DEG = 0.5
#: Leading comment lines searched for ``# crs: ...`` in text files.
COMMENT_LINES = 64

_AUTH_CODE = re.compile(r"^(urn:ogc:def:crs:)?[A-Za-z][\w.-]*:{1,2}[\w.+:-]+$")
_WKT_START = re.compile(r"^[A-Za-z][A-Za-z0-9_]*\s*\[")
_COMMENT = re.compile(r"^\s*#\s*crs\s*[:=]\s*(.+?)\s*$", re.IGNORECASE)


class CRSError(TunnelsimError, ValueError):
    """A coordinate reference system is malformed, unknown, not in metres, or differs
    from another input's."""


def _pyproj() -> Any:
    try:
        import pyproj
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise CRSError("Expected the optional package pyproj to handle a coordinate "
                       "reference system; install it with: pip install "
                       "'tunnelsim[crs]' (or pip install pyproj).") from exc
    return pyproj


def _short(text: str, n: int = 60) -> str:
    text = " ".join(str(text).split())
    return repr(text if len(text) <= n else text[:n - 3] + "...")


def parse_crs(value: Any, *, metric: bool = True, what: str = "CRS") -> Any:
    """A ``pyproj.CRS`` from ``value``: a string (``EPSG:n`` or another
    ``AUTHORITY:CODE``, WKT1/WKT2, PROJJSON text), a PROJJSON dict or a ``pyproj.CRS``.

    With ``metric`` (default), every axis must be in metres (projected, geocentric,
    engineering, or projected + vertical), as tunnelsim's coordinates are. ``what``
    names the value in messages (e.g. "--crs").

    Raises
    ------
    CRSError
        For an empty or unrecognised string (a bare number, a name, a PROJ string),
        one PROJ does not know or cannot parse, a CRS not in metres (with
        ``metric``), and when pyproj is not installed.
    """
    pyproj = _pyproj()
    if isinstance(value, pyproj.CRS):
        crs = value
    else:
        crs = _from_value(pyproj, value, what)
    if metric:
        _check_metric(crs, what)
    return crs


def _from_value(pyproj: Any, value: Any, what: str) -> Any:
    try:
        if isinstance(value, dict):
            return pyproj.CRS.from_json_dict(value)
        if not isinstance(value, str):
            raise CRSError(f"Expected {what} as a string ({CRS_FORMS}), got "
                           f"{type(value).__name__}.")
        text = value.strip()
        if not text:
            raise CRSError(f"Expected {what} as {CRS_FORMS}, got an empty string.")
        if text.isdigit():
            raise CRSError(f"Expected {what} as {CRS_FORMS}, got the bare number "
                           f"{text!r}; write EPSG:{text} if that is meant.")
        if text.startswith("{"):
            return pyproj.CRS.from_json(text)
        if _WKT_START.match(text):
            return pyproj.CRS.from_wkt(text)
        if _AUTH_CODE.match(text):
            return pyproj.CRS.from_user_input(text)
    except pyproj.exceptions.CRSError as exc:
        why = " ".join(str(exc).split())
        raise CRSError(f"Expected {what} as {CRS_FORMS} that PROJ knows, got "
                       f"{_short(text if isinstance(value, str) else value)}, which it "
                       f"refuses ({why[:160]}).") from None
    raise CRSError(f"Expected {what} as {CRS_FORMS}, got {_short(text)}; names and PROJ "
                   "strings are ambiguous: give the EPSG code (e.g. EPSG:2056) or WKT.")


def _check_metric(crs: Any, what: str) -> None:
    axes = crs.axis_info or (crs.source_crs.axis_info if crs.source_crs else [])
    units = [a.unit_name for a in axes]
    ok = bool(axes) and all(a.unit_name in ("metre", "meter") and
                            math.isclose(a.unit_conversion_factor, 1.0) for a in axes)
    if not ok:
        raise CRSError(f"Expected {what} with axes in metres (projected, geocentric, or "
                       f"projected + vertical: tunnelsim's coordinates are metres), got "
                       f"{crs_label(crs)} ({crs.type_name}; {', '.join(units) or 'no axes'}"
                       "); choose its metric counterpart (e.g. a UTM zone for WGS 84).")


def crs_label(crs: Any) -> str:
    """A short name for messages: ``EPSG:2056 (CH1903+ / LV95)``; a compound without a
    code of its own names its parts' (``EPSG:2056+5728 (...)``); a CRS without any
    code, its name."""
    auth = crs.to_authority(min_confidence=90)
    code = ":".join(auth) if auth else None
    if code is None and crs.is_compound:
        parts = [c.to_authority(min_confidence=90) for c in crs.sub_crs_list]
        if parts and all(parts):
            code = parts[0][0] + ":" + "+".join(p[1] for p in parts)
    return f"{code} ({crs.name})" if code else repr(crs.name)


def crs_wkt(crs: Any) -> str:
    """WKT2:2019 of a CRS (``parse_crs``'s inputs), on one line: the normal form kept in
    tunnel JSON files."""
    c = parse_crs(crs, metric=False)
    return str(c.to_wkt("WKT2_2019"))


def file_wkt(crs: Any) -> str:
    """The WKT written into a file: WKT1 (GDAL flavour) when the CRS survives the round
    trip through it, else WKT2:2019 (see the module notes)."""
    pyproj = _pyproj()
    c = parse_crs(crs, metric=False)
    # DECISION: WKT1 first. LAS 1.4 names WKT1 (OGC 12-063r5; LAS 1.5 notes it), and
    # LAStools and older PDAL/CloudCompare builds read only WKT1; WKT2 where WKT1 would
    # lose something (PROJ's equivalence decides).
    try:
        w1 = c.to_wkt("WKT1_GDAL")
        if w1 and pyproj.CRS.from_wkt(w1).equals(c):
            return str(w1)
    except pyproj.exceptions.CRSError:
        pass
    return str(c.to_wkt("WKT2_2019"))


def same_crs(a: Any, b: Any) -> bool:
    """Whether two CRSs (strings as ``parse_crs`` takes, PROJJSON dicts or
    ``pyproj.CRS``) are equivalent for PROJ (``pyproj.CRS.equals``). Identical strings
    are the same without pyproj."""
    if isinstance(a, str) and isinstance(b, str) and " ".join(a.split()) == \
            " ".join(b.split()):
        return True
    ca, cb = parse_crs(a, metric=False), parse_crs(b, metric=False)
    return bool(ca.equals(cb))


def crs_mismatch(named: Iterable[tuple[str, Any]]
                 ) -> tuple[tuple[str, Any], tuple[str, Any]] | None:
    """The first two inputs (name, crs) whose CRSs differ, or None. Inputs without a
    CRS (None) are left out: a file that states none cannot be said to differ."""
    known = [(n, c) for n, c in named if c is not None]
    for name, crs in known[1:]:
        if not same_crs(known[0][1], crs):
            return known[0], (name, crs)
    return None


def mismatch_message(a: tuple[str, Any], b: tuple[str, Any], *, what: str = "inputs",
                     hint: str = "") -> str:
    """"Expected the inputs in one coordinate reference system, got 'a' in EPSG:2056 (...)
    and 'b' in EPSG:32632 (...)[; hint]." for a ``crs_mismatch`` pair."""
    la, lb = (crs_label(parse_crs(c, metric=False)) for _, c in (a, b))
    extra = ""
    if la == lb:   # same label, different definitions (a hand-edited WKT?)
        extra = " (the same name, different definitions)"
    return (f"Expected the {what} in one coordinate reference system, got '{a[0]}' in "
            f"{la} and '{b[0]}' in {lb}{extra}" + (f"; {hint}" if hint else "") + ".")


# ------------------------------------------------------------------------- sidecars
def sidecar_path(path: str | os.PathLike[str]) -> Path:
    """The CRS sidecar of a file: its full name plus ``.prj`` (``scan.ply.prj``).

    DECISION: appended, not a replaced suffix (GIS's ``scan.prj``): ``scan.ply`` and
    ``scan.npz`` of one run may lie side by side in different CRSs, and the name says
    which file it belongs to (as GDAL's ``.aux.xml``)."""
    p = Path(path)
    return p.with_name(p.name + SIDECAR_SUFFIX)


def write_sidecar(path: str | os.PathLike[str], crs: Any) -> Path | None:
    """Write the CRS sidecar of ``path`` (``file_wkt``), atomically; with ``crs`` None,
    remove a sidecar left from an earlier file of that name (it would state a CRS the
    new file does not have). Returns the sidecar's path, or None."""
    side = sidecar_path(path)
    if crs is None:
        side.unlink(missing_ok=True)
        return None
    text = crs if isinstance(crs, str) and _WKT_START.match(crs.strip()) else file_wkt(crs)
    with atomic_writer(side, "w") as fh:
        fh.write(text.strip() + "\n")
    return side


def read_sidecar(path: str | os.PathLike[str]) -> str | None:
    """The CRS text of ``path``'s sidecar (not parsed: no pyproj needed), or None when
    there is none or it is empty."""
    side = sidecar_path(path)
    if not side.is_file():
        return None
    try:
        text = side.read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise CRSError(f"Expected WKT text in the CRS sidecar '{side}', got an unreadable "
                       f"file ({exc}); rewrite or remove it.") from None
    return text or None


def comment_crs(path: str | os.PathLike[str]) -> str | None:
    """The CRS a text file states in a leading comment line ``# crs: VALUE`` (VALUE as
    ``parse_crs`` takes it, on one line), searched among the comment and blank lines
    before its first data line; None when it states none. Not parsed."""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            for i, line in enumerate(fh):
                if i >= COMMENT_LINES:
                    break
                text = line.strip()
                if not text:
                    continue
                if not text.startswith("#"):
                    break
                m = _COMMENT.match(text)
                if m:
                    return m.group(1)
    except OSError:
        return None
    return None


def crs_comment(crs: Any) -> str:
    """The comment line that states ``crs`` in a text file (``comment_crs`` reads it):
    ``# crs: EPSG:2056`` where an authority code is the same CRS, else the WKT on one
    line."""
    c = parse_crs(crs, metric=False)
    auth = c.to_authority(min_confidence=100)
    if auth:
        code = ":".join(auth)
        if parse_crs(code, metric=False).equals(c):
            return f"# crs: {code}"
    return "# crs: " + " ".join(file_wkt(c).split())


def text_file_crs(path: str | os.PathLike[str]) -> str | None:
    """The CRS a text file (control-point CSV, XYZ cloud) states: its ``# crs:`` comment
    line, else its sidecar ``<file>.prj``; None when neither. Not parsed."""
    return comment_crs(path) or read_sidecar(path)


# ------------------------------------------------------------------------- area of use
def area_warning(crs: Any, xyz: ArrayLike, *, what: str = "a point",
                 hint: str = "local coordinates, or easting and northing swapped?"
                 ) -> str | None:
    """A sentence when points ``xyz`` (n, 3) (or (3,)) of a projected CRS fall outside
    its area of use by more than ``AREA_MARGIN_DEG``, else None (also for CRSs without
    a projection or an area). The usual cause (``hint`` ends the sentence): local
    coordinates given a CRS (a forgotten ``--origin``), or easting and northing
    swapped."""
    pyproj = _pyproj()
    c = parse_crs(crs, metric=False)
    horiz = next((s for s in (c.sub_crs_list or [c]) if s.is_projected), None)
    area = c.area_of_use or (horiz.area_of_use if horiz is not None else None)
    if horiz is None or area is None:
        return None
    p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    tr = pyproj.Transformer.from_crs(horiz, horiz.geodetic_crs, always_xy=True)
    lon, lat = tr.transform(p[:, 0], p[:, 1], errcheck=False)
    lon, lat = np.atleast_1d(lon), np.atleast_1d(lat)
    m = AREA_MARGIN_DEG
    inside = np.isfinite(lon) & np.isfinite(lat) & \
        (lon >= area.west - m) & (lon <= area.east + m) & \
        (lat >= area.south - m) & (lat <= area.north + m)
    if inside.all():
        return None
    i = int(np.flatnonzero(~inside)[0])
    where = (f"at {lon[i]:.3f} E, {lat[i]:.3f} N" if np.isfinite(lon[i]) and
             np.isfinite(lat[i]) else "where the projection is undefined")
    return (f"{what} at ({', '.join(f'{v:.3f}' for v in p[i])}) is outside the area of "
            f"use of {crs_label(c)} ({area.name.rstrip('.')}: {area.west:g} to "
            f"{area.east:g} E, "
            f"{area.south:g} to {area.north:g} N), {where}: {hint}")

