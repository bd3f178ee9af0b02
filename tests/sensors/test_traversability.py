"""Issue 29: traversability as platform data, routes through what a platform can cross,
and re-timing instead of refusal.

- The ``[traversability]`` table loads (degrees to radians) and is validated: an
  unknown key, a missing one, a slope of 90 degrees or more are refused naming it.
- A floor tilted across the passage at a known angle (analytic plane) gives the base
  that roll in the poses, and one steeper than the platform's ``max_roll`` is refused
  naming the cross slope and the place. A hump under the belly between the wheels
  (analytic height) is refused for the ground robot (5 cm clearance) and walked.
- Re-timing: any path with kinks up to just under ``SHARP_TURN_DEG`` (hypothesis;
  the 90 degree tile's failure was a kinked route) is driven within every limit, as
  plain finite differences of the poses show; a kink is passed slower than cruise.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from raytrace import Scene
from sensors.errors import PlatformError, RouteError
from sensors.platform import SHARP_TURN_DEG, platform_trajectory
from sensors.platform_spec import PLATFORM_DIR, load_platform
from sensors.route import find_route
from tests.naive import naive_cast
from tests.sensors import route_meshes as rm

ROBOT = load_platform("ground_robot")


def test_traversability_loads_in_si_units():
    tv = ROBOT.traversability
    text = (PLATFORM_DIR / "ground_robot.toml").read_text()
    row = {ln.split("=")[0].strip(): float(ln.split("=")[1].split("#")[0])
           for ln in text.split("[traversability]")[1].splitlines()
           if "=" in ln and not ln.startswith("#")}
    assert tv.max_slope_rad == pytest.approx(math.radians(row["max_slope_deg"]))
    assert tv.max_roll_rad == pytest.approx(math.radians(row["max_roll_deg"]))
    assert (tv.max_step_m, tv.ground_clearance_m, tv.footprint_width_m,
            tv.footprint_length_m) == (row["max_step_m"], row["ground_clearance_m"],
                                       row["footprint_width_m"], row["footprint_length_m"])
    assert load_platform("walker").traversability is not None
    assert load_platform("trolley").traversability is None


@pytest.mark.parametrize("edit, match", [
    (("max_step_m", "max_stepm"), r"unknown key `max_stepm` \(did you mean `max_step_m`\?\)"),
    (("max_slope_deg = 25.0", "max_slope_deg = 95.0"), "max_slope_deg` .* below 90"),
    (("max_roll_deg = 20.0", "max_roll_deg = -5.0"), "max_roll_deg` .* > 0"),
    (("[traversability]", "[traverse]"), "unknown key `traverse`"),
])
def test_bad_traversability_is_refused(edit, match, tmp_path):
    text = (PLATFORM_DIR / "ground_robot.toml").read_text()
    assert edit[0] in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(edit[0], edit[1]))
    with pytest.raises(PlatformError, match=match):
        load_platform(p)


def _roll_deg(traj):
    return np.degrees(np.arcsin(np.clip(traj.rotations.as_matrix()[:, 2, 1], -1, 1)))


def test_cross_slope_rolls_the_base_and_too_much_is_refused():
    """Floor z = tan(theta) y: the wheels' plane is the floor, so the base rolls by
    exactly theta on it (poses, away from the ends); over max_roll it is refused."""
    for deg in (12.0, 24.0):
        g = math.tan(math.radians(deg))
        v, f = rm.strip(np.arange(0.0, 10.01, 0.25), lambda x: 1.5 + 0 * x,
                        lambda x, y: g * y)
        scene = Scene(v, f)
        if deg > math.degrees(ROBOT.traversability.max_roll_rad):
            with pytest.raises(RouteError, match=r"roll\) of 24 deg .* at \("):
                find_route(scene, platform=ROBOT)
            continue
        route = find_route(scene, platform=ROBOT)
        traj = platform_trajectory(route, ROBOT, 1.0, scene=scene)
        mid = (traj.positions[:, 0] > 2.0) & (traj.positions[:, 0] < 8.0)
        np.testing.assert_allclose(np.abs(_roll_deg(traj)[mid]), deg, atol=0.2)


def test_a_hump_under_the_belly():
    """A ridge across the passage, 8 cm high, 2 cm flat on top, 45 degree sides (no
    step over the 8 cm limit between samples 5 cm apart; 18 cm in all, shorter than
    the 20 cm wheelbase): between the ground robot's axles it lifts the floor above
    its 5 cm ground clearance, and it is refused
    naming the belly and the place; a 3 cm ridge is driven over (the floor under the
    route, brute-force rays, shows it)."""
    for h in (0.08, 0.03):
        xs = np.unique(np.concatenate([np.arange(0.0, 10.01, 0.25),
                                       [5.0 - h, 5.0, 5.02, 5.02 + h]]))

        def fz(x, y, h=h):
            up = np.clip((x - (5.0 - h)), 0, h) - np.clip(x - 5.02, 0, h)
            return up + 0 * y
        v, f = rm.strip(xs, lambda x: 1.5 + 0 * x, fz)
        if h > ROBOT.traversability.ground_clearance_m:
            with pytest.raises(RouteError, match=r"under its belly .* at \((4\.9\d*|5|5\.0\d*), "):
                find_route(Scene(v, f), platform=ROBOT)
            find_route(Scene(v, f), platform=load_platform("walker"), height_m=1.5)
        else:
            route = find_route(Scene(v, f), platform=ROBOT)
            p = route.points
            assert p[:, 0].min() < 1.0 and p[:, 0].max() > 9.0           # end to end
            k = np.flatnonzero(np.abs(p[:, 0] - 5.0) < 0.5)               # over the ridge
            s = np.linspace(0, 1, 101)[:, None]
            dense = np.vstack([p[i] + s * (p[i + 1] - p[i]) for i in k[:-1]])
            t = naive_cast(v, f, dense, np.tile([0.0, 0, -1], (len(dense), 1)))[0]
            assert (dense[:, 2] - t).max() == pytest.approx(h, abs=1e-6)


def _kinked(turns_deg, seg_m):
    """A polyline of straight legs ``seg_m`` long sampled every 0.25 m, turning by
    each of ``turns_deg`` (deg) at the leg ends: a route with kinks."""
    pts, head, p = [np.zeros(2)], 0.0, np.zeros(2)
    for turn in [0.0, *turns_deg]:
        head += math.radians(turn)
        d = np.array([math.cos(head), math.sin(head)])
        for _ in range(int(round(seg_m / 0.25))):
            p = p + 0.25 * d
            pts.append(p)
    xy = np.array(pts)
    return np.column_stack([xy, np.full(len(xy), 0.5)])


def _check(traj, lim):
    """Speed, acceleration, jerk and yaw rate of the poses by plain finite differences
    within the limits (0.1 %)."""
    t, p = traj.times, traj.positions
    dt = np.diff(t)
    v = np.diff(p[:, :2], axis=0) / dt[:, None]
    a = np.diff(v, axis=0) / (0.5 * (dt[1:] + dt[:-1]))[:, None]
    j = np.diff(a, axis=0) / dt[1:-1, None]
    n = np.linalg.norm
    m = traj.rotations.as_matrix()
    yaw = np.unwrap(np.arctan2(m[:, 1, 0], m[:, 0, 0]))
    tol = 1.001
    assert n(v, axis=1).max() <= lim.max_speed_mps * tol
    assert n(a, axis=1).max() <= lim.max_accel_mps2 * tol
    assert n(j, axis=1).max() <= lim.max_jerk_mps3 * tol
    assert np.abs(np.diff(yaw) / dt).max() <= lim.max_yaw_rate_radps * tol
    return n(v, axis=1)


@settings(max_examples=8, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(turns=st.lists(st.floats(-(SHARP_TURN_DEG - 1), SHARP_TURN_DEG - 1),
                      min_size=1, max_size=3),
       seg=st.sampled_from([1.5, 2.5, 4.0]),
       speed=st.sampled_from([0.3, 1.0]))
def test_kinked_paths_are_retimed_within_the_limits(turns, seg, speed):
    """The 90 degree tile's refusal ('a jerk of 14.33 above 1 after 8 plans', the
    same at every speed) came from kinks in its route: every kinked path is now driven
    within the limits, slower at each kink than on the straights."""
    path = _kinked(turns, seg)
    traj = platform_trajectory(path, ROBOT, speed)
    vel = _check(traj, ROBOT.limits)
    assert vel.max() > 0.25 * speed                                  # it does drive
    big = [i for i, tr in enumerate(turns) if abs(tr) > 20]
    for i in big:              # the kink's position: the end of leg i (from 0)
        corner = path[int(round(seg / 0.25)) * (i + 1), :2]
        near = np.linalg.norm(traj.positions[1:, :2] - corner, axis=1) < 0.05
        if near.any():
            assert vel[near].max() < speed
