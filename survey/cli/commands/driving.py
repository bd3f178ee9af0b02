"""Command that simulates a moving sensor: drive (a lidar or profiler on a platform,
each pulse cast from the pose at its own time; in time windows on the execution layer).

Guards (each a one-line error, exit 2, no output left behind): a drive whose every pose
is beyond the sensor's range of the mesh's bounding box (unless ``--allow-outside``), a
drive that returns no point or fewer than ``MIN_DRIVE_RETURN`` of its pulses (unless
``--allow-outside``), ``--duration`` beyond the trajectory's end (checked before the
mesh is even loaded).
"""

from __future__ import annotations

import math

from survey.cli.common import (
    CommandSet,
    Progress,
    cluster_options,
    open_cluster,
    pair,
    physics_options,
    xyz,
)
from survey.cli.commands.simruns import (
    box_text,
    crs_option,
    finish_run,
    output_crs,
    run_settings,
)
from survey.errors import TunnelsimCLIError
from sensors.io.errors import TunnelFileError

#: A drive returning fewer points than this share of its pulses is refused (unless
#: --allow-outside). ASSUMED from measurements (1 s drives): inside a tunnel a platform
#: returns most of its pulses (VLP-16 in the tbm tunnel 94 %, in the shared 80 m cave
#: 95 %, in a 20 m tile open at both ends 80 %; a RoboSense Airy 92-97 %), and still
#: 12 % on a path that runs partly outside the walls of an S-bend tile; a trajectory
#: 100 m off the mesh returned 2 points of 578,704 pulses (issue 21: 6 points). 1 %
#: sits far from both.
MIN_DRIVE_RETURN = 0.01
#: --along auto: the clearance the route keeps from the mesh (``find_route``'s
#: default), and that the platform's poses must keep too (issue 20).
ROUTE_CLEARANCE_M = 0.2


