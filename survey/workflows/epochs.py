"""``tunnelsim m3c2`` and ``tunnelsim convergence`` as library calls: the comparison of
two epochs, with the files the commands write.

``m3c2_to_file`` runs M3C2 (``survey.analysis.m3c2``; tile by tile with
``survey.cluster.m3c2_tiles``) and writes the core points with the M3C2 fields and the
report beside them; ``convergence_files`` measures chords between control points and
the radial change per section (``survey.analysis.convergence``) and writes the report.
The commands parse their options, call one of these, and print from the result.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from raytrace.fileio import write_json
from survey.errors import CompareError
from survey.workflows.files import opened_executor, output_folder, write_text_file

__all__ = ["ConvergenceResult", "M3C2FileResult", "convergence_files", "m3c2_to_file"]

PathLike = str | os.PathLike[str]
ProgressFn = Callable[[int, int], None]
#: Points of an epoch sampled to find the chainages it covers (``convergence_files``
#: with ``every_m``).
COVER_SAMPLE = 200_000
#: The file suffixes M3C2 writes its core points as.
LAS_SUFFIXES = (".las", ".laz")


@dataclass(frozen=True)
class M3C2FileResult:
    """What ``m3c2_to_file`` wrote and computed.

    Attributes
    ----------
    output : Path
        The core points with the M3C2 fields (LAS/LAZ), as given.
    orientation : str
        The normals' orientation as the report states it ("z", "axis" or "X,Y,Z").
    summary : dict
        What the .json beside ``output`` holds (``survey.report.epochs.m3c2_summary``):
        core_points, with_distance, significant, significant_share, median_m, mean_m,
        p05_m, p95_m, median_lod_m, parameters, epoch1, epoch2, orientation.
    epoch_points : (int, int) or None
        Points of epoch 1 and epoch 2 (None tile by tile: they are never all read).
    report, html, json, figure : Path
        ``STEM_report.md``, ``STEM_report.html``, ``STEM.json`` and ``STEM.png``.
    """

    output: Path
    orientation: str
    summary: dict[str, Any]
    epoch_points: tuple[int, int] | None
    report: Path
    html: Path
    json: Path
    figure: Path

    @property
    def files(self) -> tuple[Path, ...]:
        """Every file written."""
        return (self.output, self.json, self.figure, self.report, self.html)


@dataclass(frozen=True)
class ConvergenceResult:
    """What ``convergence_files`` wrote and computed.

    Attributes
    ----------
    output_dir : Path
        The output folder, as given.
    chords : survey.analysis.convergence.Chords or None
        Chords between the control points of both epochs.
    changes : tuple of survey.analysis.convergence.RadialChange
        Radial change per section (with two epoch clouds).
    summary : dict
        What convergence.json holds.
    markdown : str
        convergence.md (with its header block).
    files : tuple of Path
        Every file written, in the order the command lists them.
    """

    output_dir: Path
    chords: Any
    changes: tuple[Any, ...]
    summary: dict[str, Any]
    markdown: str
    files: tuple[Path, ...]


# ---------------------------------------------------------------------------- shared
def _check_crs(paths: Sequence[PathLike], allow_mismatch: bool) -> str | None:
    """Refuse (unless ``allow_mismatch``) inputs stating different CRSs; returns the
    first stated CRS text (the outputs state it)."""
    from sensors.io.cloudread import cloud_crs_text
    from sensors.io.crs import CRSError, crs_mismatch, mismatch_message

    stated = [(str(p), cloud_crs_text(p)) for p in paths]
    if not allow_mismatch:
        pair_ = crs_mismatch(stated)
        if pair_ is not None:
            raise CRSError(mismatch_message(*pair_, what="epochs",
                                            hint="reproject one epoch into the other's "
                                                 "CRS first, or pass --allow-crs-mismatch "
                                                 "if a label is wrong"))
    return next((c for _, c in stated if c is not None), None)


def _tunnel(path: PathLike) -> tuple[Any, Any]:
    """(Alignment, profile centre (2,)) of a tunnel JSON, a LandXML alignment or a
    station CSV (``load_tunnel``); without a profile the alignment is the axis, centre
    (0, 0)."""
    from survey.world.alignment_io import load_tunnel

    t = load_tunnel(Path(path), option="--tunnel")
    return t.alignment, t.centre


def _epoch_points(path: PathLike) -> np.ndarray:
    """Points of an epoch: a cloud, or a mesh's vertices."""
    from sensors.io.cloudread import read_reference

    return read_reference(path)[0]


