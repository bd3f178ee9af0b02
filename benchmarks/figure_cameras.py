"""The README's camera figure: one frame of each shipped camera in the demo tunnel
(colour, depth and thermal side by side), made by ``survey.workflows.render.render_frame``
(what ``tunnelsim render`` runs) and drawn from the files it writes.

The tunnel is the ``bfo`` preset (the demo's 300 m gallery) at 0.1 m edges; the cameras
stand on the centreline at chainage 183 m, 1.5 m above the floor, looking along the
axis: the wet floor (180-230 m), the cables on the left wall, rock bolts and the
prisms at 187.5 m are in view. The colour camera's headlamp is the default 1000 cd; the
D435's auto-exposure sets the time and gain (stated in the panel's title).

Usage::

    python benchmarks/figure_cameras.py                       # docs/cameras_frame.png
    python benchmarks/figure_cameras.py -o frame.png --keep frames/
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", default=str(ROOT / "docs" / "cameras_frame.png"))
    ap.add_argument("--keep", help="keep the frames' files in this folder")
    ap.add_argument("--chainage", type=float, default=183.0)
    ap.add_argument("--lamp-cd", type=float, default=1000.0)
    a = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    from survey.world.mesh import write_tunnel
    from survey.world.presets import preset
    from survey.workflows.render import render_frame

    work = Path(a.keep) if a.keep else Path(tempfile.mkdtemp())
    work.mkdir(parents=True, exist_ok=True)
    tun, _ = preset("bfo", edge_length_m=0.1)
    mesh = work / "bfo.ply"
    write_tunnel(tun, mesh)
    at = tun.alignment.to_world(a.chainage, 0.0, 1.5)
    _, heading, _ = tun.alignment.plan(np.array(a.chainage))
    heading_deg = float(np.degrees(heading))
    res = {}
    for name in ("realsense_d435_color", "realsense_d435_depth", "lwir_640"):
        res[name] = render_frame(mesh, name, at, work / name, heading_deg=heading_deg,
                                 lamp_cd=a.lamp_cd, seed=1)

    fig, ax = plt.subplots(1, 3, figsize=(16, 3.9), constrained_layout=True)
    rgb = np.asarray(Image.open(work / "realsense_d435_color" / "rgb.png"))
    ax[0].imshow(rgb)
    c = res["realsense_d435_color"]
    ax[0].set_title(f"colour: D435 RGB 1920x1080, {a.lamp_cd:g} cd lamp, AE "
                    f"{c.exposure_s * 1e3:.3g} ms, gain {c.gain:.3g}", fontsize=9)
    depth = np.load(work / "realsense_d435_depth" / "depth.npy")
    im = ax[1].imshow(depth, cmap="viridis_r", vmin=0.0, vmax=10.0)
    ax[1].set_title("depth: D435 depth 1280x720 (z within 0.28-10 m)", fontsize=10)
    fig.colorbar(im, ax=ax[1], label="z-depth (m); white: no data", shrink=0.9)
    th = np.asarray(Image.open(work / "lwir_640" / "thermal.png")).astype(np.float64)
    th = np.where(th > 0, th / 100.0 - 273.15, np.nan)
    im = ax[2].imshow(th, cmap="inferno")
    ax[2].set_title("thermal: LWIR 640x512, apparent temperature", fontsize=10)
    fig.colorbar(im, ax=ax[2], label="°C (cables 25, rock 13, wet floor 12)", shrink=0.9)
    for x in ax:
        x.set_xticks([])
        x.set_yticks([])
    out = Path(a.output)
    fig.savefig(out, dpi=90)
    for name, r in res.items():
        print(f"{name}: hit {r.hit_fraction:.1%}, depth {r.depth_min_m:.2f}-"
              f"{r.depth_max_m:.2f} m, mean {r.mean_value:.4g}, {r.seconds:.1f} s")
    print(f"wrote {out}")
    return out


if __name__ == "__main__":
    main()
