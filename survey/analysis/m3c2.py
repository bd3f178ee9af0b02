"""M3C2 distances between two epochs (Lague, Brodu & Leroux 2013, ISPRS J. Photogramm.
82:10-26), with the parameters and semantics of py4dgeo's ``M3C2`` (3DGeo Heidelberg)
and CloudCompare's M3C2 plugin.

At each core point i:

1. Normal: at each radius of ``normal_radii_m``, the eigenvector of the smallest
   eigenvalue of the covariance of the normal epoch's points within that radius; the
   radius with the highest planarity (l1 - l0) / l2 wins (py4dgeo's rule; the first on
   ties). Oriented so that n . orientation >= 0 (py4dgeo's ``orientation_vector``,
   default +Z), or towards given points (``towards``; CloudCompare's "towards a
   point": the tunnel axis, ``towards_axis``). Or given (``normals``).
2. Cylinder: the points of each epoch with |t| <= L and distance to the axis
   <= ``cyl_radius_m``, t = (p - c_i) . n_i, L = max(``max_depth_m``, radius) (py4dgeo
   uses the radius as half-length when ``max_distance`` is smaller).
3. Distance = centre2 - centre1 of the projections t: their means, or with ``robust``
   their medians (py4dgeo ``robust_aggr``, CloudCompare "use median"). Positive along
   the normal: with normals towards the tunnel axis, positive is convergence.
4. LoD95 = 1.96 (sqrt(s1^2 / n1 + s2^2 / n2) + registration error) (Lague et al. 2013,
   eq. 1; py4dgeo ``lodetection``), s the standard deviation (ddof 1) of the
   projections (IQR with ``robust``), n the counts; significant where |d| > LoD95.

Parameter names: py4dgeo ``normal_radii`` / ``cyl_radius`` / ``max_distance`` /
``registration_error`` / ``robust_aggr`` are ``normal_radii_m`` / ``cyl_radius_m`` /
``max_depth_m`` / ``registration_error_m`` / ``robust`` here. CloudCompare's normal
and projection *scales* are diameters (``M3C2Params.from_cloudcompare`` halves them);
its "max depth" is the same half-length as ``max_depth_m``.

Differences from py4dgeo (``tests/survey/analysis/test_m3c2.py`` shows the equality):

- The cylinder holds |t| <= L. py4dgeo cuts it into ceil(L / r) slabs and keeps
  |t - t_k| < L / N in each, so a point on a slab boundary is counted 0, 1 or 2
  times as rounding falls: with an even N, a core point taken from the epoch (t = 0)
  is such a point. Here it counts once (as in Lague et al. and CloudCompare).
- UTM coordinates: everything runs about a local origin (float64), so results do not
  change with a 5,000 km offset; py4dgeo's cylinder membership does at that offset
  (tested), so the equality tests give py4dgeo shifted clouds.
- A core point without a normal (fewer than three neighbours at every radius) gets
  NaN, as do cylinders with no point in an epoch (and a NaN LoD with one point).

Streaming: the two epochs are held as grids (``EpochGrid``: 32 bytes per point);
core points are processed in chunks of ``CHUNK`` (``M3C2.compute`` per chunk, or
``m3c2`` for arrays), so the outputs never need to be held whole. Epochs larger than
memory run in x, y tiles with a halo (``survey.cluster.m3c2_tiles``), each tile on
the whole epoch's grid lattice (``EpochGrid.lattice_of``), with the same bits.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points, positive
from survey.analysis.compare import check_overlap
from survey.errors import CompareError

if TYPE_CHECKING:
    from survey.world.alignment import Alignment

__all__ = ["CHUNK", "LOD_Z", "M3C2", "EpochGrid", "M3C2Params", "M3C2Result",
           "lod95", "m3c2", "subsample", "towards_axis"]

Floats = NDArray[np.float64]

#: Core points per chunk (bounds the memory of one ``compute`` call).
CHUNK = 1 << 18
#: The 95 % two-sided normal quantile of the level of detection (Lague et al. 2013,
#: eq. 1; py4dgeo and CloudCompare use 1.96 too).
LOD_Z = 1.96
#: Grid cells per axis at most (2^20 keeps the cell keys within int64).
MAX_CELLS_PER_AXIS = 1 << 20


def _positive(value: Any, name: str, zero: bool = False) -> float:
    return positive(value, name, CompareError, zero=zero)


@dataclass(frozen=True)
class M3C2Params:
    """M3C2 parameters (py4dgeo's meaning; radii and half-lengths in metres).

    Attributes
    ----------
    cyl_radius_m : float > 0
        Projection cylinder radius (py4dgeo ``cyl_radius``; half CloudCompare's
        projection scale).
    max_depth_m : float >= 0
        Cylinder half-length along the normal (py4dgeo ``max_distance``,
        CloudCompare "max depth"); a value below the radius acts as the radius.
    normal_radii_m : tuple of float > 0
        Normal radii (py4dgeo ``normal_radii``; half CloudCompare's normal scales);
        empty when normals are given.
    registration_error_m : float >= 0
        Added to the LoD95 inside the 1.96 factor (py4dgeo ``registration_error``).
    robust : bool
        Median and IQR instead of mean and standard deviation (py4dgeo
        ``robust_aggr``).
    """

    cyl_radius_m: float
    max_depth_m: float
    normal_radii_m: tuple[float, ...] = ()
    registration_error_m: float = 0.0
    robust: bool = False

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "cyl_radius_m", _positive(self.cyl_radius_m, "cyl_radius_m"))
        set_(self, "max_depth_m", _positive(self.max_depth_m, "max_depth_m", zero=True))
        set_(self, "registration_error_m",
             _positive(self.registration_error_m, "registration_error_m", zero=True))
        radii = np.atleast_1d(np.asarray(self.normal_radii_m, dtype=object))
        set_(self, "normal_radii_m",
             tuple(_positive(r, "normal_radii_m") for r in radii.ravel()))
        set_(self, "robust", bool(self.robust))

    @classmethod
    def from_cloudcompare(cls, *, normal_scales_m: ArrayLike, projection_scale_m: float,
                          max_depth_m: float, registration_error_m: float = 0.0,
                          use_median: bool = False) -> M3C2Params:
        """Parameters from CloudCompare's dialog: scales are diameters (halved here,
        as py4dgeo's ``CloudCompareM3C2`` does)."""
        scales = np.atleast_1d(np.asarray(normal_scales_m, dtype=np.float64))
        return cls(0.5 * _positive(projection_scale_m, "projection_scale_m"), max_depth_m,
                   tuple(0.5 * float(s) for s in scales), registration_error_m, use_median)

    @property
    def half_length_m(self) -> float:
        """The cylinder's half-length L = max(max_depth_m, cyl_radius_m)."""
        return max(self.max_depth_m, self.cyl_radius_m)

    @property
    def n_slabs(self) -> int:
        """Slabs the cylinder is searched in: ceil(L / r) (py4dgeo's cut)."""
        return max(1, int(np.ceil(self.half_length_m / self.cyl_radius_m - 1e-12)))

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class EpochGrid:
    """One epoch's points in a uniform grid for M3C2 queries (layout in
    ``survey._kernels.m3c2``).

    Parameters
    ----------
    points : (n, 3) array_like of float, or structured array with x, y, z
        World coordinates, metres (UTM-sized values are fine).
    origin : (3,) array_like of float
        Local origin subtracted before anything else (float64).
    cell_m : float > 0
        Cell edge, m (raised where the extent would need more than
        ``MAX_CELLS_PER_AXIS`` cells per axis).
    lattice : (lo (3,), h, dims (3,)), optional
        The grid to use instead of the points' own (``lattice_of`` of a larger set's
        bounds; ``cell_m`` is then ignored); the points may then be none, and must lie
        in the lattice's box (cells are clipped to it).
    """

    def __init__(self, points: ArrayLike, origin: ArrayLike, cell_m: float, *,
                 lattice: tuple[ArrayLike, float, ArrayLike] | None = None) -> None:
        from survey._kernels.m3c2 import cell_keys

        p, _ = as_points(points, "points", CompareError)
        self.origin = np.asarray(origin, dtype=np.float64).reshape(3)
        if lattice is None:
            if len(p) == 0:
                raise CompareError("Expected an epoch with points, got none.")
            #: (2, 3) float64 (min, max) rows in world coordinates, m (NaN: no points).
            self.bounds = np.stack([p.min(axis=0), p.max(axis=0)])
            lo, h, dims = self.lattice_of(self.bounds, self.origin, cell_m)
        else:
            lo = np.asarray(lattice[0], dtype=np.float64).reshape(3)
            h = _positive(lattice[1], "lattice cell")
            dims = np.asarray(lattice[2], dtype=np.int64).reshape(3)
            if (dims < 1).any() or int(np.prod(dims.astype(object))) >= 1 << 62:
                raise CompareError(f"Expected 1 to 2^62 lattice cells, got dims "
                                   f"{dims.tolist()}.")
            self.bounds = np.stack([p.min(axis=0), p.max(axis=0)]) if len(p) else \
                np.full((2, 3), np.nan)
        self.h = h
        self.lo = lo
        self.dims = dims
        local = p - self.origin
        keys = np.empty(len(local), dtype=np.int64)
        cell_keys(local, lo, 1.0 / h, self.dims, keys)
        order = np.argsort(keys, kind="stable")
        self.keys = keys[order]
        self.points = np.ascontiguousarray(local[order])

    @staticmethod
    def lattice_of(bounds: ArrayLike, origin: ArrayLike, cell_m: float
                   ) -> tuple[Floats, float, NDArray[np.int64]]:
        """(lo (3,), h, dims (3,) int64): the grid an epoch with world ``bounds`` (2, 3)
        gets about ``origin``: its corner at the local minimum, cells of ``cell_m``
        (raised to keep ``MAX_CELLS_PER_AXIS``).

        DECISION: a function of the bounds alone, so that a piece of the epoch (a
        tile, ``survey.cluster.m3c2_tiles``) gets the whole epoch's lattice: the same
        cell keys, the same cells visited per query, the same order of points, hence
        the same sums to the last bit. (min(p - o) = fl(min(p) - o): rounding is
        monotone, so bounds taken over chunks give the same corner.)"""
        b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        o = np.asarray(origin, dtype=np.float64).reshape(3)
        lo, hi = b[0] - o, b[1] - o
        ext = float((hi - lo).max())
        h = max(_positive(cell_m, "cell_m"), ext / (MAX_CELLS_PER_AXIS - 2))
        dims = np.floor((hi - lo) / h).astype(np.int64) + 1
        return lo, h, dims

    def __len__(self) -> int:
        return len(self.points)

    def __repr__(self) -> str:
        return f"EpochGrid({len(self):,} points, cell {self.h:g} m)"

    @property
    def arrays(self) -> tuple[Floats, NDArray[np.int64], Floats, float, NDArray[np.int64]]:
        """(points, keys, lo, h, dims) as the kernels take them."""
        return self.points, self.keys, self.lo, self.h, self.dims


@dataclass(repr=False)
class M3C2Result:
    """M3C2 at n core points.

    Attributes
    ----------
    distance : (n,) float64, m; centre2 - centre1 along the normal (NaN: no normal, or
        an empty cylinder in an epoch)
    lod : (n,) float64, m; LoD95 (NaN also where an epoch has one point, mean mode)
    significant : (n,) bool; ``|distance| > lod`` (False where either is NaN)
    spread1, spread2 : (n,) float64, m; standard deviation (ddof 1) or IQR of the
        projections in each epoch's cylinder
    n1, n2 : (n,) int64; points in each epoch's cylinder
    normal : (n, 3) float64; unit normals used (NaN rows: none)
    normal_radius : (n,) float64, m; the normal radius chosen (NaN: normals given or
        none found)
    """

    distance: Floats
    lod: Floats
    significant: NDArray[np.bool_]
    spread1: Floats
    spread2: Floats
    n1: NDArray[np.int64]
    n2: NDArray[np.int64]
    normal: Floats
    normal_radius: Floats

    def __len__(self) -> int:
        return len(self.distance)

    def __repr__(self) -> str:
        d = self.distance
        ok = np.isfinite(d)
        if not ok.any():
            return f"M3C2Result({len(d):,} core points, no distance)"
        return (f"M3C2Result({len(d):,} core points, {int(ok.sum()):,} with a distance, "
                f"median {1000 * np.median(d[ok]):.2f} mm, {int(self.significant.sum()):,}"
                f" significant)")

    @classmethod
    def concatenate(cls, parts: list[M3C2Result]) -> M3C2Result:
        """One result of chunk results in order."""
        if not parts:
            return cls(np.empty(0), np.empty(0), np.empty(0, bool), np.empty(0),
                       np.empty(0), np.empty(0, np.int64), np.empty(0, np.int64),
                       np.empty((0, 3)), np.empty(0))
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts])
                     for f in fields(cls)))

    def fields(self) -> dict[str, np.ndarray]:
        """The per-point values as {name: (n,) array} for a LAS file's extra bytes:
        distance, lod, significant (uint8), spread1/2, n1/2, nx, ny, nz (float32
        except the counts)."""
        f32 = np.float32
        return {"distance": self.distance.astype(f32), "lod": self.lod.astype(f32),
                "significant": self.significant.astype(np.uint8),
                "spread1": self.spread1.astype(f32), "spread2": self.spread2.astype(f32),
                "n1": self.n1.astype(np.int32), "n2": self.n2.astype(np.int32),
                "nx": self.normal[:, 0].astype(f32), "ny": self.normal[:, 1].astype(f32),
                "nz": self.normal[:, 2].astype(f32)}


