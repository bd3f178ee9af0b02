"""The ``tunnelsim`` command.

Errors a user can fix (``TunnelsimError`` and bad arguments) print one line on stderr and
exit with status 2; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import platform
import sys
from importlib import metadata

import numpy as np

from raytrace.errors import TunnelsimError

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line (and exit 2), like every other
    error of the command."""

    def error(self, message):  # noqa: D401 - argparse API
        raise _UsageError(f"{self.prog}: {message} (see '{self.prog} --help')")


class _UsageError(Exception):
    pass


def _version() -> str:
    try:
        return metadata.version("tunnelsim")
    except metadata.PackageNotFoundError:  # running from a source tree
        return "0+unknown"


def _cmd_info(args) -> int:
    from raytrace.config import threading_info

    lines = [f"tunnelsim {_version()}",
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


def _parse_window(text, what, n):
    """'A:B:C' -> floats, with a one-line error naming the option."""
    parts = text.split(":")
    try:
        vals = [float(v) for v in parts]
    except ValueError:
        vals = []
    if len(vals) != n:
        raise TunnelsimCLIError(f"Expected {what}, got {text!r}.")
    return vals


class TunnelsimCLIError(TunnelsimError, ValueError):
    """A command-line value is malformed."""


def _cmd_sensors(args) -> int:
    from sensors import list_sensors, load_sensor

    for name in list_sensors():
        spec = load_sensor(name)
        print(f"{name:18s} {spec.kind:9s} {spec.vendor} {spec.model}  "
              f"range {spec.physics.range_min_m:g}-{spec.physics.range_max_m:g} m")
    return 0


def _cmd_tunnel(args) -> int:
    import time
    from pathlib import Path

    from .deformation import Bulge, Convergence
    from .presets import PRESETS, preset
    from .tunnel import edge_length_for

    out = Path(args.output)
    if out.suffix.lower() != ".ply":
        raise TunnelsimCLIError(f"Expected an output file ending in .ply, got '{out}'.")
    if not out.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing output folder, got '{out.parent}'; "
                                "create it first.")
    origin = (0.0, 0.0, 0.0) if args.origin is None else \
        _parse_window(args.origin.replace(",", ":"), "--origin as E,N,H in metres", 3)
    edge = args.edge_length
    if args.triangles is not None:
        al, prof, _, _ = PRESETS[args.preset](origin, 0.0)
        edge = edge_length_for(args.triangles, prof, al.length_m)
    t0 = time.perf_counter()
    tun, default_def = preset(args.preset, edge_length_m=edge, seed=args.seed,
                              closed_ends=args.closed_ends,
                              roughness_rms_m=None if args.roughness_mm is None
                              else args.roughness_mm / 1000.0, origin=origin,
                              heading_rad=np.deg2rad(args.heading_deg))
    deformations = [Convergence(*_parse_window(c, "--convergence START:END:MM", 3)[:2],
                                _parse_window(c, "", 3)[2] / 1000.0)
                    for c in args.convergence]
    deformations += [Bulge(a, np.deg2rad(b), r, mm / 1000.0) for a, b, r, mm in
                     (_parse_window(c, "--bulge CHAINAGE:ANGLE_DEG:RADIUS_M:MM", 4)
                      for c in args.bulge)]
    written = list(tun.write(out))
    if args.epoch2:
        ep2 = Path(args.epoch2)
        epoch = tun.deformed(deformations or default_def)
        written += list(epoch.write(ep2))
    dt = time.perf_counter() - t0
    if not args.quiet:
        counts = ", ".join(f"{k} {v:,}" for k, v in tun.metadata["face_counts"].items())
        print(f"{args.preset}: {len(tun.faces):,} triangles ({counts}), "
              f"{len(tun.vertices):,} vertices, edge length {edge:.4g} m, "
              f"{len(tun.metadata['control_points'])} control points, {dt:.1f} s")
        for p in written:
            print(f"wrote {p}")
    return 0


