"""What the simulating commands share (scan, drive): the --crs option and the CRS the
output states, the physics settings, writing a run with its summary line and its
guard against runs that miss the mesh, and coordinates as text."""

from __future__ import annotations

from survey.cli.common import Progress
from survey.errors import TunnelsimCLIError


def crs_option(c) -> None:
    c.option("--crs", metavar="CRS",
             help="coordinate reference system of the mesh's coordinates, stated in the "
                  "output (EPSG:n, WKT or PROJJSON; needs pyproj); default: the tunnel "
                  "JSON's 'crs' (or a <mesh>.prj sidecar), else none")


def output_crs(args):
    """The CRS the output states: --crs, else the mesh's (its tunnel JSON's ``crs``, or
    a ``<mesh>.prj`` sidecar), else None; --crs against the mesh's own is refused."""
    from sensors.io.crs import CRSError, mismatch_message, parse_crs, same_crs
    from sensors.io.clouds import cloud_crs_text
    from survey.world.mesh import read_meta, tunnel_crs

    js = getattr(args, "tunnel_json", None)
    where = str(js or args.mesh)
    stated = tunnel_crs(read_meta(js)) if js else cloud_crs_text(args.mesh)
    if args.crs is None:
        return stated
    crs = parse_crs(args.crs, what="--crs")
    if stated is not None and not same_crs(crs, stated):
        raise CRSError(mismatch_message(("--crs", crs), (where, stated),
                                        what="output and the mesh",
                                        hint="leave --crs out to take the mesh's"))
    return crs


def run_settings(args):
    from dataclasses import replace

    from sensors import Settings

    if args.ideal:
        base = Settings.ideal()
    else:
        base = Settings(range_noise=not args.no_noise, angle_jitter=not args.no_noise,
                        detection=not args.no_detection)
    return replace(base, beam_subrays=args.beam_subrays, mixed=args.mixed,
                   attenuation_per_m=args.attenuation, particle_rate_per_m=args.particles,
                   returns=getattr(args, "returns", None))


def finish_run(args, run, label, *, min_return: float = 0.0, where: str = "",
                crs=None, bag=None, robot=None) -> int:
    """Write the run and print its summary; refuse (the output removed by
    ``run_command``) a run that returned no point, or fewer than ``min_return`` of its
    pulses (``where`` says what the caller knows: the poses, the mesh's box).
    ``robot`` (``sensors.robot.RobotDescription``): a ROS 2 bag output takes its
    frames from it (``write_robot_bag``)."""
    from sensors.writers import format_of

    prog = Progress(args.quiet)
    try:
        if robot is not None and format_of(args.output) in ("mcap", "rosbag2"):
            stats = write_robot_bag(args.output, run, robot, progress=prog, crs=crs,
                                    **(bag or {}))
        else:
            # A drifted run (--slam-drift) states no CRS, and its write takes none.
            stats = run.write(args.output, progress=prog, fields=args.fields,
                              **({} if crs is None else {"crs": crs}), **(bag or {}))
    finally:
        prog.close()
    pulses, points = int(stats["pulses"]), int(stats["points"])
    if points == 0 or points < min_return * pulses:
        share = f" ({100 * points / max(pulses, 1):.2g} % returned, below " \
                f"{100 * min_return:g} %)" if points else ""
        raise TunnelsimCLIError(f"Expected the {label} to see the mesh, got {points:,} "
                                f"points from {pulses:,} pulses{share}{where}.")
    if not args.quiet:
        print(f"{label}: {stats['pulses']:,} pulses, {stats['points']:,} points "
              f"(hit ratio {100 * stats['hit_ratio']:.1f} %), {stats['seconds']:.1f} s, "
              f"{stats['rays_per_s'] / 1e6:.2f} Mrays/s -> {stats['path']}")
    return 0


def write_robot_bag(path, run, robot, *, progress=None, crs=None, **bag) -> dict:
    """A drive's ROS 2 bag in the frames of ``robot`` (issue 30): /tf and the ground
    truth odometry for base_link (``robot.base_trajectory``), /tf_static base_link ->
    sensor and base_link -> imu_link, the IMU at its mount, /odom wheel odometry
    (``sensors.bag.DEFAULT_WHEEL_ODOMETRY``, seeded by the run's seed). The points are
    the run's, in the sensor frame, as ``Run.write`` writes them. Returns the run's
    stats plus the path."""
    from sensors.bag import DEFAULT_WHEEL_ODOMETRY, RosbagStream
    from sensors.io.crs import file_wkt, parse_crs
    from sensors.writers import format_of

    spec = run.sensor
    mount = robot.sensor_mount_from_base()
    info = {"sensor": spec.name, "seed": run.seed,
            "mount_lever_arm_m": list(mount.lever_arm_m),
            "mount_boresight_xyzw": mount.boresight.as_quat().tolist(),
            "robot": robot.name, "mast_height_m": robot.mast_height_m}
    if crs is not None:
        info["crs"] = file_wkt(parse_crs(crs, metric=True, what="the output CRS"))
    span = (run.t0, run.t0 + run.duration_s)
    with RosbagStream(path, spec, single_file=format_of(path) == "mcap", seed=run.seed,
                      mount=mount, trajectory=robot.base_trajectory(run.trajectory),
                      span_s=span, info=info, imu_mount=robot.imu_mount(),
                      wheel_odometry=DEFAULT_WHEEL_ODOMETRY,
                      returns=run.settings.returns, **bag) as w:
        for chunk in run:
            w.write_points(chunk)
            if progress is not None:
                progress(run.pass_stats["pulses"], run.n_pulses)
    return dict(run.stats, path=str(path))


def xyz_text(p) -> str:
    """(x, y, z) to the millimetre (a BVH box is padded by ~1e-6 of its size)."""
    return "(" + ", ".join(f"{round(float(c), 3) + 0.0:.10g}" for c in p) + ")"


def box_text(lo, hi) -> str:
    return f"{xyz_text(lo)}-{xyz_text(hi)}"


__all__ = ["box_text", "crs_option", "finish_run", "output_crs", "run_settings",
           "write_robot_bag", "xyz_text"]
