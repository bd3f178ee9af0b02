"""Export a tunnel and a sensor rig to Gazebo (SDFormat 1.9) for Gazebo Harmonic or
Ignition Gazebo Fortress: a world folder that loads as is and talks to ROS 2.

    world_dir/
      world.sdf                      the world: systems, scene, lights, the origin frame,
                                     the tunnel, the robot (lidar, IMU, ground truth)
      bridge.yaml                    ros_gz_bridge configuration (cloud, IMU, TF,
                                     ground-truth odometry, clock, cmd_vel)
      models/tunnel/model.config     Gazebo model metadata (local origin recorded)
      models/tunnel/model.sdf        static model: visual mesh + collision mesh
      models/tunnel/meshes/tunnel.obj            visual mesh (OBJ), local coordinates
      models/tunnel/meshes/tunnel_collision.stl  collision mesh (decimated when large)
      README.txt                     how to run it, and what SDF cannot express
      robot.urdf, robot.launch.py    the robot (``sensors.robot``, the drive's
                                     ground_robot): base_link -> sensor / imu_link
                                     (/ the camera's link -> optical frame), and
                                     robot_state_publisher (ROS 2 Python launch file)

The robot is the ground_robot platform's description (issue 30): the model's origin is
base_link on the ground contact plane, the sensor on its mast (``body.mast_height_m``),
the IMU in its body (``[mounts]``), the wheels the platform's track apart; the sensor
poses in the SDF are the URDF's base_link -> sensor (``robot_description``).

The flavour (``gazebo_sdf.FLAVOURS``) picks the plugin and message names, the resource
path variable and the launch line; ``gazebo_sdf`` documents the topics and where each
name comes from.

Coordinates: metres, Z up, shifted to a local origin (UTM-sized numbers would lose
millimetres in Gazebo's float32 render buffers): the robot's start rounded to whole
metres, the ``map -> odom`` a drive's bag states for a robot starting there
(``Trajectory.origin``); the origin is the world's frame
``map_origin`` (at -origin: world = local + origin), and is recorded in
``model.config``, ``model.sdf`` (a ``tunnelsim:origin`` custom element) and README.
When the tunnel states a coordinate reference system (its JSON's ``crs``, or a
``<mesh>.prj`` sidecar; ``sensors.io.cloudread.cloud_crs_text``), the same places name
it (``tunnelsim:crs`` holds the WKT in model.sdf, the name in the frame).

DECISION: no ``<spherical_coordinates>``. Gazebo places that origin on the WGS 84
ellipsoid in a local tangent plane: a projected CRS's grid north differs from true
north by the meridian convergence (up to ~3 deg at a UTM zone's edge), its metres by
the projection's scale (-400 to +400 ppm), its heights are orthometric, not
ellipsoidal, and SDF's ``heading_deg`` sign changed meaning between versions. Written
without all of that, a simulated GPS would disagree with the survey by metres and
look authoritative; the CRS and the origin are recorded instead.

Robot start: on a generated tunnel (its JSON holds the alignment) 1 m into it (or at
``chainage_m``) on the floor under the axis, facing along it. On any other mesh, or
with ``waypoints``, at the start of the route ``sensors.route.find_route`` finds (the
one ``tunnelsim drive --along auto`` drives), facing along it; the lamps then hang
along that route.

With a camera (``camera``, ``tunnelsim gazebo --camera``): its sensor on the chassis
where a drive's camera sits by default (``sensors.camera_drive.default_camera_mount``:
10 cm below the lidar's origin, level, looking ahead), its optical frame as a model
``<frame>`` (and both frames in robot.urdf, the drive's names: ``sensors.robot.
camera_link``), its image and CameraInfo in bridge.yaml, and the ground_robot platform's
``[[lamps]]`` as spot lights on the chassis (``gazebo_sdf.camera_sdf``,
``lamp_light_sdf``). DECISION: the lamps come with the camera only: the lidar needs no
light, and a world exported before the camera existed stays as it was.

The lidar is translated from our spec into ``<sensor type="gpu_lidar">``
(``gazebo_sdf.lidar_sdf``); the IMU carries ``sensors.bag.ImuModel``'s noise
(``gazebo_sdf.imu_sdf``). What SDF cannot express is listed in a comment inside
``world.sdf`` and returned for the CLI summary.

``laser_retro``: Gazebo Sim returns a visual's ``laser_retro`` as the gpu_lidar's
intensity unchanged (gz-sim ``SceneManager`` stores it as the visual's "laser_retro"
user data; gz-rendering's GpuRays test expects that value back in the intensity
channel), so its scale is the consumer's. We write Velodyne's calibrated reflectivity:
0-100 for diffuse targets of 0-100 % reflectivity (VLP-16 User Manual, "Calibrated
Reflectivity"), i.e. 100 x the mesh's area-weighted mean face reflectivity.
DECISION: one value for the whole lining (one visual); splitting the mesh by material
would multiply visuals and meshes for a number no driver calibrates against.

Collision mesh: vertex clustering on a uniform grid (Rossignac & Borrel 1993,
"Multi-resolution 3D approximations for rendering complex scenes"): vertices in one cell
merge to their mean, degenerate triangles are dropped.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.fileio import atomic_writer
from sensors.robot import rpy_of
from survey.errors import GazeboExportError

from .gazebo_sdf import (BASE, FLAVOURS, RANGE_RESOLUTION_M, ROBOT, Flavour,
                         bridge_entries, bridge_yaml, camera_sdf, chassis_z, crs_suffix,
                         imu_sdf, lamp_light_sdf, lidar_sdf, model_config, model_sdf,
                         optical_frame_sdf, origin_frame, robot_sdf, world_sdf)
from .gazebo_sdf import flavour as flavour_of

if TYPE_CHECKING:
    from raytrace import Scene
    from sensors.camera import CameraSpec
    from sensors.imu import ImuModel
    from sensors.spec_types import SensorSpec
    from survey.world.alignment import Alignment

__all__ = ["COLLISION_MAX_TRIANGLES", "LASER_RETRO_SCALE",
           "MAX_METRIC_EXTENT_M", "ROUTE_CLEARANCE_M", "ROUTE_HEIGHT_M",
           "decimate",
           "export_gazebo", "laser_retro", "unit_warnings", "write_obj"]

Floats = NDArray[np.float64]

#: The visual mesh is decimated for collisions above this many triangles.
COLLISION_MAX_TRIANGLES = 200_000
#: A mesh larger than this (m) is probably not in metres.
MAX_METRIC_EXTENT_M = 10_000.0
#: laser_retro per unit reflectivity: Velodyne's calibrated reflectivity scale (module
#: doc).
LASER_RETRO_SCALE = 100.0
#: Height of the route above the floor (m) where the mesh has no JSON: the default of
#: ``tunnelsim drive --height``, so that the robot starts where that drive does.
ROUTE_HEIGHT_M = 0.5
#: Distance the route keeps from the mesh where it can (m): drive's ``--clearance``
#: default.
ROUTE_CLEARANCE_M = 0.2
#: Distance along the route (m) over which the robot's start heading is taken.
HEADING_BASE_M = 0.5


# ------------------------------------------------------------------------------- checks
def unit_warnings(vertices: ArrayLike) -> list[str]:
    """Plain-language warnings about units and axes of a tunnel mesh (n, 3)."""
    v = np.asarray(vertices, dtype=np.float64)
    ext = v.max(axis=0) - v.min(axis=0)
    out = []
    big = float(ext.max())
    if big > MAX_METRIC_EXTENT_M:
        alt = [f"in {unit} it would be {big / f:,.0f} m long" for f, unit in
               ((100.0, "centimetres"), (1000.0, "millimetres"))
               if big / f <= MAX_METRIC_EXTENT_M]
        out.append(f"mesh extents {big:,.0f} m exceed {MAX_METRIC_EXTENT_M:,.0f} m, so it "
                   f"is probably not in metres ({'; '.join(alt) or 'unknown unit'}); "
                   "Gazebo expects metres: scale it first")
    elif big < 0.5:
        out.append(f"mesh extents {big:.3f} m: far too small for a tunnel; is it in "
                   "kilometres?")
    if ext[2] > max(ext[0], ext[1]):
        out.append(f"the mesh is tallest along Z ({ext[2]:.1f} m vs {ext[0]:.1f} x "
                   f"{ext[1]:.1f} m in X, Y): a tunnel runs horizontally, so it may be "
                   "Y-up; Gazebo is Z-up")
    return out


def decimate(vertices: ArrayLike, faces: ArrayLike, cell_m: float
             ) -> tuple[Floats, NDArray[np.int64]]:
    """Vertex clustering (see module doc): (vertices (k, 3), faces (j, 3))."""
    v = np.asarray(vertices, dtype=np.float64)
    key = np.floor((v - v.min(axis=0)) / cell_m).astype(np.int64)
    _, cl, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    cl = cl.ravel()
    nv = np.zeros((len(counts), 3))
    np.add.at(nv, cl, v)
    nv /= counts[:, None]
    f = cl[np.asarray(faces)]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    return nv, f[np.sort(first)]


def _decimate_to(vertices: Floats, faces: NDArray[np.int64], max_tris: int
                 ) -> tuple[Floats, NDArray[np.int64]]:
    if len(faces) <= max_tris:
        return vertices, faces
    ext = np.ptp(vertices, axis=0)
    cell = float(np.sqrt(np.prod(np.sort(ext)[1:]) / max(len(faces), 1)))
    for _ in range(30):
        v2, f2 = decimate(vertices, faces, cell)
        if len(f2) <= max_tris:
            return v2, f2
        cell *= 1.3
    return v2, f2


def _check_output(out: Path, force: bool, mount: str) -> None:
    if out.exists() and not force:
        raise GazeboExportError(f"Expected a new output folder, got '{out}' which exists; "
                                "pass --force to replace it.")
    if not out.parent.exists():
        raise GazeboExportError(f"Expected an existing parent folder for '{out}', got none.")
    if mount not in ("level", "down"):
        raise GazeboExportError(f"Expected mount 'level' or 'down', got {mount!r}.")


def robot_description(sensor: SensorSpec, mount: str, camera: CameraSpec | None = None
                      ) -> Any:
    """The world's robot (issue 30): the ground_robot platform's description
    (``sensors.robot``; base_link on the ground contact plane, the sensor on its mast,
    the IMU in its body), the sensor level, upside down (``mount`` "down"), or (a
    profiler) turned to scan the cross-section; with ``camera``, its body and optical
    frames where a drive puts a camera by default (module doc), so that robot.urdf
    holds the frames the camera's images name."""
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from sensors.camera_drive import default_camera_mount
    from sensors.robot import camera_link

    from sensors.pointcloud2 import GENERIC_DRIVER
    from sensors.platform_spec import load_platform
    from sensors.robot import RobotDescription
    from sensors.trajectory import Mount

    if sensor.kind == "profiler":
        m = Mount((0.0, 0.0, 0.0), Rotation.from_euler("xyz", [0.0, -np.pi / 2, 0.0]))
    elif mount == "down":
        m = Mount.pointing_down((0.0, 0.0, 0.0))
    else:
        m = Mount()
    desc = RobotDescription.from_platform(load_platform("ground_robot"),
                                          (sensor.driver or GENERIC_DRIVER).frame_id, m)
    if camera is None:
        return desc
    lidar_xyz, _ = desc.base_to_sensor()
    link = default_camera_mount(Mount(tuple(np.asarray(lidar_xyz).tolist())))
    return replace(desc, cameras=(camera_link(camera, link),))