class _Progress:
    """A one-line progress bar on stderr (only on a terminal)."""

    def __init__(self, quiet):
        import time

        self.on = not quiet and sys.stderr.isatty()
        self.t0 = time.perf_counter()

    def __call__(self, done, total):
        import time

        if not self.on:
            return
        dt = time.perf_counter() - self.t0
        frac = done / max(total, 1)
        eta = dt / frac - dt if frac > 0 else 0.0
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r[{bar:<30}] {100 * frac:5.1f} %  {done / 1e6:.1f}M/"
                         f"{total / 1e6:.1f}M rays  {done / max(dt, 1e-9) / 1e6:.2f} "
                         f"Mrays/s  ETA {eta:.0f} s ")
        sys.stderr.flush()

    def close(self):
        if self.on:
            sys.stderr.write("\n")


def _settings(args):
    from sensors import Settings

    if args.ideal:
        base = Settings.ideal()
    else:
        base = Settings(range_noise=not args.no_noise, angle_jitter=not args.no_noise,
                        detection=not args.no_detection)
    from dataclasses import replace

    return replace(base, beam_subrays=args.beam_subrays, mixed=args.mixed,
                   attenuation_per_m=args.attenuation, particle_rate_per_m=args.particles)


def _xyz(text, what):
    return _parse_window(text.replace(",", ":"), f"{what} as X,Y,Z in metres", 3)


def _finish_run(args, run, label):
    from raytrace import set_threads

    if args.threads:
        set_threads(args.threads)
    prog = _Progress(args.quiet)
    try:
        stats = run.write(args.output, progress=prog, fields=args.fields)
    finally:
        prog.close()
    if not args.quiet:
        print(f"{label}: {stats['pulses']:,} pulses, {stats['points']:,} points "
              f"(hit ratio {100 * stats['hit_ratio']:.1f} %), {stats['seconds']:.1f} s, "
              f"{stats['rays_per_s'] / 1e6:.2f} Mrays/s -> {stats['path']}")
    return 0


def _cmd_scan(args) -> int:
    from scipy.spatial.transform import Rotation

    from sensors import load_sensor, simulate_station
    from sensors.meshes import load_mesh

    spec = load_sensor(args.sensor)
    scene, refl = load_mesh(args.mesh)
    run = simulate_station(scene, spec, _xyz(args.at, "--at"),
                           attitude=Rotation.from_euler("z", args.heading_deg, degrees=True),
                           resolution=args.resolution,
                           step_rad=None if args.step_deg is None else np.deg2rad(args.step_deg),
                           settings=_settings(args), seed=args.seed,
                           reflectivity=refl if refl is not None else args.reflectivity)
    return _finish_run(args, run, f"{spec.name} {run.scan.resolution or 'custom step'}")


def _cmd_drive(args) -> int:
    from sensors import Mount, Trajectory, load_sensor, simulate_drive
    from sensors.meshes import load_mesh

    spec = load_sensor(args.sensor)
    scene, refl = load_mesh(args.mesh)
    if args.trajectory:
        traj = Trajectory.read(args.trajectory)
    else:
        if args.along != "centreline" or args.speed is None:
            raise TunnelsimCLIError("Expected --trajectory FILE, or --along centreline with "
                                    "--speed V, got neither.")
        from .tunnel_io import TunnelFileError, sidecar
        from .alignment import Alignment
        import json

        js = sidecar(args.mesh)
        if not js.is_file():
            raise TunnelFileError(f"Expected the tunnel metadata '{js}' for --along "
                                  "centreline (made by 'tunnelsim tunnel'), got none; pass "
                                  "--trajectory instead.")
        al = Alignment.from_dict(json.loads(js.read_text())["alignment"])
        c0, c1 = al.chainage_range
        s = np.arange(c0 + args.margin, c1 - args.margin, 0.5)
        pts = al.to_world(s, args.offset, args.height)
        traj = Trajectory.along_polyline(pts, args.speed)
    if args.mount == "down":
        mount = Mount.pointing_down(_xyz(args.lever, "--lever"))
    else:
        mount = Mount(_xyz(args.lever, "--lever"))
    t_end = None if args.duration is None else traj.start_s + args.duration
    run = simulate_drive(scene, spec, traj, mount, settings=_settings(args), seed=args.seed,
                         reflectivity=refl if refl is not None else args.reflectivity,
                         t_end=t_end)
    return _finish_run(args, run, f"{spec.name} drive {run.duration_s:.1f} s")


