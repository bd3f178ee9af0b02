"""Monitoring workflows (issue 17): ``sections_files`` (cross-sections against the
design: over-/underbreak, areas, volumes; ``tunnelsim sections``) and ``rings_files``
(best-fit circle and ellipse per section; ``tunnelsim rings``).

Both cut a cloud (streamed chunk by chunk) or a mesh at chainages of an alignment (a
tunnel JSON, LandXML or station CSV, or one fitted to the input), write their tables,
JSON, Markdown/HTML report and figures into an output folder, and return a frozen
result with the paths and the numbers the commands print. Errors keep the commands'
messages (they name the options, e.g. ``--every``): a Python caller reads the keyword
of the same name (``every_m``).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from survey.errors import CompareError
from survey.workflows.files import output_folder, write_text_file

__all__ = ["DESIGN_ORDERS", "RingsResult", "SectionsResult", "rings_files",
           "section_alignment", "sections_files"]

PathLike = str | os.PathLike[str]

#: Vertex orders of a design profile file (``design_order``).
DESIGN_ORDERS = ("file", "angle")


@dataclass(frozen=True)
class SectionsResult:
    """What ``sections_files`` wrote and measured.

    Attributes
    ----------
    output : Path, the output folder
    files : tuple of Path, the files written into it (tables, JSON, report .md and
        .html, PNGs)
    report : survey.analysis.overbreak.SectionReport, the comparison (every section's
        deviations, areas, classes, and the volumes between them)
    design_name : str, the design profile's name
    sections : int, number of sections
    overbreak_m3, underbreak_m3 : float, volumes between the first and last section
        (m3)
    largest_overbreak_m : float, the largest deviation outside the design (m)
    largest_overbreak_chainage_m : float, where it is (chainage, m)
    """

    output: Path
    files: tuple[Path, ...]
    report: Any
    design_name: str
    sections: int
    overbreak_m3: float
    underbreak_m3: float
    largest_overbreak_m: float
    largest_overbreak_chainage_m: float


@dataclass(frozen=True)
class RingsResult:
    """What ``rings_files`` wrote and fitted.

    Attributes
    ----------
    output : Path, the output folder
    files : tuple of Path, the files written into it (rings.csv, .md, .html, .json,
        .png)
    rings : tuple of survey.analysis.rings.RingFit, the fits by chainage
    floor_heights_m : tuple of float or None, each section's floor height in the
        section frame (m; ``min_height_m`` given)
    min_diameter_m, max_diameter_m : float, the smallest minor and largest major axis
        of the ellipses (m)
    max_ovality : float, the largest ovality (a fraction)
    poor_fits : int, rings that fit a circle or an ellipse no better than
        ``survey.analysis.rings.FIT_RMS_WARN_M`` rms (a warning says so)
    """

    output: Path
    files: tuple[Path, ...]
    rings: tuple[Any, ...]
    floor_heights_m: tuple[float, ...] | None
    min_diameter_m: float
    max_diameter_m: float
    max_ovality: float
    poor_fits: int = 0

    @property
    def floor_median_m(self) -> float | None:
        """The median floor height (m) in the section frame, or None."""
        return None if self.floor_heights_m is None else \
            float(np.median(self.floor_heights_m))


# ---------------------------------------------------------------------------- shared
@contextlib.contextmanager
def _output_folder(path: PathLike, force: bool) -> Iterator[Path]:
    """The output folder (``output_folder``) for the block; removed again when the block
    fails and the folder was made here (the files of a folder that existed are
    replaced one by one, atomically, so a failure leaves them whole)."""
    made = not Path(path).exists()
    out = output_folder(path, force=force, error=CompareError)
    try:
        yield out
    except BaseException:
        if made:
            shutil.rmtree(out, ignore_errors=True)
        raise


def _check_input(path: PathLike) -> None:
    if not Path(path).is_file():
        raise CompareError(f"Expected an input cloud or mesh, got '{path}' which does "
                           "not exist.")


def section_alignment(input: PathLike, *, tunnel_json: PathLike | None = None,
                      fit_axis: bool = False, start_xy: tuple[float, float] | None = None,
                      chainage_at_m: float | None = None, reverse: bool = False,
                      seed: int = 0) -> tuple[Any, Any]:
    """The alignment sections and rings cut along, and its profile.

    From ``tunnel_json`` (a tunnel JSON, LandXML or chainage,E,N,H CSV; default: the
    .json beside a tunnel .ply ``input``), or fitted to ``input`` (``fit_axis``: a
    seeded subset, chainage from ``start_xy``/``chainage_at_m``/``reverse``;
    ``survey.workflows.axis.fitted_axis``).

    Parameters
    ----------
    input : path-like
        The cloud or mesh to be cut.
    tunnel_json : path-like, optional
    fit_axis : bool
    start_xy, chainage_at_m, reverse
        The chainage datum of a fitted axis (only with ``fit_axis``).
    seed : int
        Seed of the subset a fitted axis is fitted to.

    Returns
    -------
    alignment : survey.world.Alignment
    profile : survey.world.profiles.Profile or None
        The tunnel JSON's profile; None for a LandXML/CSV alignment or a fitted axis.

    Raises
    ------
    survey.errors.CompareError
        For both or neither of ``tunnel_json`` and ``fit_axis``, or a datum without
        ``fit_axis``.
    sensors.io.errors.TunnelFileError
        When the alignment file cannot be read.

    Examples
    --------
    >>> al, prof = section_alignment("scan.laz", tunnel_json="bfo.json")  # doctest: +SKIP
    """
    from survey.world.alignment_io import load_tunnel
    from sensors.io.tunnel_json import sidecar

    js = tunnel_json
    if js is None and not fit_axis and Path(input).suffix.lower() == ".ply" \
            and sidecar(str(input)).is_file():
        js = str(sidecar(str(input)))
    if js is not None and fit_axis:
        raise CompareError("Expected --tunnel-json or --fit-axis, got both.")
    if js is None and not fit_axis:
        raise CompareError("Expected --tunnel-json T.json (the alignment) or --fit-axis, "
                           "got neither.")
    if not fit_axis and (start_xy is not None or reverse or chainage_at_m is not None):
        raise CompareError("Expected --start, --chainage-at and --reverse with "
                           "--fit-axis (the chainage of a fitted axis), got them with "
                           "--tunnel-json, whose alignment has its chainage.")
    if js is not None:
        t = load_tunnel(str(js), option="--tunnel-json")
        return t.alignment, t.profile
    from survey.workflows.axis import fitted_axis

    al, _, _ = fitted_axis(input, seed=seed, start_xy=start_xy,
                           chainage_at_m=chainage_at_m, reverse=reverse)
    return al, None


def _chainages(al: Any, every_m: float | None, at_m: Sequence[float] | None,
               width_m: float) -> Any:
    from survey.analysis.sections import section_chainages

    if (every_m is None) == (at_m is None):
        raise CompareError("Expected --every M or --at C[,C...] (section chainages), "
                           f"got {'both' if every_m is not None else 'neither'}.")
    return section_chainages(al, every_m=every_m, at=None if at_m is None else list(at_m),
                             half_width_m=width_m)


def _cuts(input: PathLike, al: Any, chainages: Any, width_m: float, max_points: int,
          seed: int, classes: Sequence[float] | None) -> list[Any]:
    """The section cuts; ``classes``: the classification codes kept (whole, 0-255)."""
    from sensors.io.errors import PointFileError
    from survey.analysis.developed import is_mesh_file
    from survey.analysis.sections import cut_file

    if width_m is None or not width_m >= 0:
        raise CompareError(f"Expected --width >= 0 m, got {width_m}.")
    codes = None
    if classes is not None:
        vals = list(classes)
        text = ",".join(f"{v:g}" for v in vals)
        if not vals or any(v != int(v) or not 0 <= v <= 255 for v in vals):
            raise CompareError(f"Expected --classes as whole codes 0-255 (e.g. 64,2), "
                               f"got {text!r}.")
        codes = [int(v) for v in vals]
        if is_mesh_file(input):
            raise CompareError(f"Expected a classified point cloud for --classes, got "
                               f"the mesh '{input}'; leave out --classes.")
    try:
        cuts = cut_file(input, al, chainages, width_m, max_points=max_points, seed=seed,
                        classes=codes)
    except PointFileError as e:
        if codes is None or "classification" not in str(e):
            raise
        raise CompareError(f"Expected a per-point classification in '{input}' for "
                           "--classes, got none; classify it with 'tunnelsim preprocess "
                           "--segment' or leave out --classes.") from None
    if codes is not None and not any(len(c.yz) for c in cuts):
        raise CompareError(f"Expected points of classes {text} in the section bands, got "
                           "none; check --classes.")
    return cuts


def _design(design: PathLike | None, prof: Any, fitted: bool, order: str,
            shift_m: Sequence[float] | None, closed: bool | None) -> Any:
    """The design profile: the file ``design``, or the tunnel JSON's profile."""
    from survey.analysis.design import DesignProfile, read_design_profile

    if design is not None:
        if order not in DESIGN_ORDERS:
            raise CompareError(f"Expected --design-order as one of "
                               f"{', '.join(DESIGN_ORDERS)}, got {order!r}.")
        d = read_design_profile(design, closed=closed, order=order,
                                shift_m=(0.0, 0.0) if shift_m is None else shift_m)
    elif prof is not None:
        d = DesignProfile.from_profile(prof)
    else:
        raise CompareError("Expected --design FILE with --fit-axis or with an alignment "
                           "without a profile (LandXML, station CSV), got none.")
    if fitted:
        # DECISION: a fitted axis runs through the profile's mid-range centre
        # (survey.clouds.axis.estimate_axis), so the design is centred the same way.
        y0, y1, z0, z1 = d.extent()
        d = d.shifted(-0.5 * (y0 + y1), -0.5 * (z0 + z1))
    return d


