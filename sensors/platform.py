"""Platforms as data, and the motion of a platform along a path.

The platform files and their loader live in ``sensors.platform_spec`` (re-exported
here). Motions:

- ``wheeled``: a ground robot. The path is smoothed by a cubic spline, the speed along
  it is the fastest profile within the limits (below), starting and stopping at rest,
  and the heading is the path's tangent (no side slip). The base rests on the floor
  under its four wheels (rays cast down at the contact points, a least-squares plane
  through them: pitch and roll), and the platform frame is the top of the mast,
  ``mast_height_m`` along the base's z above the floor under its centre.
- ``walking``: a person carrying the sensor. The same path and speed profile; the
  sensor ``mast_height_m`` above the floor under the walker, level, bobbing once a step
  and swaying sideways (and rolling) once a stride, faded in with the speed.
- ``rail``: a trolley on its track: the path exactly, pitched with the grade
  (``Trajectory.along_polyline``).
- ``static``: a tripod at the start of the path.

Speed profile (wheeled, walking). With x = v^2 along the arc length s, heading psi(s),
kappa = dpsi/ds: yaw rate = v kappa, yaw acceleration = v^2 dkappa/ds + a kappa,
along-track acceleration a = x'/2, lateral v^2 kappa. Each is kept within a share of its
limit (``SHARES``) by a cap on x and on |a| at every s, and x is the largest profile
under those caps with x = 0 at both ends, found by a forward and a backward pass: the
time-optimal path parameterisation of Bobrow, Dubowsky & Gibson (1985, "Time-optimal
control of robotic manipulators along specified paths", IJRR 4(3)) in its discrete
form (Pham 2014, "A general, fast, and robust implementation of the time-optimal path
parameterization algorithm", IEEE T-RO 30(6)). The distance travelled is then averaged
over ``2 max_accel / max_jerk`` seconds (a boxcar), which keeps every bound and limits
the jerk to 2 a / T. The sampled motion is checked against every limit by finite
differences; where the boxcar's shift along the path breaks one, the profile is planned
again with smaller shares, and then (issue 29: re-timing, not refusal) from the first
shares again with the path slowed down near each place that broke a limit, each cap
held over the distance the boxcar averages at that speed, as a driver slows through a
rough spot; what is left after ``_TRIES`` plans is removed by stretching time. The
path's parameter at a distance along it, u(s), is a cubic spline: a linear u(s) made
the speed jump at every sample of a sharply bent path, a jerk no profile removes.

>>> spec = load_platform("ground_robot")
>>> spec
PlatformSpec(ground_robot: wheeled, mast 0.5 m, up to 1 m/s, 60 deg/s)
"""

from __future__ import annotations

import math
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from ._checks import as_number, as_points
from .errors import PlatformError
from .platform_spec import Gait, Limits, PlatformSpec, load_platform
from .route import Route
from .trajectory import Trajectory

__all__ = ["DS_M", "RIDE_SIGMA_S", "SHARES", "SHARP_TURN_DEG", "platform_trajectory"]

#: Shares of the limits the planned profile may use (the rest absorbs the boxcar's
#: shift along the path): along-track and lateral acceleration (0.8^2 + 0.6^2 = 1: the
#: total stays within the limit), and the two terms of the yaw acceleration.
#: DECISION: split caps, not one joint constraint: each holds on its own, so the passes
#: need no root finding and no cap can make another infeasible.
#: The jerk j = (da/dt - v^3 kappa^2) along + (3 v a kappa + v^3 dkappa/ds) across has
#: four terms: the boxcar's along-track jerk, v^3 kappa^2, 3 v a kappa and
#: v^3 dkappa/ds, with shares summing to 0.7 along and 0.7 across (0.99 in all).
SHARES: Final = {"along": 0.8, "lateral": 0.6, "yaw_turn": 0.5, "yaw_speed": 0.5,
                 "jerk_boxcar": 0.5, "jerk_turn": 0.2, "jerk_accel": 0.3,
                 "jerk_bend": 0.4}
