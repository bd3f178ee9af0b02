"""Drift correction of a simulated MLS run through the generated tunnel: SLAM drift
(attitude random walks) of ~0.3-1 m over 300 m, prisms every 25 m observed with mm
noise; the corrected cloud is compared with the simulation's truth."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace import Scene
from sensors import Settings, Trajectory, load_sensor, simulate_drive
from sensors.spec import SPEC_DIR
from survey.errors import DriftError
from survey.adjust.drift import fit_drift, leave_one_out
from survey.world.presets import preset
from survey.adjust.slam import slam_trajectory, to_slam_frame

SPEED = 2.0


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tun, _ = preset("bfo", edge_length_m=0.25)
    al = tun.alignment
    c0, c1 = al.chainage_range
    s = np.arange(c0 + 0.5, c1 - 0.5, 0.25)
    true = Trajectory.along_polyline(al.to_world(s, 0.0, 1.0), SPEED, rate_hz=50)
    slam = slam_trajectory(true, seed=4)
    # A light profile scanner (user TOML): 20 profiles/s x 500 points keeps the test fast.
    text = (SPEC_DIR / "zf_profiler_9012.toml").read_text()
    text = text.replace("profile_rate_hz = 200.0", "profile_rate_hz = 20.0")
    text = text.replace("points_per_profile = 5000", "points_per_profile = 500")
    text = text.replace('name = "zf_profiler_9012"', 'name = "light_profiler"')
    toml = tmp_path_factory.mktemp("spec") / "light.toml"
    toml.write_text(text)
    pts = np.concatenate(list(simulate_drive(Scene(tun.vertices, tun.faces), load_sensor(toml),
                                             true, settings=Settings.ideal())))
    truth = np.stack([pts["x"], pts["y"], pts["z"]], 1)
    mls = to_slam_frame(true, slam, truth, pts["time"])
    # Control points: prism centres; observed in the MLS frame when the trolley passes.
    rng = np.random.default_rng(9)
    cps = tun.metadata["control_points"]
    g = np.array([c["xyz"] for c in cps])
    tau = np.array([(c["chainage_m"] - s[0]) / SPEED for c in cps])
    m = to_slam_frame(true, slam, g, tau) + rng.normal(0, 0.003, g.shape)
    g_obs = g + rng.normal(0, 0.0015, g.shape)
    return dict(truth=truth, mls=mls, time=pts["time"], m=m, tau=tau, g=g_obs,
                g_true=g, ids=[c["id"] for c in cps], true=true, slam=slam)


def test_drift_is_realistic(run):
    err = np.linalg.norm(run["mls"] - run["truth"], axis=1)
    assert 0.3 < err.max() < 1.5          # ~0.3-1 m over 300 m, as a SLAM run drifts


def test_piecewise_correction_reaches_millimetres(run):
    corr = fit_drift(run["m"], run["tau"], run["g"], sigma_world_m=0.0015, ids=run["ids"])
    fixed = corr.apply(run["mls"], run["time"])
    rms = np.sqrt(np.mean(np.sum((fixed - run["truth"]) ** 2, axis=1)))
    assert rms <= 0.005
    # A single similarity for the whole run cannot follow the drift.
    glob = fit_drift(run["m"], run["tau"], run["g"], model="global")
    rms_g = np.sqrt(np.mean(np.sum((glob.apply(run["mls"], run["time"]) - run["truth"]) ** 2,
                                   axis=1)))
    assert rms_g > 5 * rms
    # The corrected trajectory follows the true one.
    ct = corr.apply_trajectory(run["slam"])
    inner = (ct.times > run["tau"].min()) & (ct.times < run["tau"].max())
    assert np.abs(ct.positions[inner] - run["true"].positions[inner]).max() < 0.02


def test_check_points_tell_the_true_accuracy(run):
    """Leave-one-out residuals at the prisms against the error the corrected cloud
    really has near them (truth known here): the same size, millimetres."""
    loo = leave_one_out(run["m"], run["tau"], run["g"], sigma_world_m=0.0015)
    loo_rms = np.sqrt(np.mean(np.sum(loo ** 2, axis=1)))
    corr = fit_drift(run["m"], run["tau"], run["g"], sigma_world_m=0.0015)
    true_err = corr.apply(run["m"], run["tau"]) - run["g_true"]
    assert loo_rms < 0.02
    assert loo_rms >= np.sqrt(np.mean(np.sum(corr.residuals ** 2, axis=1)))  # honest > fit
    near = np.sqrt(np.mean(np.sum(true_err ** 2, axis=1)))
    assert 0.3 * loo_rms < near + 0.003 and near < 3 * loo_rms + 0.003


def test_bad_drift_input():
    with pytest.raises(DriftError, match="at least 3"):
        fit_drift(np.zeros((2, 3)), np.zeros(2), np.zeros((2, 3)))
    with pytest.raises(DriftError, match="model"):
        fit_drift(np.eye(3) * 5, np.arange(3.0), np.eye(3) * 5, model="spline")
