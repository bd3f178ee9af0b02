"""Sensor benchmark: a full Z+F IMAGER 5016 station streamed to LAZ, against Open3D's
bare casting of the same rays, in one run.

* ``ours``: ``sensors.simulate_station`` end to end: pattern generation, casting (cube
  map from the station), return physics (noise, jitter, detection, intensity) and the
  LAZ writer (compact extra bytes, the station default), into a temporary file.
* ``open3d``: the same rays (same pattern, generated outside the timing) through
  ``open3d.t.geometry.RaycastingScene.cast_rays`` in chunks of 1M rays; casting only.

Each engine runs in its own subprocess; peak memory is its maximum RSS. The mesh is the
``bfo`` preset (300 m gallery with cables, niches, bolts and prisms) at the edge length
that gives about 1M triangles; the station stands on the centreline at chainage 60 m,
1.5 m above the floor.

Usage::

    python benchmarks/bench_sensors.py                       # superhigh: 225M rays
    python benchmarks/bench_sensors.py --resolution high --json out.json

Needs the ``bench`` extra (open3d); Open3D also needs libusb-1.0 (Debian:
``apt-get install libusb-1.0-0``).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _world(edge):
    from survey.world.presets import preset

    tun, _ = preset("bfo", edge_length_m=edge)
    at = tun.alignment.to_world(60.0, 0.0, 1.5)
    return tun, np.asarray(at, dtype=np.float64)


def _ours(a) -> dict:
    from raytrace import Scene
    from sensors import simulate_station

    tun, at = _world(a.edge)
    t0 = time.perf_counter()
    scene = Scene(tun.vertices, tun.faces)
    build = time.perf_counter() - t0
    # Compile the kernels outside the timing (a tiny station).
    simulate_station(scene, "zf_imager_5016", at, resolution="preview",
                     reflectivity=tun.reflectivity).write(Path(a.tmp) / "warm.laz")
    run = simulate_station(scene, "zf_imager_5016", at, resolution=a.resolution,
                           reflectivity=tun.reflectivity)
    out = Path(a.tmp) / f"station.{a.format}"
    t0 = time.perf_counter()
    stats = run.write(out, fields=a.fields)
    wall = time.perf_counter() - t0
    return {"engine": "ours", "triangles": int(len(tun.faces)), "build_s": build,
            "rays": run.n_pulses, "points": stats["points"], "wall_s": wall,
            "mrays_per_s": run.n_pulses / wall / 1e6,
            "file_mb": out.stat().st_size / 2**20,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _open3d(a) -> dict:
    import open3d as o3d

    from sensors import TLSScan, load_sensor

    tun, at = _world(a.edge)
    t0 = time.perf_counter()
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(o3d.core.Tensor(tun.vertices.astype(np.float32)),
                     o3d.core.Tensor(tun.faces.astype(np.uint32)))
    scan = TLSScan(load_sensor("zf_imager_5016"), a.resolution)
    rays = np.empty((1, 6), np.float32)
    sc.cast_rays(o3d.core.Tensor(rays))               # builds the BVH
    build = time.perf_counter() - t0
    cast = 0.0
    hits = 0
    for c in scan.chunks(1 << 20):
        rays = np.empty((len(c), 6), np.float32)
        rays[:, :3] = at
        rays[:, 3:] = c.direction
        t = o3d.core.Tensor(rays)
        t0 = time.perf_counter()
        ans = sc.cast_rays(t)
        d = ans["t_hit"].numpy()
        cast += time.perf_counter() - t0
        hits += int(np.isfinite(d).sum())
    return {"engine": "open3d", "triangles": int(len(tun.faces)), "build_s": build,
            "rays": scan.n_pulses, "points": hits, "wall_s": cast,
            "mrays_per_s": scan.n_pulses / cast / 1e6, "file_mb": 0.0,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="superhigh")
    ap.add_argument("--edge", type=float, default=0.1,
                    help="lining edge length of the bfo tunnel (0.1 m: ~0.8M triangles in "
                         "all; 0.09 m: ~1M)")
    ap.add_argument("--format", default="laz", choices=["laz", "las", "npz", "ply"])
    ap.add_argument("--fields", default="compact", choices=["compact", "full"])
    ap.add_argument("--engines", nargs="+", default=["ours", "open3d"])
    ap.add_argument("--json", help="write the figures to this file")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--tmp", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps({"ours": _ours, "open3d": _open3d}[a.child](a)))
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for eng in a.engines:
            cmd = [sys.executable, __file__, "--child", eng, "--tmp", tmp, "--resolution",
                   a.resolution, "--edge", str(a.edge), "--format", a.format, "--fields",
                   a.fields]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            rows.append(json.loads(out.strip().splitlines()[-1]))
            r = rows[-1]
            print(f"{r['engine']:7s} {r['triangles']:,} triangles, {r['rays']:,} rays -> "
                  f"{r['points']:,} points: {r['wall_s']:.1f} s, {r['mrays_per_s']:.2f} "
                  f"Mrays/s, peak RSS {r['peak_rss_mb']:.0f} MB, file {r['file_mb']:.0f} MB",
                  flush=True)
    if len(rows) == 2:
        print(f"ratio ours end-to-end / Open3D bare casting: "
              f"{rows[0]['mrays_per_s'] / rows[1]['mrays_per_s']:.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps({"resolution": a.resolution, "format": a.format,
                                            "fields": a.fields, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
