"""Commands that simulate scanners: scan (TLS station), drive (moving platform)."""

from __future__ import annotations

from survey.cli.common import CommandSet, Progress, pair, physics_options, xyz
from survey.errors import TunnelFileError, TunnelsimCLIError


def register(commands: CommandSet) -> None:
    """Add scan and drive."""
    c = commands.add(
        "scan", cmd_scan, seeded=True, help="simulate a TLS station on a mesh",
        description="Simulate a terrestrial laser scanner station on a mesh and stream the "
                    "points to a file (LAS/LAZ, PLY, NPZ, E57).",
        epilog="Example: tunnelsim scan --mesh bfo.ply --sensor zf_imager_5016 "
               "--resolution superhigh --at 150,2,1.5 -o station.laz")
    c.option("--mesh", required=True, path="in",
             help="mesh file (PLY with reflectivity, OBJ, ...)")
    c.option("--sensor", default="zf_imager_5016", path="toml",
             help="sensor name ('tunnelsim sensors' lists them) or a .toml file")
    g = c.exclusive(required=True)
    c.option("--at", group=g, metavar="X,Y,Z", help="station position (m)")
    c.option("--chainage", group=g, type=float, metavar="M",
             help="station on the tunnel axis at this chainage, --height above the floor "
                  "(axis from --tunnel-json or the mesh's .json)")
    c.option("--height", type=float, default=1.5, metavar="M",
             help="instrument height above the floor with --chainage (default 1.5)")
    c.option("--tunnel-json", path="in",
             help="axis for --chainage (default: the mesh's .json)")
    c.option("--resolution", help="resolution preset of the sensor (e.g. superhigh)")
    c.option("--step-deg", type=float, metavar="DEG",
             help="angular step in degrees instead of a preset")
    c.option("--heading-deg", type=float, default=0.0, metavar="DEG",
             help="station heading, degrees counter-clockwise from +x")
    physics_options(c)

    c = commands.add(
        "drive", cmd_drive, seeded=True,
        help="simulate a moving lidar or profiler along a trajectory",
        description="Simulate a sensor on a moving platform: each pulse is cast from the "
                    "pose at its own time (rolling shutter).",
        epilog="Example: tunnelsim drive --mesh bfo.ply --sensor robosense_airy --along "
               "centreline --speed 1 --mount down --lever 0,0,0.5 -o drive.laz")
    c.option("--mesh", required=True, path="in", help="mesh file")
    c.option("--sensor", default="robosense_airy", path="toml",
             help="sensor name or a .toml file")
    c.option("--trajectory", path="in",
             help="TUM text (t x y z qx qy qz qw) or CSV trajectory")
    c.option("--along", choices=["centreline"],
             help="drive along the tunnel centreline (needs the mesh's .json)")
    c.option("--speed", type=float, metavar="M_S", help="speed along the centreline")
    c.option("--height", type=float, default=0.5, metavar="M",
             help="platform height above the centreline (default 0.5)")
    c.option("--offset", type=float, default=0.0, metavar="M",
             help="platform offset left of the centreline (default 0)")
    c.option("--margin", type=float, default=1.0, metavar="M",
             help="distance kept from the portals (default 1)")
    c.option("--mount", choices=["level", "down"], default="level",
             help="sensor z up (level) or pointing down (default level)")
    c.option("--lever", default="0,0,0", metavar="X,Y,Z",
             help="lever arm platform -> sensor in metres (default 0,0,0)")
    c.option("--duration", type=float, metavar="S", help="simulate only the first S seconds")
    c.option("--chainage", metavar="START,END",
             help="with --along: drive only this chainage range in m")
    c.option("--rate", type=float, metavar="HZ",
             help="rotation (profile) rate in Hz instead of the spec's; the firing rate "
                  "stays, so points per turn (per profile) change")
    c.option("--standstill", type=float, default=0.0, metavar="S",
             help="with --along: stand still S seconds before and after the drive, as a "
                  "real MLS run does (SLAM initialises on a still sensor; default 0)")
    c.option("--slam-drift", action="store_true",
             help="with --along: write the cloud in a drifting SLAM frame, with the SLAM "
                  "and true trajectories (_trajectory.txt, _true_trajectory.txt) and the "
                  "control points (_cp_world.csv, _cp_observed.csv) for 'tunnelsim "
                  "correct'")
    physics_options(c)


