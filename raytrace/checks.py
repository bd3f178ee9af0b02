"""Validation at the public boundary: meshes, rays and their [t_min, t_max] limits for
``Scene`` (coerced with ``np.asarray`` and checked here, once, before any kernel runs),
and ``as_points``, the one rule for point arguments that ``sensors`` and ``survey`` use too.

Every failure is a ``MeshError`` or ``RayError`` (both ``ValueError``) whose message
says what was expected, what was got and what to do.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._kernels.rays import (UNIT_TOL, count_bad_directions, count_nonfinite,
                           count_not_unit, rows_unlike_first, shift_origins,
                           unit_directions)
from .errors import MeshError, RayError

__all__ = ["as_points", "as_xyz", "first_rows", "positive", "prepare_cast", "prepare_rays",
           "shape_text", "validate_mesh"]


def shape_text(a: Any) -> str:
    """The shape of ``a`` as written in messages: "(5, 2)"."""
    return str(tuple(np.shape(a)))


def first_rows(idx: ArrayLike, k: int = 10) -> str:
    """The first ``k`` indices of ``idx`` for a message: "1, 4, 7, ... (12 in all)"."""
    flat = np.asarray(idx).ravel()
    s = ", ".join(str(int(i)) for i in flat[:k])
    return s + (f", ... ({flat.size} in all)" if flat.size > k else "")


def positive(value: Any, name: str, error: type[ValueError], *, zero: bool = False,
             what: str = "a number of metres") -> float:
    """``value`` as a float that is finite and > 0 (>= 0 with ``zero``), else ``error``
    naming the argument ``name`` (``what`` says the kind: "a number of metres")."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise error(f"Expected `{name}` as {what}, got {value!r}.") from None
    if not (np.isfinite(v) and (v >= 0 if zero else v > 0)):
        raise error(f"Expected a {'non-negative' if zero else 'positive'} finite "
                    f"`{name}`, got {value!r}.")
    return v


def as_xyz(a: ArrayLike, name: str, error: type[ValueError]) -> NDArray[np.float64]:
    """``a`` as float64 coordinates: any numeric array, or a structured array with fields
    ``x``, ``y``, ``z`` (a point cloud record, a PLY vertex element), which becomes
    (n, 3). No copy when ``a`` is already float64. Shapes are checked by the caller."""
    names = getattr(getattr(a, "dtype", None), "names", None)
    if names:
        if not {"x", "y", "z"} <= set(names):
            raise error(f"Expected `{name}` as numbers or a structured array with fields "
                        f"x, y, z, got fields {', '.join(names)}; pass an (n, 3) array.")
        rec = np.asarray(a)
        return np.stack([rec["x"], rec["y"], rec["z"]], axis=-1).astype(np.float64)
    try:
        return np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise error(f"Expected `{name}` as numbers, got {type(a).__name__} that NumPy "
                    f"cannot convert to float64 ({exc}); pass an array of numbers.") from None


def as_points(a: ArrayLike, name: str, error: type[ValueError], *, finite: bool = True,
              min_points: int = 0) -> tuple[NDArray[np.float64], bool]:
    """``a`` as (n, 3) float64 coordinates, and whether it was a single (3,) point: the
    one rule for every public function of the three packages that takes points.
    Results follow one rule too: a function that *maps* points keeps the caller's shape
    ((3,) in, (3,) out: ``HelmertResult.apply``); one that *measures* points returns one
    value per point, so a single point gives (1,)-shaped results (``cloud_to_mesh``,
    ``Scene.cast``).

    Accepts an (n, 3) array-like of numbers, a single (3,) point, or a structured array
    with fields x, y, z (``sensors.POINT_DTYPE``, a PLY vertex element). ``finite``
    refuses NaN and inf; ``min_points`` refuses fewer points. Errors are ``error``.
    """
    p = as_xyz(a, name, error)
    single = p.shape == (3,)
    if single:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 3:
        raise error(f"Expected `{name}` to have shape (n, 3) or (3,), got {shape_text(p)}; "
                    "pass one row of x, y, z per point.")
    if len(p) < min_points:
        raise error(f"Expected at least {min_points} point(s) in `{name}`, got {len(p)}.")
    if finite:
        bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
        if bad.size:
            raise error(f"Expected finite coordinates in `{name}`, got NaN or inf in "
                        f"{bad.size} point(s) (first at row {int(bad[0])}); drop those "
                        "points first.")
    return p, single


