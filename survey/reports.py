"""Readable reports (Markdown) of adjustments, as surveyors expect from adjustment
software: parameters with standard deviations, sigma0, tests, residuals per point."""

from __future__ import annotations

import numpy as np


def helmert_report(res, *, title: str = "Helmert adjustment") -> str:
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
