"""Cluster benchmark (issue 19): the same campaign and the same drive in this process and
on a dask LocalCluster of 1 and 2 workers on this machine, with the speed-up, the
efficiency and the overhead per task, and a projection for a 5 km tunnel.

* ``stations``: ``--stations`` TLS stations (default 8, Z+F IMAGER 5016 at
  ``--resolution``, default preview) every 10 m on the axis of a generated ``tbm``
  tunnel, written to LAZ with a manifest (``survey.cluster.scan_stations``).
* ``drive``: a VLP-16 for ``--drive-s`` seconds (default 60) at 1 m/s along the axis,
  in ``--window-s`` windows (default 5), merged into one NPZ
  (``survey.cluster.simulate_windows``; needs ``sensors.Run.chunks``, skipped without).
* ``overhead``: 64 empty tasks through the executor: the scheduling cost per task; and
  the cluster's start (workers spawned, simulation imported) timed apart.

Speed-up = in-process wall / cluster wall (cluster start excluded, reported apart);
efficiency = speed-up / workers. Each worker of an N-worker LocalCluster gets
cores / N Numba threads, so on this 2-core machine 2 workers trade Numba's threads for
processes: the figure says what the dask layer costs or gains, not a cluster's scaling.

Projection: the 5 km tunnel scanned every 5 m (1,000 stations) at ``high`` (about 56M
rays each): time = ceil(1000 / W) x (rays / measured in-process rays/s + overhead per
task) + start, on W machines like this one. ASSUMED: each worker is a machine like this
one (its per-station speed is the measured in-process one), the shared filesystem keeps
up (LAZ about 25 B a point), and no worker is lost.

Usage::

    python benchmarks/bench_cluster.py --json benchmarks/results_cluster.json
    python benchmarks/bench_cluster.py --stations 4 --drive-s 10    # a quick look
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

#: Rays of one "high" IMAGER 5016 station (10,000 px / 360 deg, 320 deg vertical).
HIGH_RAYS = 56e6
#: The 5 km tunnel scanned every 5 m.
PROJECT_STATIONS = 1000


def _noop(x):
    return x


def _tunnel(tmp: Path) -> Path:
    from survey.cli.main import main

    out = tmp / "tbm.ply"
    assert main(["tunnel", "--preset", "tbm", "--triangles", "200000", "-o", str(out),
                 "--quiet"]) == 0
    return out


def _stations(scene, mesh: Path, n: int):
    from survey.analysis.planning import axis_stations
    from survey.cluster import Station
    from survey.world.mesh import read_axis
    from sensors.io.tunnel_json import sidecar

    al, hc = read_axis(sidecar(mesh))
    ch = 10.0 + 10.0 * np.arange(n)
    xyz = axis_stations(scene, al, hc, ch, height_m=1.5)
    return [Station(tuple(map(float, p)), 0.0, float(c)) for p, c in zip(xyz, ch)]


def _drive_run(scene, refl, mesh: Path, duration_s: float):
    from sensors import Trajectory, load_sensor, simulate_drive
    from sensors.platform import platform_trajectory
    from sensors.platform_spec import load_platform
    from survey.world.mesh import read_axis
    from sensors.io.tunnel_json import sidecar

    al, _hc = read_axis(sidecar(mesh))
    s = np.append(np.arange(5.0, 5.0 + duration_s + 2, 0.5), 5.0 + duration_s + 2)
    traj = platform_trajectory(al.to_world(s, 0.0, 0.5), load_platform("trolley"), 1.0)
    assert isinstance(traj, Trajectory)
    return simulate_drive(scene, load_sensor("velodyne_vlp16"), traj, seed=1,
                          reflectivity=refl, t_end=traj.start_s + duration_s)


def _one(workers, scene, refl, spec, stations, args, tmp: Path, drive_run):
    from survey.cluster import open_executor, scan_stations, simulate_windows

    out: dict = {"workers": workers or 0}
    t0 = time.perf_counter()
    ex = open_executor(workers)
    out["start_s"] = time.perf_counter() - t0
    try:
        t0 = time.perf_counter()
        ex.map(_noop, list(range(64)))
        out["overhead_per_task_s"] = (time.perf_counter() - t0) / 64
        folder = tmp / f"st{workers}"
        folder.mkdir()
        t0 = time.perf_counter()
        camp = scan_stations(scene, spec, stations, folder, executor=ex,
                             resolution=args.resolution, seed=0, reflectivity=refl)
        out["stations_wall_s"] = time.perf_counter() - t0
        out["station_task_s"] = camp.seconds.tolist()
        out["stations_points"] = camp.points
        out["stations_pulses"] = camp.pulses
        out["stations_sha256"] = [s["sha256"] for s in camp.manifest["stations"]]
        shutil.rmtree(folder)
        if drive_run is not None:
            t0 = time.perf_counter()
            m = simulate_windows(drive_run, args.window_s, tmp / f"d{workers}.npz",
                                 reflectivity=refl, executor=ex)
            out["drive_wall_s"] = time.perf_counter() - t0
            out["drive_points"] = m["points"]
            out["drive_windows"] = len(m["windows"])
            out["drive_sha256"] = m["sha256"]
            (tmp / f"d{workers}.npz").unlink()
    finally:
        ex.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stations", type=int, default=8)
    ap.add_argument("--resolution", default="preview")
    ap.add_argument("--drive-s", type=float, default=60.0)
    ap.add_argument("--window-s", type=float, default=5.0)
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args()

    from sensors import load_sensor
    from sensors.io.meshes import load_mesh
    from sensors.simulate import Run

    tmp = Path(tempfile.mkdtemp(prefix="bench_cluster_"))
    try:
        mesh = _tunnel(tmp)
        scene, refl = load_mesh(mesh)
        spec = load_sensor("zf_imager_5016")
        stations = _stations(scene, mesh, args.stations)
        drive = _drive_run(scene, refl, mesh, args.drive_s) if hasattr(Run, "chunks") \
            else None
        # Warm the Numba cache in this process first (every run then loads, not
        # compiles).
        from survey.cluster import scan_stations

        warm = tmp / "warm"
        warm.mkdir()
        scan_stations(scene, spec, stations[:1], warm, step_rad=math.radians(5))
        runs = [_one(w, scene, refl, spec, stations, args, tmp, drive)
                for w in (None, 1, 2)]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    base = runs[0]
    for r in runs:
        assert r["stations_sha256"] == base["stations_sha256"], "stations differ"
        if drive is not None:
            assert r["drive_sha256"] == base["drive_sha256"], "drive differs"
        w = max(r["workers"], 1)
        r["stations_speedup"] = base["stations_wall_s"] / r["stations_wall_s"]
        r["stations_efficiency"] = r["stations_speedup"] / w
        if drive is not None:
            r["drive_speedup"] = base["drive_wall_s"] / r["drive_wall_s"]
            r["drive_efficiency"] = r["drive_speedup"] / w
    rays_per_s = base["stations_pulses"] / base["stations_wall_s"]
    one_cluster = runs[1]
    per_task = one_cluster["stations_wall_s"] / args.stations - \
        base["stations_wall_s"] / args.stations
    high_s = HIGH_RAYS / rays_per_s
    projection = {str(w): (math.ceil(PROJECT_STATIONS / w) * (high_s + max(per_task, 0.0))
                           + one_cluster["start_s"]) / 3600.0 for w in (1, 8, 64)}
    result = {"stations": args.stations, "resolution": args.resolution,
              "drive_s": args.drive_s if drive is not None else None,
              "window_s": args.window_s, "runs": runs,
              "in_process_rays_per_s": rays_per_s,
              "cluster_overhead_per_station_s": per_task,
              "high_station_s": high_s, "projection_5km_hours": projection}
    for r in runs:
        name = "in-process" if not r["workers"] else f"{r['workers']} worker(s)"
        line = (f"{name:12s} start {r['start_s']:5.1f} s  stations "
                f"{r['stations_wall_s']:6.1f} s (x{r['stations_speedup']:.2f}, eff "
                f"{100 * r['stations_efficiency']:.0f} %)  empty task "
                f"{1e3 * r['overhead_per_task_s']:.1f} ms")
        if drive is not None:
            line += (f"  drive {r['drive_wall_s']:6.1f} s (x{r['drive_speedup']:.2f}, "
                     f"eff {100 * r['drive_efficiency']:.0f} %)")
        print(line)
    print(f"per-station cost {base['stations_wall_s'] / args.stations:.2f} s "
          f"({rays_per_s / 1e6:.2f} Mrays/s), cluster overhead per station "
          f"{per_task:.2f} s; a high station {high_s:.0f} s")
    print("5 km tunnel, 1,000 high stations: " + ", ".join(
        f"{w} workers {h:.1f} h" for w, h in projection.items()))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
