"""Monitoring commands (issue 17): m3c2 (distances between epochs with LoD95) and
convergence (chords between control points, radial change per section)."""

from __future__ import annotations

from survey.cli.common import (
    CommandSet,
    cluster_options,
    floats,
    header_values,
    open_cluster,
    report_options,
    say,
)
from survey.errors import TunnelsimCLIError


def register(commands: CommandSet) -> None:
    """Add m3c2 and convergence."""
    c = commands.add(
        "m3c2", cmd_m3c2,
        help="M3C2 distances between two epochs, with LoD95 and significance",
        description="M3C2 (Lague et al. 2013) with py4dgeo's parameters: normals from "
                    "epoch 1 at the --normal-radii (highest planarity wins), a cylinder "
                    "of --cyl-radius and half-length --max-depth along each normal, "
                    "distance = mean (or --robust: median) of epoch 2 minus epoch 1, "
                    "LoD95 = 1.96 (sqrt(s1²/n1 + s2²/n2) + --reg-error). Writes the core "
                    "points with the fields distance, lod, significant, spread1/2, n1/2, "
                    "nx/ny/nz (.las/.laz), and _report.md, .json, .png beside it. Epochs "
                    "stating different CRSs, or lying apart, are refused.",
        epilog="Example: tunnelsim m3c2 e1.laz e2.laz --core-spacing 0.5 --cyl-radius 0.1 "
               "--max-depth 0.2 --normal-radii 0.1,0.2 --orient axis --tunnel t.json "
               "-o m3c2.laz (epochs larger than memory, on 4 local workers: add "
               "--tile-m 10 --workers 4)")
    c.option("epoch1", path="in", help="earlier epoch (cloud)")
    c.option("epoch2", path="in", help="later epoch (cloud)")
    c.option("-o", "--output", required=True, path="out",
             help="core points with the M3C2 fields (.las/.laz)")
    g = c.exclusive()
    c.option("--core", path="in", group=g,
             help="core points (a cloud; LAS/LAZ fields are kept); default: epoch 1")
    c.option("--core-spacing", type=float, metavar="M", group=g,
             help="core points: epoch 1 subsampled to one point per M-metre cell")
    c.option("--cyl-radius", type=float, required=True, metavar="M",
             help="projection cylinder radius in m (py4dgeo cyl_radius; half "
                  "CloudCompare's projection scale)")
    c.option("--max-depth", type=float, required=True, metavar="M",
             help="cylinder half-length along the normal in m (py4dgeo max_distance)")
    c.option("--normal-radii", metavar="M[,M...]",
             help="normal radii in m (py4dgeo normal_radii; half CloudCompare's normal "
                  "scales); default: 2x the cylinder radius")
    c.option("--reg-error", type=float, default=0.0, metavar="M",
             help="registration error in m, added to the LoD95 (default 0)")
    c.option("--robust", action="store_true", help="median and IQR instead of mean and std")
    c.option("--orient", default="z", metavar="z|axis|X,Y,Z",
             help="normal orientation: +Z (default, py4dgeo's), towards the tunnel axis "
                  "(needs --tunnel; positive distance = convergence), or a vector")
    c.option("--tunnel", path="in",
             help="alignment for --orient axis: a tunnel JSON ('tunnelsim tunnel' or "
                  "'tunnelsim axis'; the axis through the profile centre), a LandXML "
                  "(.xml/.landxml) or a chainage,E,N,H CSV (the alignment is the axis)")
    c.option("--allow-crs-mismatch", action="store_true",
             help="compare epochs that state different CRSs (refused by default)")
    c.option("--tile-m", type=float, metavar="M",
             help="run in square tiles of M metres in x, y with a halo, each a task (on "
                  "--workers or --scheduler): memory set by the tile, not by the epochs; "
                  "the same results; epochs as clouds, spilled into tiles beside -o")
    cluster_options(c, needs=("tile-m",))
    report_options(c)

    c = commands.add(
        "convergence", cmd_convergence,
        help="convergence between epochs: chords between points, radial change by angle",
        description="Chord lengths between named points of each section in two epochs "
                    "(--control1/--control2: tunnel JSONs with control points, or "
                    "control-point CSVs) and, with two clouds, the radial change by angle "
                    "about the section centre at --at chainages (or --every M), in the "
                    "alignment frame of --tunnel. Positive = convergence. Writes "
                    "convergence.md, convergence.json, chords.csv, radial.csv and "
                    "radial.png into the output folder.",
        epilog="Example: tunnelsim convergence e1.laz e2.laz --tunnel t.json --control1 "
               "t.json --control2 t2.json --every 10 -o conv/")
    c.option("epochs", nargs="*", metavar="EPOCH", path="in",
             help="two clouds (earlier, later) for the radial change; none for chords only")
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--tunnel", required=True, path="in",
             help="the alignment and the profile's centre: a tunnel JSON ('tunnelsim "
                  "tunnel' or 'tunnelsim axis'), a LandXML (.xml/.landxml) or a "
                  "chainage,E,N,H CSV (no profile: the alignment is the centre)")
    c.option("--control1", path="in", help="points of epoch 1 (tunnel JSON or CSV)")
    c.option("--control2", path="in", help="points of epoch 2 (tunnel JSON or CSV)")
    c.option("--sigma-mm", type=float, metavar="MM",
             help="point precision per coordinate (mm): chords get LoD95 = 3.92 sigma")
    g = c.exclusive()
    c.option("--at", metavar="S[,S...]", group=g, help="section chainages in m")
    c.option("--every", type=float, metavar="M", group=g, help="a section every M metres")
    c.option("--band", type=float, default=0.25, metavar="M",
             help="half-width of a section along the axis in m (default 0.25)")
    c.option("--angle-step", type=float, default=5.0, metavar="DEG",
             help="angular bin in degrees (default 5)")
    c.option("--allow-crs-mismatch", action="store_true",
             help="compare epochs that state different CRSs (refused by default)")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    report_options(c)


