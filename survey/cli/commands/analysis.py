"""Commands that analyse: compare (C2C / C2M), plan (TLS stations), study (MLS speeds)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from survey.cli.common import (
    CommandSet,
    Progress,
    cluster_options,
    floats,
    out_dir,
    open_cluster,
    pair,
    report_options,
    say,
    write_headed_report,
    write_json,
    write_text,
)
from survey.errors import TunnelsimCLIError


def register(commands: CommandSet) -> None:
    """Add compare, plan and study."""
    c = commands.add(
        "compare", cmd_compare,
        help="cloud-to-cloud or cloud-to-mesh distances, with statistics",
        description="Distances from one or more clouds to a reference, CloudCompare "
                    "semantics: exact nearest neighbour (C2C) or signed distance to a mesh "
                    "(C2M, positive on the side of the triangle normal). The last path is "
                    "the reference (cloud, or a mesh .ply/.obj/.stl). Writes stats.csv, "
                    "stats.md (mean, median, std, 95 %, RMS per scan), histogram.png and "
                    "each cloud as LAZ with the scalar field 'distance'.",
        epilog="Example: tunnelsim compare station_sim.laz station_real.laz --max-dist 0.5 "
               "-o compare/")
    c.option("clouds", nargs="+", metavar="CLOUD", path="in",
             help="compared cloud(s), then the reference")
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--max-dist", type=float, metavar="M",
             help="clamp distances at M metres (points farther get M)")
    c.option("--split", action="store_true",
             help="also write the X/Y/Z components (compared - nearest reference)")
    c.option("--model", choices=["plane"],
             help="local model of the reference: least-squares plane of --k points")
    c.option("--k", type=int, default=6, help="neighbours for --model (default 6)")
    c.option("--allow-disjoint", action="store_true",
             help="compare clouds whose bounding boxes lie more than 1 m apart (refused "
                  "by default: different frames or units)")
    c.option("--allow-crs-mismatch", action="store_true",
             help="compare inputs that state different coordinate reference systems "
                  "(refused by default: reproject one first)")
    c.option("--tile-m", type=float, metavar="M",
             help="compare tile by tile (x, y tiles of M metres, spilled to disk in "
                  "the output folder): memory bounded by a tile, not by the clouds, and "
                  "the tiles run as tasks (on --workers or --scheduler); the same "
                  "distances as one piece. A reference cloud needs --max-dist (the "
                  "tiles' halo)")
    cluster_options(c, needs=("tile-m",))
    c.option("--threads", type=int, help="Numba threads (default: all cores)")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    c.option("--quiet", action="store_true", help="no progress bar or summary")
    report_options(c)

    c = commands.add(
        "plan", cmd_plan,
        help="TLS station planning: coverage of spacings, optimised station set",
        description="Quality of every lining cell (coverage, point spacing from the "
                    "preset's angular step and range, incidence, range) for stations on "
                    "the axis at fixed spacings, and optionally the smallest station set "
                    "reaching a target coverage (MILP, greedy bound). Writes plan.csv, "
                    "plan.md, plan.json and coverage.png (unrolled chainage x angle). "
                    "On any mesh (no tunnel .json, or --along auto) the stations stand "
                    "along the route found in the mesh and offset across it, coverage "
                    "is measured on the mesh's own triangles (area-weighted), chainage "
                    "is the distance along the route, and route.csv is written too.",
        epilog="Example: tunnelsim plan --mesh bfo.ply --sensor zf_imager_5016 "
               "--resolution high --spacing 5,10 --optimize --target 0.99 -o plan/")
    c.option("--mesh", required=True, path="in",
             help="tunnel mesh (its .json gives the axis), or any mesh")
    _route_options(c, "stations")
    c.option("--offsets", default="1", metavar="M[,M...]",
             help="with --along auto and --optimize: candidate stations also this far "
                  "left and right of the route, where they fit (default 1)")
    c.option("--clearance", type=float, default=0.2, metavar="M",
             help="with --along auto: smallest distance of a station from the mesh "
                  "(default 0.2)")
    c.option("--sensor", default="zf_imager_5016", path="toml",
             help="TLS sensor name or .toml")
    c.option("--resolution", help="resolution preset (default: the sensor's)")
    c.option("--spacing", default="5,10", metavar="M[,M...]",
             help="station spacings to compare in metres (default 5,10)")
    c.option("--optimize", action="store_true",
             help="find the smallest station set for --target")
    c.option("--target", type=float, default=0.99,
             help="coverage share to reach with --optimize (default 0.99)")
    c.option("--candidate-step", type=float, default=2.5, metavar="M",
             help="candidate stations every M metres (default 2.5)")
    c.option("--time-limit", type=float, default=60.0, metavar="S",
             help="MILP time limit in seconds (default 60)")
    c.option("--spacing-mm", type=float, default=5.0,
             help="point-spacing threshold in mm (default 5)")
    c.option("--incidence-deg", type=float, default=70.0,
             help="incidence threshold in degrees (default 70)")
    c.option("--range", type=float, default=30.0, metavar="M",
             help="range threshold in metres (default 30)")
    c.option("--cell", default="0.25,2", metavar="M,DEG",
             help="lining cell size along (m) and around (deg) (default 0.25,2); with "
                  "--along auto, M is the largest edge of a triangle sample")
    c.option("--height", type=float, default=1.5, metavar="M",
             help="instrument height above the floor (default 1.5)")
    cluster_options(c)
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--threads", type=int, help="Numba threads (default: all cores)")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    c.option("--quiet", action="store_true", help="print nothing on success")
    report_options(c)

    c = commands.add(
        "study", cmd_study, seeded=True, help="MLS speed x scan-rate x mounting study",
        description="Drive a spinning lidar (or profiler) through an evaluation strip at "
                    "each speed, rate and mounting: density on lining and floor, empty "
                    "lining share, along-track line spacing, rolling-shutter distortion. "
                    "Writes study.csv, study.md and study.png (floor rings per speed, "
                    "density vs speed).",
        epilog="Example: tunnelsim study --mesh bfo.ply --sensor robosense_airy --speeds "
               "0,1,3 --rates 10,20 --mounts down -o study/")
    c.option("--mesh", required=True, path="in",
             help="tunnel mesh (its .json gives the axis), or any mesh: then the sensor "
                  "drives along the route found in it, the strip is in distance along "
                  "the route and the cells are the mesh's own triangles")
    _route_options(c, "the sensor")
    c.option("--cell", type=float, default=0.1, metavar="M",
             help="cell size (m): along the axis, or with --along auto the largest "
                  "edge of a triangle sample (default 0.1)")
    c.option("--sensor", default="robosense_airy", path="toml", help="sensor name or .toml")
    c.option("--speeds", default="0,1,3", metavar="V[,V...]",
             help="speeds in m/s (default 0,1,3)")
    c.option("--rates", default="10", metavar="HZ[,HZ...]",
             help="rotation (profile) rates in Hz (default 10)")
    c.option("--mounts", default="level,down", metavar="level,down",
             help="mountings (default level,down)")
    c.option("--strip", metavar="START,END",
             help="evaluation strip in chainage (default: 5 m mid-tunnel)")
    c.option("--lead", type=float, default=5.0, metavar="M",
             help="drive this far before and after the strip (default 5)")
    c.option("--height", type=float, default=0.5, metavar="M",
             help="sensor height above the floor (default 0.5)")
    c.option("--ideal", action="store_true",
             help="exact geometry: no noise, every return detected")
    c.option("--seed", type=int, default=0, help="random seed (default 0)")
    cluster_options(c)
    c.option("-o", "--output", required=True, path="out", help="output folder")
    c.option("--threads", type=int, help="Numba threads (default: all cores)")
    c.option("--force", action="store_true", help="write into a non-empty folder")
    c.option("--quiet", action="store_true", help="print nothing on success")
    report_options(c)


def _route_options(c, who: str) -> None:
    """--along and --waypoints of plan and study."""
    c.option("--along", choices=["centreline", "auto"],
             help=f"centreline: {who} on the tunnel axis (needs the mesh's .json); auto: "
                  "along the route found in the mesh (default: centreline when the "
                  ".json gives the axis, else auto)")
    c.option("--waypoints", path="in", metavar="CSV",
             help="with --along auto: x,y[,z] rows the route passes in order")


def _along(args) -> str:
    """'centreline' or 'auto': --along, else centreline where the mesh's .json gives
    the axis; --waypoints refused with the centreline."""
    from survey.world.mesh import read_meta, sidecar

    along = args.along
    if along is None:
        js = sidecar(args.mesh)
        along = "centreline" if js.is_file() and \
            {"alignment", "profile"} <= set(read_meta(js)) else "auto"
    if args.waypoints and along != "auto":
        raise TunnelsimCLIError("Expected --waypoints with --along auto, got it with the "
                                "tunnel centreline (the mesh's .json gives the axis; pass "
                                "--along auto).")
    return along


def _waypoints(args):
    from sensors.route import read_waypoints

    return read_waypoints(args.waypoints) if args.waypoints else None


# ---------------------------------------------------------------------------- compare
def _load_reference(path):
    from survey.analysis.compare import ReferenceCloud, ReferenceMesh
    from sensors.io.clouds import read_reference

    v, f = read_reference(path)
    return (ReferenceMesh(v, f), "mesh") if f is not None else (ReferenceCloud(v), "cloud")


def _compared_boxes(args, compared, ref) -> list[int]:
    """Refuse (unless --allow-disjoint) a compared cloud whose bounding box lies more
    than ``OVERLAP_TOL_M`` from the reference's; one pass over each cloud (bounds from
    the points, not a header). Returns the number of points of each compared cloud."""
    import numpy as np

    from survey.analysis.compare import check_overlap
    from sensors.io.clouds import cloud_bounds
    from survey.errors import CompareError

    total = []
    for c in compared:
        lo, hi, n = cloud_bounds(c)
        total.append(n)
        if args.allow_disjoint:
            continue
        try:
            check_overlap(np.stack([lo, hi]), ref.bounds,
                          names=(f"'{c}'", f"the reference '{args.clouds[-1]}'"))
        except CompareError as exc:
            raise CompareError(f"{str(exc).rstrip('?.')}? Pass --allow-disjoint if you "
                               "mean it.") from exc
    return total


def _check_crs(args, compared, ref_path) -> dict:
    """Refuse (unless --allow-crs-mismatch) inputs that state different coordinate
    reference systems, naming the first two; inputs stating none are not compared.
    Returns {path: CRS text or None} of the compared clouds (their outputs state it)."""
    from sensors.io.crs import CRSError, crs_mismatch, mismatch_message
    from sensors.io.clouds import cloud_crs_text

    stated = {c: cloud_crs_text(c) for c in [*compared, ref_path]}
    if not args.allow_crs_mismatch:
        pair_ = crs_mismatch(stated.items())
        if pair_ is not None:
            raise CRSError(mismatch_message(
                *pair_, what="compared clouds and the reference",
                hint="reproject one into the other's CRS first (e.g. PDAL "
                     "filters.reprojection), or pass --allow-crs-mismatch if a label is "
                     "wrong"))
    return stated


def cmd_compare(args) -> int:
    if len(args.clouds) < 2:
        raise TunnelsimCLIError("Expected at least two paths (compared cloud(s), then the "
                                f"reference), got {len(args.clouds)}.")
    *compared, ref_path = args.clouds
    for c in compared:
        if not Path(c).is_file():
            raise TunnelsimCLIError(f"Expected a compared cloud, got '{c}' which does not "
                                    "exist.")
    if (args.workers or args.scheduler) and args.tile_m is None:
        raise TunnelsimCLIError("Expected --tile-m with --workers or --scheduler (the "
                                "tasks are tiles), got none.")
    if args.tile_m is not None and not args.tile_m > 0:
        raise TunnelsimCLIError(f"Expected --tile-m as a positive number of metres, got "
                                f"{args.tile_m:g}.")
    # DECISION: before the boxes: two CRSs explain a disjoint pair better than a box.
    crs = _check_crs(args, compared, ref_path)
    if args.tile_m is not None:
        return _compare_tiled(args, compared, ref_path, crs)
    ref, kind = _load_reference(ref_path)
    if kind == "mesh" and (args.split or args.model):
        raise TunnelsimCLIError("Expected --split/--model only with a reference cloud, got "
                                "a mesh (cloud-to-mesh distances are signed, not split).")
    total = sum(_compared_boxes(args, compared, ref))
    out = out_dir(args.output, args.force)
    prog = Progress(args.quiet, unit="points")
    try:
        rows, hist = _distances(args, compared, ref, kind, out, lambda n: prog(n, total),
                                crs)
    finally:
        prog.close()
    return _compare_outputs(args, ref_path, kind, out, rows, hist)


def _compare_outputs(args, ref_path, kind, out, rows, hist) -> int:
    """stats.csv, stats.md and histogram.png of a comparison, and the summary line."""
    from survey.report.compare import plot_histogram, stats_csv, stats_markdown

    title = "C2M (signed)" if kind == "mesh" else "C2C"
    write_text(out / "stats.csv", stats_csv(rows))
    md = stats_markdown(rows, title=title)
    plot_histogram(hist, out / "histogram.png",
                   xlabel=f"{title} distance to {Path(ref_path).name} (mm)")
    compared = [c for c in args.clouds if c != ref_path]
    write_headed_report(
        args, out / "stats.md",
        f"# {title} distances to {Path(ref_path).name}\n\n" + md +
        ("" if args.max_dist is None else
         f"\nDistances beyond {args.max_dist} m are clamped to it.\n") +
        "\n![histogram](histogram.png)\n",
        [*[("compared", c, "") for c in compared],
         ("reference", ref_path, "mesh" if kind == "mesh" else "cloud")],
        crs_from=[*compared, ref_path],
        settings=[("distance", title), ("max distance (m)",
                                        "none" if args.max_dist is None
                                        else f"{args.max_dist:g}")])
    say(args, md.rstrip() + f"\n-> {out}/ (stats.csv, stats.md/.html, histogram.png, "
                            "*_distance.laz with scalar field 'distance')")
    return 0


def _compare_tiled(args, compared, ref_path, crs) -> int:
    """compare --tile-m: the reference cloud spilled into tiles with a halo of
    --max-dist (or the mesh sent once), each compared cloud spilled and compared tile by
    tile on the executor, then written in its own order (``survey.cluster.compare``)."""
    from survey.analysis.developed import is_mesh_file
    from sensors.io.clouds import iter_points

    from survey.cluster import TaskProgress
    from survey.cluster.compare import spill_cloud, tiled_distances

    mesh = is_mesh_file(ref_path)
    if mesh and (args.split or args.model):
        raise TunnelsimCLIError("Expected --split/--model only with a reference cloud, got "
                                "a mesh (cloud-to-mesh distances are signed, not split).")
    if not mesh and args.max_dist is None:
        raise TunnelsimCLIError("Expected --max-dist with --tile-m and a reference cloud "
                                "(the nearest point is looked for within it: the tiles' "
                                "halo), got none.")
    if args.model:
        raise TunnelsimCLIError("Expected --tile-m without --model (a plane's k "
                                "neighbours can lie beyond a tile's halo), got both.")
    if not mesh and args.max_dist > args.tile_m:
        import warnings

        warnings.warn(f"--max-dist {args.max_dist:g} m is larger than --tile-m "
                      f"{args.tile_m:g} m: each tile reads its neighbours' points within "
                      "it too, so memory and time grow with (1 + 2 max-dist / tile)^2; "
                      "--max-dist is in metres (0.05 for 5 cm).", UserWarning,
                      stacklevel=2)
    out = out_dir(args.output, args.force)
    ref, kind, spill = None, "mesh", None
    if mesh:
        ref, kind = _load_reference(ref_path)
    else:
        kind = "cloud"
        spill = spill_cloud(iter_points(ref_path), args.tile_m, args.max_dist, folder=out)
    try:
        counts = _compared_boxes(args, compared, ref if ref is not None else spill)
        tiled = {}
        with open_cluster(args) as ex:
            for c, n in zip(compared, counts):
                bar = TaskProgress(args.quiet, unit=f"tiles of {Path(c).name}")
                try:
                    tiled[c] = tiled_distances(
                        iter_points(c), n, tile_m=args.tile_m, reference=spill, mesh=ref,
                        max_distance_m=args.max_dist, split=args.split, executor=ex,
                        folder=out, progress=bar)
                finally:
                    bar.close()
    finally:
        if spill is not None:
            spill.close()
    try:
        rows, hist = _distances(args, compared, None, kind, out, lambda n: None, crs,
                                tiled=tiled)
    finally:
        for t in tiled.values():
            t.close()
    return _compare_outputs(args, ref_path, kind, out, rows, hist)


def _distances(args, compared, ref, kind, out, progress, crs=None, tiled=None):
    """Write each compared cloud with its distances (``NAME_distance.laz``, stating the
    cloud's CRS ``crs[path]``), block by block (``progress(points done)`` after each);
    returns (stats rows, distances) by cloud name. ``tiled``: {path: TiledDistances}
    computed before (``compare --tile-m``), read in the cloud's order."""
    import numpy as np

    from survey.analysis.compare import BLOCK, Distances, distance_stats
    from sensors.io.clouds import annotate_las, iter_points, write_points_las

    rows, hist = {}, {}
    done = 0
    for c in compared:
        name = Path(c).stem
        got: list = []
        pos = 0

        def dist(xyz, got=got, c=c):
            nonlocal done, pos
            if tiled is not None:
                t, sl = tiled[c], slice(pos, pos + len(xyz))
                pos += len(xyz)
                r = Distances(np.array(t.distance[sl]), np.zeros(len(xyz), np.int64))
                if t.diff is not None:
                    r.dx, r.dy, r.dz = (np.array(t.diff[sl, i]) for i in range(3))
            elif kind == "mesh":
                r = ref.distances(xyz, max_distance_m=args.max_dist)
            else:
                r = ref.distances(xyz, max_distance_m=args.max_dist, split=args.split,
                                  model=args.model, k=args.k)
            got.append(r.distance)
            extra = {"distance": r.distance.astype(np.float32)}
            if args.split:
                extra.update(dx=r.dx.astype(np.float32), dy=r.dy.astype(np.float32),
                             dz=r.dz.astype(np.float32))
            done += len(xyz)
            progress(done)
            return extra

        dst = out / f"{name}_distance.laz"
        if Path(c).suffix.lower() in (".las", ".laz"):
            # Streamed, and every input field (intensity, time, classes...) kept; blocks
            # of BLOCK points for the progress bar.
            annotate_las(c, dst, dist, chunk=BLOCK)
        else:
            parts = list(iter_points(c, chunk=BLOCK))
            extras = [dist(p) for p in parts]
            write_points_las(dst, np.concatenate(parts),
                             {k: np.concatenate([e[k] for e in extras])
                              for k in extras[0]}, crs=(crs or {}).get(c))
        rows[name] = distance_stats(np.concatenate(got))
        hist[name] = np.concatenate(got)
    return rows, hist


# ---------------------------------------------------------------------------- plan
def cmd_plan(args) -> int:
    import numpy as np

    from sensors import load_sensor
    from survey.analysis.planning import Planner, RoutePlanner, Thresholds
    from survey.clouds.axis import tunnel_frame
    from survey.report.planning import (
        plan_csv,
        plan_markdown,
        plan_summary,
        plot_coverage,
    )

    from survey.cli.common import warn_radian_like

    warn_radian_like(args.incidence_deg, "--incidence-deg")
    spec = load_sensor(args.sensor)
    cell_m, cell_deg = pair(args.cell, "--cell as M,DEG")
    spacings = floats(args.spacing, "--spacing")
    offsets = floats(args.offsets, "--offsets")
    th = Thresholds(args.spacing_mm / 1000.0, np.deg2rad(args.incidence_deg), args.range)
    along = _along(args)
    if along == "auto":
        from sensors.io.meshes import load_mesh

        wp = _waypoints(args)
        scene, _ = load_mesh(args.mesh)
        pl: Planner = RoutePlanner(scene, spec, waypoints=wp, resolution=args.resolution,
                                   thresholds=th, sample_m=cell_m, height_m=args.height,
                                   clearance_m=args.clearance)
    else:
        scene, _, al, hc = tunnel_frame(args.mesh)
        pl = Planner(scene, al, hc, spec, resolution=args.resolution, thresholds=th,
                     cell_m=cell_m, cell_rad=np.deg2rad(cell_deg), height_m=args.height)
    out = out_dir(args.output, args.force)
    sets = [pl.spaced(sp) for sp in spacings]
    cand = None
    if args.optimize:
        if isinstance(pl, RoutePlanner):
            side = np.abs(np.asarray(offsets))
            cand = pl.candidates(args.candidate_step, np.concatenate([side, -side]))
        else:
            cand = pl.spaced(args.candidate_step)
    with open_cluster(args) as ex:
        if ex.kind != "in-process":
            _fan_out_stations(ex, pl, [*sets, *([] if cand is None else [cand])], out,
                              args.quiet)
    plans = [pl.evaluate(c, f"every {sp:g} m") for c, sp in zip(sets, spacings)]
    info = None
    if cand is not None:
        best, greedy, info = pl.optimize(cand, target=args.target,
                                         time_limit_s=args.time_limit)
        plans += [best, greedy]
    write_text(out / "plan.csv", "".join(
        plan_csv(p, pl) if i == 0 else plan_csv(p, pl).split("\n", 1)[1]
        for i, p in enumerate(plans)))
    md = plan_markdown(plans, pl, info)
    plot_coverage(plans, pl, out / "coverage.png")
    write_headed_report(args, out / "plan.md", md, [("mesh", args.mesh, "")],
                        crs_from=[args.mesh])
    write_json(out / "plan.json", plan_summary(plans, pl, info))
    files = "plan.csv, plan.md, plan.json, coverage.png"
    if isinstance(pl, RoutePlanner):
        pl.route.write_csv(out / "route.csv")
        files += ", route.csv"
    say(args, md.split("\n## Largest")[0].rstrip() + f"\n-> {out}/ ({files})")
    return 0


def _fan_out_stations(ex, pl, chainage_sets, out, quiet) -> None:
    """Compute the station qualities every plan will need as tasks on ``ex`` (the
    planner, with its scene and cells, sent once) and give them to the planner; the
    plans are then the same as computed one by one here."""
    import numpy as np

    from survey.cluster import TaskProgress, call_shared

    need = pl.uncached(np.concatenate([pl.stations_at(c) for c in chainage_sets
                                       if len(c)] or [np.zeros((0, 3))]))
    ref = ex.share(pl, out)
    bar = TaskProgress(quiet, unit="stations")
    try:
        got = ex.map(call_shared, [(ref, "quality", (p,)) for p in need], progress=bar)
    finally:
        bar.close()
    pl.remember(need, got)


# ---------------------------------------------------------------------------- study
def cmd_study(args) -> int:
    from sensors import Settings, load_sensor
    from survey.analysis.study import Study
    from survey.clouds.axis import tunnel_frame
    from survey.report.study import plot_study, study_csv, study_markdown

    spec = load_sensor(args.sensor)
    strip = None
    if args.strip:
        a, b = pair(args.strip, "--strip as START,END in m")
        strip = (a, b)
    speeds = floats(args.speeds, "--speeds")
    rates = floats(args.rates, "--rates")
    mounts = [m.strip() for m in args.mounts.split(",") if m.strip()]
    kw = dict(strip_m=strip, lead_m=args.lead,
              settings=Settings.ideal() if args.ideal else None, seed=args.seed,
              keep_points=40_000)
    route = None
    if _along(args) == "auto":
        from sensors.io.meshes import load_mesh
        from sensors.route import find_route

        wp = _waypoints(args)
        scene, refl = load_mesh(args.mesh)
        route = find_route(scene, waypoints=wp, height_m=args.height)
        st = Study.along_route(scene, route, spec, sample_m=args.cell,
                               reflectivity=refl if refl is not None else 0.5, **kw)
    else:
        scene, refl, al, hc = tunnel_frame(args.mesh)
        st = Study(scene, al, hc, spec, height_m=args.height, cell_m=args.cell,
                   reflectivity=refl if refl is not None else 0.5, **kw)
    out = out_dir(args.output, args.force)

    def progress(i, n):
        if not args.quiet and sys.stderr.isatty():
            sys.stderr.write(f"\rstudy: {i}/{n} configurations ")
            sys.stderr.flush()

    with open_cluster(args) as ex:
        if ex.kind == "in-process":
            rows = st.grid(speeds, rates, mounts, progress=progress)
        else:
            from survey.cluster import call_shared

            combos = st.configurations(speeds, rates, mounts)
            ref = ex.share(st, out)
            got = ex.map(call_shared, [(ref, "run_kept", c) for c in combos],
                         progress=progress)
            rows = [row for row, _ in got]
            for (v, f, m), (_, kp) in zip(combos, got):
                if kp is not None:
                    st.kept[(float(v), float(f), m)] = kp
    if not args.quiet and sys.stderr.isatty():
        sys.stderr.write("\n")
    write_text(out / "study.csv", study_csv(rows))
    md = study_markdown(rows, spec.name, st.strip_m, st.lead_m, route=route)
    plot_study(st, rows, out / "study.png", rings_mount="down" if "down" in mounts else None,
               rings_rate=rates[0])
    write_headed_report(args, out / "study.md", md, [("mesh", args.mesh, "")],
                        crs_from=[args.mesh], settings=[("sensor", spec.name)])
    files = "study.csv, study.md, study.png"
    if route is not None:
        route.write_csv(out / "route.csv")
        files += ", route.csv"
    say(args, md.rstrip() + f"\n-> {out}/ ({files})")
    return 0


__all__ = ["cmd_compare", "cmd_plan", "cmd_study", "register"]
