"""Parametric tunnel generator: alignment x profile x features -> labelled triangle mesh.

The lining is a structured grid swept along the alignment: rings at chainages s_i, each
the profile sampled at parameters t_j (``Profile.sample``), placed in the vertical
cross-section of the alignment at s_i (``Alignment.to_world``). Every grid vertex sits on
the design profile, then moves along the profile's outward normal by

- a recess depth inside a niche or drainage channel (the recess walls are one
  ``RECESS_EDGE_M`` wide ring/column of the grid: near-vertical, never degenerate), and
- the lining roughness: a stationary Gaussian random field with Gaussian
  autocorrelation exp(-d^2 / (2 L^2)) over the developed lining (chainage, t), made by
  smoothing white noise on a fixed grid (L/4 cells) with a Gaussian kernel of standard
  deviation L / sqrt(2), then interpolated to the vertices; it is independent of the
  mesh resolution for a given seed, scaled to ``roughness_rms_m`` and clipped at
  ``ROUGHNESS_CLIP`` standard deviations.

Cables, bolt plates and prisms are separate closed solids. Faces of the lining point
into the tunnel (towards a scanner); faces of the closed solids point out of them.
Everything is vectorised NumPy: a 1M-triangle tunnel takes seconds.
"""

from __future__ import annotations


import numpy as np

from raytrace.shapes import icosphere

from survey.world import features as F
from survey.world.alignment import Alignment
from survey.world.profiles import Profile
from survey.errors import TunnelError
from survey.world.mesh import LABEL, LABELS, REFLECTIVITY, TunnelMesh


#: Width of the sloping wall of a recess (niche sides, sill and lintel; channel banks).
RECESS_EDGE_M = 0.02
#: Roughness is clipped at this many standard deviations (so it is bounded).
ROUGHNESS_CLIP = 3.5
#: Largest mesh the generator will build (guards against a mistyped edge length).
MAX_TRIANGLES = 60_000_000
#: Sides of the stalk of a prism and its cross-section (m).
_STALK_M = 0.012


# Unit cube, vertex v = x + 2 y + 4 z, faces wound outward (right-handed frame).
_CUBE_V = np.array([[(v >> 0) & 1, (v >> 1) & 1, (v >> 2) & 1] for v in range(8)], float)
_CUBE_F = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                    [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]])


def edge_length_for(n_triangles: int, profile: Profile, length_m: float) -> float:
    """Edge length that gives about ``n_triangles`` lining triangles (2 per square cell
    of the developed lining, perimeter x length)."""
    n = int(n_triangles)
    if n < 100:
        raise TunnelError(f"Expected at least 100 triangles, got {n}.")
    return float(np.sqrt(2.0 * profile.perimeter_m * length_m / n))


def _fill(breaks, spacing):
    """Sorted unique break points, each interval split evenly (pieces <= spacing)."""
    b = np.unique(np.asarray(breaks, dtype=np.float64))
    b = b[np.concatenate([[True], np.diff(b) > 1e-6])]
    n = np.maximum(1, np.ceil(np.diff(b) / spacing - 1e-9).astype(np.int64))
    start = np.repeat(b[:-1], n)
    step = np.repeat(np.diff(b) / n, n)
    k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    return np.append(start + k * step, b[-1])


def _roughness(s, t, s0, length, perimeter, rms, corr, seed):
    """Roughness field (len(s), len(t)) on the ring x profile grid (see module doc)."""
    from scipy.ndimage import gaussian_filter, map_coordinates

    g = corr / 4.0
    ns = int(np.ceil(length / g)) + 1
    nt = max(8, int(np.ceil(perimeter / g)))
    gs, gt = length / (ns - 1), perimeter / nt
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((ns, nt))
    sig = corr / np.sqrt(2.0)
    fld = gaussian_filter(noise, (sig / gs, sig / gt), mode=("nearest", "wrap"))
    fld /= max(fld.std(), 1e-300)
    fld = np.concatenate([fld, fld[:, :1]], axis=1)  # periodic in t
    ii = np.broadcast_to(((s - s0) / gs)[:, None], (len(s), len(t)))
    jj = np.broadcast_to((t / gt)[None, :], (len(s), len(t)))
    out = map_coordinates(fld, [ii.ravel(), jj.ravel()], order=1, mode="nearest")
    out = out.reshape(len(s), len(t)) * rms
    return np.clip(out, -ROUGHNESS_CLIP * rms, ROUGHNESS_CLIP * rms)


