"""Trajectory errors (ATE, RPE per path length) against evo, the reference the figures
claim to reproduce, on realistic drifting odometry, plus analytic cases (a pure scale
error, a constant offset), the association by interpolation, the report and the plot."""

from __future__ import annotations

import functools
import json
import math

import numpy as np
import pytest
from evo.core import filters, metrics
from evo.core.trajectory import PoseTrajectory3D
from evo.core.units import Unit
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from sensors import Trajectory
from survey.analysis.trajectory import (RelativeError, TrajectoryErrors, align_origin,
                                        path_pairs, trajectory_errors)
from survey.errors import CompareError
from survey.report.slam import plot_slam, slam_report

#: Modest world coordinates: evo works in world coordinates, so UTM-sized ones would
#: limit its own precision to ~1e-9 m (tested separately with a looser tolerance).
ORIGIN = np.array([1200.0, -800.0, 40.0])
#: Agreement with evo: both are float64 evaluations of the same formulas in a different
#: order; relative 1e-9 (the brief), absolute 1e-12 m or rad for figures near zero.
RTOL, ATOL = 1e-9, 1e-12
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# ---------------------------------------------------------------------- data
@functools.cache
def curved_truth(origin: tuple[float, float, float] = tuple(ORIGIN)) -> Trajectory:
    """~155 m S-curve with a grade and a vertical curve, 2 m/s, 100 Hz."""
    s = np.linspace(0.0, 150.0, 601)
    pts = np.stack([s, 8.0 * np.sin(s / 25.0), 0.02 * s + 0.5 * np.sin(s / 40.0)], 1)
    return Trajectory.along_polyline(pts + np.asarray(origin), 2.0, rate_hz=100.0,
                                     follow_grade=True)


def drifting(truth: Trajectory, *, yaw_rad_per_m: float = 1.5e-4, scale: float = 1.01,
             noise_m: float = 0.002, rot_noise_rad: float = 5e-4, seed: int = 0,
             t_shift_s: float = 0.033) -> Trajectory:
    """A 10 Hz odometry estimate: dead reckoning of the true steps with a yaw error
    growing with the distance, a scale error and white noise, in its own frame (starts
    at a random pose, as KISS-ICP starts at the identity). Two poses before and three
    after the truth's span (dropped by the evaluation)."""
    rng = np.random.default_rng(seed)
    te = np.arange(truth.start_s - 0.2 + t_shift_s, truth.end_s + 0.3, 0.1)
    q, rq = truth.interpolate(np.clip(te, truth.start_s, truth.end_s))
    steps = np.diff(q, axis=0)
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(steps, axis=1))])
    yaw = Rotation.from_rotvec(np.outer(yaw_rad_per_m * dist, [0.0, 0.0, 1.0]))
    steps = scale * yaw[:-1].apply(steps) + rng.normal(0.0, noise_m, steps.shape)
    p = np.concatenate([[np.zeros(3)], np.cumsum(steps, axis=0)])
    rp = yaw * rq * Rotation.from_rotvec(rng.normal(0.0, rot_noise_rad, (len(te), 3)))
    frame = Rotation.from_rotvec(rng.normal(0.0, 1.0, 3))
    p = frame.apply(p) + rng.normal(0.0, 50.0, 3)
    return Trajectory(te, p, frame * rp)


def evo_traj(t, pos, rot: Rotation) -> PoseTrajectory3D:
    q = rot.as_quat()
    return PoseTrajectory3D(np.asarray(pos, dtype=float), q[:, [3, 0, 1, 2]], np.asarray(t))


