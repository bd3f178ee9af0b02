"""The tunnel axis of a cloud or mesh, and the unrolling about it.

Points may be (n, 3), a single (3,) point or a structured array with fields x, y, z.
Angles are radians: ``phi`` from the crown, positive to the left.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points
from survey.errors import AlignmentError, ReconstructionError
from survey.world.alignment import Alignment
from survey.world.mesh import read_axis
from sensors.io.tunnel_json import read_meta, sidecar

if TYPE_CHECKING:
    from raytrace import Scene

__all__ = ["AXIS_SAMPLE", "AXIS_SPAN_FACTOR", "EXTENT_SAMPLE", "LINING_FULL_SHARE",
           "LINING_LOW_QUANTILE", "LINING_MIN_COVER", "LINING_REF_M", "LINING_REL_TOL",
           "LINING_SECTORS", "LINING_SHARE", "PORTAL_BAND_M", "PROFILE_SECTORS",
           "UNROLL_CHUNK", "LiningExtent", "apply_datum", "cell_runs", "estimate_axis",
           "extend_chainage", "fill_gaps", "fit_profile", "lining_extent", "sample_points", "tunnel_frame", "unroll",
           "unroll_extended"]

Floats = NDArray[np.float64]

#: Points used to estimate the axis (a seeded random subset of larger clouds).
AXIS_SAMPLE = 200_000
#: A slice whose extent across or up differs from the median slice's by more than this
#: factor is not a cross-section of the tube (terrain beyond a portal: a 40 m wide
#: ground, a portal face); the first pass, whose slices cut a curve obliquely, allows
#: twice as much. ASSUMED: a tunnel's profile changes by far less than 1.5x between
#: slices, terrain by far more.
AXIS_SPAN_FACTOR = 1.5

# Where the lining ends (``lining_extent``): rings along the axis x LINING_SECTORS
# sectors around it; a sector is lining when its median radius is within
# LINING_REL_TOL of the reference (the median over the neighbouring full rings) and a
# ring is lining when enough of its sectors are. Beyond a portal the crown and the
# walls are gone and the ground, the portal face and vegetation lie metres away from
# the lining's radius: the share drops (the brief of issue 18; thresholds ASSUMED,
# chosen with margin on the generated portal of tests/survey/clouds/test_portal.py, where a
# ring just outside keeps ~20 % of its sectors on the floor's radius).
#: Angular sectors of a ring (10 deg).
LINING_SECTORS = 36
#: Some ring must have points in at least this share of its sectors (a lining
#: surrounds the axis; a profiler's blind sector is 10-20 %). ASSUMED.
LINING_MIN_COVER = 0.5
#: A ring is full (a reference ring) with at least this share of the largest sector
#: occupancy of any ring (a profiler's blind sector under the trolley stays out).
LINING_FULL_SHARE = 0.75
#: A sector is on the lining within this relative distance of the reference radius
#: (ASSUMED: drill-and-blast overbreak is decimetres on metres of radius; terrain lies
#: metres off).
LINING_REL_TOL = 0.1
#: A ring is lining when at least this share of a full ring's occupied sectors is on
#: the lining.
LINING_SHARE = 0.5
#: A sector is also on the lining when this quantile of its radii is (ASSUMED: the
#: lining keeps 10 % of the points of the ring that holds the portal face).
LINING_LOW_QUANTILE = 0.1
#: The reference radii of a ring: median over full rings within this distance (m).
LINING_REF_M = 10.0
#: Within this distance of an end of the lining (m), points farther out than the
#: lining (by LINING_REL_TOL) are terrain: the portal face around the opening, ground
#: falling away (ASSUMED: the face stands within a ring of the portal; a face leaning
#: back more than this over the crown is not caught).
PORTAL_BAND_M = 2.0
#: Points used to find the extent (a seeded random subset of larger clouds).
EXTENT_SAMPLE = 1_000_000


def _centres(q: Floats) -> tuple[Floats, Floats]:
    """Robust mid-range centre of 2-D points (k, 2)."""
    a = np.percentile(q, [2, 98], axis=0)
    return (a[0] + a[1]) / 2, a[1] - a[0]


def _tube_like(spans: list[Floats], factor: float) -> NDArray[np.bool_]:
    """Which slices (spans (k, 2): across, up) are within ``factor`` of the median
    slice's span in both directions: cross-sections of the tube, not terrain."""
    if not spans:
        return np.zeros(0, dtype=bool)
    sp = np.maximum(np.array(spans), 1e-9)
    ratio = sp / np.median(sp, axis=0)
    return ((ratio <= factor) & (ratio >= 1.0 / factor)).all(axis=1)


