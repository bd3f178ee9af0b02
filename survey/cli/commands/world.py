"""Commands about the world and the tool: info, sensors, tunnel."""

from __future__ import annotations

import platform
import sys
from importlib import metadata

import numpy as np

from survey.errors import TunnelsimCLIError
from survey.cli.main import _parse_window, _version


def cmd_info(args) -> int:
    from raytrace.config import threading_info

    lines = [f"tunnelsim {_version()}",
             f"python {platform.python_version()} ({platform.machine()}, {platform.system()})"]
    for pkg in ("numpy", "numba", "scipy", "trimesh", "laspy", "lazrs", "pyproj", "pye57",
                "embreex", "open3d"):
        try:
            lines.append(f"{pkg} {metadata.version(pkg)}")
        except metadata.PackageNotFoundError:
            lines.append(f"{pkg} (not installed)")
    info = threading_info()
    lines.append(f"numba threading layer: {info['threading_layer']}")
    lines.append(f"numba threads: {info['threads']} of {info['max_threads']}")
    print("\n".join(lines))
    return 0


def cmd_sensors(args) -> int:
    from sensors import list_sensors, load_sensor

    for name in list_sensors():
        spec = load_sensor(name)
        print(f"{name:18s} {spec.kind:9s} {spec.vendor} {spec.model}  "
              f"range {spec.physics.range_min_m:g}-{spec.physics.range_max_m:g} m")
    return 0


def cmd_tunnel(args) -> int:
    import time
    from pathlib import Path

    from survey.world.deformation import Bulge, Convergence
    from survey.world.presets import PRESETS, preset
    from survey.world.generator import edge_length_for

    out = Path(args.output)
    if out.suffix.lower() != ".ply":
        raise TunnelsimCLIError(f"Expected an output file ending in .ply, got '{out}'.")
    if not out.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing output folder, got '{out.parent}'; "
                                "create it first.")
    origin = (0.0, 0.0, 0.0) if args.origin is None else \
        _parse_window(args.origin.replace(",", ":"), "--origin as E,N,H in metres", 3)
    edge = args.edge_length
    if args.triangles is not None:
        al, prof, _, _ = PRESETS[args.preset](origin, 0.0)
        edge = edge_length_for(args.triangles, prof, al.length_m)
    t0 = time.perf_counter()
    tun, default_def = preset(args.preset, edge_length_m=edge, seed=args.seed,
                              closed_ends=args.closed_ends,
                              roughness_rms_m=None if args.roughness_mm is None
                              else args.roughness_mm / 1000.0, origin=origin,
                              heading_rad=np.deg2rad(args.heading_deg))
    deformations = [Convergence(*_parse_window(c, "--convergence START:END:MM", 3)[:2],
                                _parse_window(c, "", 3)[2] / 1000.0)
                    for c in args.convergence]
    deformations += [Bulge(a, np.deg2rad(b), r, mm / 1000.0) for a, b, r, mm in
                     (_parse_window(c, "--bulge CHAINAGE:ANGLE_DEG:RADIUS_M:MM", 4)
                      for c in args.bulge)]
    written = list(tun.write(out))
    if args.epoch2:
        ep2 = Path(args.epoch2)
        epoch = tun.deformed(deformations or default_def)
        written += list(epoch.write(ep2))
    dt = time.perf_counter() - t0
    if not args.quiet:
        counts = ", ".join(f"{k} {v:,}" for k, v in tun.metadata["face_counts"].items())
        print(f"{args.preset}: {len(tun.faces):,} triangles ({counts}), "
              f"{len(tun.vertices):,} vertices, edge length {edge:.4g} m, "
              f"{len(tun.metadata['control_points'])} control points, {dt:.1f} s")
        for p in written:
            print(f"wrote {p}")
    return 0


def cmd_gazebo(args) -> int:
    import warnings

    from sensors import load_sensor

    from survey.export.gazebo import export_gazebo

    spec = load_sensor(args.sensor)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            info = export_gazebo(args.mesh, spec, args.output, force=args.force,
                                 mount=args.mount, chainage_m=args.chainage)
        finally:   # unit warnings first: they often explain a later failure
            for w in caught:
                print(f"tunnelsim: warning: {w.message}", file=sys.stderr)
    if not args.quiet:
        print(f"wrote {info['path']}/world.sdf and models/tunnel ({info['triangles']:,} "
              f"triangles, collision {info['collision_triangles']:,}); local origin "
              f"{' '.join(f'{x:.3f}' for x in info['origin'])} m")
        print(f"{spec.name} as gpu_lidar; SDF cannot express:")
        for x in info["limitations"]:
            print(f"  - {x}")
        print(f"run: cd {info['path']} && GZ_SIM_RESOURCE_PATH=$PWD/models gz sim world.sdf")
    return 0
