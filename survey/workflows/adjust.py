"""The surveyor's adjustment as library calls: ``adjust_files`` (a Helmert transformation
between two control-point files), ``transform_file`` (apply it to a cloud) and
``correct_file`` (correct the drift of an MLS run with control points). They write the
files ``tunnelsim adjust``, ``transform`` and ``correct`` write, byte for byte but for
the reports' time stamps, and return what those commands print.

Coordinate reference systems (``sensors.io.crs``): a control-point CSV states its CRS in
a leading comment line ``# crs: EPSG:2056`` (or in a sidecar ``<file>.prj``);
``adjust_files`` refuses two files that state different CRSs (unless
``allow_crs_mismatch``: a datum transformation estimated on purpose) and records both in
its JSON (``source_crs``, ``target_crs``, WKT2); ``transform_file`` writes the target CRS
into the output (``crs``, else the one the JSON records), refuses a cloud stating another
CRS than the transform's source, and drops an input's CRS it cannot replace (with a
warning); ``correct_file`` gives the corrected cloud the control points' CRS.

Error messages name the command-line options (``--columns``, ``--crs``), as the command
prints them; each keyword is named like its option (``crs`` is ``--crs``).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from raytrace.fileio import write_json
from sensors import Trajectory
from sensors.io.cloudmap import KEEP_CRS, map_cloud
from sensors.io.cloudread import cloud_crs_text
from sensors.io.crs import (
    CRSError,
    crs_label,
    crs_mismatch,
    crs_wkt,
    mismatch_message,
    parse_crs,
    same_crs,
    text_file_crs,
)
from survey.adjust.controlpoints import (
    ControlPoints,
    match,
    read_control_points,
    unmatched_message,
)
from survey.adjust.drift import DriftCorrection, fit_drift, leave_one_out
from survey.adjust.helmert import HelmertResult
from survey.adjust.snooping import Snooping, data_snooping
from survey.errors import ControlPointError, DriftError, HelmertError
from survey.report.adjustment import drift_report, helmert_report
from survey.report.header import report_header
from survey.report.html import write_report

__all__ = ["AdjustResult", "CorrectResult", "TransformResult", "adjust_files",
           "correct_file", "transform_file"]

PathLike = str | Path


@dataclass(frozen=True)
class AdjustResult:
    """What ``adjust_files`` computed and wrote.

    Attributes
    ----------
    helmert : HelmertResult
        The final adjustment (after data snooping, when asked).
    snooping : Snooping
        Every step of the data snooping (one step without it).
    report : str
        The report's Markdown (``survey.report.adjustment.helmert_report``), with its
        header: what ``tunnelsim adjust`` prints.
    unmatched : str or None
        The control point ids found in one file only, in words (None: all matched).
    source_crs, target_crs : str or None
        The CRS each file states (as written there), None where it states none.
    report_path, json_path : Path or None
        The files written (the report's HTML lies beside ``report_path``).
    """

    helmert: HelmertResult
    snooping: Snooping
    report: str
    unmatched: str | None
    source_crs: str | None
    target_crs: str | None
    report_path: Path | None = None
    json_path: Path | None = None


@dataclass(frozen=True)
class TransformResult:
    """What ``transform_file`` wrote.

    Attributes
    ----------
    output : Path, the transformed cloud
    points : int, the points transformed
    inverse : bool, whether the inverse transform was applied
    crs : str or None
        The CRS the output states: ``crs`` as given, else the WKT2 the Helmert JSON
        records; None when it states none.
    crs_label : str or None
        ``crs`` in words (``sensors.io.crs.crs_label``).
    """

    output: Path
    points: int
    inverse: bool
    crs: str | None
    crs_label: str | None


@dataclass(frozen=True)
class CorrectResult:
    """What ``correct_file`` computed and wrote.

    Attributes
    ----------
    correction : survey.adjust.drift.DriftCorrection
        The fitted drift correction.
    check_residuals_m : (k, 3) float64
        Leave-one-out check-point residuals (m): each control point predicted by the
        correction fitted without it, minus its world coordinates.
    model : str, "piecewise" or "global"
    points : int, the points corrected
    control_points : int, the control points used (found in both files)
    check_rms_m, check_max_m : float
        RMS and largest length of ``check_residuals_m`` (m).
    correction_max_m : float
        Largest shift of the trajectory's positions (m).
    output, trajectory_path, report_path, plot_path : Path
        The corrected cloud, the corrected trajectory (``<output>_trajectory.txt``),
        the report (``<output>_report.md``, its HTML beside it) and its plot
        (``<output>_correction.png``).
    json_path : Path or None
        The key figures as JSON, when asked.
    """

    correction: DriftCorrection
    check_residuals_m: NDArray[np.float64]
    model: str
    points: int
    control_points: int
    check_rms_m: float
    check_max_m: float
    correction_max_m: float
    output: Path
    trajectory_path: Path
    report_path: Path
    plot_path: Path
    json_path: Path | None = None


# ------------------------------------------------------------------- shared pieces
def _read_as(points: ControlPoints) -> str:
    """How a control-point file was read (its dialect in words)."""
    return "" if points.dialect is None else points.dialect.describe()


def _label(crs: Any) -> str:
    """A CRS in words; "none stated" for None."""
    return "none stated" if crs is None else crs_label(parse_crs(crs, metric=False))


def _wkt(crs: str | None) -> str | None:
    return None if crs is None else crs_wkt(crs)


def _json_out(path: PathLike, obj: Any, error: type[Exception]) -> Path:
    """Strict JSON written atomically; its folder must exist (else ``error``)."""
    p = Path(path)
    if not p.parent.exists():
        # The message ``tunnelsim`` has always printed for a missing output folder.
        raise error(f"Expected an existing folder for '{p}', got none; create it first.")
    return write_json(p, obj)


# ------------------------------------------------------------------- adjust
def _control_crs(source: PathLike, target: PathLike, allow_mismatch: bool
                 ) -> tuple[str | None, str | None]:
    """The CRSs the two control-point files state (``# crs:`` line or sidecar), refused
    when they differ unless ``allow_mismatch``."""
    crs_a, crs_b = text_file_crs(source), text_file_crs(target)
    if not allow_mismatch:
        pair = crs_mismatch([(str(source), crs_a), (str(target), crs_b)])
        if pair is not None:
            raise CRSError(mismatch_message(
                *pair, what="two control-point files",
                hint="between two stated CRSs a Helmert is a datum transformation: use "
                     "the published one (PROJ, pyproj.Transformer), or pass "
                     "--allow-crs-mismatch to estimate your own"))
    return crs_a, crs_b


def adjust_files(source: PathLike, target: PathLike, *, columns: str | None = None,
                 source_columns: str | None = None, target_columns: str | None = None,
                 model: str = "7", exclude: Iterable[str] = (), snoop: bool = False,
                 strict: bool = False, angles: str = "deg",
                 allow_reflection: bool = False, allow_scale: bool = False,
                 allow_crs_mismatch: bool = False, max_iter: int = 50,
                 report_path: PathLike | None = None, json_path: PathLike | None = None,
                 project: str | None = None, instrument: str | None = None
                 ) -> AdjustResult:
    """Least-squares Helmert transformation between two control-point files
    (``tunnelsim adjust``).

    Parameters
    ----------
    source, target : path-like
        Control points (id, x = Easting, y = Northing, z = height, optional sigma or
        sx, sy, sz in m) in the source and the target system, in any dialect
        ``survey.adjust.controlpoints.read_control_points`` reads; matched by id.
    columns, source_columns, target_columns : str, optional
        The columns of both files / of one file only, as ``--columns`` takes them
        (``"1,3,2,4"``, ``"Punkt,Y,X,Höhe"`` or ``"id=...,e=...,n=...,h=..."``);
        default: found from the header.
    model : {"7", "6", "9"}
        Similarity (default), rigid, or scale per axis.
    exclude : iterable of str
        Control point ids to leave out.
    snoop : bool
        Baarda's data snooping: remove the point with the largest test above the
        critical value and adjust again, until none is above.
    strict : bool
        Refuse ids found in one file only (default: a warning).
    angles : {"deg", "gon"}
        The report's rotations in arcsec and degrees, or in gon.
    allow_reflection, allow_scale : bool
        Fit even when the two systems are mirror images / with a scale beyond
        1,000 ppm.
    allow_crs_mismatch : bool
        Adjust between files that state different CRSs.
    max_iter : int
        Gauss-Newton iterations at most.
    report_path : path-like, optional
        Write the Markdown report here and the same as HTML beside it (.html).
    json_path : path-like, optional
        Write the parameters and statistics here (``HelmertResult.from_dict`` reads
        them back; ``transform_file`` applies them).
    project, instrument : str, optional
        The user's words the report header states.

    Returns
    -------
    AdjustResult

    Raises
    ------
    ControlPointError
        A control-point file that cannot be read, or ids in one file only with
        ``strict``.
    sensors.io.crs.CRSError
        Two files stating different CRSs (without ``allow_crs_mismatch``).
    HelmertError
        Too few points, mirror images, a scale beyond 1,000 ppm, no convergence, or
        a ``json_path`` whose folder does not exist.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from survey.adjust.helmert import from_parameters
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> src = np.array([[0.0, 0, 0], [50, 0, 0], [0, 60, 0], [40, 40, 8], [10, 30, 3]])
    >>> h = from_parameters([100.0, 200.0, 5.0], [0.0, 0.0, 900.0], 10.0)
    >>> ids = ["A", "B", "C", "D", "E"]
    >>> _ = ControlPoints(ids, src).write(d / "local.csv")
    >>> _ = ControlPoints(ids, h.apply(src)).write(d / "grid.csv")
    >>> r = adjust_files(d / "local.csv", d / "grid.csv", json_path=d / "h.json")
    >>> [round(float(v), 3) for v in r.helmert.translation_m]
    [100.0, 200.0, 5.0]
    >>> r.json_path.name
    'h.json'
    """
    a = read_control_points(source, columns=source_columns or columns,
                            flag="--source-columns" if source_columns else "--columns")
    b = read_control_points(target, columns=target_columns or columns,
                            flag="--target-columns" if target_columns else "--columns")
    names = (str(source), str(target))
    crs_a, crs_b = _control_crs(source, target, allow_crs_mismatch)
    ia, ib = match(a, b, unmatched_ids="error" if strict else "warn", names=names)
    lost = unmatched_message(a, b, names)
    sn = data_snooping(a.xyz[ia], b.xyz[ib], ids=[a.ids[i] for i in ia],
                       model=str(model),  # type: ignore[arg-type]
                       sigma_source_m=None if a.sigma is None else a.sigma[ia],
                       sigma_target_m=None if b.sigma is None else b.sigma[ib],
                       exclude=list(exclude), snoop=snoop, max_iter=max_iter,
                       allow_reflection=allow_reflection, allow_scale=allow_scale)
    res = sn.result
    stated = crs_a is not None or crs_b is not None
    notes = [f"control point ids not in both files, left out: {lost}."] if lost else []
    if stated:
        notes.append(f"coordinate reference systems: source {_label(crs_a)}, target "
                     f"{_label(crs_b)}.")
    head = report_header(
        [("source", source, _read_as(a)), ("target", target, _read_as(b))],
        crs=f"source {_label(crs_a)}, target {_label(crs_b)}" if stated else None,
        project=project, instrument=instrument,
        settings=[("model", f"{model} parameters"),
                  ("data snooping", "yes" if snoop else "no")])
    text = helmert_report(res, angles=angles, snooping=sn, notes=notes, header=head)
    if report_path is not None:
        write_report(report_path, text)
    if json_path is not None:
        _json_out(json_path, {**res.to_dict(), **sn.to_dict(),
                              "unmatched_ids": lost or None,
                              "source_crs": _wkt(crs_a), "target_crs": _wkt(crs_b),
                              "inputs": [{"role": i.role, "path": i.path,
                                          "sha256": i.sha256, "read_as": i.note}
                                         for i in head.inputs],
                              "project": project, "instrument": instrument},
                  HelmertError)
    return AdjustResult(res, sn, text, lost or None, crs_a, crs_b,
                        None if report_path is None else Path(report_path),
                        None if json_path is None else Path(json_path))


# ------------------------------------------------------------------- transform
def _read_helmert(path: PathLike) -> tuple[HelmertResult, dict[str, Any]]:
    """The Helmert transform of an ``adjust --json`` file and the file's object."""
    p = Path(path)
    if not p.is_file():
        raise HelmertError(f"Expected a Helmert JSON (from 'tunnelsim adjust --json'), "
                           f"got '{p}' which does not exist.")
    try:
        d = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise HelmertError(f"Expected JSON in '{p}', got invalid text ({exc}).") from exc
    return HelmertResult.from_dict(d), d   # refuses anything but adjust's JSON object


def _json_crs(d: dict[str, Any], key: str, p: PathLike) -> str | None:
    v = d.get(key)
    if v is not None and not (isinstance(v, str) and v.strip()):
        raise HelmertError(f"Expected '{key}' in '{p}' as WKT text or null, got {v!r}.")
    return v


def _transform_crs(cloud: PathLike, output: PathLike, d: dict[str, Any], p: PathLike,
                   inverse: bool, crs: str | None) -> Any:
    """The CRS the transformed cloud states: ``crs``, else the target (with ``inverse``
    the source) CRS the Helmert JSON records, else None. Refuses a cloud stating another
    CRS than the transform's source, and ``crs`` against a recorded target."""
    src, dst = _json_crs(d, "source_crs", p), _json_crs(d, "target_crs", p)
    if inverse:
        src, dst = dst, src
    target = parse_crs(crs, what="--crs") if crs is not None else None
    side = "source" if inverse else "target"
    if target is not None and dst is not None and not same_crs(target, dst):
        raise CRSError(f"Expected --crs to agree with the {side} CRS recorded in '{p}', "
                       f"got {_label(target)} and {_label(dst)}; leave --crs out, or "
                       "adjust again with control points in that CRS.")
    have = cloud_crs_text(cloud)
    if have is not None and src is not None and not same_crs(have, src):
        raise CRSError(mismatch_message(
            (str(cloud), have), (f"{p} ({'target' if inverse else 'source'})", src),
            what="cloud and the transform's input system",
            hint="the transform was estimated for other coordinates"))
    out = target if target is not None else dst
    if out is None and have is not None:
        warnings.warn(f"'{output}' states no CRS: the input's {_label(have)} does "
                      "not hold after the transform; give the new one with --crs.",
                      UserWarning, stacklevel=3)
    return out


def _pose_mover(res: HelmertResult, inverse: bool
                ) -> Callable[[Any, Any], tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """A station pose (position (3,), quaternion x, y, z, w (4,), sensor to world) in
    the Helmert's target system (source system with ``inverse``): position through
    ``apply`` (``apply_inverse``), attitude R -> R_h R (R_h^T R).

    DECISION: the attitude takes the Helmert's rotation only: a rotation has no scale,
    so the points of a similarity are the new pose applied to the sensor-frame points
    times (1 + s) (LAS/PLY keep the points' coordinates, E57 the scaled scan-frame
    ones; ``sensors.io.cloudmap._map_e57``), as ``HelmertResult.apply_trajectory``
    treats attitudes."""
    r_h = np.asarray(res.rotation_matrix, dtype=np.float64)
    rot_h = Rotation.from_matrix(r_h.T if inverse else r_h)
    move = res.apply_inverse if inverse else res.apply

    def pose(position: Any, quaternion_xyzw: Any
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        rot = rot_h * Rotation.from_quat(quaternion_xyzw)
        return move(np.asarray(position, dtype=np.float64)), rot.as_quat()
    return pose


def transform_file(cloud: PathLike, helmert: PathLike, output: PathLike, *,
                   inverse: bool = False, crs: str | None = None) -> TransformResult:
    """Apply the Helmert transform of an ``adjust --json`` file (or its inverse) to a
    cloud, chunk by chunk, keeping every other field (``tunnelsim transform``).

    A LAS/LAZ or binary PLY cloud has its points moved; an E57 station its pose (a
    scale goes into its scan-frame points). The station pose a tunnelsim file records
    (LAS/LAZ VLR, PLY comment, E57 pose) is transformed too.

    Parameters
    ----------
    cloud : path-like
        Input cloud (.las, .laz, .ply, .e57).
    helmert : path-like
        The JSON ``adjust_files(json_path=...)`` (``tunnelsim adjust --json``) wrote.
    output : path-like
        Output cloud, of the input's kind; written atomically.
    inverse : bool
        Apply the inverse transform (target system back to the source system).
    crs : str, optional
        The output's CRS (EPSG:n, WKT or PROJJSON; needs pyproj); default: the target
        CRS the JSON records (the source CRS with ``inverse``), else none.

    Returns
    -------
    TransformResult

    Raises
    ------
    HelmertError
        A missing or malformed Helmert JSON.
    sensors.io.crs.CRSError
        ``crs`` against the CRS the JSON records, or a cloud stating another CRS than
        the transform's input system.
    sensors.io.errors.PointFileError
        A cloud that cannot be read or written.

    Warns
    -----
    UserWarning
        When the input states a CRS that no longer holds and none replaces it.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from survey.adjust.helmert import from_parameters
    >>> from sensors.io.cloudmap import write_points_las
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> src = np.array([[0.0, 0, 0], [50, 0, 0], [0, 60, 0], [40, 40, 8]])
    >>> h = from_parameters([100.0, 200.0, 5.0], [0.0, 0.0, 0.0], 0.0)
    >>> ids = ["A", "B", "C", "D"]
    >>> _ = ControlPoints(ids, src).write(d / "a.csv")
    >>> _ = ControlPoints(ids, h.apply(src)).write(d / "b.csv")
    >>> _ = adjust_files(d / "a.csv", d / "b.csv", json_path=d / "h.json")
    >>> _ = write_points_las(d / "c.las", src)
    >>> transform_file(d / "c.las", d / "h.json", d / "c2.las").points
    4
    """
    res, d = _read_helmert(helmert)
    out_crs = _transform_crs(cloud, output, d, helmert, inverse, crs)
    move = res.apply_inverse if inverse else res.apply
    n = map_cloud(cloud, output, lambda xyz, t: move(xyz), crs=out_crs,
                  pose=_pose_mover(res, inverse))
    return TransformResult(Path(output), int(n), bool(inverse), out_crs,
                           None if out_crs is None else _label(out_crs))


# ------------------------------------------------------------------- correct
def correct_file(trajectory: PathLike, cloud: PathLike, control: PathLike,
                 observed: PathLike, output: PathLike, *, model: str = "piecewise",
                 columns: str | None = None, json_path: PathLike | None = None,
                 project: str | None = None, instrument: str | None = None
                 ) -> CorrectResult:
    """Correct a drifting MLS run (trajectory and cloud with GPS time) with control
    points (``tunnelsim correct``).

    Writes the corrected cloud ``output``, the corrected trajectory
    ``<output>_trajectory.txt``, a report ``<output>_report.md`` (and .html) with the
    plot ``<output>_correction.png``, and, when asked, the key figures as JSON. The
    corrected cloud states the control points' CRS (where they state one).

    Parameters
    ----------
    trajectory : path-like
        The MLS trajectory (TUM or CSV, ``sensors.Trajectory.read``).
    cloud : path-like
        The MLS cloud with GPS time per point (.las/.laz/.ply).
    control : path-like
        Control points in world coordinates (id, x, y, z[, sigma]).
    observed : path-like
        The same points in the MLS frame with the time each was observed
        (id, x, y, z, time).
    output : path-like
        The corrected cloud.
    model : {"piecewise", "global"}
        Piecewise rigid per control section (default) or one similarity.
    columns : str, optional
        The columns of ``control`` and ``observed``, as ``--columns`` takes them
        (``time=NAME`` for the time column).
    json_path : path-like, optional
        Also write the key figures (check-point RMS, largest correction) here.
    project, instrument : str, optional
        The user's words the report header states.

    Returns
    -------
    CorrectResult

    Raises
    ------
    ControlPointError
        An unreadable control-point file, or ``observed`` without a time column.
    DriftError
        Control points observed outside the trajectory's time span, a cloud without
        GPS time, too few control points for the model, or a ``json_path`` whose
        folder does not exist.

    Examples
    --------
    >>> res = correct_file("slam.txt", "mls.laz", "cp.csv", "cp_mls.csv",
    ...                    "corrected.laz")                     # doctest: +SKIP
    >>> f"check-point RMS {res.check_rms_m * 1000:.1f} mm"      # doctest: +SKIP
    'check-point RMS 1.9 mm'

    ``tests/survey/workflows/test_adjust_workflow.py`` builds such inputs: a straight
    run with a linear drift, corrected to the truth within a few mm.
    """
    traj = Trajectory.read(trajectory)
    world = read_control_points(control, columns=columns)
    # The corrected cloud lies in the control points' system: it states their CRS.
    world_crs = text_file_crs(control)
    seen = read_control_points(observed, columns=columns)
    if seen.time is None:
        raise ControlPointError(f"Expected a 'time' column in '{observed}' (when each "
                                "control point was observed by the MLS), got none.")
    ia, ib = match(seen, world)
    m, t, g = seen.xyz[ia], seen.time[ia], world.xyz[ib]
    if len(t) and (t.min() < traj.start_s - 1.0 or t.max() > traj.end_s + 1.0):
        from sensors.trajectory import time_base_hint

        raise DriftError(
            f"Expected the control points' times within the trajectory's "
            f"[{traj.start_s:g}, {traj.end_s:g}] s, got [{t.min():g}, {t.max():g}] s"
            f"{time_base_hint(traj.times, t)}.")
    sw = None if world.sigma is None else world.sigma[ib].mean(axis=1)
    ids = [seen.ids[i] for i in ia]
    kind: Any = model
    corr = fit_drift(m, t, g, model=kind, sigma_world_m=sw, ids=ids)
    loo = leave_one_out(m, t, g, model=kind, sigma_world_m=sw)
    out = Path(output)

    def moved(xyz: NDArray[np.float64], tt: NDArray[np.float64] | None
              ) -> NDArray[np.float64]:
        if tt is None:
            raise DriftError(f"Expected GPS time per point in '{cloud}' to correct "
                             "drift, got none.")
        return corr.apply(xyz, tt)

    n = map_cloud(cloud, out, moved, crs=KEEP_CRS if world_crs is None else world_crs)
    fixed = corr.apply_trajectory(traj)
    traj_out = out.with_name(out.stem + "_trajectory.txt")
    fixed.write(traj_out)
    report = out.with_name(out.stem + "_report.md")
    plot = out.with_name(out.stem + "_correction.png")
    head = report_header(
        [("trajectory", trajectory, ""), ("cloud", cloud, ""),
         ("control points (world)", control, _read_as(world)),
         ("control points (MLS frame, timed)", observed, _read_as(seen))],
        crs=None if world_crs is None else _label(world_crs),
        project=project, instrument=instrument, settings=[("model", model)])
    write_report(report, drift_report(corr, loo, traj=traj, header=head, plot_path=plot))
    rms = float(np.sqrt(np.mean(np.sum(loo ** 2, axis=1))))
    check_max = float(np.max(np.linalg.norm(loo, axis=1)))
    shift = float(np.max(np.linalg.norm(fixed.positions - traj.positions, axis=1)))
    if json_path is not None:
        _json_out(json_path, {"model": model, "control_points": len(ids),
                              "points": int(n), "check_rms_m": rms,
                              "check_max_m": check_max, "correction_max_m": shift},
                  DriftError)
    return CorrectResult(corr, np.asarray(loo, dtype=np.float64), model, int(n), len(ids),
                         rms, check_max, shift, out, traj_out, report, plot,
                         None if json_path is None else Path(json_path))
