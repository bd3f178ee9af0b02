"""Commands on point clouds: preprocess (voxel grid, outliers), mesh (reconstruction)."""

from __future__ import annotations

from survey.cli.common import CommandSet, pair, write_json

#: Cloud formats the readers take.
CLOUD_INPUTS = ".las/.laz/.ply/.xyz/.npz/.e57"


def register(commands: CommandSet) -> None:
    """Add preprocess and mesh."""
    c = commands.add(
        "preprocess", cmd_preprocess,
        help="voxel-grid downsampling and outlier removal of a cloud",
        description="Stream a cloud (LAS/LAZ/PLY/XYZ/NPZ/E57) through a voxel grid "
                    "(centroid per voxel, Open3D semantics), then remove statistical and "
                    "radius outliers (Open3D semantics) and write LAS/LAZ with the number "
                    "of points per voxel.",
        epilog="Example: tunnelsim preprocess mls.laz -o clean.laz --voxel 0.02 --sor 8,2.0 "
               "--segment")
    c.option("cloud", path="in", help="input cloud")
    c.option("-o", "--output", required=True, path="out", help="output cloud (.las/.laz)")
    c.option("--voxel", type=float, metavar="M", help="voxel size in metres")
    c.option("--sor", metavar="K,STD_RATIO",
             help="statistical outlier removal: K neighbours (the point included), "
                  "threshold mean + STD_RATIO x std")
    c.option("--ror", metavar="N,RADIUS_M",
             help="radius outlier removal: at least N other points within RADIUS_M")
    c.option("--crop", metavar="START,END",
             help="keep the chainage range START..END in m (axis from --tunnel-json or "
                  "estimated)")
    c.option("--segment", action="store_true",
             help="classify lining (64), floor (2), attachments (65), objects (66), "
                  "terrain beyond a portal (67), noise (7) as LAS classification")
    c.option("--tunnel-json", path="in",
             help="alignment for --segment from a generated tunnel's JSON (default: "
                  "estimated from the cloud)")
    c.option("--quiet", action="store_true", help="print nothing on success")

    c = commands.add(
        "mesh", cmd_mesh, help="reconstruct a mesh from cleaned clouds (tunnels, caves)",
        description="Tunnel-aware reconstruction (--method tunnel): unroll the lining "
                    "around the centreline (estimated, or from a tunnel JSON), take a "
                    "median radius per cell, fill gaps (vertex property support = 0), "
                    "triangulate; open portals, found from the data (where the rings stop "
                    "being lining: terrain beyond a portal is left out). Solid "
                    "reconstruction (--method solid) of any space, caves and mines "
                    "included: screened Poisson with normals oriented towards the "
                    "scanner of each point (a station's pose from its LAS/PLY/E57 file, "
                    "the trajectory at each point's time, or the "
                    "nearest of --scanners), trimmed where no point lies within --trim, "
                    "support 0 where it filled a hole. --method auto (default): the "
                    "tunnel mesher when --tunnel-json is given or a tunnel axis is found, "
                    "judged on its result (extrapolated share, points off the tube, "
                    "surface far from the points) and replaced by solid when the fit is "
                    "poor (a branching mine); else solid. --max-triangles and "
                    "--max-error compact the mesh of any method by quadric decimation "
                    "(Open3D), the error measured after.",
        epilog="Example: tunnelsim mesh clean.laz -o tunnel.ply --cell 0.1,2 (or "
               "tunnelsim mesh st01.laz st02.laz st03.laz -o cave.ply --method solid; "
               "tunnelsim mesh drive.laz -o mine.ply --trajectory drive_true_trajectory.txt; "
               "tunnelsim mesh st*.laz -o mine.ply --max-triangles 200000 --max-error 0.02)")
    c.option("cloud", nargs="+", metavar="CLOUD", path="in",
             help=f"input cloud(s) ({CLOUD_INPUTS}); several: e.g. one file per station")
    c.option("-o", "--output", required=True, path="out", help="output mesh (.ply)")
    c.option("--method", choices=["auto", "tunnel", "poisson", "solid"], default="auto",
             help="auto (default): tunnel if an axis is given or found and the tunnel "
                  "fit is good, else solid (the JSON says which and why); "
                  "tunnel: tunnel-aware mesher; poisson: Open3D Poisson oriented by the "
                  "tunnel axis; solid: Poisson oriented by the scanners (any space)")
    c.option("--cell", metavar="M,DEG",
             help="tunnel: cell size along the axis (m) and around it (deg); default "
                  "0.1,2, or for a profile cloud (profiles with gaps between them) the "
                  "profiles' spacing along the axis, said when chosen")
    c.option("--detail", action="store_true",
             help="tunnel: add a detail layer: attachments (cables, pipes) as closed tubes "
                  "(vertex support -1)")
    c.option("--depth", type=int, default=10,
             help="poisson: octree depth (default 10)")
    c.option("--triangles", type=int, metavar="N",
             help="tunnel: triangle budget: coarsen the cells until the mesh fits")
    c.option("--max-triangles", type=int, metavar="N",
             help="any method: quadric decimation (Garland & Heckbert, Open3D) to at "
                  "most N triangles; the error to the undecimated mesh is measured and "
                  "reported")
    c.option("--max-error", type=float, metavar="M",
             help="any method: the fewest triangles (within --max-triangles if given) "
                  "whose measured error to the undecimated mesh (symmetric, at vertices "
                  "and face centres) is at most M metres")
    c.option("--min-points", type=int, default=3,
             help="tunnel: cells with fewer points are interpolated (default 3)")
    c.option("--tunnel-json", path="in", help="use the alignment of a generated tunnel's JSON")
    c.option("--voxel", type=float, default=0.02, metavar="M",
             help="voxel grid (m) the clouds stream through while they are read "
                  "(centroid and point count per voxel; the tunnel mesher weights each "
                  "voxel by its count), so the peak memory is about 170 bytes per "
                  "occupied voxel (about lining area / M^2 voxels), whatever the number "
                  "of points; solid: also the finest "
                  "Poisson cell. Default 0.02; 0: no grid, every point in memory "
                  "(tunnel and poisson only)")
    c.option("--trim", type=float, metavar="M",
             help="solid: remove the surface farther than M from every point (default 5 "
                  "voxels, at least 0.3 m): holes up to about 2 M wide stay filled")
    c.option("--trajectory", path="in",
             help="solid: the platform trajectory (TUM .txt or .csv, e.g. a drive's "
                  "_true_trajectory.txt): the scanner at each point's gps_time")
    c.option("--scanners", path="in", metavar="FILE",
             help="solid: scanner positions (x y z per row, a route CSV or a TUM file) for "
                  "clouds that record none; each point takes the nearest")
    c.option("--json", path="out", help="also write the reconstruction quality as JSON")
    c.option("--figure", metavar="PNG", path="out",
             help="tunnel: also write the unrolled support map (points per cell) as PNG")
    c.option("--quiet", action="store_true", help="print nothing on success")


