"""Developed views and clearance reports: PNG with a colour bar, the raster as NPY with
a JSON sidecar that writes its grid down, tiles along long tunnels, and the clearance
violations as CSV and Markdown.

Raster files. ``<stem>_<from>_<to>.npy`` holds one statistic (float32, NaN = no data)
as an array (rows = arc length, columns = chainage); ``<stem>_<from>_<to>.json`` beside
it gives the grid (lower edges of cell 0, cell sizes, shape), the field and its unit,
the statistic, the arc's zero and direction, the design, the alignment and the CRS.
Chainages in names are surveyors' km+m (``0+100.000``). Every file is written
atomically.

Colours. Deviations and differences (and the clearance margin) on a diverging map
(RdBu; red for overbreak and for a violated margin) with limits symmetric about 0: by
default the ``LIMIT_PERCENTILE`` of |value| over the cells with data (``colour_scale``),
so portal terrain or a fitting metres off does not set the scale; cells beyond it take
the end colours and the colour bar shows arrows; the scale chosen is written to each
JSON sidecar (``colour_scale``). The intensity in grey; cells without data are
transparent over a hatched background, so "no data" never looks like a value. A
clearance figure outlines every region and labels the ``LABELLED_REGIONS`` deepest.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from survey.analysis.clearance import ClearanceResult, ViolationRegion
from survey.analysis.developed import DevelopedRaster
from survey.errors import CompareError

__all__ = ["LABELLED_REGIONS", "LIMIT_PERCENTILE", "RASTER_FORMAT", "ColourScale",
           "clearance_markdown", "chainage_label", "colour_scale", "merge_line",
           "plot_developed",
           "regions_csv", "tile_stem", "violations_csv", "write_developed"]

#: Identifies the JSON sidecars of developed rasters (and their version).
RASTER_FORMAT = "tunnelsim developed raster 1"
#: Percentile of ``|value|`` over the cells with data that sets a diverging colour bar's
#: limits when none is given (the same on every tile).
#: DECISION: 98, not 99.9 (issue 31): a profile tunnel's portal terrain or a fitting
#: metres off the design fills more than 0.1 % of the cells and set a +-2.8 m bar on
#: a real tunnel, which hid millimetre changes; 2 % of cells may now lie beyond the
#: bar (drawn in the end colours; the bar's arrows say so, and the sidecar JSON and
#: developed.md give the share).
LIMIT_PERCENTILE = 98.0
#: Regions labelled (R<n>: depth) on a clearance figure: the deepest ones; every region
#: is still outlined and listed in regions.csv. DECISION: 12 labels stay readable on an
#: 8-18 inch wide figure; thousands overprinted each other (issue 31).
LABELLED_REGIONS = 12
#: Values in mm on the colour bar for these units (metres are too coarse to read).
_MM_FIELDS = ("deviation", "distance", "margin")


def chainage_label(chainage_m: float) -> str:
    """``0+100.000``: km+m, the surveyors' chainage notation (negative: ``-0+005.000``)."""
    sign = "-" if chainage_m < 0 else ""
    a = abs(float(chainage_m))
    km = int(np.floor(a / 1000.0 + 1e-12))
    return f"{sign}{km}+{a - 1000 * km:07.3f}"


def tile_stem(stem: str, from_m: float, to_m: float) -> str:
    """``<stem>_0+000.000_0+100.000``."""
    return f"{stem}_{chainage_label(from_m)}_{chainage_label(to_m)}"


@dataclass(frozen=True)
class ColourScale:
    """The diverging colour bar of a developed view: +-``limit`` in the raster's unit,
    how it was chosen (``source``: "given", "percentile" or "tolerance"), the share of
    cells with data beyond it (drawn in the end colours) and, for "tolerance", the
    class ``edges`` (increasing, the raster's unit) that colour the view in classes."""

    limit: float
    source: str
    percentile: float | None
    beyond_share: float
    edges: tuple[float, ...] | None = None

    def to_dict(self, unit: str) -> dict[str, Any]:
        if self.source == "given":
            chosen = "given (--limit-mm)"
        elif self.source == "tolerance":
            chosen = "tolerance classes (--tolerance)"
        else:
            chosen = (f"{self.percentile:g}th percentile of |value| over the cells with "
                      "data (default)")
        return {"limit": self.limit, "unit": unit, "symmetric_about_zero": True,
                "chosen": chosen, "cells_beyond_share": self.beyond_share,
                "class_edges": None if self.edges is None else list(self.edges)}


