"""What an IMU on the platform measures: the trajectory's true motion and the noise.

``platform_motion`` differentiates a ``Trajectory`` (positions, attitude, velocity,
body angular rate, acceleration); ``ImuModel`` is the Kalibr noise and bias model of the
simulated IMU, whose standard normals ``imu_normals`` draws reproducibly per block of
samples. ``sensors.bag`` turns them into ``sensor_msgs/msg/Imu`` messages (and
re-exports the public names).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from sensors.io.errors import PointFileError
from .trajectory import Mount, Trajectory

__all__ = ["DEFAULT_IMU", "DEFAULT_WHEEL_ODOMETRY", "IMU_STREAM", "ODOM_STREAM",
           "STANDARD_GRAVITY", "ImuModel", "WheelOdometryModel", "imu_normals",
           "mounted_trajectory", "platform_motion"]

#: Standard gravity (m/s^2, 3rd CGPM 1901); the IMU's specific force adds it along +z.
STANDARD_GRAVITY: Final = 9.80665
#: Random stream of the IMU noise, apart from the simulation's streams (0-4).
IMU_STREAM: Final = 101
#: Random stream of the wheel odometry's noise.
ODOM_STREAM: Final = 103
_IMU_BLOCK: Final = 1 << 14


def platform_motion(trajectory: Trajectory, t: ArrayLike, step_s: float | None = None
                    ) -> tuple[NDArray[np.float64], Rotation, NDArray[np.float64],
                               NDArray[np.float64], NDArray[np.float64]]:
    """True platform motion at times t (n,): positions (n, 3) world, body-to-world
    Rotation (n), world velocity (n, 3) m/s, body angular rate (n, 3) rad/s and world
    acceleration (n, 3) m/s^2.

    Central differences of the interpolated poses over ``step_s`` (default: the
    trajectory's median pose spacing): the interpolant is piecewise linear (positions)
    and piecewise constant-rate (SLERP), so a shorter step would see its kinks as
    spikes; over the pose spacing a uniformly sampled parabola gives its exact second
    derivative. Within ``step_s`` of the ends the nearest interior difference is used.
    Angular rate: rotvec(R(t - h)^T R(t + h)) / 2h (body frame).
    """
    tq = np.atleast_1d(np.asarray(t, dtype=np.float64))
    pos, rot = trajectory.interpolate(tq)
    n = len(tq)
    zero = np.zeros((n, 3))
    if len(trajectory) < 2:
        return pos, rot, zero, zero.copy(), zero.copy()
    h = float(np.median(np.diff(trajectory.times))) if step_s is None else float(step_s)
    lo, hi = trajectory.start_s, trajectory.end_s
    h = min(h, 0.5 * (hi - lo))
    tc = np.clip(tq, lo + h, hi - h)
    (pm, rm), (p0, _), (pp, rp) = (trajectory.interpolate(tc + d, local=True)
                                   for d in (-h, 0.0, h))
    vel = (pp - pm) / (2 * h)
    acc = (pp - 2 * p0 + pm) / h ** 2
    omega = (rm.inv() * rp).as_rotvec() / (2 * h)
    return pos, rot, vel, omega, acc


def mounted_trajectory(trajectory: Trajectory, mount: Mount) -> Trajectory:
    """The trajectory of a frame rigidly mounted on the platform (``mount``: its origin
    and axes in the platform frame): position p + R lever, attitude R boresight. Its
    ``platform_motion`` is then that frame's own motion (the lever arm's centripetal
    and tangential accelerations included, as the IMU at that place measures them)."""
    rot = trajectory.rotations
    return Trajectory(trajectory.times,
                      trajectory.positions + rot.apply(np.asarray(mount.lever_arm_m)),
                      rot * mount.boresight)


@dataclass(frozen=True)
class WheelOdometryModel:
    """Noise of the simulated wheel odometry (``/odom``): a planar (x, y, yaw) dead
    reckoning of the distance driven along the heading and the heading change, each
    step's errors zero-mean normal with variances growing linearly with what was
    driven and turned in that step (Chong & Kleeman 1997, "Accurate odometry and
    error modelling for a mobile robot", ICRA: wheel-distance variance proportional to
    the distance; so the odometry's error is a random walk, the same at any rate):
    var(ds) = distance_var_per_m |ds| + distance_var_per_rad |dpsi|,
    var(dpsi) = yaw_var_per_rad |dpsi| + yaw_var_per_m |ds|; and a constant scale error
    of the distance (wheel radius), drawn once per seed, N(0, scale_sigma).

    All values ASSUMED (no measured model of the platforms' odometry): 1 cm per
    sqrt(m) of distance, 1 deg per sqrt(rad) turned and 0.5 deg per sqrt(m) driven
    (slip on rock), a 1 % scale sigma. Units: m^2/m, m^2/rad, rad^2/rad, rad^2/m.
    """

    distance_var_per_m: float = 1.0e-4
    distance_var_per_rad: float = 1.0e-6
    yaw_var_per_rad: float = 3.0e-4
    yaw_var_per_m: float = 7.6e-5
    scale_sigma: float = 0.01

    def __post_init__(self) -> None:
        for name, v in asdict(self).items():
            if not (isinstance(v, (int, float)) and not isinstance(v, bool)
                    and np.isfinite(v) and v >= 0):
                raise PointFileError(f"Expected `WheelOdometryModel.{name}` to be a "
                                     f"finite number >= 0, got {v!r}.")


DEFAULT_WHEEL_ODOMETRY: Final = WheelOdometryModel()


@dataclass(frozen=True)
class ImuModel:
    """Noise and bias of the simulated IMU (Kalibr's continuous-time model; Kalibr wiki
    "IMU Noise Model"): per sample, white noise sigma = density sqrt(rate_hz); the bias
    starts at N(0, bias_sigma) per axis and takes random-walk steps of sigma =
    random_walk / sqrt(rate_hz). Densities in rad/s/sqrt(Hz) and m/s^2/sqrt(Hz),
    random walks in rad/s^2/sqrt(Hz) and m/s^3/sqrt(Hz), bias sigmas in rad/s and m/s^2.

    Defaults: the EuRoC MAV dataset's VI-Sensor IMU (ADIS16448, imu0/sensor.yaml) for
    the densities and random walks; rate and turn-on biases ASSUMED.
    """

    rate_hz: float = 200.0                 # EuRoC imu0 rate
    gyro_noise_density: float = 1.6968e-4
    gyro_random_walk: float = 1.9393e-5
    accel_noise_density: float = 2.0e-3
    accel_random_walk: float = 3.0e-3
    gyro_bias_sigma: float = 1.0e-3        # ASSUMED (0.06 deg/s turn-on bias, 1 sigma)
    accel_bias_sigma: float = 0.02         # ASSUMED (2 mg turn-on bias, 1 sigma)

    def __post_init__(self) -> None:
        for name, v in asdict(self).items():
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and \
                np.isfinite(v) and (v > 0 if name == "rate_hz" else v >= 0)
            if not ok:
                least = "> 0" if name == "rate_hz" else ">= 0"
                raise PointFileError(f"Expected `ImuModel.{name}` to be a finite number "
                                     f"{least}, got {v!r}.")

    def sample_sigmas(self) -> tuple[float, float, float, float]:
        """Per-sample sigmas: gyro white noise (rad/s), accel white noise (m/s^2), gyro
        bias step (rad/s), accel bias step (m/s^2)."""
        r = np.sqrt(self.rate_hz)
        return (self.gyro_noise_density * r, self.accel_noise_density * r,
                self.gyro_random_walk / r, self.accel_random_walk / r)


DEFAULT_IMU: Final = ImuModel()


def imu_normals(seed: int, first: int, n: int, width: int,
                cache: list[tuple[int, NDArray[np.float64]]] | None = None,
                stream: int = IMU_STREAM) -> NDArray[np.float64]:
    """Standard normals (n, width) for samples [first, first + n), the same however
    they are asked for: block b of ``_IMU_BLOCK`` samples comes from
    ``default_rng([seed, stream, b])`` (``IMU_STREAM`` by default; the wheel odometry
    has its own). ``cache`` (a one-item list) keeps the last block drawn."""
    if n <= 0:
        return np.empty((0, width))
    b0, b1 = first // _IMU_BLOCK, (first + n - 1) // _IMU_BLOCK
    parts = []
    for b in range(b0, b1 + 1):
        if cache and cache[0][0] == b:
            parts.append(cache[0][1])
            continue
        block = np.random.default_rng([seed, stream, b]).standard_normal(
            (_IMU_BLOCK, width))
        if cache is not None:
            cache[:] = [(b, block)]
        parts.append(block)
    off = first - b0 * _IMU_BLOCK
    return np.concatenate(parts)[off:off + n]
