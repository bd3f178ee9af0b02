"""Time the survey workflow's analysis steps on the 300 m BFO-like gallery: station
planning (issue 7: "a 300 m tunnel with 60 candidates plans in minutes on 2 cores") and
one MLS study configuration, plus the C2C comparison of two station clouds.

    python benchmarks/bench_workflow.py [--json results_workflow.json]

No Embree counterpart: these steps are not ray-casting benchmarks (planning casts one
occlusion ray per cell and station with our engine, whose speed against Embree is in
bench_raycast.py).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--json")
    a = ap.parse_args()
    from raytrace import Scene
    from sensors import load_sensor, simulate_station
    from survey.analysis.compare import cloud_to_cloud
    from survey.analysis.planning import Planner
    from survey.world.presets import preset
    from survey.analysis.study import Study

    tun, _ = preset("bfo", edge_length_m=0.1)
    scene = Scene(tun.vertices, tun.faces)
    hc = float(tun.profile.centroid[1])
    out = {"triangles": int(len(tun.faces))}
    for cands in (60, 120):
        t = time.perf_counter()
        pl = Planner(scene, tun.alignment, hc, load_sensor("zf_imager_5016"),
                     resolution="high")
        cand = pl.spaced(300.0 / cands)
        best, greedy, info = pl.optimize(cand, target=0.99)
        dt = time.perf_counter() - t
        out[f"plan_{cands}"] = {"seconds": dt, "cells": int(len(pl.cells.area)),
                                "milp": info.get("milp"), "greedy": info["greedy"],
                                "optimal": bool(info.get("optimal")),
                                "reachable": info["reachable"]}
        print(f"plan, {cands} candidates, {len(pl.cells.area):,} cells: {dt:.1f} s "
              f"(MILP {info.get('milp')} stations, greedy {info['greedy']}, reachable "
              f"{100 * info['reachable']:.2f} %)")
    st = Study(scene, tun.alignment, hc, load_sensor("robosense_airy"), strip=(100, 103),
               lead_m=3.0)
    t = time.perf_counter()
    r = st.run(1.0, 10.0, "down")
    dt = time.perf_counter() - t
    out["study_1mps"] = {"seconds": dt, "pulses": r.pulses}
    print(f"study, Airy down 1 m/s over 9 m: {r.pulses:,} pulses in {dt:.1f} s "
          f"({r.pulses / dt / 1e6:.2f} Mpulses/s incl. evaluation)")
    clouds = []
    for s in (25.0, 25.5):
        run = simulate_station(scene, "zf_imager_5016", [s, 0.0, 1.5], resolution="middle")
        clouds.append(np.concatenate([np.stack([c["x"], c["y"], c["z"]], 1) for c in run]))
    t = time.perf_counter()
    d = cloud_to_cloud(clouds[0], clouds[1]).distance
    dt = time.perf_counter() - t
    out["c2c"] = {"seconds": dt, "points": [len(c) for c in clouds]}
    print(f"C2C {len(clouds[0]):,} -> {len(clouds[1]):,} points: {dt:.1f} s "
          f"(median {1000 * np.median(d):.1f} mm)")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
