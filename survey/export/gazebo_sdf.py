"""The texts of a Gazebo world folder (``survey.export.gazebo.export_gazebo``): SDFormat
1.9 for the world, the tunnel model and the robot, its sensors and systems, and the
``ros_gz_bridge`` configuration, for one of two Gazebo lines (``FLAVOURS``).

Gazebo lines (the flavour picks plugin files, class names, message names, the resource
path variable and the command line; the SDF is the same):

- ``harmonic``: Gazebo Harmonic (gz-sim 8, libsdformat 14), paired with ROS 2 Jazzy.
  Plugins ``gz-sim-<system>-system`` / ``gz::sim::systems::<System>``, messages
  ``gz.msgs.*``, ``GZ_SIM_RESOURCE_PATH``, ``gz sim`` (gz-sim's
  ``src/systems/*/*.cc`` register both names with ``GZ_ADD_PLUGIN_ALIAS``; the
  ros_gz_bridge README for Jazzy lists ``gz.msgs.*``).
- ``fortress``: Ignition Gazebo 6 "Fortress" (libsdformat 12: the checker the tests
  build), paired with ROS 2 Humble. Plugins ``ignition-gazebo-<system>-system`` /
  ``ignition::gazebo::systems::<System>`` (the ``ignition::gazebo`` aliases gz-sim
  kept until version 8 carry the Fortress names), messages ``ignition.msgs.*`` (the
  ros_gz_bridge README for Humble, docs.ros.org/en/humble/p/ros_gz_bridge),
  ``IGN_GAZEBO_RESOURCE_PATH``, ``ign gazebo``.

Topics on the Gazebo side are written out explicitly (a leading '/', so that the
partition-free name is the one the bridge asks for):

- the lidar: ``<topic>/lidar</topic>``. gz-sensors' ``GpuLidarSensor::Load`` calls
  ``SetTopic(Topic() + "/points")`` before it advertises the ``PointCloudPacked``
  publisher (the parent ``Lidar`` class advertises the ``LaserScan`` on the plain
  topic), so the cloud is ``/lidar/points``. A topic already ending in ``/points``
  would give ``.../points/points``: ``lidar_sdf`` refuses one.
- the IMU: ``/imu`` (``gz.msgs.IMU``).
- ground truth: ``PosePublisher`` publishes on ``<scoped model name>/pose``, i.e.
  ``/model/robot/pose`` (gz-sim ``PosePublisher.cc``: ``scopedName(entity) +
  "/pose"``), a ``Pose_V`` with the model, link and sensor frames (bridged to
  ``/tf``); ``OdometryPublisher`` on ``/ground_truth/odometry`` (``<odom_topic>``)
  with its own TF moved to ``<tf_topic>`` ``/ground_truth/odometry/tf`` (its default,
  ``/model/robot/pose``, is the PosePublisher's topic).
- the wheels: ``DiffDrive`` listens on ``/cmd_vel``; its wheel odometry and TF go to
  ``/model/robot/wheel_odometry`` and ``/model/robot/wheel_tf`` (their defaults,
  ``/model/robot/odometry`` and ``/model/robot/tf``, would read as ground truth).
- ``/clock``: published by the server itself (gz-sim's ``SimulationRunner``
  advertises ``/clock`` next to ``/world/<name>/clock``).

The camera (``camera_sdf``, ``tunnelsim gazebo --camera``): a ``camera`` /
``depth_camera`` / ``thermal_camera`` sensor (``wideanglecamera`` for a fisheye) on
the image topic the bag uses (``sensors.bag.camera_topics``: the RealSense wrapper's
``/camera/color/image_raw`` for the D435, ``/NAME/image_raw`` otherwise); gz-sensors
advertises the CameraInfo beside it, the image topic's last part replaced by
``camera_info`` (``CameraSensor::AdvertiseInfo``), which is the bag's info topic too.
Gazebo's camera looks along its sensor frame's +x with +z up (camera_link, REP 103's
body axes); the optical frame (z forward, x right, y down) is a ``<frame>`` of the
robot model named as the bag's ``*_optical_frame``. The platform's ``[[lamps]]``
become ``<light>``s of the chassis link (``lamp_light_sdf``).

DECISION: the ROS topic names are the ones ``sensors.bag`` writes in a bag of a drive
(cloud: the driver's topic; ``/imu/data_raw``; ``/odometry/ground_truth``; ``/tf``), so
that a stack set up on a recorded drive runs on the simulation unchanged. The frames
differ: Gazebo names them by scope (``robot::chassis::lidar``), which only the
``gz_frame_id`` / ``ignition_frame_id`` extension elements change, and libsdformat
refuses those as unknown elements.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final
from xml.sax.saxutils import escape

import numpy as np

from survey.errors import GazeboExportError

if TYPE_CHECKING:
    from sensors.camera import CameraSpec
    from sensors.imu import ImuModel
    from sensors.spec_types import SensorSpec

__all__ = ["BASE", "CAMERA_CLIP_M", "CLOCK_TOPIC", "LIGHT_RANGE_LUX", "LIGHT_REF_CD",
           "camera_sdf", "lamp_light_sdf", "optical_frame_sdf", "CMD_VEL_TOPIC", "FLAVOURS", "GT_ODOMETRY_TOPIC",
           "IMU_BIAS_CORRELATION_S", "IMU_GZ_TOPIC", "LIDAR_GZ_TOPIC", "POINTS_SUFFIX",
           "RANGE_RESOLUTION_M", "ROBOT", "Flavour", "bridge_entries", "bridge_yaml",
           "crs_suffix", "flavour", "imu_sdf", "lidar_sdf", "model_config", "model_sdf",
           "chassis_z", "origin_frame", "pose_topic", "robot_sdf", "world_sdf"]

#: Range resolution written to SDF (m): ASSUMED, the specs give no range quantisation.
RANGE_RESOLUTION_M: Final = 0.001
#: LIMO-sized differential-drive base (AgileX LIMO: 322 x 220 x 251 mm, 4.2 kg; public
#: product sheet). Track and wheel radius are the ground_robot platform's (issue 30:
#: the world's robot is the drive's; ``robot_sdf`` takes them from its description),
#: the wheels centred on the track.
BASE: Final = {"length": 0.322, "width": 0.220, "height": 0.10, "clearance": 0.05,
               "wheel_radius": 0.045, "wheel_width": 0.045, "track": 0.175, "mass": 4.2}
#: The robot model's name: it scopes the PosePublisher's topic and the frames.
ROBOT: Final = "robot"
LIDAR_GZ_TOPIC: Final = "/lidar"
#: gz-sensors' GpuLidarSensor publishes the cloud on ``<topic>`` + this.
POINTS_SUFFIX: Final = "/points"
IMU_GZ_TOPIC: Final = "/imu"
GT_ODOMETRY_TOPIC: Final = "/ground_truth/odometry"
CMD_VEL_TOPIC: Final = "/cmd_vel"
CLOCK_TOPIC: Final = "/clock"
#: Correlation time of the IMU bias process (s). gz-sensors' GaussianNoiseModel
#: (after Rotors' gazebo_imu_plugin) drives the bias as a Gauss-Markov process whose
#: step over dt has sigma = dynamic_bias_stddev * sqrt(tau/2 (1 - exp(-2 dt/tau))),
#: ~ dynamic_bias_stddev * sqrt(dt) for dt << tau: a random walk of that density, the
#: Kalibr parameter ``sensors.bag.ImuModel`` holds. ASSUMED: 1000 s (Rotors' ADIS16448
#: default), long against a drive, so the bias wanders as ImuModel's does.
IMU_BIAS_CORRELATION_S: Final = 1000.0
#: Near and far clip planes (m) of a colour or thermal camera (a depth camera's are its
#: depth range): ASSUMED, nearer than any wall a robot touches, beyond any sight line
#: along a tunnel; our renderer has none.
CAMERA_CLIP_M: Final = (0.02, 1000.0)
#: Candela of a light of SDF ``<intensity>`` 1. Gazebo's lights are not photometric
#: (``<intensity>`` is a relative scale, the camera has no exposure): DECISION, 1000 cd
#: (``render``'s headlamp) is 1, so the lamps keep their ratios.
LIGHT_REF_CD: Final = 1000.0
#: A lamp's ``<attenuation><range>`` ends where its axis illuminance I / d^2 falls to
#: this (lux): ASSUMED, a moonlit night's order; OGRE cuts the light off there.
LIGHT_RANGE_LUX: Final = 0.1
#: SDF ``<image><format>`` by camera kind (gz-sensors' formats: RGB8, depth as 32-bit
#: float metres, thermal as 16-bit counts of 0.01 K).
IMAGE_FORMATS: Final = {"color": "R8G8B8", "depth": "R_FLOAT32", "thermal": "L16"}
_SENSOR_TYPES: Final = {"color": "camera", "depth": "depth_camera",
                        "thermal": "thermal_camera"}


@dataclass(frozen=True)
class Flavour:
    """One Gazebo line: how its plugins, messages, resource path and commands are
    named (see module doc)."""

    name: str
    title: str
    ros: str
    plugin_file: str         # "{}" -> the system's file stem, e.g. "imu"
    plugin_class: str        # "{}" -> the system's class, e.g. "Imu"
    msgs: str                # message package prefix, e.g. "gz.msgs."
    resource_env: str
    launch: str
    topic_cli: str

    def plugin(self, stem: str, cls: str, body: str = "", indent: int = 4) -> str:
        """A ``<plugin>`` element for system ``stem`` / ``cls`` with ``body`` inside."""
        pad = " " * indent
        head = (f'{pad}<plugin filename="{self.plugin_file.format(stem)}" '
                f'name="{self.plugin_class.format(cls)}"')
        if not body:
            return head + "/>"
        inner = "\n".join(pad + "  " + line for line in body.strip().splitlines())
        return f"{head}>\n{inner}\n{pad}</plugin>"

    def run_line(self, folder: str = "$PWD") -> str:
        """The command that opens the world from inside its folder."""
        return f"{self.resource_env}={folder}/models {self.launch} world.sdf"


FLAVOURS: Final[dict[str, Flavour]] = {
    "harmonic": Flavour("harmonic", "Gazebo Harmonic (gz-sim 8)", "ROS 2 Jazzy",
                        "gz-sim-{}-system", "gz::sim::systems::{}", "gz.msgs.",
                        "GZ_SIM_RESOURCE_PATH", "gz sim", "gz topic"),
    "fortress": Flavour("fortress", "Ignition Gazebo Fortress (6)", "ROS 2 Humble",
                        "ignition-gazebo-{}-system", "ignition::gazebo::systems::{}",
                        "ignition.msgs.", "IGN_GAZEBO_RESOURCE_PATH", "ign gazebo",
                        "ign topic"),
}


def flavour(name: str) -> Flavour:
    """The ``Flavour`` called ``name``; ``GazeboExportError`` for another name."""
    try:
        return FLAVOURS[name]
    except (KeyError, TypeError):
        raise GazeboExportError(f"Expected a Gazebo flavour {' or '.join(map(repr, FLAVOURS))}"
                                f", got {name!r}.") from None


def pose_topic(model: str = ROBOT) -> str:
    """The PosePublisher's topic on a top-level model (``/model/<name>/pose``)."""
    return f"/model/{model}/pose"


