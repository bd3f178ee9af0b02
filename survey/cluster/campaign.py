"""A campaign of TLS stations: one output file per station and a manifest, simulated on
any ``Executor`` (this process, a LocalCluster, a dask cluster) with the same bytes.

Each station's seed is derived from the campaign's seed and the station's index
(``station_seed``), so a station is reproduced alone by ``tunnelsim scan --at X,Y,Z
--seed S`` with the manifest's seed S, and the result does not depend on which worker
ran it, in which order, or how often (a task lost with a killed worker reruns
elsewhere and writes the same file; every file is written atomically).

The manifest (``manifest.json``, ``MANIFEST_FORMAT``) lists per station: its index,
chainage (or None), pose (position in m, heading in degrees counter-clockwise from +x,
quaternion x, y, z, w), file (relative to the manifest), pulses, points, seed and the
file's SHA-256. It holds no timing, so that two runs of a campaign give the same
manifest byte for byte.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from survey.errors import PlanningError

from .execution import ClusterError, Executor, SceneRef

__all__ = ["MANIFEST_FORMAT", "MANIFEST_NAME", "Campaign", "Station", "read_plan",
           "scan_stations", "sha256_of", "station_file", "station_seed"]

#: ``format`` of a campaign manifest; bump when its keys change.
MANIFEST_FORMAT = "tunnelsim-campaign/1"
#: File name of the manifest in a campaign's folder.
MANIFEST_NAME = "manifest.json"
#: Suffixes a station file may take (the formats ``Run.write`` writes for a station).
STATION_FORMATS = ("laz", "las", "ply", "npz", "e57")


@dataclass(frozen=True)
class Station:
    """One TLS station of a campaign.

    Attributes
    ----------
    position : (3,) tuple of float
        Instrument position in world coordinates (m).
    heading_rad : float
        Heading, radians counter-clockwise from +x (the station is level).
    chainage_m : float or None
        Chainage along the tunnel axis, when the station was placed by one.
    """

    position: tuple[float, float, float]
    heading_rad: float = 0.0
    chainage_m: float | None = None


def station_seed(base_seed: int, index: int) -> int:
    """The seed of station ``index`` (>= 0) of a campaign seeded ``base_seed`` (>= 0).

    ``numpy.random.SeedSequence(base_seed, spawn_key=(index,))``'s first 64-bit word,
    its top bit cleared (a non-negative int64): the spawned child sequences NumPy
    recommends for parallel streams (NumPy docs, "Parallel random number generation"),
    so stations draw independent streams, and a station's seed depends on nothing but
    the two numbers.

    >>> station_seed(0, 0) == station_seed(0, 0) != station_seed(0, 1)
    True
    """
    for v, what in ((base_seed, "base_seed"), (index, "index")):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ClusterError(f"Expected `{what}` as a whole number >= 0, got {v!r}.")
    word = np.random.SeedSequence(int(base_seed), spawn_key=(int(index),)).generate_state(
        1, dtype=np.uint64)[0]
    return int(word) >> 1


def sha256_of(path: str | os.PathLike[str], block: int = 1 << 20) -> str:
    """Hex SHA-256 of a file, read ``block`` bytes at a time."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(block):
            h.update(chunk)
    return h.hexdigest()


