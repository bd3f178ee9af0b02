"""Validate sections against design on the real design profile and a generated tunnel.

1. The real profile (a CSV of digitised x, y points, e.g. the Maoliling tunnel's first
   lining from ../shared/data/design_profiles/, MIT) is read (angle order: the points
   are saved sorted by x), placed in the section frame (centred, invert at height 0)
   and drawn with a synthetic as-built section around it (5-15 cm of overbreak).
2. The bfo-like preset with its rock relief is cut every 10 m; the extracted deviation
   is compared with the generator's known field on grid rings (max error, mm).
3. Throughput of the streamed cloud cut (points per second).

Usage: python benchmarks/validate_sections.py PROFILE.csv [-o OUTDIR]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from survey.analysis.design import DesignProfile, read_design_profile
from survey.analysis.overbreak import compare_sections
from survey.analysis.sections import cut_cloud, cut_mesh
from survey.report.sections import plot_section, sections_markdown
from survey.world.alignment import Alignment, straight
from survey.world.presets import preset
from survey.world.rock import surface_relief


def real_profile(path: Path, out: Path) -> None:
    raw = read_design_profile(path, order="angle")
    y0, y1, z0, _ = raw.extent()
    d = raw.shifted(-0.5 * (y0 + y1), -z0)
    print(f"{path.name}: {d}, area {d.area_m2:.2f} m^2, extent {d.extent()}")
    al = Alignment([straight(20.0)])
    rng = np.random.default_rng(0)
    t = rng.uniform(0, d.length_m, 60_000)
    over = 0.10 + 0.05 * np.sin(2 * np.pi * t / d.length_m * 3)
    yz = d.points(t) + over[:, None] * d.normals(t) + rng.normal(0, 0.003, (len(t), 1))
    s = rng.uniform(9.95, 10.05, len(t))
    pts = al.to_world(s, yz[:, 0], yz[:, 1])
    rep = compare_sections(cut_cloud(pts, al, [10.0], 0.05), d, alignment=al)
    sec = rep.sections[0]
    print(f"  synthetic as-built: mean {1000 * sec.mean_m:.1f} mm (truth "
          f"{1000 * over.mean():.1f}), max {1000 * sec.max_m:.1f} mm (truth 150)")
    plot_section(sec, rep, out / "real_profile_section.png")
    (out / "real_profile_report.md").write_text(sections_markdown(rep, source=path.name))


def generated(out: Path) -> None:
    tun, _ = preset("bfo", edge_length_m=0.05)
    al = tun.alignment
    rings = np.unique(tun.vertex_chainage)
    s = rings[np.searchsorted(rings, np.arange(10.0, 300.0, 10.0))]
    t0 = time.perf_counter()
    cuts = cut_mesh(tun.vertices, tun.faces, al, s)
    rep = compare_sections(cuts, DesignProfile.from_profile(tun.profile), alignment=al)
    dt = time.perf_counter() - t0
    meta = tun.metadata["parameters"]
    from survey.world.rock import RockRelief

    rel = RockRelief.from_dict(meta["relief"])
    c0, c1 = al.chainage_range
    errs = []
    for sec in rep.sections:
        truth = surface_relief(tun.profile, [sec.chainage_m], sec.t_m, c0, c1,
                               texture_rms_m=meta["roughness_rms_m"],
                               texture_corr_m=meta["roughness_corr_m"], relief=rel,
                               seed=meta["seed"])[0]
        ok = np.isfinite(sec.deviation_m)
        errs.append(np.median(np.abs(sec.deviation_m[ok] - truth[ok])))
    print(f"bfo preset (edge 5 cm, with niches, cables, bolts): {len(rep.sections)} "
          f"sections in {dt:.1f} s; median |error| per section {1000 * np.median(errs):.2f} "
          f"mm (features and the mesh's 5 cm chords included); overbreak "
          f"{rep.overbreak_m3:.1f} m^3, underbreak {rep.underbreak_m3:.1f} m^3")
    (out / "bfo_report.md").write_text(sections_markdown(rep, source="bfo preset",
                                                         plots=False))


def throughput() -> None:
    al = Alignment([straight(300.0)])
    rng = np.random.default_rng(1)
    n = 2_000_000
    s = rng.uniform(0, 300, n)
    ang = rng.uniform(0, 2 * np.pi, n)
    pts = al.to_world(s, 2.5 * np.cos(ang), 2.5 + 2.5 * np.sin(ang))
    t0 = time.perf_counter()
    cut_cloud(np.array_split(pts, 4), al, np.arange(5.0, 300.0, 5.0), 0.05)
    dt = time.perf_counter() - t0
    print(f"streamed cut: {n / dt / 1e6:.2f} M points/s (every 5 m, +-5 cm bands)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("profile", type=Path, help="design profile CSV (x, y)")
    ap.add_argument("-o", "--output", type=Path, default=Path("validate_sections_out"))
    a = ap.parse_args()
    a.output.mkdir(exist_ok=True)
    real_profile(a.profile, a.output)
    generated(a.output)
    throughput()


if __name__ == "__main__":
    main()
