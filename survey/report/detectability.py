"""The detectability study on paper: detect.json (everything), detect.csv (one row per
configuration and deformation kind), targets.csv (one row per configuration and
target), detect.md and detect.png (detection share against magnitude, false alarms)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from survey.analysis.detectability import Detectability, DetectRow

__all__ = ["detect_csv", "detect_markdown", "detect_summary", "plot_detectability",
           "targets_csv"]

_SUMMARY_KEYS = ("sensor", "sensor_kind", "speed_mps", "spacing_m", "noise", "points1",
                 "points2", "core_points", "reference_points", "false_alarm_rate",
                 "median_lod_m")


def _num(v: Any) -> str:
    if isinstance(v, str):
        return v
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return "nan" if not math.isfinite(float(v)) else f"{float(v):.6g}"


def _pass(r: DetectRow) -> str:
    """'1 m/s' or 'stations every 10 m'."""
    return f"stations every {r.spacing_m:g} m" if r.sensor_kind == "tls" else \
        f"{r.speed_mps:g} m/s"


def detect_summary(study: Detectability, rows: Sequence[DetectRow], *,
                   extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """JSON-ready: the layout, the M3C2 parameters, the definitions and every row."""
    from survey.analysis.detect_layout import BULGE_CORE_FRACTION
    from survey.analysis.detect_stats import POD_TARGET

    return {
        "format": "tunnelsim-detect/1",
        "tunnel": study.tunnel.metadata.get("name"),
        "layout": study.layout.to_dict(),
        "m3c2": study.params.to_dict(),
        "core_spacing_m": study.core_spacing_m,
        "reference_margin_m": study.margin_m,
        "seed": study.seed,
        "definitions": {
            "detected_share": "share of the target region's core points with "
                              "|d| > LoD95 and d > 0",
            "target_region": {"convergence": "plateau shrunk by the cylinder radius",
                              "bulge": f"within {BULGE_CORE_FRACTION:.3g} x radius of "
                                       "a bulge centre"},
            "pod_target": POD_TARGET,
            "detectable_m": "smallest magnitude whose share and every larger one's is "
                            ">= pod_target (NaN: none)",
            "a95_m": "a-hat versus a model (MIL-HDBK-1823A): (LoD + 1.645 tau - b0) / b1",
            "false_alarm_rate": "share of reference core points with |d| > LoD95",
        },
        **(dict(extra) if extra else {}),
        "rows": [r.to_dict() for r in rows],
    }


def detect_csv(rows: Sequence[DetectRow]) -> str:
    """One line per configuration and kind: the configuration, the false-alarm rate,
    the reference LoD95, detectable_m and a95_m (SI units)."""
    head = [*_SUMMARY_KEYS, "kind", "detectable_m", "a95_m"]
    lines = [",".join(head)]
    for r in rows:
        d = r.to_dict()
        for kind in r.detectable_m:
            lines.append(",".join([*(_num(d[k]) for k in _SUMMARY_KEYS), kind,
                                   _num(r.detectable_m[kind]), _num(r.a95_m[kind])]))
    return "\n".join(lines) + "\n"


def targets_csv(rows: Sequence[DetectRow]) -> str:
    """One line per configuration and target (kind, magnitude): core points in its
    region, the detected share, median distance and LoD95 there (SI units)."""
    keys = ("sensor", "speed_mps", "spacing_m", "noise")
    cols = ("kind", "magnitude_m", "points", "detected_share", "median_distance_m",
            "median_lod_m")
    lines = [",".join([*keys, *cols])]
    for r in rows:
        d = r.to_dict()
        for t in r.targets:
            td = t.to_dict()
            lines.append(",".join([*(_num(d[k]) for k in keys),
                                   *(_num(td[c]) for c in cols)]))
    return "\n".join(lines) + "\n"


def _mm(v: float) -> str:
    return "none" if not math.isfinite(v) else f"{1000 * v:.1f}"


def detect_markdown(study: Detectability, rows: Sequence[DetectRow]) -> str:
    """Markdown: what was laid out, the definitions and one table line per
    configuration."""
    from survey.analysis.detect_stats import POD_TARGET

    lay, prm = study.layout, study.params
    conv, bulge = lay.targets
    mags = ", ".join(f"{1000 * m:g}" for m in lay.magnitudes_m)
    out = [
        "# Detectability study", "",
        f"Known deformations of {mags} mm (one epoch 2 each) on "
        f"{study.tunnel.metadata.get('name', 'the tunnel')}: radial convergence over "
        f"chainage {conv.plateau_m[0]:.2f}-{conv.plateau_m[1]:.2f} m (full value; "
        f"{conv.taper_m:g} m tapers), a ring of {len(bulge.deformations(1.0))} bulges of "
        f"{bulge.radius_m:g} m radius at {bulge.centre_m:.2f} m; undeformed reference "
        f"lining {lay.reference_m[0]:.2f}-{lay.reference_m[1]:.2f} m and between. "
        f"M3C2: cylinder radius {prm.cyl_radius_m:g} m, half-length "
        f"{prm.half_length_m:g} m, normals at "
        f"{', '.join(f'{r:g}' for r in prm.normal_radii_m)} m towards the axis; core "
        f"points every {study.core_spacing_m:g} m. "
        f"Detected: |d| > LoD95 with d > 0. The smallest detectable magnitude is the "
        f"smallest tested one detected at >= {POD_TARGET:.0%} of its region's core "
        "points (and every larger one); a95 is the MIL-HDBK-1823A a-hat vs a estimate. "
        "False alarms: share of reference core points beyond LoD95.", "",
        "| sensor | pass | noise x | core points | false alarms | LoD95 ref (mm) | "
        "convergence: smallest / a95 (mm) | bulge: smallest / a95 (mm) |",
        "|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r.sensor} | {_pass(r)} | {r.noise:g} | {r.core_points:,} | "
                   f"{r.false_alarm_rate:.1%} | {_mm(r.median_lod_m)} | "
                   f"{_mm(r.detectable_m['convergence'])} / "
                   f"{_mm(r.a95_m['convergence'])} | "
                   f"{_mm(r.detectable_m['bulge'])} / {_mm(r.a95_m['bulge'])} |")
    return "\n".join(out) + "\n"


def plot_detectability(rows: Sequence[DetectRow], path: str | Path) -> str | Path:
    """Three panels: detected share against magnitude for convergence and for bulges
    (one line per configuration, the 95 % line dashed) and the false-alarm rate per
    configuration (the nominal 5 % dashed). Atomic PNG."""
    from survey.analysis.detect_stats import POD_TARGET
    from survey.report.plotting import pyplot, save_png

    from matplotlib.ticker import FixedLocator, NullLocator, ScalarFormatter

    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6), dpi=110,
                             gridspec_kw={"width_ratios": [1, 1, 0.7]})
    cmap = plt.get_cmap("viridis")
    n = max(len(rows), 1)
    labels = [f"#{i + 1} {r.sensor}, {_pass(r)}, noise x{r.noise:g}"
              for i, r in enumerate(rows)]
    mags = sorted({1000 * t.magnitude_m for r in rows for t in r.targets})
    for ax, kind in zip(axes[:2], ("convergence", "bulge")):
        for i, r in enumerate(rows):
            sc = sorted((t for t in r.targets if t.kind == kind),
                        key=lambda t: t.magnitude_m)
            ax.plot([1000 * t.magnitude_m for t in sc], [t.detected_share for t in sc],
                    "o-", color=cmap(0.9 * i / max(n - 1, 1)), label=labels[i])
        ax.axhline(POD_TARGET, ls="--", color="grey", lw=1)
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(FixedLocator(mags))
        ax.xaxis.set_minor_locator(NullLocator())
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel("magnitude (mm)")
        ax.set_ylabel("share of core points detected")
        ax.set_title(f"{kind}: detection against magnitude", fontsize=9)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=6)
    ax = axes[2]
    y = np.arange(len(rows))
    ax.barh(y, [100 * r.false_alarm_rate for r in rows],
            color=[cmap(0.9 * i / max(n - 1, 1)) for i in range(len(rows))])
    ax.axvline(5.0, ls="--", color="grey", lw=1)
    ax.set_yticks(y, [f"#{i + 1}" for i in range(len(rows))], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("false alarms on undeformed lining (%)")
    ax.set_title("false-alarm rate (LoD95: nominal 5 %)", fontsize=9)
    fig.tight_layout()
    save_png(fig, path)
    return path
