"""Commands of the surveyor's adjustment: adjust (Helmert), transform, correct (drift)."""

from __future__ import annotations

import numpy as np

from survey.errors import TunnelsimCLIError
from survey.cli.main import _write_text


def cmd_adjust(args) -> int:
    import json

    from survey.adjust.controlpoints import match, read_control_points
    from survey.adjust.helmert import fit_helmert
    from survey.report.adjustment import helmert_report

    a = read_control_points(args.source)
    b = read_control_points(args.target)
    ia, ib = match(a, b)
    res = fit_helmert(a.xyz[ia], b.xyz[ib], model=args.model,
                      sigma_source=None if a.sigma is None else a.sigma[ia],
                      sigma_target=None if b.sigma is None else b.sigma[ib],
                      ids=[a.ids[i] for i in ia])
    text = helmert_report(res)
    if args.report:
        _write_text(args.report, text)
    if args.json:
        _write_text(args.json, json.dumps(res.to_dict(), indent=1))
    if not args.quiet:
        print(text, end="")
    return 0


def cmd_transform(args) -> int:
    import json
    from pathlib import Path

    from survey.clouds.cloudio import map_cloud
    from survey.adjust.helmert import HelmertResult

    p = Path(args.helmert)
    if not p.is_file():
        raise TunnelsimCLIError(f"Expected a Helmert JSON (from 'tunnelsim adjust --json'), "
                                f"got '{p}' which does not exist.")
    try:
        res = HelmertResult.from_dict(json.loads(p.read_text()))
    except json.JSONDecodeError as exc:
        raise TunnelsimCLIError(f"Expected JSON in '{p}', got invalid text ({exc}).") from exc
    n = map_cloud(args.cloud, args.output, lambda xyz, t: res.apply(xyz))
    if not args.quiet:
        print(f"transformed {n:,} points -> {args.output}")
    return 0


def cmd_correct(args) -> int:
    from pathlib import Path

    from sensors import Trajectory

    from survey.clouds.cloudio import map_cloud
    from survey.errors import ControlPointError
    from survey.adjust.controlpoints import match, read_control_points
    from survey.adjust.drift import fit_drift, leave_one_out
    from survey.report.adjustment import drift_report

    traj = Trajectory.read(args.trajectory)
    world = read_control_points(args.control)
    seen = read_control_points(args.observed)
    if seen.time is None:
        raise ControlPointError(f"Expected a 'time' column in '{args.observed}' (when each "
                                "control point was observed by the MLS), got none.")
    ia, ib = match(seen, world)
    m, t, g = seen.xyz[ia], seen.time[ia], world.xyz[ib]
    sw = None if world.sigma is None else world.sigma[ib].mean(axis=1)
    ids = [seen.ids[i] for i in ia]
    corr = fit_drift(m, t, g, model=args.model, sigma_world=sw, ids=ids)
    loo = leave_one_out(m, t, g, model=args.model, sigma_world=sw)
    out = Path(args.output)
    n = map_cloud(args.cloud, out, lambda xyz, tt: corr.apply(xyz, tt) if tt is not None
                  else _no_time(args.cloud))
    fixed = corr.apply_trajectory(traj)
    traj_out = out.with_name(out.stem + "_trajectory.txt")
    fixed.write(traj_out)
    report = out.with_name(out.stem + "_report.md")
    _write_text(report, drift_report(corr, loo, traj=traj,
                                     plot_path=out.with_name(out.stem + "_correction.png")))
    rms = np.sqrt(np.mean(np.sum(loo ** 2, axis=1)))
    if args.json:
        import json

        _write_text(args.json, json.dumps({
            "model": args.model, "control_points": len(ids), "points": int(n),
            "check_rms_m": float(rms),
            "check_max_m": float(np.max(np.linalg.norm(loo, axis=1))),
            "correction_max_m": float(np.max(np.linalg.norm(
                fixed.positions - traj.positions, axis=1)))}, indent=2) + "\n")
    if not args.quiet:
        print(f"corrected {n:,} points with {len(ids)} control points ({args.model}); "
              f"check-point RMS {rms * 1000:.1f} mm -> {out}, {traj_out.name}, {report.name}")
    return 0


def _no_time(path):
    raise TunnelsimCLIError(f"Expected GPS time per point in '{path}' to correct drift, got "
                            "none.")