def _rel(t, t0, per):
    """Parameter distance from t0 going counter-clockwise, in [0, per)."""
    return np.mod(np.asarray(t, dtype=np.float64) - t0, per)


def _arc_between(profile, ta, tb, wanted):
    """(start, length) of the profile arc between parameters ta and tb whose midpoint
    satisfies ``wanted`` (of the two arcs a pair of points splits a closed curve into)."""
    per = profile.perimeter_m
    lo, hi = sorted((ta % per, tb % per))
    if wanted(0.5 * (lo + hi)):
        return lo, hi - lo
    return hi, lo + per - hi


def grid_faces(rings, k, first, outward):
    """Faces of a closed-around tube grid of ``rings`` x ``k`` vertices starting at
    vertex ``first``; ``outward`` flips the winding (solids) from the lining's
    inward-facing one."""
    i = np.arange(rings - 1)[:, None] * k
    j = np.arange(k)[None, :]
    a = (first + i + j).ravel()
    b = (first + i + (j + 1) % k).ravel()
    c, d = a + k, b + k
    if outward:
        return np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    return np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])


def fan_faces(centre, ring, forward):
    nxt = np.roll(ring, -1)
    c = np.full(len(ring), centre)
    return np.stack([c, ring, nxt] if forward else [c, nxt, ring], 1)


class _Builder:
    """Collects mesh parts in local (chainage, offset, height) or world coordinates."""

    def __init__(self, alignment):
        self.al = alignment
        self.v, self.f, self.lab, self.s, self.t = [], [], [], [], []
        self.n = 0

    def add(self, verts, faces, labels, s, t):
        self.v.append(verts)
        self.f.append(faces + self.n)
        self.lab.append(np.broadcast_to(np.asarray(labels, np.uint8), (len(faces),)))
        self.s.append(np.broadcast_to(np.asarray(s, float), (len(verts),)))
        self.t.append(np.broadcast_to(np.asarray(t, float), (len(verts),)))
        self.n += len(verts)

    def world(self, s, y, z):
        """World points for local coordinates (broadcast), via the alignment frame."""
        return self.al.to_world(s, y, z)

    def result(self):
        return (np.concatenate(self.v), np.concatenate(self.f).astype(np.int64),
                np.concatenate(self.lab), np.concatenate(self.s), np.concatenate(self.t))


