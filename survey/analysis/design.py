"""Design profiles for as-built comparison: a polyline in the section frame.

A design profile is the line a tunnel section is compared with, in the cross-section
frame of ``survey.world.alignment`` (offset y to the left, height z up, metres). It is
a polyline, closed (a full section) or open (an arch without invert, a wall), taken
from the tunnel JSON's ``Profile`` (sampled every 1 cm, within 0.02 mm of its arcs) or
from a file of ``y, z`` vertices.

Orientation: the vertices are stored so that the polygon (closed by the chord between
the ends when open) is counter-clockwise; the outside (rock side) of every segment is
then on the right of the direction of travel. A signed deviation is positive outside
the design line (overbreak) and negative inside (underbreak).

Closest points (``DesignProfile.locate``) are exact: a uniform grid of segment lists
searched ring by ring (``survey._kernels.sections``). On a vertex the side is decided by the vertex's
pseudo-normal (the sum of the two segment normals; the 2-D case of Baerentzen & Aanaes
2005, "Signed distance computation using the angle weighted pseudonormal", IEEE TVCG
11(3)), so the sign is right at corners too. A point whose closest design point is an
end of an open profile lies beyond the design and gets NaN.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.errors import ProfileError
from survey.world.profiles import Profile

__all__ = ["PROFILE_STEP_M", "DesignProfile", "read_design_profile"]

Floats = NDArray[np.float64]

#: Vertex spacing of a ``Profile`` turned into a design polyline (m).
PROFILE_STEP_M = 0.01
#: Cell of the segment grid of ``locate`` (m), at least; and the most cells along a side.
_GRID_CELL_M = 0.05
_GRID_MAX_CELLS = 1024
#: Margin of the grid around the design (m), at least (points beyond test every segment).
_GRID_MARGIN_M = 1.0
#: Vertices closer than this are one vertex (m).
_SAME_VERTEX_M = 1e-9
#: With ``order="angle"`` and ``closed=None``: an angular gap wider than this between
#: consecutive vertices (seen from their centroid) makes the profile open. ASSUMED: a
#: digitised closed section has no gap of 30 deg; an arch without invert has one.
_OPEN_GAP_RAD = np.deg2rad(30.0)


def _segments_cross(a: Floats, b: Floats, closed: bool) -> tuple[int, int] | None:
    """First pair (i, j) of non-adjacent segments a[i]-b[i], a[j]-b[j] that touch or
    cross, or None: orientation tests on all pairs in row blocks (O(k^2) time,
    O(256 k) memory; design profiles have up to a few thousand vertices)."""
    k = len(a)

    def orient(p: Floats, q: Floats, r: Floats) -> Floats:
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - \
            (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])

    def between(p: Floats, q: Floats, r: Floats) -> NDArray[np.bool_]:
        return ((np.minimum(p[..., 0], q[..., 0]) <= r[..., 0])
                & (r[..., 0] <= np.maximum(p[..., 0], q[..., 0]))
                & (np.minimum(p[..., 1], q[..., 1]) <= r[..., 1])
                & (r[..., 1] <= np.maximum(p[..., 1], q[..., 1])))

    j = np.arange(k)
    for i0 in range(0, k, 256):
        i = np.arange(i0, min(k, i0 + 256))[:, None]
        ai, bi, aj, bj = a[i], b[i], a[j][None], b[j][None]
        o1, o2 = orient(ai, bi, aj), orient(ai, bi, bj)
        o3, o4 = orient(aj, bj, ai), orient(aj, bj, bi)
        cross = (o1 * o2 < 0) & (o3 * o4 < 0)
        touch = (((o1 == 0) & between(ai, bi, aj)) | ((o2 == 0) & between(ai, bi, bj))
                 | ((o3 == 0) & between(aj, bj, ai)) | ((o4 == 0) & between(aj, bj, bi)))
        adjacent = np.abs(j[None] - i) <= 1
        if closed:
            adjacent |= np.abs(j[None] - i) == k - 1
        bad = (cross | touch) & ~adjacent
        if bad.any():
            r, c = np.nonzero(bad)
            return int(i[r[0], 0]), int(c[0])
    return None


class DesignProfile:
    """A design line in the section frame: a closed or open polyline (see module doc).

    Parameters
    ----------
    vertices : (k, 2) float64
        (offset, height) vertices in m, in either direction; k >= 3 (two segments at
        least). A closed profile may repeat its first vertex at the end.
    closed : bool
        Whether the last vertex joins the first.
    name : str
        Shown in reports.

    Raises
    ------
    ProfileError
        Fewer than two segments, non-finite vertices, a polyline that crosses or
        touches itself, or a zero-area closed profile.
    """

    def __init__(self, vertices: ArrayLike, *, closed: bool, name: str = "design") -> None:
        v = np.asarray(vertices, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 2 or not np.isfinite(v).all():
            raise ProfileError(f"Expected design vertices as finite (offset, height) pairs "
                               f"of shape (k, 2), got shape {v.shape}"
                               f"{'' if v.ndim != 2 or v.shape[1:] != (2,) else ' with NaN'}.")
        # DECISION: repeated consecutive vertices (common in digitised drawings) are
        # merged rather than refused: they carry no geometry.
        if len(v):
            keep = np.concatenate([[True], np.linalg.norm(np.diff(v, axis=0), axis=1)
                                   > _SAME_VERTEX_M])
            v = v[keep]
        if closed and len(v) > 1 and np.linalg.norm(v[0] - v[-1]) <= _SAME_VERTEX_M:
            v = v[:-1]
        n_seg = len(v) if closed else len(v) - 1
        if len(v) < 3 or n_seg < 2:
            raise ProfileError(f"Expected a design profile of at least two segments (3 "
                               f"distinct vertices), got {max(n_seg, 0)} segment"
                               f"{'s' if n_seg != 1 else ''}.")
        b = np.roll(v, -1, axis=0) if closed else v[1:]
        a = v if closed else v[:-1]
        hit = _segments_cross(a, b, closed)
        if hit is not None:
            raise ProfileError(f"Expected a design profile that does not cross itself, got "
                               f"segments {hit[0]} and {hit[1]} crossing; if the vertices "
                               "are unordered (digitised points sorted by x), order them "
                               "by angle (order='angle', CLI --design-order angle).")
        ring = np.vstack([v, v[:1]])
        area2 = float(np.sum(ring[:-1, 0] * ring[1:, 1] - ring[1:, 0] * ring[:-1, 1]))
        if closed and abs(area2) <= 1e-12:
            raise ProfileError("Expected a closed design profile enclosing an area, got "
                               "zero area.")
        if area2 < 0:  # clockwise (or an open line whose closure is): reverse
            v = v[::-1].copy()
        self.vertices: Floats = v
        self.closed = bool(closed)
        self.name = str(name)
        self._a = v if closed else v[:-1]
        self._b = np.roll(v, -1, axis=0) if closed else v[1:]
        d = self._b - self._a
        self._len = np.linalg.norm(d, axis=1)
        self._dir = d / self._len[:, None]
        self._normal = np.stack([self._dir[:, 1], -self._dir[:, 0]], axis=1)  # outward
        self._t0 = np.concatenate([[0.0], np.cumsum(self._len)])
        self._grid_cache: tuple[NDArray[np.int64], NDArray[np.int64], float, float,
                                float, int, int] | None = None

    def __repr__(self) -> str:
        kind = "closed" if self.closed else "open"
        return (f"DesignProfile({self.name!r}, {kind}, {len(self._len)} segments, "
                f"length {self.length_m:.3f} m)")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_profile(cls, profile: Profile, name: str | None = None) -> DesignProfile:
        """The closed design line of a ``Profile``: its pieces sampled every
        ``PROFILE_STEP_M`` with every piece end kept (corners stay sharp); a chord of
        1 cm lies within h^2 / (8 R) = 0.013 mm of an arc of radius 1 m."""
        p = profile.points(profile.sample(PROFILE_STEP_M))
        return cls(p, closed=True, name=name or profile.name)

    @classmethod
    def from_points(cls, points: ArrayLike, *, closed: bool | None = None,
                    order: str = "file", name: str = "design") -> DesignProfile:
        """A design profile from vertices (k, 2).

        ``order``: "file" keeps the given order; "angle" sorts the vertices by their
        angle about the centroid (digitised points saved sorted by x), starting after
        the widest angular gap. ``closed``: None decides: in file order, closed when
        the last vertex repeats the first; in angle order, closed unless a gap wider
        than 30 deg (ASSUMED) is left (an arch without invert).
        """
        v = np.asarray(points, dtype=np.float64)
        if order not in ("file", "angle"):
            raise ProfileError(f"Expected order 'file' or 'angle', got {order!r}.")
        if v.ndim != 2 or v.shape[1] != 2 or not np.isfinite(v).all():
            raise ProfileError(f"Expected design vertices as finite (offset, height) pairs "
                               f"of shape (k, 2), got shape {v.shape}.")
        if order == "file":
            if closed is None:
                closed = len(v) > 3 and bool(np.linalg.norm(v[0] - v[-1]) <= _SAME_VERTEX_M)
            return cls(v, closed=closed, name=name)
        c = v.mean(axis=0)
        ang = np.arctan2(v[:, 1] - c[1], v[:, 0] - c[0])
        # DECISION: ties in angle (a vertical wall seen from level) by distance, so
        # a straight run keeps its order.
        o = np.lexsort((np.hypot(*(v - c).T), ang))
        v, ang = v[o], ang[o]
        gaps = np.diff(np.append(ang, ang[0] + 2 * np.pi))
        start = (int(np.argmax(gaps)) + 1) % len(v)
        v = np.roll(v, -start, axis=0)
        if closed is None:
            closed = bool(gaps.max() <= _OPEN_GAP_RAD)
        return cls(v, closed=closed, name=name)

    def shifted(self, dy_m: float, dz_m: float) -> DesignProfile:
        """The same profile moved by (dy_m, dz_m) in the section frame."""
        return DesignProfile(self.vertices + np.array([dy_m, dz_m], dtype=np.float64),
                             closed=self.closed, name=self.name)

    # ------------------------------------------------------------------ geometry
    @property
    def length_m(self) -> float:
        """Length of the polyline (m), the closing segment included when closed."""
        return float(self._t0[-1])

    @property
    def area_m2(self) -> float:
        """Enclosed area (m^2) of a closed profile; NaN for an open one."""
        if not self.closed:
            return float("nan")
        a, b = self._a, self._b
        return float(0.5 * np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]))

    @property
    def centre(self) -> Floats:
        """(2,) area centroid of a closed profile; the vertex mean of an open one."""
        if not self.closed:
            return np.asarray(self.vertices.mean(axis=0), dtype=np.float64)
        a, b = self._a, self._b
        cr = a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]
        area = 0.5 * cr.sum()
        return np.array([np.sum((a[:, 0] + b[:, 0]) * cr),
                         np.sum((a[:, 1] + b[:, 1]) * cr)]) / (6.0 * area)

    def extent(self) -> tuple[float, float, float, float]:
        """(min offset, max offset, min height, max height) of the vertices, m."""
        v = self.vertices
        return (float(v[:, 0].min()), float(v[:, 0].max()), float(v[:, 1].min()),
                float(v[:, 1].max()))

    def _seg_at(self, t: Floats) -> tuple[NDArray[np.intp], Floats]:
        t = np.asarray(t, dtype=np.float64)
        t = np.mod(t, self.length_m) if self.closed else np.clip(t, 0.0, self.length_m)
        i = np.clip(np.searchsorted(self._t0, t, side="right") - 1, 0, len(self._len) - 1)
        return i, t - self._t0[i]

    def points(self, t: ArrayLike) -> Floats:
        """Points (..., 2) at arc lengths t (m; wrapped when closed, clipped when
        open)."""
        i, u = self._seg_at(np.asarray(t, dtype=np.float64))
        return self._a[i] + u[..., None] * self._dir[i]

    def normals(self, t: ArrayLike) -> Floats:
        """Outward unit normals (..., 2) of the segments at arc lengths t."""
        i, _ = self._seg_at(np.asarray(t, dtype=np.float64))
        return self._normal[i]

    def _grid(self) -> tuple[NDArray[np.int64], NDArray[np.int64], float, float, float,
                             int, int]:
        """The segment grid of ``survey._kernels.sections`` (built once)."""
        from survey._kernels.sections import build_grid

        if self._grid_cache is None:
            lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
            size = float(max(hi - lo))
            margin = max(_GRID_MARGIN_M, 0.25 * size)
            cell = max(_GRID_CELL_M, (size + 2 * margin) / _GRID_MAX_CELLS)
            x0, y0 = lo - margin
            nx = int(np.ceil((hi[0] - lo[0] + 2 * margin) / cell)) + 1
            ny = int(np.ceil((hi[1] - lo[1] + 2 * margin) / cell)) + 1
            start, items = build_grid(self._a, self._b, float(x0), float(y0), cell, nx, ny)
            self._grid_cache = (start, items, float(x0), float(y0), cell, nx, ny)
        return self._grid_cache

    def locate(self, yz: ArrayLike) -> tuple[Floats, Floats]:
        """(deviation (n,), t (n,)) of points (n, 2) in the section frame: the signed
        distance to the design line (m; > 0 outside, overbreak) and the arc length of
        the closest design point (m). NaN for points beyond the ends of an open
        profile (their closest design point is an end)."""
        from survey._kernels.sections import closest_segments

        p = np.ascontiguousarray(yz, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2:
            raise ProfileError(f"Expected section points of shape (n, 2), got {p.shape}.")
        if len(p) == 0:
            return np.empty(0), np.empty(0)
        if not np.isfinite(p).all():
            raise ProfileError("Expected finite section points, got NaN or infinite ones.")
        m = len(self._len)
        s = np.empty(len(p), np.int64)
        u = np.empty(len(p))
        d = np.empty(len(p))
        start, items, x0, y0, cell, nx, ny = self._grid()
        closest_segments(p, self._a, self._dir, self._len, start, items, x0, y0, cell,
                         nx, ny, s, u, d)
        f = self._a[s] + u[:, None] * self._dir[s]
        # Side: the segment normal inside a segment, the vertex pseudo-normal on a
        # vertex (the sum of the two segment normals).
        at_start = u <= 0.0
        at_end = u >= self._len[s]
        nrm = self._normal[s].copy()
        prev = (s - 1) % m
        nxt = (s + 1) % m
        has_prev = self.closed | (s > 0)
        has_next = self.closed | (s < m - 1)
        ps = at_start & has_prev
        nrm[ps] += self._normal[prev[ps]]
        pe = at_end & has_next
        nrm[pe] += self._normal[nxt[pe]]
        side = np.einsum("ij,ij->i", p - f, nrm)
        dev = np.where(side < 0, -d, d)
        t = self._t0[s] + u
        if not self.closed:
            beyond = (at_start & (s == 0)) | (at_end & (s == m - 1))
            dev = np.where(beyond & (d > 0), np.nan, dev)
        if self.closed:
            t = np.mod(t, self.length_m)
        return dev, t


def read_design_profile(path: str | os.PathLike[str], *, closed: bool | None = None,
                        order: str = "file", shift_m: ArrayLike = (0.0, 0.0)
                        ) -> DesignProfile:
    """A design profile from a CSV or TXT file of ``y, z`` vertices (offset, height in
    m, in the section frame; commas, semicolons or whitespace; a header line and
    ``#`` comments are skipped). ``shift_m`` (dy, dz) moves it into the section frame
    (a profile digitised in drawing coordinates); ``closed`` and ``order`` as in
    ``DesignProfile.from_points``. Raises ``ProfileError`` for a missing or unreadable
    file and for every check of ``DesignProfile``."""
    p = Path(path)
    if not p.is_file():
        raise ProfileError(f"Expected a design profile file, got '{p}' which does not "
                           "exist.")
    rows: list[list[float]] = []
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise ProfileError(f"Expected a readable design profile, got '{p}' ({exc}).") from None
    for n, line in enumerate(text.splitlines(), 1):
        s = line.split("#", 1)[0].strip()
        if not s:
            continue
        words = s.replace(",", " ").replace(";", " ").split()
        try:
            vals = [float(w) for w in words[:2]]
        except ValueError:
            if not rows:  # a header line
                continue
            raise ProfileError(f"Expected numeric y, z columns in '{p}', got line {n}: "
                               f"{line.strip()[:60]!r}.") from None
        if len(vals) < 2:
            raise ProfileError(f"Expected two columns (y, z) in '{p}', got line {n}: "
                               f"{line.strip()[:60]!r}.")
        rows.append(vals)
    if not rows:
        raise ProfileError(f"Expected y, z vertices in '{p}', got none.")
    sh = np.asarray(shift_m, dtype=np.float64).reshape(-1)
    if sh.shape != (2,) or not np.isfinite(sh).all():
        raise ProfileError(f"Expected `shift_m` as finite (dy, dz), got {sh.tolist()}.")
    v = np.asarray(rows, dtype=np.float64) + sh
    return DesignProfile.from_points(v, closed=closed, order=order, name=p.stem)