def estimate_axis(points: ArrayLike, *, slice_m: float = 2.0, knot_spacing_m: float = 15.0,
                  min_points: int = 50) -> tuple[Alignment, float]:
    """(Alignment, centre height h_c in m) of a tunnel cloud (n, 3): a centreline at the
    profile's mid-height and the height of the profile centre above it (0 here: the
    axis runs through the centre). Slices ``slice_m`` long, knots every
    ``knot_spacing_m``; slices with fewer than ``min_points`` points are skipped, and so
    are slices whose extent across or up is off the median slice's by more than
    ``AXIS_SPAN_FACTOR`` (twice that in the first pass): terrain beyond a portal (the
    ground in front of it, the portal face) does not pull the axis."""
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
    cen, spans = [], []
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
        spans.append(span)
    cen = [c for c, ok in zip(cen, _tube_like(spans, 2 * AXIS_SPAN_FACTOR)) if ok]
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
    pts, spans = [], []
    for k in np.unique(sb[inner]):
        m = inner & (sb == k)
        if m.sum() < min_points:
            continue
        c, span = _centres(np.stack([off[m], h[m]], 1))
        sc = float(np.median(s[m]))
        pts.append(al.to_world(sc, c[0], c[1]))
        spans.append(span)
    pts = [q for q, ok in zip(pts, _tube_like(spans, AXIS_SPAN_FACTOR)) if ok]
    if len(pts) < 5:
        raise ReconstructionError("Expected cross-sections along the first axis estimate, "
                                  "got too few (could not find a tunnel axis).")
    al2 = Alignment.fit(np.array(pts), knot_spacing_m=max(knot_spacing_m, 3 * slice_m))
    return al2, 0.0


