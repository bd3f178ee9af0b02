"""The axis command (issue 31): a tunnel JSON fitted to a cloud, with the user's
chainage, for develop, clearance, sections, convergence and m3c2 --orient axis."""

from __future__ import annotations

from pathlib import Path

from survey.cli.common import CommandSet, pair, say, write_json
from survey.errors import TunnelsimCLIError

#: Format tag of the JSON the axis command writes (the tunnel JSON's alignment and
#: profile, without a mesh).
AXIS_FORMAT = "tunnelsim-axis/1"


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


def fitted_axis(args, path):
    """(alignment with the user's chainage, datum record, sample points) of the input
    ``path``: the axis of a seeded subset (``AXIS_SAMPLE`` points), extended to the
    data's ends, with --start/--chainage-at/--reverse (or --alignment)."""
    from survey.clouds.axis import apply_datum, estimate_axis, sample_points
    from survey.world.alignment_io import load_tunnel

    # DECISION: 'axis' has no --seed: its subset is drawn with seed 0, as
    # estimate_axis draws its own (the axis must not change with a seed); sections and
    # rings --fit-axis pass theirs.
    pts = sample_points(path, seed=getattr(args, "seed", 0))
    al, _ = estimate_axis(pts)
    ref = getattr(args, "alignment", None)
    if ref is not None and (args.start is not None or args.reverse):
        raise TunnelsimCLIError("Expected --alignment or --start/--reverse (where the "
                                "chainage comes from), got both.")
    start = pair(args.start, "--start as X,Y in metres") if args.start else None
    reference = load_tunnel(ref, option="--alignment").alignment if ref else None
    at = 0.0 if args.chainage_at is None else args.chainage_at
    al, rec = apply_datum(al, pts, start_xy=start, chainage_at_m=at,
                          reverse=args.reverse, reference=reference)
    return al, rec, pts


def cmd_axis(args) -> int:
    import numpy as np

    from survey.analysis.design import read_design_profile
    from survey.clouds.axis import fit_profile
    from sensors.io.clouds import cloud_crs_text
    from survey.world.profiles import Profile

    src = Path(args.input)
    if not src.is_file():
        raise TunnelsimCLIError(f"Expected an input cloud or mesh, got '{src}' which does "
                                "not exist.")
    out = Path(args.output)
    if out.suffix.lower() != ".json":
        raise TunnelsimCLIError(f"Expected -o as a .json file, got '{out}'.")
    if not out.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing folder for '{out}', got none; "
                                "create it first.")
    if args.alignment is not None and args.chainage_at is not None:
        raise TunnelsimCLIError("Expected --chainage-at with --start (the alignment of "
                                "--alignment gives the chainage), got it with "
                                "--alignment.")
    al, rec, pts = fitted_axis(args, src)
    if args.profile in ("sectors", "circle"):
        prof = fit_profile(al, pts, kind=args.profile)
    else:
        d = read_design_profile(args.profile)
        if not d.closed:
            raise TunnelsimCLIError(f"Expected --profile as a closed design profile, got "
                                    f"an open one in '{args.profile}'.")
        y0, y1, z0, z1 = d.extent()
        prof = Profile.from_polyline(d.vertices - [0.5 * (y0 + y1), 0.5 * (z0 + z1)],
                                     name=Path(args.profile).stem)
    meta = {"format": AXIS_FORMAT, "name": src.stem, "source": src.name,
            "alignment": al.to_dict(), "profile": prof.to_dict(), "datum": rec,
            "fit": {"points_used": int(len(pts)), "profile": args.profile,
                    "axis": "profile centre"}}
    try:
        crs = cloud_crs_text(src)
    except Exception:   # a mesh or a file without a CRS statement
        crs = None
    if crs:
        meta["crs"] = crs
    write_json(out, meta)
    lo, hi = al.chainage_range
    a, b = al.point(lo), al.point(hi)
    extra = ""
    if rec["kind"] == "alignment":
        extra = f"; largest chainage difference to --alignment {rec['max_difference_m']:.3f} m"
    elif rec["kind"] == "start":
        extra = f"; --start lies {rec['start_offset_m']:.3f} m off the axis"
    say(args, f"axis of {al.length_m:.1f} m: chainage {lo:.3f} at ({a[0]:.3f}, "
              f"{a[1]:.3f}) to {hi:.3f} at ({b[0]:.3f}, {b[1]:.3f}){extra}; profile "
              f"'{prof.name}' (mean radius {np.sqrt(abs(_area(prof)) / np.pi):.3f} m) "
              f"-> {out}")
    return 0


def _area(prof) -> float:
    """Area (m^2) enclosed by a profile (its dense polygon, shoelace formula)."""
    import numpy as np

    _, p = prof.dense()
    y, z = p[:, 0], p[:, 1]
    return float(0.5 * np.sum(y * np.roll(z, -1) - np.roll(y, -1) * z))


__all__ = ["AXIS_FORMAT", "cmd_axis", "datum_options", "fitted_axis", "register"]
