"""The axis workflow (``tunnelsim axis``): a tunnel JSON fitted to a cloud or mesh, with
the user's chainage, for develop, clearance, sections, convergence and m3c2 --orient
axis; and ``fitted_axis``, the fitted alignment that sections and rings ``--fit-axis``
cut along.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from survey.errors import AlignmentError

__all__ = ["AXIS_FORMAT", "AXIS_PROFILES", "AxisResult", "axis_file", "fitted_axis"]

PathLike = str | os.PathLike[str]

#: Format tag of the JSON ``axis_file`` writes (the tunnel JSON's alignment and
#: profile, without a mesh).
AXIS_FORMAT = "tunnelsim-axis/1"
#: The fitted profiles ``axis_file`` takes by name (any other ``profile`` is a file).
AXIS_PROFILES = ("sectors", "circle")


@dataclass(frozen=True)
class AxisResult:
    """What ``axis_file`` wrote and fitted.

    Attributes
    ----------
    output : Path, the tunnel JSON written
    alignment : survey.world.Alignment, the fitted axis with the user's chainage
    profile : survey.world.profiles.Profile, the cross-section written
    datum : mapping, how the chainage was set (the JSON's "datum": ``kind`` "start",
        "alignment" or the default, with ``start_offset_m`` / ``max_difference_m``)
    points_used : int, points of the seeded subset the axis was fitted to
    chainage_start_m, chainage_end_m : float, the axis' chainage range (m)
    start_point, end_point : tuple of 3 float, (x, y, z) of the axis at those
        chainages (m)
    length_m : float, the axis' length (m)
    mean_radius_m : float, radius of the circle of the profile's area (m)
    crs : str or None, the CRS text the input states
    """

    output: Path
    alignment: Any
    profile: Any
    datum: Mapping[str, Any]
    points_used: int
    chainage_start_m: float
    chainage_end_m: float
    start_point: tuple[float, float, float]
    end_point: tuple[float, float, float]
    length_m: float
    mean_radius_m: float
    crs: str | None = None


def fitted_axis(path: PathLike, *, seed: int = 0,
                start_xy: tuple[float, float] | None = None,
                chainage_at_m: float | None = None, reverse: bool = False,
                alignment: PathLike | None = None
                ) -> tuple[Any, dict[str, Any], NDArray[np.float64]]:
    """The tunnel axis of a cloud or mesh with the user's chainage.

    The axis of a seeded subset (``survey.clouds.axis.AXIS_SAMPLE`` points;
    ``estimate_axis``), extended to the data's ends, with chainage ``chainage_at_m``
    at the point nearest ``start_xy`` (``reverse``: running the other way), or the
    chainage and direction of the design ``alignment`` (``apply_datum``).

    Parameters
    ----------
    path : path-like
        Cloud (.las/.laz/.ply/.xyz/.txt/.csv/.npz/.e57) or mesh.
    seed : int
        Seed of the subset.
    start_xy : (float, float), optional
        Plan coordinates (m) of the start point.
    chainage_at_m : float, optional
        Chainage of the start point (default 0).
    reverse : bool
        Run the chainage the other way from the start point.
    alignment : path-like, optional
        A tunnel JSON, LandXML or chainage,E,N,H CSV whose chainage the axis takes.

    Returns
    -------
    alignment : survey.world.Alignment
    datum : dict
        The datum record of the tunnel JSON.
    points : (n, 3) float64
        The subset the axis was fitted to.

    Raises
    ------
    survey.errors.AlignmentError
        For ``alignment`` together with ``start_xy`` or ``reverse``.
    survey.errors.ReconstructionError
        When no axis is found.

    Examples
    --------
    >>> al, datum, pts = fitted_axis("scan.laz", start_xy=(2600012.5, 1200030.2),
    ...                              chainage_at_m=1250.0)  # doctest: +SKIP
    >>> datum["kind"]  # doctest: +SKIP
    'start'
    """
    from survey.clouds.axis import apply_datum, estimate_axis, sample_points
    from survey.world.alignment_io import load_tunnel

    if alignment is not None and (start_xy is not None or reverse):
        raise AlignmentError("Expected --alignment or --start/--reverse (where the "
                             "chainage comes from), got both.")
    pts = sample_points(str(path), seed=seed)
    al, _ = estimate_axis(pts)
    reference = load_tunnel(str(alignment), option="--alignment").alignment if alignment \
        else None
    at = 0.0 if chainage_at_m is None else chainage_at_m
    al, rec = apply_datum(al, pts, start_xy=start_xy, chainage_at_m=at, reverse=reverse,
                          reference=reference)
    return al, rec, pts


def _area(prof: Any) -> float:
    """Area (m^2) enclosed by a profile (its dense polygon, shoelace formula)."""
    _, p = prof.dense()
    y, z = p[:, 0], p[:, 1]
    return float(0.5 * np.sum(y * np.roll(z, -1) - np.roll(y, -1) * z))


def _profile(al: Any, pts: NDArray[np.float64], profile: PathLike) -> Any:
    """The cross-section written: fitted (``AXIS_PROFILES``) or a design file centred
    on the axis by its mid-range (as sections --fit-axis centres it)."""
    from survey.analysis.design import read_design_profile
    from survey.clouds.axis import fit_profile
    from survey.world.profiles import Profile

    if str(profile) in AXIS_PROFILES:
        return fit_profile(al, pts, kind=str(profile))
    d = read_design_profile(profile)
    if not d.closed:
        raise AlignmentError(f"Expected --profile as a closed design profile, got an "
                             f"open one in '{profile}'.")
    y0, y1, z0, z1 = d.extent()
    return Profile.from_polyline(d.vertices - [0.5 * (y0 + y1), 0.5 * (z0 + z1)],
                                 name=Path(profile).stem)


def axis_file(input: PathLike, output: PathLike, *,
              start_xy: tuple[float, float] | None = None,
              chainage_at_m: float | None = None, reverse: bool = False,
              alignment: PathLike | None = None,
              profile: PathLike = "sectors") -> AxisResult:
    """Fit the tunnel axis and a cross-section profile to a cloud or mesh and write a
    tunnel JSON with the user's chainage (``tunnelsim axis``).

    Parameters
    ----------
    input : path-like
        Cloud (.las/.laz/.ply/.xyz/.txt/.csv/.npz/.e57) or mesh.
    output : path-like
        The tunnel JSON to write (.json; its folder must exist).
    start_xy, chainage_at_m, reverse, alignment
        The chainage datum, as in ``fitted_axis``; ``chainage_at_m`` goes with
        ``start_xy``, not with ``alignment``.
    profile : {"sectors", "circle"} or path-like
        sectors: median radius in 5 deg sectors; circle: median radius; or a closed
        design profile file of y,z (centred on the axis by its mid-range).

    Returns
    -------
    AxisResult

    Raises
    ------
    survey.errors.AlignmentError
        For a missing input, an output that is not a .json in an existing folder,
        conflicting datum options or an open design profile.
    survey.errors.ReconstructionError
        When no axis is found.

    Examples
    --------
    >>> r = axis_file("scan.laz", "tunnel.json", start_xy=(2600012.5, 1200030.2),
    ...               chainage_at_m=1250.0)  # doctest: +SKIP
    >>> round(r.chainage_start_m, 3)  # doctest: +SKIP
    1250.0
    """
    from raytrace.fileio import write_json
    from sensors.io.cloudread import cloud_crs_text

    src, out = Path(input), Path(output)
    if not src.is_file():
        raise AlignmentError(f"Expected an input cloud or mesh, got '{src}' which does "
                             "not exist.")
    if out.suffix.lower() != ".json":
        raise AlignmentError(f"Expected -o as a .json file, got '{out}'.")
    if not out.parent.exists():
        raise AlignmentError(f"Expected an existing folder for '{out}', got none; "
                             "create it first.")
    if alignment is not None and chainage_at_m is not None:
        raise AlignmentError("Expected --chainage-at with --start (the alignment of "
                             "--alignment gives the chainage), got it with --alignment.")
    # DECISION: 'axis' has no --seed: its subset is drawn with seed 0, as
    # estimate_axis draws its own (the axis must not change with a seed); sections and
    # rings --fit-axis pass theirs.
    al, rec, pts = fitted_axis(src, seed=0, start_xy=start_xy, chainage_at_m=chainage_at_m,
                               reverse=reverse, alignment=alignment)
    prof = _profile(al, pts, profile)
    meta = {"format": AXIS_FORMAT, "name": src.stem, "source": src.name,
            "alignment": al.to_dict(), "profile": prof.to_dict(), "datum": rec,
            "fit": {"points_used": int(len(pts)), "profile": str(profile),
                    "axis": "profile centre"}}
    try:
        crs = cloud_crs_text(src)
    except Exception:   # a mesh or a file without a CRS statement
        crs = None
    if crs:
        meta["crs"] = crs
    write_json(out, meta)
    lo, hi = al.chainage_range
    a, b = al.point(lo), al.point(hi)
    return AxisResult(out, al, prof, rec, int(len(pts)), float(lo), float(hi),
                      (float(a[0]), float(a[1]), float(a[2])),
                      (float(b[0]), float(b[1]), float(b[2])), float(al.length_m),
                      float(np.sqrt(abs(_area(prof)) / np.pi)), crs or None)