def extend_chainage(alignment: Alignment, points: ArrayLike, s: ArrayLike
                    ) -> NDArray[np.float64]:
    """Chainages (n,) of points (n, 3) with the alignment extended straight beyond its
    ends: ``Alignment.to_local`` gives a point beyond an end that end's chainage; here
    it gets the end chainage plus its distance along the end tangent (negative before
    the start)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    s = np.array(s, dtype=np.float64)
    c0, c1 = alignment.chainage_range
    for end in (c0, c1):
        at = np.flatnonzero(s == end)
        if len(at):
            xy, th, _ = alignment.plan(np.full(len(at), end))
            d = p[at, :2] - xy
            along = d[:, 0] * np.cos(th) + d[:, 1] * np.sin(th)
            s[at] = end + (np.minimum(along, 0.0) if end == c0 else np.maximum(along, 0.0))
    return s


@dataclass(frozen=True)
class LiningExtent:
    """Where the lining runs along the axis (``lining_extent``).

    Attributes
    ----------
    start_m, end_m : float, the lining's chainage range (m; the outer edges of its
        first and last rings)
    ring_m : float, ring length used (m; the requested one shortened so that whole
        rings span the points)
    ref_start, ref_end : (LINING_SECTORS,) float64, reference lining radius per sector
        at the first and last lining ring (m; the sector i spans angles
        [-pi + i d, -pi + (i + 1) d) from the crown, d = 2 pi / LINING_SECTORS)
    lining_share : (r,) float64, share of each ring's sectors on the lining (for
        diagnostics), rings from ``ring_start_m`` every ``ring_m``
    ring_start_m : float, chainage of the first ring's lower edge (m)
    portal_start, portal_end : bool, whether points lie beyond that end by more than a
        ring (terrain: the end is a portal; else the data just stop there)
    """

    start_m: float
    end_m: float
    ring_m: float
    ref_start: Floats
    ref_end: Floats
    lining_share: Floats
    ring_start_m: float
    portal_start: bool = True
    portal_end: bool = True

    def terrain(self, s: ArrayLike, phi: ArrayLike, rho: ArrayLike) -> NDArray[np.bool_]:
        """Mask (n,) of the points that are not lining: chainage s (n,) beyond a portal
        end of the extent, or within ``PORTAL_BAND_M`` of a portal end and farther out than the
        lining there (radius rho (n,) above the end ring's reference by
        LINING_REL_TOL; angle phi (n,) from the crown, radians). Where the data just
        stop, points behind the lining near the end are left to the caller (noise or a
        recess, as anywhere)."""
        s, phi, rho = (np.asarray(x, dtype=np.float64) for x in (s, phi, rho))
        # Beyond an end where the data just stop (a sample's end, rounding) is not
        # terrain: only beyond a portal.
        out = (self.portal_start & (s < self.start_m)) | (self.portal_end & (s > self.end_m))
        j = np.mod(np.floor((phi + np.pi) / (2 * np.pi / LINING_SECTORS)).astype(np.int64),
                   LINING_SECTORS)
        for ref, near in ((self.ref_start, self.portal_start
                           & (s < self.start_m + PORTAL_BAND_M)),
                          (self.ref_end, self.portal_end
                           & (s > self.end_m - PORTAL_BAND_M))):
            r = ref[j]
            out |= near & np.isfinite(r) & (rho > (1 + LINING_REL_TOL) * r)
        return out


def lining_extent(s: ArrayLike, phi: ArrayLike, rho: ArrayLike, *, ring_m: float = 0.25
                  ) -> LiningExtent:
    """Where the lining runs along the axis, from unrolled points (chainage s, angle
    phi from the crown, radius rho about the profile centre; each (n,), m and rad).

    Rings of ``ring_m`` x ``LINING_SECTORS`` sectors take the median radius of their
    points. Full rings (sector occupancy >= LINING_FULL_SHARE x the largest) give the
    reference: per sector, the median over full rings within LINING_REF_M. A sector is
    on the lining when its median or its LINING_LOW_QUANTILE radius is within
    LINING_REL_TOL of its reference; a ring is lining when at
    least LINING_SHARE x the full rings' median occupancy of its sectors are. The extent
    runs from the first to the last lining ring (empty rings between profiles and
    interior clutter do not cut it; terrain only lies beyond the ends).

    Raises
    ------
    ReconstructionError
        When no ring has points in LINING_MIN_COVER of its sectors, or none is lining
        (the points do not surround the axis).
    """
    s, phi, rho = (np.asarray(x, dtype=np.float64).reshape(-1) for x in (s, phi, rho))
    if not (len(s) == len(phi) == len(rho) and len(s) and ring_m > 0):
        raise ReconstructionError(f"Expected equal-length non-empty s, phi, rho and "
                                  f"ring_m > 0, got {len(s)}, {len(phi)}, {len(rho)}, "
                                  f"{ring_m}.")
    if len(s) > EXTENT_SAMPLE:      # shares and medians need a sample, not every point
        pick = np.random.default_rng(0).choice(len(s), EXTENT_SAMPLE, replace=False)
        s, phi, rho = s[pick], phi[pick], rho[pick]
    n_sec = LINING_SECTORS
    # Rings of equal length <= ring_m spanning the points exactly: no partial end ring
    # (with fewer points, fewer sectors occupied) that would read as not lining.
    s0 = float(s.min())
    n_r = max(1, int(np.ceil((s.max() - s0) / ring_m)))
    ring_m = max((float(s.max()) - s0) / n_r, 1e-9)
    i = np.minimum(np.floor((s - s0) / ring_m).astype(np.int64), n_r - 1)
    j = np.mod(np.floor((phi + np.pi) / (2 * np.pi / n_sec)).astype(np.int64), n_sec)
    ids, rs, starts, counts = cell_runs(i * n_sec + j, rho)
    flat = np.full(n_r * n_sec, np.nan)
    flat[ids] = 0.5 * (rs[starts + (counts - 1) // 2] + rs[starts + counts // 2])
    r = flat.reshape(n_r, n_sec)
    # The low quantile too: in the ring that holds the portal the face's points (metres
    # of wall around the opening) outnumber the lining's and pull the median out, but
    # the lining is still the innermost surface there.
    flat = np.full(n_r * n_sec, np.nan)
    flat[ids] = rs[starts + ((counts - 1) * LINING_LOW_QUANTILE).astype(np.int64)]
    r_low = flat.reshape(n_r, n_sec)
    occ = np.isfinite(r).mean(axis=1)
    if occ.max() < LINING_MIN_COVER:
        raise ReconstructionError(f"Expected rings of points around the axis (a lining), "
                                  f"got at most {100 * occ.max():.0f} % of the sectors of "
                                  f"a ring occupied; is this a tunnel, and the axis right?")
    full = np.flatnonzero(occ >= LINING_FULL_SHARE * occ.max())
    centre = s0 + (np.arange(n_r) + 0.5) * ring_m
    ref = np.empty_like(r)
    lo_k = np.searchsorted(centre[full], centre - LINING_REF_M)
    hi_k = np.searchsorted(centre[full], centre + LINING_REF_M, side="right")
    with warnings.catch_warnings():          # all-NaN sectors (a blind sector) stay NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        glob = np.nanmedian(r[full], axis=0)
        for k in range(n_r):
            ref[k] = (np.nanmedian(r[full[lo_k[k]:hi_k[k]]], axis=0)
                      if hi_k[k] > lo_k[k] else glob)
    with np.errstate(invalid="ignore"):
        on = ((np.abs(r - ref) <= LINING_REL_TOL * ref)
              | (np.abs(r_low - ref) <= LINING_REL_TOL * ref))
    share = on.sum(axis=1) / n_sec
    lining = np.flatnonzero(share >= LINING_SHARE * np.median(occ[full]))
    if len(lining) == 0:
        raise ReconstructionError("Expected rings of points around the axis (a lining), "
                                  "got none; is this a tunnel, and the axis right?")
    a, b = lining[0], lining[-1]
    start, end = s0 + a * ring_m, s0 + (b + 1) * ring_m
    return LiningExtent(start, end, float(ring_m), ref[a].copy(), ref[b].copy(), share, s0,
                        bool((s < start - ring_m).any()), bool((s > end + ring_m).any()))


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


#: Points unrolled at a time by ``unroll_extended`` (its temporaries, ~200 bytes a
#: point in ``Alignment.to_local``, stay this size).
UNROLL_CHUNK = 1 << 20


def unroll_extended(points: ArrayLike, alignment: Alignment | None = None,
                    centre_height_m: float | None = None
                    ) -> tuple[Alignment, float, Floats, Floats, Floats]:
    """(alignment, h_c, s, phi, rho) as ``unroll``, with the chainage s (n,) extended
    straight beyond the alignment's ends (``extend_chainage``), computed
    ``UNROLL_CHUNK`` points at a time: the result is 24 bytes a point, the temporaries
    one chunk's."""
    p, _ = as_points(points, "points", ReconstructionError)
    if alignment is None:
        alignment, _ = estimate_axis(p)
    hc = 0.0 if centre_height_m is None else float(centre_height_m)
    n = len(p)
    s, phi, rho = np.empty(n), np.empty(n), np.empty(n)
    for a in range(0, n, UNROLL_CHUNK):
        q = p[a:a + UNROLL_CHUNK]
        _, _, s_k, _, _, phi[a:a + len(q)], rho[a:a + len(q)] = unroll(q, alignment, hc)
        s[a:a + len(q)] = extend_chainage(alignment, q, s_k)
    return alignment, hc, s, phi, rho


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
    from sensors.io.meshes import load_mesh

    sc, refl = load_mesh(mesh_path) if scene is None else (scene, None)
    js = sidecar(mesh_path)
    if js.is_file():
        meta = read_meta(js)
        if "alignment" in meta and "profile" in meta:
            al, hc = read_axis(js)
            return sc, refl, al, hc
    al, hc = estimate_axis(np.asarray(sc.vertices))
    return sc, refl, al, hc



