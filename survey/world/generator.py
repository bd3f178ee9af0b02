"""Parametric tunnel generator: alignment x profile x features -> labelled triangle mesh.

The lining is a structured grid swept along the alignment: rings at chainages s_i, each
the profile sampled at parameters t_j (``Profile.sample``), placed in the vertical
cross-section of the alignment at s_i (``Alignment.to_world``). Every grid vertex sits on
the design profile, then moves along the profile's outward normal by

- a recess depth inside a niche or drainage channel (the recess walls are one
  ``RECESS_EDGE_M`` wide ring/column of the grid: near-vertical, never degenerate), and
- the surface relief (``survey.world.rock``): the lining roughness (a Gaussian texture,
  ``roughness_rms_m``, clipped at ``ROUGHNESS_CLIP`` standard deviations) and, for a
  drill-and-blast tunnel, the rock relief's overbreak (``relief``). Both are fields over
  the developed lining sampled on fixed grids: the same seed gives the same surface at
  every edge length.

Cables, bolt plates and prisms are separate closed solids placed on the relieved
surface: each is offset along the profile normal by the relief of the lining grid at its
(chainage, t), interpolated on the grid's own triangles, so it sits on the rock whatever
the relief. Faces of the lining point into the tunnel (towards a scanner); faces of the
closed solids point out of them.
Everything is vectorised NumPy: a 1M-triangle tunnel takes seconds.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.shapes import icosphere
from survey.errors import TunnelError
from survey.world import features as F
from survey.world.alignment import Alignment
from survey.world.mesh import LABEL, LABELS, REFLECTIVITY, TunnelMesh
from survey.world.profiles import Profile
from survey.world.rock import TEXTURE_CLIP, RockRelief, surface_relief

__all__ = ["MAX_TRIANGLES", "RECESS_EDGE_M", "ROUGHNESS_CLIP", "edge_length_for",
           "fan_faces", "grid_faces", "make_tunnel"]

Floats = NDArray[np.float64]
Ints = NDArray[np.int64]


#: Width of the sloping wall of a recess (niche sides, sill and lintel; channel banks).
RECESS_EDGE_M = 0.02
#: Roughness is clipped at this many standard deviations (so it is bounded).
ROUGHNESS_CLIP = TEXTURE_CLIP
#: How far bolt plates and prism stalks reach into the rock behind their footprint's
#: highest point, so that no gap opens under them (m).
_EMBED_M = 0.005
#: Largest mesh the generator will build (guards against a mistyped edge length).
MAX_TRIANGLES = 60_000_000
#: Sides of the stalk of a prism and its cross-section (m).
_STALK_M = 0.012


# Unit cube, vertex v = x + 2 y + 4 z, faces wound outward (right-handed frame).
_CUBE_V = np.array([[(v >> 0) & 1, (v >> 1) & 1, (v >> 2) & 1] for v in range(8)], float)
_CUBE_F = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                    [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]])


def edge_length_for(n_triangles: int, profile: Profile, length_m: float) -> float:
    """Edge length (m) that gives about ``n_triangles`` lining triangles (2 per square
    cell of the developed lining, perimeter x length)."""
    n = int(n_triangles)
    if n < 100:
        raise TunnelError(f"Expected at least 100 triangles, got {n}.")
    return float(np.sqrt(2.0 * profile.perimeter_m * length_m / n))


def _fill(breaks: ArrayLike, spacing: float) -> Floats:
    """Sorted unique break points, each interval split evenly (pieces <= spacing)."""
    b = np.unique(np.asarray(breaks, dtype=np.float64))
    b = b[np.concatenate([[True], np.diff(b) > 1e-6])]
    n = np.maximum(1, np.ceil(np.diff(b) / spacing - 1e-9).astype(np.int64))
    start = np.repeat(b[:-1], n)
    step = np.repeat(np.diff(b) / n, n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    return np.append(start + k * step, b[-1])


def _rel(t: ArrayLike, t0: float, per: float) -> Any:
    """Parameter distance from t0 going counter-clockwise, in [0, per)."""
    return np.mod(np.asarray(t, dtype=np.float64) - t0, per)


def _arc_between(profile: Profile, ta: float, tb: float,
                 wanted: Callable[[float], Any]) -> tuple[float, float]:
    """(start, length) of the profile arc between parameters ta and tb whose midpoint
    satisfies ``wanted`` (of the two arcs a pair of points splits a closed curve into)."""
    per = profile.perimeter_m
    lo, hi = sorted((ta % per, tb % per))
    if wanted(0.5 * (lo + hi)):
        return lo, hi - lo
    return hi, lo + per - hi


def grid_faces(rings: int, k: int, first: int, outward: bool) -> Ints:
    """Faces (2 (rings - 1) k, 3) of a closed-around tube grid of ``rings`` x ``k``
    vertices starting at vertex ``first``; ``outward`` flips the winding (solids) from
    the lining's inward-facing one."""
    i = np.arange(rings - 1)[:, None] * k
    j = np.arange(k)[None, :]
    a = (first + i + j).ravel()
    b = (first + i + (j + 1) % k).ravel()
    c, d = a + k, b + k
    if outward:
        return np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    return np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])


