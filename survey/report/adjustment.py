"""Readable reports (Markdown) of adjustments, as surveyors expect from adjustment
software: parameters with standard deviations, sigma0, tests, residuals per point."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from survey.errors import DriftError

if TYPE_CHECKING:  # annotations only: the report module stays light to import
    from sensors.trajectory import Trajectory
    from survey.adjust.drift import DriftCorrection
    from survey.adjust.helmert import HelmertResult

__all__ = ["drift_report", "helmert_report"]


def helmert_report(res: HelmertResult, *, title: str = "Helmert adjustment") -> str:
    """Markdown report of a ``HelmertResult``."""
    lines = [f"# {title}", "",
             f"Model: {res.model}-parameter, PROJ form x_target = t + (1 + s·1e-6)·R·x_source, "
             "R = Rx(rx)·Ry(ry)·Rz(rz) (position-vector convention, exact rotations).", "",
             f"Points: {len(res.ids)}, redundancy {res.dof}, iterations {res.iterations}.", "",
             "| parameter | value | std. dev. |", "|---|---:|---:|"]
    for k, name in enumerate("xyz"):
        lines.append(f"| t{name} (m) | {res.translation_m[k]:.4f} | "
                     f"{res.translation_sigma_m[k]:.4f} |")
    for k, name in enumerate("xyz"):
        lines.append(f"| r{name} (arcsec, position vector) | {res.rotation_arcsec[k]:.4f} | "
                     f"{res.rotation_sigma_arcsec[k]:.4f} |")
    sc, ss = np.atleast_1d(res.scale_ppm), np.atleast_1d(res.scale_sigma_ppm)
    for k in range(len(sc)):
        lines.append(f"| scale{'' if len(sc) == 1 else ' ' + 'xyz'[k]} (ppm) | {sc[k]:.3f} | "
                     f"{ss[k]:.3f} |")
    cf = res.rotation_arcsec_cf
    lines += ["", f"Rotations in the coordinate-frame convention (EPSG 1032): "
              f"{cf[0]:.4f}, {cf[1]:.4f}, {cf[2]:.4f} arcsec.", "",
              f"σ0 a posteriori: {res.sigma0:.4f}"]
    g = res.global_test
    if g.get("interval"):
        lo, hi = g["interval"]
        verdict = "passed" if g["passed"] else "REJECTED"
        lines.append(f"Global test: vᵀPv = {g['statistic']:.3f}, χ²({g['dof']}) 95 % "
                     f"interval [{lo:.3f}, {hi:.3f}]: {verdict}.")
    else:
        lines.append("Global test: not applicable (no a priori standard deviations; σ0 "
                     "estimated, τ-tests used).")
    name = "Baarda w" if res.test == "w" else "Pope τ"
    lines += ["", f"Outlier test: {name}, critical value {res.critical:.2f} (α = 0.001). "
              f"Flagged: {', '.join(res.outliers) if res.outliers else 'none'}.", "",
              "| point | vx (mm) | vy (mm) | vz (mm) | redundancy | test | MDB (mm) |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    for i, pid in enumerate(res.ids):
        v = res.residuals[i] * 1000
        flag = " **" if pid in res.outliers else ""
        lines.append(f"| {pid}{flag} | {v[0]:.2f} | {v[1]:.2f} | {v[2]:.2f} | "
                     f"{res.redundancy[i].mean():.2f} | {res.w_tests[i]:.2f} | "
                     f"{res.mdb_m[i] * 1000:.1f} |")
    return "\n".join(lines) + "\n"


def drift_report(corr: DriftCorrection, loo: NDArray[np.float64], *,
                 traj: Trajectory | None = None, plot_path: Path | None = None,
                 title: str = "MLS drift correction") -> str:
    """Markdown report of a ``DriftCorrection``: fit residuals and leave-one-out
    check-point residuals per control point, and (with the MLS trajectory) the
    correction magnitude along the distance travelled, plotted to ``plot_path``."""
    fit = corr.residuals
    if fit is None:
        raise DriftError("Expected a fitted DriftCorrection (from fit_drift), got one "
                         "without residuals.")
    rms_fit = float(np.sqrt(np.mean(np.sum(fit ** 2, axis=1))))
    rms_loo = float(np.sqrt(np.mean(np.sum(loo ** 2, axis=1))))
    lines = [f"# {title}", "",
             f"Model: {corr.model}" + (f" ({corr.interpolation} blending, "
                                       f"{len(corr.times)} control sections)"
                                       if corr.model == "piecewise" else ""), "",
             f"Control points: {len(fit)}. RMS of the fit residuals: "
             f"{rms_fit * 1000:.1f} mm. RMS of the leave-one-out check-point residuals "
             f"(each point predicted without it, the honest accuracy): "
             f"{rms_loo * 1000:.1f} mm.", ""]
    if traj is not None:
        p = traj.positions
        dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        mag = corr.magnitude(p, traj.times)
        lines.append(f"Correction along the run: up to {mag.max():.3f} m "
                     f"(at {dist[np.argmax(mag)]:.0f} m), mean {mag.mean():.3f} m.")
        if plot_path is not None:
            _plot_correction(dist, mag, plot_path)
            lines += ["", f"![correction along the run]({plot_path.name})"]
        lines.append("")
    lines += ["| point | fit dx | fit dy | fit dz | check dx | check dy | check dz | "
              "check |v| |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for i, pid in enumerate(corr.ids or range(len(fit))):
        a, b = fit[i] * 1000, loo[i] * 1000
        lines.append(f"| {pid} | {a[0]:.1f} | {a[1]:.1f} | {a[2]:.1f} | {b[0]:.1f} | "
                     f"{b[1]:.1f} | {b[2]:.1f} | {np.linalg.norm(b):.1f} |")
    lines.append("")
    lines.append("Residuals in mm (corrected minus control coordinates).")
    return "\n".join(lines) + "\n"


def _plot_correction(dist: NDArray[np.float64], mag: NDArray[np.float64],
                     path: Path) -> None:
    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.plot(dist, mag * 1000)
    ax.set_xlabel("distance along the run (m)")
    ax.set_ylabel("correction (mm)")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    save_png(fig, path, dpi=120)