# --------------------------------------------------------------------------- sections
def sections_files(input: PathLike, output: PathLike, *,
                   tunnel_json: PathLike | None = None, fit_axis: bool = False,
                   start_xy: tuple[float, float] | None = None,
                   chainage_at_m: float | None = None, reverse: bool = False,
                   every_m: float | None = None, at_m: Sequence[float] | None = None,
                   width_m: float = 0.05, max_points: int = 1_000_000,
                   classes: Sequence[float] | None = None,
                   design: PathLike | None = None, design_order: str = "file",
                   design_shift_m: Sequence[float] | None = None,
                   design_closed: bool | None = None, bin_m: float = 0.05,
                   tolerance_edges_m: Sequence[float] | None = None, plots: bool = True,
                   force: bool = False, seed: int = 0, project: str | None = None,
                   instrument: str | None = None) -> SectionsResult:
    """Cut a cloud or mesh into cross-sections, compare each with the design profile
    and write an as-built report (``tunnelsim sections``).

    Writes into ``output``: sections.csv (max/min/mean deviation, over- and underbreak
    areas, tolerance classes), volumes.csv (average end areas), contours.csv (the
    as-built line), report.json, report.md and report.html (with the header block), and
    one section_<km>+<m>.png per chainage (``plots``).

    Parameters
    ----------
    input : path-like
        Cloud (.las/.laz/.ply/.xyz/.txt/.csv/.npz/.e57) or mesh (.ply with faces,
        .obj/.stl/.off).
    output : path-like
        Output folder (created; a non-empty one only with ``force``).
    tunnel_json, fit_axis, start_xy, chainage_at_m, reverse
        The alignment (``section_alignment``).
    every_m : float, optional
        A section every this many metres of chainage (at whole multiples).
    at_m : sequence of float, optional
        Sections at these chainages (m); exactly one of ``every_m`` and ``at_m``.
    width_m : float
        Half-width of each band along the axis (m; a mesh is cut by the plane itself).
    max_points : int
        Most points kept per section (a seeded random subset beyond).
    classes : sequence of int, optional
        Keep only points of these LAS classification codes (whole, 0-255).
    design : path-like, optional
        Design profile file (y,z in the section frame); default: the tunnel JSON's.
    design_order : {"file", "angle"}
        Vertex order of ``design``: as in the file, or sorted by angle about their
        centroid.
    design_shift_m : (float, float), optional
        Move ``design`` by (dy, dz) m into the section frame.
    design_closed : bool or None
        Whether ``design`` is closed (None: decided from the file).
    bin_m : float
        Bin length along the design for the as-built line (m).
    tolerance_edges_m : sequence of float, optional
        Deviation class edges (m); default
        ``survey.analysis.overbreak.TOLERANCE_EDGES_M``.
    plots : bool
        Write the section PNGs.
    force : bool
        Write into a non-empty folder.
    seed : int
        Seed of the subsets (points per section, a fitted axis).
    project, instrument : str, optional
        The user's words the report header states.

    Returns
    -------
    SectionsResult

    Raises
    ------
    survey.errors.CompareError
        For a missing input, bad or conflicting options, or sections without points.
    survey.errors.AlignmentError
        For chainages outside the alignment.
    sensors.io.errors.FileFormatError
        When an input file cannot be read.

    Examples
    --------
    >>> r = sections_files("scan.laz", "sections", tunnel_json="bfo.json",
    ...                    every_m=5.0)  # doctest: +SKIP
    >>> r.sections, round(r.overbreak_m3, 3)  # doctest: +SKIP
    (21, 3.412)
    """
    from raytrace.fileio import json_text
    from survey.analysis.overbreak import TOLERANCE_EDGES_M, compare_sections
    from survey.report.header import write_headed_report
    from survey.report.sections import (contours_csv, plot_section, section_png_name,
                                        sections_csv, sections_markdown, volumes_csv)

    _check_input(input)
    edges = TOLERANCE_EDGES_M if tolerance_edges_m is None else \
        tuple(np.asarray(tolerance_edges_m, dtype=np.float64))
    al, prof = section_alignment(input, tunnel_json=tunnel_json, fit_axis=fit_axis,
                                 start_xy=start_xy, chainage_at_m=chainage_at_m,
                                 reverse=reverse, seed=seed)
    d = _design(design, prof, fit_axis, design_order, design_shift_m, design_closed)
    chainages = _chainages(al, every_m, at_m, width_m)
    with _output_folder(output, force) as out:
        cuts = _cuts(input, al, chainages, width_m, max_points, seed, classes)
        rep = compare_sections(cuts, d, alignment=al, bin_m=bin_m,
                               tolerance_edges_m=edges, seed=seed)
        files = [write_text_file(out / "sections.csv", sections_csv(rep)),
                 write_text_file(out / "volumes.csv", volumes_csv(rep)),
                 write_text_file(out / "contours.csv", contours_csv(rep)),
                 write_text_file(out / "report.json", json_text(rep.to_dict()))]
        if plots:
            for s in rep.sections:
                p = out / section_png_name(s.chainage_m)
                plot_section(s, rep, p)
                files.append(p)
        files += write_headed_report(
            out / "report.md", sections_markdown(rep, source=Path(input).name,
                                                 plots=plots),
            inputs=[("cloud or mesh", input, ""),
                    ("alignment", tunnel_json, "fitted axis" if fit_axis else ""),
                    *([("design", design, "")] if design else [])],
            crs_from=[input], settings=[("band (m)", f"±{width_m:g}")],
            project=project, instrument=instrument)
    worst = max(rep.sections, key=lambda s: s.max_m)
    return SectionsResult(out, tuple(files), rep, d.name, len(rep.sections),
                          rep.overbreak_m3, rep.underbreak_m3, float(worst.max_m),
                          float(worst.chainage_m))


