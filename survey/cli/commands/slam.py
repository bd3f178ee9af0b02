"""The slam command: real LiDAR odometry (KISS-ICP, GenZ-ICP) on a simulated drive."""

from __future__ import annotations

from survey.cli.common import CommandSet, report_options, write_headed_report, write_json
from survey.errors import TunnelsimCLIError

#: Trajectory suffixes ``slam -o`` writes (TUM text, or CSV).
TRAJECTORY_SUFFIXES = (".txt", ".tum", ".csv")


def register(commands: CommandSet) -> None:
    """Add slam."""
    c = commands.add(
        "slam", cmd_slam, seeded=True,
        help="run LiDAR odometry (KISS-ICP) on a simulated drive",
        description="Run real LiDAR odometry on a drive simulated with 'tunnelsim drive "
                    "--fields full' (per-point times and sensor-frame points; or a ROS 2 "
                    "bag from 'tunnelsim drive -o drive.mcap') and write "
                    "the estimated platform trajectory (TUM). With --truth: anchor it at "
                    "the true start pose and evaluate it as evo does (ATE after first-pose "
                    "alignment, drift per 10 m and 100 m): _report.md, .json and .png "
                    "beside it. With --cloud: the drive (or --place, another drive on the "
                    "same platform) re-placed with the estimated poses; with --control "
                    "too: the control points as a surveyor has them for 'tunnelsim "
                    "correct' (<cloud>_cp_world.csv, <cloud>_cp_observed.csv). Needs the "
                    "optional extra: pip install 'tunnelsim[slam]'.",
        epilog="Example: tunnelsim slam drive.laz -o estimate.txt --truth "
               "drive_true_trajectory.txt --cloud slam_cloud.laz --control tunnel.json")
    c.option("drive", path="in",
             help="drive with full fields (.las/.laz), or a ROS 2 bag (.mcap or a rosbag2 "
                  "folder from 'tunnelsim drive -o drive.mcap')")
    c.option("-o", "--output", required=True, path="out",
             help="estimated platform trajectory (.txt/.tum TUM, or .csv)")
    c.option("--odometry", choices=["kiss-icp", "genz-icp"], default="kiss-icp",
             help="LiDAR odometry (default kiss-icp)")
    c.option("--truth", path="in",
             help="the true platform trajectory (drive's _true_trajectory.txt): anchor "
                  "and evaluate")
    c.option("--cloud", path="out",
             help="write the drive re-placed with the estimated poses here (.las/.laz)")
    c.option("--place", path="in",
             help="with --cloud: re-place this drive instead (e.g. a profiler on the same "
                  "platform; full fields)")
    c.option("--control", path="in",
             help="with --truth and --cloud: tunnel JSON whose control points to observe")
    c.option("--voxel", type=float, metavar="M",
             help="odometry map voxel in m (default 0.5 for KISS-ICP, 0.3 for GenZ-ICP)")
    c.option("--max-range", type=float, default=100.0, metavar="M",
             help="ignore points farther than this (default 100)")
    report_options(c)


def _check_args(args):
    """Everything that can be checked before the odometry runs (so that bad input
    fails at once and leaves no file)."""
    from pathlib import Path

    out = Path(args.output)
    if out.suffix.lower() not in TRAJECTORY_SUFFIXES:
        raise TunnelsimCLIError(f"Expected -o as a trajectory file {TRAJECTORY_SUFFIXES} "
                                f"(TUM text or CSV), got '{out}'.")
    if args.cloud and Path(args.cloud).suffix.lower() not in (".las", ".laz"):
        raise TunnelsimCLIError(f"Expected --cloud as .las/.laz, got '{args.cloud}'.")
    if args.place and not args.cloud:
        raise TunnelsimCLIError("Expected --cloud OUT.laz with --place (where to write the "
                                "re-placed drive), got none.")
    if args.control and not (args.truth and args.cloud):
        raise TunnelsimCLIError("Expected --truth and --cloud with --control (control "
                                "points are observed in the re-placed cloud), got "
                                f"{'no --truth' if not args.truth else 'no --cloud'}.")


def _control(path):
    """(ids, (k, 3) xyz) of the control points in a tunnel JSON."""
    import numpy as np

    from sensors.io.errors import TunnelFileError
    from survey.world.mesh import read_meta

    cps = read_meta(path).get("control_points")
    if not cps:
        raise TunnelFileError(f"Expected 'control_points' in '{path}' (a JSON written by "
                              "'tunnelsim tunnel'), got none.")
    return [c["id"] for c in cps], np.array([c["xyz"] for c in cps], dtype=np.float64)


