"""Find routes in meshes tunnelsim did not make (``sensors.route.find_route``) and check
them: length, smallest clearance (the route's own figure, and a brute-force
point-to-triangle distance over every triangle), height above the floor, how close the
ends come to the mesh's open ends, and the time taken.

Input: the folder of the DARPA SubT tiles (``../shared/data/meshes``, see its README);
the meshes ``cave_straight_80m.ply`` and ``tunnel_bend_left.ply`` are routed, with
``--all`` the straight tiles too, and with ``--big`` a generated 1M-triangle, 300 m
horseshoe tube (``raytrace.shapes.tunnel_tube``) for the time on a large mesh.

Usage::

    python benchmarks/validate_routes.py ../shared/data/meshes [--all] [--big]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

MESHES = ("cave_straight_80m.ply", "tunnel_bend_left.ply")
MORE = ("tunnel_tile_5.ply", "rough_tunnel_tile_straight.ply")


def brute_distance(points, vertices, faces):
    """Distance of each point to the nearest triangle, every triangle tried: the foot of
    the perpendicular when it falls inside (barycentric coordinates from the 2x2 normal
    equations), else the nearest point of the three edges."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    e1, e2 = b - a, c - a
    g11, g12, g22 = (np.einsum("ij,ij->i", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    det = g11 * g22 - g12 ** 2
    ok = det > 1e-18 * np.maximum(g11, g22) ** 2

    def seg(p, u, v):
        d = v - u
        t = np.clip(np.einsum("ij,ij->i", p - u, d) / np.maximum(
            np.einsum("ij,ij->i", d, d), 1e-300), 0, 1)
        return np.linalg.norm(p - (u + t[:, None] * d), axis=1)

    out = np.empty(len(points))
    for i, p in enumerate(points):
        w = p - a
        r1, r2 = np.einsum("ij,ij->i", w, e1), np.einsum("ij,ij->i", w, e2)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (g22 * r1 - g12 * r2) / det
            v = (g11 * r2 - g12 * r1) / det
        inside = ok & (u >= 0) & (v >= 0) & (u + v <= 1)
        face = np.linalg.norm(w - u[:, None] * e1 - v[:, None] * e2, axis=1)
        P = np.broadcast_to(p, a.shape)
        edge = np.minimum(np.minimum(seg(P, a, b), seg(P, b, c)), seg(P, c, a))
        out[i] = np.where(inside, face, edge).min()
    return out


def check(name, scene, height_m):
    from sensors.route import find_route

    t = time.perf_counter()
    route = find_route(scene, height_m=height_m)
    seconds = time.perf_counter() - t
    v, f = np.asarray(scene.vertices), np.asarray(scene.faces)
    brute = brute_distance(route.points, v, f)
    down = scene.cast(route.points, [0.0, 0.0, -1.0]).t
    lo, hi = v.min(axis=0), v.max(axis=0)
    ends = [float(min(np.min(p[:2] - lo[:2]), np.min(hi[:2] - p[:2])))
            for p in route.points[[0, -1]]]
    print(f"{name}: {len(f):,} triangles, voxel {route.voxel_m:.3f} m")
    print(f"  route {route.length_m:.1f} m, {len(route.points)} points, found in "
          f"{seconds:.2f} s")
    diff = np.abs(brute - route.clearance_m).max()
    print(f"  smallest clearance {route.min_clearance_m:.3f} m (brute force "
          f"{brute.min():.3f} m, largest difference {diff:.1e} m)")
    print(f"  height above the floor {np.nanmin(down):.3f}-{np.nanmax(down):.3f} m "
          f"(asked {height_m:g})")
    print(f"  ends {ends[0]:.2f} m and {ends[1]:.2f} m from the mesh's box in plan "
          f"(its open ends lie on the box)")
    return dict(name=name, length_m=route.length_m, min_clearance_m=route.min_clearance_m,
                seconds=seconds)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir", help="folder of the SubT meshes (../shared/data/meshes)")
    ap.add_argument("--height", type=float, default=0.5, help="sensor height (m)")
    ap.add_argument("--all", action="store_true", help="the straight tiles too")
    ap.add_argument("--big", action="store_true", help="a generated 1M-triangle tube too")
    args = ap.parse_args()
    from sensors.meshes import load_mesh

    folder = Path(args.mesh_dir)
    names = MESHES + (MORE if args.all else ())
    missing = [n for n in names if not (folder / n).is_file()]
    if missing:
        sys.exit(f"Expected {', '.join(missing)} in '{folder}', got none.")
    rows = []
    for n in names:
        scene, _ = load_mesh(folder / n)
        rows.append(check(n, scene, args.height))
    if args.big:
        from raytrace import Scene
        from raytrace.shapes import tunnel_tube

        v, f = tunnel_tube(1_000_000, length_m=300.0, seed=1)
        rows.append(check("tunnel_tube 1M, 300 m", Scene(v, f), args.height))
    print("\n| mesh | route (m) | smallest clearance (m) | time (s) |\n|---|---|---|---|")
    for r in rows:
        print(f"| {r['name']} | {r['length_m']:.1f} | {r['min_clearance_m']:.3f} | "
              f"{r['seconds']:.2f} |")


if __name__ == "__main__":
    main()