def _pose_in_chassis(xyz: Floats, rot: Any) -> str:
    """An SDF pose in the chassis link (which sits ``chassis_z`` above the model's
    origin, base_link): SDF's rpy, like URDF's, is fixed-axis roll, pitch, yaw."""
    p = np.asarray(xyz, dtype=np.float64) - [0.0, 0.0, chassis_z()]
    return " ".join(f"{x:.15g}" for x in (*p, *rpy_of(rot)))


def _camera_parts(cam: CameraSpec, desc: Any) -> tuple[str, str, dict[str, Any]]:
    """(XML for the chassis link: the camera sensor and the platform's lamp lights,
    XML of the optical frame, facts for the result) of ``cam`` on the world's robot
    ``desc`` (module doc)."""
    from scipy.spatial.transform import Rotation

    from sensors.bag import camera_topics
    from sensors.camera_drive import LINK_FROM_OPTICAL
    from sensors.platform_spec import load_platform
    from sensors.shading import platform_lamps

    topics = camera_topics(cam)
    link = next(c.mount for c in desc.cameras if c.optical_frame == topics.frame_id)
    xyz = np.asarray(link.lever_arm_m, dtype=np.float64)
    sensor_xml, limits = camera_sdf(cam, topic=topics.image,
                                    pose=_pose_in_chassis(xyz, link.boresight))
    optical = link.boresight * Rotation.from_matrix(LINK_FROM_OPTICAL)
    frame_xml = optical_frame_sdf(topics.frame_id, _pose_in_chassis(xyz, optical))
    # The lamps of the world's robot (ground_robot), in the chassis link's frame.
    spec = load_platform("ground_robot")
    T = np.eye(4)
    T[2, 3] = -chassis_z()
    lamps = platform_lamps(spec, T)
    lights = [lamp_light_sdf(f"headlight_{i}", pl.kind, lp.position, lp.direction,
                             lp.intensity_cd, lp.beam_half_angle_rad,
                             lp.cutoff_half_angle_rad)
              for i, (pl, lp) in enumerate(zip(spec.lamps, lamps))]
    facts = {"name": cam.name, "kind": cam.kind, "topic": topics.image,
             "info_topic": topics.info, "optical_frame": topics.frame_id,
             "link": topics.link, "camera_link_xyz_m": xyz.tolist(), "lamps": len(lights),
             "limitations": limits}
    return "\n".join([sensor_xml, *lights]), frame_xml, facts


