"""Reports of an odometry / SLAM evaluation (``survey.analysis.trajectory``): a Markdown
table of the ATE and RPE figures with units, and a PNG of the top view and of the error
along / across / up the direction of travel against the distance travelled."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from survey.errors import CompareError

if TYPE_CHECKING:  # annotations only: the report module stays light to import
    from sensors.trajectory import Trajectory
    from survey.analysis.trajectory import TrajectoryErrors

__all__ = ["plot_slam", "slam_report"]

P = TypeVar("P", bound="str | Path")

_ALIGN_TEXT = {
    "origin": "the estimate moved rigidly so that its first pose equals the truth's pose "
              "at that time (evo `align_origin`): the drift of an odometry that starts from "
              "a known pose",
    "none": "none (the estimate is taken in the truth's frame as it is)",
    "se3": "rigid least-squares fit of the positions (Umeyama 1991; evo `--align`)",
    "sim3": "similarity least-squares fit of the positions, scale included (Umeyama "
            "1991; evo `--align --correct_scale`)",
}


def _f(v: float, digits: int = 3) -> str:
    return "n/a" if math.isnan(v) else f"{v:.{digits}f}"


def slam_report(errors: TrajectoryErrors, *, odometry: str,
                plot_path: str | os.PathLike[str] | None = None,
                title: str = "Odometry against the true trajectory") -> str:
    """Markdown report of ``TrajectoryErrors``.

    Parameters
    ----------
    errors : TrajectoryErrors
        From ``trajectory_errors``.
    odometry : str
        What produced the estimate (e.g. "KISS-ICP 1.2, default settings").
    plot_path : path, optional
        A figure written by ``plot_slam``, linked (by file name) from the report.
    title : str
        The heading.

    Returns
    -------
    str
        Markdown text: the figures in metres, % and degrees.
    """
    e = errors
    if e.align not in _ALIGN_TEXT:
        raise CompareError(f"Expected errors from trajectory_errors with align one of "
                           f"{', '.join(_ALIGN_TEXT)}, got {e.align!r}.")
    dropped = (f" ({e.n_dropped} estimate poses outside the truth's time span dropped)"
               if e.n_dropped else "")
    lines = [f"# {title}", "",
             f"Odometry: {odometry}.", "",
             f"Evaluated: {e.n_poses} poses{dropped}, {e.start_s:.2f}-{e.end_s:.2f} s, "
             f"{e.path_length_m:.2f} m of true path.", "",
             f"Alignment: {_ALIGN_TEXT[e.align]}"
             + (f"; scale {e.alignment_scale:.6f}" if e.align == "sim3" else "") + ".", "",
             "| figure | value |", "|---|---:|",
             f"| ATE RMS (m) | {_f(e.ate_rms_m)} |",
             f"| ATE mean (m) | {_f(e.ate_mean_m)} |",
             f"| ATE median (m) | {_f(e.ate_median_m)} |",
             f"| ATE max (m) | {_f(e.ate_max_m)} |",
             f"| final position error (m) | {_f(e.final_error_m)} |",
             f"| final position error (% of path) | {_f(e.final_error_pct, 2)} |",
             f"| final error along the travel (m) | {_f(e.final_error_along_m)} |",
             f"| final error lateral, left + (m) | {_f(e.final_error_lateral_m)} |",
             f"| final error vertical, up + (m) | {_f(e.final_error_vertical_m)} |",
             f"| final attitude error (deg) | "
             f"{_f(math.degrees(e.final_rotation_error_rad))} |", ""]
    if e.relative:
        lines += ["| RPE over | pairs | RMS (m) | mean (m) | max (m) | mean (% of Δ) | "
                  "rotation mean (deg) |", "|---|---:|---:|---:|---:|---:|---:|"]
        for r in e.relative:
            lines.append(f"| {r.delta_m:g} m | {r.n_pairs} | {_f(r.rms_m)} | "
                         f"{_f(r.mean_m)} | {_f(r.max_m)} | {_f(r.mean_pct, 2)} | "
                         f"{_f(math.degrees(r.rot_mean_rad))} |")
        if any(r.n_pairs == 0 for r in e.relative):
            lines.append("")
            lines.append("n/a: the path is shorter than Δ, no pair of poses.")
        lines.append("")
    whose = "estimate's" if e.pairs_from == "estimate" else "true"
    lines.append(
        "Computed as evo (Grupp 2017) does: the truth is interpolated at the estimate's "
        "times (positions linearly, attitudes by SLERP); ATE is |p_est − p_true| per pose "
        "after the alignment (evo APE, translation part); RPE takes consecutive pose pairs "
        f"(i, j) where the {whose} path from i first reaches Δ (evo `filter_pairs_by_path`, "
        "all_pairs=False) and the relative error E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j) (Sturm et "
        "al. 2012; Q truth, P estimate): translation |t(E)|, rotation the angle of R(E).")
    lines.append("Along / lateral / vertical: the error in the frame of the truth's heading "
                 "(horizontal direction of its x axis, left, world up).")
    if plot_path is not None:
        lines += ["", f"![trajectory errors]({Path(plot_path).name})"]
    return "\n".join(lines) + "\n"


def plot_slam(estimate: Trajectory, truth: Trajectory, errors: TrajectoryErrors,
              path: P) -> P:
    """PNG of an evaluation (atomic): top view of the truth and of the aligned estimate
    (every estimate pose, moved by ``errors.alignment_matrix``), and the error along /
    lateral / vertical against the true distance travelled. Returns ``path``."""
    from survey.report.plotting import pyplot, save_png

    o = truth.origin
    a = errors.alignment_matrix
    est = (estimate.positions - o) @ a[:3, :3].T + (a[:3, 3] + a[:3, :3] @ o - o)
    tru = truth.positions - o
    plt = pyplot()
    fig, (top, err) = plt.subplots(1, 2, figsize=(11, 4.2), dpi=110)
    top.plot(tru[:, 0], tru[:, 1], color="k", lw=1.2, label="truth")
    top.plot(est[:, 0], est[:, 1], color="tab:red", lw=1.0, label="estimate (aligned)")
    top.plot(tru[:1, 0], tru[:1, 1], "o", color="k", ms=4)
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel(f"x from {o[0]:.0f} (m)")
    top.set_ylabel(f"y from {o[1]:.0f} (m)")
    top.set_title("top view")
    top.legend(fontsize=8)
    top.grid(alpha=0.3)
    d = errors.distance_m
    err.plot(d, errors.error_along_m, label="along the travel")
    err.plot(d, errors.error_lateral_m, label="lateral (left +)")
    err.plot(d, errors.error_vertical_m, label="vertical (up +)")
    err.plot(d, np.linalg.norm(errors.error_m, axis=1), color="k", lw=0.8, ls="--",
             label="|error|")
    err.set_xlabel("distance travelled (m)")
    err.set_ylabel("estimate − truth (m)")
    err.set_title(f"position error, align={errors.align}")
    err.legend(fontsize=8)
    err.grid(alpha=0.3)
    fig.tight_layout()
    return save_png(fig, path)