# ---------------------------------------------------------------------------- plans
def read_plan(path: str | os.PathLike[str], name: str | None = None
              ) -> tuple[str, list[Station]]:
    """The stations of a plan in a ``plan.json`` written by ``tunnelsim plan``.

    Parameters
    ----------
    path : str or path
    name : str, optional
        The plan to take (its ``name``, e.g. "every 10 m" or "optimised"); default: the
        optimised plan when the file has one (``optimisation`` is set: its first plan
        after the spacings), else the only plan.

    Returns
    -------
    name : str
    stations : list of Station
        Level, heading 0, with the plan's chainages.

    Raises
    ------
    PlanningError
        A file that is missing, not JSON, not a plan file, holds several plans and no
        ``name`` chooses one, or names no such plan.
    """
    p = Path(path)
    if not p.is_file():
        raise PlanningError(f"Expected a plan file (plan.json from 'tunnelsim plan'), got "
                            f"'{p}' which does not exist.")
    try:
        data = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PlanningError(f"Expected JSON in '{p}', got unreadable text ({exc}).") \
            from None
    plans = data.get("plans") if isinstance(data, dict) else None
    if not isinstance(plans, list) or not plans or \
            not all(isinstance(q, dict) and "name" in q for q in plans):
        raise PlanningError(f"Expected a 'plans' list in '{p}' (plan.json written by "
                            "'tunnelsim plan'), got none.")
    names = [str(q["name"]) for q in plans]
    if name is None:
        opt = [n for n in names if n.startswith("optim")]
        if opt:
            name = opt[0]
        elif len(names) == 1:
            name = names[0]
        else:
            raise PlanningError(f"Expected --plan-name to choose one of the plans "
                                f"{names} in '{p}', got none.")
    if name not in names:
        raise PlanningError(f"Expected a plan named one of {names} in '{p}', got "
                            f"{name!r}.")
    plan = plans[names.index(name)]
    try:
        xyz = np.asarray(plan["stations_xyz"], dtype=np.float64).reshape(-1, 3)
        ch = np.asarray(plan.get("chainages_m", [math.nan] * len(xyz)),
                        dtype=np.float64).reshape(-1)
    except (KeyError, TypeError, ValueError):
        raise PlanningError(f"Expected 'stations_xyz' as (k, 3) numbers in plan {name!r} "
                            f"of '{p}', got {str(plan.get('stations_xyz'))[:60]}.") from None
    if len(ch) != len(xyz) or not np.isfinite(xyz).all() or not len(xyz):
        raise PlanningError(f"Expected finite stations, one chainage each, in plan "
                            f"{name!r} of '{p}', got {len(xyz)} stations and {len(ch)} "
                            "chainages.")
    return name, [Station((float(x), float(y), float(z)), 0.0,
                          None if not math.isfinite(c) else float(c))
                  for (x, y, z), c in zip(xyz, ch)]


# ---------------------------------------------------------------------------- tasks
@dataclass(frozen=True)
class _Job:
    """What one worker needs to simulate and write one station (picklable)."""

    index: int
    station: Station
    seed: int
    path: str
    scene: SceneRef
    sensor: Any
    resolution: str | None
    step_rad: float | None
    settings: Any
    reflectivity: float
    fields: str | None
    crs: Any


def scan_station_job(job: _Job) -> dict[str, Any]:
    """Simulate and write one station (runs on a worker); its manifest row."""
    import warnings

    from scipy.spatial.transform import Rotation

    from sensors import simulate_station

    scene, refl = job.scene.load()
    rot = Rotation.from_euler("z", job.station.heading_rad)
    with warnings.catch_warnings():
        # The caller checked the stations against the mesh's box.
        warnings.filterwarnings("ignore", "Station .* outside the mesh", UserWarning)
        run = simulate_station(scene, job.sensor, job.station.position, attitude=rot,
                               resolution=job.resolution, step_rad=job.step_rad,
                               settings=job.settings, seed=job.seed,
                               reflectivity=refl if refl is not None else job.reflectivity)
    stats = run.write(job.path, fields=job.fields,
                      **({} if job.crs is None else {"crs": job.crs}))
    st = job.station
    return {"station": job.index,
            "chainage_m": st.chainage_m,
            "pose": {"position_m": [float(c) for c in st.position],
                     "heading_deg": math.degrees(st.heading_rad),
                     "quaternion_xyzw": [float(q) for q in rot.as_quat()]},
            "file": Path(job.path).name,
            "pulses": int(stats["pulses"]),
            "points": int(stats["points"]),
            "seed": job.seed,
            "sha256": sha256_of(job.path),
            "seconds": float(stats["seconds"])}


@dataclass
class Campaign:
    """The result of ``scan_stations``.

    Attributes
    ----------
    folder : Path
    manifest : dict
        What ``manifest.json`` holds.
    manifest_path : Path
    seconds : (k,) float64
        Simulation time of each station on its worker (s); not in the manifest.
    """

    folder: Path
    manifest: dict[str, Any]
    manifest_path: Path
    seconds: NDArray[np.float64]

    @property
    def points(self) -> int:
        """Points of all stations."""
        return int(sum(s["points"] for s in self.manifest["stations"]))

    @property
    def pulses(self) -> int:
        """Pulses of all stations."""
        return int(sum(s["pulses"] for s in self.manifest["stations"]))

    def __repr__(self) -> str:
        return (f"Campaign({len(self.manifest['stations'])} stations, {self.points:,} "
                f"points -> {self.folder})")


