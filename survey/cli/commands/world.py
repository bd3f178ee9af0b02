"""Commands about the world and the tool: info, sensors, tunnel, gazebo."""

from __future__ import annotations

import sys

from survey.cli.common import CommandSet, numbers, parse_window, version, warn_radian_like
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
                    "the route 'drive --along auto' finds. What SDF cannot express about "
                    "the sensor is listed.",
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
    c.option("-o", "--output", required=True, path="out", help="output world folder (new)")
    c.option("--force", action="store_true", help="replace an existing folder")
    c.option("--quiet", action="store_true", help="print nothing on success")

    commands.add("sensors", cmd_sensors, printing=True, help="list the sensor models",
                 description="List the shipped sensor models with kind and source file.",
                 epilog="Example: tunnelsim sensors")


def cmd_info(args) -> int:
    import platform
    from importlib import metadata

    from raytrace.config import threading_info

    lines = [f"tunnelsim {version()}",
             f"python {platform.python_version()} ({platform.machine()}, {platform.system()})"]
    for pkg in ("numpy", "numba", "scipy", "trimesh", "laspy", "lazrs", "pyproj", "pye57",
                "embreex", "open3d"):
        try:
            lines.append(f"{pkg} {metadata.version(pkg)}")
        except metadata.PackageNotFoundError:
            lines.append(f"{pkg} (not installed)")
    info = threading_info()
    lines.append(f"numba threading layer: {info['threading_layer']}")
    lines.append(f"numba threads: {info['threads']} of {info['max_threads']}")
    print("\n".join(lines))
    return 0


def cmd_sensors(args) -> int:
    from sensors import list_sensors, load_sensor

    for name in list_sensors():
        spec = load_sensor(name)
        print(f"{name:18s} {spec.kind:9s} {spec.vendor} {spec.model}  "
              f"range {spec.physics.range_min_m:g}-{spec.physics.range_max_m:g} m")
    return 0


def cmd_tunnel(args) -> int:
    import time
    import warnings
    from pathlib import Path

    import numpy as np

    from survey.world.deformation import Bulge, Convergence
    from survey.world.generator import edge_length_for
    from survey.world.presets import PRESETS, RELIEF, preset
    from survey.world.rock import RockRelief

    out = Path(args.output)
    if out.suffix.lower() != ".ply":
        raise TunnelsimCLIError(f"Expected an output file ending in .ply, got '{out}'.")
    if not out.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing output folder, got '{out.parent}'; "
                                "create it first.")
    origin = (0.0, 0.0, 0.0) if args.origin is None else \
        numbers(args.origin, "--origin as E,N,H in metres", 3)
    crs = None
    if args.crs is not None:   # checked before the mesh is made (seconds)
        from sensors.io.crs import area_warning, parse_crs

        crs = parse_crs(args.crs, what="--crs")
        where = area_warning(crs, origin, what="--origin" if args.origin else
                             "the default origin", hint="give the portal's position in "
                             "that CRS with --origin E,N,H" if args.origin is None else
                             "easting and northing swapped, or another CRS meant?")
        if where:
            warnings.warn(where[0].upper() + where[1:], UserWarning, stacklevel=1)
    edge = args.edge_length
    if args.triangles is not None:
        al, prof, _, _ = PRESETS[args.preset](origin, 0.0)
        edge = edge_length_for(args.triangles, prof, al.length_m)
    t0 = time.perf_counter()
    deformations: list = []
    for c in args.convergence:
        a, b, mm = parse_window(c, "--convergence START:END:MM", 3)
        deformations.append(Convergence(a, b, mm / 1000.0))
    for c in args.bulge:
        s, ang, r, mm = parse_window(c, "--bulge CHAINAGE:ANGLE_DEG:RADIUS_M:MM", 4)
        deformations.append(Bulge(s, np.deg2rad(ang), r, mm / 1000.0))
    relief = RELIEF[args.preset] if args.relief is None else \
        None if args.relief == "none" else (RELIEF[args.preset] or RockRelief())
    if args.relief_scale is not None:
        if relief is None:
            raise TunnelsimCLIError("Expected --relief-scale with rock relief, got a "
                                    f"smooth lining ({args.preset}, --relief "
                                    f"{args.relief or 'default'}); add --relief rock.")
        relief = relief.scaled(args.relief_scale)
    warn_radian_like(args.heading_deg, "--heading-deg")
    tun, default_def = preset(args.preset, edge_length_m=edge, seed=args.seed,
                              closed_ends=args.closed_ends,
                              roughness_rms_m=None if args.roughness_mm is None
                              else args.roughness_mm / 1000.0, relief=relief,
                              origin=origin, heading_rad=np.deg2rad(args.heading_deg))
    if crs is not None:
        tun = tun.with_crs(crs)
    written = list(tun.write(out))
    if args.epoch2:
        epoch = tun.deformed(deformations or default_def)
        written += list(epoch.write(Path(args.epoch2)))
    dt = time.perf_counter() - t0
    if not args.quiet:
        counts = ", ".join(f"{k} {v:,}" for k, v in tun.metadata["face_counts"].items())
        print(f"{args.preset}: {len(tun.faces):,} triangles ({counts}), "
              f"{len(tun.vertices):,} vertices, edge length {edge:.4g} m, "
              f"{len(tun.metadata['control_points'])} control points, relief "
              f"{'none' if relief is None else 'rock'}, "
              f"{tun.metadata.get('crs_name', 'local coordinates (no CRS)')}, {dt:.1f} s")
        for p in written:
            print(f"wrote {p}")
    return 0


