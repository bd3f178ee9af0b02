"""Commands that analyse: compare (C2C / C2M), plan (TLS stations), study (MLS speeds)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from survey.errors import TunnelsimCLIError
from survey.cli.main import _parse_window
from survey.clouds.axis import tunnel_frame


def out_dir(path, force=False) -> Path:
    """An output folder: created when missing; an existing, non-empty one only with
    ``force`` (files in it are then replaced one by one, atomically)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise TunnelsimCLIError(f"Expected an output folder, got '{p}' which is a file; "
                                "choose another name.")
    if p.is_dir() and any(p.iterdir()) and not force:
        raise TunnelsimCLIError(f"Expected a new or empty output folder, got '{p}' which "
                                "holds files; pass --force to replace them.")
    if not p.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing parent folder for '{p}', got none; "
                                "create it first.")
    p.mkdir(exist_ok=True)
    return p


def _floats(text, what):
    try:
        vals = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        vals = []
    if not vals:
        raise TunnelsimCLIError(f"Expected {what} as comma-separated numbers, got {text!r}.")
    return vals


def _say(args, text):
    if not getattr(args, "quiet", False):
        print(text)


# ---------------------------------------------------------------------------- compare
def _load_reference(path):
    p = Path(path)
    if p.suffix.lower() in (".ply", ".obj", ".stl", ".off"):
        import trimesh

        if not p.is_file():
            raise TunnelsimCLIError(f"Expected a reference cloud or mesh, got '{p}' which "
                                    "does not exist.")
        try:
            m = trimesh.load(str(p), process=False)
        except Exception as exc:   # trimesh raises many types
            raise TunnelsimCLIError(f"Expected a readable reference, got '{p}' which failed "
                                    f"with: {exc}") from exc
        faces = getattr(m, "faces", None)
        if faces is not None and len(faces):
            from survey.analysis.compare import ReferenceMesh
            return ReferenceMesh(np.asarray(m.vertices), np.asarray(faces)), "mesh"
    from survey.clouds.cloudio import iter_points
    from survey.analysis.compare import ReferenceCloud
    return ReferenceCloud(np.concatenate(list(iter_points(p)))), "cloud"


def cmd_compare(args) -> int:
    from raytrace import set_threads

    from survey.clouds.cloudio import annotate_las, iter_points, write_points_las
    from survey.analysis.compare import distance_stats
    from survey.report.compare import plot_histogram, stats_csv, stats_markdown
    from survey.cli.main import _write_text

    if len(args.clouds) < 2:
        raise TunnelsimCLIError("Expected at least two paths (compared cloud(s), then the "
                                f"reference), got {len(args.clouds)}.")
    if args.threads:
        set_threads(args.threads)
    *compared, ref_path = args.clouds
    for c in compared:
        if not Path(c).is_file():
            raise TunnelsimCLIError(f"Expected a compared cloud, got '{c}' which does not "
                                    "exist.")
    ref, kind = _load_reference(ref_path)
    if kind == "mesh" and (args.split or args.model):
        raise TunnelsimCLIError("Expected --split/--model only with a reference cloud, got "
                                "a mesh (cloud-to-mesh distances are signed, not split).")
    out = out_dir(args.output, args.force)
    rows, hist = {}, {}
    for c in compared:
        name = Path(c).stem
        got = []

        def dist(xyz):
            if kind == "mesh":
                r = ref.distances(xyz, max_dist=args.max_dist)
            else:
                r = ref.distances(xyz, max_dist=args.max_dist, split=args.split,
                                  model=args.model, k=args.k)
            got.append(r.distance)
            extra = {"distance": r.distance.astype(np.float32)}
            if args.split:
                extra.update(dx=r.dx.astype(np.float32), dy=r.dy.astype(np.float32),
                             dz=r.dz.astype(np.float32))
            return extra

        dst = out / f"{name}_distance.laz"
        if Path(c).suffix.lower() in (".las", ".laz"):
            # Streamed, and every input field (intensity, time, classes...) kept.
            annotate_las(c, dst, dist)
        else:
            pts = np.concatenate(list(iter_points(c)))
            write_points_las(dst, pts, dist(pts))
        rows[name] = distance_stats(np.concatenate(got))
        hist[name] = np.concatenate(got)
    title = "C2M (signed)" if kind == "mesh" else "C2C"
    _write_text(out / "stats.csv", stats_csv(rows))
    md = stats_markdown(rows, title=title)
    _write_text(out / "stats.md", f"# {title} distances to {Path(ref_path).name}\n\n" + md +
                ("" if args.max_dist is None else
                 f"\nDistances beyond {args.max_dist} m are clamped to it.\n"))
    plot_histogram(hist, out / "histogram.png",
                   xlabel=f"{title} distance to {Path(ref_path).name} (mm)")
    _say(args, md.rstrip() + f"\n-> {out}/ (stats.csv, stats.md, histogram.png, "
                             "*_distance.laz with scalar field 'distance')")
    return 0


