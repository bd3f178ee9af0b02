"""Workflows on point clouds: ``preprocess_file`` (voxel grid, crop, outliers,
segmentation; ``tunnelsim preprocess``) and ``mesh_files`` (reconstruction with the
method choice, voxel streaming, decimation and the solid fallback; ``tunnelsim mesh``).

Each writes the files its command writes and returns a frozen result with the paths and
every number the command prints. Errors keep the command's messages (they name its
options, e.g. ``--voxel``): a Python caller reads the keyword of the same name.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from survey.errors import ReconstructionError

__all__ = ["DEFAULT_CELL", "MESH_METHODS", "MeshResult", "PreprocessResult", "mesh_files",
           "preprocess_file"]

PathLike = str | os.PathLike[str]

#: The tunnel mesher's cells without ``cell_m``/``cell_deg`` (m along the axis, degrees
#: around it).
DEFAULT_CELL = (0.1, 2.0)
#: The methods ``mesh_files`` takes (``--method``).
MESH_METHODS = ("auto", "tunnel", "poisson", "solid")
#: Most input points the decimated mesh's point-to-mesh distances are measured on (a
#: seeded random subset beyond).
COMPACT_SAMPLE = 200_000


# ------------------------------------------------------------------------- preprocess
@dataclass(frozen=True)
class PreprocessResult:
    """What ``preprocess_file`` wrote and counted.

    Attributes
    ----------
    output : Path, the LAS/LAZ written
    input_points : int, points read
    voxel_points : int, points after the voxel grid (``input_points`` without one)
    kept_points : int, points written (after crop and outlier removal)
    classes : tuple of (code, name, count) or None, the segmentation's classes in
        increasing code (None without ``segment``)
    """

    output: Path
    input_points: int
    voxel_points: int
    kept_points: int
    classes: tuple[tuple[int, str, int], ...] | None = None


def _tunnel_axis(path: PathLike | None) -> tuple[Any, float | None]:
    """(Alignment, profile-centre height) from a tunnel JSON, or (None, None)."""
    if not path:
        return None, None
    from survey.world.mesh import read_axis

    return read_axis(str(path))


def preprocess_file(cloud: PathLike, output: PathLike, *, voxel_m: float | None = None,
                    sor: tuple[int, float] | None = None,
                    ror: tuple[int, float] | None = None,
                    crop_m: tuple[float, float] | None = None, segment: bool = False,
                    tunnel_json: PathLike | None = None) -> PreprocessResult:
    """Stream a cloud through a voxel grid, crop it to a chainage range, remove outliers,
    optionally classify it, and write LAS/LAZ (``tunnelsim preprocess``).

    Parameters
    ----------
    cloud : path-like
        Input cloud (LAS/LAZ/PLY/XYZ/NPZ/E57); its extra dimensions travel with the
        points, and its colour (a voxel's: the linear-light mean of its points').
    output : path-like
        Output cloud (.las/.laz), with the number of points per voxel; LAS RGB 16-bit
        (point format 7) when the input carries colour.
    voxel_m : float, optional
        Voxel size (m): centroid per voxel, Open3D semantics. None: no grid.
    sor : (int, float), optional
        Statistical outlier removal: K neighbours (the point included) and the
        threshold mean + STD_RATIO x std (``--sor K,STD_RATIO``).
    ror : (int, float), optional
        Radius outlier removal: at least N other points within RADIUS_M
        (``--ror N,RADIUS_M``).
    crop_m : (float, float), optional
        Keep the chainage range START..END (m) of the axis of ``tunnel_json``, or of the
        axis estimated from the cloud.
    segment : bool
        Classify lining (64), floor (2), attachments (65), objects (66), terrain beyond a
        portal (67), noise (7) as the LAS classification.
    tunnel_json : path-like, optional
        The alignment for ``crop_m`` and ``segment`` (a tunnel JSON, LandXML or CSV).

    Returns
    -------
    PreprocessResult

    Raises
    ------
    sensors.io.errors.PointFileError
        When the cloud cannot be read.
    survey.errors.PreprocessError, survey.errors.ReconstructionError
        For bad parameters, or no axis found for ``crop_m``/``segment``.

    Examples
    --------
    >>> r = preprocess_file("scan.laz", "clean.laz", voxel_m=0.02,
    ...                     sor=(8, 2.0))  # doctest: +SKIP
    >>> r.input_points, r.voxel_points, r.kept_points  # doctest: +SKIP
    (1250000, 310421, 309877)
    """
    from sensors.io.cloudfields import cloud_appearance
    from sensors.io.cloudread import cloud_bounds
    from survey.clouds.preprocess import (VoxelGrid, colour_fields, extra_dims,
                                          iter_points_colour, radius_outliers,
                                          rgb_from_fields, statistical_outliers,
                                          write_preprocessed)

    lo, _hi, n_in = cloud_bounds(cloud)
    # The input's extra dimensions (LAS/LAZ extra bytes) travel with the points, and
    # its colour (averaged in linear light; issue 35).
    dims = extra_dims(cloud)
    app = cloud_appearance(cloud)
    coloured = app.colour is not None
    if voxel_m is not None:
        grid = VoxelGrid(voxel_m, lo)
        for xyz, f, rgb in iter_points_colour(cloud, app):
            grid.add(xyz, {**f, **colour_fields(rgb, len(xyz))} if coloured else f)
        pts, counts = grid.result()
        extra = grid.fields()
    else:
        parts = list(iter_points_colour(cloud, app))
        pts = np.concatenate([p for p, _, _ in parts])
        extra = {k: np.concatenate([f[k] for _, f, _ in parts]) for k in dims}
        if coloured:
            cf = [colour_fields(c, len(p)) for p, _, c in parts]
            extra.update({k: np.concatenate([f[k] for f in cf]) for k in cf[0]})
        counts = np.ones(len(pts), dtype=np.int64)
    rgb16 = rgb_from_fields(extra) if coloured else None
    keep = np.ones(len(pts), dtype=bool)
    if crop_m is not None:
        s0, s1 = crop_m
        al, _ = _tunnel_axis(tunnel_json)
        if al is None:
            from survey.clouds.axis import estimate_axis
            al, _ = estimate_axis(pts)
        s, _, _ = al.to_local(pts)
        keep &= (s >= s0) & (s <= s1)
    if sor is not None:
        keep &= ~statistical_outliers(pts, k=int(sor[0]), std_ratio=sor[1])
    if ror is not None:
        keep &= ~radius_outliers(pts, min_neighbours=int(ror[0]), radius_m=ror[1])
    cls = None
    classes = None
    if segment:
        from survey.clouds.segment import CLASS_NAMES, segment_tunnel

        al, hc = _tunnel_axis(tunnel_json)
        cls = segment_tunnel(pts[keep], alignment=al, centre_height_m=hc)
        u, c = np.unique(cls, return_counts=True)
        classes = tuple((k, CLASS_NAMES[k], v) for k, v in zip(u.tolist(), c.tolist()))
    write_preprocessed(output, pts[keep], counts[keep],
                       {k: v[keep] for k, v in extra.items()}, dims, classification=cls,
                       rgb=None if rgb16 is None else rgb16[keep])
    return PreprocessResult(Path(output), int(n_in), int(len(pts)), int(keep.sum()),
                            classes)


# ------------------------------------------------------------------------------- mesh
@dataclass(frozen=True)
class MeshResult:
    """What ``mesh_files`` wrote and measured.

    Attributes
    ----------
    output : Path, the PLY written (per-vertex ``support`` for tunnel and solid)
    method : str, the method that made it: "tunnel", "poisson" or "solid"
    method_asked : str, ``method`` as given ("auto" included)
    method_reason : str, why ``method`` ran (auto: the judgement of the tunnel fit)
    input_points : int, points read from the clouds
    voxels : int or None, points after the voxel grid (None: ``voxel_m`` 0, every
        point)
    voxel_m : float, the voxel grid's size (m)
    triangles : int, triangles written (after decimation)
    triangles_undecimated : int, triangles before decimation (= ``triangles``
        without)
    report : mapping, the reconstruction quality, as the JSON ``json_path`` holds it
        (written or not): point-to-surface ``mean_m``, ``median_m``, ``p95_m``,
        ``max_m``, ``extrapolated_share`` (tunnel), ``unsupported_share``, ``depth``,
        ``cell_m``, ``trim_m`` (solid), the method choice (``method_reason``,
        ``auto``, ``cell_chosen``) and ``decimation``
    decimation : mapping or None, the decimation block (triangles before and after,
        tries, error both ways, points-to-mesh distances); None when none was asked
    depth : int or None, the Poisson octree depth (poisson and solid)
    cell_m, cell_deg : float or None, the tunnel mesher's cell (m, degrees; None when
        it did not run)
    profile_spacing_m : float or None, the profiles' spacing along the axis when the
        cell was chosen from it (a profile cloud)
    cell_how : str or None, how the cell was chosen when not given
    detail_faces : int or None, triangles of the detail layer (``detail``)
    json_path, figure : Path or None, the JSON and the support-map PNG written
    appearance : mapping, per attribute ("colour", "temperature") whether the mesh has
        it and where it came from (the files, how they store it, the vertices that
        took the nearest point's value), the radius averaged over; also the report's
        "appearance" (``survey.clouds.colour.describe``)
    """

    output: Path
    method: str
    method_asked: str
    method_reason: str
    input_points: int
    voxels: int | None
    voxel_m: float
    triangles: int
    triangles_undecimated: int
    report: Mapping[str, Any] = field(default_factory=dict)
    decimation: Mapping[str, Any] | None = None
    depth: int | None = None
    cell_m: float | None = None
    cell_deg: float | None = None
    profile_spacing_m: float | None = None
    cell_how: str | None = None
    detail_faces: int | None = None
    json_path: Path | None = None
    figure: Path | None = None
    appearance: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class _MeshJob:
    """The options of one ``mesh_files`` call, as its steps read them."""

    clouds: tuple[str, ...]
    output: Path
    method: str
    cell: tuple[float, float] | None
    detail: bool
    depth: int
    triangles: int | None
    max_triangles: int | None
    max_error_m: float | None
    min_points: int
    tunnel_json: PathLike | None
    voxel_m: float
    trim_m: float | None
    trajectory: PathLike | None
    scanners: PathLike | None
    json_path: Path | None
    figure: Path | None
    colour: bool = True
    temperature: bool = True
    #: The clouds' colour and temperature (``sensors.io.cloudfields.CloudAppearance``
    #: per cloud) and the sources, found before the points are read.
    appearances: tuple[Any, ...] = ()
    sources: Mapping[str, list[str]] = field(default_factory=dict)

    @property
    def carries(self) -> tuple[bool, bool]:
        """(any cloud has colour, any has temperature), what was asked for."""
        return (any(a.colour is not None for a in self.appearances),
                any(a.temperature is not None for a in self.appearances))


#: Options of one method that another method does not take, with their command-line
#: names (a silent no-op would let a user believe they acted).
_METHOD_ONLY = {"tunnel": (("detail", "--detail"), ("triangles", "--triangles"),
                           ("figure", "--figure")),
                "solid": (("trim_m", "--trim"), ("trajectory", "--trajectory"),
                          ("scanners", "--scanners"))}


def _check_method_options(job: _MeshJob, method: str) -> None:
    """Refuse an option of another method than the one that runs (auto resolved)."""
    for m, names in _METHOD_ONLY.items():
        given = [flag for name, flag in names if getattr(job, name) not in (None, False)]
        if given and method != m:
            how = "" if job.method == method else f" (--method {job.method} chose it)"
            raise ReconstructionError(f"Expected {given[0]} with --method {m}, got --method "
                                      f"{method}{how}; pass --method {m}.")


def _check_job(job: _MeshJob) -> None:
    """Refuse a bad method, --max-triangles or --max-error before anything is read."""
    from survey.clouds.decimate import MIN_TRIANGLES

    if job.method not in MESH_METHODS:
        raise ReconstructionError(f"Expected --method as one of {', '.join(MESH_METHODS)}, "
                                  f"got {job.method!r}.")
    if not job.clouds:
        raise ReconstructionError("Expected at least one input cloud, got none.")
    if job.max_triangles is not None and job.max_triangles < MIN_TRIANGLES:
        raise ReconstructionError(f"Expected --max-triangles >= {MIN_TRIANGLES}, got "
                                  f"{job.max_triangles}; pass a larger --max-triangles.")
    if job.max_error_m is not None and not (np.isfinite(job.max_error_m)
                                            and job.max_error_m > 0):
        raise ReconstructionError(f"Expected a positive --max-error (m), got "
                                  f"{job.max_error_m:g}; pass e.g. --max-error 0.02.")


def _write_json(path: Path, obj: Any) -> None:
    """Strict JSON, atomically (``raytrace.fileio``); the folder must exist."""
    from raytrace.fileio import write_json

    if not path.parent.exists():
        raise ReconstructionError(f"Expected an existing folder for '{path}', got none; "
                                  "create it first.")
    write_json(path, obj)


def _default_cell(pts: NDArray[np.float64], al: Any
                  ) -> tuple[float, float, str, float | None]:
    """(cell m, cell deg, how, profile spacing or None) when no cell is given:
    ``DEFAULT_CELL``, or for a profile cloud one cell per profile along the axis
    (``survey.analysis.developed.station_spacing``). DECISION: a cell shorter than the
    profiles' spacing leaves most columns without a point, and the mesher then
    interpolates them: on the real Ringo profiles (0.5 m) 0.1 m cells were 80 %
    interpolated, 0.5 m cells 2.9 % (issue 31)."""
    from survey.analysis.developed import station_spacing

    ax = al
    if ax is None:
        from survey.clouds.axis import estimate_axis

        ax, _ = estimate_axis(pts)
    s, _, _ = ax.to_local(pts)
    spacing = station_spacing(s)
    if spacing <= DEFAULT_CELL[0]:
        return (*DEFAULT_CELL, "default (no profile spacing above it)", None)
    cell = round(float(spacing), 3)
    return cell, DEFAULT_CELL[1], f"a profile cloud, profiles every {spacing:.3f} m", \
        float(spacing)


def _auto_method(job: _MeshJob, pts: NDArray[np.float64]) -> tuple[str, str]:
    """(method, reason): the method ``auto`` first tries: tunnel when ``tunnel_json``
    is given or the cloud has a tunnel axis (``estimate_axis`` succeeds), else solid;
    the tunnel mesh is judged afterwards (``_mesh_tunnel``)."""
    if job.method != "auto":
        return job.method, f"--method {job.method} asked"
    if job.tunnel_json:
        return "tunnel", "--tunnel-json gives the axis"
    from survey.clouds.axis import estimate_axis

    try:
        estimate_axis(pts)
    except ReconstructionError as exc:
        return "solid", f"no tunnel axis found ({exc})"
    return "tunnel", "a tunnel axis was found"


def _compact(job: _MeshJob, vertices: Any, faces: Any, support: Any, points: Any
             ) -> tuple[Any, Any, Any, dict[str, Any] | None]:
    """The mesh decimated as ``max_triangles`` / ``max_error_m`` ask (or as it is), the
    support carried to the nearest original vertex, and the "decimation" JSON block
    (None when nothing was asked), with the input points' distances to the result."""
    if job.max_triangles is None and job.max_error_m is None:
        return vertices, faces, support, None
    from survey.clouds.decimate import decimate_mesh, point_mesh_distances

    dec = decimate_mesh(vertices, faces, max_triangles=job.max_triangles,
                        max_error_m=job.max_error_m)
    sup = None if support is None else np.asarray(support)[dec.nearest_original]
    p = np.asarray(points, dtype=np.float64)
    if len(p) > COMPACT_SAMPLE:
        p = p[np.random.default_rng(0).choice(len(p), COMPACT_SAMPLE, replace=False)]
    # A local origin keeps UTM-sized coordinates exact in the distance kernel.
    origin = np.round(p.mean(axis=0))
    d = point_mesh_distances(p - origin, dec.vertices - origin, dec.faces)
    block = dict(dec.quality, points_to_mesh={
        "median_m": float(np.median(d)), "p95_m": float(np.percentile(d, 95)),
        "max_m": float(d.max()), "points": int(len(p))})
    return dec.vertices, dec.faces, sup, block


def _fallback_possible(job: _MeshJob, why: str) -> None:
    """Refuse the solid fallback when a cloud records no scanner position."""
    from survey.clouds.scanners import station_position

    for c in job.clouds:
        if station_position(c) is None:
            raise ReconstructionError(
                f"Expected scanner positions for the solid route --method auto falls "
                f"back to ({why}), got '{c}' that records no station pose; pass "
                "--scanners FILE or --trajectory FILE, or --method tunnel to keep the "
                "tunnel mesh.")


def _read_reduced(clouds: Sequence[str], voxel_m: float, job: _MeshJob | None = None
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64] | None, int, Any]:
    """(points (m, 3), counts (m,) int64 or None, input points, the
    ``survey.clouds.colour.AppearanceCloud`` or None) of the clouds streamed through a
    voxel grid of ``voxel_m`` (centroid and count per voxel,
    ``survey.clouds.preprocess.VoxelGrid``), or every point when ``voxel_m`` is 0. The
    clouds' colour and temperature (``job.appearances``) travel in the same grid: six
    more float64 sums a voxel (48 bytes, about 150 bytes at the merges' peak: measured
    1.23 -> 2.29 GB for 10^7 points, 7.1 M voxels; 24 bytes a voxel kept after), and
    a LAS file with RGB is read once more before, for its 8- or 16-bit colour.

    Memory bound: one bounds pass, then the grid holds 40 bytes per occupied voxel
    (key, three sums, count), about three times that while chunks merge, plus one chunk
    of points (``sensors.io.cloudread.CHUNK``); the occupied voxels are about lining area /
    voxel_m^2 (times the noise's thickness in voxels), whatever the number of points.
    The mesher then needs ~90 bytes a voxel. Measured peak RSS of ``tunnelsim mesh``
    (a 5 m tube 300 m long, 2 mm noise, 2 cm voxels): 1.26 GB for 10^7 points (8.4 M
    voxels), 2.53 GB for 3 x 10^7 (18.4 M), 4.74 GB for 10^8 (29.0 M); every point in
    memory (``voxel_m`` 0) costs ~86 bytes a point (2.58 GB for 3 x 10^7).
    """
    from sensors.io.cloudread import cloud_bounds, iter_points
    from survey.clouds.preprocess import VoxelGrid

    if not (np.isfinite(voxel_m) and voxel_m >= 0):
        raise ReconstructionError(f"Expected --voxel >= 0 (m), got {voxel_m:g}.")
    if job is not None and any(job.carries):
        return _read_reduced_appearance(job, voxel_m)
    if voxel_m == 0:
        pts = np.concatenate([xyz for c in clouds for xyz in iter_points(c)])
        return pts, None, len(pts), None
    lo = np.min([cloud_bounds(c)[0] for c in clouds], axis=0)
    grid = VoxelGrid(voxel_m, lo)
    n_in = 0
    for c in clouds:
        for xyz in iter_points(c):
            grid.add(xyz)
            n_in += len(xyz)
    pts, counts = grid.result()
    return pts, counts, n_in, None