def evo_figures(est: Trajectory, tru: Trajectory, deltas, *, align: str = "origin",
                pairs_from_reference: bool = False) -> dict:
    """Every figure of ``trajectory_errors`` as evo computes it."""
    inside = (est.times >= tru.start_s) & (est.times <= tru.end_s)
    t = est.times[inside]
    E = evo_traj(t, est.positions[inside], est.rotations[np.flatnonzero(inside)])
    Q = evo_traj(t, *tru.interpolate(t))
    scale = 1.0
    if align == "origin":
        E.align_origin(Q)
    elif align in ("se3", "sim3"):
        scale = E.align(Q, correct_scale=align == "sim3")[2]
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((Q, E))
    st_ = ape.get_all_statistics()
    rot = metrics.APE(metrics.PoseRelation.rotation_angle_rad)
    rot.process_data((Q, E))
    out = dict(n_poses=len(t), n_dropped=int((~inside).sum()), ate_rms_m=st_["rmse"],
               ate_mean_m=st_["mean"], ate_median_m=st_["median"], ate_max_m=st_["max"],
               final_error_m=ape.error[-1], final_rotation_error_rad=rot.error[-1],
               alignment_scale=scale, positions=E.positions_xyz, rpe={})
    for d in deltas:
        r = {}
        for rel, key in ((metrics.PoseRelation.translation_part, ""),
                         (metrics.PoseRelation.rotation_angle_rad, "rot_")):
            m = metrics.RPE(rel, delta=d, delta_unit=Unit.meters, all_pairs=False,
                            pairs_from_reference=pairs_from_reference)
            try:
                m.process_data((Q, E))
            except filters.FilterException:    # evo: no pair at all
                r = dict(n_pairs=0)
                break
            s = m.get_all_statistics()
            unit = "rad" if key else "m"
            r.update({f"{key}rms_{unit}": s["rmse"], f"{key}mean_{unit}": s["mean"],
                      f"{key}max_{unit}": s["max"], "n_pairs": len(m.error)})
            if not key:
                r["median_m"] = s["median"]
        out["rpe"][d] = r
    return out


def assert_matches_evo(e: TrajectoryErrors, ref: dict) -> None:
    assert (e.n_poses, e.n_dropped) == (ref["n_poses"], ref["n_dropped"])
    for k in ("ate_rms_m", "ate_mean_m", "ate_median_m", "ate_max_m", "final_error_m",
              "final_rotation_error_rad", "alignment_scale"):
        np.testing.assert_allclose(getattr(e, k), ref[k], rtol=RTOL, atol=ATOL, err_msg=k)
    for d, r in ref["rpe"].items():
        mine = e.rpe(d)
        assert mine.n_pairs == r["n_pairs"], d
        if r["n_pairs"] == 0:
            assert math.isnan(mine.rms_m) and math.isnan(mine.rot_mean_rad)
            continue
        for k, v in r.items():
            np.testing.assert_allclose(getattr(mine, k), v, rtol=RTOL, atol=ATOL,
                                       err_msg=f"{k} at {d} m")
        np.testing.assert_allclose(mine.mean_pct, 100 * r["mean_m"] / d, rtol=RTOL)


# ---------------------------------------------------------------------- against evo
@pytest.mark.parametrize("align", ["origin", "none", "se3", "sim3"])
def test_every_figure_matches_evo(align):
    tru = curved_truth()
    est = drifting(tru, seed=3)
    if align == "none":     # the same frame is needed: put the estimate there first
        est = align_origin(est, tru)
    deltas = (5.0, 10.0, 37.5, 100.0, 500.0)
    e = trajectory_errors(est, tru, deltas_m=deltas, align=align)
    ref = evo_figures(est, tru, deltas, align=align)
    assert_matches_evo(e, ref)
    assert ref["rpe"][500.0]["n_pairs"] == 0 and ref["rpe"][10.0]["n_pairs"] >= 10
    assert e.n_dropped == 5
    # The per-pose errors are evo's aligned estimate minus the truth.
    q, _ = tru.interpolate(e.times_s)
    np.testing.assert_allclose(e.error_m, ref["positions"] - q, rtol=0, atol=1e-9)
    if align == "origin":   # realistic drift: metres over 150 m, a few % of the distance
        assert 0.3 < e.final_error_m < 10 and 0.2 < e.final_error_pct < 5


def test_pairs_from_the_truth_match_evo_pairs_from_reference():
    tru = curved_truth()
    est = drifting(tru, seed=5, scale=1.03)
    e = trajectory_errors(est, tru, deltas_m=(10.0, 50.0), pairs_from="truth")
    assert_matches_evo(e, evo_figures(est, tru, (10.0, 50.0), pairs_from_reference=True))
    other = trajectory_errors(est, tru, deltas_m=(10.0, 50.0))
    # 3 % scale: the estimate's path reaches 10 m 3 % sooner, other pairs.
    assert abs(other.rpe(10.0).mean_m - e.rpe(10.0).mean_m) > 1e-3


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2 ** 16), yaw=st.floats(-4e-4, 4e-4),
       scale=st.floats(0.95, 1.05), noise=st.floats(0.0, 0.02),
       delta=st.floats(1.0, 80.0))
