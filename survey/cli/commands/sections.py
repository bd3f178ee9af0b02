"""Monitoring commands (issue 17): sections (as-built against design) and rings."""

from __future__ import annotations

from survey.cli.commands.axis import datum_options, datum_values
from survey.cli.common import (CommandSet, floats, header_values, pair, report_options,
                               say)

def _cut_options(c) -> None:
    """Input, axis, chainages and band options shared by sections and rings."""
    c.option("input", path="in",
             help="cloud (.las/.laz/.ply/.xyz/.txt/.csv/.npz/.e57) or mesh (.ply with "
                  "faces, .obj/.stl/.off)")
    c.option("--tunnel-json", path="in",
             help="the alignment that gives chainage and the section frame: a tunnel "
                  "JSON ('tunnelsim tunnel' or 'tunnelsim axis'), a LandXML alignment "
                  "(.xml/.landxml) or a chainage,E,N,H CSV (default: the .json beside a "
                  "tunnel .ply)")
    c.option("--fit-axis", action="store_true",
             help="fit the axis to the input instead (chainage as --start/--chainage-at/"
                  "--reverse set it, as 'tunnelsim axis' does; the section frame is "
                  "centred on the profile centre)")
    datum_options(c, with_alignment=False)
    c.option("--every", type=float, metavar="M",
             help="a section every M metres of chainage (at whole multiples of M)")
    c.option("--at", metavar="C[,C...]", help="sections at these chainages (m)")
    c.option("--width", type=float, default=0.05, metavar="M",
             help="half-width of each band along the axis, m (default 0.05; a mesh is "
                  "cut by the plane itself)")
    c.option("--max-points", type=int, default=1_000_000, metavar="N",
             help="most points kept per section (a random subset beyond; default 1e6)")
    c.option("--classes", metavar="C[,C...]",
             help="keep only points of these classification codes (a LAS "
                  "classification, e.g. from 'tunnelsim preprocess --segment': lining 64, "
                  "floor 2; so lamps (65), cables and people (66) do not count as "
                  "underbreak)")
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    report_options(c)


def register(commands: CommandSet) -> None:
    """Add sections and rings."""
    c = commands.add(
        "sections", cmd_sections, seeded=True,
        help="cross-sections against the design: over-/under-break, areas, volumes",
        description="Cut a cloud (streamed chunk by chunk) or a mesh into cross-sections "
                    "at chainages of the tunnel's alignment, compare each with the design "
                    "profile (the tunnel JSON's, or a polyline file of y,z vertices in the "
                    "section frame: offset left, height above the alignment) and write an "
                    "as-built report: sections.csv (max/min/mean deviation, over- and "
                    "underbreak areas, tolerance classes), volumes.csv (average end areas), "
                    "contours.csv (the as-built line), report.md, report.json and one "
                    "section_<km>+<m>.png per chainage.",
        epilog="Example: tunnelsim sections scan.laz --tunnel-json bfo.json --every 5 "
               "-o sections/")
    _cut_options(c)
    c.option("--design", path="in",
             help="design profile file (CSV/TXT of y,z in the section frame; default: "
                  "the tunnel JSON's profile)")
    c.option("--design-order", choices=["file", "angle"], default="file",
             help="vertex order of --design: as in the file, or sorted by angle about "
                  "their centroid (digitised points saved sorted by x)")
    c.option("--design-shift", metavar="DY,DZ",
             help="move --design by DY,DZ metres into the section frame (a profile in "
                  "drawing coordinates)")
    c.option("--design-closed", choices=["auto", "yes", "no"], default="auto",
             help="whether --design is a closed profile (auto: see the docs)")
    c.option("--bin", type=float, default=0.05, metavar="M",
             help="bin length along the design for the as-built line, m (default 0.05)")
    c.option("--tolerance", metavar="MM[,MM...]",
             help="deviation class edges in mm (default -20,0,50,100,200)")
    c.option("--no-plots", action="store_true", help="write no section PNGs")

    c = commands.add(
        "rings", cmd_rings, seeded=True,
        help="best-fit circle and ellipse per section: diameters, ovality, centre offset",
        description="Cut a cloud or a mesh into cross-sections as 'sections' does and fit "
                    "a circle and an ellipse to each (algebraic start, then orthogonal-"
                    "distance Gauss-Newton/LM; outliers beyond 3 robust sigma dropped): "
                    "rings.csv, rings.md, rings.json and rings.png (diameters, ovality, "
                    "centre offset from the design centre along the chainage).",
        epilog="Example: tunnelsim rings tbm_scan.laz --tunnel-json tbm.json --every 1.5 "
               "--width 0.02 -o rings/")
    _cut_options(c)
    c.option("--nominal-diameter", type=float, metavar="M",
             help="nominal diameter for the ovality (default: the mean of the fitted "
                  "axes)")
    c.option("--min-height", type=float, metavar="M",
             help="use only points at least M above the floor (leave out the invert, "
                  "track bed or walkway); the floor: --rail-height, else the alignment "
                  "of --tunnel-json (height 0 of its section frame), else with "
                  "--fit-axis each section's lowest points (its 1st percentile of "
                  "heights), as a fitted axis runs through the profile's centre")
    c.option("--rail-height", type=float, metavar="M",
             help="height of the rail or floor in the section frame (m, negative below "
                  "the alignment or fitted axis) that --min-height is measured from")


