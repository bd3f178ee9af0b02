"""Scan workflows: what ``tunnelsim scan`` does (one TLS station, or a campaign of
stations), as library functions that take paths and keyword options, write the same
files and return what the command prints.

- ``scan_to_file``: one station on a mesh -> a point file (LAS/LAZ, PLY, NPZ, E57).
- ``scan_campaign``: stations every STEP m on the tunnel axis, or a plan's, -> one
  file per station and ``manifest.json`` in a folder (on an executor).

Guards (each a ``SimulationError`` naming the command-line option): a station outside
the mesh's bounding box (unless ``allow_outside``), a station that returns no point,
chainages off the tunnel axis.

DECISION: nothing heavy is imported at module level (NumPy, SciPy, the simulator are
imported where they run): ``survey.cli.commands.scanning`` reads this module's
``STATION_FORMATS`` and ``station_heading_deg`` on every ``tunnelsim`` start, which must
not load NumPy.
"""

from __future__ import annotations

import math
import os
import warnings
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
    sensor_spec,
    write_run,
    xyz_text,
)

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from sensors.spec_types import SensorSpec
    from survey.cluster import Campaign, Executor

#: A campaign's station file formats (``survey.cluster.campaign.STATION_FORMATS``).
STATION_FORMATS = ("laz", "las", "ply", "npz", "e57")



@dataclass(frozen=True)
class ScanResult:
    """What ``scan_to_file`` wrote.

    Attributes
    ----------
    output : RunOutput
    sensor : str
        The sensor's name.
    resolution : str
        The resolution preset scanned, or ``"custom step"``.
    station_xyz : (float, float, float)
        The station's position (m).
    crs : str or None
        The CRS the file states.
    """

    output: RunOutput
    sensor: str
    resolution: str
    station_xyz: tuple[float, float, float]
    crs: str | None

    @property
    def label(self) -> str:
        """``"<sensor> <resolution>"``, as the command's summary starts."""
        return f"{self.sensor} {self.resolution}"


@dataclass(frozen=True)
class CampaignResult:
    """What ``scan_campaign`` wrote.

    Attributes
    ----------
    campaign : survey.cluster.Campaign
        The folder, ``manifest.json`` (and what it holds), each station's time.
    sensor, resolution : str
        The sensor's name and the resolution scanned (``"custom step"`` for a step).
    stations, pulses, points : int
    wall_s : float
        Wall-clock time of the campaign (s).
    simulation_s : float
        Simulation time summed over the stations (s).
    where : str
        Where it ran (``"in-process"``, ``"local, 4 workers"`` ...).
    """

    campaign: Campaign
    sensor: str
    resolution: str
    stations: int
    pulses: int
    points: int
    wall_s: float
    simulation_s: float
    where: str

    @property
    def manifest_path(self) -> Path:
        """The campaign's ``manifest.json``."""
        return self.campaign.manifest_path


def station_heading_deg(heading_deg: float | None, azimuth_deg: float | None) -> float:
    """A station's heading in degrees counter-clockwise from +x (east), from a heading
    or from an azimuth (clockwise from grid north, +y): heading = 90 - azimuth; 0 when
    neither is given.

    Examples
    --------
    >>> station_heading_deg(None, 30.0)
    60.0
    """
    if azimuth_deg is not None:
        return 90.0 - azimuth_deg
    return 0.0 if heading_deg is None else heading_deg