def _read_reduced_appearance(job: _MeshJob, voxel_m: float
                             ) -> tuple[NDArray[np.float64], NDArray[np.int64] | None,
                                        int, Any]:
    """``_read_reduced`` with the clouds' colour and temperature (``job.carries``)."""
    from sensors.io.cloudfields import iter_appearance
    from sensors.io.cloudread import cloud_bounds
    from survey.clouds.colour import AppearanceCloud, AppearanceGrid, appearance_fields

    has_rgb, has_t = job.carries
    chunks = ((xyz, rgb, t) for a in job.appearances
              for xyz, rgb, t in iter_appearance(a.path, a))
    if voxel_m == 0:
        pts_l, fields_l = [], []
        for xyz, rgb, t in chunks:
            pts_l.append(xyz)
            fields_l.append(appearance_fields(rgb, t, len(xyz), has_rgb, has_t))
        pts = np.concatenate(pts_l)
        fields = {k: np.concatenate([f[k] for f in fields_l]) for k in fields_l[0]}
        del pts_l, fields_l
        return pts, None, len(pts), AppearanceCloud.from_means(pts, fields, None,
                                                               dict(job.sources))
    lo = np.min([cloud_bounds(c)[0] for c in job.clouds], axis=0)
    grid = AppearanceGrid(voxel_m, lo, colour=has_rgb, temperature=has_t,
                          sources=dict(job.sources))
    for xyz, rgb, t in chunks:
        grid.add(xyz, rgb, t)
    pts, counts, cloud = grid.result()
    return pts, counts, grid.n_points, cloud


