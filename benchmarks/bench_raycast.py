"""Ray-casting benchmark: tunnelsim's ``raytrace.Scene`` against Embree, in one run.

Engines (each in its own subprocess, so memory figures are not mixed up):

* ``ours``    raytrace.Scene (Numba, all threads)
* ``open3d``  open3d.t.geometry.RaycastingScene (Embree inside, all threads)
* ``embreex`` embreex EmbreeScene.run (Embree 4, as trimesh uses it)

Meshes and ray sets (identical for every engine; seeded; made once in the parent
process and handed to the workers as files):

* ``tube`` meshes: straight 300 m horseshoe tunnels (3 m wide, 2 mm correlated
  roughness, open portals) of ~0.1M, 1M and 4M triangles (``raytrace.shapes.tunnel_tube``):

  - coherent:   one station at mid-tunnel, 1.5 m above the floor; vertical profiles in
    scan order (elevation -70 deg .. 250 deg through the zenith, 180 deg of azimuth),
    like a TLS head turning while its mirror spins, with a (3,) origin;
  - incoherent: random origins inside the tunnel, random directions.

* ``bfo``: the ``bfo`` preset at 0.1 m edge length (``survey.world.preset``, 0.81M
  triangles; issue 16's reference scene):

  - drive: the rays of a RoboSense Airy driven at 1 m/s along the centreline, 0.5 m above
    it, from chainage 100 m (``--drive-s`` seconds, 6.9M rays for 8 s): each pulse's
    direction turned into the world with the sensor pose at its own time and cast from
    that pose's position, (n, 3) origins (``sensors`` pattern and trajectory code,
    without the return physics);
  - station-as-array: a Z+F IMAGER 5016 station (``--station-step-deg``, 4.0M rays for
    0.12 deg) at chainage 60 m, 1.5 m height, in scan order, its origin repeated as an
    (n, 3) array (all rows equal);
  - station: the same rays with a (3,) origin;
  - random: random directions from origins within 0.5 m of the drive's pulse
    origins.

Figures: build seconds (best of two builds), scene memory (RSS growth over the first
build, MB), Mrays/s (best of three casts of the same rays; for ``ours`` each cast from
a shared origin includes building the station's cube map), and each engine's ratio to
Open3D. Agreement of hit/miss and t with Open3D on the first 200k rays of each set is
printed too (a benchmark that is fast and wrong is useless).

Build rounds (``--build-rounds N``): builds only, no rays and no memory figures. All
engines are built in one process, N rounds, the engine order reversed every other round,
so that a loaded machine slows every engine alike; each engine's best and median, and
their ratios to Open3D's best and median, are reported.

Usage::

    python benchmarks/bench_raycast.py                      # tubes 0.1M, 1M, 4M; bfo
    python benchmarks/bench_raycast.py --sizes 1e6 --rays 2e6 --json out.json
    python benchmarks/bench_raycast.py --sizes "" --engines ours,open3d   # bfo only
    python benchmarks/bench_raycast.py --sizes "" --build-rounds 10       # bfo builds

Needs the ``bench`` extra (open3d, embreex); Open3D also needs the system library
libusb-1.0 (Debian: ``apt-get install libusb-1.0-0``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

CHECK_RAYS = 200_000
REPEATS = 3


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def coherent_rays(n: int, origin=(150.0, 0.0, 1.5)):
    """n rays (rounded to a full grid) from one station, in scan order."""
    n_cols = int(round(np.sqrt(n / 1.6)))
    n_rows = int(round(n / n_cols))
    az = np.linspace(0.0, np.pi, n_cols, endpoint=False)
    el = np.linspace(np.deg2rad(-70.0), np.deg2rad(250.0), n_rows)
    ce, se = np.cos(el), np.sin(el)
    d = np.empty((n_cols, n_rows, 3))
    d[:, :, 0] = np.cos(az)[:, None] * ce[None, :]
    d[:, :, 1] = np.sin(az)[:, None] * ce[None, :]
    d[:, :, 2] = se[None, :]
    return np.asarray(origin, dtype=np.float64), d.reshape(-1, 3)


def incoherent_rays(n: int, seed: int = 42):
    rng = np.random.default_rng(seed)
    o = np.empty((n, 3))
    o[:, 0] = rng.uniform(2.0, 298.0, n)
    o[:, 1] = rng.uniform(-1.2, 1.2, n)
    o[:, 2] = rng.uniform(0.3, 2.6, n)
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return o, d


# --------------------------------------------------------------------------- engines
# Each engine: ``warm()`` imports the library and runs a one-triangle scene (loading
# compiled kernels, starting thread pools) before the memory baseline is taken; then the
# constructor builds the real scene, timed.
class Ours:
    name = "ours"

    @staticmethod
    def warm():
        from raytrace import Scene

        from raytrace.shapes import tunnel_tube

        # Large enough to reach the parallel build phase, so every kernel is loaded.
        s = Scene(*tunnel_tube(20_000, length_m=20.0))
        s.cast(np.array([10.0, 0, 1.5]), np.ones((20_000, 3)))
        s.cast(np.ones((10, 3)), np.ones((10, 3)))

    def __init__(self, v, f):
        from raytrace import Scene

        self.scene = Scene(v, f)

    def cast(self, o, d):
        # Drop the cube map kept from the last call: its build counts in every timing.
        self.scene._view_cache = None
        h = self.scene.cast(o, d)
        return h.t


class Open3D:
    name = "open3d"

    @staticmethod
    def warm():
        Open3D(np.eye(3), np.array([[0, 1, 2]]))

    def __init__(self, v, f):
        import open3d as o3d

        self.o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)),
                                 o3d.core.Tensor(f.astype(np.uint32)))
        # Open3D builds the BVH lazily, on the first query: include it in the build.
        self.scene.cast_rays(o3d.core.Tensor(np.array([[150, 0, 1.5, 1, 0, 0]], np.float32)))

    def cast(self, o, d):
        rays = np.empty((d.shape[0], 6), dtype=np.float32)
        rays[:, :3] = o
        rays[:, 3:] = d
        t = self.scene.cast_rays(self.o3d.core.Tensor(rays))["t_hit"].numpy()
        return t.astype(np.float64)


class Embreex:
    name = "embreex"

    @staticmethod
    def warm():
        Embreex(np.eye(3), np.array([[0, 1, 2]]))

    def __init__(self, v, f):
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh

        self.scene = rtcs.EmbreeScene()
        TriangleMesh(self.scene, v.astype(np.float32), f.astype(np.int32))
        self.scene.run(np.array([[150, 0, 1.5]], np.float32), np.array([[1, 0, 0]], np.float32))

    def cast(self, o, d):
        o32 = np.broadcast_to(np.asarray(o, np.float32), d.shape).copy()
        r = self.scene.run(o32, d.astype(np.float32), output=1)
        t = r["tfar"].astype(np.float64)
        t[r["geomID"] < 0] = np.inf
        return t


ENGINES: dict[str, Any] = {"ours": Ours, "open3d": Open3D, "embreex": Embreex}


def worker(engine: str, mesh_path: str, rays_path: str, out_dir: str) -> dict:
    z = np.load(mesh_path)
    v, f = z["v"], z["f"]
    ENGINES[engine].warm()
    rss0 = _rss_mb()
    t0 = time.perf_counter()
    eng = ENGINES[engine](v, f)
    build_s = time.perf_counter() - t0
    scene_mb = _rss_mb() - rss0
    # Second build, timed only: the first also pays first-touch page faults.
    t0 = time.perf_counter()
    eng = ENGINES[engine](v, f)
    build_s = min(build_s, time.perf_counter() - t0)
    res = dict(engine=engine, triangles=int(len(f)), build_s=build_s, scene_mb=scene_mb)
    if engine == "ours":
        res["ours_nbytes_mb"] = eng.scene.nbytes / 2**20
        res["ours_stats"] = eng.scene.stats
    rays = np.load(rays_path)
    kinds = [k[:-2] for k in rays.files if k.endswith("_d")]
    res["sets"] = kinds
    for kind in kinds:
        o, d = rays[f"{kind}_o"], rays[f"{kind}_d"]
        if o.shape[0] == 1 and kind.endswith("_array"):
            o = np.repeat(o, d.shape[0], axis=0)  # stored once, cast as (n, 3)
        elif o.shape[0] == 1:
            o = o[0]  # a (3,) origin
        eng.cast(o if o.ndim == 1 else o[:1000], d[:1000])  # warm-up
        dt = np.inf
        for _ in range(REPEATS):  # best of REPEATS: this VM's timings vary by ~30 %
            t0 = time.perf_counter()
            t = eng.cast(o, d)
            dt = min(dt, time.perf_counter() - t0)
        res[f"{kind}_mrays"] = d.shape[0] / dt / 1e6
        res[f"{kind}_rays"] = int(d.shape[0])
        res[f"{kind}_hit"] = float(np.isfinite(t).mean())
        np.save(Path(out_dir) / f"{engine}_{kind}.npy", t[:CHECK_RAYS])
        del o, d, t
    res["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return res


def drive_rays(tun, seconds: float, chainage_m: float = 100.0, height_m: float = 0.5):
    """(origins (n, 3), directions (n, 3)): a RoboSense Airy on a platform at 1 m/s
    along the centreline, each pulse from the sensor pose at its own time (as
    ``sensors.simulate_drive`` casts them, without the return physics)."""
    from sensors import Mount, Trajectory, load_sensor
    from sensors.patterns import scan_for

    s = np.append(np.arange(chainage_m, chainage_m + seconds + 2.0, 0.5),
                  chainage_m + seconds + 2.0)
    traj = Trajectory.along_polyline(tun.alignment.to_world(s, 0.0, height_m), 1.0)
    o, d = [], []
    for p in scan_for(load_sensor("robosense_airy"), duration_s=seconds).chunks():
        pos, mat = traj.sensor_matrices(p.time, Mount())
        o.append(pos)
        d.append(np.einsum("nij,nj->ni", mat, p.direction))
    return np.concatenate(o), np.concatenate(d)


def station_rays(tun, step_deg: float, chainage_m: float = 60.0, height_m: float = 1.5):
    """(origin (3,), directions (n, 3)): a level Z+F IMAGER 5016 station, scan order."""
    from sensors import load_sensor
    from sensors.patterns import scan_for

    at = np.asarray(tun.alignment.to_world(chainage_m, 0.0, height_m), dtype=np.float64)
    scan = scan_for(load_sensor("zf_imager_5016"), step_rad=np.deg2rad(step_deg))
    return at.reshape(3), np.concatenate([p.direction for p in scan.chunks()])


def near_path_rays(path_origins, n: int, seed: int = 7, spread_m: float = 0.5):
    """n random directions from origins within ``spread_m`` of random path origins."""
    rng = np.random.default_rng(seed)
    o = path_origins[rng.integers(0, len(path_origins), n)] + rng.uniform(
        -spread_m, spread_m, (n, 3))
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return o, d


def _run_engines(engines, mesh, rays, tmp):
    results = {}
    for eng in engines:
        cmd = [sys.executable, __file__, "--worker", eng, "--mesh", str(mesh),
               "--ray-file", str(rays), "--out", tmp]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            print(f"[{eng}] failed:\n{p.stderr[-2000:]}", file=sys.stderr)
            continue
        results[eng] = json.loads(p.stdout.strip().splitlines()[-1])
    return results


def _compare(results, label, tmp):
    """Ratios to Open3D and agreement with it, added to each engine's row."""
    ref = results.get("open3d")
    rows = []
    for eng, r in results.items():
        r["mesh"] = label
        for kind in r["sets"]:
            if ref and eng != "open3d":
                a = np.load(Path(tmp) / f"{eng}_{kind}.npy")
                b = np.load(Path(tmp) / f"open3d_{kind}.npy")
                r[f"{kind}_agree"], r[f"{kind}_max_dt"] = _agreement(a, b)
            if ref:
                r[f"{kind}_ratio"] = r[f"{kind}_mrays"] / ref[f"{kind}_mrays"]
        if ref:
            r["build_ratio"] = r["build_s"] / ref["build_s"]
            r["mem_ratio"] = r["scene_mb"] / max(ref["scene_mb"], 1e-9)
        rows.append(r)
    return rows


