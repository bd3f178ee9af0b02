"""Tunnels with a junction: a straight branch gallery meeting the main one at right angles.

Construction (a groin: the mitre joint of two equal galleries). The main gallery's
lining occupies, in the local frame of its alignment at the junction chainage
(x along the axis, y to the left, z up), the region |y| <= w(z), where w(z) is the
half-width of a profile symmetric about its vertical axis whose horizontal slices are
single intervals (horseshoe, arched rectangle, circle). A branch with the same profile
leaving to the left along +y occupies y >= 0, |x| <= w(z). A main wall point (x, w, z) is
inside the branch where |x| < w, and a branch wall point (+-w, y, z) inside the main
where y < w: the two surfaces meet exactly in the vertical diagonal planes y = |x|, the
groins of a cross vault where two equal barrel vaults meet at right angles (e.g. Heyman,
*The Stone Skeleton*, 1995, ch. 4; the mitre joint of equal pipes is the same plane cut).
A profile sample (w, z) of the junction-side half therefore lies on the groin at
(-w, w, z) and at (w, w, z), for the main and the branch alike, and the mesh is built
without any surface intersection:

- the main lining is the generator's structured grid (rings x profile samples) except
  where the junction-side half of a ring lies inside the branch (``block_m`` either side
  of the junction); there each profile column of the main's junction side runs from the
  block's end ring to its groin point, and the branch's columns run from the same groin
  points out to the branch portal;
- consecutive columns of unequal length are joined by a zipper: two chains of vertices
  ordered along the gallery, triangulated by always advancing the chain whose next
  vertex is nearer (the "merge" triangulation of two contours; Fuchs, Kedem & Uselton
  1977 solve it optimally, the greedy merge is enough for chains that both follow the
  ring grid). Groin points are shared vertices, so the seam is closed by construction:
  every edge has two faces except along the portals' rings.

Then every vertex moves along its design normal (the profile's outward normal in its
gallery's cross-section; on the groin the mean of the two galleries') by the lining
roughness: a stationary Gaussian field over space with autocorrelation
exp(-d^2 / (2 L^2)) (the texture of ``survey.world.rock``), made as a sum of random
cosines (the spectral representation, Shinozuka & Deodatis 1991), clipped at
``ROUGHNESS_CLIP`` standard deviations. It is a field of position, so the groin, which
the rock texture's (chainage, profile) grid cannot describe, is as rough as the walls.
Faces of the lining point into the tunnel, as ``make_tunnel``'s do.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from survey.errors import TunnelError
from survey.world.alignment import Alignment, straight
from survey.world.generator import MAX_TRIANGLES, ROUGHNESS_CLIP, fan_faces, grid_faces
from survey.world.mesh import LABEL, LABELS, REFLECTIVITY, TunnelMesh
from survey.world.profiles import Profile

__all__ = ["Branch", "ROUGHNESS_MODES", "branch_alignment", "make_junction_tunnel"]

Floats = NDArray[np.float64]
Ints = NDArray[np.int64]

#: Random cosines in the roughness field (its one-point distribution is Gaussian to
#: within a few per cent from ~100 modes on).
ROUGHNESS_MODES = 256
#: Ring samples nearer than this fraction of the edge length to a groin point are
#: dropped from a column (they would give slivers).
_GROIN_GAP = 0.3
#: Profile samples of the two halves must mirror each other to this tolerance (m).
_SYMMETRY_TOL_M = 1e-9


@dataclass(frozen=True)
class Branch:
    """A straight branch gallery with the main gallery's profile, leaving the main
    alignment at right angles.

    Parameters
    ----------
    chainage_m : float
        Main chainage where the branch axis meets the main axis (m); the main gallery
        must be straight and level for its width either side of it.
    side : {"left", "right"}
        Side of the main gallery (looking up-chainage) the branch leaves on.
    length_m : float
        From the main axis to the branch portal (m), along the branch axis.
    """

    chainage_m: float
    side: str
    length_m: float

    def __post_init__(self) -> None:
        if self.side not in ("left", "right"):
            raise TunnelError(f"Expected the branch side 'left' or 'right', got "
                              f"{self.side!r}.")
        for name, v in (("chainage_m", self.chainage_m), ("length_m", self.length_m)):
            if not np.isfinite(v):
                raise TunnelError(f"Expected a finite branch `{name}`, got {v}.")
        if self.length_m <= 0:
            raise TunnelError(f"Expected a positive branch `length_m`, got "
                              f"{self.length_m}.")

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON-ready): chainage_m, side, length_m."""
        return {"chainage_m": float(self.chainage_m), "side": self.side,
                "length_m": float(self.length_m)}


