"""Monitoring commands (issue 17): develop (developed views of the deviation from
design, an epoch difference or the intensity) and clearance (an envelope swept along
the alignment)."""

from __future__ import annotations

from pathlib import Path

from survey.cli.common import (CommandSet, floats, out_dir, pair, report_options, say,
                               write_headed_report, write_json, write_text)
from survey.errors import TunnelsimCLIError

#: --field choices of develop (an M3C2 output's ``distance``, a scan's ``intensity``).
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


def _tunnel(args):
    """(Alignment, Profile or None, CRS text or None) from --tunnel-json (a tunnel JSON,
    LandXML or station CSV) or the JSON beside a tunnel PLY."""
    from survey.world.alignment_io import load_tunnel
    from survey.world.mesh import sidecar

    js = args.tunnel_json
    if js is None and Path(args.input).suffix.lower() == ".ply" and \
            sidecar(args.input).is_file():
        js = str(sidecar(args.input))
    if js is None:
        raise TunnelsimCLIError("Expected --tunnel-json T.json (the alignment), got none.")
    t = load_tunnel(js, option="--tunnel-json")
    return t.alignment, t.profile, t.crs


def _design(args, prof):
    from survey.analysis.design import DesignProfile, read_design_profile

    if args.design is not None:
        shift = pair(args.design_shift, "--design-shift as DY,DZ in metres") \
            if args.design_shift else (0.0, 0.0)
        return read_design_profile(args.design, order=args.design_order, shift_m=shift)
    if prof is None:
        raise TunnelsimCLIError("Expected --design FILE (the alignment of --tunnel-json "
                                "has no profile: a LandXML, a station CSV), got none.")
    return DesignProfile.from_profile(prof)


def _setup(args):
    """(alignment, design, chainage range or None, crs) after checking the input."""
    from sensors.io.clouds import cloud_crs_text

    if not Path(args.input).is_file():
        raise TunnelsimCLIError(f"Expected an input cloud or mesh, got '{args.input}' "
                                "which does not exist.")
    for flag, v in (("--cell", args.cell), ("--cell-arc", args.cell_arc),
                    ("--tile-m", args.tile_m)):
        if v is not None and not v > 0:
            raise TunnelsimCLIError(f"Expected {flag} > 0 m, got {v}.")
    if args.tile_m is not None and args.cell is not None:
        # Checked before the (long) pass over the input.
        r = args.tile_m / args.cell
        if abs(r - round(r)) > 1e-6 * max(1.0, r):
            raise TunnelsimCLIError(f"Expected --tile-m a whole multiple of --cell "
                                    f"({args.cell:g} m), got {args.tile_m:g} m.")
    al, prof, crs = _tunnel(args)
    _choose_cell(args, al)
    design = _design(args, prof)
    rng = None
    if args.chainage_from is not None or args.chainage_to is not None:
        lo, hi = al.chainage_range
        rng = (lo if args.chainage_from is None else args.chainage_from,
               hi if args.chainage_to is None else args.chainage_to)
    try:
        crs = cloud_crs_text(args.input) or crs
    except Exception:   # a mesh or a file without a CRS statement: the tunnel's
        pass
    return al, design, rng, crs


def _choose_cell(args, al) -> None:
    """Set args.cell (and args.cell_arc) when --cell is not given, from the station
    spacing of the input (``file_station_spacing``), and args.cell_chosen: a line that
    says what was chosen (printed, and written to the JSON as ``cell_chosen``)."""
    from survey.analysis.developed import (DEFAULT_CELL_M, default_cell,
                                           file_station_spacing)

    if args.cell is not None:
        args.cell_chosen = f"cell {args.cell:g} m along the chainage (--cell)"
        return
    spacing = file_station_spacing(args.input, al)
    args.cell = default_cell(spacing, args.tile_m)
    if args.cell_arc is None:
        args.cell_arc = DEFAULT_CELL_M
    if spacing > 0:
        args.cell_chosen = (f"cell {args.cell:g} m along the chainage: the input is a "
                            f"profile cloud with stations every {spacing:.3f} m (one "
                            f"column per station; set it with --cell)")
    else:
        args.cell_chosen = (f"cell {args.cell:g} m along the chainage (the default for a "
                            f"dense cloud or a mesh; set it with --cell)")