def fan_faces(centre: int, ring: Ints, forward: bool) -> Ints:
    """Faces (len(ring), 3) of a fan from vertex ``centre`` to the closed ``ring`` of
    vertex indices; ``forward`` picks the winding."""
    nxt = np.roll(ring, -1)
    c = np.full(len(ring), centre)
    return np.stack([c, ring, nxt] if forward else [c, nxt, ring], 1)


class _Builder:
    """Collects mesh parts: vertices, faces, labels, and the (chainage, profile t) of
    the lining point each vertex is or is attached to."""

    def __init__(self) -> None:
        self.v: list[Floats] = []
        self.f: list[Ints] = []
        self.lab: list[NDArray[np.uint8]] = []
        self.s: list[Floats] = []
        self.t: list[Floats] = []
        self.n = 0

    def add(self, verts: Floats, faces: Ints, labels: ArrayLike, s: ArrayLike,
            t: ArrayLike) -> None:
        self.v.append(verts)
        self.f.append(faces + self.n)
        self.lab.append(np.broadcast_to(np.asarray(labels, np.uint8), (len(faces),)))
        self.s.append(np.broadcast_to(np.asarray(s, float), (len(verts),)))
        self.t.append(np.broadcast_to(np.asarray(t, float), (len(verts),)))
        self.n += len(verts)

    def result(self) -> tuple[Floats, Ints, NDArray[np.uint8], Floats, Floats]:
        return (np.concatenate(self.v), np.concatenate(self.f).astype(np.int64),
                np.concatenate(self.lab), np.concatenate(self.s), np.concatenate(self.t))


class _Recess(NamedTuple):
    """A recess cut into the lining: a rectangle in (chainage, profile t), metres."""

    s0: float
    s1: float
    t0: float
    width: float
    depth: float
    label: int


class _Tunnel(NamedTuple):
    """What every stage of ``make_tunnel`` reads: the geometry and its extent."""

    alignment: Alignment
    profile: Profile
    c0: float
    c1: float
    reach_m: float          # farthest the relieved lining lies outside the design line


def _span(f: Any, tun: _Tunnel) -> tuple[float, float]:
    """A feature's chainage range (None ends: the tunnel's), checked to lie inside."""
    c0, c1 = tun.c0, tun.c1
    a = c0 if f.start_m is None else f.start_m
    b = c1 if f.end_m is None else f.end_m
    if a < c0 - 1e-9 or b > c1 + 1e-9:
        raise TunnelError(f"Expected {type(f).__name__} chainages within the tunnel "
                          f"[{c0:g}, {c1:g}] m, got [{a:g}, {b:g}].")
    return a, b


def _check_parameters(alignment: Alignment, profile: Profile, edge_length_m: float,
                      roughness_rms_m: float, roughness_corr_m: float,
                      features: Sequence[object], relief: object) -> float:
    """Validate make_tunnel's arguments; the edge length as a float."""
    if relief is not None and not isinstance(relief, RockRelief):
        raise TunnelError(f"Expected `relief` as a RockRelief or None, got "
                          f"{type(relief).__name__}.")
    if not isinstance(alignment, Alignment) or not isinstance(profile, Profile):
        raise TunnelError(f"Expected an Alignment and a Profile, got "
                          f"{type(alignment).__name__} and {type(profile).__name__}.")
    h = float(edge_length_m)
    if not (np.isfinite(h) and h > 0):
        raise TunnelError(f"Expected a positive `edge_length_m`, got {edge_length_m}.")
    c0, c1 = alignment.chainage_range
    est = 2.0 * profile.perimeter_m * (c1 - c0) / (h * h)
    if est > MAX_TRIANGLES:
        raise TunnelError(f"Expected at most {MAX_TRIANGLES:,} triangles, got about "
                          f"{est:,.0f} for edge_length_m={h}; use a larger edge length.")
    for name_, v in (("roughness_rms_m", roughness_rms_m),
                     ("roughness_corr_m", roughness_corr_m)):
        if not (np.isfinite(v) and v >= 0):
            raise TunnelError(f"Expected `{name_}` >= 0, got {v}.")
    if roughness_rms_m > 0 and roughness_corr_m <= 0:
        raise TunnelError("Expected a positive `roughness_corr_m` with roughness, got 0.")
    for f in features:
        if type(f) not in F.KINDS.values():
            raise TunnelError(f"Expected features from survey.world.features, got "
                              f"{type(f).__name__}.")
    return h


