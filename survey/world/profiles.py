"""Tunnel cross-section profiles: closed 2-D curves in the (offset, height) plane.

A profile is a chain of exact pieces, straight lines and circular arcs, traversed
counter-clockwise in the (offset y to the left, height z up) plane, so that its outward
normal is the tangent turned clockwise. Height 0 is the alignment's elevation (the floor
or top of rail at the centreline, by the convention of this package). Positions on the
profile are given by its arc-length parameter ``t`` in [0, perimeter).

Meshes sample the pieces exactly (every vertex lies on the design curve) with a target
spacing, keeping the ends of every piece and any extra break points that features need
(niche edges, a drainage channel), so sharp corners stay sharp.

Shapes (all dimensions in metres):

- ``circle(radius_m)``: bored (TBM) tunnel, invert touching height 0.
- ``horseshoe(span_m, springline_m)``: the classical horseshoe of hydraulic and
  gallery tunnels: a semicircular crown of radius r = span/2 above the springline,
  side walls that are arcs of radius 2r centred on the opposite springline point, and a
  flat floor (the "standard horseshoe" of USBR practice with a flat invert).
- ``arched_rectangle(width_m, wall_height_m, rise_m)``: vertical walls and a
  segmental arch roof of the given rise (rise = width/2 gives a semicircular roof).
- ``Profile.from_polyline(points)``: any closed simple polygon, e.g. a design profile.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.errors import ProfileError

__all__ = ["FLOOR_MAX_TILT_RAD", "Profile", "arched_rectangle", "circle", "horseshoe"]

Floats = NDArray[np.float64]

#: Faces whose outward normal points down within this angle of -z are "floor".
FLOOR_MAX_TILT_RAD = np.deg2rad(30.0)
#: Spacing of the dense sampling used to locate positions on the profile (m).
_DENSE_M = 1e-3

_LINE, _ARC = 0, 1


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise ProfileError(f"Expected `{name}` to be a positive number of metres, got "
                           f"{value}.")
    return value


class Profile:
    """A closed cross-section made of line and arc pieces (counter-clockwise).

    Build with ``circle``, ``horseshoe``, ``arched_rectangle`` or
    ``Profile.from_polyline``. ``pieces`` is a tuple of dicts, each either
    ``{"kind": "line", "start": (y, z), "end": (y, z)}`` or
    ``{"kind": "arc", "centre": (y, z), "radius": r, "angle_start": a0,
    "angle_sweep": da}`` (radians, da > 0 counter-clockwise).
    """

    def __init__(self, pieces: Iterable[Mapping[str, Any]], name: str = "custom") -> None:
        pieces = list(pieces)
        self.name = name
        kind, geo, lengths = [], [], []
        for p in pieces:
            if p["kind"] == "line":
                a = np.asarray(p["start"], float)
                b = np.asarray(p["end"], float)
                kind.append(_LINE)
                geo.append([a[0], a[1], b[0], b[1], 0.0])
                lengths.append(float(np.hypot(*(b - a))))
            elif p["kind"] == "arc":
                c = np.asarray(p["centre"], float)
                kind.append(_ARC)
                geo.append([c[0], c[1], float(p["radius"]), float(p["angle_start"]),
                            float(p["angle_sweep"])])
                lengths.append(abs(float(p["radius"]) * float(p["angle_sweep"])))
            else:
                raise ProfileError(f"Expected piece kinds 'line' or 'arc', got "
                                   f"{p['kind']!r}.")
        self._kind = np.array(kind, dtype=np.int8)
        self._geo = np.array(geo, dtype=np.float64).reshape(-1, 5)
        self._len = np.array(lengths)
        if len(self._len) == 0 or not np.isfinite(self._geo).all() or \
                (self._len <= 0).any():
            raise ProfileError("Expected a profile of pieces with finite geometry and "
                               "positive length, got a degenerate piece.")
        self._t0 = np.concatenate([[0.0], np.cumsum(self._len)])
        self._dense: tuple[Floats, Floats] | None = None
        self.pieces = tuple(dict(p) for p in pieces)
        # Closedness, then orientation from the exact signed area.
        ends = self._piece_points(np.arange(len(self._len)), self._len)
        starts = self._piece_points(np.arange(len(self._len)), np.zeros(len(self._len)))
        gap = np.linalg.norm(ends - np.roll(starts, -1, axis=0), axis=1).max()
        if gap > 1e-9 * max(1.0, self.perimeter_m):
            raise ProfileError(f"Expected the profile pieces to join end to start, got a "
                               f"gap of {gap:.3g} m.")
        area, my, mz = self._moments()
        if area <= 0:
            raise ProfileError(f"Expected a counter-clockwise profile (positive area), got "
                               f"signed area {area:.3g} m^2.")
        self.area_m2 = float(area)
        self.centroid = np.array([my, mz]) / area

    def __repr__(self) -> str:
        return (f"Profile({self.name!r}, perimeter {self.perimeter_m:.3f} m, area "
                f"{self.area_m2:.3f} m^2, {len(self._len)} pieces)")

    def _moments(self) -> tuple[float, float, float]:
        """Exact area and first moments (A, A*cy, A*cz) by Green's theorem over the
        pieces: A = 1/2 closed-integral (y dz - z dy), A cy = closed-integral y^2/2 dz,
        A cz = -closed-integral z^2/2 dy, integrated in closed form on lines and arcs."""
        area = my = mz = 0.0
        for kind, g in zip(self._kind, self._geo):
            if kind == _LINE:
                y0, z0, y1, z1 = g[:4]
                area += 0.5 * (y0 * z1 - y1 * z0)
                my += (z1 - z0) / 6.0 * (y0 * y0 + y0 * y1 + y1 * y1)
                mz -= (y1 - y0) / 6.0 * (z0 * z0 + z0 * z1 + z1 * z1)
            else:
                cy, cz, r, a0, da = g
                a1 = a0 + da
                sa0, sa1, ca0, ca1 = np.sin(a0), np.sin(a1), np.cos(a0), np.cos(a1)
                area += 0.5 * (r * cy * (sa1 - sa0) - r * cz * (ca1 - ca0) + r * r * da)
                # r/2 * integral of (cy^2 cos + 2 cy r cos^2 + r^2 cos^3) da
                my += 0.5 * r * (cy * cy * (sa1 - sa0)
                                 + 2 * cy * r * (da / 2 + (np.sin(2 * a1) - np.sin(2 * a0)) / 4)
                                 + r * r * ((sa1 - sa1 ** 3 / 3) - (sa0 - sa0 ** 3 / 3)))
                # r/2 * integral of (cz^2 sin + 2 cz r sin^2 + r^2 sin^3) da
                mz += 0.5 * r * (cz * cz * (ca0 - ca1)
                                 + 2 * cz * r * (da / 2 - (np.sin(2 * a1) - np.sin(2 * a0)) / 4)
                                 + r * r * ((-ca1 + ca1 ** 3 / 3) - (-ca0 + ca0 ** 3 / 3)))
        return area, my, mz

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_polyline(cls, points: ArrayLike, name: str = "polyline") -> Profile:
        """A closed simple polygon (k, 2) of (offset, height) vertices; the last joins
        the first. Either orientation; self-intersecting polygons are rejected."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 3 or not np.isfinite(p).all():
            raise ProfileError(f"Expected `points` as at least 3 finite (offset, height) "
                               f"pairs of shape (k, 2), got shape {p.shape}.")
        if np.allclose(p[0], p[-1]):
            p = p[:-1]
        seg = np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1)
        if (seg <= 1e-9).any():
            raise ProfileError(f"Expected distinct consecutive profile vertices, got a "
                               f"repeated vertex at index {int(np.argmax(seg <= 1e-9))}; "
                               "remove duplicates.")
        hit = _first_self_intersection(p)
        if hit is not None:
            i, j = hit
            raise ProfileError(f"Expected a simple (non-self-intersecting) profile, got "
                               f"edges {i} and {j} crossing; fix the polygon's vertex "
                               "order.")
        y, z = p[:, 0], p[:, 1]
        if np.sum(y * np.roll(z, -1) - np.roll(y, -1) * z) < 0:
            p = p[::-1]
        q = np.roll(p, -1, axis=0)
        return cls([{"kind": "line", "start": tuple(a), "end": tuple(b)}
                    for a, b in zip(p, q)], name=name)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON-ready) that ``from_dict`` turns back into this profile."""
        return {"name": self.name, "pieces": [
            {k: (list(v) if isinstance(v, tuple) else v) for k, v in p.items()}
            for p in self.pieces]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Profile:
        """The profile of a ``to_dict`` dictionary."""
        try:
            return cls(d["pieces"], name=d.get("name", "custom"))
        except (KeyError, TypeError) as exc:
            raise ProfileError(f"Expected a profile dictionary with pieces, got "
                               f"{sorted(d) if isinstance(d, Mapping) else type(d)}."
                               ) from exc

    # ------------------------------------------------------------------ evaluation
    @property
    def perimeter_m(self) -> float:
        """Length of the closed curve (m)."""
        return float(self._t0[-1])

    def _locate(self, t: ArrayLike) -> tuple[NDArray[np.intp], Floats]:
        t = np.mod(np.asarray(t, dtype=np.float64), self.perimeter_m)
        i = np.clip(np.searchsorted(self._t0, t, side="right") - 1, 0, len(self._len) - 1)
        return i, t - self._t0[i]

    def _piece_points(self, i: Any, u: Any) -> Floats:
        g = self._geo[i]
        line = self._kind[i] == _LINE
        f = u / self._len[i]
        ang = g[..., 3] + g[..., 4] * f
        y = np.where(line, g[..., 0] + (g[..., 2] - g[..., 0]) * f,
                     g[..., 0] + g[..., 2] * np.cos(ang))
        z = np.where(line, g[..., 1] + (g[..., 3] - g[..., 1]) * f,
                     g[..., 1] + g[..., 2] * np.sin(ang))
        return np.stack([y, z], axis=-1)

    def _piece_normals(self, i: Any, u: Any) -> Floats:
        g = self._geo[i]
        line = self._kind[i] == _LINE
        d = np.stack([g[..., 2] - g[..., 0], g[..., 3] - g[..., 1]], axis=-1)
        d /= np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-300)
        ln = np.stack([d[..., 1], -d[..., 0]], axis=-1)  # tangent turned clockwise
        ang = g[..., 3] + g[..., 4] * u / self._len[i]
        # An arc traversed counter-clockwise bulges outward (normal = radial); one
        # traversed clockwise is a concave piece (normal = -radial).
        sgn = np.sign(g[..., 4])[..., None]
        an = sgn * np.stack([np.cos(ang), np.sin(ang)], axis=-1)
        return np.where(line[..., None], ln, an)

    def points(self, t: ArrayLike) -> Floats:
        """Points (..., 2) (offset, height in m) at arc-length parameters t (m, wrapped to
        the perimeter)."""
        i, u = self._locate(t)
        return self._piece_points(i, u)

    def normals(self, t: ArrayLike) -> Floats:
        """Outward unit normals (..., 2) at t; at a join between pieces (a corner), the
        normalised mean of the two pieces' normals."""
        i, u = self._locate(t)
        n = self._piece_normals(i, u)
        at_join = u <= 1e-12 * max(1.0, self.perimeter_m)
        if np.any(at_join):
            prev = (i - 1) % len(self._len)
            n_prev = self._piece_normals(prev, self._len[prev])
            m = n + n_prev
            m /= np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-300)
            n = np.where(at_join[..., None], m, n)
        return n

    def sample(self, spacing_m: float, breaks: ArrayLike = ()) -> Floats:
        """Arc-length parameters (k,) of mesh vertices: every piece start and every
        break, each interval split evenly into pieces no longer than ``spacing_m``."""
        spacing_m = _positive("spacing_m", spacing_m)
        b = np.concatenate([self._t0[:-1], np.mod(np.asarray(breaks, float),
                                                  self.perimeter_m)])
        b = np.unique(b)
        # Merge breaks closer than a micrometre (they would give degenerate faces).
        b = b[np.concatenate([[True], np.diff(b) > 1e-6])]
        ends = np.append(b[1:], self.perimeter_m)
        n = np.maximum(1, np.ceil((ends - b) / spacing_m - 1e-9).astype(np.int64))
        start = np.repeat(b, n)
        step = np.repeat((ends - b) / n, n)
        k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        return start + k * step

    def dense(self) -> tuple[Floats, Floats]:
        """Dense polyline (t, points) with ~1 mm spacing for locating positions."""
        if self._dense is None:
            t = self.sample(_DENSE_M)
            self._dense = (t, self.points(t))
        return self._dense

    def distance(self, yz: ArrayLike) -> Floats:
        """Distance (n,) of points (n, 2) from the profile curve (exact pieces)."""
        yz = np.asarray(yz, dtype=np.float64)
        out = np.full(len(yz), np.inf)
        for i in range(len(self._len)):
            g = self._geo[i]
            if self._kind[i] == _LINE:
                a, b = g[:2], g[2:4]
                ab = b - a
                w = np.clip(((yz - a) @ ab) / (ab @ ab), 0.0, 1.0)
                d = np.linalg.norm(yz - (a + w[:, None] * ab), axis=1)
            else:
                c, r, a0, da = g[:2], g[2], g[3], g[4]
                v = yz - c
                ang = np.arctan2(v[:, 1], v[:, 0])
                # Within the arc's angular range: radial distance; else nearest end.
                rel = np.mod((ang - a0) * np.sign(da), 2 * np.pi)
                inside = rel <= abs(da)
                d_end = np.minimum(
                    np.linalg.norm(yz - (c + r * np.array([np.cos(a0), np.sin(a0)])), axis=1),
                    np.linalg.norm(yz - (c + r * np.array([np.cos(a0 + da),
                                                           np.sin(a0 + da)])), axis=1))
                d = np.where(inside, np.abs(np.linalg.norm(v, axis=1) - r), d_end)
            out = np.minimum(out, d)
        return out

    # ------------------------------------------------------------------ positions
    def extent(self) -> tuple[float, float, float, float]:
        """(max offset to the left, max offset to the right, min height, max height), m."""
        _, p = self.dense()
        return float(p[:, 0].max()), float(-p[:, 0].min()), float(p[:, 1].min()), \
            float(p[:, 1].max())

    def _crossing(self, values: Floats, level: float,
                  choose: Callable[[Floats], int]) -> Any:
        """Parameters where the dense polyline's ``values`` cross ``level``; pick one."""
        t, _ = self.dense()
        v = values - level
        nxt = np.roll(v, -1)
        idx = np.nonzero((v == 0) | (np.sign(v) != np.sign(nxt)) & (nxt != 0))[0]
        if len(idx) == 0:
            return None
        t_next = np.append(t[1:], self.perimeter_m)
        w = np.where(v[idx] == 0, 0.0, v[idx] / np.where(v[idx] == nxt[idx], 1.0,
                                                         v[idx] - nxt[idx]))
        tc = t[idx] + w * (t_next[idx] - t[idx])
        return tc[choose(self.points(tc))]

    def t_at_height(self, side: str, height_m: float) -> float:
        """Parameter of the wall point on ``side`` ('left' or 'right') at a height."""
        if side not in ("left", "right"):
            raise ProfileError(f"Expected side 'left' or 'right', got {side!r}.")
        sgn = 1.0 if side == "left" else -1.0
        _, p = self.dense()
        t = self._crossing(p[:, 1], float(height_m),
                           lambda q: int(np.argmax(sgn * q[:, 0])))
        if t is None or sgn * self.points(t)[0] <= 0:
            lo, hi = p[:, 1].min(), p[:, 1].max()
            raise ProfileError(f"Expected a height within the profile's {side} wall "
                               f"({lo:.3f} to {hi:.3f} m), got {height_m} m.")
        return float(t)

    def t_at_floor_offset(self, offset_m: float) -> float:
        """Parameter of the lowest profile point at a given offset (on the floor)."""
        _, p = self.dense()
        t = self._crossing(p[:, 0], float(offset_m), lambda q: int(np.argmin(q[:, 1])))
        if t is None:
            raise ProfileError(f"Expected an offset within the profile "
                               f"({p[:, 0].min():.3f} to {p[:, 0].max():.3f} m), got "
                               f"{offset_m} m.")
        return float(t)

    def t_at_angle(self, angle_rad: float) -> float:
        """Parameter where the ray from the centroid at ``angle_rad`` from the crown
        (positive towards the left) leaves the profile (the farthest crossing)."""
        _, p = self.dense()
        d = np.array([np.sin(angle_rad), np.cos(angle_rad)])
        q = p - self.centroid
        # Signed distance across the ray's line; crossings ahead of the centroid.
        side = q[:, 0] * d[1] - q[:, 1] * d[0]
        t = self._crossing(side, 0.0, lambda pts: int(np.argmax(
            np.where((pts - self.centroid) @ d > 0, (pts - self.centroid) @ d, -np.inf))))
        if t is None:
            raise ProfileError(f"Expected the angle {angle_rad} rad to meet the profile.")
        return float(t)

    def is_floor(self, t: ArrayLike) -> NDArray[np.bool_]:
        """True where the outward normal at t points down within FLOOR_MAX_TILT_RAD."""
        return self.normals(t)[..., 1] < -np.cos(FLOOR_MAX_TILT_RAD)

    def star_shaped_about_centroid(self) -> bool:
        """Whether every dense edge faces away from the centroid (a fan cap is valid)."""
        _, p = self.dense()
        q = p - self.centroid
        r = np.roll(q, -1, axis=0)
        return bool((q[:, 0] * r[:, 1] - q[:, 1] * r[:, 0] > 0).all())