def _lamps(points: Floats, spacing_m: float) -> str:
    """Point lights at ``points`` (k, 3), local coordinates, lighting ``spacing_m``."""
    return "\n".join(f"""    <light name="lamp_{i}" type="point">
      <pose>{p[0]:.3f} {p[1]:.3f} {p[2]:.3f} 0 0 0</pose>
      <diffuse>1 0.95 0.85 1</diffuse><specular>0.2 0.2 0.2 1</specular>
      <attenuation><range>{1.5 * spacing_m:g}</range><constant>0.3</constant>
        <linear>0.05</linear><quadratic>0.005</quadratic></attenuation>
      <cast_shadows>false</cast_shadows>
    </light>""" for i, p in enumerate(points))


def _axis_lamps(al: Alignment, hc: float, spacing_m: float) -> Floats:
    """Lamp positions (world) along a tunnel axis, 1 m above the profile centre, every
    ``spacing_m``."""
    c0, c1 = al.chainage_range
    ls = np.arange(c0 + spacing_m / 2, c1, spacing_m)
    return np.asarray(al.to_world(ls, 0.0, hc), dtype=np.float64).reshape(-1, 3) + \
        [0.0, 0.0, 1.0]


def _route_lamps(scene: Scene, points: Floats, distance_m: Floats,
                 spacing_m: float) -> Floats:
    """Lamp positions (world) along a route, every ``spacing_m`` (one at the middle of a
    shorter route), half-way from the route point up to the roof above it (a ray cast
    up; 1 m above the point where none is hit)."""
    length = float(distance_m[-1])
    at = np.arange(spacing_m / 2, length, spacing_m) if length > spacing_m else \
        np.array([length / 2])
    p = points[np.minimum(np.searchsorted(distance_m, at), len(points) - 1)]
    up = scene.cast(p, np.array([0.0, 0.0, 1.0]))
    rise = np.where(np.isfinite(up.t), up.t / 2, 1.0)
    return p + np.column_stack([np.zeros((len(p), 2)), rise])


