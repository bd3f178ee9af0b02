"""Drive workflow: what ``tunnelsim drive`` (a sensor on a moving platform) does, as a
library function that takes paths and keyword options, writes the same files and
returns what the command prints.

- ``drive_to_file``: a drive along a trajectory file, the tunnel's centreline or a
  route found in the mesh -> points or a ROS 2 bag in the robot's frames, the true
  trajectory, the robot's URDF and launch file (and with ``slam_drift`` the SLAM files);
  with ``cameras`` their frames along the drive (in the bag, or PNG folders beside the
  point file: ``sensors.camera_drive``).

Guards (each a ``SimulationError`` naming the command-line option): a drive whose
every pose is beyond the sensor's range of the mesh's bounding box (unless
``allow_outside``), a drive that returns no point or fewer than ``MIN_DRIVE_RETURN``
of its pulses; ``duration_s`` beyond the trajectory's end is refused before the mesh
is loaded.

DECISION: nothing heavy is imported at module level (NumPy, SciPy, the simulator are
imported where they run): ``survey.cli.commands.driving`` reads this module's constants
on every ``tunnelsim`` start, which must not load NumPy.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sensors.errors import SimulationError

from .simrun import (
    ProgressFn,
    RunOutput,
    box_text,
    check_returned,
    number_text,
    output_crs,
    physics_settings,
    run_output,
    sensor_spec,
    write_run,
)

if TYPE_CHECKING:
    from sensors.platform_spec import PlatformSpec
    from sensors.robot import RobotDescription
    from sensors.simulate import Run
    from sensors.spec_types import SensorSpec
    from sensors.trajectory import Trajectory
    from survey.adjust.slam import DriftedRun
    from survey.cluster import Executor

#: A drive returning fewer points than this share of its pulses is refused (unless
#: ``allow_outside``). ASSUMED from measurements (1 s drives): inside a tunnel a
#: platform returns most of its pulses (VLP-16 in the tbm tunnel 94 %, in the shared
#: 80 m cave 95 %, in a 20 m tile open at both ends 80 %; a RoboSense Airy 92-97 %),
#: and still 12 % on a path that runs partly outside the walls of an S-bend tile; a
#: trajectory 100 m off the mesh returned 2 points of 578,704 pulses (issue 21: 6
#: points). 1 % sits far from both.
MIN_DRIVE_RETURN = 0.01
#: ``along="auto"``: the clearance the route keeps from the mesh (``find_route``'s
#: default), and that the platform's poses must keep too (issue 20).
ROUTE_CLEARANCE_M = 0.2


# ---------------------------------------------------------------------------- results
@dataclass(frozen=True)
class AutoRoute:
    """The route a drive with ``along="auto"`` found and drove.

    Attributes
    ----------
    csv : Path
        ``<stem>_route.csv`` beside the output.
    length_m, min_clearance_m, voxel_m, seconds : float
        The route's length, its smallest clearance, the voxel it was sought on, the
        time the search took.
    platform, motion : str
        The platform driven and its kind of motion.
    drive_s : float
        Duration of the platform's trajectory (s).
    height_m : float
        Sensor mount above the floor (m).
    pose_clearance_m : float
        Smallest distance of the platform's poses to the mesh (m).
    """

    csv: Path
    length_m: float
    min_clearance_m: float
    voxel_m: float
    seconds: float
    platform: str
    motion: str
    drive_s: float
    height_m: float
    pose_clearance_m: float


@dataclass(frozen=True)
class SweepCut:
    """A drive cut back to its last whole sweep (revolution or profile).

    Attributes
    ----------
    sweeps : int
    period_s : float
        One sweep (s).
    start_s, end_s : float
        The drive's start and its new end (s).
    left_out_s : float
        The partial sweep left out (s).
    """

    sweeps: int
    period_s: float
    start_s: float
    end_s: float
    left_out_s: float


@dataclass(frozen=True)
class SlamFiles:
    """The files of a drive observed through a drifting SLAM (``slam_drift``).

    Attributes
    ----------
    trajectory, true_trajectory, cp_observed, cp_world : Path
    observed : int
        Control points observed.
    """

    trajectory: Path
    true_trajectory: Path
    cp_observed: Path
    cp_world: Path
    observed: int


@dataclass(frozen=True)
class RobotFiles:
    """The drive's robot description (``sensors.robot``) and the files written of it.

    Attributes
    ----------
    name : str
    mast_height_m : float
        base_link below the platform frame (m).
    urdf, launch : Path
        ``<stem>_robot.urdf`` and ``<stem>_robot.launch.py``.
    """

    name: str
    mast_height_m: float
    urdf: Path
    launch: Path


@dataclass(frozen=True)
class CameraRun:
    """One camera's frames along a drive.

    Attributes
    ----------
    name, kind : str
        The camera and its kind ("color", "depth", "thermal").
    width, height : int
    rate_hz : float
        Frames per second taken.
    frames : int
    rays : int
        Primary rays cast (pixels x frames x samples per pixel).
    shutter : str
        "global" or "rolling".
    lamps : str
        What lit the frames (colour cameras; "no light needed" for depth and thermal).
    folder : Path or None
        ``<stem>_cameras/<name>`` for a point-file output; None in a bag.
    topics : tuple of str
        The image and camera_info topics in a bag; empty for a folder.
    seconds : float
        Time spent rendering the camera's frames and writing them (into the bag, or
        the folder) (s); not in the lidar's ``RunOutput.seconds``.
    """

    name: str
    kind: str
    width: int
    height: int
    rate_hz: float
    frames: int
    rays: int
    shutter: str
    lamps: str
    folder: Path | None
    topics: tuple[str, ...]
    seconds: float


@dataclass(frozen=True)
class DriveResult:
    """What ``drive_to_file`` wrote.

    Attributes
    ----------
    output : RunOutput
    sensor : str
    duration_s : float
        The time driven (s).
    crs : str or None
        The CRS the output states (None for a drifted cloud).
    route : AutoRoute or None
        With ``along="auto"``.
    sweeps : SweepCut or None
        When the drive was cut back to its last whole sweep.
    true_trajectory : Path or None
        ``<stem>_true_trajectory.txt`` (also written, as the SLAM's truth, with
        ``slam_drift``).
    base_trajectory : Path or None
        ``<stem>_base_link_trajectory.txt``, where base_link is not the platform frame.
    poses : int
        Poses of the true trajectory.
    slam : SlamFiles or None
    robot : RobotFiles
    windows : int
        Time windows simulated (0: one piece).
    window_s : float or None
    where : str or None
        Where the windows ran.
    cameras : tuple of CameraRun
        The cameras' frames (``cameras=``).
    """

    output: RunOutput
    sensor: str
    duration_s: float
    crs: str | None
    route: AutoRoute | None
    sweeps: SweepCut | None
    true_trajectory: Path | None
    base_trajectory: Path | None
    poses: int
    slam: SlamFiles | None
    robot: RobotFiles
    windows: int
    window_s: float | None
    where: str | None
    cameras: tuple[CameraRun, ...] = ()

    @property
    def label(self) -> str:
        """``"<sensor> drive <duration> s"``, as the command's summary starts."""
        return f"{self.sensor} drive {self.duration_s:.1f} s"


