"""Sections against design: over- and under-break, areas, volumes, tolerance classes.

Each section's points are located on the design line (``DesignProfile.locate``: signed
deviation, > 0 outside = overbreak, and the arc length t of the closest design point).
The as-built line is the median deviation in bins of ``bin_m`` along the design
(robust to noise and stray points, and every length of the design weighs the same,
wherever the scanner stood); bins without points are gaps, filled by linear
interpolation when shorter than ``max_gap_m`` and left out of the areas otherwise
(``coverage`` says how much of the design was seen). A bin's median stands for its
centre to within the point spacing times the slope of the deviation along the design.

Areas: the region between the design line and the as-built line is cut into pieces
between neighbouring bin centres, quadrilaterals (design point, next design point,
next as-built point, as-built point) split at the zero crossing where the deviation
changes sign; their exact polygon areas (shoelace) include the curvature term
integral of (d + kappa d^2 / 2) dt that a plain integral of d would miss. Overbreak
and underbreak areas are the sums of the outside and inside pieces.

Volumes between consecutive sections: the average end-area rule (V = L (A1 + A2) / 2,
the earthworks standard), with Pappus's centroid theorem for curved alignments: an area
whose centroid lies at offset y (left) on a plan curve of curvature kappa sweeps
A (1 - kappa y) per metre of chainage, so each end area is weighted by that factor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from survey.analysis.design import DesignProfile
from survey.analysis.sections import SectionCut
from survey.errors import CompareError
from survey.world.alignment import Alignment

__all__ = ["BIN_M", "MAX_GAP_M", "PLOT_POINTS", "TOLERANCE_EDGES_M", "Section",
           "SectionReport", "Volume", "class_labels", "compare_sections"]

Floats = NDArray[np.float64]

#: Bin length along the design line for the as-built line (m). ASSUMED 5 cm: finer
#: than an as-built report's usual 10-20 cm stations around the profile, coarse enough
#: for tens of points per bin at TLS densities.
BIN_M = 0.05
#: Gaps in the as-built line up to this length are interpolated (m). ASSUMED.
MAX_GAP_M = 0.5
#: Class edges of the deviation (m): below -20 mm (underbreak beyond tolerance), -20 to
#: 0, 0 to 50, 50 to 100, 100 to 200 mm and beyond. ASSUMED; typical of drill-and-blast
#: contracts (no underbreak tolerated beyond a few centimetres, overbreak paid in bands).
TOLERANCE_EDGES_M = (-0.02, 0.0, 0.05, 0.10, 0.20)
#: Points of each section kept for its plot (a random subset).
PLOT_POINTS = 20_000


def class_labels(edges_m: Sequence[float]) -> list[str]:
    """Labels of the classes between ``edges_m`` (in mm): "< -20", "-20 to 0", ...,
    "> 200"."""
    e = [f"{1000 * v:g}" for v in edges_m]
    return [f"< {e[0]}"] + [f"{a} to {b}" for a, b in zip(e[:-1], e[1:])] + [f"> {e[-1]}"]


@dataclass(frozen=True)
class Section:
    """One section compared with the design (lengths m, areas m^2).

    Attributes
    ----------
    chainage_m, half_width_m : float
        Where the section is and its band's half-width.
    n_points : int
        Points compared (those beyond the ends of an open design are not).
    t_m : (b,) float64
        Bin centres along the design line.
    deviation_m : (b,) float64
        As-built line: median deviation per bin (> 0 overbreak), gaps NaN.
    count : (b,) int64
        Points per bin.
    coverage : float
        Share of the design length with points (0-1).
    mean_m, max_m, min_m : float
        Mean (length-weighted), largest and smallest deviation of the observed bins:
        ``max_m`` is the largest overbreak, ``min_m`` (< 0) the largest underbreak.
    overbreak_area_m2, underbreak_area_m2 : float
        Areas outside and inside the design line (both >= 0).
    overbreak_offset_m, underbreak_offset_m : float
        Offsets (left) of those areas' centroids (for Pappus volumes); NaN without area.
    class_share : (c,) float64
        Share of the observed design length in each tolerance class.
    plot_yz, plot_deviation : (k, 2), (k,) float64
        A random subset of the points and their deviations, for plots.
    """

    chainage_m: float
    half_width_m: float
    n_points: int
    t_m: Floats = field(repr=False)
    deviation_m: Floats = field(repr=False)
    count: NDArray[np.int64] = field(repr=False)
    coverage: float
    mean_m: float
    max_m: float
    min_m: float
    overbreak_area_m2: float
    underbreak_area_m2: float
    overbreak_offset_m: float
    underbreak_offset_m: float
    class_share: Floats = field(repr=False)
    plot_yz: Floats = field(repr=False)
    plot_deviation: Floats = field(repr=False)

    @property
    def net_area_m2(self) -> float:
        """Overbreak minus underbreak area (m^2)."""
        return self.overbreak_area_m2 - self.underbreak_area_m2

    def to_dict(self) -> dict[str, Any]:
        """The summary figures (JSON-ready)."""
        return {"chainage_m": self.chainage_m, "half_width_m": self.half_width_m,
                "n_points": self.n_points, "coverage": self.coverage,
                "mean_m": self.mean_m, "max_m": self.max_m, "min_m": self.min_m,
                "overbreak_area_m2": self.overbreak_area_m2,
                "underbreak_area_m2": self.underbreak_area_m2,
                "net_area_m2": self.net_area_m2,
                "class_share": self.class_share.tolist()}


@dataclass(frozen=True)
class Volume:
    """Volumes (m^3) between two consecutive sections (average end areas, Pappus)."""

    from_m: float
    to_m: float
    overbreak_m3: float
    underbreak_m3: float

    @property
    def net_m3(self) -> float:
        return self.overbreak_m3 - self.underbreak_m3


@dataclass(frozen=True)
class SectionReport:
    """Sections compared with a design: ``sections`` (by chainage), ``volumes``
    between consecutive ones, the ``design``, the class ``tolerance_edges_m`` and the
    ``bin_m`` used."""

    sections: tuple[Section, ...]
    volumes: tuple[Volume, ...]
    design: DesignProfile
    tolerance_edges_m: tuple[float, ...]
    bin_m: float

    def __repr__(self) -> str:
        return (f"SectionReport({len(self.sections)} sections against {self.design.name!r}, "
                f"overbreak {self.overbreak_m3:.3f} m^3, underbreak "
                f"{self.underbreak_m3:.3f} m^3)")

    @property
    def overbreak_m3(self) -> float:
        """Total overbreak volume between the first and last section (m^3)."""
        return float(sum(v.overbreak_m3 for v in self.volumes))

    @property
    def underbreak_m3(self) -> float:
        """Total underbreak volume between the first and last section (m^3)."""
        return float(sum(v.underbreak_m3 for v in self.volumes))

    def to_dict(self) -> dict[str, Any]:
        """Summary (JSON-ready): design, settings, sections and volumes."""
        return {"design": self.design.name, "design_closed": self.design.closed,
                "design_length_m": self.design.length_m, "bin_m": self.bin_m,
                "tolerance_edges_m": list(self.tolerance_edges_m),
                "classes_mm": class_labels(self.tolerance_edges_m),
                "overbreak_m3": self.overbreak_m3, "underbreak_m3": self.underbreak_m3,
                "sections": [s.to_dict() for s in self.sections],
                "volumes": [{"from_m": v.from_m, "to_m": v.to_m,
                             "overbreak_m3": v.overbreak_m3,
                             "underbreak_m3": v.underbreak_m3} for v in self.volumes]}


def _bin_medians(b: NDArray[np.intp], d: Floats, nb: int) -> tuple[Floats, NDArray[np.int64]]:
    """Median of d per bin b (nb bins; NaN where empty) and the counts."""
    order = np.lexsort((d, b))
    bs, ds = b[order], d[order]
    count = np.bincount(bs, minlength=nb).astype(np.int64)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    med = np.full(nb, np.nan)
    ok = count > 0
    lo = start[ok] + (count[ok] - 1) // 2
    hi = start[ok] + count[ok] // 2
    med[ok] = 0.5 * (ds[lo] + ds[hi])
    return med, count


def _fill_gaps(t: Floats, d: Floats, length: float, closed: bool, max_gap: float) -> Floats:
    """d with NaN runs no longer than ``max_gap`` (in t) filled linearly (periodic when
    closed; never beyond the first or last observed bin of an open line)."""
    ok = np.isfinite(d)
    if ok.all() or ok.sum() < 2:
        return d
    out = d.copy()
    to, do = t[ok], d[ok]
    if closed:
        fill = np.interp(t, to, do, period=length)
        nxt = np.searchsorted(to, t) % len(to)
        prv = (nxt - 1) % len(to)
        gap = np.mod(to[nxt] - to[prv], length)
    else:
        fill = np.interp(t, to, do)
        nxt = np.clip(np.searchsorted(to, t), 0, len(to) - 1)
        prv = np.clip(nxt - 1, 0, len(to) - 1)
        gap = np.where((t < to[0]) | (t > to[-1]), np.inf, to[nxt] - to[prv])
    use = ~ok & (gap <= max_gap + 1e-12)
    out[use] = fill[use]
    return out


def _shoelace(poly: Floats) -> tuple[Floats, Floats]:
    """Signed area (counter-clockwise > 0) and centroid offset y of polygons (n, k, 2)."""
    x, y = poly[..., 0], poly[..., 1]
    x1, y1 = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    cr = x * y1 - x1 * y
    a = 0.5 * cr.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cy = np.where(a != 0, ((x + x1) * cr).sum(axis=1) / (6.0 * a), 0.0)
    return a, cy


def _areas(design: DesignProfile, t: Floats, d: Floats
           ) -> tuple[float, float, float, float]:
    """(overbreak area, underbreak area, their centroid offsets) between the design and
    the as-built line d(t) (bins; NaN gaps break the line)."""
    if design.closed:
        i = np.arange(len(t))
        j = (i + 1) % len(t)
        ta, tb = t[i], t[j]
        tb = np.where(tb < ta, tb + design.length_m, tb)
        da, db = d[i], d[j]
    else:
        # The end half-bins: the first and last values held to the ends of the line.
        tt = np.concatenate([[0.0], t, [design.length_m]])
        dd = np.concatenate([d[:1], d, d[-1:]])
        ta, tb, da, db = tt[:-1], tt[1:], dd[:-1], dd[1:]
    ok = np.isfinite(da) & np.isfinite(db)
    ta, tb, da, db = ta[ok], tb[ok], da[ok], db[ok]
    pa, pb = design.points(ta), design.points(tb)
    # Normals of the segment at each end (not at the piece's middle): the as-built
    # point is the design point moved along the normal there.
    qa = pa + da[:, None] * design.normals(ta)
    qb = pb + db[:, None] * design.normals(tb)
    change = (da * db) < 0
    vals, ys = [], []
    same = ~change
    if same.any():
        a, cy = _shoelace(np.stack([pa[same], pb[same], qb[same], qa[same]], axis=1))
        vals.append(-a)
        ys.append(cy)
    if change.any():
        f = da[change] / (da[change] - db[change])
        z = pa[change] + f[:, None] * (pb[change] - pa[change])
        a1, c1 = _shoelace(np.stack([pa[change], z, qa[change]], axis=1))
        a2, c2 = _shoelace(np.stack([z, pb[change], qb[change]], axis=1))
        vals += [-a1, -a2]
        ys += [c1, c2]
    v = np.concatenate(vals) if vals else np.empty(0)
    y = np.concatenate(ys) if ys else np.empty(0)
    over, under = np.clip(v, 0, None), np.clip(-v, 0, None)
    ao, au = float(over.sum()), float(under.sum())
    yo = float((over * y).sum() / ao) if ao > 0 else float("nan")
    yu = float((under * y).sum() / au) if au > 0 else float("nan")
    return ao, au, yo, yu


def _section(cut: SectionCut, design: DesignProfile, bin_m: float, max_gap_m: float,
             edges: Floats, rng: np.random.Generator) -> Section:
    where = f"chainage {cut.chainage_m:g} m" + \
        (f" +- {cut.half_width_m:g} m" if cut.half_width_m else "")
    if len(cut.yz) == 0:
        raise CompareError(f"Expected points in the section band at {where}, got none; "
                           "widen the band or leave this chainage out (a gap in the "
                           "scan?).")
    dev, t = design.locate(cut.yz)
    ok = np.isfinite(dev)
    if not ok.any():
        raise CompareError(f"Expected points along the design line at {where}, got "
                           f"{len(dev)} points all beyond the ends of the open design "
                           f"'{design.name}'; is the design in the section frame?")
    length = design.length_m
    nb = max(1, int(np.ceil(length / bin_m - 1e-9)))
    width = length / nb
    tc = np.asarray((np.arange(nb) + 0.5) * width, dtype=np.float64)
    b = np.clip((t[ok] / width).astype(np.intp), 0, nb - 1)
    med, count = _bin_medians(b, dev[ok], nb)
    filled = _fill_gaps(tc, med, length, design.closed, max_gap_m)
    seen = np.isfinite(med)
    ao, au, yo, yu = _areas(design, tc, filled)
    cls = np.bincount(np.digitize(med[seen], edges), minlength=len(edges) + 1)
    pick = rng.permutation(len(dev))[:PLOT_POINTS]
    return Section(
        chainage_m=cut.chainage_m, half_width_m=cut.half_width_m, n_points=int(ok.sum()),
        t_m=tc, deviation_m=med, count=count, coverage=float(seen.mean()),
        mean_m=float(med[seen].mean()), max_m=float(med[seen].max()),
        min_m=float(med[seen].min()), overbreak_area_m2=ao, underbreak_area_m2=au,
        overbreak_offset_m=yo, underbreak_offset_m=yu,
        class_share=cls / max(1, int(seen.sum())),
        plot_yz=cut.yz[pick], plot_deviation=dev[pick])


def compare_sections(cuts: Sequence[SectionCut], design: DesignProfile, *,
                     alignment: Alignment | None = None, bin_m: float = BIN_M,
                     max_gap_m: float = MAX_GAP_M,
                     tolerance_edges_m: Sequence[float] = TOLERANCE_EDGES_M,
                     seed: int = 0) -> SectionReport:
    """Compare sections with a design profile.

    Parameters
    ----------
    cuts : sequence of SectionCut
        From ``cut_cloud``, ``cut_file`` or ``cut_mesh``, in the design's frame.
    design : DesignProfile
    alignment : Alignment or None
        For the plan curvature of the Pappus volume factor; None: straight.
    bin_m : float
        Bin length along the design line (m).
    max_gap_m : float
        Longest gap of the as-built line that is interpolated (m).
    tolerance_edges_m : sequence of float
        Increasing class edges of the deviation (m).
    seed : int
        Seed of the plotted point subsets.

    Returns
    -------
    SectionReport

    Raises
    ------
    CompareError
        An empty band (one message naming its chainage), a band whose points all lie
        beyond an open design's ends, or bad settings.
    """
    if not isinstance(design, DesignProfile):
        raise CompareError(f"Expected a DesignProfile, got {type(design).__name__}.")
    bin_m, max_gap_m = float(bin_m), float(max_gap_m)
    if not (np.isfinite(bin_m) and bin_m > 0):
        raise CompareError(f"Expected a positive bin length, got {bin_m} m.")
    if not (np.isfinite(max_gap_m) and max_gap_m >= 0):
        raise CompareError(f"Expected a gap length >= 0, got {max_gap_m} m.")
    edges = np.asarray(tolerance_edges_m, dtype=np.float64).ravel()
    if len(edges) == 0 or not np.isfinite(edges).all() or (np.diff(edges) <= 0).any():
        raise CompareError(f"Expected increasing, finite tolerance class edges, got "
                           f"{edges.tolist()}.")
    if len(cuts) == 0:
        raise CompareError("Expected at least one section, got none.")
    rng = np.random.default_rng(seed)
    cuts = sorted(cuts, key=lambda c: c.chainage_m)
    secs = tuple(_section(c, design, bin_m, max_gap_m, edges, rng) for c in cuts)
    s = np.array([x.chainage_m for x in secs])
    kappa = alignment.plan(s)[2] if alignment is not None else np.zeros(len(s))

    def swept(area: float, y: float, k: float) -> float:
        return area * (1.0 - k * y) if area > 0 else 0.0

    vols = []
    for i in range(len(secs) - 1):
        a, b = secs[i], secs[i + 1]
        ln = b.chainage_m - a.chainage_m
        vo = 0.5 * ln * (swept(a.overbreak_area_m2, a.overbreak_offset_m, kappa[i])
                         + swept(b.overbreak_area_m2, b.overbreak_offset_m, kappa[i + 1]))
        vu = 0.5 * ln * (swept(a.underbreak_area_m2, a.underbreak_offset_m, kappa[i])
                         + swept(b.underbreak_area_m2, b.underbreak_offset_m, kappa[i + 1]))
        vols.append(Volume(a.chainage_m, b.chainage_m, float(vo), float(vu)))
    return SectionReport(secs, tuple(vols), design, tuple(float(e) for e in edges), bin_m)
