"""Commands that simulate scanners: scan (TLS station), drive (moving platform)."""

from __future__ import annotations

import sys

import numpy as np

from ..cli import TunnelsimCLIError, _xyz


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
    run = simulate_station(scene, spec, _xyz(args.at, "--at"),
                           attitude=Rotation.from_euler("z", args.heading_deg, degrees=True),
                           resolution=args.resolution,
                           step_rad=None if args.step_deg is None else np.deg2rad(args.step_deg),
                           settings=_settings(args), seed=args.seed,
                           reflectivity=refl if refl is not None else args.reflectivity)
    return _finish_run(args, run, f"{spec.name} {run.scan.resolution or 'custom step'}")


def cmd_drive(args) -> int:
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
        from ..tunnel_io import TunnelFileError, sidecar
        from ..alignment import Alignment
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
