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
                    "support 0 where it filled a hole. --method auto (default): tunnel "
                    "when --tunnel-json is given or a tunnel axis is found, else solid.",
        epilog="Example: tunnelsim mesh clean.laz -o tunnel.ply --cell 0.1,2 (or "
               "tunnelsim mesh st01.laz st02.laz st03.laz -o cave.ply --method solid; "
               "tunnelsim mesh drive.laz -o mine.ply --trajectory drive_true_trajectory.txt)")
    c.option("cloud", nargs="+", metavar="CLOUD", path="in",
             help=f"input cloud(s) ({CLOUD_INPUTS}); several: e.g. one file per station")
    c.option("-o", "--output", required=True, path="out", help="output mesh (.ply)")
    c.option("--method", choices=["auto", "tunnel", "poisson", "solid"], default="auto",
             help="auto (default): tunnel if an axis is given or found, else solid; "
                  "tunnel: tunnel-aware mesher; poisson: Open3D Poisson oriented by the "
                  "tunnel axis; solid: Poisson oriented by the scanners (any space)")
    c.option("--cell", default="0.1,2", metavar="M,DEG",
             help="tunnel: cell size along the axis (m) and around it (deg), default 0.1,2")
    c.option("--detail", action="store_true",
             help="tunnel: add a detail layer: attachments (cables, pipes) as closed tubes "
                  "(vertex support -1)")
    c.option("--depth", type=int, default=10,
             help="poisson: octree depth (default 10)")
    c.option("--triangles", type=int, metavar="N",
             help="tunnel: triangle budget: coarsen the cells until the mesh fits")
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

    from survey.clouds.cloudio import cloud_bounds, iter_points, write_points_las
    from survey.clouds.preprocess import (
        VoxelGrid,
        radius_outliers,
        statistical_outliers,
    )

    lo, _hi, n_in = cloud_bounds(args.cloud)
    if args.voxel is not None:
        grid = VoxelGrid(args.voxel, lo)
        for xyz in iter_points(args.cloud):
            grid.add(xyz)
        pts, counts = grid.result()
    else:
        pts = np.concatenate(list(iter_points(args.cloud)))
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
    write_points_las(args.output, pts[keep],
                     {"voxel_count": counts[keep].astype(np.uint32)}, classification=cls)
    if not args.quiet:
        print(f"{n_in:,} points -> {len(pts):,} after the voxel grid -> {int(keep.sum()):,} "
              f"after outlier removal -> {args.output}")
        if cls is not None:
            from survey.clouds.segment import CLASS_NAMES

            u, c = np.unique(cls, return_counts=True)
            print("classes: " + ", ".join(f"{CLASS_NAMES[k]} ({k}) {v:,}"
                                          for k, v in zip(u.tolist(), c.tolist())))
    return 0


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


def _mesh_method(args, pts) -> str:
    """The method --method auto resolves to: tunnel when --tunnel-json is given or the
    cloud has a tunnel axis (``estimate_axis`` succeeds), else solid."""
    if args.method != "auto":
        return args.method
    if args.tunnel_json:
        return "tunnel"
    from survey.clouds.axis import estimate_axis
    from survey.errors import ReconstructionError

    try:
        estimate_axis(pts)
    except ReconstructionError:
        return "solid"
    return "tunnel"


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

    from survey.clouds.cloudio import cloud_bounds, iter_points
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
    method = args.method
    if method == "auto" and not args.tunnel_json and (args.trajectory or args.scanners):
        method = "solid"           # scanner positions are what the solid route asks for
    if method == "solid":
        _check_method_options(args, method)
        return _mesh_solid(args, clouds)
    pts, counts, n_in = _read_reduced(clouds, args.voxel)
    method = _mesh_method(args, pts)
    _check_method_options(args, method)
    if method == "solid":
        del pts
        return _mesh_solid(args, clouds)
    al, hc = _tunnel_axis(args.tunnel_json)
    if method == "poisson":
        from survey.clouds.reconstruct import poisson_tunnel
        from survey.world.mesh import write_ply

        v, f = poisson_tunnel(pts, alignment=al, centre_height_m=hc, depth=args.depth)
        write_ply(args.output, v, f)
        if not args.quiet:
            print(f"{n_in:,} points -> {len(f):,} triangles (Poisson, depth "
                  f"{args.depth}, trimmed) -> {args.output}")
        return 0
    from survey.clouds.reconstruct import reconstruct_within_budget

    cell_m, cell_deg = pair(args.cell, "--cell as M,DEG")
    if args.triangles is None:
        from survey.clouds.reconstruct import reconstruct_tunnel

        rec = reconstruct_tunnel(pts, alignment=al, centre_height_m=hc, cell_m=cell_m,
                                 cell_rad=np.deg2rad(cell_deg), min_points=args.min_points,
                                 counts=counts)
    else:
        rec = reconstruct_within_budget(pts, args.triangles, alignment=al, centre_height_m=hc,
                                        cell_m=cell_m, cell_rad=np.deg2rad(cell_deg),
                                        min_points=args.min_points, counts=counts)
    if args.detail:
        from survey.clouds.detail import with_detail_layer

        mesh = with_detail_layer(rec, pts)
        mesh.write(args.output)
        if not args.quiet:
            print(f"detail layer: {mesh.detail_faces:,} triangles of attachment tubes")
    else:
        rec.write(args.output)
    if args.figure:
        from survey.report.reconstruct import plot_support

        plot_support(rec, args.figure)
    q: dict = rec.quality or {}
    if args.json:
        write_json(args.json, q)
    if not args.quiet:
        via = "" if counts is None else f" ({len(pts):,} voxels of {args.voxel:g} m)"
        print(f"{q['points']:,} points{via} -> {q['triangles']:,} triangles -> "
              f"{args.output}; "
              f"point-to-surface mean {q['mean_m'] * 1000:.1f} mm, median "
              f"{q['median_m'] * 1000:.1f} mm, 95 % {q['p95_m'] * 1000:.1f} mm, max "
              f"{q['max_m'] * 1000:.1f} mm; extrapolated {100 * q['extrapolated_share']:.1f} %")
    return 0


def _mesh_solid(args, clouds) -> int:
    """--method solid: the clouds stream through a scanner-aware voxel grid (bounds
    first, one pass each), then ``reconstruct_solid``."""
    import numpy as np

    from survey.clouds.cloudio import cloud_bounds
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
    rec.write(args.output)
    q = dict(rec.quality, method="solid", input_points=grid.n_points, depth=rec.depth,
             cell_m=rec.cell_m, trim_m=rec.trim_m, support_radius_m=rec.support_radius_m)
    if args.json:
        write_json(args.json, q)
    if not args.quiet:
        print(f"{grid.n_points:,} points -> {len(pts):,} voxels -> {q['triangles']:,} "
              f"triangles -> {args.output} (solid: depth {rec.depth}, cell "
              f"{rec.cell_m * 1000:.0f} mm, trim {rec.trim_m * 1000:.0f} mm); "
              f"point-to-surface mean {q['mean_m'] * 1000:.1f} mm, median "
              f"{q['median_m'] * 1000:.1f} mm, 95 % {q['p95_m'] * 1000:.1f} mm; support 0 "
              f"on {100 * q['unsupported_share']:.1f} % of the vertices")
    return 0


__all__ = ["CLOUD_INPUTS", "cmd_mesh", "cmd_preprocess", "register"]
