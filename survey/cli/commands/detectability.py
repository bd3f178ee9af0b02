"""Monitoring commands (issue 17): detect, the detectability study (what deformation a
survey detects, and its false alarms, for a sensor x speed / station spacing x noise
grid)."""

from __future__ import annotations

import sys

from survey.cli.common import (CommandSet, floats, out_dir, report_options, say,
                               write_headed_report, write_json, write_text)
from survey.errors import TunnelsimCLIError

__all__ = ["FULL", "QUICK", "cmd_detect", "register"]

#: Defaults of the full study and of --quick (a value given on the command line wins).
#: DECISION: --quick is a tbm-like tube of coarse edges (0.2 m), a compact layout and
#: TLS preview scans: 2 noise factors x 4 epochs of 3 preview stations take about a
#: minute on 2 shared cores, enough for the tests and the demo.
FULL = {"preset": "tbm", "edge_length": 0.1, "resolution": "middle", "zone": 5.0,
        "taper": 0.5, "gap": 1.0, "bulge_radius": 0.5, "reference": 2.0,
        "core_spacing": 0.1, "magnitudes": "1,2,5,10", "stations": "10,20",
        "speeds": "1,3", "noise": "0.5,1,2"}
QUICK = {"preset": "tbm", "edge_length": 0.2, "resolution": "preview", "zone": 2.0,
         "taper": 0.25, "gap": 0.5, "bulge_radius": 0.4, "reference": 1.5,
         "core_spacing": 0.15, "magnitudes": "2,5,10", "stations": "10", "speeds": "3",
         "noise": "1,30"}


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


def _get(args, name: str):
    v = getattr(args, name, None)
    return (QUICK if args.quick else FULL)[name] if v is None else v


def cmd_detect(args) -> int:
    from sensors import load_sensor
    from survey.analysis.detectability import Detectability, DetectLayout
    from survey.analysis.m3c2 import M3C2Params
    from survey.report.detectability import (detect_csv, detect_markdown, detect_summary,
                                             plot_detectability, targets_csv)

    names = [n.strip() for n in args.sensor.split(",") if n.strip()]
    if not names:
        raise TunnelsimCLIError(f"Expected --sensor NAME[,NAME...], got {args.sensor!r}.")
    specs = [load_sensor(n) for n in names]
    mags = [m / 1000.0 for m in floats(_get(args, "magnitudes"), "--magnitudes (mm)")]
    noises = floats(_get(args, "noise"), "--noise")
    spacings = floats(_get(args, "stations"), "--stations") \
        if any(s.kind == "tls" for s in specs) else []
    speeds = floats(_get(args, "speeds"), "--speeds") \
        if any(s.kind != "tls" for s in specs) else []
    if args.mesh:
        if args.edge_length is not None:
            raise TunnelsimCLIError("Expected --edge-length only with --preset, got it "
                                    "with --mesh (the mesh has its own edges).")
        from survey.world.mesh import read_tunnel

        tunnel = read_tunnel(args.mesh)
    else:
        from survey.world.presets import preset

        tunnel, _ = preset(args.preset or _get(args, "preset"),
                           edge_length_m=_get(args, "edge_length"), seed=args.seed)
    kw = dict(zone_m=_get(args, "zone"), taper_m=_get(args, "taper"),
              gap_m=_get(args, "gap"), bulge_radius_m=_get(args, "bulge_radius"),
              reference_m=_get(args, "reference"))
    start = args.start
    if start is None:
        probe = DetectLayout.build(0.0, mags, **kw)
        c0, c1 = tunnel.alignment.chainage_range
        start = round(0.5 * (c0 + c1) - 0.5 * probe.length_m, 2)
    layout = DetectLayout.build(start, mags, **kw)
    prm = M3C2Params(args.cyl_radius, args.max_depth,
                     tuple(floats(args.normal_radii, "--normal-radii")), args.reg_error)
    study = Detectability(tunnel, layout, params=prm,
                          core_spacing_m=_get(args, "core_spacing"), seed=args.seed)
    out = out_dir(args.output, args.force)

    def progress(i, n):
        if not args.quiet and sys.stderr.isatty():
            sys.stderr.write(f"\rdetect: {i}/{n} configurations ")
            sys.stderr.flush()

    rows = study.grid(specs, speeds_mps=speeds, spacings_m=spacings, noises=noises,
                      progress=progress, resolution=_get(args, "resolution"),
                      rate_hz=args.rate, height_m=args.height)
    if not args.quiet and sys.stderr.isatty():
        sys.stderr.write("\n")
    write_json(out / "detect.json", detect_summary(
        study, rows, extra={"quick": bool(args.quick),
                            "resolution": _get(args, "resolution"), "rate_hz": args.rate}))
    write_text(out / "detect.csv", detect_csv(rows))
    write_text(out / "targets.csv", targets_csv(rows))
    md = detect_markdown(study, rows)
    plot_detectability(rows, out / "detect.png")
    write_headed_report(args, out / "detect.md", md,
                        [("mesh", args.mesh, "")] if args.mesh else [],
                        crs_from=[args.mesh] if args.mesh else [],
                        settings=[("sensors", args.sensor),
                                  ("tunnel", "the mesh" if args.mesh
                                   else f"preset {args.preset or _get(args, 'preset')}")])
    say(args, md.rstrip() + f"\n-> {out}/ (detect.json, detect.csv, targets.csv, "
                            "detect.md, detect.png)")
    return 0