def _tunnel_axis(path):
    """(Alignment, profile-centre height) from a tunnel JSON, or (None, None)."""
    if not path:
        return None, None
    from survey.world.mesh import read_axis

    return read_axis(path)


def cmd_preprocess(args) -> int:
    import numpy as np

    from sensors.io.clouds import cloud_bounds
    from survey.clouds.preprocess import (
        VoxelGrid,
        extra_dims,
        iter_points_extra,
        radius_outliers,
        statistical_outliers,
        write_preprocessed,
    )

    lo, _hi, n_in = cloud_bounds(args.cloud)
    # The input's extra dimensions (LAS/LAZ extra bytes) travel with the points.
    dims = extra_dims(args.cloud)
    if args.voxel is not None:
        grid = VoxelGrid(args.voxel, lo)
        for xyz, f in iter_points_extra(args.cloud):
            grid.add(xyz, f)
        pts, counts = grid.result()
        extra = grid.fields()
    else:
        parts = list(iter_points_extra(args.cloud))
        pts = np.concatenate([p for p, _ in parts])
        extra = {k: np.concatenate([f[k] for _, f in parts]) for k in dims}
        counts = np.ones(len(pts), dtype=np.int64)
    keep = np.ones(len(pts), dtype=bool)
    if args.crop:
        s0, s1 = pair(args.crop, "--crop as START,END in m")
        al, _ = _tunnel_axis(args.tunnel_json)
        if al is None:
            from survey.clouds.axis import estimate_axis
            al, _ = estimate_axis(pts)
        s, _, _ = al.to_local(pts)
        keep &= (s >= s0) & (s <= s1)
    if args.sor:
        k, ratio = pair(args.sor, "--sor as K,STD_RATIO")
        keep &= ~statistical_outliers(pts, k=int(k), std_ratio=ratio)
    if args.ror:
        nb, rad = pair(args.ror, "--ror as N,RADIUS_M")
        keep &= ~radius_outliers(pts, min_neighbours=int(nb), radius_m=rad)
    cls = None
    if args.segment:
        from survey.clouds.segment import segment_tunnel

        al, hc = _tunnel_axis(args.tunnel_json)
        cls = segment_tunnel(pts[keep], alignment=al, centre_height_m=hc)
    write_preprocessed(args.output, pts[keep], counts[keep],
                       {k: v[keep] for k, v in extra.items()}, dims, classification=cls)
    if not args.quiet:
        print(f"{n_in:,} points -> {len(pts):,} after the voxel grid -> {int(keep.sum()):,} "
              f"after outlier removal -> {args.output}")
        if cls is not None:
            from survey.clouds.segment import CLASS_NAMES

            u, c = np.unique(cls, return_counts=True)
            print("classes: " + ", ".join(f"{CLASS_NAMES[k]} ({k}) {v:,}"
                                          for k, v in zip(u.tolist(), c.tolist())))
    return 0