def _write_mesh(job: _MeshJob, vertices: Any, faces: Any,
                fields: Mapping[str, Any], cloud: Any) -> dict[str, Any]:
    """Write the mesh's PLY (``sensors.io.meshes.write_mesh``: float64 vertices,
    ``fields`` as float64, as ``survey.world.mesh.write_ply`` writes them) with the
    colour and temperature of ``cloud`` at each vertex (``survey.clouds.colour``);
    returns the report's "appearance" block."""
    from sensors.io.meshes import write_mesh
    from survey.clouds.colour import appearance_radius, describe, transfer_appearance

    vf: dict[str, np.ndarray] = {k: np.asarray(a, dtype="<f8") for k, a in fields.items()}
    app = None
    if cloud is not None:
        app = transfer_appearance(cloud, vertices,
                                  appearance_radius(vertices, faces, job.voxel_m))
        vf.update(app.vertex_fields())
    write_mesh(job.output, np.asarray(vertices, dtype=np.float64), np.asarray(faces),
               vertex_fields=vf, comments=("written by tunnelsim",))
    return describe(app, job.sources, {"colour": not job.colour,
                                       "temperature": not job.temperature})


def _solid_appearance(job: _MeshJob) -> Any:
    """The clouds' colour and temperature through their own voxel grid (the solid
    route's grid carries scanner positions, not fields): one more pass over the
    clouds, only when they carry either."""
    if not any(job.carries):
        return None
    return _read_reduced_appearance(job, job.voxel_m)[3]


