"""Export a tunnel and a sensor rig to Gazebo (SDFormat 1.9; Gazebo Sim, Fortress and
later): a world folder that loads as is.

    world_dir/
      world.sdf                      the world: scene, lights, physics, tunnel, robot
      models/tunnel/model.config     Gazebo model metadata (local origin recorded)
      models/tunnel/model.sdf        static model: visual mesh + collision mesh
      models/tunnel/meshes/tunnel.obj            visual mesh (OBJ), local coordinates
      models/tunnel/meshes/tunnel_collision.stl  collision mesh (decimated when large)
      README.txt                     how to run it, and what SDF cannot express

Coordinates: metres, Z up, shifted to a local origin (UTM-sized numbers would lose
millimetres in Gazebo's float32 render buffers); the origin is recorded in
``model.config``, ``model.sdf`` (a ``tunnelsim:origin`` custom element) and README.
When the tunnel states a coordinate reference system (its JSON's ``crs``, or a
``<mesh>.prj`` sidecar; ``survey.clouds.cloudio.cloud_crs_text``), the same places name
it (``tunnelsim:crs`` holds the WKT): world = local + origin, in that CRS.

DECISION: no ``<spherical_coordinates>``. Gazebo places that origin on the WGS 84
ellipsoid in a local tangent plane: a projected CRS's grid north differs from true
north by the meridian convergence (up to ~3 deg at a UTM zone's edge), its metres by
the projection's scale (-400 to +400 ppm), its heights are orthometric, not
ellipsoidal, and SDF's ``heading_deg`` sign changed meaning between versions. Written
without all of that, a simulated GPS would disagree with the survey by metres and
look authoritative; the CRS and the origin are recorded instead.

The lidar is translated from our spec into ``<sensor type="gpu_lidar">``: horizontal
samples per revolution from the column period and rotation rate, vertical samples and
limits from the channel table, range limits, Gaussian noise at the spec's reference
conditions, update rate = rotation (profile) rate. What SDF cannot express is listed in
a comment inside ``world.sdf`` and returned for the CLI summary.

Collision mesh: vertex clustering on a uniform grid (Rossignac & Borrel 1993,
"Multi-resolution 3D approximations for rendering complex scenes"): vertices in one cell
merge to their mean, degenerate triangles are dropped.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any
from xml.sax.saxutils import escape

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.fileio import atomic_writer
from survey.errors import GazeboExportError

if TYPE_CHECKING:
    from sensors.spec import SensorSpec
    from survey.world.alignment import Alignment

__all__ = ["BASE", "COLLISION_MAX_TRIANGLES", "MAX_METRIC_EXTENT_M", "RANGE_RESOLUTION_M",
           "decimate", "export_gazebo", "lidar_sdf", "unit_warnings", "write_obj"]

Floats = NDArray[np.float64]

#: The visual mesh is decimated for collisions above this many triangles.
COLLISION_MAX_TRIANGLES = 200_000
#: A mesh larger than this (m) is probably not in metres.
MAX_METRIC_EXTENT_M = 10_000.0
#: Range resolution written to SDF (m): ASSUMED, the specs give no range quantisation.
RANGE_RESOLUTION_M = 0.001
#: LIMO-sized differential-drive base (AgileX LIMO: 322 x 220 x 251 mm, wheels 45 mm
#: radius, track 172 mm, 4.2 kg; public product sheet).
BASE = {"length": 0.322, "width": 0.220, "height": 0.10, "clearance": 0.05,
        "wheel_radius": 0.045, "wheel_width": 0.045, "track": 0.172, "mass": 4.2}


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


# ------------------------------------------------------------------------------ sensor
def lidar_sdf(spec: SensorSpec, *, name: str = "lidar", topic: str = "lidar",
              pose: str = "0 0 0 0 0 0", indent: int = 10) -> tuple[str, list[str]]:
    """(XML of a ``<sensor type="gpu_lidar">``, list of what SDF cannot express)."""
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
    pad = " " * indent
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
    return "\n".join(pad + line for line in xml.splitlines()), limits


# ------------------------------------------------------------------------------- world
def _inertia_box(m: float, x: float, y: float, z: float) -> str:
    return (f"<inertial><mass>{m:g}</mass><inertia><ixx>{m * (y * y + z * z) / 12:.6g}</ixx>"
            f"<iyy>{m * (x * x + z * z) / 12:.6g}</iyy><izz>{m * (x * x + y * y) / 12:.6g}"
            "</izz><ixy>0</ixy><ixz>0</ixz><iyz>0</iyz></inertia></inertial>")


def _robot_sdf(pose: str, sensor_xml: str) -> str:
    b = BASE
    zc = b["clearance"] + b["height"] / 2
    wr, ww = b["wheel_radius"], b["wheel_width"]
    wheels = []
    joints = []
    for side, y in (("left", b["track"] / 2 + ww / 2), ("right", -b["track"] / 2 - ww / 2)):
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
    return f"""    <model name="robot">
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
      <joint name="caster_joint" type="ball"><parent>chassis</parent><child>caster</child>
      </joint>
      <plugin filename="gz-sim-diff-drive-system" name="gz::sim::systems::DiffDrive">
        <left_joint>left_wheel_joint</left_joint>
        <right_joint>right_wheel_joint</right_joint>
        <wheel_separation>{b["track"] + ww}</wheel_separation>
        <wheel_radius>{wr}</wheel_radius>
        <topic>cmd_vel</topic>
      </plugin>
    </model>"""


def _check_output(out: Path, force: bool, mount: str) -> None:
    if out.exists() and not force:
        raise GazeboExportError(f"Expected a new output folder, got '{out}' which exists; "
                                "pass --force to replace it.")
    if not out.parent.exists():
        raise GazeboExportError(f"Expected an existing parent folder for '{out}', got none.")
    if mount not in ("level", "down"):
        raise GazeboExportError(f"Expected mount 'level' or 'down', got {mount!r}.")


def _sensor_pose(sensor: SensorSpec, mount: str) -> str:
    """The lidar's SDF pose on the chassis: level, upside down, or (a profiler) turned
    to scan the cross-section."""
    top = BASE["clearance"] + BASE["height"]
    if sensor.kind == "profiler":
        return f"0.10 0 {top + 0.05:.3f} 0 -1.5707963 0"
    if mount == "down":
        return f"0.10 0 {top + 0.15:.3f} 3.14159265 0 0"
    return f"0.10 0 {top + 0.05:.3f} 0 0 0"


def _lights_sdf(al: Alignment, hc: float, origin: Floats, spacing_m: float) -> str:
    """Point lights along the axis under the crown, every ``spacing_m``."""
    c0, c1 = al.chainage_range
    ls = np.arange(c0 + spacing_m / 2, c1, spacing_m)
    top = al.to_world(ls, 0.0, hc) - origin
    return "\n".join(f"""    <light name="lamp_{i}" type="point">
      <pose>{p[0]:.3f} {p[1]:.3f} {p[2] + 1.0:.3f} 0 0 0</pose>
      <diffuse>1 0.95 0.85 1</diffuse><specular>0.2 0.2 0.2 1</specular>
      <attenuation><range>{1.5 * spacing_m:g}</range><constant>0.3</constant>
        <linear>0.05</linear><quadratic>0.005</quadratic></attenuation>
      <cast_shadows>false</cast_shadows>
    </light>""" for i, p in enumerate(top))


def _in_crs(crs_name: str | None) -> str:
    """" in EPSG:2056 (CH1903+ / LV95)" for the texts that name the local origin (no
    '--', which an XML comment cannot hold)."""
    return "" if crs_name is None else " in " + crs_name.replace("--", "- -")


def _world_sdf(mesh_name: str, sensor_name: str, org: str, lim_text: str, lights: str,
               robot: str, crs_name: str | None = None) -> str:
    """world.sdf: physics, systems, scene, lights, the tunnel model and the robot."""
    return f"""<?xml version="1.0"?>
