"""Trajectory errors of an odometry/SLAM estimate against the true trajectory, with
evo's definitions (Grupp 2017, github.com/MichaelGrupp/evo; the tests compare every
figure with evo 1.38 on the same data).

Steps:

1. **Association by interpolation.** The truth is continuous (a simulated drive sampled
   at e.g. 100 Hz), the estimate comes at the LiDAR frame rate (~10 Hz): the truth is
   *interpolated* at the estimate's times (``Trajectory.interpolate``: positions
   linearly, attitudes by SLERP), not matched to the nearest timestamp. Estimate poses
   outside the truth's time span are dropped and counted (``n_dropped``).
2. **Alignment** of the estimate onto the truth: ``"origin"`` (evo ``align_origin``:
   the rigid motion that puts the estimate's first pose on the truth's pose at that
   time; what an odometry that starts from a known pose sees), ``"none"`` (same frame
   already), ``"se3"`` / ``"sim3"`` (Umeyama 1991 least squares on the positions,
   without / with scale; evo ``align(correct_scale=...)``).
3. **ATE** (absolute trajectory error, evo APE w.r.t. the translation part): per pose
   |p_est - p_true|; RMS, mean, median, max. The final error, also as % of the path
   travelled (the truth's path over the evaluated span, along its own samples) and
   split along the direction of travel / lateral / vertical in the local frame of the
   truth's heading (the horizontal projection of the body x axis; vertical is world z).
4. **RPE** (relative pose error, Sturm et al. 2012, evo RPE with ``delta_unit=meters``,
   ``all_pairs=False``): pose pairs (i, j) chosen along the path: starting at i = 0, the
   path length is accumulated pose to pose and j is the first pose where it reaches
   ``delta`` (>=); the accumulator then restarts at j, which becomes the next i (evo
   ``filters.filter_pairs_by_path``). For each pair the relative error pose
   E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j) (Q truth, P aligned estimate, as 4x4 SE(3)); the
   translation error is |t(E)|, the rotation error the angle of R(E). The path is the
   estimate's by default (evo's ``pairs_from_reference=False``).

A delta longer than the path gives no pair: its figures are NaN (evo raises instead).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from sensors.trajectory import Trajectory
from survey.errors import CompareError

__all__ = ["ALIGNMENTS", "RelativeError", "TrajectoryErrors", "align_origin",
           "path_pairs", "trajectory_errors"]

#: Alignments ``trajectory_errors`` knows.
ALIGNMENTS = ("origin", "none", "se3", "sim3")
#: Relative tolerance of "within the truth's time span", as ``Trajectory.interpolate``.
TIME_RTOL = 1e-9
#: Smallest ratio of the second to the first singular value of the position covariance
#: that the Umeyama alignment accepts (a straight line leaves the roll about it free).
UMEYAMA_RANK_RTOL = 1e-12

Align = Literal["origin", "none", "se3", "sim3"]


@dataclass(frozen=True)
class RelativeError:
    """RPE figures for one path delta.

    ``n_pairs`` is 0 (and every figure NaN) when the path is shorter than
    ``delta_m``. ``mean_pct`` is ``mean_m`` as % of ``delta_m``.
    """

    delta_m: float
    n_pairs: int
    rms_m: float
    mean_m: float
    median_m: float
    max_m: float
    mean_pct: float
    rot_rms_rad: float
    rot_mean_rad: float
    rot_max_rad: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready figures (NaN becomes None, i.e. null)."""
        return {k: _json(v) for k, v in self.__dict__.items()}


