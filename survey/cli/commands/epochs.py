"""Monitoring commands (issue 17): m3c2 (distances between epochs with LoD95) and
convergence (chords between control points, radial change per section)."""

from __future__ import annotations

from pathlib import Path

from survey.cli.common import (
    CommandSet,
    cluster_options,
    floats,
    numbers,
    open_cluster,
    out_dir,
    crs_words,
    report_header,
    report_options,
    say,
    write_json,
    write_text,
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


# ---------------------------------------------------------------------------- shared
def _check_crs(args, paths) -> str | None:
    """Refuse (unless --allow-crs-mismatch) inputs stating different CRSs; returns the
    first stated CRS text (the outputs state it)."""
    from sensors.io.crs import CRSError, crs_mismatch, mismatch_message
    from sensors.io.clouds import cloud_crs_text

    stated = [(str(p), cloud_crs_text(p)) for p in paths]
    if not args.allow_crs_mismatch:
        pair_ = crs_mismatch(stated)
        if pair_ is not None:
            raise CRSError(mismatch_message(*pair_, what="epochs",
                                            hint="reproject one epoch into the other's "
                                                 "CRS first, or pass --allow-crs-mismatch "
                                                 "if a label is wrong"))
    return next((c for _, c in stated if c is not None), None)


def _tunnel(path):
    """(Alignment, profile centre (2,)) of --tunnel: a tunnel JSON, a LandXML alignment
    or a station CSV (``load_tunnel``); without a profile the alignment is the axis,
    centre (0, 0)."""
    from survey.world.alignment_io import load_tunnel

    t = load_tunnel(path, option="--tunnel")
    return t.alignment, t.centre


def _epoch_points(path):
    """Points of an epoch: a cloud, or a mesh's vertices."""
    from sensors.io.clouds import read_reference

    return read_reference(path)[0]


# ---------------------------------------------------------------------------- m3c2
def _m3c2_params(args):
    from survey.analysis.m3c2 import M3C2Params

    radii = floats(args.normal_radii, "--normal-radii") if args.normal_radii else \
        [2.0 * args.cyl_radius] if args.cyl_radius and args.cyl_radius > 0 else []
    return M3C2Params(args.cyl_radius, args.max_depth, tuple(radii), args.reg_error,
                      args.robust)


def cmd_m3c2(args) -> int:
    import numpy as np

    from survey.analysis.m3c2 import CHUNK, M3C2, M3C2Result, subsample, towards_axis
    from sensors.io.clouds import annotate_las, iter_points, write_points_las

    out = Path(args.output)
    if out.suffix.lower() not in (".las", ".laz"):
        raise TunnelsimCLIError(f"Expected -o as .las/.laz, got '{out}'.")
    if not out.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing folder for '{out}', got none; "
                                "create it first.")
    prm = _m3c2_params(args)
    orient = args.orient.strip().lower()
    axis = None
    vector: tuple[float, ...] = (0.0, 0.0, 1.0)
    if orient == "axis":
        if not args.tunnel:
            raise TunnelsimCLIError("Expected --tunnel T.json with --orient axis (the "
                                    "alignment gives the axis), got none.")
        axis = _tunnel(args.tunnel)
    elif orient != "z":
        vector = tuple(numbers(args.orient, "--orient as z, axis or X,Y,Z", 3))
    if args.tile_m is None and (args.workers is not None or args.scheduler):
        raise TunnelsimCLIError("Expected --tile-m with --workers or --scheduler (M3C2 "
                                "runs on a cluster tile by tile), got no --tile-m.")
    if args.tile_m is not None and not args.tile_m > 0:
        raise TunnelsimCLIError(f"Expected a positive --tile-m, got {args.tile_m:g}.")
    inputs = [args.epoch1, args.epoch2] + ([args.core] if args.core else [])
    crs = _check_crs(args, inputs)
    if args.tile_m is not None:
        return _m3c2_tiled(args, out, prm, orient, vector, axis, crs)
    e1, e2 = _epoch_points(args.epoch1), _epoch_points(args.epoch2)
    job = M3C2(e1, e2, prm)
    say(args, f"M3C2 on {len(e1):,} and {len(e2):,} points...")

    def run(xyz):
        tw = None if axis is None else towards_axis(axis[0], xyz, axis[1])
        return job.compute(xyz, orientation=vector, towards=tw)

    parts: list = []
    if args.core and Path(args.core).suffix.lower() in (".las", ".laz"):
        def annotate(xyz):
            r = run(xyz)
            parts.append(r)
            return r.fields()
        annotate_las(args.core, out, annotate, chunk=CHUNK)
    else:
        core = np.concatenate(list(iter_points(args.core))) if args.core else \
            subsample(e1, args.core_spacing) if args.core_spacing else e1
        parts = [run(core[a:a + CHUNK]) for a in range(0, len(core), CHUNK)]
        res = M3C2Result.concatenate(parts)
        write_points_las(out, core, res.fields(), crs=crs)
    res = M3C2Result.concatenate(parts)
    _m3c2_reports(args, out, prm, orient, res.distance, res.lod, res.significant)
    return 0


