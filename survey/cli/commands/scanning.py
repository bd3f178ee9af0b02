"""Command that simulates a terrestrial scanner: scan (one TLS station, or a campaign
of stations with --chainages / --plan, on the execution layer).

Guards (each a one-line error, exit 2, no output left behind): a station outside the
mesh's bounding box (unless ``--allow-outside``), a station that returns no point. A
degree option whose value looks like radians is a warning (``radian_like``).
"""

from __future__ import annotations

import math

from survey.cli.common import (
    CommandSet,
    cluster_options,
    open_cluster,
    out_dir,
    parse_window,
    physics_options,
    warn_radian_like,
    xyz,
)
from survey.cli.commands.simruns import (
    crs_option,
    run_settings,
    summary_line,
    waveform_data,
    waveform_option,
    with_progress,
)
from survey.errors import TunnelsimCLIError
# Light at import (it loads NumPy only where it runs): every tunnelsim start reads this.
from survey.workflows.scan import STATION_FORMATS, station_heading_deg


def register(commands: CommandSet) -> None:
    """Add scan."""
    c = commands.add(
        "scan", cmd_scan, seeded=True, help="simulate a TLS station on a mesh",
        description="Simulate a terrestrial laser scanner station on a mesh and stream the "
                    "points to a file (LAS/LAZ, PLY, NPZ, E57).",
        epilog="Example: tunnelsim scan --mesh bfo.ply --sensor zf_imager_5016 "
               "--resolution superhigh --at 150,2,1.5 -o station.laz (a campaign on 4 "
               "local workers: tunnelsim scan --mesh bfo.ply --resolution high "
               "--chainages 10:300:5 --workers 4 -o campaign/)")
    c.option("--mesh", required=True, path="in",
             help="mesh file (PLY with reflectivity, OBJ, ...)")
    c.option("--sensor", default="zf_imager_5016", path="toml",
             help="sensor name ('tunnelsim sensors' lists them) or a .toml file")
    g = c.exclusive(required=True)
    c.option("--at", group=g, metavar="X,Y,Z", help="station position (m)")
    c.option("--chainage", group=g, type=float, metavar="M",
             help="station on the tunnel axis at this chainage, --height above the floor "
                  "(axis from --tunnel-json or the mesh's .json)")
    c.option("--chainages", group=g, metavar="START:STOP:STEP",
             help="a campaign: a station every STEP m from START to STOP (included when "
                  "on the grid) on the tunnel axis; -o is then a folder that receives "
                  "one file per station and manifest.json")
    c.option("--plan", group=g, path="in", metavar="PLAN_JSON",
             help="a campaign: the stations of a plan.json written by 'tunnelsim plan' "
                  "(the optimised plan, or --plan-name); -o is then a folder")
    c.option("--plan-name", metavar="NAME",
             help="with --plan: the plan to scan (e.g. 'every 10 m'; default the "
                  "optimised one, or the only one)")
    c.option("--height", type=float, default=1.5, metavar="M",
             help="instrument height above the floor with --chainage(s) (default 1.5)")
    c.option("--tunnel-json", path="in",
             help="axis for --chainage(s) (default: the mesh's .json)")
    c.option("--resolution", help="resolution preset of the sensor (e.g. superhigh)")
    c.option("--step-deg", type=float, metavar="DEG",
             help="angular step in degrees instead of a preset")
    g = c.exclusive()
    c.option("--heading-deg", type=float, group=g, metavar="DEG",
             help="station heading, degrees counter-clockwise from +x (east) (default 0)")
    c.option("--azimuth-deg", type=float, group=g, metavar="DEG",
             help="station heading as surveyors give it: degrees clockwise from grid north "
                  "(+y); heading = 90 - azimuth")
    c.option("--allow-outside", action="store_true",
             help="scan from a station outside the mesh's bounding box (e.g. a portal "
                  "seen from outside) instead of refusing it")
    c.option("--format", choices=list(STATION_FORMATS),
             help="with --chainages / --plan: the stations' file format (default laz)")
    c.option("--force", action="store_true",
             help="with --chainages / --plan: write into an output folder that holds "
                  "files (they are replaced one by one); a single station's file is "
                  "replaced with or without it")
    cluster_options(c, needs=("chainages", "plan"))
    crs_option(c)
    physics_options(c)
    waveform_option(c)


def cmd_scan(args) -> int:
    from survey.workflows.scan import scan_to_file

    warn_radian_like(args.heading_deg, "--heading-deg")
    warn_radian_like(args.azimuth_deg, "--azimuth-deg")
    heading_deg = station_heading_deg(args.heading_deg, args.azimuth_deg)
    if args.chainages is not None or args.plan is not None:
        return _scan_campaign(args, heading_deg)
    given = [f for f, v in (("--workers", args.workers), ("--scheduler", args.scheduler),
                            ("--plan-name", args.plan_name), ("--format", args.format))
             if v]
    if given:
        raise TunnelsimCLIError(f"Expected {given[0]} with --chainages or --plan (a "
                                "campaign of stations), got it with a single station.")
    at = None if args.at is None else xyz(args.at, "--at")
    res = with_progress(args, scan_to_file, mesh=args.mesh, output=args.output,
                        sensor=args.sensor, at=at, chainage_m=args.chainage,
                        height_m=args.height, tunnel_json=args.tunnel_json,
                        heading_rad=math.radians(heading_deg), **_station_options(args),
                        waveform_data=waveform_data(args))
    if not args.quiet:
        print(summary_line(res.label, res.output, args.output))
    return 0


def _station_options(args) -> dict:
    """The keywords a station and a campaign share."""
    return dict(resolution=args.resolution,
                step_rad=None if args.step_deg is None else math.radians(args.step_deg),
                allow_outside=args.allow_outside, crs=args.crs,
                settings=run_settings(args), seed=args.seed,
                reflectivity=args.reflectivity, fields=args.fields)


def _scan_campaign(args, heading_deg: float) -> int:
    """tunnelsim scan --chainages / --plan: one file per station and manifest.json in
    the -o folder, on the executor --workers / --scheduler choose."""
    from survey.cluster import TaskProgress
    from survey.workflows.scan import scan_campaign

    chainages = None if args.chainages is None else parse_window(
        args.chainages, "--chainages as START:STOP:STEP in m", 3)
    folder = out_dir(args.output, force=args.force)
    prog = TaskProgress(args.quiet, unit="stations")
    try:
        with open_cluster(args) as ex:
            res = scan_campaign(args.mesh, folder, chainages_m=chainages, plan=args.plan,
                                plan_name=args.plan_name, sensor=args.sensor,
                                height_m=args.height, tunnel_json=args.tunnel_json,
                                heading_rad=math.radians(heading_deg),
                                fmt=args.format or "laz", executor=ex, progress=prog,
                                **_station_options(args))
    finally:
        prog.close()
    if not args.quiet:
        print(f"{res.sensor} {res.resolution}: {res.stations} stations, {res.pulses:,} "
              f"pulses, {res.points:,} points, {res.wall_s:.1f} s ({res.where}; "
              f"{res.simulation_s:.1f} s of simulation) -> {res.manifest_path}")
    return 0


__all__ = ["cmd_scan", "register"]