def _first_self_intersection(p: Floats) -> tuple[int, int] | None:
    """First pair (i, j) of non-adjacent edges of the closed polygon p that touch or
    cross, or None. Orientation tests on all pairs, in row blocks (O(k^2) time,
    O(k * block) memory): profiles have hundreds to a few thousand vertices."""
    k = len(p)
    a, b = p, np.roll(p, -1, axis=0)

    def orient(p1: Floats, p2: Floats, p3: Floats) -> Floats:
        return (p2[..., 0] - p1[..., 0]) * (p3[..., 1] - p1[..., 1]) - \
            (p2[..., 1] - p1[..., 1]) * (p3[..., 0] - p1[..., 0])

    def on_seg(p1: Floats, p2: Floats, q: Floats) -> NDArray[np.bool_]:
        return (np.minimum(p1[..., 0], p2[..., 0]) <= q[..., 0]) & \
            (q[..., 0] <= np.maximum(p1[..., 0], p2[..., 0])) & \
            (np.minimum(p1[..., 1], p2[..., 1]) <= q[..., 1]) & \
            (q[..., 1] <= np.maximum(p1[..., 1], p2[..., 1]))

    j = np.arange(k)
    for i0 in range(0, k, 256):
        i = np.arange(i0, min(k, i0 + 256))[:, None]
        ai, bi = a[i], b[i]
        aj, bj = a[j][None], b[j][None]
        o1, o2 = orient(ai, bi, aj), orient(ai, bi, bj)
        o3, o4 = orient(aj, bj, ai), orient(aj, bj, bi)
        cross = (o1 * o2 < 0) & (o3 * o4 < 0)
        touch = ((o1 == 0) & on_seg(ai, bi, aj)) | ((o2 == 0) & on_seg(ai, bi, bj)) | \
            ((o3 == 0) & on_seg(aj, bj, ai)) | ((o4 == 0) & on_seg(aj, bj, bi))
        adjacent = (j[None] == i) | (j[None] == (i + 1) % k) | (j[None] == (i - 1) % k)
        bad = (cross | touch) & ~adjacent
        if bad.any():
            r, c = np.nonzero(bad)
            return int(i[r[0], 0]), int(c[0])
    return None


