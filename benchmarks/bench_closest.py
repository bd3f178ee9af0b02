"""Closest-point benchmark: signed cloud-to-mesh distances of a simulated TLS station
against the mesh it scanned, ours against CloudCompare's C2M and Open3D, in one run.

* ``ours``: ``survey.analysis.compare.ReferenceMesh`` (the engine's ``raytrace.Scene``
  build) and its ``distances`` (``Scene.closest``: exact nearest triangle, float64,
  signed), all threads; also the bare ``Scene.closest`` query (``ours_scene``) and its
  work per point (nodes visited and triangles tested, ``--profile``).
* ``cloudcompare``: headless ``CloudCompare -SILENT ... -C2M_DIST`` (Debian's package,
  2.11); its own timing line ``[ComputeDistances] Time`` (the distance computation,
  octree included) and the whole process's wall time. Skipped where it is not installed.
* ``open3d``: ``open3d.t.geometry.RaycastingScene``: ``add_triangles`` (Embree build)
  and ``compute_distance`` (unsigned, float32). Skipped where open3d is missing.

Each engine's distances are compared with float64 brute force (every triangle tried)
on a sample of the points. Queries are best of three.

Usage::

    python benchmarks/bench_closest.py                    # bfo preset, 0.1 m edges
    python benchmarks/bench_closest.py --edge 0.25 --every 5 --json out.json

Needs the ``bench`` extra for Open3D, and ``apt-get install cloudcompare`` for
CloudCompare (run headless with ``QT_QPA_PLATFORM=offscreen``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _world(edge: float, every: int, resolution: str):
    """The bfo preset and the points of one station (every ``every``-th return)."""
    from raytrace import Scene
    from sensors import simulate_station
    from survey.world.presets import preset

    tun, _ = preset("bfo", edge_length_m=edge)
    at = np.asarray(tun.alignment.to_world(60.0, 0.0, 1.5), dtype=np.float64)
    scene = Scene(tun.vertices, tun.faces)
    pts = np.concatenate([np.stack([c["x"], c["y"], c["z"]], 1) for c in
                          simulate_station(scene, "zf_imager_5016", at,
                                           resolution=resolution, seed=1,
                                           reflectivity=tun.reflectivity)])
    return np.asarray(tun.vertices, np.float64), np.asarray(tun.faces, np.int64), \
        np.ascontiguousarray(pts[::every])


def _best(fn, repeat=3):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _brute(points, v, f):
    """Unsigned float64 distances, every triangle a candidate (NumPy, vectorised over
    the triangles; Ericson 2005, 5.1.5, as ``tests/raytrace/test_closest.py`` spells
    it)."""
    # The scene's local origin (the box centre in whole metres, raytrace.Scene): in the
    # same frame the arithmetic is the kernel's, so the distances agree bit for bit.
    org = np.round(0.5 * (v.min(axis=0) + v.max(axis=0)))
    loc = v - org
    a = loc[f[:, 0]]
    ab = loc[f[:, 1]] - a
    ac = loc[f[:, 2]] - a
    out = np.empty(len(points))

    def dot(u, w):
        return u[:, 0] * w[:, 0] + u[:, 1] * w[:, 1] + u[:, 2] * w[:, 2]

    for i, p in enumerate(points - org):
        ap = p - a
        d1, d2 = dot(ab, ap), dot(ac, ap)
        bp = ap - ab
        d3, d4 = dot(ab, bp), dot(ac, bp)
        cp = ap - ac
        d5, d6 = dot(ab, cp), dot(ac, cp)
        vc, vb, va = d1 * d4 - d3 * d2, d5 * d2 - d1 * d6, d3 * d6 - d5 * d4
        with np.errstate(divide="ignore", invalid="ignore"):
            den = 1.0 / (va + vb + vc)
            e = ap - ab * (vb * den)[:, None] - ac * (vc * den)[:, None]
            cases = [((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
                      bp - ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None] * (ac - ab)),
                     ((vb <= 0) & (d2 >= 0) & (d6 <= 0), ap - (d2 / (d2 - d6))[:, None] * ac),
                     ((d6 >= 0) & (d5 <= d6), cp),
                     ((vc <= 0) & (d1 >= 0) & (d3 <= 0), ap - (d1 / (d1 - d3))[:, None] * ab),
                     ((d3 >= 0) & (d4 <= d3), bp), ((d1 <= 0) & (d2 <= 0), ap)]
            for m, o in cases:                      # the first region (last here) wins
                e = np.where(m[:, None], o, e)
        out[i] = np.sqrt(np.nanmin(dot(e, e)))
    return out


def _profile(points, v, f):
    """Mean BVH records visited and triangles tested per point of ``Scene.closest`` (a
    counting copy of the kernel's loop, one thread)."""
    from numba import njit

    from raytrace import Scene
    from raytrace._kernels.closest import BOUND_SLACK, offset_to_triangle
    from raytrace._kernels.simd import LANES
    from raytrace._kernels.traverse import CHILD, COUNT

    @njit
    def count(nodes, links, tris, ids, pts, stack_size):
        visits = 0
        tests = 0
        st_node = np.empty(stack_size, dtype=np.int64)
        st_dist = np.empty(stack_size)
        cd = np.empty(LANES)
        cl = np.empty(LANES, dtype=np.int64)
        cn = np.empty(LANES, dtype=np.int64)
        prev = -1
        for r in range(pts.shape[0]):
            px, py, pz = pts[r, 0], pts[r, 1], pts[r, 2]
            best, best_id, best_slot = np.inf, 2 ** 62, -1
            if prev >= 0:
                ex, ey, ez = offset_to_triangle(tris, prev, px, py, pz)
                best, best_id, best_slot = ex * ex + ey * ey + ez * ez, ids[prev], prev
                tests += 1
            sp, cur = 0, 0
            while cur >= 0:
                visits += 1
                cull = best * BOUND_SLACK
                k = 0
                for lane in range(LANES):
                    if nodes[cur, lane] > nodes[cur, 3 * LANES + lane]:
                        continue
                    d = 0.0
                    for ax in range(3):
                        lo = np.float64(nodes[cur, ax * LANES + lane])
                        hi = np.float64(nodes[cur, (3 + ax) * LANES + lane])
                        g = max(lo - pts[r, ax], pts[r, ax] - hi, 0.0)
                        d += g * g
                    if d > cull:
                        continue
                    q = k
                    while q > 0 and cd[q - 1] > d:
                        cd[q], cl[q] = cd[q - 1], cl[q - 1]
                        q -= 1
                    cd[q], cl[q] = d, lane
                    k += 1
                n_int = 0
                for q in range(k):
                    if cd[q] > best * BOUND_SLACK:
                        continue
                    lane = cl[q]
                    cnt = links[cur, COUNT + lane]
                    if cnt > 0:
                        first = links[cur, CHILD + lane]
                        for j in range(first, first + cnt):
                            tests += 1
                            ex, ey, ez = offset_to_triangle(tris, j, px, py, pz)
                            d2 = ex * ex + ey * ey + ez * ez
                            if d2 < best or (d2 == best and ids[j] < best_id):
                                best, best_id, best_slot = d2, ids[j], j
                    else:
                        cn[n_int], cd[n_int] = links[cur, CHILD + lane], cd[q]
                        n_int += 1
                cur = -1
                cur_d = 0.0
                for q in range(n_int - 1, -1, -1):
                    if cd[q] > best * BOUND_SLACK:
                        continue
                    if cur >= 0:
                        st_node[sp], st_dist[sp] = cur, cur_d
                        sp += 1
                    cur, cur_d = cn[q], cd[q]
                while cur < 0 and sp > 0:
                    sp -= 1
                    if st_dist[sp] <= best * BOUND_SLACK:
                        cur = st_node[sp]
            prev = best_slot
        return visits / pts.shape[0], tests / pts.shape[0]

    scene = Scene(v, f)
    local = np.ascontiguousarray(points - scene.origin_offset)
    nodes = scene._nodes
    return count(nodes, nodes.view(np.int32), scene._tris, scene._ids, local,
                 scene._stack_size)


def _ours(points, v, f):
    from survey.analysis.compare import ReferenceMesh

    ReferenceMesh(v[:50], np.array([[0, 1, 2]])).distances(points[:10])   # compile
    build, ref = _best(lambda: ReferenceMesh(v, f), 2)
    query, d = _best(lambda: ref.distances(points))
    return {"build_s": build, "query_s": query}, np.abs(d.distance)


def _ours_scene(points, v, f):
    from raytrace import Scene

    Scene(v[:50], np.array([[0, 1, 2]])).closest(points[:10])            # compile
    build, scene = _best(lambda: Scene(v, f), 2)
    query, near = _best(lambda: scene.closest(points))
    return {"build_s": build, "query_s": query}, near.distance


def _open3d(points, v, f):
    import open3d as o3d

    org = v.mean(axis=0)
    vv = (v - org).astype(np.float32)
    pp = o3d.core.Tensor((points - org).astype(np.float32))

    def build():
        s = o3d.t.geometry.RaycastingScene()
        s.add_triangles(o3d.core.Tensor(vv), o3d.core.Tensor(f.astype(np.uint32)))
        s.compute_distance(pp[:1])           # Embree commits the scene on first query
        return s

    b, scene = _best(build, 2)
    q, d = _best(lambda: scene.compute_distance(pp).numpy())
    return {"build_s": b, "query_s": q, "version": o3d.__version__}, d.astype(np.float64)


def _cloudcompare(points, v, f):
    exe = shutil.which("CloudCompare")
    if exe is None:
        return None, None
    import trimesh

    org = v.mean(axis=0)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        trimesh.Trimesh(v - org, f, process=False).export(tmp / "mesh.ply")
        np.savetxt(tmp / "cloud.asc", points - org, fmt="%.6f")
        env = {**os.environ, "QT_QPA_PLATFORM": "offscreen"}
        best = None
        for _ in range(3):
            t0 = time.perf_counter()
            r = subprocess.run([exe, "-SILENT", "-AUTO_SAVE", "OFF", "-C_EXPORT_FMT", "ASC",
                                "-O", "cloud.asc", "-O", "mesh.ply", "-C2M_DIST",
                                "-SAVE_CLOUDS", "FILE", "out.asc"],
                               cwd=tmp, env=env, capture_output=True, text=True, timeout=600)
            wall = time.perf_counter() - t0
            m = re.search(r"\[ComputeDistances\] Time: ([0-9.]+) s", r.stdout)
            if m is None:
                raise RuntimeError(f"Expected CloudCompare's timing line, got:\n{r.stdout}"
                                   f"\n{r.stderr}")
            got = {"query_s": float(m.group(1)), "process_s": wall}
            if best is None or got["query_s"] < best["query_s"]:
                best = got
        d = np.loadtxt(tmp / "out.asc", comments="/")[:, 3]
        ver = subprocess.run(["dpkg-query", "-W", "-f=${Version}", "cloudcompare"],
                             capture_output=True, text=True).stdout.strip()
        best["version"] = ver or "?"
    return best, np.abs(d)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--edge", type=float, default=0.1, help="bfo preset edge length, m")
    ap.add_argument("--resolution", default="preview", help="the station's resolution")
    ap.add_argument("--every", type=int, default=5, help="keep every N-th return")
    ap.add_argument("--check", type=int, default=300, help="points checked by brute force")
    ap.add_argument("--engines", default="ours,ours_scene,cloudcompare,open3d")
    ap.add_argument("--profile", action="store_true",
                    help="also count BVH records visited and triangles tested per point")
    ap.add_argument("--json", help="write the figures to this file")
    a = ap.parse_args()

    v, f, p = _world(a.edge, a.every, a.resolution)
    print(f"mesh: bfo preset at {a.edge} m, {len(f):,} triangles; points: {len(p):,} "
          f"(station at chainage 60 m, {a.resolution}, every {a.every}th)")
    rng = np.random.default_rng(0)
    sample = rng.choice(len(p), min(a.check, len(p)), replace=False)
    truth = _brute(p[sample], v, f)
    res = {"triangles": len(f), "points": len(p), "edge_m": a.edge, "engines": {}}
    runners = {"ours": _ours, "ours_scene": _ours_scene, "cloudcompare": _cloudcompare,
               "open3d": _open3d}
    for name in a.engines.split(","):
        try:
            fig, d = runners[name](p, v, f)
        except ImportError as exc:
            print(f"{name}: skipped ({exc})")
            continue
        if fig is None:
            print(f"{name}: skipped (not installed)")
            continue
        fig["max_abs_err_m"] = float(np.abs(d[sample] - truth).max())
        fig["mpoints_per_s"] = len(p) / fig["query_s"] / 1e6
        res["engines"][name] = fig
    base = res["engines"].get("cloudcompare") or res["engines"].get("open3d")
    print(f"{'engine':13s} {'build s':>8s} {'query s':>8s} {'Mpts/s':>7s} "
          f"{'ratio':>6s} {'max |d - brute| m':>18s}")
    for name, fig in res["engines"].items():
        ratio = base["query_s"] / fig["query_s"] if base else float("nan")
        fig["ratio_to_reference"] = ratio
        b = fig.get("build_s")
        print(f"{name:13s} {b if b is not None else float('nan'):8.3f} "
              f"{fig['query_s']:8.3f} {fig['mpoints_per_s']:7.3f} {ratio:6.2f} "
              f"{fig['max_abs_err_m']:18.2e}")
    if "cloudcompare" in res["engines"]:
        print(f"cloudcompare whole process (load, octree, C2M, save): "
              f"{res['engines']['cloudcompare']['process_s']:.2f} s")
    if a.profile:
        visits, tests = _profile(p, v, f)
        res["visits_per_point"], res["tests_per_point"] = visits, tests
        print(f"Scene.closest work per point: {visits:.1f} 8-wide records visited, "
              f"{tests:.1f} triangles tested")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