def build_rounds(engines, v, f, rounds: int, label: str) -> list[dict[str, Any]]:
    """Build seconds of every engine on (v, f), ``rounds`` alternated rounds in this
    process (order reversed every other round); rows with best, median, all rounds
    and the ratios of best and median to Open3D's."""
    for eng in engines:
        ENGINES[eng].warm()
    times: dict[str, list[float]] = {eng: [] for eng in engines}
    for r in range(rounds):
        for eng in (engines if r % 2 == 0 else engines[::-1]):
            t0 = time.perf_counter()
            obj = ENGINES[eng](v, f)
            times[eng].append(time.perf_counter() - t0)
            del obj
    rows = []
    ref = times.get("open3d")
    for eng, ts in times.items():
        best, median = float(np.min(ts)), float(np.median(ts))
        row: dict[str, Any] = dict(engine=eng, mesh=label, triangles=int(len(f)),
                                   rounds=rounds, build_best_s=best, build_median_s=median,
                                   build_s_all=[float(t) for t in ts])
        if ref:
            row["build_ratio_best"] = best / float(np.min(ref))
            row["build_ratio_median"] = median / float(np.median(ref))
        rows.append(row)
    return rows


def _print_build_table(rows):
    r0 = rows[0]
    print(f"\n### {r0['mesh']}: {r0['triangles']:,} triangles; builds, {r0['rounds']} "
          "alternated rounds in one process\n")
    print("| engine | best s | median s | ratio to Open3D (best / median) |")
    print("|---|---:|---:|---|")
    for r in rows:
        ratio = (f"{r['build_ratio_best']:.2f} / {r['build_ratio_median']:.2f}"
                 if "build_ratio_best" in r else "-")
        print(f"| {r['engine']} | {r['build_best_s']:.3f} | {r['build_median_s']:.3f} | "
              f"{ratio} |")
    sys.stdout.flush()


