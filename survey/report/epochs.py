"""Reports of an epoch comparison: M3C2 summary (Markdown, JSON-ready dict, histogram)
and convergence tables (chords, radial change per section) with a polar plot."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from survey.analysis.convergence import Chords, RadialChange, summarise
from survey.analysis.m3c2 import M3C2Params
from survey.report.header import ReportHeader, header_lines

__all__ = ["chords_csv", "convergence_markdown", "m3c2_markdown", "m3c2_summary",
           "plot_m3c2_histogram", "plot_radial", "radial_csv"]


def m3c2_summary(distance: np.ndarray, lod: np.ndarray, significant: np.ndarray,
                 params: M3C2Params, **extra: Any) -> dict[str, Any]:
    """Key figures (metres): core points, with a distance, significant share, median,
    mean, 5/95 % of the distances, median LoD95, and the parameters."""
    d = np.asarray(distance, dtype=np.float64)
    ok = np.isfinite(d)
    v = d[ok]
    q = np.percentile(v, [5, 95]) if v.size else (np.nan, np.nan)
    lv = np.asarray(lod, dtype=np.float64)
    lv = lv[np.isfinite(lv)]
    return {"core_points": int(d.size), "with_distance": int(ok.sum()),
            "significant": int(np.count_nonzero(significant)),
            "significant_share": float(np.count_nonzero(significant) / max(ok.sum(), 1)),
            "median_m": float(np.median(v)) if v.size else float("nan"),
            "mean_m": float(v.mean()) if v.size else float("nan"),
            "p05_m": float(q[0]), "p95_m": float(q[1]),
            "median_lod_m": float(np.median(lv)) if lv.size else float("nan"),
            "parameters": params.to_dict(), **extra}


def m3c2_markdown(summary: Mapping[str, Any], *, title: str = "M3C2",
                  header: ReportHeader | None = None, figure: str | None = None) -> str:
    """The summary as a Markdown report (millimetres); ``header`` (inputs, CRS, ...)
    below the title; ``figure``: the histogram's file name, shown at the end."""
    p = summary["parameters"]
    mm = 1000.0
    lines = [f"# {title}", ""] + (header_lines(header) if header is not None else []) + [
             "Lague, Brodu & Leroux (2013); py4dgeo's parameters and LoD95 = 1.96 "
             "(sqrt(s1²/n1 + s2²/n2) + registration error). Positive: along the normal "
             "(towards the axis when oriented so: convergence).", "",
             "| quantity | value |", "|---|---:|",
             f"| core points | {summary['core_points']:,} |",
             f"| with a distance | {summary['with_distance']:,} |",
             f"| significant (abs(d) > LoD95) | {summary['significant']:,} "
             f"({100 * summary['significant_share']:.1f} %) |",
             f"| median distance (mm) | {mm * summary['median_m']:.2f} |",
             f"| mean distance (mm) | {mm * summary['mean_m']:.2f} |",
             f"| 5 % / 95 % (mm) | {mm * summary['p05_m']:.2f} / "
             f"{mm * summary['p95_m']:.2f} |",
             f"| median LoD95 (mm) | {mm * summary['median_lod_m']:.2f} |", "",
             "| parameter | value |", "|---|---:|",
             f"| cylinder radius (m) | {p['cyl_radius_m']:g} |",
             f"| max depth (m, half-length) | {p['max_depth_m']:g} |",
             f"| normal radii (m) | {', '.join(f'{r:g}' for r in p['normal_radii_m']) or 'given'} |",
             f"| registration error (m) | {p['registration_error_m']:g} |",
             f"| statistic | {'median / IQR' if p['robust'] else 'mean / std'} |"]
    if figure:
        lines += ["", f"![M3C2 distances (mm)]({figure})"]
    return "\n".join(lines) + "\n"


def plot_m3c2_histogram(distance: np.ndarray, significant: np.ndarray,
                        path: str | Path) -> str | Path:
    """Histogram PNG of M3C2 distances (mm), significant ones shaded; atomic."""
    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    d = np.asarray(distance, dtype=float)
    ok = np.isfinite(d)
    fig, ax = plt.subplots(figsize=(7, 4), dpi=110)
    v = 1000 * d[ok]
    lo, hi = (np.percentile(v, [0.5, 99.5]) if v.size else (0.0, 1.0))
    if hi <= lo:
        hi = lo + 1.0
    ax.hist(v, bins=80, range=(lo, hi), histtype="step", lw=1.4, label="all")
    ax.hist(1000 * d[ok & np.asarray(significant, bool)], bins=80, range=(lo, hi),
            alpha=0.4, label="significant")
    ax.set_xlabel("M3C2 distance (mm)")
    ax.set_ylabel("core points")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_png(fig, path)
    return path


