"""Monitoring commands (issue 17): detect, the detectability study (what deformation a
survey detects, and its false alarms, for a sensor x speed / station spacing x noise
grid). ``survey.workflows.detect.detect_study`` does the work; this module parses and
prints."""

from __future__ import annotations

from survey.cli.common import CommandSet, floats, report_options, say
from survey.errors import TunnelsimCLIError

__all__ = ["cmd_detect", "register"]


def register(commands: CommandSet) -> None:
    """Add detect."""
    c = commands.add(
        "detect", cmd_detect, seeded=True,
        help="detectability study: smallest deformation detected, false alarms",
        description="Lay known deformations on a generated tunnel (a radial convergence "
                    "zone and a ring of bulges, at each --magnitudes, beside undeformed "
                    "lining), scan it twice (as built and deformed) with each sensor at "
                    "each station spacing (TLS) or speed (MLS) and noise factor, run M3C2 "
                    "(normals towards the axis) and report the smallest magnitude detected "
                    "at >= 95 % of the deformed region's core points (|d| > LoD95, d > 0), "
                    "its a-hat vs a estimate (MIL-HDBK-1823A), and the false-alarm rate on "
                    "undeformed lining. Writes detect.json, detect.csv, targets.csv, "
                    "detect.md and detect.png.",
        epilog="Example: tunnelsim detect --sensor zf_imager_5016,zf_profiler_9012 "
               "--stations 10,20 --speeds 1,3 --noise 0.5,1,2 --magnitudes 2,5,10 -o det/")
    g = c.exclusive()
    c.option("--mesh", path="in", group=g,
             help="a generated tunnel (.ply with its .json, 'tunnelsim tunnel')")
    c.option("--preset", choices=["bfo", "tbm"], group=g,
             help="generate this preset instead (default tbm)")
    c.option("--edge-length", type=float, metavar="M",
             help="with --preset: lining edge length in m (default 0.1; quick 0.2)")
    c.option("--sensor", default="zf_imager_5016", metavar="NAME[,NAME...]",
             help="sensor names or .toml files (default zf_imager_5016)")
    c.option("--stations", metavar="M[,M...]",
             help="TLS station spacings in m (default 10,20; quick 10)")
    c.option("--speeds", metavar="V[,V...]",
             help="speeds of moving sensors in m/s (default 1,3; quick 3)")
    c.option("--noise", metavar="K[,K...]",
             help="factors on each sensor's range and angle noise (default 0.5,1,2; "
                  "quick 1,30)")
    c.option("--magnitudes", metavar="MM[,MM...]",
             help="deformation magnitudes in mm (default 1,2,5,10; quick 2,5,10)")
    c.option("--start", type=float, metavar="M",
             help="chainage where the layout starts (default: centred in the tunnel)")
    c.option("--zone", type=float, metavar="M",
             help="length of the convergence plateau in m (default 5; quick 2); a TLS "
                  "stands at its start, so half the spacing holds every distance")
    c.option("--bulge-radius", type=float, metavar="M",
             help="bulge radius in m (default 0.5; quick 0.4)")
    c.option("--resolution", help="TLS resolution preset (default middle; quick preview)")
    c.option("--rate", type=float, metavar="HZ",
             help="rotation / profile rate of moving sensors (default: the sensor's)")
    c.option("--height", type=float, metavar="M",
             help="sensor height above the floor (default 1.5 TLS, 1.0 moving)")
    c.option("--core-spacing", type=float, metavar="M",
             help="core points: one per M-metre cube of epoch 1 (default 0.1; quick 0.15)")
    c.option("--cyl-radius", type=float, default=0.1, metavar="M",
             help="M3C2 cylinder radius in m (default 0.1)")
    c.option("--max-depth", type=float, default=0.1, metavar="M",
             help="M3C2 cylinder half-length in m (default 0.1)")
    c.option("--normal-radii", default="0.25", metavar="M[,M...]",
             help="M3C2 normal radii in m (default 0.25)")
    c.option("--reg-error", type=float, default=0.0, metavar="M",
             help="registration error in m added to the LoD95 (default 0: the "
                  "simulated epochs share one frame)")
    c.option("--quick", action="store_true",
             help="a small study (about a minute): the tests' and the demo's")
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    report_options(c)


def _numbers(text: str | None, what: str, scale: float = 1.0) -> list[float] | None:
    """An option's comma-separated numbers divided by ``scale``; None when not given (the
    library's default, ``survey.workflows.detect.FULL`` or ``QUICK``)."""
    return None if text is None else [v / scale for v in floats(text, what)]


def cmd_detect(args) -> int:
    from survey.report.progress import Progress
    from survey.workflows.detect import detect_study

    if args.mesh and args.edge_length is not None:
        raise TunnelsimCLIError("Expected --edge-length only with --preset, got it "
                                "with --mesh (the mesh has its own edges).")
    # Options not given are None: the library's default (FULL or QUICK) then.
    with Progress(args.quiet, unit="configurations", style="count") as bar:
        res = detect_study(
            args.output, mesh=args.mesh, preset=args.preset,
            edge_length_m=args.edge_length, sensors=args.sensor,
            spacings_m=_numbers(args.stations, "--stations"),
            speeds_mps=_numbers(args.speeds, "--speeds"),
            noises=_numbers(args.noise, "--noise"),
            magnitudes_m=_numbers(args.magnitudes, "--magnitudes (mm)", 1000.0),
            start_m=args.start, zone_m=args.zone, bulge_radius_m=args.bulge_radius,
            resolution=args.resolution, rate_hz=args.rate, height_m=args.height,
            core_spacing_m=args.core_spacing, cyl_radius_m=args.cyl_radius,
            max_depth_m=args.max_depth,
            normal_radii_m=floats(args.normal_radii, "--normal-radii"),
            reg_error_m=args.reg_error, quick=args.quick, force=args.force,
            seed=args.seed, project=args.project, instrument=args.instrument,
            progress=bar)
    say(args, res.markdown.rstrip() + f"\n-> {res.folder}/ (detect.json, detect.csv, "
                                      "targets.csv, detect.md, detect.png)")
    return 0
