"""``tunnelsim develop`` and ``tunnelsim clearance`` as library calls: developed views
of a cloud or mesh along the alignment, and an envelope swept along it, with the files
the commands write.

``develop_files`` and ``clearance_files`` read the alignment (a tunnel JSON, LandXML or
station CSV) and the design, choose the raster cell from the data where none is given,
stream the input through ``survey.analysis.developed.develop_file`` /
``survey.analysis.clearance.clearance_file``, and write the rasters, tables and the
headed report (``survey.report.developed``, ``survey.report.header``). The command line
parses its options, calls one of them and prints from the result.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from survey.errors import CompareError

__all__ = ["ClearanceFilesResult", "DevelopFilesResult", "FIELD_CHOICES", "STAT_CHOICES",
           "clearance_files", "develop_files"]

PathLike = str | os.PathLike[str]

#: ``field`` choices of ``develop_files`` (an M3C2 output's ``distance``, a scan's
#: ``intensity``).
FIELD_CHOICES = ("deviation", "distance", "intensity")
#: ``stat`` choices of ``develop_files``: the per-cell statistic written and drawn.
STAT_CHOICES = ("mean", "min", "max", "count")
#: Colour-bar limit of the clearance view (m) when no violation is deeper.
CLEARANCE_MIN_LIMIT_M = 0.05


# ---------------------------------------------------------------------------- results
@dataclass(frozen=True)
class DevelopFilesResult:
    """What ``develop_files`` wrote and computed.

    Attributes
    ----------
    output_dir : Path
        The output folder, as given.
    raster : survey.analysis.developed.DevelopedRaster
        The raster (cells over chainage x arc; ``meta`` as written to the JSON).
    field, stat : str
        What is shown and the per-cell statistic.
    points : int
        Points (or mesh samples) on the raster.
    rows, columns : int
        Cells along the arc and along the chainage.
    share_with_data : float
        Fraction (0..1) of the cells holding data.
    cell_chosen : str
        How the chainage cell was chosen, in one line.
    scale : survey.report.developed.ColourScale or None
        The colour scale (None for the intensity and the count).
    scale_line : str or None
        The colour scale in one line (mm), as printed.
    figures : tuple of str
        The PNG tiles' names (in ``output_dir``).
    files : tuple of Path
        Every file written: the tiles (PNG, NPY, JSON), developed.md, developed.html.
    report : str
        The report's Markdown as written (header included).
    """

    output_dir: Path
    raster: Any
    field: str
    stat: str
    points: int
    rows: int
    columns: int
    share_with_data: float
    cell_chosen: str
    scale: Any
    scale_line: str | None
    figures: tuple[str, ...]
    files: tuple[Path, ...]
    report: str


@dataclass(frozen=True)
class ClearanceFilesResult:
    """What ``clearance_files`` wrote and computed.

    Attributes
    ----------
    output_dir : Path
        The output folder, as given.
    clearance : survey.analysis.clearance.ClearanceResult
        Violations, regions (deepest first), the margin raster, the envelope.
    envelope_name : str
        The envelope's name (its file stem, or "box WxH").
    regions : int
        Violation regions found (0: clear).
    max_depth_m : float
        Depth of the deepest violation (m; 0 when clear).
    deepest_chainage_m : float or None
        Chainage of the deepest violation (None when clear).
    min_margin_m : float
        Smallest margin between the lining and the envelope (m; < 0 inside).
    cell_chosen : str
        How the chainage cell was chosen, in one line.
    merge_line : str
        How the violating cells were grouped into regions, in one line.
    figures : tuple of str
        The margin view's PNG tiles' names (in ``output_dir``).
    files : tuple of Path
        Every file written: the margin tiles, violations.csv, regions.csv,
        clearance.json, clearance.md, clearance.html.
    report : str
        The report's Markdown as written (header included).
    """

    output_dir: Path
    clearance: Any
    envelope_name: str
    regions: int
    max_depth_m: float
    deepest_chainage_m: float | None
    min_margin_m: float
    cell_chosen: str
    merge_line: str
    figures: tuple[str, ...]
    files: tuple[Path, ...]
    report: str


# ---------------------------------------------------------------------------- the frame
@dataclass(frozen=True)
class _Frame:
    """The alignment, design, cells, chainage range and CRS both workflows share."""

    alignment: Any
    design: Any
    cell_m: float
    cell_arc_m: float | None
    cell_chosen: str
    chainage_range: tuple[float, float] | None
    crs: str | None


def _tunnel(source: PathLike, tunnel: PathLike | None) -> tuple[Any, Any, str | None]:
    """(Alignment, Profile or None, CRS text or None) from ``tunnel`` (a tunnel JSON,
    LandXML or station CSV) or the JSON beside a tunnel PLY ``source``."""
    from survey.world.alignment_io import load_tunnel
    from sensors.io.tunnel_json import sidecar

    js = tunnel
    if js is None and Path(source).suffix.lower() == ".ply" and \
            sidecar(Path(source)).is_file():
        js = str(sidecar(Path(source)))
    if js is None:
        raise CompareError("Expected --tunnel-json T.json (the alignment), got none.")
    t = load_tunnel(str(js), option="--tunnel-json")
    return t.alignment, t.profile, t.crs


def _design(design: PathLike | None, order: str, shift_m: Sequence[float], prof: Any) -> Any:
    from survey.analysis.design import DesignProfile, read_design_profile

    if design is not None:
        return read_design_profile(design, order=order,
                                   shift_m=(float(shift_m[0]), float(shift_m[1])))
    if prof is None:
        raise CompareError("Expected --design FILE (the alignment of --tunnel-json has no "
                           "profile: a LandXML, a station CSV), got none.")
    return DesignProfile.from_profile(prof)


def _choose_cell(source: PathLike, al: Any, cell_m: float | None, cell_arc_m: float | None,
                 tile_m: float | None) -> tuple[float, float | None, str]:
    """(cell, arc cell, a line saying what was chosen): ``cell_m`` as given, or the
    station spacing of a profile cloud (``file_station_spacing``, ``default_cell``)."""
    from survey.analysis.developed import DEFAULT_CELL_M, default_cell, file_station_spacing

    if cell_m is not None:
        return cell_m, cell_arc_m, f"cell {cell_m:g} m along the chainage (--cell)"
    spacing = file_station_spacing(source, al)
    cell = default_cell(spacing, tile_m)
    if cell_arc_m is None:
        cell_arc_m = DEFAULT_CELL_M
    if spacing > 0:
        return cell, cell_arc_m, (f"cell {cell:g} m along the chainage: the input is a "
                                  f"profile cloud with stations every {spacing:.3f} m (one "
                                  f"column per station; set it with --cell)")
    return cell, cell_arc_m, (f"cell {cell:g} m along the chainage (the default for a "
                              f"dense cloud or a mesh; set it with --cell)")


def _frame(source: PathLike, *, tunnel: PathLike | None, design: PathLike | None,
           design_order: str, design_shift_m: Sequence[float], cell_m: float | None,
           cell_arc_m: float | None, tile_m: float | None, chainage_from_m: float | None,
           chainage_to_m: float | None) -> _Frame:
    """Check the input and the cells, then read the alignment and the design."""
    from sensors.io.cloudread import cloud_crs_text

    if not Path(source).is_file():
        raise CompareError(f"Expected an input cloud or mesh, got '{source}' which does "
                           "not exist.")
    for flag, v in (("--cell", cell_m), ("--cell-arc", cell_arc_m), ("--tile-m", tile_m)):
        if v is not None and not v > 0:
            raise CompareError(f"Expected {flag} > 0 m, got {v}.")
    if tile_m is not None and cell_m is not None:
        # Checked before the (long) pass over the input.
        r = tile_m / cell_m
        if abs(r - round(r)) > 1e-6 * max(1.0, r):
            raise CompareError(f"Expected --tile-m a whole multiple of --cell "
                               f"({cell_m:g} m), got {tile_m:g} m.")
    al, prof, crs = _tunnel(source, tunnel)
    cell, cell_arc, chosen = _choose_cell(source, al, cell_m, cell_arc_m, tile_m)
    des = _design(design, design_order, design_shift_m, prof)
    rng = None
    if chainage_from_m is not None or chainage_to_m is not None:
        lo, hi = al.chainage_range
        rng = (lo if chainage_from_m is None else chainage_from_m,
               hi if chainage_to_m is None else chainage_to_m)
    try:
        crs = cloud_crs_text(source) or crs
    except Exception:   # a mesh or a file without a CRS statement: the tunnel's
        pass
    return _Frame(al, des, cell, cell_arc, chosen, rng, crs)


def _no_points(source: PathLike) -> CompareError:
    return CompareError(f"Expected points of '{source}' on the tunnel between the "
                        "chainages asked, got none; check --tunnel-json, --from/--to and "
                        "the input's CRS.")


# ---------------------------------------------------------------------------- develop
def _scale_line(scale: Any) -> str:
    """The colour scale chosen (``survey.report.developed.ColourScale``), in one line
    (mm)."""
    if scale.edges is not None:
        return (f"colour classes at {', '.join(f'{1000 * e:g}' for e in scale.edges)} mm "
                f"(--tolerance); {100 * scale.beyond_share:.1f} % of the cells lie "
                "beyond them")
    how = "--limit-mm" if scale.source == "given" else \
        f"the {scale.percentile:g}th percentile of |value|; set it with --limit-mm"
    return (f"colour scale +-{1000 * scale.limit:.1f} mm ({how}); "
            f"{100 * scale.beyond_share:.1f} % of the cells lie beyond it")


def _develop_markdown(raster: Any, source: PathLike, stat: str, cell_chosen: str,
                      pngs: Sequence[str], scale: Any = None) -> str:
    """The developed view's report (without its header)."""
    g = raster.grid
    v = raster.statistic(stat)
    ok = np.isfinite(v)
    arc = raster.meta.get("arc", {})
    lines = [f"# Developed view: {raster.field}", "",
             f"Input: `{Path(source).name}`; design **{arc.get('design')}** "
             f"({'closed' if arc.get('design_closed') else 'open'}, "
             f"{arc.get('design_length_m', float('nan')):.3f} m); arc length from the "
             f"{arc.get('zero')}, positive to the left.", "",
             f"Grid: {g.n_s} x {g.n_arc} cells of {g.cell_s_m:g} m (chainage) x "
             f"{g.cell_arc_m:.4g} m (arc), from chainage {g.chainage0_m:g} m; "
             f"{raster.meta['points']:,} points ({raster.meta['left_out']:,} left out: "
             f"beyond the alignment, the design's ends or --max-deviation); "
             f"{100 * (raster.count > 0).mean():.1f} % of the cells hold data.", ""]
    if ok.any():
        lines += [f"{stat} {raster.field}: {np.nanmin(v):.4g} to {np.nanmax(v):.4g} "
                  f"{raster.unit if stat != 'count' else 'points'}.", ""]
    lines += [f"Raster: {cell_chosen}.", ""]
    if scale is not None:
        lines += [f"Colour scale: {_scale_line(scale)}.", ""]
    lines += [f"![{p}]({p})" for p in pngs]
    return "\n".join(lines) + "\n"


