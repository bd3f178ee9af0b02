"""``tunnelsim plan`` and ``tunnelsim study`` as library calls: TLS station planning and
the MLS speed x rate x mounting study on a mesh, with the files the commands write.

``plan_stations`` and ``run_study`` choose the frame (the tunnel axis from the mesh's
JSON, or the route found in any mesh), run ``survey.analysis.planning`` /
``survey.analysis.study`` (on an executor where asked) and write the reports of
``survey.report.planning`` / ``survey.report.study``; the commands parse their options,
call one of these, and print from the result.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from raytrace.fileio import write_json
from survey.errors import PlanningError, StudyError, TunnelsimError
from survey.workflows.files import opened_executor, output_folder, write_text_file

__all__ = ["PlanResult", "StudyResult", "plan_stations", "resolve_along", "run_study"]

PathLike = str | os.PathLike[str]
ProgressFn = Callable[[int, int], None]
#: Floor points kept per configuration for the study's figure.
STUDY_KEEP_POINTS = 40_000


@dataclass(frozen=True)
class PlanResult:
    """What ``plan_stations`` wrote and computed.

    Attributes
    ----------
    output_dir : Path
        The output folder, as given.
    along : {"centreline", "auto"}
        Stations on the tunnel axis, or along the route found in the mesh.
    plans : tuple of survey.analysis.planning.Plan
        One per spacing, then (with ``optimize``) the optimised and the greedy set.
    markdown : str
        plan.md without its header block.
    summary : dict
        What plan.json holds.
    route_file : Path or None
        route.csv (``along="auto"``).
    files : tuple of Path
        Every file written.
    """

    output_dir: Path
    along: str
    plans: tuple[Any, ...]
    markdown: str
    summary: dict[str, Any]
    route_file: Path | None
    files: tuple[Path, ...]


@dataclass(frozen=True)
class StudyResult:
    """What ``run_study`` wrote and computed.

    Attributes
    ----------
    output_dir : Path
        The output folder, as given.
    sensor : str
        The sensor's name.
    rows : tuple of survey.analysis.study.StudyRow
        One per configuration (speed, rate, mounting).
    strip_m : (float, float)
        The evaluation strip, m of chainage (or of distance along the route).
    lead_m : float
        The run-in before and after the strip, m.
    markdown : str
        study.md without its header block.
    route_file : Path or None
        route.csv (along the route found in the mesh).
    files : tuple of Path
        Every file written.
    """

    output_dir: Path
    sensor: str
    rows: tuple[Any, ...]
    strip_m: tuple[float, float]
    lead_m: float
    markdown: str
    route_file: Path | None
    files: tuple[Path, ...]


def resolve_along(mesh: PathLike, along: str | None, waypoints: Any = None, *,
                  error: type[TunnelsimError] = PlanningError) -> str:
    """'centreline' or 'auto': ``along``, else centreline where the mesh's JSON gives the
    axis (alignment and profile); waypoints are refused with the centreline."""
    from sensors.io.tunnel_json import read_meta, sidecar

    if along is None:
        js = sidecar(Path(mesh))
        along = "centreline" if js.is_file() and \
            {"alignment", "profile"} <= set(read_meta(js)) else "auto"
    if along not in ("centreline", "auto"):
        raise error(f"Expected --along centreline or auto, got {along!r}.")
    if waypoints is not None and along != "auto":
        raise error("Expected --waypoints with --along auto, got it with the tunnel "
                    "centreline (the mesh's .json gives the axis; pass --along auto).")
    return along


def _waypoints(waypoints: Any) -> Any:
    """Waypoints (k, 3) of a CSV path, or the array given; None stays None."""
    from sensors.route import read_waypoints

    if waypoints is None:
        return None
    if isinstance(waypoints, (str, os.PathLike)):
        return read_waypoints(waypoints)
    return np.asarray(waypoints, dtype=np.float64)


# ---------------------------------------------------------------------------- plan
def plan_stations(mesh: PathLike, output_dir: PathLike, *,
                  sensor: Any = "zf_imager_5016", resolution: str | None = None,
                  spacings_m: Sequence[float] = (5.0, 10.0), optimize: bool = False,
                  target: float = 0.99, candidate_step_m: float = 2.5,
                  time_limit_s: float = 60.0, spacing_threshold_m: float = 0.005,
                  incidence_deg: float = 70.0, range_m: float = 30.0,
                  cell_m: float = 0.25, cell_deg: float = 2.0, height_m: float = 1.5,
                  along: str | None = None, waypoints: Any = None,
                  offsets_m: Sequence[float] = (1.0,), clearance_m: float = 0.2,
                  executor: Any = None, force: bool = False, project: str | None = None,
                  instrument: str | None = None, progress: ProgressFn | None = None
                  ) -> PlanResult:
    """TLS station planning on a mesh, written as ``tunnelsim plan`` writes it.

    Quality of every lining cell (coverage, point spacing, incidence, range) for
    stations at each spacing, and with ``optimize`` the smallest station set reaching
    ``target`` (MILP, greedy bound). Writes plan.csv, plan.md, plan.html, plan.json,
    coverage.png and (along a route) route.csv into ``output_dir``.

    Parameters
    ----------
    mesh : path-like
        Tunnel mesh (its JSON gives the axis) or any mesh.
    output_dir : path-like
        Output folder: created; an existing non-empty one only with ``force``.
    sensor : str, path-like or sensors.SensorSpec
        TLS sensor name or TOML (``sensors.load_sensor``).
    resolution : str, optional
        Resolution preset (default: the sensor's).
    spacings_m : sequence of float
        Station spacings to compare, m.
    optimize : bool
        Also find the smallest station set for ``target``.
    target : float
        Coverage share to reach with ``optimize``.
    candidate_step_m : float
        Candidate stations every this many metres.
    time_limit_s : float
        MILP time limit, s.
    spacing_threshold_m, incidence_deg, range_m : float
        Quality thresholds: point spacing (m), incidence (degrees, as the command's
        --incidence-deg), range (m).
    cell_m, cell_deg : float
        Lining cell along (m) and around (degrees); along a route, ``cell_m`` is the
        largest edge of a triangle sample.
    height_m : float
        Instrument height above the floor, m.
    along : {"centreline", "auto"}, optional
        Stations on the tunnel axis (needs the mesh's JSON) or along the route found in
        the mesh (default: centreline when the JSON gives the axis).
    waypoints : path-like or (k, 2|3) array, optional
        With ``along="auto"``: points the route passes in order.
    offsets_m : sequence of float
        With ``along="auto"`` and ``optimize``: candidates also this far left and right
        of the route, m.
    clearance_m : float
        With ``along="auto"``: smallest distance of a station from the mesh, m.
    executor : survey.cluster.Executor or callable () -> Executor, optional
        Where the station qualities are computed (default: this process); a callable is
        called after the folder is made, what it returns closed at the end.
    force : bool
        Write into a non-empty ``output_dir``.
    project, instrument : str, optional
        The user's words the report header states.
    progress : callable(done, total), optional
        Stations done on a cluster (not called in-process).

    Returns
    -------
    PlanResult

    Raises
    ------
    PlanningError
        Bad options for the mesh, a non-empty ``output_dir`` without ``force``.

    Examples
    --------
    >>> r = plan_stations("bfo.ply", "plan", spacings_m=[5, 10])    # doctest: +SKIP
    >>> [round(p.coverage, 3) for p in r.plans]                      # doctest: +SKIP
    [0.998, 0.981]
    """
    from sensors import load_sensor
    from survey.analysis.planning import Planner, RoutePlanner, Thresholds

    spec = load_sensor(sensor) if isinstance(sensor, (str, os.PathLike)) else sensor
    th = Thresholds(spacing_threshold_m, np.deg2rad(incidence_deg), range_m)
    how = resolve_along(mesh, along, waypoints)
    if how == "auto":
        from sensors.io.meshes import load_mesh

        wp = _waypoints(waypoints)
        scene, _ = load_mesh(mesh)
        pl: Planner = RoutePlanner(scene, spec, waypoints=wp, resolution=resolution,
                                   thresholds=th, sample_m=cell_m, height_m=height_m,
                                   clearance_m=clearance_m)
    else:
        from survey.clouds.axis import tunnel_frame

        scene, _, al, hc = tunnel_frame(Path(mesh))
        pl = Planner(scene, al, hc, spec, resolution=resolution, thresholds=th,
                     cell_m=cell_m, cell_rad=np.deg2rad(cell_deg), height_m=height_m)
    out = output_folder(output_dir, force=force, error=PlanningError)
    sets = [pl.spaced(sp) for sp in spacings_m]
    cand = None
    if optimize:
        if isinstance(pl, RoutePlanner):
            side = np.abs(np.asarray(offsets_m, dtype=np.float64))
            cand = pl.candidates(candidate_step_m, np.concatenate([side, -side]))
        else:
            cand = pl.spaced(candidate_step_m)
    with opened_executor(executor) as ex:
        if ex.kind != "in-process":
            _fan_out_stations(ex, pl, [*sets, *([] if cand is None else [cand])], out,
                              progress)
    plans = [pl.evaluate(c, f"every {sp:g} m") for c, sp in zip(sets, spacings_m)]
    info = None
    if cand is not None:
        best, greedy, info = pl.optimize(cand, target=target, time_limit_s=time_limit_s)
        plans += [best, greedy]
    return _plan_outputs(mesh, out, Path(output_dir), pl, plans, info, how,
                         project=project, instrument=instrument)


def _plan_outputs(mesh: PathLike, out: Path, given: Path, pl: Any, plans: list[Any],
                  info: Any, how: str, *, project: str | None,
                  instrument: str | None) -> PlanResult:
    """plan.csv, plan.md/.html, plan.json, coverage.png (and route.csv)."""
    from survey.analysis.planning import RoutePlanner
    from survey.report.header import write_headed_report
    from survey.report.planning import plan_csv, plan_markdown, plan_summary, plot_coverage

    write_text_file(out / "plan.csv", "".join(
        plan_csv(p, pl) if i == 0 else plan_csv(p, pl).split("\n", 1)[1]
        for i, p in enumerate(plans)))
    md = plan_markdown(plans, pl, info)
    plot_coverage(plans, pl, out / "coverage.png")
    reports = write_headed_report(out / "plan.md", md, inputs=[("mesh", mesh, "")],
                                  crs_from=[mesh], project=project, instrument=instrument)
    summary = plan_summary(plans, pl, info)
    write_json(out / "plan.json", summary)
    route = None
    if isinstance(pl, RoutePlanner):
        route = out / "route.csv"
        pl.route.write_csv(route)
    files = (out / "plan.csv", *reports, out / "plan.json", out / "coverage.png",
             *([] if route is None else [route]))
    return PlanResult(output_dir=given, along=how, plans=tuple(plans), markdown=md,
                      summary=summary, route_file=route, files=files)


def _fan_out_stations(ex: Any, pl: Any, chainage_sets: list[Any], out: Path,
                      progress: ProgressFn | None) -> None:
    """Compute the station qualities every plan will need as tasks on ``ex`` (the
    planner, with its scene and cells, sent once) and give them to the planner; the
    plans are then the same as computed one by one here."""
    from survey.cluster import call_shared

    need = pl.uncached(np.concatenate([pl.stations_at(c) for c in chainage_sets
                                       if len(c)] or [np.zeros((0, 3))]))
    ref = ex.share(pl, out)
    got = ex.map(call_shared, [(ref, "quality", (p,)) for p in need], progress=progress)
    pl.remember(need, got)


# ---------------------------------------------------------------------------- study
def run_study(mesh: PathLike, output_dir: PathLike, *, sensor: Any = "robosense_airy",
              speeds_mps: Sequence[float] = (0.0, 1.0, 3.0),
              rates_hz: Sequence[float] = (10.0,),
              mounts: Sequence[str] = ("level", "down"),
              strip_m: tuple[float, float] | None = None, lead_m: float = 5.0,
              height_m: float = 0.5, cell_m: float = 0.1, ideal: bool = False,
              seed: int = 0, along: str | None = None, waypoints: Any = None,
              executor: Any = None, force: bool = False, project: str | None = None,
              instrument: str | None = None, progress: ProgressFn | None = None
              ) -> StudyResult:
    """The MLS speed x scan-rate x mounting study on a mesh, written as ``tunnelsim
    study`` writes it.

    A spinning lidar (or profiler) drives through an evaluation strip at each speed,
    rate and mounting: density on lining and floor, empty lining share, along-track
    line spacing, rolling-shutter distortion. Writes study.csv, study.md, study.html,
    study.png and (along a route) route.csv into ``output_dir``.

    Parameters
    ----------
    mesh : path-like
        Tunnel mesh (its JSON gives the axis) or any mesh.
    output_dir : path-like
        Output folder: created; an existing non-empty one only with ``force``.
    sensor : str, path-like or sensors.SensorSpec
        Sensor name or TOML.
    speeds_mps, rates_hz : sequence of float
        Speeds (m/s) and rotation (profile) rates (Hz).
    mounts : sequence of {"level", "down"}
        Mountings.
    strip_m : (float, float), optional
        Evaluation strip in chainage, m (default: 5 m mid-tunnel).
    lead_m : float
        Drive this far before and after the strip, m.
    height_m : float
        Sensor height above the floor, m.
    cell_m : float
        Cell size along the axis, or along a route the largest edge of a triangle
        sample, m.
    ideal : bool
        Exact geometry: no noise, every return detected.
    seed : int
        Random seed.
    along, waypoints
        As in ``plan_stations``.
    executor : survey.cluster.Executor or callable () -> Executor, optional
        Where the configurations run (default: this process).
    force : bool
        Write into a non-empty ``output_dir``.
    project, instrument : str, optional
        The user's words the report header states.
    progress : callable(done, total), optional
        Configurations done.

    Returns
    -------
    StudyResult

    Raises
    ------
    StudyError
        Bad options for the mesh, a non-empty ``output_dir`` without ``force``.

    Examples
    --------
    >>> r = run_study("bfo.ply", "study", speeds_mps=[0, 1])         # doctest: +SKIP
    >>> [row.speed_mps for row in r.rows]                            # doctest: +SKIP
    [0.0, 0.0, 1.0, 1.0]
    """
    from sensors import Settings, load_sensor
    from survey.analysis.study import Study

    spec = load_sensor(sensor) if isinstance(sensor, (str, os.PathLike)) else sensor
    speeds, rates, mounts = list(speeds_mps), list(rates_hz), list(mounts)
    kw: dict[str, Any] = dict(strip_m=strip_m, lead_m=lead_m,
                              settings=Settings.ideal() if ideal else None, seed=seed,
                              keep_points=STUDY_KEEP_POINTS)
    route = None
    if resolve_along(mesh, along, waypoints, error=StudyError) == "auto":
        from sensors.io.meshes import load_mesh
        from sensors.route import find_route

        wp = _waypoints(waypoints)
        scene, refl = load_mesh(mesh)
        route = find_route(scene, waypoints=wp, height_m=height_m)
        st = Study.along_route(scene, route, spec, sample_m=cell_m,
                               reflectivity=refl if refl is not None else 0.5, **kw)
    else:
        from survey.clouds.axis import tunnel_frame

        scene, refl, al, hc = tunnel_frame(Path(mesh))
        st = Study(scene, al, hc, spec, height_m=height_m, cell_m=cell_m,
                   reflectivity=refl if refl is not None else 0.5, **kw)
    out = output_folder(output_dir, force=force, error=StudyError)
    with opened_executor(executor) as ex:
        if ex.kind == "in-process":
            rows = st.grid(speeds, rates, mounts, progress=progress)
        else:
            from survey.cluster import call_shared

            combos = st.configurations(speeds, rates, mounts)
            ref = ex.share(st, out)
            got = ex.map(call_shared, [(ref, "run_kept", c) for c in combos],
                         progress=progress)
            rows = [row for row, _ in got]
            for (v, f, m), (_, kp) in zip(combos, got):
                if kp is not None:
                    st.kept[(float(v), float(f), m)] = kp
    return _study_outputs(mesh, out, Path(output_dir), st, spec.name, rows, route,
                          mounts, rates, project=project, instrument=instrument)


def _study_outputs(mesh: PathLike, out: Path, given: Path, st: Any, sensor: str,
                   rows: list[Any], route: Any, mounts: list[str], rates: list[float],
                   *, project: str | None, instrument: str | None) -> StudyResult:
    """study.csv, study.md/.html, study.png (and route.csv)."""
    from survey.report.header import write_headed_report
    from survey.report.study import plot_study, study_csv, study_markdown

    write_text_file(out / "study.csv", study_csv(rows))
    md = study_markdown(rows, sensor, st.strip_m, st.lead_m, route=route)
    plot_study(st, rows, out / "study.png",
               rings_mount="down" if "down" in mounts else None, rings_rate=rates[0])
    reports = write_headed_report(out / "study.md", md, inputs=[("mesh", mesh, "")],
                                  crs_from=[mesh], settings=[("sensor", sensor)],
                                  project=project, instrument=instrument)
    route_file = None
    if route is not None:
        route_file = out / "route.csv"
        route.write_csv(route_file)
    files = (out / "study.csv", *reports, out / "study.png",
             *([] if route_file is None else [route_file]))
    return StudyResult(output_dir=given, sensor=sensor, rows=tuple(rows),
                       strip_m=(float(st.strip_m[0]), float(st.strip_m[1])),
                       lead_m=float(st.lead_m), markdown=md, route_file=route_file,
                       files=files)
