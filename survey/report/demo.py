"""The demo's key numbers: read back from the files its pipeline wrote, so the report,
``summary.json`` and the tests all see the same figures."""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import Any

import numpy as np


#: Points of each MLS cloud compared with the true mesh in the summary (a seeded random
#: subsample: C2M of the full run would dominate the demo's time, and 200k points give the
#: RMS to well under 1 % relative standard error).
C2M_SAMPLE = 200_000


def _csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def cloud_c2m_rms(clouds: list[str | os.PathLike[str]], mesh: str | os.PathLike[str], *,
                  sample: int = C2M_SAMPLE, seed: int = 0) -> list[float | None]:
    """RMS (m) of the signed cloud-to-mesh distance of each cloud against ``mesh``.

    The clouds must hold the same points in the same order (a run and its corrected
    copy): one seeded subsample of ``sample`` indices is drawn for all of them, so the
    figures compare the same points. A cloud of another size, or with no finite
    distance, gives None.
    """
    from survey.analysis.compare import ReferenceMesh
    from sensors.io.cloudread import read_points
    from sensors.io.meshes import read_mesh

    m = read_mesh(mesh)
    ref = ReferenceMesh(m.vertices, m.faces)
    pts = [read_points(c) for c in clouds]
    n = len(pts[0])
    idx = np.random.default_rng(seed).choice(n, min(sample, n), replace=False) \
        if n else np.zeros(0, dtype=np.int64)
    out: list[float | None] = []
    for p in pts:
        if len(p) != n or not n:
            out.append(None)
            continue
        d = ref.distances(p[idx]).distance
        d = d[np.isfinite(d)]
        out.append(float(np.sqrt(np.mean(d * d))) if len(d) else None)
    return out


#: The demo's MLS files (its pipeline's names): the raw trajectory both branches write,
#: the evaluation the slam step writes beside it, and each branch's true trajectory.
RAW_TRAJECTORY = "mls_raw_trajectory.txt"
SLAM_EVALUATION = "mls_raw_trajectory.json"
TRUE_TRAJECTORY = {True: "slam_lidar_true_trajectory.txt",
                   False: "mls_raw_true_trajectory.txt"}
#: summary.json's ``drift_model`` for the fallback branch.
DRIFT_MODEL = "random walk (model; the slam extra is not installed)"
#: The slam step's figures summary.json carries (names of its JSON).
SLAM_KEYS = ("final_error_m", "final_error_pct", "ate_rms_m", "path_length_m")


def ran_slam(folder: str | os.PathLike[str]) -> bool:
    """Whether a demo folder's raw MLS run came from real SLAM (the slam step) rather
    than the drift model: the slam step's evaluation is there and not older than the
    raw trajectory (a folder rerun with ``--force`` on the other branch keeps the other
    branch's files; the newer trajectory tells which branch wrote it)."""
    d = Path(folder)
    ev, raw = d / SLAM_EVALUATION, d / RAW_TRAJECTORY
    return ev.is_file() and raw.is_file() and ev.stat().st_mtime >= raw.stat().st_mtime


def _position_errors(est, truth) -> tuple[np.ndarray, np.ndarray]:
    """Times (n,) of the estimate within the truth's span and |p_est - p_true| (n,) m
    there, the truth interpolated at the estimate's times (the SLAM estimate is stamped
    per frame, the truth per pose of the drive; the drift model shares the truth's
    times, where this is the pose-by-pose difference)."""
    t = est.times
    ok = (t >= truth.start_s) & (t <= truth.end_s)
    p, _ = truth.interpolate(t[ok])
    return t[ok], np.linalg.norm(est.positions[ok] - p, axis=1)