def _m3c2_tiled(args, out: Path, prm, orient: str, vector, axis, crs) -> int:
    """cmd_m3c2 with --tile-m: ``survey.cluster.m3c2_tiles.m3c2_files`` on the executor
    --workers / --scheduler ask for; the results stay on disk until written."""
    from functools import partial

    import numpy as np

    from survey.analysis.m3c2 import CHUNK, towards_axis
    from sensors.io.clouds import annotate_las, write_points_las
    from survey.cluster.execution import TaskProgress
    from survey.cluster.m3c2_tiles import m3c2_files

    las_core = bool(args.core) and Path(args.core).suffix.lower() in (".las", ".laz")
    core = args.core if args.core else args.core_spacing
    ex = open_cluster(args)
    prog = TaskProgress(args.quiet, "tiles")
    where = "in this process" if ex.kind == "in-process" else f"on the {ex.kind}"
    say(args, f"M3C2 in tiles of {args.tile_m:g} m {where}...")
    try:
        # DECISION: the spill goes beside -o: a folder every worker sees (as the
        # scenes of 'scan --workers' do), on the disk that takes the output anyway.
        store = m3c2_files(args.epoch1, args.epoch2, core, prm, tile_m=args.tile_m,
                           orientation=vector,
                           towards=None if axis is None else
                           partial(towards_axis, axis[0], centre=axis[1]),
                           executor=ex, spill_dir=out.parent, progress=prog)
    finally:
        prog.close()
        ex.close()
    with store:
        if las_core:
            done = [0]

            def annotate(xyz):
                a = done[0]
                done[0] += len(xyz)
                if not np.array_equal(store.xyz(a, done[0]), xyz):
                    raise TunnelsimCLIError(f"Expected '{args.core}' to read the same "
                                            "points twice, got others; was it changed?")
                return store.result(a, done[0]).fields()
            annotate_las(args.core, out, annotate, chunk=CHUNK)
        else:
            write_points_las(out, store.column("xyz"), store.las_fields(), crs=crs)
        _m3c2_reports(args, out, prm, orient, store.column("distance"),
                      store.column("lod"), store.column("significant"))
    return 0


def _m3c2_reports(args, out: Path, prm, orient: str, distance, lod, significant) -> None:
    """The summary (.json, _report.md/.html), the histogram (.png) and the closing
    line."""
    from survey.report.epochs import m3c2_markdown, m3c2_summary, plot_m3c2_histogram
    from survey.report.html import write_report

    summ = m3c2_summary(distance, lod, significant, prm,
                        epoch1=str(args.epoch1), epoch2=str(args.epoch2),
                        orientation=orient)
    write_json(out.with_name(out.stem + ".json"), summ)
    png = out.with_name(out.stem + ".png")
    plot_m3c2_histogram(distance, significant, png)
    inputs = [("epoch 1 (earlier)", args.epoch1, ""), ("epoch 2 (later)", args.epoch2, "")]
    if args.core:
        inputs.append(("core points", args.core, ""))
    head = report_header(args, inputs, crs=crs_words([args.epoch1, args.epoch2]),
                         settings=[("normal orientation", orient)])
    write_report(out.with_name(out.stem + "_report.md"),
                 m3c2_markdown(summ, title=f"M3C2 {Path(args.epoch1).name} -> "
                                           f"{Path(args.epoch2).name}", header=head,
                               figure=png.name))
    say(args, f"M3C2: {summ['with_distance']:,} of {summ['core_points']:,} core points, "
              f"median {1000 * summ['median_m']:.2f} mm, {summ['significant']:,} "
              f"significant (median LoD95 {1000 * summ['median_lod_m']:.2f} mm) -> "
              f"{out.name}, {out.stem}_report.md, {out.stem}.json, {out.stem}.png")


# ---------------------------------------------------------------------------- convergence
def _named_points(path):
    """{id: xyz} of a tunnel JSON's control points or a control-point CSV."""
    import numpy as np

    from survey.analysis.convergence import control_points
    from survey.world.mesh import read_meta

    if Path(path).suffix.lower() == ".json":
        return control_points(read_meta(path))
    from survey.adjust.controlpoints import read_control_points

    cp = read_control_points(path)
    return {k: np.asarray(v, dtype=np.float64) for k, v in zip(cp.ids, cp.xyz)}


def _covered(points, alignment) -> tuple[float, float]:
    """Chainage range (m) of points (n, 3) along the alignment (a sample of them)."""
    import numpy as np

    p = np.asarray(points, dtype=np.float64)
    if len(p) > 200_000:
        p = p[np.random.default_rng(0).choice(len(p), 200_000, replace=False)]
    s = alignment.to_local(p)[0]
    return float(np.percentile(s, 0.1)), float(np.percentile(s, 99.9))


