"""Commands of the surveyor's adjustment: adjust (Helmert), transform, correct (drift).

Coordinate reference systems (``sensors.io.crs``): a control-point CSV states its CRS in
a leading comment line ``# crs: EPSG:2056`` (or in a sidecar ``<file>.prj``); ``adjust``
refuses two files that state different CRSs (unless ``--allow-crs-mismatch``: a datum
transformation estimated on purpose) and records both in its JSON (``source_crs``,
``target_crs``, WKT2); ``transform`` writes the target CRS into the output (``--crs``,
else the one the JSON records), refuses a cloud stating another CRS than the
transform's source, and drops an input's CRS it cannot replace (with a warning);
``correct`` gives the corrected cloud the control points' CRS.

Each command calls one library function (``survey.workflows.adjust``: ``adjust_files``,
``transform_file``, ``correct_file``) and prints from its result.
"""

from __future__ import annotations

from survey.cli.common import CommandSet, report_options


def register(commands: CommandSet) -> None:
    """Add adjust, transform and correct."""
    c = commands.add(
        "adjust", cmd_adjust, help="Helmert adjustment between two control-point files",
        description="Least-squares Helmert transformation (PROJ form, position-vector "
                    "convention) between two files of control points (id,x,y,z"
                    "[,sigma|sx,sy,sz]; x = Easting, y = Northing, z = height) matched by "
                    "id, with residuals, sigma0, global test, "
                    "every w/tau-test above its critical value, correlations and the PROJ "
                    "string. Refused unless meant: mirror images (swapped axes), a scale "
                    "beyond 1,000 ppm (different units), no convergence. Files are read "
                    "as office software and total stations write them: comma, "
                    "semicolon, tab or white space between fields, decimal comma, UTF-8 "
                    "or Latin-1, headers in English or German (Name,E,N,H; Punkt;"
                    "Rechtswert;Hochwert;Höhe) or none (id,E,N,H in that order); "
                    "--columns maps any other header. --report writes Markdown and a "
                    "self-contained HTML beside it.",
        epilog="Example: tunnelsim adjust mls_cp.csv total_station.csv --model 7 --snoop "
               "--report adjust.md --json helmert.json --project 'Lot 3' --instrument "
               "'TS16'")
    c.option("source", path="in", help="control points in the source system (CSV/text)")
    c.option("target", path="in", help="control points in the target system (CSV/text)")
    c.option("--columns", metavar="ID,E,N,H",
             help="the columns of id, easting, northing, height (and sigma) in both files, "
                  "as 1-based numbers or header names (e.g. 1,3,2,4 or Punkt,Y,X,Höhe), "
                  "or as id=...,e=...,n=...,h=...[,sigma=...|sx=...,sy=...,sz=...]; "
                  "default: found from the header")
    c.option("--source-columns", metavar="ID,E,N,H",
             help="like --columns, for the source file only")
    c.option("--target-columns", metavar="ID,E,N,H",
             help="like --columns, for the target file only")
    c.option("--model", choices=["7", "6", "9"], default="7",
             help="7 similarity (default), 6 rigid, 9 scale per axis")
    c.option("--exclude", metavar="ID,...", help="leave these control points out")
    c.option("--snoop", action="store_true",
             help="Baarda's data snooping: remove the point with the largest test above "
                  "the critical value, adjust again, repeat until none is above")
    c.option("--strict", action="store_true",
             help="refuse ids found in only one file (default: a warning)")
    c.option("--angles", choices=["deg", "gon"], default="deg",
             help="rotations in arcsec and degrees (default) or gon")
    c.option("--allow-reflection", action="store_true",
             help="fit even when the two systems are mirror images")
    c.option("--allow-scale", action="store_true",
             help="accept a scale beyond 1,000 ppm")
    c.option("--allow-crs-mismatch", action="store_true",
             help="adjust between files that state different CRSs ('# crs:' lines): a "
                  "datum transformation estimated on purpose")
    c.option("--max-iter", type=int, default=50, metavar="N",
             help="Gauss-Newton iterations at most (default 50)")
    c.option("--report", path="out",
             help="write the Markdown report here, and the same as self-contained HTML "
                  "beside it (.html)")
    c.option("--json", path="out", help="write the result (parameters and statistics) here")
    report_options(c)
    c.option("--quiet", action="store_true", help="do not print the report")

    c = commands.add(
        "transform", cmd_transform, help="apply a Helmert transform to a point cloud",
        description="Apply the Helmert transform of 'tunnelsim adjust --json' (or its "
                    "inverse) to a LAS/LAZ or binary PLY cloud, chunk by chunk, keeping "
                    "every other field, or to an E57 station (its pose; a scale goes "
                    "into its scan-frame points). The station pose a tunnelsim file "
                    "records (LAS/LAZ VLR, PLY comment, E57 pose) is transformed too.",
        epilog="Example: tunnelsim transform --helmert helmert.json mls.laz -o mls_utm.laz")
    c.option("cloud", path="in", help="input cloud (.las, .laz, .ply, .e57)")
    c.option("--helmert", required=True, path="in",
             help="Helmert JSON from 'tunnelsim adjust'")
    c.option("--inverse", action="store_true",
             help="apply the inverse transform (target system back to the source system)")
    c.option("--crs", metavar="CRS",
             help="coordinate reference system of the output (EPSG:n, WKT or PROJJSON; "
                  "needs pyproj); default: the target CRS 'adjust --json' recorded (the "
                  "source CRS with --inverse), else none")
    c.option("-o", "--output", required=True, path="out", help="output cloud (same kind)")
    c.option("--quiet", action="store_true", help="print nothing on success")

    c = commands.add(
        "correct", cmd_correct, help="correct the drift of an MLS run with control points",
        description="Correct a drifting MLS run (trajectory and cloud with GPS time) with "
                    "control points: world coordinates (--control, id,x,y,z[,sigma]) and "
                    "their MLS-frame coordinates with observation time (--observed, "
                    "id,x,y,z,time). Writes the corrected cloud, the corrected trajectory "
                    "(_trajectory.txt), a report (_report.md) and a plot of the correction.",
        epilog="Example: tunnelsim correct --trajectory slam.txt --cloud mls.laz --control "
               "cp.csv --observed cp_mls.csv -o corrected.laz")
    c.option("--trajectory", required=True, path="in", help="MLS trajectory (TUM or CSV)")
    c.option("--cloud", required=True, path="in",
             help="MLS cloud with GPS time (.las/.laz/.ply)")
    c.option("--control", required=True, path="in",
             help="control points, world coordinates (CSV)")
    c.option("--observed", required=True, path="in",
             help="the same points in the MLS frame with their time (CSV)")
    c.option("--model", choices=["piecewise", "global"], default="piecewise",
             help="piecewise rigid per control section (default) or one similarity")
    c.option("-o", "--output", required=True, path="out", help="corrected cloud")
    c.option("--json", path="out", help="also write the key figures (check-point RMS, "
                                        "largest correction) as JSON")
    c.option("--columns", metavar="ID,E,N,H",
             help="the columns of id, easting, northing, height in --control and "
                  "--observed (as for 'adjust --columns'; time=NAME for the time column)")
    report_options(c)
    c.option("--quiet", action="store_true", help="print nothing on success")


