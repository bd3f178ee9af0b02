"""Real SLAM in the loop (issue 15): LiDAR odometry on simulated Airy drives.

For each world and odometry: a RoboSense Airy on a platform driving the centreline at
``--speed`` (still 1 s at both ends), the odometry on its frames, the evaluation against
the truth as evo does it (``survey.analysis.trajectory``), and - in the rock gallery -
the Z+F profiler on the same platform placed with the estimated trajectory, corrected
with the control prisms (every 25 m, piecewise rigid, ``survey.adjust.drift``), and its
C2M RMS against the true mesh before and after the correction (on a seeded uniform
subsample of ~200,000 of its points).

Targets (issue 15): KISS-ICP on a 100 m drive at 1 m/s through the default ``bfo``
preset drifts <= 1 % of the distance travelled; the corrected cloud's RMS error <= 10 mm.
The ``tbm`` rows show the degeneracy of a smooth segmental lining.

    python benchmarks/bench_slam.py [--length 100] [--speed 1] [--tbm-length 40]
        [--odometry kiss-icp,genz-icp] [--json benchmarks/results_slam.json]

Everything stays in memory (no LAZ): the drive's frames are simulated once and fed to
each odometry; re-placing the profiler uses ``to_slam_frame`` on its true points, which
equals re-placing its sensor-frame points (tests/survey/adjust/test_odometry.py).
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

from raytrace import Scene
from sensors import Mount, Trajectory, load_sensor, simulate_drive
from survey.adjust.drift import fit_drift
from survey.adjust.odometry import odometry_trajectory, run_odometry
from survey.adjust.slam import observe_control, to_slam_frame
from survey.analysis.compare import ReferenceMesh
from survey.analysis.trajectory import trajectory_errors
from survey.clouds.drives import ScanFrame, frames_from_points
from survey.world.presets import preset
from survey.world.rock import RockRelief

SAMPLE = 200_000


def drive_frames(mesh, a_m: float, b_m: float, speed: float, accel: float | None):
    """(frames, truth, scene): the Airy drive's frames (kept in memory) and truth."""
    scene = Scene(mesh.vertices, mesh.faces)
    s = np.append(np.arange(a_m, b_m, 0.5), b_m)
    truth = Trajectory.along_polyline(mesh.alignment.to_world(s, 0.0, 0.5), speed,
                                      accel_mps2=accel).with_standstill(1.0, 1.0)
    run = simulate_drive(scene, load_sensor("robosense_airy"), truth, Mount(), seed=1,
                         reflectivity=mesh.reflectivity)
    t0 = time.perf_counter()
    # Sensor-frame points kept as float32 (3 um at 30 m): 20 bytes a point, ~1.8 GB
    # for 100 s of Airy; the odometry takes them as float64 frame by frame.
    frames = [ScanFrame(f.frame, f.points.astype(np.float32), f.times)
              for f in frames_from_points(run)]
    return frames, truth, scene, time.perf_counter() - t0


def profiler_points(scene, mesh, truth: Trajectory, keep: int = SAMPLE):
    """About ``keep`` of the profiler's points (x, y, z world and time), a seeded
    uniform subsample drawn chunk by chunk (the whole run is ~1 M points/s)."""
    run = simulate_drive(scene, load_sensor("zf_profiler_9012"), truth, Mount(), seed=2,
                         reflectivity=mesh.reflectivity)
    rng = np.random.default_rng(3)
    p = min(1.0, keep / max(run.n_pulses, 1))
    xyz, t = [], []
    for c in run:
        m = rng.random(len(c)) < p
        xyz.append(np.stack([c["x"][m], c["y"][m], c["z"][m]], 1))
        t.append(c["time"][m].astype(np.float64))
    return np.concatenate(xyz), np.concatenate(t)


def c2m_rms(ref: ReferenceMesh, xyz: np.ndarray, idx: np.ndarray) -> float:
    d = ref.distances(xyz[idx]).distance
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d * d)))