def cmd_develop(args) -> int:
    from survey.analysis.developed import develop_file
    from survey.report.developed import colour_scale, write_developed

    al, design, rng, crs = _setup(args)
    if args.max_deviation is not None and not args.max_deviation > 0:
        raise TunnelsimCLIError(f"Expected --max-deviation > 0 m, got {args.max_deviation}.")
    if args.limit_mm is not None and not args.limit_mm > 0:
        raise TunnelsimCLIError(f"Expected --limit-mm > 0, got {args.limit_mm}.")
    edges = None
    if args.tolerance is not None:
        mm = floats(args.tolerance, "--tolerance")
        if args.limit_mm is not None or args.field == "intensity" or args.stat == "count":
            raise TunnelsimCLIError("Expected --tolerance alone, for deviations or "
                                    "distances, got it with --limit-mm, --field intensity "
                                    "or --stat count; leave one out.")
        if any(b <= a for a, b in zip(mm, mm[1:])):
            raise TunnelsimCLIError(f"Expected --tolerance edges increasing in mm, got "
                                    f"{args.tolerance!r}.")
        edges = [v / 1000.0 for v in mm]
    out = out_dir(args.output, args.force)
    raster = develop_file(args.input, al, design, field=args.field, cell_m=args.cell,
                          cell_arc_m=args.cell_arc, chainage_range=rng,
                          max_deviation_m=args.max_deviation)
    if raster.meta["points"] == 0:
        raise TunnelsimCLIError(f"Expected points of '{args.input}' on the tunnel between "
                                "the chainages asked, got none; check --tunnel-json, "
                                "--from/--to and the input's CRS.")
    raster.meta["cell_chosen"] = args.cell_chosen
    limit = None if args.limit_mm is None else args.limit_mm / 1000.0
    scale = colour_scale(raster, args.stat, limit=limit, edges=edges)
    paths = write_developed(raster, out, tile_m=args.tile_m, stat=args.stat, crs=crs,
                            limit=limit, edges=edges)
    pngs = [p.name for p in paths if p.suffix == ".png"]
    write_headed_report(args, out / "developed.md",
                        _develop_markdown(raster, args, pngs, scale),
                        [("cloud", args.input, ""), ("alignment", args.tunnel_json, ""),
                         *([("design", args.design, "")] if args.design else [])],
                        crs_from=[args.input],
                        settings=[("field", f"{args.field} ({args.stat})"),
                                  ("cell (m)", f"{raster.grid.cell_s_m:g} along the "
                                   f"chainage x {raster.grid.cell_arc_m:g} along the arc")])
    seen = raster.count > 0
    say(args, f"developed {args.field} ({args.stat}): {raster.meta['points']:,} points in "
              f"{raster.grid.n_arc} x {raster.grid.n_s} cells, {100 * seen.mean():.0f} % "
              f"with data, {len(pngs)} tile{'s' if len(pngs) != 1 else ''} -> {out}/")
    say(args, args.cell_chosen)
    if scale is not None:
        say(args, _scale_line(scale))
    return 0


def _scale_line(scale) -> str:
    """The colour scale chosen, in one line (mm)."""
    if scale.edges is not None:
        return (f"colour classes at {', '.join(f'{1000 * e:g}' for e in scale.edges)} mm "
                f"(--tolerance); {100 * scale.beyond_share:.1f} % of the cells lie "
                "beyond them")
    how = "--limit-mm" if scale.source == "given" else \
        f"the {scale.percentile:g}th percentile of |value|; set it with --limit-mm"
    return (f"colour scale +-{1000 * scale.limit:.1f} mm ({how}); "
            f"{100 * scale.beyond_share:.1f} % of the cells lie beyond it")