def _plan_recesses(tun: _Tunnel, features: Sequence[F.Feature], closed_ends: bool
                   ) -> tuple[list[_Recess], list[float], list[float]]:
    """Niches and drainage channels as recesses, and the chainage and profile break
    points the lining grid must keep (recess edges, feature ends)."""
    profile, c0, c1 = tun.profile, tun.c0, tun.c1
    per = profile.perimeter_m
    e = RECESS_EDGE_M
    recesses: list[_Recess] = []
    s_breaks, t_breaks = [c0, c1], []
    for f in features:
        if isinstance(f, F.Niche):
            a, b = _span(f, tun)
            ta = profile.t_at_height(f.side, f.bottom_m)
            tb = profile.t_at_height(f.side, f.top_m)
            sgn = 1.0 if f.side == "left" else -1.0
            t0, w = _arc_between(profile, ta, tb,
                                 lambda tm: sgn * profile.points(tm)[0] > 0)
            recesses.append(_Recess(a, b, t0, w, f.depth_m, LABEL["niche"]))
        elif isinstance(f, F.Drainage):
            a, b = _span(f, tun)
            ta = profile.t_at_floor_offset(f.offset_m - f.width_m / 2)
            tb = profile.t_at_floor_offset(f.offset_m + f.width_m / 2)
            t0, w = _arc_between(profile, ta, tb, profile.is_floor)
            if not profile.is_floor(t0 + w / 2):
                raise TunnelError(f"Expected the drainage channel on the floor, got offset "
                                  f"{f.offset_m} m which is not on a floor piece.")
            recesses.append(_Recess(a, b, t0, w, f.depth_m, LABEL["drainage"]))
        elif isinstance(f, (F.WetFloor, F.Cable)):
            s_breaks += list(_span(f, tun))
    for r in recesses:
        s0, s1, t0, w, _, _ = r
        if (s1 - s0) <= 2 * e + 1e-6 or w <= 2 * e + 1e-6:
            raise TunnelError(f"Expected recesses larger than {2 * e} m in each direction, "
                              f"got {s1 - s0:.3g} x {w:.3g} m.")
        if closed_ends and (s0 <= c0 + 1e-9 or s1 >= c1 - 1e-9):
            raise TunnelError("Expected recesses to stop short of closed ends, got one "
                              "reaching a portal; shorten it or leave the ends open.")
        s_breaks += [s0, s0 + e, s1 - e, s1]
        t_breaks += [t0, t0 + e, t0 + w - e, t0 + w]
    for i, r in enumerate(recesses):
        for q in recesses[i + 1:]:
            t_overlap = (np.mod(q[2] - r[2], per) < r[3]) or (np.mod(r[2] - q[2], per) < q[3])
            if r[0] < q[1] and q[0] < r[1] and t_overlap:
                raise TunnelError(f"Expected non-overlapping niches and channels, got two "
                                  f"overlapping between chainages {max(r[0], q[0]):g} and "
                                  f"{min(r[1], q[1]):g} m.")
    return recesses, s_breaks, t_breaks