def scan_to_file(mesh: str | os.PathLike[str], output: str | os.PathLike[str], *,
                 sensor: str | os.PathLike[str] | SensorSpec = "zf_imager_5016",
                 at: Sequence[float] | None = None, chainage_m: float | None = None,
                 height_m: float = 1.5, tunnel_json: str | os.PathLike[str] | None = None,
                 resolution: str | None = None, step_rad: float | None = None,
                 heading_rad: float = 0.0, allow_outside: bool = False,
                 crs: str | None = None, settings: Any = None, seed: int = 0,
                 reflectivity: float = 0.5, fields: str | None = None,
                 waveform_data: str | None = None,
                 progress: ProgressFn | None = None) -> ScanResult:
    """Simulate one terrestrial laser scanner station on a mesh into a point file:
    what ``tunnelsim scan`` does.

    Parameters
    ----------
    mesh : str or path-like
        Mesh file (PLY with reflectivity, OBJ, ...).
    output : str or path-like
        Point file: .laz, .las, .ply, .npz or .e57.
    sensor : str, path-like or SensorSpec
        A sensor name, a TOML file or a loaded spec.
    at : (3,) float, optional
        Station position (m). Give ``at`` or ``chainage_m``.
    chainage_m : float, optional
        Station on the tunnel axis (``tunnel_json`` or the mesh's .json), ``height_m``
        above the floor.
    height_m : float
        Instrument height above the floor with ``chainage_m`` (m).
    tunnel_json : str or path-like, optional
        The axis for ``chainage_m`` and the CRS (default: the mesh's .json).
    resolution : str, optional
        Resolution preset of the sensor (default its own).
    step_rad : float, optional
        Angular step instead of a preset (rad).
    heading_rad : float
        Station heading counter-clockwise from +x (rad).
    allow_outside : bool
        Scan from a station outside the mesh's bounding box.
    crs : str, optional
        CRS of the mesh's coordinates, stated in the file (default the mesh's own).
    settings : sensors.Settings, optional
        Physics switches (default ``Settings()``).
    seed : int
    reflectivity : float
        Reflectivity where the mesh has none.
    fields : {"compact", "full"}, optional
        LAS/LAZ extra bytes.
    waveform_data : {"internal", "external"}, optional
        With ``settings.waveform``: the wave packets in the .las, or in ``NAME.wdp``
        beside the output (default: the format's, ``sensors.writers``).
    progress : callable (done_pulses, total_pulses), optional

    Returns
    -------
    ScanResult

    Raises
    ------
    SimulationError
        A station outside the mesh's box (unless ``allow_outside``), a station that
        returns no point, a chainage off the axis.
    sensors.io.errors.FileFormatError
        An unreadable mesh or tunnel JSON.

    Examples
    --------
    >>> from survey.workflows.scan import scan_to_file
    >>> # r = scan_to_file("tunnel.ply", "station.laz", at=(10, 0, 1.5),
    >>> #                  resolution="low")
    >>> # r.output.points, r.output.path
    """
    import numpy as np
    from scipy.spatial.transform import Rotation

    from sensors import simulate_station
    from sensors.io.meshes import load_mesh
    from sensors.patterns import TLSScan

    spec = sensor_spec(sensor)
    scene, refl = load_mesh(mesh)
    stated = output_crs(mesh, crs, tunnel_json=tunnel_json)
    if chainage_m is not None:
        pos = stations_on_axis(mesh, scene, [chainage_m], "--chainage", height_m=height_m,
                               tunnel_json=tunnel_json)[0]
    elif at is not None:
        pos = np.asarray(at, dtype=np.float64)
    else:
        raise SimulationError("Expected a station, got neither --at nor --chainage; "
                              "pass --at X,Y,Z.")
    lo, hi = scene.bounds
    if not allow_outside and ((np.asarray(pos) < lo) | (np.asarray(pos) > hi)).any():
        raise SimulationError(f"Expected a station inside the mesh's bounding box "
                              f"{box_text(lo, hi)}, got {xyz_text(pos)}; is it in another "
                              "coordinate frame? Pass --allow-outside to scan the mesh "
                              "from outside.")
    with warnings.catch_warnings():
        # Refused above, or allowed by allow_outside: the library's warning is said.
        warnings.filterwarnings("ignore", "Station .* outside the mesh", UserWarning)
        run = simulate_station(scene, spec, pos, attitude=Rotation.from_euler(
                                   "z", heading_rad), resolution=resolution,
                               step_rad=step_rad, settings=physics_settings(settings),
                               seed=seed,
                               reflectivity=refl if refl is not None else reflectivity)
    res = (run.scan.resolution if isinstance(run.scan, TLSScan) else None) or \
        "custom step"
    out = write_run(run, output, fields=fields, crs=stated, progress=progress,
                    waveform_data=waveform_data)
    check_returned(f"{spec.name} {res}", out.pulses, out.points, 0.0,
                   f" at {xyz_text(pos)}; put the station where it sees the mesh")
    xyz = tuple(float(c) for c in pos)
    return ScanResult(out, spec.name, res, (xyz[0], xyz[1], xyz[2]), stated)