def laser_retro(reflectivity: ArrayLike | None, vertices: ArrayLike, faces: ArrayLike,
                default: float = 0.5) -> float:
    """``laser_retro`` of a mesh (module doc): ``LASER_RETRO_SCALE`` x the area-weighted
    mean of the per-face ``reflectivity`` (n_faces,) in [0, 1], or x ``default`` where
    the mesh has none."""
    if reflectivity is None:
        return LASER_RETRO_SCALE * float(default)
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[np.asarray(faces, dtype=np.int64)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                axis=1)
    r = np.asarray(reflectivity, dtype=np.float64)
    if area.sum() <= 0:
        return LASER_RETRO_SCALE * float(r.mean()) if len(r) else \
            LASER_RETRO_SCALE * float(default)
    return LASER_RETRO_SCALE * float(np.sum(area * r) / area.sum())


def _has_axis_json(mesh_path: str | Path) -> bool:
    """Whether the mesh has the generator's JSON with an alignment and a profile."""
    from sensors.io.tunnel_json import read_meta, sidecar

    js = sidecar(mesh_path)
    if not js.is_file():
        return False
    meta = read_meta(js)
    return "alignment" in meta and "profile" in meta


def _placement(mesh_path: str | Path, scene: Scene, chainage_m: float | None,
               waypoints: ArrayLike | None, route_height_m: float, spacing_m: float,
               route_clearance_m: float | None = None, voxel_m: float | None = None
               ) -> tuple[Floats, float, Floats, Any]:
    """(robot floor point (3,) world, yaw rad, lamp positions (k, 3) world, the Route or
    None): on the tunnel axis where the JSON gives one and no waypoints are asked,
    else at the start of the route found in the mesh (module doc)."""
    if waypoints is None and _has_axis_json(mesh_path):
        from survey.analysis.planning import axis_stations
        from survey.clouds.axis import tunnel_frame

        if route_clearance_m is not None or voxel_m is not None:
            raise GazeboExportError("Expected a route clearance or voxel only where a "
                                    "route is found (a mesh without its tunnel JSON, or "
                                    "with waypoints), got one for a generated tunnel's "
                                    "axis; leave --clearance and --voxel out or pass "
                                    "--waypoints.")
        _, _, al, hc = tunnel_frame(mesh_path, scene)
        s0 = al.chainage_range[0] + 1.0 if chainage_m is None else float(chainage_m)
        floor = np.asarray(axis_stations(scene, al, hc, [s0], height_m=0.0)[0],
                           dtype=np.float64)
        yaw = float(al.heading(np.array([s0]))[0])
        return floor, yaw, _axis_lamps(al, hc, spacing_m), None
    if chainage_m is not None:
        why = "waypoints" if waypoints is not None else "no tunnel JSON beside the mesh"
        raise GazeboExportError(f"Expected a start chainage only for a generated tunnel's "
                                f"axis, got one with {why}; the robot starts at the "
                                "route's first point: leave the chainage out.")
    from sensors.errors import RouteError
    from sensors.platform_spec import load_platform
    from sensors.route import find_route

    # DECISION: the route is the ground robot's (the world's robot is LIMO-sized, as
    # the ground_robot platform is): it keeps to ground that robot can cross.
    try:
        route = find_route(scene, waypoints=waypoints, height_m=route_height_m,
                           clearance_m=ROUTE_CLEARANCE_M if route_clearance_m is None
                           else route_clearance_m, voxel_m=voxel_m,
                           platform=load_platform("ground_robot"))
    except RouteError as exc:       # the world's robot is fixed: no --platform here
        raise RouteError(re.sub(r"pass --platform [^;]*?, or --waypoints",
                                "pass --waypoints", str(exc))) from None
    d, p = route.distance_m, route.points
    k = min(int(np.searchsorted(d, HEADING_BASE_M)), len(p) - 1)
    step = p[k] - p[0]
    yaw = float(np.arctan2(step[1], step[0]))
    return np.asarray(route.floor[0], dtype=np.float64), yaw, \
        _route_lamps(scene, p, d, spacing_m), route


