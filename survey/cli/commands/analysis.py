"""Commands that analyse: compare (C2C / C2M), plan (TLS stations), study (MLS speeds)."""

from __future__ import annotations

import sys
from pathlib import Path

from survey.cli.common import (
    CommandSet,
    cluster_options,
    floats,
    header_values,
    open_cluster,
    pair,
    report_options,
    say,
    warn_radian_like,
)
from survey.errors import TunnelsimCLIError


def register(commands: CommandSet) -> None:
    """Add compare, plan and study."""
    c = commands.add(
        "compare", cmd_compare,
        help="cloud-to-cloud or cloud-to-mesh distances, with statistics",
        description="Distances from one or more clouds to a reference, CloudCompare "
                    "semantics: exact nearest neighbour (C2C) or signed distance to a mesh "
                    "(C2M, positive on the side of the triangle normal). The last path is "
                    "the reference (cloud, or a mesh .ply/.obj/.stl). Writes stats.csv, "
                    "stats.md (mean, median, std, 95 %, RMS per scan), histogram.png and "
                    "each cloud as LAZ with the scalar field 'distance'.",
        epilog="Example: tunnelsim compare station_sim.laz station_real.laz --max-dist 0.5 "
               "-o compare/")
    c.option("clouds", nargs="+", metavar="CLOUD", path="in",
             help="compared cloud(s), then the reference")
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--max-dist", type=float, metavar="M",
             help="clamp distances at M metres (points farther get M)")
    c.option("--split", action="store_true",
             help="also write the X/Y/Z components (compared - nearest reference)")
    c.option("--model", choices=["plane"],
             help="local model of the reference: least-squares plane of --k points")
    c.option("--k", type=int, default=6, help="neighbours for --model (default 6)")
    c.option("--allow-disjoint", action="store_true",
             help="compare clouds whose bounding boxes lie more than 1 m apart (refused "
                  "by default: different frames or units)")
    c.option("--allow-crs-mismatch", action="store_true",
             help="compare inputs that state different coordinate reference systems "
                  "(refused by default: reproject one first)")
    c.option("--tile-m", type=float, metavar="M",
             help="compare tile by tile (x, y tiles of M metres, spilled to disk in "
                  "the output folder): memory bounded by a tile, not by the clouds, and "
                  "the tiles run as tasks (on --workers or --scheduler); the same "
                  "distances as one piece. A reference cloud needs --max-dist (the "
                  "tiles' halo)")
    cluster_options(c, needs=("tile-m",))
    c.option("--threads", type=int, help="Numba threads (default: all cores)")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    c.option("--quiet", action="store_true", help="no progress bar or summary")
    report_options(c)

    c = commands.add(
        "plan", cmd_plan,
        help="TLS station planning: coverage of spacings, optimised station set",
        description="Quality of every lining cell (coverage, point spacing from the "
                    "preset's angular step and range, incidence, range) for stations on "
                    "the axis at fixed spacings, and optionally the smallest station set "
                    "reaching a target coverage (MILP, greedy bound). Writes plan.csv, "
                    "plan.md, plan.json and coverage.png (unrolled chainage x angle). "
                    "On any mesh (no tunnel .json, or --along auto) the stations stand "
                    "along the route found in the mesh and offset across it, coverage "
                    "is measured on the mesh's own triangles (area-weighted), chainage "
                    "is the distance along the route, and route.csv is written too.",
        epilog="Example: tunnelsim plan --mesh bfo.ply --sensor zf_imager_5016 "
               "--resolution high --spacing 5,10 --optimize --target 0.99 -o plan/")
    c.option("--mesh", required=True, path="in",
             help="tunnel mesh (its .json gives the axis), or any mesh")
    _route_options(c, "stations")
    c.option("--offsets", default="1", metavar="M[,M...]",
             help="with --along auto and --optimize: candidate stations also this far "
                  "left and right of the route, where they fit (default 1)")
    c.option("--clearance", type=float, default=0.2, metavar="M",
             help="with --along auto: smallest distance of a station from the mesh "
                  "(default 0.2)")
    c.option("--sensor", default="zf_imager_5016", path="toml",
             help="TLS sensor name or .toml")
    c.option("--resolution", help="resolution preset (default: the sensor's)")
    c.option("--spacing", default="5,10", metavar="M[,M...]",
             help="station spacings to compare in metres (default 5,10)")
    c.option("--optimize", action="store_true",
             help="find the smallest station set for --target")
    c.option("--target", type=float, default=0.99,
             help="coverage share to reach with --optimize (default 0.99)")
    c.option("--candidate-step", type=float, default=2.5, metavar="M",
             help="candidate stations every M metres (default 2.5)")
    c.option("--time-limit", type=float, default=60.0, metavar="S",
             help="MILP time limit in seconds (default 60)")
    c.option("--spacing-mm", type=float, default=5.0,
             help="point-spacing threshold in mm (default 5)")
    c.option("--incidence-deg", type=float, default=70.0,
             help="incidence threshold in degrees (default 70)")
    c.option("--range", type=float, default=30.0, metavar="M",
             help="range threshold in metres (default 30)")
    c.option("--cell", default="0.25,2", metavar="M,DEG",
             help="lining cell size along (m) and around (deg) (default 0.25,2); with "
                  "--along auto, M is the largest edge of a triangle sample")
    c.option("--height", type=float, default=1.5, metavar="M",
             help="instrument height above the floor (default 1.5)")
    cluster_options(c)
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--threads", type=int, help="Numba threads (default: all cores)")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    c.option("--quiet", action="store_true", help="print nothing on success")
    report_options(c)

    c = commands.add(
        "study", cmd_study, seeded=True, help="MLS speed x scan-rate x mounting study",
        description="Drive a spinning lidar (or profiler) through an evaluation strip at "
                    "each speed, rate and mounting: density on lining and floor, empty "
                    "lining share, along-track line spacing, rolling-shutter distortion. "
                    "Writes study.csv, study.md and study.png (floor rings per speed, "
                    "density vs speed).",
        epilog="Example: tunnelsim study --mesh bfo.ply --sensor robosense_airy --speeds "
               "0,1,3 --rates 10,20 --mounts down -o study/")
    c.option("--mesh", required=True, path="in",
             help="tunnel mesh (its .json gives the axis), or any mesh: then the sensor "
                  "drives along the route found in it, the strip is in distance along "
                  "the route and the cells are the mesh's own triangles")
    _route_options(c, "the sensor")
    c.option("--cell", type=float, default=0.1, metavar="M",
             help="cell size (m): along the axis, or with --along auto the largest "
                  "edge of a triangle sample (default 0.1)")
    c.option("--sensor", default="robosense_airy", path="toml", help="sensor name or .toml")
    c.option("--speeds", default="0,1,3", metavar="V[,V...]",
             help="speeds in m/s (default 0,1,3)")
    c.option("--rates", default="10", metavar="HZ[,HZ...]",
             help="rotation (profile) rates in Hz (default 10)")
    c.option("--mounts", default="level,down", metavar="level,down",
             help="mountings (default level,down)")
    c.option("--strip", metavar="START,END",
             help="evaluation strip in chainage (default: 5 m mid-tunnel)")
    c.option("--lead", type=float, default=5.0, metavar="M",
             help="drive this far before and after the strip (default 5)")
    c.option("--height", type=float, default=0.5, metavar="M",
             help="sensor height above the floor (default 0.5)")
    c.option("--ideal", action="store_true",
             help="exact geometry: no noise, every return detected")
    c.option("--seed", type=int, default=0, help="random seed (default 0)")
    cluster_options(c)
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--threads", type=int, help="Numba threads (default: all cores)")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    c.option("--quiet", action="store_true", help="print nothing on success")
    report_options(c)


