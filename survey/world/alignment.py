"""Tunnel alignment: the surveyor's 3-D centreline with chainage.

Plan: a chain of elements, each with curvature varying linearly along its length
(straight: 0 -> 0; circular arc: 1/R -> 1/R; clothoid transition: 1/R1 -> 1/R2), the
standard road/rail alignment elements (e.g. Casal et al. 2017; any highway design
manual). Heading is then a quadratic in the element's local chainage; the position is its
integral, evaluated exactly for straights and arcs and by Gauss–Legendre quadrature for
clothoids (the integrand cos/sin of a quadratic is smooth; 24 nodes per <= 10 m panel
give ~1e-13 m).

Elevation: piecewise linear in chainage through (chainage, elevation) points (grades;
no vertical curves).

Local coordinates of a point: chainage s of its foot point on the plan curve, offset
along the horizontal left normal, height above the centreline's elevation at s. The
cross-section is the vertical plane perpendicular to the plan tangent (the usual
convention for tunnel profiles). Angles are radians, heading counter-clockwise from +x
(east): convert a bearing (clockwise from north) with pi/2 - bearing.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points
from survey.errors import AlignmentError

__all__ = ["STATION_TOL_M", "Alignment", "Element", "arc", "clothoid", "curve", "straight"]

Floats = NDArray[np.float64]

#: Gauss–Legendre nodes and weights on [0, 1] for the clothoid quadrature: 24 nodes for
#: panels up to _PANEL_M, 8 for panels up to _SHORT_PANEL_M (fitted alignments are chains
#: of ~2 m clothoids; 8 nodes integrate them to ~1e-15 m, and to_local on a million
#: points gets 3x faster).
_GL_X, _GL_W = np.polynomial.legendre.leggauss(24)
_GL_X = 0.5 * (_GL_X + 1.0)
_GL_W = 0.5 * _GL_W
_GL8_X, _GL8_W = np.polynomial.legendre.leggauss(8)
_GL8_X = 0.5 * (_GL8_X + 1.0)
_GL8_W = 0.5 * _GL8_W
_SHORT_PANEL_M = 2.5
#: Longest quadrature panel (m).
_PANEL_M = 10.0
#: Largest distance (m) of a station from the curve ``from_stations`` builds through it,
#: in chainage or offset: design stations are exact to mm; more means the chainage is
#: not the distance along the curve.
STATION_TOL_M = 0.01


@dataclass(frozen=True)
class Element:
    """One plan element: ``length_m`` (m) and curvature from ``k_start`` to ``k_end``
    (1/m, positive turning left)."""

    length_m: float
    k_start: float
    k_end: float


def straight(length_m: float) -> Element:
    """A straight of ``length_m`` (m)."""
    return Element(float(length_m), 0.0, 0.0)


def arc(length_m: float, radius_m: float) -> Element:
    """Circular arc; ``radius_m`` > 0 turns left, < 0 turns right."""
    if radius_m == 0 or not np.isfinite(radius_m):
        raise AlignmentError(f"Expected a finite, non-zero arc radius, got {radius_m}; "
                             "use straight() for a straight.")
    return Element(float(length_m), 1.0 / radius_m, 1.0 / radius_m)


def clothoid(length_m: float, radius_start_m: float, radius_end_m: float) -> Element:
    """Clothoid transition between two radii (``np.inf`` for a straight end)."""
    k0 = 0.0 if np.isinf(radius_start_m) else 1.0 / radius_start_m
    k1 = 0.0 if np.isinf(radius_end_m) else 1.0 / radius_end_m
    return Element(float(length_m), k0, k1)


def curve(deflection_rad: float, radius_m: float, transition_m: float) -> list[Element]:
    """A symmetric curve: clothoid in from a straight, circular arc, clothoid out.

    Each clothoid of length L turns by L / (2 R), so the arc's own deflection is
    deflection - L / R (e.g. Casal et al. 2017, eq. for the spiral angle). The radius
    must therefore be at least ``L / |deflection|``: a smaller radius is more than the
    clothoids allow, and is an error rather than a silent negative-length arc.
    ``deflection_rad`` > 0 turns left. Returns [clothoid, arc, clothoid].
    """
    d = float(deflection_rad)
    r = float(radius_m)
    ln = float(transition_m)
    if not (np.isfinite(d) and d != 0):
        raise AlignmentError(f"Expected a non-zero finite deflection angle, got {d} rad.")
    if not (np.isfinite(r) and r > 0):
        raise AlignmentError(f"Expected a positive radius, got {r} m.")
    if not (np.isfinite(ln) and ln >= 0):
        raise AlignmentError(f"Expected a transition length >= 0, got {ln} m.")
    arc_angle = abs(d) - ln / r
    if arc_angle <= 0:
        raise AlignmentError(f"Expected a radius of at least {ln / abs(d):.6g} m for "
                             f"clothoids of {ln:g} m and a deflection of {d:.6g} rad, got "
                             f"{r:g} m: the radius is smaller than the clothoids allow; "
                             "use a larger radius or shorter transitions.")
    sgn = np.sign(d)
    out = []
    if ln > 0:
        out.append(clothoid(ln, np.inf, sgn * r))
    out.append(arc(arc_angle * r, sgn * r))
    if ln > 0:
        out.append(clothoid(ln, sgn * r, np.inf))
    return out


class Alignment:
    """A 3-D tunnel centreline with chainage.

    Parameters
    ----------
    elements : sequence of Element
        Plan elements in order (``straight``, ``arc``, ``clothoid``).
    start_xy : (2,) float
        Plan position (m) at chainage ``start_chainage_m``.
    heading_rad : float
        Plan direction at the start (radians), counter-clockwise from +x.
    profile : (k, 2) sequence of (chainage_m, elevation_m)
        Elevation points (the vertical profile, not the cross-section ``Profile``),
        chainage increasing; linear in between and constant beyond.
    start_chainage_m : float
        Chainage of the first point (surveyors rarely start at 0).

    Notes
    -----
    ``repr`` is one line; ``to_local`` / ``to_world`` convert between world points
    and (chainage, offset, height), all in metres.
    """

    def __init__(self, elements: Iterable[Element], start_xy: ArrayLike = (0.0, 0.0),
                 heading_rad: float = 0.0, profile: ArrayLike = ((0.0, 0.0),),
                 start_chainage_m: float = 0.0) -> None:
        elements = list(elements)
        if not elements:
            raise AlignmentError("Expected at least one plan element, got none.")
        for i, e in enumerate(elements):
            if not isinstance(e, Element):
                raise AlignmentError(f"Expected Element objects, got {type(e).__name__} at "
                                     f"position {i}; build them with straight/arc/clothoid.")
            if not (np.isfinite(e.length_m) and e.length_m > 0):
                raise AlignmentError(f"Expected a positive element length, got "
                                     f"{e.length_m} at element {i}.")
            if not (np.isfinite(e.k_start) and np.isfinite(e.k_end)):
                raise AlignmentError(f"Expected finite curvatures, got {e.k_start}, "
                                     f"{e.k_end} at element {i}.")
        prof = np.asarray(profile, dtype=np.float64)
        if prof.ndim != 2 or prof.shape[1] != 2 or len(prof) == 0 or \
                not np.isfinite(prof).all():
            raise AlignmentError(f"Expected `profile` as (k, 2) finite (chainage, elevation) "
                                 f"pairs, got shape {prof.shape}.")
        if (np.diff(prof[:, 0]) <= 0).any():
            raise AlignmentError("Expected `profile` chainages strictly increasing; sort "
                                 "them and remove duplicates.")
        self.elements = tuple(elements)
        self.start_chainage_m = float(start_chainage_m)
        self._len = np.array([e.length_m for e in elements])
        self._k0 = np.array([e.k_start for e in elements])
        self._k1 = np.array([e.k_end for e in elements])
        self._s0 = self.start_chainage_m + np.concatenate([[0.0], np.cumsum(self._len)])
        self._profile = prof
        # Start state of each element: position and heading.
        n = len(elements)
        self._xy0 = np.empty((n, 2))
        self._th0 = np.empty(n)
        xy = np.asarray(start_xy, dtype=np.float64).reshape(2)
        th = float(heading_rad)
        for i in range(n):
            self._xy0[i] = xy
            self._th0[i] = th
            xy = self._plan_in(np.array([i]), np.array([self._len[i]]))[0]
            th = th + self._k0[i] * self._len[i] + 0.5 * (self._k1[i] - self._k0[i]) * \
                self._len[i]
        self._xy_end = xy

    def __repr__(self) -> str:
        c0, c1 = self.chainage_range
        x, y = self._xy0[0]
        return (f"Alignment({self.length_m:.1f} m, chainage {c0:g}-{c1:g} m, "
                f"{len(self.elements)} elements, start ({x:.3f}, {y:.3f}), heading "
                f"{self._th0[0]:.4f} rad)")

    @classmethod
    def fit(cls, points: ArrayLike, *, knot_spacing_m: float = 15.0,
            segment_m: float = 2.0, profile_step_m: float = 5.0,
            start_chainage_m: float = 0.0) -> Alignment:
        """Fit an alignment to centreline points (n, 3) ordered along the tunnel.

        Each coordinate is fitted against chord length by a least-squares cubic
        B-spline with knots every ``knot_spacing_m`` (de Boor 1978;
        ``scipy.interpolate.make_lsq_spline``). DECISION: not a smoothing spline with
        GCV smoothing: that is tuned for positions, left the curvature of a noisy 200 m
        arc wandering by +-10 %, and its natural end conditions force zero curvature at
        both ends. The knot spacing sets the shortest curvature change resolved. The
        fitted plan curve's
        curvature is sampled every ``segment_m`` of arc length and the alignment is
        built from clothoid elements between those samples (curvature continuous), so
        the result is an ordinary element alignment, placed by the rigid fit that best
        matches the smoothed curve. The profile takes the smoothed elevation every
        ``profile_step_m``.
        """
        from scipy.interpolate import make_lsq_spline

        p, _ = as_points(points, "points", AlignmentError, finite=False)
        if len(p) < 5 or not np.isfinite(p).all():
            raise AlignmentError(f"Expected at least 5 finite centreline points of shape "
                                 f"(n, 3), got {p.shape}.")
        origin = p[0].copy()  # fit in a local frame: UTM numbers would cost precision
        q = p - origin
        chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
        if (np.diff(chord) <= 0).any():
            raise AlignmentError("Expected distinct consecutive centreline points, got "
                                 "repeated ones; remove duplicates first.")
        n_int = max(0, int(round(chord[-1] / knot_spacing_m)) - 1)
        inner = np.linspace(0.0, chord[-1], n_int + 2)[1:-1]
        knots = np.concatenate([[0.0] * 4, inner, [chord[-1]] * 4])
        if len(p) < len(knots) - 4:
            raise AlignmentError(f"Expected at least {len(knots) - 4} points for a knot "
                                 f"spacing of {knot_spacing_m} m, got {len(p)}; pass more "
                                 "points or a larger knot_spacing_m.")
        try:
            sx, sy, sz = (make_lsq_spline(chord, q[:, c], knots, k=3) for c in range(3))
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise AlignmentError(f"Expected centreline points that cover every knot "
                                 f"interval, got a fit failure ({exc}); pass evenly spaced "
                                 "points or a larger knot_spacing_m.") from exc
        shape, start, heading, arc_len, t = cls._from_plan_curve(sx, sy, chord[-1],
                                                                 segment_m)
        total = shape.length_m
        n_prof = max(2, int(round(total / profile_step_m)) + 1)
        s_prof = np.linspace(0.0, total, n_prof)
        z_prof = sz(np.interp(s_prof, arc_len, t)) + origin[2]
        return cls(shape.elements, start_xy=start + origin[:2], heading_rad=heading,
                   profile=np.stack([s_prof + start_chainage_m, z_prof], axis=1),
                   start_chainage_m=start_chainage_m)

    @classmethod
    def _from_plan_curve(cls, sx: Any, sy: Any, t_end: float, segment_m: float
                         ) -> tuple[Alignment, Floats, float, Floats, Floats]:
        """(element shape at the origin, start (2,), heading, arc length (m,), parameter
        (m,)) of the plan curve (sx(t), sy(t)), t in [0, t_end] (callables with
        ``derivative``, e.g. scipy splines): its curvature sampled every ``segment_m``
        of arc length, clothoid elements in between (curvature continuous), placed by
        the rigid fit that best matches the curve. The start and heading place the
        shape; ``arc_len`` maps the parameter grid ``t`` to arc length."""
        # Arc length of the plan curve on a fine parameter grid.
        t = np.linspace(0.0, t_end, max(1000, int(t_end / 0.05)))
        dx, dy = sx.derivative()(t), sy.derivative()(t)
        speed = np.hypot(dx, dy)
        arc_len = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1])
                                                   * np.diff(t))])
        ddx, ddy = sx.derivative(2)(t), sy.derivative(2)(t)
        kappa = (dx * ddy - dy * ddx) / speed ** 3
        total = arc_len[-1]
        n_seg = max(1, int(round(total / segment_m)))
        knots = np.linspace(0.0, total, n_seg + 1)
        k_knots = np.interp(knots, arc_len, kappa)
        seg = total / n_seg
        elements = [Element(seg, float(k_knots[i]), float(k_knots[i + 1]))
                    for i in range(n_seg)]
        # Start pose: not the spline's end derivative (smoothing splines are least
        # certain at their ends, and a heading error there grows along the whole
        # length) but the 2-D rigid transform that best maps the integrated element
        # curve onto the smoothed curve at every metre (Kabsch 1976, in the plane).
        shape = cls(elements)
        s_chk = np.linspace(0.0, total, max(2, int(total) + 1))
        a = shape.plan(s_chk)[0]
        t_chk = np.interp(s_chk, arc_len, t)
        b = np.stack([sx(t_chk), sy(t_chk)], axis=1)
        ca, cb = a.mean(axis=0), b.mean(axis=0)
        h = (a - ca).T @ (b - cb)
        heading = float(np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1]))
        rot = np.array([[np.cos(heading), -np.sin(heading)],
                        [np.sin(heading), np.cos(heading)]])
        return shape, cb - rot @ ca, heading, arc_len, t

    @classmethod
    def from_stations(cls, chainage_m: ArrayLike, points: ArrayLike, *,
                      segment_m: float = 1.0) -> Alignment:
        """The alignment through surveyed centreline stations: chainages (n,) float64
        (m, strictly increasing) and their points (n, 3) float64 (E, N, H).

        Unlike ``fit`` (a least-squares smoother for measured, noisy centres) this
        interpolates: E and N are cubic splines of the given chainage (not-a-knot,
        ``scipy.interpolate.CubicSpline``; two stations give a straight), whose
        curvature, sampled every ``segment_m`` of arc length, defines clothoid elements
        (``_from_plan_curve``). The chainage is the given one (the first station's is
        the start); the elevation is linear between the stations' H. Design stations
        are points of the design curve, and its chainage is the arc length: a station
        whose chainage on the result differs from the given one by more than
        ``STATION_TOL_M`` (a chainage equation, a jump, mixed-up columns) raises
        ``AlignmentError``.
        """
        from scipy.interpolate import CubicSpline

        s = np.asarray(chainage_m, dtype=np.float64).reshape(-1)
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) != len(s) or len(s) < 2:
            raise AlignmentError(f"Expected at least 2 stations: chainages (n,) and points "
                                 f"(n, 3), got shapes {s.shape} and {p.shape}.")
        if not (np.isfinite(s).all() and np.isfinite(p).all()):
            raise AlignmentError("Expected finite chainages and coordinates, got NaN or "
                                 "inf; remove the incomplete rows.")
        if (np.diff(s) <= 0).any():
            i = int(np.argmax(np.diff(s) <= 0))
            raise AlignmentError(f"Expected strictly increasing chainages, got {s[i]:g} "
                                 f"then {s[i + 1]:g} m; sort the stations and remove "
                                 "repeated ones.")
        origin = p[0].copy()       # local frame: UTM numbers would cost precision
        q = p - origin
        u = s - s[0]
        if len(s) == 2:
            sx = CubicSpline(u, q[:, 0], bc_type="natural")
            sy = CubicSpline(u, q[:, 1], bc_type="natural")
        else:
            sx, sy = CubicSpline(u, q[:, 0]), CubicSpline(u, q[:, 1])
        shape, start, heading, _, _ = cls._from_plan_curve(sx, sy, u[-1],
                                                           min(segment_m, u[-1]))
        al = cls(shape.elements, start_xy=start + origin[:2], heading_rad=heading,
                 profile=np.stack([s, p[:, 2]], axis=1), start_chainage_m=s[0])
        got, off, _ = al.to_local(p)
        bad = np.abs(got - s) + np.abs(off)
        if bad.max() > STATION_TOL_M:
            i = int(np.argmax(bad))
            raise AlignmentError(f"Expected every station on the curve at its chainage "
                                 f"(within {STATION_TOL_M:g} m), got station {s[i]:g} m at "
                                 f"chainage {got[i]:.4f} m, offset {off[i]:.4f} m: the "
                                 "chainage is not the distance along E,N (a chainage "
                                 "equation, a jump, or columns mixed up).")
        return al

    # ------------------------------------------------------------------ chainage datum
    def reversed(self) -> Alignment:
        """The same centreline run the other way: chainage from this end (the new start
        chainage is this one's), offsets to the new left."""
        c0, c1 = self.chainage_range
        xy, th, _ = self.plan(c1)
        els = [Element(e.length_m, -e.k_end, -e.k_start) for e in reversed(self.elements)]
        prof = self._profile[::-1].copy()
        prof[:, 0] = c0 + (c1 - prof[:, 0])
        return Alignment(els, start_xy=xy, heading_rad=float(th) + np.pi, profile=prof,
                         start_chainage_m=c0)

    def with_start_chainage(self, start_chainage_m: float) -> Alignment:
        """The same centreline with its chainage shifted to start at
        ``start_chainage_m`` (m)."""
        d = float(start_chainage_m) - self.start_chainage_m
        prof = self._profile.copy()
        prof[:, 0] += d
        return Alignment(self.elements, start_xy=self._xy0[0], heading_rad=self._th0[0],
                         profile=prof, start_chainage_m=float(start_chainage_m))

    def extended(self, before_m: float, after_m: float) -> Alignment:
        """The alignment with straights of ``before_m`` and ``after_m`` (m, >= 0) added
        along its end tangents; chainages of the existing part are kept, the grade at
        each end continues."""
        b, a = float(before_m), float(after_m)
        if not (np.isfinite(b) and np.isfinite(a) and b >= 0 and a >= 0):
            raise AlignmentError(f"Expected extensions >= 0 m, got {before_m}, {after_m}.")
        c0, c1 = self.chainage_range
        # Extensions below a nanometre are none (a sliver element, a repeated profile
        # chainage).
        b = b if b > 1e-9 else 0.0
        a = a if a > 1e-9 else 0.0
        els = list(self.elements)
        start, th0 = self._xy0[0], self._th0[0]
        prof = self._profile
        if b > 0:
            els.insert(0, straight(b))
            start = start - b * np.array([np.cos(th0), np.sin(th0)])
            if c0 - b < prof[0, 0] - 1e-9:
                g = self.grade(c0)
                prof = np.vstack([[c0 - b, self.elevation(c0) - g * b], prof])
        if a > 0:
            els.append(straight(a))
            if c1 + a > prof[-1, 0] + 1e-9:
                g = self.grade(np.nextafter(c1, -np.inf))
                prof = np.vstack([prof, [c1 + a, self.elevation(c1) + g * a]])
        # Profile points at the old ends keep the elevation there exact.
        return Alignment(els, start_xy=start, heading_rad=th0, profile=prof,
                         start_chainage_m=c0 - b)

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON-ready) that ``from_dict`` turns back into this alignment."""
        return {"elements": [[e.length_m, e.k_start, e.k_end] for e in self.elements],
                "start_xy": [float(v) for v in self._xy0[0]],
                "heading_rad": float(self._th0[0]),
                "profile": self._profile.tolist(),
                "start_chainage_m": self.start_chainage_m}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Alignment:
        """The alignment of a ``to_dict`` dictionary."""
        try:
            return cls([Element(*map(float, e)) for e in d["elements"]],
                       start_xy=d["start_xy"], heading_rad=d["heading_rad"],
                       profile=d["profile"], start_chainage_m=d["start_chainage_m"])
        except (KeyError, TypeError) as exc:
            raise AlignmentError(f"Expected an alignment dictionary with elements, "
                                 f"start_xy, heading_rad, profile and start_chainage_m, got "
                                 f"keys {sorted(d) if isinstance(d, dict) else type(d)}."
                                 ) from exc

    def min_radius(self) -> tuple[float, float]:
        """(smallest left-turning radius, smallest right-turning radius) in metres;
        inf where the alignment never turns that way. Curvature is linear within each
        element, so its extremes are at element ends."""
        k = np.concatenate([self._k0, self._k1])
        kl, kr = k.max(initial=0.0), -k.min(initial=0.0)
        return (1.0 / kl if kl > 0 else np.inf), (1.0 / kr if kr > 0 else np.inf)

    def chainage_of_curvature(self, k: float) -> float:
        """Chainage of the first element end where the curvature equals the extreme
        value k (used to name the place in error messages)."""
        ends = np.concatenate([self._s0[:-1], self._s0[1:]])
        kk = np.concatenate([self._k0, self._k1])
        return float(ends[int(np.argmin(np.abs(kk - k)))])

    # ------------------------------------------------------------------ plan geometry
    @property
    def length_m(self) -> float:
        """Total length (m) along the plan curve."""
        return float(self._len.sum())

    @property
    def chainage_range(self) -> tuple[float, float]:
        """(first, last) chainage (m)."""
        return float(self._s0[0]), float(self._s0[-1])

    def _locate(self, s: ArrayLike) -> tuple[NDArray[np.intp], Floats]:
        s = np.asarray(s, dtype=np.float64)
        lo, hi = self._s0[0], self._s0[-1]
        tol = 1e-9 * max(1.0, abs(hi))
        if ((s < lo - tol) | (s > hi + tol)).any():
            bad = s[(s < lo - tol) | (s > hi + tol)]
            raise AlignmentError(f"Expected chainages within [{lo}, {hi}], got "
                                 f"{bad.ravel()[:5].tolist()}.")
        i = np.clip(np.searchsorted(self._s0, s, side="right") - 1, 0, len(self._len) - 1)
        return i, np.clip(s - self._s0[i], 0.0, self._len[i])

    def _heading_in(self, i: Any, u: Any) -> Any:
        c = (self._k1[i] - self._k0[i]) / self._len[i]
        return self._th0[i] + self._k0[i] * u + 0.5 * c * u * u

    def _curvature_in(self, i: Any, u: Any) -> Any:
        return self._k0[i] + (self._k1[i] - self._k0[i]) * u / self._len[i]

    def _plan_in(self, i: ArrayLike, u: ArrayLike) -> Floats:
        """Plan position at local chainage u of element i (vectorised)."""
        i = np.asarray(i)
        u = np.asarray(u, dtype=np.float64)
        th0 = self._th0[i]
        k0 = self._k0[i]
        k1 = self._k1[i]
        out = np.empty(u.shape + (2,))
        straight_ = (k0 == 0) & (k1 == 0)
        arc_ = (k0 == k1) & ~straight_
        other = ~(straight_ | arc_)
        if straight_.any():
            out[straight_, 0] = u[straight_] * np.cos(th0[straight_])
            out[straight_, 1] = u[straight_] * np.sin(th0[straight_])
        if arc_.any():
            k = k0[arc_]
            a, uu = th0[arc_], u[arc_]
            out[arc_, 0] = (np.sin(a + k * uu) - np.sin(a)) / k
            out[arc_, 1] = (np.cos(a) - np.cos(a + k * uu)) / k
        if other.any():
            io, uo = i[other], u[other]
            n_panels = int(np.ceil(max(uo.max(), 1e-12) / _PANEL_M))
            acc = np.zeros((len(uo), 2))
            h = uo / n_panels
            gx, gw = (_GL8_X, _GL8_W) if h.max() <= _SHORT_PANEL_M else (_GL_X, _GL_W)
            for p in range(n_panels):
                x = (p + gx[None, :]) * h[:, None]  # (q, nodes)
                th = self._heading_in(io[:, None], x)
                acc[:, 0] += (np.cos(th) * gw).sum(axis=1) * h
                acc[:, 1] += (np.sin(th) * gw).sum(axis=1) * h
            out[other] = acc
        return self._xy0[i] + out

    def plan(self, s: ArrayLike) -> tuple[Floats, Floats, Floats]:
        """Plan position (..., 2) in m, heading (...) in radians and curvature (...) in
        1/m at chainages s (m)."""
        i, u = self._locate(s)
        xy = self._plan_in(i, u)
        return xy, self._heading_in(i, u), self._curvature_in(i, u)

    def heading(self, s: ArrayLike) -> Floats:
        """Plan heading (radians, counter-clockwise from +x) at chainages s."""
        i, u = self._locate(s)
        return self._heading_in(i, u)

    def elevation(self, s: ArrayLike) -> Floats:
        """Centreline elevation (m) at chainages s (linear between profile points)."""
        return np.interp(np.asarray(s, dtype=np.float64), self._profile[:, 0],
                         self._profile[:, 1])

    def point(self, s: ArrayLike) -> Floats:
        """Centreline points (..., 3) at chainages s."""
        xy, _, _ = self.plan(s)
        return np.concatenate([xy, self.elevation(s)[..., None]], axis=-1)

    def frame(self, s: ArrayLike) -> tuple[Floats, Floats, Floats]:
        """Moving frame at chainages s: (tangent, normal, up), each (..., 3) unit.

        tangent: plan direction (horizontal); normal: horizontal, to the left; up: +z.
        Together they span the vertical cross-section used by ``to_local``; the slope
        of the centreline is given by ``grade``.
        """
        _, th, _ = self.plan(s)
        c, sn = np.cos(th), np.sin(th)
        z = np.zeros_like(c)
        t = np.stack([c, sn, z], axis=-1)
        n = np.stack([-sn, c, z], axis=-1)
        up = np.stack([z, z, np.ones_like(c)], axis=-1)
        return t, n, up

    def grade(self, s: ArrayLike) -> Floats:
        """Slope dz/ds of the elevation profile at chainages s (right-hand value at a
        profile point)."""
        s = np.asarray(s, dtype=np.float64)
        p = self._profile
        if len(p) == 1:
            return np.zeros_like(s)
        g = np.diff(p[:, 1]) / np.diff(p[:, 0])
        j = np.clip(np.searchsorted(p[:, 0], s, side="right") - 1, 0, len(g) - 1)
        inside = (s >= p[0, 0]) & (s < p[-1, 0])
        return np.where(inside, g[j], 0.0)

    # ------------------------------------------------------------------ local frame
    def to_world(self, chainage: ArrayLike, offset: ArrayLike, height: ArrayLike
                 ) -> Floats:
        """World points (..., 3) from chainage, left offset and height (m, broadcast)."""
        s, off, h = np.broadcast_arrays(np.asarray(chainage, dtype=np.float64),
                                        np.asarray(offset, dtype=np.float64),
                                        np.asarray(height, dtype=np.float64))
        xy, th, _ = self.plan(s)
        x = xy[..., 0] - off * np.sin(th)
        y = xy[..., 1] + off * np.cos(th)
        return np.stack([x, y, self.elevation(s) + h], axis=-1)

    def to_local(self, points: ArrayLike, *, max_iter: int = 30
                 ) -> tuple[Floats, Floats, Floats]:
        """(chainage, offset, height), each (n,) in m, of world points (n, 3); a single
        (3,) point gives (1,) arrays. Structured arrays with x, y, z are accepted.

        The foot point is found by a coarse search on the centreline sampled every
        metre, then Newton's method on (p - c(s)) . t(s) = 0, with
        d/ds = -(1 - kappa (p - c) . n). Points beyond the ends get the end chainage
        (their offset is then measured in the end cross-section).
        """
        from scipy.spatial import cKDTree

        p, _ = as_points(points, "points", AlignmentError)
        lo, hi = self.chainage_range
        n_s = max(2, int(np.ceil((hi - lo) / 1.0)) + 1)
        s_grid = np.linspace(lo, hi, n_s)
        xy_grid, _, _ = self.plan(s_grid)
        _, j = cKDTree(xy_grid).query(p[:, :2])
        s = s_grid[j]
        for _ in range(max_iter):
            xy, th, k = self.plan(s)
            d = p[:, :2] - xy
            t_dot = d[:, 0] * np.cos(th) + d[:, 1] * np.sin(th)
            n_dot = -d[:, 0] * np.sin(th) + d[:, 1] * np.cos(th)
            denom = 1.0 - k * n_dot
            step = t_dot / np.where(np.abs(denom) > 1e-3, denom, 1.0)
            s_new = np.clip(s + step, lo, hi)
            done = np.abs(s_new - s) < 1e-12 * max(1.0, abs(hi))
            s = s_new
            if done.all():
                break
        xy, th, _ = self.plan(s)
        d = p[:, :2] - xy
        offset = -d[:, 0] * np.sin(th) + d[:, 1] * np.cos(th)
        height = p[:, 2] - self.elevation(s)
        return s, offset, height