def _settings(args):
    from dataclasses import replace

    from sensors import Settings

    if args.ideal:
        base = Settings.ideal()
    else:
        base = Settings(range_noise=not args.no_noise, angle_jitter=not args.no_noise,
                        detection=not args.no_detection)
    return replace(base, beam_subrays=args.beam_subrays, mixed=args.mixed,
                   attenuation_per_m=args.attenuation, particle_rate_per_m=args.particles)


def _finish_run(args, run, label) -> int:
    prog = Progress(args.quiet)
    try:
        stats = run.write(args.output, progress=prog, fields=args.fields)
    finally:
        prog.close()
    if not args.quiet:
        print(f"{label}: {stats['pulses']:,} pulses, {stats['points']:,} points "
              f"(hit ratio {100 * stats['hit_ratio']:.1f} %), {stats['seconds']:.1f} s, "
              f"{stats['rays_per_s'] / 1e6:.2f} Mrays/s -> {stats['path']}")
    return 0


def cmd_scan(args) -> int:
    import numpy as np
    from scipy.spatial.transform import Rotation

    from sensors import load_sensor, simulate_station
    from sensors.meshes import load_mesh

    spec = load_sensor(args.sensor)
    scene, refl = load_mesh(args.mesh)
    at = _station_on_axis(args, scene) if args.chainage is not None else xyz(args.at, "--at")
    run = simulate_station(scene, spec, at,
                           attitude=Rotation.from_euler("z", args.heading_deg, degrees=True),
                           resolution=args.resolution,
                           step_rad=None if args.step_deg is None else np.deg2rad(args.step_deg),
                           settings=_settings(args), seed=args.seed,
                           reflectivity=refl if refl is not None else args.reflectivity)
    resolution = getattr(run.scan, "resolution", None) or "custom step"
    return _finish_run(args, run, f"{spec.name} {resolution}")


def _station_on_axis(args, scene):
    from pathlib import Path

    from survey.analysis.planning import axis_stations
    from survey.world.mesh import read_axis, sidecar

    js = Path(args.tunnel_json) if args.tunnel_json else sidecar(args.mesh)
    if not js.is_file():
        raise TunnelsimCLIError(f"Expected a tunnel JSON for --chainage ('{js}'), got none; "
                                "pass --tunnel-json or --at X,Y,Z.")
    al, hc = read_axis(js)
    c0, c1 = al.chainage_range
    if not c0 <= args.chainage <= c1:
        raise TunnelsimCLIError(f"Expected --chainage within [{c0:g}, {c1:g}] m, got "
                                f"{args.chainage:g}.")
    return axis_stations(scene, al, hc, [args.chainage], height_m=args.height)[0]


