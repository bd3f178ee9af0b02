"""Commands of the surveyor's adjustment: adjust (Helmert), transform, correct (drift).

Coordinate reference systems (``sensors.io.crs``): a control-point CSV states its CRS in
a leading comment line ``# crs: EPSG:2056`` (or in a sidecar ``<file>.prj``); ``adjust``
refuses two files that state different CRSs (unless ``--allow-crs-mismatch``: a datum
transformation estimated on purpose) and records both in its JSON (``source_crs``,
``target_crs``, WKT2); ``transform`` writes the target CRS into the output (``--crs``,
else the one the JSON records), refuses a cloud stating another CRS than the
transform's source, and drops an input's CRS it cannot replace (with a warning);
``correct`` gives the corrected cloud the control points' CRS.
"""

from __future__ import annotations

from survey.cli.common import (
    CommandSet,
    report_header,
    report_options,
    write_json,
)
from survey.errors import TunnelsimCLIError


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


def _read_as(points) -> str:
    """How a control-point file was read (its dialect in words)."""
    return "" if points.dialect is None else points.dialect.describe()


def _read_points(path, columns: str | None, flag: str):
    from survey.adjust.controlpoints import read_control_points

    return read_control_points(path, columns=columns, flag=flag)


def cmd_adjust(args) -> int:
    from survey.adjust.controlpoints import match, unmatched_message
    from survey.adjust.snooping import data_snooping
    from survey.report.adjustment import helmert_report
    from survey.report.html import write_report

    a = _read_points(args.source, args.source_columns or args.columns,
                     "--source-columns" if args.source_columns else "--columns")
    b = _read_points(args.target, args.target_columns or args.columns,
                     "--target-columns" if args.target_columns else "--columns")
    names = (str(args.source), str(args.target))
    crs_a, crs_b = _control_crs(args)
    ia, ib = match(a, b, unmatched_ids="error" if args.strict else "warn", names=names)
    lost = unmatched_message(a, b, names)
    exclude = [k.strip() for k in (args.exclude or "").split(",") if k.strip()]
    sn = data_snooping(a.xyz[ia], b.xyz[ib], ids=[a.ids[i] for i in ia], model=args.model,
                       sigma_source_m=None if a.sigma is None else a.sigma[ia],
                       sigma_target_m=None if b.sigma is None else b.sigma[ib],
                       exclude=exclude, snoop=args.snoop, max_iter=args.max_iter,
                       allow_reflection=args.allow_reflection,
                       allow_scale=args.allow_scale)
    res = sn.result
    notes = [f"control point ids not in both files, left out: {lost}."] if lost else []
    if crs_a is not None or crs_b is not None:
        notes.append(f"coordinate reference systems: source {_label(crs_a)}, target "
                     f"{_label(crs_b)}.")
    crs_text = (f"source {_label(crs_a)}, target {_label(crs_b)}"
                if crs_a is not None or crs_b is not None else None)
    head = report_header(args, [("source", args.source, _read_as(a)),
                                ("target", args.target, _read_as(b))],
                         crs=crs_text, settings=[("model", f"{args.model} parameters"),
                                                 ("data snooping", "yes" if args.snoop
                                                  else "no")])
    text = helmert_report(res, angles=args.angles, snooping=sn, notes=notes, header=head)
    if args.report:
        write_report(args.report, text)
    if args.json:
        write_json(args.json, {**res.to_dict(), **sn.to_dict(),
                               "unmatched_ids": lost or None,
                               "source_crs": _wkt(crs_a), "target_crs": _wkt(crs_b),
                               "inputs": [{"role": i.role, "path": i.path,
                                           "sha256": i.sha256, "read_as": i.note}
                                          for i in head.inputs],
                               "project": args.project, "instrument": args.instrument})
    if not args.quiet:
        print(text, end="")
    return 0