def _indent(xml: str, indent: int) -> str:
    pad = " " * indent
    return "\n".join(pad + line for line in xml.splitlines())


# ---------------------------------------------------------------------------- sensors
def lidar_sdf(spec: SensorSpec, *, name: str = "lidar", topic: str = LIDAR_GZ_TOPIC,
              pose: str = "0 0 0 0 0 0", indent: int = 10) -> tuple[str, list[str]]:
    """(XML of a ``<sensor type="gpu_lidar">``, list of what SDF cannot express).

    ``topic`` is the scan's; the cloud goes to ``topic + "/points"`` (module doc), so a
    topic ending in ``/points`` is refused."""
    if topic.rstrip("/").endswith(POINTS_SUFFIX):
        raise GazeboExportError(f"Expected a lidar topic without the '{POINTS_SUFFIX}' "
                                f"suffix gz-sensors adds for the cloud, got {topic!r}; the "
                                f"cloud would be on '{topic}{POINTS_SUFFIX}'.")
    p: Any = spec.pattern          # SpinningPattern or ProfilerPattern (by kind)
    ph = spec.physics
    limits = ["per-pulse timing (each Gazebo sweep is rendered at one instant: no "
              "rolling shutter)", "dual/multiple returns and beam divergence (one return "
              "per ray)", "intensity physics (reflectivity, incidence, range falloff) and "
              "detection probability", "range noise that depends on range and "
              "reflectivity (SDF: one constant Gaussian sigma)"]
    if spec.kind == "spinning":
        rate = p.rotation_hz
        cols = 1.0 / (p.rotation_hz * p.column_period_s)
        h = (int(round(cols)), -np.pi, np.pi * (1 - 2 / round(cols)))
        e = np.sort(p.elevations_rad)
        v = (len(e), float(e[0]), float(e[-1]))
        d = np.diff(e)
        if len(d) and np.ptp(d) > 1e-6:
            limits.append("non-uniform channel elevations (SDF spaces the vertical "
                          f"samples evenly from {np.degrees(e[0]):.2f} to "
                          f"{np.degrees(e[-1]):.2f} deg)")
        if abs(cols - round(cols)) > 1e-3:
            limits.append(f"a non-integer number of columns per turn ({cols:.2f}; "
                          f"written as {round(cols)})")
        if np.ptp(p.azimuth_offsets_rad) > 0:
            limits.append("per-channel azimuth offsets")
    elif spec.kind == "profiler":
        rate = p.profile_rate_hz
        b0, b1 = (float(np.mod(b, 2 * np.pi)) for b in p.blind_sector_rad)
        # Scan from the blind sector's end round to its start (0 = up, towards +y).
        lo, hi = b1 - 2 * np.pi, b0
        n = int(round(p.points_per_profile * (hi - lo) / (2 * np.pi)))
        h = (n, lo, hi)
        v = (1, 0.0, 0.0)
    else:
        raise GazeboExportError(f"Expected a spinning lidar or a profiler for the robot, "
                                f"got {spec.name} ({spec.kind}); a TLS station has no "
                                "Gazebo sensor model.")
    sigma = float(np.hypot(ph.range_sigma_floor_m, ph.range_sigma_m))
    xml = f"""<sensor name="{escape(name)}" type="gpu_lidar">
  <pose>{pose}</pose>
  <topic>{escape(topic)}</topic>
  <update_rate>{rate:g}</update_rate>
  <always_on>true</always_on>
  <visualize>true</visualize>
  <lidar>
    <scan>
      <horizontal>
        <samples>{h[0]}</samples>
        <resolution>1</resolution>
        <min_angle>{h[1]:.9f}</min_angle>
        <max_angle>{h[2]:.9f}</max_angle>
      </horizontal>
      <vertical>
        <samples>{v[0]}</samples>
        <resolution>1</resolution>
        <min_angle>{v[1]:.9f}</min_angle>
        <max_angle>{v[2]:.9f}</max_angle>
      </vertical>
    </scan>
    <range>
      <min>{ph.range_min_m:g}</min>
      <max>{ph.range_max_m:g}</max>
      <resolution>{RANGE_RESOLUTION_M:g}</resolution>
    </range>
    <noise>
      <type>gaussian</type>
      <mean>0</mean>
      <stddev>{sigma:.6g}</stddev>
    </noise>
  </lidar>
</sensor>"""
    return _indent(xml, indent), limits


