"""PointCloud2 points as the common ROS 2 lidar drivers lay them out.

``LAYOUTS`` holds each driver's ``sensor_msgs/msg/PointCloud2`` point (field names, byte
offsets, types and point step, from the driver's own source); ``cloud_points`` turns one
sweep of simulated ``POINT_DTYPE`` records into those points, and ``organise`` lays a
revolution's points out in the driver's organised grid (ouster-ros: rings x columns,
a cell for every pulse). ``return_topics`` and ``returns_in_one_cloud`` place the
returns of a multiple-return drive as each driver does. ``sensors.bag`` writes
them (and re-exports these names); ``GENERIC_DRIVER`` stands in for a sensor file
without a ``[driver]`` table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from .io.errors import PointFileError
from .physics import intensity_constants
from .spec import Driver, Physics

__all__ = ["GENERIC_DRIVER", "LAYOUTS", "OUSTER_REFLECTIVITY_MAX", "OUSTER_SIGNAL_MAX",
           "PointLayout", "cloud_points", "organise", "organised_width", "received_power",
           "return_topics", "returns_in_one_cloud"]


@dataclass(frozen=True)
class PointLayout:
    """One driver's PointCloud2 point: (name, byte offset, little-endian NumPy type) per
    field and the point step, as the driver's own code lays them out."""

    name: str
    package: str
    source: str
    fields: tuple[tuple[str, int, str], ...]
    point_step: int

    @property
    def dtype(self) -> np.dtype:
        """The point as a NumPy structured dtype (offsets and item size kept)."""
        return np.dtype({"names": [f[0] for f in self.fields],
                         "formats": [np.dtype("<" + f[2]) for f in self.fields],
                         "offsets": [f[1] for f in self.fields],
                         "itemsize": self.point_step})