def _check_fit(tun: _Tunnel, recesses: Sequence[_Recess], closed_ends: bool) -> None:
    """The lining must not fold in curves, and fan caps need a star-shaped profile."""
    # A curve tighter than the tunnel is wide folds the lining on its inner side.
    left, right, _, _ = tun.profile.extent()
    reach = max((r.depth for r in recesses), default=0.0) + tun.reach_m
    r_left, r_right = tun.alignment.min_radius()
    for side, ext, rad, sgn in (("left", left, r_left, 1), ("right", right, r_right, -1)):
        if ext + reach >= rad:
            where = tun.alignment.chainage_of_curvature(sgn / rad)
            raise TunnelError(f"Expected curve radii larger than the tunnel's {side} "
                              f"half-width ({ext + reach:.3f} m), got a {side}-hand radius "
                              f"of {rad:.3f} m near chainage {where:g} m; the lining would "
                              "fold on the inside of the curve.")
    if closed_ends and not tun.profile.star_shaped_about_centroid():
        raise TunnelError("Expected a profile star-shaped about its centroid for closed "
                          "ends (fan caps), got one that is not; leave the ends open.")


#: Tolerance (m) for grid rows and columns on a recess edge.
_GRID_TOL_M = 1e-7


class _Grid(NamedTuple):
    """The lining grid: ring chainages (nr,), profile parameters (k,) and the surface
    relief (nr, k) of its vertices (recesses not included), m."""

    s: Floats
    t: Floats
    relief: Floats


def _on_grid(grid: _Grid, per: float, sq: ArrayLike, tq: ArrayLike) -> Floats:
    """The relief at points (sq, tq) (same shape) as the lining mesh carries it:
    linear on each grid triangle (cells split along the diagonal from (i, j + 1) to
    (i + 1, j), as ``grid_faces`` does), so a feature offset by it sits on the mesh."""
    s, t, f = grid
    sq = np.asarray(sq, dtype=np.float64)
    tq = np.mod(np.asarray(tq, dtype=np.float64), per)
    i = np.clip(np.searchsorted(s, sq, side="right") - 1, 0, len(s) - 2)
    j = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, len(t) - 1)
    j1 = (j + 1) % len(t)
    t_hi = np.where(j1 == 0, per, t[j1])
    u = np.clip((sq - s[i]) / (s[i + 1] - s[i]), 0.0, 1.0)
    v = np.clip((tq - t[j]) / (t_hi - t[j]), 0.0, 1.0)
    fa, fb, fc, fd = f[i, j], f[i, j1], f[i + 1, j], f[i + 1, j1]
    lower = fa + u * (fc - fa) + v * (fb - fa)
    upper = fd + (1 - u) * (fb - fd) + (1 - v) * (fc - fd)
    return np.asarray(np.where(u + v <= 1.0, lower, upper), dtype=np.float64)


def _lining(b: _Builder, tun: _Tunnel, s: Floats, t: Floats,
            recesses: Sequence[_Recess], features: Sequence[F.Feature],
            relief: Floats, closed_ends: bool) -> None:
    """The lining grid (rings at chainages ``s`` x profile parameters ``t``): vertices
    pushed into recesses and by the surface ``relief`` (nr, k), faces labelled per cell,
    and the fan caps of closed ends."""
    alignment, profile, c0, c1 = tun.alignment, tun.profile, tun.c0, tun.c1
    per, e, tol = profile.perimeter_m, RECESS_EDGE_M, _GRID_TOL_M
    k, nr = len(t), len(s)
    n2 = profile.normals(t)                    # (k, 2) outward vertex normals
    yz = np.broadcast_to(profile.points(t), (nr, k, 2)).copy()
    push = np.zeros((nr, k))
    for s0, s1, t0, w, depth, _ in recesses:
        rows = (s >= s0 + e - tol) & (s <= s1 - e + tol)
        rel = _rel(t, t0, per)
        cols = (rel >= e - tol) & (rel <= w - e + tol)
        push[np.ix_(rows, cols)] += depth
    push += relief
    yz += push[:, :, None] * n2[None, :, :]
    verts = alignment.to_world(s[:, None], yz[..., 0], yz[..., 1]).reshape(-1, 3)
    faces = grid_faces(nr, k, 0, outward=False)
    # Labels per grid cell (ring interval x profile interval), same for both triangles.
    sm = 0.5 * (s[:-1] + s[1:])
    tm = 0.5 * (t + np.append(t[1:], per))
    cell = np.where(profile.is_floor(tm), LABEL["floor"], LABEL["lining"])
    cell = np.broadcast_to(cell, (nr - 1, k)).astype(np.uint8)
    for f in features:
        if isinstance(f, F.WetFloor):
            rows = (sm > f.start_m) & (sm < f.end_m)
            cell[rows] = np.where(cell[rows] == LABEL["floor"], LABEL["wet_floor"],
                                  cell[rows])
    for s0, s1, t0, w, _, lab_r in recesses:
        rel = _rel(tm, t0, per)
        cell[np.ix_((sm > s0) & (sm < s1), (rel > 0) & (rel < w))] = lab_r
    lab = np.concatenate([cell.ravel(), cell.ravel()])
    b.add(verts, faces, lab, np.repeat(s, k), np.tile(t, nr))
    if closed_ends:
        cy, cz = profile.centroid
        caps = alignment.to_world(np.array([c0, c1]), cy, cz)
        n0 = nr * k
        ring0, ring1 = np.arange(k), (nr - 1) * k + np.arange(k)
        b.v[-1] = np.concatenate([verts, caps])
        b.s[-1] = np.concatenate([b.s[-1], [c0, c1]])
        b.t[-1] = np.concatenate([b.t[-1], [np.nan, np.nan]])
        cap_f = np.concatenate([fan_faces(n0, ring0, True), fan_faces(n0 + 1, ring1, False)])
        b.f[-1] = np.concatenate([b.f[-1], cap_f])
        b.lab[-1] = np.concatenate([lab, np.full(len(cap_f), LABEL["end_cap"], np.uint8)])
        b.n += 2


