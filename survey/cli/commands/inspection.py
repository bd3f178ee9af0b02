"""Monitoring commands (issue 17): develop (developed views of the deviation from
design, an epoch difference or the intensity) and clearance (an envelope swept along
the alignment)."""

from __future__ import annotations

from survey.cli.common import CommandSet, floats, pair, report_options, say
from survey.errors import TunnelsimCLIError

#: --field choices of develop (an M3C2 output's ``distance``, a scan's ``intensity``);
#: the library's ``survey.workflows.inspection.FIELD_CHOICES``, written out here so
#: that building the parser does not load the library.
FIELD_CHOICES = ("deviation", "distance", "intensity")


def _frame_options(c) -> None:
    """Input, tunnel, design, grid and output options shared by develop and clearance."""
    c.option("input", path="in",
             help="cloud (.las/.laz/.ply/.npz/.csv/.txt/.xyz) or mesh (.ply with faces, "
                  ".obj/.stl/.off)")
    c.option("--tunnel-json", path="in",
             help="the alignment that gives chainage and the section frame: a tunnel "
                  "JSON ('tunnelsim tunnel' or 'tunnelsim axis'), a LandXML alignment "
                  "(.xml/.landxml) or a chainage,E,N,H CSV (default: the .json beside a "
                  "tunnel .ply)")
    c.option("--design", path="in",
             help="design profile file (CSV/TXT of y,z in the section frame) for the arc "
                  "length (and the deviation); default: the tunnel JSON's profile")
    c.option("--design-order", choices=["file", "angle"], default="file",
             help="vertex order of --design: as in the file, or sorted by angle")
    c.option("--design-shift", metavar="DY,DZ",
             help="move --design by DY,DZ metres into the section frame")
    c.option("--cell", type=float, metavar="M",
             help="raster cell along the chainage, m (default: 0.05, or the station "
                  "spacing of a profile cloud, found from the first points read; printed "
                  "and written to the JSON)")
    c.option("--cell-arc", type=float, metavar="M",
             help="raster cell along the arc, m (default --cell, or 0.05 when --cell is "
                  "chosen from the data; shortened to divide a closed profile exactly)")
    c.option("--from", dest="chainage_from", type=float, metavar="M",
             help="first chainage (default: the alignment's start)")
    c.option("--to", dest="chainage_to", type=float, metavar="M",
             help="last chainage (default: the alignment's end)")
    c.option("--tile-m", type=float, metavar="M",
             help="one PNG + NPY + JSON per tile of M metres of chainage (at whole "
                  "multiples of M), for long tunnels")
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    report_options(c)


def register(commands: CommandSet) -> None:
    """Add develop and clearance."""
    c = commands.add(
        "develop", cmd_develop,
        help="developed (unrolled) view: deviation, epoch difference or intensity over "
             "chainage x arc length",
        description="Unroll a cloud (streamed chunk by chunk) or a mesh (area samples) "
                    "along the tunnel's alignment: a raster over chainage x arc length "
                    "along the design profile, measured from the crown, positive to the "
                    "left. --field deviation: signed distance to the design (> 0 "
                    "overbreak); distance: a per-point field such as the output of "
                    "'tunnelsim m3c2'; intensity. Writes developed_<field>_<from>_<to>.png "
                    "(colour bar; hatched = no data), .npy (float32, NaN = no data) and "
                    ".json (the grid: origins, cells, units, arc zero, alignment, CRS) per "
                    "tile, and developed.md.",
        epilog="Example: tunnelsim develop scan.laz --tunnel-json t.json --cell 0.05 "
               "--tile-m 100 -o dev/")
    _frame_options(c)
    c.option("--field", choices=list(FIELD_CHOICES), default="deviation",
             help="what to show (default deviation)")
    c.option("--stat", choices=["mean", "min", "max", "count"], default="mean",
             help="per-cell statistic written and drawn (default mean)")
    c.option("--max-deviation", type=float, metavar="M",
             help="leave out points farther than M from the design line (fittings, "
                  "people, the platform)")
    c.option("--limit-mm", type=float, metavar="MM",
             help="colour-bar limit +-MM for deviations and distances (default: the 98th "
                  "percentile of |value| over the cells with data, the same on every "
                  "tile; printed and written to each JSON as colour_scale)")
    c.option("--tolerance", metavar="MM[,MM...]",
             help="colour deviations and distances in tolerance classes with these "
                  "increasing edges in mm (e.g. -20,0,50,100,200) instead of a "
                  "continuous bar")

    c = commands.add(
        "clearance", cmd_clearance,
        help="clearance: an envelope swept along the alignment, every violation",
        description="Sweep a gauge/envelope polygon (CSV/TXT of y,z in the section "
                    "frame, or box:WIDTH,HEIGHT[,BOTTOM]) along the alignment and find "
                    "every point of the lining (a cloud, streamed, or a mesh's area "
                    "samples) inside it: violations.csv (per raster cell its deepest "
                    "point: chainage, offset, height, arc position, depth), regions.csv "
                    "(touching cells grouped), clearance.md, clearance.json and the "
                    "developed view of the margin with the regions drawn "
                    "(clearance_margin_<from>_<to>.png/.npy/.json).",
        epilog="Example: tunnelsim clearance scan.laz --tunnel-json t.json --envelope "
               "gauge.csv -o clr/")
    _frame_options(c)
    c.option("--envelope", required=True, metavar="FILE|box:W,H[,B]",
             help="envelope polygon: a CSV/TXT file of y,z (closed) or box:WIDTH,HEIGHT"
                  "[,BOTTOM] in m")
    c.option("--required", type=float, default=0.0, metavar="M",
             help="free space required beyond the envelope, m (default 0)")
    c.option("--merge-gap", default="auto", metavar="M|auto",
             help="violating cells at most M metres apart (cells without a violation "
                  "between them, along each axis) form one region; 0: touching cells "
                  "only (default auto: 2 x the data's spacing along the chainage, the "
                  "station spacing of a profile cloud; printed)")