#: The tunnel mesher's cells without --cell (m along the axis, degrees around it).
DEFAULT_CELL = (0.1, 2.0)


def _default_cell(args, pts, al) -> tuple[float, float, str]:
    """--cell when not given: ``DEFAULT_CELL``, or for a profile cloud one cell per
    profile along the axis (``survey.analysis.developed.station_spacing``). DECISION: a
    cell shorter than the profiles' spacing leaves most columns without a point, and
    the mesher then interpolates them: on the real Ringo profiles (0.5 m) 0.1 m cells
    were 80 % interpolated, 0.5 m cells 2.9 % (issue 31)."""
    from survey.analysis.developed import station_spacing

    ax = al
    if ax is None:
        from survey.clouds.axis import estimate_axis

        ax, _ = estimate_axis(pts)
    s, _, _ = ax.to_local(pts)
    spacing = station_spacing(s)
    if spacing <= DEFAULT_CELL[0]:
        return (*DEFAULT_CELL, "default (no profile spacing above it)")
    cell = round(float(spacing), 3)
    how = f"a profile cloud, profiles every {spacing:.3f} m"
    if not args.quiet:
        print(f"cell: {cell:g} m along the axis ({how}) x {DEFAULT_CELL[1]:g} deg; "
              "--cell M,DEG sets it")
    return cell, DEFAULT_CELL[1], how


#: Options of one method that another method does not take (a silent no-op would
#: let a user believe they acted).
_METHOD_ONLY = {"tunnel": ("detail", "triangles", "figure"),
                "solid": ("trim", "trajectory", "scanners")}


def _check_method_options(args, method: str) -> None:
    """Refuse an option of another method than the one that runs (auto resolved)."""
    from survey.cli.common import UsageError

    for m, names in _METHOD_ONLY.items():
        given = [n for n in names if getattr(args, n) not in (None, False)]
        if given and method != m:
            how = "" if args.method == method else f" (--method {args.method} chose it)"
            raise UsageError(f"Expected --{given[0]} with --method {m}, got --method "
                             f"{method}{how}; pass --method {m}.")


def _mesh_method(args, pts) -> tuple[str, str]:
    """(method, reason): the method --method auto first tries: tunnel when --tunnel-json
    is given or the cloud has a tunnel axis (``estimate_axis`` succeeds), else solid;
    the tunnel mesh is judged afterwards (``cmd_mesh``)."""
    if args.method != "auto":
        return args.method, f"--method {args.method} asked"
    if args.tunnel_json:
        return "tunnel", "--tunnel-json gives the axis"
    from survey.clouds.axis import estimate_axis
    from survey.errors import ReconstructionError

    try:
        estimate_axis(pts)
    except ReconstructionError as exc:
        return "solid", f"no tunnel axis found ({exc})"
    return "tunnel", "a tunnel axis was found"