def mesh_files(clouds: PathLike | Sequence[PathLike], output: PathLike, *,
               method: str = "auto", cell_m: float | None = None,
               cell_deg: float | None = None, detail: bool = False, depth: int = 10,
               triangles: int | None = None, max_triangles: int | None = None,
               max_error_m: float | None = None, min_points: int = 3,
               tunnel_json: PathLike | None = None, voxel_m: float = 0.02,
               trim_m: float | None = None, trajectory: PathLike | None = None,
               scanners: PathLike | None = None, json_path: PathLike | None = None,
               figure: PathLike | None = None, colour: bool = True,
               temperature: bool = True) -> MeshResult:
    """Reconstruct a mesh from cleaned clouds (``tunnelsim mesh``).

    The clouds stream through a voxel grid (centroid and count per voxel). ``tunnel``:
    unroll the lining around the centreline (estimated, or from ``tunnel_json``), a
    median radius per cell, gaps filled (vertex ``support`` 0), open portals found from
    the data. ``solid``: screened Poisson oriented towards the scanner of each point
    (a station's pose from its file, ``trajectory`` at each point's time, or the
    nearest of ``scanners``), trimmed where no point lies within ``trim_m``.
    ``poisson``: Open3D Poisson oriented by the tunnel axis. ``auto``: tunnel when an
    axis is given or found, judged on its result (``survey.clouds.meshchoice``) and
    replaced by solid when the fit is poor; else solid. ``max_triangles`` /
    ``max_error_m`` decimate the mesh of any method (quadric, Open3D), the error
    measured after.

    Parameters
    ----------
    clouds : path-like or sequence of path-like
        Input cloud(s) (LAS/LAZ/PLY/XYZ/NPZ/E57), e.g. one file per station.
    output : path-like
        Output mesh (.ply).
    method : {"auto", "tunnel", "poisson", "solid"}
    cell_m, cell_deg : float, optional
        tunnel: cell size along the axis (m) and around it (degrees), both or
        neither; neither: ``DEFAULT_CELL``, or for a profile cloud the profiles'
        spacing along the axis (``MeshResult.cell_how`` says).
    detail : bool
        tunnel: add attachments (cables, pipes) as closed tubes (vertex support -1).
    depth : int
        poisson: octree depth.
    triangles : int, optional
        tunnel: triangle budget: coarsen the cells until the mesh fits.
    max_triangles : int, optional
        Any method: quadric decimation to at most this many triangles.
    max_error_m : float, optional
        Any method: the fewest triangles (within ``max_triangles``) whose measured
        error to the undecimated mesh is at most this (m).
    min_points : int
        tunnel: cells with fewer points are interpolated.
    tunnel_json : path-like, optional
        The alignment of a generated tunnel's JSON (or LandXML / CSV).
    voxel_m : float
        The voxel grid (m) the clouds stream through; solid: also the finest Poisson
        cell. 0: no grid, every point in memory (tunnel and poisson only).
    trim_m : float, optional
        solid: remove the surface farther than this from every point (default 5
        voxels, at least 0.3 m).
    trajectory : path-like, optional
        solid: the platform trajectory (TUM .txt or .csv): the scanner at each point's
        gps_time.
    scanners : path-like, optional
        solid: scanner positions (x y z rows, a route CSV or a TUM file); each point
        takes the nearest.
    json_path : path-like, optional
        Also write the reconstruction quality (``MeshResult.report``) as JSON.
    figure : path-like, optional
        tunnel: also write the unrolled support map (points per cell) as PNG.
    colour : bool
        Write per-vertex ``red green blue`` (uint8 sRGB) when a cloud carries colour
        (``sensors.io.cloudfields.cloud_appearance``): the linear-light mean of the
        points near each vertex (``survey.clouds.colour``). False (``--no-colour``):
        leave it out.
    temperature : bool
        Write per-vertex ``temperature`` (float32, K) when a cloud carries one, the
        mean of the points near each vertex. False (``--no-temperature``): leave it
        out.

    Returns
    -------
    MeshResult

    Raises
    ------
    survey.errors.ReconstructionError
        For bad options (an option of another method than the one that runs, a bad
        ``max_triangles``/``max_error_m``/``voxel_m``), no usable axis, or the solid
        fallback without scanner positions.
    sensors.io.errors.PointFileError
        When a cloud cannot be read.

    Examples
    --------
    >>> r = mesh_files(["st01.laz", "st02.laz"], "cave.ply", method="solid",
    ...                max_triangles=200_000)  # doctest: +SKIP
    >>> r.method, r.triangles <= 200_000, r.report["median_m"] < 0.01  # doctest: +SKIP
    ('solid', True, True)
    """
    if (cell_m is None) != (cell_deg is None):
        raise ReconstructionError("Expected cell_m and cell_deg together (--cell M,DEG), "
                                  "got one of them; pass both or neither.")
    paths = (clouds,) if isinstance(clouds, (str, os.PathLike)) else tuple(clouds)
    job = _MeshJob(tuple(str(c) for c in paths), Path(output), method,
                   None if cell_m is None else (float(cell_m), float(cell_deg or 0.0)),
                   detail, depth, triangles, max_triangles, max_error_m, min_points,
                   tunnel_json, voxel_m, trim_m, trajectory, scanners,
                   None if json_path is None else Path(json_path),
                   None if figure is None else Path(figure), bool(colour),
                   bool(temperature))
    _check_job(job)
    if job.colour or job.temperature:
        from survey.clouds.colour import cloud_appearances

        apps, sources = cloud_appearances(job.clouds, colour=job.colour,
                                          temperature=job.temperature)
        job = replace(job, appearances=tuple(apps), sources=sources)
    chosen = job.method
    choice: dict[str, Any] = {"method_asked": job.method}
    if chosen == "auto" and not job.tunnel_json and (job.trajectory or job.scanners):
        chosen = "solid"           # scanner positions are what the solid route asks for
        choice["method_reason"] = "scanner positions given (--trajectory/--scanners)"
    if chosen == "solid":
        _check_method_options(job, chosen)
        choice.setdefault("method_reason", "--method solid asked")
        return _mesh_solid(job, choice, {})
    pts, counts, n_in, cloud = _read_reduced(job.clouds, job.voxel_m, job)
    chosen, choice["method_reason"] = _auto_method(job, pts)
    _check_method_options(job, chosen)
    if chosen == "solid":
        del pts
        return _mesh_solid(job, choice, {}, cloud if job.voxel_m > 0 else None)
    if chosen == "poisson":
        return _mesh_poisson(job, choice, pts, counts, n_in, cloud)
    return _mesh_tunnel(job, choice, pts, counts, cloud)