@dataclass(frozen=True, eq=False)
class TrajectoryErrors:
    """Errors of an estimate against the truth (see the module doc for definitions).

    Scalars: ``align`` and ``pairs_from`` (as asked); ``n_poses`` evaluated and
    ``n_dropped`` (estimate poses outside the truth's span); ``start_s``, ``end_s``;
    ``path_length_m`` (truth path over the span); ``ate_*_m``; ``final_error_m``,
    ``final_error_pct`` (% of the path length), ``final_error_along_m``,
    ``final_error_lateral_m`` (left positive), ``final_error_vertical_m`` (up
    positive), signed, estimate minus truth; ``final_rotation_error_rad``;
    ``alignment_scale`` (1 except for sim3); ``relative``: one ``RelativeError`` per
    delta.

    Arrays, one row per evaluated pose: ``times_s`` (n,) float64; ``distance_m`` (n,)
    float64, truth path travelled since the first pose; ``error_m`` (n, 3) float64,
    aligned estimate minus truth, world axes; ``error_along_m``, ``error_lateral_m``,
    ``error_vertical_m`` (n,) float64, the same in the local heading frame of each pose.
    ``alignment_matrix`` (4, 4) float64: world estimate -> world truth,
    x' = A[:3, :3] x + A[:3, 3] (A[:3, :3] = scale * rotation).
    """

    align: str
    pairs_from: str
    n_poses: int
    n_dropped: int
    start_s: float
    end_s: float
    path_length_m: float
    ate_rms_m: float
    ate_mean_m: float
    ate_median_m: float
    ate_max_m: float
    final_error_m: float
    final_error_pct: float
    final_error_along_m: float
    final_error_lateral_m: float
    final_error_vertical_m: float
    final_rotation_error_rad: float
    alignment_scale: float
    relative: tuple[RelativeError, ...]
    times_s: NDArray[np.float64]
    distance_m: NDArray[np.float64]
    error_m: NDArray[np.float64]
    error_along_m: NDArray[np.float64]
    error_lateral_m: NDArray[np.float64]
    error_vertical_m: NDArray[np.float64]
    alignment_matrix: NDArray[np.float64]

    @property
    def ate_m(self) -> NDArray[np.float64]:
        """(n,) float64 per-pose translation error ``|error_m|`` (m)."""
        return np.asarray(np.linalg.norm(self.error_m, axis=1))

    def rpe(self, delta_m: float) -> RelativeError:
        """The ``RelativeError`` of ``delta_m``."""
        for r in self.relative:
            if r.delta_m == delta_m:
                return r
        raise CompareError(f"Expected one of the evaluated deltas "
                           f"{[r.delta_m for r in self.relative]} m, got {delta_m!r}.")

    def to_dict(self) -> dict[str, Any]:
        """The scalar figures, JSON-ready (units in the key names; NaN becomes None).
        The per-pose arrays are left out."""
        arrays = {"relative", "times_s", "distance_m", "error_m", "error_along_m",
                  "error_lateral_m", "error_vertical_m", "alignment_matrix"}
        out = {k: _json(v) for k, v in self.__dict__.items() if k not in arrays}
        out["rpe"] = [r.to_dict() for r in self.relative]
        return out

    def __repr__(self) -> str:
        rpe = ", ".join(f"RPE/{r.delta_m:g} m {r.mean_pct:.2f} %" for r in self.relative)
        return (f"TrajectoryErrors({self.n_poses} poses, {self.path_length_m:.1f} m, "
                f"align={self.align}, ATE RMS {self.ate_rms_m:.3f} m, max "
                f"{self.ate_max_m:.3f} m, final {self.final_error_m:.3f} m "
                f"({self.final_error_pct:.2f} %)" + (f", {rpe}" if rpe else "") + ")")


def _json(v: Any) -> Any:
    if isinstance(v, (bool, str)) or v is None:
        return v
    if isinstance(v, (int, np.integer)):
        return int(v)
    f = float(v)
    return None if math.isnan(f) else f


# ---------------------------------------------------------------------- association
def _check(traj: Any, name: str) -> Trajectory:
    if not isinstance(traj, Trajectory):
        raise CompareError(f"Expected `{name}` as a sensors.Trajectory, got "
                           f"{type(traj).__name__}; build one with Trajectory(times, "
                           "positions, rotations) or Trajectory.read(path).")
    return traj