def _check_compact(args) -> None:
    """Refuse a bad --max-triangles / --max-error before the reconstruction runs."""
    import numpy as np

    from survey.cli.common import UsageError
    from survey.clouds.decimate import MIN_TRIANGLES

    if args.max_triangles is not None and args.max_triangles < MIN_TRIANGLES:
        raise UsageError(f"Expected --max-triangles >= {MIN_TRIANGLES}, got "
                         f"{args.max_triangles}; pass a larger --max-triangles.")
    if args.max_error is not None and not (np.isfinite(args.max_error)
                                           and args.max_error > 0):
        raise UsageError(f"Expected a positive --max-error (m), got {args.max_error:g}; "
                         "pass e.g. --max-error 0.02.")


def _compact(args, vertices, faces, support, points):
    """The mesh decimated as --max-triangles / --max-error ask (or as it is), the
    support carried to the nearest original vertex, and the "decimation" JSON block
    (None when nothing was asked), with the input points' distances to the result."""
    import numpy as np

    if args.max_triangles is None and args.max_error is None:
        return vertices, faces, support, None
    from survey.clouds.decimate import decimate_mesh, point_mesh_distances

    dec = decimate_mesh(vertices, faces, max_triangles=args.max_triangles,
                        max_error_m=args.max_error)
    sup = None if support is None else np.asarray(support)[dec.nearest_original]
    p = np.asarray(points, dtype=np.float64)
    if len(p) > 200_000:
        p = p[np.random.default_rng(0).choice(len(p), 200_000, replace=False)]
    origin = np.round(p.mean(axis=0))
    d = point_mesh_distances(p - origin, dec.vertices - origin, dec.faces)
    block = dict(dec.quality, points_to_mesh={
        "median_m": float(np.median(d)), "p95_m": float(np.percentile(d, 95)),
        "max_m": float(d.max()), "points": int(len(p))})
    return dec.vertices, dec.faces, sup, block


def _print_compact(block) -> None:
    e = block["error"]
    a, b = e["original_to_decimated"], e["decimated_to_original"]
    print(f"decimated {block['triangles_before']:,} -> {block['triangles']:,} triangles "
          f"(quadric, Open3D, {block['tries']} tries): undecimated -> decimated median "
          f"{a['median_m'] * 1000:.1f} mm, 95 % {a['p95_m'] * 1000:.1f} mm, max "
          f"{a['max_m'] * 1000:.1f} mm; back: median {b['median_m'] * 1000:.1f} mm, 95 % "
          f"{b['p95_m'] * 1000:.1f} mm, max {b['max_m'] * 1000:.1f} mm; points -> mesh "
          f"median {block['points_to_mesh']['median_m'] * 1000:.1f} mm")


def _fallback_possible(args, clouds, why: str) -> None:
    """Refuse the solid fallback when a cloud records no scanner position."""
    from survey.cli.common import UsageError
    from survey.clouds.scanners import station_position

    for c in clouds:
        if station_position(c) is None:
            raise UsageError(f"Expected scanner positions for the solid route --method "
                             f"auto falls back to ({why}), got '{c}' that records no "
                             "station pose; pass --scanners FILE or --trajectory FILE, or "
                             "--method tunnel to keep the tunnel mesh.")


def _read_reduced(clouds, voxel_m: float):
    """(points (m, 3), counts (m,) int64 or None, input points) of the clouds streamed
    through a voxel grid of ``voxel_m`` (centroid and count per voxel,
    ``survey.clouds.preprocess.VoxelGrid``), or every point when ``voxel_m`` is 0.

    Memory bound: one bounds pass, then the grid holds 40 bytes per occupied voxel
    (key, three sums, count), about three times that while chunks merge, plus one chunk
    of points (``cloudio.CHUNK``); the occupied voxels are about lining area /
    voxel_m^2 (times the noise's thickness in voxels), whatever the number of points.
    The mesher then needs ~90 bytes a voxel. Measured peak RSS of ``tunnelsim mesh``
    (a 5 m tube 300 m long, 2 mm noise, 2 cm voxels): 1.26 GB for 10^7 points (8.4 M
    voxels), 2.53 GB for 3 x 10^7 (18.4 M), 4.74 GB for 10^8 (29.0 M); every point in
    memory (``voxel_m`` 0) costs ~86 bytes a point (2.58 GB for 3 x 10^7).
    """
    import numpy as np

    from sensors.io.clouds import cloud_bounds, iter_points
    from survey.clouds.preprocess import VoxelGrid
    from survey.errors import ReconstructionError

    if not (np.isfinite(voxel_m) and voxel_m >= 0):
        raise ReconstructionError(f"Expected --voxel >= 0 (m), got {voxel_m:g}.")
    if voxel_m == 0:
        pts = np.concatenate([xyz for c in clouds for xyz in iter_points(c)])
        return pts, None, len(pts)
    lo = np.min([cloud_bounds(c)[0] for c in clouds], axis=0)
    grid = VoxelGrid(voxel_m, lo)
    n_in = 0
    for c in clouds:
        for xyz in iter_points(c):
            grid.add(xyz)
            n_in += len(xyz)
    pts, counts = grid.result()
    return pts, counts, n_in


