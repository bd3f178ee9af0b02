"""The tunnel axis of a cloud or mesh, and the unrolling about it.

Points may be (n, 3), a single (3,) point or a structured array with fields x, y, z.
Angles are radians: ``phi`` from the crown, positive to the left.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points
from survey.errors import AlignmentError, ReconstructionError
from survey.world.alignment import Alignment
from survey.world.mesh import read_axis, read_meta, sidecar

if TYPE_CHECKING:
    from raytrace import Scene

__all__ = ["AXIS_SAMPLE", "cell_runs", "estimate_axis", "fill_gaps", "tunnel_frame",
           "unroll"]

Floats = NDArray[np.float64]

#: Points used to estimate the axis (a seeded random subset of larger clouds).
AXIS_SAMPLE = 200_000


def _centres(q: Floats) -> tuple[Floats, Floats]:
    """Robust mid-range centre of 2-D points (k, 2)."""
    a = np.percentile(q, [2, 98], axis=0)
    return (a[0] + a[1]) / 2, a[1] - a[0]


def estimate_axis(points: ArrayLike, *, slice_m: float = 2.0, knot_spacing_m: float = 15.0,
                  min_points: int = 50) -> tuple[Alignment, float]:
    """(Alignment, centre height h_c in m) of a tunnel cloud (n, 3): a centreline at the
    profile's mid-height and the height of the profile centre above it (0 here: the
    axis runs through the centre). Slices ``slice_m`` long, knots every
    ``knot_spacing_m``; slices with fewer than ``min_points`` points are skipped."""
    p, _ = as_points(points, "points", ReconstructionError)
    if len(p) < 3 * min_points:
        raise ReconstructionError(f"Expected a cloud of at least {3 * min_points} points "
                                  f"(n, 3), got shape {p.shape}.")
    if len(p) > AXIS_SAMPLE:   # the axis needs shape, not every point
        p = p[np.random.default_rng(0).choice(len(p), AXIS_SAMPLE, replace=False)]
    origin = np.round(p.mean(axis=0))
    q = p - origin
    # Principal direction in plan (tunnels are near-horizontal).
    cov = np.cov(q[:, :2].T)
    w, v = np.linalg.eigh(cov)
    if w[1] < 9.0 * max(w[0], 1e-12):
        raise ReconstructionError("Expected an elongated tunnel-shaped cloud, got one "
                                  "whose plan extent is not elongated (could not find a "
                                  "tunnel axis).")
    d = v[:, 1]
    along = q[:, :2] @ d
    n_sl = max(2, int(np.ceil(np.ptp(along) / slice_m)))
    edges = np.linspace(along.min(), along.max(), n_sl + 1)
    idx = np.clip(np.searchsorted(edges, along, side="right") - 1, 0, n_sl - 1)
    nrm = np.array([-d[1], d[0]])
    cen = []
    for k in range(n_sl):
        m = idx == k
        if m.sum() < min_points:
            continue
        lat = q[m, :2] @ nrm
        c, span = _centres(np.stack([lat, q[m, 2]], 1))
        # The slice must surround its centre: points on both sides and above/below.
        rel = np.stack([lat - c[0], q[m, 2] - c[1]], 1)
        ang = np.arctan2(rel[:, 1], rel[:, 0])
        cover = np.unique(np.floor((ang + np.pi) / (np.pi / 6)).astype(int)).size
        if cover < 9:
            continue
        a = 0.5 * (edges[k] + edges[k + 1])
        cen.append(np.array([*(a * d + c[0] * nrm), c[1]]))
    if len(cen) < 5:
        raise ReconstructionError("Expected cross-sections that surround an axis, got too "
                                  "few (could not find a tunnel axis); is this a tunnel?")
    cen = np.array(cen) + origin
    try:
        al = Alignment.fit(cen, knot_spacing_m=max(knot_spacing_m, 3 * slice_m))
    except AlignmentError as exc:
        raise ReconstructionError(f"Expected a smooth centreline through the cross-"
                                  f"sections, got a fit failure ({exc}); could not find a "
                                  "tunnel axis.") from exc
    # Second pass: centres of slices perpendicular to the first alignment.
    s, off, h = al.to_local(p)
    c0, c1 = al.chainage_range
    inner = (s > c0 + 1e-6) & (s < c1 - 1e-6)
    sb = np.floor((s - c0) / slice_m).astype(int)
    pts = []
    for k in np.unique(sb[inner]):
        m = inner & (sb == k)
        if m.sum() < min_points:
            continue
        c, _ = _centres(np.stack([off[m], h[m]], 1))
        sc = float(np.median(s[m]))
        pts.append(al.to_world(sc, c[0], c[1]))
    if len(pts) < 5:
        raise ReconstructionError("Expected cross-sections along the first axis estimate, "
                                  "got too few (could not find a tunnel axis).")
    al2 = Alignment.fit(np.array(pts), knot_spacing_m=max(knot_spacing_m, 3 * slice_m))
    return al2, 0.0


def unroll(points: ArrayLike, alignment: Alignment | None = None,
           centre_height_m: float | None = None
           ) -> tuple[Alignment, float, Floats, Floats, Floats, Floats, Floats]:
    """(alignment, h_c, s, offset, height, phi, rho) of points (n, 3) about the profile
    centre: the alignment estimated when not given (its axis runs through the centre,
    h_c = 0), chainage s, offset and height (m, each (n,)), phi (n,) from the crown
    positive to the left (radians), rho (n,) the distance from the centre (m)."""
    p, _ = as_points(points, "points", ReconstructionError)
    if alignment is None:
        alignment, _ = estimate_axis(p)
    hc = 0.0 if centre_height_m is None else float(centre_height_m)
    s, off, h = alignment.to_local(p)
    return alignment, hc, s, off, h, np.arctan2(off, h - hc), np.hypot(off, h - hc)


def cell_runs(cell: NDArray[Any], values: Floats
              ) -> tuple[NDArray[Any], Floats, NDArray[np.intp], NDArray[np.intp]]:
    """Values grouped by cell: (cell ids (k,), values sorted within each cell (n,),
    start of each cell's run (k,), run lengths (k,))."""
    order = np.lexsort((values, cell))
    cs, vs = cell[order], values[order]
    starts = np.flatnonzero(np.concatenate([[True], cs[1:] != cs[:-1]]))
    return cs[starts], vs, starts, np.diff(np.append(starts, len(cs)))


def fill_gaps(grid: Floats, axis_coords: Floats) -> Floats:
    """NaN cells of a (rings, around) grid filled in place: periodic linear
    interpolation around each ring, then linear along the axis at ``axis_coords``."""
    n_a = grid.shape[1]
    ang = np.arange(n_a)
    for row in grid:
        ok = np.isfinite(row)
        if ok.any() and not ok.all():
            row[~ok] = np.interp(ang[~ok], ang[ok], row[ok], period=n_a)
    for col in grid.T:
        ok = np.isfinite(col)
        if ok.any() and not ok.all():
            col[~ok] = np.interp(axis_coords[~ok], axis_coords[ok], col[ok])
    return grid


def tunnel_frame(mesh_path: str | Path, scene: Scene | None = None
                 ) -> tuple[Scene, Any, Alignment, float]:
    """(Scene, reflectivity, Alignment, profile-centre height in m) of a mesh: the axis
    from the generated tunnel's JSON beside it, else estimated from the mesh vertices.
    With ``scene`` given, the mesh is not loaded again and reflectivity is None."""
    from sensors.meshes import load_mesh

    sc, refl = load_mesh(mesh_path) if scene is None else (scene, None)
    js = sidecar(mesh_path)
    if js.is_file():
        meta = read_meta(js)
        if "alignment" in meta and "profile" in meta:
            al, hc = read_axis(js)
            return sc, refl, al, hc
    import trimesh

    mesh: Any = trimesh.load(str(mesh_path), force="mesh", process=False)
    v = np.asarray(mesh.vertices)
    al, hc = estimate_axis(v)
    return sc, refl, al, hc