def register(commands: CommandSet) -> None:
    """Add drive."""
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
    c.option("--along", choices=["centreline", "auto"],
             help="centreline: drive along the tunnel centreline (needs the mesh's "
                  ".json); auto: along a route found in any mesh, the middle of its "
                  "passage between its farthest ends or through --waypoints, keeping "
                  "--clearance from the mesh on ground the --platform can cross (writes "
                  "_route.csv)")
    c.option("--waypoints", path="in", metavar="CSV",
             help="with --along auto: x,y[,z] rows to drive through in order (z picks "
                  "the floor below it where passages cross)")
    c.option("--clearance", type=float, metavar="M",
             help="with --along auto: distance the route keeps from the mesh at the "
                  "sensor's height where the passage allows (default 0.2); a narrower "
                  "spot the platform fits through is driven with a warning")
    c.option("--voxel", type=float, metavar="M",
             help="with --along auto: voxel edge of the grid the route is sought on "
                  "(default: the finest that keeps the grid within 2 million voxels, not "
                  "below 0.05 m); smaller finds the middle of narrow passages")
    c.option("--platform", path="toml",
             help="with --along: what carries the sensor, a name (ground_robot, "
                  "trolley, walker, tripod: sensors/platforms/*.toml) or a .toml file "
                  "(default trolley with --along centreline, ground_robot with --along "
                  "auto)")
    c.option("--level", action="store_true",
             help="with --along: keep the platform level (it does not pitch with the "
                  "grade or roll with the floor; its height still follows the floor)")
    c.option("--speed", type=float, metavar="M_S", help="speed along the path (m/s)")
    c.option("--height", type=float, metavar="M",
             help="sensor mount height above the centreline, or above the floor with "
                  "--along auto (default: the platform's mast height, 0.5 for the "
                  "trolley and the ground robot)")
    c.option("--offset", type=float, default=0.0, metavar="M",
             help="platform offset left of the centreline (default 0)")
    c.option("--margin", type=float, default=1.0, metavar="M",
             help="distance kept from the portals (default 1)")
    c.option("--mount", choices=["level", "down"], default="level",
             help="sensor z up (level) or pointing down (default level)")
    c.option("--lever", default="0,0,0", metavar="X,Y,Z",
             help="lever arm platform -> sensor in metres (default 0,0,0)")
    c.option("--duration", type=float, metavar="S", help="simulate only the first S seconds")
    c.option("--window-s", type=float, metavar="S",
             help="simulate in time windows of about S seconds (cut at whole sweeps), "
                  "each a task (on --workers or --scheduler); the output holds the same "
                  "points as one piece")
    cluster_options(c, needs=("window-s",))
    c.option("--keep-partial-sweep", action="store_true",
             help="keep the last sweep (revolution or profile) even when it is partial; "
                  "by default a drive ends at its last whole sweep, as a driver "
                  "publishes whole revolutions")
    c.option("--chainage", metavar="START,END",
             help="with --along: drive only this chainage range in m")
    c.option("--rate", type=float, metavar="HZ",
             help="rotation (profile) rate in Hz instead of the spec's; the firing rate "
                  "stays, so points per turn (per profile) change")
    c.option("--accel", type=float, metavar="M_S2",
             help="with --along: start and stop at rest, accelerating and braking at this "
                  "rate (default: full speed from the first instant); SLAM on a sudden "
                  "start can slip by a blast round in a rock gallery")
    c.option("--standstill", type=float, default=0.0, metavar="S",
             help="with --along: stand still S seconds before and after the drive, as a "
                  "real MLS run does (SLAM initialises on a still sensor; default 0)")
    c.option("--allow-outside", action="store_true",
             help="drive a trajectory that lies beyond the sensor's range of the mesh's "
                  "bounding box, or that returns fewer than 1 %% of its pulses, instead of "
                  "refusing it")
    c.option("--slam-drift", action="store_true",
             help="with --along: write the cloud in a drifting SLAM frame, with the SLAM "
                  "and true trajectories (_trajectory.txt, _true_trajectory.txt) and the "
                  "control points (_cp_world.csv, _cp_observed.csv) for 'tunnelsim "
                  "correct'")
    c.option("--start-time", metavar="TIME",
             help="with a ROS 2 bag output (-o NAME.mcap or a folder): the ROS time of the "
                  "scan's start, seconds since 1970 or ISO 8601 with its offset "
                  "(2024-05-01T12:00:00Z), so that the bag merges with recorded data "
                  "(default: the trajectory's own times)")
    c.option("--ros-distro", choices=["humble", "jazzy"],
             help="with a ROS 2 bag folder: the rosbag2 metadata layout, humble "
                  "(version 5) or jazzy (version 9; the default)")
    crs_option(c)
    physics_options(c)
    # The shared -o help names the point formats; a drive also writes ROS 2 bags.
    for action in c.parser._actions:
        if "--output" in action.option_strings:
            action.help = ("output: points (.laz, .las, .ply, .npz) or a ROS 2 bag (.mcap, "
                           "or a name without a suffix: a rosbag2 folder); the robot's "
                           "URDF and launch file (<name>_robot.urdf, "
                           "<name>_robot.launch.py) are written beside it")


def _bag_options(args) -> dict:
    """--start-time and --ros-distro for the bag writer (checked before simulating)."""
    if args.start_time is None and args.ros_distro is None:
        return {}
    from sensors.bag import parse_start_time
    from sensors.writers import format_of

    if format_of(args.output) not in ("mcap", "rosbag2"):
        raise TunnelsimCLIError(f"Expected --start-time and --ros-distro with a ROS 2 bag "
                                f"(-o NAME.mcap or a folder), got -o {args.output}.")
    out: dict = {}
    if args.start_time is not None:
        out["start_time_ns"] = parse_start_time(args.start_time)
    if args.ros_distro is not None:
        out["ros_distro"] = args.ros_distro
    return out


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