def _numbers_text(text: str, what: str, n: int) -> list[float]:
    """'A,B,...' (commas or colons) -> ``n`` floats, or ``CompareError`` naming the
    option and its form (``what``), as the command line parses them."""
    try:
        vals = [float(v) for v in re.split(r"[,:]", text)]
    except ValueError:
        vals = []
    if len(vals) != n:
        raise CompareError(f"Expected {what}, got {text!r}.")
    return vals


def _floats_text(text: str, what: str) -> list[float]:
    """'A,B,...' -> one or more floats, or ``CompareError`` naming the option."""
    try:
        vals = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        vals = []
    if not vals:
        raise CompareError(f"Expected {what} as comma-separated numbers, got {text!r}.")
    return vals


# ---------------------------------------------------------------------------- m3c2
def _orientation(orientation: str | Sequence[float], tunnel: PathLike | None
                 ) -> tuple[str, tuple[float, ...], Any]:
    """(label, vector, (alignment, centre) or None) of ``orientation``: "z", "axis"
    (needs ``tunnel``) or a vector (3,) (as "X,Y,Z" text or numbers)."""
    if isinstance(orientation, str):
        label = orientation.strip().lower()
    else:
        label = ",".join(f"{float(v):g}" for v in orientation)
    if label == "axis":
        if not tunnel:
            raise CompareError("Expected --tunnel T.json with --orient axis (the "
                               "alignment gives the axis), got none.")
        return label, (0.0, 0.0, 1.0), _tunnel(tunnel)
    if label == "z":
        return label, (0.0, 0.0, 1.0), None
    if isinstance(orientation, str):
        return label, tuple(_numbers_text(orientation, "--orient as z, axis or X,Y,Z",
                                          3)), None
    vec = tuple(float(v) for v in orientation)
    if len(vec) != 3:
        raise CompareError(f"Expected --orient as z, axis or X,Y,Z, got {label!r}.")
    return label, vec, None