def cmd_adjust(args) -> int:
    from survey.workflows.adjust import adjust_files

    exclude = [k.strip() for k in (args.exclude or "").split(",") if k.strip()]
    res = adjust_files(args.source, args.target, columns=args.columns,
                       source_columns=args.source_columns,
                       target_columns=args.target_columns, model=args.model,
                       exclude=exclude, snoop=args.snoop, strict=args.strict,
                       angles=args.angles, allow_reflection=args.allow_reflection,
                       allow_scale=args.allow_scale,
                       allow_crs_mismatch=args.allow_crs_mismatch,
                       max_iter=args.max_iter, report_path=args.report,
                       json_path=args.json, project=args.project,
                       instrument=args.instrument)
    if not args.quiet:
        print(res.report, end="")
    return 0


def cmd_transform(args) -> int:
    from survey.workflows.adjust import transform_file

    res = transform_file(args.cloud, args.helmert, args.output, inverse=args.inverse,
                         crs=args.crs)
    if not args.quiet:
        way = "inverse-transformed" if res.inverse else "transformed"
        into = "" if res.crs_label is None else f" ({res.crs_label})"
        print(f"{way} {res.points:,} points -> {args.output}{into}")
    return 0


def cmd_correct(args) -> int:
    from survey.workflows.adjust import correct_file

    res = correct_file(args.trajectory, args.cloud, args.control, args.observed,
                       args.output, model=args.model, columns=args.columns,
                       json_path=args.json, project=args.project,
                       instrument=args.instrument)
    if not args.quiet:
        print(f"corrected {res.points:,} points with {res.control_points} control points "
              f"({res.model}); check-point RMS {res.check_rms_m * 1000:.1f} mm -> "
              f"{res.output}, {res.trajectory_path.name}, {res.report_path.name}")
    return 0


__all__ = ["cmd_adjust", "cmd_correct", "cmd_transform", "register"]