def branch_alignment(main: Alignment, branch: Branch) -> Alignment:
    """The branch's own alignment: a level straight from the main axis point at
    ``branch.chainage_m`` (chainage 0) to its portal (``branch.length_m``)."""
    xy, th, _ = main.plan(np.array([branch.chainage_m]))
    sgn = 1.0 if branch.side == "left" else -1.0
    z = float(main.elevation(branch.chainage_m))
    return Alignment([straight(branch.length_m)], start_xy=xy[0],
                     heading_rad=float(th[0]) + sgn * np.pi / 2, profile=((0.0, z),))


def _fill(breaks: list[float], spacing: float) -> Floats:
    """Break points, each interval split evenly into pieces no longer than spacing."""
    parts = [np.linspace(a, b, max(1, int(np.ceil((b - a) / spacing - 1e-9))) + 1)[:-1]
             for a, b in zip(breaks[:-1], breaks[1:])]
    return np.append(np.concatenate(parts), breaks[-1])


def _ring(profile: Profile, h: float) -> tuple[Floats, int]:
    """Profile parameters (K,) of a ring that is mirror-symmetric: starting at the floor
    centre (index 0), counter-clockwise, the crown at index m; sample K - k mirrors k."""
    per = profile.perimeter_m
    t_fc = profile.t_at_floor_offset(0.0)
    t_cr = profile.t_at_angle(0.0)
    half = np.mod(t_cr - t_fc, per)
    t = profile.sample(h, breaks=[t_fc, t_cr])
    rel = np.mod(t - t_fc, per)
    left = np.sort(rel[rel <= half + 1e-9])
    left[-1] = half
    if left[0] > 1e-9:
        left = np.concatenate([[0.0], left])
    left[0] = 0.0
    right = per - left[-2:0:-1]
    ring = np.mod(t_fc + np.concatenate([left, right]), per)
    m = len(left) - 1
    p = profile.points(ring)
    k = np.arange(len(ring))
    mirror = p[(len(ring) - k) % len(ring)]
    err = np.abs(p[:, 0] + mirror[:, 0]).max() + np.abs(p[:, 1] - mirror[:, 1]).max()
    if err > _SYMMETRY_TOL_M or abs(p[0, 0]) > _SYMMETRY_TOL_M or \
            abs(p[m, 0]) > _SYMMETRY_TOL_M or not (p[1:m, 0] > 0).all():
        raise TunnelError(f"Expected a profile symmetric about its vertical axis for a "
                          f"junction, got {profile.name!r} (mirror error {err:.3g} m).")
    return ring, m


def _zip(a: Ints, au: Floats, b: Ints, bu: Floats) -> list[tuple[int, int, int]]:
    """Triangles between two chains of vertices a and b ordered by u (a is the lower
    profile column): counter-clockwise in (u, column), like ``grid_faces`` cells."""
    out = []
    i = j = 0
    na, nb = len(a) - 1, len(b) - 1
    while i < na or j < nb:
        if j == nb or (i < na and au[i + 1] <= bu[j + 1]):
            out.append((int(a[i]), int(a[i + 1]), int(b[j])))
            i += 1
        else:
            out.append((int(a[i]), int(b[j + 1]), int(b[j])))
            j += 1
    return out