def station_file(index: int, count: int, fmt: str) -> str:
    """The file name of station ``index`` of ``count``: station_007.laz (at least three
    digits, more when the campaign needs them)."""
    return f"station_{index:0{max(3, len(str(max(count - 1, 0))))}d}.{fmt}"


def scan_stations(scene: Any, sensor: Any, stations: Sequence[Station],
                  folder: str | os.PathLike[str], *, executor: Executor | None = None,
                  resolution: str | None = None, step_rad: float | None = None,
                  settings: Any = None, seed: int = 0,
                  reflectivity: NDArray[np.float64] | float | None = None,
                  fmt: str = "laz", fields: str | None = None, crs: Any = None,
                  progress: Callable[[int, int], None] | None = None,
                  info: dict[str, Any] | None = None) -> Campaign:
    """Simulate ``stations`` into ``folder`` (one file each, ``station_000.laz`` ...)
    and write ``manifest.json`` there.

    Parameters
    ----------
    scene : raytrace.Scene
    sensor : SensorSpec
        A TLS sensor (``sensors.load_sensor``).
    stations : sequence of Station
    folder : str or path
        An existing folder; every worker must see it (it receives the files, and on a
        cluster the shared scene while the campaign runs).
    executor : Executor, optional
        Where the stations run (``open_executor``); this process by default.
    resolution, step_rad, settings, fields, crs
        As for ``sensors.simulate_station`` and ``Run.write``.
    seed : int >= 0
        The campaign's seed; station i uses ``station_seed(seed, i)``.
    reflectivity : (n_faces,) float64 or float, optional
        Per-face reflectivity (shipped with the scene), or one value for a mesh without
        (default ``settings.reflectivity``).
    fmt : {"laz", "las", "ply", "npz", "e57"}
    progress : callable(done, total), optional
        Called on this process as stations finish.
    info : dict, optional
        Extra keys for the manifest (the mesh, the command's settings).

    Returns
    -------
    Campaign

    Raises
    ------
    ClusterError
        No stations, a bad format or folder, or a cluster that lost a task for good.
    """
    from sensors import Settings

    if not stations:
        raise ClusterError("Expected at least one station, got none.")
    if fmt not in STATION_FORMATS:
        raise ClusterError(f"Expected a station format in {STATION_FORMATS}, got {fmt!r}.")
    out = Path(folder)
    if not out.is_dir():
        raise ClusterError(f"Expected an existing output folder, got '{out}'; create it "
                           "first.")
    ex = Executor() if executor is None else executor
    st = Settings() if settings is None else settings
    per_face = reflectivity is not None and np.ndim(reflectivity) > 0
    ref = ex.share_scene(scene, np.asarray(reflectivity, dtype=np.float64)
                         if per_face else None, out)
    default_rho = float(reflectivity) if reflectivity is not None and not per_face \
        else float(st.reflectivity)
    jobs = [_Job(i, s, station_seed(seed, i),
                 str((out / station_file(i, len(stations), fmt)).resolve()), ref, sensor,
                 resolution, step_rad, st, default_rho, fields, crs)
            for i, s in enumerate(stations)]
    rows = ex.map(scan_station_job, jobs, progress=progress)
    seconds = np.array([r.pop("seconds") for r in rows], dtype=np.float64)
    manifest = {"format": MANIFEST_FORMAT,
                "sensor": getattr(sensor, "name", str(sensor)),
                "resolution": resolution,
                "step_rad": step_rad,
                "seed": int(seed),
                "seed_rule": "numpy SeedSequence(seed, spawn_key=(station,)), first "
                             "uint64 word >> 1",
                **(info or {}),
                "stations": rows,
                "totals": {"stations": len(rows),
                           "pulses": int(sum(r["pulses"] for r in rows)),
                           "points": int(sum(r["points"] for r in rows))}}
    from raytrace.fileio import write_json

    path = write_json(out / MANIFEST_NAME, manifest)
    _remove_stale_parts(out, [Path(j.path).name for j in jobs])
    return Campaign(out, manifest, path, seconds)


def _remove_stale_parts(folder: Path, names: list[str]) -> None:
    """Remove what a worker killed while writing left behind: the writers' temporaries
    ``.name.*`` (a ``.part`` file, an NPZ writer's folder) of the campaign's files (the
    files themselves were written again, whole, by the rerun)."""
    import shutil

    for name in names:
        for p in folder.glob(f".{name}.*"):
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