#: Path sampling of the speed profile (m) and the first share of the limits planned
#: with, shrunk by ``_SHRINK`` (at most ``_TRIES`` times) while a check fails.
DS_M = 0.02
#: A vertex where the path turns by more than this is a corner the base stops at and
#: turns on the spot (ASSUMED; a route's vertices turn by a few degrees, one that turns
#: back from a waypoint by ~180).
SHARP_TURN_DEG = 60.0
_FIRST_SHARE, _SHRINK, _TRIES = 0.9, 0.8, 40
#: Rounds that shrink the shares everywhere before slowing down locally, and the factor
#: on v^2 of each local slow-down (issue 29: re-timing instead of refusing).
_GLOBAL_TRIES, _SLOW = 8, 0.5
#: ASSUMED: the base's suspension, tyres and inertia smooth the floor under the wheels
#: over this time (Gaussian sigma, s): a step in a triangulated floor is not a jolt.
#: DECISION: 0.3 s, the smallest of those tried that keeps the mast top's motion within
#: the ground robot's limits on the SubT cave's rough floor at 1 m/s (measured with
#: benchmarks/validate_routes.py: 0.05 s gave 4.7 m/s^2 and 100 m/s^3 at the top of
#: the 0.5 m mast, 0.2 s 0.46 m/s^2 and 2.7 m/s^3, 0.3 s 0.38 m/s^2 and 0.9 m/s^3;
#: the sensor stays 0.487-0.518 m above the floor under it).
RIDE_SIGMA_S = 0.3
#: Rays cast down for the floor start at the path (inside the passage) and reach
#: twice the mount height plus this (m, ASSUMED): a path given at another height than
#: the platform's still finds its floor, a hole in the floor is not a lower passage.
_CAST_EXTRA_M = 1.0
_X_FLOOR = 1e-6     # (m/s)^2: a cusp slows to 1 mm/s rather than stopping for ever


def platform_trajectory(path: ArrayLike | Route, platform: PlatformSpec | str,
                        speed_mps: float, *, scene: Any = None, rate_hz: float = 100.0,
                        start_time: float = 0.0, accel_mps2: float | None = None,
                        follow_grade: bool = True, height_m: float | None = None
                        ) -> Trajectory:
    """The trajectory of a platform driven along a path (see the module's method).

    Parameters
    ----------
    path : (n, 3) array_like of float, or Route
        Points the sensor mount passes near, ``height_m`` above the floor (a
        ``Route``'s points, or a centreline lifted by the drive height), n >= 2.
    platform : PlatformSpec or str
        A spec, or a name or path for ``load_platform``.
    speed_mps : float
        Cruising speed (m/s), at most the platform's ``max_speed_mps``.
    scene : raytrace.Scene, optional
        The mesh: the floor under the wheels (wheeled) or the walker is found by rays
        cast down. Without it the floor lies ``height_m`` below the path, and a wheeled
        platform pitches with the path's grade and does not roll.
    rate_hz : float
        Pose rate (Hz).
    start_time : float
        Time of the first pose (s).
    accel_mps2 : float, optional
        Rail: start and stop at this rate (``Trajectory.along_polyline``). Wheeled and
        walking: an acceleration limit below the platform's.
    follow_grade : bool
        Pitch (and roll) with the floor; False keeps the sensor level (its height still
        follows the floor).
    height_m : float, optional
        Height of the sensor mount above the floor (m); the platform's mast height by
        default.

    Returns
    -------
    Trajectory
        The platform frame (x forward, y left, z up) at the mount, at ``rate_hz``; a
        static one for a tripod (at ``start_time``).

    Raises
    ------
    PlatformError
        A speed or acceleration above the platform's limits, a path too short, or a
        profile that meets the limits in no planning round.
    """
    spec = platform if isinstance(platform, PlatformSpec) else load_platform(platform)
    pts = as_points(path.points if isinstance(path, Route) else path, "path", PlatformError)
    if len(pts) < 2:
        raise PlatformError(f"Expected a path of at least 2 points (n, 3), got {len(pts)}.")
    speed_mps = as_number(speed_mps, "speed_mps", PlatformError, unit="m/s", lo=0,
                          lo_open=True)
    rate_hz = as_number(rate_hz, "rate_hz", PlatformError, unit="Hz", lo=0, lo_open=True)
    start_time = as_number(start_time, "start_time", PlatformError, unit="s")
    h = spec.mast_height_m if height_m is None else as_number(
        height_m, "height_m", PlatformError, unit="m", lo=0, lo_open=True)
    lim = spec.limits
    if lim is not None and speed_mps > lim.max_speed_mps:
        raise PlatformError(f"Expected a speed at most the {spec.name}'s "
                            f"{lim.max_speed_mps:g} m/s, got {speed_mps:g} m/s; lower the "
                            "speed or use another platform.")
    if spec.motion == "static":
        return _static(pts, h, scene, start_time)
    if spec.motion == "rail":
        return Trajectory.along_polyline(pts, speed_mps, rate_hz=rate_hz,
                                         start_time=start_time, follow_grade=follow_grade,
                                         accel_mps2=accel_mps2)
    assert lim is not None
    if accel_mps2 is not None:
        accel_mps2 = as_number(accel_mps2, "accel_mps2", PlatformError, unit="m/s^2",
                               lo=0, lo_open=True)
        if accel_mps2 > lim.max_accel_mps2:
            raise PlatformError(f"Expected an acceleration at most the {spec.name}'s "
                                f"{lim.max_accel_mps2:g} m/s^2, got {accel_mps2:g} m/s^2.")
        lim = Limits(lim.max_speed_mps, accel_mps2, lim.max_jerk_mps3,
                     lim.max_yaw_rate_radps, lim.max_yaw_accel_radps2)
    t, q, psi, dist, grade = _drive(pts, speed_mps, lim, rate_hz)
    fwd = np.column_stack([np.cos(psi), np.sin(psi), np.zeros(len(psi))])
    left = np.column_stack([-fwd[:, 1], fwd[:, 0], np.zeros(len(psi))])
    if spec.motion == "wheeled":
        pos, rot = _wheeled(spec, q, grade, fwd, left, h, scene, rate_hz, follow_grade)
    else:
        assert spec.gait is not None
        pos, rot = _walking(spec.gait, q, t, dist, psi, left, speed_mps, h, scene, rate_hz)
    return Trajectory(start_time + t, pos, rot)