LAYOUTS: Final[dict[str, PointLayout]] = {
    # ros-drivers/velodyne (ROS 2), velodyne_pointcloud/src/lib/pointcloudXYZIRT.cpp:
    # six fields given to PointCloud2Modifier::setPointCloud2Fields, which packs them
    # (offset += count * size; point_step = the sum). time: s after the cloud's stamp.
    "velodyne": PointLayout(
        "velodyne", "velodyne_pointcloud",
        "ros-drivers/velodyne velodyne_pointcloud/src/lib/pointcloudXYZIRT.cpp",
        (("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 12, "f4"),
         ("ring", 16, "u2"), ("time", 18, "f4")), 22),
    # ouster-lidar/ouster-ros, include/ouster_ros/os_point.h (ouster_ros::Point):
    # PCL_ADD_POINT4D pads x y z to 16 bytes, EIGEN_ALIGN16 rounds the struct to 48;
    # pcl::toROSMsg keeps the C++ offsets. intensity = signal photons, t: ns after the
    # cloud's stamp, ring = pixel row (uint16 since ouster-ros 20230114, uint8 before),
    # reflectivity = calibrated reflectivity, ambient = near-IR photons, range in mm.
    "ouster": PointLayout(
        "ouster", "ouster-ros", "ouster-lidar/ouster-ros include/ouster_ros/os_point.h",
        (("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 16, "f4"),
         ("t", 20, "u4"), ("reflectivity", 24, "u2"), ("ring", 26, "u2"),
         ("ambient", 28, "u2"), ("range", 32, "u4")), 48),
    # RoboSense-LiDAR/rslidar_sdk, src/source/source_pointcloud_ros.hpp toRosMsg with
    # POINT_TYPE_XYZIRT: addPointField packs the fields; timestamp: absolute s.
    "robosense": PointLayout(
        "robosense", "rslidar_sdk",
        "RoboSense-LiDAR/rslidar_sdk src/source/source_pointcloud_ros.hpp",
        (("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 12, "f4"),
         ("ring", 16, "u2"), ("timestamp", 18, "f8")), 26),
}

#: For a sensor file without a ``[driver]`` table (a profiler, a user's lidar): the
#: velodyne layout, which most LiDAR odometry reads, with ring = the pattern's channel.
GENERIC_DRIVER: Final = Driver("tunnelsim", "velodyne", "lidar", "/points", "channel",
                               255.0, 0.0)



#: Largest signal the ouster layout reports: the 16-bit SIGNAL channel of the
#: RNG19_RFL8_SIG16_NIR16 profile (ouster-ros copies it into the float ``intensity``).
OUSTER_SIGNAL_MAX: Final = 65535.0
#: Ouster's calibrated reflectivity is one byte (0-100 Lambertian, 101-255
#: retro-reflective).
OUSTER_REFLECTIVITY_MAX: Final = 255.0


def received_power(intensity: NDArray[np.floating], physics: Physics
                   ) -> NDArray[np.float64]:
    """The received power P (relative units, ``sensors.physics``) of returns of
    simulated ``intensity`` (n,): the inverse of the intensity formula,
    P = P_min 10^(intensity log10(P_sat / P_min)). Exact within [P_min, P_sat]; a
    return detected below P_min (intensity clipped to 0) comes back as P_min."""
    p_min, log_span = intensity_constants(physics)
    return p_min * np.power(10.0, np.asarray(intensity, dtype=np.float64) * log_span)


def cloud_points(layout: PointLayout, sweep: NDArray[np.void], stamp_s: float,
                 rings: NDArray[np.uint16], intensity_max: float, *,
                 physics: Physics | None = None, signal_photons_at_threshold: float = 0.0,
                 time_shift_s: float = 0.0) -> NDArray[np.void]:
    """One sweep's ``POINT_DTYPE`` records (n,) as the layout's points (n,).

    x, y, z are the sensor-frame point (sx, sy, sz) as float32; ring = ``rings`` of
    the channel; times relative to ``stamp_s`` (s), except robosense's absolute
    ``timestamp`` (the record's time + ``time_shift_s``: the bag's epoch shift).

    velodyne, robosense: intensity = simulated intensity x ``intensity_max`` (the
    drivers' 8-bit return strength as float32).

    ouster (``physics`` needed): the received power P is recovered from the simulated
    intensity (``received_power``); ``intensity`` = signal photons =
    ``signal_photons_at_threshold`` x P / P_min (ASSUMED: photon counts proportional to
    the power), capped at ``OUSTER_SIGNAL_MAX``; ``reflectivity`` = Ouster's calibrated
    reflectivity, 100 x P R^2 = 100 rho cos(incidence) exp(-2 alpha R) (the device
    corrects the signal for range only; the lidar equation of ``sensors.physics``),
    rounded, within [0, 255]; ``ambient`` = 0 (near-IR background not modelled);
    ``range`` in mm; ``t`` in ns.
    """
    out = np.zeros(len(sweep), dtype=layout.dtype)
    for a, b in (("x", "sx"), ("y", "sy"), ("z", "sz")):
        out[a] = sweep[b]
    out["ring"] = rings[sweep["channel"]]
    dt = sweep["time"] - stamp_s
    if layout.name == "ouster":
        if physics is None or not signal_photons_at_threshold > 0:
            raise PointFileError("Expected `physics` and a positive "
                             "`signal_photons_at_threshold` for the ouster layout, got "
                             f"{physics!r} and {signal_photons_at_threshold!r}.")
        p = received_power(sweep["intensity"], physics)
        out["intensity"] = np.minimum(signal_photons_at_threshold * p /
                                      physics.threshold_power, OUSTER_SIGNAL_MAX)
        r = sweep["range"].astype(np.float64)
        out["reflectivity"] = np.round(np.clip(100.0 * p * r * r, 0.0,
                                               OUSTER_REFLECTIVITY_MAX))
        out["t"] = np.round(dt * 1e9)
        out["range"] = np.round(r * 1e3)
        return out
    out["intensity"] = sweep["intensity"].astype(np.float64) * intensity_max
    if layout.name == "velodyne":
        out["time"] = dt
    else:
        out["timestamp"] = sweep["time"] + time_shift_s
    return out


def organised_width(rotation_hz: float, column_period_s: float) -> int:
    """Columns of one revolution (the organised cloud's width): 1 / (f T), which must
    be a whole number (1024 for an OS1 in 1024x10)."""
    w = 1.0 / (rotation_hz * column_period_s)
    n = int(round(w))
    if n < 1 or abs(w - n) > 1e-6 * w:
        raise PointFileError(f"Expected a whole number of columns per revolution for an "
                         f"organised cloud, got {w:.6g}; use the device's rotation rate.")
    return n


def organise(layout: PointLayout, points: NDArray[np.void], sweep: NDArray[np.void],
             rings: NDArray[np.uint16], width: int, column_period_s: float,
             firing_offsets_s: NDArray[np.float64], no_return: str = "zero"
             ) -> tuple[NDArray[np.void], bool]:
    """One revolution's layout points (n,) (``cloud_points`` of ``sweep`` (n,)) in the
    driver's organised grid: (rings x width,) row-major, row = ring, column = the
    record's ``column``, as ouster-ros's scan_to_cloud_f fills it (index u W + v).

    A cell without a return holds ring = its row, t = its column's firing time after
    the revolution's start (ns; ouster-ros copies the column timestamp there too) and
    zeros elsewhere, x, y, z NaN for ``no_return = "nan"``. Returns (grid, is_dense):
    is_dense is true only when every cell has a return (ROS: no invalid points).

    Raises
    ------
    PointFileError
        For rings that share a row (two beams at one elevation) or a column outside
        [0, width).
    """
    rings = np.asarray(rings)
    height = len(rings)
    if len(np.unique(rings)) != height or rings.max(initial=0) >= height:
        raise PointFileError(f"Expected one ring per channel for an organised cloud, got "
                         f"{len(np.unique(rings))} distinct rings for {height} channels.")
    grid = np.zeros(height * width, dtype=layout.dtype)
    channel_of_row = np.empty(height, dtype=np.int64)
    channel_of_row[rings] = np.arange(height)
    row = np.repeat(np.arange(height), width)
    col = np.tile(np.arange(width), height)
    grid["ring"] = row
    if "t" in (layout.dtype.names or ()):
        t_cell = col * column_period_s + np.asarray(firing_offsets_s)[channel_of_row[row]]
        grid["t"] = np.round(t_cell * 1e9)
    if no_return == "nan":
        for a in ("x", "y", "z"):
            grid[a] = np.nan
    column = np.asarray(sweep["column"], dtype=np.int64)
    if len(column) and (column.min() < 0 or column.max() >= width):
        raise PointFileError(f"Expected columns within [0, {width}) in a revolution, got "
                         f"{column.min()} to {column.max()}.")
    idx = rings[sweep["channel"]].astype(np.int64) * width + column
    grid[idx] = points
    dense = len(np.unique(idx)) == len(grid)
    return grid, dense


def return_topics(driver: Driver) -> tuple[str, ...]:
    """The cloud topics of a multiple-return drive, the one of return 1 first: the
    driver's topic, and ``topic + dual_topic_suffix`` for return 2 where the driver
    publishes it on a topic of its own (ouster-ros, ``Driver.dual_topic_suffix``);
    the driver's topic alone where every return goes into the one cloud."""
    if driver.dual_topic_suffix:
        return (driver.topic, driver.topic + driver.dual_topic_suffix)
    return (driver.topic,)


def returns_in_one_cloud(sweep: NDArray[np.void]) -> NDArray[np.intp]:
    """Indices (n,) that put one sweep of multiple-return records (n,)
    (``RETURN_POINT_DTYPE``) in the order of a driver that publishes every return in
    the one cloud: firing by firing (``column``), in each firing the points of return 1
    (all its channels, in the records' order: the firing order), then those of return 2.

    velodyne_pointcloud (ros-drivers/velodyne, velodyne_pointcloud/src/lib/rawdata.cpp,
    ``unpack_vlp16``) appends every data block of a packet in packet order, and a
    dual-return packet holds the two returns of the same firings in consecutive blocks;
    rs_driver's Airy decoder (src/rs_driver/driver/decoder/decoder_RSAIRY.hpp,
    ``FourInOneBlockIterator``) likewise decodes the blocks of both returns of a firing
    one after the other into one cloud.

    DECISION: which return a device puts in the first block is not in the drivers'
    source (they decode blocks in order whatever they hold); the simulation's order is
    kept: return 1 (the nearest reported echo) first. The VLP-16 packs two firings in a
    block; this orders by single firings (one ``column``).
    """
    names = sweep.dtype.names or ()
    if "return_number" not in names:
        return np.arange(len(sweep))
    # np.lexsort is stable: within a firing and return, the records keep their order.
    return np.lexsort((np.asarray(sweep["return_number"]), np.asarray(sweep["column"])))
