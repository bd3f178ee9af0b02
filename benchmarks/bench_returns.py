"""Multiple-return benchmark (issue 34): the cost of ``Settings(returns=...)`` per pulse,
and the single-return default path against the committed code, in one process.

A VLP-16 (or ``--sensor``) drives at 2 m/s along the ``bfo`` preset's centreline with
dust (``--particles`` per metre) for ``--drive-s`` seconds; each variant simulates the
whole drive (no file written), ``--repeat`` times after a first (compiling) pass, the
passes going round the variants, the fastest pass of each reported:

* ``head``: the default path of ``sensors/simulate.py`` as ``git show HEAD:`` gives it
  (loaded as a module of the ``sensors`` package beside the working tree's): the
  baseline of "the single-return default path stays as fast as it is"; its points
  must equal the working tree's default bit for bit (checked, reported).
* ``default``: the working tree, ``returns=None``.
* ``strongest``, ``dual``, ``last``...: the waveform model in that return mode.
* ``waveform``, ``dual+waveform``: full-waveform output (``Settings(waveform=True)``)
  in the strongest (a survey scanner's default) and the dual mode: every return also
  carries its 256-bin waveform window. The sensor is made a waveform recorder for the
  run (``[returns] waveform = true`` in code: the cost depends on the pulses and
  sub-rays, not on whose pattern fires them), so the rows compare on one drive.

Each variant runs with ``--subrays`` sub-rays per pulse (1, 7 or 19). Results:
pulses/s, ns per pulse, and the cost relative to ``default``. With ``--write`` each
variant's pass is also written to a temporary .las (waveform: LAS 1.4 point format 9
with the packets in its EVLR) and that time and size reported.

Usage::

    python benchmarks/bench_returns.py                         # 2 s, 7 sub-rays
    python benchmarks/bench_returns.py --drive-s 5 --subrays 1 --json out.json
    python benchmarks/bench_returns.py --modes strongest,dual,waveform,dual+waveform
"""

from __future__ import annotations

import argparse
import gc
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
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
    ap.add_argument("--modes", default="strongest,dual,last,waveform,dual+waveform")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--pause", type=float, default=1.0,
                    help="seconds of rest before each pass (the memory a waveform pass "
                         "freed is returned before the next is timed)")
    ap.add_argument("--write", action="store_true",
                    help="also time writing each variant's pass to a .las")
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

    wf_spec = replace(spec, returns=replace(spec.returns, waveform=True))

    def settings(mode):
        m, wf = (mode.removesuffix("+waveform"), True) if mode and mode.endswith(
            "waveform") else (mode, False)
        m = None if m == "waveform" else m        # the device's default mode
        return Settings(beam_subrays=a.subrays, particle_rate_per_m=a.particles,
                        attenuation_per_m=0.01, returns=m, waveform=wf)

    def usable(m):
        base = m.removesuffix("+waveform")
        return base == "waveform" or base in spec.returns.modes

    variants = [("default", new, None)] + ([("head", head, None)] if head else []) + \
        [(m, new, m) for m in a.modes.split(",") if usable(m)]
    rows, points = {}, {}
    tmp = Path(tempfile.mkdtemp())
    best = dict.fromkeys([v[0] for v in variants], np.inf)
    runs = {}

    def one_pass(name, mod, mode):
        gc.collect()
        time.sleep(a.pause)
        st = settings(mode)
        run = mod.simulate_drive(scene, wf_spec if st.waveform else spec, traj,
                                 settings=st, t_end=t_end, cache_bytes=0)
        t = time.perf_counter()
        # The default and HEAD keep their points (compared bit for bit); the others
        # count them (a waveform pass is ~650 bytes a return).
        if name in ("default", "head"):
            pts = list(run)
            points[name] = np.concatenate(pts)
            n = len(points[name])
        else:
            n = sum(len(c) for c in run)
        best[name] = min(best[name], time.perf_counter() - t)
        runs[name] = (run, n)

    # DECISION: a first pass of every variant compiles; the timed passes then go round
    # the variants (not one variant's repeats in a row), so that a drift of the
    # machine's load or clock touches every variant alike.
    for v in variants:
        one_pass(*v)
    best = dict.fromkeys(best, np.inf)
    for _ in range(a.repeat):
        for v in variants:
            one_pass(*v)
    for name, mod, _mode in variants:
        run, n_points = runs[name]
        n_pulses = run.n_pulses
        rows[name] = {"pulses": int(n_pulses), "points": int(n_points),
                      "seconds": best[name], "pulses_per_s": n_pulses / best[name],
                      "ns_per_pulse": 1e9 * best[name] / n_pulses}
        if a.write and mod is new:
            las_out = tmp / f"{name.replace('+', '_')}.las"
            t = time.perf_counter()
            run.write(las_out)
            rows[name]["write_s"] = time.perf_counter() - t
            rows[name]["las_bytes"] = las_out.stat().st_size
            las_out.unlink()
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
    print(f"{'variant':<14} {'pulses':>9} {'points':>9} {'s':>7} {'Mpulse/s':>9} "
          f"{'ns/pulse':>9} {'x default':>9}")
    for name, r in rows.items():
        extra = (f"  write {r['write_s']:.2f} s, {r['las_bytes'] / 1e6:.1f} MB"
                 if "write_s" in r else "")
        print(f"{name:<14} {r['pulses']:>9,} {r['points']:>9,} {r['seconds']:>7.3f} "
              f"{r['pulses_per_s'] / 1e6:>9.3f} {r['ns_per_pulse']:>9.0f} "
              f"{r['relative']:>9.2f}{extra}")
    if a.json:
        Path(a.json).write_text(json.dumps(out, indent=2))
    return 0 if same in (None, True) else 1


if __name__ == "__main__":
    sys.exit(main())