def validate_mesh(vertices: ArrayLike, faces: ArrayLike
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """``vertices`` (n, 3) float64 and ``faces`` (m, 3) int64, checked: non-empty,
    finite, integral indices within range. No copy when they already have those dtypes.

    Raises
    ------
    MeshError
    """
    v = as_xyz(vertices, "vertices", MeshError)
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"Expected `vertices` to have shape (n, 3), got {shape_text(v)}; "
                        "pass one row of x, y, z per vertex.")
    if v.shape[0] == 0:
        raise MeshError("Expected at least 3 `vertices`, got an empty array; the mesh is "
                        "empty.")
    # DECISION: whole-array checks first, the per-row reductions that name the bad rows
    # only on failure (bfo: 40-47 ms of every build -> 8-12 ms, ENGINE5).
    bad = np.empty(0, dtype=np.intp) if np.isfinite(v).all() else \
        np.flatnonzero(~np.isfinite(v).all(axis=1))
    if bad.size:
        raise MeshError(f"Expected finite `vertices`, got NaN/inf at vertex index(es) "
                        f"{first_rows(bad)}; remove or repair them.")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3:
        raise MeshError(f"Expected `faces` to have shape (m, 3), got {shape_text(f)}; only "
                        "triangles are supported (triangulate polygons first).")
    if f.shape[0] == 0:
        raise MeshError("Expected at least one face, got an empty `faces` array; the mesh "
                        "is empty.")
    if not np.issubdtype(f.dtype, np.integer):
        if np.issubdtype(f.dtype, np.floating) and np.isfinite(f).all() and \
                (f == np.round(f)).all():
            f = f.astype(np.int64)
        else:
            raise MeshError(f"Expected integer `faces`, got dtype {f.dtype}; pass vertex "
                            "indices as integers.")
    f = f.astype(np.int64, copy=False)
    bad = np.empty(0, dtype=np.intp) if f.min() >= 0 and f.max() < v.shape[0] else \
        np.flatnonzero(((f < 0) | (f >= v.shape[0])).any(axis=1))
    if bad.size:
        raise MeshError(f"Expected face indices in [0, {v.shape[0] - 1}], got out-of-range "
                        f"indices in face(s) {first_rows(bad)}; the faces refer to missing "
                        "vertices.")
    return v, f


def _at(bad: NDArray[np.intp], size: int) -> str:
    """" at ray(s) 3, 7" for per-ray values; "" for one value shared by all rays."""
    return f" at ray(s) {first_rows(bad)}" if size > 1 else ""


def _rows(a: NDArray[np.float64], name: str) -> NDArray[np.float64]:
    """(3,) -> (1, 3); (k, 3) kept; anything else refused."""
    if a.shape == (3,):
        return a[None, :]
    if a.ndim != 2 or a.shape[1] != 3:
        raise RayError(f"Expected `{name}` to have shape (n, 3), got {shape_text(a)}; "
                       "pass one row per ray, or one (3,) row shared by all.")
    return a


