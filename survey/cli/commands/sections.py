"""Monitoring commands (issue 17): sections (as-built against design) and rings."""

from __future__ import annotations

import warnings
from pathlib import Path

from survey.cli.commands.axis import datum_options
from survey.cli.common import (CommandSet, floats, out_dir, pair, report_options, say,
                               write_headed_report, write_json, write_text)
from survey.errors import TunnelsimCLIError

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


def _alignment(args):
    """(Alignment, Profile or None): from --tunnel-json (or the JSON beside a tunnel
    PLY; a LandXML or station CSV has no profile) or fitted to the input (--fit-axis,
    with the chainage datum of --start/--chainage-at/--reverse)."""
    from survey.world.alignment_io import load_tunnel
    from survey.world.mesh import sidecar

    js = args.tunnel_json
    if js is None and not args.fit_axis and Path(args.input).suffix.lower() == ".ply" \
            and sidecar(args.input).is_file():
        js = str(sidecar(args.input))
    if js is not None and args.fit_axis:
        raise TunnelsimCLIError("Expected --tunnel-json or --fit-axis, got both.")
    if js is None and not args.fit_axis:
        raise TunnelsimCLIError("Expected --tunnel-json T.json (the alignment) or "
                                "--fit-axis, got neither.")
    if not args.fit_axis and (args.start is not None or args.reverse or
                              args.chainage_at is not None):
        raise TunnelsimCLIError("Expected --start, --chainage-at and --reverse with "
                                "--fit-axis (the chainage of a fitted axis), got them "
                                "with --tunnel-json, whose alignment has its chainage.")
    if js is not None:
        t = load_tunnel(js, option="--tunnel-json")
        return t.alignment, t.profile
    return _fitted_axis(args), None


def _fitted_axis(args):
    """An alignment fitted to a seeded random subset of the input's points, with the
    user's chainage (``survey.cli.commands.axis.fitted_axis``)."""
    from survey.cli.commands.axis import fitted_axis

    al, _, _ = fitted_axis(args, Path(args.input))
    return al


def _chainages(args, al):
    from survey.analysis.sections import section_chainages

    if (args.every is None) == (args.at is None):
        raise TunnelsimCLIError("Expected --every M or --at C[,C...] (section chainages), "
                                f"got {'both' if args.every is not None else 'neither'}.")
    at = floats(args.at, "--at") if args.at is not None else None
    return section_chainages(al, every_m=args.every, at=at, half_width_m=args.width)


def _design(args, prof, fitted):
    """The design profile: --design, or the tunnel JSON's profile."""
    from survey.analysis.design import DesignProfile, read_design_profile

    if args.design is not None:
        shift = pair(args.design_shift, "--design-shift as DY,DZ in metres") \
            if args.design_shift else (0.0, 0.0)
        closed = {"auto": None, "yes": True, "no": False}[args.design_closed]
        d = read_design_profile(args.design, closed=closed, order=args.design_order,
                                shift_m=shift)
    elif prof is not None:
        d = DesignProfile.from_profile(prof)
    else:
        raise TunnelsimCLIError("Expected --design FILE with --fit-axis or with an "
                                "alignment without a profile (LandXML, station CSV), "
                                "got none.")
    if fitted:
        # DECISION: a fitted axis runs through the profile's mid-range centre
        # (survey.clouds.axis.estimate_axis), so the design is centred the same way.
        y0, y1, z0, z1 = d.extent()
        d = d.shifted(-0.5 * (y0 + y1), -0.5 * (z0 + z1))
    return d


def _cuts(args, al, chainages):
    from survey.analysis.sections import cut_file

    if args.width is None or not args.width >= 0:
        raise TunnelsimCLIError(f"Expected --width >= 0 m, got {args.width}.")
    from sensors.io.errors import PointFileError

    classes = None
    if args.classes is not None:
        vals = floats(args.classes, "--classes")
        if not vals or any(v != int(v) or not 0 <= v <= 255 for v in vals):
            raise TunnelsimCLIError(f"Expected --classes as whole codes 0-255 (e.g. 64,2), "
                                    f"got {args.classes!r}.")
        classes = [int(v) for v in vals]
        from survey.analysis.developed import is_mesh_file

        if is_mesh_file(args.input):
            raise TunnelsimCLIError(f"Expected a classified point cloud for --classes, got "
                                    f"the mesh '{args.input}'; leave out --classes.")
    try:
        cuts = cut_file(args.input, al, chainages, args.width, max_points=args.max_points,
                        seed=args.seed, classes=classes)
    except PointFileError as e:
        if classes is None or "classification" not in str(e):
            raise
        raise TunnelsimCLIError(f"Expected a per-point classification in "
                                f"'{args.input}' for --classes, got none; classify it "
                                "with 'tunnelsim preprocess --segment' or leave out "
                                "--classes.") from None
    if classes is not None and not any(len(c.yz) for c in cuts):
        raise TunnelsimCLIError(f"Expected points of classes {args.classes} in the "
                                "section bands, got none; check --classes.")
    return cuts