def _centreline(args, meta, platform, scene=None):
    """The centreline (or --chainage part of it), --offset left and --height (default
    the platform's mast height) above it, driven by ``platform``: a trolley rides it
    exactly (the generated tunnels' drive, pitched with the grade unless --level);
    another platform follows it on the floor of ``scene``."""
    import numpy as np

    from sensors.platform import platform_trajectory
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
    height = platform.mast_height_m if args.height is None else args.height
    return platform_trajectory(al.to_world(s, args.offset, height), platform, args.speed,
                               scene=scene, accel_mps2=args.accel,
                               follow_grade=not args.level, height_m=height)


def cmd_drive(args) -> int:
    from pathlib import Path

    from sensors import Mount, Trajectory, load_sensor, simulate_drive
    from sensors.io.meshes import load_mesh

    if args.window_s is not None and args.slam_drift:
        raise TunnelsimCLIError("Expected --window-s without --slam-drift (the drifted "
                                "cloud is written in one piece), got both.")
    if (args.workers or args.scheduler) and args.window_s is None:
        raise TunnelsimCLIError("Expected --window-s with --workers or --scheduler (a "
                                "drive is split into time windows to run on a cluster), "
                                "got no --window-s.")
    if args.slam_drift and not args.along:
        raise TunnelsimCLIError("Expected --along centreline with --slam-drift (the control "
                                "points come from the tunnel's JSON), got a trajectory "
                                "file.")
    _check_auto(args)
    lx, ly, lz = xyz(args.lever, "--lever")
    lever = (lx, ly, lz)
    spec = load_sensor(args.sensor)
    if args.rate is not None:
        from sensors.spec import with_rate

        spec = with_rate(spec, args.rate)
    if not Path(args.mesh).is_file():
        raise TunnelsimCLIError(f"Expected a mesh file, got '{args.mesh}' which does not "
                                "exist.")
    crs = output_crs(args)      # before the simulation: a bad --crs fails at once
    bag = _bag_options(args)
    meta = scene = refl = platform = None
    if args.trajectory:
        traj = Trajectory.read(args.trajectory)
    else:
        from sensors.platform_spec import load_platform

        if args.along is None:
            raise TunnelsimCLIError("Expected --trajectory FILE, or --along centreline (or "
                                    "auto) with --speed V, got neither.")
        if args.speed is None:
            raise TunnelsimCLIError(f"Expected --speed V (m/s) with --along {args.along}, "
                                    "got none; pass e.g. --speed 1.")
        auto = args.along == "auto"
        platform = load_platform(args.platform or ("ground_robot" if auto else "trolley"))
        if platform.motion == "static" and (args.duration is None or args.standstill):
            raise TunnelsimCLIError(f"Expected --duration S (and no --standstill) with the "
                                    f"static platform {platform.name}, got "
                                    f"{'--standstill' if args.standstill else 'none'}.")
        if auto:
            scene, refl = load_mesh(args.mesh)
            traj = _auto_route(args, scene, platform)
        else:
            meta = _tunnel_meta(args.mesh)
            if platform.motion != "rail":      # it finds the floor in the mesh
                scene, refl = load_mesh(args.mesh)
            traj = _centreline(args, meta, platform, scene)
        if args.standstill:
            traj = traj.with_standstill(args.standstill, args.standstill)
    # DECISION: checked before the mesh is loaded (a large mesh's BVH takes seconds);
    # --along auto needs the mesh to find its route first.
    t_end = _drive_end(args.duration, traj)
    if not args.keep_partial_sweep:
        t_end = _whole_sweeps(spec, traj, t_end, quiet=args.quiet)
    mount = Mount.pointing_down(lever) if args.mount == "down" else Mount(lever)
    if scene is None:
        scene, refl = load_mesh(args.mesh)
    where = _check_drive_reach(args, scene, spec, traj, mount, t_end)
    robot = _robot(args, spec, platform, mount)
    run = simulate_drive(scene, spec, traj, mount, settings=run_settings(args), seed=args.seed,
                         reflectivity=refl if refl is not None else args.reflectivity,
                         t_end=t_end)
    driven = trimmed(traj, t_end)      # every output covers the same time span
    if args.slam_drift:
        run = _slam_files(args, run, driven, meta, full=traj, crs=crs)
        # DECISION: the drifted cloud lies in the SLAM frame, which is not the mesh's
        # CRS to survey accuracy (that is what 'correct' repairs): it states none; the
        # world control points state it, and 'correct' gives it to the corrected cloud.
        crs = None
    else:                              # every drive writes the truth it drove (issue 22)
        _true_trajectory(args, driven, robot)
    label = f"{spec.name} drive {run.duration_s:.1f} s"
    if args.window_s is not None:
        code = _finish_windows(args, run, label, refl if refl is not None else
                               args.reflectivity, crs=crs,
                               min_return=0.0 if args.allow_outside else MIN_DRIVE_RETURN)
    else:
        # DECISION: a drifted run's bag keeps its own frames (the SLAM frame's poses).
        code = finish_run(args, run, label,
                          min_return=0.0 if args.allow_outside else MIN_DRIVE_RETURN,
                          where=where, crs=crs, bag=bag,
                          robot=None if args.slam_drift else robot)
    _robot_files(args, robot)
    return code


