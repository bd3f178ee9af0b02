"""Control-point files: CSV with a header naming at least ``id, x, y, z`` and optionally
``sigma`` (one standard deviation for all three coordinates, m) or ``sx, sy, sz`` and
``time`` (s, when the point was observed in a moving system). Matching two files by id
gives the common points of a Helmert adjustment; ids found in one file only are left
out, silently, with a warning or as an error (``match(..., unmatched_ids=...)``)."""

from __future__ import annotations

import csv
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from raytrace.fileio import atomic_writer
from survey.errors import ControlPointError

__all__ = ["ControlPoints", "match", "read_control_points", "unmatched", "unmatched_message"]


@dataclass(repr=False)
class ControlPoints:
    """Named points: ids (n,) str; xyz (n, 3) float64, m; sigma (n, 3) float64 (m) or
    None; time (n,) float64 (s) or None."""

    ids: list[str]
    xyz: NDArray[np.float64]
    sigma: NDArray[np.float64] | None = None
    time: NDArray[np.float64] | None = None

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


def read_control_points(path: str | Path) -> ControlPoints:
    """Read a control-point CSV (see the module doc)."""
    path = Path(path)
    if not path.is_file():
        raise ControlPointError(f"Expected a control-point CSV, got '{path}' which does not "
                                "exist.")
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(line for line in fh if line.strip() and
                                   not line.lstrip().startswith("#")))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ControlPointError(f"Expected a UTF-8 text CSV in '{path}', got a file that "
                                f"does not decode ({exc}); save it as CSV text.") from None
    if not rows:
        raise ControlPointError(f"Expected a header 'id,x,y,z[,sigma|sx,sy,sz][,time]' in "
                                f"'{path}', got an empty file.")
    head = [h.strip().lower() for h in rows[0]]
    for need in ("id", "x", "y", "z"):
        if need not in head:
            raise ControlPointError(f"Expected a column '{need}' in '{path}', got columns "
                                    f"{head}.")
    col = {h: i for i, h in enumerate(head)}
    ids: list[str] = []
    rows_xyz: list[list[float]] = []
    sig: list[list[float]] = []
    tim: list[float] = []
    for k, r in enumerate(rows[1:], start=2):
        try:
            ids.append(r[col["id"]].strip())
            rows_xyz.append([float(r[col[c]]) for c in "xyz"])
            if "sigma" in col:
                sig.append([float(r[col["sigma"]])] * 3)
            elif "sx" in col:
                sig.append([float(r[col[c]]) for c in ("sx", "sy", "sz")])
            if "time" in col:
                tim.append(float(r[col["time"]]))
        except (IndexError, ValueError) as exc:
            raise ControlPointError(f"Expected numbers in every column of line {k} of "
                                    f"'{path}', got {r!r}.") from exc
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
    return ControlPoints(ids, xyz, sigma, np.array(tim) if tim else None)


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