def _cut_values(args) -> dict:
    """The keywords sections and rings share, from the options of ``_cut_options``."""
    return {"tunnel_json": args.tunnel_json, "fit_axis": args.fit_axis,
            **datum_values(args), "every_m": args.every,
            "at_m": floats(args.at, "--at") if args.at is not None else None,
            "width_m": args.width, "max_points": args.max_points,
            "classes": floats(args.classes, "--classes") if args.classes is not None
            else None, "force": args.force, "seed": args.seed, **header_values(args)}


def cmd_sections(args) -> int:
    from survey.workflows.sections import sections_files

    edges = None if args.tolerance is None else \
        tuple(v / 1000.0 for v in floats(args.tolerance, "--tolerance"))
    shift = pair(args.design_shift, "--design-shift as DY,DZ in metres") \
        if args.design_shift else None
    r = sections_files(args.input, args.output, design=args.design,
                       design_order=args.design_order, design_shift_m=shift,
                       design_closed={"auto": None, "yes": True, "no": False}[
                           args.design_closed],
                       bin_m=args.bin, tolerance_edges_m=edges, plots=not args.no_plots,
                       **_cut_values(args))
    say(args, f"{r.sections} sections against '{r.design_name}': overbreak "
              f"{r.overbreak_m3:.3f} m^3, underbreak {r.underbreak_m3:.3f} m^3; largest "
              f"overbreak {1000 * r.largest_overbreak_m:.0f} mm at "
              f"{r.largest_overbreak_chainage_m:g} m -> {r.output}/")
    return 0


def cmd_rings(args) -> int:
    from survey.workflows.sections import rings_files

    r = rings_files(args.input, args.output, nominal_diameter_m=args.nominal_diameter,
                    min_height_m=args.min_height, rail_height_m=args.rail_height,
                    **_cut_values(args))
    if r.floor_heights_m is not None:
        src = "--rail-height" if args.rail_height is not None else \
            ("each section's lowest points (its 1st percentile of heights)"
             if args.fit_axis else "the alignment of --tunnel-json")
        say(args, f"--min-height {args.min_height:g} m above the floor: {src}, at "
                  f"{r.floor_median_m:.3f} m in the section frame (median)")
    say(args, f"{len(r.rings)} rings: diameters {1000 * r.min_diameter_m:.1f} to "
              f"{1000 * r.max_diameter_m:.1f} mm, largest ovality "
              f"{100 * r.max_ovality:.3f} % -> {r.output}/")
    return 0


__all__ = ["cmd_rings", "cmd_sections", "register"]
