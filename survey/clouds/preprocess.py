"""Point-cloud preprocessing: streaming voxel-grid downsampling and outlier removal.

Voxel grid (Open3D's ``voxel_down_sample`` semantics): the grid is anchored at the
cloud's minimum bound minus half a voxel, voxel index floor((p - anchor) /
voxel_size_m), and a
voxel's output point is the centroid of its input points. Streaming: a first pass finds
the bound (or the LAS header gives it), the second accumulates per-voxel sums in
float64 relative to the anchor (UTM-sized inputs keep their precision) chunk by chunk,
so memory grows with the number of occupied voxels, not with the input: 40 bytes a
voxel (packed key, three sums, count) held, about three times that while chunks merge
(the sort of the keys), plus one chunk's points. Output order: by voxel key (Open3D's
order is unspecified).

Outlier filters, on an in-memory cloud (run them after the voxel grid):

- statistical (``statistical_outliers``): for each point the mean distance to its
  ``k`` nearest neighbours, the point itself included as Open3D's KNN search returns it
  (so k = 8 means the point and 7 others); a point is an outlier when that mean exceeds
  mean + std_ratio * std over all points (population standard deviation), as in
  Open3D's ``remove_statistical_outlier``.
- radius (``radius_outliers``): a point survives with at least ``min_neighbours``
  other points within ``radius_m`` (the point itself not counted), which is what
  Open3D's ``remove_radius_outlier(nb_points=min_neighbours)`` does (checked against it
  in the tests).

Points may be (n, 3), a single (3,) point or a structured array with fields x, y, z.

Extra dimensions (issue 31): a LAS/LAZ input's extra bytes (``section``, ``chainage``,
another writer's fields) travel with the points (``iter_points_extra``), through the
voxel grid (``VoxelGrid.add(points, fields)``, ``VoxelGrid.fields``) into the output
with their types, scales and descriptions (``extra_dims``, ``write_preprocessed``).
A voxel's value of a floating-point dimension is the mean of its points' values, an
integer dimension's the value of its first point in file order (see
``VoxelGrid.fields``).

Colour (issue 35): a cloud's colour (LAS RGB, 8-bit values in 16-bit fields detected;
PLY, NPZ and E57 colour; ``sensors.io.cloudfields.cloud_appearance``) travels too
(``iter_points_colour``): a voxel's colour is the mean of its points' colour in linear
light (sRGB decoded and encoded again, IEC 61966-2-1), written as LAS RGB 16-bit
(point format 7, as LAS 1.4 R15 asks) by ``write_preprocessed(..., rgb=)``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from raytrace.checks import as_points
from survey.errors import PreprocessError

__all__ = ["COLOUR_KEYS", "VoxelGrid", "colour_fields", "extra_dims", "iter_points_colour",
           "iter_points_extra", "radius_outliers", "rgb_from_fields",
           "statistical_outliers", "voxel_down_sample", "write_preprocessed"]

Fields = dict[str, NDArray[Any]]


def _check_points(p: ArrayLike, name: str = "points") -> NDArray[np.float64]:
    pts, _ = as_points(p, name, PreprocessError)
    if len(pts) == 0:
        raise PreprocessError(f"Expected a non-empty cloud, got 0 points in `{name}`.")
    return pts


class VoxelGrid:
    """Streaming voxel-grid accumulator.

    ``VoxelGrid(voxel_size_m, min_bound)``, then ``add(points)`` per chunk, then
    ``result()`` -> (m, 3) centroids and (m,) counts. ``min_bound`` (3,) is the cloud's
    minimum, metres (the grid anchor is min_bound - voxel_size_m / 2).

    Per-point fields (``add(points, fields)``, the same names in every chunk) give one
    value per voxel (``fields()``, in ``result``'s order): 8 more bytes a voxel per
    field.
    """

    #: Bits per axis in the packed voxel key (2 cm voxels: 42 km per axis).
    BITS = 21

    def __init__(self, voxel_size_m: float, min_bound: ArrayLike) -> None:
        try:
            size = float(voxel_size_m)
        except (TypeError, ValueError):
            size = float("nan")
        if not (np.isfinite(size) and size > 0):
            raise PreprocessError(f"Expected a positive voxel size `voxel_size_m` (m), got "
                                  f"{voxel_size_m!r}.")
        self.voxel_size_m = size
        lo = np.asarray(min_bound, dtype=np.float64)
        if lo.shape != (3,) or not np.isfinite(lo).all():
            raise PreprocessError(f"Expected a finite `min_bound` of shape (3,), got "
                                  f"{lo.shape}; pass the cloud's minimum x, y, z.")
        self.anchor = lo - size / 2
        self._keys = np.empty(0, dtype=np.int64)
        self._sums = np.empty((0, 3))
        self._counts = np.empty(0, dtype=np.int64)
        self._pending: list[tuple[NDArray[Any], NDArray[Any], NDArray[Any], Fields]] = []
        self._pending_n = 0
        self._fields: Fields | None = None           # per voxel: sums or first values

    def __repr__(self) -> str:
        return (f"VoxelGrid({self.voxel_size_m:g} m, "
                f"{len(self._keys) + self._pending_n:,} voxels so far)")

    def add(self, points: ArrayLike, fields: Mapping[str, ArrayLike] | None = None
            ) -> None:
        """Accumulate a chunk of points (n, 3) or (3,), or a structured array, with
        per-point ``fields`` {name: (n,) array} (the same names in every chunk)."""
        p, _ = as_points(points, "points", PreprocessError, finite=False)
        vals = {k: np.asarray(v) for k, v in (fields or {}).items()}
        if self._fields is None:
            self._fields = {k: np.empty((0,) + v.shape[1:], _kept_dtype(v.dtype))
                            for k, v in vals.items()}
        if set(vals) != set(self._fields) or any(len(v) != len(p) for v in vals.values()):
            raise PreprocessError(f"Expected the fields {sorted(self._fields)} with one "
                                  f"value per point ({len(p)}), got "
                                  f"{ {k: len(v) for k, v in vals.items()} }.")
        if len(p) == 0:
            return
        local = p - self.anchor
        idx = np.floor(local / self.voxel_size_m).astype(np.int64)
        if (idx < 0).any() or (idx >= 1 << self.BITS).any():
            raise PreprocessError(f"Expected points within the bounds given to the voxel "
                                  f"grid, got one outside; pass the cloud's true minimum "
                                  f"bound (or the extent exceeds "
                                  f"{(1 << self.BITS) * self.voxel_size_m:.0f} m).")
        key = (idx[:, 0] << (2 * self.BITS)) | (idx[:, 1] << self.BITS) | idx[:, 2]
        u, first, inv = np.unique(key, return_index=True, return_inverse=True)
        sums = np.stack([np.bincount(inv, weights=local[:, k], minlength=len(u))
                         for k in range(3)], 1)
        self._pending.append((u, sums, np.bincount(inv, minlength=len(u)),
                              {k: _reduce(v, inv, first, len(u)) for k, v in vals.items()}))
        self._pending_n += len(u)
        if self._pending_n > max(1 << 22, len(self._keys)):
            self._merge()

    def _merge(self) -> None:
        if not self._pending:
            return
        # The grid's arrays and the pending chunks go once concatenated: the merge's
        # peak is the concatenation and the sort's arrays, not those beside them too.
        # The grid's own voxels come first, then the chunks in the order they came:
        # a key's first occurrence is its first point in input order.
        parts = [(self._keys, self._sums, self._counts, self._fields or {})] + \
            self._pending
        self._pending, self._pending_n = [], 0
        del self._keys, self._sums, self._counts
        keys = np.concatenate([k for k, _, _, _ in parts])
        counts = np.concatenate([c for _, _, c, _ in parts])
        sums = np.concatenate([s for _, s, _, _ in parts])
        fields = {k: np.concatenate([f[k] for _, _, _, f in parts])
                  for k in (self._fields or {})}
        del parts
        u, first, inv = np.unique(keys, return_index=True, return_inverse=True)
        del keys
        self._sums = np.stack([np.bincount(inv, weights=sums[:, k], minlength=len(u))
                               for k in range(3)], 1)
        del sums
        self._counts = np.bincount(inv, weights=counts, minlength=len(u)).astype(np.int64)
        self._fields = {k: _reduce(v, inv, first, len(u)) for k, v in fields.items()}
        self._keys = u

    def result(self) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """(centroids (m, 3) float64 world, counts (m,) int64), ordered by voxel key."""
        self._merge()
        return self._sums / self._counts[:, None] + self.anchor, self._counts.copy()

    def fields(self, dtypes: Mapping[str, Any] | None = None) -> Fields:
        """The value of every field per voxel {name: (m,)}, in ``result``'s order.

        DECISION: a floating-point field gets the mean of the voxel's points (summed
        in float64, as the coordinates: the centroid's chainage is the points' mean
        chainage), an integer field the value of the voxel's first point in input
        order: integers are labels and counts (a section number, a class, an id),
        whose mean is no value any point had (the mean of sections 3 and 4 is no
        section). ``dtypes`` {name: dtype}: the types to return (default: float64
        for floating-point fields, the input's type for integers)."""
        self._merge()
        out: Fields = {}
        for k, v in (self._fields or {}).items():
            if v.dtype.kind == "f":
                v = v / np.maximum(self._counts, 1).reshape((-1,) + (1,) * (v.ndim - 1))
            out[k] = v.astype((dtypes or {}).get(k, v.dtype), copy=False)
        return out


def _kept_dtype(dt: np.dtype) -> np.dtype:
    """What a voxel keeps of a field of type ``dt``: float64 sums of a floating-point
    field, the values of any other."""
    return np.dtype(np.float64) if dt.kind == "f" else dt


def _reduce(values: NDArray[Any], inv: NDArray[np.intp], first: NDArray[np.intp],
            m: int) -> NDArray[Any]:
    """Per-voxel float64 sums of a floating-point field (``values`` may be sums
    already), the first value of any other (``first``: index of each voxel's first
    element)."""
    if values.dtype.kind == "f":
        flat = values.reshape(len(values), -1).astype(np.float64)
        sums = np.stack([np.bincount(inv, weights=flat[:, j], minlength=m)
                         for j in range(flat.shape[1])], 1)
        return sums.reshape((m,) + values.shape[1:])
    return values[first]


def voxel_down_sample(points: ArrayLike, voxel_size_m: float) -> NDArray[np.float64]:
    """Centroid per voxel of ``voxel_size_m`` (Open3D semantics, see module doc).

    Parameters
    ----------
    points : (n, 3) or (3,) array_like of float, or structured array with x, y, z
        The cloud, metres; not empty.
    voxel_size_m : float
        Voxel edge length, metres, > 0.

    Returns
    -------
    (m, 3) float64
        The centroid of the points in each occupied voxel (m <= n voxels), metres, in
        the input's coordinates, ordered by voxel key.

    Raises
    ------
    PreprocessError
        Points not (n, 3) or (3,), not finite or none at all, a voxel size that is not
        a positive number, or a cloud wider than 2**21 voxels along an axis
        (``VoxelGrid.BITS``).
    """
    p = _check_points(points)
    g = VoxelGrid(voxel_size_m, p.min(axis=0))
    g.add(p)
    return g.result()[0]


def statistical_outliers(points: ArrayLike, *, k: int = 8,
                         std_ratio: float = 2.0) -> NDArray[np.bool_]:
    """Boolean mask (n,) of the statistical outliers (see module doc): ``k`` nearest
    neighbours (the point included), threshold mean + ``std_ratio`` x std."""
    p = _check_points(points)
    k = int(k)
    if k < 2:
        raise PreprocessError(f"Expected k >= 2 neighbours (the point included), got {k}.")
    if not (np.isfinite(std_ratio) and std_ratio > 0):
        raise PreprocessError(f"Expected a positive std_ratio, got {std_ratio}.")
    local = p - p.min(axis=0)
    d, _ = cKDTree(local).query(local, k=min(k, len(p)), workers=-1)
    d = d.reshape(len(p), -1)           # one point: query returns (n,) for k = 1
    mean = d.mean(axis=1)
    thr = mean.mean() + std_ratio * mean.std()
    return mean > thr


def radius_outliers(points: ArrayLike, *, min_neighbours: int = 4,
                    radius_m: float = 0.05) -> NDArray[np.bool_]:
    """Boolean mask (n,) of points with fewer than ``min_neighbours`` other points
    within ``radius_m``."""
    p = _check_points(points)
    if not (np.isfinite(radius_m) and radius_m > 0) or int(min_neighbours) < 1:
        raise PreprocessError(f"Expected min_neighbours >= 1 and a positive radius_m, got "
                              f"{min_neighbours}, {radius_m}.")
    local = p - p.min(axis=0)
    tree = cKDTree(local)
    counts = tree.query_ball_point(local, radius_m, return_length=True, workers=-1)
    return counts - 1 < int(min_neighbours)          # the query point is in its own ball


def extra_dims(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The extra dimensions of a LAS/LAZ cloud {name: laspy ``ExtraBytesParams``}
    (type, description, scale and offset as the file has them; bytes no descriptor
    names are left out), in record order; {} for other formats."""
    from sensors.io.las import LasSource
    from sensors.io.cloudread import cloud_errors, existing_cloud

    p = existing_cloud(path)
    if p.suffix.lower() not in (".las", ".laz"):
        return {}
    import laspy

    with cloud_errors(), LasSource(p) as src:
        dims = list(src.header.point_format.extra_dimensions)
    if any(d.name == "ExtraBytes" for d in dims):
        import warnings

        warnings.warn(f"'{p}' holds extra bytes that no extra-bytes descriptor names; "
                      "they are not carried (only described dimensions are).",
                      UserWarning, stacklevel=2)
    return {d.name: laspy.ExtraBytesParams(
        name=d.name, type=np.dtype(d.dtype), description=d.description,
        offsets=d.offsets, scales=d.scales, no_data=d.no_data)
        for d in dims if d.name != "ExtraBytes"}


def iter_points_extra(path: str | os.PathLike[str], *, chunk: int = 1 << 20
                      ) -> Iterator[tuple[NDArray[np.float64], Fields]]:
    """(xyz (n, 3) float64, {name: (n,) stored values}) of a cloud, chunk by chunk:
    a LAS/LAZ file's extra dimensions (``extra_dims``) as stored (before their scale
    and offset), {} for other formats (``sensors.io.cloudread.iter_points``). The
    same checks and errors as ``iter_points``."""
    from sensors.io.cloudread import existing_cloud, iter_points

    p = existing_cloud(path)
    names = list(extra_dims(p))
    if not names:
        for xyz in iter_points(p, chunk=chunk):
            yield xyz, {}
        return
    for xyz, fields, _ in _las_chunks(p, names, None, chunk):
        yield xyz, fields


def _las_chunks(p: Path, names: list[str], colour: Any, chunk: int
                ) -> Iterator[tuple[NDArray[np.float64], Fields, NDArray[np.float64] | None]]:
    """(xyz, {extra dimension: stored values}, colour (n, 3) in [0, 1] or None) of a
    LAS/LAZ file chunk by chunk, with ``iter_points``' checks and errors; ``colour``:
    the file's colour encoding (``CloudAppearance.colour``) or None."""
    from sensors.io.las import LasSource
    from sensors.io.cloudread import (
        check_finite,
        check_las_scale,
        cloud_errors,
        las_xyz,
        no_points,
    )

    n = 0
    with cloud_errors(), LasSource(p) as src:
        check_las_scale(src.header, p)
        for rec in src.chunks(chunk):
            xyz = las_xyz(rec)
            check_finite(xyz, p, n)
            n += len(xyz)
            rgb = None if colour is None else \
                colour.unit(np.stack([np.asarray(rec[k]) for k in colour.names], 1))
            yield xyz, {k: np.array(rec.array[k]) for k in names}, rgb
    if n == 0:
        raise no_points(p)


#: The voxel grid's keys of a point's linear colour (n, 3) and of its weight (1: the
#: point has a colour); no LAS dimension name holds a NUL byte.
COLOUR_KEYS = ("\0rgb", "\0rgb_n")


def colour_fields(rgb: NDArray[np.float64] | None, n: int) -> Fields:
    """The grid's colour fields (``COLOUR_KEYS``) of ``n`` points' sRGB colour (n, 3)
    in [0, 1] (NaN or None: no colour): linear colour and weight."""
    from sensors.shading import srgb_decode

    if rgb is None:
        return {COLOUR_KEYS[0]: np.zeros((n, 3)), COLOUR_KEYS[1]: np.zeros(n)}
    ok = np.asarray(np.isfinite(rgb).all(axis=1))
    return {COLOUR_KEYS[0]: np.where(ok[:, None], srgb_decode(np.nan_to_num(rgb)), 0.0),
            COLOUR_KEYS[1]: ok.astype(np.float64)}


def rgb_from_fields(fields: Fields) -> NDArray[np.uint16]:
    """LAS RGB 16-bit (n, 3) of per-voxel ``colour_fields`` means (popped from
    ``fields``): the linear mean over the points with a colour, sRGB-encoded; black
    for a voxel without any."""
    from sensors.shading import srgb_encode

    lin = np.asarray(fields.pop(COLOUR_KEYS[0]), dtype=np.float64)
    w = np.asarray(fields.pop(COLOUR_KEYS[1]), dtype=np.float64)
    mean = np.divide(lin, w[:, None], out=np.zeros_like(lin), where=w[:, None] > 0)
    return np.rint(srgb_encode(mean) * 65535.0).astype(np.uint16)


def iter_points_colour(path: str | os.PathLike[str], appearance: Any, *,
                       chunk: int = 1 << 20
                       ) -> Iterator[tuple[NDArray[np.float64], Fields,
                                           NDArray[np.float64] | None]]:
    """(xyz (n, 3), {extra dimension: (n,) stored values}, colour (n, 3) sRGB in
    [0, 1] or None) of a cloud, chunk by chunk, in one pass: ``iter_points_extra``
    with the colour ``appearance`` (``sensors.io.cloudfields.CloudAppearance``)
    found."""
    from sensors.io.cloudfields import iter_appearance

    enc = appearance.colour
    p = Path(path)
    if enc is None:
        for xyz, f in iter_points_extra(p, chunk=chunk):
            yield xyz, f, None
        return
    if p.suffix.lower() not in (".las", ".laz"):
        for xyz, rgb, _ in iter_appearance(p, appearance, temperature=False, chunk=chunk):
            yield xyz, {}, rgb
        return
    yield from _las_chunks(p, list(extra_dims(p)), enc, chunk)


def write_preprocessed(path: str | os.PathLike[str], xyz: ArrayLike,
                       counts: ArrayLike, extra: Mapping[str, ArrayLike] | None = None,
                       dims: Mapping[str, Any] | None = None,
                       classification: ArrayLike | None = None, *, crs: Any = None,
                       rgb: ArrayLike | None = None) -> Path:
    """Write a preprocessed cloud as LAS/LAZ 1.4 (``sensors.io.las.write_las``): points
    ``xyz`` (n, 3), ``voxel_count`` (n,) (input points per voxel, 1 without a grid),
    the input's extra dimensions ``extra`` {name: (n,) stored values} described by
    ``dims`` (``extra_dims``: type, description, scale, offset kept), classification
    codes (n,), colour ``rgb`` (n, 3) uint16 (LAS RGB 16-bit: point format 7 instead
    of 6) and the CRS ``crs``. Atomic. Returns the path."""
    from sensors.io.las import write_las
    from sensors.io.cloudread import cloud_errors

    dims = dict(dims or {})
    cols: dict[str, NDArray[Any]] = {"voxel_count": np.asarray(counts).astype(np.uint32)}
    for k, v in (extra or {}).items():
        if k in cols:
            # DECISION: an input preprocessed before has its own counts; this grid's
            # replace them (a count per voxel of a voxel grid is not a sum of labels).
            import warnings

            warnings.warn(f"The input's {k!r} is replaced by this run's count of input "
                          "points per voxel.", UserWarning, stacklevel=2)
            dims.pop(k, None)
            continue
        dt = np.dtype(dims[k].type) if k in dims else np.asarray(v).dtype
        cols[k] = np.asarray(v).astype(dt)
    fields = {} if classification is None else {"classification":
                                                np.asarray(classification)}
    fmt = 6
    if rgb is not None:
        c = np.asarray(rgb).astype(np.uint16).reshape(-1, 3)
        fields.update(red=c[:, 0], green=c[:, 1], blue=c[:, 2])
        fmt = 7
    with cloud_errors():
        return write_las(path, np.asarray(xyz, dtype=np.float64), fields=fields,
                         extra=cols, extra_dims=dims, crs=crs, point_format=fmt)