def _agreement(a, b):
    ha, hb = np.isfinite(a), np.isfinite(b)
    both = ha & hb
    return (float((ha == hb).mean()), float(np.abs(a[both] - b[both]).max()) if both.any()
            else 0.0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="1e5,1e6,4e6",
                    help="tube triangle counts, comma-separated ('' for none)")
    ap.add_argument("--rays", type=float, default=1e7, help="rays per tube set (default 10M)")
    ap.add_argument("--bfo-edge", type=float, default=0.1,
                    help="edge length of the bfo preset, m (0: skip the bfo sets)")
    ap.add_argument("--drive-s", type=float, default=8.0,
                    help="seconds of Airy drive (default 8: 6.9M rays)")
    ap.add_argument("--station-step-deg", type=float, default=0.12,
                    help="angular step of the station (default 0.12 deg: 4.0M rays)")
    ap.add_argument("--random-rays", type=float, default=4e6,
                    help="random rays near the drive's path (default 4M)")
    ap.add_argument("--engines", default="ours,open3d,embreex")
    ap.add_argument("--build-rounds", type=int, default=0,
                    help="builds only: this many alternated rounds of every engine in "
                    "one process (best and median); no rays")
    ap.add_argument("--json", help="write all figures to this JSON file")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--mesh", help=argparse.SUPPRESS)
    ap.add_argument("--ray-file", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.worker, args.mesh, args.ray_file, args.out)))
        return 0

    # DECISION: the repository root only where raytrace is not importable otherwise (an
    # uninstalled checkout): first on the path it hid the engine a PYTHONPATH names, so
    # in-process A/B runs (--build-rounds) timed this tree twice.
    import importlib.util

    if importlib.util.find_spec("raytrace") is None:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from raytrace.shapes import tunnel_tube

    engines = args.engines.split(",")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        mesh, rays = Path(tmp) / "mesh.npz", Path(tmp) / "rays.npz"
        for size in (int(float(s)) for s in args.sizes.split(",") if s.strip()):
            v, f = tunnel_tube(size, length_m=300.0, roughness_m=0.002, seed=0)
            if args.build_rounds > 0:
                new = build_rounds(engines, v, f, args.build_rounds, "tube")
                _print_build_table(new)
                rows += new
                continue
            np.savez(mesh, v=v, f=f)
            so, sd = coherent_rays(int(args.rays))
            io, idir = incoherent_rays(int(args.rays))
            np.savez(rays, coherent_o=so[None], coherent_d=sd, incoherent_o=io,
                     incoherent_d=idir)
            del so, sd, io, idir
            new = _compare(_run_engines(engines, mesh, rays, tmp), "tube", tmp)
            _print_table(new)
            rows += new
        if args.bfo_edge > 0:
            from survey.world.presets import preset

            tun, _ = preset("bfo", edge_length_m=args.bfo_edge)
            if args.build_rounds > 0:
                new = build_rounds(engines, np.asarray(tun.vertices),
                                   np.asarray(tun.faces), args.build_rounds, "bfo")
                _print_build_table(new)
                rows += new
                if args.json:
                    Path(args.json).write_text(json.dumps(rows, indent=1))
                return 0
            np.savez(mesh, v=tun.vertices, f=tun.faces)
            do, dd = drive_rays(tun, args.drive_s)
            so, sd = station_rays(tun, args.station_step_deg)
            ro, rd = near_path_rays(do, int(args.random_rays))
            # Station origin stored once; the worker repeats it for the (n, 3) set.
            np.savez(rays, drive_o=do, drive_d=dd, station_array_o=so[None],
                     station_array_d=sd, station_o=so[None], station_d=sd, random_o=ro,
                     random_d=rd)
            del do, dd, so, sd, ro, rd
            new = _compare(_run_engines(engines, mesh, rays, tmp), "bfo", tmp)
            _print_table(new)
            rows += new
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


