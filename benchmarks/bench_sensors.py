"""Sensor benchmark: a full Z+F IMAGER 5016 station streamed to LAZ, against Open3D's
bare casting of the same rays and against lazrs compressing the same points alone, and
a RoboSense Airy drive end to end to LAZ/LAS/NPZ against real time, in one run.

* ``ours``: ``sensors.simulate_station`` end to end: pattern generation, casting (cube
  map from the station), return physics (noise, jitter, detection, intensity) and the
  LAZ writer (compact extra bytes, the station default), into a temporary file.
* ``open3d``: the same rays (same pattern, generated outside the timing) through
  ``open3d.t.geometry.RaycastingScene.cast_rays`` in chunks of 1M rays; casting only.
* ``lazrs``: the station's points (written to LAS by ``ours`` first, untimed) compressed
  to LAZ by laspy + lazrs alone, chunk by chunk: the floor for ``ours`` to LAZ.
* ``drive``: the Airy at 1 m/s along the centreline of the same tunnel (0.5 m above the
  floor, from chainage 50 m) for ``--drive-s`` seconds, simulated and written by
  ``Run.write`` (writer thread on), once per ``--drive-formats`` entry, plus a pass
  without writing (``sim``): wall time, real-time factor (simulated seconds / wall
  seconds) and M points/s. ``--drive-sensor ouster_os1_64`` gives the OS1-64 rows of
  issue 30 (its speed as x real time, into memory and to LAZ).
* ``size``: the LAZ size of issue 30: a ``--size-sensor`` (default VLP-16) drive of
  ``--size-s`` seconds (default 120) on the same line, simulated once into memory, then
  written as LAZ (full fields: sensor_x.. and range float32, the default since issue
  30), as LAZ with the float64 types of earlier versions (``LAS_EXTRA_F8``) and as an
  MCAP bag: bytes, bytes per point, write wall time.

Each engine runs in its own subprocess; peak memory is its maximum RSS. The mesh is the
``bfo`` preset (300 m gallery with cables, niches, bolts and prisms) at the edge length
that gives about 1M triangles; the station stands on the centreline at chainage 60 m,
1.5 m above the floor.

Usage::

    python benchmarks/bench_sensors.py                       # superhigh: 225M rays
    python benchmarks/bench_sensors.py --resolution high --json out.json
    python benchmarks/bench_sensors.py --engines drive --drive-s 60
    python benchmarks/bench_sensors.py --engines size --size-s 120          # issue 30
    python benchmarks/bench_sensors.py --engines drive --drive-sensor ouster_os1_64 \
        --drive-s 10 --drive-formats laz:full
    python benchmarks/bench_sensors.py --engines ours --format las          # issue 33
    python benchmarks/bench_sensors.py --engines drive --drive-formats laz:compact

Issue 33 rows: a station or drive whose pulses exceed the run's replay cache (SUPERHIGH,
a 60 s Airy drive) is written with LAS/LAZ records made straight from the pulse kernels
(``sensors.simulate``); a shorter drive (``--drive-s`` 5) fits the cache and is written
from point records. Every timed row gives its CPU time and the load average before and
after (the VM is shared: compare rows of one run).

Needs the ``bench`` extra (open3d); Open3D also needs libusb-1.0 (Debian:
``apt-get install libusb-1.0-0``).
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
    # Compile the kernels outside the timing (a tiny station, in the same format, with
    # no replay cache: the path a station too large for the cache takes, issue 33).
    simulate_station(scene, "zf_imager_5016", at, resolution="preview",
                     reflectivity=tun.reflectivity, cache_bytes=0).write(
        Path(a.tmp) / f"warm.{a.format}", fields=a.fields)
    run = simulate_station(scene, "zf_imager_5016", at, resolution=a.resolution,
                           reflectivity=tun.reflectivity)
    out = Path(a.tmp) / f"station.{a.format}"
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    c0 = time.process_time()
    stats = run.write(out, fields=a.fields)
    wall = time.perf_counter() - t0
    return {"engine": "ours", "triangles": int(len(tun.faces)), "build_s": build,
            "rays": run.n_pulses, "points": stats["points"], "wall_s": wall,
            "cpu_s": time.process_time() - c0,
            "mrays_per_s": run.n_pulses / wall / 1e6,
            "file_mb": out.stat().st_size / 2**20,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "load_before": load, "load_after": os.getloadavg()[0]}


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


def _lazrs(a) -> dict:
    """lazrs alone: the station's LAS records (from ``ours``, untimed) to LAZ."""
    import laspy

    from raytrace import Scene
    from sensors import simulate_station

    tun, at = _world(a.edge)
    scene = Scene(tun.vertices, tun.faces)
    src = Path(a.tmp) / "station_for_lazrs.las"
    run = simulate_station(scene, "zf_imager_5016", at, resolution=a.resolution,
                           reflectivity=tun.reflectivity)
    run.write(src, fields=a.fields)
    wall = 0.0
    with laspy.open(src) as r:
        head = r.header
        n = head.point_count
        # Same chunks as the writer's (one per simulated chunk, ~1M pulses).
        with laspy.open(Path(a.tmp) / "lazrs.laz", mode="w", header=head,
                        do_compress=True) as w:
            for rec in r.chunk_iterator(1 << 20):
                t0 = time.perf_counter()
                w.write_points(rec)
                wall += time.perf_counter() - t0
            t0 = time.perf_counter()
        wall += time.perf_counter() - t0                  # the close (last chunk)
    return {"engine": "lazrs", "triangles": int(len(tun.faces)), "build_s": 0.0,
            "rays": run.n_pulses, "points": int(n), "wall_s": wall,
            "mrays_per_s": run.n_pulses / wall / 1e6,
            "file_mb": (Path(a.tmp) / "lazrs.laz").stat().st_size / 2**20,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _drive(a) -> list[dict]:
    from raytrace import Scene
    from sensors import Mount, Trajectory, load_sensor, simulate_drive

    tun, _ = _world(a.edge)
    scene = Scene(tun.vertices, tun.faces)
    s = np.array([50.0, 50.0 + a.drive_s + 1.0])
    truth = Trajectory.along_polyline(tun.alignment.to_world(s, 0.0, 0.5), 1.0)
    sensor = load_sensor(a.drive_sensor)

    def run(d):
        return simulate_drive(scene, sensor, truth, Mount(), seed=1,
                              reflectivity=tun.reflectivity, t_end=truth.start_s + d)
    # Compile every kernel outside the timing (a short drive, every format).
    for spec in a.drive_formats:
        fmt, fields = spec.split(":")
        run(0.1).write(Path(a.tmp) / f"warm.{fmt}", fields=fields)
        # ... and the LAS/LAZ records made straight from the kernels (issue 33), the
        # path of a drive too long for the replay cache (the default 60 s).
        simulate_drive(scene, sensor, truth, Mount(), seed=1, reflectivity=tun.reflectivity,
                       t_end=truth.start_s + 0.1, cache_bytes=0).write(
            Path(a.tmp) / f"warm.{fmt}", fields=fields)
    rows = []
    for spec in ["sim:-"] + list(a.drive_formats):
        fmt, fields = spec.split(":")
        r = run(a.drive_s)
        load = os.getloadavg()[0]
        t0 = time.perf_counter()
        c0 = time.process_time()
        if fmt == "sim":
            n = sum(len(c) for c in r)
            size = 0.0
        else:
            out = Path(a.tmp) / f"drive.{fmt}"
            n = r.write(out, fields=fields)["points"]
            size = out.stat().st_size / 2**20
            out.unlink()
        wall = time.perf_counter() - t0
        rows.append({"engine": f"drive {fmt}" + ("" if fmt in ("sim", "npz", "ply")
                                                 else f" {fields}"),
                     "simulated_s": a.drive_s, "pulses": r.n_pulses, "points": int(n),
                     "wall_s": wall, "cpu_s": time.process_time() - c0,
                     "realtime_factor": a.drive_s / wall, "mpoints_per_s": n / wall / 1e6,
                     "file_mb": size, "load_before": load,
                     "load_after": os.getloadavg()[0],
                     "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024})
    return rows


def _size(a) -> list[dict]:
    """Issue 30: the size of a drive's LAZ (float32 and float64 sensor fields) and of
    its MCAP bag, from one simulation held in memory."""
    import sensors.writers
    from raytrace import Scene
    from sensors import Mount, Trajectory, load_sensor, simulate_drive
    from sensors.io.fields import LAS_EXTRA, LAS_EXTRA_F8

    tun, _ = _world(a.edge)
    scene = Scene(tun.vertices, tun.faces)
    s = np.array([50.0, 50.0 + a.size_s + 1.0])
    truth = Trajectory.along_polyline(tun.alignment.to_world(s, 0.0, 0.5), 1.0)
    sensor = load_sensor(a.size_sensor)

    def run(d):
        return simulate_drive(scene, sensor, truth, Mount(), seed=1,
                              reflectivity=tun.reflectivity, t_end=truth.start_s + d)
    run(0.1).write(Path(a.tmp) / "warm.laz", fields="full")     # compile outside
    r = run(a.size_s)
    t0 = time.perf_counter()
    chunks = list(r)
    sim = time.perf_counter() - t0
    n = sum(len(c) for c in chunks)
    rows = [{"engine": f"size sim {a.size_sensor}", "simulated_s": a.size_s,
             "points": n, "wall_s": sim, "bytes": 0, "bytes_per_point": 0.0}]
    for label, name, extra, fields in (("laz f4 (default)", "d.laz", LAS_EXTRA, "full"),
                                       ("laz f8 (old)", "d8.laz", LAS_EXTRA_F8, "full"),
                                       ("mcap bag", "d.mcap", LAS_EXTRA, None)):
        sensors.writers.LAS_EXTRA = extra          # _LasPoints reads it when opened
        out = Path(a.tmp) / name
        t0 = time.perf_counter()
        r.write(out, fields=fields, points=chunks)
        wall = time.perf_counter() - t0
        size = out.stat().st_size
        out.unlink()
        rows.append({"engine": f"size {label}", "simulated_s": a.size_s, "points": n,
                     "wall_s": wall, "bytes": size, "bytes_per_point": size / max(n, 1)})
    sensors.writers.LAS_EXTRA = LAS_EXTRA
    for row in rows:
        row["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="superhigh")
    ap.add_argument("--edge", type=float, default=0.1,
                    help="lining edge length of the bfo tunnel (0.1 m: ~0.8M triangles in "
                         "all; 0.09 m: ~1M)")
    ap.add_argument("--format", default="laz", choices=["laz", "las", "npz", "ply"])
    ap.add_argument("--fields", default="compact", choices=["compact", "full"])
    ap.add_argument("--engines", nargs="+", default=["ours", "open3d", "lazrs", "drive"],
                    choices=["ours", "open3d", "lazrs", "drive", "size"])
    ap.add_argument("--drive-s", type=float, default=60.0,
                    help="simulated seconds of the Airy drive (default 60, as issue 16)")
    ap.add_argument("--drive-formats", nargs="+",
                    default=["laz:compact", "laz:full", "las:full", "npz:full"],
                    help="FORMAT:FIELDS entries written by the drive rows")
    ap.add_argument("--drive-sensor", default="robosense_airy",
                    help="sensor of the drive rows (issue 30: ouster_os1_64)")
    ap.add_argument("--size-s", type=float, default=120.0,
                    help="simulated seconds of the size rows (default 120, issue 30)")
    ap.add_argument("--size-sensor", default="velodyne_vlp16",
                    help="sensor of the size rows (default velodyne_vlp16)")
    ap.add_argument("--json", help="write the figures to this file")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--tmp", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps({"ours": _ours, "open3d": _open3d, "lazrs": _lazrs,
                          "drive": _drive, "size": _size}[a.child](a)))
        return
    rows: list[dict] = []
    drives: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        for eng in a.engines:
            cmd = [sys.executable, __file__, "--child", eng, "--tmp", tmp, "--resolution",
                   a.resolution, "--edge", str(a.edge), "--format", a.format, "--fields",
                   a.fields, "--drive-s", str(a.drive_s), "--drive-sensor",
                   a.drive_sensor, "--size-s", str(a.size_s), "--size-sensor",
                   a.size_sensor, "--drive-formats", *a.drive_formats]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            got = json.loads(out.strip().splitlines()[-1])
            if eng == "size":
                drives += got
                for r in got:
                    print(f"{r['engine']:24s} {r['simulated_s']:.0f} s, {r['points']:,} "
                          f"points: {r['bytes']:,} bytes ({r['bytes']/1e9:.3f} GB), "
                          f"{r['bytes_per_point']:.2f} bytes/point, {r['wall_s']:.1f} s "
                          f"wall, peak RSS {r['peak_rss_mb']:.0f} MB", flush=True)
                continue
            if eng == "drive":
                drives += got
                for r in got:
                    print(f"{r['engine']:22s} {r['simulated_s']:.0f} s, {r['points']:,} "
                          f"points: {r['wall_s']:.1f} s wall ({r['cpu_s']:.1f} s CPU), "
                          f"{r['realtime_factor']:.2f}x real time, "
                          f"{r['mpoints_per_s']:.2f} M points/s, file "
                          f"{r['file_mb']:.0f} MB, peak RSS {r['peak_rss_mb']:.0f} MB, "
                          f"load {r['load_before']:.1f} -> {r['load_after']:.1f}",
                          flush=True)
                continue
            rows.append(got)
            r = rows[-1]
            cpu = f" ({r['cpu_s']:.1f} s CPU)" if "cpu_s" in r else ""
            load = (f", load {r['load_before']:.1f} -> {r['load_after']:.1f}"
                    if "load_before" in r else "")
            print(f"{r['engine']:7s} {r['triangles']:,} triangles, {r['rays']:,} rays -> "
                  f"{r['points']:,} points: {r['wall_s']:.1f} s{cpu}, "
                  f"{r['mrays_per_s']:.2f} Mrays/s, peak RSS {r['peak_rss_mb']:.0f} MB, "
                  f"file {r['file_mb']:.0f} MB{load}", flush=True)
    by = {r["engine"]: r for r in rows}
    if "ours" in by and "open3d" in by:
        print(f"ratio ours end-to-end / Open3D bare casting: "
              f"{by['ours']['mrays_per_s'] / by['open3d']['mrays_per_s']:.2f}")
    if "ours" in by and "lazrs" in by and a.format == "laz":
        print(f"ratio ours end-to-end to LAZ / lazrs compressing the same points alone: "
              f"{by['ours']['mrays_per_s'] / by['lazrs']['mrays_per_s']:.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps({"resolution": a.resolution, "format": a.format,
                                            "fields": a.fields, "rows": rows,
                                            "drive_s": a.drive_s, "drives": drives},
                                           indent=1))


if __name__ == "__main__":
    main()