def _develop_markdown(raster, args, pngs, scale=None) -> str:
    import numpy as np

    g = raster.grid
    v = raster.statistic(args.stat)
    ok = np.isfinite(v)
    arc = raster.meta.get("arc", {})
    lines = [f"# Developed view: {raster.field}", "",
             f"Input: `{Path(args.input).name}`; design **{arc.get('design')}** "
             f"({'closed' if arc.get('design_closed') else 'open'}, "
             f"{arc.get('design_length_m', float('nan')):.3f} m); arc length from the "
             f"{arc.get('zero')}, positive to the left.", "",
             f"Grid: {g.n_s} x {g.n_arc} cells of {g.cell_s_m:g} m (chainage) x "
             f"{g.cell_arc_m:.4g} m (arc), from chainage {g.chainage0_m:g} m; "
             f"{raster.meta['points']:,} points ({raster.meta['left_out']:,} left out: "
             f"beyond the alignment, the design's ends or --max-deviation); "
             f"{100 * (raster.count > 0).mean():.1f} % of the cells hold data.", ""]
    if ok.any():
        lines += [f"{args.stat} {raster.field}: {np.nanmin(v):.4g} to {np.nanmax(v):.4g} "
                  f"{raster.unit if args.stat != 'count' else 'points'}.", ""]
    lines += [f"Raster: {args.cell_chosen}.", ""]
    if scale is not None:
        lines += [f"Colour scale: {_scale_line(scale)}.", ""]
    lines += [f"![{p}]({p})" for p in pngs]
    return "\n".join(lines) + "\n"


def cmd_clearance(args) -> int:
    from survey.analysis.clearance import clearance_file, read_envelope
    from survey.report.developed import (clearance_markdown, merge_line, regions_csv,
                                         violations_csv, write_developed)

    gap: float | str = "auto"
    if args.merge_gap != "auto":
        try:
            gap = float(args.merge_gap)
        except ValueError:
            gap = float("nan")
        if not gap >= 0:
            raise TunnelsimCLIError(f"Expected --merge-gap auto or a gap >= 0 m, got "
                                    f"{args.merge_gap!r}.")
    al, design, rng, crs = _setup(args)
    envelope = read_envelope(args.envelope)
    if not (args.required >= 0):
        raise TunnelsimCLIError(f"Expected --required >= 0 m, got {args.required}.")
    out = out_dir(args.output, args.force)
    res = clearance_file(args.input, al, envelope, design, cell_m=args.cell,
                         cell_arc_m=args.cell_arc, chainage_range=rng,
                         required_m=args.required, merge_gap_m=gap)
    res.meta["cell_chosen"] = args.cell_chosen
    if res.points == 0:
        raise TunnelsimCLIError(f"Expected points of '{args.input}' on the tunnel between "
                                "the chainages asked, got none; check --tunnel-json, "
                                "--from/--to and the input's CRS.")
    lim = max(res.max_depth_m, 0.05)
    paths = write_developed(res.margin, out, stem="clearance_margin", tile_m=args.tile_m,
                            stat="min", crs=crs, limit=lim, regions=res.regions)
    pngs = [p.name for p in paths if p.suffix == ".png"]
    write_text(out / "violations.csv", violations_csv(res))
    write_text(out / "regions.csv", regions_csv(res))
    write_json(out / "clearance.json", res.to_dict())
    write_headed_report(args, out / "clearance.md",
                        clearance_markdown(res, source=Path(args.input).name, figures=pngs),
                        [("cloud", args.input, ""), ("alignment", args.tunnel_json, ""),
                         ("envelope", args.envelope, "")],
                        crs_from=[args.input])
    if res.regions:
        worst = res.regions[0]
        say(args, f"clearance against '{envelope.name}': {len(res.regions)} violation "
                  f"region{'s' if len(res.regions) != 1 else ''}, deepest "
                  f"{1000 * worst.max_depth_m:.1f} mm at chainage "
                  f"{worst.deepest_chainage_m:.3f} m -> {out}/")
        say(args, args.cell_chosen)
        say(args, merge_line(res))
    else:
        say(args, f"clearance against '{envelope.name}': clear, smallest margin "
                  f"{1000 * res.min_margin_m:.1f} mm -> {out}/")
    return 0


__all__ = ["FIELD_CHOICES", "cmd_clearance", "cmd_develop", "register"]