def _control_crs(args) -> tuple[str | None, str | None]:
    """The CRSs the two control-point files state (``# crs:`` line or sidecar), refused
    when they differ unless --allow-crs-mismatch."""
    from sensors.io.crs import CRSError, crs_mismatch, mismatch_message, text_file_crs

    crs_a, crs_b = text_file_crs(args.source), text_file_crs(args.target)
    if not args.allow_crs_mismatch:
        pair = crs_mismatch([(args.source, crs_a), (args.target, crs_b)])
        if pair is not None:
            raise CRSError(mismatch_message(
                *pair, what="two control-point files",
                hint="between two stated CRSs a Helmert is a datum transformation: use "
                     "the published one (PROJ, pyproj.Transformer), or pass "
                     "--allow-crs-mismatch to estimate your own"))
    return crs_a, crs_b


def _wkt(crs: str | None) -> str | None:
    from sensors.io.crs import crs_wkt

    return None if crs is None else crs_wkt(crs)


def _label(crs) -> str:
    from sensors.io.crs import crs_label, parse_crs

    return "none stated" if crs is None else crs_label(parse_crs(crs, metric=False))


def _json_crs(d: dict, key: str, p) -> str | None:
    v = d.get(key)
    if v is not None and not (isinstance(v, str) and v.strip()):
        raise TunnelsimCLIError(f"Expected '{key}' in '{p}' as WKT text or null, got "
                                f"{v!r}.")
    return v


def _transform_crs(args, d: dict, p):
    """The CRS the transformed cloud states: --crs, else the target (with --inverse the
    source) CRS the Helmert JSON records, else None. Refuses a cloud stating another
    CRS than the transform's source, and --crs against a recorded target."""
    from sensors.io.crs import CRSError, mismatch_message, parse_crs, same_crs
    from sensors.io.clouds import cloud_crs_text

    src, dst = _json_crs(d, "source_crs", p), _json_crs(d, "target_crs", p)
    if args.inverse:
        src, dst = dst, src
    target = parse_crs(args.crs, what="--crs") if args.crs is not None else None
    side = "source" if args.inverse else "target"
    if target is not None and dst is not None and not same_crs(target, dst):
        raise CRSError(f"Expected --crs to agree with the {side} CRS recorded in '{p}', "
                       f"got {_label(target)} and {_label(dst)}; leave --crs out, or "
                       "adjust again with control points in that CRS.")
    have = cloud_crs_text(args.cloud)
    if have is not None and src is not None and not same_crs(have, src):
        raise CRSError(mismatch_message(
            (str(args.cloud), have), (f"{p} ({'target' if args.inverse else 'source'})",
                                      src),
            what="cloud and the transform's input system",
            hint="the transform was estimated for other coordinates"))
    out = target if target is not None else dst
    if out is None and have is not None:
        import warnings

        warnings.warn(f"'{args.output}' states no CRS: the input's {_label(have)} does "
                      "not hold after the transform; give the new one with --crs.",
                      UserWarning, stacklevel=2)
    return out


