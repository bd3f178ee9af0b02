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
    from sensors.crs import CRSError, mismatch_message, parse_crs, same_crs
    from survey.clouds.cloudio import cloud_crs_text
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
                crs=None, bag=None) -> int:
    """Write the run and print its summary; refuse (the output removed by
    ``run_command``) a run that returned no point, or fewer than ``min_return`` of its
    pulses (``where`` says what the caller knows: the poses, the mesh's box)."""
    prog = Progress(args.quiet)
    try:
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


def xyz_text(p) -> str:
    """(x, y, z) to the millimetre (a BVH box is padded by ~1e-6 of its size)."""
    return "(" + ", ".join(f"{round(float(c), 3) + 0.0:.10g}" for c in p) + ")"


def box_text(lo, hi) -> str:
    return f"{xyz_text(lo)}-{xyz_text(hi)}"


__all__ = ["box_text", "crs_option", "finish_run", "output_crs", "run_settings",
           "xyz_text"]
