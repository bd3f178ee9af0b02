"""Commands on point clouds: preprocess (voxel grid, outliers), mesh (reconstruction)."""

from __future__ import annotations

from survey.cli.common import CommandSet, pair

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
                    "of points per voxel; a coloured cloud's colour is kept (a voxel's: "
                    "the linear-light mean of its points'), as LAS RGB 16-bit.",
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
    c.option("--no-colour", action="store_true",
             help="leave out the per-vertex colour (red green blue, uint8 sRGB) that is "
                  "otherwise taken from clouds that carry colour (LAS RGB, 8-bit values "
                  "in 16-bit fields detected; PLY red/green/blue; E57 colour): the "
                  "linear-light mean of the points within half a mesh edge of each "
                  "vertex, the nearest point where none is; colour and temperature "
                  "add about 150 bytes per occupied voxel to the peak memory")
    c.option("--no-temperature", action="store_true",
             help="leave out the per-vertex temperature (K) that is otherwise taken "
                  "from clouds with a 'temperature' field in kelvin (a LAS extra "
                  "dimension, a PLY property)")
    c.option("--json", path="out", help="also write the reconstruction quality as JSON")
    c.option("--figure", metavar="PNG", path="out",
             help="tunnel: also write the unrolled support map (points per cell) as PNG")
    c.option("--quiet", action="store_true", help="print nothing on success")


def cmd_preprocess(args) -> int:
    from survey.workflows.clouds import preprocess_file

    def two(text, what, whole=False):
        if not text:
            return None
        a, b = pair(text, what)
        return (int(a), b) if whole else (a, b)

    r = preprocess_file(args.cloud, args.output, voxel_m=args.voxel,
                        crop_m=two(args.crop, "--crop as START,END in m"),
                        sor=two(args.sor, "--sor as K,STD_RATIO", whole=True),
                        ror=two(args.ror, "--ror as N,RADIUS_M", whole=True),
                        segment=args.segment, tunnel_json=args.tunnel_json)
    if not args.quiet:
        print(f"{r.input_points:,} points -> {r.voxel_points:,} after the voxel grid -> "
              f"{r.kept_points:,} after outlier removal -> {args.output}")
        if r.classes is not None:
            print("classes: " + ", ".join(f"{name} ({k}) {v:,}"
                                          for k, name, v in r.classes))
    return 0


def cmd_mesh(args) -> int:
    from survey.workflows.clouds import mesh_files

    cell = pair(args.cell, "--cell as M,DEG") if args.cell is not None else (None, None)
    r = mesh_files(args.cloud, args.output, method=args.method, cell_m=cell[0],
                   cell_deg=cell[1], detail=args.detail, depth=args.depth,
                   triangles=args.triangles, max_triangles=args.max_triangles,
                   max_error_m=args.max_error, min_points=args.min_points,
                   tunnel_json=args.tunnel_json, voxel_m=args.voxel, trim_m=args.trim,
                   trajectory=args.trajectory, scanners=args.scanners,
                   json_path=args.json, figure=args.figure,
                   colour=not args.no_colour, temperature=not args.no_temperature)
    if args.quiet:
        return 0
    if r.profile_spacing_m is not None:
        print(f"cell: {r.cell_m:g} m along the axis ({r.cell_how}) x {r.cell_deg:g} deg; "
              "--cell M,DEG sets it")
    {"poisson": _print_poisson, "tunnel": _print_tunnel, "solid": _print_solid}[
        r.method](r, args.output)
    if r.decimation:
        _print_compact(r.decimation)
    _print_appearance(r.appearance)
    return 0


def _print_appearance(block) -> None:
    """Where the mesh's vertex colour and temperature came from (or why it has none)."""
    for what, names in (("colour", "red green blue"), ("temperature", "temperature")):
        b = block.get(what)
        if not b:
            continue
        if not b["written"]:
            if what == "colour" or b["why"].startswith("left out"):
                print(f"{what}: none ({b['why']})")
            continue
        print(f"{what}: vertex {names} from {'; '.join(b['sources'])}; mean of the points "
              f"within {block['radius_m'] * 1000:.0f} mm (at most {block['neighbours']} "
              f"nearest voxels), {b['fallback_vertices']:,} vertices with none took the "
              "nearest point's")


def _mm(q, key: str) -> str:
    """A distance of the report in millimetres, as the summaries print it."""
    return f"{q[key] * 1000:.1f} mm"


def _print_poisson(r, output) -> None:
    print(f"{r.input_points:,} points -> {r.triangles:,} triangles (Poisson, depth "
          f"{r.depth}, trimmed) -> {output}")


def _print_tunnel(r, output) -> None:
    q = r.report
    if r.detail_faces is not None:
        print(f"detail layer: {r.detail_faces:,} triangles of attachment tubes")
    via = "" if r.voxels is None else f" ({r.voxels:,} voxels of {r.voxel_m:g} m)"
    print(f"{q['points']:,} points{via} -> {r.triangles_undecimated:,} triangles -> "
          f"{output}; point-to-surface mean {_mm(q, 'mean_m')}, median "
          f"{_mm(q, 'median_m')}, 95 % {_mm(q, 'p95_m')}, max {_mm(q, 'max_m')}; "
          f"extrapolated {100 * q['extrapolated_share']:.1f} %")
    if r.method_asked == "auto":
        print(f"method tunnel: {r.method_reason}")


def _print_solid(r, output) -> None:
    q = r.report
    print(f"{r.input_points:,} points -> {r.voxels:,} voxels -> {r.triangles:,} "
          f"triangles -> {output} (solid: depth {q['depth']}, cell "
          f"{q['cell_m'] * 1000:.0f} mm, trim {q['trim_m'] * 1000:.0f} mm); "
          f"point-to-surface mean {_mm(q, 'mean_m')}, median {_mm(q, 'median_m')}, "
          f"95 % {_mm(q, 'p95_m')}; support 0 on {100 * q['unsupported_share']:.1f} % "
          "of the vertices")
    print(f"method solid: {r.method_reason}")


def _print_compact(block) -> None:
    e = block["error"]
    a, b = e["original_to_decimated"], e["decimated_to_original"]
    print(f"decimated {block['triangles_before']:,} -> {block['triangles']:,} triangles "
          f"(quadric, Open3D, {block['tries']} tries): undecimated -> decimated median "
          f"{a['median_m'] * 1000:.1f} mm, 95 % {a['p95_m'] * 1000:.1f} mm, max "
          f"{a['max_m'] * 1000:.1f} mm; back: median {b['median_m'] * 1000:.1f} mm, 95 % "
          f"{b['p95_m'] * 1000:.1f} mm, max {b['max_m'] * 1000:.1f} mm; points -> mesh "
          f"median {block['points_to_mesh']['median_m'] * 1000:.1f} mm")


__all__ = ["CLOUD_INPUTS", "cmd_mesh", "cmd_preprocess", "register"]
