"""Find routes in meshes tunnelsim did not make (``sensors.route.find_route``) and check
them: length, smallest clearance (the route's own figure, and a brute-force
point-to-triangle distance over every triangle), height above the floor, how close the
ends come to the mesh's open ends, and the time taken.

Input: the folder of the DARPA SubT tiles (``../shared/data/meshes``, see its README);
the meshes ``cave_straight_80m.ply`` and ``tunnel_bend_left.ply`` are routed, with
``--all`` the straight tiles too, and with ``--big`` a generated 1M-triangle, 300 m
horseshoe tube (``raytrace.shapes.tunnel_tube``) for the time on a large mesh, and the
generated ``junction`` preset (90-degree bend, T-junction). For each of the
``--platforms`` a route is found on ground it can cross (``find_route(platform=...)``,
issue 29) and driven at 1 m/s (``sensors.platform.platform_trajectory``): the
smallest clearance of its poses, the largest speed, acceleration, jerk and yaw rate of
the sensor poses against the platform's limits, and the largest roll and pitch of its
poses against its traversability.

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


def motion(t, p, q):
    """Largest horizontal speed, acceleration, jerk and yaw rate of a trajectory's
    samples (finite differences), as its TUM file gives them."""
    from scipy.spatial.transform import Rotation

    yaw = np.unwrap(Rotation.from_quat(q).as_euler("ZYX")[:, 0])
    dt = np.diff(t)
    v = np.diff(p[:, :2], axis=0) / dt[:, None]
    a = np.diff(v, axis=0) / (0.5 * (dt[1:] + dt[:-1]))[:, None]
    j = np.diff(a, axis=0) / dt[1:-1, None]
    n = np.linalg.norm
    return (n(v, axis=1).max(), n(a, axis=1).max(), n(j, axis=1).max(),
            np.abs(np.diff(yaw) / dt).max())


def drive(scene, space, platform):
    """The platform's own route (on ground it can cross) driven at 1 m/s: duration,
    smallest pose clearance, the largest motion figures of its poses against the
    platform's limits, and their largest roll and pitch."""
    import warnings

    from sensors.platform import platform_trajectory
    from sensors.platform_spec import load_platform
    from sensors.route import find_route

    spec = load_platform(platform)
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            route = find_route(scene, height_m=spec.mast_height_m, space=space,
                               platform=spec)
        for w in caught:
            print(f"  {platform}: warning: {w.message}")
        found = time.perf_counter() - t0
        t0 = time.perf_counter()
        traj = platform_trajectory(route, spec, 1.0, scene=scene)
    except Exception as exc:                 # a refusal is a result here
        print(f"  {platform}: {type(exc).__name__}: {exc}")
        return dict(platform=platform, error=str(exc))
    secs = time.perf_counter() - t0
    m = traj.rotations.as_matrix()
    pitch = np.degrees(np.abs(np.arcsin(np.clip(m[:, 2, 0], -1, 1)))).max()
    roll = np.degrees(np.abs(np.arcsin(np.clip(m[:, 2, 1], -1, 1)))).max()
    print(f"  {platform}: route {route.length_m:.1f} m found in {found:.2f} s, largest "
          f"roll {roll:.1f} deg, pitch {pitch:.1f} deg")
    p, q = traj.positions, traj.rotations.as_quat()
    clear = float(space.distance(p[::5]).min())
    v, a, j, w = motion(traj.times, p, q)
    lim = spec.limits
    print(f"  {platform}: {traj.duration_s:.1f} s for {route.length_m:.1f} m (planned in "
          f"{secs:.2f} s), smallest pose clearance {clear:.3f} m; sensor poses: speed "
          f"{v:.2f} m/s, acceleration {a:.2f} m/s^2, jerk {j:.1f} m/s^3, yaw rate "
          f"{np.degrees(w):.1f} deg/s (limits {lim.max_speed_mps:g} m/s, "
          f"{lim.max_accel_mps2:g} m/s^2, {lim.max_jerk_mps3:g} m/s^3, "
          f"{np.degrees(lim.max_yaw_rate_radps):.0f} deg/s)")
    return dict(platform=platform, clearance_m=clear, accel=a, jerk=j,
                yaw_dps=float(np.degrees(w)))


def check(name, scene, height_m, platforms=()):
    from sensors.freespace import free_space
    from sensors.route import find_route

    t = time.perf_counter()
    space = free_space(scene)
    route = find_route(scene, height_m=height_m, space=space)
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
    for pf in platforms:
        drive(scene, space, pf)
    return dict(name=name, length_m=route.length_m, min_clearance_m=route.min_clearance_m,
                seconds=seconds)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh_dir", help="folder of the SubT meshes (../shared/data/meshes)")
    ap.add_argument("--height", type=float, default=0.5, help="sensor height (m)")
    ap.add_argument("--all", action="store_true", help="the straight tiles too")
    ap.add_argument("--big", action="store_true", help="a generated 1M-triangle tube too")
    ap.add_argument("--platforms", default="ground_robot,walker",
                    help="platforms driven along each route at 1 m/s ('' for none)")
    args = ap.parse_args()
    from sensors.io.meshes import load_mesh

    folder = Path(args.mesh_dir)
    names = MESHES + (MORE if args.all else ())
    missing = [n for n in names if not (folder / n).is_file()]
    if missing:
        sys.exit(f"Expected {', '.join(missing)} in '{folder}', got none.")
    rows = []
    for n in names:
        scene, _ = load_mesh(folder / n)
        rows.append(check(n, scene, args.height,
                          [p for p in args.platforms.split(",") if p]))
    if args.big:
        from raytrace import Scene
        from raytrace.shapes import tunnel_tube

        v, f = tunnel_tube(1_000_000, length_m=300.0, seed=1)
        rows.append(check("tunnel_tube 1M, 300 m", Scene(v, f), args.height))
        from survey.world.presets import preset

        tun = preset("junction", edge_length_m=0.1)[0]
        scene = Scene(tun.vertices, tun.faces)
        rows.append(check(f"junction preset ({len(tun.faces):,} triangles)", scene,
                          args.height, [p for p in args.platforms.split(",") if p]))
    print("\n| mesh | route (m) | smallest clearance (m) | time (s) |\n|---|---|---|---|")
    for r in rows:
        print(f"| {r['name']} | {r['length_m']:.1f} | {r['min_clearance_m']:.3f} | "
              f"{r['seconds']:.2f} |")


if __name__ == "__main__":
    main()
