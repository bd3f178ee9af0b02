"""Command that simulates a moving sensor: drive (a lidar or profiler on a platform,
each pulse cast from the pose at its own time; in time windows on the execution layer;
with ``--camera``, camera frames along the drive, each row of a rolling shutter from
its own pose).

Guards (each a one-line error, exit 2, no output left behind): a drive whose every pose
is beyond the sensor's range of the mesh's bounding box (unless ``--allow-outside``), a
drive that returns no point or fewer than ``MIN_DRIVE_RETURN`` of its pulses (unless
``--allow-outside``), ``--duration`` beyond the trajectory's end (checked before the
mesh is even loaded).
"""

from __future__ import annotations

import contextlib

from survey.cli.common import (
    CommandSet,
    cluster_options,
    floats,
    open_cluster,
    pair,
    physics_options,
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
from survey.workflows.drive import MIN_DRIVE_RETURN, ROUTE_CLEARANCE_M


def register(commands: CommandSet) -> None:
    """Add drive."""
    c = commands.add(
        "drive", cmd_drive, seeded=True,
        help="simulate a moving lidar or profiler along a trajectory",
        description="Simulate a sensor on a moving platform: each pulse is cast from the "
                    "pose at its own time (rolling shutter); --camera adds camera frames "
                    "along the drive.",
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
    c.option("--camera", action="append", path="toml", metavar="NAME|FILE",
             help="a camera on the platform (a name from 'tunnelsim cameras' or a .toml "
                  "file; repeatable): its frames along the drive, each row of a rolling "
                  "shutter from the pose at its own time, in the ROS 2 bag "
                  "(sensor_msgs/Image + CameraInfo on the camera driver's topics, "
                  "/camera/color/image_raw for the RealSense colour stream) or, beside a "
                  "point file, in <name>_cameras/<camera>/ (PNG frames, frames.csv, "
                  "camera_info.json); --no-noise also drops the cameras' noise")
    c.option("--camera-rate-hz", type=float, metavar="HZ",
             help="with --camera: frames per second, at most the camera's (default its "
                  "frame rate)")
    c.option("--camera-mount", metavar="X,Y,Z[,ROLL,PITCH,YAW]",
             help="with --camera: camera_link in base_link (x forward, y left, z up), "
                  "metres and degrees (default: 0.1 m below the lidar, level, looking "
                  "forward); the optical frame is camera_link turned to z forward, x "
                  "right, y down")
    c.option("--camera-samples", type=int, default=1, metavar="N",
             help="with a colour or thermal --camera: rays per pixel, a square number "
                  "(1, 4, 9 ...), their radiance averaged (anti-aliasing; default 1; a "
                  "depth camera keeps the pixel centre's ray)")
    c.option("--lamp-cd", type=float, metavar="CD",
             help="with --camera: a headlamp beside the camera, candela (default: none "
                  "on a platform with [[lamps]], which light the frames, else 1000; "
                  "given with them both light; 0: none)")
    crs_option(c)
    physics_options(c)
    waveform_option(c)
    # The shared -o help names the point formats; a drive also writes ROS 2 bags.
    for action in c.parser._actions:
        if "--output" in action.option_strings:
            action.help = ("output: points (.laz, .las, .ply, .npz) or a ROS 2 bag (.mcap, "
                           "or a name without a suffix: a rosbag2 folder); the robot's "
                           "URDF and launch file (<name>_robot.urdf, "
                           "<name>_robot.launch.py) are written beside it")


def cmd_drive(args) -> int:
    from survey.workflows.drive import drive_to_file

    if (args.workers or args.scheduler) and args.window_s is None:
        raise TunnelsimCLIError("Expected --window-s with --workers or --scheduler (a "
                                "drive is split into time windows to run on a cluster), "
                                "got no --window-s.")
    lever = xyz(args.lever, "--lever")
    chainage = pair(args.chainage, "--chainage as START,END in m") if args.chainage \
        else None
    cluster = open_cluster(args) if args.window_s is not None else contextlib.nullcontext()
    with cluster as ex:
        res = with_progress(
            args, drive_to_file, mesh=args.mesh, output=args.output, sensor=args.sensor,
            trajectory=args.trajectory or None, along=args.along,
            waypoints=args.waypoints or None, clearance_m=args.clearance,
            voxel_m=args.voxel, platform=args.platform or None, level=args.level,
            speed_mps=args.speed, height_m=args.height, offset_m=args.offset,
            margin_m=args.margin, mount=args.mount, lever_arm_m=lever,
            duration_s=args.duration, keep_partial_sweep=args.keep_partial_sweep,
            chainage_m=chainage, rate_hz=args.rate, accel_mps2=args.accel,
            standstill_s=args.standstill, allow_outside=args.allow_outside,
            slam_drift=args.slam_drift, start_time=args.start_time,
            ros_distro=args.ros_distro, crs=args.crs, settings=run_settings(args),
            seed=args.seed, reflectivity=args.reflectivity, fields=args.fields,
            waveform_data=waveform_data(args), window_s=args.window_s, executor=ex,
            cameras=args.camera or (), camera_rate_hz=args.camera_rate_hz,
            camera_mount=floats(args.camera_mount, "--camera-mount X,Y,Z[,ROLL,PITCH,YAW]")
            if args.camera_mount else None, camera_samples=args.camera_samples,
            lamp_cd=args.lamp_cd, camera_noise=not args.no_noise)
    if not args.quiet:
        for line in drive_lines(res, args.output):
            print(line)
    return 0


def drive_lines(res, output) -> list[str]:
    """What ``tunnelsim drive`` prints of a ``DriveResult``, line by line, in the order
    the drive made them."""
    lines = []
    if res.route is not None:
        r = res.route
        lines += [f"route: {r.length_m:.1f} m, smallest clearance {r.min_clearance_m:.2f} "
                  f"m (voxel {r.voxel_m:.2f} m, {r.seconds:.1f} s) -> {r.csv.name}",
                  f"platform: {r.platform} ({r.motion}), {r.drive_s:.1f} s, sensor mount "
                  f"{r.height_m:g} m above the floor, smallest clearance "
                  f"{r.pose_clearance_m:.2f} m"]
    if res.sweeps is not None:
        s = res.sweeps
        lines.append(f"drive ends at its last whole sweep: {s.sweeps} sweeps of "
                     f"{s.period_s:g} s, t = {s.start_s:g} to {s.end_s:g} s "
                     f"({s.left_out_s:.3g} s of a partial sweep left out; "
                     "--keep-partial-sweep keeps it)")
    if res.slam is not None:
        m = res.slam
        lines.append(f"SLAM drift: {m.observed} control points observed; wrote "
                     f"{m.trajectory.name}, {m.true_trajectory.name}, "
                     f"{m.cp_observed.name}, {m.cp_world.name}")
    else:
        lines.append(f"true trajectory: {res.poses} poses -> {res.true_trajectory.name}")
        if res.base_trajectory is not None:
            lines.append(f"base_link trajectory: {res.poses} poses -> "
                         f"{res.base_trajectory.name}")
    o = res.output
    lines.append(f"{res.label}: {res.windows} windows of ~{res.window_s:g} s on "
                 f"{res.where}: {o.pulses:,} pulses, {o.points:,} points -> {output}"
                 if res.windows else summary_line(res.label, o, output))
    for cr in res.cameras:
        where = f"{cr.folder.parent.name}/{cr.folder.name}/" if cr.folder is not None \
            else " and ".join(cr.topics)
        lines.append(f"camera {cr.name}: {cr.frames} frames of {cr.width}x{cr.height} at "
                     f"{cr.rate_hz:g} Hz ({cr.shutter} shutter, {cr.lamps}), "
                     f"{cr.rays / 1e6:.3g} M rays -> {where} (rendered and written in "
                     f"{cr.seconds:.1f} s)")
    b = res.robot
    lines.append(f"robot: {b.name}, base_link {b.mast_height_m:g} m below the platform "
                 f"frame -> {b.urdf.name}, {b.launch.name}")
    return lines


__all__ = ["cmd_drive", "drive_lines", "register"]