def _robot(args, spec, platform, mount):
    """The drive's robot description (``sensors.robot``): the platform's (--platform,
    at --height) carrying the sensor on --mount/--lever; for --trajectory, base_link is
    the trajectory's frame."""
    from sensors.pointcloud2 import GENERIC_DRIVER
    from sensors.robot import RobotDescription

    frame = (spec.driver or GENERIC_DRIVER).frame_id
    if platform is None:
        return RobotDescription("platform", frame, 0.0, mount)
    return RobotDescription.from_platform(platform, frame, mount, height_m=args.height)


def _robot_files(args, robot) -> None:
    """``<stem>_robot.urdf`` and ``<stem>_robot.launch.py`` (robot_state_publisher)
    beside the output."""
    from pathlib import Path

    out = Path(args.output)
    stem = output_stem(out)
    urdf = robot.write_urdf(out.with_name(f"{stem}_robot.urdf"))
    launch = robot.write_launch(out.with_name(f"{stem}_robot.launch.py"), urdf.name)
    if not args.quiet:
        print(f"robot: {robot.name}, base_link {robot.mast_height_m:g} m below the "
              f"platform frame -> {urdf.name}, {launch.name}")


def _finish_windows(args, run, label, reflectivity, *, crs, min_return: float) -> int:
    """Write a drive simulated in windows (``survey.cluster.simulate_windows``) on the
    executor --workers / --scheduler ask for, merged into --output."""
    from survey.cluster import simulate_windows

    ex = open_cluster(args)
    where = ex.describe()
    prog = Progress(args.quiet)
    try:
        man = simulate_windows(run, args.window_s, args.output, reflectivity=reflectivity,
                               executor=ex, fields=args.fields, crs=crs,
                               progress=prog)
    finally:
        prog.close()
        ex.close()
    wins = man.get("windows", [])
    points = sum(int(w.get("points", 0)) for w in wins)
    if points == 0 or points < min_return * run.n_pulses:
        raise TunnelsimCLIError(f"Expected the {label} to see the mesh, got {points:,} "
                                f"points from {run.n_pulses:,} pulses.")
    if not args.quiet:
        print(f"{label}: {len(wins)} windows of ~{args.window_s:g} s on {where}: "
              f"{run.n_pulses:,} pulses, {points:,} points -> {args.output}")
    return 0


