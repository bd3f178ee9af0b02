"""``tunnelsim tunnel``, ``gazebo``, ``info`` and ``sensors`` as library calls: a preset
tunnel written as PLY + JSON (and a deformed second epoch), a Gazebo world folder, the
versions and threading this installation runs with, and the shipped sensor models.

The command line parses its options, calls one of these and prints from the result.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from survey.errors import GazeboExportError, TunnelError

__all__ = ["GazeboResult", "SensorModel", "SoftwareInfo", "TunnelResult",
           "INFO_PACKAGES", "gazebo_files", "sensor_models", "software_info",
           "tunnel_files"]

PathLike = str | os.PathLike[str]

#: The dependencies ``software_info`` reports, in this order.
INFO_PACKAGES = ("numpy", "numba", "scipy", "trimesh", "laspy", "lazrs", "pyproj", "pye57",
                 "embreex", "open3d")


# ---------------------------------------------------------------------------- info
@dataclass(frozen=True)
class SoftwareInfo:
    """Versions and threading of this installation (``tunnelsim info``).

    Attributes
    ----------
    version : str
        tunnelsim's version ("0+unknown" from a bare source tree).
    python, machine, system : str
        Python's version, the machine ("x86_64") and the operating system ("Linux").
    packages : tuple of (str, str or None)
        (name, version) of each of ``INFO_PACKAGES``; None when not installed.
    threading_layer : str
        Numba's threading layer ("tbb", "omp" or "workqueue").
    threads, max_threads : int
        Numba threads in use and the most that may be set.
    """

    version: str
    python: str
    machine: str
    system: str
    packages: tuple[tuple[str, str | None], ...]
    threading_layer: str
    threads: int
    max_threads: int


def software_info() -> SoftwareInfo:
    """Versions of tunnelsim and its dependencies, Numba's threading layer and threads.

    Returns
    -------
    SoftwareInfo

    Examples
    --------
    >>> info = software_info()
    >>> dict(info.packages)["numpy"] is not None and info.threads >= 1
    True
    """
    import platform
    from importlib import metadata

    from raytrace.config import threading_info

    try:
        version = metadata.version("tunnelsim")
    except metadata.PackageNotFoundError:  # running from a source tree
        version = "0+unknown"
    pkgs: list[tuple[str, str | None]] = []
    for pkg in INFO_PACKAGES:
        try:
            pkgs.append((pkg, metadata.version(pkg)))
        except metadata.PackageNotFoundError:
            pkgs.append((pkg, None))
    t = threading_info()
    return SoftwareInfo(version=version, python=platform.python_version(),
                        machine=platform.machine(), system=platform.system(),
                        packages=tuple(pkgs), threading_layer=str(t["threading_layer"]),
                        threads=int(t["threads"]), max_threads=int(t["max_threads"]))


# ---------------------------------------------------------------------------- sensors
@dataclass(frozen=True)
class SensorModel:
    """One shipped sensor model (``tunnelsim sensors``): its registry ``name``, kind,
    vendor, model and range (m)."""

    name: str
    kind: str
    vendor: str
    model: str
    range_min_m: float
    range_max_m: float


def sensor_models() -> tuple[SensorModel, ...]:
    """The shipped sensor models, in the registry's order (``sensors.list_sensors``).

    Returns
    -------
    tuple of SensorModel

    Examples
    --------
    >>> "robosense_airy" in [m.name for m in sensor_models()]
    True
    """
    from sensors import list_sensors, load_sensor

    out = []
    for name in list_sensors():
        spec = load_sensor(name)
        out.append(SensorModel(name, spec.kind, spec.vendor, spec.model,
                               float(spec.physics.range_min_m),
                               float(spec.physics.range_max_m)))
    return tuple(out)


# ---------------------------------------------------------------------------- tunnel
@dataclass(frozen=True)
class TunnelResult:
    """What ``tunnel_files`` wrote and made.

    Attributes
    ----------
    tunnel : survey.world.mesh.TunnelMesh
        The tunnel (first epoch).
    preset : str
        The preset's name.
    triangles, vertices : int
        Its triangles and vertices.
    face_counts : dict of str to int
        Triangles per surface label (lining, floor, ...).
    edge_length_m : float
        The target edge length used (from ``triangles`` when that was given).
    control_points : int
        Control points on the tunnel.
    relief : {"none", "rock"}
        The surface relief.
    crs_name : str
        The CRS in words, or "local coordinates (no CRS)".
    seconds : float
        Time taken to make and write the meshes.
    files : tuple of Path
        Every file written: the PLY and its JSON, then the second epoch's.
    """

    tunnel: Any
    preset: str
    triangles: int
    vertices: int
    face_counts: dict[str, int]
    edge_length_m: float
    control_points: int
    relief: str
    crs_name: str
    seconds: float
    files: tuple[Path, ...]


def _deformations(convergence: Sequence[Sequence[float]],
                  bulges: Sequence[Sequence[float]]) -> list[Any]:
    import numpy as np

    from survey.world.deformation import Bulge, Convergence

    # DECISION: float() at entry: the deformations are written to the epoch's JSON,
    # where an int 10 would read "10" and the command line's 10.0 "10.0".
    out: list[Any] = [Convergence(float(a), float(b), float(mm) / 1000.0)
                      for a, b, mm in convergence]
    out += [Bulge(float(s), np.deg2rad(float(ang)), float(r), float(mm) / 1000.0)
            for s, ang, r, mm in bulges]
    return out


def tunnel_files(output: PathLike, *, preset: str = "bfo", edge_length_m: float = 0.1,
                 triangles: int | None = None, roughness_rms_m: float | None = None,
                 relief: str | None = None, relief_scale: float | None = None,
                 closed_ends: bool = False, origin: Sequence[float] | None = None,
                 heading_deg: float = 0.0, crs: str | None = None,
                 epoch2: PathLike | None = None,
                 convergence: Sequence[Sequence[float]] = (),
                 bulges: Sequence[Sequence[float]] = (), seed: int = 0) -> TunnelResult:
    """Generate a labelled preset tunnel and write it as ``tunnelsim tunnel`` does: a
    binary PLY with face labels and reflectivity, and the JSON beside it (alignment,
    profile, features, control points); optionally a deformed second epoch.

    Parameters
    ----------
    output : path-like
        The mesh, ending in .ply, in an existing folder (the JSON is written beside).
    preset : {"bfo", "tbm", "junction"}
        Which tunnel.
    edge_length_m : float
        Target edge length of the lining (m).
    triangles : int, optional
        Target number of lining triangles instead of ``edge_length_m``.
    roughness_rms_m : float, optional
        Lining roughness, standard deviation (m); default the preset's.
    relief : {"none", "rock"}, optional
        Surface relief (default the preset's: bfo rock, tbm none).
    relief_scale : float, optional
        Multiply the rock relief's overbreak by this factor.
    closed_ends : bool
        Cap both portals (a watertight mesh).
    origin : (3,) float, optional
        E, N, H of the first portal's centreline point (default 0, 0, 0).
    heading_deg : float
        Initial direction, degrees counter-clockwise from east.
    crs : str, optional
        The CRS of the coordinates (EPSG:n, WKT or PROJJSON; needs pyproj).
    epoch2 : path-like, optional
        Also write a deformed second epoch (.ply + .json) here.
    convergence : sequence of (start_m, end_m, amount_mm)
        Radial convergence between two chainages (default for ``epoch2``: the
        preset's deformations).
    bulges : sequence of (chainage_m, angle_deg, radius_m, amount_mm)
        Local inward bulges at a chainage and angle from the crown.
    seed : int
        Roughness and relief seed.

    Returns
    -------
    TunnelResult

    Raises
    ------
    survey.errors.TunnelError
        A bad output name or folder, relief scale without relief, a bad preset.
    sensors.io.crs.CRSError
        A CRS that cannot be read (the message names --crs).

    Warns
    -----
    UserWarning
        When ``origin`` lies outside the area of use of ``crs``.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> r = tunnel_files(pathlib.Path(tempfile.mkdtemp()) / "t.ply", preset="tbm",
    ...                  edge_length_m=0.75)
    >>> r.relief, [p.suffix for p in r.files]
    ('none', ['.ply', '.json'])
    """
    import numpy as np

    from survey.world.generator import edge_length_for
    from survey.world.presets import PRESETS, RELIEF, preset as make_preset
    from survey.world.rock import RockRelief

    out = Path(output)
    if out.suffix.lower() != ".ply":
        raise TunnelError(f"Expected an output file ending in .ply, got '{out}'.")
    if not out.parent.exists():
        raise TunnelError(f"Expected an existing output folder, got '{out.parent}'; "
                          "create it first.")
    at = (0.0, 0.0, 0.0) if origin is None else tuple(float(v) for v in origin)
    crs_obj = None
    if crs is not None:   # checked before the mesh is made (seconds)
        from sensors.io.crs import area_warning, parse_crs

        crs_obj = parse_crs(crs, what="--crs")
        where = area_warning(crs_obj, at, what="--origin" if origin is not None else
                             "the default origin", hint="give the portal's position in "
                             "that CRS with --origin E,N,H" if origin is None else
                             "easting and northing swapped, or another CRS meant?")
        if where:
            warnings.warn(where[0].upper() + where[1:], UserWarning, stacklevel=2)
    edge = float(edge_length_m)
    if triangles is not None:
        al, prof, _, _ = PRESETS[preset](at, 0.0)
        edge = edge_length_for(triangles, prof, al.length_m)
    t0 = time.perf_counter()
    deformations = _deformations(convergence, bulges)
    rel = RELIEF[preset] if relief is None else \
        None if relief == "none" else (RELIEF[preset] or RockRelief())
    if relief_scale is not None:
        if rel is None:
            raise TunnelError("Expected --relief-scale with rock relief, got a smooth "
                              f"lining ({preset}, --relief {relief or 'default'}); add "
                              "--relief rock.")
        rel = rel.scaled(float(relief_scale))
    tun, default_def = make_preset(preset, edge_length_m=edge, seed=seed,
                                   closed_ends=closed_ends,
                                   roughness_rms_m=None if roughness_rms_m is None
                                   else float(roughness_rms_m), relief=rel, origin=at,
                                   heading_rad=np.deg2rad(float(heading_deg)))
    if crs_obj is not None:
        tun = tun.with_crs(crs_obj)
    written = list(tun.write(out))
    if epoch2:
        epoch = tun.deformed(deformations or default_def)
        written += list(epoch.write(Path(epoch2)))
    return TunnelResult(
        tunnel=tun, preset=preset, triangles=len(tun.faces), vertices=len(tun.vertices),
        face_counts=dict(tun.metadata["face_counts"]), edge_length_m=float(edge),
        control_points=len(tun.metadata["control_points"]),
        relief="none" if rel is None else "rock",
        crs_name=tun.metadata.get("crs_name", "local coordinates (no CRS)"),
        seconds=time.perf_counter() - t0, files=tuple(written))


# ---------------------------------------------------------------------------- gazebo
@dataclass(frozen=True)
class GazeboResult:
    """What ``gazebo_files`` wrote (``survey.export.gazebo.export_gazebo``'s facts).

    Attributes
    ----------
    path : Path
        The world folder.
    sensor : str
        The sensor's name.
    flavour : str
        "harmonic" or "fortress".
    triangles, collision_triangles : int
        The visual mesh's and the decimated collision mesh's triangles.
    laser_retro : float
        The tunnel's ``laser_retro``.
    origin : (3,) tuple of float
        The local origin (m) the world's coordinates are relative to.
    crs : str or None
        The CRS in words.
    robot_pose : (4,) tuple of float
        x, y, z (m, local) and yaw (rad) of the robot's start.
    route : dict or None
        ``length_m`` and ``min_clearance_m`` of the route found (None: on the axis).
    limitations : tuple of str
        What SDF cannot express about the sensor.
    run : str
        The command line that starts the world (in ``path``).
    info : dict
        Everything ``export_gazebo`` returned.
    camera : str or None
        The camera's name (``camera=``), its sensor on the robot with the platform's
        lamps.
    camera_topic : str or None
        Its image topic (the CameraInfo beside it, ``.../camera_info``).
    camera_limitations : tuple of str
        What SDF cannot express about the camera.
    """

    path: Path
    sensor: str
    flavour: str
    triangles: int
    collision_triangles: int
    laser_retro: float
    origin: tuple[float, ...]
    crs: str | None
    robot_pose: tuple[float, ...]
    route: dict[str, Any] | None
    limitations: tuple[str, ...]
    run: str
    info: dict[str, Any]
    camera: str | None = None
    camera_topic: str | None = None
    camera_limitations: tuple[str, ...] = ()


def gazebo_files(mesh: PathLike, output_dir: PathLike, *, sensor: Any = "robosense_airy",
                 flavour: str = "harmonic", mount: str = "level",
                 chainage_m: float | None = None, waypoints: Any = None,
                 clearance_m: float | None = None, voxel_m: float | None = None,
                 force: bool = False, camera: Any = None) -> GazeboResult:
    """Write a Gazebo world folder for the tunnel and a lidar robot, as ``tunnelsim
    gazebo`` does (``survey.export.gazebo.export_gazebo``).

    Parameters
    ----------
    mesh : path-like
        The tunnel mesh (its .json gives the axis; any other mesh: a route is found).
    output_dir : path-like
        The world folder (new; an existing one only with ``force``, then replaced).
    sensor : str, path-like or sensors.SensorSpec
        A spinning lidar or profiler: a shipped name, a .toml file, or a spec.
    flavour : {"harmonic", "fortress"}
        Gazebo line.
    mount : {"level", "down"}
        Lidar z up or pointing down.
    chainage_m : float, optional
        Robot start chainage on a generated tunnel (default: first chainage + 1 m).
    waypoints : path-like or (k, 2) or (k, 3) array_like of float, optional
        x, y[, z] rows the route passes through in order (a CSV as drive's, or an
        array); the robot starts at the first.
    clearance_m, voxel_m : float > 0, optional
        The route's clearance from the mesh and the voxel it is sought on, as drive's.
    force : bool
        Replace an existing folder.
    camera : str, path-like or sensors.camera.CameraSpec, optional
        A camera (a shipped name, a .toml file, or a spec) on the robot, 10 cm below
        the lidar looking ahead, with the same intrinsics, its body and optical
        frames in robot.urdf (a drive's names), and the ground_robot platform's lamps
        as lights (``survey.export.gazebo``).

    Returns
    -------
    GazeboResult

    Raises
    ------
    survey.errors.GazeboExportError
        Bad options or a mesh the export cannot place a robot in.
    sensors.errors.CameraSpecError
        An unknown camera or a bad camera file.

    Warns
    -----
    UserWarning
        As ``export_gazebo`` (units that look wrong, what the sensor loses).

    Examples
    --------
    >>> r = gazebo_files("bfo.ply", "world", flavour="fortress")   # doctest: +SKIP
    >>> r.path / "world.sdf", r.run                                # doctest: +SKIP
    """
    from sensors import load_sensor
    from sensors.route import read_waypoints
    from survey.export.gazebo import export_gazebo

    spec = load_sensor(sensor) if isinstance(sensor, (str, os.PathLike)) else sensor
    cam = None
    if isinstance(camera, (str, os.PathLike)):
        from sensors.camera import load_camera
        from sensors.errors import CameraSpecError

        try:
            cam = load_camera(camera)
        except CameraSpecError as exc:
            raise CameraSpecError(f"--camera: {exc} 'tunnelsim cameras' lists the "
                                  "names.") from None
    elif camera is not None:
        cam = camera
    wp = read_waypoints(waypoints) if isinstance(waypoints, (str, os.PathLike)) \
        else waypoints
    for flag, value in (("--clearance", clearance_m), ("--voxel", voxel_m)):
        if value is not None and not (value > 0 and value < float("inf")):
            raise GazeboExportError(f"Expected a positive {flag} in metres, got "
                                    f"{value:g}.")
    info = export_gazebo(Path(mesh), spec, Path(output_dir), force=force, mount=mount,
                         chainage_m=chainage_m, flavour=flavour, waypoints=wp,
                         route_clearance_m=clearance_m, voxel_m=voxel_m, camera=cam)
    return GazeboResult(
        path=Path(info["path"]), sensor=spec.name, flavour=info.get("flavour", flavour),
        triangles=int(info["triangles"]),
        collision_triangles=int(info["collision_triangles"]),
        laser_retro=float(info["laser_retro"]),
        origin=tuple(float(x) for x in info["origin"]), crs=info.get("crs"),
        robot_pose=tuple(float(x) for x in info["robot_pose"]), route=info["route"],
        limitations=tuple(info["limitations"]), run=str(info["run"]), info=info,
        camera=None if cam is None else cam.name,
        camera_topic=None if info.get("camera") is None else info["camera"]["topic"],
        camera_limitations=() if info.get("camera") is None else
        tuple(info["camera"]["limitations"]))