# ---------------------------------------------------------------------- small pieces
def sweep_rate_hz(spec: SensorSpec) -> float | None:
    """Sweeps per second of a sensor: a spinning lidar's revolutions, a profiler's
    profiles; None for a terrestrial scanner (it has no sweeps a drive is cut at).

    Examples
    --------
    >>> from sensors import load_sensor
    >>> sweep_rate_hz(load_sensor("velodyne_vlp16"))
    10.0
    """
    from sensors.spec_types import ProfilerPattern, SpinningPattern

    p = spec.pattern
    if isinstance(p, SpinningPattern):
        return float(p.rotation_hz)
    if isinstance(p, ProfilerPattern):
        return float(p.profile_rate_hz)
    return None


def output_stem(out: str | os.PathLike[str]) -> str:
    """The stem the files beside an output are named after: ``d`` for ``d.laz`` and
    for ``d.copc.laz`` (COPC's double suffix), ``d`` for a bag folder ``d``."""
    name = Path(out).name
    return name[:-len(".copc.laz")] if name.lower().endswith(".copc.laz") else Path(out).stem


def beside(out: str | os.PathLike[str], suffix: str) -> Path:
    """The file ``<stem><suffix>`` beside output ``out`` (``output_stem``)."""
    p = Path(out)
    return p.with_name(f"{output_stem(p)}{suffix}")


def trimmed(traj: Trajectory, t_end: float | None) -> Trajectory:
    """``traj`` up to ``t_end`` (s), its last pose interpolated at ``t_end``: what a
    drive with a duration covers. The same trajectory when ``t_end`` is None or at its
    end, or when it is static."""
    import numpy as np

    from sensors import Trajectory

    if t_end is None or len(traj) < 2 or t_end >= traj.end_s:
        return traj
    t = np.append(traj.times[traj.times < t_end], t_end)
    pos, rot = traj.interpolate(t)
    return Trajectory(t, pos, rot)


def drive_end(duration_s: float | None, traj: Trajectory) -> float | None:
    """The end time of a drive of ``duration_s`` (None: the whole trajectory).

    Raises
    ------
    SimulationError
        For a duration that is not positive or runs past the trajectory's end.
    """
    if duration_s is None:
        return None
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise SimulationError(f"Expected a positive --duration in seconds, got "
                              f"{duration_s:g}.")
    if len(traj) > 1 and duration_s > traj.duration_s * (1 + 1e-12) + 1e-9:
        raise SimulationError(f"Expected --duration at most the trajectory's "
                              f"{traj.duration_s:g} s (t = {traj.start_s:g} to "
                              f"{traj.end_s:g} s), got {duration_s:g} s; leave --duration "
                              "out to drive all of it.")
    return traj.start_s + duration_s


def whole_sweeps_end(spec: SensorSpec, traj: Trajectory, t_end: float | None
                     ) -> tuple[float | None, SweepCut | None]:
    """The end time of a drive cut back to its last whole sweep (a spinning lidar's
    revolution, a profiler's profile; sweeps start at the trajectory's first instant),
    and what was cut; ``(t_end, None)`` for a terrestrial scanner, a static platform,
    or a drive shorter than one sweep or ending on a whole sweep."""
    rate = sweep_rate_hz(spec)
    if not rate or len(traj) < 2:
        return t_end, None
    end = traj.end_s if t_end is None else t_end
    n = math.floor((end - traj.start_s) * rate + 1e-9)
    whole = traj.start_s + n / rate
    if n < 1 or whole >= end - 1e-9:
        return t_end, None
    return whole, SweepCut(n, 1 / rate, traj.start_s, whole, end - whole)


def _lever(lever_arm_m: Sequence[float]) -> tuple[float, float, float]:
    vals = [float(v) for v in lever_arm_m]
    if len(vals) != 3 or not all(map(math.isfinite, vals)):
        raise SimulationError(f"Expected --lever as X,Y,Z in metres, got "
                              f"{','.join(f'{v:g}' for v in vals)!r}.")
    return vals[0], vals[1], vals[2]