def _legs(pts: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """The path cut at its sharp corners (a turn over ``SHARP_TURN_DEG`` at a vertex: a
    waypoint the route turns back from), each leg with 2 points or more."""
    d = np.diff(pts[:, :2], axis=0)
    keep = np.concatenate([[True], np.linalg.norm(d, axis=1) > 1e-9])
    pts = pts[keep]
    d = np.diff(pts[:, :2], axis=0)
    if len(pts) < 2:
        raise PlatformError("Expected a path of distinct points, got all of them at "
                            "one place in plan.")
    turn = np.abs(np.angle(np.exp(1j * np.diff(np.arctan2(d[:, 1], d[:, 0])))))
    cut = np.flatnonzero(turn > math.radians(SHARP_TURN_DEG)) + 1
    bounds = np.concatenate([[0], cut, [len(pts) - 1]])
    return [pts[a:b + 1] for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def _drive(pts: NDArray[np.float64], speed: float, lim: Limits, rate_hz: float
           ) -> tuple[NDArray[np.float64], ...]:
    """The base's motion along the path: times (k,) from 0 at ``rate_hz``, positions
    (k, 3) on the path, heading (k,), distance driven (k,) and grade dz/ds (k,). Each
    leg (``_legs``) runs from rest to rest; between legs the base turns on the spot."""
    parts: list[tuple[NDArray[np.float64], ...]] = []
    for leg in _legs(pts):
        curve = _Curve(leg)
        t, s = _timed(curve, speed, lim, rate_hz)
        u = curve.u_at(s)
        q, d1 = curve.spline(u), curve.spline(u, 1)
        psi = np.unwrap(np.arctan2(d1[:, 1], d1[:, 0]))
        grade = d1[:, 2] / np.maximum(np.linalg.norm(d1[:, :2], axis=1), 1e-12)
        if parts:
            tp, qp, pp, sp, gp = parts[-1]
            turn = np.angle(np.exp(1j * (psi[0] - pp[-1])))
            psi += pp[-1] + turn - psi[0]
            tt, a = _turn_on_the_spot(turn, lim, rate_hz)
            n = len(tt)
            parts.append((tt, np.repeat(qp[-1:], n, axis=0), pp[-1] + a,
                          np.full(n, sp[-1]), np.linspace(gp[-1], grade[0], n)))
            s = s + sp[-1]
        parts.append((t, q, psi, s, grade))
    t = np.concatenate([p[0] + i / rate_hz for i, p in zip(
        np.cumsum([0] + [len(p[0]) for p in parts[:-1]]), parts)])
    return (t, *(np.concatenate([p[k] for p in parts]) for k in range(1, 5)))


def _turn_on_the_spot(angle: float, lim: Limits, rate_hz: float
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Times (k,) from 0 and the heading change (k,) of a turn by ``angle`` (rad) from
    rest to rest: the yaw acceleration at ``_FIRST_SHARE`` of its limit up to the yaw
    rate's, then braking alike (a trapezoid, triangular for a small turn)."""
    w = _FIRST_SHARE * lim.max_yaw_rate_radps
    al = _FIRST_SHARE * lim.max_yaw_accel_radps2
    big = abs(angle)
    w = min(w, math.sqrt(al * big))
    ta = w / al
    total = 2 * ta + (big - w * ta) / w
    t = np.arange(1, int(np.ceil(total * rate_hz)) + 1) / rate_hz
    a = np.where(t < ta, 0.5 * al * t ** 2,
                 np.where(t < total - ta, 0.5 * al * ta ** 2 + w * (t - ta),
                          big - 0.5 * al * np.maximum(total - t, 0.0) ** 2))
    return t - t[0], math.copysign(1.0, angle) * np.minimum(a, big)


class _Curve:
    """The path as a cubic spline through its points (parameter u: the chord length in
    plan, so that u follows s closely and u(s) can be interpolated linearly), and
    its length in plan s, heading psi, kappa = dpsi/ds and dkappa/ds every ``DS_M``."""

    def __init__(self, pts: NDArray[np.float64]) -> None:
        step = np.linalg.norm(np.diff(pts[:, :2], axis=0), axis=1)
        keep = np.concatenate([[True], step > 1e-6])
        pts = pts[keep]
        if len(pts) < 2:
            raise PlatformError("Expected a path of distinct points, got all of them at "
                                "one place.")
        knots = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts[:, :2], axis=0),
                                                                axis=1))])
        self.spline = CubicSpline(knots, pts, axis=0)
        self.u = np.linspace(0.0, knots[-1], max(3, int(np.ceil(knots[-1] / DS_M)) + 1))
        q = self.spline(self.u)
        d1 = self.spline(self.u, 1)
        # DECISION: s is the distance in plan: the limits bound the base's horizontal
        # motion (what its wheels drive); over a rough floor a 3-D arc length would
        # make the horizontal speed wobble with the floor's slope.
        self.s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q[:, :2], axis=0),
                                                                 axis=1))])
        self.z = q[:, 2]
        psi = np.unwrap(np.arctan2(d1[:, 1], d1[:, 0]))
        self.kappa = np.gradient(psi, self.s)
        self.dkappa = np.gradient(self.kappa, self.s)
        # DECISION: u(s) by a cubic spline, not linear interpolation: a piecewise
        # linear u(s) makes the speed along the path jump at every DS_M sample where
        # the chord parameter runs off the arc length (a sharp bend), and the poses'
        # jerk by finite differences then shows spikes no profile can remove (issue 29).
        self._u_of_s = CubicSpline(self.s, self.u)

    def u_at(self, s: NDArray[np.float64]) -> NDArray[np.float64]:
        """The spline's parameter (k,) at plan distances s (k,) along it."""
        return np.asarray(self._u_of_s(np.clip(s, 0.0, self.s[-1])), dtype=np.float64)