def _noise(white: float, bias: float, walk: float) -> str:
    return (f'<noise type="gaussian"><mean>0</mean><stddev>{white:.6g}</stddev>'
            f"<bias_mean>0</bias_mean><bias_stddev>{bias:.6g}</bias_stddev>"
            f"<dynamic_bias_stddev>{walk:.6g}</dynamic_bias_stddev>"
            "<dynamic_bias_correlation_time>"
            f"{IMU_BIAS_CORRELATION_S:g}</dynamic_bias_correlation_time></noise>")


def imu_sdf(imu: ImuModel, *, name: str = "imu", topic: str = IMU_GZ_TOPIC,
            pose: str = "0 0 0 0 0 0", indent: int = 8) -> str:
    """XML of a ``<sensor type="imu">`` with the noise of ``imu`` (``ImuModel``).

    Per axis, SDF's Gaussian noise holds the white noise per sample (density x
    sqrt(rate), ``ImuModel.sample_sigmas``), the turn-on bias (``bias_stddev``) and the
    bias random walk (``dynamic_bias_stddev`` = the Kalibr random-walk density, see
    ``IMU_BIAS_CORRELATION_S``); the update rate is ``imu.rate_hz``."""
    gyro_white, accel_white, _, _ = imu.sample_sigmas()
    parts = []
    for tag, white, bias, walk in (
            ("angular_velocity", gyro_white, imu.gyro_bias_sigma, imu.gyro_random_walk),
            ("linear_acceleration", accel_white, imu.accel_bias_sigma,
             imu.accel_random_walk)):
        axes = "\n".join(f"    <{a}>{_noise(white, bias, walk)}</{a}>" for a in "xyz")
        parts.append(f"  <{tag}>\n{axes}\n  </{tag}>")
    body = "\n".join(parts)
    xml = f"""<sensor name="{escape(name)}" type="imu">
  <pose>{pose}</pose>
  <topic>{escape(topic)}</topic>
  <update_rate>{imu.rate_hz:g}</update_rate>
  <always_on>true</always_on>
  <imu>
{body}
  </imu>
</sensor>"""
    return _indent(xml, indent)


