"""The axis command (issue 31): a tunnel JSON fitted to a cloud, with the user's
chainage, for develop, clearance, sections, convergence and m3c2 --orient axis."""

from __future__ import annotations

from survey.cli.common import CommandSet, pair, say


def datum_options(c, *, with_alignment: bool) -> None:
    """The chainage datum options of a fitted axis (axis, sections/rings --fit-axis)."""
    c.option("--start", metavar="X,Y",
             help="chainage --chainage-at at the axis point nearest X,Y (plan "
                  "coordinates of the cloud), increasing away from it towards the "
                  "farther end (default: the end where the axis begins, running east, "
                  "or north for a north-south axis)")
    c.option("--chainage-at", type=float, metavar="S",
             help="chainage of the start point in m (default 0)")
    c.option("--reverse", action="store_true",
             help="run the chainage the other way from the start point")
    if with_alignment:
        c.option("--alignment", path="in", metavar="FILE",
                 help="take the chainage (and its direction) from this alignment: a "
                      "tunnel JSON, LandXML (.xml/.landxml) or chainage,E,N,H CSV")


def register(commands: CommandSet) -> None:
    """Add axis."""
    c = commands.add(
        "axis", cmd_axis,
        help="fit the tunnel axis and profile to a cloud: a tunnel JSON with your chainage",
        description="Fit the tunnel axis to a cloud or mesh (slice centres, a least-"
                    "squares spline, clothoid elements; survey.clouds.axis), extend it "
                    "to the ends of the data and give it your chainage: --start X,Y "
                    "with --chainage-at S (and --reverse), or --alignment FILE (a "
                    "design alignment: its chainage and direction). A cross-section "
                    "profile is fitted too (--profile). Writes a tunnel JSON that "
                    "every --tunnel / --tunnel-json option reads (sections, rings, "
                    "develop, clearance, convergence, m3c2 --orient axis; preprocess "
                    "--crop, mesh and scan --tunnel-json too). The axis runs through "
                    "the profile centre.",
        epilog="Example: tunnelsim axis scan.laz --start 2600012.5,1200030.2 "
               "--chainage-at 1250 -o tunnel.json")
    c.option("input", path="in",
             help="cloud (.las/.laz/.ply/.xyz/.txt/.csv/.npz/.e57) or mesh")
    c.option("-o", "--output", required=True, path="out", help="tunnel JSON to write (.json)")
    datum_options(c, with_alignment=True)
    c.option("--profile", default="sectors", metavar="sectors|circle|FILE",
             help="cross-section written: sectors (median radius in 5 deg sectors, "
                  "default), circle (median radius) or a design file of y,z (centred on "
                  "the axis by its mid-range, as sections --fit-axis does)")


def datum_values(args) -> dict:
    """The chainage datum keywords of ``survey.workflows.axis.fitted_axis`` from
    --start/--chainage-at/--reverse (and --alignment where the command has it)."""
    start = pair(args.start, "--start as X,Y in metres") if args.start else None
    return {"start_xy": None if start is None else tuple(start),
            "chainage_at_m": args.chainage_at, "reverse": args.reverse}


def cmd_axis(args) -> int:
    from survey.workflows.axis import axis_file

    r = axis_file(args.input, args.output, alignment=args.alignment,
                  profile=args.profile, **datum_values(args))
    extra = ""
    if r.datum["kind"] == "alignment":
        extra = ("; largest chainage difference to --alignment "
                 f"{r.datum['max_difference_m']:.3f} m")
    elif r.datum["kind"] == "start":
        extra = f"; --start lies {r.datum['start_offset_m']:.3f} m off the axis"
    a, b = r.start_point, r.end_point
    say(args, f"axis of {r.length_m:.1f} m: chainage {r.chainage_start_m:.3f} at "
              f"({a[0]:.3f}, {a[1]:.3f}) to {r.chainage_end_m:.3f} at ({b[0]:.3f}, "
              f"{b[1]:.3f}){extra}; profile '{r.profile.name}' (mean radius "
              f"{r.mean_radius_m:.3f} m) -> {r.output}")
    return 0


__all__ = ["cmd_axis", "datum_options", "datum_values", "register"]
