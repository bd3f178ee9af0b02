"""Commands that simulate scanners: scan (TLS station), drive (moving platform)."""

from __future__ import annotations

import sys

import numpy as np

from survey.errors import TunnelsimCLIError
from survey.cli.main import _parse_window, _xyz


class Progress:
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


def _finish_run(args, run, label):
    from raytrace import set_threads

    if args.threads:
        set_threads(args.threads)
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
    from scipy.spatial.transform import Rotation

    from sensors import load_sensor, simulate_station
    from sensors.meshes import load_mesh

    spec = load_sensor(args.sensor)
    scene, refl = load_mesh(args.mesh)
    if args.chainage is not None:
        at = _station_on_axis(args, scene)
    else:
        at = _xyz(args.at, "--at")
    run = simulate_station(scene, spec, at,
                           attitude=Rotation.from_euler("z", args.heading_deg, degrees=True),
                           resolution=args.resolution,
                           step_rad=None if args.step_deg is None else np.deg2rad(args.step_deg),
                           settings=_settings(args), seed=args.seed,
                           reflectivity=refl if refl is not None else args.reflectivity)
    return _finish_run(args, run, f"{spec.name} {run.scan.resolution or 'custom step'}")


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


def cmd_drive(args) -> int:
    from sensors import Mount, Trajectory, load_sensor, simulate_drive
    from sensors.meshes import load_mesh

    spec = load_sensor(args.sensor)
    if args.rate is not None:
        from sensors.spec import with_rate

        spec = with_rate(spec, args.rate)
    scene, refl = load_mesh(args.mesh)
    if args.trajectory:
        traj = Trajectory.read(args.trajectory)
    else:
        if args.along != "centreline" or args.speed is None:
            raise TunnelsimCLIError("Expected --trajectory FILE, or --along centreline with "
                                    "--speed V, got neither.")
        from survey.errors import TunnelFileError
        from survey.world.mesh import sidecar
        from survey.world.alignment import Alignment
        import json

        js = sidecar(args.mesh)
        if not js.is_file():
            raise TunnelFileError(f"Expected the tunnel metadata '{js}' for --along "
                                  "centreline (made by 'tunnelsim tunnel'), got none; pass "
                                  "--trajectory instead.")
        meta = json.loads(js.read_text())
        al = Alignment.from_dict(meta["alignment"])
        c0, c1 = al.chainage_range
        a, b = c0 + args.margin, c1 - args.margin
        if args.chainage:
            a, b = _parse_window(args.chainage.replace(",", ":"),
                                 "--chainage as START,END in m", 2)
            if not (c0 <= a < b <= c1):
                raise TunnelsimCLIError(f"Expected --chainage within [{c0:g}, {c1:g}] m with "
                                        f"START < END, got {args.chainage!r}.")
        s = np.append(np.arange(a, b, 0.5), b)
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
    if args.slam_drift:
        if not args.along:
            raise TunnelsimCLIError("Expected --along centreline with --slam-drift (the "
                                    "control points come from the tunnel's JSON), got a "
                                    "trajectory file.")
        run = _slam_run(args, run, traj, meta)
    return _finish_run(args, run, f"{spec.name} drive {run.duration_s:.1f} s")


#: Prism centres picked from an MLS cloud, per axis (m): ASSUMED, typical of fitting a
#: sphere/prism target in a dense profiler cloud.
PRISM_SIGMA_MLS_M = 0.003
#: Total-station control points, per axis (m): ASSUMED (a monitoring network).
CONTROL_SIGMA_M = 0.0015


class _MappedRun:
    """A Run whose point chunks pass through ``fn`` (e.g. into a SLAM map frame)."""

    def __init__(self, run, fn):
        self._run, self._fn = run, fn

    def __getattr__(self, name):
        return getattr(self._run, name)

    def __iter__(self):
        for pts in self._run:
            yield self._fn(pts)


def _slam_run(args, run, traj, meta):
    """Drifting SLAM: the cloud in the SLAM map frame, plus the SLAM and true
    trajectories and the control points (world, and observed in the MLS frame)."""
    from pathlib import Path

    from survey.adjust.controlpoints import ControlPoints
    from survey.adjust.slam import slam_trajectory, to_slam_frame

    slam = slam_trajectory(traj, seed=args.seed + 1)
    out = Path(args.output)
    stem = out.with_name(out.stem)
    slam.write(f"{stem}_trajectory.txt")
    traj.write(f"{stem}_true_trajectory.txt")
    cps = meta.get("control_points", [])
    g = np.array([c["xyz"] for c in cps]).reshape(-1, 3)
    ids = [c["id"] for c in cps]
    # Observation time: when the platform is nearest to the point.
    t = traj.times
    near = np.argmin(np.linalg.norm(traj.positions[None, :, :2] - g[:, None, :2], axis=2),
                     axis=1) if len(g) else np.zeros(0, dtype=int)
    tau = t[near]
    inside = (tau > t[0]) & (tau < t[-1])
    rng = np.random.default_rng(args.seed + 2)
    m = to_slam_frame(traj, slam, g[inside], tau[inside]) + \
        rng.normal(0, PRISM_SIGMA_MLS_M, (int(inside.sum()), 3))
    sel = [i for i, k in zip(ids, inside) if k]
    ControlPoints(sel, m, time=tau[inside]).write(f"{stem}_cp_observed.csv")
    gw = g + rng.normal(0, CONTROL_SIGMA_M, g.shape)
    ControlPoints(ids, gw, sigma=np.full(g.shape, CONTROL_SIGMA_M)).write(
        f"{stem}_cp_world.csv")

    def to_map(pts):
        if len(pts):
            xyz = to_slam_frame(traj, slam, np.stack([pts["x"], pts["y"], pts["z"]], 1),
                                pts["time"])
            pts = pts.copy()
            pts["x"], pts["y"], pts["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        return pts

    if not args.quiet:
        print(f"SLAM drift: {len(sel)} control points observed; wrote {stem.name}_trajectory"
              f".txt, {stem.name}_true_trajectory.txt, {stem.name}_cp_observed.csv, "
              f"{stem.name}_cp_world.csv")
    return _MappedRun(run, to_map)