def cmd_slam(args) -> int:
    from pathlib import Path

    from sensors import Trajectory
    from survey.adjust.odometry import platform_trajectory, run_odometry
    from survey.clouds.drives import iter_frames, open_drive, replace_drive

    _check_args(args)
    drive = open_drive(args.drive)
    place = open_drive(args.place) if args.place else drive
    if args.cloud and place.kind != "las":
        raise TunnelsimCLIError(f"Expected a LAS/LAZ drive to re-place with --cloud, got the "
                                f"ROS 2 bag '{place.path}'; pass --place DRIVE.laz (the same "
                                "drive written with --fields full).")
    truth = Trajectory.read(args.truth) if args.truth else None
    control = _control(args.control) if args.control else None
    if not args.quiet:
        print(f"{args.odometry} on {drive.n_points:,} points of {drive.sensor} "
              f"({drive.time_span_s[1] - drive.time_span_s[0]:.1f} s)...")
    res = run_odometry(iter_frames(drive), method=args.odometry, voxel_size_m=args.voxel,
                       max_range_m=args.max_range)
    start = None
    if truth is not None:
        pos, rot = truth.interpolate([res.times[0]])
        start = (pos[0], rot[0])
    lo = min(drive.time_span_s[0], place.time_span_s[0])
    hi = max(drive.time_span_s[1], place.time_span_s[1])
    est = platform_trajectory(res, drive.mount, start=start, span_s=(lo, hi))
    out = Path(args.output)
    est.write(out)
    said = [out.name]
    summary = {"odometry": args.odometry, "frames": len(res.times),
               "skipped_frames": len(res.skipped), "points": res.n_points,
               "odometry_seconds": res.seconds, **res.settings}
    if truth is not None:
        summary.update(_evaluate(args, est, truth, out, summary))
        said += [f"{out.stem}_report.md", f"{out.stem}.json", f"{out.stem}.png"]
    if args.cloud:
        n = replace_drive(place, args.cloud, est)
        said.append(Path(args.cloud).name)
        summary["cloud_points"] = n
        if control is not None and truth is not None:
            said += _observe(args, truth, est, control)
    if not args.quiet:
        line = (f"{args.odometry}: {len(res.times)} frames in {res.seconds:.1f} s "
                f"({len(res.skipped)} partial skipped)")
        if "final_error_pct" in summary:
            line += (f"; final error {100 * summary['final_error_m']:.1f} cm = "
                     f"{summary['final_error_pct']:.2f} % of {summary['path_length_m']:.1f} m, "
                     f"ATE RMS {100 * summary['ate_rms_m']:.1f} cm")
        print(line + " -> " + ", ".join(said))
    return 0


def _evaluate(args, est, truth, out, run: dict) -> dict:
    """Evaluate against the truth (survey.analysis.trajectory) and write the report,
    the JSON (with ``run``: frames, points, odometry seconds and settings) and the plot
    beside the trajectory; returns the key figures."""
    from survey.analysis.trajectory import trajectory_errors
    from survey.report.slam import plot_slam, slam_report

    err = trajectory_errors(est, truth)
    png = out.with_name(out.stem + ".png")
    plot_slam(est, truth, err, png)
    write_headed_report(args, out.with_name(out.stem + "_report.md"),
                        slam_report(err, odometry=args.odometry, plot_path=png),
                        [("drive", args.drive, ""), ("truth", args.truth, "")],
                        settings=[("odometry", str(args.odometry))])
    d = err.to_dict()
    write_json(out.with_name(out.stem + ".json"), dict(d, **run))
    return {k: d[k] for k in ("final_error_m", "final_error_pct", "path_length_m",
                              "ate_rms_m") if k in d}


def _observe(args, truth, est, control) -> list[str]:
    """The control points a surveyor has for the re-placed cloud: world coordinates
    by total station, and the prisms picked in the cloud with the time they were
    passed (survey.adjust.slam.observe_control)."""
    from pathlib import Path

    from survey.adjust.slam import observe_control

    ids, xyz = control
    observed, world = observe_control(truth, est, ids, xyz, seed=args.seed)
    c = Path(args.cloud)
    names = [f"{c.stem}_cp_observed.csv", f"{c.stem}_cp_world.csv"]
    observed.write(c.with_name(names[0]))
    world.write(c.with_name(names[1]))
    return names


__all__ = ["cmd_slam", "register"]