# ---------------------------------------------------------------------------- plan
def cmd_plan(args) -> int:
    from raytrace import set_threads
    from sensors import load_sensor

    from survey.cli.main import _write_text
    from survey.report.planning import plan_csv, plan_markdown, plot_coverage
    from survey.analysis.planning import Planner, Thresholds

    if args.threads:
        set_threads(args.threads)
    spec = load_sensor(args.sensor)
    cell_m, cell_deg = _parse_window(args.cell.replace(",", ":"), "--cell as M,DEG", 2)
    scene, _, al, hc = tunnel_frame(args.mesh)
    th = Thresholds(args.spacing_mm / 1000.0, np.deg2rad(args.incidence_deg), args.range)
    pl = Planner(scene, al, hc, spec, resolution=args.resolution, thresholds=th,
                 cell_m=cell_m, cell_rad=np.deg2rad(cell_deg), height_m=args.height)
    out = out_dir(args.output, args.force)
    plans = [pl.evaluate(pl.spaced(sp), f"every {sp:g} m")
             for sp in _floats(args.spacing, "--spacing")]
    info = None
    if args.optimize:
        cand = pl.spaced(args.candidate_step)
        best, greedy, info = pl.optimize(cand, target=args.target,
                                         time_limit_s=args.time_limit)
        plans += [best, greedy]
    _write_text(out / "plan.csv", "".join(
        plan_csv(p, pl) if i == 0 else plan_csv(p, pl).split("\n", 1)[1]
        for i, p in enumerate(plans)))
    md = plan_markdown(plans, pl, info)
    _write_text(out / "plan.md", md)
    plot_coverage(plans, pl, out / "coverage.png")
    import json
    _write_text(out / "plan.json", json.dumps({
        "sensor": spec.name, "resolution": pl.resolution,
        "plans": [{"name": p.name, "stations": len(p.chainages), "coverage": p.coverage,
                   "gaps": len(p.gaps), "chainages_m": p.chainages.tolist()}
                  for p in plans],
        "optimisation": info}, indent=2, default=float) + "\n")
    _say(args, md.split("\n## Largest")[0].rstrip() +
         f"\n-> {out}/ (plan.csv, plan.md, plan.json, coverage.png)")
    return 0


# ---------------------------------------------------------------------------- study
def cmd_study(args) -> int:
    from raytrace import set_threads
    from sensors import Settings, load_sensor

    from survey.cli.main import _write_text
    from survey.analysis.study import Study
    from survey.report.study import plot_study, study_csv, study_markdown

    if args.threads:
        set_threads(args.threads)
    spec = load_sensor(args.sensor)
    scene, refl, al, hc = tunnel_frame(args.mesh)
    strip = None
    if args.strip:
        strip = _parse_window(args.strip.replace(",", ":"), "--strip as START,END in m", 2)
    mounts = [m.strip() for m in args.mounts.split(",") if m.strip()]
    st = Study(scene, al, hc, spec, strip=strip, lead_m=args.lead, height_m=args.height,
               settings=Settings.ideal() if args.ideal else None, seed=args.seed,
               reflectivity=refl if refl is not None else 0.5, keep_points=40_000)
    out = out_dir(args.output, args.force)
    speeds = _floats(args.speeds, "--speeds")
    rates = _floats(args.rates, "--rates")

    def progress(i, n):
        if not args.quiet and sys.stderr.isatty():
            sys.stderr.write(f"\rstudy: {i}/{n} configurations ")
            sys.stderr.flush()

    rows = st.grid(speeds, rates, mounts, progress=progress)
    if not args.quiet and sys.stderr.isatty():
        sys.stderr.write("\n")
    _write_text(out / "study.csv", study_csv(rows))
    md = study_markdown(rows, spec.name, st.strip, st.lead)
    _write_text(out / "study.md", md)
    plot_study(st, rows, out / "study.png", rings_mount="down" if "down" in mounts else None,
               rings_rate=rates[0])
    _say(args, md.rstrip() + f"\n-> {out}/ (study.csv, study.md, study.png)")
    return 0
