"""Cross-sections of a cloud or a mesh at chainages along an alignment.

A section at chainage s is the set of points whose chainage lies within s +- w (the
band), in the alignment's cross-section frame (``Alignment.to_local``: offset to the
left, height above the centreline's elevation, metres). A mesh is cut by the section
plane itself (the vertical plane through the centreline point, normal to the plan
tangent) and the cut polyline is sampled every ``spacing_m``.

Streaming: a cloud file is read chunk by chunk (``sensors.io.cloudread.iter_points``)
and only the points inside a band are kept, so memory is bounded by the band contents,
and by ``max_points`` per section beyond that (a uniform random subset: every point
gets a seeded random key and the ``max_points`` smallest keys are kept, bottom-k
sampling, so the subset does not depend on the chunk size).

Most points of a file lie in no band, and ``Alignment.to_local`` (Newton on the plan
curve) is the costly step, so a cheap first test comes before it: the nearest of the
centreline points every ``_PRE_STEP_M`` and one projection on its tangent give an
approximate chainage whose error is bounded (see ``_approx_chainage``); only points
that may lie in a band go through ``to_local``.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points
from survey.errors import AlignmentError, CompareError
from survey.world.alignment import Alignment

__all__ = ["FLOOR_PERCENTILE", "MAX_SECTION_POINTS", "SectionCut", "above_floor",
           "cut_cloud", "cut_file", "cut_mesh", "section_chainages"]

Floats = NDArray[np.float64]

#: Most points kept per section (a uniform random subset beyond; ~16 MB per section).
MAX_SECTION_POINTS = 1_000_000
#: Percentile of a section's heights taken as its floor (``above_floor``). DECISION: 1,
#: the profile's lowest points, while a few stray points below the floor (a drain, a
#: multipath echo) do not move it.
FLOOR_PERCENTILE = 1.0
#: Spacing of the centreline points of the first, approximate chainage test (m).
_PRE_STEP_M = 0.5
#: Samples per metre of a mesh cut polyline, by default every 5 mm.
MESH_SPACING_M = 0.005
#: Suffixes read as meshes (a PLY is a mesh when it has faces).
MESH_SUFFIXES = (".obj", ".stl", ".off")


@dataclass(frozen=True)
class SectionCut:
    """The points of one section in the section frame.

    Attributes
    ----------
    chainage_m : float
        Chainage of the section (m).
    half_width_m : float
        Half-width w of the band (m); 0 for a mesh cut by the plane.
    yz : (n, 2) float64
        (offset, height) of the points (m).
    n_in_band : int
        Points found in the band (more than ``len(yz)`` when thinned).
    """

    chainage_m: float
    half_width_m: float
    yz: Floats
    n_in_band: int

    def __repr__(self) -> str:
        return (f"SectionCut(chainage {self.chainage_m:g} m +- {self.half_width_m:g} m, "
                f"{len(self.yz):,} points)")


def above_floor(cut: SectionCut, min_height_m: float, *, floor_m: float | None = None
                ) -> tuple[SectionCut, float]:
    """The points of ``cut`` at least ``min_height_m`` above the floor, and the floor
    height used (m, in the section frame).

    The floor is ``floor_m`` when given (a rail or floor height in the section frame),
    else the section's ``FLOOR_PERCENTILE`` of heights: its lowest points. So the
    height is measured from the rail or floor, whatever the frame's origin (a fitted
    axis runs through the profile's centre, metres above the floor).
    """
    h = float(min_height_m)
    if not np.isfinite(h):
        raise CompareError(f"Expected a finite minimum height in m, got {min_height_m!r}.")
    if floor_m is not None:
        f = float(floor_m)
        if not np.isfinite(f):
            raise CompareError(f"Expected a finite floor height in m, got {floor_m!r}.")
    elif len(cut.yz):
        f = float(np.percentile(cut.yz[:, 1], FLOOR_PERCENTILE))
    else:
        f = 0.0
    keep = cut.yz[:, 1] >= f + h
    return SectionCut(cut.chainage_m, cut.half_width_m, cut.yz[keep], cut.n_in_band), f


def section_chainages(alignment: Alignment, *, every_m: float | None = None,
                      at: ArrayLike | None = None, half_width_m: float = 0.0) -> Floats:
    """Section chainages (k,) float64, sorted: ``at`` as given, or every ``every_m``
    at whole multiples of it (0+005, 0+010, ... as surveyors number them) whose band
    s +- ``half_width_m`` lies within the alignment.

    Raises ``AlignmentError`` for a band reaching outside the alignment, and
    ``CompareError`` for neither or both of ``every_m`` and ``at``, a non-positive
    step, repeated chainages, or bands that overlap.
    """
    w = float(half_width_m)
    if not (np.isfinite(w) and w >= 0):
        raise CompareError(f"Expected a half-width >= 0 m, got {half_width_m}.")
    c0, c1 = alignment.chainage_range
    if (every_m is None) == (at is None):
        raise CompareError("Expected either `every_m` or `at` (section chainages), got "
                           f"{'both' if every_m is not None else 'neither'}.")
    if every_m is not None:
        e = float(every_m)
        if not (np.isfinite(e) and e > 0):
            raise CompareError(f"Expected a positive section spacing, got {every_m} m.")
        k0 = int(np.ceil((c0 + w) / e - 1e-9))
        k1 = int(np.floor((c1 - w) / e + 1e-9))
        s = np.arange(k0, k1 + 1, dtype=np.float64) * e
        if len(s) == 0:
            raise AlignmentError(f"Expected at least one section every {e:g} m within the "
                                 f"alignment [{c0:g}, {c1:g}] m, got none.")
    else:
        s = np.sort(np.atleast_1d(np.asarray(at, dtype=np.float64)).ravel())
        if len(s) == 0 or not np.isfinite(s).all():
            raise CompareError(f"Expected finite section chainages, got {s.tolist()}.")
        tol = 1e-9 * max(1.0, abs(c1))
        bad = s[(s - w < c0 - tol) | (s + w > c1 + tol)]
        if len(bad):
            raise AlignmentError(f"Expected section chainages with their band (+- {w:g} m) "
                                 f"within the alignment [{c0:g}, {c1:g}] m, got "
                                 f"{bad[:5].tolist()}.")
    gaps = np.diff(s)
    if len(gaps) and gaps.min() <= 2 * w:
        raise CompareError(f"Expected sections more than two half-widths ({2 * w:g} m) "
                           f"apart, got {gaps.min():g} m between two; bands must not "
                           "overlap.")
    return s


def _approx_chainage(alignment: Alignment, xy: Floats) -> tuple[Floats, Floats]:
    """(approximate chainage (n,), bound on its error (n,)) of plan points xy (n, 2).

    The nearest centreline point c_j (every ``_PRE_STEP_M``) and one step along its
    tangent: s = s_j + a with a = (p - c_j) . t_j. The foot chainage s* solves
    f(s) = (p - c(s)) . t(s) = 0 with f' = -(1 - kappa (p - c) . n), so
    s* - s_j = a / (1 - kappa(xi) e(xi)) for some xi between them, e the offset, and
    |s* - s| <= |a| K A / (1 - K A), K the largest |curvature| and A = r + 2 |a| a
    bound on the offset there (r = |p - c_j|), valid while K A < 1/2; beyond that the
    bound is infinite (the point goes to ``to_local``)."""
    from scipy.spatial import cKDTree

    c0, c1 = alignment.chainage_range
    n = max(2, int(np.ceil((c1 - c0) / _PRE_STEP_M)) + 1)
    sj = np.linspace(c0, c1, n)
    cxy, th, _ = alignment.plan(sj)
    kmax = float(max(np.abs(np.concatenate([[e.k_start, e.k_end]
                                            for e in alignment.elements])).max(), 0.0))
    r, j = cKDTree(cxy).query(xy)
    d = xy - cxy[j]
    a = d[:, 0] * np.cos(th[j]) + d[:, 1] * np.sin(th[j])
    ka = kmax * (r + 2.0 * np.abs(a))
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.where(ka < 0.5, np.abs(a) * ka / (1.0 - ka), np.inf)
    return sj[j] + a, err + 1e-9 * max(1.0, abs(c1))


class _Bands:
    """Accumulates the points of each band over chunks (bottom-k thinning)."""

    def __init__(self, alignment: Alignment, chainages: Floats, half_width_m: float,
                 max_points: int, seed: int) -> None:
        if int(max_points) < 1:
            raise CompareError(f"Expected `max_points` >= 1, got {max_points}.")
        self.al = alignment
        self.s = chainages
        self.w = half_width_m
        self.cap = int(max_points)
        self.rng = np.random.default_rng(seed)
        self.yz: list[list[Floats]] = [[] for _ in chainages]
        self.keys: list[list[Floats]] = [[] for _ in chainages]
        self.held = np.zeros(len(chainages), np.int64)
        self.seen = np.zeros(len(chainages), np.int64)

    def _nearest(self, s: Floats) -> tuple[NDArray[np.intp], Floats]:
        k = np.clip(np.searchsorted(self.s, s), 1, len(self.s) - 1) if len(self.s) > 1 \
            else np.zeros(len(s), np.intp)
        if len(self.s) > 1:
            left = np.abs(s - self.s[k - 1]) <= np.abs(s - self.s[k])
            k = np.where(left, k - 1, k)
        return k, np.abs(s - self.s[k])

    def add(self, p: Floats) -> None:
        if len(p) == 0:
            return
        sa, err = _approx_chainage(self.al, p[:, :2])
        _, dist = self._nearest(sa)
        near = dist <= self.w + err
        if not near.any():
            return
        s, off, h = self.al.to_local(p[near])
        k, dist = self._nearest(s)
        inb = dist <= self.w
        k, yz = k[inb], np.stack([off[inb], h[inb]], axis=1)
        keys = self.rng.random(len(k))
        for i in np.unique(k):
            m = k == i
            self.yz[i].append(yz[m])
            self.keys[i].append(keys[m])
            self.seen[i] += int(m.sum())
            self.held[i] += int(m.sum())
            if self.held[i] > 2 * self.cap:
                self._thin(i)

    def _thin(self, i: int) -> None:
        yz, keys = np.concatenate(self.yz[i]), np.concatenate(self.keys[i])
        if len(keys) > self.cap:
            keep = np.argpartition(keys, self.cap - 1)[:self.cap]
            yz, keys = yz[keep], keys[keep]
        self.yz[i], self.keys[i] = [yz], [keys]
        self.held[i] = len(keys)

    def cuts(self) -> list[SectionCut]:
        out = []
        for i, s in enumerate(self.s):
            if self.yz[i]:
                self._thin(i)
                yz = self.yz[i][0]
                # Restore the file order's independence: sort by key (a random order).
                yz = yz[np.argsort(self.keys[i][0], kind="stable")]
            else:
                yz = np.empty((0, 2))
            out.append(SectionCut(float(s), self.w, yz, int(self.seen[i])))
        return out


def cut_cloud(points: ArrayLike | Iterable[ArrayLike], alignment: Alignment,
              chainages: ArrayLike, half_width_m: float, *,
              max_points: int = MAX_SECTION_POINTS, seed: int = 0) -> list[SectionCut]:
    """Sections of a cloud: points (n, 3) float64, or an iterable of such chunks.

    Parameters
    ----------
    points : (n, 3) array_like or iterable of (m, 3) arrays
        World coordinates (m), in the alignment's frame (UTM-sized values are fine).
    alignment : Alignment
        The centreline whose chainage and cross-section frame are used.
    chainages : (k,) array_like
        Section chainages (m), e.g. from ``section_chainages``; bands must not overlap.
    half_width_m : float
        Half-width w of each band along the axis (m).
    max_points : int
        Most points kept per section (uniform random subset beyond, seeded).
    seed : int
        Seed of that subset.

    Returns
    -------
    list of SectionCut
        One per chainage (sorted); a band without points has an empty ``yz``
        (``survey.analysis.overbreak`` refuses it with a clear error).
    """
    s = np.sort(np.atleast_1d(np.asarray(chainages, dtype=np.float64)))
    if len(s) == 0:
        raise CompareError("Expected at least one section chainage, got none.")
    c0, c1 = alignment.chainage_range
    w = float(half_width_m)
    if ((s - w < c0 - 1e-9) | (s + w > c1 + 1e-9)).any():
        raise AlignmentError(f"Expected section bands within the alignment [{c0:g}, "
                             f"{c1:g}] m, got chainages {s.tolist()[:5]} +- {w:g} m.")
    bands = _Bands(alignment, s, w, max_points, seed)
    chunks = [points] if isinstance(points, np.ndarray) or not isinstance(points, Iterable) \
        else points
    for chunk in chunks:
        p, _ = as_points(chunk, "points", CompareError)
        bands.add(p)
    return bands.cuts()


def cut_file(path: str | os.PathLike[str], alignment: Alignment, chainages: ArrayLike,
             half_width_m: float, *, max_points: int = MAX_SECTION_POINTS, seed: int = 0,
             mesh_spacing_m: float = MESH_SPACING_M,
             classes: Sequence[int] | None = None) -> list[SectionCut]:
    """Sections of a file: a mesh (PLY with faces, OBJ, STL, OFF) is cut by the section
    planes (``cut_mesh``; ``half_width_m`` unused), a cloud (every format of
    ``sensors.io.cloudread.iter_points``) is streamed chunk by chunk (``cut_cloud``).
    ``classes``: keep only the points of a cloud whose ``classification`` (LAS, or a
    PLY/NPZ/CSV field of that name; ``survey.clouds.segment`` writes lining 64 and
    floor 2) is one of these codes. Raises ``PointFileError`` for an unreadable file
    or a cloud without a classification, ``CompareError`` for classes with a mesh."""
    from sensors.io.ply import read_ply_header
    from sensors.io.cloudread import iter_points, read_reference

    p = Path(path)
    kind = p.suffix.lower()
    is_mesh = kind in MESH_SUFFIXES
    if kind == ".ply" and p.is_file():
        try:
            head = read_ply_header(p)
            is_mesh = any(e.name == "face" and e.count > 0 for e in head.elements)
        except Exception:  # a broken header: iter_points names the problem
            is_mesh = False
    if is_mesh:
        if classes is not None:
            raise CompareError(f"Expected a classified point cloud to keep classes "
                               f"{list(classes)} of, got the mesh '{p}'.")
        v, f = read_reference(p)
        assert f is not None
        return cut_mesh(v, f, alignment, chainages, spacing_m=mesh_spacing_m)
    if classes is None:
        return cut_cloud(iter_points(p), alignment, chainages, half_width_m,
                         max_points=max_points, seed=seed)
    from sensors.io.cloudfields import iter_field

    keep = np.asarray(sorted({int(c) for c in classes}), dtype=np.float64)
    chunks = (xyz[np.isin(c, keep)] for xyz, c in iter_field(p, "classification"))
    return cut_cloud(chunks, alignment, chainages, half_width_m, max_points=max_points,
                     seed=seed)


def _plane_segments(v: Floats, faces: NDArray[np.int64], g: Floats
                    ) -> tuple[Floats, Floats]:
    """End points (m, 3) and (m, 3) of the segments where the triangles ``faces`` of
    vertices v cross the plane g = 0 (g (n,) signed vertex distances). A vertex with
    g = 0 counts as on the positive side (a consistent tie rule, so an edge lying in
    the plane is produced once, by the triangle on its negative side)."""
    pos = g[faces] >= 0.0
    npos = pos.sum(axis=1)
    cross = (npos == 1) | (npos == 2)
    f, pos = faces[cross], pos[cross]
    # The lone vertex (the one on the side with a single vertex) and the other two.
    lone_is_pos = pos.sum(axis=1) == 1
    lone = np.where(lone_is_pos, np.argmax(pos, axis=1), np.argmin(pos, axis=1))
    rows = np.arange(len(f))
    i0 = f[rows, lone]
    i1 = f[rows, (lone + 1) % 3]
    i2 = f[rows, (lone + 2) % 3]

    def on_edge(i: NDArray[np.int64], j: NDArray[np.int64]) -> Floats:
        gi, gj = g[i], g[j]
        u = gi / (gi - gj)
        return v[i] + u[:, None] * (v[j] - v[i])

    return on_edge(i0, i1), on_edge(i0, i2)


def cut_mesh(vertices: ArrayLike, faces: ArrayLike, alignment: Alignment,
             chainages: ArrayLike, *, spacing_m: float = MESH_SPACING_M
             ) -> list[SectionCut]:
    """Sections of a triangle mesh: the polyline where it crosses each section plane
    (vertical, through the centreline point, normal to the plan tangent), sampled at
    the midpoints of pieces no longer than ``spacing_m`` (so every length of the cut
    weighs the same), in the section frame.

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        The mesh's vertices, m.
    faces : (m, 3) array_like of int
        Vertex indices of each triangle.
    alignment : Alignment
        The centreline that places the section planes.
    chainages : (k,) array_like of float
        Section chainages, m, within the alignment.
    spacing_m : float
        Longest piece of the cut polyline that gives one sample, m (default
        ``MESH_SPACING_M``).

    Returns
    -------
    list of SectionCut
        One per chainage, by increasing chainage, ``half_width_m`` 0.

    Notes
    -----
    Only triangles near the plane's chainage are cut (not the tunnel's far side of a
    bend that the infinite plane also meets).
    """
    v, _ = as_points(vertices, "vertices", CompareError)
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or (len(f) and (f.min() < 0 or f.max() >= len(v))):
        raise CompareError(f"Expected faces (m, 3) indexing {len(v)} vertices, got shape "
                           f"{f.shape}.")
    f = f.astype(np.int64)
    h = float(spacing_m)
    if not (np.isfinite(h) and h > 0):
        raise CompareError(f"Expected a positive sampling spacing, got {spacing_m} m.")
    s = np.sort(np.atleast_1d(np.asarray(chainages, dtype=np.float64)))
    c0, c1 = alignment.chainage_range
    if len(s) == 0 or ((s < c0 - 1e-9) | (s > c1 + 1e-9)).any():
        raise AlignmentError(f"Expected section chainages within the alignment [{c0:g}, "
                             f"{c1:g}] m, got {s.tolist()[:5]}.")
    sa, err = _approx_chainage(alignment, v[:, :2])
    edge = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2).max(initial=0.0)
    _, heading, _ = alignment.plan(s)
    cen = alignment.point(s)
    out = []
    for k, sk in enumerate(s):
        near_v = np.abs(sa - sk) <= edge + err
        fk = f[near_v[f].any(axis=1)]
        t = np.array([np.cos(heading[k]), np.sin(heading[k]), 0.0])
        n = np.array([-np.sin(heading[k]), np.cos(heading[k]), 0.0])
        g = (v - cen[k]) @ t
        a, b = _plane_segments(v, fk, g)
        ya, yb = (a - cen[k]) @ n, (b - cen[k]) @ n
        za, zb = a[:, 2] - cen[k, 2], b[:, 2] - cen[k, 2]
        ln = np.hypot(yb - ya, zb - za)
        m = np.maximum(1, np.ceil(ln / h).astype(np.int64))
        seg = np.repeat(np.arange(len(ln)), m)
        j = np.arange(m.sum()) - np.repeat(np.cumsum(m) - m, m)
        u = (j + 0.5) / m[seg]
        yz = np.stack([ya[seg] + u * (yb - ya)[seg], za[seg] + u * (zb - za)[seg]], axis=1)
        out.append(SectionCut(float(sk), 0.0, yz, len(yz)))
    return out