def cmd_mesh(args) -> int:
    import numpy as np

    clouds = list(args.cloud)
    _check_compact(args)
    method = args.method
    choice: dict = {"method_asked": args.method}
    if method == "auto" and not args.tunnel_json and (args.trajectory or args.scanners):
        method = "solid"           # scanner positions are what the solid route asks for
        choice["method_reason"] = "scanner positions given (--trajectory/--scanners)"
    if method == "solid":
        _check_method_options(args, method)
        choice.setdefault("method_reason", "--method solid asked")
        return _mesh_solid(args, clouds, choice)
    pts, counts, n_in = _read_reduced(clouds, args.voxel)
    method, choice["method_reason"] = _mesh_method(args, pts)
    _check_method_options(args, method)
    if method == "solid":
        del pts
        return _mesh_solid(args, clouds, choice)
    al, hc = _tunnel_axis(args.tunnel_json)
    if method == "poisson":
        from survey.clouds.reconstruct import poisson_tunnel
        from survey.world.mesh import write_ply

        v, f = poisson_tunnel(pts, alignment=al, centre_height_m=hc, depth=args.depth)
        v, f, _, block = _compact(args, v, f, None, pts)
        write_ply(args.output, v, f)
        if args.json:
            write_json(args.json, {"method": "poisson", **choice, "points": int(n_in),
                                   "triangles": int(len(f)), "decimation": block})
        if not args.quiet:
            print(f"{n_in:,} points -> {len(f):,} triangles (Poisson, depth "
                  f"{args.depth}, trimmed) -> {args.output}")
            if block:
                _print_compact(block)
        return 0
    from survey.clouds.reconstruct import reconstruct_within_budget

    if args.cell is not None:
        cell_m, cell_deg = pair(args.cell, "--cell as M,DEG")
    else:
        cell_m, cell_deg, how = _default_cell(args, pts, al)
        choice["cell_chosen"] = {"cell_m": cell_m, "cell_deg": cell_deg, "how": how}
    if args.triangles is None:
        from survey.clouds.reconstruct import reconstruct_tunnel

        rec = reconstruct_tunnel(pts, alignment=al, centre_height_m=hc, cell_m=cell_m,
                                 cell_rad=np.deg2rad(cell_deg), min_points=args.min_points,
                                 counts=counts)
    else:
        rec = reconstruct_within_budget(pts, args.triangles, alignment=al, centre_height_m=hc,
                                        cell_m=cell_m, cell_rad=np.deg2rad(cell_deg),
                                        min_points=args.min_points, counts=counts)
    if args.method == "auto":
        from survey.clouds.meshchoice import judge_tunnel_fit

        judged = judge_tunnel_fit(pts, rec.vertices, rec.faces, rec.support, counts=counts)
        choice["auto"] = judged.as_json()
        if not judged.good:
            _fallback_possible(args, clouds, judged.reason)
            _check_method_options(args, "solid")
            choice["method_reason"] = f"{judged.reason}: fell back to solid"
            del pts, counts, rec
            return _mesh_solid(args, clouds, choice)
        choice["method_reason"] += f"; {judged.reason}"
    from survey.world.mesh import write_ply

    if args.detail:
        from survey.clouds.detail import with_detail_layer

        mesh = with_detail_layer(rec, pts)
        v, f, sup = mesh.vertices, mesh.faces, mesh.support
        if not args.quiet:
            print(f"detail layer: {mesh.detail_faces:,} triangles of attachment tubes")
    else:
        v, f, sup = rec.vertices, rec.faces, rec.support.astype(np.float64)
    v, f, sup, block = _compact(args, v, f, sup, pts)
    write_ply(args.output, v, f, vertex_fields={"support": sup})
    if args.figure:
        from survey.report.reconstruct import plot_support

        plot_support(rec, args.figure)
    q: dict = rec.quality or {}
    if args.json:
        extra = {"method": "tunnel", **choice}
        if block is not None:
            extra.update(decimation=block, triangles=block["triangles"],
                         triangles_undecimated=q["triangles"])
        write_json(args.json, {**q, **extra})
    if not args.quiet:
        via = "" if counts is None else f" ({len(pts):,} voxels of {args.voxel:g} m)"
        print(f"{q['points']:,} points{via} -> {q['triangles']:,} triangles -> "
              f"{args.output}; "
              f"point-to-surface mean {q['mean_m'] * 1000:.1f} mm, median "
              f"{q['median_m'] * 1000:.1f} mm, 95 % {q['p95_m'] * 1000:.1f} mm, max "
              f"{q['max_m'] * 1000:.1f} mm; extrapolated {100 * q['extrapolated_share']:.1f} %")
        if args.method == "auto":
            print(f"method tunnel: {choice['method_reason']}")
        if block:
            _print_compact(block)
    return 0