def _f(x: float) -> str:
    """A float written so that it reads back exactly (repr's 17 digits)."""
    return repr(float(x))


def camera_sdf(cam: CameraSpec, *, name: str | None = None, topic: str,
               pose: str = "0 0 0 0 0 0", indent: int = 8) -> tuple[str, list[str]]:
    """(XML of the camera's ``<sensor>``, list of what SDF cannot express about it).

    Intrinsics, exactly (``_f``): ``<horizontal_fov>`` = 2 atan(w / (2 fx)) for a
    pinhole, w / fx for a fisheye (equidistant: r = f theta, through the image's edges),
    ``<image>`` w x h, ``<clip>`` (a depth camera's depth range), ``<update_rate>`` the
    frame rate; a pinhole's Brown-Conrady ``<distortion>`` k1 k2 k3 p1 p2 (OpenCV's
    definitions, which gz-rendering's distortion pass applies) and ``<center>``, and
    ``<lens><intrinsics>`` fx fy cx cy.

    DECISION: SDF's image coordinates start at the top-left pixel's outer corner: its
    defaults put the principal point at the image's centre as ``<cx>`` = w / 2 (160 for
    320 pixels) and ``<center>`` = 0.5 0.5; ours (OpenCV's) start at that pixel's
    centre, so ``<cx>`` = cx + 0.5 and ``<center>`` = ((cx + 0.5) / w, (cy + 0.5) / h)
    (a centred camera's (w - 1) / 2 gives exactly w / 2 and 0.5). gz-sensors copies
    ``<intrinsics>`` into the CameraInfo it publishes, which therefore reads 0.5 px more
    than OpenCV's cx, cy (every Gazebo camera's camera_info does: cx = w / 2)."""
    if cam.model == "fisheye" and cam.kind != "color":
        raise GazeboExportError(f"Expected a pinhole lens for a {cam.kind} camera in "
                                f"Gazebo, got the fisheye {cam.name}; gz-sensors' wide-"
                                "angle camera is colour only: pass a pinhole --camera.")
    w, h = cam.width, cam.height
    limits = ["exposure, shot and read noise and the full well's clip (written without "
              "image noise: SDF has one Gaussian sigma in image units)",
              "the tunnel's albedo per surface (one material for the whole lining)",
              "photometric lamps: Gazebo's <intensity> is relative (1 = "
              f"{LIGHT_REF_CD:g} cd), the spot's ramp is OGRE's falloff between the "
              "cones, not linear in angle"]
    if not cam.global_shutter:
        limits.append(f"the rolling shutter ({cam.line_time_s * 1e6:g} us per row; "
                      "Gazebo renders a frame at one instant)")
    if cam.kind == "depth":
        limits.append("depth as 32-bit float metres (Gazebo), not the RealSense "
                      "driver's 16UC1 millimetres")
    if cam.kind == "thermal":
        limits.append("surface temperatures and emissivities (Gazebo's thermal camera "
                      "sees a visual's <temperature> or the world's ambient), the "
                      "spectral band and the NETD")
    near, far = cam.depth_range_m if cam.depth_range_m is not None else CAMERA_CLIP_M
    cx_sdf, cy_sdf = cam.cx + 0.5, cam.cy + 0.5
    if cam.model == "pinhole":
        stype = _SENSOR_TYPES[cam.kind]
        hfov = 2.0 * np.arctan(w / (2.0 * cam.fx))
        k1, k2, p1, p2, k3 = (float(x) for x in cam.distortion)
        lens = f"""  <distortion>
    <k1>{_f(k1)}</k1>
    <k2>{_f(k2)}</k2>
    <k3>{_f(k3)}</k3>
    <p1>{_f(p1)}</p1>
    <p2>{_f(p2)}</p2>
    <center>{_f(cx_sdf / w)} {_f(cy_sdf / h)}</center>
  </distortion>
  <lens>
    <type>gnomonical</type>
    <scale_to_hfov>true</scale_to_hfov>
    <intrinsics>
      <fx>{_f(cam.fx)}</fx>
      <fy>{_f(cam.fy)}</fy>
      <cx>{_f(cx_sdf)}</cx>
      <cy>{_f(cy_sdf)}</cy>
      <s>0</s>
    </intrinsics>
  </lens>"""
    else:
        stype = "wideanglecamera"
        hfov = w / cam.fx
        if np.any(cam.distortion != 0):
            limits.append("the Kannala-Brandt distortion k1-k4 (the wide-angle camera's "
                          "equidistant lens is written without it)")
        if abs(cam.fy - cam.fx) > 1e-9 * cam.fx or abs(cx_sdf - w / 2) > 1e-9 * w or \
                abs(cy_sdf - h / 2) > 1e-9 * h:
            limits.append("a fisheye's fy != fx or off-centre principal point (the "
                          "wide-angle camera scales its lens to <horizontal_fov>)")
        # The corners see furthest off the axis: theta = r / f (equidistant).
        cutoff = min(float(np.hypot(w / 2.0, h / 2.0) / cam.fx), np.pi)
        lens = f"""  <lens>
    <type>equidistant</type>
    <scale_to_hfov>true</scale_to_hfov>
    <cutoff_angle>{_f(cutoff)}</cutoff_angle>
    <env_texture_size>1024</env_texture_size>
  </lens>"""
    if hfov < 0.1 or hfov > 2 * np.pi:
        raise GazeboExportError(f"Expected a camera whose horizontal field of view SDF "
                                f"can hold (0.1-6.283 rad), got {hfov:.4g} rad for "
                                f"{cam.name}; pass another --camera.")
    depth = "" if cam.kind != "depth" else f"""
  <depth_camera>
    <output>depths</output>
    <clip>
      <near>{_f(near)}</near>
      <far>{_f(far)}</far>
    </clip>
  </depth_camera>"""
    xml = f"""<sensor name="{escape(name or cam.name)}" type="{stype}">
  <pose>{pose}</pose>
  <topic>{escape(topic)}</topic>
  <update_rate>{_f(cam.frame_rate_hz)}</update_rate>
  <always_on>true</always_on>
  <visualize>false</visualize>
  <camera name="{escape(name or cam.name)}">
  <horizontal_fov>{_f(hfov)}</horizontal_fov>
  <image>
    <width>{w}</width>
    <height>{h}</height>
    <format>{IMAGE_FORMATS[cam.kind]}</format>
  </image>
  <clip>
    <near>{_f(near)}</near>
    <far>{_f(far)}</far>
  </clip>{depth}
{lens}
  </camera>
</sensor>"""
    # The camera's children sit one level in.
    lines = xml.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("  <camera "))
    end = next(i for i, ln in enumerate(lines) if ln == "  </camera>")
    lines[start + 1:end] = ["  " + ln for ln in lines[start + 1:end]]
    return _indent("\n".join(lines), indent), limits


