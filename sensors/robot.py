"""One robot description for a drive, its bag and its Gazebo world (issue 30).

A ``RobotDescription`` is the tree of frames a ROS stack expects (REP 105, REP 103:
x forward, y left, z up):

- ``base_link``: on the ground contact plane under the platform's centre (for a wheeled
  base the plane through its four wheel contacts, ``sensors.platform``);
- ``mast_link``: the platform frame, ``mast_height_m`` along base_link's z (the frame a
  drive's ``_true_trajectory.txt`` gives and ``Mount`` starts from);
- the sensor's frame (its driver's ``frame_id``, e.g. ``os_sensor``): the ``Mount``'s
  lever arm and boresight from ``mast_link``;
- ``imu_link``: the platform file's ``[mounts]`` (on the base), else the platform frame;
- a wheeled base's four wheels (``continuous`` joints about y, at +-wheelbase/2,
  +-track/2 and the wheel radius above the contact plane);
- the cameras a drive carries (``cameras``, issue 35): each camera's body frame (its
  driver's, e.g. ``camera_link``; ``CameraLink.link``) fixed in base_link by the
  camera's mount, and its optical frame (``*_optical_frame``: z forward, x right, y
  down) fixed in that by REP 103's rotation, rpy (-pi/2, 0, -pi/2). The colour and
  depth streams of one device share its body frame, each with its own optical frame.

From it: ``urdf()`` (a xacro-free URDF, fixed joints for the mounts), the transforms the
bag's ``/tf_static`` states (``base_to_sensor``, ``base_to_imu``, ``base_to_camera``:
the same numbers), the
base_link trajectory of a drive (``base_trajectory``) and a ROS 2 Python launch file
that starts ``robot_state_publisher`` with the URDF (``launch_file``).

URDF joint angles are fixed-axis roll, pitch, yaw (R = Rz(yaw) Ry(pitch) Rx(roll);
urdfdom's ``Rotation::setFromRPY``), scipy's ``from_euler("xyz", ...)``.

>>> from sensors.platform_spec import load_platform
>>> robot = RobotDescription.from_platform(load_platform("ground_robot"), "os_sensor")
>>> robot.base_to_sensor()[0]
array([0. , 0. , 0.5])
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Final
from xml.sax.saxutils import quoteattr

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from .errors import PlatformError
from .platform_spec import PlatformSpec
from .trajectory import Mount, Trajectory

if TYPE_CHECKING:
    from .camera import CameraSpec

__all__ = ["BASE_FRAME", "IMU_FRAME", "MAST_FRAME", "OPTICAL_RPY", "CameraLink",
           "RobotDescription", "camera_link", "launch_file", "rpy_of"]

BASE_FRAME: Final = "base_link"
MAST_FRAME: Final = "mast_link"
IMU_FRAME: Final = "imu_link"
_WHEELS: Final = (("front_left", 1, 1), ("front_right", 1, -1), ("rear_left", -1, 1),
                  ("rear_right", -1, -1))
#: Body drawn in the URDF when the platform gives no footprint (m); a picture only.
_BODY_M: Final = (0.3, 0.2)
#: A camera's body frame -> its optical frame (REP 103: z forward, x right, y down),
#: as URDF rpy (rad): the rotation whose columns are the optical axes in the body
#: frame, x_opt = -y, y_opt = -z, z_opt = x (``sensors.camera_drive.LINK_FROM_OPTICAL``;
#: the realsense-ros and image_pipeline URDFs write the same joint).
OPTICAL_RPY: Final = (-math.pi / 2, 0.0, -math.pi / 2)


@dataclass(frozen=True)
class CameraLink:
    """One camera on the robot: its frames in the URDF and on ``/tf_static``.

    Attributes
    ----------
    link : str
        The camera's body frame (x forward, y left, z up; ``camera_link`` for a
        RealSense, ``NAME_link`` otherwise: ``sensors.bag.camera_topics``).
    optical_frame : str
        Its optical frame (the images' ``frame_id``).
    mount : Mount
        base_link -> ``link``: lever arm (m) and rotation (``--camera-mount``).
    """

    link: str
    optical_frame: str
    mount: Mount = field(default_factory=Mount)

    def __post_init__(self) -> None:
        for key in ("link", "optical_frame"):
            v = getattr(self, key)
            if not isinstance(v, str) or not v or any(c.isspace() for c in v):
                raise PlatformError(f"Expected `CameraLink.{key}` to be a frame name "
                                    f"without spaces, got {v!r}.")
        if self.link == self.optical_frame:
            raise PlatformError(f"Expected a camera's optical frame to differ from its "
                                f"body frame, got {self.link!r} for both.")


def camera_link(cam: CameraSpec, mount: Mount) -> CameraLink:
    """The frames of ``cam`` (its driver's names, ``sensors.bag.camera_topics``) with
    its body frame on ``mount`` (base_link -> body frame)."""
    from .bag import camera_topics

    tp = camera_topics(cam)
    return CameraLink(tp.link, tp.frame_id, mount)


@dataclass(frozen=True)
class RobotDescription:
    """The frames of a platform carrying a sensor (see the module notes).

    Attributes
    ----------
    name : str
        The robot's name (the platform's; ``"platform"`` for a trajectory file).
    sensor_frame : str
        The sensor's frame (its driver's ``frame_id``).
    mast_height_m : float
        ``mast_link`` above ``base_link`` along its z (m); 0 when base_link is the
        platform frame (a drive along a trajectory file).
    sensor_mount : Mount
        ``mast_link`` -> sensor (the drive's ``--lever`` and ``--mount``).
    imu_xyz_m : (3,) tuple of float
        ``imu_link``'s origin in base_link (m).
    imu_rotation : Rotation
        base_link axes -> imu_link axes.
    wheelbase_m, track_m, wheel_radius_m : float
        A wheeled base's wheels (0: none).
    footprint_m : (float, float)
        Length and width of the body drawn (m).
    cameras : tuple of CameraLink
        The cameras carried (a drive's ``--camera``, ``gazebo --camera``); two
        streams of one device name the same body frame on the same mount.
    """

    name: str
    sensor_frame: str
    mast_height_m: float = 0.0
    sensor_mount: Mount = field(default_factory=Mount)
    imu_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    imu_rotation: Rotation = field(default_factory=Rotation.identity)
    wheelbase_m: float = 0.0
    track_m: float = 0.0
    wheel_radius_m: float = 0.0
    footprint_m: tuple[float, float] = _BODY_M
    cameras: tuple[CameraLink, ...] = ()

    def __post_init__(self) -> None:
        for key in ("mast_height_m", "wheelbase_m", "track_m", "wheel_radius_m"):
            v = getattr(self, key)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise PlatformError(f"Expected `RobotDescription.{key}` to be a finite "
                                    f"number >= 0, got {v!r}.")
        for key in ("name", "sensor_frame"):
            v = getattr(self, key)
            if not isinstance(v, str) or not v or any(c.isspace() for c in v):
                raise PlatformError(f"Expected `RobotDescription.{key}` to be a name "
                                    f"without spaces, got {v!r}.")
        if self.sensor_frame in (BASE_FRAME, MAST_FRAME, IMU_FRAME):
            raise PlatformError(f"Expected a sensor frame other than {BASE_FRAME}, "
                                f"{MAST_FRAME} and {IMU_FRAME}, got {self.sensor_frame!r}.")
        object.__setattr__(self, "cameras", tuple(self.cameras))
        taken = {BASE_FRAME, MAST_FRAME, IMU_FRAME, self.sensor_frame,
                 *(f"{w}_wheel" for w, _, _ in _WHEELS)}
        links: dict[str, Mount] = {}
        optical: set[str] = set()
        for c in self.cameras:
            if not isinstance(c, CameraLink):
                raise PlatformError(f"Expected `RobotDescription.cameras` to hold "
                                    f"CameraLink, got {type(c).__name__}.")
            for name in (c.link, c.optical_frame):
                if name in taken:
                    raise PlatformError(f"Expected camera frames other than the robot's "
                                        f"own ({', '.join(sorted(taken))}), got {name!r}.")
            if c.optical_frame in optical or c.optical_frame in links:
                raise PlatformError(f"Expected each camera's optical frame once, got "
                                    f"{c.optical_frame!r} twice; pass each --camera once.")
            if c.link in optical:
                raise PlatformError(f"Expected {c.link!r} as a body frame or an optical "
                                    "frame, got it as both.")
            seen = links.setdefault(c.link, c.mount)
            if seen is not c.mount and not _same_mount(seen, c.mount):
                raise PlatformError(f"Expected one place for the camera frame {c.link!r} "
                                    "(the streams of one device share it), got two mounts.")
            optical.add(c.optical_frame)

    # ------------------------------------------------------------------ building
    @classmethod
    def from_platform(cls, spec: PlatformSpec, sensor_frame: str,
                      mount: Mount | None = None, *, height_m: float | None = None
                      ) -> RobotDescription:
        """The description of ``spec`` carrying a sensor on ``mount``; ``height_m``:
        the drive's mount height (``--height``) instead of the mast's.

        DECISION: base_link lies on the ground contact plane for a wheeled base only,
        whose drive puts the base on the floor under its wheels (``sensors.platform``);
        a trolley rides the centreline (no floor in its model), a walker's and a
        tripod's frame is the sensor's carrier: their base_link is the platform frame
        (``mast_height_m`` 0), as the bag had it before issue 30."""
        h = spec.mast_height_m if height_m is None else float(height_m)
        if spec.motion != "wheeled":
            h = 0.0
        # DECISION: without [mounts] the IMU stays where it was before issue 30, at the
        # platform frame (a walker's IMU rides with the sensor it carries).
        imu = (0.0, 0.0, h) if spec.imu_xyz_m is None else spec.imu_xyz_m
        trav = spec.traversability
        foot = _BODY_M if trav is None else (trav.footprint_length_m,
                                              trav.footprint_width_m)
        return cls(spec.name, sensor_frame, h, mount or Mount(), imu,
                   Rotation.from_euler("xyz", spec.imu_rpy_rad), spec.wheelbase_m,
                   spec.track_m, spec.wheel_radius_m, foot)

    # ------------------------------------------------------------------ transforms
    def base_to_mast(self) -> NDArray[np.float64]:
        """``mast_link``'s origin in base_link, (3,) float64 (m)."""
        return np.array([0.0, 0.0, self.mast_height_m])

    def base_to_sensor(self) -> tuple[NDArray[np.float64], Rotation]:
        """The sensor frame in base_link: origin (3,) float64 (m) and the rotation
        base_link axes -> sensor axes."""
        return (self.base_to_mast() + np.asarray(self.sensor_mount.lever_arm_m),
                self.sensor_mount.boresight)

    def base_to_imu(self) -> tuple[NDArray[np.float64], Rotation]:
        """``imu_link`` in base_link: origin (3,) float64 (m) and rotation."""
        return np.asarray(self.imu_xyz_m, dtype=np.float64), self.imu_rotation

    def sensor_mount_from_base(self) -> Mount:
        """base_link -> sensor as a ``Mount`` (the bag's ``/tf_static``)."""
        xyz, rot = self.base_to_sensor()
        return Mount(tuple(xyz.tolist()), rot)

    def imu_mount(self) -> Mount:
        """base_link -> imu_link as a ``Mount``."""
        xyz, rot = self.base_to_imu()
        return Mount(tuple(xyz.tolist()), rot)

    def base_to_camera(self, frame: str) -> tuple[NDArray[np.float64], Rotation]:
        """A camera frame (a ``CameraLink``'s body or optical frame) in base_link:
        origin (3,) float64 (m) and the rotation base_link axes -> its axes.

        Raises
        ------
        PlatformError
            ``frame`` is no camera frame of this robot.
        """
        for c in self.cameras:
            if frame == c.link:
                return np.asarray(c.mount.lever_arm_m, dtype=np.float64), c.mount.boresight
            if frame == c.optical_frame:
                return (np.asarray(c.mount.lever_arm_m, dtype=np.float64),
                        c.mount.boresight * Rotation.from_euler("xyz", OPTICAL_RPY))
        known = ", ".join(self.camera_frames()) or "none"
        raise PlatformError(f"Expected a camera frame of the robot ({known}), got "
                            f"{frame!r}.")

    def camera_frames(self) -> tuple[str, ...]:
        """The camera frames, body frames first, each once, in the cameras' order."""
        links = dict.fromkeys(c.link for c in self.cameras)
        return (*links, *(c.optical_frame for c in self.cameras))

    def base_trajectory(self, platform: Trajectory) -> Trajectory:
        """base_link's poses from the platform frame's (``mast_link``; a drive's
        trajectory): each moved ``mast_height_m`` down its own z, the attitudes kept."""
        rot = platform.rotations
        pos = platform.positions - rot.apply(self.base_to_mast())
        return Trajectory(platform.times, pos, rot)

    # ------------------------------------------------------------------ URDF
    def urdf(self) -> str:
        """The robot as a xacro-free URDF (text): links base_link, mast_link, the
        sensor frame, imu_link, the wheels and the cameras' frames; fixed joints for
        the mounts (a camera: base_link -> body frame, body frame -> optical frame)."""
        length, width = self.footprint_m
        body_h = max(min(self.mast_height_m, 0.25), 0.02)
        lines = ['<?xml version="1.0"?>',
                 "<!-- Written by tunnelsim from the platform file (sensors/platforms) "
                 "and the drive's mount; base_link on the ground contact plane. -->",
                 f"<robot name={quoteattr(self.name)}>",
                 _link(BASE_FRAME, _box((length, width, body_h),
                                        (0.0, 0.0, self.wheel_radius_m + 0.5 * body_h))),
                 _link(MAST_FRAME), _link(self.sensor_frame), _link(IMU_FRAME)]
        lines.append(_joint("mast_joint", BASE_FRAME, MAST_FRAME, self.base_to_mast(),
                            Rotation.identity()))
        lines.append(_joint("sensor_joint", MAST_FRAME, self.sensor_frame,
                            np.asarray(self.sensor_mount.lever_arm_m),
                            self.sensor_mount.boresight))
        lines.append(_joint("imu_joint", BASE_FRAME, IMU_FRAME, *self.base_to_imu()))
        if self.wheelbase_m > 0 and self.track_m > 0 and self.wheel_radius_m > 0:
            r = self.wheel_radius_m
            for name, fx, fy in _WHEELS:
                link = f"{name}_wheel"
                lines.append(_link(link, _cylinder(r, 0.4 * r)))
                lines.append(_joint(f"{link}_joint", BASE_FRAME, link,
                                    np.array([fx * 0.5 * self.wheelbase_m,
                                              fy * 0.5 * self.track_m, r]),
                                    Rotation.identity(), kind="continuous"))
        done: set[str] = set()
        for c in self.cameras:
            if c.link not in done:
                done.add(c.link)
                lines.append(_link(c.link))
                lines.append(_joint(f"{c.link}_joint", BASE_FRAME, c.link,
                                    np.asarray(c.mount.lever_arm_m), c.mount.boresight))
            lines.append(_link(c.optical_frame))
            # DECISION: the optical joint's rpy is written as REP 103 states it
            # (OPTICAL_RPY), not re-derived from a rotation matrix, so that the text is
            # the one every ROS camera URDF carries.
            lines.append(_joint(f"{c.optical_frame}_joint", c.link, c.optical_frame,
                                np.zeros(3), rpy=OPTICAL_RPY))
        lines.append("</robot>")
        return "\n".join(lines) + "\n"

    def write_urdf(self, path: str | os.PathLike[str]) -> Path:
        """Write ``urdf()`` to ``path`` (atomic); returns the path."""
        return _write(Path(path), self.urdf())

    def write_launch(self, path: str | os.PathLike[str], urdf_name: str) -> Path:
        """Write ``launch_file(urdf_name)`` to ``path`` (atomic); returns the path."""
        return _write(Path(path), launch_file(urdf_name))


def launch_file(urdf_name: str) -> str:
    """A ROS 2 Python launch file (``ros2 launch ./<file>.launch.py``) that starts
    ``robot_state_publisher`` with the URDF ``urdf_name`` found beside it
    (``use_sim_time`` argument, default true: a bag played with ``--clock``)."""
    return f'''"""Written by tunnelsim: robot_state_publisher for {urdf_name} (beside this
file).

ros2 launch ./{Path(urdf_name).stem}.launch.py       # with: ros2 bag play BAG --clock
"""
from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

URDF = Path(__file__).resolve().with_name({urdf_name!r})


def generate_launch_description():
    sim_time = LaunchConfiguration("use_sim_time")
    return LaunchDescription([
        DeclareLaunchArgument("use_sim_time", default_value="true"),
        Node(package="robot_state_publisher", executable="robot_state_publisher",
             output="screen",
             parameters=[{{"robot_description": URDF.read_text(),
                          "use_sim_time": sim_time}}]),
    ])
'''


def _fmt(v: NDArray[np.float64] | tuple[float, ...]) -> str:
    return " ".join(f"{float(x):.15g}" for x in v)


def rpy_of(rot: Rotation) -> NDArray[np.float64]:
    """URDF/SDF roll, pitch, yaw (fixed axes x, y, z; rad) of ``rot``. At a pitch of
    ±90 deg (a profiler turned on its side) the yaw is folded into the roll, which
    SciPy announces with a gimbal-lock warning: the rotation is still exact, so the
    warning is not passed on to the user."""
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        return rot.as_euler("xyz")


def _origin(xyz: NDArray[np.float64], rot: Rotation | None,
            rpy: tuple[float, float, float] | None = None) -> str:
    if rpy is None:
        assert rot is not None
        angles: NDArray[np.float64] | tuple[float, ...] = rpy_of(rot)
    else:
        angles = rpy
    return f'<origin xyz="{_fmt(xyz)}" rpy="{_fmt(angles)}"/>'


def _link(name: str, visual: str = "") -> str:
    if not visual:
        return f"  <link name={quoteattr(name)}/>"
    return f"  <link name={quoteattr(name)}>\n    <visual>{visual}</visual>\n  </link>"


def _box(size: tuple[float, float, float], at: tuple[float, float, float]) -> str:
    return (f'{_origin(np.asarray(at), Rotation.identity())}<geometry><box '
            f'size="{_fmt(size)}"/></geometry>')


def _cylinder(radius: float, length: float) -> str:
    # URDF cylinders lie along z: rolled by 90 deg to lie along the wheel's axle (y).
    return (f'{_origin(np.zeros(3), Rotation.from_euler("x", math.pi / 2))}<geometry>'
            f'<cylinder radius="{radius:.15g}" length="{length:.15g}"/></geometry>')


def _same_mount(a: Mount, b: Mount) -> bool:
    return bool(np.array_equal(np.asarray(a.lever_arm_m), np.asarray(b.lever_arm_m))
                and np.allclose(a.boresight.as_matrix(), b.boresight.as_matrix(),
                                rtol=0.0, atol=1e-12))


def _joint(name: str, parent: str, child: str, xyz: NDArray[np.float64],
           rot: Rotation | None = None, kind: str = "fixed", *,
           rpy: tuple[float, float, float] | None = None) -> str:
    axis = '\n    <axis xyz="0 1 0"/>' if kind == "continuous" else ""
    return (f"  <joint name={quoteattr(name)} type={quoteattr(kind)}>\n"
            f"    <parent link={quoteattr(parent)}/>\n    <child link={quoteattr(child)}/>"
            f"\n    {_origin(np.asarray(xyz, dtype=np.float64), rot, rpy)}{axis}"
            "\n  </joint>")


def _write(path: Path, text: str) -> Path:
    from raytrace.fileio import atomic_writer

    with atomic_writer(path, "w") as fh:
        fh.write(text)
    return path