def _common(estimate: Any, truth: Any) -> tuple[Trajectory, Trajectory,
                                                NDArray[np.bool_]]:
    """Both trajectories checked, and the mask of estimate poses within the truth's
    time span (at least 2)."""
    est, tru = _check(estimate, "estimate"), _check(truth, "truth")
    if len(tru) < 2:
        raise CompareError(f"Expected a truth trajectory of at least 2 poses to "
                           f"interpolate, got {len(tru)}.")
    lo, hi = tru.start_s, tru.end_s
    eps = TIME_RTOL * max(1.0, abs(hi))
    inside = (est.times >= lo - eps) & (est.times <= hi + eps)
    k = int(inside.sum())
    if k == 0:
        raise CompareError(f"Expected the estimate's times [{est.start_s}, {est.end_s}] s "
                           f"to overlap the truth's [{lo}, {hi}] s, got no common time; "
                           "check that both use the same clock.")
    if k < 2:
        raise CompareError(f"Expected at least 2 estimate poses within the truth's time "
                           f"span [{lo}, {hi}] s, got {k}; check the clocks or give a "
                           "longer truth.")
    return est, tru, inside


def _clip_times(t: NDArray[np.float64], truth: Trajectory) -> NDArray[np.float64]:
    return np.clip(t, truth.start_s, truth.end_s)