def m3c2_to_file(epoch1: PathLike, epoch2: PathLike, output: PathLike, *,
                 cyl_radius_m: float, max_depth_m: float,
                 normal_radii_m: Sequence[float] | None = None,
                 reg_error_m: float = 0.0, robust: bool = False,
                 core: PathLike | None = None, core_spacing_m: float | None = None,
                 orientation: str | Sequence[float] = "z",
                 tunnel: PathLike | None = None, allow_crs_mismatch: bool = False,
                 tile_m: float | None = None, executor: Any = None,
                 project: str | None = None, instrument: str | None = None,
                 progress: ProgressFn | None = None,
                 on_read: Callable[[int, int], None] | None = None) -> M3C2FileResult:
    """M3C2 distances between two epochs with LoD95 and significance (Lague et al.
    2013, py4dgeo's parameters), written as ``tunnelsim m3c2`` writes them.

    Writes ``output`` (the core points with the fields distance, lod, significant,
    spread1/2, n1/2, nx/ny/nz; a LAS/LAZ ``core`` keeps its fields) and beside it
    ``STEM.json`` (the summary), ``STEM.png`` (histogram) and ``STEM_report.md`` /
    ``.html``.

    Parameters
    ----------
    epoch1, epoch2 : path-like
        The earlier and the later epoch (clouds, or meshes' vertices).
    output : path-like
        The core points' file, .las or .laz, in an existing folder.
    cyl_radius_m : float
        Projection cylinder radius, m (py4dgeo ``cyl_radius``).
    max_depth_m : float
        Cylinder half-length along the normal, m (py4dgeo ``max_distance``).
    normal_radii_m : sequence of float, optional
        Normal radii, m (default: twice the cylinder radius).
    reg_error_m : float
        Registration error added to the LoD95, m.
    robust : bool
        Median and IQR instead of mean and standard deviation.
    core : path-like, optional
        Core points (a cloud; LAS/LAZ fields are kept); default: epoch 1.
    core_spacing_m : float, optional
        Core points: epoch 1 subsampled to one point per cell of this many metres
        (not with ``core``).
    orientation : {"z", "axis"} or (3,) sequence or "X,Y,Z"
        Normal orientation: +Z, towards the tunnel axis of ``tunnel`` (positive
        distance = convergence), or a vector.
    tunnel : path-like, optional
        Alignment for ``orientation="axis"``: tunnel JSON, LandXML or station CSV.
    allow_crs_mismatch : bool
        Compare epochs that state different CRSs.
    tile_m : float > 0, optional
        Run in square tiles of this many metres (spilled beside ``output``), each a
        task on ``executor``; the same results.
    executor : survey.cluster.Executor or callable () -> Executor, optional
        Where the tiles run (default: this process); a callable is called when the
        tiles start, what it returns closed after them.
    project, instrument : str, optional
        The user's words the report header states.
    progress : callable(done, total), optional
        Tiles done (tile by tile).
    on_read : callable(n1, n2), optional
        Called with both epochs' point counts once they are read (in one piece).

    Returns
    -------
    M3C2FileResult

    Raises
    ------
    CompareError
        Bad parameters, an output that is not .las/.laz or whose folder is missing,
        epochs lying apart.
    sensors.io.crs.CRSError
        Epochs stating different CRSs.

    Examples
    --------
    >>> r = m3c2_to_file("e1.laz", "e2.laz", "m3c2.laz", cyl_radius_m=0.1,
    ...                  max_depth_m=0.2, core_spacing_m=0.5)          # doctest: +SKIP
    >>> r.summary["median_m"]                                          # doctest: +SKIP
    0.0021
    """
    from survey.analysis.m3c2 import M3C2Params

    out = Path(output)
    if out.suffix.lower() not in LAS_SUFFIXES:
        raise CompareError(f"Expected -o as .las/.laz, got '{out}'.")
    if not out.parent.exists():
        raise CompareError(f"Expected an existing folder for '{out}', got none; create "
                           "it first.")
    if core is not None and core_spacing_m is not None:
        raise CompareError("Expected --core or --core-spacing, got both.")
    radii = list(normal_radii_m) if normal_radii_m is not None else \
        [2.0 * cyl_radius_m] if cyl_radius_m and cyl_radius_m > 0 else []
    prm = M3C2Params(cyl_radius_m, max_depth_m, tuple(radii), reg_error_m, robust)
    label, vector, axis = _orientation(orientation, tunnel)
    if tile_m is not None and not tile_m > 0:
        raise CompareError(f"Expected a positive --tile-m, got {tile_m:g}.")
    crs = _check_crs([epoch1, epoch2] + ([core] if core else []), allow_crs_mismatch)
    if tile_m is not None:
        dist, lod, sig, store = _m3c2_tiled(epoch1, epoch2, out, prm, vector, axis, crs,
                                            core=core, core_spacing_m=core_spacing_m,
                                            tile_m=tile_m, executor=executor,
                                            progress=progress)
        with store:
            res = _m3c2_reports(epoch1, epoch2, out, prm, label, dist, lod, sig, core,
                                None, project=project, instrument=instrument)
        return res
    e1, e2 = _epoch_points(epoch1), _epoch_points(epoch2)
    if on_read is not None:
        on_read(len(e1), len(e2))
    r = _m3c2_whole(e1, e2, out, prm, vector, axis, crs, core=core,
                    core_spacing_m=core_spacing_m)
    return _m3c2_reports(epoch1, epoch2, out, prm, label, r.distance, r.lod,
                         r.significant, core, (len(e1), len(e2)), project=project,
                         instrument=instrument)


def _m3c2_whole(e1: np.ndarray, e2: np.ndarray, out: Path, prm: Any,
                vector: tuple[float, ...], axis: Any, crs: str | None, *,
                core: PathLike | None, core_spacing_m: float | None) -> Any:
    """M3C2 on the whole epochs, core points chunk by chunk; the core points written
    to ``out`` (a LAS/LAZ core streamed with its fields). Returns the M3C2Result."""
    from sensors.io.cloudmap import annotate_las, write_points_las
    from sensors.io.cloudread import iter_points
    from survey.analysis.m3c2 import CHUNK, M3C2, M3C2Result, subsample, towards_axis

    job = M3C2(e1, e2, prm)

    def run(xyz: np.ndarray) -> Any:
        tw = None if axis is None else towards_axis(axis[0], xyz, axis[1])
        return job.compute(xyz, orientation=vector, towards=tw)

    parts: list[Any] = []
    if core and Path(core).suffix.lower() in LAS_SUFFIXES:
        def annotate(xyz: np.ndarray) -> dict[str, np.ndarray]:
            r = run(xyz)
            parts.append(r)
            return r.fields()
        annotate_las(Path(core), out, annotate, chunk=CHUNK)
    else:
        pts = np.concatenate(list(iter_points(core))) if core else \
            subsample(e1, core_spacing_m) if core_spacing_m else e1
        parts = [run(pts[a:a + CHUNK]) for a in range(0, len(pts), CHUNK)]
        res = M3C2Result.concatenate(parts)
        write_points_las(out, pts, res.fields(), crs=crs)
    return M3C2Result.concatenate(parts)