def _print_table(rows):
    if not rows:
        return
    kinds = rows[0]["sets"]
    r0 = rows[0]
    print(f"\n### {r0['mesh']}: {r0['triangles']:,} triangles; rays: " +
          ", ".join(f"{k} {r0[k + '_rays']:,}" for k in kinds) + "\n")
    print("| engine | build s | scene MB | " + " | ".join(f"{k} Mrays/s" for k in kinds) +
          " | peak RSS MB | ratio to Open3D (build / mem / " + " / ".join(kinds) +
          ") | agreement with Open3D (hit/miss, max abs dt m) |")
    print("|---|---:|---:|" + "---:|" * len(kinds) + "---:|---|---|")
    for r in rows:
        ratio = (" / ".join([f"{r['build_ratio']:.2f}", f"{r['mem_ratio']:.2f}"] +
                            [f"{r[k + '_ratio']:.2f}" for k in kinds])
                 if "build_ratio" in r else "-")
        agree = ("; ".join(f"{k} {100 * r[k + '_agree']:.4f} %, {r[k + '_max_dt']:.1e}"
                           for k in kinds) if f"{kinds[0]}_agree" in r else "(reference)")
        print(f"| {r['engine']} | {r['build_s']:.2f} | {r['scene_mb']:.0f} | " +
              " | ".join(f"{r[k + '_mrays']:.2f}" for k in kinds) +
              f" | {r['peak_rss_mb']:.0f} | {ratio} | {agree} |")
    sys.stdout.flush()


if __name__ == "__main__":
    sys.exit(main())
