"""Readable reports (Markdown) of adjustments, as surveyors expect from adjustment
software: parameters with standard deviations, sigma0, tests, residuals per point."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from survey.errors import DriftError, HelmertError
from survey.report.header import ReportHeader, header_lines

if TYPE_CHECKING:  # annotations only: the report module stays light to import
    from sensors.trajectory import Trajectory
    from survey.adjust.drift import DriftCorrection
    from survey.adjust.helmert import HelmertResult
    from survey.adjust.snooping import Snooping

__all__ = ["ANGLE_UNITS", "drift_report", "helmert_report", "sigma0_lines"]


#: Angle units of the report's rotation table besides arcseconds.
ANGLE_UNITS = {"deg": ("degrees", 1.0 / 3600.0), "gon": ("gon", 400.0 / (360.0 * 3600.0))}
_MODEL_NAMES = {"7": "similarity", "6": "rigid", "9": "scale per source axis"}


def helmert_report(res: HelmertResult, *, title: str = "Helmert adjustment",
                   angles: str = "deg", snooping: Snooping | None = None,
                   notes: Sequence[str] = (), header: ReportHeader | None = None) -> str:
    """Markdown report of a ``HelmertResult``.

    Parameters
    ----------
    res : HelmertResult, the (final) adjustment
    title : str
    angles : "deg" or "gon", the unit of the rotations beside arcseconds
    snooping : Snooping, optional
        Points excluded by hand and the steps of data snooping
        (``survey.adjust.snooping.data_snooping``); ``res`` is then its ``result``.
    notes : sequence of str
        Lines shown near the top (warnings about the input, e.g. unmatched ids).
    header : ReportHeader, optional
        Inputs with checksums, CRS, software, date, project and instrument, written
        below the title (``survey.report.header``).
    """
    if angles not in ANGLE_UNITS:
        raise HelmertError(f"Expected angles 'deg' or 'gon', got {angles!r}.")
    basis = res.sigma_basis
    why = ("from the given standard deviations of the points, σ0 = 1"
           if basis == "a priori" else f"scaled by the estimated σ0 = {_sigma0_text(res)}")
    lines = [f"# {title}", ""]
    if header is not None:
        lines += header_lines(header)
    lines += ["Axes: x = Easting, y = Northing, z = height (m).", "",
              f"Model: {res.model}-parameter ({_MODEL_NAMES[res.model]}): `{res.formula}` "
             "(position-vector convention, EPSG 1033, exact rotations).", "",
             f"Points: {len(res.ids)}, redundancy {res.dof}, iterations {res.iterations}.", ""]
    lines += [f"- **Note:** {n}" for n in notes] + ([""] if notes else [])
    lines += ["## Parameters", "",
              f"Standard deviations **{basis}** ({why}).", "",
              f"| parameter | value | std. dev. ({basis}) |", "|---|---:|---:|"]
    for k, name in enumerate("xyz"):
        lines.append(f"| t{name} (m) | {res.translation_m[k]:.4f} | "
                     f"{res.translation_sigma_m[k]:.4f} |")
    sc, ss = np.atleast_1d(res.scale_ppm), np.atleast_1d(res.scale_sigma_ppm)
    for k in range(len(sc)):
        lines.append(f"| scale{'' if len(sc) == 1 else ' ' + 'xyz'[k]} (ppm) | {sc[k]:.3f} | "
                     f"{ss[k]:.3f} |")
    unit, per_arcsec = ANGLE_UNITS[angles]
    lines += ["", f"| rotation (position vector) | arcsec | std. dev. (arcsec, {basis}) | "
              f"{unit} | std. dev. ({unit}) |", "|---|---:|---:|---:|---:|"]
    for k, name in enumerate("xyz"):
        r, sd = res.rotation_arcsec[k], res.rotation_sigma_arcsec[k]
        lines.append(f"| r{name} | {r:.4f} | {sd:.4f} | {r * per_arcsec:.8f} | "
                     f"{sd * per_arcsec:.8f} |")
    cf = res.rotation_arcsec_cf
    lines += ["", f"Rotations in the coordinate-frame convention (EPSG 1032): "
              f"{cf[0]:.4f}, {cf[1]:.4f}, {cf[2]:.4f} arcsec.", "",
              f"PROJ: `{res.to_proj()}`", ""]
    lines += _correlations(res)
    lines += _tests(res)
    if snooping is not None:
        lines += _snooping(snooping)
    from survey.adjust.helmert_stats import ALPHA, DELTA0, POWER

    lines += ["## Residuals", "",
              f"Residuals v = target − transformed source (mm). Redundancy number: the "
              f"share of an error the residual shows (unitless, 0 to 1). Test: "
              f"{'Baarda w' if res.test == 'w' else 'Pope τ'} (unitless). MDB: Baarda's "
              f"minimal detectable bias (Baarda 1968), the smallest error in one "
              f"coordinate of the point that the test finds with power "
              f"{100 * POWER:.0f} % at α0 = {100 * ALPHA:g} % (δ0 = {DELTA0}), largest "
              f"of x, y, z, in mm"
              + (", from the given standard deviations." if res.test == "w" else
                 ", from the estimated σ0."), "",
              f"| point | vx (mm) | vy (mm) | vz (mm) | redundancy (unitless) | "
              f"{'w' if res.test == 'w' else 'τ'} (unitless) | MDB (mm, power "
              f"{100 * POWER:.0f} %, α0 {100 * ALPHA:g} %) |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    rank = {k: i + 1 for i, k in enumerate(res.outliers)}
    for i, pid in enumerate(res.ids):
        v = res.residuals[i] * 1000
        flag = f" **({rank[pid]})**" if pid in rank else ""
        lines.append(f"| {pid}{flag} | {v[0]:.2f} | {v[1]:.2f} | {v[2]:.2f} | "
                     f"{res.redundancy[i].mean():.2f} | {res.w_tests[i]:.2f} | "
                     f"{res.mdb_m[i] * 1000:.1f} |")
    return "\n".join(lines) + "\n"


def _correlations(res: HelmertResult) -> list[str]:
    """The correlation matrix and the warnings above |rho| = 0.95."""
    names = res.parameter_names
    lines = ["## Correlations of the parameters (unitless)", "",
             "Translations at the centroid of the points (the PROJ translation at the "
             "origin is always correlated with the rotations).", "",
             "| | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for i, a in enumerate(names):
        lines.append(f"| {a} | " + " | ".join(f"{res.correlation[i, k]:.3f}"
                                              for k in range(len(names))) + " |")
    lines.append("")
    lines += [f"- **Warning:** {w}." for w in res.correlation_warnings]
    return lines + ([""] if res.correlation_warnings else [])


def _sigma0_text(res: HelmertResult) -> str:
    """σ0 with its unit: metres with unit weights, a unitless ratio with given sigmas."""
    if res.test == "w":
        return f"{res.sigma0:.4g} (unitless)"
    return f"{res.sigma0 * 1000:.2f} mm"


def sigma0_lines(res: HelmertResult) -> list[str]:
    """σ0 under a label that says what it is.

    DECISION: with unit weights (no standard deviations given) the weight matrix is
    I in 1/m², so σ0 = sqrt(vᵀv / r) is a length: the a-posteriori standard deviation
    of one coordinate, in metres (shown in mm). With given standard deviations, σ0 is
    the unitless ratio of the actual to the stated precision (a priori σ0 = 1) and its
    square is the variance factor; the two are never printed under one label
    (Niemeier, "Ausgleichungsrechnung", 2008, 4.3; Ghilani 2010, 16.5)."""
    if res.test == "w":
        return ["- σ0 a priori: 1 (unitless; the given standard deviations).",
                f"- σ0 a posteriori (ratio of actual to stated precision): "
                f"{res.sigma0:.4f} (unitless).",
                f"- Variance factor σ0² (a posteriori / a priori): {res.sigma0 ** 2:.4f} "
                "(unitless).", ""]
    return [f"- σ0 a posteriori, the standard deviation of one coordinate (unit weights, "
            f"so in metres): {res.sigma0:.6f} m = {res.sigma0 * 1000:.2f} mm.",
            "- Variance factor: not defined (no a-priori standard deviations given; pass "
            "sigma or sx,sy,sz columns to test the stated precision).", ""]


def _tests(res: HelmertResult) -> list[str]:
    """sigma0, the global test and every point above the critical value."""
    lines = ["## Tests", ""] + sigma0_lines(res)
    g = res.global_test
    if g.get("interval"):
        lo, hi = g["interval"]
        verdict = "passed" if g["passed"] else "REJECTED"
        lines.append(f"Global test: vᵀPv = {g['statistic']:.3f} (unitless), "
                     f"χ²({g['dof']}) 95 % interval [{lo:.3f}, {hi:.3f}]: {verdict}.")
    else:
        lines.append("Global test: not applicable (no a priori standard deviations; σ0 "
                     "estimated, τ-tests used).")
    if res.test == "w":
        name = ("Baarda w (Baarda 1968), critical value "
                f"{res.critical:.2f} (α0 = 0.001, two-sided standard normal)")
    else:
        name = (f"Pope τ (σ0 estimated; Pope 1976), critical value {res.critical:.2f} "
                f"(α0 = 0.001, {res.dof} degrees of freedom)")
    sym = "w" if res.test == "w" else "τ"
    lines += ["", f"Outlier test: {name}."]
    if res.outliers:
        ranked = ", ".join(f"{t['id']} {sym} = {t['statistic']:.2f}"
                           for t in res.outlier_tests)
        lines.append(f"Above the critical value, largest first ({len(res.outliers)}): "
                     f"{ranked}.")
        if len(res.outliers) > 1:
            lines.append("Only the largest is an outlier for certain: one blunder raises "
                         "its neighbours' tests too. Remove one point at a time (data "
                         "snooping: `tunnelsim adjust --snoop`).")
    else:
        lines.append("Flagged: none.")
    return lines + [""]


def _s0(value: float, test: str) -> str:
    """σ0 in a table whose header gives the unit (unitless ratio, or mm)."""
    return f"{value:.4f}" if test == "w" else f"{value * 1000:.2f}"


def _snooping(sn: Snooping) -> list[str]:
    """Points excluded by hand and every step of data snooping."""
    lines = []
    if sn.excluded:
        lines += [f"Excluded by hand (--exclude): {', '.join(sn.excluded)}.", ""]
    if not sn.snooped:
        return lines
    first = sn.initial
    lines += ["## Data snooping (Baarda 1968)", "",
              "Iterative: the point with the largest test above the critical value (w: "
              "3.29 for α0 = 0.001, two-sided standard normal; τ when σ0 is estimated) is "
              "removed and the network adjusted again, until no test exceeds it.", "",
              f"| step | removed | test (unitless) | critical (unitless) | σ0 after "
              f"({'unitless' if first.test == 'w' else 'mm'}) | points left | still above |",
              "|---:|---|---:|---:|---:|---:|---:|",
              f"| 0 | – | – | {first.critical:.2f} | {_s0(first.sigma0, first.test)} | "
              f"{len(first.ids)} | {len(first.outliers)} |"]
    for k, st in enumerate(sn.steps, start=1):
        sym = "w" if st.test == "w" else "τ"
        lines.append(f"| {k} | {st.removed} | {sym} = {st.statistic:.2f} | "
                     f"{st.critical:.2f} | {_s0(st.sigma0_after, st.test)} | {st.points_left} | "
                     f"{st.above_after} |")
    gone = ", ".join(sn.removed) if sn.steps else "none"
    lines += ["", f"Removed: {gone}. Ended: {sn.stopped}.", ""]
    return lines


def drift_report(corr: DriftCorrection, loo: NDArray[np.float64], *,
                 traj: Trajectory | None = None, plot_path: Path | None = None,
                 title: str = "MLS drift correction",
                 header: ReportHeader | None = None) -> str:
    """Markdown report of a ``DriftCorrection``: fit residuals and leave-one-out
    check-point residuals per control point, and (with the MLS trajectory) the
    correction magnitude along the distance travelled, plotted to ``plot_path``;
    ``header`` (inputs, CRS, ...) below the title."""
    fit = corr.residuals
    if fit is None:
        raise DriftError("Expected a fitted DriftCorrection (from fit_drift), got one "
                         "without residuals.")
    rms_fit = float(np.sqrt(np.mean(np.sum(fit ** 2, axis=1))))
    rms_loo = float(np.sqrt(np.mean(np.sum(loo ** 2, axis=1))))
    lines = [f"# {title}", ""] + (header_lines(header) if header is not None else []) + [
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