def _pose_mover(res, inverse: bool):
    """A station pose (position (3,), quaternion x, y, z, w (4,), sensor to world) in
    the Helmert's target system (source system with ``inverse``): position through
    ``apply`` (``apply_inverse``), attitude R -> R_h R (R_h^T R).

    DECISION: the attitude takes the Helmert's rotation only: a rotation has no scale,
    so the points of a similarity are the new pose applied to the sensor-frame points
    times (1 + s) (LAS/PLY keep the points' coordinates, E57 the scaled scan-frame
    ones; ``sensors.io.clouds._map_e57``), as ``HelmertResult.apply_trajectory``
    treats attitudes."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    r_h = np.asarray(res.rotation_matrix, dtype=np.float64)
    r_h = Rotation.from_matrix(r_h.T if inverse else r_h)
    move = res.apply_inverse if inverse else res.apply

    def pose(position, quaternion_xyzw):
        rot = r_h * Rotation.from_quat(quaternion_xyzw)
        return move(np.asarray(position, dtype=np.float64)), rot.as_quat()
    return pose


def cmd_transform(args) -> int:
    import json
    from pathlib import Path

    from survey.adjust.helmert import HelmertResult
    from sensors.io.clouds import map_cloud

    p = Path(args.helmert)
    if not p.is_file():
        raise TunnelsimCLIError(f"Expected a Helmert JSON (from 'tunnelsim adjust --json'), "
                                f"got '{p}' which does not exist.")
    try:
        d = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise TunnelsimCLIError(f"Expected JSON in '{p}', got invalid text ({exc}).") from exc
    res = HelmertResult.from_dict(d)      # refuses anything but adjust's JSON object
    out_crs = _transform_crs(args, d, p)
    move = res.apply_inverse if args.inverse else res.apply
    n = map_cloud(args.cloud, args.output, lambda xyz, t: move(xyz), crs=out_crs,
                  pose=_pose_mover(res, args.inverse))
    if not args.quiet:
        way = "inverse-transformed" if args.inverse else "transformed"
        into = "" if out_crs is None else f" ({_label(out_crs)})"
        print(f"{way} {n:,} points -> {args.output}{into}")
    return 0


def cmd_correct(args) -> int:
    from pathlib import Path

    import numpy as np

    from sensors import Trajectory
    from survey.adjust.controlpoints import match, read_control_points
    from survey.adjust.drift import fit_drift, leave_one_out
    from sensors.io.clouds import map_cloud
    from survey.errors import ControlPointError
    from survey.report.adjustment import drift_report

    from sensors.io.crs import text_file_crs
    from sensors.io.clouds import KEEP_CRS

    traj = Trajectory.read(args.trajectory)
    world = read_control_points(args.control, columns=args.columns)
    # The corrected cloud lies in the control points' system: it states their CRS.
    world_crs = text_file_crs(args.control)
    seen = read_control_points(args.observed, columns=args.columns)
    if seen.time is None:
        raise ControlPointError(f"Expected a 'time' column in '{args.observed}' (when each "
                                "control point was observed by the MLS), got none.")
    ia, ib = match(seen, world)
    m, t, g = seen.xyz[ia], seen.time[ia], world.xyz[ib]
    if len(t) and (t.min() < traj.start_s - 1.0 or t.max() > traj.end_s + 1.0):
        from sensors.trajectory import time_base_hint

        raise TunnelsimCLIError(
            f"Expected the control points' times within the trajectory's "
            f"[{traj.start_s:g}, {traj.end_s:g}] s, got [{t.min():g}, {t.max():g}] s"
            f"{time_base_hint(traj.times, t)}.")
    sw = None if world.sigma is None else world.sigma[ib].mean(axis=1)
    ids = [seen.ids[i] for i in ia]
    corr = fit_drift(m, t, g, model=args.model, sigma_world_m=sw, ids=ids)
    loo = leave_one_out(m, t, g, model=args.model, sigma_world_m=sw)
    out = Path(args.output)

    def moved(xyz, tt):
        if tt is None:
            raise TunnelsimCLIError(f"Expected GPS time per point in '{args.cloud}' to "
                                    "correct drift, got none.")
        return corr.apply(xyz, tt)

    n = map_cloud(args.cloud, out, moved,
                  crs=KEEP_CRS if world_crs is None else world_crs)
    fixed = corr.apply_trajectory(traj)
    traj_out = out.with_name(out.stem + "_trajectory.txt")
    fixed.write(traj_out)
    report = out.with_name(out.stem + "_report.md")
    head = report_header(
        args, [("trajectory", args.trajectory, ""), ("cloud", args.cloud, ""),
               ("control points (world)", args.control, _read_as(world)),
               ("control points (MLS frame, timed)", args.observed,
                _read_as(seen))],
        crs=None if world_crs is None else _label(world_crs),
        settings=[("model", args.model)])
    from survey.report.html import write_report

    write_report(report, drift_report(corr, loo, traj=traj, header=head,
                                      plot_path=out.with_name(out.stem + "_correction.png")))
    rms = float(np.sqrt(np.mean(np.sum(loo ** 2, axis=1))))
    if args.json:
        write_json(args.json, {
            "model": args.model, "control_points": len(ids), "points": int(n),
            "check_rms_m": rms,
            "check_max_m": float(np.max(np.linalg.norm(loo, axis=1))),
            "correction_max_m": float(np.max(np.linalg.norm(
                fixed.positions - traj.positions, axis=1)))})
    if not args.quiet:
        print(f"corrected {n:,} points with {len(ids)} control points ({args.model}); "
              f"check-point RMS {rms * 1000:.1f} mm -> {out}, {traj_out.name}, {report.name}")
    return 0


__all__ = ["cmd_adjust", "cmd_correct", "cmd_transform", "register"]