def cmd_convergence(args) -> int:
    import numpy as np

    from survey.analysis.convergence import chords, radial_change, sections_every
    from survey.report.epochs import (
        chords_csv,
        convergence_markdown,
        plot_radial,
        radial_csv,
    )

    if len(args.epochs) not in (0, 2):
        raise TunnelsimCLIError(f"Expected two epochs (earlier, later) or none, got "
                                f"{len(args.epochs)}.")
    if bool(args.control1) != bool(args.control2):
        raise TunnelsimCLIError("Expected --control1 and --control2 together, got one.")
    if not args.epochs and not args.control1:
        raise TunnelsimCLIError("Expected two epochs or --control1/--control2, got "
                                "neither: nothing to compare.")
    if args.epochs and not (args.at or args.every):
        raise TunnelsimCLIError("Expected --at S[,S...] or --every M with epochs, got "
                                "neither.")
    al, centre = _tunnel(args.tunnel)
    sigma = None if args.sigma_mm is None else args.sigma_mm / 1000.0
    ch = None
    if args.control1:
        ch = chords(_named_points(args.control1), _named_points(args.control2),
                    alignment=al, sigma_m=sigma)
    changes: list = []
    if args.epochs:
        _check_crs(args, args.epochs)
        e1, e2 = _epoch_points(args.epochs[0]), _epoch_points(args.epochs[1])
        if args.at:
            at = np.asarray(floats(args.at, "--at"), dtype=np.float64)
        else:
            # DECISION: --every N puts sections every N m of the alignment where both
            # epochs have points (a station covers tens of metres of a long tunnel).
            at = sections_every(al, args.every)
            lo, hi = _covered(e1, al)
            lo2, hi2 = _covered(e2, al)
            lo, hi = max(lo, lo2) + args.band, min(hi, hi2) - args.band
            at = at[(at >= lo) & (at <= hi)]
            if not len(at):
                raise TunnelsimCLIError(f"Expected both epochs to cover a section every "
                                        f"{args.every:g} m, got them overlapping over "
                                        f"chainages {lo:.1f} to {hi:.1f} m only; use --at "
                                        "or a smaller --every.")
        changes = radial_change(e1, e2, al, at, centre=centre, band_m=args.band,
                                angle_step_rad=np.deg2rad(args.angle_step))
    from survey.report.html import write_report

    out = out_dir(args.output, args.force)
    said = ["convergence.md", "convergence.html", "convergence.json"]
    summary: dict = {"chords": [] if ch is None else ch.rows(), "sections": []}
    if ch is not None:
        write_text(out / "chords.csv", chords_csv(ch))
        said.append("chords.csv")
    if changes:
        from survey.analysis.convergence import summarise

        summary["sections"] = summarise(changes)
        write_text(out / "radial.csv", radial_csv(changes))
        plot_radial(changes, out / "radial.png")
        said += ["radial.csv", "radial.png"]
    inputs = [(f"epoch {k + 1} ({'earlier' if k == 0 else 'later'})", p, "")
              for k, p in enumerate(args.epochs)]
    inputs += [(f"points of epoch {k}", p, "") for k, p in
               ((1, args.control1), (2, args.control2)) if p]
    inputs.append(("tunnel (alignment, profile)", args.tunnel, ""))
    settings = [("sections", (f"at {args.at} m" if args.at else f"every {args.every:g} m")
                 if args.epochs else "none (chords only)")]
    if args.epochs:
        settings += [("band (half-width along the axis)", f"{args.band:g} m"),
                     ("angle step", f"{args.angle_step:g}°")]
    if args.sigma_mm is not None:
        settings.append(("point precision (per coordinate)", f"{args.sigma_mm:g} mm"))
    head = report_header(args, inputs, settings=settings, crs=crs_words(
        list(args.epochs) + [args.control1, args.control2]))
    epochs = ([Path(p).name for p in args.epochs] if args.epochs else
              [Path(args.control1).name, Path(args.control2).name])
    md = convergence_markdown(ch, changes, header=head, epochs=epochs,
                              band_m=args.band if changes else None,
                              angle_step_deg=args.angle_step if changes else None,
                              figure="radial.png" if changes else None)
    write_report(out / "convergence.md", md)
    summary.update({"epochs": [str(p) for p in args.epochs],
                    "control": [str(p) for p in (args.control1, args.control2) if p],
                    "band_m": args.band, "angle_step_deg": args.angle_step,
                    "inputs": [{"role": i.role, "path": i.path, "sha256": i.sha256}
                               for i in head.inputs]})
    write_json(out / "convergence.json", summary)
    say(args, md.rstrip() + f"\n-> {out}/ ({', '.join(said)})")
    return 0


__all__ = ["cmd_convergence", "cmd_m3c2", "register"]
