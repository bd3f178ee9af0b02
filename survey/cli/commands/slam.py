"""The slam command: real LiDAR odometry (KISS-ICP, GenZ-ICP) on a simulated drive
(``survey.workflows.slam.slam_file`` does the work; this module parses and prints)."""

from __future__ import annotations

from survey.cli.common import CommandSet, report_options


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


def cmd_slam(args) -> int:
    from survey.workflows.slam import slam_file

    def announce(drive) -> None:
        if not args.quiet:
            print(f"{args.odometry} on {drive.n_points:,} points of {drive.sensor} "
                  f"({drive.time_span_s[1] - drive.time_span_s[0]:.1f} s)...")

    res = slam_file(args.drive, args.output, odometry=args.odometry, truth=args.truth,
                    cloud=args.cloud, place=args.place, control=args.control,
                    voxel_m=args.voxel, max_range_m=args.max_range, seed=args.seed,
                    project=args.project, instrument=args.instrument,
                    on_start=announce)
    if not args.quiet:
        odo, s = res.odometry, res.summary
        line = (f"{args.odometry}: {len(odo.times)} frames in {odo.seconds:.1f} s "
                f"({len(odo.skipped)} partial skipped)")
        if "final_error_pct" in s:
            line += (f"; final error {100 * s['final_error_m']:.1f} cm = "
                     f"{s['final_error_pct']:.2f} % of {s['path_length_m']:.1f} m, "
                     f"ATE RMS {100 * s['ate_rms_m']:.1f} cm")
        print(line + " -> " + ", ".join(p.name for p in res.written))
    return 0


__all__ = ["cmd_slam", "register"]