def test_property_random_drifts_match_evo(seed, yaw, scale, noise, delta):
    tru = curved_truth()
    est = drifting(tru, yaw_rad_per_m=yaw, scale=scale, noise_m=noise, seed=seed)
    e = trajectory_errors(est, tru, deltas_m=(delta,))
    assert_matches_evo(e, evo_figures(est, tru, (delta,)))


def test_utm_sized_coordinates_agree_to_evos_own_precision():
    # evo computes in world coordinates: at 5e6 m its rounding is ~1e-9 m; ours keeps a
    # local origin, so the agreement is bounded by evo's precision, not ours.
    tru = curved_truth((500_000.0, 5_400_000.0, 300.0))
    est = drifting(tru, seed=1)
    e = trajectory_errors(est, tru)
    ref = evo_figures(est, tru, (10.0, 100.0))
    np.testing.assert_allclose(e.ate_rms_m, ref["ate_rms_m"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(e.final_error_m, ref["final_error_m"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(e.rpe(10.0).mean_m, ref["rpe"][10.0]["mean_m"], atol=1e-8)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 16), n=st.integers(2, 300), delta=st.floats(0.05, 30.0))
def test_property_path_pairs_are_evos(seed, n, delta):
    rng = np.random.default_rng(seed)
    pos = np.cumsum(rng.normal(0.0, 0.5, (n, 3)), axis=0)
    poses = [np.block([[np.eye(3), p[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]])
             for p in pos]
    ref = filters.filter_pairs_by_path(poses, delta, all_pairs=False)
    assert path_pairs(pos, delta).tolist() == [list(p) for p in ref]


def test_align_origin_is_evos():
    tru = curved_truth()
    est = drifting(tru, seed=2)
    moved = align_origin(est, tru)
    inside = (est.times >= tru.start_s) & (est.times <= tru.end_s)
    i0 = int(np.argmax(inside))
    q0, r0 = tru.interpolate(est.times[i0:i0 + 1])
    np.testing.assert_allclose(moved.positions[i0], q0[0], rtol=0, atol=1e-9)
    assert (moved.rotations[i0] * r0[0].inv()).magnitude() < 1e-12
    ref = evo_figures(est, tru, ())["positions"]
    np.testing.assert_allclose(moved.positions[inside], ref, rtol=0, atol=1e-9)
    assert len(moved) == len(est)          # the dropped poses are moved too


# ---------------------------------------------------------------------- analytic
def straight(heading_rad: float, *, length_m: float = 120.0, speed: float = 1.3
             ) -> Trajectory:
    d = np.array([math.cos(heading_rad), math.sin(heading_rad), 0.0])
    return Trajectory.along_polyline([ORIGIN, ORIGIN + length_m * d], speed, rate_hz=100.0)


def at_10hz(tru: Trajectory, positions_fn) -> Trajectory:
    t = np.arange(tru.start_s, tru.end_s, 0.1)
    q, r = tru.interpolate(t)
    return Trajectory(t, positions_fn(q), r)


def test_pure_scale_error_on_a_straight_line():
    s, speed, heading = 1.03, 1.3, math.radians(35.0)
    tru = straight(heading, speed=speed)
    est = at_10hz(tru, lambda q: q[0] + s * (q - q[0]))
    e = trajectory_errors(est, tru, deltas_m=(10.0, 100.0))
    length = speed * (e.end_s - e.start_s)
    np.testing.assert_allclose(e.path_length_m, length, rtol=1e-12)
    np.testing.assert_allclose(e.final_error_m, (s - 1) * length, rtol=1e-9)
    np.testing.assert_allclose(e.final_error_pct, 100 * (s - 1), rtol=1e-9)
    np.testing.assert_allclose(e.final_error_along_m, (s - 1) * length, rtol=1e-9)
    assert abs(e.final_error_lateral_m) < 1e-9 and abs(e.final_error_vertical_m) < 1e-9
    step = 0.1 * speed                      # true distance between estimate poses
    by_truth = trajectory_errors(est, tru, deltas_m=(10.0, 100.0), pairs_from="truth")
    for delta in (10.0, 100.0):
        # Pairs along the estimate's path: k steps, the first with k s step >= delta;
        # along the true path, the first with k step >= delta (no ties at these values).
        for res, k in ((e, math.ceil(delta / (s * step))),
                       (by_truth, math.ceil(delta / step))):
            r = res.rpe(delta)
            assert r.n_pairs == (len(est) - 1) // k
            np.testing.assert_allclose([r.rms_m, r.mean_m, r.max_m], (s - 1) * k * step,
                                       rtol=1e-9)
            assert r.rot_max_rad < 1e-12
        # Hence ~ (s - 1) delta per delta of true path, (s - 1) / s delta of estimated.
        assert 0 <= by_truth.rpe(delta).mean_m - (s - 1) * delta < (s - 1) * step
        assert 0 <= e.rpe(delta).mean_m - (s - 1) * delta / s < (s - 1) * step


def test_a_constant_offset_vanishes_after_the_origin_alignment():
    tru = curved_truth()
    t = np.arange(tru.start_s + 0.01, tru.end_s, 0.1)
    q, r = tru.interpolate(t)
    g = Rotation.from_euler("zyx", [1.1, 0.2, -0.3])
    est = Trajectory(t, g.apply(q) + [3.0, -7.0, 2.0], g * r)     # another frame
    e = trajectory_errors(est, tru)
    assert e.ate_max_m < 1e-9 and e.final_rotation_error_rad < 1e-9
    assert all(x.max_m < 1e-9 and x.rot_max_rad < 1e-9 for x in e.relative)


def test_offset_in_the_heading_frame_without_alignment():
    heading = math.radians(-120.0)
    tru = straight(heading)
    along = np.array([math.cos(heading), math.sin(heading), 0.0])
    left = np.array([-math.sin(heading), math.cos(heading), 0.0])
    b = 0.3 * along - 0.2 * left + 0.1 * np.array([0.0, 0.0, 1.0])
    est = at_10hz(tru, lambda q: q + b)
    e = trajectory_errors(est, tru, align="none")
    np.testing.assert_allclose([e.final_error_along_m, e.final_error_lateral_m,
                                e.final_error_vertical_m], [0.3, -0.2, 0.1], atol=1e-12)
    np.testing.assert_allclose([e.ate_rms_m, e.ate_max_m], np.linalg.norm(b), rtol=1e-12)
    np.testing.assert_allclose(e.error_along_m, 0.3, atol=1e-12)


def test_the_truth_is_interpolated_not_nearest():
    # Estimate poses half-way between truth samples, exactly on the truth: zero error.
    # A nearest-timestamp association would see 2 m/s x 5 ms = 1 cm.
    tru = curved_truth()
    t = np.arange(tru.start_s + 0.005, tru.end_s, 0.1)
    q, r = tru.interpolate(t)
    e = trajectory_errors(Trajectory(t, q, r), tru, align="none")
    assert e.ate_max_m < 1e-9
    # Path length: the truth's own polyline between the first and last estimate times.
    k = (tru.times > t[0]) & (tru.times < t[-1])
    ends = tru.interpolate([t[0], t[-1]])[0]
    poly = np.concatenate([ends[:1], tru.positions[k], ends[1:]])
    np.testing.assert_allclose(e.path_length_m,
                               np.linalg.norm(np.diff(poly, axis=0), axis=1).sum(),
                               rtol=1e-12)
    np.testing.assert_allclose(e.distance_m[[0, -1]], [0.0, e.path_length_m])


def test_a_delta_longer_than_the_path_gives_nan_recorded_as_null():
    tru = curved_truth()
    e = trajectory_errors(drifting(tru), tru, deltas_m=(10.0, 1000.0))
    r = e.rpe(1000.0)
    assert r.n_pairs == 0 and all(math.isnan(getattr(r, k)) for k in
                                  ("rms_m", "mean_m", "max_m", "mean_pct", "rot_mean_rad"))
    d = json.loads(json.dumps(e.to_dict(), allow_nan=False))
    assert d["rpe"][1]["mean_m"] is None and d["rpe"][1]["n_pairs"] == 0
    assert d["rpe"][0]["mean_m"] == e.rpe(10.0).mean_m
    assert d["ate_rms_m"] == e.ate_rms_m and d["n_dropped"] == 5
    assert isinstance(r, RelativeError)


# ---------------------------------------------------------------------- errors
def test_invalid_inputs_raise():
    tru = curved_truth()
    est = drifting(tru)
    with pytest.raises(CompareError, match=r"Expected `estimate` as a sensors.Trajectory"):
        trajectory_errors(np.zeros((5, 8)), tru)  # type: ignore[arg-type]
    with pytest.raises(CompareError, match=r"Expected `truth` as a sensors.Trajectory"):
        align_origin(est, "truth.txt")  # type: ignore[arg-type]
    with pytest.raises(CompareError, match=r"at least 2 poses to interpolate, got 1"):
        trajectory_errors(est, Trajectory.static(ORIGIN, t=5.0))
    late = Trajectory(est.times + 1000.0, est.positions, est.rotations)
    with pytest.raises(CompareError, match=r"to overlap the truth's .* no common time"):
        trajectory_errors(late, tru)
    one = Trajectory([tru.end_s - 0.01, tru.end_s + 1.0], [ORIGIN, ORIGIN + 1],
                     Rotation.identity(2))
    with pytest.raises(CompareError, match=r"at least 2 estimate poses within .* got 1"):
        trajectory_errors(one, tru)
    with pytest.raises(CompareError, match=r"Expected `align` one of .* got 'umeyama'"):
        trajectory_errors(est, tru, align="umeyama")  # type: ignore[arg-type]
    with pytest.raises(CompareError, match=r"Expected `pairs_from` 'estimate' or 'truth'"):
        trajectory_errors(est, tru, pairs_from="both")  # type: ignore[arg-type]
    for bad in ((10.0, -1.0), (float("nan"),), "ten", 0.0):
        with pytest.raises(CompareError, match=r"Expected `deltas_m` as positive"):
            trajectory_errors(est, tru, deltas_m=bad)  # type: ignore[arg-type]
    line = straight(0.3)
    with pytest.raises(CompareError, match=r"spread in at least 2 directions .* "
                                           r"align='origin'"):
        trajectory_errors(at_10hz(line, lambda q: 1.01 * q), line, align="se3")
    with pytest.raises(CompareError, match=r"Expected one of the evaluated deltas"):
        trajectory_errors(est, tru).rpe(20.0)


# ---------------------------------------------------------------------- report, plot
def test_markdown_report_holds_the_figures():
    tru = curved_truth()
    e = trajectory_errors(drifting(tru), tru, deltas_m=(10.0, 100.0, 1000.0))
    md = slam_report(e, odometry="KISS-ICP 1.2 (defaults)", plot_path="run/slam.png")
    for v in (e.ate_rms_m, e.ate_max_m, e.ate_mean_m, e.final_error_m,
              e.final_error_along_m, e.final_error_lateral_m, e.path_length_m):
        assert f"{v:.3f}" in md or f"{v:.2f}" in md
    assert f"| {e.final_error_pct:.2f} |" in md
    for d in (10.0, 100.0):
        r = e.rpe(d)
        assert (f"| {d:g} m | {r.n_pairs} | {r.rms_m:.3f} | {r.mean_m:.3f} | "
                f"{r.max_m:.3f} | {r.mean_pct:.2f} | "
                f"{math.degrees(r.rot_mean_rad):.3f} |") in md
    assert "| 1000 m | 0 | n/a |" in md
    assert "KISS-ICP 1.2 (defaults)" in md and "align_origin" in md
    assert "5 estimate poses outside" in md and "![trajectory errors](slam.png)" in md
    e3 = trajectory_errors(drifting(tru), tru, align="sim3")
    sim = slam_report(e3, odometry="x")
    assert f"scale {e3.alignment_scale:.6f}" in sim and "Umeyama" in sim


def test_plot_is_a_png_that_follows_the_estimate(tmp_path):
    tru = curved_truth()
    pngs = []
    for k, yaw in enumerate((1.5e-4, -3e-4)):
        est = drifting(tru, yaw_rad_per_m=yaw)
        e = trajectory_errors(est, tru)
        out = plot_slam(est, tru, e, tmp_path / f"slam{k}.png")
        assert out == tmp_path / f"slam{k}.png"
        data = out.read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 20_000
        pngs.append(data)
    assert pngs[0] != pngs[1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["slam0.png", "slam1.png"]