def colour_scale(raster: DevelopedRaster, stat: str = "mean", *,
                 limit: float | None = None,
                 edges: Sequence[float] | None = None) -> ColourScale | None:
    """The diverging colour scale of ``raster``'s ``stat`` (None for the intensity and
    the count, which are not diverging): ``limit`` (the raster's unit) when given, else
    the ``LIMIT_PERCENTILE`` of |value| over the cells with data (1 mm when they are
    all 0). ``edges``: tolerance class edges (increasing, the raster's unit): the
    view is coloured in those classes, the limit is the largest |edge|."""
    if raster.field == "intensity" or stat == "count":
        return None
    data = raster.statistic(stat)
    ok = np.isfinite(data)
    v = np.abs(data[ok])
    e = None
    if edges is not None:
        e = tuple(float(x) for x in edges)
        if not e or any(b <= a for a, b in zip(e, e[1:])) or \
                not all(np.isfinite(x) for x in e):
            raise CompareError(f"Expected increasing finite class edges, got "
                               f"{list(edges)}.")
        lim, src, q = max(abs(e[0]), abs(e[-1])) or 1e-3, "tolerance", None
    elif limit is not None:
        lim, src, q = float(limit), "given", None
    else:
        lim = float(np.percentile(v, LIMIT_PERCENTILE)) if len(v) else 0.0
        lim, src, q = (lim if lim > 0 else 1e-3), "percentile", LIMIT_PERCENTILE
    if e is not None:
        w = data[ok]
        beyond = float(((w < e[0]) | (w > e[-1])).mean()) if len(w) else 0.0
    else:
        beyond = float((v > lim).mean()) if len(v) else 0.0
    return ColourScale(lim, src, q, beyond, e)


def _sidecar(raster: DevelopedRaster, stat: str, cols: slice, npy_name: str,
             crs: str | None, scale: ColourScale | None = None) -> dict[str, Any]:
    g = raster.grid
    grid = g.to_dict()
    grid["chainage_origin_m"] = g.chainage0_m + (cols.start or 0) * g.cell_s_m
    grid["columns"] = (cols.stop or g.n_s) - (cols.start or 0)
    return {"format": RASTER_FORMAT, "file": npy_name, "field": raster.field,
            "unit": raster.unit if stat != "count" else "1", "statistic": stat,
            "array": {"shape": [g.n_arc, grid["columns"]], "dtype": "float32",
                      "rows": "arc length u along the design from the zero (m), "
                              "increasing with the row index",
                      "columns": "chainage (m), increasing with the column index",
                      "no_data": "NaN"},
            "grid": grid, "crs": crs,
            "colour_scale": None if scale is None else scale.to_dict(raster.unit),
            **{k: v for k, v in raster.meta.items() if k not in ("grid",)}}


def write_developed(raster: DevelopedRaster, folder: str | Path, *, stem: str | None = None,
                    tile_m: float | None = None, stat: str = "mean", png: bool = True,
                    crs: str | None = None, limit: float | None = None,
                    regions: Sequence[ViolationRegion] = (),
                    edges: Sequence[float] | None = None) -> list[Path]:
    """Write the raster's ``stat`` as NPY + JSON (+ PNG) into ``folder``: one set, or
    one per tile of ``tile_m`` metres (chainages at whole multiples of it). Returns the
    paths written. ``limit``: colour-bar limit in the raster's unit (default the
    ``LIMIT_PERCENTILE`` of ``|value|``, ``colour_scale``; written to each JSON sidecar
    as ``colour_scale``); ``edges``: tolerance class edges that colour the view in
    classes instead; ``regions`` are outlined on the PNGs."""
    from raytrace.fileio import atomic_writer, write_json

    folder = Path(folder)
    stem = stem or f"developed_{raster.field}"
    data = raster.statistic(stat)
    g = raster.grid
    if tile_m is None:
        tiles = [(g.chainage0_m, g.chainage0_m + g.n_s * g.cell_s_m, slice(0, g.n_s))]
    else:
        tiles = g.tiles(tile_m)
    scale = colour_scale(raster, stat, limit=limit, edges=edges)
    lim = None if scale is None else scale.limit
    out: list[Path] = []
    for a, b, cols in tiles:
        name = tile_stem(stem, a, b)
        npy = folder / f"{name}.npy"
        with atomic_writer(npy) as fh:
            np.save(fh, np.ascontiguousarray(data[:, cols], dtype=np.float32))
        out.append(npy)
        out.append(write_json(folder / f"{name}.json",
                              _sidecar(raster, stat, cols, npy.name, crs, scale)))
        if png:
            out.append(plot_developed(raster, folder / f"{name}.png", stat=stat,
                                      columns=cols, limit=lim, regions=regions,
                                      edges=None if scale is None else scale.edges))
    return out


