"""Argument checks at the sensors API boundary: numbers, whole numbers and points.

Each failure is the caller's package error (a ``TunnelsimError`` and ``ValueError``)
with the house message "Expected ..., got ...". Points are taken as ``raytrace`` takes
them: an (n, 3) array, one (3,) row, or records with fields x, y, z.
"""

from __future__ import annotations

import math
import numbers

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points as points_and_flag

__all__ = ["as_number", "as_points", "as_whole"]


def as_number(value: object, name: str, error: type[ValueError], *, unit: str,
              lo: float | None = None, hi: float | None = None,
              lo_open: bool = False) -> float:
    """``value`` as a finite float within [lo, hi] (or (lo, hi] with ``lo_open``; either
    end may be None), or ``error`` naming ``name``, the range and the ``unit``."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        v = float(value)
        if math.isfinite(v) and (lo is None or (v > lo if lo_open else v >= lo)) and \
                (hi is None or v <= hi):
            return v
    if lo is not None and hi is not None:
        cond = f" within {'(' if lo_open else '['}{lo:g}, {hi:g}]"
    elif lo is not None:
        cond = f" {'>' if lo_open else '>='} {lo:g}"
    elif hi is not None:
        cond = f" <= {hi:g}"
    else:
        cond = ""
    raise error(f"Expected `{name}` to be a finite number{cond} ({unit}), got {value!r}.")


def as_whole(value: object, name: str, error: type[ValueError], *, lo: int) -> int:
    """``value`` as an int >= ``lo`` (any integer type, not bool or float)."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool) and \
            int(value) >= lo:
        return int(value)
    raise error(f"Expected `{name}` to be a whole number >= {lo}, got {value!r}.")


def as_points(a: ArrayLike, name: str, error: type[ValueError]) -> NDArray[np.float64]:
    """(n, 3) float64 from (n, 3), one (3,) row, or x, y, z records; finite (the rule of
    ``raytrace.checks.as_points``, without its single-point flag)."""
    return points_and_flag(a, name, error)[0]