<!-- Generated by tunnelsim from {escape(mesh_name)}. Coordinates are local:
     world = local + ({org}) m{escape(_in_crs(crs_name))}.
     Sensor {escape(sensor_name)} translated to gpu_lidar. SDF cannot express:
{escape(lim_text)}
     Run: GZ_SIM_RESOURCE_PATH=$PWD/models gz sim world.sdf -->
<sdf version="1.9">
  <world name="tunnel_world">
    <physics name="default" type="ode"><max_step_size>0.002</max_step_size>
      <real_time_factor>1</real_time_factor></physics>
    <plugin filename="gz-sim-physics-system" name="gz::sim::systems::Physics"/>
    <plugin filename="gz-sim-user-commands-system" name="gz::sim::systems::UserCommands"/>
    <plugin filename="gz-sim-scene-broadcaster-system"
            name="gz::sim::systems::SceneBroadcaster"/>
    <plugin filename="gz-sim-sensors-system" name="gz::sim::systems::Sensors">
      <render_engine>ogre2</render_engine>
    </plugin>
    <gravity>0 0 -9.81</gravity>
    <scene>
      <ambient>0.15 0.15 0.15 1</ambient>
      <background>0 0 0 1</background>
      <shadows>false</shadows>
      <grid>false</grid>
    </scene>
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


def _model_sdf(org: str, crs_name: str | None = None, crs_wkt: str | None = None) -> str:
    """models/tunnel/model.sdf: the static tunnel, visual OBJ and collision STL; the
    local origin and (when stated) the CRS as tunnelsim custom elements."""
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
      </visual>
      <collision name="collision">
        <geometry><mesh><uri>model://tunnel/meshes/tunnel_collision.stl</uri></mesh>
        </geometry>
      </collision>
    </link>
  </model>
</sdf>
"""


def _model_config(mesh_name: str, n_faces: int, n_collision: int, org: str,
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
        _in_crs(crs_name))}.</description>
</model>
"""