# ---------------------------------------------------------------------------- chainage
#: Angular sectors of a profile fitted to a cloud (``fit_profile``, 5 deg each).
PROFILE_SECTORS = 72


def sample_points(path: str | Path, n: int = AXIS_SAMPLE, *, seed: int = 0) -> Floats:
    """A seeded uniform subset (at most ``n``, 3) float64 of a cloud file's points
    (streamed: bottom-k sampling, every point a random key, the n smallest kept), or
    a mesh's vertices (PLY with faces, OBJ, STL, OFF)."""
    from sensors.io.cloudread import iter_points, read_reference

    p = Path(path)
    if p.suffix.lower() in (".ply", ".obj", ".stl", ".off"):
        return read_reference(p)[0]
    rng = np.random.default_rng(seed)
    keep, keys = np.empty((0, 3)), np.empty(0)
    for chunk in iter_points(p):
        keep = np.vstack([keep, chunk])
        keys = np.concatenate([keys, rng.random(len(chunk))])
        if len(keys) > n:
            sel = np.argpartition(keys, n - 1)[:n]
            keep, keys = keep[sel], keys[sel]
    return keep


def apply_datum(alignment: Alignment, points: ArrayLike, *,
                start_xy: ArrayLike | None = None, chainage_at_m: float = 0.0,
                reverse: bool = False, reference: Alignment | None = None
                ) -> tuple[Alignment, dict[str, Any]]:
    """A fitted axis with the user's chainage: (alignment, datum record for the JSON).

    The axis is first extended straight along its end tangents to cover the points
    (``extend_chainage``: a fitted axis ends half a slice inside the cloud). Then:

    - ``reference`` (a design alignment): the direction of the reference, and the
      chainage that best matches it (least squares over the axis every metre, where
      the axis lies within the reference); the record gives the largest difference.
    - ``start_xy`` (2,): chainage ``chainage_at_m`` at the axis point nearest to it,
      increasing away from it towards the farther end of the axis (the axis is
      extended to reach it when it lies beyond an end).
    - neither: ``chainage_at_m`` at the end where the axis begins, running towards
      increasing easting (or northing, for an axis running more north-south).

    ``reverse`` flips the direction of the last two (the chainage at the start point
    stays ``chainage_at_m``).
    """
    p, _ = as_points(points, "points", ReconstructionError)
    al = alignment
    c0, c1 = al.chainage_range
    s_pts = extend_chainage(al, p, al.to_local(p)[0])
    al = al.extended(max(0.0, c0 - float(s_pts.min())), max(0.0, float(s_pts.max()) - c1))
    rec: dict[str, Any] = {}
    if reference is not None:
        if start_xy is not None or reverse:
            raise ReconstructionError("Expected a reference alignment or a start point "
                                      "and direction, got both.")
        lo, hi = al.chainage_range
        s_own = np.linspace(lo, hi, max(2, int(hi - lo) + 1))
        pts = al.point(s_own)
        s_ref = extend_chainage(reference, pts, reference.to_local(pts)[0])
        r0, r1 = reference.chainage_range
        inside = (s_ref > r0) & (s_ref < r1)
        if inside.sum() < 2:
            raise ReconstructionError(f"Expected the axis to run along the reference "
                                      f"alignment (chainage {r0:g} to {r1:g} m), got it "
                                      "beside its ends; is it the same tunnel and CRS?")
        slope = np.polyfit(s_own[inside], s_ref[inside], 1)[0]
        if slope < 0:
            al = al.reversed()
            s_own = al.chainage_range[0] + (hi - s_own)
        shift = float(np.mean(s_ref[inside] - s_own[inside]))
        al = al.with_start_chainage(al.chainage_range[0] + shift)
        diff = s_ref[inside] - (s_own[inside] + shift)
        rec = {"kind": "alignment", "max_difference_m": float(np.abs(diff).max()),
               "covered_m": [float(s_ref[inside].min()), float(s_ref[inside].max())]}
        return al, rec
    if start_xy is not None:
        xy = np.asarray(start_xy, dtype=np.float64).reshape(2)
        q = np.array([[xy[0], xy[1], float(np.median(p[:, 2]))]])
        lo, hi = al.chainage_range
        s0 = float(extend_chainage(al, q, al.to_local(q)[0])[0])
        al = al.extended(max(0.0, lo - s0), max(0.0, s0 - hi))
        lo, hi = al.chainage_range
        flip = (s0 - lo > hi - s0) != bool(reverse)
        if flip:
            al = al.reversed()
            s0 = lo + (hi - s0)
        al = al.with_start_chainage(float(chainage_at_m) - (s0 - lo))
        foot = al.point(float(chainage_at_m))
        rec = {"kind": "start", "start_xy": xy.tolist(), "chainage_at_m":
               float(chainage_at_m), "reverse": bool(reverse),
               "start_offset_m": float(np.hypot(*(foot[:2] - xy)))}
        return al, rec
    lo, hi = al.chainage_range
    a, b = al.point(lo), al.point(hi)
    d = b - a
    backwards = (d[0] < 0) if abs(d[0]) >= abs(d[1]) else (d[1] < 0)
    if backwards != bool(reverse):
        al = al.reversed()
    al = al.with_start_chainage(float(chainage_at_m))
    rec = {"kind": "end", "chainage_at_m": float(chainage_at_m), "reverse": bool(reverse),
           "start_xy": al.point(float(chainage_at_m))[:2].tolist()}
    return al, rec