def _check_site(main: Alignment, profile: Profile, branch: Branch, block: float,
                h: float) -> None:
    """The main gallery must be straight and level over the block, which must fit."""
    c0, c1 = main.chainage_range
    sj = float(branch.chainage_m)
    if not (c0 + block + h <= sj <= c1 - block - h):
        raise TunnelError(f"Expected the branch chainage within [{c0 + block + h:g}, "
                          f"{c1 - block - h:g}] m (the junction needs {block:g} m either "
                          f"side), got {sj:g} m.")
    ends = main.start_chainage_m + np.cumsum([e.length_m for e in main.elements])
    s = np.concatenate([np.linspace(sj - block, sj + block, 41),
                        ends[(ends > sj - block) & (ends < sj + block)]])
    _, _, kappa = main.plan(s)
    z = main.elevation(s)
    if np.abs(kappa).max() > 1e-12 or np.abs(z - z[0]).max() > 1e-9:
        raise TunnelError(f"Expected the main gallery straight and level within "
                          f"{block:g} m of the junction at {sj:g} m, got a curve or a "
                          "grade there; move the branch to a level straight.")
    if branch.length_m < block + h:
        raise TunnelError(f"Expected a branch longer than the junction block "
                          f"({block + h:.3g} m), got {branch.length_m:g} m.")


def _roughness(points: Floats, rms_m: float, corr_m: float, seed: int) -> Floats:
    """Gaussian field (n,) at points (n, 3): sqrt(2/N) sum cos(k.p + phi), k ~ N(0,
    I / L^2), phi ~ U(0, 2 pi), times rms_m (covariance rms^2 exp(-d^2 / (2 L^2));
    Shinozuka & Deodatis 1991), clipped at ROUGHNESS_CLIP rms."""
    if rms_m == 0 or len(points) == 0:
        return np.zeros(len(points))
    rng = np.random.default_rng(seed)
    k = rng.normal(0.0, 1.0 / corr_m, (ROUGHNESS_MODES, 3))
    phi = rng.uniform(0.0, 2 * np.pi, ROUGHNESS_MODES)
    out = np.empty(len(points))
    for a in range(0, len(points), 65536):       # bounded memory: (chunk, modes)
        p = points[a:a + 65536]
        out[a:a + 65536] = np.cos(p @ k.T + phi).sum(axis=1)
    out *= rms_m * np.sqrt(2.0 / ROUGHNESS_MODES)
    return np.clip(out, -ROUGHNESS_CLIP * rms_m, ROUGHNESS_CLIP * rms_m)


def _world_normals(al: Alignment, s: Floats, n2: Floats) -> Floats:
    """Outward profile normals n2 (..., 2) in the cross-sections at chainages s (...)."""
    th = al.heading(s)
    ny, nz = n2[..., 0], n2[..., 1]
    return np.stack(np.broadcast_arrays(-ny * np.sin(th), ny * np.cos(th), nz), -1)


def _check_parameters(main: Alignment, profile: Profile, branch: Branch, h: float,
                      rms: float, corr: float) -> None:
    if not isinstance(main, Alignment) or not isinstance(profile, Profile) or \
            not isinstance(branch, Branch):
        raise TunnelError(f"Expected an Alignment, a Profile and a Branch, got "
                          f"{type(main).__name__}, {type(profile).__name__} and "
                          f"{type(branch).__name__}.")
    if not (np.isfinite(h) and h > 0):
        raise TunnelError(f"Expected a positive `edge_length_m`, got {h}.")
    est = 2.0 * profile.perimeter_m * (main.length_m + branch.length_m) / (h * h)
    if est > MAX_TRIANGLES:
        raise TunnelError(f"Expected at most {MAX_TRIANGLES:,} triangles, got about "
                          f"{est:,.0f} for edge_length_m={h}; use a larger edge length.")
    if not (np.isfinite(rms) and rms >= 0 and np.isfinite(corr) and corr >= 0):
        raise TunnelError(f"Expected roughness_rms_m and roughness_corr_m >= 0, got "
                          f"{rms} and {corr}.")
    if rms > 0 and corr <= 0:
        raise TunnelError("Expected a positive `roughness_corr_m` with roughness, got 0.")
    left, right, _, _ = profile.extent()
    r_left, r_right = main.min_radius()
    reach = ROUGHNESS_CLIP * rms
    if left + reach >= r_left or right + reach >= r_right:
        raise TunnelError(f"Expected curve radii larger than the tunnel's half-width "
                          f"({max(left, right) + reach:.3f} m), got "
                          f"{min(r_left, r_right):.3f} m; the lining would fold on the "
                          "inside of the curve.")