def make_tunnel(alignment: Alignment, profile: Profile, *, edge_length_m: float = 0.1,
                features=(), roughness_rms_m: float = 0.002, roughness_corr_m: float = 0.3,
                closed_ends: bool = False, seed: int = 0, name: str = "tunnel"
                ) -> TunnelMesh:
    """Generate a tunnel mesh.

    Parameters
    ----------
    alignment : Alignment
        Centreline; the mesh spans its whole chainage range.
    profile : Profile
        Cross-section in (left offset, height above the alignment).
    edge_length_m : float
        Target edge length of the lining grid (see ``edge_length_for``).
    features : sequence
        ``Cable``, ``Niche``, ``Drainage``, ``WetFloor``, ``Bolts``, ``Prisms``.
    roughness_rms_m, roughness_corr_m : float
        Lining roughness (standard deviation, correlation length); 0 for a smooth lining.
    closed_ends : bool
        Cap both portals (watertight) instead of leaving them open.
    seed : int
        Seed of the roughness field.

    Returns
    -------
    TunnelMesh
    """
    if not isinstance(alignment, Alignment) or not isinstance(profile, Profile):
        raise TunnelError(f"Expected an Alignment and a Profile, got "
                          f"{type(alignment).__name__} and {type(profile).__name__}.")
    h = float(edge_length_m)
    if not (np.isfinite(h) and h > 0):
        raise TunnelError(f"Expected a positive `edge_length_m`, got {edge_length_m}.")
    c0, c1 = alignment.chainage_range
    length = c1 - c0
    est = 2.0 * profile.perimeter_m * length / (h * h)
    if est > MAX_TRIANGLES:
        raise TunnelError(f"Expected at most {MAX_TRIANGLES:,} triangles, got about "
                          f"{est:,.0f} for edge_length_m={h}; use a larger edge length.")
    for name_, v in (("roughness_rms_m", roughness_rms_m),
                     ("roughness_corr_m", roughness_corr_m)):
        if not (np.isfinite(v) and v >= 0):
            raise TunnelError(f"Expected `{name_}` >= 0, got {v}.")
    if roughness_rms_m > 0 and roughness_corr_m <= 0:
        raise TunnelError("Expected a positive `roughness_corr_m` with roughness, got 0.")
    features = list(features)
    for f in features:
        if type(f) not in F.KINDS.values():
            raise TunnelError(f"Expected features from survey.world.features, got "
                              f"{type(f).__name__}.")
    per = profile.perimeter_m
    e = RECESS_EDGE_M

    def span(f):
        a = c0 if f.start_m is None else f.start_m
        b = c1 if f.end_m is None else f.end_m
        if a < c0 - 1e-9 or b > c1 + 1e-9:
            raise TunnelError(f"Expected {type(f).__name__} chainages within the tunnel "
                              f"[{c0:g}, {c1:g}] m, got [{a:g}, {b:g}].")
        return a, b

    # Recesses: rectangles in (s, t) with their depth.
    recesses = []  # (s0, s1, t0, t1, depth, label)
    s_breaks, t_breaks = [c0, c1], []
    for f in features:
        if isinstance(f, F.Niche):
            a, b = span(f)
            ta = profile.t_at_height(f.side, f.bottom_m)
            tb = profile.t_at_height(f.side, f.top_m)
            sgn = 1.0 if f.side == "left" else -1.0
            t0, w = _arc_between(profile, ta, tb,
                                 lambda tm: sgn * profile.points(tm)[0] > 0)
            recesses.append((a, b, t0, w, f.depth_m, LABEL["niche"]))
        elif isinstance(f, F.Drainage):
            a, b = span(f)
            ta = profile.t_at_floor_offset(f.offset_m - f.width_m / 2)
            tb = profile.t_at_floor_offset(f.offset_m + f.width_m / 2)
            t0, w = _arc_between(profile, ta, tb, profile.is_floor)
            if not profile.is_floor(t0 + w / 2):
                raise TunnelError(f"Expected the drainage channel on the floor, got offset "
                                  f"{f.offset_m} m which is not on a floor piece.")
            recesses.append((a, b, t0, w, f.depth_m, LABEL["drainage"]))
        elif isinstance(f, (F.WetFloor, F.Cable)):
            s_breaks += list(span(f))
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

    # A curve tighter than the tunnel is wide folds the lining on its inner side.
    left, right, _, _ = profile.extent()
    reach = max((r[4] for r in recesses), default=0.0) + ROUGHNESS_CLIP * roughness_rms_m
    r_left, r_right = alignment.min_radius()
    for side, ext, rad, sgn in (("left", left, r_left, 1), ("right", right, r_right, -1)):
        if ext + reach >= rad:
            where = alignment.chainage_of_curvature(sgn / rad)
            raise TunnelError(f"Expected curve radii larger than the tunnel's {side} "
                              f"half-width ({ext + reach:.3f} m), got a {side}-hand radius "
                              f"of {rad:.3f} m near chainage {where:g} m; the lining would "
                              "fold on the inside of the curve.")
    if closed_ends and not profile.star_shaped_about_centroid():
        raise TunnelError("Expected a profile star-shaped about its centroid for closed "
                          "ends (fan caps), got one that is not; leave the ends open.")

    # ---- lining grid
    s = _fill(s_breaks, h)
    t = profile.sample(h, breaks=t_breaks)
    k, nr = len(t), len(s)
    n2 = profile.normals(t)                    # (k, 2) outward vertex normals
    yz = np.broadcast_to(profile.points(t), (nr, k, 2)).copy()
    push = np.zeros((nr, k))
    tol = 1e-7
    for s0, s1, t0, w, depth, _ in recesses:
        rows = (s >= s0 + e - tol) & (s <= s1 - e + tol)
        rel = _rel(t, t0, per)
        cols = (rel >= e - tol) & (rel <= w - e + tol)
        push[np.ix_(rows, cols)] += depth
    if roughness_rms_m > 0:
        push += _roughness(s, t, c0, length, per, roughness_rms_m, roughness_corr_m, seed)
    yz += push[:, :, None] * n2[None, :, :]
    b = _Builder(alignment)
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
    for s0, s1, t0, w, _, lab in recesses:
        rel = _rel(tm, t0, per)
        cell[np.ix_((sm > s0) & (sm < s1), (rel > 0) & (rel < w))] = lab
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

    # ---- closed solids
    control = []
    niches = [(r[0], r[1], r[2], r[3]) for r in recesses if r[5] == LABEL["niche"]]

    def in_niche(sv, tv, margin):
        return any(a - margin < sv < bb + margin and
                   _rel(tv, t0 - margin, per) < w + 2 * margin
                   for a, bb, t0, w in niches)

    for f in features:
        if isinstance(f, F.Cable):
            a, bb = span(f)
            tc = profile.t_at_height(f.side, f.height_m)
            p, n = profile.points(tc), profile.normals(tc)
            centre = p - n * (f.gap_m + f.radius_m)
            phi = 2 * np.pi * np.arange(int(f.sides)) / int(f.sides)
            ring = centre + f.radius_m * np.stack([np.cos(phi), np.sin(phi)], 1)
            rs = s[(s >= a - tol) & (s <= bb + tol)]
            m = len(ring)
            cv = alignment.to_world(rs[:, None], ring[None, :, 0], ring[None, :, 1])
            cc = alignment.to_world(np.array([rs[0], rs[-1]]), centre[0], centre[1])
            verts_c = np.concatenate([cv.reshape(-1, 3), cc])
            nc = len(rs) * m
            fc = np.concatenate([grid_faces(len(rs), m, 0, outward=True),
                                 fan_faces(nc, np.arange(m), False),
                                 fan_faces(nc + 1, (len(rs) - 1) * m + np.arange(m), True)])
            b.add(verts_c, fc, LABEL["cable"],
                  np.concatenate([np.repeat(rs, m), [rs[0], rs[-1]]]), tc)
        elif isinstance(f, F.Bolts):
            a, bb = span(f)
            chain = np.arange(a + f.spacing_m / 2, bb - f.plate_m / 2, f.spacing_m)
            for ang in f.angles_rad:
                tb = profile.t_at_angle(ang)
                p, n = profile.points(tb), profile.normals(tb)
                tau = np.array([-n[1], n[0]])
                embed = ROUGHNESS_CLIP * roughness_rms_m + 0.005
                for sb in chain:
                    if in_niche(sb, tb, f.plate_m):
                        continue
                    x, u, w = _CUBE_V.T
                    sl = sb + (x - 0.5) * f.plate_m
                    lat = p[None] + ((u - 0.5) * f.plate_m)[:, None] * tau - \
                        (w * (f.thickness_m + embed) - embed)[:, None] * n
                    b.add(alignment.to_world(sl, lat[:, 0], lat[:, 1]), _CUBE_F,
                          LABEL["bolt"], sb, tb)
        elif isinstance(f, F.Prisms):
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
                    p, n = profile.points(tp), profile.normals(tp)
                    tau = np.array([-n[1], n[0]])
                    ctr = p - n * f.standoff_m
                    cw = alignment.to_world(sc, ctr[0], ctr[1])
                    b.add(cw + sph_v, sph_f, LABEL["prism"], sc, tp)
                    embed = ROUGHNESS_CLIP * roughness_rms_m + 0.005
                    x, u, w = _CUBE_V.T
                    sl = sc + (x - 0.5) * _STALK_M
                    lat = p[None] + ((u - 0.5) * _STALK_M)[:, None] * tau - \
                        (w * (f.standoff_m + embed) - embed)[:, None] * n
                    b.add(alignment.to_world(sl, lat[:, 0], lat[:, 1]), _CUBE_F,
                          LABEL["prism"], sc, tp)
                    th = alignment.heading(sc)
                    nw = [float(-n[0] * np.sin(th)), float(n[0] * np.cos(th)), float(n[1])]
                    control.append({"id": f"P{len(control) + 1:03d}", "chainage_m": sc,
                                    "angle_rad": ang, "profile_t_m": float(tp),
                                    "xyz": cw.tolist(), "lining_normal": nw})

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
                       "seed": int(seed), "recess_edge_m": e},
        "labels": {str(i): n for i, n in enumerate(LABELS)},
        "reflectivity": dict(REFLECTIVITY),
        "face_counts": {n: int(c) for n, c in zip(LABELS, counts) if c},
        "n_vertices": int(len(verts)), "n_faces": int(len(faces)),
        "bounds": [verts.min(axis=0).tolist(), verts.max(axis=0).tolist()],
        "control_points": control,
    }
    return TunnelMesh(verts, faces, labels, vs, vt, alignment, profile, meta)