def _physics_options(p):
    p.add_argument("--ideal", action="store_true",
                   help="exact geometry: no noise, no jitter, every return detected")
    p.add_argument("--no-noise", action="store_true", help="no range noise, no angle jitter")
    p.add_argument("--no-detection", action="store_true",
                   help="keep every return within range (no detection probability)")
    p.add_argument("--beam-subrays", type=int, default=1, choices=[1, 7, 19],
                   help="sub-rays per pulse for beam divergence (default 1: off)")
    p.add_argument("--mixed", default="average", choices=["average", "strongest"],
                   help="how sub-returns combine (default average)")
    p.add_argument("--attenuation", type=float, default=0.0, metavar="PER_M",
                   help="dust/fog extinction coefficient in 1/m (default 0)")
    p.add_argument("--particles", type=float, default=0.0, metavar="PER_M",
                   help="rate of airborne-particle returns per metre (default 0)")
    p.add_argument("--reflectivity", type=float, default=0.5,
                   help="reflectivity where the mesh has none (default 0.5)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--threads", type=int, help="Numba threads (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    p.add_argument("--fields", choices=["compact", "full"],
                   help="LAS/LAZ extra bytes: compact (stations' default) or full (every "
                        "field; moving platforms' default)")
    p.add_argument("-o", "--output", required=True,
                   help="output points: .laz, .las, .ply, .npz (or .e57 for stations)")


def _write_text(path, text):
    from raytrace.fileio import atomic_writer

    from pathlib import Path
    path = Path(path)
    if not path.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing folder for '{path}', got none.")
    with atomic_writer(path, "w") as fh:
        fh.write(text)


def _cmd_adjust(args) -> int:
    import json

    from .controlpoints import match, read_control_points
    from .helmert import fit_helmert
    from .reports import helmert_report

    a = read_control_points(args.source)
    b = read_control_points(args.target)
    ia, ib = match(a, b)
    res = fit_helmert(a.xyz[ia], b.xyz[ib], model=args.model,
                      sigma_source=None if a.sigma is None else a.sigma[ia],
                      sigma_target=None if b.sigma is None else b.sigma[ib],
                      ids=[a.ids[i] for i in ia])
    text = helmert_report(res)
    if args.report:
        _write_text(args.report, text)
    if args.json:
        _write_text(args.json, json.dumps(res.to_dict(), indent=1))
    if not args.quiet:
        print(text, end="")
    return 0


def _cmd_transform(args) -> int:
    import json
    from pathlib import Path

    from .cloudio import map_cloud
    from .helmert import HelmertResult

    p = Path(args.helmert)
    if not p.is_file():
        raise TunnelsimCLIError(f"Expected a Helmert JSON (from 'tunnelsim adjust --json'), "
                                f"got '{p}' which does not exist.")
    try:
        res = HelmertResult.from_dict(json.loads(p.read_text()))
    except json.JSONDecodeError as exc:
        raise TunnelsimCLIError(f"Expected JSON in '{p}', got invalid text ({exc}).") from exc
    n = map_cloud(args.cloud, args.output, lambda xyz, t: res.apply(xyz))
    if not args.quiet:
        print(f"transformed {n:,} points -> {args.output}")
    return 0