def chords_csv(ch: Chords) -> str:
    """Chord table as CSV (metres)."""
    lines = ["id_a,id_b,chainage_m,length1_m,length2_m,convergence_m,lod_m,significant"]
    for r in ch.rows():
        lines.append(f"{r['id_a']},{r['id_b']},{r['chainage_m']:.4f},{r['length1_m']:.6f},"
                     f"{r['length2_m']:.6f},{r['convergence_m']:.6f},{r['lod_m']:.6f},"
                     f"{int(r['significant'])}")
    return "\n".join(lines) + "\n"


def radial_csv(changes: Sequence[RadialChange]) -> str:
    """Radial change per section and angle as CSV (metres, degrees)."""
    lines = ["chainage_m,angle_deg,radius1_m,radius2_m,change_m,lod_m,n1,n2,significant"]
    for rc in changes:
        for j in range(len(rc.angle_rad)):
            lines.append(f"{rc.chainage_m:.4f},{np.rad2deg(rc.angle_rad[j]):.2f},"
                         f"{rc.radius1_m[j]:.6f},{rc.radius2_m[j]:.6f},"
                         f"{rc.change_m[j]:.6f},{rc.lod_m[j]:.6f},{rc.n1[j]},{rc.n2[j]},"
                         f"{int(rc.significant[j])}")
    return "\n".join(lines) + "\n"


def convergence_markdown(ch: Chords | None, changes: Sequence[RadialChange], *,
                         header: ReportHeader | None = None,
                         epochs: Sequence[str] = (), band_m: float | None = None,
                         angle_step_deg: float | None = None,
                         figure: str | None = None) -> str:
    """Chord and section tables in millimetres.

    Parameters
    ----------
    ch : Chords or None; changes : radial change per section
    header : ReportHeader, optional (inputs with checksums, CRS, date, ...)
    epochs : the names of the earlier and the later epoch (files), stated in the text
    band_m : half-width of a section along the axis (m); angle_step_deg : bin (deg)
    figure : the polar plot's file name (beside the report), shown below the table
    """
    out = ["# Convergence between epochs", ""]
    if header is not None:
        out += header_lines(header)
    if epochs:
        out += [f"Epochs: earlier {epochs[0]}, later {epochs[1]}." if len(epochs) == 2
                else f"Epochs: {', '.join(epochs)}.", ""]
    if changes and band_m is not None and angle_step_deg is not None:
        out += [f"Sections: points within ±{band_m:g} m of each chainage along the axis; "
                f"radii in bins of {angle_step_deg:g}° about the section centre.", ""]
    out += ["Positive: the section closes (chords shorten, the lining moves towards the "
            "axis)."]
    if ch is not None and len(ch):
        out += ["", "## Chords", "",
                "| chord | chainage (m) | L1 (m) | L2 (m) | convergence (mm) | "
                "LoD95 (mm) | significant |", "|---|---:|---:|---:|---:|---:|:---:|"]
        for r in ch.rows():
            out.append(f"| {r['id_a']}-{r['id_b']} | {r['chainage_m']:.2f} | "
                       f"{r['length1_m']:.4f} | {r['length2_m']:.4f} | "
                       f"{1000 * r['convergence_m']:+.2f} | {1000 * r['lod_m']:.2f} | "
                       f"{'yes' if r['significant'] else 'no'} |")
    if changes:
        out += ["", "## Radial change by section", "",
                "| chainage (m) | bins | median (mm) | min (mm) | max (mm) | "
                "significant bins |", "|---:|---:|---:|---:|---:|---:|"]
        for r in summarise(changes):
            out.append(f"| {r['chainage_m']:.2f} | {r['bins']} | "
                       f"{1000 * r['median_m']:+.2f} | {1000 * r['min_m']:+.2f} | "
                       f"{1000 * r['max_m']:+.2f} | {r['significant']} |")
        if figure:
            out += ["", f"![radial change by angle (mm)]({figure})"]
    return "\n".join(out) + "\n"


def plot_radial(changes: Sequence[RadialChange], path: str | Path) -> str | Path:
    """Radial change (mm) against angle from the crown, one line per section; atomic."""
    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4), dpi=110)
    for rc in changes:
        o = np.argsort(rc.angle_rad)
        ax.plot(np.rad2deg(rc.angle_rad[o]), 1000 * rc.change_m[o], lw=1.2,
                label=f"{rc.chainage_m:g} m")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xlabel("angle from the crown, positive to the left (deg)")
    ax.set_ylabel("radial change, + inward (mm)")
    if changes:
        ax.legend(fontsize=8, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_png(fig, path)
    return path