def _cable(b: _Builder, tun: _Tunnel, f: F.Cable, grid: _Grid) -> None:
    """A closed polygonal tube along the rings of the lining, ``gap_m`` clear of the
    relieved surface at its profile point on every ring, capped at both ends."""
    profile, alignment, tol = tun.profile, tun.alignment, _GRID_TOL_M
    a, bb = _span(f, tun)
    tc = profile.t_at_height(f.side, f.height_m)
    p, n = profile.points(tc), profile.normals(tc)
    rs = grid.s[(grid.s >= a - tol) & (grid.s <= bb + tol)]
    lift = _on_grid(grid, profile.perimeter_m, rs, np.full(len(rs), tc))
    centre = p[None] - n[None] * (f.gap_m + f.radius_m - lift)[:, None]    # (nr, 2)
    phi = 2 * np.pi * np.arange(int(f.sides)) / int(f.sides)
    ring = centre[:, None] + f.radius_m * np.stack([np.cos(phi), np.sin(phi)], 1)[None]
    m = ring.shape[1]
    cv = alignment.to_world(rs[:, None], ring[..., 0], ring[..., 1])
    cc = alignment.to_world(rs[[0, -1]], centre[[0, -1], 0], centre[[0, -1], 1])
    verts_c = np.concatenate([cv.reshape(-1, 3), cc])
    nc = len(rs) * m
    fc = np.concatenate([grid_faces(len(rs), m, 0, outward=True),
                         fan_faces(nc, np.arange(m), False),
                         fan_faces(nc + 1, (len(rs) - 1) * m + np.arange(m), True)])
    b.add(verts_c, fc, LABEL["cable"], np.concatenate([np.repeat(rs, m), [rs[0], rs[-1]]]),
          tc)


def _embedded_boxes(tun: _Tunnel, grid: _Grid, tc: float, sc: Floats, size: float,
                    height: float) -> tuple[Floats, Floats]:
    """World corners (m, 8, 3) of boxes ``size`` wide (along the tunnel and the
    profile) standing ``height`` proud of the relieved lining points at (sc (m,), tc),
    and those points' relief (m,). Each box's back reaches ``_EMBED_M`` behind the
    highest point of the relief under its footprint, so no gap opens under it."""
    p, n = tun.profile.points(tc), tun.profile.normals(tc)
    tau = np.array([-n[1], n[0]])            # direction of increasing t
    per = tun.profile.perimeter_m
    sc = np.asarray(sc, dtype=np.float64)
    lift = _on_grid(grid, per, sc, np.full(len(sc), tc))
    # The footprint sampled 5 x 5 (the grid's relief is piecewise linear; its maximum
    # between samples exceeds theirs by a fraction of a millimetre at 0.1 m edges).
    off = np.linspace(-0.5, 0.5, 5) * size
    under = _on_grid(grid, per, sc[:, None, None] + off[None, :, None],
                     np.broadcast_to(tc + off[None, None, :], (len(sc), 5, 5)))
    embed = under.reshape(len(sc), -1).max(axis=1) - lift + _EMBED_M
    x, u, w = _CUBE_V.T
    sl = sc[:, None] + (x - 0.5)[None] * size                              # (m, 8)
    depth = lift[:, None] - (w[None] * (height + embed[:, None]) - embed[:, None])
    lat = p + ((u - 0.5) * size)[None, :, None] * tau + depth[..., None] * n
    return tun.alignment.to_world(sl, lat[..., 0], lat[..., 1]), lift


