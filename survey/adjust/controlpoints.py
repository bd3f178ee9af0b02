"""Control-point files: delimited text tables with a header naming at least the id and
the three coordinates (``id,x,y,z``, ``Name,E,N,H``, ``Punkt;Rechtswert;Hochwert;Höhe``
with decimal commas, ...; ``ALIASES``) or without a header (``id, E, N, H`` in that
order), optionally ``sigma`` (one standard deviation for all three coordinates, m) or
``sx, sy, sz`` and ``time`` (s, when the point was observed in a moving system). The
dialect (encoding, delimiter, decimal mark, header) is sniffed by ``sensors.io.tables``;
``--columns`` maps the columns of any other header. Axis convention: x = Easting,
y = Northing, z = height.

Matching two files by id gives the common points of a Helmert adjustment; ids found in
one file only are left out, silently, with a warning or as an error
(``match(..., unmatched_ids=...)``)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

from raytrace.fileio import atomic_writer
from survey.errors import ControlPointError

if TYPE_CHECKING:
    from sensors.io.tables import Dialect

__all__ = ["ALIASES", "COLUMN_FIELDS", "ControlPoints", "match", "parse_column_option",
           "read_control_points", "unmatched", "unmatched_message"]


@dataclass(repr=False)
class ControlPoints:
    """Named points: ids (n,) str; xyz (n, 3) float64, m (Easting, Northing, height);
    sigma (n, 3) float64 (m) or None; time (n,) float64 (s) or None; dialect: how the
    file was written (``sensors.io.tables.Dialect``) when read from one, else None."""

    ids: list[str]
    xyz: NDArray[np.float64]
    sigma: NDArray[np.float64] | None = None
    time: NDArray[np.float64] | None = None
    dialect: Dialect | None = field(default=None, compare=False)

    def __len__(self) -> int:
        return len(self.ids)

    def __repr__(self) -> str:
        extra = "".join([", sigma" if self.sigma is not None else "",
                         ", time" if self.time is not None else ""])
        first = ", ".join(self.ids[:3]) + (", ..." if len(self.ids) > 3 else "")
        return f"ControlPoints({len(self.ids)} points [{first}]{extra})"

    def write(self, path: str | Path) -> Path:
        """Write the CSV (atomically) that ``read_control_points`` reads back."""
        path = Path(path)
        with atomic_writer(path, "w") as fh:
            cols = ["id", "x", "y", "z"] + (["sx", "sy", "sz"] if self.sigma is not None
                                            else []) + (["time"] if self.time is not None
                                                        else [])
            fh.write(",".join(cols) + "\n")
            for i, name in enumerate(self.ids):
                row = [name] + [f"{v:.6f}" for v in self.xyz[i]]
                if self.sigma is not None:
                    row += [f"{v:.6g}" for v in self.sigma[i]]
                if self.time is not None:
                    row.append(f"{self.time[i]:.9f}")
                fh.write(",".join(row) + "\n")
        return path


#: The header names each field may go by (compared after
#: ``sensors.io.tables.normalise_name``: case, spaces, '_', '-', '.' and a unit in brackets
#: ignored). Axis convention: x = Easting, y = Northing, z = height.
#: DECISION: German "Rechtswert" is the easting and "Hochwert" the northing. German
#: geodesy also calls the easting Y and the northing X (Gauss-Krüger); a header with
#: German names (Punkt, Höhe, ...) and bare X/Y columns is therefore refused as
#: ambiguous (``--columns`` says which is which) instead of guessed.
ALIASES: dict[str, tuple[str, ...]] = {
    "id": ("id", "name", "point", "pointid", "pointname", "punkt", "pkt", "pt", "nr",
           "no", "number", "punktnummer", "punktnr", "pktnr", "pnr"),
    "x": ("x", "e", "easting", "east", "rechtswert", "rw", "ost", "ostwert"),
    "y": ("y", "n", "northing", "north", "hochwert", "hw", "nord", "nordwert"),
    "z": ("z", "h", "height", "elevation", "elev", "höhe", "hoehe", "hohe", "alt",
          "altitude"),
    "sigma": ("sigma", "sd", "std", "stddev", "σ"),
    "sx": ("sx", "sigmax", "se"), "sy": ("sy", "sigmay", "sn"), "sz": ("sz", "sigmaz", "sh"),
    "time": ("time", "t", "timestamp", "zeit")}
#: ``--columns`` fields in their positional order (id, E, N, H, ...): the user's names.
COLUMN_FIELDS = ("id", "e", "n", "h", "sigma")
_FIELD_OF = {"id": "id", "e": "x", "n": "y", "h": "z", "x": "x", "y": "y", "z": "z",
             "sigma": "sigma", "sx": "sx", "sy": "sy", "sz": "sz", "time": "time"}
_GERMAN = {"punkt", "pkt", "punktnummer", "punktnr", "pktnr", "höhe", "hoehe", "hohe",
           "rechtswert", "hochwert", "nr", "pnr"}


def parse_column_option(text: str | None, flag: str = "--columns") -> dict[str, str] | None:
    """A ``--columns`` value as {field: column}, fields "id", "x", "y", "z" (and
    "sigma", "sx", "sy", "sz", "time"); None for None.

    Positional: ``1,3,2,4`` or ``Punkt,Y,X,Höhe`` give the columns of id, E, N, H
    (and sigma) in that order; named: ``id=Punkt,e=Y,n=X,h=Höhe`` (also ``x=``,
    ``y=``, ``z=``, ``sx=`` ... ``time=``). A column is a 1-based number or a header
    name."""
    from sensors.io.errors import TableFileError
    from sensors.io.tables import parse_columns

    if text is None:
        return None
    try:
        raw = parse_columns(text, tuple(_FIELD_OF) if "=" in text else COLUMN_FIELDS,
                            flag=flag)
    except TableFileError as exc:
        raise ControlPointError(str(exc)) from None
    return {_FIELD_OF[k]: v for k, v in raw.items()}


def read_control_points(path: str | Path, *, columns: dict[str, str] | str | None = None,
                        flag: str = "--columns") -> ControlPoints:
    """Read a control-point table in any of the dialects surveyors' software writes.

    Parameters
    ----------
    path : str or Path
        Delimited text (comma, semicolon, tab, '|' or white space; decimal point, or
        decimal comma with a delimiter other than the comma; UTF-8, UTF-16 with BOM,
        Windows-1252 or Latin-1), sniffed by ``sensors.io.tables``. A header names the
        columns (``ALIASES``: ``id,x,y,z``, ``Name,E,N,H``,
        ``Punkt;Rechtswert;Hochwert;Höhe``, optionally ``sigma`` or ``sx,sy,sz`` in
        metres and ``time`` in seconds); a file without a header is ``id, E, N, H`` in
        that order. Axis convention: x = Easting, y = Northing, z = height.
    columns : dict or str, optional
        The column of each field, for headers the aliases do not cover
        (``parse_column_option``; a str is parsed as ``--columns``).
    flag : str
        The option named in messages.

    Returns
    -------
    ControlPoints
        With ``dialect`` (``sensors.io.tables.Dialect``) telling what was read.

    Raises
    ------
    ControlPointError
        A missing file, no consistent delimiter, a field that cannot be mapped or is not
        a number, repeated ids, sigmas not positive. The message names the dialect found
        and the option (``--columns``).
    """
    from sensors.io.tables import map_columns, normalise_name, read_table

    path = Path(path)
    what = "control-point file"
    table = read_table(path, what=what, error=ControlPointError)
    cols = parse_column_option(columns, flag) if isinstance(columns, str) else columns
    if table.names is not None and not cols:
        normed = {normalise_name(n) for n in table.names}
        if normed & _GERMAN and ({"x", "y"} & normed) and not (
                {"rechtswert", "hochwert", "e", "n", "easting", "northing"} & normed):
            raise ControlPointError(
                f"Expected easting and northing columns named unambiguously in '{path}', "
                f"got X/Y in a German header ({', '.join(repr(n) for n in table.names)}): "
                "in German geodesy X is the northing (Hochwert) and Y the easting "
                f"(Rechtswert), the opposite of x = Easting here; pass {flag} id,e,n,h "
                f"naming them (e.g. {flag} id=Punkt,e=Y,n=X,h=Höhe).")
    col = map_columns(table, ALIASES, ("id", "x", "y", "z"), columns=cols,
                      headerless=("id", "x", "y", "z"), what=what, flag=flag,
                      error=ControlPointError, labels={"x": "e", "y": "n", "z": "h"})
    found = table.dialect.describe()
    ids: list[str] = []
    rows_xyz: list[list[float]] = []
    sig: list[list[float]] = []
    tim: list[float] = []
    name_of = (lambda f: repr(table.names[col[f]]) if table.names else
               f"column {col[f] + 1}")
    for r, k in zip(table.rows, table.lines):
        ids.append(r[col["id"]].strip().strip('"'))
        fields = ["x", "y", "z"] + (["sigma"] if "sigma" in col else
                                    ["sx", "sy", "sz"] if "sx" in col else []) + (
            ["time"] if "time" in col else [])
        vals = {}
        for f in fields:
            try:
                vals[f] = table.number(r[col[f]])
            except ValueError:
                axis = {"x": " (easting)", "y": " (northing)", "z": " (height)"}.get(f, "")
                raise ControlPointError(
                    f"Expected a number in {name_of(f)}{axis} on line {k} of '{path}', "
                    f"got {r[col[f]]!r}; found {found}; pass {flag} to map the columns "
                    f"(e.g. {flag} 1,2,3,4 for id,E,N,H).") from None
        rows_xyz.append([vals["x"], vals["y"], vals["z"]])
        if "sigma" in vals:
            sig.append([vals["sigma"]] * 3)
        elif "sx" in vals:
            sig.append([vals["sx"], vals["sy"], vals["sz"]])
        if "time" in vals:
            tim.append(vals["time"])
    if not ids:
        raise ControlPointError(f"Expected control points below the header of '{path}', "
                                f"got none; found {found}.")
    seen = set()
    for i in ids:
        if i in seen:
            raise ControlPointError(f"Expected unique point ids in '{path}', got {i!r} "
                                    "twice.")
        seen.add(i)
    xyz = np.array(rows_xyz, dtype=np.float64).reshape(-1, 3)
    sigma = np.array(sig, dtype=np.float64) if sig else None
    if sigma is not None and (sigma <= 0).any():
        raise ControlPointError(f"Expected positive sigmas in '{path}'.")
    out = ControlPoints(ids, xyz, sigma, np.array(tim) if tim else None)
    out.dialect = table.dialect
    return out


def _some(ids: list[str], k: int = 5) -> str:
    """The first ``k`` ids for a message: "CP01, CP02, ... (12 in all)"."""
    text = ", ".join(ids[:k])
    return text + (f", ... ({len(ids)} in all)" if len(ids) > k else "")


def unmatched(a: ControlPoints, b: ControlPoints) -> tuple[list[str], list[str]]:
    """The ids of ``a`` that ``b`` lacks and the ids of ``b`` that ``a`` lacks, each in
    its file's order."""
    in_a, in_b = set(a.ids), set(b.ids)
    return [k for k in a.ids if k not in in_b], [k for k in b.ids if k not in in_a]