# ------------------------------------------------------------------------------ rings
def rings_files(input: PathLike, output: PathLike, *,
                tunnel_json: PathLike | None = None, fit_axis: bool = False,
                start_xy: tuple[float, float] | None = None,
                chainage_at_m: float | None = None, reverse: bool = False,
                every_m: float | None = None, at_m: Sequence[float] | None = None,
                width_m: float = 0.05, max_points: int = 1_000_000,
                classes: Sequence[float] | None = None,
                nominal_diameter_m: float | None = None, min_height_m: float | None = None,
                rail_height_m: float | None = None, force: bool = False, seed: int = 0,
                project: str | None = None, instrument: str | None = None) -> RingsResult:
    """Cut a cloud or mesh into cross-sections as ``sections_files`` does and fit a
    circle and an ellipse to each (``tunnelsim rings``).

    Algebraic start, then orthogonal-distance Gauss-Newton/LM; outliers beyond 3
    robust sigma dropped (``survey.analysis.rings``). Writes into ``output``:
    rings.csv, rings.md and rings.html (with the header block), rings.json and
    rings.png (diameters, ovality, centre offset from the design centre along the
    chainage). A ``UserWarning`` says when rings fit a circle or an ellipse poorly
    (a horseshoe).

    Parameters
    ----------
    input, output, tunnel_json, fit_axis, start_xy, chainage_at_m, reverse
        As in ``sections_files``.
    every_m, at_m, width_m, max_points, classes, force, seed, project, instrument
        As in ``sections_files``.
    nominal_diameter_m : float, optional
        Nominal diameter for the ovality (default: the mean of the fitted axes).
    min_height_m : float, optional
        Use only points at least this high above the floor (leave out the invert).
        The floor: ``rail_height_m``, else the alignment of ``tunnel_json`` (height 0
        of its section frame), else with ``fit_axis`` each section's lowest points
        (its 1st percentile of heights).
    rail_height_m : float, optional
        Height of the rail or floor in the section frame (m) that ``min_height_m`` is
        measured from (only with ``min_height_m``).

    Returns
    -------
    RingsResult

    Raises
    ------
    survey.errors.CompareError
        For a missing input, bad or conflicting options, or sections too sparse to fit.

    Examples
    --------
    >>> r = rings_files("tbm_scan.laz", "rings", tunnel_json="tbm.json", every_m=1.5,
    ...                 width_m=0.02)  # doctest: +SKIP
    >>> round(r.max_ovality * 100, 3)  # doctest: +SKIP
    0.412
    """
    from raytrace.fileio import json_text
    from survey.analysis.design import DesignProfile
    from survey.analysis.rings import FIT_RMS_WARN_M, fit_rings, poor_fits
    from survey.analysis.sections import above_floor
    from survey.report.header import write_headed_report
    from survey.report.sections import plot_rings, rings_csv, rings_markdown

    _check_input(input)
    al, prof = section_alignment(input, tunnel_json=tunnel_json, fit_axis=fit_axis,
                                 start_xy=start_xy, chainage_at_m=chainage_at_m,
                                 reverse=reverse, seed=seed)
    if rail_height_m is not None and min_height_m is None:
        raise CompareError("Expected --rail-height with --min-height (the height it "
                           "measures from), got it alone; add --min-height M.")
    for flag, v in (("--min-height", min_height_m), ("--rail-height", rail_height_m)):
        if v is not None and not np.isfinite(v):
            raise CompareError(f"Expected {flag} a finite height in m, got {v}.")
    chainages = _chainages(al, every_m, at_m, width_m)
    with _output_folder(output, force) as out:
        cuts = _cuts(input, al, chainages, width_m, max_points, seed, classes)
        floors = None
        if min_height_m is not None:
            # DECISION: with --tunnel-json the alignment is the floor (a tunnel JSON runs
            # along the invert, as before); a fitted axis runs through the profile centre,
            # so each section's lowest points are the floor there (issue 31).
            rail = rail_height_m if rail_height_m is not None else \
                (None if fit_axis else 0.0)
            kept = [above_floor(c, min_height_m, floor_m=rail) for c in cuts]
            cuts = [k[0] for k in kept]
            floors = [k[1] for k in kept]
        ref = DesignProfile.from_profile(prof).centre if prof is not None else np.zeros(2)
        rings = fit_rings(cuts, reference_centre=ref, nominal_diameter_m=nominal_diameter_m)
        bad = poor_fits(rings)
        if bad:
            worst = max(bad, key=lambda r: min(r.circle.rms_m, r.ellipse.rms_m))
            rms = min(worst.circle.rms_m, worst.ellipse.rms_m)
            warnings.warn(f"{len(bad)} of {len(rings)} rings fit a circle or an ellipse no "
                          f"better than {1000 * FIT_RMS_WARN_M:g} mm rms (worst "
                          f"{1000 * rms:.0f} mm at chainage {worst.chainage_m:g} m): the "
                          "section is not a ring (a horseshoe?), so its diameters and "
                          "ovality mean little; compare it with its design profile with "
                          "'tunnelsim sections --design', or drop the invert with "
                          "--min-height.", UserWarning, stacklevel=2)
        files = [write_text_file(out / "rings.csv", rings_csv(rings))]
        files += write_headed_report(
            out / "rings.md", rings_markdown(rings, source=Path(input).name),
            inputs=[("cloud or mesh", input, ""),
                    ("alignment", tunnel_json, "fitted axis" if fit_axis else "")],
            crs_from=[input], project=project, instrument=instrument)
        rows = [r.to_dict() for r in rings]
        if floors is not None:
            for row, f in zip(rows, sorted(zip([c.chainage_m for c in cuts], floors))):
                row["floor_height_m"] = f[1]
        files.append(write_text_file(out / "rings.json", json_text(rows)))
        plot_rings(rings, out / "rings.png")
        files.append(out / "rings.png")
    return RingsResult(out, tuple(files), tuple(rings),
                       None if floors is None else tuple(float(f) for f in floors),
                       float(min(r.ellipse.diameters_m[1] for r in rings)),
                       float(max(r.ellipse.diameters_m[0] for r in rings)),
                       float(max(r.ovality for r in rings)), len(bad))