def _m3c2_tiled(epoch1: PathLike, epoch2: PathLike, out: Path, prm: Any,
                vector: tuple[float, ...], axis: Any, crs: str | None, *,
                core: PathLike | None, core_spacing_m: float | None, tile_m: float,
                executor: Any, progress: ProgressFn | None) -> tuple[Any, ...]:
    """M3C2 tile by tile (``survey.cluster.m3c2_tiles.m3c2_files``) on the executor;
    the core points written to ``out``. Returns (distance, lod, significant, store):
    columns of the store on disk, which the caller closes."""
    from functools import partial

    from sensors.io.cloudmap import annotate_las, write_points_las
    from survey.analysis.m3c2 import CHUNK, towards_axis
    from survey.cluster.m3c2_tiles import m3c2_files

    las_core = bool(core) and Path(str(core)).suffix.lower() in LAS_SUFFIXES
    with opened_executor(executor) as ex:
        # DECISION: the spill goes beside the output: a folder every worker sees (as
        # the scenes of 'scan --workers' do), on the disk that takes the output anyway.
        store = m3c2_files(epoch1, epoch2, core if core else core_spacing_m, prm,
                           tile_m=tile_m, orientation=vector,
                           towards=None if axis is None else
                           partial(towards_axis, axis[0], centre=axis[1]),
                           executor=ex, spill_dir=out.parent, progress=progress)
    try:
        if las_core:
            done = [0]

            def annotate(xyz: np.ndarray) -> dict[str, np.ndarray]:
                a = done[0]
                done[0] += len(xyz)
                if not np.array_equal(store.xyz(a, done[0]), xyz):
                    raise CompareError(f"Expected '{core}' to read the same points "
                                       "twice, got others; was it changed?")
                return store.result(a, done[0]).fields()
            annotate_las(Path(str(core)), out, annotate, chunk=CHUNK)
        else:
            write_points_las(out, store.column("xyz"), store.las_fields(), crs=crs)
    except BaseException:
        store.close()
        raise
    return (store.column("distance"), store.column("lod"), store.column("significant"),
            store)


def _m3c2_reports(epoch1: PathLike, epoch2: PathLike, out: Path, prm: Any, label: str,
                  distance: Any, lod: Any, significant: Any, core: PathLike | None,
                  epoch_points: tuple[int, int] | None, *, project: str | None,
                  instrument: str | None) -> M3C2FileResult:
    """The summary (.json, _report.md/.html) and the histogram (.png)."""
    from survey.report.epochs import m3c2_markdown, m3c2_summary, plot_m3c2_histogram
    from survey.report.header import report_header
    from survey.report.html import write_report

    summ = m3c2_summary(distance, lod, significant, prm, epoch1=str(epoch1),
                        epoch2=str(epoch2), orientation=label)
    js = out.with_name(out.stem + ".json")
    write_json(js, summ)
    png = out.with_name(out.stem + ".png")
    plot_m3c2_histogram(distance, significant, png)
    inputs = [("epoch 1 (earlier)", epoch1, ""), ("epoch 2 (later)", epoch2, "")]
    if core:
        inputs.append(("core points", core, ""))
    head = report_header(inputs, crs_from=[epoch1, epoch2],
                         settings=[("normal orientation", label)], project=project,
                         instrument=instrument)
    md, html = write_report(out.with_name(out.stem + "_report.md"),
                            m3c2_markdown(summ, title=f"M3C2 {Path(epoch1).name} -> "
                                                      f"{Path(epoch2).name}", header=head,
                                          figure=png.name))
    return M3C2FileResult(output=out, orientation=label, summary=summ,
                          epoch_points=epoch_points, report=md, html=html, json=js,
                          figure=png)


# ---------------------------------------------------------------------------- convergence
def _named_points(path: PathLike) -> dict[str, np.ndarray]:
    """{id: xyz} of a tunnel JSON's control points or a control-point CSV."""
    from survey.analysis.convergence import control_points

    if Path(path).suffix.lower() == ".json":
        from sensors.io.tunnel_json import read_meta

        return control_points(read_meta(Path(path)))
    from survey.adjust.controlpoints import read_control_points

    cp = read_control_points(Path(path))
    return {k: np.asarray(v, dtype=np.float64) for k, v in zip(cp.ids, cp.xyz)}