def unmatched_message(a: ControlPoints, b: ControlPoints,
                      names: tuple[str, str] = ("source", "target")) -> str:
    """What ``unmatched`` found, in words, with examples of the ids seen in each file
    (so that "CP5" against "CP05" shows at once); "" when every id is in both."""
    only_a, only_b = unmatched(a, b)
    if not only_a and not only_b:
        return ""
    parts = []
    for (here, there), only in zip((names, names[::-1]), (only_a, only_b)):
        if only:
            parts.append(f"{len(only)} id{'s' if len(only) > 1 else ''} of '{here}' "
                         f"missing from '{there}' ({_some(only, 10)})")
    common = len(a) - len(only_a)
    return (f"{' and '.join(parts)}; {common} in both (ids seen: '{names[0]}' "
            f"{_some(a.ids)}; '{names[1]}' {_some(b.ids)})")


def match(a: ControlPoints, b: ControlPoints, *, require_all: bool = False,
          unmatched_ids: Literal["ignore", "warn", "error"] = "ignore",
          names: tuple[str, str] = ("source", "target")
          ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Indices (ia, ib), each (k,), of the points present in both (by id), in a's order.

    Parameters
    ----------
    a, b : ControlPoints
    require_all : bool
        Every point of ``a`` must have a partner (``b`` may hold more).
    unmatched_ids : "ignore", "warn" or "error"
        What an id found in only one of the two does: nothing, a ``UserWarning`` or a
        ``ControlPointError``; either message names the ids on each side, with examples
        of the ids seen (``unmatched_message``).
    names : (str, str)
        How the messages name ``a`` and ``b`` (file names).

    Raises
    ------
    ControlPointError
        Fewer than 3 common points; a missing partner with ``require_all``; any
        unmatched id with ``unmatched_ids="error"``.
    """
    if unmatched_ids not in ("ignore", "warn", "error"):
        raise ControlPointError(f"Expected unmatched_ids 'ignore', 'warn' or 'error', got "
                                f"{unmatched_ids!r}.")
    pos = {k: i for i, k in enumerate(b.ids)}
    missing = [k for k in a.ids if k not in pos]
    if require_all and missing:
        raise ControlPointError(f"Expected a partner for every source point, got none for "
                                f"{missing[:10]}.")
    ia = [i for i, k in enumerate(a.ids) if k in pos]
    ib = [pos[a.ids[i]] for i in ia]
    if len(ia) < 3:
        raise ControlPointError(f"Expected at least 3 points common to both files (matched "
                                f"by id), got {len(ia)} (ids seen: '{names[0]}' "
                                f"{_some(a.ids)}; '{names[1]}' {_some(b.ids)}).")
    text = unmatched_message(a, b, names) if unmatched_ids != "ignore" else ""
    if text and unmatched_ids == "error":
        raise ControlPointError(f"Expected every control point id in both files (strict "
                                f"matching), got {text}.")
    if text:
        warnings.warn(f"Control point ids not in both files, left out: {text}.",
                      UserWarning, stacklevel=2)
    return np.array(ia), np.array(ib)
