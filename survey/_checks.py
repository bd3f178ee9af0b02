"""Point arguments at the survey API boundary: one rule for every function that takes
points.

Accepted, wherever points are taken:

- an ``(n, 3)`` array-like of numbers (any numeric dtype; converted to float64, without
  a copy when it already is one);
- a single point ``(3,)``;
- a structured array with fields ``x``, ``y``, ``z`` (a point record as
  ``sensors.POINT_DTYPE``, a PLY vertex element), shape ``(n,)`` or ``()``.

Results, by one rule:

- a function that *maps* points to points keeps the caller's shape: ``(3,)`` in,
  ``(3,)`` out (``HelmertResult.apply``, ``DriftCorrection.apply``);
- a function that *measures* points returns one value per point, so a single point gives
  ``(1,)``-shaped results (``cloud_to_mesh``, ``cloud_to_cloud``, ``Alignment.to_local``,
  the outlier masks), as ``raytrace.Scene.cast`` does for one ray.

Every refusal is the caller's package error (a ``TunnelsimError`` and ``ValueError``)
with the house message "Expected ..., got ...; ...".
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["as_points"]


def _shape(a: Any) -> str:
    """The shape of ``a`` as messages write it: "(5, 2)"."""
    return str(tuple(np.shape(a)))


def _xyz_fields(a: Any, name: str, error: type[ValueError]) -> NDArray[np.float64] | None:
    """(…, 3) float64 from a structured array with x, y, z fields; None if not one."""
    names = getattr(getattr(a, "dtype", None), "names", None)
    if not names:
        return None
    if not {"x", "y", "z"} <= set(names):
        raise error(f"Expected `{name}` with fields x, y, z, got a structured array with "
                    f"fields {', '.join(names)}; pass an (n, 3) array of coordinates.")
    rec = np.asarray(a)
    return np.stack([rec["x"], rec["y"], rec["z"]], axis=-1).astype(np.float64, copy=False)


def as_points(a: ArrayLike, name: str, error: type[ValueError], *, finite: bool = True,
              min_points: int = 0) -> tuple[NDArray[np.float64], bool]:
    """``a`` as (n, 3) float64 coordinates, and whether it was a single (3,) point.

    Parameters
    ----------
    a : (n, 3) or (3,) array_like of float, or structured array with x, y, z
    name : the argument's name, for messages
    error : the package error class to raise
    finite : refuse NaN and inf coordinates
    min_points : refuse fewer points than this
    """
    p = _xyz_fields(a, name, error)
    if p is None:
        try:
            p = np.asarray(a, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise error(f"Expected `{name}` as numbers of shape (n, 3), got "
                        f"{type(a).__name__} that NumPy cannot convert to float64 ({exc}); "
                        "pass an array of coordinates.") from None
    single = p.shape == (3,)
    if single:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 3:
        raise error(f"Expected `{name}` to have shape (n, 3) or (3,), got {_shape(p)}; "
                    "pass one row of x, y, z per point.")
    if len(p) < min_points:
        raise error(f"Expected at least {min_points} point(s) in `{name}`, got {len(p)}.")
    if finite and not np.isfinite(p).all():
        bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
        raise error(f"Expected finite coordinates in `{name}`, got NaN or inf in "
                    f"{len(bad)} point(s) (first at row {int(bad[0])}); drop those points "
                    "first.")
    return p, single