def _add_boxes(b: _Builder, boxes: Floats, label: int, sc: Floats, tc: float) -> None:
    """Add boxes (m, 8, 3) as one part, each attached to the lining at (sc[i], tc)."""
    m = len(boxes)
    faces = (_CUBE_F[None] + 8 * np.arange(m)[:, None, None]).reshape(-1, 3)
    b.add(boxes.reshape(-1, 3), faces, label, np.repeat(sc, 8), tc)


def _bolts(b: _Builder, tun: _Tunnel, f: F.Bolts, grid: _Grid,
           in_niche: Callable[[float, float, float], bool]) -> None:
    """Bolt bearing plates: boxes every ``spacing_m`` at each angle (none in niches)."""
    a, bb = _span(f, tun)
    chain = np.arange(a + f.spacing_m / 2, bb - f.plate_m / 2, f.spacing_m)
    for ang in f.angles_rad:
        tb = tun.profile.t_at_angle(ang)
        sb = np.array([c for c in chain if not in_niche(c, tb, f.plate_m)])
        if len(sb):
            boxes, _ = _embedded_boxes(tun, grid, tb, sb, f.plate_m, f.thickness_m)
            _add_boxes(b, boxes, LABEL["bolt"], sb, tb)


def _prisms(b: _Builder, tun: _Tunnel, f: F.Prisms, grid: _Grid,
            in_niche: Callable[[float, float, float], bool],
            control: list[dict[str, Any]]) -> None:
    """Prisms (a sphere on a stalk ``standoff_m`` long, standing on the relieved
    lining) per cross-section and angle; their centres are appended to ``control`` as
    control points."""
    c0, c1, profile, alignment = tun.c0, tun.c1, tun.profile, tun.alignment
    sph_v, sph_f = icosphere(1, f.radius_m)
    for sc in f.chainages_m:
        if not (c0 <= sc <= c1):
            raise TunnelError(f"Expected prism chainages within [{c0:g}, {c1:g}] "
                              f"m, got {sc:g}.")
        for ang in f.angles_rad:
            tp = profile.t_at_angle(ang)
            if in_niche(sc, tp, 0.05):
                raise TunnelError(f"Expected prisms outside niches, got one at "
                                  f"chainage {sc:g} m, angle {ang:g} rad.")
            stalk, lifts = _embedded_boxes(tun, grid, tp, np.array([sc]), _STALK_M,
                                           f.standoff_m)
            lift = float(lifts[0])
            p, n = profile.points(tp), profile.normals(tp)
            ctr = p + n * (lift - f.standoff_m)
            cw = alignment.to_world(sc, ctr[0], ctr[1])
            b.add(cw + sph_v, sph_f, LABEL["prism"], sc, tp)
            b.add(stalk[0], _CUBE_F, LABEL["prism"], sc, tp)
            th = alignment.heading(sc)
            nw = [float(-n[0] * np.sin(th)), float(n[0] * np.cos(th)), float(n[1])]
            control.append({"id": f"P{len(control) + 1:03d}", "chainage_m": sc,
                            "angle_rad": ang, "profile_t_m": float(tp),
                            "xyz": cw.tolist(), "lining_normal": nw, "relief_m": lift})


def _solids(b: _Builder, tun: _Tunnel, features: Sequence[F.Feature], grid: _Grid,
            recesses: Sequence[_Recess]) -> list[dict[str, Any]]:
    """Cables, bolt plates and prisms as closed solids, in the order given; returns the
    control points (the prism centres)."""
    per = tun.profile.perimeter_m
    niches = [(r.s0, r.s1, r.t0, r.width) for r in recesses if r.label == LABEL["niche"]]

    def in_niche(sv: float, tv: float, margin: float) -> bool:
        return any(a - margin < sv < bb + margin and
                   _rel(tv, t0 - margin, per) < w + 2 * margin
                   for a, bb, t0, w in niches)

    control: list[dict[str, Any]] = []
    for f in features:
        if isinstance(f, F.Cable):
            _cable(b, tun, f, grid)
        elif isinstance(f, F.Bolts):
            _bolts(b, tun, f, grid, in_niche)
        elif isinstance(f, F.Prisms):
            _prisms(b, tun, f, grid, in_niche, control)
    return control