def _cmd_correct(args) -> int:
    from pathlib import Path

    from sensors import Trajectory

    from .cloudio import map_cloud
    from .controlpoints import ControlPointError, match, read_control_points
    from .drift import fit_drift, leave_one_out
    from .reports import drift_report

    traj = Trajectory.read(args.trajectory)
    world = read_control_points(args.control)
    seen = read_control_points(args.observed)
    if seen.time is None:
        raise ControlPointError(f"Expected a 'time' column in '{args.observed}' (when each "
                                "control point was observed by the MLS), got none.")
    ia, ib = match(seen, world)
    m, t, g = seen.xyz[ia], seen.time[ia], world.xyz[ib]
    sw = None if world.sigma is None else world.sigma[ib].mean(axis=1)
    ids = [seen.ids[i] for i in ia]
    corr = fit_drift(m, t, g, model=args.model, sigma_world=sw, ids=ids)
    loo = leave_one_out(m, t, g, model=args.model, sigma_world=sw)
    out = Path(args.output)
    n = map_cloud(args.cloud, out, lambda xyz, tt: corr.apply(xyz, tt) if tt is not None
                  else _no_time(args.cloud))
    fixed = corr.apply_trajectory(traj)
    traj_out = out.with_name(out.stem + "_trajectory.txt")
    fixed.write(traj_out)
    report = out.with_name(out.stem + "_report.md")
    _write_text(report, drift_report(corr, loo, traj=traj,
                                     plot_path=out.with_name(out.stem + "_correction.png")))
    if not args.quiet:
        rms = np.sqrt(np.mean(np.sum(loo ** 2, axis=1)))
        print(f"corrected {n:,} points with {len(ids)} control points ({args.model}); "
              f"check-point RMS {rms * 1000:.1f} mm -> {out}, {traj_out.name}, {report.name}")
    return 0


def _no_time(path):
    raise TunnelsimCLIError(f"Expected GPS time per point in '{path}' to correct drift, got "
                            "none.")


def _cmd_preprocess(args) -> int:
    from .cloudio import cloud_bounds, iter_points, write_points_las
    from .preprocess import VoxelGrid, radius_outliers, statistical_outliers

    lo, hi, n_in = cloud_bounds(args.cloud)
    if args.voxel is not None:
        grid = VoxelGrid(args.voxel, lo)
        for xyz in iter_points(args.cloud):
            grid.add(xyz)
        pts, counts = grid.result()
    else:
        pts = np.concatenate(list(iter_points(args.cloud)))
        counts = np.ones(len(pts), dtype=np.int64)
    keep = np.ones(len(pts), dtype=bool)
    if args.sor:
        k, ratio = _parse_window(args.sor.replace(",", ":"), "--sor as K,STD_RATIO", 2)
        keep &= ~statistical_outliers(pts, int(k), ratio)
    if args.ror:
        nb, rad = _parse_window(args.ror.replace(",", ":"), "--ror as N,RADIUS_M", 2)
        keep &= ~radius_outliers(pts, int(nb), rad)
    write_points_las(args.output, pts[keep],
                     {"voxel_count": counts[keep].astype(np.uint32)})
    if not args.quiet:
        print(f"{n_in:,} points -> {len(pts):,} after the voxel grid -> {int(keep.sum()):,} "
              f"after outlier removal -> {args.output}")
    return 0