# ---------------------------------------------------------------------- constructors
def circle(radius_m: float) -> Profile:
    """Circular (bored) profile of radius ``radius_m``, invert at height 0."""
    r = _positive("radius_m", radius_m)
    return Profile([{"kind": "arc", "centre": (0.0, r), "radius": r,
                     "angle_start": -np.pi / 2, "angle_sweep": 2 * np.pi}],
                   name=f"circle r={r:g} m")


def horseshoe(span_m: float, springline_m: float | None = None) -> Profile:
    """Horseshoe with a flat floor: crown semicircle of radius r = span/2 above the
    springline (default height r), side arcs of radius 2r centred on the opposite
    springline point, down to the floor at height 0.

    Floor width = 2 (sqrt(4 r^2 - h^2) - r) for springline height h: 1.46 r at the
    default h = r, 0.65 r at the largest accepted h = 1.5 r.
    """
    span = _positive("span_m", span_m)
    r = span / 2.0
    h = r if springline_m is None else _positive("springline_m", springline_m)
    if h > 1.5 * r:
        raise ProfileError(f"Expected `springline_m` at most 1.5 x the crown radius "
                           f"({1.5 * r:g} m) so that the side arcs reach the floor with a "
                           f"usable width, got {h} m.")
    big = 2.0 * r
    yf = np.sqrt(big * big - h * h) - r  # floor half-width
    # Right wall: arc centred at the left springline point (-r, h), from the floor
    # corner (yf, 0) up to the right springline (r, h), counter-clockwise.
    a_right0 = np.arctan2(0.0 - h, yf + r)
    # Left wall: arc centred at (r, h), from (-r, h) (angle pi) down to (-yf, 0).
    a_left1 = np.arctan2(0.0 - h, -yf - r)
    pieces = [
        {"kind": "line", "start": (-yf, 0.0), "end": (yf, 0.0)},
        {"kind": "arc", "centre": (-r, h), "radius": big, "angle_start": a_right0,
         "angle_sweep": 0.0 - a_right0},
        {"kind": "arc", "centre": (0.0, h), "radius": r, "angle_start": 0.0,
         "angle_sweep": np.pi},
        {"kind": "arc", "centre": (r, h), "radius": big, "angle_start": np.pi,
         "angle_sweep": np.mod(a_left1, 2 * np.pi) - np.pi},
    ]
    return Profile(pieces, name=f"horseshoe span={span:g} m springline={h:g} m")