def _mesh_poisson(job: _MeshJob, choice: dict[str, Any], pts: NDArray[np.float64],
                  counts: NDArray[np.int64] | None, n_in: int, cloud: Any = None
                  ) -> MeshResult:
    """``poisson``: Open3D Poisson oriented by the tunnel axis."""
    from survey.clouds.reconstruct import poisson_tunnel

    al, hc = _tunnel_axis(job.tunnel_json)
    v, f = poisson_tunnel(pts, alignment=al, centre_height_m=hc, depth=job.depth)
    n_faces = len(f)
    v, f, _, block = _compact(job, v, f, None, pts)
    appearance = _write_mesh(job, v, f, {}, cloud)
    report = {"method": "poisson", **choice, "points": int(n_in),
              "triangles": int(len(f)), "decimation": block, "appearance": appearance}
    if job.json_path:
        _write_json(job.json_path, report)
    return MeshResult(job.output, "poisson", job.method, choice["method_reason"],
                      int(n_in), None if counts is None else int(len(pts)), job.voxel_m,
                      int(len(f)), int(n_faces), report, block, depth=job.depth,
                      json_path=job.json_path, appearance=appearance)


def _mesh_tunnel(job: _MeshJob, choice: dict[str, Any], pts: NDArray[np.float64],
                 counts: NDArray[np.int64] | None, cloud: Any = None) -> MeshResult:
    """``tunnel`` (and ``auto``'s first try): the tunnel mesher, judged under auto."""
    from survey.clouds.reconstruct import reconstruct_tunnel, reconstruct_within_budget

    al, hc = _tunnel_axis(job.tunnel_json)
    spacing = how = None
    if job.cell is not None:
        cell_m, cell_deg = job.cell
    else:
        cell_m, cell_deg, how, spacing = _default_cell(pts, al)
        choice["cell_chosen"] = {"cell_m": cell_m, "cell_deg": cell_deg, "how": how}
    cells: dict[str, Any] = {"cell_m": cell_m, "cell_deg": cell_deg,
                             "profile_spacing_m": spacing, "cell_how": how}
    kw = dict(alignment=al, centre_height_m=hc, cell_m=cell_m,
              cell_rad=np.deg2rad(cell_deg), min_points=job.min_points, counts=counts)
    rec = reconstruct_tunnel(pts, **kw) if job.triangles is None else \
        reconstruct_within_budget(pts, job.triangles, **kw)
    if job.method == "auto":
        from survey.clouds.meshchoice import judge_tunnel_fit

        judged = judge_tunnel_fit(pts, rec.vertices, rec.faces, rec.support, counts=counts)
        choice["auto"] = judged.as_json()
        if not judged.good:
            _fallback_possible(job, judged.reason)
            _check_method_options(job, "solid")
            choice["method_reason"] = f"{judged.reason}: fell back to solid"
            del pts, counts, rec
            return _mesh_solid(job, choice, cells, cloud if job.voxel_m > 0 else None)
        choice["method_reason"] += f"; {judged.reason}"
    detail_faces = None
    if job.detail:
        from survey.clouds.detail import with_detail_layer

        mesh = with_detail_layer(rec, pts)
        v, f, sup = mesh.vertices, mesh.faces, mesh.support
        detail_faces = int(mesh.detail_faces)
    else:
        v, f, sup = rec.vertices, rec.faces, rec.support.astype(np.float64)
    v, f, sup, block = _compact(job, v, f, sup, pts)
    appearance = _write_mesh(job, v, f, {"support": sup}, cloud)
    if job.figure:
        from survey.report.reconstruct import plot_support

        plot_support(rec, job.figure)
    q: dict[str, Any] = rec.quality or {}
    extra: dict[str, Any] = {"method": "tunnel", **choice, "appearance": appearance}
    if block is not None:
        extra.update(decimation=block, triangles=block["triangles"],
                     triangles_undecimated=q["triangles"])
    report = {**q, **extra}
    if job.json_path:
        _write_json(job.json_path, report)
    return MeshResult(job.output, "tunnel", job.method, choice["method_reason"],
                      int(q["points"]), None if counts is None else int(len(pts)),
                      job.voxel_m, int(len(f)), int(q["triangles"]), report, block,
                      detail_faces=detail_faces, json_path=job.json_path,
                      figure=job.figure, appearance=appearance, **cells)