def _route_options(c, who: str) -> None:
    """--along and --waypoints of plan and study."""
    c.option("--along", choices=["centreline", "auto"],
             help=f"centreline: {who} on the tunnel axis (needs the mesh's .json); auto: "
                  "along the route found in the mesh (default: centreline when the "
                  ".json gives the axis, else auto)")
    c.option("--waypoints", path="in", metavar="CSV",
             help="with --along auto: x,y[,z] rows the route passes in order")


# ---------------------------------------------------------------------------- compare
def cmd_compare(args) -> int:
    """compare: ``survey.workflows.compare.compare_files``, then the summary."""
    from survey.cli.common import Progress
    from survey.workflows.compare import compare_files

    if len(args.clouds) < 2:
        raise TunnelsimCLIError("Expected at least two paths (compared cloud(s), then the "
                                f"reference), got {len(args.clouds)}.")
    if (args.workers or args.scheduler) and args.tile_m is None:
        raise TunnelsimCLIError("Expected --tile-m with --workers or --scheduler (the "
                                "tasks are tiles), got none.")
    *compared, ref_path = args.clouds
    # Tile by tile, each compared cloud gets a bar of tiles instead.
    prog = Progress(args.quiet or args.tile_m is not None, unit="points")
    try:
        r = compare_files(
            compared, ref_path, args.output, max_distance_m=args.max_dist,
            split=args.split, model=args.model, k=args.k,
            allow_disjoint=args.allow_disjoint,
            allow_crs_mismatch=args.allow_crs_mismatch, tile_m=args.tile_m,
            executor=lambda: open_cluster(args), force=args.force, progress=prog,
            tile_progress=lambda c: Progress(args.quiet, unit=f"tiles of {Path(c).name}",
                                             style="count"),
            **header_values(args))
    except BaseException:
        if prog.calls:
            prog.close()
        raise
    prog.close()
    say(args, r.table.rstrip() + f"\n-> {r.output_dir}/ (stats.csv, stats.md/.html, "
                                 "histogram.png, *_distance.laz with scalar field "
                                 "'distance')")
    return 0