def plot_developed(raster: DevelopedRaster, path: str | Path, *, stat: str = "mean",
                   columns: slice | None = None, limit: float | None = None,
                   regions: Sequence[ViolationRegion] = (), title: str | None = None,
                   edges: Sequence[float] | None = None) -> Path:
    """PNG of a developed view (chainage across, arc length up, crown at 0, left wall
    above it) with a colour bar (in classes at ``edges``, the raster's unit, when
    given); ``regions`` outlined, the ``LABELLED_REGIONS`` deepest numbered; atomic."""
    import matplotlib.patches as mpatches

    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    g = raster.grid
    cols = columns if columns is not None else slice(0, g.n_s)
    data = raster.statistic(stat)[:, cols]
    j0 = cols.start or 0
    j1 = cols.stop if cols.stop is not None else g.n_s
    s0 = g.chainage0_m + j0 * g.cell_s_m
    s1 = g.chainage0_m + j1 * g.cell_s_m
    a0, a1 = g.arc0_m, g.arc0_m + g.n_arc * g.cell_arc_m
    mm = raster.field in _MM_FIELDS and stat != "count"
    shown = data * 1000.0 if mm else data
    unit = "mm" if mm else ("points" if stat == "count" else raster.unit)
    ok = np.isfinite(shown)
    if stat == "count" or raster.field == "intensity":
        cmap = plt.get_cmap("viridis" if stat == "count" else "gray").copy()
        lo, hi = (np.percentile(shown[ok], [1, 99]) if ok.any() else (0.0, 1.0))
        vmin, vmax = float(lo), float(max(hi, lo + 1e-12))
    else:
        # DECISION: red is the bad side: overbreak and convergence for deviations, a
        # violation (negative margin) for the clearance margin.
        cmap = plt.get_cmap("RdBu" if raster.field == "margin" else "RdBu_r").copy()
        lim = (limit * (1000.0 if mm else 1.0)) if limit is not None else \
            (float(np.nanmax(np.abs(shown))) if ok.any() else 1.0)
        lim = lim if lim > 0 else 1.0
        vmin, vmax = -lim, lim
    cmap = cmap.with_extremes(bad=(0, 0, 0, 0))
    width = float(np.clip(0.12 * (s1 - s0) + 3.0, 8.0, 18.0))
    fig, ax = plt.subplots(figsize=(width, 4.8), dpi=110)
    ax.add_patch(mpatches.Rectangle((s0, a0), s1 - s0, a1 - a0, fill=False, hatch="///",
                                    ec="0.75", lw=0, zorder=0))
    norm = None
    if edges is not None and not (stat == "count" or raster.field == "intensity"):
        from matplotlib.colors import BoundaryNorm

        b = np.asarray(edges, dtype=np.float64) * (1000.0 if mm else 1.0)
        norm = BoundaryNorm(b, ncolors=cmap.N, extend="both")
    im = ax.imshow(np.ma.masked_invalid(shown), origin="lower", aspect="auto",
                   extent=(s0, s1, a0, a1), cmap=cmap, interpolation="nearest", zorder=1,
                   **({"norm": norm} if norm is not None else {"vmin": vmin, "vmax": vmax}))
    label = {"deviation": "deviation from design", "distance": "distance (epoch 2 - 1)",
             "intensity": "intensity", "margin": "clearance margin"}.get(raster.field,
                                                                         raster.field)
    extend = "neither"
    if norm is not None:
        extend = "both"
        vmin, vmax = float(norm.boundaries[0]), float(norm.boundaries[-1])
    elif ok.any() and not (stat == "count" or raster.field == "intensity"):
        over, under = bool((shown[ok] > vmax).any()), bool((shown[ok] < vmin).any())
        extend = {(True, True): "both", (True, False): "max", (False, True): "min"}.get(
            (over, under), "neither")
    cb = fig.colorbar(im, ax=ax, pad=0.01, extend=extend)
    cb.set_label(f"{label}, {stat} ({unit})")
    ax.axhline(0.0, color="k", lw=0.5, ls=":", zorder=2)
    # Regions are numbered deepest first: only the deepest LABELLED_REGIONS get a label.
    for r in regions:
        if r.chainage_to_m < s0 or r.chainage_from_m > s1:
            continue
        spans = [(r.arc_from_m, r.arc_to_m)] if r.arc_from_m <= r.arc_to_m else \
            [(r.arc_from_m, a1), (a0, r.arc_to_m)]
        for lo_, hi_ in spans:
            ax.add_patch(mpatches.Rectangle((r.chainage_from_m, lo_),
                                            r.chainage_to_m - r.chainage_from_m, hi_ - lo_,
                                            fill=False, ec="k", lw=1.0, zorder=3))
        if r.region > LABELLED_REGIONS:
            continue
        ax.annotate(f"R{r.region}: {1000 * r.max_depth_m:.0f} mm",
                    (r.deepest_chainage_m, r.deepest_arc_m), fontsize=7, zorder=4,
                    xytext=(3, 3), textcoords="offset points")
    arc = raster.meta.get("arc", {})
    ax.set_xlim(s0, s1)
    ax.set_ylim(a0, a1)
    ax.set_xlabel("chainage (m)")
    ax.set_ylabel(f"arc length from the {arc.get('zero', 'zero')} (m, + left)")
    more = sum(1 for r in regions if r.region > LABELLED_REGIONS)
    ax.set_title(title or f"{label}: {chainage_label(s0)} to {chainage_label(s1)}"
                 f"{'  (hatched: no data)' if (~ok).any() else ''}"
                 + (f"  (labels: the {LABELLED_REGIONS} deepest of {len(regions)} regions)"
                    if more else ""), fontsize=9)
    fig.tight_layout()
    save_png(fig, Path(path))
    return Path(path)