def _readme(fl: Flavour, mesh_name: str, sensor_name: str, out_name: str, org: str,
            origin: Floats, lim_text: str, start: str, crs_name: str | None = None,
            crs_wkt: str | None = None, frame_id: str = "lidar",
            camera: dict[str, Any] | None = None) -> str:
    crs = "Coordinate reference system: none stated (local coordinates)\n" \
        if crs_wkt is None else (f"Coordinate reference system: {crs_name}\n  WKT: "
                                 f"{' '.join(crs_wkt.split())}\n")
    o = " ".join(f"--{a} {x:.3f}" for a, x in zip("xyz", origin))
    return (f"Gazebo world for {mesh_name} with {sensor_name} on a LIMO-sized robot, "
            f"for {fl.title}.\n"
            f"Run:     cd {out_name} && {fl.run_line()}\n"
            f"Bridge:  ros2 run ros_gz_bridge parameter_bridge --ros-args -p "
            f"config_file:=$PWD/bridge.yaml   ({fl.ros}; add -p use_sim_time:=true to "
            "your nodes)\n"
            f"Drive:   {fl.topic_cli} -t /cmd_vel -m {fl.msgs}Twist -p "
            "'linear: {x: 0.5}'\n"
            f"Start:   {start}\n"
            f"Local origin (world = local + origin): {org} m{crs_suffix(crs_name)}; SDF "
            "frame map_origin.\n"
            f"  As a ROS frame: ros2 run tf2_ros static_transform_publisher {o} "
            "--frame-id map --child-frame-id odom (the drive's bag states the same "
            "map -> odom)\n"
            f"{crs}"
            f"Frames (Gazebo's scoped names): tunnel_world -> {ROBOT} (its origin is "
            f"base_link, on the ground contact plane) -> {ROBOT}::chassis -> "
            f"{ROBOT}::chassis::{sensor_name}, {ROBOT}::chassis::imu\n"
            f"ROS frames (robot.urdf; ros2 launch ./robot.launch.py): base_link -> "
            f"mast_link -> {frame_id}, base_link -> imu_link, as the drive's bag\n"
            "Ground truth: /tf (PosePublisher) and /odometry/ground_truth "
            "(OdometryPublisher, frame tunnel_world)\n"
            + ("" if camera is None else
               f"Camera: {camera['name']} ({camera['kind']}) on {ROBOT}::chassis, "
               f"{camera['topic']} and {camera['info_topic']} (bridged); optical frame "
               f"{ROBOT}::{camera['optical_frame']}; {camera['lamps']} headlights on the "
               f"chassis; robot.urdf: base_link -> {camera['link']} -> "
               f"{camera['optical_frame']}\n") +
            f"Not expressible in SDF:\n{lim_text}\n")