def _mesh_solid(args, clouds, choice: dict) -> int:
    """--method solid: the clouds stream through a scanner-aware voxel grid (bounds
    first, one pass each), then ``reconstruct_solid``."""
    import numpy as np

    from sensors.io.clouds import cloud_bounds
    from survey.clouds.scanners import iter_scanned, read_positions
    from survey.clouds.solid import ScannerVoxelGrid, reconstruct_solid
    from survey.errors import ReconstructionError

    if not (np.isfinite(args.voxel) and args.voxel > 0):
        raise ReconstructionError(f"Expected a positive --voxel (m), got {args.voxel:g}.")
    traj = None
    if args.trajectory:
        from sensors import Trajectory

        traj = Trajectory.read(args.trajectory)
    stations = read_positions(args.scanners) if args.scanners else None
    lo = np.min([cloud_bounds(c)[0] for c in clouds], axis=0)
    grid = ScannerVoxelGrid(args.voxel, lo)
    for c in clouds:
        for xyz, scanner in iter_scanned(c, trajectory=traj, stations=stations):
            grid.add(xyz, scanner)
    pts, scanners, _ = grid.result()
    rec = reconstruct_solid(pts, scanners=scanners, cell_m=args.voxel, trim_m=args.trim)
    v, f, sup, block = _compact(args, rec.vertices, rec.faces,
                                rec.support.astype(np.float64), pts)
    from survey.world.mesh import write_ply

    write_ply(args.output, v, f, vertex_fields={"support": sup})
    q = dict(rec.quality, method="solid", **choice, input_points=grid.n_points,
             depth=rec.depth, cell_m=rec.cell_m, trim_m=rec.trim_m,
             support_radius_m=rec.support_radius_m)
    if block is not None:
        q.update(decimation=block, triangles=block["triangles"],
                 triangles_undecimated=rec.quality["triangles"])
    if args.json:
        write_json(args.json, q)
    if not args.quiet:
        print(f"{grid.n_points:,} points -> {len(pts):,} voxels -> {q['triangles']:,} "
              f"triangles -> {args.output} (solid: depth {rec.depth}, cell "
              f"{rec.cell_m * 1000:.0f} mm, trim {rec.trim_m * 1000:.0f} mm); "
              f"point-to-surface mean {q['mean_m'] * 1000:.1f} mm, median "
              f"{q['median_m'] * 1000:.1f} mm, 95 % {q['p95_m'] * 1000:.1f} mm; support 0 "
              f"on {100 * q['unsupported_share']:.1f} % of the vertices")
        print(f"method solid: {q['method_reason']}")
        if block:
            _print_compact(block)
    return 0


__all__ = ["CLOUD_INPUTS", "cmd_mesh", "cmd_preprocess", "register"]
