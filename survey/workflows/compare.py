"""``tunnelsim compare`` as a library call: distances from clouds to a reference cloud
(C2C) or mesh (C2M), whole or tile by tile, with the files the command writes.

``compare_files`` is the only file-to-file comparison: the command line parses its
options, calls it, and prints from the ``CompareResult`` it returns. The arithmetic is
``survey.analysis.compare`` (one piece) and ``survey.cluster.compare`` (tiles); the
tables and the figure are ``survey.report.compare``.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from survey.errors import CompareError
from survey.workflows.files import ExecutorArg, opened_executor, output_folder, write_text_file

__all__ = ["CompareResult", "compare_files"]

PathLike = str | os.PathLike[str]
#: (done, total) after each block of points or each finished tile.
ProgressFn = Callable[[int, int], None]

#: Title of each kind of comparison, in the tables, the report and the figure.
TITLES = {"mesh": "C2M (signed)", "cloud": "C2C"}
#: The message when --split/--model meet a mesh (one piece and tiled alike).
_SPLIT_MESH = ("Expected --split/--model only with a reference cloud, got a mesh "
               "(cloud-to-mesh distances are signed, not split).")


@dataclass(frozen=True)
class CompareResult:
    """What ``compare_files`` wrote and computed.

    Attributes
    ----------
    output_dir : Path
        The output folder, as given.
    reference : str
        The reference's path, as given.
    kind : {"cloud", "mesh"}
        What the reference is: C2C (unsigned) or C2M (signed) distances.
    title : str
        "C2C" or "C2M (signed)".
    stats : mapping of str to mapping of str to float
        Per compared cloud (its file stem): ``distance_stats`` (n, mean, median, std,
        p95, rms, max_abs; m).
    table : str
        The statistics as the Markdown table (mm) the command prints.
    distance_files : tuple of Path
        Each compared cloud with the scalar field ``distance``, in input order.
    files : tuple of Path
        Every file written: stats.csv, stats.md, stats.html, histogram.png, then the
        ``distance_files``.
    tiles : int or None
        Tiles run, summed over the compared clouds (None: compared in one piece).
    """

    output_dir: Path
    reference: str
    kind: str
    title: str
    stats: Mapping[str, Mapping[str, float]]
    table: str
    distance_files: tuple[Path, ...]
    files: tuple[Path, ...]
    tiles: int | None = None


# ---------------------------------------------------------------------------- outputs
# ---------------------------------------------------------------------------- checks
def _load_reference(path: PathLike) -> tuple[Any, str]:
    from sensors.io.cloudread import read_reference
    from survey.analysis.compare import ReferenceCloud, ReferenceMesh

    v, f = read_reference(path)
    return (ReferenceMesh(v, f), "mesh") if f is not None else (ReferenceCloud(v), "cloud")


def _compared_boxes(compared: Sequence[PathLike], reference: PathLike, ref: Any,
                    allow_disjoint: bool) -> list[int]:
    """Refuse (unless ``allow_disjoint``) a compared cloud whose bounding box lies more
    than ``OVERLAP_TOL_M`` from the reference's; one pass over each cloud (bounds from
    the points, not a header). Returns the number of points of each compared cloud."""
    from sensors.io.cloudread import cloud_bounds
    from survey.analysis.compare import check_overlap

    total = []
    for c in compared:
        lo, hi, n = cloud_bounds(c)
        total.append(n)
        if allow_disjoint:
            continue
        try:
            check_overlap(np.stack([lo, hi]), ref.bounds,
                          names=(f"'{c}'", f"the reference '{reference}'"))
        except CompareError as exc:
            raise CompareError(f"{str(exc).rstrip('?.')}? Pass --allow-disjoint if you "
                               "mean it.") from exc
    return total


def _check_crs(compared: Sequence[PathLike], reference: PathLike,
               allow_mismatch: bool) -> dict[Any, str | None]:
    """Refuse (unless ``allow_mismatch``) inputs that state different coordinate
    reference systems, naming the first two; inputs stating none are not compared.
    Returns {path: CRS text or None} (the outputs state the compared cloud's)."""
    from sensors.io.cloudread import cloud_crs_text
    from sensors.io.crs import CRSError, crs_mismatch, mismatch_message

    stated = {c: cloud_crs_text(c) for c in [*compared, reference]}
    if not allow_mismatch:
        pair_ = crs_mismatch([(str(p), t) for p, t in stated.items()])
        if pair_ is not None:
            raise CRSError(mismatch_message(
                *pair_, what="compared clouds and the reference",
                hint="reproject one into the other's CRS first (e.g. PDAL "
                     "filters.reprojection), or pass --allow-crs-mismatch if a label is "
                     "wrong"))
    return stated


# ---------------------------------------------------------------------------- compare
def compare_files(compared: Sequence[PathLike], reference: PathLike,
                  output_dir: PathLike, *, max_distance_m: float | None = None,
                  split: bool = False, model: str | None = None, k: int = 6,
                  allow_disjoint: bool = False, allow_crs_mismatch: bool = False,
                  tile_m: float | None = None, executor: ExecutorArg = None,
                  force: bool = False, project: str | None = None,
                  instrument: str | None = None, progress: ProgressFn | None = None,
                  tile_progress: Callable[[str], ProgressFn] | None = None
                  ) -> CompareResult:
    """Distances from each compared cloud to a reference cloud (C2C) or mesh (C2M),
    written as ``tunnelsim compare`` writes them.

    Writes into ``output_dir``: each compared cloud as ``NAME_distance.laz`` with the
    scalar field ``distance`` (and ``dx``, ``dy``, ``dz`` with ``split``; a LAS/LAZ
    input keeps every field), ``stats.csv`` (m), ``stats.md`` and ``stats.html`` (mm,
    with the report header) and ``histogram.png``.

    Parameters
    ----------
    compared : sequence of path-like
        The compared clouds (any format ``sensors.io.cloudread`` reads).
    reference : path-like
        The reference: a cloud, or a mesh (.ply/.obj/.stl with faces).
    output_dir : path-like
        Output folder: created; an existing non-empty one only with ``force``.
    max_distance_m : float, optional
        Clamp distances at this many metres (required tile by tile with a reference
        cloud: it is the tiles' halo).
    split : bool
        Also the components compared - nearest reference point (reference cloud only).
    model : {"plane"}, optional
        Local model of a reference cloud: least-squares plane of ``k`` neighbours.
    k : int
        Neighbours for ``model``.
    allow_disjoint : bool
        Compare clouds whose bounding boxes lie more than 1 m from the reference's.
    allow_crs_mismatch : bool
        Compare inputs that state different coordinate reference systems.
    tile_m : float > 0, optional
        Compare tile by tile (x, y tiles of this many metres, spilled into
        ``output_dir``); the same distances as one piece.
    executor : survey.cluster.Executor or callable () -> Executor, optional
        Where the tiles run (default: this process); a callable is called when the
        tiles start and what it returns is closed after them.
    force : bool
        Write into a non-empty ``output_dir``.
    project, instrument : str, optional
        The user's words the report header states.
    progress : callable(done, total), optional
        Points done and the total, after each block (one piece).
    tile_progress : callable(path) -> callable(done, total), optional
        Tile by tile: called with each compared cloud's path before its tiles run;
        what it returns gets (tiles done, tiles) and, if it has one, ``close()`` at
        the end of that cloud.

    Returns
    -------
    CompareResult

    Raises
    ------
    CompareError
        Missing compared cloud, bad ``tile_m``, clouds far apart, options that do not
        fit the reference, a non-empty ``output_dir`` without ``force``.
    sensors.io.crs.CRSError
        Inputs stating different CRSs.
    sensors.io.errors.PointFileError, MeshFileError
        Unreadable inputs.

    Examples
    --------
    >>> r = compare_files(["scan.laz"], "design.ply", "cmp")       # doctest: +SKIP
    >>> r.stats["scan"]["rms"]                                       # doctest: +SKIP
    0.0042
    """
    compared = list(compared)
    if not compared:
        raise CompareError("Expected at least one compared cloud, got none.")
    for c in compared:
        if not Path(c).is_file():
            raise CompareError(f"Expected a compared cloud, got '{c}' which does not "
                               "exist.")
    if tile_m is not None and not tile_m > 0:
        raise CompareError(f"Expected --tile-m as a positive number of metres, got "
                           f"{tile_m:g}.")
    # DECISION: before the boxes: two CRSs explain a disjoint pair better than a box.
    crs = _check_crs(compared, reference, allow_crs_mismatch)
    opts = dict(max_distance_m=max_distance_m, split=split, model=model, k=k)
    if tile_m is not None:
        kind, rows, hist, tiles = _tiled(compared, reference, output_dir, crs, opts,
                                         tile_m=tile_m, allow_disjoint=allow_disjoint,
                                         executor=executor, force=force,
                                         tile_progress=tile_progress)
    else:
        ref, kind = _load_reference(reference)
        if kind == "mesh" and (split or model):
            raise CompareError(_SPLIT_MESH)
        total = sum(_compared_boxes(compared, reference, ref, allow_disjoint))
        out = output_folder(output_dir, force=force)
        tiles = None
        rows, hist = _distances(compared, ref, kind, out, opts, crs,
                                lambda n: progress(n, total) if progress else None)
    return _outputs(compared, reference, kind, Path(output_dir), rows, hist, tiles,
                    max_distance_m=max_distance_m, project=project,
                    instrument=instrument)


def _outputs(compared: list[Any], reference: PathLike, kind: str, out: Path,
             rows: dict[str, dict[str, float]], hist: dict[str, np.ndarray],
             tiles: int | None, *, max_distance_m: float | None, project: str | None,
             instrument: str | None) -> CompareResult:
    """stats.csv, stats.md/.html and histogram.png of a comparison."""
    from survey.report.compare import plot_histogram, stats_csv, stats_markdown
    from survey.report.header import write_headed_report

    title = TITLES[kind]
    name = Path(reference).name
    write_text_file(out / "stats.csv", stats_csv(rows))
    md = stats_markdown(rows, title=title)
    plot_histogram(hist, out / "histogram.png",
                   xlabel=f"{title} distance to {name} (mm)")
    # As the command always did: a compared path equal to the reference's is not
    # listed twice among the report's inputs.
    listed = [c for c in compared if str(c) != str(reference)]
    reports = write_headed_report(
        out / "stats.md",
        f"# {title} distances to {name}\n\n" + md +
        ("" if max_distance_m is None else
         f"\nDistances beyond {max_distance_m} m are clamped to it.\n") +
        "\n![histogram](histogram.png)\n",
        inputs=[*[("compared", c, "") for c in listed],
                ("reference", reference, "mesh" if kind == "mesh" else "cloud")],
        crs_from=[*compared, reference],
        settings=[("distance", title), ("max distance (m)",
                                        "none" if max_distance_m is None
                                        else f"{max_distance_m:g}")],
        project=project, instrument=instrument)
    laz = tuple(out / f"{Path(c).stem}_distance.laz" for c in compared)
    return CompareResult(output_dir=out, reference=str(reference), kind=kind, title=title,
                         stats=rows, table=md, distance_files=laz,
                         files=(out / "stats.csv", *reports, out / "histogram.png", *laz),
                         tiles=tiles)


def _tiled(compared: list[Any], reference: PathLike, output_dir: PathLike,
           crs: dict[Any, str | None], opts: dict[str, Any], *, tile_m: float,
           allow_disjoint: bool, executor: ExecutorArg, force: bool,
           tile_progress: Callable[[str], ProgressFn] | None
           ) -> tuple[str, dict[str, dict[str, float]], dict[str, np.ndarray], int]:
    """Tile by tile: the reference cloud spilled into tiles with a halo of the maximum
    distance (or the mesh sent once), each compared cloud spilled and compared tile by
    tile on the executor, then written in its own order (``survey.cluster.compare``).
    Returns (kind, stats rows, distances, tiles run)."""
    from sensors.io.cloudread import iter_points
    from survey.analysis.developed import is_mesh_file
    from survey.cluster.compare import spill_cloud, tiled_distances

    max_d = opts["max_distance_m"]
    mesh = is_mesh_file(reference)
    if mesh and (opts["split"] or opts["model"]):
        raise CompareError(_SPLIT_MESH)
    if not mesh and max_d is None:
        raise CompareError("Expected --max-dist with --tile-m and a reference cloud "
                           "(the nearest point is looked for within it: the tiles' "
                           "halo), got none.")
    if opts["model"]:
        raise CompareError("Expected --tile-m without --model (a plane's k neighbours "
                           "can lie beyond a tile's halo), got both.")
    if not mesh and max_d > tile_m:
        warnings.warn(f"--max-dist {max_d:g} m is larger than --tile-m {tile_m:g} m: "
                      "each tile reads its neighbours' points within it too, so memory "
                      "and time grow with (1 + 2 max-dist / tile)^2; --max-dist is in "
                      "metres (0.05 for 5 cm).", UserWarning, stacklevel=3)
    out = output_folder(output_dir, force=force)
    ref, kind, spill = None, "mesh", None
    if mesh:
        ref, kind = _load_reference(reference)
    else:
        kind = "cloud"
        spill = spill_cloud(iter_points(reference), tile_m, max_d, folder=out)
    tiled: dict[Any, Any] = {}
    try:
        counts = _compared_boxes(compared, reference, ref if ref is not None else spill,
                                 allow_disjoint)
        with opened_executor(executor) as ex:
            for c, n in zip(compared, counts):
                bar = tile_progress(str(c)) if tile_progress is not None else None
                try:
                    tiled[c] = tiled_distances(
                        iter_points(c), n, tile_m=tile_m, reference=spill, mesh=ref,
                        max_distance_m=max_d, split=opts["split"], executor=ex,
                        folder=out, progress=bar)
                finally:
                    close = getattr(bar, "close", None)
                    if close is not None:
                        close()
    finally:
        if spill is not None:
            spill.close()
    try:
        rows, hist = _distances(compared, None, kind, out, opts, crs, lambda n: None,
                                tiled=tiled)
    finally:
        for t in tiled.values():
            t.close()
    return kind, rows, hist, sum(t.tiles for t in tiled.values())


def _distances(compared: list[Any], ref: Any, kind: str, out: Path,
               opts: dict[str, Any], crs: dict[Any, str | None],
               progress: Callable[[int], None], tiled: dict[Any, Any] | None = None
               ) -> tuple[dict[str, dict[str, float]], dict[str, np.ndarray]]:
    """Write each compared cloud with its distances (``NAME_distance.laz``, stating the
    cloud's CRS ``crs[path]``), block by block (``progress(points done)`` after each);
    returns (stats rows, distances) by cloud name. ``tiled``: {path: TiledDistances}
    computed before (tile by tile), read in the cloud's order."""
    from sensors.io.cloudmap import annotate_las, write_points_las
    from sensors.io.cloudread import iter_points
    from survey.analysis.compare import BLOCK, Distances, distance_stats

    rows, hist = {}, {}
    done = 0
    for c in compared:
        name = Path(c).stem
        got: list[np.ndarray] = []
        pos = 0

        def dist(xyz: np.ndarray, got: list[np.ndarray] = got, c: Any = c
                 ) -> dict[str, np.ndarray]:
            nonlocal done, pos
            if tiled is not None:
                t, sl = tiled[c], slice(pos, pos + len(xyz))
                pos += len(xyz)
                r = Distances(np.array(t.distance[sl]), np.zeros(len(xyz), np.int64))
                if t.diff is not None:
                    r.dx, r.dy, r.dz = (np.array(t.diff[sl, i]) for i in range(3))
            elif kind == "mesh":
                r = ref.distances(xyz, max_distance_m=opts["max_distance_m"])
            else:
                r = ref.distances(xyz, max_distance_m=opts["max_distance_m"],
                                  split=opts["split"], model=opts["model"], k=opts["k"])
            got.append(r.distance)
            extra = {"distance": r.distance.astype(np.float32)}
            if opts["split"]:
                assert r.dx is not None and r.dy is not None and r.dz is not None
                extra.update(dx=r.dx.astype(np.float32), dy=r.dy.astype(np.float32),
                             dz=r.dz.astype(np.float32))
            done += len(xyz)
            progress(done)
            return extra

        dst = out / f"{name}_distance.laz"
        if Path(c).suffix.lower() in (".las", ".laz"):
            # Streamed, and every input field (intensity, time, classes...) kept; blocks
            # of BLOCK points for the progress bar.
            annotate_las(c, dst, dist, chunk=BLOCK)
        else:
            parts = list(iter_points(c, chunk=BLOCK))
            extras = [dist(p) for p in parts]
            write_points_las(dst, np.concatenate(parts),
                             {key: np.concatenate([e[key] for e in extras])
                              for key in extras[0]}, crs=crs.get(c))
        rows[name] = distance_stats(np.concatenate(got))
        hist[name] = np.concatenate(got)
    return rows, hist