def _cmd_mesh(args) -> int:
    import json

    from .alignment import Alignment
    from .cloudio import iter_points
    from .reconstruct import reconstruct_tunnel

    cell_m, cell_deg = _parse_window(args.cell.replace(",", ":"), "--cell as M,DEG", 2)
    pts = np.concatenate(list(iter_points(args.cloud)))
    al = hc = None
    if args.tunnel_json:
        from pathlib import Path
        js = Path(args.tunnel_json)
        if not js.is_file():
            raise TunnelsimCLIError(f"Expected a tunnel JSON, got '{js}' which does not "
                                    "exist.")
        meta = json.loads(js.read_text())
        al = Alignment.from_dict(meta["alignment"])
        from .profiles import Profile
        hc = float(Profile.from_dict(meta["profile"]).centroid[1])
    rec = reconstruct_tunnel(pts, alignment=al, centre_height_m=hc, cell_m=cell_m,
                             cell_rad=np.deg2rad(cell_deg), min_points=args.min_points)
    rec.write(args.output)
    if not args.quiet:
        q = rec.quality
        print(f"{q['points']:,} points -> {q['triangles']:,} triangles -> {args.output}; "
              f"point-to-surface mean {q['mean_m'] * 1000:.1f} mm, median "
              f"{q['median_m'] * 1000:.1f} mm, 95 % {q['p95_m'] * 1000:.1f} mm, max "
              f"{q['max_m'] * 1000:.1f} mm; extrapolated {100 * q['extrapolated_share']:.1f} %")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="tunnelsim",
        description="Tunnel digital twins: meshes from laser scans, simulated scanners.",
        epilog="Example: tunnelsim info",
    )
    parser.add_argument("--version", action="version", version=f"tunnelsim {_version()}")
    parser.add_argument("--debug", action="store_true",
                        help="show tracebacks instead of one-line errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    p = sub.add_parser("info", help="versions, Numba threading layer and thread count",
                       description="Print versions of tunnelsim and its dependencies, the "
                                   "Numba threading layer and thread count.",
                       epilog="Example: tunnelsim info")
    p.set_defaults(func=_cmd_info)

    p = sub.add_parser(
        "tunnel", help="generate a tunnel mesh (PLY + JSON metadata)",
        description="Generate a labelled tunnel mesh from a preset: binary PLY with face "
                    "labels and reflectivity, and a JSON file beside it with the alignment, "
                    "profile, features and control points. Optionally a second, deformed "
                    "epoch with the displacement per vertex.",
        epilog="Example: tunnelsim tunnel -o bfo.ply --preset bfo --edge-length 0.08 "
               "--epoch2 bfo_epoch2.ply --convergence 120:160:5")
    p.add_argument("-o", "--output", required=True, help="output mesh (.ply)")
    p.add_argument("--preset", default="bfo", choices=["bfo", "tbm"],
                   help="which tunnel (default: bfo, the seed study's gallery)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--edge-length", type=float, default=0.1, metavar="M",
                   help="target edge length of the lining in metres (default 0.1)")
    g.add_argument("--triangles", type=int, metavar="N",
                   help="target number of lining triangles instead of an edge length")
    p.add_argument("--roughness-mm", type=float, metavar="MM",
                   help="lining roughness, standard deviation in mm (preset default)")
    p.add_argument("--closed-ends", action="store_true",
                   help="cap both portals (watertight mesh)")
    p.add_argument("--origin", metavar="E,N,H",
                   help="coordinates of the first portal's centreline point, e.g. UTM")
    p.add_argument("--heading-deg", type=float, default=0.0, metavar="DEG",
                   help="initial direction, degrees counter-clockwise from east")
    p.add_argument("--epoch2", metavar="PATH",
                   help="also write a deformed second epoch (.ply + .json)")
    p.add_argument("--convergence", action="append", default=[], metavar="START:END:MM",
                   help="radial convergence in mm between two chainages (repeatable; "
                        "default for --epoch2: the preset's)")
    p.add_argument("--bulge", action="append", default=[],
                   metavar="CHAINAGE:ANGLE_DEG:RADIUS_M:MM",
                   help="local inward bulge at a chainage and angle from the crown")
    p.add_argument("--seed", type=int, default=0, help="roughness seed (default 0)")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=_cmd_tunnel)

    p = sub.add_parser(
        "scan", help="simulate a TLS station on a mesh",
        description="Simulate a terrestrial laser scanner station on a mesh and stream the "
                    "points to a file (LAS/LAZ, PLY, NPZ, E57).",
        epilog="Example: tunnelsim scan --mesh bfo.ply --sensor zf_imager_5016 "
               "--resolution superhigh --at 150,2,1.5 -o station.laz")
    p.add_argument("--mesh", required=True, help="mesh file (PLY with reflectivity, OBJ, ...)")
    p.add_argument("--sensor", default="zf_imager_5016",
                   help="sensor name ('tunnelsim sensors' lists them) or a .toml file")
    p.add_argument("--at", required=True, metavar="X,Y,Z", help="station position (m)")
    p.add_argument("--resolution", help="resolution preset of the sensor (e.g. superhigh)")
    p.add_argument("--step-deg", type=float, metavar="DEG",
                   help="angular step in degrees instead of a preset")
    p.add_argument("--heading-deg", type=float, default=0.0, metavar="DEG",
                   help="station heading, degrees counter-clockwise from +x")
    _physics_options(p)
    p.set_defaults(func=_cmd_scan)

    p = sub.add_parser(
        "drive", help="simulate a moving lidar or profiler along a trajectory",
        description="Simulate a sensor on a moving platform: each pulse is cast from the pose "
                    "at its own time (rolling shutter).",
        epilog="Example: tunnelsim drive --mesh bfo.ply --sensor robosense_airy --along "
               "centreline --speed 1 --mount down --lever 0,0,0.5 -o drive.laz")
    p.add_argument("--mesh", required=True, help="mesh file")
    p.add_argument("--sensor", default="robosense_airy", help="sensor name or a .toml file")
    p.add_argument("--trajectory", help="TUM text (t x y z qx qy qz qw) or CSV trajectory")
    p.add_argument("--along", choices=["centreline"],
                   help="drive along the tunnel centreline (needs the mesh's .json)")
    p.add_argument("--speed", type=float, metavar="M_S", help="speed along the centreline")
    p.add_argument("--height", type=float, default=0.5, metavar="M",
                   help="platform height above the centreline (default 0.5)")
    p.add_argument("--offset", type=float, default=0.0, metavar="M",
                   help="platform offset left of the centreline (default 0)")
    p.add_argument("--margin", type=float, default=1.0, metavar="M",
                   help="distance kept from the portals (default 1)")
    p.add_argument("--mount", choices=["level", "down"], default="level",
                   help="sensor z up (level) or pointing down (default level)")
    p.add_argument("--lever", default="0,0,0", metavar="X,Y,Z",
                   help="lever arm platform -> sensor in metres (default 0,0,0)")
    p.add_argument("--duration", type=float, metavar="S",
                   help="simulate only the first S seconds")
    _physics_options(p)
    p.set_defaults(func=_cmd_drive)

    p = sub.add_parser(
        "adjust", help="Helmert adjustment between two control-point files",
        description="Least-squares Helmert transformation (PROJ form, position-vector "
                    "convention) between two CSV files of control points (id,x,y,z"
                    "[,sigma|sx,sy,sz]) matched by id, with residuals, sigma0, global "
                    "test and outlier tests.",
        epilog="Example: tunnelsim adjust mls_cp.csv total_station.csv --model 7 "
               "--report adjust.md --json helmert.json")
    p.add_argument("source", help="control points in the source system (CSV)")
    p.add_argument("target", help="control points in the target system (CSV)")
    p.add_argument("--model", choices=["7", "6", "9"], default="7",
                   help="7 similarity (default), 6 rigid, 9 scale per axis")
    p.add_argument("--report", help="write the Markdown report here")
    p.add_argument("--json", help="write the result (parameters and statistics) here")
    p.add_argument("--quiet", action="store_true", help="do not print the report")
    p.set_defaults(func=_cmd_adjust)

    p = sub.add_parser(
        "transform", help="apply a Helmert transform to a point cloud",
        description="Apply the Helmert transform of 'tunnelsim adjust --json' to a LAS/LAZ "
                    "or binary PLY cloud, chunk by chunk, keeping every other field.",
        epilog="Example: tunnelsim transform --helmert helmert.json mls.laz -o mls_utm.laz")
    p.add_argument("cloud", help="input cloud (.las, .laz, .ply)")
    p.add_argument("--helmert", required=True, help="Helmert JSON from 'tunnelsim adjust'")
    p.add_argument("-o", "--output", required=True, help="output cloud (same kind)")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=_cmd_transform)

    p = sub.add_parser(
        "correct", help="correct the drift of an MLS run with control points",
        description="Correct a drifting MLS run (trajectory and cloud with GPS time) with "
                    "control points: world coordinates (--control, id,x,y,z[,sigma]) and "
                    "their MLS-frame coordinates with observation time (--observed, "
                    "id,x,y,z,time). Writes the corrected cloud, the corrected trajectory "
                    "(_trajectory.txt), a report (_report.md) and a plot of the correction.",
        epilog="Example: tunnelsim correct --trajectory slam.txt --cloud mls.laz --control "
               "cp.csv --observed cp_mls.csv -o corrected.laz")
    p.add_argument("--trajectory", required=True, help="MLS trajectory (TUM or CSV)")
    p.add_argument("--cloud", required=True, help="MLS cloud with GPS time (.las/.laz/.ply)")
    p.add_argument("--control", required=True, help="control points, world coordinates (CSV)")
    p.add_argument("--observed", required=True,
                   help="the same points in the MLS frame with their time (CSV)")
    p.add_argument("--model", choices=["piecewise", "global"], default="piecewise",
                   help="piecewise rigid per control section (default) or one similarity")
    p.add_argument("-o", "--output", required=True, help="corrected cloud")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=_cmd_correct)

    p = sub.add_parser(
        "preprocess", help="voxel-grid downsampling and outlier removal of a cloud",
        description="Stream a cloud (LAS/LAZ/PLY/XYZ/NPZ/E57) through a voxel grid "
                    "(centroid per voxel, Open3D semantics), then remove statistical and "
                    "radius outliers (Open3D semantics) and write LAS/LAZ with the number "
                    "of points per voxel.",
        epilog="Example: tunnelsim preprocess mls.laz -o clean.laz --voxel 0.02 --sor 8,2.0")
    p.add_argument("cloud", help="input cloud")
    p.add_argument("-o", "--output", required=True, help="output cloud (.las/.laz)")
    p.add_argument("--voxel", type=float, metavar="M", help="voxel size in metres")
    p.add_argument("--sor", metavar="K,STD_RATIO",
                   help="statistical outlier removal: K neighbours (the point included), "
                        "threshold mean + STD_RATIO x std")
    p.add_argument("--ror", metavar="N,RADIUS_M",
                   help="radius outlier removal: at least N other points within RADIUS_M")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=_cmd_preprocess)

    p = sub.add_parser(
        "mesh", help="reconstruct a tunnel mesh from a cleaned cloud",
        description="Tunnel-aware reconstruction: unroll the lining around the centreline "
                    "(estimated, or from a tunnel JSON), take a median radius per cell, "
                    "fill gaps (vertex property support = 0), triangulate; open portals.",
        epilog="Example: tunnelsim mesh clean.laz -o tunnel.ply --cell 0.1,2")
    p.add_argument("cloud", help="input cloud (.las/.laz/.ply/.xyz/.npz/.e57)")
    p.add_argument("-o", "--output", required=True, help="output mesh (.ply)")
    p.add_argument("--cell", default="0.1,2", metavar="M,DEG",
                   help="cell size along the axis (m) and around it (deg), default 0.1,2")
    p.add_argument("--min-points", type=int, default=3,
                   help="cells with fewer points are interpolated (default 3)")
    p.add_argument("--tunnel-json", help="use the alignment of a generated tunnel's JSON")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(func=_cmd_mesh)

    p = sub.add_parser("sensors", help="list the sensor models",
                       description="List the shipped sensor models with kind and source "
                                   "file.", epilog="Example: tunnelsim sensors")
    p.set_defaults(func=_cmd_sensors)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    debug = "--debug" in argv
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return EXIT_USAGE
        return int(args.func(args) or 0)
    except (TunnelsimError, _UsageError) as exc:
        if debug:
            raise
        print(f"tunnelsim: error: {exc}" if isinstance(exc, TunnelsimError) else str(exc),
              file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        if debug:
            raise
        print("tunnelsim: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