def demo_summary(folder: str | os.PathLike[str], *, slam: bool | None = None
                 ) -> dict[str, Any]:
    """Key numbers of a finished demo folder (missing pieces are left out).

    Parameters
    ----------
    folder : path
        The demo's output folder.
    slam : bool, optional
        Whether the demo ran the real SLAM branch (its steps with ``requires = "slam"``)
        or the drift-model fallback; by default told from the files (``ran_slam``).

    Returns
    -------
    dict
        JSON-ready figures; with ``slam``: ``slam`` (odometry, final error, ATE RMS,
        path length of the odometry against the truth) and ``drift_model``, the
        odometry's name or ``DRIFT_MODEL``.
    """
    from sensors import Trajectory

    d = Path(folder)
    slam = ran_slam(d) if slam is None else slam
    out: dict[str, Any] = {}
    raw, true_path = d / RAW_TRAJECTORY, d / TRUE_TRAJECTORY[slam]
    ev = json.loads((d / SLAM_EVALUATION).read_text()) \
        if slam and (d / SLAM_EVALUATION).is_file() else None
    if ev is not None:
        out["drift_model"] = ev.get("odometry", "kiss-icp")
        out["slam"] = {"odometry": out["drift_model"], **{k: ev.get(k) for k in SLAM_KEYS}}
    elif raw.is_file() and not slam:
        out["drift_model"] = DRIFT_MODEL
    if raw.is_file() and true_path.is_file():
        est = Trajectory.read(raw)
        true = Trajectory.read(true_path)
        _, err = _position_errors(est, true)
        if len(err):
            out["raw_drift_max_m"] = float(err.max())
        fixed = d / "mls_corrected_trajectory.txt"
        seen = d / "mls_raw_cp_observed.csv"
        if fixed.is_file() and seen.is_file():
            from survey.adjust.controlpoints import read_control_points

            # Between the first and the last control point the correction is constrained;
            # beyond them it extrapolates.
            tau = read_control_points(seen).time
            t, err = _position_errors(Trajectory.read(fixed), true)
            ok = np.zeros(len(t), dtype=bool) if tau is None or not len(tau) else \
                (t >= tau.min()) & (t <= tau.max())
            if ok.any():
                out["corrected_drift_max_m"] = float(err[ok].max())
    if all((d / f).is_file() for f in ("mls_raw.laz", "mls_corrected.laz", "tunnel.ply")):
        # The drift of the cloud itself, on its points (issue 15): the trajectory
        # figures above do not show a cloud that was written without its drift.
        before, after = cloud_c2m_rms([d / "mls_raw.laz", d / "mls_corrected.laz"],
                                      d / "tunnel.ply")
        out["cloud_c2m_rms_before_m"] = before
        out["cloud_c2m_rms_after_m"] = after
    if (d / "mls_corrected.json").is_file():
        c = json.loads((d / "mls_corrected.json").read_text())
        out["corrected_check_rms_m"] = c["check_rms_m"]
        out["corrected_check_max_m"] = c["check_max_m"]
        out["control_points"] = c["control_points"]
    if (d / "reconstructed.json").is_file():
        q = json.loads((d / "reconstructed.json").read_text())
        out["reconstruction"] = {k: q[k] for k in ("triangles", "median_m", "p95_m",
                                                   "extrapolated_share")}
    table = {}
    for p in sorted(d.glob("compare*/stats.csv")):
        for row in _csv(p):
            table[row["scan"]] = {k: float(v) for k, v in row.items() if k != "scan"}
    if table:
        out["table1"] = table
    if (d / "plan" / "plan.json").is_file():
        pj = json.loads((d / "plan" / "plan.json").read_text())
        out["plan"] = {p["name"]: {"stations": p["stations"], "coverage": p["coverage"]}
                       for p in pj["plans"]}
    if (d / "study" / "study.csv").is_file():
        out["study"] = [{k: (v if k == "mount" else float(v)) for k, v in r.items()}
                        for r in _csv(d / "study" / "study.csv")]
    if (d / "detect" / "detect.json").is_file():
        rows = json.loads((d / "detect" / "detect.json").read_text())["rows"]
        out["detect"] = [{k: r[k] for k in ("sensor", "sensor_kind", "spacing_m",
                                            "speed_mps", "noise", "false_alarm_rate",
                                            "detectable_m", "a95_m")} for r in rows]
    out["gazebo_world"] = (d / "gazebo" / "world.sdf").is_file()
    return out