def optical_frame_sdf(name: str, pose: str, link: str = "chassis", indent: int = 6) -> str:
    """A model ``<frame>`` ``name`` attached to ``link`` at ``pose`` (in ``link``): the
    camera's optical frame (z forward, x right, y down; REP 103)."""
    pad = " " * indent
    return (f'{pad}<frame name="{escape(name)}" attached_to="{escape(link)}">\n'
            f'{pad}  <pose relative_to="{escape(link)}">{pose}</pose>\n{pad}</frame>')


def lamp_light_sdf(name: str, kind: str, position: Any, direction: Any,
                   intensity_cd: float, beam_half_angle_rad: float,
                   cutoff_half_angle_rad: float, indent: int = 8) -> str:
    """A ``<light>`` of a lamp, its position and beam ``direction`` (unit) in the
    parent's frame (the light's pose carries no rotation: the direction is the
    link's).

    Inverse-square falloff (``<constant>`` 0, ``<linear>`` 0, ``<quadratic>`` 1, OGRE's
    1 / (c + l d + q d^2)) out to ``<range>`` where I / d^2 = ``LIGHT_RANGE_LUX``;
    ``<intensity>`` I / ``LIGHT_REF_CD``. A spot's ``<inner_angle>`` and
    ``<outer_angle>`` are the full cone angles (2 x the beam and cutoff half-angles: SDF
    describes them as OGRE does its spotlight range, "the angle covered by the bright
    inner cone"), ``<falloff>`` 1 (linear)."""
    p = np.asarray(position, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    pad = " " * indent
    rng = float(np.sqrt(max(intensity_cd, 0.0) / LIGHT_RANGE_LUX))
    spot = "" if kind != "spot" else (
        f"\n{pad}  <spot><inner_angle>{_f(2 * beam_half_angle_rad)}</inner_angle>"
        f"<outer_angle>{_f(2 * cutoff_half_angle_rad)}</outer_angle>"
        "<falloff>1</falloff></spot>")
    return (f'{pad}<light name="{escape(name)}" type="{"spot" if kind == "spot" else "point"}">\n'
            f"{pad}  <pose>{' '.join(_f(x) for x in p)} 0 0 0</pose>\n"
            f"{pad}  <cast_shadows>true</cast_shadows>\n"
            f"{pad}  <intensity>{_f(intensity_cd / LIGHT_REF_CD)}</intensity>\n"
            f"{pad}  <diffuse>1 1 1 1</diffuse><specular>0.1 0.1 0.1 1</specular>\n"
            f"{pad}  <attenuation><range>{_f(max(rng, 0.1))}</range><constant>0</constant>"
            "<linear>0</linear><quadratic>1</quadratic></attenuation>\n"
            f"{pad}  <direction>{' '.join(_f(x) for x in d)}</direction>{spot}\n"
            f"{pad}</light>")


# ----------------------------------------------------------------------------- bridge
def bridge_entries(fl: Flavour, cloud_ros_topic: str,
                   camera_topics: tuple[str, str] | None = None) -> list[dict[str, str]]:
    """The ``ros_gz_bridge`` entries of the world (module doc), in the documented YAML
    config's keys: ros_topic_name, gz_topic_name, ros_type_name, gz_type_name,
    direction (ros_gz_bridge ``bridge_config.cpp``); with ``camera_topics`` (image,
    info), the camera's Image and CameraInfo, the same names on both sides."""
    from sensors.bag import IMU_TOPIC, ODOMETRY_TOPIC

    m = fl.msgs
    rows = [(CLOCK_TOPIC, CLOCK_TOPIC, "rosgraph_msgs/msg/Clock", "Clock", "GZ_TO_ROS"),
            (cloud_ros_topic, LIDAR_GZ_TOPIC + POINTS_SUFFIX, "sensor_msgs/msg/PointCloud2",
             "PointCloudPacked", "GZ_TO_ROS"),
            (IMU_TOPIC, IMU_GZ_TOPIC, "sensor_msgs/msg/Imu", "IMU", "GZ_TO_ROS"),
            (ODOMETRY_TOPIC, GT_ODOMETRY_TOPIC, "nav_msgs/msg/Odometry", "Odometry",
             "GZ_TO_ROS"),
            ("/tf", pose_topic(), "tf2_msgs/msg/TFMessage", "Pose_V", "GZ_TO_ROS"),
            (CMD_VEL_TOPIC, CMD_VEL_TOPIC, "geometry_msgs/msg/Twist", "Twist",
             "ROS_TO_GZ")]
    if camera_topics is not None:
        image, info = camera_topics
        rows += [(image, image, "sensor_msgs/msg/Image", "Image", "GZ_TO_ROS"),
                 (info, info, "sensor_msgs/msg/CameraInfo", "CameraInfo", "GZ_TO_ROS")]
    return [{"ros_topic_name": r, "gz_topic_name": g, "ros_type_name": rt,
             "gz_type_name": m + gt, "direction": d} for r, g, rt, gt, d in rows]


def bridge_yaml(entries: list[dict[str, str]], fl: Flavour) -> str:
    """The entries as a ``parameter_bridge`` ``config_file`` (a YAML list)."""
    lines = [f"# ros_gz_bridge configuration for {fl.title} and {fl.ros}, written by "
             "tunnelsim.", "# Run: ros2 run ros_gz_bridge parameter_bridge --ros-args "
             "-p config_file:=$PWD/bridge.yaml"]
    for e in entries:
        lines += [f'- {k}: "{v}"' if i == 0 else f'  {k}: "{v}"'
                  for i, (k, v) in enumerate(e.items()) if k != "direction"]
        lines.append(f"  direction: {e['direction']}")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ world
def _inertia_box(m: float, x: float, y: float, z: float) -> str:
    return (f"<inertial><mass>{m:g}</mass><inertia><ixx>{m * (y * y + z * z) / 12:.6g}</ixx>"
            f"<iyy>{m * (x * x + z * z) / 12:.6g}</iyy><izz>{m * (x * x + y * y) / 12:.6g}"
            "</izz><ixy>0</ixy><ixz>0</ixz><iyz>0</iyz></inertia></inertial>")


def chassis_z() -> float:
    """Height of the chassis link's frame above the model's origin (base_link) (m)."""
    return BASE["clearance"] + BASE["height"] / 2


def robot_sdf(fl: Flavour, pose: str, sensor_xml: str, imu_xml: str,
              pose_rate_hz: float, *, track_m: float | None = None,
              wheel_radius_m: float | None = None, frames_xml: str = "") -> str:
    """The robot model: chassis (carrying the lidar and the IMU), two driven wheels and
    a caster; DiffDrive, PosePublisher and OdometryPublisher systems (module doc).
    The model's origin is base_link (the ground contact plane); ``track_m`` and
    ``wheel_radius_m`` (the platform's; ``BASE``'s by default) place the wheels,
    centred ``track_m`` apart. ``frames_xml``: model-level ``<frame>``s (a camera's
    optical frame)."""
    b = dict(BASE)
    if track_m:
        b["track"] = track_m
    if wheel_radius_m:
        b["wheel_radius"] = wheel_radius_m
    zc = chassis_z()
    wr, ww = b["wheel_radius"], b["wheel_width"]
    wheels = []
    joints = []
    for side, y in (("left", b["track"] / 2), ("right", -b["track"] / 2)):
        wheels.append(f"""      <link name="{side}_wheel">
        <pose>0 {y:.4f} {wr:.4f} -1.5707963 0 0</pose>
        {_inertia_box(0.3, 2 * wr, 2 * wr, ww)}
        <collision name="collision"><geometry><cylinder><radius>{wr}</radius>
          <length>{ww}</length></cylinder></geometry></collision>
        <visual name="visual"><geometry><cylinder><radius>{wr}</radius>
          <length>{ww}</length></cylinder></geometry></visual>
      </link>""")
        joints.append(f"""      <joint name="{side}_wheel_joint" type="revolute">
        <parent>chassis</parent><child>{side}_wheel</child>
        <axis><xyz expressed_in="__model__">0 1 0</xyz></axis>
      </joint>""")
    drive = fl.plugin("diff-drive", "DiffDrive", f"""
<left_joint>left_wheel_joint</left_joint>
<right_joint>right_wheel_joint</right_joint>
<wheel_separation>{b["track"]}</wheel_separation>
<wheel_radius>{wr}</wheel_radius>
<topic>{CMD_VEL_TOPIC}</topic>
<odom_topic>/model/{ROBOT}/wheel_odometry</odom_topic>
<tf_topic>/model/{ROBOT}/wheel_tf</tf_topic>""", indent=6)
    # PosePublisher: the model (in the world), its links and sensors, as one Pose_V;
    # publish_nested_model_pose also publishes the top-level model (PosePublisher.cc).
    poses = fl.plugin("pose-publisher", "PosePublisher", f"""
<publish_link_pose>true</publish_link_pose>
<publish_sensor_pose>true</publish_sensor_pose>
<publish_collision_pose>false</publish_collision_pose>
<publish_visual_pose>false</publish_visual_pose>
<publish_nested_model_pose>true</publish_nested_model_pose>
<use_pose_vector_msg>true</use_pose_vector_msg>
<update_frequency>{pose_rate_hz:g}</update_frequency>""", indent=6)
    odom = fl.plugin("odometry-publisher", "OdometryPublisher", f"""
<odom_frame>tunnel_world</odom_frame>
<robot_base_frame>{ROBOT}</robot_base_frame>
<odom_publish_frequency>{pose_rate_hz:g}</odom_publish_frequency>
<odom_topic>{GT_ODOMETRY_TOPIC}</odom_topic>
<tf_topic>{GT_ODOMETRY_TOPIC}/tf</tf_topic>
<dimensions>3</dimensions>""", indent=6)
    return f"""    <model name="{ROBOT}">
      <pose>{pose}</pose>
      <link name="chassis">
        <pose>0 0 {zc:.4f} 0 0 0</pose>
        {_inertia_box(b["mass"], b["length"], b["width"], b["height"])}
        <collision name="collision"><geometry><box><size>{b["length"]} {b["width"]}
          {b["height"]}</size></box></geometry></collision>
        <visual name="visual"><geometry><box><size>{b["length"]} {b["width"]}
          {b["height"]}</size></box></geometry>
          <material><diffuse>0.9 0.6 0.1 1</diffuse><ambient>0.9 0.6 0.1 1</ambient>
          </material></visual>
{sensor_xml}
{imu_xml}
      </link>
      <link name="caster">
        <pose>{-b["length"] / 2 + 0.03:.4f} 0 {wr / 2:.4f} 0 0 0</pose>
        {_inertia_box(0.1, wr, wr, wr)}
        <collision name="collision"><geometry><sphere><radius>{wr / 2}</radius></sphere>
          </geometry><surface><friction><ode><mu>0</mu><mu2>0</mu2></ode></friction>
          </surface></collision>
      </link>
{chr(10).join(wheels)}
{chr(10).join(joints)}
{frames_xml}
      <joint name="caster_joint" type="ball"><parent>chassis</parent><child>caster</child>
      </joint>
{drive}
{poses}
{odom}
    </model>"""


def crs_suffix(crs_name: str | None) -> str:
    """" in EPSG:2056 (CH1903+ / LV95)" for the texts that name the local origin (no
    '--', which an XML comment cannot hold)."""
    return "" if crs_name is None else " in " + crs_name.replace("--", "- -")


def origin_frame(origin: Any, crs_name: str | None, indent: int = 4) -> str:
    """``<frame name="map_origin">``: where the CRS origin lies in the world's local
    coordinates (world = local + origin, so the frame sits at -origin), with the CRS
    named in a ``tunnelsim:crs`` element when stated."""
    o = np.asarray(origin, dtype=np.float64)
    pad = " " * indent
    crs = "" if crs_name is None else \
        f"\n{pad}  <tunnelsim:crs>{escape(crs_name)}</tunnelsim:crs>"
    return (f'{pad}<frame name="map_origin">\n{pad}  <pose>{-o[0]:.3f} {-o[1]:.3f} '
            f"{-o[2]:.3f} 0 0 0</pose>{crs}\n{pad}</frame>")


def world_sdf(fl: Flavour, mesh_name: str, sensor_name: str, org: str, lim_text: str,
              lights: str, robot: str, frame: str, crs_name: str | None = None) -> str:
    """world.sdf: physics, systems, scene, the origin frame, lights, the tunnel model
    and the robot."""
    sensors = fl.plugin("sensors", "Sensors", "<render_engine>ogre2</render_engine>")
    systems = "\n".join([fl.plugin("physics", "Physics"),
                         fl.plugin("user-commands", "UserCommands"),
                         fl.plugin("scene-broadcaster", "SceneBroadcaster"),
                         sensors, fl.plugin("imu", "Imu")])
    return f"""<?xml version="1.0"?>
<!-- Generated by tunnelsim from {escape(mesh_name)} for {escape(fl.title)}.
     Coordinates are local: world = local + ({org}) m{escape(crs_suffix(crs_name))}
     (frame map_origin). Sensor {escape(sensor_name)} translated to gpu_lidar. SDF
     cannot express:
{escape(lim_text)}
     Run: {escape(fl.run_line())}
     ROS 2 ({escape(fl.ros)}): ros_gz_bridge with bridge.yaml (README.txt) -->
<sdf version="1.9" xmlns:tunnelsim="https://github.com/tunnelsim">
  <world name="tunnel_world">
    <physics name="default" type="ode"><max_step_size>0.002</max_step_size>
      <real_time_factor>1</real_time_factor></physics>
{systems}
    <gravity>0 0 -9.81</gravity>
    <scene>
      <ambient>0.15 0.15 0.15 1</ambient>
      <background>0 0 0 1</background>
      <shadows>false</shadows>
      <grid>false</grid>
    </scene>
{frame}
{lights}
    <include>
      <uri>model://tunnel</uri>
      <name>tunnel</name>
      <static>true</static>
      <pose>0 0 0 0 0 0</pose>
    </include>
{robot}
  </world>
</sdf>
"""


def model_sdf(org: str, laser_retro: float, crs_name: str | None = None,
              crs_wkt: str | None = None) -> str:
    """models/tunnel/model.sdf: the static tunnel, visual OBJ and collision STL with
    ``laser_retro``; the local origin and (when stated) the CRS as tunnelsim custom
    elements."""
    crs = ""
    if crs_wkt is not None:
        name = escape(crs_name or "", {'"': "&quot;"})
        crs = (f'\n    <tunnelsim:crs name="{name}">'
               f"{escape(' '.join(crs_wkt.split()))}</tunnelsim:crs>")
    return f"""<?xml version="1.0"?>
<sdf version="1.9" xmlns:tunnelsim="https://github.com/tunnelsim">
  <model name="tunnel">
    <static>true</static>
    <tunnelsim:origin>{org}</tunnelsim:origin>{crs}
    <link name="lining">
      <visual name="visual">
        <geometry><mesh><uri>model://tunnel/meshes/tunnel.obj</uri></mesh></geometry>
        <laser_retro>{laser_retro:.4g}</laser_retro>
      </visual>
      <collision name="collision">
        <laser_retro>{laser_retro:.4g}</laser_retro>
        <geometry><mesh><uri>model://tunnel/meshes/tunnel_collision.stl</uri></mesh>
        </geometry>
      </collision>
    </link>
  </model>
</sdf>
"""


def model_config(mesh_name: str, n_faces: int, n_collision: int, org: str,
                 crs_name: str | None = None) -> str:
    """models/tunnel/model.config: Gazebo's model metadata."""
    return f"""<?xml version="1.0"?>
<model>
  <name>tunnel</name>
  <version>1.0</version>
  <sdf version="1.9">model.sdf</sdf>
  <author><name>tunnelsim</name></author>
  <description>Tunnel mesh from {escape(mesh_name)}: {n_faces:,} triangles
    (collision {n_collision:,}). Local coordinates: world = local + ({org}) m{escape(
        crs_suffix(crs_name))}.</description>
</model>
"""