def _timed(curve: _Curve, speed: float, lim: Limits, rate_hz: float
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Times (k,) from 0 at ``rate_hz`` and the distance along the path at each (k,),
    from rest to rest within ``lim``: planned, averaged, checked (module docstring).

    Re-timing, not refusal (issue 29): where the check finds a limit broken, the path
    within the boxcar's reach of that place is driven slower (its speed cap lowered by
    ``_SLOW``), and the profile planned again, as a driver slows through a rough spot;
    after ``_TRIES`` rounds whatever is left is removed by stretching time (speed
    scales by 1/k, acceleration 1/k^2, jerk 1/k^3)."""
    share = _FIRST_SHARE
    width_s = 2.0 * lim.max_accel_mps2 / (SHARES["jerk_boxcar"] * lim.max_jerk_mps3) if \
        math.isfinite(lim.max_jerk_mps3) else 0.0
    w = max(1, int(round(width_s * rate_hz)) | 1)
    slow = np.ones(len(curve.s))
    reach = speed * (w / rate_hz) + 2 * DS_M      # the boxcar's reach along the path
    t = s = first_bad = np.zeros(0)
    for k in range(_TRIES):
        t, s = _profile(curve, speed, lim, share, rate_hz, slow,
                        w / rate_hz if k >= _GLOBAL_TRIES else 0.0)
        pad = w // 2 + 1
        s = np.concatenate([np.zeros(pad), s, np.full(pad, s[-1])])
        s = ndimage.uniform_filter1d(s, w, mode="nearest")
        t = np.arange(len(s)) / rate_hz
        bad = _violation(curve, t, s, speed, lim)
        if not bad.any():
            return t, s
        # DECISION: the first rounds shrink the shares everywhere, as before issue 29
        # (a smooth path that needed it keeps its timing); then, from the first plan's
        # shares again, the path slows down only near the places that broke a limit.
        if k == 0:
            first_bad = s[bad]
        if k < _GLOBAL_TRIES - 1:
            share *= _SHRINK
            continue
        if k == _GLOBAL_TRIES - 1:
            share, s_bad = _FIRST_SHARE, first_bad
        else:
            s_bad = s[bad]
        # The boxcar mixes the speeds of its width around each sample: slow down the
        # path that it reaches at the speed driven there now.
        v = np.abs(np.gradient(s, t))
        near = np.zeros(len(curve.s), dtype=np.bool_)
        for lo, hi in _runs(s_bad):
            here = (s >= lo - reach) & (s <= hi + reach)
            r = float(v[here].max()) * (w / rate_hz) + 2 * DS_M
            near |= (curve.s >= lo - r) & (curve.s <= hi + r)
        slow[near] *= _SLOW
    return _stretched(curve, t, s, speed, lim, rate_hz)


def _runs(x: NDArray[np.float64]) -> list[tuple[float, float]]:
    """Sorted values x grouped into runs (lo, hi) with gaps under ``4 DS_M``."""
    x = np.sort(x)
    cut = np.flatnonzero(np.diff(x) > 4 * DS_M) + 1
    return [(float(g[0]), float(g[-1])) for g in np.split(x, cut) if len(g)]


def _stretched(curve: _Curve, t: NDArray[np.float64], s: NDArray[np.float64],
               speed: float, lim: Limits, rate_hz: float
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The motion s(t) slowed down uniformly, s(t / k) with the smallest k (a few
    tries) that brings every limit within bounds: speed scales by 1/k, acceleration
    and yaw acceleration by 1/k^2, jerk by 1/k^3."""
    u = curve.u_at(s)
    p, d1 = curve.spline(u)[:, :2], curve.spline(u, 1)
    psi = np.unwrap(np.arctan2(d1[:, 1], d1[:, 0]))
    v, a, j, wr, wa = _rates(t, p, psi)
    k = max(1.0, v / speed, math.sqrt(a / lim.max_accel_mps2),
            (j / lim.max_jerk_mps3) ** (1 / 3), wr / lim.max_yaw_rate_radps,
            math.sqrt(wa / lim.max_yaw_accel_radps2))
    for _ in range(_TRIES):
        k *= 1.02
        tk = np.arange(int(np.ceil(t[-1] * k * rate_hz)) + 1) / rate_hz
        sk = np.interp(tk / k, t, s)
        sk[-1] = s[-1]
        bad = _violation(curve, tk, sk, speed, lim)
        if not bad.any():
            return tk, sk
    i = int(np.flatnonzero(bad)[0])
    where = curve.spline(curve.u_at(sk[i:i + 1]))[0]
    raise PlatformError(f"Expected a motion within the platform's limits, got none at "
                        f"({where[0]:.6g}, {where[1]:.6g}) even {k:.3g} times slower; "
                        "the path turns too sharply there: pass --waypoints to avoid it.")