# ---------------------------------------------------------------------------- plan
def cmd_plan(args) -> int:
    """plan: ``survey.workflows.planning.plan_stations``, then the summary."""
    from survey.cli.common import Progress
    from survey.workflows.planning import plan_stations

    warn_radian_like(args.incidence_deg, "--incidence-deg")
    cell_m, cell_deg = pair(args.cell, "--cell as M,DEG")
    spacings = floats(args.spacing, "--spacing")
    offsets = floats(args.offsets, "--offsets")
    bar = Progress(args.quiet, unit="stations", style="count")
    try:
        r = plan_stations(
            args.mesh, args.output, sensor=args.sensor, resolution=args.resolution,
            spacings_m=spacings, optimize=args.optimize, target=args.target,
            candidate_step_m=args.candidate_step, time_limit_s=args.time_limit,
            spacing_threshold_m=args.spacing_mm / 1000.0,
            incidence_deg=args.incidence_deg, range_m=args.range, cell_m=cell_m,
            cell_deg=cell_deg, height_m=args.height, along=args.along,
            waypoints=args.waypoints or None, offsets_m=offsets,
            clearance_m=args.clearance, executor=lambda: open_cluster(args),
            force=args.force, progress=bar, **header_values(args))
    finally:
        if bar.calls:       # drawn only when the stations ran on a cluster
            bar.close()
    files = "plan.csv, plan.md, plan.json, coverage.png"
    if r.route_file is not None:
        files += ", route.csv"
    say(args, r.markdown.split("\n## Largest")[0].rstrip() +
        f"\n-> {r.output_dir}/ ({files})")
    return 0


# ---------------------------------------------------------------------------- study
def cmd_study(args) -> int:
    """study: ``survey.workflows.planning.run_study``, then the summary."""
    from survey.workflows.planning import run_study

    strip = None
    if args.strip:
        a, b = pair(args.strip, "--strip as START,END in m")
        strip = (a, b)
    mounts = [m.strip() for m in args.mounts.split(",") if m.strip()]

    def progress(i, n):
        if not args.quiet and sys.stderr.isatty():
            sys.stderr.write(f"\rstudy: {i}/{n} configurations ")
            sys.stderr.flush()

    r = run_study(args.mesh, args.output, sensor=args.sensor,
                  speeds_mps=floats(args.speeds, "--speeds"),
                  rates_hz=floats(args.rates, "--rates"), mounts=mounts, strip_m=strip,
                  lead_m=args.lead, height_m=args.height, cell_m=args.cell,
                  ideal=args.ideal, seed=args.seed, along=args.along,
                  waypoints=args.waypoints or None, executor=lambda: open_cluster(args),
                  force=args.force, progress=progress, **header_values(args))
    if not args.quiet and sys.stderr.isatty():
        sys.stderr.write("\n")
    files = "study.csv, study.md, study.png"
    if r.route_file is not None:
        files += ", route.csv"
    say(args, r.markdown.rstrip() + f"\n-> {r.output_dir}/ ({files})")
    return 0


__all__ = ["cmd_compare", "cmd_plan", "cmd_study", "register"]
