"""Commands on point clouds: preprocess (voxel grid, outliers), mesh (reconstruction)."""

from __future__ import annotations

import numpy as np

from survey.errors import TunnelsimCLIError
from survey.cli.main import _parse_window


def cmd_preprocess(args) -> int:
    from survey.clouds.cloudio import cloud_bounds, iter_points, write_points_las
    from survey.clouds.preprocess import VoxelGrid, radius_outliers, statistical_outliers

    lo, hi, n_in = cloud_bounds(args.cloud)
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
        s0, s1 = _parse_window(args.crop.replace(",", ":"), "--crop as START,END in m", 2)
        al, _ = _tunnel_axis(args.tunnel_json)
        if al is None:
            from survey.clouds.axis import estimate_axis
            al, _ = estimate_axis(pts)
        s, _, _ = al.to_local(pts)
        keep &= (s >= s0) & (s <= s1)
    if args.sor:
        k, ratio = _parse_window(args.sor.replace(",", ":"), "--sor as K,STD_RATIO", 2)
        keep &= ~statistical_outliers(pts, int(k), ratio)
    if args.ror:
        nb, rad = _parse_window(args.ror.replace(",", ":"), "--ror as N,RADIUS_M", 2)
        keep &= ~radius_outliers(pts, int(nb), rad)
    cls = None
    if args.segment:
        from survey.clouds.segment import CLASS_NAMES, segment_tunnel

        al, hc = _tunnel_axis(args.tunnel_json)
        cls = segment_tunnel(pts[keep], alignment=al, centre_height_m=hc)
    write_points_las(args.output, pts[keep],
                     {"voxel_count": counts[keep].astype(np.uint32)}, classification=cls)
    if not args.quiet:
        print(f"{n_in:,} points -> {len(pts):,} after the voxel grid -> {int(keep.sum()):,} "
              f"after outlier removal -> {args.output}")
        if cls is not None:
            u, c = np.unique(cls, return_counts=True)
            print("classes: " + ", ".join(f"{CLASS_NAMES[k]} ({k}) {v:,}"
                                          for k, v in zip(u.tolist(), c.tolist())))
    return 0


def _tunnel_axis(path):
    """(Alignment, profile-centre height) from a tunnel JSON, or (None, None)."""
    if not path:
        return None, None
    from survey.world.mesh import read_axis

    return read_axis(path)


def cmd_mesh(args) -> int:
    from survey.clouds.cloudio import iter_points
    from survey.clouds.reconstruct import reconstruct_tunnel

    cell_m, cell_deg = _parse_window(args.cell.replace(",", ":"), "--cell as M,DEG", 2)
    pts = np.concatenate(list(iter_points(args.cloud)))
    al, hc = _tunnel_axis(args.tunnel_json)
    if args.method == "poisson":
        from survey.clouds.reconstruct import poisson_tunnel
        from survey.world.mesh import write_ply

        v, f = poisson_tunnel(pts, alignment=al, centre_height_m=hc, depth=args.depth)
        write_ply(args.output, v, f)
        if not args.quiet:
            print(f"{len(pts):,} points -> {len(f):,} triangles (Poisson, depth "
                  f"{args.depth}, trimmed) -> {args.output}")
        return 0
    rec = reconstruct_tunnel(pts, alignment=al, centre_height_m=hc, cell_m=cell_m,
                             cell_rad=np.deg2rad(cell_deg), min_points=args.min_points)
    f = 1.0
    while args.triangles and len(rec.faces) > args.triangles:
        # A triangle budget: the same reconstruction on proportionally larger cells
        # (both directions scaled alike; cell counts round, so step until it fits),
        # which keeps the grid regular and the support meaningful.
        f *= max(1.02, np.sqrt(len(rec.faces) / args.triangles))
        rec = reconstruct_tunnel(pts, alignment=rec.alignment,
                                 centre_height_m=rec.centre_height_m, cell_m=cell_m * f,
                                 cell_rad=min(np.deg2rad(cell_deg) * f, np.pi / 4 - 1e-9),
                                 min_points=args.min_points)
        if f > 1e3:
            raise TunnelsimCLIError(f"Expected a reachable triangle budget, got "
                                    f"{args.triangles}; ask for more triangles.")
    if args.detail:
        from survey.clouds.detail import attachment_tubes
        from survey.clouds.segment import ATTACHMENT, segment_tunnel
        from survey.world.mesh import write_ply

        cls = segment_tunnel(pts, alignment=rec.alignment,
                             centre_height_m=rec.centre_height_m)
        tv, tf = attachment_tubes(pts[cls == ATTACHMENT], rec.alignment)
        # Detail-layer vertices carry support -1.
        write_ply(args.output, np.concatenate([rec.vertices, tv]),
                  np.concatenate([rec.faces, tf + len(rec.vertices)]),
                  vertex_fields={"support": np.concatenate(
                      [rec.support.astype(np.float64), np.full(len(tv), -1.0)])})
        if not args.quiet:
            print(f"detail layer: {len(tf):,} triangles of attachment tubes")
    else:
        rec.write(args.output)
    if args.figure:
        from survey.report.reconstruct import plot_support
        plot_support(rec, args.figure)
    if args.json:
        import json

        from survey.cli.main import _write_text
        _write_text(args.json, json.dumps(rec.quality, indent=2) + "\n")
    if not args.quiet:
        q = rec.quality
        print(f"{q['points']:,} points -> {q['triangles']:,} triangles -> {args.output}; "
              f"point-to-surface mean {q['mean_m'] * 1000:.1f} mm, median "
              f"{q['median_m'] * 1000:.1f} mm, 95 % {q['p95_m'] * 1000:.1f} mm, max "
              f"{q['max_m'] * 1000:.1f} mm; extrapolated {100 * q['extrapolated_share']:.1f} %")
    return 0