def _profile(curve: _Curve, speed: float, lim: Limits, c: float, rate_hz: float,
             slow: NDArray[np.float64] | None = None, hold_s: float = 0.0
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The fastest x = v^2 under the caps (``SHARES`` x ``c`` of the limits, times
    ``slow`` (per path sample) where the motion must slow down), sampled at
    ``rate_hz``: times and distances (constant acceleration between path samples).
    With ``hold_s``, each cap holds over the distance driven at its speed in
    ``hold_s`` either side (``_hold``)."""
    k, dk, s = np.abs(curve.kappa), np.abs(curve.dkappa), curve.s
    a_max, yaw_acc = lim.max_accel_mps2 * c, lim.max_yaw_accel_radps2 * c
    jerk = lim.max_jerk_mps3 * c
    # A straight stretch (kappa 0 or ~1e-160) makes its caps infinite: divisions by
    # zero and squares that overflow to inf are the intended "no cap" there.
    with np.errstate(divide="ignore", over="ignore"):
        x_cap = np.minimum.reduce([
            np.full(len(s), speed ** 2), (c * lim.max_yaw_rate_radps / k) ** 2,
            SHARES["lateral"] * a_max / k, SHARES["yaw_speed"] * yaw_acc / dk,
            (SHARES["jerk_turn"] * jerk / k ** 2) ** (2 / 3),
            (SHARES["jerk_bend"] * jerk / dk) ** (2 / 3)])
        a_cap = np.minimum(SHARES["along"] * a_max, SHARES["yaw_turn"] * yaw_acc / k)
        a_jerk = SHARES["jerk_accel"] * jerk / (3.0 * k)         # / v: 3 v a kappa
    if slow is not None:
        x_cap = x_cap * slow
    x_cap = np.maximum(x_cap, _X_FLOOR)
    if hold_s > 0:
        x_cap = _hold(x_cap, s, hold_s, speed ** 2)
    x_cap[[0, -1]] = 0.0
    a_seg = np.minimum(a_cap[:-1], a_cap[1:])
    aj_seg = np.minimum(a_jerk[:-1], a_jerk[1:])
    ds = np.diff(s)
    x = x_cap.copy()
    # a <= a_jerk / v at both ends of a step, with v the faster end's: the step's
    # largest v^2 is its end's (forward) or start's (backward).
    for i in range(len(x) - 1):                                   # forward: speed up
        x[i + 1] = min(x[i + 1], x[i] + 2.0 * ds[i] * a_seg[i])
        top = math.sqrt(x[i + 1])
        if top > 0 and x[i + 1] > x[i] + 2.0 * ds[i] * aj_seg[i] / top:
            x[i + 1] = _step_with_jerk(x[i], 2.0 * ds[i] * aj_seg[i])
    for i in range(len(x) - 2, -1, -1):                           # backward: brake
        x[i] = min(x[i], x[i + 1] + 2.0 * ds[i] * a_seg[i])
        top = math.sqrt(x[i])
        if top > 0 and x[i] > x[i + 1] + 2.0 * ds[i] * aj_seg[i] / top:
            x[i] = _step_with_jerk(x[i + 1], 2.0 * ds[i] * aj_seg[i])
    v = np.sqrt(x)
    dt = 2.0 * ds / np.maximum(v[:-1] + v[1:], 1e-12)
    t_knot = np.concatenate([[0.0], np.cumsum(dt)])
    acc = (x[1:] - x[:-1]) / (2.0 * ds)
    t = np.arange(int(np.ceil(t_knot[-1] * rate_hz)) + 1) / rate_hz
    k = np.clip(np.searchsorted(t_knot, t, side="right") - 1, 0, len(ds) - 1)
    tau = np.minimum(t - t_knot[k], dt[k])
    out = np.minimum(s[k] + v[k] * tau + 0.5 * acc[k] * tau ** 2, s[k + 1])
    out[-1] = s[-1]
    return t, np.maximum.accumulate(out)


def _hold(x_cap: NDArray[np.float64], s: NDArray[np.float64], hold_s: float,
          top: float) -> NDArray[np.float64]:
    """Caps x_cap (n,) on v^2 at path samples s (n,) each held over s_i +- v_i hold_s
    (v_i = sqrt(x_cap_i)): where the boxcar of ``hold_s`` seconds averages the
    distance driven, the speed is then constant across a sharp bend, and the averaged
    motion passes it at the capped speed (a constant-speed motion is its own boxcar
    average). Lowest caps first; caps at ``top`` (the cruise) need no hold."""
    out = x_cap.copy()
    for i in np.argsort(x_cap):
        if x_cap[i] >= top:
            break
        r = math.sqrt(x_cap[i]) * hold_s + DS_M
        a, b = np.searchsorted(s, [s[i] - r, s[i] + r])
        np.minimum(out[a:b + 1], x_cap[i], out=out[a:b + 1])
    return out


def _step_with_jerk(x0: float, b: float) -> float:
    """The largest x1 >= x0 with x1 - x0 <= b / sqrt(x1) (a step's speed-up bounded by
    3 v a kappa): x1 is the root of sqrt(x1) (x1 - x0) = b, by Newton's method from
    an upper bound (the function is convex and increasing there)."""
    x1 = x0 + b ** (2 / 3) + b / max(math.sqrt(x0), 1e-12) if x0 > 0 else b ** (2 / 3)
    for _ in range(30):
        r = math.sqrt(x1)
        f = r * (x1 - x0) - b
        if abs(f) <= 1e-12 * max(b, 1e-12):
            break
        x1 -= f / (1.5 * r - 0.5 * x0 / r)
    return max(x0, x1)


def _violation(curve: _Curve, t: NDArray[np.float64], s: NDArray[np.float64],
               speed: float, lim: Limits) -> NDArray[np.bool_]:
    """The samples (k,) bool near which the sampled motion breaks a limit, by finite
    differences of the plan position and heading, as a user differentiating the poses
    would (each difference marks the samples it spans)."""
    u = curve.u_at(s)
    p, d1 = curve.spline(u)[:, :2], curve.spline(u, 1)
    psi = np.unwrap(np.arctan2(d1[:, 1], d1[:, 0]))
    bad = np.zeros(len(t), dtype=np.bool_)
    if len(t) < 4:
        return bad
    tol = 1 + 1e-4      # the spline's chord parameter vs its arc length
    for order, x, top in _differences(t, p, psi, speed, lim):
        over = np.flatnonzero(x > top * tol)
        for d in range(order + 1):
            bad[over + d] = True
    return bad


def _differences(t: NDArray[np.float64], p: NDArray[np.float64], psi: NDArray[np.float64],
                 speed: float, lim: Limits
                 ) -> list[tuple[int, NDArray[np.float64], float]]:
    """(order, magnitude per difference, limit) of the speed, acceleration, jerk, yaw
    rate and yaw acceleration by differences of the samples (``_rates``' formulas)."""
    v, a, j, w, al = _finite_differences(t, p, psi)
    return [(1, v, speed), (2, a, lim.max_accel_mps2), (3, j, lim.max_jerk_mps3),
            (1, w, lim.max_yaw_rate_radps), (2, al, lim.max_yaw_accel_radps2)]


def _finite_differences(t: NDArray[np.float64], p: NDArray[np.float64],
                        psi: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """|speed|, |acceleration|, |jerk| of positions p (k, d) and |yaw rate|, |yaw
    acceleration| of headings psi (k,), by differences of the samples (each one
    shorter than the last)."""
    dt = np.diff(t)
    v = np.diff(p, axis=0) / dt[:, None]
    a = np.diff(v, axis=0) / (0.5 * (dt[1:] + dt[:-1]))[:, None]
    j = np.diff(a, axis=0) / dt[1:-1, None]
    w = np.diff(psi) / dt
    al = np.diff(w) / (0.5 * (dt[1:] + dt[:-1]))
    n = np.linalg.norm
    return n(v, axis=1), n(a, axis=1), n(j, axis=1), np.abs(w), np.abs(al)


def _rates(t: NDArray[np.float64], p: NDArray[np.float64], psi: NDArray[np.float64]
           ) -> tuple[float, float, float, float, float]:
    """Largest speed, acceleration, jerk (of positions p (k, d)), yaw rate and yaw
    acceleration (of headings psi (k,)) by central differences on the samples."""
    if len(t) < 4:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    v, a, j, w, al = (float(x.max()) for x in _finite_differences(t, p, psi))
    return v, a, j, w, al


def _floor_z(scene: Any, xy: NDArray[np.float64], z_from: NDArray[np.float64],
             z_hint: NDArray[np.float64], reach_m: float) -> NDArray[np.float64]:
    """Floor height under points xy (n, 2), by rays cast down from heights z_from (n,)
    (the path's, inside the passage) over ``reach_m``; where none hits (a hole, beyond
    a portal), z_hint (n,)."""
    org = np.column_stack([xy, z_from])
    t = scene.cast(org, [0.0, 0.0, -1.0], t_max=reach_m).t
    return np.where(np.isfinite(t), org[:, 2] - t, z_hint)


def _reach(h: float) -> float:
    return 2.0 * h + _CAST_EXTRA_M


def _wheeled(spec: PlatformSpec, q: NDArray[np.float64], grade: NDArray[np.float64],
             fwd: NDArray[np.float64], left: NDArray[np.float64], h: float, scene: Any,
             rate_hz: float, follow_grade: bool) -> tuple[NDArray[np.float64], Rotation]:
    """Mast-top positions (k, 3) and attitudes of a wheeled base on the floor under
    its four wheels (front left, front right, rear left, rear right)."""
    a, b = 0.5 * spec.wheelbase_m, 0.5 * spec.track_m
    sign = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=np.float64)
    if scene is None:           # the path's own floor, its grade: no roll
        zf = (q[:, 2] - h)[:, None] + sign[None, :, 0] * a * grade[:, None]
    else:
        xy = (q[:, None, :2] + sign[None, :, :1] * a * fwd[:, None, :2]
              + sign[None, :, 1:] * b * left[:, None, :2])
        zf = _floor_z(scene, xy.reshape(-1, 2), np.repeat(q[:, 2], 4),
                      np.repeat(q[:, 2] - h, 4), _reach(h)).reshape(-1, 4)
    # Least-squares plane through the four contacts (a rectangle): its height at the
    # centre, its slope forward and to the left.
    z0 = zf.mean(axis=1)
    g_fwd = ((zf[:, 0] + zf[:, 1]) - (zf[:, 2] + zf[:, 3])) / (4 * a)
    g_left = ((zf[:, 0] + zf[:, 2]) - (zf[:, 1] + zf[:, 3])) / (4 * b) if b > 0 else 0 * z0
    sig = RIDE_SIGMA_S * rate_hz
    z0, g_fwd, g_left = (ndimage.gaussian_filter1d(x, sig, mode="nearest")
                         for x in (z0, g_fwd, g_left))
    if not follow_grade:
        g_fwd, g_left = 0 * g_fwd, 0 * g_left
    grad = g_fwd[:, None] * fwd + g_left[:, None] * left       # world dz/dx, dz/dy
    zb = np.column_stack([-grad[:, 0], -grad[:, 1], np.ones(len(q))])
    zb /= np.linalg.norm(zb, axis=1)[:, None]
    xb = fwd - np.einsum("ij,ij->i", fwd, zb)[:, None] * zb
    xb /= np.linalg.norm(xb, axis=1)[:, None]
    rot = Rotation.from_matrix(np.stack([xb, np.cross(zb, xb), zb], axis=2))
    base = np.column_stack([q[:, :2], z0])
    return base + h * zb, rot


def _walking(gait: Gait, q: NDArray[np.float64], t: NDArray[np.float64],
             s: NDArray[np.float64], psi: NDArray[np.float64], left: NDArray[np.float64],
             speed: float, h: float, scene: Any, rate_hz: float
             ) -> tuple[NDArray[np.float64], Rotation]:
    """Sensor positions (k, 3) and attitudes of a walker: level, ``h`` above the floor
    under the walker, with the gait's bob (step frequency) and sway (stride frequency)
    scaled by speed / cruising speed (0 at rest)."""
    zf = q[:, 2] - h
    if scene is not None:
        zf = ndimage.gaussian_filter1d(_floor_z(scene, q[:, :2], q[:, 2], zf, _reach(h)),
                                       RIDE_SIGMA_S * rate_hz, mode="nearest")
    v = np.gradient(s, t)
    env = np.clip(v / speed, 0.0, 1.0)
    step = 2 * np.pi * gait.step_hz * t
    bob = 0.5 * gait.bob_m * env * np.sin(step)
    sway = 0.5 * gait.sway_m * env * np.sin(0.5 * step)
    pos = np.column_stack([q[:, :2], zf + h + bob]) + sway[:, None] * left
    # DECISION: the body rolls toward the stance side (with the sway) and pitches with
    # the bob; zero at rest like the sway, so a still walker is a still sensor.
    roll = gait.roll_rad * env * np.sin(0.5 * step)
    pitch = gait.pitch_rad * env * np.sin(step)
    return pos, Rotation.from_euler("ZYX", np.column_stack([psi, pitch, roll]))


def _static(pts: NDArray[np.float64], h: float, scene: Any, t: float) -> Trajectory:
    """A tripod at the path's first point, ``h`` above the floor there, level, facing
    along the path."""
    d = pts[1] - pts[0]
    p = pts[0].copy()
    if scene is not None:
        p[2] = _floor_z(scene, p[None, :2], p[None, 2], p[None, 2] - h, _reach(h))[0] + h
    return Trajectory.static(p, Rotation.from_euler("z", math.atan2(d[1], d[0])), t=t)