def _check_auto(args) -> None:
    """Refuse --waypoints without --along auto, and the options --along auto does not
    take (they need the tunnel's JSON)."""
    auto = args.along == "auto" and not args.trajectory
    if args.waypoints and not auto:
        other = "--trajectory" if args.trajectory else "--along centreline"
        raise TunnelsimCLIError(f"Expected --waypoints with --along auto, got it with "
                                f"{other}.")
    given = [f for f, on in (("--platform", args.platform), ("--level", args.level)) if on]
    if args.trajectory and given:
        raise TunnelsimCLIError(f"Expected {given[0]} with --along, got it with "
                                "--trajectory (the file gives the platform's poses).")
    route_opts = [f for f, on in (("--clearance", args.clearance is not None),
                                  ("--voxel", args.voxel is not None)) if on]
    if route_opts and not auto:
        raise TunnelsimCLIError(f"Expected {route_opts[0]} with --along auto (it shapes "
                                "the route found in the mesh), got it without.")
    for flag, value in (("--clearance", args.clearance), ("--voxel", args.voxel)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise TunnelsimCLIError(f"Expected a positive {flag} in metres, got "
                                    f"{value:g}.")
    bad = [flag for flag, given in (("--slam-drift", args.slam_drift),
                                    ("--chainage", args.chainage),
                                    ("--offset", args.offset)) if given]
    if auto and bad:
        hint = ("; use --waypoints and --duration to choose the part driven"
                if bad[0] == "--chainage" else "")
        raise TunnelsimCLIError(f"Expected {bad[0]} with --along centreline (it needs the "
                                f"tunnel's JSON), got it with --along auto{hint}.")


def _auto_route(args, scene, platform):
    """The route found in the mesh (``sensors.route.find_route``) at --height (default
    the platform's mast height) above the floor, written beside the output as
    ``_route.csv``, and ``platform`` driven along it at --speed (--accel)
    (``sensors.platform.platform_trajectory``); the smallest clearance of its poses is
    reported, and a trajectory closer to the mesh than the route's clearance refused."""
    from pathlib import Path

    import numpy as np

    from sensors.platform import platform_trajectory
    from sensors.route import find_route, free_space, read_waypoints

    wp = read_waypoints(args.waypoints) if args.waypoints else None
    height = platform.mast_height_m if args.height is None else args.height
    clearance = ROUTE_CLEARANCE_M if args.clearance is None else args.clearance
    space = free_space(scene, voxel_m=args.voxel)
    route = find_route(scene, waypoints=wp, height_m=height, space=space,
                       clearance_m=clearance, platform=platform)
    traj = platform_trajectory(route, platform, args.speed, scene=scene,
                               accel_mps2=args.accel, follow_grade=not args.level,
                               height_m=height)
    p = traj.positions
    # Poses every ~5 cm of travel (and the first and last): the exact distance to the
    # mesh; the route itself is checked at every point by find_route.
    step = max(1, int(0.05 / max(float(np.median(np.linalg.norm(np.diff(p, axis=0),
                                                                axis=1))), 1e-6))) \
        if len(p) > 1 else 1
    clear = float(space.distance(np.vstack([p[::step], p[-1:]])).min())
    # The poses follow a spline through the route's points: they may come a little
    # nearer than the route where it is narrow (issue 29: the route's own least
    # clearance, with 1 cm for the spline, is what is asked of them then).
    need = min(clearance, route.min_clearance_m - 0.01)
    if clear < need:
        raise TunnelsimCLIError(f"Expected the {platform.name} to keep {need:.3g} m from "
                                f"the mesh, got {clear:.3g} m; use --waypoints to steer it "
                                "or a smaller --voxel.")
    out = Path(args.output)
    path = route.write_csv(out.with_name(f"{output_stem(out)}_route.csv"))
    if not args.quiet:
        print(f"route: {route.length_m:.1f} m, smallest clearance "
              f"{route.min_clearance_m:.2f} m (voxel {route.voxel_m:.2f} m, "
              f"{route.seconds:.1f} s) -> {path.name}")
        print(f"platform: {platform.name} ({platform.motion}), {traj.duration_s:.1f} s, "
              f"sensor mount {height:g} m above the floor, smallest clearance "
              f"{clear:.2f} m")
    return traj


def _drive_end(duration_s: float | None, traj) -> float | None:
    """The end time of a drive of ``--duration`` (None: the whole trajectory), refused
    when it is not positive or runs past the trajectory's end."""
    if duration_s is None:
        return None
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise TunnelsimCLIError(f"Expected a positive --duration in seconds, got "
                                f"{duration_s:g}.")
    if len(traj) > 1 and duration_s > traj.duration_s * (1 + 1e-12) + 1e-9:
        raise TunnelsimCLIError(f"Expected --duration at most the trajectory's "
                                f"{traj.duration_s:g} s (t = {traj.start_s:g} to "
                                f"{traj.end_s:g} s), got {duration_s:g} s; leave --duration "
                                "out to drive all of it.")
    return traj.start_s + duration_s


def _whole_sweeps(spec, traj, t_end: float | None, *, quiet: bool) -> float | None:
    """The end time of a drive cut back to its last whole sweep (a spinning lidar's
    revolution, a profiler's profile; sweeps start at the trajectory's first instant),
    with a note of what was left out; ``t_end`` unchanged for other sensors, a static
    platform, or a drive shorter than one sweep."""
    import math

    rate = getattr(spec.pattern, "rotation_hz", None) or getattr(spec.pattern,
                                                                 "profile_rate_hz", None)
    if not rate or len(traj) < 2:
        return t_end
    end = traj.end_s if t_end is None else t_end
    n = math.floor((end - traj.start_s) * rate + 1e-9)
    whole = traj.start_s + n / rate
    if n < 1 or whole >= end - 1e-9:
        return t_end
    if not quiet:
        print(f"drive ends at its last whole sweep: {n} sweeps of {1 / rate:g} s, "
              f"t = {traj.start_s:g} to {whole:g} s ({end - whole:.3g} s of a partial "
              "sweep left out; --keep-partial-sweep keeps it)")
    return whole


def output_stem(out) -> str:
    """The stem the files beside an output are named after: ``d`` for ``d.laz`` and
    for ``d.copc.laz`` (COPC's double suffix), ``d`` for a bag folder ``d``."""
    from pathlib import Path

    name = Path(out).name
    return name[:-len(".copc.laz")] if name.lower().endswith(".copc.laz") else Path(out).stem


def trimmed(traj, t_end: float | None):
    """``traj`` up to ``t_end`` (s), its last pose interpolated at ``t_end``: what a drive
    with ``--duration`` covers. The same trajectory when ``t_end`` is None or at its end,
    or when it is static."""
    import numpy as np

    from sensors import Trajectory

    if t_end is None or len(traj) < 2 or t_end >= traj.end_s:
        return traj
    t = np.append(traj.times[traj.times < t_end], t_end)
    pos, rot = traj.interpolate(t)
    return Trajectory(t, pos, rot)


def _check_drive_reach(args, scene, spec, traj, mount, t_end) -> str:
    """Refuse (unless --allow-outside) a drive whose every sensor position lies farther
    from the mesh's bounding box than the sensor's maximum range: it cannot return a
    point. Returns the clause that explains a drive returning (almost) nothing.

    DECISION: the margin is the sensor's range, not a fixed one: a pose within range of
    the box may see the mesh (a drive starting before a portal), and one beyond it
    never does, so the refusal before simulating is certain, not a guess. A drive that
    comes within range but returns almost nothing is refused after the simulation
    (``MIN_DRIVE_RETURN``)."""
    import numpy as np

    a, b = traj.start_s, traj.end_s if t_end is None else t_end
    t = np.unique(np.concatenate([[a, b], traj.times[(traj.times > a) & (traj.times < b)]]))
    if len(traj) < 2:
        t = t[:1]
    pos, _ = traj.sensor_matrices(t, mount)
    lo, hi = scene.bounds
    gap = np.linalg.norm(np.maximum(np.maximum(lo - pos, pos - hi), 0.0), axis=1)
    reach = spec.physics.range_max_m
    span = f"sensor positions within {box_text(pos.min(axis=0), pos.max(axis=0))}"
    if gap.min() > reach and not args.allow_outside:
        raise TunnelsimCLIError(f"Expected a trajectory within the {spec.name}'s "
                                f"{reach:g} m range of the mesh's bounding box "
                                f"{box_text(lo, hi)}, got {span}, {gap.min():.6g} m from it at "
                                "the nearest; is it in another coordinate frame? Pass "
                                "--allow-outside if you mean it.")
    hint = "" if args.allow_outside else "; pass --allow-outside if you mean it"
    return (f"; the {span} may lie outside the mesh {box_text(lo, hi)} or in another "
            f"coordinate frame{hint}")


def _true_trajectory(args, traj, robot=None) -> None:
    """The platform's true trajectory of a drive, beside the cloud
    (``_true_trajectory.txt``, TUM; for --trajectory, the input trimmed to what was
    driven): the ground truth a SLAM estimate is judged by; and base_link's
    (``_base_link_trajectory.txt``, the bag's odom -> base_link) where base_link is not
    the platform frame (a wheeled robot: on the ground contact plane)."""
    from pathlib import Path

    out = Path(args.output)
    path = traj.write(out.with_name(f"{output_stem(out)}_true_trajectory.txt"))
    if not args.quiet:
        print(f"true trajectory: {len(traj)} poses -> {path.name}")
    if robot is not None and robot.mast_height_m > 0:
        base = robot.base_trajectory(traj).write(
            out.with_name(f"{output_stem(out)}_base_link_trajectory.txt"))
        if not args.quiet:
            print(f"base_link trajectory: {len(traj)} poses -> {base.name}")


def _slam_files(args, run, traj, meta, *, full=None, crs=None):
    """Observe the drive through a drifting SLAM (``survey.adjust.slam``) and write what
    a surveyor would have besides the cloud: the SLAM and true trajectories and the
    control points (world, and observed in the MLS frame). Returns the drifted run.

    ``traj`` is the part driven; when it is a part of ``full`` (``--duration``), the
    control points are those the full drive passes nearest (horizontally) within the
    part's time span, as ``observe_control`` times its observations."""
    from pathlib import Path

    import numpy as np

    from survey.adjust.slam import observe_slam

    cps = meta.get("control_points", [])
    ids = [c["id"] for c in cps]
    g = np.array([c["xyz"] for c in cps], dtype=np.float64).reshape(-1, 3)
    if full is not None and full is not traj and len(g):
        near = np.argmin(np.linalg.norm(full.positions[None, :, :2] - g[:, None, :2],
                                        axis=2), axis=1)
        keep = full.times[near] <= traj.end_s
        ids, g = [i for i, k in zip(ids, keep) if k], g[keep]
    obs = observe_slam(run, traj, ids, g, seed=args.seed)
    out = Path(args.output)
    stem = out.with_name(output_stem(out))
    obs.slam.write(f"{stem}_trajectory.txt")
    obs.true.write(f"{stem}_true_trajectory.txt")
    obs.observed.write(f"{stem}_cp_observed.csv")
    world_csv = obs.world.write(f"{stem}_cp_world.csv")
    if crs is not None:     # the world points are in the mesh's CRS: say so
        from sensors.io.crs import crs_comment

        world_csv.write_text(crs_comment(crs) + "\n" + world_csv.read_text())
    if not args.quiet:
        print(f"SLAM drift: {len(obs.observed)} control points observed; wrote "
              f"{stem.name}_trajectory.txt, {stem.name}_true_trajectory.txt, "
              f"{stem.name}_cp_observed.csv, {stem.name}_cp_world.csv")
    return obs.run


__all__ = ["MIN_DRIVE_RETURN", "ROUTE_CLEARANCE_M", "cmd_drive", "output_stem", "register",
           "trimmed"]
