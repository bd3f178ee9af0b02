"""Tunnel generator benchmark: time and peak memory to build the BFO-like tunnel at
several resolutions, each in its own subprocess (peak RSS per size).

No other tool generates these tunnels, so there is no side-by-side engine here; the
target from the generator's issue is absolute: a 1M-triangle tunnel in seconds (the
figure is recorded, never asserted in a test). Writing the PLY + JSON is timed
separately.

Usage::

    python benchmarks/bench_generator.py                  # edges 0.6, 0.1, 0.075, 0.0336 m
    python benchmarks/bench_generator.py --edge 0.075 --json out.json

The default edge lengths give about 50k, 0.8M, 1.3M and 5.7M triangles in all
(lining plus the four cables, bolt plates and prisms).
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


def _one(edge: float) -> dict:
    from survey.world.presets import preset

    preset("bfo", edge_length_m=0.5)  # imports and first-call costs out of the timing
    t0 = time.perf_counter()
    tun, _ = preset("bfo", edge_length_m=edge)
    gen = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        tun.write(Path(d) / "t.ply")
        wr = time.perf_counter() - t0
        size = (Path(d) / "t.ply").stat().st_size
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"edge_length_m": edge,
            "triangles": int(len(tun.faces)), "vertices": int(len(tun.vertices)),
            "generate_s": gen, "write_s": wr, "ply_mb": size / 2**20,
            "peak_rss_mb": peak}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--edge", type=float, nargs="+", default=[0.6, 0.1, 0.075, 0.0336],
                    help="lining edge lengths (m)")
    ap.add_argument("--json", help="write the figures to this file")
    ap.add_argument("--child", type=float, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps(_one(a.child)))
        return
    rows = []
    for n in a.edge:
        out = subprocess.run([sys.executable, __file__, "--child", str(n)], check=True,
                             capture_output=True, text=True).stdout
        rows.append(json.loads(out.strip().splitlines()[-1]))
        r = rows[-1]
        print(f"{r['triangles']:>10,} triangles (edge {r['edge_length_m']:.4f} m): "
              f"generate {r['generate_s']:.2f} s, write {r['write_s']:.2f} s "
              f"({r['ply_mb']:.0f} MB), peak RSS {r['peak_rss_mb']:.0f} MB", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
