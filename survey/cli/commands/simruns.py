"""What the simulating commands share (scan, drive): the --crs and --waveform options,
the physics settings made from the options, the progress bar around a library call,
and the summary line of a written run. The work itself is done by
``survey.workflows.scan`` and ``survey.workflows.drive``."""

from __future__ import annotations


def crs_option(c) -> None:
    c.option("--crs", metavar="CRS",
             help="coordinate reference system of the mesh's coordinates, stated in the "
                  "output (EPSG:n, WKT or PROJJSON; needs pyproj); default: the tunnel "
                  "JSON's 'crs' (or a <mesh>.prj sidecar), else none")


def waveform_option(c) -> None:
    """--waveform (issue 34; help text from ``sensors.waveform``'s author)."""
    c.option("--waveform", nargs="?", const="auto", choices=["auto", "internal", "external"],
             default=None, metavar="{internal,external}",
             help="full-waveform output (survey scanners: zf_imager_5016, "
                  "zf_profiler_9012): each point keeps its pulse's sampled waveform as LAS "
                  "1.4 wave packets (point format 9 in .las, 4 in .laz); the packets go "
                  "into the .las (internal, the default for .las) or into NAME.wdp beside "
                  "the output (external, the default and only choice for .laz); .las/.laz "
                  "outputs only")


def waveform_data(args) -> str | None:
    """Where --waveform puts the wave packets: None (the format's default) or
    "internal" / "external"."""
    w = getattr(args, "waveform", None)
    return None if w in (None, "auto") else w


def run_settings(args):
    """The physics settings (``sensors.Settings``) the options ask for."""
    from dataclasses import replace

    from sensors import Settings

    if args.ideal:
        base = Settings.ideal()
    else:
        base = Settings(range_noise=not args.no_noise, angle_jitter=not args.no_noise,
                        detection=not args.no_detection)
    more = {"waveform": True} if getattr(args, "waveform", None) is not None else {}
    return replace(base, beam_subrays=args.beam_subrays, mixed=args.mixed,
                   attenuation_per_m=args.attenuation, particle_rate_per_m=args.particles,
                   returns=getattr(args, "returns", None), **more)


def with_progress(args, call, **kwargs):
    """``call(**kwargs, progress=bar)`` with a progress bar on stderr (unless
    --quiet), closed whatever happens."""
    from survey.cli.common import Progress

    prog = Progress(args.quiet)
    try:
        return call(**kwargs, progress=prog)
    finally:
        prog.close()


def summary_line(label: str, out, path) -> str:
    """``<label>: N pulses, M points (hit ratio ..), .. s, .. Mrays/s -> <path>``, of a
    ``survey.workflows.simrun.RunOutput``."""
    return (f"{label}: {out.pulses:,} pulses, {out.points:,} points (hit ratio "
            f"{100 * out.hit_ratio:.1f} %), {out.seconds:.1f} s, "
            f"{out.rays_per_s / 1e6:.2f} Mrays/s -> {path}")


__all__ = ["crs_option", "run_settings", "summary_line", "waveform_data", "waveform_option",
           "with_progress"]