def stations_on_axis(mesh: str | os.PathLike[str], scene: Any, chainages: ArrayLike,
                     flag: str, *, height_m: float,
                     tunnel_json: str | os.PathLike[str] | None = None) -> Any:
    """Stations (k, 3) float64 on the tunnel axis (``tunnel_json`` or the mesh's .json)
    at ``chainages`` (k,) m, ``height_m`` above the floor of ``scene``; ``flag`` names
    the option the chainages came from in the errors."""
    from survey.analysis.planning import axis_stations
    from survey.world.mesh import read_axis
    from sensors.io.tunnel_json import sidecar

    js = Path(tunnel_json) if tunnel_json else sidecar(Path(mesh))
    if not js.is_file():
        other = " or --at X,Y,Z" if flag == "--chainage" else ""
        raise SimulationError(f"Expected a tunnel JSON for {flag} ('{js}'), got none; "
                              f"pass --tunnel-json{other}.")
    al, hc = read_axis(js)
    c0, c1 = al.chainage_range
    import numpy as np

    ch = np.asarray(chainages, dtype=np.float64).reshape(-1)
    lo, hi = float(ch.min()), float(ch.max())
    if not (c0 <= lo and hi <= c1):
        got = f"{lo:g}" if lo == hi else f"{lo:g} to {hi:g} m"
        raise SimulationError(f"Expected {flag} within [{c0:g}, {c1:g}] m, got {got}.")
    return axis_stations(scene, al, hc, ch, height_m=height_m)


def _campaign_stations(mesh: str | os.PathLike[str], scene: Any, heading_rad: float, *,
                       chainages_m: Sequence[float] | None, plan: Any,
                       plan_name: str | None, height_m: float,
                       tunnel_json: Any) -> tuple[list[Any], dict[str, Any]]:
    """(the stations of ``chainages_m`` or ``plan``, what the manifest says of them)."""
    import numpy as np

    from survey.cluster import Station, read_plan

    if plan is not None:
        name, stations = read_plan(plan, plan_name)
        return [Station(s.position, heading_rad, s.chainage_m) for s in stations], \
            {"plan": str(plan), "plan_name": name}
    start, stop, step = (float(v) for v in chainages_m or ())
    text = ":".join(number_text(v) for v in (start, stop, step))
    if not (all(map(math.isfinite, (start, stop, step))) and step > 0 and stop >= start):
        raise SimulationError(f"Expected --chainages START:STOP:STEP with STEP > 0 and "
                              f"STOP >= START, got {text!r}.")
    # Chainages on the grid START + k STEP up to STOP, STOP included when on it (to a
    # micrometre: 0.1 steps do not add up exactly in binary).
    ch = start + step * np.arange(int(math.floor((stop - start) / step + 1e-9)) + 1)
    xyz = stations_on_axis(mesh, scene, ch, "--chainages", height_m=height_m,
                           tunnel_json=tunnel_json)
    return [Station((float(x), float(y), float(z)), heading_rad, float(c))
            for (x, y, z), c in zip(xyz, ch)], {"chainages": text, "height_m": height_m}