def one(world: str, mesh, frames, truth, method: str, prof=None):
    t0 = time.perf_counter()
    res = run_odometry(frames, method=method)
    wall = time.perf_counter() - t0
    pos, rot = truth.interpolate([res.times[0]])
    est = odometry_trajectory(res, Mount(), start=(pos[0], rot[0]),
                              span_s=(truth.start_s, truth.end_s))
    e = trajectory_errors(est, truth)
    row = {"world": world, "odometry": method, "frames": len(res.times),
           "path_m": e.path_length_m, "final_error_m": e.final_error_m,
           "final_error_pct": e.final_error_pct,
           "final_along_m": e.final_error_along_m, "final_lateral_m": e.final_error_lateral_m,
           "final_vertical_m": e.final_error_vertical_m, "ate_rms_m": e.ate_rms_m,
           "rpe10_pct": e.rpe(10.0).mean_pct, "odometry_s": res.seconds, "wall_s": wall}
    if prof is not None:
        xyz, t, ref, idx = prof
        placed = to_slam_frame(truth, est, xyz, t)
        cps = mesh.metadata["control_points"]
        obs, wld = observe_control(truth, est, [c["id"] for c in cps],
                                   np.array([c["xyz"] for c in cps]), seed=0)
        ids = {i: k for k, i in enumerate(wld.ids)}
        g = wld.xyz[[ids[i] for i in obs.ids]]
        corr = fit_drift(obs.xyz, obs.time, g, model="piecewise")
        fixed = corr.apply(placed, t)
        # Between the first and the last control point passed: where the correction
        # interpolates (beyond them it extrapolates the end sections).
        inner = idx[(t[idx] >= obs.time.min()) & (t[idx] <= obs.time.max())]
        row.update(control_points=len(obs.ids),
                   cloud_rms_before_m=c2m_rms(ref, placed, idx),
                   cloud_rms_after_m=c2m_rms(ref, fixed, idx),
                   cloud_rms_after_inside_m=c2m_rms(ref, fixed, inner),
                   inside_fraction=len(inner) / len(idx))
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--length", type=float, default=100.0, help="bfo drive length (m)")
    ap.add_argument("--tbm-length", type=float, default=40.0)
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--accel", type=float, default=None,
                    help="start/stop acceleration (m/s^2); default: full speed at once")
    ap.add_argument("--odometry", default="kiss-icp,genz-icp")
    ap.add_argument("--texture-mm", type=float, default=None,
                    help="bfo rock texture rms in mm instead of the preset's (sensitivity)")
    ap.add_argument("--no-tbm", action="store_true", help="skip the tbm rows")
    ap.add_argument("--json")
    a = ap.parse_args()
    methods = a.odometry.split(",")
    rows = []
    print(f"# bench_slam {time.strftime('%Y-%m-%d')} on {platform.node()}, "
          f"{platform.processor() or platform.machine()}")
    relief = "preset" if a.texture_mm is None else \
        RockRelief(texture_rms_m=a.texture_mm / 1000.0)
    bfo, _ = preset("bfo", edge_length_m=0.1, relief=relief)
    frames, truth, scene, _ = drive_frames(bfo, 5.0, 5.0 + a.length, a.speed, a.accel)
    xyz, t = profiler_points(scene, bfo, truth)
    ref = ReferenceMesh(bfo.vertices, bfo.faces)
    idx = np.arange(len(xyz))
    true_rms = c2m_rms(ref, xyz, idx)
    for m in methods:
        rows.append(one("bfo", bfo, frames, truth, m, (xyz, t, ref, idx)))
        print(json.dumps(rows[-1]))
    del frames
    if not a.no_tbm:
        tbm, _ = preset("tbm", edge_length_m=0.1)
        frames, truth, scene, _ = drive_frames(tbm, 5.0, 5.0 + a.tbm_length, a.speed,
                                               a.accel)
        for m in methods:
            rows.append(one("tbm", tbm, frames, truth, m))
            print(json.dumps(rows[-1]))
    print(f"\nprofiler cloud placed with the true trajectory: C2M RMS {1000 * true_rms:.2f} mm")
    print("\n| world | odometry | path (m) | final error (m) | % of path | along / lateral / "
          "vertical (m) | ATE RMS (m) | RPE 10 m (%) | cloud RMS before / after (mm) | "
          "odometry (s) |")
    print("|---|---|---:|---:|---:|---|---:|---:|---|---:|")
    for r in rows:
        cloud = (f"{1000 * r['cloud_rms_before_m']:.1f} / {1000 * r['cloud_rms_after_m']:.1f}"
                 f" ({1000 * r['cloud_rms_after_inside_m']:.1f} between the control points)"
                 if "cloud_rms_after_m" in r else "-")
        print(f"| {r['world']} | {r['odometry']} | {r['path_m']:.1f} | "
              f"{r['final_error_m']:.3f} | {r['final_error_pct']:.2f} | "
              f"{r['final_along_m']:+.3f} / {r['final_lateral_m']:+.3f} / "
              f"{r['final_vertical_m']:+.3f} | {r['ate_rms_m']:.3f} | {r['rpe10_pct']:.2f} | "
              f"{cloud} | {r['odometry_s']:.0f} |")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"date": time.strftime("%Y-%m-%d"), "args": vars(a),
                       "profiler_true_rms_m": true_rms, "rows": rows}, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
