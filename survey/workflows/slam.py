"""Real LiDAR odometry (KISS-ICP, GenZ-ICP) on a simulated drive, as one library call:
``slam_file`` writes what ``tunnelsim slam`` writes and returns what it prints.

Needs the optional extra: ``pip install 'tunnelsim[slam]'``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from raytrace.fileio import write_json
from sensors import Trajectory
from sensors.io.errors import TunnelFileError
from sensors.io.tunnel_json import read_meta
from survey.adjust.odometry import OdometryResult, odometry_trajectory, run_odometry
from survey.adjust.slam import observe_control
from survey.analysis.trajectory import TrajectoryErrors, trajectory_errors
from survey.clouds.drives import DriveFile, iter_frames, open_drive, replace_drive
from survey.errors import OdometryError
from survey.report.header import write_headed_report
from survey.report.slam import plot_slam, slam_report

__all__ = ["KEY_FIGURES", "TRAJECTORY_SUFFIXES", "SlamResult", "slam_file"]

PathLike = str | Path

#: Trajectory suffixes ``slam_file`` writes (TUM text, or CSV).
TRAJECTORY_SUFFIXES = (".txt", ".tum", ".csv")
#: The key figures of an evaluation that the result and the summary line carry.
KEY_FIGURES = ("final_error_m", "final_error_pct", "path_length_m", "ate_rms_m")


@dataclass(frozen=True)
class SlamResult:
    """What ``slam_file`` computed and wrote.

    Attributes
    ----------
    odometry : OdometryResult
        The odometry's sensor poses, frames, skipped frames, points, seconds, settings.
    trajectory : sensors.Trajectory
        The estimated platform trajectory, as written to ``trajectory_path``.
    trajectory_path : Path
    errors : TrajectoryErrors or None
        The evaluation against the truth (with ``truth``).
    report_path, json_path, plot_path : Path or None
        ``<output stem>_report.md`` (and .html), ``<stem>.json``, ``<stem>.png`` beside
        the trajectory (with ``truth``).
    cloud_path : Path or None, the re-placed drive (with ``cloud``)
    cloud_points : int or None, its point count
    observed_path, world_path : Path or None
        ``<cloud stem>_cp_observed.csv`` and ``<cloud stem>_cp_world.csv`` (with
        ``control``).
    summary : dict
        What the JSON records besides the evaluation: odometry, frames,
        skipped_frames, points, odometry_seconds, the odometry's settings, and (with
        ``truth``) the key figures ``final_error_m``, ``final_error_pct``,
        ``path_length_m``, ``ate_rms_m`` (those the evaluation has), and
        ``cloud_points`` (with ``cloud``).
    written : tuple of Path
        Every file written, in the order ``tunnelsim slam`` names them.
    """

    odometry: OdometryResult
    trajectory: Trajectory
    trajectory_path: Path
    errors: TrajectoryErrors | None = None
    report_path: Path | None = None
    json_path: Path | None = None
    plot_path: Path | None = None
    cloud_path: Path | None = None
    cloud_points: int | None = None
    observed_path: Path | None = None
    world_path: Path | None = None
    summary: dict[str, Any] = field(default_factory=dict)
    written: tuple[Path, ...] = ()

    @property
    def final_error_m(self) -> float | None:
        """Distance between the last estimated and true positions (m), with ``truth``."""
        return self.summary.get("final_error_m")

    @property
    def final_error_pct(self) -> float | None:
        """``final_error_m`` in % of the path length, with ``truth``."""
        return self.summary.get("final_error_pct")

    @property
    def path_length_m(self) -> float | None:
        """The true path's length over the evaluated span (m), with ``truth``."""
        return self.summary.get("path_length_m")

    @property
    def ate_rms_m(self) -> float | None:
        """RMS absolute trajectory error after first-pose alignment (m), with ``truth``."""
        return self.summary.get("ate_rms_m")


def _check(output: Path, cloud: PathLike | None, place: PathLike | None,
           control: PathLike | None, truth: PathLike | None) -> None:
    """Everything that can be checked before the odometry runs (so that bad input
    fails at once and leaves no file)."""
    if output.suffix.lower() not in TRAJECTORY_SUFFIXES:
        raise OdometryError(f"Expected -o as a trajectory file {TRAJECTORY_SUFFIXES} "
                            f"(TUM text or CSV), got '{output}'.")
    if cloud and Path(cloud).suffix.lower() not in (".las", ".laz"):
        raise OdometryError(f"Expected --cloud as .las/.laz, got '{cloud}'.")
    if place and not cloud:
        raise OdometryError("Expected --cloud OUT.laz with --place (where to write the "
                            "re-placed drive), got none.")
    if control and not (truth and cloud):
        raise OdometryError("Expected --truth and --cloud with --control (control "
                            "points are observed in the re-placed cloud), got "
                            f"{'no --truth' if not truth else 'no --cloud'}.")


def _control(path: PathLike) -> tuple[list[str], NDArray[np.float64]]:
    """(ids, (k, 3) xyz) of the control points in a tunnel JSON."""
    cps = read_meta(Path(path)).get("control_points")
    if not cps:
        raise TunnelFileError(f"Expected 'control_points' in '{path}' (a JSON written by "
                              "'tunnelsim tunnel'), got none.")
    return [c["id"] for c in cps], np.array([c["xyz"] for c in cps], dtype=np.float64)