def scan_campaign(mesh: str | os.PathLike[str], folder: str | os.PathLike[str], *,
                  chainages_m: Sequence[float] | None = None,
                  plan: str | os.PathLike[str] | None = None, plan_name: str | None = None,
                  sensor: str | os.PathLike[str] | SensorSpec = "zf_imager_5016",
                  height_m: float = 1.5, tunnel_json: str | os.PathLike[str] | None = None,
                  resolution: str | None = None, step_rad: float | None = None,
                  heading_rad: float = 0.0, allow_outside: bool = False,
                  fmt: str = "laz", crs: str | None = None, settings: Any = None,
                  seed: int = 0, reflectivity: float = 0.5, fields: str | None = None,
                  executor: Executor | None = None,
                  progress: ProgressFn | None = None) -> CampaignResult:
    """Simulate a campaign of TLS stations into ``folder``: one file per station and
    ``manifest.json``, on ``executor`` (what ``tunnelsim scan --chainages`` / ``--plan``
    does).

    Parameters
    ----------
    mesh : str or path-like
    folder : str or path-like
        Output folder, created when missing (its parent must exist); files in it are
        replaced one by one.
    chainages_m : (start, stop, step) float, optional
        A station every ``step`` m from ``start`` to ``stop`` (included when on the
        grid) on the tunnel axis, ``height_m`` above the floor.
    plan : str or path-like, optional
        A ``plan.json`` of ``tunnelsim plan``; ``plan_name`` picks one of its plans
        (default the optimised one, or the only one). Give ``chainages_m`` or ``plan``.
    sensor, height_m, tunnel_json, resolution, step_rad, heading_rad
        As in ``scan_to_file``.
    allow_outside, crs, settings, seed, reflectivity, fields
        As in ``scan_to_file``.
    fmt : {"laz", "las", "ply", "npz", "e57"}
        The stations' file format.
    executor : survey.cluster.Executor, optional
        Where the stations run (default in this process).
    progress : callable (done_stations, total_stations), optional

    Returns
    -------
    CampaignResult

    Raises
    ------
    SimulationError
        A sensor that is not a TLS, stations outside the mesh's box (unless
        ``allow_outside``), a station that returns no point, chainages off the axis.

    Examples
    --------
    >>> from survey.workflows.scan import scan_campaign
    >>> # r = scan_campaign("tunnel.ply", "campaign", chainages_m=(10, 50, 10),
    >>> #                   resolution="low")
    >>> # r.manifest_path, r.points
    """
    import time
    from dataclasses import asdict

    import numpy as np

    from sensors.io.meshes import load_mesh
    from sensors.spec_types import TLSPattern
    from survey.cluster import Executor, scan_stations

    if plan_name is not None and plan is None:
        raise SimulationError("Expected --plan-name with --plan, got it with --chainages.")
    if (plan is None) == (chainages_m is None):
        raise SimulationError("Expected one of --chainages START:STOP:STEP or --plan "
                              "PLAN_JSON, got " + ("both." if plan is not None else
                                                   "neither."))
    spec = sensor_spec(sensor)
    if not isinstance(spec.pattern, TLSPattern):
        raise SimulationError(f"Expected a TLS sensor for a campaign of stations, got "
                              f"{spec.name} ({spec.kind}); use 'tunnelsim drive'.")
    out = Path(folder)
    out.mkdir(exist_ok=True)
    stated = output_crs(mesh, crs, tunnel_json=tunnel_json)
    ex = Executor() if executor is None else executor
    scene, refl = load_mesh(mesh)
    stations, info = _campaign_stations(mesh, scene, heading_rad, chainages_m=chainages_m,
                                        plan=plan, plan_name=plan_name, height_m=height_m,
                                        tunnel_json=tunnel_json)
    lo, hi = scene.bounds
    at = np.array([s.position for s in stations])
    outside = np.flatnonzero(((at < lo) | (at > hi)).any(axis=1))
    if len(outside) and not allow_outside:
        raise SimulationError(f"Expected every station inside the mesh's bounding box "
                              f"{box_text(lo, hi)}, got station {int(outside[0])} at "
                              f"{xyz_text(at[outside[0]])} ({len(outside)} outside); is "
                              "the plan of another mesh? Pass --allow-outside to scan "
                              "them anyway.")
    settings = physics_settings(settings)
    t0 = time.perf_counter()
    camp = scan_stations(scene, spec, stations, out, executor=ex, resolution=resolution,
                         step_rad=step_rad, settings=settings, seed=seed,
                         reflectivity=refl if refl is not None else reflectivity,
                         fmt=fmt, fields=fields, crs=stated, progress=progress,
                         info={"mesh": str(mesh), **info, "settings": asdict(settings)})
    wall = time.perf_counter() - t0
    empty = [s["station"] for s in camp.manifest["stations"] if s["points"] == 0]
    if empty:
        raise SimulationError(f"Expected every station to see the mesh, got no point at "
                              f"station {empty[0]} ({len(empty)} such); put the stations "
                              "where they see the mesh.")
    res = resolution or ("custom step" if step_rad is not None else
                         spec.pattern.default_resolution)
    where = f"{ex.kind}, {ex.workers} workers" if ex.workers > 1 else ex.kind
    return CampaignResult(camp, spec.name, res, len(stations), camp.pulses, camp.points,
                          wall, float(camp.seconds.sum()), where)



__all__ = ["STATION_FORMATS", "CampaignResult", "ScanResult", "scan_campaign",
           "scan_to_file", "station_heading_deg", "stations_on_axis"]
