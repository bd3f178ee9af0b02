"""Multiple-return benchmark (issue 34): the cost of ``Settings(returns=...)`` per pulse,
and the single-return default path against the committed code, in one process.

A VLP-16 (or ``--sensor``) drives at 2 m/s along the ``bfo`` preset's centreline with
dust (``--particles`` per metre) for ``--drive-s`` seconds; each variant simulates the
whole drive (no file written), ``--repeat`` times, the fastest pass reported:

* ``head``: the default path of ``sensors/simulate.py`` as ``git show HEAD:`` gives it
  (loaded as a module of the ``sensors`` package beside the working tree's): the
  baseline of "the single-return default path stays as fast as it is"; its points
  must equal the working tree's default bit for bit (checked, reported).
* ``default``: the working tree, ``returns=None``.
* ``strongest``, ``dual``, ``last``...: the waveform model in that return mode.

Each variant runs with ``--subrays`` sub-rays per pulse (1, 7 or 19). Results:
pulses/s, ns per pulse, and the cost relative to ``default``.

Usage::

    python benchmarks/bench_returns.py                         # 2 s, 7 sub-rays
    python benchmarks/bench_returns.py --drive-s 5 --subrays 1 --json out.json
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def _head_simulate():
    """``sensors/simulate.py`` at git HEAD, as module ``sensors._head_simulate``
    (relative imports resolve in the working tree's ``sensors``), or None."""
    try:
        text = subprocess.run(["git", "show", "HEAD:sensors/simulate.py"], cwd=ROOT,
                              check=True, capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    import sensors

    path = Path(tempfile.mkdtemp()) / "_head_simulate.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("sensors._head_simulate", path)
    mod = importlib.util.module_from_spec(spec)
    mod.__package__ = sensors.__name__
    sys.modules["sensors._head_simulate"] = mod
    spec.loader.exec_module(mod)
    return mod


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sensor", default="velodyne_vlp16")
    ap.add_argument("--drive-s", type=float, default=2.0)
    ap.add_argument("--subrays", type=int, default=7, choices=[1, 7, 19])
    ap.add_argument("--particles", type=float, default=0.05)
    ap.add_argument("--edge-length", type=float, default=0.25)
    ap.add_argument("--modes", default="strongest,dual,last")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json")
    a = ap.parse_args(argv)

    import numba

    from raytrace import Scene
    from sensors import Settings, Trajectory, load_sensor
    from sensors import simulate as new
    from survey.world.presets import preset

    tun, _ = preset("bfo", edge_length_m=a.edge_length)
    al = tun.alignment
    c0, _c1 = al.chainage_range
    s = np.arange(c0 + 5.0, c0 + 5.0 + 2.0 * a.drive_s + 2.0, 0.25)
    traj = Trajectory.along_polyline(al.to_world(s, 0.0, 1.0), 2.0, rate_hz=50)
    scene = Scene(tun.vertices, tun.faces)
    spec = load_sensor(a.sensor)
    head = _head_simulate()
    t_end = traj.start_s + a.drive_s

    def settings(mode):
        return Settings(beam_subrays=a.subrays, particle_rate_per_m=a.particles,
                        attenuation_per_m=0.01, returns=mode)

    variants = [("default", new, None)] + ([("head", head, None)] if head else []) + \
        [(m, new, m) for m in a.modes.split(",") if m in spec.returns.modes]
    rows, points = {}, {}
    for name, mod, mode in variants:   # a first pass compiles; then timed passes
        best = np.inf
        for _ in range(a.repeat + 1):
            run = mod.simulate_drive(scene, spec, traj, settings=settings(mode),
                                     t_end=t_end, cache_bytes=0)
            t = time.perf_counter()
            pts = list(run)
            best = min(best, time.perf_counter() - t)
        n_pulses = run.n_pulses
        pts = np.concatenate(pts)
        points[name] = pts
        rows[name] = {"pulses": int(n_pulses), "points": int(len(pts)),
                      "seconds": best, "pulses_per_s": n_pulses / best,
                      "ns_per_pulse": 1e9 * best / n_pulses}
    base = rows["default"]["ns_per_pulse"]
    for r in rows.values():
        r["relative"] = r["ns_per_pulse"] / base
    same = None
    if "head" in points:
        same = points["head"].tobytes() == points["default"].tobytes()
    out = {"sensor": a.sensor, "drive_s": a.drive_s, "subrays": a.subrays,
           "particles_per_m": a.particles, "threads": numba.get_num_threads(),
           "default_equals_head": same, "variants": rows,
           "date": time.strftime("%Y-%m-%d", time.gmtime())}
    print(f"{a.sensor}, {a.drive_s:g} s drive, {a.subrays} sub-rays, dust "
          f"{a.particles:g}/m, {numba.get_num_threads()} threads; default == HEAD bit for "
          f"bit: {same}")
    print(f"{'variant':<10} {'pulses':>9} {'points':>9} {'s':>7} {'Mpulse/s':>9} "
          f"{'ns/pulse':>9} {'x default':>9}")
    for name, r in rows.items():
        print(f"{name:<10} {r['pulses']:>9,} {r['points']:>9,} {r['seconds']:>7.3f} "
              f"{r['pulses_per_s'] / 1e6:>9.3f} {r['ns_per_pulse']:>9.0f} "
              f"{r['relative']:>9.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=2))
    return 0 if same in (None, True) else 1


if __name__ == "__main__":
    sys.exit(main())