# ---------------------------------------------------------------------- clearance
def violations_csv(result: ClearanceResult) -> str:
    """One row per violating cell, deepest first (m)."""
    lines = ["region,chainage_m,offset_m,height_m,arc_m,depth_m,points"]
    v = result.violations
    for i in range(len(v)):
        lines.append(f"{v.region[i]},{v.chainage_m[i]:.4f},{v.offset_m[i]:.4f},"
                     f"{v.height_m[i]:.4f},{v.arc_m[i]:.4f},{v.depth_m[i]:.5f},{v.points[i]}")
    return "\n".join(lines) + "\n"


def regions_csv(result: ClearanceResult) -> str:
    """One row per violation region (m, m^2)."""
    keys = list(ViolationRegion.__dataclass_fields__)
    lines = [",".join(keys)]
    for r in result.regions:
        d = r.to_dict()
        lines.append(",".join(str(d[k]) if isinstance(d[k], int) else f"{d[k]:.5f}"
                              for k in keys))
    return "\n".join(lines) + "\n"


def merge_line(result: ClearanceResult) -> str:
    """One line on how the violating cells were grouped into regions (the merge gap,
    how it was chosen, the groups of touching cells merged)."""
    m = result.meta.get("merge")
    if not m:
        return f"{len(result.regions)} regions of touching cells"
    if m["gap_m"] > 0:
        src = "--merge-gap" if m["chosen"] == "given" else \
            f"{m['chosen']}; set it with --merge-gap"
        return (f"{m['touching_groups']:,} groups of touching violating cells merged into "
                f"{m['regions']:,} regions: cells up to {m['gap_m']:.3g} m apart join "
                f"({src}); the figure labels the {LABELLED_REGIONS} deepest")
    return (f"{m['regions']:,} regions of touching violating cells (--merge-gap 0); the "
            f"figure labels the {LABELLED_REGIONS} deepest")


def clearance_markdown(result: ClearanceResult, *, title: str = "Clearance",
                       source: str = "", figures: Sequence[str] = ()) -> str:
    """The clearance report: envelope, settings, verdict, regions (mm) and figures."""
    g = result.margin.grid
    out = [f"# {title}", ""]
    if source:
        out += [f"Input: `{source}`", ""]
    out += [f"Envelope: **{result.envelope.name}** ({len(result.envelope.vertices)} "
            f"vertices), swept along the alignment"
            + (f", with {1000 * result.required_m:g} mm free space required beyond it"
               if result.required_m else "") + ". "
            f"Cells of {1000 * g.cell_s_m:g} mm (chainage) x {1000 * g.cell_arc_m:.1f} mm "
            f"(arc from the crown, + left)"
            + (f"; {result.meta['cell_chosen']}" if result.meta.get("cell_chosen") else "")
            + ".", "",
            f"Points checked: {result.points:,}; smallest margin "
            f"{1000 * result.min_margin_m:.1f} mm.", ""]
    if not result.regions:
        out += ["**Clear**: no point of the lining lies inside the envelope.", ""]
    else:
        out += [f"**{len(result.regions)} violation region"
                f"{'s' if len(result.regions) != 1 else ''}**, "
                f"{result.violating_points:,} points, deepest "
                f"{1000 * result.max_depth_m:.1f} mm.", "",
                f"Regions: {merge_line(result)}.", "",
                "| region | chainage from (m) | to (m) | arc from (m) | to (m) | area (m²) | "
                "points | max depth (mm) | at chainage (m) | offset (m) | height (m) |",
                "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for r in result.regions:
            out.append(f"| R{r.region} | {r.chainage_from_m:.3f} | {r.chainage_to_m:.3f} | "
                       f"{r.arc_from_m:.3f} | {r.arc_to_m:.3f} | {r.area_m2:.3f} | "
                       f"{r.points:,} | {1000 * r.max_depth_m:.1f} | "
                       f"{r.deepest_chainage_m:.3f} | {r.deepest_offset_m:.3f} | "
                       f"{r.deepest_height_m:.3f} |")
        out += ["", "Every violating cell (its deepest point): `violations.csv`."]
    if figures:
        out += ["", "## Developed view of the margin", ""]
        out += [f"![{f}]({f})" for f in figures]
    return "\n".join(out) + "\n"
