"""Commands about the world and the tool: info, sensors, tunnel, gazebo."""

from __future__ import annotations

import sys
from pathlib import Path

from survey.cli.common import CommandSet, numbers, parse_window, warn_radian_like
from survey.errors import TunnelsimCLIError


def register(commands: CommandSet) -> None:
    """Add info, sensors, tunnel and gazebo."""
    commands.add("info", cmd_info, printing=True,
                 help="versions, Numba threading layer and thread count",
                 description="Print versions of tunnelsim and its dependencies, the Numba "
                             "threading layer and thread count.",
                 epilog="Example: tunnelsim info")

    c = commands.add(
        "tunnel", cmd_tunnel, seeded=True, help="generate a tunnel mesh (PLY + JSON metadata)",
        description="Generate a labelled tunnel mesh from a preset: binary PLY with face "
                    "labels and reflectivity, and a JSON file beside it with the alignment, "
                    "profile, features and control points. Optionally a second, deformed "
                    "epoch with the displacement per vertex.",
        epilog="Example: tunnelsim tunnel -o bfo.ply --preset bfo --edge-length 0.08 "
               "--epoch2 bfo_epoch2.ply --convergence 120:160:5")
    c.option("-o", "--output", required=True, path="out", help="output mesh (.ply)")
    c.option("--preset", default="bfo", choices=["bfo", "tbm", "junction"],
             help="which tunnel (default: bfo, the seed study's gallery; tbm: a segmental "
                  "lining; junction: a mine drift with a 90-degree bend and a T-junction)")
    g = c.exclusive()
    c.option("--edge-length", group=g, type=float, default=0.1, metavar="M",
             help="target edge length of the lining in metres (default 0.1)")
    c.option("--triangles", group=g, type=int, metavar="N",
             help="target number of lining triangles instead of an edge length")
    c.option("--roughness-mm", type=float, metavar="MM",
             help="lining roughness (the fine texture), standard deviation in mm; with "
                  "rock relief it replaces the relief's texture (default: the preset's)")
    c.option("--relief", choices=["none", "rock"],
             help="surface relief: 'rock' for drill-and-blast overbreak (decimetre relief "
                  "over metres, a look-out sawtooth per blasting round, none on the "
                  "floor), 'none' for a smooth lining (default: the preset's, bfo rock, "
                  "tbm none)")
    c.option("--relief-scale", type=float, metavar="FACTOR",
             help="multiply the rock relief's overbreak (mean, rms, underbreak, look-out) "
                  "by FACTOR, e.g. 2 for a rougher gallery (default 1)")
    c.option("--closed-ends", action="store_true", help="cap both portals (watertight mesh)")
    c.option("--origin", metavar="E,N,H",
             help="coordinates of the first portal's centreline point, e.g. UTM")
    c.option("--heading-deg", type=float, default=0.0, metavar="DEG",
             help="initial direction, degrees counter-clockwise from east")
    c.option("--crs", metavar="CRS",
             help="coordinate reference system of the coordinates (with --origin): "
                  "EPSG:n, WKT or PROJJSON, metre axes, e.g. EPSG:2056; kept in the JSON "
                  "and stated in every scan of the tunnel (needs pyproj)")
    c.option("--epoch2", metavar="PATH", path="out",
             help="also write a deformed second epoch (.ply + .json)")
    c.option("--convergence", action="append", default=[], metavar="START:END:MM",
             help="radial convergence in mm between two chainages (repeatable; default "
                  "for --epoch2: the preset's)")
    c.option("--bulge", action="append", default=[], metavar="CHAINAGE:ANGLE_DEG:RADIUS_M:MM",
             help="local inward bulge at a chainage and angle from the crown")
    c.option("--seed", type=int, default=0, help="roughness and relief seed (default 0)")
    c.option("--quiet", action="store_true", help="print nothing on success")

    c = commands.add(
        "gazebo", cmd_gazebo,
        help="export the tunnel and a lidar robot as a Gazebo world (SDF 1.9)",
        description="Write a Gazebo world folder for Gazebo Harmonic or Ignition Gazebo "
                    "Fortress: world.sdf (underground lighting, the tunnel as a static "
                    "model, a LIMO-sized differential-drive robot carrying the lidar as a "
                    "gpu_lidar sensor, an IMU with the bag's noise model and ground-truth "
                    "pose and odometry publishers), bridge.yaml for ros_gz_bridge, the "
                    "tunnel model (OBJ visual, decimated STL collision, laser_retro from "
                    "the mesh's reflectivity) in local coordinates, and a README. On a "
                    "mesh without the tunnel JSON the robot starts at the beginning of "
                    "the route 'drive --along auto' finds. --camera adds a camera sensor "
                    "with the same intrinsics (10 cm below the lidar, looking ahead) and "
                    "the robot's headlights. What SDF cannot express about the sensors "
                    "is listed.",
        epilog="Example: tunnelsim gazebo --mesh bfo.ply --sensor robosense_airy "
               "--flavour fortress -o world/")
    c.option("--mesh", required=True, path="in",
             help="tunnel mesh (its .json gives the axis; any other mesh: a route is "
                  "found in it)")
    c.option("--sensor", default="robosense_airy", path="toml",
             help="spinning lidar or profiler, name or .toml (default robosense_airy)")
    c.option("--flavour", choices=["harmonic", "fortress"], default="harmonic",
             help="Gazebo line: harmonic (gz sim, ROS 2 Jazzy) or fortress (ign gazebo, "
                  "ROS 2 Humble) (default harmonic)")
    c.option("--mount", choices=["level", "down"], default="level",
             help="lidar z up (level) or pointing down (default level)")
    c.option("--chainage", type=float, metavar="M",
             help="robot start chainage on a generated tunnel (default: first chainage "
                  "+ 1 m)")
    c.option("--waypoints", path="in", metavar="CSV",
             help="x,y[,z] rows the route passes through in order, as drive's; the robot "
                  "starts at the first")
    c.option("--clearance", type=float, metavar="M",
             help="distance the route keeps from the mesh where it can, as drive's "
                  "(default 0.2)")
    c.option("--voxel", type=float, metavar="M",
             help="voxel edge of the grid the route is sought on, as drive's (default: "
                  "the finest within 2 million voxels)")
    c.option("--camera", path="toml", metavar="NAME|FILE",
             help="add this camera ('tunnelsim cameras' lists them, or a .toml) to the "
                  "robot: its Gazebo sensor with the same intrinsics, its image and "
                  "camera_info in bridge.yaml, the ground_robot's lamps as lights")
    c.option("-o", "--output", required=True, path="out", help="output world folder (new)")
    c.option("--force", action="store_true", help="replace an existing folder")
    c.option("--quiet", action="store_true", help="print nothing on success")

    commands.add("sensors", cmd_sensors, printing=True, help="list the sensor models",
                 description="List the shipped sensor models with kind and source file.",
                 epilog="Example: tunnelsim sensors")


