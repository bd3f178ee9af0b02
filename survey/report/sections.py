"""Reports of sections against design and of ring fits: CSV, Markdown (an as-built
report: per-section over-/under-break, areas, volumes, tolerance classes) and a PNG
per section."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from survey.analysis.overbreak import Section, SectionReport, class_labels
from survey.analysis.rings import RingFit

__all__ = ["contours_csv", "plot_rings", "plot_section", "rings_csv", "rings_markdown",
           "section_png_name", "sections_csv", "sections_markdown", "volumes_csv"]


def section_png_name(chainage_m: float) -> str:
    """File name of a section's plot: ``section_0+012.500.png`` (km+m, surveyors'
    chainage notation)."""
    km = int(np.floor(chainage_m / 1000.0))
    return f"section_{km}+{chainage_m - 1000 * km:07.3f}.png"


def _share_name(label: str) -> str:
    """CSV column of a class label: "< -20" -> share_below_-20_mm."""
    s = label.replace("< ", "below_").replace("> ", "above_").replace(" to ", "_to_")
    return f"share_{s}_mm"


def sections_csv(report: SectionReport) -> str:
    """One row per section (metres, m^2; class shares 0-1)."""
    labels = class_labels(report.tolerance_edges_m)
    head = ["chainage_m", "half_width_m", "n_points", "coverage", "mean_m", "max_m",
            "min_m", "overbreak_area_m2", "underbreak_area_m2", "net_area_m2"] + \
        [_share_name(lab) for lab in labels]
    lines = [",".join(head)]
    for s in report.sections:
        vals = [f"{s.chainage_m:.3f}", f"{s.half_width_m:.3f}", str(s.n_points),
                f"{s.coverage:.4f}", f"{s.mean_m:.6f}", f"{s.max_m:.6f}", f"{s.min_m:.6f}",
                f"{s.overbreak_area_m2:.6f}", f"{s.underbreak_area_m2:.6f}",
                f"{s.net_area_m2:.6f}"] + [f"{v:.4f}" for v in s.class_share]
        lines.append(",".join(vals))
    return "\n".join(lines) + "\n"


def volumes_csv(report: SectionReport) -> str:
    """Volumes between consecutive sections (m^3) and their running totals."""
    lines = ["from_m,to_m,overbreak_m3,underbreak_m3,net_m3,cumulative_overbreak_m3,"
             "cumulative_underbreak_m3"]
    co = cu = 0.0
    for v in report.volumes:
        co += v.overbreak_m3
        cu += v.underbreak_m3
        lines.append(f"{v.from_m:.3f},{v.to_m:.3f},{v.overbreak_m3:.6f},"
                     f"{v.underbreak_m3:.6f},{v.net_m3:.6f},{co:.6f},{cu:.6f}")
    return "\n".join(lines) + "\n"


def contours_csv(report: SectionReport) -> str:
    """The as-built line of every section: chainage, design arc length t, design point
    (y, z), deviation (NaN in gaps) and the points per bin."""
    lines = ["chainage_m,t_m,design_y_m,design_z_m,deviation_m,points"]
    for s in report.sections:
        p = report.design.points(s.t_m)
        for t, (y, z), d, n in zip(s.t_m, p, s.deviation_m, s.count):
            lines.append(f"{s.chainage_m:.3f},{t:.4f},{y:.4f},{z:.4f},"
                         f"{'nan' if not np.isfinite(d) else f'{d:.6f}'},{n}")
    return "\n".join(lines) + "\n"


def sections_markdown(report: SectionReport, *, title: str = "As-built sections",
                      source: str = "", plots: bool = True) -> str:
    """The as-built report: settings, a table per section (mm, m^2), volumes, classes,
    and the section plots (``section_png_name``) when ``plots``."""
    d = report.design
    labels = class_labels(report.tolerance_edges_m)
    out = [f"# {title}", ""]
    if source:
        out += [f"Input: `{source}`", ""]
    out += [f"Design profile: **{d.name}** ({'closed' if d.closed else 'open'}, "
            f"{d.length_m:.3f} m). Deviation > 0 is overbreak (outside the design line), "
            f"< 0 underbreak. As-built line: median deviation in bins of "
            f"{1000 * report.bin_m:g} mm along the design.", "",
            "## Sections", "",
            "| chainage (m) | points | coverage | mean (mm) | max overbreak (mm) | "
            "max underbreak (mm) | overbreak (m²) | underbreak (m²) |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for s in report.sections:
        out.append(f"| {s.chainage_m:.3f} | {s.n_points:,} | {100 * s.coverage:.0f} % | "
                   f"{1000 * s.mean_m:.1f} | {1000 * max(s.max_m, 0.0):.1f} | "
                   f"{1000 * max(-s.min_m, 0.0):.1f} | {s.overbreak_area_m2:.4f} | "
                   f"{s.underbreak_area_m2:.4f} |")
    out += ["", "## Volumes", "",
            f"Between chainage {report.sections[0].chainage_m:.3f} and "
            f"{report.sections[-1].chainage_m:.3f} m (average end areas, Pappus on "
            f"curves): overbreak **{report.overbreak_m3:.3f} m³**, underbreak "
            f"**{report.underbreak_m3:.3f} m³**.", "",
            "| from (m) | to (m) | overbreak (m³) | underbreak (m³) |",
            "|---:|---:|---:|---:|"]
    for v in report.volumes:
        out.append(f"| {v.from_m:.3f} | {v.to_m:.3f} | {v.overbreak_m3:.4f} | "
                   f"{v.underbreak_m3:.4f} |")
    out += ["", "## Tolerance classes", "",
            "Share of the observed design line in each deviation class (mm).", "",
            "| chainage (m) | " + " | ".join(labels) + " |",
            "|---:|" + "---:|" * len(labels)]
    for s in report.sections:
        out.append(f"| {s.chainage_m:.3f} | " +
                   " | ".join(f"{100 * v:.0f} %" for v in s.class_share) + " |")
    if plots:
        out += ["", "## Section plots", ""]
        out += [f"![section {s.chainage_m:.3f} m]({section_png_name(s.chainage_m)})"
                for s in report.sections]
    return "\n".join(out) + "\n"


def plot_section(section: Section, report: SectionReport, path: str | Path, *,
                 ring: RingFit | None = None) -> str | Path:
    """PNG of one section: the design line, the points coloured by deviation (mm), the
    as-built line and, with ``ring``, the fitted ellipse; atomic."""
    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    d = report.design
    fig, ax = plt.subplots(figsize=(7, 6), dpi=110)
    v = np.vstack([d.vertices, d.vertices[:1]]) if d.closed else d.vertices
    ax.plot(v[:, 0], v[:, 1], "k-", lw=1.2, label=f"design ({d.name})")
    dev = 1000 * section.plot_deviation
    ok = np.isfinite(dev)
    lim = float(np.nanpercentile(np.abs(dev[ok]), 98)) if ok.any() else 1.0
    sc = ax.scatter(section.plot_yz[ok, 0], section.plot_yz[ok, 1], c=dev[ok], s=2,
                    cmap="RdBu_r", vmin=-max(lim, 1.0), vmax=max(lim, 1.0))
    fig.colorbar(sc, ax=ax, label="deviation from design (mm, > 0 overbreak)")
    line = d.points(section.t_m) + section.deviation_m[:, None] * d.normals(section.t_m)
    ax.plot(line[:, 0], line[:, 1], "-", color="tab:orange", lw=1.0,
            label="as-built (bin medians)")
    if ring is not None:
        e = ring.ellipse
        ph = np.linspace(0, 2 * np.pi, 361)
        c, s = np.cos(e.angle_rad), np.sin(e.angle_rad)
        x, y = e.a_m * np.cos(ph), e.b_m * np.sin(ph)
        ax.plot(e.centre[0] + c * x - s * y, e.centre[1] + s * x + c * y, "--",
                color="tab:green", lw=1.0, label="best-fit ellipse")
    ax.set_aspect("equal")
    ax.set_xlabel("offset, left (m)")
    ax.set_ylabel("height (m)")
    ax.set_title(f"chainage {section.chainage_m:.3f} m: max overbreak "
                 f"{1000 * section.max_m:.0f} mm, max underbreak "
                 f"{1000 * max(-section.min_m, 0):.0f} mm, {section.overbreak_area_m2:.3f} m²",
                 fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_png(fig, path)
    return path


def rings_csv(rings: Sequence[RingFit]) -> str:
    """One row per section: circle and ellipse parameters (m, degrees), ovality."""
    if not rings:
        return "chainage_m\n"
    keys = list(rings[0].to_dict())
    lines = [",".join(keys)]
    for r in rings:
        dct = r.to_dict()
        lines.append(",".join(str(dct[k]) if isinstance(dct[k], int) else f"{dct[k]:.6f}"
                              for k in keys))
    return "\n".join(lines) + "\n"


def rings_markdown(rings: Sequence[RingFit], *, title: str = "Ring fits",
                   source: str = "") -> str:
    """Markdown table of the ring fits (mm, degrees, %)."""
    out = [f"# {title}", ""]
    if source:
        out += [f"Input: `{source}`", ""]
    out += ["Geometric (orthogonal-distance) best-fit circle and ellipse per section; "
            "centre offset from the design centre (y left, z up); ovality = "
            "(D_max - D_min) / D_nominal. σ: formal standard deviation of the diameter "
            "from the scatter of the points about the fit (s0² (JᵀJ)⁻¹, the points taken "
            "as independent: a lower bound, as neighbouring scan points share errors).",
            "",
            "| chainage (m) | points | circle D (mm) | σ circle D (mm) | D max (mm) | "
            "σ D max (mm) | D min (mm) | σ D min (mm) | major axis (deg) | ovality (%) | "
            "offset y (mm) | offset z (mm) | rms (mm) |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rings:
        dmax, dmin = r.ellipse.diameters_m
        smax, smin = r.ellipse.diameters_sigma_m
        out.append(f"| {r.chainage_m:.3f} | {r.n_points:,} | {1000 * r.circle.diameter_m:.1f} "
                   f"| {1000 * r.circle.diameter_sigma_m:.2f} "
                   f"| {1000 * dmax:.1f} | {1000 * smax:.2f} | {1000 * dmin:.1f} | "
                   f"{1000 * smin:.2f} | "
                   f"{np.rad2deg(r.ellipse.angle_rad):.1f} | {100 * r.ovality:.3f} | "
                   f"{1000 * r.centre_offset_m[0]:.1f} | {1000 * r.centre_offset_m[1]:.1f} | "
                   f"{1000 * r.ellipse.rms_m:.1f} |")
    return "\n".join(out) + "\n"


def plot_rings(rings: Sequence[RingFit], path: str | Path) -> str | Path:
    """PNG of diameters, ovality and centre offset along the chainage; atomic."""
    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    s = np.array([r.chainage_m for r in rings])
    dmax = np.array([r.ellipse.diameters_m[0] for r in rings]) * 1000
    dmin = np.array([r.ellipse.diameters_m[1] for r in rings]) * 1000
    off = np.array([r.centre_offset_m for r in rings]) * 1000
    fig, axs = plt.subplots(3, 1, figsize=(8, 7), dpi=110, sharex=True)
    axs[0].plot(s, dmax, "o-", ms=3, label="D max")
    axs[0].plot(s, dmin, "o-", ms=3, label="D min")
    axs[0].set_ylabel("diameter (mm)")
    axs[0].legend(fontsize=8)
    axs[1].plot(s, [100 * r.ovality for r in rings], "o-", ms=3)
    axs[1].set_ylabel("ovality (%)")
    axs[2].plot(s, off[:, 0], "o-", ms=3, label="offset y")
    axs[2].plot(s, off[:, 1], "o-", ms=3, label="offset z")
    axs[2].set_ylabel("centre offset (mm)")
    axs[2].set_xlabel("chainage (m)")
    axs[2].legend(fontsize=8)
    for ax in axs:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_png(fig, path)
    return path
