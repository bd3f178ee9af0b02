"""Simulated SLAM drift for mobile-mapping studies.

A SLAM trajectory drifts because small errors of its attitude integrate into position
error (no GNSS underground). Model, per axis (roll, pitch, heading), in the distance
travelled s: an attitude error e(s) = angle random walk (white noise on the angle,
``*_rw`` rad per sqrt(m)) + the integral of a bias that itself walks randomly
(``*_bias_rw`` rad per m per sqrt(m)) - the two terms of the usual gyro/odometry error
model (IEEE Std 952 names them angle random walk and rate random walk). The SLAM
position integrates the true displacement rotated by the current attitude error:

    R_slam(t) = R_e(t) R_true(t),  p_slam[k+1] = p_slam[k] + R_e[k] (p_true[k+1] - p_true[k])

With the defaults the drift reaches ~0.3-1 m over 300 m and is smooth over tens of
metres, as SLAM drift in a feature-poor gallery is. The map the SLAM system builds
places a world point x seen at time t at x_slam = p_slam(t) + R_e(t) (x - p_true(t)).
ASSUMED values: no published drift spectrum for the seed study's sensors was at hand.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from sensors import Trajectory
from sensors.trajectory import Mount


def slam_trajectory(true: Trajectory, *, heading_rw: float = 2e-5, pitch_rw: float = 1e-5,
                    roll_rw: float = 1e-5, heading_bias_rw: float = 1.5e-6,
                    pitch_bias_rw: float = 0.5e-6, roll_bias_rw: float = 0.3e-6,
                    seed: int = 0) -> Trajectory:
    """The drifting SLAM estimate of a true trajectory (same times)."""
    rng = np.random.default_rng(seed)
    p = true.positions
    ds = np.linalg.norm(np.diff(p, axis=0), axis=1)
    sq = np.sqrt(ds)[:, None]
    arw = rng.standard_normal((len(ds), 3)) * sq * np.array([roll_rw, pitch_rw, heading_rw])
    bias = np.cumsum(rng.standard_normal((len(ds), 3)) * sq *
                     np.array([roll_bias_rw, pitch_bias_rw, heading_bias_rw]), axis=0)
    steps = arw + bias * ds[:, None]
    e = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
    # Error rotation in world axes: roll about x, pitch about y, heading about z.
    re = Rotation.from_rotvec(e)
    inc = np.diff(p - p[0], axis=0)
    ps = np.vstack([np.zeros(3), np.cumsum(re[:-1].apply(inc), axis=0)]) + p[0]
    return Trajectory(true.times, ps, re * true.rotations)


def to_slam_frame(true: Trajectory, slam: Trajectory, xyz, times):
    """World points (n, 3) seen at ``times`` (n,) placed in the SLAM map frame."""
    t = np.asarray(times, dtype=np.float64)
    pt, mt = true.sensor_matrices(t, Mount())
    ps, ms = slam.sensor_matrices(t, Mount())
    re = np.einsum("nij,nkj->nik", ms, mt)          # R_slam R_true^T
    d = np.asarray(xyz, dtype=np.float64) - pt
    return ps + np.einsum("nij,nj->ni", re, d)