def fit_profile(alignment: Alignment, points: ArrayLike, *, kind: str = "sectors",
                sectors: int = PROFILE_SECTORS) -> Any:
    """A cross-section ``Profile`` of a cloud about a fitted axis (which runs through
    the profile centre): ``"sectors"``: the median radius in each of ``sectors``
    angular sectors over the whole length (sectors without points interpolated
    around), a star-shaped polygon; ``"circle"``: the median radius, a circle centred
    on the axis. Points beyond the axis' ends are left out."""
    from survey.world.profiles import Profile

    p, _ = as_points(points, "points", ReconstructionError)
    s, off, h = alignment.to_local(p)
    c0, c1 = alignment.chainage_range
    m = (s > c0) & (s < c1)
    if m.sum() < 3 * sectors:
        raise ReconstructionError(f"Expected at least {3 * sectors} points along the axis "
                                  f"for a profile, got {int(m.sum())}.")
    phi, rho = np.arctan2(off[m], h[m]), np.hypot(off[m], h[m])
    if kind == "circle":
        rm = float(np.median(rho))
        return Profile([{"kind": "arc", "centre": (0.0, 0.0), "radius": rm,
                         "angle_start": 0.0, "angle_sweep": 2 * np.pi}],
                       name=f"fitted circle r={rm:.3f} m")
    if kind != "sectors":
        raise ReconstructionError(f"Expected a profile kind 'sectors' or 'circle', got "
                                  f"{kind!r}.")
    step = 2 * np.pi / sectors
    j = np.mod(np.floor((phi + np.pi) / step).astype(np.int64), sectors)
    ids, rs, starts, counts = cell_runs(j, rho)
    r = np.full(sectors, np.nan)
    r[ids] = 0.5 * (rs[starts + (counts - 1) // 2] + rs[starts + counts // 2])
    centre = -np.pi + (np.arange(sectors) + 0.5) * step
    fill_gaps(r[None, :], np.zeros(1))
    return Profile.from_polyline(np.stack([r * np.sin(centre), r * np.cos(centre)], 1),
                                 name=f"fitted {sectors} sectors")