def make_tunnel(alignment: Alignment, profile: Profile, *, edge_length_m: float = 0.1,
                features: Iterable[F.Feature] = (), roughness_rms_m: float | None = None,
                roughness_corr_m: float | None = None, relief: RockRelief | None = None,
                closed_ends: bool = False, seed: int = 0, name: str = "tunnel"
                ) -> TunnelMesh:
    """Generate a tunnel mesh.

    Parameters
    ----------
    alignment : Alignment
        Centreline; the mesh spans its whole chainage range.
    profile : Profile
        Cross-section in (left offset, height above the alignment), metres.
    edge_length_m : float
        Target edge length of the lining grid (see ``edge_length_for``).
    features : sequence
        ``Cable``, ``Niche``, ``Drainage``, ``WetFloor``, ``Bolts``, ``Prisms``.
    roughness_rms_m, roughness_corr_m : float or None
        Lining roughness, the fine texture everywhere (standard deviation, correlation
        length); 0 for a smooth lining. None: the relief's ``texture_rms_m`` /
        ``texture_corr_m`` when ``relief`` is given, else 0.002 m / 0.3 m (a smooth
        segmental or shotcrete lining). Values given replace the relief's texture.
    relief : RockRelief or None
        Drill-and-blast overbreak on top of the roughness (``survey.world.rock``);
        None for a smooth lining.
    closed_ends : bool
        Cap both portals (watertight) instead of leaving them open.
    seed : int
        Seed of the roughness and relief fields (>= 0).
    name : str
        Recorded in the metadata.

    Returns
    -------
    TunnelMesh
    """
    features = list(features)
    # DECISION: roughness and relief add up (texture + overbreak); the roughness is the
    # texture layer of the rock relief, so a relief brings its own unless one is given,
    # and the texture of a given seed is the same surface with or without the relief.
    if roughness_rms_m is None:
        roughness_rms_m = relief.texture_rms_m if isinstance(relief, RockRelief) else 0.002
    if roughness_corr_m is None:
        roughness_corr_m = relief.texture_corr_m if isinstance(relief, RockRelief) else 0.3
    h = _check_parameters(alignment, profile, edge_length_m, roughness_rms_m,
                          roughness_corr_m, features, relief)
    c0, c1 = alignment.chainage_range
    reach = ROUGHNESS_CLIP * roughness_rms_m + (0.0 if relief is None
                                                else relief.overbreak_max_m)
    tun = _Tunnel(alignment, profile, c0, c1, reach)
    recesses, s_breaks, t_breaks = _plan_recesses(tun, features, closed_ends)
    _check_fit(tun, recesses, closed_ends)
    s = _fill(s_breaks, h)
    t = profile.sample(h, breaks=t_breaks)
    grid = _Grid(s, t, surface_relief(profile, s, t, c0, c1, texture_rms_m=roughness_rms_m,
                                      texture_corr_m=roughness_corr_m, relief=relief,
                                      seed=seed))
    b = _Builder()
    _lining(b, tun, s, t, recesses, features, grid.relief, closed_ends)
    control = _solids(b, tun, features, grid, recesses)
    verts, faces, labels, vs, vt = b.result()
    counts = np.bincount(labels, minlength=len(LABELS))
    meta = {
        "name": name,
        "alignment": alignment.to_dict(),
        "profile": profile.to_dict(),
        "features": [F.to_dict(f) for f in features],
        "parameters": {"edge_length_m": h, "roughness_rms_m": roughness_rms_m,
                       "roughness_corr_m": roughness_corr_m,
                       "roughness_clip_sigma": ROUGHNESS_CLIP, "closed_ends": closed_ends,
                       "seed": int(seed), "recess_edge_m": RECESS_EDGE_M,
                       "relief": None if relief is None else relief.to_dict(),
                       "relief_reach_m": reach},
        "labels": {str(i): n for i, n in enumerate(LABELS)},
        "reflectivity": dict(REFLECTIVITY),
        "face_counts": {n: int(c) for n, c in zip(LABELS, counts) if c},
        "n_vertices": int(len(verts)), "n_faces": int(len(faces)),
        "bounds": [verts.min(axis=0).tolist(), verts.max(axis=0).tolist()],
        "control_points": control,
    }
    return TunnelMesh(verts, faces, labels, vs, vt, alignment, profile, meta)
