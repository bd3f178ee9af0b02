"""Clearance: a gauge or envelope polygon swept along the alignment, and every place
where the lining enters it.

The envelope is a closed polygon in the section frame (offset y to the left, height z
above the alignment, m), the same at every chainage (a structure gauge, a vehicle's
kinematic envelope plus its allowances, a required free cross-section). A point of
the lining (a cloud point, or an area sample of a mesh) at (s, y, z) violates it when
it lies inside the polygon by more than nothing: its margin, the signed distance to
the envelope's boundary (``DesignProfile.locate``, exact, > 0 outside), is negative,
and its depth is -margin (how far it intrudes; a feature must be cut back this much).
``required_m`` > 0 asks for that much free space beyond the envelope: points with a
margin below it are violations, depth ``required_m - margin``.

Positions are reported in the developed frame of the tunnel's design line
(``survey.analysis.developed``: chainage, arc length from the crown, positive to the
left), so violations can be drawn on any developed view, and as offset and height.

Bounded memory: points are streamed; the margin raster (per cell: the smallest
margin) is a ``RasterAccumulator``; per violating cell only its deepest point is kept.
DECISION: the report lists violations per cell of that raster (the deepest point of
each cell with a violation), not per point: a scan holds up to 10^4 points per square
metre, and a list per point would repeat one intrusion thousands of times. Cells that
touch (8-neighbours, across the seam of a closed profile too) form a violation region.

Merging. A profile cloud (stations every 0.5 m, 5 cm cells) or a rough lining breaks
one intrusion into many groups of touching cells: a real profile tunnel gave 609 of
them. With ``merge_gap_m`` violating cells separated by at most that many metres of
cells without a violation (along the chainage and along the arc, each) join one
region; ``"auto"`` takes ``MERGE_GAP_SPACINGS`` times the data's spacing along the
chainage (the station spacing of a profile cloud, found from the raster columns
that hold points; the cell of a dense scan). What was merged is recorded in
``ClearanceResult.meta["merge"]``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points
from survey.analysis.design import DesignProfile, read_design_profile
from survey.analysis.developed import (MESH_SAMPLES_PER_CELL,
    DevelopedFrame,
    DevelopedGrid,
    DevelopedRaster,
    RasterAccumulator,
    file_chunks,
    station_spacing)
from survey.errors import CompareError, ProfileError
from survey.world.alignment import Alignment

__all__ = ["MERGE_GAP_SPACINGS", "ClearanceResult", "ViolationRegion", "Violations",
           "auto_merge_gap", "box_envelope", "chainage_spacing", "clearance",
           "clearance_file", "read_envelope"]

Floats = NDArray[np.float64]

#: The automatic merge gap, in data spacings along the chainage (module doc).
#: DECISION: 2, so violations on successive stations join, and so do those on either
#: side of one missing profile or one empty cell of a rough dense scan; two intrusions
#: closer than this are one place to cut back anyway.
MERGE_GAP_SPACINGS = 2.0


def box_envelope(width_m: float, height_m: float, *, bottom_m: float = 0.0,
                 centre_offset_m: float = 0.0) -> DesignProfile:
    """A rectangular envelope ``width_m`` wide, from ``bottom_m`` to ``bottom_m +
    height_m`` above the alignment, centred at ``centre_offset_m`` (m)."""
    vals = (width_m, height_m, bottom_m, centre_offset_m)
    if not all(np.isfinite(v) for v in vals) or width_m <= 0 or height_m <= 0:
        raise ProfileError(f"Expected a box envelope of positive width and height, got "
                           f"width {width_m} m, height {height_m} m.")
    y0, y1 = centre_offset_m - 0.5 * width_m, centre_offset_m + 0.5 * width_m
    z0, z1 = bottom_m, bottom_m + height_m
    return DesignProfile([[y0, z0], [y1, z0], [y1, z1], [y0, z1]], closed=True,
                         name=f"box {width_m:g} x {height_m:g} m")


def read_envelope(spec: str | os.PathLike[str]) -> DesignProfile:
    """An envelope from ``box:W,H[,BOTTOM]`` (``box_envelope``) or a CSV/TXT file of
    y, z vertices in the section frame (``read_design_profile``, closed). Raises
    ``ProfileError`` for a bad spec, a missing file or a polygon that crosses itself."""
    text = str(spec)
    if text.lower().startswith("box:"):
        try:
            vals = [float(v) for v in text[4:].split(",")]
        except ValueError:
            vals = []
        if len(vals) not in (2, 3):
            raise ProfileError(f"Expected an envelope 'box:WIDTH,HEIGHT[,BOTTOM]' in m, got "
                               f"{text!r}.")
        return box_envelope(vals[0], vals[1], bottom_m=vals[2] if len(vals) == 3 else 0.0)
    return read_design_profile(Path(text), closed=True)


@dataclass(frozen=True, repr=False)
class Violations:
    """The deepest violating point of each violating cell; (k,) arrays, deepest first.

    Attributes
    ----------
    chainage_m, offset_m, height_m : float64, its position (m)
    arc_m : float64, its arc length along the design from the crown (m, + left)
    depth_m : float64, how far it lies inside the envelope (plus ``required_m``)
    points : int64, violating points in the cell
    region : int64, the region it belongs to (1-based)
    """

    chainage_m: Floats
    offset_m: Floats
    height_m: Floats
    arc_m: Floats
    depth_m: Floats
    points: NDArray[np.int64]
    region: NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.depth_m)

    def __repr__(self) -> str:
        if not len(self):
            return "Violations(none)"
        return (f"Violations({len(self)} cells, deepest {1000 * self.depth_m.max():.1f} mm "
                f"at chainage {self.chainage_m[0]:.3f} m)")

    def rows(self) -> list[dict[str, Any]]:
        """One dict per violating cell (JSON-ready)."""
        return [{"chainage_m": float(self.chainage_m[i]), "offset_m": float(self.offset_m[i]),
                 "height_m": float(self.height_m[i]), "arc_m": float(self.arc_m[i]),
                 "depth_m": float(self.depth_m[i]), "points": int(self.points[i]),
                 "region": int(self.region[i])} for i in range(len(self))]


@dataclass(frozen=True)
class ViolationRegion:
    """Touching violating cells: their extent (cell edges, m; a region across the
    invert seam of a closed profile has ``arc_from_m`` > ``arc_to_m``), cells, points,
    area of the developed surface (m^2) and the deepest point."""

    region: int
    chainage_from_m: float
    chainage_to_m: float
    arc_from_m: float
    arc_to_m: float
    cells: int
    points: int
    area_m2: float
    max_depth_m: float
    deepest_chainage_m: float
    deepest_offset_m: float
    deepest_height_m: float
    deepest_arc_m: float

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True, repr=False)
class ClearanceResult:
    """The clearance check of one input against one envelope.

    Attributes
    ----------
    envelope : DesignProfile
    required_m : float, free space asked beyond the envelope (m)
    margin : DevelopedRaster, per cell the smallest margin (m; < required: violation)
    violations : Violations, per violating cell
    regions : tuple of ViolationRegion, by region number (deepest region first)
    points : int, points checked
    violating_points : int, points whose margin is below ``required_m``
    meta : dict, how violating cells were merged into regions ("merge": the gap used
        and why)
    """

    envelope: DesignProfile
    required_m: float
    margin: DevelopedRaster
    violations: Violations
    regions: tuple[ViolationRegion, ...]
    points: int
    violating_points: int
    meta: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        if not self.regions:
            return (f"ClearanceResult({self.envelope.name!r}: clear, {self.points:,} points, "
                    f"smallest margin {1000 * self.min_margin_m:.1f} mm)")
        return (f"ClearanceResult({self.envelope.name!r}: {len(self.regions)} violation "
                f"regions, {self.violating_points:,} of {self.points:,} points, deepest "
                f"{1000 * self.max_depth_m:.1f} mm)")

    @property
    def max_depth_m(self) -> float:
        """Deepest violation (m); 0 when clear."""
        return float(self.violations.depth_m.max()) if len(self.violations) else 0.0

    @property
    def min_margin_m(self) -> float:
        """Smallest margin of any point to the envelope (m; < 0 inside)."""
        m = self.margin.min
        return float(np.nanmin(m)) if np.isfinite(m).any() else float("nan")

    def to_dict(self) -> dict[str, Any]:
        """Summary (JSON-ready): envelope, settings, regions and violating cells."""
        return {"envelope": self.envelope.name,
                "envelope_vertices_m": self.envelope.vertices.tolist(),
                "required_m": self.required_m, "points": self.points,
                "violating_points": self.violating_points,
                "min_margin_m": self.min_margin_m, "max_depth_m": self.max_depth_m,
                "cell_chainage_m": self.margin.grid.cell_s_m,
                "cell_arc_m": self.margin.grid.cell_arc_m,
                "arc": self.margin.meta.get("arc"),
                "regions": [r.to_dict() for r in self.regions],
                "violations": self.violations.rows(), **self.meta}


class _Deepest:
    """Per violating cell: the deepest point so far (sparse; bounded by the grid)."""

    def __init__(self) -> None:
        self.cell = np.empty(0, np.int64)
        self.data = np.empty((0, 5))   # depth, s, offset, height, u
        self.count = np.empty(0, np.int64)

    def add(self, cell: NDArray[np.int64], data: Floats) -> None:
        cell = np.concatenate([self.cell, cell])
        data = np.concatenate([self.data, data])
        ones = np.concatenate([self.count, np.ones(len(cell) - len(self.count), np.int64)])
        # Deepest first within each cell; ties by chainage, so chunking cannot matter.
        order = np.lexsort((data[:, 1], -data[:, 0], cell))
        cell, data, ones = cell[order], data[order], ones[order]
        first = np.concatenate([[True], cell[1:] != cell[:-1]]) if len(cell) else \
            np.empty(0, bool)
        starts = np.nonzero(first)[0]
        self.count = np.add.reduceat(ones, starts) if len(starts) else ones[:0]
        self.cell, self.data = cell[first], data[first]


def _regions(mask: NDArray[np.bool_], wrap: bool) -> tuple[NDArray[np.int64], int]:
    """Labels (8-connected; rows joined across the seam when ``wrap``) of a mask."""
    from scipy import ndimage

    lab, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    lab = lab.astype(np.int64)
    if wrap and n and mask.shape[0] > 1:
        parent = np.arange(n + 1)

        def find(a: int) -> int:
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = int(parent[a])
            return a

        top, bottom = lab[-1], lab[0]
        for dj in (-1, 0, 1):
            b = np.roll(bottom, dj)
            if dj == -1:
                b[-1] = 0
            elif dj == 1:
                b[0] = 0
            both = (top > 0) & (b > 0)
            for x, y in zip(top[both], b[both]):
                rx, ry = find(int(x)), find(int(y))
                if rx != ry:
                    parent[max(rx, ry)] = min(rx, ry)
        roots = np.array([find(k) for k in range(n + 1)])
        uniq, new = np.unique(roots, return_inverse=True)
        lab = new[lab].astype(np.int64)   # root 0 (background) stays 0
        n = len(uniq) - 1
    return lab, n


def chainage_spacing(raster: DevelopedRaster) -> float:
    """The data's spacing along the chainage (m): the station spacing of a profile
    cloud, found from the raster columns that hold points (``station_spacing`` on
    their centres, in bins of the cell: a station slightly skew to the axis fills a
    run of columns), else the cell (a dense scan)."""
    g = raster.grid
    occupied = raster.count.sum(axis=0) > 0
    spacing = station_spacing(g.chainage_centres()[occupied], bin_m=g.cell_s_m)
    return spacing if spacing > 0 else float(g.cell_s_m)


def auto_merge_gap(raster: DevelopedRaster) -> float:
    """The automatic merge gap (m): ``MERGE_GAP_SPACINGS`` x the largest of the data's
    chainage spacing and the two cell sizes."""
    g = raster.grid
    return MERGE_GAP_SPACINGS * max(chainage_spacing(raster), g.cell_s_m, g.cell_arc_m)


def _dilate(mask: NDArray[np.bool_], rows: int, cols: int, wrap: bool) -> NDArray[np.bool_]:
    """One-sided box dilation: a cell is set when a set cell lies at most ``rows`` below
    it and ``cols`` before it (rows wrap on a closed profile). Two set cells' boxes
    then touch (8-neighbours) exactly when at most ``rows`` / ``cols`` empty cells lie
    between them along each axis. Separable: one pass per axis."""
    out = mask.copy()
    for k in range(1, cols + 1):
        if k >= mask.shape[1]:
            break
        out[:, k:] |= mask[:, :-k]
    base = out.copy()
    for k in range(1, rows + 1):
        if wrap:
            out |= np.roll(base, k, axis=0)
        elif k < mask.shape[0]:
            out[k:] |= base[:-k]
    return out


def clearance(points: Any, alignment: Alignment, envelope: DesignProfile,
              design: DesignProfile, *, cell_m: float = 0.05, cell_arc_m: float | None = None,
              chainage_range: tuple[float, float] | None = None, required_m: float = 0.0,
              zero: str | float = "crown", merge_gap_m: float | str | None = None
              ) -> ClearanceResult:
    """Check the points of a lining against an envelope swept along the alignment.

    Parameters
    ----------
    points : (n, 3) array_like or an iterable of (m, 3) chunks
        World points (m; a cloud, or ``mesh_samples`` of a mesh).
    alignment : Alignment
    envelope : DesignProfile
        Closed polygon in the section frame (``read_envelope``).
    design : DesignProfile
        The line of the developed frame (arc positions), usually the tunnel's profile.
    cell_m, cell_arc_m : float
        Raster cells along the chainage and the arc (m).
    chainage_range : (from, to) or None
        Chainages checked (default: the whole alignment).
    required_m : float
        Free space required beyond the envelope (m, >= 0).
    zero : "crown" or float
        Arc-length zero of the developed frame.
    merge_gap_m : float, "auto" or None
        Violating cells at most this far apart (m of cells without a violation, along
        each axis) join one region; None or 0: only touching cells; "auto":
        ``auto_merge_gap`` (module doc).

    Returns
    -------
    ClearanceResult
        ``meta["merge"]``: the gap, how it was chosen, the groups of touching cells and
        the regions they were merged into.

    Raises
    ------
    CompareError
        An open envelope, a negative ``required_m`` or ``merge_gap_m``, and the errors
        of ``develop``'s grid.
    AlignmentError
        A range outside the alignment.
    """
    if not isinstance(envelope, DesignProfile) or not envelope.closed:
        raise CompareError("Expected a closed envelope polygon (a DesignProfile with "
                           f"closed=True), got {envelope!r}.")
    req = float(required_m)
    if not (np.isfinite(req) and req >= 0):
        raise CompareError(f"Expected `required_m` >= 0, got {required_m!r}.")
    auto = isinstance(merge_gap_m, str)
    if auto and merge_gap_m != "auto":
        raise CompareError(f"Expected `merge_gap_m` 'auto', None or a gap >= 0 m, got "
                           f"{merge_gap_m!r}.")
    gap = 0.0 if merge_gap_m is None or isinstance(merge_gap_m, str) else float(merge_gap_m)
    if not (np.isfinite(gap) and gap >= 0):
        raise CompareError(f"Expected `merge_gap_m` >= 0 m, got {merge_gap_m!r}.")
    frame = DevelopedFrame(alignment, design, zero=zero)
    grid = DevelopedGrid.covering(frame, cell_m, cell_arc_m=cell_arc_m,
                                  chainage_range=chainage_range)
    acc = RasterAccumulator(grid)
    deep = _Deepest()
    checked = violating = 0
    chunks = [points] if isinstance(points, np.ndarray) or not hasattr(points, "__iter__") \
        else points
    for chunk in chunks:
        p, _ = as_points(chunk, "points", CompareError)
        if len(p) == 0:
            continue
        s, u, _, off, h = frame.locate(p)
        margin, _ = envelope.locate(np.stack([off, h], axis=1))
        cells = grid.cells(s, u)
        checked += acc.add(s, u, margin)
        bad = (cells >= 0) & (margin < req)
        violating += int(bad.sum())
        if bad.any():
            deep.add(cells[bad], np.stack([req - margin[bad], s[bad], off[bad], h[bad],
                                           u[bad]], axis=1))
    raster = acc.raster(field="margin", unit="m", frame=frame,
                        meta={"points": checked, "envelope": envelope.name,
                              "required_m": req})
    mask = np.zeros(grid.shape, bool)
    rows, cols = np.divmod(deep.cell, grid.n_s)
    mask[rows, cols] = True
    lab, n = _regions(mask, grid.wrap)
    touching = n
    if auto:
        gap = auto_merge_gap(raster)
    if gap > 0 and n > 1:
        # Empty cells allowed between two violating cells of one region, per axis.
        gr = int(np.floor(gap / grid.cell_arc_m + 1e-9))
        gc = int(np.floor(gap / grid.cell_s_m + 1e-9))
        lab, n = _regions(_dilate(mask, gr, gc, grid.wrap), grid.wrap)
        # Renumber 1..n over the regions that hold violating cells.
        used = np.unique(lab[rows, cols])
        remap = np.zeros(int(lab.max()) + 1, np.int64)
        remap[used] = np.arange(1, len(used) + 1)
        lab = remap[lab]
        n = len(used)
    reg_of = lab[rows, cols]
    d = deep.data
    regions = []
    for k in range(1, n + 1):
        m = reg_of == k
        r_k, c_k = rows[m], cols[m]
        j = int(np.argmax(d[m, 0]))
        arcs = np.unique(r_k)
        if grid.wrap and len(arcs) > 1 and (0 in arcs) and (grid.n_arc - 1 in arcs):
            # Across the seam: the extent runs from the first row after the largest gap.
            gaps = np.diff(np.append(arcs, arcs[0] + grid.n_arc))
            g = int(np.argmax(gaps))
            a_lo = grid.arc0_m + arcs[(g + 1) % len(arcs)] * grid.cell_arc_m
            a_hi = grid.arc0_m + (arcs[g] + 1) * grid.cell_arc_m
        else:
            a_lo = grid.arc0_m + r_k.min() * grid.cell_arc_m
            a_hi = grid.arc0_m + (r_k.max() + 1) * grid.cell_arc_m
        regions.append(ViolationRegion(
            region=k, chainage_from_m=float(grid.chainage0_m + c_k.min() * grid.cell_s_m),
            chainage_to_m=float(grid.chainage0_m + (c_k.max() + 1) * grid.cell_s_m),
            arc_from_m=float(a_lo), arc_to_m=float(a_hi), cells=int(m.sum()),
            points=int(deep.count[m].sum()),
            area_m2=float(m.sum() * grid.cell_s_m * grid.cell_arc_m),
            max_depth_m=float(d[m, 0][j]), deepest_chainage_m=float(d[m, 1][j]),
            deepest_offset_m=float(d[m, 2][j]), deepest_height_m=float(d[m, 3][j]),
            deepest_arc_m=float(d[m, 4][j])))
    # Number regions deepest first (then by chainage), as a report lists them.
    regions.sort(key=lambda r: (-r.max_depth_m, r.chainage_from_m))
    renum = {r.region: i + 1 for i, r in enumerate(regions)}
    regions = [ViolationRegion(**{**r.to_dict(), "region": renum[r.region]}) for r in regions]
    region_no = np.array([renum[int(k)] for k in reg_of], np.int64)
    order = np.lexsort((d[:, 1], -d[:, 0])) if len(d) else np.empty(0, np.int64)
    viol = Violations(d[order, 1], d[order, 2], d[order, 3], d[order, 4], d[order, 0],
                      deep.count[order], region_no[order])
    how = ("auto: " f"{MERGE_GAP_SPACINGS:g} x the data's chainage spacing "
           f"{chainage_spacing(raster):.3g} m (or the cell)") if auto else \
        ("given" if gap > 0 else "none: touching cells only")
    merge = {"gap_m": gap, "chosen": how, "touching_groups": touching, "regions": n}
    return ClearanceResult(envelope, req, raster, viol, tuple(regions), checked, violating,
                           {"merge": merge})


def clearance_file(path: str | os.PathLike[str], alignment: Alignment,
                   envelope: DesignProfile, design: DesignProfile, *, cell_m: float = 0.05,
                   cell_arc_m: float | None = None,
                   chainage_range: tuple[float, float] | None = None,
                   required_m: float = 0.0, zero: str | float = "crown",
                   mesh_spacing_m: float | None = None,
                   merge_gap_m: float | str | None = None) -> ClearanceResult:
    """``clearance`` on a file, streamed: a cloud chunk by chunk, a mesh by area samples
    every ``mesh_spacing_m`` (default the cell / ``MESH_SAMPLES_PER_CELL``; a depth is
    then exact at the samples, and a mesh vertex deeper than every sample near it is
    found to within the spacing times the surface's slope)."""
    h = float(mesh_spacing_m) if mesh_spacing_m is not None else \
        float(cell_m) / MESH_SAMPLES_PER_CELL
    res = clearance(file_chunks(path, "deviation", spacing_m=h), alignment, envelope,
                    design, cell_m=cell_m, cell_arc_m=cell_arc_m,
                    chainage_range=chainage_range, required_m=required_m, zero=zero,
                    merge_gap_m=merge_gap_m)
    res.meta["source"] = Path(path).name
    res.margin.meta["source"] = Path(path).name
    return res