def arched_rectangle(width_m: float, wall_height_m: float, rise_m: float | None = None
                     ) -> Profile:
    """Flat floor, vertical walls of ``wall_height_m`` and a segmental arch roof with
    ``rise_m`` above the wall tops (default width/2: a semicircle)."""
    w = _positive("width_m", width_m)
    hw = _positive("wall_height_m", wall_height_m)
    half = w / 2.0
    f = half if rise_m is None else _positive("rise_m", rise_m)
    if f > half + 1e-12:
        raise ProfileError(f"Expected `rise_m` at most half the width ({half:g} m) for a "
                           f"segmental arch, got {f} m.")
    rad = (half * half + f * f) / (2.0 * f)  # circle through both springings and crown
    cz = hw + f - rad
    a0 = np.arctan2(hw - cz, half)
    pieces = [
        {"kind": "line", "start": (-half, 0.0), "end": (half, 0.0)},
        {"kind": "line", "start": (half, 0.0), "end": (half, hw)},
        {"kind": "arc", "centre": (0.0, cz), "radius": rad, "angle_start": a0,
         "angle_sweep": np.pi - 2 * a0},
        {"kind": "line", "start": (-half, hw), "end": (-half, 0.0)},
    ]
    return Profile(pieces, name=f"arched rectangle {w:g} x {hw:g} m, rise {f:g} m")