def cmd_sections(args) -> int:
    import numpy as np

    from survey.analysis.overbreak import TOLERANCE_EDGES_M, compare_sections
    from survey.report.sections import (contours_csv, plot_section, section_png_name,
                                        sections_csv, sections_markdown, volumes_csv)

    if not Path(args.input).is_file():
        raise TunnelsimCLIError(f"Expected an input cloud or mesh, got '{args.input}' which "
                                "does not exist.")
    edges = TOLERANCE_EDGES_M if args.tolerance is None else \
        tuple(np.asarray(floats(args.tolerance, "--tolerance")) / 1000.0)
    al, prof = _alignment(args)
    design = _design(args, prof, args.fit_axis)
    chainages = _chainages(args, al)
    out = out_dir(args.output, args.force)
    cuts = _cuts(args, al, chainages)
    rep = compare_sections(cuts, design, alignment=al, bin_m=args.bin,
                           tolerance_edges_m=edges, seed=args.seed)
    write_text(out / "sections.csv", sections_csv(rep))
    write_text(out / "volumes.csv", volumes_csv(rep))
    write_text(out / "contours.csv", contours_csv(rep))
    write_json(out / "report.json", rep.to_dict())
    if not args.no_plots:
        for s in rep.sections:
            plot_section(s, rep, out / section_png_name(s.chainage_m))
    write_headed_report(args, out / "report.md",
                        sections_markdown(rep, source=Path(args.input).name,
                                          plots=not args.no_plots),
                        [("cloud or mesh", args.input, ""),
                         ("alignment", args.tunnel_json, "fitted axis" if args.fit_axis
                          else ""),
                         *([("design", args.design, "")] if args.design else [])],
                        crs_from=[args.input],
                        settings=[("band (m)", f"±{args.width:g}")] if getattr(
                            args, "width", None) is not None else None)
    worst = max(rep.sections, key=lambda s: s.max_m)
    say(args, f"{len(rep.sections)} sections against '{design.name}': overbreak "
              f"{rep.overbreak_m3:.3f} m^3, underbreak {rep.underbreak_m3:.3f} m^3; largest "
              f"overbreak {1000 * worst.max_m:.0f} mm at {worst.chainage_m:g} m -> {out}/")
    return 0


def cmd_rings(args) -> int:
    import numpy as np

    from survey.analysis.design import DesignProfile
    from survey.analysis.rings import FIT_RMS_WARN_M, fit_rings, poor_fits
    from survey.analysis.sections import above_floor
    from survey.report.sections import plot_rings, rings_csv, rings_markdown

    if not Path(args.input).is_file():
        raise TunnelsimCLIError(f"Expected an input cloud or mesh, got '{args.input}' which "
                                "does not exist.")
    al, prof = _alignment(args)
    if args.rail_height is not None and args.min_height is None:
        raise TunnelsimCLIError("Expected --rail-height with --min-height (the height it "
                                "measures from), got it alone; add --min-height M.")
    for flag, v in (("--min-height", args.min_height), ("--rail-height", args.rail_height)):
        if v is not None and not np.isfinite(v):
            raise TunnelsimCLIError(f"Expected {flag} a finite height in m, got {v}.")
    chainages = _chainages(args, al)
    out = out_dir(args.output, args.force)
    cuts = _cuts(args, al, chainages)
    floors = None
    if args.min_height is not None:
        # DECISION: with --tunnel-json the alignment is the floor (a tunnel JSON runs
        # along the invert, as before); a fitted axis runs through the profile centre,
        # so each section's lowest points are the floor there (issue 31).
        rail = args.rail_height if args.rail_height is not None else \
            (None if args.fit_axis else 0.0)
        kept = [above_floor(c, args.min_height, floor_m=rail) for c in cuts]
        cuts = [k[0] for k in kept]
        floors = [k[1] for k in kept]
    ref = DesignProfile.from_profile(prof).centre if prof is not None else np.zeros(2)
    rings = fit_rings(cuts, reference_centre=ref, nominal_diameter_m=args.nominal_diameter)
    bad = poor_fits(rings)
    if bad:
        worst = max(bad, key=lambda r: min(r.circle.rms_m, r.ellipse.rms_m))
        rms = min(worst.circle.rms_m, worst.ellipse.rms_m)
        warnings.warn(f"{len(bad)} of {len(rings)} rings fit a circle or an ellipse no "
                      f"better than {1000 * FIT_RMS_WARN_M:g} mm rms (worst "
                      f"{1000 * rms:.0f} mm at chainage {worst.chainage_m:g} m): the "
                      "section is not a ring (a horseshoe?), so its diameters and "
                      "ovality mean little; compare it with its design profile with "
                      "'tunnelsim sections --design', or drop the invert with "
                      "--min-height.", UserWarning, stacklevel=2)
    write_text(out / "rings.csv", rings_csv(rings))
    write_headed_report(args, out / "rings.md",
                        rings_markdown(rings, source=Path(args.input).name),
                        [("cloud or mesh", args.input, ""),
                         ("alignment", args.tunnel_json, "fitted axis" if args.fit_axis
                          else "")],
                        crs_from=[args.input])
    rows = [r.to_dict() for r in rings]
    if floors is not None:
        for row, f in zip(rows, sorted(zip([c.chainage_m for c in cuts], floors))):
            row["floor_height_m"] = f[1]
    write_json(out / "rings.json", rows)
    plot_rings(rings, out / "rings.png")
    dmax = max(r.ellipse.diameters_m[0] for r in rings)
    dmin = min(r.ellipse.diameters_m[1] for r in rings)
    if floors is not None:
        src = "--rail-height" if args.rail_height is not None else \
            ("each section's lowest points (its 1st percentile of heights)"
             if args.fit_axis else "the alignment of --tunnel-json")
        say(args, f"--min-height {args.min_height:g} m above the floor: {src}, at "
                  f"{np.median(floors):.3f} m in the section frame (median)")
    say(args, f"{len(rings)} rings: diameters {1000 * dmin:.1f} to {1000 * dmax:.1f} mm, "
              f"largest ovality {100 * max(r.ovality for r in rings):.3f} % -> {out}/")
    return 0


__all__ = ["cmd_rings", "cmd_sections", "register"]
