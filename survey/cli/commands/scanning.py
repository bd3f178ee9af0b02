"""Command that simulates a terrestrial scanner: scan (one TLS station, or a campaign
of stations with --chainages / --plan, on the execution layer).

Guards (each a one-line error, exit 2, no output left behind): a station outside the
mesh's bounding box (unless ``--allow-outside``), a station that returns no point. A
degree option whose value looks like radians is a warning (``radian_like``).
"""

from __future__ import annotations

import math
import warnings

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
    box_text,
    crs_option,
    finish_run,
    output_crs,
    run_settings,
    xyz_text,
)
from survey.errors import TunnelsimCLIError

#: --format of a campaign: ``survey.cluster.campaign.STATION_FORMATS`` (spelt out here:
#: every ``tunnelsim`` start reads this module, and the library imports NumPy).
STATION_FORMATS = ("laz", "las", "ply", "npz", "e57")


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


def cmd_scan(args) -> int:
    import numpy as np
    from scipy.spatial.transform import Rotation

    from sensors import load_sensor, simulate_station
    from sensors.io.meshes import load_mesh

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
    spec = load_sensor(args.sensor)
    scene, refl = load_mesh(args.mesh)
    crs = output_crs(args)      # before the simulation: a bad --crs fails at once
    at = _station_on_axis(args, scene) if args.chainage is not None else xyz(args.at, "--at")
    lo, hi = scene.bounds
    if not args.allow_outside and ((np.asarray(at) < lo) | (np.asarray(at) > hi)).any():
        raise TunnelsimCLIError(f"Expected a station inside the mesh's bounding box "
                                f"{box_text(lo, hi)}, got {xyz_text(at)}; is it in another "
                                "coordinate frame? Pass --allow-outside to scan the mesh "
                                "from outside.")
    with warnings.catch_warnings():
        # Refused above, or allowed by --allow-outside: the library's warning is said.
        warnings.filterwarnings("ignore", "Station .* outside the mesh", UserWarning)
        run = simulate_station(scene, spec, at,
                               attitude=Rotation.from_euler("z", heading_deg, degrees=True),
                               resolution=args.resolution,
                               step_rad=None if args.step_deg is None
                               else np.deg2rad(args.step_deg),
                               settings=run_settings(args), seed=args.seed,
                               reflectivity=refl if refl is not None else args.reflectivity)
    resolution = getattr(run.scan, "resolution", None) or "custom step"
    return finish_run(args, run, f"{spec.name} {resolution}",
                       where=f" at {xyz_text(at)}; put the station where it sees the mesh",
                       crs=crs)


def _campaign_stations(args, scene, heading_deg: float):
    """(the stations of --chainages or --plan, what the manifest says of them)."""
    import numpy as np

    from survey.cluster import Station, read_plan

    h = math.radians(heading_deg)
    if args.plan is not None:
        name, stations = read_plan(args.plan, args.plan_name)
        return [Station(s.position, h, s.chainage_m) for s in stations], \
            {"plan": str(args.plan), "plan_name": name}
    start, stop, step = parse_window(args.chainages, "--chainages as START:STOP:STEP in "
                                     "m", 3)
    if not (all(map(math.isfinite, (start, stop, step))) and step > 0 and stop >= start):
        raise TunnelsimCLIError(f"Expected --chainages START:STOP:STEP with STEP > 0 and "
                                f"STOP >= START, got {args.chainages!r}.")
    # Chainages on the grid START + k STEP up to STOP, STOP included when on it (to a
    # micrometre: 0.1 steps do not add up exactly in binary).
    ch = start + step * np.arange(int(math.floor((stop - start) / step + 1e-9)) + 1)
    xyz = _stations_on_axis(args, scene, ch, "--chainages")
    return [Station((float(x), float(y), float(z)), h, float(c))
            for (x, y, z), c in zip(xyz, ch)], {"chainages": args.chainages,
                                                "height_m": args.height}