# ------------------------------------------------------------------------------ drive
def _check_drive_options(*, trajectory: Any, along: str | None, waypoints: Any,
                         clearance_m: float | None, voxel_m: float | None,
                         platform: Any, level: bool, chainage_m: Any, offset_m: float,
                         slam_drift: bool, window_s: float | None, mount: str) -> None:
    """Refuse option combinations a drive does not take (each error names the
    command-line option)."""
    if window_s is not None and slam_drift:
        raise SimulationError("Expected --window-s without --slam-drift (the drifted "
                              "cloud is written in one piece), got both.")
    if slam_drift and not along:
        raise SimulationError("Expected --along centreline with --slam-drift (the control "
                              "points come from the tunnel's JSON), got a trajectory "
                              "file.")
    if along not in (None, "centreline", "auto"):
        raise SimulationError(f"Expected --along centreline or auto, got {along!r}.")
    if mount not in ("level", "down"):
        raise SimulationError(f"Expected --mount level or down, got {mount!r}.")
    auto = along == "auto" and trajectory is None
    if waypoints is not None and not auto:
        other = "--trajectory" if trajectory is not None else "--along centreline"
        raise SimulationError(f"Expected --waypoints with --along auto, got it with "
                              f"{other}.")
    given = [f for f, on in (("--platform", platform is not None), ("--level", level)) if on]
    if trajectory is not None and given:
        raise SimulationError(f"Expected {given[0]} with --along, got it with "
                              "--trajectory (the file gives the platform's poses).")
    route_opts = [f for f, on in (("--clearance", clearance_m is not None),
                                  ("--voxel", voxel_m is not None)) if on]
    if route_opts and not auto:
        raise SimulationError(f"Expected {route_opts[0]} with --along auto (it shapes "
                              "the route found in the mesh), got it without.")
    for flag, value in (("--clearance", clearance_m), ("--voxel", voxel_m)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise SimulationError(f"Expected a positive {flag} in metres, got {value:g}.")
    bad = [flag for flag, on in (("--slam-drift", slam_drift),
                                 ("--chainage", chainage_m is not None),
                                 ("--offset", bool(offset_m))) if on]
    if auto and bad:
        hint = ("; use --waypoints and --duration to choose the part driven"
                if bad[0] == "--chainage" else "")
        raise SimulationError(f"Expected {bad[0]} with --along centreline (it needs the "
                              f"tunnel's JSON), got it with --along auto{hint}.")


def _bag_options(output: str | os.PathLike[str], start_time: str | float | None,
                 ros_distro: str | None) -> dict[str, Any]:
    """``start_time`` and ``ros_distro`` for the bag writer (checked before
    simulating)."""
    if start_time is None and ros_distro is None:
        return {}
    from sensors.bag import parse_start_time
    from sensors.writers import format_of

    if format_of(output) not in ("mcap", "rosbag2"):
        raise SimulationError(f"Expected --start-time and --ros-distro with a ROS 2 bag "
                              f"(-o NAME.mcap or a folder), got -o {output}.")
    out: dict[str, Any] = {}
    if start_time is not None:
        out["start_time_ns"] = parse_start_time(str(start_time))
    if ros_distro is not None:
        out["ros_distro"] = ros_distro
    return out


def _tunnel_meta(mesh: str | os.PathLike[str]) -> dict[str, Any]:
    """The JSON beside a generated tunnel's mesh (alignment, control points)."""
    import json

    from sensors.io.errors import TunnelFileError
    from sensors.io.tunnel_json import sidecar

    js = sidecar(Path(mesh))
    if not js.is_file():
        raise TunnelFileError(f"Expected the tunnel metadata '{js}' for --along centreline "
                              "(made by 'tunnelsim tunnel'), got none; pass --trajectory "
                              "instead.")
    try:
        meta = json.loads(js.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise TunnelFileError(f"Expected JSON in '{js}', got unreadable text ({exc}).") \
            from exc
    if not isinstance(meta, dict) or "alignment" not in meta:
        raise TunnelFileError(f"Expected an 'alignment' in '{js}' (a JSON written by "
                              "'tunnelsim tunnel'), got none.")
    return meta


def _centreline(meta: dict[str, Any], platform: PlatformSpec, speed_mps: float, *,
                scene: Any, chainage_m: Sequence[float] | None, margin_m: float,
                offset_m: float, height_m: float | None, accel_mps2: float | None,
                level: bool) -> Trajectory:
    """The centreline (or the ``chainage_m`` part of it), ``offset_m`` left and
    ``height_m`` (default the platform's mast height) above it, driven by
    ``platform``: a trolley rides it exactly (pitched with the grade unless ``level``);
    another platform follows it on the floor of ``scene``."""
    import numpy as np

    from sensors.platform import platform_trajectory
    from survey.world.alignment import Alignment

    al = Alignment.from_dict(meta["alignment"])
    c0, c1 = al.chainage_range
    a, b = c0 + margin_m, c1 - margin_m
    if chainage_m is not None:
        a, b = (float(v) for v in chainage_m)
        if not (c0 <= a < b <= c1):
            raise SimulationError(f"Expected --chainage within [{c0:g}, {c1:g}] m with "
                                  f"START < END, got '{number_text(a)},"
                                  f"{number_text(b)}'.")
    s = np.append(np.arange(a, b, 0.5), b)
    height = platform.mast_height_m if height_m is None else height_m
    return platform_trajectory(al.to_world(s, offset_m, height), platform, speed_mps,
                               scene=scene, accel_mps2=accel_mps2, follow_grade=not level,
                               height_m=height)


def _auto_route(output: str | os.PathLike[str], scene: Any, platform: PlatformSpec,
                speed_mps: float, *, waypoints: Any, height_m: float | None,
                clearance_m: float | None, voxel_m: float | None,
                accel_mps2: float | None, level: bool) -> tuple[Trajectory, AutoRoute]:
    """The route found in the mesh (``sensors.route.find_route``) at ``height_m``
    (default the platform's mast height) above the floor, written beside the output as
    ``_route.csv``, and ``platform`` driven along it (``platform_trajectory``); a
    trajectory closer to the mesh than the route's clearance is refused."""
    import numpy as np

    from sensors.platform import platform_trajectory
    from sensors.route import find_route, read_waypoints
    from sensors.freespace import free_space

    wp = None if waypoints is None else read_waypoints(waypoints) \
        if isinstance(waypoints, (str, os.PathLike)) else np.asarray(waypoints, float)
    height = platform.mast_height_m if height_m is None else height_m
    clearance = ROUTE_CLEARANCE_M if clearance_m is None else clearance_m
    space = free_space(scene, voxel_m=voxel_m)
    route = find_route(scene, waypoints=wp, height_m=height, space=space,
                       clearance_m=clearance, platform=platform)
    traj = platform_trajectory(route, platform, speed_mps, scene=scene,
                               accel_mps2=accel_mps2, follow_grade=not level,
                               height_m=height)
    p = traj.positions
    # Poses every ~5 cm of travel (and the first and last): the exact distance to the
    # mesh; the route itself is checked at every point by find_route.
    step = max(1, int(0.05 / max(float(np.median(np.linalg.norm(np.diff(p, axis=0),
                                                                axis=1))), 1e-6))) \
        if len(p) > 1 else 1
    clear = float(space.distance(np.vstack([p[::step], p[-1:]])).min())
    # The poses follow a spline through the route's points: they may come a little
    # nearer than the route where it is narrow (issue 29: the route's own least
    # clearance, with 1 cm for the spline, is what is asked of them then).
    need = min(clearance, route.min_clearance_m - 0.01)
    if clear < need:
        raise SimulationError(f"Expected the {platform.name} to keep {need:.3g} m from "
                              f"the mesh, got {clear:.3g} m; use --waypoints to steer it "
                              "or a smaller --voxel.")
    path = route.write_csv(beside(output, "_route.csv"))
    return traj, AutoRoute(Path(path), float(route.length_m), float(route.min_clearance_m),
                           float(route.voxel_m), float(route.seconds), platform.name,
                           platform.motion, float(traj.duration_s), float(height), clear)


def _check_drive_reach(scene: Any, spec: SensorSpec, traj: Trajectory, mount: Any,
                       t_end: float | None, allow_outside: bool) -> str:
    """Refuse (unless ``allow_outside``) a drive whose every sensor position lies
    farther from the mesh's bounding box than the sensor's maximum range: it cannot
    return a point. Returns the clause that explains a drive returning (almost)
    nothing.

    DECISION: the margin is the sensor's range, not a fixed one: a pose within range of
    the box may see the mesh (a drive starting before a portal), and one beyond it
    never does, so the refusal before simulating is certain, not a guess. A drive that
    comes within range but returns almost nothing is refused after the simulation
    (``MIN_DRIVE_RETURN``)."""
    import numpy as np

    a, b = traj.start_s, traj.end_s if t_end is None else t_end
    t = np.unique(np.concatenate([[a, b], traj.times[(traj.times > a) & (traj.times < b)]]))
    if len(traj) < 2:
        t = t[:1]
    pos, _ = traj.sensor_matrices(t, mount)
    lo, hi = scene.bounds
    gap = np.linalg.norm(np.maximum(np.maximum(lo - pos, pos - hi), 0.0), axis=1)
    reach = spec.physics.range_max_m
    span = f"sensor positions within {box_text(pos.min(axis=0), pos.max(axis=0))}"
    if gap.min() > reach and not allow_outside:
        raise SimulationError(f"Expected a trajectory within the {spec.name}'s "
                              f"{reach:g} m range of the mesh's bounding box "
                              f"{box_text(lo, hi)}, got {span}, {gap.min():.6g} m from it "
                              "at the nearest; is it in another coordinate frame? Pass "
                              "--allow-outside if you mean it.")
    hint = "" if allow_outside else "; pass --allow-outside if you mean it"
    return (f"; the {span} may lie outside the mesh {box_text(lo, hi)} or in another "
            f"coordinate frame{hint}")


def drive_robot(spec: SensorSpec, platform: PlatformSpec | None, mount: Any,
                height_m: float | None = None) -> RobotDescription:
    """A drive's robot description (``sensors.robot``): the platform's (at
    ``height_m``) carrying the sensor on ``mount``; without a platform (a trajectory
    file), base_link is the trajectory's frame."""
    from sensors.pointcloud2 import GENERIC_DRIVER
    from sensors.robot import RobotDescription

    frame = (spec.driver or GENERIC_DRIVER).frame_id
    if platform is None:
        return RobotDescription("platform", frame, 0.0, mount)
    return RobotDescription.from_platform(platform, frame, mount, height_m=height_m)


def _with_cameras(robot: RobotDescription, cams: Sequence[Any]) -> RobotDescription:
    """``robot`` carrying the drive's cameras (``sensors.camera_drive.DriveCamera``):
    their body and optical frames, as the bag's ``/tf_static`` states them."""
    from dataclasses import replace

    from sensors.robot import camera_link

    return replace(robot, cameras=tuple(camera_link(dc.cam, dc.link_mount) for dc in cams))


def _robot_files(output: str | os.PathLike[str], robot: RobotDescription) -> RobotFiles:
    """``<stem>_robot.urdf`` and ``<stem>_robot.launch.py`` (robot_state_publisher)
    beside the output."""
    urdf = robot.write_urdf(beside(output, "_robot.urdf"))
    launch = robot.write_launch(beside(output, "_robot.launch.py"), urdf.name)
    return RobotFiles(robot.name, float(robot.mast_height_m), Path(urdf), Path(launch))


def _slam_files(output: str | os.PathLike[str], run: Run, traj: Trajectory,
                meta: dict[str, Any], *, full: Trajectory, crs: Any, seed: int
                ) -> tuple[DriftedRun, SlamFiles]:
    """Observe the drive through a drifting SLAM (``survey.adjust.slam``) and write
    what a surveyor would have besides the cloud: the SLAM and true trajectories and
    the control points (world, and observed in the MLS frame). Returns the drifted run.

    ``traj`` is the part driven; when it is a part of ``full`` (a duration), the
    control points are those the full drive passes nearest (horizontally) within the
    part's time span, as ``observe_control`` times its observations."""
    import numpy as np

    from survey.adjust.slam import observe_slam

    cps = meta.get("control_points", [])
    ids = [c["id"] for c in cps]
    g = np.array([c["xyz"] for c in cps], dtype=np.float64).reshape(-1, 3)
    if full is not traj and len(g):
        near = np.argmin(np.linalg.norm(full.positions[None, :, :2] - g[:, None, :2],
                                        axis=2), axis=1)
        keep = full.times[near] <= traj.end_s
        ids, g = [i for i, k in zip(ids, keep) if k], g[keep]
    obs = observe_slam(run, traj, ids, g, seed=seed)
    files = SlamFiles(Path(obs.slam.write(beside(output, "_trajectory.txt"))),
                      Path(obs.true.write(beside(output, "_true_trajectory.txt"))),
                      Path(obs.observed.write(beside(output, "_cp_observed.csv"))),
                      Path(obs.world.write(beside(output, "_cp_world.csv"))),
                      len(obs.observed))
    if crs is not None:     # the world points are in the mesh's CRS: say so
        from sensors.io.crs import crs_comment

        files.cp_world.write_text(crs_comment(crs) + "\n" + files.cp_world.read_text())
    return obs.run, files


def _write_drive(run: Run, output: str | os.PathLike[str], *, fields: str | None,
                 crs: Any, progress: ProgressFn | None, bag: dict[str, Any] | None,
                 robot: RobotDescription | None, waveform_data: str | None,
                 cameras: Sequence[Any]) -> tuple[RunOutput, dict[str, float]]:
    """Write the drive ``run`` to ``output``: a bag in the frames of ``robot`` when given
    and the output is a bag (``survey.workflows.robotbag``, the ``cameras``' frames in
    it), else ``write_run`` (``Run.write``, which refuses a waveform run into a bag).
    Returns what was written (the lidar's own time and rate) and the seconds each
    camera's frames took in the bag (name: s; empty without a robot's bag)."""
    from sensors.writers import format_of

    if robot is not None and format_of(output) in ("mcap", "rosbag2") and \
            not getattr(run.settings, "waveform", False):
        from survey.workflows.robotbag import write_robot_bag

        stats = write_robot_bag(output, run, robot, progress=progress, crs=crs,
                                cameras=cameras, **(bag or {}))
        return run_output(stats, output), dict(stats["camera_seconds"])
    return write_run(run, output, fields=fields, crs=crs, progress=progress, bag=bag,
                     waveform_data=waveform_data), {}


# ---------------------------------------------------------------------------- cameras
def _check_camera_options(output: str | os.PathLike[str], cameras: Sequence[Any], *,
                          rate_hz: float | None, mount: Sequence[float] | None,
                          samples: int, lamp_cd: float | None, slam_drift: bool,
                          window_s: float | None) -> list[Any]:
    """The cameras of a drive (``CameraSpec``), loaded and checked with their options
    before anything is simulated (each error names the command-line option)."""
    from sensors.camera import CameraSpec, load_camera
    from sensors.camera_drive import camera_mount, drive_lamps, frame_times
    from sensors.errors import CameraSpecError
    from sensors.shading import stratified_offsets
    from sensors.writers import format_of

    if not cameras:
        given = [f for f, on in (("--camera-rate-hz", rate_hz is not None),
                                 ("--camera-mount", mount is not None),
                                 ("--camera-samples", samples != 1),
                                 ("--lamp-cd", lamp_cd is not None)) if on]
        if given:
            raise SimulationError(f"Expected --camera NAME with {given[0]}, got no "
                                  "--camera.")
        return []
    specs = []
    for c in cameras:
        if isinstance(c, CameraSpec):
            specs.append(c)
            continue
        try:
            specs.append(load_camera(c))
        except CameraSpecError as exc:
            raise CameraSpecError(f"--camera: {exc} 'tunnelsim cameras' lists the names."
                                  ) from None
    names = [c.name for c in specs]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise SimulationError(f"Expected each --camera once, got {twice[0]} "
                              f"{names.count(twice[0])} times.")
    for cam in specs:
        frame_times(cam, (0.0, 0.0), rate_hz)           # the rate against each camera

    if samples != 1 and all(c.kind == "depth" for c in specs):
        raise SimulationError(f"Expected --camera-samples 1 for the depth camera "
                              f"{specs[0].name} (a depth camera does not average), got "
                              f"{samples}; drop --camera-samples.")
    try:
        stratified_offsets(samples)
    except SimulationError as exc:
        raise SimulationError(str(exc).replace("--samples", "--camera-samples")) from None
    if mount is not None:
        camera_mount(mount)
    drive_lamps(None, lamp_cd)
    if format_of(output) in ("mcap", "rosbag2"):
        bad = [f for f, on in (("--slam-drift", slam_drift),
                               ("--window-s", window_s is not None)) if on]
        if bad:
            raise SimulationError(f"Expected --camera in a ROS 2 bag without {bad[0]}, got "
                                  f"both; write the points to a file (the frames go to "
                                  "PNG folders beside it) or drop one.")
    return specs


def _drive_cameras(specs: Sequence[Any], mesh: str | os.PathLike[str], scene: Any,
                   base_traj: Trajectory, span_s: tuple[float, float], *,
                   lidar_mount: Any, mount: Sequence[float] | None,
                   platform: PlatformSpec | None, lamp_cd: float | None,
                   rate_hz: float | None, samples: int, seed: int, noise: bool
                   ) -> tuple[list[Any], str]:
    """The drive's cameras (``sensors.camera_drive.DriveCamera``) on base_link's
    trajectory, and what lights them."""
    from sensors.appearance import mesh_appearance
    from sensors.camera_drive import (DriveCamera, camera_mount, default_camera_mount,
                                      drive_lamps, readout_s)
    from sensors.io.meshes import read_mesh
    from survey.workflows.render import label_names

    m = read_mesh(mesh)
    app = mesh_appearance(m, label_names(mesh) if "label" in m.face_fields else None)
    link = camera_mount(mount) if mount is not None else default_camera_mount(lidar_mount)
    lamps, said = drive_lamps(platform, lamp_cd)
    out = []
    for k, cam in enumerate(specs):
        dc = DriveCamera(scene, cam, base_traj, link, app, span_s=span_s, rate_hz=rate_hz,
                         lamps=lamps, seed=seed, noise=noise, index=k,
                         samples_per_pixel=1 if cam.kind == "depth" else samples)
        if not len(dc):
            raise SimulationError(f"Expected the drive ({span_s[1] - span_s[0]:.3g} s) to "
                                  f"hold one frame of {cam.name}, whose readout takes "
                                  f"{readout_s(cam):.3g} s, got none; pass a longer "
                                  "--duration.")
        out.append(dc)
    return out, said


def _camera_runs(cams: Sequence[Any], lamps: str, folders: Sequence[Path | None],
                 seconds: dict[str, float]) -> tuple[CameraRun, ...]:
    """What each camera made (``seconds``: its time, by name)."""
    from sensors.bag import camera_topics

    out = []
    for dc, folder in zip(cams, folders):
        c = dc.cam
        tp = camera_topics(c)
        out.append(CameraRun(c.name, c.kind, c.width, c.height, float(dc.rate_hz), len(dc),
                             dc.rays * dc.samples_per_pixel,
                             "global" if c.global_shutter else "rolling",
                             lamps if c.kind == "color" else "no light needed", folder,
                             () if folder is not None else (tp.image, tp.info),
                             float(seconds.get(c.name, 0.0))))
    return tuple(out)


def _planned_trajectory(mesh: str | os.PathLike[str], output: str | os.PathLike[str], *,
                        along: str | None, platform: Any, speed_mps: float | None,
                        duration_s: float | None, standstill_s: float,
                        route_opts: dict[str, Any], line_opts: dict[str, Any]) -> tuple:
    """The trajectory of a drive ``along`` the centreline or a route found in the mesh:
    (trajectory, platform spec, tunnel JSON or None, (scene, reflectivity) or None,
    AutoRoute or None)."""
    from sensors.io.meshes import load_mesh
    from sensors.platform_spec import PlatformSpec, load_platform

    if along is None:
        raise SimulationError("Expected --trajectory FILE, or --along centreline (or "
                              "auto) with --speed V, got neither.")
    if speed_mps is None:
        raise SimulationError(f"Expected --speed V (m/s) with --along {along}, got none; "
                              "pass e.g. --speed 1.")
    auto = along == "auto"
    if not isinstance(platform, PlatformSpec):
        platform = load_platform(platform or ("ground_robot" if auto else "trolley"))
    if platform.motion == "static" and (duration_s is None or standstill_s):
        raise SimulationError(f"Expected --duration S (and no --standstill) with the "
                              f"static platform {platform.name}, got "
                              f"{'--standstill' if standstill_s else 'none'}.")
    meta = loaded = route = None
    if auto:
        loaded = load_mesh(mesh)
        traj, route = _auto_route(output, loaded[0], platform, speed_mps, **route_opts)
    else:
        meta = _tunnel_meta(mesh)
        if platform.motion != "rail":      # it finds the floor in the mesh
            loaded = load_mesh(mesh)
        traj = _centreline(meta, platform, speed_mps,
                           scene=None if loaded is None else loaded[0], **line_opts)
    if standstill_s:
        traj = traj.with_standstill(standstill_s, standstill_s)
    return traj, platform, meta, loaded, route


def drive_to_file(mesh: str | os.PathLike[str], output: str | os.PathLike[str], *,
                  sensor: str | os.PathLike[str] | SensorSpec = "robosense_airy",
                  trajectory: str | os.PathLike[str] | Trajectory | None = None,
                  along: str | None = None, waypoints: Any = None,
                  clearance_m: float | None = None, voxel_m: float | None = None,
                  platform: str | os.PathLike[str] | PlatformSpec | None = None,
                  level: bool = False, speed_mps: float | None = None,
                  height_m: float | None = None, offset_m: float = 0.0,
                  margin_m: float = 1.0, mount: str = "level",
                  lever_arm_m: Sequence[float] = (0.0, 0.0, 0.0),
                  duration_s: float | None = None, keep_partial_sweep: bool = False,
                  chainage_m: Sequence[float] | None = None, rate_hz: float | None = None,
                  accel_mps2: float | None = None, standstill_s: float = 0.0,
                  allow_outside: bool = False, slam_drift: bool = False,
                  start_time: str | float | None = None, ros_distro: str | None = None,
                  crs: str | None = None, settings: Any = None, seed: int = 0,
                  reflectivity: float = 0.5, fields: str | None = None,
                  waveform_data: str | None = None, window_s: float | None = None,
                  executor: Executor | None = None,
                  progress: ProgressFn | None = None,
                  cameras: Sequence[str | os.PathLike[str] | Any] = (),
                  camera_rate_hz: float | None = None,
                  camera_mount: Sequence[float] | None = None,
                  camera_samples: int = 1, lamp_cd: float | None = None,
                  camera_noise: bool = True) -> DriveResult:
    """Simulate a sensor on a moving platform into a point file or a ROS 2 bag, each
    pulse cast from the pose at its own time (rolling shutter): what ``tunnelsim
    drive`` does, with every file it writes.

    With ``cameras``, their frames along the drive (``sensors.camera_drive``: a
    rolling shutter's rows each from the pose at its own time) go into the bag
    (``sensor_msgs/Image`` + ``CameraInfo`` on the camera driver's topics,
    ``sensors.bag.camera_topics``), or beside a point file into
    ``<stem>_cameras/<camera>/`` (``sensors.camera_io.FrameFolder``).

    Beside ``output`` (named after its stem, ``output_stem``): the true trajectory
    ``_true_trajectory.txt`` (TUM; and ``_base_link_trajectory.txt`` where base_link
    is not the platform frame), the robot's ``_robot.urdf`` and ``_robot.launch.py``,
    ``_route.csv`` with ``along="auto"``; with ``slam_drift`` the SLAM trajectory and
    the control points (``_trajectory.txt``, ``_cp_world.csv``, ``_cp_observed.csv``)
    instead of the base_link trajectory. A bag output (``.mcap`` or a name without a
    suffix) is written in the robot's frames (``survey.workflows.robotbag``).

    Parameters
    ----------
    mesh : str or path-like
        Mesh file.
    output : str or path-like
        .laz, .las, .copc.laz, .ply, .npz, or a ROS 2 bag (.mcap, or a folder name).
    sensor : str, path-like or SensorSpec
        A sensor name, a TOML file or a loaded spec.
    trajectory : str, path-like or sensors.Trajectory, optional
        TUM text (t x y z qx qy qz qw) or CSV trajectory. Give it or ``along``.
    along : {"centreline", "auto"}, optional
        Drive along the tunnel centreline (needs the mesh's .json) or along a route
        found in the mesh (between its farthest ends, or through ``waypoints``).
    waypoints : str, path-like or (k, 2|3) float, optional
        With ``along="auto"``: x, y[, z] to drive through in order.
    clearance_m : float, optional
        With ``along="auto"``: distance the route keeps from the mesh (default
        ``ROUTE_CLEARANCE_M``).
    voxel_m : float, optional
        With ``along="auto"``: voxel edge of the route's grid (default: automatic).
    platform : str, path-like or PlatformSpec, optional
        With ``along``: what carries the sensor (default trolley on the centreline,
        ground_robot on a route).
    level : bool
        With ``along``: keep the platform level.
    speed_mps : float, optional
        Speed along the path (m/s), needed with ``along``.
    height_m : float, optional
        Sensor mount height above the centreline (above the floor on a route; default
        the platform's mast height).
    offset_m, margin_m : float
        Platform offset left of the centreline; distance kept from the portals (m).
    mount : {"level", "down"}
        Sensor z up, or pointing down.
    lever_arm_m : (3,) float
        Lever arm platform -> sensor (m).
    duration_s : float, optional
        Simulate only the first ``duration_s`` seconds.
    keep_partial_sweep : bool
        Keep the last, partial sweep (by default a drive ends at its last whole one).
    chainage_m : (start, end) float, optional
        With ``along="centreline"``: drive only this chainage range (m).
    rate_hz : float, optional
        Rotation (profile) rate instead of the spec's.
    accel_mps2 : float, optional
        With ``along``: start and stop at rest with this acceleration.
    standstill_s : float
        With ``along``: stand still this long before and after the drive (s).
    allow_outside : bool
        Drive a trajectory beyond the sensor's range of the mesh's box, or one returning
        fewer than ``MIN_DRIVE_RETURN`` of its pulses, instead of refusing it.
    slam_drift : bool
        With ``along="centreline"``: write the cloud in a drifting SLAM frame, with the
        SLAM and true trajectories and the control points.
    start_time : str or float, optional
        With a bag: ROS time of the scan's start, seconds since 1970 or ISO 8601 with
        its offset.
    ros_distro : {"humble", "jazzy"}, optional
        With a bag folder: the rosbag2 metadata layout.
    crs : str, optional
        CRS of the mesh's coordinates, stated in the output (default the mesh's own).
    settings : sensors.Settings, optional
        Physics switches (default ``Settings()``).
    seed : int
    reflectivity : float
        Reflectivity where the mesh has none.
    fields : {"compact", "full"}, optional
        LAS/LAZ extra bytes.
    waveform_data : {"internal", "external"}, optional
        With ``settings.waveform``: where the wave packets go (as in ``scan_to_file``).
    window_s : float, optional
        Simulate in time windows of about this many seconds (cut at whole sweeps), each
        a task on ``executor``; the output holds the same points as one piece.
    executor : survey.cluster.Executor, optional
        Where the windows run (default in this process); only with ``window_s``.
    progress : callable (done_pulses, total_pulses), optional
    cameras : sequence of str, path-like or sensors.camera.CameraSpec
        Cameras on the platform (names, TOML files or specs), each once.
    camera_rate_hz : float, optional
        Frames per second (default each camera's frame rate; at most that).
    camera_mount : (3,) or (6,) float, optional
        base_link -> camera_link: X, Y, Z (m)[, roll, pitch, yaw (deg)] (default
        ``sensors.camera_drive.default_camera_mount``: 0.1 m below the lidar, level,
        looking forward). One mount for all the cameras (one device).
    camera_samples : int
        Colour and thermal cameras: rays per pixel (a square number), their radiance
        averaged (anti-aliasing); depth cameras take the pixel centre whatever it is.
    lamp_cd : float, optional
        A headlamp beside the camera (candela; default none on a platform with lamps,
        else 1000; given with them both light): ``sensors.camera_drive.drive_lamps``.
    camera_noise : bool
        The cameras' shot, read and NETD noise.

    Returns
    -------
    DriveResult

    Raises
    ------
    SimulationError
        Options that do not go together, a duration past the trajectory, a trajectory
        out of the sensor's reach of the mesh, a drive that returns too few points.
    sensors.errors.PlatformError, sensors.errors.RouteError
        A platform that cannot follow the path, no route in the mesh.
    sensors.io.errors.FileFormatError
        An unreadable mesh, trajectory or tunnel JSON.

    Examples
    --------
    >>> from survey.workflows.drive import drive_to_file
    >>> # r = drive_to_file("tunnel.ply", "drive.laz", sensor="velodyne_vlp16",
    >>> #                   along="centreline", speed_mps=1.0, duration_s=2.0)
    >>> # r.output.points, r.true_trajectory, r.robot.urdf
    """
    from sensors import Mount, Trajectory, simulate_drive
    from sensors.io.meshes import load_mesh
    from sensors.writers import format_of

    _check_drive_options(trajectory=trajectory, along=along, waypoints=waypoints,
                         clearance_m=clearance_m, voxel_m=voxel_m, platform=platform,
                         level=level, chainage_m=chainage_m, offset_m=offset_m,
                         slam_drift=slam_drift, window_s=window_s, mount=mount)
    if executor is not None and window_s is None:
        raise SimulationError("Expected --window-s with --workers or --scheduler (a drive "
                              "is split into time windows to run on a cluster), got no "
                              "--window-s.")
    lever = _lever(lever_arm_m)
    spec = sensor_spec(sensor, rate_hz)
    if not Path(mesh).is_file():
        raise SimulationError(f"Expected a mesh file, got '{mesh}' which does not exist.")
    cam_specs = _check_camera_options(output, cameras, rate_hz=camera_rate_hz,
                                      mount=camera_mount, samples=camera_samples,
                                      lamp_cd=lamp_cd, slam_drift=slam_drift,
                                      window_s=window_s)
    stated = output_crs(mesh, crs)      # before the simulation: a bad crs fails at once
    bag = _bag_options(output, start_time, ros_distro)
    meta = loaded = plat = route = None
    if trajectory is not None:
        traj = trajectory if isinstance(trajectory, Trajectory) else \
            Trajectory.read(trajectory)
    else:
        traj, plat, meta, loaded, route = _planned_trajectory(
            mesh, output, along=along, platform=platform, speed_mps=speed_mps,
            duration_s=duration_s, standstill_s=standstill_s,
            route_opts=dict(waypoints=waypoints, height_m=height_m,
                            clearance_m=clearance_m, voxel_m=voxel_m,
                            accel_mps2=accel_mps2, level=level),
            line_opts=dict(chainage_m=chainage_m, margin_m=margin_m, offset_m=offset_m,
                           height_m=height_m, accel_mps2=accel_mps2, level=level))
    # DECISION: checked before the mesh is loaded (a large mesh's BVH takes seconds);
    # along="auto" needs the mesh to find its route first.
    t_end = drive_end(duration_s, traj)
    sweeps = None
    if not keep_partial_sweep:
        t_end, sweeps = whole_sweeps_end(spec, traj, t_end)
    mnt = Mount.pointing_down(lever) if mount == "down" else Mount(lever)
    scene, refl = load_mesh(mesh) if loaded is None else loaded
    where = _check_drive_reach(scene, spec, traj, mnt, t_end, allow_outside)
    robot = drive_robot(spec, plat, mnt, height_m)
    refl_or = refl if refl is not None else reflectivity
    # A Run, or with slam_drift the DriftedRun made of it (written alike).
    run: Any = simulate_drive(scene, spec, traj, mnt,
                              settings=physics_settings(settings), seed=seed,
                              reflectivity=refl_or, t_end=t_end)
    driven = trimmed(traj, t_end)      # every output covers the same time span
    cams: list[Any] = []
    lamps_said = ""
    if cam_specs:
        cams, lamps_said = _drive_cameras(
            cam_specs, mesh, scene, robot.base_trajectory(traj),
            (run.t0, run.t0 + run.duration_s), lidar_mount=robot.sensor_mount_from_base(),
            mount=camera_mount, platform=plat, lamp_cd=lamp_cd, rate_hz=camera_rate_hz,
            samples=camera_samples, seed=seed, noise=camera_noise)
        robot = _with_cameras(robot, cams)
    slam = true_path = base_path = None
    if slam_drift:
        assert meta is not None        # slam_drift needs along="centreline"
        run, slam = _slam_files(output, run, driven, meta, full=traj, crs=stated,
                                seed=seed)
        # DECISION: the drifted cloud lies in the SLAM frame, which is not the mesh's
        # CRS to survey accuracy (that is what 'correct' repairs): it states none; the
        # world control points state it, and 'correct' gives it to the corrected cloud.
        stated = None
    else:                              # every drive writes the truth it drove (issue 22)
        true_path = Path(driven.write(beside(output, "_true_trajectory.txt")))
        if robot.mast_height_m > 0:
            base_path = Path(robot.base_trajectory(driven).write(
                beside(output, "_base_link_trajectory.txt")))
    label = f"{spec.name} drive {run.duration_s:.1f} s"
    min_return = 0.0 if allow_outside else MIN_DRIVE_RETURN
    n_windows, ran_on = 0, None
    cam_s: dict[str, float] = {}       # each camera's seconds (name: s)
    if window_s is not None:
        from survey.cluster import Executor, simulate_windows

        ex = Executor() if executor is None else executor
        ran_on = ex.describe()
        man = simulate_windows(run, window_s, output, reflectivity=refl_or, executor=ex,
                               fields=fields, crs=stated, progress=progress)
        wins = man.get("windows", [])
        n_windows = len(wins)
        points = sum(int(w.get("points", 0)) for w in wins)
        check_returned(label, run.n_pulses, points, min_return, "", share=False)
        nan = float("nan")
        out = RunOutput(Path(output), int(run.n_pulses), points, nan, nan, nan)
    else:
        # DECISION: a drifted run's bag keeps its own frames (the SLAM frame's poses).
        out, cam_s = _write_drive(run, output, fields=fields, crs=stated,
                                  progress=progress, bag=bag,
                                  robot=None if slam_drift else robot,
                                  waveform_data=waveform_data, cameras=cams)
        check_returned(label, out.pulses, out.points, min_return, where)
    folders: list[Path | None] = [None] * len(cams)
    if cams and format_of(output) not in ("mcap", "rosbag2"):
        from sensors.camera_drive import write_frame_folder

        for k, dc in enumerate(cams):
            t0 = time.perf_counter()
            folders[k] = write_frame_folder(dc, beside(output, "_cameras") / dc.cam.name,
                                            info={"lamps": lamps_said, "sensor": spec.name})
            cam_s[dc.cam.name] = time.perf_counter() - t0
    files = _robot_files(output, robot)
    return DriveResult(out, spec.name, float(run.duration_s), stated, route, sweeps,
                       true_path, base_path, len(driven), slam, files, n_windows,
                       window_s, ran_on, _camera_runs(cams, lamps_said, folders, cam_s))


__all__ = ["MIN_DRIVE_RETURN", "ROUTE_CLEARANCE_M", "AutoRoute", "CameraRun", "DriveResult",
           "RobotFiles", "SlamFiles", "SweepCut", "beside", "drive_end", "drive_robot",
           "drive_to_file", "output_stem", "sweep_rate_hz", "trimmed", "whole_sweeps_end"]