def _frame_values(args) -> dict:
    """The keywords of the frame options (``_frame_options``) for the workflows, the
    syntax of --design-shift checked here."""
    shift = pair(args.design_shift, "--design-shift as DY,DZ in metres") \
        if args.design is not None and args.design_shift else (0.0, 0.0)
    return dict(tunnel=args.tunnel_json, design=args.design,
                design_order=args.design_order, design_shift_m=shift, cell_m=args.cell,
                cell_arc_m=args.cell_arc, chainage_from_m=args.chainage_from,
                chainage_to_m=args.chainage_to, tile_m=args.tile_m, force=args.force,
                project=args.project, instrument=args.instrument)


def cmd_develop(args) -> int:
    from survey.workflows.inspection import develop_files

    tol = None if args.tolerance is None else floats(args.tolerance, "--tolerance")
    r = develop_files(args.input, args.output, field=args.field, stat=args.stat,
                      max_deviation_m=args.max_deviation, limit_mm=args.limit_mm,
                      tolerance_mm=tol, **_frame_values(args))
    n = len(r.figures)
    say(args, f"developed {r.field} ({r.stat}): {r.points:,} points in "
              f"{r.rows} x {r.columns} cells, {100 * r.share_with_data:.0f} % "
              f"with data, {n} tile{'s' if n != 1 else ''} -> {r.output_dir}/")
    say(args, r.cell_chosen)
    if r.scale_line is not None:
        say(args, r.scale_line)
    return 0


def cmd_clearance(args) -> int:
    from survey.workflows.inspection import clearance_files

    gap: float | str = "auto"
    if args.merge_gap != "auto":
        try:
            gap = float(args.merge_gap)
        except ValueError:
            gap = float("nan")
        if not gap >= 0:
            raise TunnelsimCLIError(f"Expected --merge-gap auto or a gap >= 0 m, got "
                                    f"{args.merge_gap!r}.")
    r = clearance_files(args.input, args.output, envelope=args.envelope,
                        required_m=args.required, merge_gap_m=gap, **_frame_values(args))
    if r.regions:
        say(args, f"clearance against '{r.envelope_name}': {r.regions} violation "
                  f"region{'s' if r.regions != 1 else ''}, deepest "
                  f"{1000 * r.max_depth_m:.1f} mm at chainage "
                  f"{r.deepest_chainage_m:.3f} m -> {r.output_dir}/")
        say(args, r.cell_chosen)
        say(args, r.merge_line)
    else:
        say(args, f"clearance against '{r.envelope_name}': clear, smallest margin "
                  f"{1000 * r.min_margin_m:.1f} mm -> {r.output_dir}/")
    return 0


__all__ = ["FIELD_CHOICES", "cmd_clearance", "cmd_develop", "register"]