def export_gazebo(mesh_path: str | Path, sensor: SensorSpec, out_dir: str | Path, *,
                  force: bool = False, mount: str = "level",
                  chainage_m: float | None = None, light_spacing_m: float = 25.0,
                  flavour: str = "harmonic", waypoints: ArrayLike | None = None,
                  route_height_m: float = ROUTE_HEIGHT_M, imu: ImuModel | None = None,
                  reflectivity: float = 0.5, route_clearance_m: float | None = None,
                  voxel_m: float | None = None,
                  camera: CameraSpec | None = None) -> dict[str, Any]:
    """Write the world folder (see module doc).

    Parameters
    ----------
    mesh_path : the tunnel mesh (PLY, with its JSON sidecar when generated; any mesh)
    sensor : SensorSpec, a spinning lidar or a profiler
    out_dir : the world folder; an existing one is refused unless ``force`` (then
        replaced as a whole, atomically)
    mount : "level" or "down"
    chainage_m : where the robot starts on a generated tunnel's axis (default: 1 m in)
    light_spacing_m : distance between the lamps along the axis or route (m)
    flavour : "harmonic" or "fortress" (``gazebo_sdf.FLAVOURS``)
    waypoints : (k, 2) or (k, 3) array_like of float, optional
        The route's waypoints (``sensors.route.find_route``; world coordinates); the
        robot starts at the route's start even on a generated tunnel.
    route_height_m : the route's height above the floor (m), as drive's ``--height``
    imu : sensors.bag.ImuModel, optional
        The IMU's noise (default ``sensors.bag.DEFAULT_IMU``).
    reflectivity : float
        Reflectivity for ``laser_retro`` where the mesh has none per face (0-1).
    route_clearance_m, voxel_m : float, optional
        The route's clearance where the passage allows (default ``ROUTE_CLEARANCE_M``)
        and the voxel it is sought on (``find_route``'s ``clearance_m`` and
        ``voxel_m``; drive's ``--clearance`` and ``--voxel``); refused for a generated
        tunnel's axis.
    camera : sensors.camera.CameraSpec, optional
        A camera on the robot, with the ground_robot platform's lamps (module doc).

    Returns
    -------
    dict
        path, flavour, triangles, collision_triangles, origin (m), crs (its name, e.g.
        "EPSG:2056 (CH1903+ / LV95)", or None), crs_wkt (or None), limitations,
        warnings, robot_pose (x, y, z in m, local coordinates; yaw in radians),
        route (None, or length_m and min_clearance_m of the route found), laser_retro,
        bridge (the entries of bridge.yaml), run (the launch line), camera (None, or
        name, kind, topic, info_topic, optical_frame, link (the camera's body frame in
        robot.urdf), camera_link_xyz_m, lamps,
        limitations).

    Raises
    ------
    GazeboExportError
        An existing folder without ``force``, an unknown mount or flavour, a chainage
        without a tunnel axis, a TLS sensor, a fisheye depth or thermal camera.
    sensors.errors.TrajectoryError
        No route in the mesh (``find_route``).
    """
    import trimesh

    from sensors.imu import DEFAULT_IMU
    from sensors.pointcloud2 import GENERIC_DRIVER
    from sensors.bag import POSE_RATE_HZ
    from sensors.io.crs import crs_label, parse_crs
    from sensors.io.meshes import load_mesh
    from sensors.io.cloudread import cloud_crs_text

    fl = flavour_of(flavour)
    out = Path(out_dir)
    _check_output(out, force, mount)
    crs_wkt = cloud_crs_text(mesh_path) if Path(mesh_path).is_file() else None
    crs_name = None if crs_wkt is None else crs_label(parse_crs(crs_wkt, metric=False))
    scene, refl = load_mesh(mesh_path)
    v, f = scene.vertices, scene.faces
    warns = unit_warnings(v)
    for w in warns:
        warnings.warn(w, UserWarning, stacklevel=2)
    desc = robot_description(sensor, mount, camera)
    sensor_xml, limits = lidar_sdf(sensor, name=sensor.name,
                                   pose=_pose_in_chassis(*desc.base_to_sensor()))
    cam_xml, frame_xml, cam_facts = ("", "", None) if camera is None else \
        _camera_parts(camera, desc)
    floor, yaw, lamps, route = _placement(mesh_path, scene, chainage_m, waypoints,
                                          route_height_m, light_spacing_m,
                                          route_clearance_m, voxel_m)
    # DECISION (issue 30): the local origin is the one a drive's bag states as map ->
    # odom for a robot starting here (``Trajectory.origin``: base_link's first
    # position rounded to whole metres), so that the world and the bag share odom.
    origin = np.round(floor)
    floor = floor - origin
    retro = laser_retro(refl if refl is not None and len(refl) == len(f) else None, v, f,
                        default=reflectivity)
    cv, cf = _decimate_to(v - origin, f, COLLISION_MAX_TRIANGLES)
    lim_text = "\n".join(f"  - {x}" for x in limits)
    if cam_facts is not None:
        lim_text += f"\n  camera {camera.name if camera else ''}:\n" + "\n".join(
            f"  - {x}" for x in cam_facts["limitations"])
    org = " ".join(f"{x:.3f}" for x in origin)
    name = Path(mesh_path).name
    robot = robot_sdf(fl, f"{floor[0]:.6f} {floor[1]:.6f} {floor[2]:.6f} 0 0 {yaw:.9f}",
                      sensor_xml, imu_sdf(imu or DEFAULT_IMU,
                                          pose=_pose_in_chassis(*desc.base_to_imu()))
                      + ("\n" + cam_xml if cam_xml else ""),
                      POSE_RATE_HZ, track_m=desc.track_m,
                      wheel_radius_m=desc.wheel_radius_m, frames_xml=frame_xml)
    entries = bridge_entries(fl, (sensor.driver or GENERIC_DRIVER).topic,
                             None if cam_facts is None else
                             (cam_facts["topic"], cam_facts["info_topic"]))
    start = (f"route start ({route.length_m:.1f} m route, smallest clearance "
             f"{route.min_clearance_m:.2f} m)" if route is not None else "tunnel axis") + \
        f" at local {floor[0]:.3f} {floor[1]:.3f} {floor[2]:.3f} m, yaw {yaw:.4f} rad"

    def fill(tmp: Path) -> None:
        (tmp / "models" / "tunnel" / "meshes").mkdir(parents=True)
        _write(tmp / "world.sdf", world_sdf(fl, name, sensor.name, org, lim_text,
                                            _lamps(lamps - origin, light_spacing_m), robot,
                                            origin_frame(origin, crs_name), crs_name))
        _write(tmp / "bridge.yaml", bridge_yaml(entries, fl))
        _write(tmp / "models" / "tunnel" / "model.sdf",
               model_sdf(org, retro, crs_name, crs_wkt))
        _write(tmp / "models" / "tunnel" / "model.config",
               model_config(name, len(f), len(cf), org, crs_name))
        mdir = tmp / "models" / "tunnel" / "meshes"
        write_obj(mdir / "tunnel.obj", v - origin, f)
        trimesh.Trimesh(cv, cf, process=False).export(mdir / "tunnel_collision.stl")
        _write(tmp / "README.txt", _readme(fl, name, sensor.name, out.name, org, origin,
                                           lim_text, start, crs_name, crs_wkt,
                                           desc.sensor_frame, cam_facts))
        desc.write_urdf(tmp / "robot.urdf")
        desc.write_launch(tmp / "robot.launch.py", "robot.urdf")

    _replace_folder(out, fill)
    return {"path": str(out), "flavour": fl.name, "triangles": int(len(f)),
            "collision_triangles": int(len(cf)), "origin": origin.tolist(),
            "crs": crs_name, "crs_wkt": crs_wkt, "limitations": limits, "warnings": warns,
            "robot_pose": [float(floor[0]), float(floor[1]), float(floor[2]), yaw],
            "route": None if route is None else
            {"length_m": route.length_m, "min_clearance_m": route.min_clearance_m},
            "laser_retro": retro, "bridge": entries, "run": fl.run_line(),
            "camera": cam_facts}


def _replace_folder(out: Path, fill: Callable[[Path], None]) -> None:
    """Build the folder in a temporary sibling with ``fill(tmp)``, then swap it in for
    ``out`` (a crash leaves ``out`` as it was and no temporary behind)."""
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        fill(tmp)
        if out.exists():
            old = out.with_name(f".{out.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_obj(path: str | Path, vertices: ArrayLike, faces: ArrayLike) -> str | Path:
    """Wavefront OBJ (vertices to 0.1 mm, 1-based faces), streamed; atomic. OBJ needs
    no extra package and Gazebo (Classic and Sim) loads it."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64) + 1
    with atomic_writer(path, "w") as fh:
        fh.write(f"# tunnelsim: {len(v)} vertices, {len(f)} triangles, metres, Z up\n")
        for i in range(0, len(v), 200_000):
            np.savetxt(fh, v[i:i + 200_000], fmt="v %.4f %.4f %.4f")
        for i in range(0, len(f), 200_000):
            np.savetxt(fh, f[i:i + 200_000], fmt="f %d %d %d")
    return path


def _write(path: Path, text: str) -> None:
    with atomic_writer(path, "w") as fh:
        fh.write(text)