def _tolerance_edges_m(tolerance_mm: Sequence[float] | None, limit_mm: float | None,
                       field: str, stat: str) -> list[float] | None:
    if tolerance_mm is None:
        return None
    mm = [float(v) for v in tolerance_mm]
    if limit_mm is not None or field == "intensity" or stat == "count":
        raise CompareError("Expected --tolerance alone, for deviations or distances, got "
                           "it with --limit-mm, --field intensity or --stat count; leave "
                           "one out.")
    if not mm or any(b <= a for a, b in zip(mm, mm[1:])):
        raise CompareError(f"Expected --tolerance edges increasing in mm, got "
                           f"{','.join(f'{v:g}' for v in mm)!r}.")
    return [v / 1000.0 for v in mm]


def develop_files(source: PathLike, output_dir: PathLike, *, tunnel: PathLike | None = None,
                  design: PathLike | None = None, design_order: str = "file",
                  design_shift_m: Sequence[float] = (0.0, 0.0), field: str = "deviation",
                  stat: str = "mean", cell_m: float | None = None,
                  cell_arc_m: float | None = None, chainage_from_m: float | None = None,
                  chainage_to_m: float | None = None, tile_m: float | None = None,
                  max_deviation_m: float | None = None, limit_mm: float | None = None,
                  tolerance_mm: Sequence[float] | None = None, force: bool = False,
                  project: str | None = None, instrument: str | None = None
                  ) -> DevelopFilesResult:
    """A developed (unrolled) view of a cloud or mesh along the tunnel's alignment,
    written as ``tunnelsim develop`` writes it.

    Writes into ``output_dir`` per tile ``developed_<field>_<from>_<to>`` .png (colour
    bar; hatched = no data), .npy (float32, NaN = no data) and .json (the grid), then
    ``developed.md`` and ``developed.html`` with the report header.

    Parameters
    ----------
    source : path-like
        A cloud (.las/.laz/.ply/.npz/.csv/.txt/.xyz, streamed) or a mesh (.ply with
        faces, .obj/.stl/.off: area samples).
    output_dir : path-like
        Output folder: created; an existing non-empty one only with ``force``.
    tunnel : path-like, optional
        The alignment: a tunnel JSON, a LandXML alignment or a chainage,E,N,H CSV
        (default: the .json beside a tunnel .ply ``source``).
    design : path-like, optional
        Design profile (CSV/TXT of y,z in the section frame); default: the tunnel
        JSON's profile.
    design_order : {"file", "angle"}
        Vertex order of ``design``.
    design_shift_m : (2,) float
        Move ``design`` by (dy, dz) metres.
    field : {"deviation", "distance", "intensity"}
        What to show: signed distance to the design (> 0 overbreak), a per-point
        ``distance`` field (an M3C2 output), or the intensity.
    stat : {"mean", "min", "max", "count"}
        Per-cell statistic written and drawn.
    cell_m : float > 0, optional
        Cell along the chainage (m); default 0.05 or a profile cloud's station
        spacing, found from the first points read (``DevelopFilesResult.cell_chosen``).
    cell_arc_m : float > 0, optional
        Cell along the arc (m); default ``cell_m``, or 0.05 when the cell is chosen.
    chainage_from_m, chainage_to_m : float, optional
        Chainage range (default: the alignment's).
    tile_m : float > 0, optional
        One set of files per tile of this many metres (a whole multiple of the cell).
    max_deviation_m : float > 0, optional
        Leave out points farther than this from the design line.
    limit_mm : float > 0, optional
        Colour-bar limit +- in mm (default: the 98th percentile of ``|value|``).
    tolerance_mm : sequence of float, optional
        Increasing tolerance-class edges in mm (instead of a continuous bar).
    force : bool
        Write into a non-empty ``output_dir``.
    project, instrument : str, optional
        The user's words the report header states.

    Returns
    -------
    DevelopFilesResult

    Raises
    ------
    survey.errors.CompareError
        Bad options (messages name the command-line options), no points on the tunnel.
    sensors.io.errors.FileFormatError
        An unreadable input, alignment or design file.

    Examples
    --------
    >>> from survey.workflows.inspection import develop_files
    >>> r = develop_files("scan.laz", "dev", tunnel="t.json",
    ...                   tile_m=100)                          # doctest: +SKIP
    >>> r.points, r.share_with_data, r.figures[0]             # doctest: +SKIP
    """
    from survey.analysis.developed import develop_file
    from survey.report.developed import colour_scale, write_developed
    from survey.report.header import write_headed_report
    from survey.workflows.files import output_folder

    fr = _frame(source, tunnel=tunnel, design=design, design_order=design_order,
                design_shift_m=design_shift_m, cell_m=cell_m, cell_arc_m=cell_arc_m,
                tile_m=tile_m, chainage_from_m=chainage_from_m,
                chainage_to_m=chainage_to_m)
    if max_deviation_m is not None and not max_deviation_m > 0:
        raise CompareError(f"Expected --max-deviation > 0 m, got {max_deviation_m}.")
    if limit_mm is not None and not limit_mm > 0:
        raise CompareError(f"Expected --limit-mm > 0, got {limit_mm}.")
    edges = _tolerance_edges_m(tolerance_mm, limit_mm, field, stat)
    out = output_folder(output_dir, force=force)
    raster = develop_file(source, fr.alignment, fr.design, field=field, cell_m=fr.cell_m,
                          cell_arc_m=fr.cell_arc_m, chainage_range=fr.chainage_range,
                          max_deviation_m=max_deviation_m)
    if raster.meta["points"] == 0:
        raise _no_points(source)
    raster.meta["cell_chosen"] = fr.cell_chosen
    limit = None if limit_mm is None else limit_mm / 1000.0
    scale = colour_scale(raster, stat, limit=limit, edges=edges)
    paths = write_developed(raster, out, tile_m=tile_m, stat=stat, crs=fr.crs,
                            limit=limit, edges=edges)
    pngs = tuple(p.name for p in paths if p.suffix == ".png")
    md = _develop_markdown(raster, source, stat, fr.cell_chosen, pngs, scale)
    written = write_headed_report(
        out / "developed.md", md,
        inputs=[("cloud", source, ""), ("alignment", tunnel, ""),
                *([("design", design, "")] if design else [])],
        crs_from=[source], project=project, instrument=instrument,
        settings=[("field", f"{field} ({stat})"),
                  ("cell (m)", f"{raster.grid.cell_s_m:g} along the chainage x "
                               f"{raster.grid.cell_arc_m:g} along the arc")])
    return DevelopFilesResult(
        output_dir=Path(output_dir), raster=raster, field=field, stat=stat,
        points=int(raster.meta["points"]), rows=raster.grid.n_arc,
        columns=raster.grid.n_s, share_with_data=float((raster.count > 0).mean()),
        cell_chosen=fr.cell_chosen, scale=scale,
        scale_line=None if scale is None else _scale_line(scale), figures=pngs,
        files=(*paths, *written), report=written[0].read_text(encoding="utf-8"))


