"""M3C2 throughput: ours (survey.analysis.m3c2, Numba) against py4dgeo's M3C2 (C++,
OpenMP) on the same data, in one run.

Data: the ``tbm`` preset tunnel and its second epoch (the preset's deformation: 5 mm
convergence), each scanned from the same station by the ZF Imager 5016 model; epochs at
a UTM-sized origin for ours and shifted to a local origin for py4dgeo (which needs it:
see tests/survey/analysis/test_m3c2.py). Core points: epoch 1 subsampled on a ``--spacing``
grid. Parameters: normal radii ``--normal-radii``, cylinder radius ``--radius``,
max depth ``--depth`` (0.3 m: ceil(L / r) = 3 slabs, so a core point taken from
epoch 1 sits mid-slab and py4dgeo counts it once too); normals oriented +Z as
py4dgeo's default.

Timed, best of ``--repeat`` after one warm-up (Numba compiles on first use):

* ``normals``: multiscale normals at the core points (ours ``M3C2.normals``; py4dgeo
  ``M3C2.directions``).
* ``distances``: distances and LoD95 with given normals (ours ``M3C2.compute(...,
  normals=)``; py4dgeo ``M3C2(corepoint_normals=...).run()``).
* ``setup``: search structures (our grids; py4dgeo's k-d trees).

Both use every core (``--threads`` sets ours and OpenMP's). The distances of both for
the same normals are compared (max |difference|, and the core points whose counts
differ: py4dgeo drops or doubles points on its slab boundaries).

Usage::

    python benchmarks/bench_m3c2.py                      # 0.25 degree step, 5 cm grid
    python benchmarks/bench_m3c2.py --step-deg 0.1 --spacing 0.05 --json out.json
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time

import numpy as np

UTM = np.array([500_000.0, 5_000_000.0, 300.0])


def _epochs(step_deg: float):
    from raytrace import Scene
    from sensors import simulate_station
    from survey.world.presets import preset

    tun, deform = preset("tbm", edge_length_m=0.1, origin=tuple(UTM))
    ep = tun.deformed(deform)
    at = np.asarray(tun.alignment.to_world(50.0, 0.0, 1.5), dtype=np.float64)
    out = []
    for k, m in enumerate((tun, ep)):
        run = simulate_station(Scene(m.vertices, m.faces), "zf_imager_5016", at,
                               step_rad=np.deg2rad(step_deg), seed=k + 1)
        out.append(np.concatenate([np.stack([c["x"], c["y"], c["z"]], 1) for c in run]))
    return out


def _best(fn, repeat):
    best, res = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = fn()
        best = min(best, time.perf_counter() - t0)
    return best, res


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--step-deg", type=float, default=0.25)
    ap.add_argument("--spacing", type=float, default=0.05)
    ap.add_argument("--radius", type=float, default=0.1)
    ap.add_argument("--depth", type=float, default=0.3)
    ap.add_argument("--normal-radii", default="0.1,0.2")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", type=int)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    if a.threads:
        os.environ["OMP_NUM_THREADS"] = str(a.threads)
    import py4dgeo
    from raytrace import set_threads, threads
    from survey.analysis.m3c2 import M3C2, M3C2Params, subsample

    logging.getLogger("py4dgeo").setLevel(logging.WARNING)
    set_threads(a.threads)
    radii = tuple(float(r) for r in a.normal_radii.split(","))
    e1, e2 = _epochs(a.step_deg)
    core = subsample(e1, a.spacing)
    prm = M3C2Params(a.radius, a.depth, radii)

    # ours: warm-up (compile), then timed
    M3C2(e1[:1000], e2[:1000], prm).compute(core[:10])
    t_setup, job = _best(lambda: M3C2(e1, e2, prm), a.repeat)
    t_norm, (nrm, _) = _best(lambda: job.normals(core), a.repeat)
    t_dist, ours = _best(lambda: job.compute(core, normals=nrm), a.repeat)

    # py4dgeo on the same clouds, shifted to the local origin
    s1, s2, sc = e1 - UTM, e2 - UTM, core - UTM

    def p_setup():
        x, y = py4dgeo.Epoch(s1), py4dgeo.Epoch(s2)
        x.build_kdtree()
        y.build_kdtree()
        return x, y
    p_t_setup, (E1, E2) = _best(p_setup, a.repeat)

    def p_normals():
        m = py4dgeo.M3C2(epochs=(E1, E2), corepoints=sc, normal_radii=radii,
                         cyl_radius=a.radius, max_distance=a.depth)
        return m.directions()
    p_t_norm, _ = _best(p_normals, a.repeat)

    def p_dist():
        m = py4dgeo.M3C2(epochs=(E1, E2), corepoints=sc, corepoint_normals=nrm,
                         cyl_radius=a.radius, max_distance=a.depth)
        return m.run()
    p_t_dist, (pd, pu) = _best(p_dist, a.repeat)

    same = ours.n1 == pu["num_samples1"]
    same &= ours.n2 == pu["num_samples2"]
    ok = same & np.isfinite(pd)
    res = {
        "points_epoch1": int(len(e1)), "points_epoch2": int(len(e2)),
        "core_points": int(len(core)), "threads": int(threads()),
        "omp_threads": int(os.environ.get("OMP_NUM_THREADS", 0) or os.cpu_count() or 0),
        "params": {"cyl_radius_m": a.radius, "max_depth_m": a.depth,
                   "normal_radii_m": list(radii)},
        "ours_s": {"setup": t_setup, "normals": t_norm, "distances": t_dist},
        "py4dgeo_s": {"setup": p_t_setup, "normals": p_t_norm, "distances": p_t_dist},
        "same_counts_share": float(same.mean()),
        "max_abs_diff_same_counts_m": float(np.abs(ours.distance - pd)[ok].max())
        if ok.any() else float("nan"),
        "median_distance_m": float(np.nanmedian(ours.distance)),
    }
    n = len(core)
    lines = ["| step | ours (s) | py4dgeo (s) | ours (core pts/s) | py4dgeo (core pts/s) "
             "| py4dgeo / ours time |", "|---|---:|---:|---:|---:|---:|"]
    for k in ("setup", "normals", "distances"):
        o, p = res["ours_s"][k], res["py4dgeo_s"][k]
        rate = (f"{n / o:,.0f} | {n / p:,.0f}" if k != "setup" else "- | -")
        lines.append(f"| {k} | {o:.3f} | {p:.3f} | {rate} | {p / o:.2f} |")
    tot_o = sum(res["ours_s"].values())
    tot_p = sum(res["py4dgeo_s"].values())
    lines.append(f"| total | {tot_o:.3f} | {tot_p:.3f} | {n / tot_o:,.0f} | "
                 f"{n / tot_p:,.0f} | {tot_p / tot_o:.2f} |")
    print(f"{len(e1):,} + {len(e2):,} points, {n:,} core points, r {a.radius} m, "
          f"L {a.depth} m, normal radii {radii}, {threads()} threads")
    print("\n".join(lines))
    print(f"same counts at {100 * res['same_counts_share']:.1f} % of core points; there "
          f"max |d_ours - d_py4dgeo| = {res['max_abs_diff_same_counts_m']:.2e} m; median "
          f"distance {1000 * res['median_distance_m']:.2f} mm")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=1)
    return res


if __name__ == "__main__":
    main()