def _readme(mesh_name: str, sensor_name: str, out_name: str, org: str,
            lim_text: str, crs_name: str | None = None, crs_wkt: str | None = None) -> str:
    crs = "Coordinate reference system: none stated (local coordinates)\n" \
        if crs_wkt is None else (f"Coordinate reference system: {crs_name}\n  WKT: "
                                 f"{' '.join(crs_wkt.split())}\n")
    return (f"Gazebo world for {mesh_name} with {sensor_name} on a LIMO-sized "
            f"robot.\nRun:  cd {out_name} && GZ_SIM_RESOURCE_PATH=$PWD/models gz sim "
            f"world.sdf\nLocal origin (world = local + origin): {org} m"
            f"{_in_crs(crs_name)}\n{crs}Drive: gz topic "
            "-t /cmd_vel -m gz.msgs.Twist -p 'linear: {x: 0.5}'\nNot expressible in "
            f"SDF:\n{lim_text}\n")


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


def export_gazebo(mesh_path: str | Path, sensor: SensorSpec, out_dir: str | Path, *,
                  force: bool = False, mount: str = "level",
                  chainage_m: float | None = None,
                  light_spacing_m: float = 25.0) -> dict[str, Any]:
    """Write the world folder (see module doc).

    Parameters
    ----------
    mesh_path : the tunnel mesh (PLY, with its JSON sidecar when generated)
    sensor : SensorSpec, a spinning lidar or a profiler
    out_dir : the world folder; an existing one is refused unless ``force`` (then
        replaced as a whole, atomically)
    mount : "level" or "down"
    chainage_m : where the robot starts (default: 1 m into the tunnel)
    light_spacing_m : distance between the lamps along the axis (m)

    Returns
    -------
    dict
        path, triangles, collision_triangles, origin (m), crs (its name, e.g.
        "EPSG:2056 (CH1903+ / LV95)", or None), crs_wkt (or None), limitations,
        warnings and robot_pose (x, y, z in m, yaw in radians).
    """
    import trimesh

    from sensors.crs import crs_label, parse_crs
    from sensors.meshes import load_mesh
    from survey.analysis.planning import axis_stations
    from survey.clouds.axis import tunnel_frame
    from survey.clouds.cloudio import cloud_crs_text

    out = Path(out_dir)
    _check_output(out, force, mount)
    crs_wkt = cloud_crs_text(mesh_path) if Path(mesh_path).is_file() else None
    crs_name = None if crs_wkt is None else crs_label(parse_crs(crs_wkt, metric=False))
    scene, _ = load_mesh(mesh_path)
    mesh: Any = trimesh.load(str(mesh_path), force="mesh", process=False)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    warns = unit_warnings(v)
    for w in warns:
        warnings.warn(w, UserWarning, stacklevel=2)
    _, _, al, hc = tunnel_frame(mesh_path, scene)
    origin = np.floor(v.min(axis=0))
    s0 = al.chainage_range[0] + 1.0 if chainage_m is None else float(chainage_m)
    floor = axis_stations(scene, al, hc, [s0], height_m=0.0)[0] - origin
    yaw = float(al.heading(np.array([s0]))[0])
    sensor_xml, limits = lidar_sdf(sensor, name=sensor.name, topic=f"{sensor.name}/points",
                                   pose=_sensor_pose(sensor, mount))
    cv, cf = _decimate_to(v - origin, f, COLLISION_MAX_TRIANGLES)
    lim_text = "\n".join(f"  - {x}" for x in limits)
    org = " ".join(f"{x:.3f}" for x in origin)
    name = Path(mesh_path).name
    robot = _robot_sdf(f"{floor[0]:.3f} {floor[1]:.3f} {floor[2]:.3f} 0 0 {yaw:.6f}",
                       sensor_xml)

    def fill(tmp: Path) -> None:
        (tmp / "models" / "tunnel" / "meshes").mkdir(parents=True)
        _write(tmp / "world.sdf", _world_sdf(name, sensor.name, org, lim_text,
                                             _lights_sdf(al, hc, origin, light_spacing_m),
                                             robot, crs_name))
        _write(tmp / "models" / "tunnel" / "model.sdf", _model_sdf(org, crs_name, crs_wkt))
        _write(tmp / "models" / "tunnel" / "model.config",
               _model_config(name, len(f), len(cf), org, crs_name))
        mdir = tmp / "models" / "tunnel" / "meshes"
        write_obj(mdir / "tunnel.obj", v - origin, f)
        trimesh.Trimesh(cv, cf, process=False).export(mdir / "tunnel_collision.stl")
        _write(tmp / "README.txt", _readme(name, sensor.name, out.name, org, lim_text,
                                           crs_name, crs_wkt))

    _replace_folder(out, fill)
    return {"path": str(out), "triangles": int(len(f)), "collision_triangles": int(len(cf)),
            "origin": origin.tolist(), "crs": crs_name, "crs_wkt": crs_wkt,
            "limitations": limits, "warnings": warns,
            "robot_pose": [float(floor[0]), float(floor[1]), float(floor[2]), yaw]}


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