# ---------------------------------------------------------------------------- m3c2
def cmd_m3c2(args) -> int:
    """m3c2: ``survey.workflows.epochs.m3c2_to_file``, then the summary line."""
    from survey.cli.common import Progress
    from survey.workflows.epochs import m3c2_to_file

    if args.tile_m is None and (args.workers is not None or args.scheduler):
        raise TunnelsimCLIError("Expected --tile-m with --workers or --scheduler (M3C2 "
                                "runs on a cluster tile by tile), got no --tile-m.")
    radii = floats(args.normal_radii, "--normal-radii") if args.normal_radii else None

    def cluster():
        ex = open_cluster(args)
        where = "in this process" if ex.kind == "in-process" else f"on the {ex.kind}"
        say(args, f"M3C2 in tiles of {args.tile_m:g} m {where}...")
        return ex

    bar = Progress(args.quiet, "tiles", style="count")
    try:
        r = m3c2_to_file(
            args.epoch1, args.epoch2, args.output, cyl_radius_m=args.cyl_radius,
            max_depth_m=args.max_depth, normal_radii_m=radii,
            reg_error_m=args.reg_error, robust=args.robust, core=args.core,
            core_spacing_m=args.core_spacing, orientation=args.orient,
            tunnel=args.tunnel, allow_crs_mismatch=args.allow_crs_mismatch,
            tile_m=args.tile_m, executor=cluster, progress=bar,
            on_read=lambda n1, n2: say(args, f"M3C2 on {n1:,} and {n2:,} points..."),
            **header_values(args))
    finally:
        if bar.calls:
            bar.close()
    s, out = r.summary, r.output
    say(args, f"M3C2: {s['with_distance']:,} of {s['core_points']:,} core points, "
              f"median {1000 * s['median_m']:.2f} mm, {s['significant']:,} "
              f"significant (median LoD95 {1000 * s['median_lod_m']:.2f} mm) -> "
              f"{out.name}, {out.stem}_report.md, {out.stem}.json, {out.stem}.png")
    return 0


# ---------------------------------------------------------------------------- convergence
def cmd_convergence(args) -> int:
    """convergence: ``survey.workflows.epochs.convergence_files``, then the report."""
    from survey.workflows.epochs import convergence_files

    r = convergence_files(
        args.output, args.tunnel, epochs=args.epochs, control1=args.control1,
        control2=args.control2,
        sigma_m=None if args.sigma_mm is None else args.sigma_mm / 1000.0,
        at_m=args.at, every_m=args.every, band_m=args.band,
        angle_step_deg=args.angle_step, allow_crs_mismatch=args.allow_crs_mismatch,
        force=args.force, **header_values(args))
    said = ", ".join(p.name for p in r.files)
    say(args, r.markdown.rstrip() + f"\n-> {r.output_dir}/ ({said})")
    return 0


__all__ = ["cmd_convergence", "cmd_m3c2", "register"]
