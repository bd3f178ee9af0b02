"""Camera benchmark (issue 35): 640x480 depth frames per second with our BVH against
Open3D's pinhole ray casting of the same mesh in the same run, and colour frames with
one lamp (a shadow ray per lit pixel).

* ``ours_depth``: ``sensors.render.render_depth`` per frame: the pixel rays (the lens
  model's, kept between frames of one camera) turned into the world, cast, and the
  frame's z-depth, range, normals and hit points.
* ``ours_cast_only``: ``Scene.cast`` of the same rays alone (turned into the world
  outside the timing): the engine's share of a depth frame. A frame's rays share one
  origin but are fewer than half a ray per triangle, so ``auto`` casts them through a
  near map (``raytrace/_kernels/nearmap.py``).
* ``ours_cast_bvh``: the same cast with ``method="bvh"`` (every ray walks the BVH): what
  the near map gains, in the same run.
* ``open3d_depth``: per frame ``RaycastingScene.create_rays_pinhole`` (the same K, its
  principal point shifted by half a pixel: Open3D puts pixel corners at integers) and
  ``cast_rays`` (Embree, float32); the scene is built outside the timing.
* ``ours_rgb``: ``render_depth``, then ``sensors.shading.luminance`` under the
  headlamp (1000 cd spot beside the camera, one shadow ray per lit pixel) with the
  label table's albedo, and ``expose`` (shot and read noise): a colour frame's work
  short of the PNG encoding.

The mesh is the ``bfo`` preset (the demo's 300 m gallery with cables, niches, bolts
and prisms) at ``--edge`` (0.1 m: about 0.8M triangles); the camera (69 deg horizontal
field of view, the D435 colour stream's, at 640x480) stands on the centreline 1.5 m
above the floor and looks along the axis, moving 0.1 m per frame from chainage 60 m.
Both engines use every core (Numba's threads; Open3D's Embree threads). The depths of
the two engines are compared on the last frame (pixels both hit) as a check that the
same work was done. Besides frames per second (wall clock), each row's CPU time per
frame (all threads of the process) is printed: on a shared machine it moves less.

Usage::

    python benchmarks/bench_cameras.py                      # 20 frames each
    python benchmarks/bench_cameras.py --frames 50 --json out.json

Needs the ``bench`` extra (open3d).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from dataclasses import replace
from datetime import datetime, timezone

import numpy as np


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--edge", type=float, default=0.1, help="mesh edge length (m)")
    ap.add_argument("--frames", type=int, default=20, help="frames per engine")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--json", help="write the results here")
    a = ap.parse_args(argv)

    import open3d as o3d

    from raytrace import Scene
    from raytrace.config import threading_info
    from sensors.appearance import mesh_appearance
    from sensors.camera import load_camera
    from sensors.io.meshes import MeshData
    from sensors.render import camera_pose, render_depth
    from sensors.shading import expose, headlamp, luminance
    from survey.world.mesh import LABELS
    from survey.world.presets import preset

    tun, _ = preset("bfo", edge_length_m=a.edge)
    # A first build in the process loads the cached kernels (~0.3 s): not the build's.
    Scene(tun.vertices[:3000], tun.faces[(tun.faces < 3000).all(axis=1)])
    t0 = time.perf_counter()
    scene = Scene(tun.vertices, tun.faces)
    build_ours = time.perf_counter() - t0
    w, h = a.width, a.height
    fx = (w / 2) / math.tan(math.radians(69.0) / 2)
    cam = replace(load_camera("realsense_d435_color"), width=w, height=h, fx=fx, fy=fx,
                  cx=(w - 1) / 2, cy=(h - 1) / 2, distortion=np.zeros(5))
    poses = [camera_pose(tun.alignment.to_world(60.0 + 0.1 * i, 0.0, 1.5), 0.0)
             for i in range(a.frames)]
    app = mesh_appearance(MeshData(tun.vertices, tun.faces,
                                   face_fields={"label": tun.labels}), LABELS)

    # Warm up: compile the kernels and fill the lens's ray cache.
    fr = render_depth(scene, cam, poses[0])
    luminance(scene, fr, [headlamp(poses[0])], app.at(fr).albedo)
    scene.cast(poses[0][:3, 3], fr.rays_cam.reshape(-1, 3), method="bvh")

    t0 = time.perf_counter()
    o3_scene = o3d.t.geometry.RaycastingScene()
    o3_scene.add_triangles(o3d.core.Tensor(tun.vertices.astype(np.float32)),
                           o3d.core.Tensor(tun.faces.astype(np.uint32)))
    K = cam.K.copy()
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    Kt = o3d.core.Tensor(K)
    # Embree builds its BVH on the first cast: warm it up outside the timing.
    o3_scene.cast_rays(o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        Kt, o3d.core.Tensor(np.linalg.inv(poses[0])), w, h))
    build_o3d = time.perf_counter() - t0

    # DECISION: the engines take turns frame by frame, so that the load of a shared
    # machine falls on both alike; each engine's time is the sum of its frames.
    rows = ("ours_depth", "ours_cast", "ours_cast_bvh", "open3d_depth", "ours_rgb")
    times = dict.fromkeys(rows, 0.0)
    cpu = dict.fromkeys(rows, 0.0)

    class _Timed:
        """Adds the block's wall-clock and CPU time (all threads) to row ``key``."""

        def __init__(self, key):
            self.key = key

        def __enter__(self):
            self.t0, self.c0 = time.perf_counter(), time.process_time()

        def __exit__(self, *exc):
            times[self.key] += time.perf_counter() - self.t0
            cpu[self.key] += time.process_time() - self.c0

    rays_cam = np.ascontiguousarray(fr.rays_cam.reshape(-1, 3))
    for i, T in enumerate(poses):
        with _Timed("ours_depth"):
            fr = render_depth(scene, cam, T)
        # The cast alone (the rays turned into the world outside the timing): the
        # engine's share of a depth frame. DECISION: einsum, not ``rays_cam @ R.T``:
        # NumPy's BLAS matmul leaves its threads spinning for a while after the call,
        # and on two cores they took the CPU from the cast timed next (2.5x slower;
        # "cast only" came out slower than the whole depth frame).
        d = np.einsum("ij,kj->ik", rays_cam, T[:3, :3])
        with _Timed("ours_cast"):
            scene.cast(T[:3, 3], d)
        with _Timed("ours_cast_bvh"):
            scene.cast(T[:3, 3], d, method="bvh")
        with _Timed("open3d_depth"):
            rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
                Kt, o3d.core.Tensor(np.linalg.inv(T)), w, h)
            t_hit = o3_scene.cast_rays(rays)["t_hit"].numpy()
        with _Timed("ours_rgb"):
            fr2 = render_depth(scene, cam, T)
            alb = np.nan_to_num(app.at(fr2).albedo, nan=0.0)
            lum = luminance(scene, fr2, [headlamp(T)], alb)
            expose(cam, lum, seed=i)
    ours_last = fr.depth_z_m
    ours_depth, ours_cast = times["ours_depth"], times["ours_cast"]
    o3d_depth, ours_rgb = times["open3d_depth"], times["ours_rgb"]
    ref = np.where(np.isfinite(t_hit), t_hit, np.nan).astype(np.float64)
    both = np.isfinite(ref) & np.isfinite(ours_last)

    res = {
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d"),
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, "
                   f"{platform.system()}",
        "numba_threads": threading_info()["threads"],
        "open3d": o3d.__version__,
        "triangles": int(len(tun.faces)), "width": w, "height": h, "frames": a.frames,
        "build_ours_s": build_ours, "build_open3d_s": build_o3d,
        "ours_depth_fps": a.frames / ours_depth,
        "ours_cast_only_fps": a.frames / ours_cast,
        "ours_cast_bvh_fps": a.frames / times["ours_cast_bvh"],
        "open3d_depth_fps": a.frames / o3d_depth,
        "ratio_ours_over_open3d": o3d_depth / ours_depth,
        "ours_rgb_one_lamp_fps": a.frames / ours_rgb,
        **{f"{k}_cpu_ms_per_frame": 1e3 * cpu[k] / a.frames for k in rows},
        "cpu_ratio_ours_over_open3d": cpu["open3d_depth"] / cpu["ours_depth"],
        "same_pixels_hit": bool((np.isfinite(ref) == np.isfinite(ours_last)).all()),
        "max_depth_difference_m": float(np.abs(ref - ours_last)[both].max()),
    }
    for k, v in res.items():
        print(f"{k:26s} {v:.4g}" if isinstance(v, float) else f"{k:26s} {v}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=1)
    return res


if __name__ == "__main__":
    main()