def _mesh_solid(job: _MeshJob, choice: dict[str, Any], cells: dict[str, Any],
                cloud: Any = None) -> MeshResult:
    """``solid``: the clouds stream through a scanner-aware voxel grid (bounds first,
    one pass each), then ``reconstruct_solid``. ``cells``: the tunnel mesher's cell
    when auto tried it first; ``cloud``: the clouds' colour and temperature when auto
    read them already (else another pass reads them)."""
    from sensors.io.cloudread import cloud_bounds
    from survey.clouds.scanners import iter_scanned, read_positions
    from survey.clouds.solid import ScannerVoxelGrid, reconstruct_solid

    if not (np.isfinite(job.voxel_m) and job.voxel_m > 0):
        raise ReconstructionError(f"Expected a positive --voxel (m), got {job.voxel_m:g}.")
    traj = None
    if job.trajectory:
        from sensors import Trajectory

        traj = Trajectory.read(job.trajectory)
    stations = read_positions(job.scanners) if job.scanners else None
    lo = np.min([cloud_bounds(c)[0] for c in job.clouds], axis=0)
    grid = ScannerVoxelGrid(job.voxel_m, lo)
    for c in job.clouds:
        for xyz, scanner in iter_scanned(c, trajectory=traj, stations=stations):
            grid.add(xyz, scanner)
    pts, scanners, _ = grid.result()
    rec = reconstruct_solid(pts, scanners=scanners, cell_m=job.voxel_m, trim_m=job.trim_m)
    v, f, sup, block = _compact(job, rec.vertices, rec.faces,
                                rec.support.astype(np.float64), pts)
    if cloud is None:
        cloud = _solid_appearance(job)
    appearance = _write_mesh(job, v, f, {"support": sup}, cloud)
    q = dict(rec.quality, method="solid", **choice, input_points=grid.n_points,
             depth=rec.depth, cell_m=rec.cell_m, trim_m=rec.trim_m,
             support_radius_m=rec.support_radius_m, appearance=appearance)
    if block is not None:
        q.update(decimation=block, triangles=block["triangles"],
                 triangles_undecimated=rec.quality["triangles"])
    if job.json_path:
        _write_json(job.json_path, q)
    return MeshResult(job.output, "solid", job.method, q["method_reason"],
                      int(grid.n_points), int(len(pts)), job.voxel_m, int(q["triangles"]),
                      int(rec.quality["triangles"]), q, block, depth=int(rec.depth),
                      json_path=job.json_path, appearance=appearance, **cells)