# ---------------------------------------------------------------------------- clearance
def clearance_files(source: PathLike, output_dir: PathLike, *, envelope: PathLike,
                    tunnel: PathLike | None = None, design: PathLike | None = None,
                    design_order: str = "file",
                    design_shift_m: Sequence[float] = (0.0, 0.0),
                    cell_m: float | None = None, cell_arc_m: float | None = None,
                    chainage_from_m: float | None = None,
                    chainage_to_m: float | None = None, tile_m: float | None = None,
                    required_m: float = 0.0, merge_gap_m: float | str = "auto",
                    force: bool = False, project: str | None = None,
                    instrument: str | None = None) -> ClearanceFilesResult:
    """An envelope swept along the alignment and every point of the lining inside it,
    written as ``tunnelsim clearance`` writes it.

    Writes into ``output_dir`` the margin's developed view per tile
    (``clearance_margin_<from>_<to>`` .png/.npy/.json, regions outlined),
    ``violations.csv`` (per cell its deepest point), ``regions.csv``,
    ``clearance.json``, ``clearance.md`` and ``clearance.html`` (with the header).

    Parameters
    ----------
    source : path-like
        A cloud (streamed) or a mesh (area samples), as for ``develop_files``.
    output_dir : path-like
        Output folder: created; an existing non-empty one only with ``force``.
    envelope : path-like or str
        The envelope polygon: a CSV/TXT of y,z (closed) or ``"box:W,H[,BOTTOM]"`` (m).
    tunnel, design, design_order, design_shift_m, cell_m, cell_arc_m
        As for ``develop_files``.
    chainage_from_m, chainage_to_m, tile_m
        As for ``develop_files``.
    required_m : float >= 0
        Free space required beyond the envelope (m).
    merge_gap_m : float >= 0 or "auto"
        Violating cells at most this far apart form one region ("auto": twice the
        data's spacing along the chainage).
    force : bool
        Write into a non-empty ``output_dir``.
    project, instrument : str, optional
        The user's words the report header states.

    Returns
    -------
    ClearanceFilesResult

    Raises
    ------
    survey.errors.CompareError
        Bad options (messages name the command-line options), no points on the tunnel.
    survey.errors.ProfileError
        An unusable envelope.
    sensors.io.errors.FileFormatError
        An unreadable input, alignment or design file.

    Examples
    --------
    >>> from survey.workflows.inspection import clearance_files
    >>> r = clearance_files("scan.laz", "clr", tunnel="t.json",
    ...                     envelope="box:4.5,4.8")               # doctest: +SKIP
    >>> r.regions, r.max_depth_m                                 # doctest: +SKIP
    """
    from raytrace.fileio import json_text
    from survey.analysis.clearance import clearance_file, read_envelope
    from survey.report.developed import (clearance_markdown, merge_line, regions_csv,
                                         violations_csv, write_developed)
    from survey.report.header import write_headed_report
    from survey.workflows.files import output_folder, write_text_file

    fr = _frame(source, tunnel=tunnel, design=design, design_order=design_order,
                design_shift_m=design_shift_m, cell_m=cell_m, cell_arc_m=cell_arc_m,
                tile_m=tile_m, chainage_from_m=chainage_from_m,
                chainage_to_m=chainage_to_m)
    env = read_envelope(envelope)
    if not (required_m >= 0):
        raise CompareError(f"Expected --required >= 0 m, got {required_m}.")
    out = output_folder(output_dir, force=force)
    res = clearance_file(source, fr.alignment, env, fr.design, cell_m=fr.cell_m,
                         cell_arc_m=fr.cell_arc_m, chainage_range=fr.chainage_range,
                         required_m=required_m, merge_gap_m=merge_gap_m)
    res.meta["cell_chosen"] = fr.cell_chosen
    if res.points == 0:
        raise _no_points(source)
    lim = max(res.max_depth_m, CLEARANCE_MIN_LIMIT_M)
    paths = write_developed(res.margin, out, stem="clearance_margin", tile_m=tile_m,
                            stat="min", crs=fr.crs, limit=lim, regions=res.regions)
    pngs = tuple(p.name for p in paths if p.suffix == ".png")
    tables = [write_text_file(out / "violations.csv", violations_csv(res)),
              write_text_file(out / "regions.csv", regions_csv(res)),
              write_text_file(out / "clearance.json", json_text(res.to_dict()))]
    written = write_headed_report(
        out / "clearance.md", clearance_markdown(res, source=Path(source).name,
                                                 figures=pngs),
        inputs=[("cloud", source, ""), ("alignment", tunnel, ""),
                ("envelope", envelope, "")],
        crs_from=[source], project=project, instrument=instrument)
    worst = res.regions[0] if res.regions else None
    return ClearanceFilesResult(
        output_dir=Path(output_dir), clearance=res, envelope_name=env.name,
        regions=len(res.regions),
        max_depth_m=0.0 if worst is None else float(worst.max_depth_m),
        deepest_chainage_m=None if worst is None else float(worst.deepest_chainage_m),
        min_margin_m=float(res.min_margin_m), cell_chosen=fr.cell_chosen,
        merge_line=merge_line(res), figures=pngs, files=(*paths, *tables, *written),
        report=written[0].read_text(encoding="utf-8"))