def summary_markdown(s: dict) -> str:
    """The report's opening table of key numbers."""
    rows = []
    if "slam" in s:
        q = s["slam"]
        rows.append(("source of the MLS drift", f"real LiDAR odometry "
                     f"({q['odometry']}) on the Airy; the profiler placed with it"))
        if all(q.get(k) is not None for k in SLAM_KEYS):
            rows.append((f"{q['odometry']} over {q['path_length_m']:.1f} m against the "
                         "truth: final error / ATE RMS",
                         f"{100 * q['final_error_m']:.1f} cm = "
                         f"{q['final_error_pct']:.2f} % of the path / "
                         f"{100 * q['ate_rms_m']:.1f} cm"))
    elif "drift_model" in s:
        rows.append(("source of the MLS drift", s["drift_model"]))
    if "raw_drift_max_m" in s:
        rows.append(("drift of the raw MLS trajectory against the truth (max)",
                     f"{1000 * s['raw_drift_max_m']:.0f} mm"))
    if "corrected_drift_max_m" in s:
        rows.append(("trajectory error after correction, between the first and last "
                     "control point (max)", f"{1000 * s['corrected_drift_max_m']:.1f} mm"))
    if "corrected_check_rms_m" in s:
        rows.append((f"after correction with {s['control_points']} control points "
                     "(leave-one-out check RMS / max)",
                     f"{1000 * s['corrected_check_rms_m']:.1f} / "
                     f"{1000 * s['corrected_check_max_m']:.1f} mm"))
    if "cloud_c2m_rms_before_m" in s:
        b, a = s["cloud_c2m_rms_before_m"], s["cloud_c2m_rms_after_m"]
        rows.append((f"MLS cloud against the true lining, C2M RMS of {C2M_SAMPLE:,} points "
                     "(raw / corrected)",
                     " / ".join("n/a" if v is None else f"{1000 * v:.1f}" for v in (b, a))
                     + " mm"))
    if "reconstruction" in s:
        r = s["reconstruction"]
        rows.append(("reconstructed lining: triangles, point-to-surface median / 95 %, "
                     "interpolated", f"{r['triangles']:,}; {1000 * r['median_m']:.1f} / "
                     f"{1000 * r['p95_m']:.1f} mm; {100 * r['extrapolated_share']:.1f} %"))
    for name, t in s.get("table1", {}).items():
        rows.append((f"Table 1 C2C {name}: mean / median / std",
                     f"{1000 * t['mean_m']:.1f} / {1000 * t['median_m']:.1f} / "
                     f"{1000 * t['std_m']:.1f} mm"))
    for name, p in s.get("plan", {}).items():
        rows.append((f"station plan '{name}'", f"{p['stations']} stations, "
                     f"{100 * p['coverage']:.1f} % of the lining within thresholds"))
    st = s.get("study", [])
    for r in st:
        if r["speed_mps"] > 0:
            rows.append((f"Airy {r['mount']} at {r['speed_mps']:g} m/s, {r['rate_hz']:g} Hz: "
                         "floor density, line spacing, rolling-shutter max",
                         f"{r['density_floor']:,.0f} pts/m^2, {r['line_spacing_m']:.3f} m, "
                         f"{1000 * r['distortion_max_m']:.0f} mm"))
    for r in s.get("detect", []):
        how = f"stations every {r['spacing_m']:g} m" if r["sensor_kind"] == "tls" \
            else f"{r['speed_mps']:g} m/s"
        lim = [("none" if v is None else f"{1000 * v:g} mm")
               for v in (r["detectable_m"]["convergence"], r["detectable_m"]["bulge"])]
        rows.append((f"detectability: {r['sensor']}, {how}, noise x{r['noise']:g}: "
                     "smallest convergence / bulge detected at 95 %, false alarms",
                     f"{lim[0]} / {lim[1]}, {100 * r['false_alarm_rate']:.1f} %"))
    if "gazebo_world" in s:
        rows.append(("Gazebo world", "gazebo/world.sdf" if s["gazebo_world"] else "missing"))
    return "\n".join(["| key number | value |", "|---|---|"] +
                     [f"| {a} | {b} |" for a, b in rows]) + "\n"


__all__ = ["C2M_SAMPLE", "DRIFT_MODEL", "RAW_TRAJECTORY", "SLAM_EVALUATION", "SLAM_KEYS",
           "TRUE_TRAJECTORY", "cloud_c2m_rms", "demo_summary", "ran_slam",
           "summary_markdown"]