def cmd_info(args) -> int:
    from survey.workflows.world import software_info

    info = software_info()
    lines = [f"tunnelsim {info.version}",
             f"python {info.python} ({info.machine}, {info.system})"]
    lines += [f"{pkg} {v}" if v is not None else f"{pkg} (not installed)"
              for pkg, v in info.packages]
    lines.append(f"numba threading layer: {info.threading_layer}")
    lines.append(f"numba threads: {info.threads} of {info.max_threads}")
    print("\n".join(lines))
    return 0


def cmd_sensors(args) -> int:
    from survey.workflows.world import sensor_models

    for m in sensor_models():
        print(f"{m.name:18s} {m.kind:9s} {m.vendor} {m.model}  "
              f"range {m.range_min_m:g}-{m.range_max_m:g} m")
    return 0


def cmd_tunnel(args) -> int:
    from survey.workflows.world import tunnel_files

    # DECISION: the name's suffix is the option's syntax, refused here as a usage
    # error (TunnelsimCLIError, as before); the library refuses it too (TunnelError).
    if Path(args.output).suffix.lower() != ".ply":
        raise TunnelsimCLIError(f"Expected an output file ending in .ply, got "
                                f"'{Path(args.output)}'.")
    origin = None if args.origin is None else \
        numbers(args.origin, "--origin as E,N,H in metres", 3)
    conv = [parse_window(c, "--convergence START:END:MM", 3) for c in args.convergence]
    bulges = [parse_window(c, "--bulge CHAINAGE:ANGLE_DEG:RADIUS_M:MM", 4)
              for c in args.bulge]
    warn_radian_like(args.heading_deg, "--heading-deg")
    r = tunnel_files(args.output, preset=args.preset, edge_length_m=args.edge_length,
                     triangles=args.triangles,
                     roughness_rms_m=None if args.roughness_mm is None
                     else args.roughness_mm / 1000.0, relief=args.relief,
                     relief_scale=args.relief_scale, closed_ends=args.closed_ends,
                     origin=origin, heading_deg=args.heading_deg, crs=args.crs,
                     epoch2=args.epoch2 or None, convergence=conv, bulges=bulges,
                     seed=args.seed)
    if not args.quiet:
        counts = ", ".join(f"{k} {v:,}" for k, v in r.face_counts.items())
        print(f"{r.preset}: {r.triangles:,} triangles ({counts}), "
              f"{r.vertices:,} vertices, edge length {r.edge_length_m:.4g} m, "
              f"{r.control_points} control points, relief {r.relief}, "
              f"{r.crs_name}, {r.seconds:.1f} s")
        for p in r.files:
            print(f"wrote {p}")
    return 0