def lod95(spread1: ArrayLike, n1: ArrayLike, spread2: ArrayLike, n2: ArrayLike,
          registration_error_m: float = 0.0) -> Floats:
    """LoD95 = 1.96 (sqrt(s1^2 / n1 + s2^2 / n2) + reg) (Lague et al. 2013, eq. 1), m;
    NaN where a count is 0."""
    s1, s2 = np.asarray(spread1, np.float64), np.asarray(spread2, np.float64)
    c1, c2 = np.asarray(n1, np.float64), np.asarray(n2, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return LOD_Z * (np.sqrt(s1 * s1 / c1 + s2 * s2 / c2) + registration_error_m)


def _orientation(orientation: ArrayLike, towards: ArrayLike | None, core_local: Floats,
                 origin: Floats) -> Floats:
    """Per-core orientation vectors (k, 3), k = 1 or n."""
    if towards is None:
        o = np.asarray(orientation, dtype=np.float64)
        if o.shape != (3,) or not np.isfinite(o).all() or not np.any(o):
            raise CompareError(f"Expected `orientation` as a non-zero (3,) vector, got "
                               f"{np.asarray(orientation).tolist()!r}.")
        return o[None, :]
    t, single = as_points(towards, "towards", CompareError)
    if not single and len(t) != len(core_local):
        raise CompareError(f"Expected `towards` as one point (3,) or one per core point "
                           f"({len(core_local)}, 3), got {t.shape}.")
    return np.ascontiguousarray((t - origin) - core_local)


class M3C2:
    """Two epochs prepared once for M3C2 on many chunks of core points.

    Parameters
    ----------
    epoch1, epoch2 : (n, 3) array_like of float, or structured arrays with x, y, z
        The earlier and the later epoch, metres, in one frame (UTM-sized coordinates
        are fine).
    params : M3C2Params
    normal_epoch : {1, 2}
        The epoch normals are computed from (py4dgeo: the first, unless
        ``cloud_for_normals``).
    origin : (3,) array_like of float, optional
        Local origin; by default the centre of epoch 1's bounding box rounded to
        whole metres.
    check_frames : bool
        Refuse epochs whose bounding boxes lie more than 1 m apart (different frames
        or units; ``survey.analysis.compare.check_overlap``).

    Raises
    ------
    CompareError
        Empty epochs, epochs in different frames, bad parameters.
    """

    def __init__(self, epoch1: ArrayLike, epoch2: ArrayLike, params: M3C2Params, *,
                 normal_epoch: int = 1, origin: ArrayLike | None = None,
                 check_frames: bool = True) -> None:
        if not isinstance(params, M3C2Params):
            raise CompareError(f"Expected `params` as M3C2Params, got "
                               f"{type(params).__name__}.")
        if normal_epoch not in (1, 2):
            raise CompareError(f"Expected `normal_epoch` 1 or 2, got {normal_epoch!r}.")
        self.params = params
        p1, _ = as_points(epoch1, "epoch1", CompareError)
        p2, _ = as_points(epoch2, "epoch2", CompareError)
        for name, p in (("epoch1", p1), ("epoch2", p2)):
            if len(p) == 0:
                raise CompareError(f"Expected `{name}` with points, got none.")
        if check_frames:
            check_overlap(np.stack([p2.min(0), p2.max(0)]),
                          np.stack([p1.min(0), p1.max(0)]), names=("epoch 2", "epoch 1"))
        if origin is None:
            origin = self.default_origin(np.stack([p1.min(axis=0), p1.max(axis=0)]))
        self.origin = np.asarray(origin, dtype=np.float64).reshape(3)
        h = self.cell_m(params)
        self.grids = (EpochGrid(p1, self.origin, h), EpochGrid(p2, self.origin, h))
        self.normal_epoch = normal_epoch

    @staticmethod
    def default_origin(bounds1: ArrayLike) -> Floats:
        """The local origin by default: the centre of epoch 1's bounds (2, 3), rounded
        to whole metres, (3,)."""
        b = np.asarray(bounds1, dtype=np.float64).reshape(2, 3)
        return np.round(0.5 * (b[0] + b[1]))

    @staticmethod
    def cell_m(params: M3C2Params) -> float:
        """The grids' cell edge, m.

        DECISION: cell edge = cylinder radius: a slab's box spans ~3 cells per axis
        (9-16 column searches), and normal balls of a few radii stay cheap."""
        return params.cyl_radius_m

    @classmethod
    def from_grids(cls, grid1: EpochGrid, grid2: EpochGrid, params: M3C2Params, *,
                   normal_epoch: int = 1) -> M3C2:
        """An M3C2 on grids built already (about one origin; either may be empty when
        built on a ``lattice``): the tiles of ``survey.cluster.m3c2_tiles``."""
        if not np.array_equal(grid1.origin, grid2.origin):
            raise CompareError(f"Expected grids about one origin, got "
                               f"{grid1.origin.tolist()} and {grid2.origin.tolist()}.")
        if normal_epoch not in (1, 2):
            raise CompareError(f"Expected `normal_epoch` 1 or 2, got {normal_epoch!r}.")
        job = cls.__new__(cls)
        job.params, job.origin = params, grid1.origin
        job.grids, job.normal_epoch = (grid1, grid2), normal_epoch
        return job

    def __repr__(self) -> str:
        return (f"M3C2({len(self.grids[0]):,} and {len(self.grids[1]):,} points, "
                f"r {self.params.cyl_radius_m:g} m, L {self.params.half_length_m:g} m)")

    def normals(self, corepoints: ArrayLike, *, orientation: ArrayLike = (0.0, 0.0, 1.0),
                towards: ArrayLike | None = None) -> tuple[Floats, Floats]:
        """Multiscale normals (n, 3) and the radius chosen (n,) at core points (n, 3)
        (module doc, step 1); NaN rows where no radius has three non-collinear
        neighbours. ``towards``: one point (3,) or one per core point (n, 3) the
        normals point to (instead of ``orientation``)."""
        from survey._kernels.m3c2 import multiscale_normals

        if not self.params.normal_radii_m:
            raise CompareError("Expected `normal_radii_m` in the parameters to compute "
                               "normals, got none; give radii or pass `normals`.")
        c = as_points(corepoints, "corepoints", CompareError)[0] - self.origin
        o = _orientation(orientation, towards, c, self.origin)
        out_n = np.empty((len(c), 3))
        out_r = np.empty(len(c))
        if len(c):
            multiscale_normals(*self.grids[self.normal_epoch - 1].arrays,
                               np.ascontiguousarray(c),
                               np.asarray(self.params.normal_radii_m, dtype=np.float64),
                               o, out_n, out_r)
        return out_n, out_r

    def compute(self, corepoints: ArrayLike, *, normals: ArrayLike | None = None,
                orientation: ArrayLike = (0.0, 0.0, 1.0),
                towards: ArrayLike | None = None) -> M3C2Result:
        """M3C2 at core points (n, 3) (one chunk; ``m3c2`` splits larger sets).

        ``normals`` (n, 3) or (3,) unit vectors replace the multiscale normals (rows
        are normalised; NaN rows give NaN results).
        """
        from survey._kernels.m3c2 import cylinder_stats

        prm = self.params
        c, _ = as_points(corepoints, "corepoints", CompareError)
        n = len(c)
        if normals is None:
            nrm, rad = self.normals(c, orientation=orientation, towards=towards)
        else:
            nrm = as_points(normals, "normals", CompareError, finite=False)[0]
            if len(nrm) == 1 and n != 1:
                nrm = np.repeat(nrm, n, axis=0)
            if len(nrm) != n:
                raise CompareError(f"Expected `normals` (n, 3) with n = {n} core points, "
                                   f"or one (3,) normal, got {len(nrm)} rows.")
            with np.errstate(invalid="ignore", divide="ignore"):
                ln = np.linalg.norm(nrm, axis=1)
                nrm = np.where((ln > 0)[:, None], nrm / ln[:, None], np.nan)
            rad = np.full(n, np.nan)
        cl = np.ascontiguousarray(c - self.origin)
        c1, s1, c2, s2 = (np.empty(n) for _ in range(4))
        n1, n2 = np.empty(n, np.int64), np.empty(n, np.int64)
        if n:
            cylinder_stats(*self.grids[0].arrays, *self.grids[1].arrays, cl,
                           np.ascontiguousarray(nrm), prm.cyl_radius_m, prm.half_length_m,
                           prm.n_slabs, prm.robust, c1, s1, n1, c2, s2, n2)
        d = c2 - c1
        lod = lod95(s1, n1, s2, n2, prm.registration_error_m)
        with np.errstate(invalid="ignore"):
            sig = np.abs(d) > lod
        return M3C2Result(d, lod, sig, s1, s2, n1, n2, nrm, rad)

    def iter_compute(self, chunks: Iterator[ArrayLike], **kwargs: Any
                     ) -> Iterator[M3C2Result]:
        """``compute`` on each chunk of core points in turn (``kwargs`` as there;
        per-point ``normals`` or ``towards`` cannot be split here: compute them per
        chunk instead)."""
        for ch in chunks:
            yield self.compute(ch, **kwargs)


def m3c2(epoch1: ArrayLike, epoch2: ArrayLike, corepoints: ArrayLike, *,
         cyl_radius_m: float, max_depth_m: float, normal_radii_m: ArrayLike = (),
         registration_error_m: float = 0.0, robust: bool = False,
         normals: ArrayLike | None = None, orientation: ArrayLike = (0.0, 0.0, 1.0),
         towards: ArrayLike | None = None, normal_epoch: int = 1,
         chunk: int = CHUNK) -> M3C2Result:
    """M3C2 distances, LoD95 and significance at core points (module doc).

    Parameters
    ----------
    epoch1, epoch2 : (n, 3) array_like of float
        The earlier and the later epoch, metres, one frame.
    corepoints : (m, 3) or (3,) array_like of float
        Where to measure, metres.
    cyl_radius_m, max_depth_m, normal_radii_m, registration_error_m, robust
        ``M3C2Params``.
    normals : (m, 3) or (3,) array_like of float, optional
        Normals to use instead of the multiscale ones.
    orientation : (3,) array_like of float
        Normals are flipped to a non-negative dot product with it (default +Z).
    towards : (3,) or (m, 3) array_like of float, optional
        Orient normals towards this point, or these points (one per core point; e.g.
        ``towards_axis``), instead.
    normal_epoch : {1, 2}
        Epoch the normals come from.
    chunk : int
        Core points per kernel call.

    Returns
    -------
    M3C2Result
        (m,) arrays (m = 1 for a single (3,) core point).
    """
    prm = M3C2Params(cyl_radius_m, max_depth_m, tuple(np.atleast_1d(normal_radii_m)),
                     registration_error_m, robust)
    c, _ = as_points(corepoints, "corepoints", CompareError)
    job = M3C2(epoch1, epoch2, prm, normal_epoch=normal_epoch)
    nrm = None if normals is None else as_points(normals, "normals", CompareError,
                                                 finite=False)[0]
    tw = None if towards is None else as_points(towards, "towards", CompareError)[0]
    step = max(1, int(chunk))
    parts = []
    for a in range(0, max(len(c), 1), step):
        sl = slice(a, a + step)
        parts.append(job.compute(
            c[sl], orientation=orientation,
            normals=None if nrm is None else (nrm if len(nrm) == 1 else nrm[sl]),
            towards=None if tw is None else (tw[0] if len(tw) == 1 else tw[sl])))
    return M3C2Result.concatenate(parts)


def subsample(points: ArrayLike, spacing_m: float) -> Floats:
    """Core points: the first point (in input order) of each cubic cell of edge
    ``spacing_m`` (CloudCompare's "subsample cloud #1" by space, on a grid), (k, 3)."""
    p, _ = as_points(points, "points", CompareError)
    h = _positive(spacing_m, "spacing_m")
    if len(p) == 0:
        return np.empty((0, 3))
    cell = np.floor((p - p.min(axis=0)) / h).astype(np.int64)
    _, first = np.unique(cell, axis=0, return_index=True)
    return p[np.sort(first)]


def towards_axis(alignment: Alignment, corepoints: ArrayLike,
                 centre: ArrayLike = (0.0, 0.0)) -> Floats:
    """The tunnel axis point in the cross-section of each core point, (n, 3): the
    alignment point at the core point's chainage moved by ``centre`` (left offset,
    height above the alignment; the profile's centroid). Pass as ``towards`` so that
    normals point into the tunnel and positive distances are convergence."""
    c, _ = as_points(corepoints, "corepoints", CompareError)
    off, hgt = np.asarray(centre, dtype=np.float64).reshape(2)
    s, _, _ = alignment.to_local(c)
    return alignment.to_world(s, off, hgt)