def _covered(points: np.ndarray, alignment: Any) -> tuple[float, float]:
    """Chainage range (m) of points (n, 3) along the alignment (a seeded sample of
    ``COVER_SAMPLE`` of them: 0.1 and 99.9 % of the chainages)."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) > COVER_SAMPLE:
        p = p[np.random.default_rng(0).choice(len(p), COVER_SAMPLE, replace=False)]
    s = alignment.to_local(p)[0]
    return float(np.percentile(s, 0.1)), float(np.percentile(s, 99.9))


def _sections(at_m: Any, every_m: float | None, al: Any, e1: np.ndarray, e2: np.ndarray,
              band_m: float) -> tuple[np.ndarray, str]:
    """(section chainages, the header's words for them) of ``at_m`` (numbers, or the
    text "S[,S...]") or every ``every_m`` metres where both epochs have points."""
    from survey.analysis.convergence import sections_every

    if at_m is not None:
        if isinstance(at_m, str):
            vals = _floats_text(at_m, "--at")
            return np.asarray(vals, dtype=np.float64), f"at {at_m} m"
        at = np.atleast_1d(np.asarray(at_m, dtype=np.float64))
        return at, "at " + ",".join(f"{v:g}" for v in at) + " m"
    assert every_m is not None
    # DECISION: every N m of the alignment where both epochs have points (a station
    # covers tens of metres of a long tunnel).
    at = sections_every(al, every_m)
    lo, hi = _covered(e1, al)
    lo2, hi2 = _covered(e2, al)
    lo, hi = max(lo, lo2) + band_m, min(hi, hi2) - band_m
    at = at[(at >= lo) & (at <= hi)]
    if not len(at):
        raise CompareError(f"Expected both epochs to cover a section every {every_m:g} m, "
                           f"got them overlapping over chainages {lo:.1f} to {hi:.1f} m "
                           "only; use --at or a smaller --every.")
    return at, f"every {every_m:g} m"


def convergence_files(output_dir: PathLike, tunnel: PathLike, *,
                      epochs: Sequence[PathLike] = (), control1: PathLike | None = None,
                      control2: PathLike | None = None, sigma_m: float | None = None,
                      at_m: Sequence[float] | str | None = None,
                      every_m: float | None = None, band_m: float = 0.25,
                      angle_step_deg: float = 5.0, allow_crs_mismatch: bool = False,
                      force: bool = False, project: str | None = None,
                      instrument: str | None = None) -> ConvergenceResult:
    """Convergence between two epochs, written as ``tunnelsim convergence`` writes it:
    chord lengths between named points of each epoch and, with two clouds, the radial
    change by angle about the section centre. Positive = convergence.

    Writes convergence.md, convergence.html and convergence.json, with control points
    chords.csv, with epochs radial.csv and radial.png, into ``output_dir``.

    Parameters
    ----------
    output_dir : path-like
        Output folder: created; an existing non-empty one only with ``force``.
    tunnel : path-like
        The alignment and the profile's centre: tunnel JSON, LandXML or a
        chainage,E,N,H CSV (no profile: the alignment is the centre).
    epochs : sequence of two path-likes, or empty
        The earlier and the later cloud, for the radial change.
    control1, control2 : path-like, optional
        Points of epoch 1 and 2 (tunnel JSONs with control points, or control-point
        CSVs), both or neither.
    sigma_m : float, optional
        Point precision per coordinate, m: chords get LoD95 = 3.92 sigma.
    at_m : sequence of float or "S[,S...]" text, optional
        Section chainages, m (the report states text as given).
    every_m : float, optional
        A section every this many metres where both epochs have points.
    band_m : float
        Half-width of a section along the axis, m.
    angle_step_deg : float
        Angular bin, degrees (as the command's --angle-step).
    allow_crs_mismatch : bool
        Compare epochs that state different CRSs.
    force : bool
        Write into a non-empty ``output_dir``.
    project, instrument : str, optional
        The user's words the report header states.

    Returns
    -------
    ConvergenceResult

    Raises
    ------
    CompareError
        Nothing to compare, one control file without the other, epochs without
        sections, sections outside the epochs, a non-empty ``output_dir``.
    sensors.io.crs.CRSError
        Epochs stating different CRSs.

    Examples
    --------
    >>> r = convergence_files("conv", "t.json", control1="t.json",
    ...                       control2="t2.json")                      # doctest: +SKIP
    >>> r.summary["chords"][0]["change_m"]                            # doctest: +SKIP
    -0.004
    """
    from survey.analysis.convergence import chords, radial_change

    epochs = list(epochs)
    if len(epochs) not in (0, 2):
        raise CompareError(f"Expected two epochs (earlier, later) or none, got "
                           f"{len(epochs)}.")
    if bool(control1) != bool(control2):
        raise CompareError("Expected --control1 and --control2 together, got one.")
    if not epochs and not control1:
        raise CompareError("Expected two epochs or --control1/--control2, got neither: "
                           "nothing to compare.")
    if epochs and at_m is None and every_m is None:
        raise CompareError("Expected --at S[,S...] or --every M with epochs, got "
                           "neither.")
    if at_m is not None and every_m is not None:
        raise CompareError("Expected --at or --every, got both.")
    al, centre = _tunnel(tunnel)
    ch = None
    if control1 and control2:
        ch = chords(_named_points(control1), _named_points(control2), alignment=al,
                    sigma_m=sigma_m)
    changes: list[Any] = []
    where = "none (chords only)"
    if epochs:
        _check_crs(epochs, allow_crs_mismatch)
        e1, e2 = _epoch_points(epochs[0]), _epoch_points(epochs[1])
        at, where = _sections(at_m, every_m, al, e1, e2, band_m)
        changes = radial_change(e1, e2, al, at, centre=centre, band_m=band_m,
                                angle_step_rad=np.deg2rad(angle_step_deg))
    out = output_folder(output_dir, force=force)
    return _convergence_outputs(out, Path(output_dir), tunnel, epochs, control1, control2,
                                ch, changes, where, sigma_m=sigma_m, band_m=band_m,
                                angle_step_deg=angle_step_deg, project=project,
                                instrument=instrument)


def _convergence_outputs(out: Path, given: Path, tunnel: PathLike, epochs: list[Any],
                         control1: Any, control2: Any, ch: Any, changes: list[Any],
                         where: str, *, sigma_m: float | None, band_m: float,
                         angle_step_deg: float, project: str | None,
                         instrument: str | None) -> ConvergenceResult:
    """chords.csv, radial.csv, radial.png, convergence.md/.html and .json."""
    from survey.analysis.convergence import summarise
    from survey.report.epochs import (
        chords_csv,
        convergence_markdown,
        plot_radial,
        radial_csv,
    )
    from survey.report.header import report_header
    from survey.report.html import write_report

    files = [out / "convergence.md", out / "convergence.html", out / "convergence.json"]
    summary: dict[str, Any] = {"chords": [] if ch is None else ch.rows(), "sections": []}
    if ch is not None:
        files.append(write_text_file(out / "chords.csv", chords_csv(ch)))
    if changes:
        summary["sections"] = summarise(changes)
        files.append(write_text_file(out / "radial.csv", radial_csv(changes)))
        plot_radial(changes, out / "radial.png")
        files.append(out / "radial.png")
    inputs = [(f"epoch {k + 1} ({'earlier' if k == 0 else 'later'})", p, "")
              for k, p in enumerate(epochs)]
    inputs += [(f"points of epoch {k}", p, "") for k, p in
               ((1, control1), (2, control2)) if p]
    inputs.append(("tunnel (alignment, profile)", tunnel, ""))
    settings = [("sections", where)]
    if epochs:
        settings += [("band (half-width along the axis)", f"{band_m:g} m"),
                     ("angle step", f"{angle_step_deg:g}°")]
    if sigma_m is not None:
        # As the command states --sigma-mm.
        settings.append(("point precision (per coordinate)", f"{sigma_m * 1000.0:g} mm"))
    head = report_header(inputs, settings=settings, crs_from=[*epochs, control1, control2],
                         project=project, instrument=instrument)
    names = ([Path(p).name for p in epochs] if epochs else
             [Path(control1).name, Path(control2).name])
    md = convergence_markdown(ch, changes, header=head, epochs=names,
                              band_m=band_m if changes else None,
                              angle_step_deg=angle_step_deg if changes else None,
                              figure="radial.png" if changes else None)
    write_report(out / "convergence.md", md)
    summary.update({"epochs": [str(p) for p in epochs],
                    "control": [str(p) for p in (control1, control2) if p],
                    "band_m": band_m, "angle_step_deg": angle_step_deg,
                    "inputs": [{"role": i.role, "path": i.path, "sha256": i.sha256}
                               for i in head.inputs]})
    write_json(out / "convergence.json", summary)
    return ConvergenceResult(output_dir=given, chords=ch, changes=tuple(changes),
                             summary=summary, markdown=md, files=tuple(files))