def cmd_gazebo(args) -> int:
    import warnings

    from survey.workflows.world import gazebo_files

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            r = gazebo_files(args.mesh, args.output, sensor=args.sensor,
                             flavour=args.flavour, mount=args.mount,
                             chainage_m=args.chainage, waypoints=args.waypoints,
                             clearance_m=args.clearance, voxel_m=args.voxel,
                             force=args.force, camera=args.camera)
        finally:   # unit warnings first: they often explain a later failure
            for w in caught:
                print(f"tunnelsim: warning: {w.message}", file=sys.stderr)
    if not args.quiet:
        _print_gazebo(r)
    return 0


def _print_gazebo(r) -> None:
    """The summary of a Gazebo world (``GazeboResult``)."""
    print(f"wrote {r.path}/world.sdf, bridge.yaml and models/tunnel "
          f"({r.triangles:,} triangles, collision "
          f"{r.collision_triangles:,}, laser_retro {r.laser_retro:.3g}); "
          f"local origin {' '.join(f'{x:.3f}' for x in r.origin)} m"
          + (f" in {r.crs}" if r.crs else ""))
    x, y, z, yaw = r.robot_pose
    where = "on the tunnel axis" if r.route is None else (
        f"at the start of the route ({r.route['length_m']:.1f} m, smallest "
        f"clearance {r.route['min_clearance_m']:.2f} m)")
    print(f"robot {where}: {x:.3f} {y:.3f} {z:.3f} m local, yaw {yaw:.3f} rad")
    print(f"{r.sensor} as gpu_lidar; SDF cannot express:")
    for item in r.limitations:
        print(f"  - {item}")
    if r.camera is not None:
        print(f"{r.camera} on {r.camera_topic} (camera_info beside it); SDF cannot "
              "express:")
        for item in r.camera_limitations:
            print(f"  - {item}")
    print("robot.urdf: base_link on the ground, the sensor and imu_link as in a "
          "drive's bag; ros2 launch ./robot.launch.py for robot_state_publisher")
    print(f"run: cd {r.path} && {r.run}")
    print("bridge: ros2 run ros_gz_bridge parameter_bridge --ros-args -p "
          "config_file:=$PWD/bridge.yaml")


__all__ = ["cmd_gazebo", "cmd_info", "cmd_sensors", "cmd_tunnel", "register"]