# ---------------------------------------------------------------------- alignment
def _umeyama(x: NDArray[np.float64], y: NDArray[np.float64], with_scale: bool
             ) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares similarity y ~ c R x + t of two (n, 3) point sets: (c, R, t).
    Umeyama 1991, eqs. 34-43 (means, variance, SVD of the covariance, sign fix)."""
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    var_x = float(np.sum(xc * xc)) / len(x)                    # eq. 36
    cov = yc.T @ xc / len(x)                                   # eq. 38, Sigma_xy
    u, d, vt = np.linalg.svd(cov)
    if not d[0] > 0 or d[1] <= UMEYAMA_RANK_RTOL * d[0]:
        raise CompareError("Expected estimate positions spread in at least 2 directions "
                           "for a Umeyama (se3/sim3) alignment, got a degenerate "
                           "covariance (a straight line or a point); use align='origin'.")
    s = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:               # eq. 43: a rotation
        s[2] = -1.0
    r = (u * s) @ vt                                           # eq. 40
    c = float(np.sum(d * s)) / var_x if with_scale else 1.0    # eq. 42
    t = my - c * r @ mx                                        # eq. 41
    return c, r, t


def _alignment(align: str, p: NDArray[np.float64], rp: Rotation, q: NDArray[np.float64],
               rq: Rotation) -> tuple[float, Rotation, NDArray[np.float64]]:
    """(scale, rotation, translation) taking the estimate (p, rp) onto the truth (q, rq),
    both in the same local frame."""
    if align == "origin":
        # evo align_origin: T = Q_0 P_0^-1, applied on the left of every pose.
        r = rq[0] * rp[0].inv()
        return 1.0, r, q[0] - r.apply(p[0])
    if align == "none":
        return 1.0, Rotation.identity(), np.zeros(3)
    c, rm, t = _umeyama(p, q, align == "sim3")
    return c, Rotation.from_matrix(rm), t


def align_origin(estimate: Trajectory, truth: Trajectory) -> Trajectory:
    """The estimate moved rigidly so that its first pose within the truth's time span
    equals the truth's pose (interpolated) at that time (evo ``align_origin``).

    Parameters
    ----------
    estimate, truth : Trajectory
        The truth needs at least 2 poses; at least 2 estimate poses must lie within its
        time span.

    Returns
    -------
    Trajectory
        Every pose of the estimate (also those outside the truth's span), moved.

    Raises
    ------
    CompareError
        For arguments that are not trajectories or time spans that do not overlap.
    """
    est, tru, inside = _common(estimate, truth)
    i0 = int(np.argmax(inside))
    o = tru.origin
    q0, rq0 = tru.interpolate(_clip_times(est.times[i0:i0 + 1], tru), local=True)
    p = est.positions - o
    r = rq0[0] * est.rotations[i0].inv()
    t = q0[0] - r.apply(p[i0])
    return Trajectory(est.times, r.apply(p) + t + o, r * est.rotations)


# ---------------------------------------------------------------------- RPE
def path_pairs(positions: ArrayLike, delta_m: float) -> NDArray[np.int64]:
    """Consecutive pose pairs separated by ``delta_m`` of path (evo
    ``filter_pairs_by_path``, ``all_pairs=False``).

    Parameters
    ----------
    positions : (n, 3) array_like of float
        Positions along the path (m).
    delta_m : float
        Path length between the poses of a pair (m), > 0.

    Returns
    -------
    (k, 2) int64
        Index pairs (i, j), i < j; j of one pair is i of the next. Empty when the path
        is shorter than ``delta_m``.
    """
    p = np.asarray(positions, dtype=np.float64)
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    ids = [0]
    acc = 0.0
    # DECISION: a plain accumulate-and-reset loop rather than searchsorted on a cumulative
    # sum: the pair choice is then the same float arithmetic as evo's (a cumsum
    # difference rounds differently and can move a pair by one pose at a tie).
    for j, d in enumerate(seg.tolist(), start=1):
        acc += d
        if acc >= delta_m:
            ids.append(j)
            acc = 0.0
    a = np.asarray(ids, dtype=np.int64)
    return np.stack([a[:-1], a[1:]], axis=1)


def _relative(delta_m: float, pairs: NDArray[np.int64], p: NDArray[np.float64],
              rp: Rotation, q: NDArray[np.float64], rq: Rotation) -> RelativeError:
    if len(pairs) == 0:
        nan = float("nan")
        return RelativeError(delta_m, 0, nan, nan, nan, nan, nan, nan, nan, nan)
    i, j = pairs[:, 0], pairs[:, 1]
    # Sturm et al. 2012, eq. 1: E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j). Its translation is
    # R(Q_rel)^T (t(P_rel) - t(Q_rel)); the rotation keeps the norm, so
    # |t(E)| = |t(P_rel) - t(Q_rel)| with t(X_rel) = R_i^T (x_j - x_i).
    tp = rp[i].inv().apply(p[j] - p[i])
    tq = rq[i].inv().apply(q[j] - q[i])
    e = np.linalg.norm(tp - tq, axis=1)
    ang = ((rq[i].inv() * rq[j]).inv() * (rp[i].inv() * rp[j])).magnitude()
    mean = float(np.mean(e))
    return RelativeError(
        delta_m=delta_m, n_pairs=len(pairs), rms_m=float(np.sqrt(np.mean(e * e))),
        mean_m=mean, median_m=float(np.median(e)), max_m=float(np.max(e)),
        mean_pct=100.0 * mean / delta_m, rot_rms_rad=float(np.sqrt(np.mean(ang * ang))),
        rot_mean_rad=float(np.mean(ang)), rot_max_rad=float(np.max(ang)))


# ---------------------------------------------------------------------- errors
def _deltas(deltas_m: Any) -> tuple[float, ...]:
    try:
        d = np.atleast_1d(np.asarray(deltas_m, dtype=np.float64))
    except (TypeError, ValueError):
        d = np.array([np.nan])
    if d.ndim != 1 or not (np.isfinite(d) & (d > 0)).all():
        raise CompareError(f"Expected `deltas_m` as positive path lengths (m), got "
                           f"{deltas_m!r}.")
    return tuple(float(x) for x in d)


def _heading_frame(rot: Rotation) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unit along-track and left-lateral horizontal axes (n, 3) of body rotations."""
    x = rot.apply([1.0, 0.0, 0.0])
    h = x[:, :2].copy()
    n = np.linalg.norm(h, axis=1)
    # ASSUMED: a body x axis pointing straight up or down has no heading; world x then.
    flat = n < 1e-9
    h[flat] = (1.0, 0.0)
    n[flat] = 1.0
    h /= n[:, None]
    zero = np.zeros(len(h))
    along = np.stack([h[:, 0], h[:, 1], zero], axis=1)
    lateral = np.stack([-h[:, 1], h[:, 0], zero], axis=1)     # z x along: left
    return along, lateral


def trajectory_errors(estimate: Trajectory, truth: Trajectory, *,
                      deltas_m: ArrayLike = (10.0, 100.0), align: Align = "origin",
                      pairs_from: Literal["estimate", "truth"] = "estimate"
                      ) -> TrajectoryErrors:
    """ATE and RPE of an estimated trajectory against the truth, as evo computes them.

    Parameters
    ----------
    estimate : Trajectory
        The odometry / SLAM output (e.g. one pose per LiDAR frame).
    truth : Trajectory
        The true trajectory, at least 2 poses, interpolated at the estimate's times.
    deltas_m : sequence of float
        Path lengths of the RPE (m), each > 0; default 10 m and 100 m.
    align : {"origin", "none", "se3", "sim3"}
        How the estimate is put onto the truth before the errors (module doc).
    pairs_from : {"estimate", "truth"}
        Whose path length selects the RPE pairs (evo: ``pairs_from_reference``).

    Returns
    -------
    TrajectoryErrors

    Raises
    ------
    CompareError
        For arguments that are not trajectories, fewer than 2 estimate poses within the
        truth's time span, an unknown ``align`` or ``pairs_from``, deltas that are not
        positive, or a degenerate (straight-line) path for the se3/sim3 alignment.
    """
    if align not in ALIGNMENTS:
        raise CompareError(f"Expected `align` one of {', '.join(map(repr, ALIGNMENTS))}, "
                           f"got {align!r}.")
    if pairs_from not in ("estimate", "truth"):
        raise CompareError(f"Expected `pairs_from` 'estimate' or 'truth', got "
                           f"{pairs_from!r}.")
    deltas = _deltas(deltas_m)
    est, tru, inside = _common(estimate, truth)
    t = est.times[inside]
    tc = _clip_times(t, tru)
    # DECISION: all arithmetic relative to the truth's local origin, so that UTM-sized
    # coordinates keep sub-nanometre precision through the alignment.
    o = tru.origin
    q, rq = tru.interpolate(tc, local=True)
    p0 = est.positions[inside] - o
    rp0 = est.rotations[np.flatnonzero(inside)]
    c, ra, ta = _alignment(align, p0, rp0, q, rq)
    p = c * ra.apply(p0) + ta
    rp = ra * rp0
    err = p - q
    ate = np.linalg.norm(err, axis=1)

    # Truth path: piecewise linear in time between its own samples, so the cumulative
    # length interpolated at t is exact (not the chord between 10 Hz estimate poses).
    tp = tru.positions - o
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(tp, axis=0), axis=1))])
    s = np.interp(tc, tru.times, cum)
    dist = s - s[0]
    length = float(dist[-1])

    along, lateral = _heading_frame(rq)
    e_along = np.einsum("ij,ij->i", err, along)
    e_lat = np.einsum("ij,ij->i", err, lateral)
    e_vert = err[:, 2].copy()

    pair_pos = p if pairs_from == "estimate" else q
    relative = tuple(_relative(d, path_pairs(pair_pos, d), p, rp, q, rq) for d in deltas)

    mat = np.eye(4)
    mat[:3, :3] = c * ra.as_matrix()
    mat[:3, 3] = o + ta - mat[:3, :3] @ o
    final = float(ate[-1])
    return TrajectoryErrors(
        align=align, pairs_from=pairs_from, n_poses=len(t), n_dropped=int((~inside).sum()),
        start_s=float(t[0]), end_s=float(t[-1]), path_length_m=length,
        ate_rms_m=float(np.sqrt(np.mean(ate * ate))), ate_mean_m=float(np.mean(ate)),
        ate_median_m=float(np.median(ate)), ate_max_m=float(np.max(ate)),
        final_error_m=final,
        final_error_pct=100.0 * final / length if length > 0 else float("nan"),
        final_error_along_m=float(e_along[-1]), final_error_lateral_m=float(e_lat[-1]),
        final_error_vertical_m=float(e_vert[-1]),
        final_rotation_error_rad=float((rq[-1].inv() * rp[-1]).magnitude()),
        alignment_scale=float(c), relative=relative, times_s=t.copy(), distance_m=dist,
        error_m=err, error_along_m=e_along, error_lateral_m=e_lat, error_vertical_m=e_vert,
        alignment_matrix=mat)