def _tunnel_meta(mesh) -> dict:
    """The JSON beside a generated tunnel's mesh (alignment, control points)."""
    import json

    from survey.world.mesh import sidecar

    js = sidecar(mesh)
    if not js.is_file():
        raise TunnelFileError(f"Expected the tunnel metadata '{js}' for --along centreline "
                              "(made by 'tunnelsim tunnel'), got none; pass --trajectory "
                              "instead.")
    try:
        meta = json.loads(js.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise TunnelFileError(f"Expected JSON in '{js}', got unreadable text ({exc}).") \
            from exc
    if not isinstance(meta, dict) or "alignment" not in meta:
        raise TunnelFileError(f"Expected an 'alignment' in '{js}' (a JSON written by "
                              "'tunnelsim tunnel'), got none.")
    return meta


def _centreline(args, meta):
    import numpy as np

    from sensors import Trajectory
    from survey.world.alignment import Alignment

    al = Alignment.from_dict(meta["alignment"])
    c0, c1 = al.chainage_range
    a, b = c0 + args.margin, c1 - args.margin
    if args.chainage:
        a, b = pair(args.chainage, "--chainage as START,END in m")
        if not (c0 <= a < b <= c1):
            raise TunnelsimCLIError(f"Expected --chainage within [{c0:g}, {c1:g}] m with "
                                    f"START < END, got {args.chainage!r}.")
    s = np.append(np.arange(a, b, 0.5), b)
    return Trajectory.along_polyline(al.to_world(s, args.offset, args.height), args.speed)


def cmd_drive(args) -> int:
    from sensors import Mount, Trajectory, load_sensor, simulate_drive
    from sensors.meshes import load_mesh

    if args.slam_drift and not args.along:
        raise TunnelsimCLIError("Expected --along centreline with --slam-drift (the control "
                                "points come from the tunnel's JSON), got a trajectory "
                                "file.")
    lx, ly, lz = xyz(args.lever, "--lever")
    lever = (lx, ly, lz)
    spec = load_sensor(args.sensor)
    if args.rate is not None:
        from sensors.spec import with_rate

        spec = with_rate(spec, args.rate)
    scene, refl = load_mesh(args.mesh)
    meta = None
    if args.trajectory:
        traj = Trajectory.read(args.trajectory)
    else:
        if args.along != "centreline" or args.speed is None:
            raise TunnelsimCLIError("Expected --trajectory FILE, or --along centreline with "
                                    "--speed V, got neither.")
        meta = _tunnel_meta(args.mesh)
        traj = _centreline(args, meta)
        if args.standstill:
            traj = traj.with_standstill(args.standstill, args.standstill)
    mount = Mount.pointing_down(lever) if args.mount == "down" else Mount(lever)
    t_end = None if args.duration is None else traj.start_s + args.duration
    run = simulate_drive(scene, spec, traj, mount, settings=_settings(args), seed=args.seed,
                         reflectivity=refl if refl is not None else args.reflectivity,
                         t_end=t_end)
    if args.slam_drift:
        run = _slam_files(args, run, traj, meta)
    elif meta is not None:
        _true_trajectory(args, traj)
    return _finish_run(args, run, f"{spec.name} drive {run.duration_s:.1f} s")


def _true_trajectory(args, traj) -> None:
    """The platform's true trajectory of a drive along the centreline, beside the cloud
    (``_true_trajectory.txt``, TUM): the ground truth a SLAM estimate is judged by."""
    from pathlib import Path

    out = Path(args.output)
    path = traj.write(out.with_name(f"{out.stem}_true_trajectory.txt"))
    if not args.quiet:
        print(f"true trajectory: {len(traj)} poses -> {path.name}")


def _slam_files(args, run, traj, meta):
    """Observe the drive through a drifting SLAM (``survey.adjust.slam``) and write what
    a surveyor would have besides the cloud: the SLAM and true trajectories and the
    control points (world, and observed in the MLS frame). Returns the drifted run."""
    from pathlib import Path

    import numpy as np

    from survey.adjust.slam import observe_slam

    cps = meta.get("control_points", [])
    obs = observe_slam(run, traj, [c["id"] for c in cps],
                       np.array([c["xyz"] for c in cps], dtype=np.float64).reshape(-1, 3),
                       seed=args.seed)
    out = Path(args.output)
    stem = out.with_name(out.stem)
    obs.slam.write(f"{stem}_trajectory.txt")
    obs.true.write(f"{stem}_true_trajectory.txt")
    obs.observed.write(f"{stem}_cp_observed.csv")
    obs.world.write(f"{stem}_cp_world.csv")
    if not args.quiet:
        print(f"SLAM drift: {len(obs.observed)} control points observed; wrote "
              f"{stem.name}_trajectory.txt, {stem.name}_true_trajectory.txt, "
              f"{stem.name}_cp_observed.csv, {stem.name}_cp_world.csv")
    return obs.run


__all__ = ["cmd_drive", "cmd_scan", "register"]