def _scan_campaign(args, heading_deg: float) -> int:
    """tunnelsim scan --chainages / --plan: one file per station and manifest.json in
    the -o folder, on the executor --workers / --scheduler choose."""
    import time
    from dataclasses import asdict

    import numpy as np

    from sensors import load_sensor
    from sensors.io.meshes import load_mesh
    from survey.cluster import TaskProgress, scan_stations

    if args.plan_name is not None and args.plan is None:
        raise TunnelsimCLIError("Expected --plan-name with --plan, got it with "
                                "--chainages.")
    spec = load_sensor(args.sensor)
    if spec.kind != "tls":
        raise TunnelsimCLIError(f"Expected a TLS sensor for a campaign of stations, got "
                                f"{spec.name} ({spec.kind}); use 'tunnelsim drive'.")
    folder = out_dir(args.output, force=args.force)
    crs = output_crs(args)      # before the simulation: a bad --crs fails at once
    with open_cluster(args) as ex:
        scene, refl = load_mesh(args.mesh)
        stations, info = _campaign_stations(args, scene, heading_deg)
        lo, hi = scene.bounds
        at = np.array([s.position for s in stations])
        out = np.flatnonzero(((at < lo) | (at > hi)).any(axis=1))
        if len(out) and not args.allow_outside:
            raise TunnelsimCLIError(f"Expected every station inside the mesh's bounding "
                                    f"box {box_text(lo, hi)}, got station {int(out[0])} at "
                                    f"{xyz_text(at[out[0]])} ({len(out)} outside); is "
                                    "the plan of another mesh? Pass --allow-outside to "
                                    "scan them anyway.")
        settings = run_settings(args)
        step = None if args.step_deg is None else math.radians(args.step_deg)
        prog = TaskProgress(args.quiet, unit="stations")
        t0 = time.perf_counter()
        try:
            camp = scan_stations(
                scene, spec, stations, folder, executor=ex, resolution=args.resolution,
                step_rad=step, settings=settings, seed=args.seed,
                reflectivity=refl if refl is not None else args.reflectivity,
                fmt=args.format or "laz", fields=args.fields, crs=crs, progress=prog,
                info={"mesh": str(args.mesh), **info, "settings": asdict(settings)})
        finally:
            prog.close()
        wall = time.perf_counter() - t0
        where = f"{ex.kind}, {ex.workers} workers" if ex.workers > 1 else ex.kind
    empty = [s["station"] for s in camp.manifest["stations"] if s["points"] == 0]
    if empty:
        raise TunnelsimCLIError(f"Expected every station to see the mesh, got no point at "
                                f"station {empty[0]} ({len(empty)} such); put the "
                                "stations where they see the mesh.")
    if not args.quiet:
        n = len(stations)
        res = args.resolution or ("custom step" if step is not None else
                                  getattr(spec.pattern, "default_resolution", ""))
        print(f"{spec.name} {res}: "
              f"{n} stations, {camp.pulses:,} pulses, {camp.points:,} points, "
              f"{wall:.1f} s ({where}; {camp.seconds.sum():.1f} s of simulation) -> "
              f"{camp.manifest_path}")
    return 0


def _stations_on_axis(args, scene, chainages, flag: str):
    """Stations (k, 3) on the tunnel axis (--tunnel-json or the mesh's .json) at
    ``chainages`` (k,) m, --height above the floor."""
    from pathlib import Path

    from survey.analysis.planning import axis_stations
    from survey.world.mesh import read_axis, sidecar

    js = Path(args.tunnel_json) if args.tunnel_json else sidecar(args.mesh)
    if not js.is_file():
        other = " or --at X,Y,Z" if flag == "--chainage" else ""
        raise TunnelsimCLIError(f"Expected a tunnel JSON for {flag} ('{js}'), got none; "
                                f"pass --tunnel-json{other}.")
    al, hc = read_axis(js)
    c0, c1 = al.chainage_range
    lo, hi = float(min(chainages)), float(max(chainages))
    if not (c0 <= lo and hi <= c1):
        got = f"{lo:g}" if lo == hi else f"{lo:g} to {hi:g} m"
        raise TunnelsimCLIError(f"Expected {flag} within [{c0:g}, {c1:g}] m, got "
                                f"{got}.")
    return axis_stations(scene, al, hc, chainages, height_m=args.height)


def station_heading_deg(heading_deg: float | None, azimuth_deg: float | None) -> float:
    """A station's heading in degrees counter-clockwise from +x (east), from
    ``--heading-deg`` or from ``--azimuth-deg`` (clockwise from grid north, +y):
    heading = 90 - azimuth; 0 when neither is given."""
    if azimuth_deg is not None:
        return 90.0 - azimuth_deg
    return 0.0 if heading_deg is None else heading_deg


def _station_on_axis(args, scene):
    return _stations_on_axis(args, scene, [args.chainage], "--chainage")[0]


__all__ = ["STATION_FORMATS", "cmd_scan", "register", "station_heading_deg"]
