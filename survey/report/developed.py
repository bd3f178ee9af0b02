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
(RdBu; red for overbreak and for a violated margin) with limits symmetric about 0; the intensity in grey; cells without data are
transparent over a hatched background, so "no data" never looks like a value.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from survey.analysis.clearance import ClearanceResult, ViolationRegion
from survey.analysis.developed import DevelopedRaster

__all__ = ["RASTER_FORMAT", "clearance_markdown", "chainage_label", "plot_developed",
           "regions_csv", "tile_stem", "violations_csv", "write_developed"]

#: Identifies the JSON sidecars of developed rasters (and their version).
RASTER_FORMAT = "tunnelsim developed raster 1"
#: Percentile of |value| that sets a diverging colour bar's limits when none is given.
#: ASSUMED: 99.9, so a few stray points do not wash out the view.
LIMIT_PERCENTILE = 99.9
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


def _sidecar(raster: DevelopedRaster, stat: str, cols: slice, npy_name: str,
             crs: str | None) -> dict[str, Any]:
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
            **{k: v for k, v in raster.meta.items() if k not in ("grid",)}}


def write_developed(raster: DevelopedRaster, folder: str | Path, *, stem: str | None = None,
                    tile_m: float | None = None, stat: str = "mean", png: bool = True,
                    crs: str | None = None, limit: float | None = None,
                    regions: Sequence[ViolationRegion] = ()) -> list[Path]:
    """Write the raster's ``stat`` as NPY + JSON (+ PNG) into ``folder``: one set, or
    one per tile of ``tile_m`` metres (chainages at whole multiples of it). Returns the
    paths written. ``limit``: colour-bar limit in the raster's unit (default the
    ``LIMIT_PERCENTILE`` of |value|); ``regions`` are outlined on the PNGs."""
    from raytrace.fileio import atomic_writer, write_json

    folder = Path(folder)
    stem = stem or f"developed_{raster.field}"
    data = raster.statistic(stat)
    g = raster.grid
    if tile_m is None:
        tiles = [(g.chainage0_m, g.chainage0_m + g.n_s * g.cell_s_m, slice(0, g.n_s))]
    else:
        tiles = g.tiles(tile_m)
    lim = limit if limit is not None else _auto_limit(raster, data, stat)
    out: list[Path] = []
    for a, b, cols in tiles:
        name = tile_stem(stem, a, b)
        npy = folder / f"{name}.npy"
        with atomic_writer(npy) as fh:
            np.save(fh, np.ascontiguousarray(data[:, cols], dtype=np.float32))
        out.append(npy)
        out.append(write_json(folder / f"{name}.json",
                              _sidecar(raster, stat, cols, npy.name, crs)))
        if png:
            out.append(plot_developed(raster, folder / f"{name}.png", stat=stat,
                                      columns=cols, limit=lim, regions=regions))
    return out


def _auto_limit(raster: DevelopedRaster, data: np.ndarray, stat: str) -> float | None:
    """The diverging colour bar's limit, shared by every tile (None: not diverging)."""
    ok = np.isfinite(data)
    if not ok.any() or raster.field == "intensity" or stat == "count":
        return None
    return float(np.percentile(np.abs(data[ok]), LIMIT_PERCENTILE)) or 1e-3


def plot_developed(raster: DevelopedRaster, path: str | Path, *, stat: str = "mean",
                   columns: slice | None = None, limit: float | None = None,
                   regions: Sequence[ViolationRegion] = (), title: str | None = None
                   ) -> Path:
    """PNG of a developed view (chainage across, arc length up, crown at 0, left wall
    above it) with a colour bar; ``regions`` outlined and numbered; atomic."""
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
    cmap.set_bad((0, 0, 0, 0))
    width = float(np.clip(0.12 * (s1 - s0) + 3.0, 8.0, 18.0))
    fig, ax = plt.subplots(figsize=(width, 4.8), dpi=110)
    ax.add_patch(mpatches.Rectangle((s0, a0), s1 - s0, a1 - a0, fill=False, hatch="///",
                                    ec="0.75", lw=0, zorder=0))
    im = ax.imshow(np.ma.masked_invalid(shown), origin="lower", aspect="auto",
                   extent=(s0, s1, a0, a1), cmap=cmap, vmin=vmin, vmax=vmax,
                   interpolation="nearest", zorder=1)
    label = {"deviation": "deviation from design", "distance": "distance (epoch 2 - 1)",
             "intensity": "intensity", "margin": "clearance margin"}.get(raster.field,
                                                                         raster.field)
    cb = fig.colorbar(im, ax=ax, pad=0.01)
    cb.set_label(f"{label}, {stat} ({unit})")
    ax.axhline(0.0, color="k", lw=0.5, ls=":", zorder=2)
    for r in regions:
        if r.chainage_to_m < s0 or r.chainage_from_m > s1:
            continue
        spans = [(r.arc_from_m, r.arc_to_m)] if r.arc_from_m <= r.arc_to_m else \
            [(r.arc_from_m, a1), (a0, r.arc_to_m)]
        for lo_, hi_ in spans:
            ax.add_patch(mpatches.Rectangle((r.chainage_from_m, lo_),
                                            r.chainage_to_m - r.chainage_from_m, hi_ - lo_,
                                            fill=False, ec="k", lw=1.0, zorder=3))
        ax.annotate(f"R{r.region}: {1000 * r.max_depth_m:.0f} mm",
                    (r.deepest_chainage_m, r.deepest_arc_m), fontsize=7, zorder=4,
                    xytext=(3, 3), textcoords="offset points")
    arc = raster.meta.get("arc", {})
    ax.set_xlim(s0, s1)
    ax.set_ylim(a0, a1)
    ax.set_xlabel("chainage (m)")
    ax.set_ylabel(f"arc length from the {arc.get('zero', 'zero')} (m, + left)")
    ax.set_title(title or f"{label}: {chainage_label(s0)} to {chainage_label(s1)}"
                 f"{'  (hatched: no data)' if (~ok).any() else ''}", fontsize=9)
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
            f"(arc from the crown, + left).", "",
            f"Points checked: {result.points:,}; smallest margin "
            f"{1000 * result.min_margin_m:.1f} mm.", ""]
    if not result.regions:
        out += ["**Clear**: no point of the lining lies inside the envelope.", ""]
    else:
        out += [f"**{len(result.regions)} violation region"
                f"{'s' if len(result.regions) != 1 else ''}**, "
                f"{result.violating_points:,} points, deepest "
                f"{1000 * result.max_depth_m:.1f} mm.", "",
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
