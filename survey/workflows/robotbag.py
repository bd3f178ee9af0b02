"""A drive's ROS 2 bag in the frames of its robot (issue 30): what ``tunnelsim drive -o
NAME.mcap`` (or a rosbag2 folder) writes, for a Python user.

``Run.write`` writes a bag in the sensor's own frames (the points, /tf of the platform
frame, the IMU at the sensor); a robot adds base_link, /tf_static and wheel odometry.
``write_robot_bag`` is that writer, the one ``drive_to_file`` calls. With
``cameras`` (``sensors.camera_drive.DriveCamera``) it renders their frames as the
points stream past and puts them in the bag on the cameras' driver topics
(``sensors.bag.camera_topics``), each frame logged at its readout end among the clouds,
poses and IMU samples.

The run's clock (``Run.stats["seconds"]``) runs while the points are consumed, so it
counts the frames rendered among them; ``write_robot_bag`` times the frames apart and
gives the lidar its own time and rate, and each camera its seconds.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:                     # the writers import NumPy: loaded where they run
    from sensors.bag import RosbagStream
    from sensors.camera_drive import DriveCamera
    from sensors.robot import RobotDescription
    from sensors.simulate import Run


def write_robot_bag(path: str | os.PathLike[str], run: Run, robot: RobotDescription, *,
                    progress: Callable[[int, int], None] | None = None, crs: Any = None,
                    start_time_ns: int | None = None, ros_distro: str | None = None,
                    cameras: Sequence[DriveCamera] = ()) -> dict[str, Any]:
    """Write ``run`` as a ROS 2 bag in the frames of ``robot``.

    The bag holds /tf and the ground-truth odometry of base_link
    (``robot.base_trajectory``), /tf_static base_link -> sensor and base_link ->
    imu_link, the IMU at its own mount, and /odom wheel odometry
    (``sensors.bag.DEFAULT_WHEEL_ODOMETRY``, seeded by the run's seed). The points are
    the run's, in the sensor frame, as ``Run.write`` writes them.

    Parameters
    ----------
    path : str or path-like
        ``NAME.mcap`` (one MCAP file) or a folder name without a suffix (rosbag2).
    run : sensors.Run
        A drive (``sensors.simulate_drive``).
    robot : sensors.robot.RobotDescription
        What carries the sensor (its mount from base_link, its IMU).
    progress : callable (done_pulses, total_pulses), optional
        Called after each chunk.
    crs : str, optional
        The mesh's coordinate reference system (EPSG:n, WKT or PROJJSON; needs pyproj),
        stated in the bag's metadata.
    start_time_ns : int, optional
        ROS time of the scan's start, ns since 1970 (default: the trajectory's times).
    ros_distro : {"humble", "jazzy"}, optional
        rosbag2 metadata layout of a folder bag (default jazzy).
    cameras : sequence of sensors.camera_drive.DriveCamera
        Cameras on the robot (their trajectory base_link's, their span the run's):
        every frame rendered and written as Image + CameraInfo.

    Returns
    -------
    dict
        The run's ``stats`` (pulses, points, hit_ratio, seconds, rays_per_s; with
        ``cameras``, ``seconds`` and ``rays_per_s`` the lidar's own, without the time
        its clock spent on the frames) plus ``path`` (str), ``camera_frames`` (frames
        written per camera name) and ``camera_seconds`` (per camera name: seconds spent
        rendering its frames and serialising and writing them into the bag).

    Raises
    ------
    sensors.io.errors.PointFileError
        For a path that is not a bag, or a bad ``ros_distro``.

    Examples
    --------
    >>> from survey.workflows.robotbag import write_robot_bag
    >>> # write_robot_bag("drive.mcap", run, RobotDescription.from_platform(...))
    """
    from sensors.imu import DEFAULT_WHEEL_ODOMETRY
    from sensors.bag import RosbagStream
    from sensors.io.crs import file_wkt, parse_crs
    from sensors.writers import format_of

    if run.trajectory is None:
        from sensors.errors import SimulationError

        raise SimulationError("Expected a drive (a run along a trajectory) for a robot's "
                              "bag, got a station.")
    spec = run.sensor
    mount = robot.sensor_mount_from_base()
    info = {"sensor": spec.name, "seed": run.seed,
            "mount_lever_arm_m": list(mount.lever_arm_m),
            "mount_boresight_xyzw": mount.boresight.as_quat().tolist(),
            "robot": robot.name, "mast_height_m": robot.mast_height_m}
    if crs is not None:
        info["crs"] = file_wkt(parse_crs(crs, metric=True, what="the output CRS"))
    bag: dict[str, Any] = {}
    if start_time_ns is not None:
        bag["start_time_ns"] = start_time_ns
    if ros_distro is not None:
        bag["ros_distro"] = ros_distro
    span = (run.t0, run.t0 + run.duration_s)
    if cameras:
        info["cameras"] = [dict(name=c.cam.name, rate_hz=c.rate_hz, frames=len(c),
                                samples_per_pixel=c.samples_per_pixel)
                           for c in cameras]
    with RosbagStream(path, spec, single_file=format_of(path) == "mcap", seed=run.seed,
                      mount=mount, trajectory=robot.base_trajectory(run.trajectory),
                      span_s=span, info=info, imu_mount=robot.imu_mount(),
                      wheel_odometry=DEFAULT_WHEEL_ODOMETRY,
                      returns=run.settings.returns,
                      cameras=[(c.cam, c.link_mount) for c in cameras], **bag) as w:
        frames = _Frames(w, cameras)
        counted = 0.0
        for chunk in run:
            # The run's clock stopped when it made this chunk: it counts the frames
            # fed before, not those fed with it (the last chunk's) or after the loop,
            # and the images the bag wrote among the points before.
            counted = sum(frames.seconds) + sum(w.image_seconds)
            for part in frames.between(chunk):
                w.write_points(part)
            if progress is not None:
                progress(int(run.pass_stats["pulses"]), run.n_pulses)
        frames.until(float("inf"))
    stats = dict(run.stats)
    if counted and stats.get("seconds") and not run.pass_stats.get("replayed"):
        stats.update(_lidar_time(stats, counted))
    return dict(stats, path=str(path),
                camera_frames={c.cam.name: len(c) for c in cameras},
                camera_seconds={c.cam.name: s + si for c, s, si in
                                zip(cameras, frames.seconds, w.image_seconds)})


def _lidar_time(stats: dict[str, Any], camera_s: float) -> dict[str, float]:
    """``seconds`` and ``rays_per_s`` of a run's ``stats`` without ``camera_s`` seconds
    its clock counted (frames rendered while the run's chunks were consumed).

    Examples
    --------
    >>> _lidar_time({"seconds": 5.0, "rays_per_s": 2e6}, 3.0)
    {'seconds': 2.0, 'rays_per_s': 5000000.0}
    """
    total = float(stats["seconds"])
    own = max(total - camera_s, 0.0)
    # The rays cast are the run's whatever the time: the rate scales by total / own.
    rays = float(stats["rays_per_s"]) * total
    return {"seconds": own, "rays_per_s": rays / own if own else 0.0}


class _Frames:
    """The cameras' frames in the order of their readout ends, rendered one at a time
    and fed to the bag just before the first point at or after that time: a cloud
    published after a frame's readout is then logged after it, and memory holds one
    frame."""

    def __init__(self, bag: RosbagStream, cameras: Sequence[DriveCamera]) -> None:
        self.bag, self.cameras = bag, cameras
        #: Seconds spent on each camera's frames (render, image, write_image).
        self.seconds = [0.0] * len(cameras)
        self.queue = sorted(((float(t) + _readout(c), k, i) for k, c in enumerate(cameras)
                             for i, t in enumerate(c.times)), key=lambda e: (e[0], e[1]))
        self.next = 0

    def until(self, t_s: float) -> None:
        """Render and feed every frame whose readout ends before ``t_s``."""
        from sensors.camera_drive import image_counts

        while self.next < len(self.queue) and self.queue[self.next][0] < t_s:
            _log, k, i = self.queue[self.next]
            cam = self.cameras[k]
            t0 = time.perf_counter()
            f = cam.render(i)
            self.bag.write_image(k, f.stamp_s, f.readout_end_s, image_counts(cam.cam, f))
            self.seconds[k] += time.perf_counter() - t0
            self.next += 1

    def between(self, chunk: Any) -> Iterator[Any]:
        """``chunk`` in pieces, the frames fed between them (at their readout ends)."""
        import numpy as np

        if self.next >= len(self.queue) or not len(chunk):
            yield chunk
            return
        t = np.asarray(chunk["time"])
        if np.any(np.diff(t) < 0):      # not in time order: feed what it may publish after
            self.until(float(np.nextafter(t.max(), np.inf)))
            yield chunk
            return
        lo = 0
        while self.next < len(self.queue) and self.queue[self.next][0] <= t[-1]:
            cut = int(np.searchsorted(t, self.queue[self.next][0], side="left"))
            if cut > lo:
                yield chunk[lo:cut]
                lo = cut
            self.until(float(np.nextafter(self.queue[self.next][0], np.inf)))
        if lo < len(chunk):
            yield chunk[lo:]


def _readout(camera: DriveCamera) -> float:
    from sensors.camera_drive import readout_s

    return readout_s(camera.cam)


__all__ = ["write_robot_bag"]