def cmd_gazebo(args) -> int:
    import warnings

    from sensors import load_sensor
    from sensors.route import read_waypoints
    from survey.export.gazebo import export_gazebo

    spec = load_sensor(args.sensor)
    wp = read_waypoints(args.waypoints) if args.waypoints else None
    for flag, value in (("--clearance", args.clearance), ("--voxel", args.voxel)):
        if value is not None and not (value > 0 and value < float("inf")):
            raise TunnelsimCLIError(f"Expected a positive {flag} in metres, got {value:g}.")
    route_kw = {k: v for k, v in (("route_clearance_m", args.clearance),
                                  ("voxel_m", args.voxel)) if v is not None}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            info = export_gazebo(args.mesh, spec, args.output, force=args.force,
                                 mount=args.mount, chainage_m=args.chainage,
                                 flavour=args.flavour, waypoints=wp, **route_kw)
        finally:   # unit warnings first: they often explain a later failure
            for w in caught:
                print(f"tunnelsim: warning: {w.message}", file=sys.stderr)
    if not args.quiet:
        print(f"wrote {info['path']}/world.sdf, bridge.yaml and models/tunnel "
              f"({info['triangles']:,} triangles, collision "
              f"{info['collision_triangles']:,}, laser_retro {info['laser_retro']:.3g}); "
              f"local origin {' '.join(f'{x:.3f}' for x in info['origin'])} m"
              + (f" in {info['crs']}" if info.get("crs") else ""))
        x, y, z, yaw = info["robot_pose"]
        where = "on the tunnel axis" if info["route"] is None else (
            f"at the start of the route ({info['route']['length_m']:.1f} m, smallest "
            f"clearance {info['route']['min_clearance_m']:.2f} m)")
        print(f"robot {where}: {x:.3f} {y:.3f} {z:.3f} m local, yaw {yaw:.3f} rad")
        print(f"{spec.name} as gpu_lidar; SDF cannot express:")
        for item in info["limitations"]:
            print(f"  - {item}")
        print(f"robot.urdf: base_link on the ground, the sensor and imu_link as in a "
              f"drive's bag; ros2 launch ./robot.launch.py for robot_state_publisher")
        print(f"run: cd {info['path']} && {info['run']}")
        print("bridge: ros2 run ros_gz_bridge parameter_bridge --ros-args -p "
              "config_file:=$PWD/bridge.yaml")
    return 0


__all__ = ["cmd_gazebo", "cmd_info", "cmd_sensors", "cmd_tunnel", "register"]