def slam_file(drive: PathLike, output: PathLike, *, odometry: str = "kiss-icp",
              truth: PathLike | None = None, cloud: PathLike | None = None,
              place: PathLike | None = None, control: PathLike | None = None,
              voxel_m: float | None = None, max_range_m: float = 100.0, seed: int = 0,
              project: str | None = None, instrument: str | None = None,
              on_start: Callable[[DriveFile], None] | None = None) -> SlamResult:
    """Run real LiDAR odometry on a simulated drive and write the estimated platform
    trajectory (``tunnelsim slam``).

    Parameters
    ----------
    drive : path-like
        A drive with full fields (.las/.laz from ``tunnelsim drive --fields full``),
        or a ROS 2 bag (.mcap or a rosbag2 folder from ``tunnelsim drive -o x.mcap``).
    output : path-like
        The estimated platform trajectory (.txt/.tum TUM, or .csv).
    odometry : {"kiss-icp", "genz-icp"}
    truth : path-like, optional
        The true platform trajectory (the drive's ``_true_trajectory.txt``): anchor the
        estimate at the true start pose and evaluate it as evo does (ATE after
        first-pose alignment, drift per 10 m and 100 m); writes ``_report.md`` (and
        .html), ``.json`` and ``.png`` beside ``output``.
    cloud : path-like, optional
        Write the drive (or ``place``) re-placed with the estimated poses here
        (.las/.laz).
    place : path-like, optional
        With ``cloud``: re-place this drive instead (another drive on the same
        platform, full fields).
    control : path-like, optional
        With ``truth`` and ``cloud``: a tunnel JSON whose control points to observe;
        writes ``<cloud>_cp_world.csv`` and ``<cloud>_cp_observed.csv`` (the input
        of ``correct_file``).
    voxel_m : float, optional
        The odometry's map voxel (m; default 0.5 for KISS-ICP, 0.3 for GenZ-ICP).
    max_range_m : float
        Points farther than this are ignored (m).
    seed : int
        Seed of the control points' observation noise.
    project, instrument : str, optional
        The user's words the report header states.
    on_start : callable, optional
        Called with the opened drive (``survey.clouds.drives.DriveFile``: points,
        sensor, time span) once the inputs are checked, before the odometry runs
        (``tunnelsim slam`` announces the run from it).

    Returns
    -------
    SlamResult

    Raises
    ------
    OdometryError
        Bad option combinations or suffixes (checked before anything runs), a bag
        to re-place, a missing backend, fewer than ``MIN_FRAMES`` whole frames.
    sensors.io.errors.PointFileError
        A drive without per-point times or sensor-frame fields.
    sensors.io.errors.TunnelFileError
        A ``control`` JSON without control points.

    Examples
    --------
    >>> res = slam_file("drive.laz", "est.txt",
    ...                 truth="drive_true_trajectory.txt")     # doctest: +SKIP
    >>> f"ATE RMS {100 * res.ate_rms_m:.1f} cm"                # doctest: +SKIP
    'ATE RMS 3.2 cm'
    """
    out = Path(output)
    _check(out, cloud, place, control, truth)
    drv = open_drive(drive)
    placed = open_drive(place) if place else drv
    if cloud and placed.kind != "las":
        raise OdometryError(f"Expected a LAS/LAZ drive to re-place with --cloud, got the "
                            f"ROS 2 bag '{placed.path}'; pass --place DRIVE.laz (the same "
                            "drive written with --fields full).")
    true = Trajectory.read(truth) if truth else None
    cps = _control(control) if control else None
    if on_start is not None:
        on_start(drv)
    res = run_odometry(iter_frames(drv), method=odometry, voxel_size_m=voxel_m,
                       max_range_m=max_range_m)
    start = None
    if true is not None:
        pos, rot = true.interpolate([res.times[0]])
        start = (pos[0], rot[0])
    lo = min(drv.time_span_s[0], placed.time_span_s[0])
    hi = max(drv.time_span_s[1], placed.time_span_s[1])
    est = odometry_trajectory(res, drv.mount, start=start, span_s=(lo, hi))
    est.write(out)
    written = [out]
    summary: dict[str, Any] = {"odometry": odometry, "frames": len(res.times),
                               "skipped_frames": len(res.skipped), "points": res.n_points,
                               "odometry_seconds": res.seconds, **res.settings}
    err = report = js = png = None
    if true is not None:
        # The evaluation (survey.analysis.trajectory) of the trajectory just made, its
        # plot, the report and the JSON (with the run's figures) beside it.
        err = trajectory_errors(est, true)
        png = out.with_name(out.stem + ".png")
        plot_slam(est, true, err, png)
        report = out.with_name(out.stem + "_report.md")
        write_headed_report(report, slam_report(err, odometry=odometry, plot_path=png),
                            inputs=[("drive", drive, ""), ("truth", truth, "")],
                            settings=[("odometry", str(odometry))], project=project,
                            instrument=instrument)
        d = err.to_dict()
        js = write_json(out.with_name(out.stem + ".json"), dict(d, **summary))
        summary.update({k: d[k] for k in KEY_FIGURES if k in d})
        written += [report, js, png]
    n = observed = world = None
    if cloud:
        n = replace_drive(placed, cloud, est)
        written.append(Path(cloud))
        summary["cloud_points"] = n
        if cps is not None and true is not None:
            # What a surveyor has for the re-placed cloud: world coordinates by total
            # station, the prisms picked in the cloud with the time they were passed.
            ob, wo = observe_control(true, est, cps[0], cps[1], seed=seed)
            c = Path(cloud)
            observed = c.with_name(f"{c.stem}_cp_observed.csv")
            world = c.with_name(f"{c.stem}_cp_world.csv")
            ob.write(observed)
            wo.write(world)
            written += [observed, world]
    return SlamResult(res, est, out, err, report, js, png,
                      None if cloud is None else Path(cloud), n, observed, world,
                      summary, tuple(written))
