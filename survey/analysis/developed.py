"""Developed (unrolled) views: rasters over chainage x arc length along the design line.

A point of the lining is placed by its chainage s (``Alignment.to_local``) and by the
arc length u of its closest point on the design profile (``DesignProfile.locate``),
measured from a zero on the design line. The raster holds, per cell, the count, sum,
minimum and maximum of a value: the signed deviation from the design (> 0 outside,
overbreak), an epoch difference carried by the points (an M3C2 ``distance``) or their
intensity. Cells without points are NaN (no data).

Arc-length zero and direction. DECISION: zero at the crown, positive towards the left,
so a closed profile runs from -L/2 (the invert, reached on the right) through the
right wall, the crown (0), the left wall to +L/2 (the invert again, reached on the
left): the crown lies in the middle of the view, as in Amberg's developed views and
CloudCompare's unroll of a cylinder cut along the invert. "Left" is the section frame's
+offset (``survey.world.alignment``), the same sign as the angles of
``survey.world.deformation.Bulge`` and ``survey.analysis.convergence`` (from the crown,
positive to the left). The crown is where the vertical through the design's centre
(area centroid of a closed profile, mid-span of an open one) meets the design line at
its highest crossing. On a closed profile the arc cells divide the perimeter exactly
(the cell is shortened to L / ceil(L / cell)), so the view wraps without a seam.

Memory. The accumulator holds 32 bytes per cell (int64 count, float64 sum, min, max)
whatever the number of points: 1 km of a 20 m perimeter at 5 cm cells is 8e6 cells,
256 MB. Points are streamed chunk by chunk (``develop_file``), so 10^8 points never
sit in memory.

Meshes are sampled uniformly over their area (``mesh_samples``: each triangle is cut
into n^2 equal sub-triangles, n = ceil(longest edge / spacing), sampled at their
centroids), so every square metre of surface weighs the same.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from dataclasses import field as dataclass_field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points, positive
from survey.analysis.design import DesignProfile
from sensors.io.cloudfields import LAS_INTENSITY_SCALE, iter_field
from survey.errors import CompareError, ProfileError
from survey.world.alignment import Alignment

__all__ = ["DEFAULT_CELL_M", "FIELDS", "FIELD_UNITS", "MESH_CHUNK",
           "MESH_SAMPLES_PER_CELL", "SPACING_BIN_M", "SPACING_SAMPLE", "STATISTICS",
           "DevelopedFrame", "DevelopedGrid", "DevelopedRaster", "RasterAccumulator",
           "crown_t", "default_cell", "develop", "develop_file", "file_chunks",
           "file_station_spacing", "is_mesh_file", "mesh_samples",
           "station_spacing"]

Floats = NDArray[np.float64]

#: Values a developed view can show from a file: the deviation from the design
#: (computed), or a per-point field of the cloud (an M3C2 ``distance``, ``intensity``).
FIELDS = ("deviation", "distance", "intensity")
#: Unit of each value ("1" for a fraction).
FIELD_UNITS = {"deviation": "m", "distance": "m", "intensity": "1", "margin": "m"}
#: Per-cell statistics a raster holds.
STATISTICS = ("mean", "min", "max", "count")
#: Default sample spacing of a mesh, as a share of the chainage cell. ASSUMED: 1/3
#: gives ~10 samples per cell, enough for a mean within the faceting error.
MESH_SAMPLES_PER_CELL = 3.0
#: Triangles sampled at once by ``mesh_samples`` (bounds its memory).
MESH_CHUNK = 1 << 16
#: Raster cell (m) of a dense cloud or a mesh, along the chainage and along the arc.
DEFAULT_CELL_M = 0.05
#: Bin (m) in which the chainages of a sample are counted to find a profile cloud's
#: stations (``station_spacing``): finer than any station spacing in use, coarser than
#: a profile scanner's spread along the axis.
SPACING_BIN_M = 0.01
#: Points read from the start of a file to find its station spacing.
SPACING_SAMPLE = 1 << 20


def _positive(value: Any, name: str) -> float:
    return positive(value, name, CompareError)


# ---------------------------------------------------------------------- the frame
class DevelopedFrame:
    """World points -> (chainage, arc length from the zero, deviation) (module doc).

    Parameters
    ----------
    alignment : Alignment
        Chainage and the section frame.
    design : DesignProfile
        The line the arc length runs along (the tunnel's profile or a design file).
    zero : "crown" or float
        Where u = 0: the crown (default), or a design arc length t (m) of
        ``DesignProfile.points``.
    """

    def __init__(self, alignment: Alignment, design: DesignProfile, *,
                 zero: str | float = "crown") -> None:
        if not isinstance(alignment, Alignment):
            raise CompareError(f"Expected an Alignment, got {type(alignment).__name__}.")
        if not isinstance(design, DesignProfile):
            raise CompareError(f"Expected a DesignProfile, got {type(design).__name__}.")
        self.alignment = alignment
        self.design = design
        if isinstance(zero, str):
            if zero != "crown":
                raise CompareError(f"Expected zero 'crown' or a design arc length in m, "
                                   f"got {zero!r}.")
            self.zero_t_m = crown_t(design)
            self.zero = "crown"
        else:
            t0 = float(zero)
            if not (np.isfinite(t0) and 0.0 <= t0 <= design.length_m):
                raise CompareError(f"Expected a zero within the design line [0, "
                                   f"{design.length_m:g}] m, got {zero!r}.")
            self.zero_t_m = t0
            self.zero = f"t = {t0:g} m"

    def __repr__(self) -> str:
        return (f"DevelopedFrame(zero at {self.zero} of {self.design.name!r}, arc "
                f"{self.arc_range[0]:.3f} to {self.arc_range[1]:.3f} m)")

    @property
    def arc_range(self) -> tuple[float, float]:
        """(lowest, highest) arc length u of the design line (m)."""
        L = self.design.length_m
        if self.design.closed:
            return -0.5 * L, 0.5 * L
        return self.zero_t_m - L, self.zero_t_m

    def arc(self, t: ArrayLike) -> Floats:
        """Arc length u (m, from the zero, positive to the left) of design arc lengths
        t (``DesignProfile`` runs counter-clockwise, to the right from the crown)."""
        u = self.zero_t_m - np.asarray(t, dtype=np.float64)
        if self.design.closed:
            L = self.design.length_m
            u = np.mod(u + 0.5 * L, L) - 0.5 * L
        return np.asarray(u, dtype=np.float64)

    def design_t(self, u: ArrayLike) -> Floats:
        """The design arc length t of arc lengths u (the inverse of ``arc``)."""
        t = self.zero_t_m - np.asarray(u, dtype=np.float64)
        if self.design.closed:
            t = np.mod(t, self.design.length_m)
        return np.asarray(t, dtype=np.float64)

    def locate(self, points: ArrayLike) -> tuple[Floats, Floats, Floats, Floats, Floats]:
        """(chainage, u, deviation, offset, height), each (n,) float64, of world points
        (n, 3) m. Points beyond the alignment's ends (``to_local`` gives them the end
        chainage) get NaN chainage; deviation is NaN beyond an open design's ends
        (their u is then the end's)."""
        p, _ = as_points(points, "points", CompareError)
        if len(p) == 0:
            e = np.empty(0)
            return e, e, e, e, e
        s, off, h = self.alignment.to_local(p)
        lo, hi = self.alignment.chainage_range
        # DECISION: a point whose foot is clamped to an end lies beyond the alignment;
        # a real point exactly on an end plane is a measure-zero loss.
        s = np.where((s <= lo) | (s >= hi), np.nan, s)
        dev, t = self.design.locate(np.stack([off, h], axis=1))
        return s, self.arc(t), dev, off, h


def crown_t(design: DesignProfile) -> float:
    """Design arc length t (m) of the crown: the highest crossing of the design line
    with the vertical through its centre (module doc)."""
    v = design.vertices
    if design.closed:
        cy = float(design.centre[0])
        a, b = v, np.roll(v, -1, axis=0)
    else:
        cy = 0.5 * float(v[:, 0].min() + v[:, 0].max())
        a, b = v[:-1], v[1:]
    ya, yb = a[:, 0] - cy, b[:, 0] - cy
    hit = (ya * yb <= 0) & (ya != yb)
    if not hit.any():
        raise ProfileError(f"Expected the design '{design.name}' to cross the vertical "
                           f"through its centre (offset {cy:g} m), got no crossing; give "
                           "the arc-length zero explicitly.")
    f = ya[hit] / (ya[hit] - yb[hit])
    z = a[hit, 1] + f * (b[hit, 1] - a[hit, 1])
    k = int(np.argmax(z))
    seg = np.nonzero(hit)[0][k]
    lengths = np.linalg.norm(b - a, axis=1)
    t0 = float(np.concatenate([[0.0], np.cumsum(lengths)])[seg])
    return t0 + float(f[k]) * float(lengths[seg])


# ---------------------------------------------------------------------- data spacing
def station_spacing(chainage_m: ArrayLike, *, bin_m: float = SPACING_BIN_M) -> float:
    """The station spacing (m) of a profile cloud from its points' chainages (n,)
    float64, or 0.0 for a cloud without regular gaps along the axis (a dense scan).

    The chainages are counted in bins of ``bin_m``; runs of occupied bins are the
    stations. DECISION: a profile cloud is one whose empty stretches between runs are
    (median) longer than the runs themselves; its spacing is the median distance
    between the centres of successive runs, so a missing profile or a gap at a portal
    does not change it.
    """
    s = np.asarray(chainage_m, dtype=np.float64).ravel()
    s = s[np.isfinite(s)]
    h = _positive(bin_m, "bin_m")
    if len(s) < 3:
        return 0.0
    k = np.unique(np.floor(s / h).astype(np.int64))
    gaps = np.diff(k)
    brk = np.nonzero(gaps > 1)[0]
    if len(brk) < 2:
        return 0.0
    starts = k[np.concatenate([[0], brk + 1])]
    ends = k[np.concatenate([brk, [len(k) - 1]])]
    empty = float(np.median(gaps[brk] - 1))
    run = float(np.median(ends - starts + 1))
    if empty <= run:
        return 0.0
    return float(np.median(np.diff(0.5 * (starts + ends)))) * h


def file_station_spacing(path: str | os.PathLike[str], alignment: Alignment, *,
                         sample: int = SPACING_SAMPLE) -> float:
    """``station_spacing`` of the first ``sample`` points of a cloud file (0.0 for a
    mesh, whose area samples are dense). Reads only the start of the file: a profile
    scanner writes profile after profile, so the start holds many stations."""
    from sensors.io.cloudread import iter_points

    if is_mesh_file(path):
        return 0.0
    got: list[Floats] = []
    n = 0
    for chunk in iter_points(path):
        got.append(np.asarray(chunk, dtype=np.float64))
        n += len(chunk)
        if n >= sample:
            break
    if not n:
        return 0.0
    p = np.concatenate(got)[:sample]
    # DECISION: every k-th point (at most 2e5 go through to_local, the costly step);
    # thinning keeps every station of a profile cloud, which holds thousands of points.
    p = p[::max(1, len(p) // 200_000)]
    s, _, _ = alignment.to_local(p)
    lo, hi = alignment.chainage_range
    return station_spacing(s[(s > lo) & (s < hi)])


def default_cell(spacing_m: float, tile_m: float | None = None) -> float:
    """The default chainage cell (m): ``DEFAULT_CELL_M``, or a profile cloud's station
    spacing (one column per station: finer cells leave most columns empty) rounded to
    1 mm and, with ``tile_m``, shortened to divide the tile."""
    c = max(DEFAULT_CELL_M, round(float(spacing_m), 3))
    if tile_m is not None:
        c = float(tile_m) / max(1, int(np.ceil(float(tile_m) / c - 1e-9)))
    return c


# ---------------------------------------------------------------------- the grid
@dataclass(frozen=True)
class DevelopedGrid:
    """A raster over chainage (columns) x arc length (rows), lower edges and cells in m.

    Cell (i, j) covers u in [arc0_m + i cell_arc_m, arc0_m + (i + 1) cell_arc_m) and
    s in [chainage0_m + j cell_s_m, chainage0_m + (j + 1) cell_s_m).
    """

    chainage0_m: float
    cell_s_m: float
    n_s: int
    arc0_m: float
    cell_arc_m: float
    n_arc: int
    wrap: bool = False

    @classmethod
    def covering(cls, frame: DevelopedFrame, cell_m: float, *,
                 cell_arc_m: float | None = None,
                 chainage_range: tuple[float, float] | None = None) -> DevelopedGrid:
        """The grid over ``chainage_range`` (default: the alignment's) and the whole
        design line; columns start at a whole multiple of ``cell_m`` (so tiles at whole
        multiples line up); rows divide the design line exactly."""
        ds = _positive(cell_m, "cell_m")
        du = ds if cell_arc_m is None else _positive(cell_arc_m, "cell_arc_m")
        lo, hi = frame.alignment.chainage_range
        c0, c1 = (lo, hi) if chainage_range is None else map(float, chainage_range)
        if not (np.isfinite(c0) and np.isfinite(c1) and c1 > c0):
            raise CompareError(f"Expected a chainage range (from, to) with to > from, got "
                               f"{chainage_range}.")
        tol = 1e-9 * max(1.0, abs(hi))
        if c0 < lo - tol or c1 > hi + tol:
            from survey.errors import AlignmentError

            raise AlignmentError(f"Expected a chainage range within the alignment [{lo:g}, "
                                 f"{hi:g}] m, got [{c0:g}, {c1:g}] m.")
        k0 = int(np.floor(c0 / ds + 1e-9))
        n_s = max(1, int(np.ceil(c1 / ds - 1e-9)) - k0)
        a0, a1 = frame.arc_range
        n_arc = max(1, int(np.ceil((a1 - a0) / du - 1e-9)))
        return cls(k0 * ds, ds, n_s, a0, (a1 - a0) / n_arc, n_arc, frame.design.closed)

    @property
    def shape(self) -> tuple[int, int]:
        """(rows = arc cells, columns = chainage cells)."""
        return self.n_arc, self.n_s

    def chainage_centres(self) -> Floats:
        """(n_s,) chainage of the column centres (m)."""
        return np.asarray(self.chainage0_m + (np.arange(self.n_s) + 0.5) * self.cell_s_m,
                          dtype=np.float64)

    def arc_centres(self) -> Floats:
        """(n_arc,) arc length of the row centres (m)."""
        return np.asarray(self.arc0_m + (np.arange(self.n_arc) + 0.5) * self.cell_arc_m,
                          dtype=np.float64)

    def cells(self, s: ArrayLike, u: ArrayLike) -> NDArray[np.int64]:
        """Flat cell index (n,) int64 of (s, u), -1 outside the grid (or NaN)."""
        s = np.asarray(s, dtype=np.float64)
        u = np.asarray(u, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            j = np.floor((s - self.chainage0_m) / self.cell_s_m)
            i = np.floor((u - self.arc0_m) / self.cell_arc_m)
            ok = np.isfinite(j) & np.isfinite(i) & (j >= 0) & (j < self.n_s)
            if self.wrap:
                i = np.mod(i, self.n_arc)
            else:  # the design's end points (u == the range's end) fall in the end row
                i = np.clip(i, 0, self.n_arc - 1)
        out = np.full(s.shape, -1, dtype=np.int64)
        out[ok] = i[ok].astype(np.int64) * self.n_s + j[ok].astype(np.int64)
        return out

    def columns(self, from_m: float, to_m: float) -> slice:
        """The columns whose centres lie in [from_m, to_m)."""
        c = self.chainage_centres()
        j = np.nonzero((c >= from_m) & (c < to_m))[0]
        return slice(int(j[0]), int(j[-1]) + 1) if len(j) else slice(0, 0)

    def tiles(self, tile_m: float) -> list[tuple[float, float, slice]]:
        """(from, to, columns) of the tiles [k T, (k + 1) T) that hold columns, T =
        ``tile_m`` a whole multiple of the chainage cell."""
        T = _positive(tile_m, "tile_m")
        r = T / self.cell_s_m
        if abs(r - round(r)) > 1e-6 * max(1.0, r) or round(r) < 1:
            raise CompareError(f"Expected a tile length that is a whole multiple of the "
                               f"cell ({self.cell_s_m:g} m), got {tile_m!r} m.")
        c = self.chainage_centres()
        k = np.floor(c / T).astype(np.int64)
        out = []
        for kk in np.unique(k):
            j = np.nonzero(k == kk)[0]
            out.append((float(kk * T), float((kk + 1) * T), slice(int(j[0]), int(j[-1]) + 1)))
        return out

    def to_dict(self) -> dict[str, Any]:
        """The grid as written beside a raster (JSON-ready)."""
        return {"chainage_origin_m": self.chainage0_m, "cell_chainage_m": self.cell_s_m,
                "columns": self.n_s, "arc_origin_m": self.arc0_m,
                "cell_arc_m": self.cell_arc_m, "rows": self.n_arc,
                "wraps_in_arc": self.wrap,
                "cell_centre": "origin + (index + 0.5) * cell; row = arc, column = "
                               "chainage; origins are the lower edges of cell 0"}


# ---------------------------------------------------------------------- accumulation
class RasterAccumulator:
    """Count, sum, minimum and maximum of values per cell of a ``DevelopedGrid``,
    added chunk by chunk (32 bytes per cell; see the module doc).

    The result does not depend on how the points are chunked, except for the
    rounding of the sums (the order of additions)."""

    def __init__(self, grid: DevelopedGrid) -> None:
        self.grid = grid
        n = grid.n_s * grid.n_arc
        self.count = np.zeros(n, np.int64)
        self.sum = np.zeros(n, np.float64)
        self.min = np.full(n, np.inf)
        self.max = np.full(n, -np.inf)

    def add(self, s: ArrayLike, u: ArrayLike, values: ArrayLike) -> int:
        """Add values (n,) at (s, u); points outside the grid or with a NaN value are
        left out. Returns the number added."""
        v = np.asarray(values, dtype=np.float64).ravel()
        c = self.grid.cells(s, u).ravel()
        if len(c) != len(v):
            raise CompareError(f"Expected one value per point, got {len(v)} values for "
                               f"{len(c)} points.")
        ok = (c >= 0) & np.isfinite(v)
        c, v = c[ok], v[ok]
        if len(c) == 0:
            return 0
        n = len(self.count)
        self.count += np.bincount(c, minlength=n)
        self.sum += np.bincount(c, weights=v, minlength=n)
        np.minimum.at(self.min, c, v)
        np.maximum.at(self.max, c, v)
        return len(c)

    def raster(self, *, field: str, unit: str, frame: DevelopedFrame | None = None,
               meta: dict[str, Any] | None = None) -> DevelopedRaster:
        """The accumulated raster (arrays (n_arc, n_s); NaN where no point fell)."""
        shape = self.grid.shape
        cnt = self.count.reshape(shape).copy()
        has = cnt > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(has, self.sum.reshape(shape) / np.maximum(cnt, 1), np.nan)
        mn = np.where(has, self.min.reshape(shape), np.nan)
        mx = np.where(has, self.max.reshape(shape), np.nan)
        info = dict(meta or {})
        if frame is not None:
            info.setdefault("arc", {
                "zero": frame.zero, "zero_design_t_m": frame.zero_t_m,
                "positive": "towards the left (+offset of the section frame)",
                "design": frame.design.name, "design_closed": frame.design.closed,
                "design_length_m": frame.design.length_m})
            info.setdefault("alignment", frame.alignment.to_dict())
        return DevelopedRaster(self.grid, field, unit, cnt, mean, mn, mx, info)


@dataclass(frozen=True, repr=False)
class DevelopedRaster:
    """A developed view: per-cell statistics of ``field`` (``unit``) on ``grid``.

    Attributes
    ----------
    grid : DevelopedGrid
    field, unit : str
    count : (n_arc, n_s) int64
        Points per cell.
    mean, min, max : (n_arc, n_s) float64
        NaN where the count is 0.
    meta : dict
        Arc zero and direction, design, alignment, CRS, source (JSON-ready).
    """

    grid: DevelopedGrid
    field: str
    unit: str
    count: NDArray[np.int64]
    mean: Floats
    min: Floats
    max: Floats
    meta: dict[str, Any] = dataclass_field(default_factory=dict)

    def __repr__(self) -> str:
        seen = self.count > 0
        g = self.grid
        return (f"DevelopedRaster({self.field} [{self.unit}], {g.n_arc} x {g.n_s} cells of "
                f"{g.cell_arc_m:.3g} x {g.cell_s_m:.3g} m, {100 * seen.mean():.0f} % with "
                f"data, {int(self.count.sum()):,} points)")

    def statistic(self, name: str) -> Floats:
        """The (n_arc, n_s) array of a statistic in ``STATISTICS`` (count as float)."""
        if name not in STATISTICS:
            raise CompareError(f"Expected a statistic in {STATISTICS}, got {name!r}.")
        if name == "count":
            return self.count.astype(np.float64)
        out: Floats = getattr(self, name)
        return out

    def cell_of(self, chainage_m: float, arc_m: float) -> tuple[int, int]:
        """(row, column) of the cell holding (chainage, arc length); ``CompareError``
        outside the grid."""
        c = int(self.grid.cells(np.array([chainage_m]), np.array([arc_m]))[0])
        if c < 0:
            raise CompareError(f"Expected a position on the raster, got chainage "
                               f"{chainage_m:g} m, arc {arc_m:g} m.")
        return divmod(c, self.grid.n_s)


# ---------------------------------------------------------------------- inputs
def _chunks(points: Any, values: ArrayLike | None
            ) -> Iterator[tuple[Floats, Floats | None]]:
    """(xyz (m, 3), values (m,) or None) chunks of ``develop``'s inputs."""
    if isinstance(points, np.ndarray) or not isinstance(points, Iterable):
        p, _ = as_points(points, "points", CompareError)
        v = None if values is None else np.asarray(values, dtype=np.float64).ravel()
        if v is not None and len(v) != len(p):
            raise CompareError(f"Expected one value per point, got {len(v)} values for "
                               f"{len(p)} points.")
        yield p, v
        return
    if values is not None:
        raise CompareError("Expected `values` only with an array of points, got them "
                           "with chunks; give (xyz, values) pairs as chunks.")
    for chunk in points:
        if isinstance(chunk, tuple):
            if len(chunk) != 2:
                raise CompareError(f"Expected a chunk as (xyz, values), got a tuple of "
                                   f"{len(chunk)}.")
            yield from _chunks(chunk[0], chunk[1])
        else:
            yield from _chunks(chunk, None)


def develop(points: Any, alignment: Alignment, design: DesignProfile, *,
            values: ArrayLike | None = None, field: str | None = None, unit: str | None = None,
            cell_m: float = 0.05, cell_arc_m: float | None = None,
            chainage_range: tuple[float, float] | None = None,
            max_deviation_m: float | None = None, zero: str | float = "crown"
            ) -> DevelopedRaster:
    """A developed view of points: of their deviation from ``design`` or of ``values``.

    Parameters
    ----------
    points : (n, 3) array_like, or an iterable of chunks
        World points (m; UTM-sized values are fine). A chunk is an (m, 3) array or an
        (xyz (m, 3), values (m,)) pair.
    alignment : Alignment
    design : DesignProfile
        The line of the arc length and of the deviation.
    values : (n,) array_like or None
        A value per point (with an array ``points``); None: the deviation (m, > 0
        overbreak) is shown.
    field, unit : str or None
        Name and unit of the values (default "deviation", "m" without values).
    cell_m, cell_arc_m : float
        Cell along the chainage and along the arc (default ``cell_m``; shortened to
        divide a closed design exactly), m.
    chainage_range : (from, to) or None
        The chainages covered (default: the alignment's).
    max_deviation_m : float or None
        Leave out points farther than this from the design line (fittings, people,
        the scanner's platform); None keeps all.
    zero : "crown" or float
        The arc-length zero (``DevelopedFrame``).

    Returns
    -------
    DevelopedRaster
        ``meta["points"]``: points added; ``meta["left_out"]``: points beyond the
        alignment, the design's ends, the range or ``max_deviation_m``.
    """
    frame = DevelopedFrame(alignment, design, zero=zero)
    grid = DevelopedGrid.covering(frame, cell_m, cell_arc_m=cell_arc_m,
                                  chainage_range=chainage_range)
    if max_deviation_m is not None:
        max_deviation_m = _positive(max_deviation_m, "max_deviation_m")
    acc = RasterAccumulator(grid)
    used = total = 0
    for xyz, v in _chunks(points, values):
        total += len(xyz)
        if len(xyz) == 0:
            continue
        s, u, dev, _, _ = frame.locate(xyz)
        keep = np.isfinite(dev)
        if max_deviation_m is not None:
            keep &= np.abs(dev) <= max_deviation_m
        val = dev if v is None else v
        used += acc.add(s[keep], u[keep], val[keep])
    if field is None:
        field = "deviation" if values is None else "value"
    if unit is None:
        unit = FIELD_UNITS.get(field, "")
    return acc.raster(field=field, unit=unit, frame=frame,
                      meta={"points": used, "left_out": total - used,
                            "max_deviation_m": max_deviation_m})


# ---------------------------------------------------------------------- files
def mesh_samples(vertices: ArrayLike, faces: ArrayLike, spacing_m: float
                 ) -> Iterator[Floats]:
    """Area-uniform samples (m, 3) of a triangle mesh, in chunks of triangles: each
    triangle cut into n^2 equal sub-triangles (n = ceil(longest edge / spacing)),
    sampled at their centroids (module doc)."""
    v, _ = as_points(vertices, "vertices", CompareError)
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or (len(f) and (f.min() < 0 or f.max() >= len(v))):
        raise CompareError(f"Expected faces (m, 3) indexing {len(v)} vertices, got shape "
                           f"{f.shape}.")
    h = _positive(spacing_m, "spacing_m")
    for a in range(0, len(f), MESH_CHUNK):
        tri = v[f[a:a + MESH_CHUNK]]                      # (k, 3, 3)
        edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
        n = np.maximum(1, np.ceil(edge / h - 1e-9)).astype(np.int64)
        for nn in np.unique(n):
            t = tri[n == nn]
            i, j = np.meshgrid(np.arange(nn), np.arange(nn), indexing="ij")
            up = (i + j) <= nn - 1
            dn = (i + j) <= nn - 2
            bu = np.concatenate([(i[up] + 1 / 3) / nn, (i[dn] + 2 / 3) / nn])
            bv = np.concatenate([(j[up] + 1 / 3) / nn, (j[dn] + 2 / 3) / nn])
            p = (t[:, None, 0] + bu[None, :, None] * (t[:, None, 1] - t[:, None, 0])
                 + bv[None, :, None] * (t[:, None, 2] - t[:, None, 0]))
            yield p.reshape(-1, 3)


def is_mesh_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is read as a mesh (OBJ/STL/OFF, or a PLY with faces)."""
    from survey.analysis.sections import MESH_SUFFIXES

    p = Path(path)
    kind = p.suffix.lower()
    if kind in MESH_SUFFIXES:
        return True
    if kind == ".ply" and p.is_file():
        from sensors.io.ply import read_ply_header

        try:
            head = read_ply_header(p)
        except Exception:  # a broken header: the reader names the problem
            return False
        return any(e.name == "face" and e.count > 0 for e in head.elements)
    return False


def file_chunks(path: str | os.PathLike[str], field: str, *, spacing_m: float
                ) -> Iterator[Any]:
    """The chunks ``develop`` takes from a file: a mesh's area samples (``spacing_m``
    apart; the deviation only), or a cloud's points streamed, with ``field``'s values
    unless the field is the deviation."""
    from sensors.io.cloudread import iter_points, read_reference

    if is_mesh_file(path):
        if field != "deviation":
            raise CompareError(f"Expected a point cloud for the field {field!r}, got the "
                               f"mesh '{path}'; a mesh gives the deviation only.")
        v, f = read_reference(path)
        assert f is not None
        return mesh_samples(v, f, spacing_m)
    if field == "deviation":
        return iter_points(path)
    return iter_field(path, field)


def develop_file(path: str | os.PathLike[str], alignment: Alignment,
                 design: DesignProfile, *, field: str = "deviation", cell_m: float = 0.05,
                 cell_arc_m: float | None = None,
                 chainage_range: tuple[float, float] | None = None,
                 max_deviation_m: float | None = None, zero: str | float = "crown",
                 mesh_spacing_m: float | None = None) -> DevelopedRaster:
    """``develop`` on a file, streamed: a cloud chunk by chunk (``iter_points``, or
    ``iter_field`` for a per-point field such as an M3C2 ``distance`` or the
    ``intensity``), a mesh by area samples every ``mesh_spacing_m`` (default the cell
    / ``MESH_SAMPLES_PER_CELL``). Raises ``PointFileError`` for unreadable files and
    ``CompareError`` for a mesh with a field other than the deviation."""
    h = mesh_spacing_m if mesh_spacing_m is not None else \
        _positive(cell_m, "cell_m") / MESH_SAMPLES_PER_CELL
    chunks = file_chunks(path, field, spacing_m=h)
    r = develop(chunks, alignment, design, field=field,
                unit=FIELD_UNITS.get(field, ""), cell_m=cell_m, cell_arc_m=cell_arc_m,
                chainage_range=chainage_range, max_deviation_m=max_deviation_m, zero=zero)
    r.meta["source"] = Path(path).name
    return r