def _limit(value: ArrayLike, name: str, n: int) -> NDArray[np.float64]:
    """A ray limit as (1,) or (n,) float64 (the kernels' layout: one value for all rays
    or one per ray)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise RayError(f"Expected `{name}` to be a number or an array of numbers, got "
                       f"{type(value).__name__}; pass a float or shape ({n},).") from None
    if a.ndim > 1 or (a.ndim == 1 and a.shape[0] not in (1, n)):
        raise RayError(f"Expected `{name}` to be a scalar or shape ({n},) (one per ray), "
                       f"got {shape_text(a)}; pass one value per ray or a single one.")
    a = a.reshape(-1)
    bad = np.flatnonzero(np.isnan(a))
    if bad.size:
        raise RayError(f"Expected `{name}` without NaN, got NaN{_at(bad, a.size)}; use "
                       "inf for no limit.")
    return np.ascontiguousarray(a)


def _raise_bad_rays(o: NDArray[np.float64], d: NDArray[np.float64]) -> None:
    """Raise the ``RayError`` that names the first bad origins or directions."""
    bad = np.flatnonzero(~np.isfinite(o).all(axis=1))
    if bad.size:
        raise RayError(f"Expected finite `origins`, got NaN/inf at row(s) {first_rows(bad)}"
                       "; drop those rays.")
    bad = np.flatnonzero(~np.isfinite(d).all(axis=1))
    if bad.size:
        raise RayError(f"Expected finite `directions`, got NaN/inf at row(s) "
                       f"{first_rows(bad)}; drop those rays.")
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    bad = np.flatnonzero(length == 0.0)
    raise RayError(f"Expected non-zero `directions`, got zero length at row(s) "
                   f"{first_rows(bad)}; drop those rays.")


def _raise_not_unit(d: NDArray[np.float64]) -> None:
    """Raise the ``RayError`` naming the first directions that are not unit vectors."""
    sq = np.einsum("ij,ij->i", d, d)
    bad = np.flatnonzero(~(np.abs(sq - 1.0) <= UNIT_TOL))
    raise RayError(f"Expected unit-length `directions` with unit=True, got length "
                   f"{float(np.sqrt(sq[bad[0]])):.12g} at row(s) {first_rows(bad)}; "
                   "normalise them, or leave unit=False to have them normalised.")


def prepare_rays(origins: ArrayLike, directions: ArrayLike, t_min: ArrayLike,
                 t_max: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                            NDArray[np.float64], NDArray[np.float64]]:
    """Checked rays in the kernels' layout.

    Parameters
    ----------
    origins, directions : (n, 3) or (3,) array_like of float
        A single row is shared by all rays.
    t_min, t_max : float or (n,) array_like of float
        0 <= t_min <= t_max; t_min finite, t_max finite or ``inf``.

    Returns
    -------
    origins : (1, 3) or (n, 3) float64, C-contiguous
    directions : (n, 3) float64, unit length, C-contiguous
    t_min, t_max : (1,) or (n,) float64, both the same length

    Raises
    ------
    RayError
    """
    o, _, d, _, tmin, tmax = _prepare(origins, directions, t_min, t_max, None)
    return o, d, tmin, tmax


#: Fewest rays that ``prepare_cast`` checks with its parallel kernels (fewer: NumPy and
#: the serial path of ``prepare_rays``).
_PARALLEL_ROWS = 64


def prepare_cast(origins: ArrayLike, directions: ArrayLike, t_min: ArrayLike,
                 t_max: ArrayLike, offset: NDArray[np.float64], given_unit: bool = False
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                            bool, NDArray[np.float64], NDArray[np.float64]]:
    """Checked rays for ``Scene.cast``: ``prepare_rays`` with the origins also shifted
    into a scene's local frame, and the directions left as given where the traversal can
    normalise them itself.

    Parameters
    ----------
    origins, directions, t_min, t_max
        As in ``prepare_rays``.
    offset : (3,) float64
        The scene's local origin: ``local = origins - offset``.
    given_unit : bool
        The caller says the directions are unit vectors already (``Scene.cast(...,
        unit=True)``): they are checked to be (``_kernels.rays.count_not_unit``) and
        returned as given, ``unit`` True, with no normalised copy.

    Returns
    -------
    origins : (1, 3) or (n, 3) float64, C-contiguous (world frame)
    local : (1, 3) or (n, 3) float64, C-contiguous: ``origins - offset``, bit for bit;
        (1, 3) also when ``origins`` are n rows that are all equal bit for bit (a
        station given as an (n, 3) array), which then casts as a single origin does
    directions : (n, 3) float64, C-contiguous: unit vectors when ``unit``, else the
        caller's non-zero finite directions, to be normalised per ray exactly as
        ``prepare_rays`` normalises them (``_kernels/rays.py``)
    unit : bool
    t_min, t_max : (1,) or (n,) float64, both the same length

    Raises
    ------
    RayError
        As ``prepare_rays``, with the same messages.
    """
    return _prepare(origins, directions, t_min, t_max, offset, given_unit)


def _shared_local(o: NDArray[np.float64], offset: NDArray[np.float64], n: int
                  ) -> NDArray[np.float64] | None:
    """``o[:1] - offset`` (1, 3) when the n rows of ``o`` are one finite origin repeated
    bit for bit, else None.

    DECISION: such an array (a station passed with one row per ray) is cast as its
    single origin: the shift of n origins, the search for runs of equal rows and the
    slicing by runs cost the (n, 3) station 25 % more than the (3,) one (issue 33),
    for the same answer. Three rows are compared first, so an array of different
    origins (a drive) costs nothing more than before.
    """
    if o.shape[0] != n or n < 2:
        return None
    first = o[0].tobytes()
    if o[n - 1].tobytes() != first or o[n // 2].tobytes() != first:
        return None
    # Every row is the first: finite when the first is.
    if not np.isfinite(o[0]).all() or rows_unlike_first(o.view(np.int64)):
        return None
    return o[:1] - offset


def _prepare(origins: ArrayLike, directions: ArrayLike, t_min: ArrayLike,
             t_max: ArrayLike, offset: NDArray[np.float64] | None,
             given_unit: bool = False
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                        bool, NDArray[np.float64], NDArray[np.float64]]:
    """``prepare_rays`` (``offset`` None: directions normalised, local = origins) and
    ``prepare_cast``."""
    d = _rows(as_xyz(directions, "directions", RayError), "directions")
    o = _rows(as_xyz(origins, "origins", RayError), "origins")
    if o.shape[0] == 1:
        n = d.shape[0]
    elif d.shape[0] in (1, o.shape[0]):
        n = o.shape[0]
    else:
        raise RayError(f"Expected `origins` to have shape ({d.shape[0]}, 3) or (3,), got "
                       f"{shape_text(o)}; pass one origin per ray or a single one.")
    o = np.ascontiguousarray(o)
    d = np.ascontiguousarray(d)
    # One fused parallel pass each (_kernels/rays.py); the NumPy passes below only run
    # to name the offending rows when something is wrong.
    # DECISION: a single origin (a station, a camera) is checked without the parallel
    # kernel: on a loaded 2-core machine each parallel region waits milliseconds for
    # its worker thread, longer than checking a few rows.
    if o.shape[0] > _PARALLEL_ROWS:
        if offset is None:
            local = o
            bad_o = count_nonfinite(o)
        else:
            shared = _shared_local(o, offset, n)
            if shared is None:
                local = np.empty_like(o)
                bad_o = shift_origins(o, offset, local)
            else:
                local, bad_o = shared, 0
    else:
        bad_o = int((~np.isfinite(o)).sum())
        local = o if offset is None else o - offset
    # DECISION: one (n, 3) direction per ray is left to the traversal to normalise
    # (``traverse.closest_hit`` with unit=False, same arithmetic, same bits): writing
    # the (n, 3) unit array cost ~7 ns a drive ray plus the page faults of a fresh
    # 24 bytes a ray, for an array the drive's casts never read again.
    # A single origin (a station, a camera) goes to a cube map or near map, whose
    # kernels take unit vectors: normalised here, as before. DECISION: not left to the
    # map's kernel to normalise per ray (as the BVH walk does): measured (bfo, 4M-ray
    # station, one thread) 88.7 ns a ray in the kernel against 60.7 + 10.5 for the
    # normalised copy; the sqrt and divisions sit on the path to the ray's cell.
    # DECISION: directions the caller says are unit vectors (a camera's, rotated and
    # normalised by the renderer) are only checked: the normalised copy cost a 640x480
    # depth frame 1.6 ms of CPU against 0.4 for the check (a fresh 7 MB array written),
    # for the same bits (issue 35).
    if given_unit:
        if count_not_unit(d):
            if bad_o or not np.isfinite(d).all():
                _raise_bad_rays(o, d)
            _raise_not_unit(d)
        copy = False
    else:
        copy = (offset is None or d.shape[0] != n or local.shape[0] != n
                or n <= _PARALLEL_ROWS)
    unit = given_unit or copy
    if copy:
        u = np.empty_like(d)
        bad_d = unit_directions(d, u)
    elif not given_unit:
        bad_d = count_bad_directions(d)
    else:
        bad_d = 0
    if bad_o or bad_d:
        _raise_bad_rays(o, d)
    if copy:
        d = u
    if d.shape[0] != n:  # one direction shared by several origins
        d = np.broadcast_to(d, (n, 3))
    tmin = _limit(t_min, "t_min", n)
    tmax = _limit(t_max, "t_max", n)
    bad = np.flatnonzero(~np.isfinite(tmin) | (tmin < 0))
    if bad.size:
        raise RayError(f"Expected a finite `t_min` >= 0, got {tmin[bad[0]]}"
                       f"{_at(bad, tmin.size)}; rays start at their origin (t_min=0.0).")
    if tmin.shape[0] != tmax.shape[0]:
        tmin = np.broadcast_to(tmin, (n,)).copy()
        tmax = np.broadcast_to(tmax, (n,)).copy()
    bad = np.flatnonzero(tmin > tmax)
    if bad.size:
        raise RayError(f"Expected `t_min` <= `t_max` for every ray, got t_min "
                       f"{tmin[bad[0]]} > t_max {tmax[bad[0]]}{_at(bad, tmin.size)}; pass "
                       "the limits by keyword: cast(o, d, t_min=..., t_max=...).")
    return o, local, d, unit, tmin, tmax
