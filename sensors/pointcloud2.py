"""PointCloud2 points as the common ROS 2 lidar drivers lay them out.

``LAYOUTS`` holds each driver's ``sensor_msgs/msg/PointCloud2`` point (field names, byte
offsets, types and point step, from the driver's own source); ``cloud_points`` turns one
sweep of simulated ``POINT_DTYPE`` records into those points. ``sensors.bag`` writes
them (and re-exports these names); ``GENERIC_DRIVER`` stands in for a sensor file
without a ``[driver]`` table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from .spec import Driver

__all__ = ["GENERIC_DRIVER", "LAYOUTS", "PointLayout", "cloud_points"]


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
    # pcl::toROSMsg keeps the C++ offsets. intensity = signal, t: ns after the cloud's
    # stamp, ring = pixel row, ambient = near-IR, range in mm.
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



def cloud_points(layout: PointLayout, sweep: NDArray[np.void], stamp_s: float,
                 rings: NDArray[np.uint16], intensity_max: float) -> NDArray[np.void]:
    """One sweep's ``POINT_DTYPE`` records (n,) as the layout's points (n,).

    x, y, z are the sensor-frame point (sx, sy, sz) as float32; ring = ``rings`` of
    the channel; intensity-like fields = intensity x ``intensity_max`` (rounded for
    integer fields); times relative to ``stamp_s`` (s) except robosense's absolute
    ``timestamp``. ouster's ambient (near-IR) is 0: no ambient light is simulated.
    """
    out = np.zeros(len(sweep), dtype=layout.dtype)
    for a, b in (("x", "sx"), ("y", "sy"), ("z", "sz")):
        out[a] = sweep[b]
    level = sweep["intensity"].astype(np.float64) * intensity_max
    out["intensity"] = level
    out["ring"] = rings[sweep["channel"]]
    dt = sweep["time"] - stamp_s
    if layout.name == "velodyne":
        out["time"] = dt
    elif layout.name == "ouster":
        out["t"] = np.round(dt * 1e9)
        # ASSUMED: the 8-bit calibrated reflectivity carries the same level as the
        # signal; signal photon counts are not modelled.
        out["reflectivity"] = np.round(level)
        out["range"] = np.round(sweep["range"] * 1e3)
    else:
        out["timestamp"] = sweep["time"]
    return out