def make_junction_tunnel(alignment: Alignment, profile: Profile, branch: Branch, *,
                         edge_length_m: float = 0.1, roughness_rms_m: float = 0.002,
                         roughness_corr_m: float = 0.3, closed_ends: bool = False,
                         seed: int = 0, name: str = "junction") -> TunnelMesh:
    """Generate a main gallery along ``alignment`` with a branch gallery (T-junction).

    Parameters
    ----------
    alignment : Alignment
        Main centreline (bends, grades allowed away from the junction).
    profile : Profile
        Cross-section of both galleries, symmetric about its vertical axis, each
        horizontal slice one interval (horseshoe, arched rectangle, circle).
    branch : Branch
        Where the branch leaves, to which side, how long.
    edge_length_m : float
        Target edge length of the lining (m).
    roughness_rms_m, roughness_corr_m : float
        Lining roughness: standard deviation and correlation length (m); 0 for smooth.
    closed_ends : bool
        Cap the three portals with fans (a watertight mesh).
    seed : int
        Seed of the roughness field.
    name : str
        Recorded in the metadata.

    Returns
    -------
    TunnelMesh
        ``alignment`` is the main one; ``metadata["branches"]`` holds, per branch, its
        ``chainage_m``, ``side``, ``length_m``, ``alignment`` (``Alignment.to_dict``)
        and ``centreline`` ((n, 3) points every metre, at the height of the profile's
        origin like the main alignment). Branch vertices have the junction's chainage
        and a NaN profile parameter (they are not on the main's cross-sections).
    """
    h = float(edge_length_m)
    rms, corr = float(roughness_rms_m), float(roughness_corr_m)
    _check_parameters(alignment, profile, branch, h, rms, corr)
    left_w, right_w, _, _ = profile.extent()
    block = max(left_w, right_w) + h                # groins lie within +-max width
    _check_site(alignment, profile, branch, block, h)
    sj = float(branch.chainage_m)
    c0, c1 = alignment.chainage_range
    bal = branch_alignment(alignment, branch)
    ring, m = _ring(profile, h)
    kk = len(ring)
    pyz = profile.points(ring)
    w = np.abs(pyz[:, 0])
    w[[0, m]] = 0.0
    # Columns of the junction side in increasing t (their strips are cut by the groin).
    side = list(range(0, m + 1)) if branch.side == "left" else list(range(m, kk)) + [0]
    strip_cut = np.zeros(kk, bool)
    strip_cut[side[:-1]] = True                     # strip k joins columns k and k + 1
    mirror = (kk - np.arange(kk)) % kk

    s = _fill([c0, sj - block, sj, sj + block, c1], h)
    i_a, i_0, i_b = (int(np.argmin(np.abs(s - v))) for v in (sj - block, sj, sj + block))
    nr = len(s)
    u = _fill([0.0, block, branch.length_m], h)[1:]
    u_a, nb = int(np.argmin(np.abs(u - block))), len(u)
    vm = alignment.to_world(s[:, None], pyz[None, :, 0], pyz[None, :, 1]).reshape(-1, 3)
    vb = bal.to_world(u[:, None], pyz[None, :, 0], pyz[None, :, 1]).reshape(-1, 3)
    n2 = profile.normals(ring)
    n_main = nr * kk
    verts = [vm, vb]
    # DECISION: roughness moves vertices along design normals, in their cross-section,
    # so that portals stay plane (vertex normals of the faces tilt at a curved portal).
    normals = [_world_normals(alignment, s[:, None], n2[None]).reshape(-1, 3),
               np.broadcast_to(_world_normals(bal, np.zeros(1), n2), (nb, kk, 3)
                               ).reshape(-1, 3)]
    vs = [np.repeat(s, kk), np.full(nb * kk, sj)]
    vt = [np.tile(ring, nr), np.full(nb * kk, np.nan)]
    nxt = n_main + nb * kk
    # Groin vertices: minus (arm towards lower chainage) and plus, per junction-side
    # column; the floor centre and the crown (w = 0) are the main's ring vertices at sj.
    groin_m, groin_p = np.full(kk, -1), np.full(kk, -1)
    for k in side:
        if w[k] == 0.0:
            groin_m[k] = groin_p[k] = i_0 * kk + k
            continue
        pts = alignment.to_world(np.array([sj - w[k], sj + w[k]]), pyz[k, 0], pyz[k, 1])
        verts.append(pts)
        both = _world_normals(alignment, np.full(1, sj), n2[k]) + \
            _world_normals(bal, np.zeros(1), n2[[k, mirror[k]]])
        normals.append(both / np.linalg.norm(both, axis=1, keepdims=True))
        vs.append(np.array([sj - w[k], sj + w[k]]))
        vt.append(np.full(2, ring[k]))
        groin_m[k], groin_p[k] = nxt, nxt + 1
        nxt += 2
    gap = _GROIN_GAP * h

    def main_chain(k: int, arm: int) -> tuple[Ints, Floats]:
        """Column k of the main on the arm before (-1) or after (+1) the junction."""
        x = s - sj
        cut = w[k] + (gap if w[k] > 0 else 0.0)
        if arm < 0:
            rows = np.arange(i_a, i_0 + 1)
            rows = rows[x[rows] < -cut]
            return (np.append(rows * kk + k, groin_m[k]),
                    np.append(x[rows], -w[k]))
        rows = np.arange(i_0, i_b + 1)
        rows = rows[x[rows] > cut]
        return np.insert(rows * kk + k, 0, groin_p[k]), np.insert(x[rows], 0, w[k])

    def branch_chain(k: int) -> tuple[Ints, Floats]:
        """Column k of the branch from its groin point to the ring at the block's end."""
        start = groin_m[k] if k in side else groin_p[mirror[k]]
        cut = w[k] + (gap if w[k] > 0 else 0.0)
        rows = np.arange(0, u_a + 1)
        rows = rows[u[rows] > cut]
        return (np.insert(n_main + rows * kk + k, 0, start), np.insert(u[rows], 0, w[k]))

    faces: list[Ints] = []
    strips: list[Ints] = []

    def add_grid(rings: int, first: int, keep: NDArray[np.bool_] | None = None) -> None:
        f = grid_faces(rings, kk, first, outward=False)
        st = np.tile(np.tile(np.arange(kk), rings - 1), 2)
        if keep is not None:
            sel = keep[st]
            f, st = f[sel], st[sel]
        faces.append(f)
        strips.append(st)

    add_grid(i_a + 1, 0)                                     # main, before the block
    add_grid(i_b - i_a + 1, i_a * kk, ~strip_cut)            # block, far side
    add_grid(nr - i_b, i_b * kk)                             # main, after the block
    add_grid(nb - u_a, n_main + u_a * kk)                    # branch, beyond the block
    zipped: list[tuple[int, int, int]] = []
    zstrip: list[int] = []
    for k in side[:-1]:
        for arm in (-1, 1):
            tri = _zip(*main_chain(k, arm), *main_chain((k + 1) % kk, arm))
            zipped += tri
            zstrip += [k] * len(tri)
    for k in range(kk):                                      # branch, inside the block
        tri = _zip(*branch_chain(k), *branch_chain((k + 1) % kk))
        zipped += tri
        zstrip += [k] * len(tri)
    faces.append(np.array(zipped, dtype=np.int64).reshape(-1, 3))
    strips.append(np.array(zstrip, dtype=np.int64))
    f_all = np.concatenate(faces)
    tm = np.mod(ring + 0.5 * np.mod(np.roll(ring, -1) - ring, profile.perimeter_m),
                profile.perimeter_m)
    strip_lab = np.where(profile.is_floor(tm), LABEL["floor"], LABEL["lining"])
    labels = strip_lab[np.concatenate(strips)].astype(np.uint8)
    if closed_ends:
        cy, cz = profile.centroid
        caps = np.concatenate([alignment.to_world(np.array([c0, c1]), cy, cz),
                               bal.to_world(np.array([branch.length_m]), cy, cz)])
        verts.append(caps)
        normals.append(np.zeros((3, 3)))                   # cap centres stay put
        vs.append(np.array([c0, c1, sj]))
        vt.append(np.full(3, np.nan))
        cap_f = np.concatenate([
            fan_faces(nxt, np.arange(kk), True),
            fan_faces(nxt + 1, (nr - 1) * kk + np.arange(kk), False),
            fan_faces(nxt + 2, n_main + (nb - 1) * kk + np.arange(kk), False)])
        f_all = np.concatenate([f_all, cap_f])
        labels = np.concatenate([labels, np.full(len(cap_f), LABEL["end_cap"], np.uint8)])
    v_all = np.concatenate(verts)
    # Drop the vertices inside the other gallery (never referenced), renumber.
    used = np.unique(f_all)
    new = np.full(len(v_all), -1)
    new[used] = np.arange(len(used))
    v_all, f_all = v_all[used], new[f_all]
    v_s, v_t = np.concatenate(vs)[used], np.concatenate(vt)[used]
    # Roughness (outward positive) evaluated in a frame at the first portal, so that
    # georeferenced coordinates keep their precision.
    origin = alignment.point(np.array([c0]))[0]
    rough = _roughness(v_all - origin, rms, corr, seed)
    v_all = v_all + rough[:, None] * np.concatenate(normals)[used]
    counts = np.bincount(labels, minlength=len(LABELS))
    n_line = max(2, int(np.ceil(branch.length_m)) + 1)
    centre = bal.point(np.linspace(0.0, branch.length_m, n_line))
    meta = {
        "name": name,
        "alignment": alignment.to_dict(),
        "profile": profile.to_dict(),
        "features": [],
        "branches": [dict(branch.to_dict(), alignment=bal.to_dict(),
                          centreline=centre.tolist())],
        "parameters": {"edge_length_m": h, "roughness_rms_m": rms,
                       "roughness_corr_m": corr, "roughness_clip_sigma": ROUGHNESS_CLIP,
                       "roughness_modes": ROUGHNESS_MODES, "closed_ends": closed_ends,
                       "seed": int(seed), "junction_block_m": block, "relief": None,
                       "relief_reach_m": ROUGHNESS_CLIP * rms},
        "labels": {str(i): n for i, n in enumerate(LABELS)},
        "reflectivity": dict(REFLECTIVITY),
        "face_counts": {n: int(c) for n, c in zip(LABELS, counts) if c},
        "n_vertices": int(len(v_all)), "n_faces": int(len(f_all)),
        "bounds": [v_all.min(axis=0).tolist(), v_all.max(axis=0).tolist()],
        "control_points": [],
    }
    return TunnelMesh(v_all, f_all, labels, v_s, v_t, alignment, profile, meta)
