"""Small meshes of the defect classes routes meet on meshes users bring (issue 29): a
rough floor with 10-20 cm steps, a passage narrowing to just above the robot's width,
a branching mine with dead ends, a steep ramp, a rough 90 degree bend, and an
artist-made tile whose pieces are not merged at their seams.

Each corridor is a strip: stations along x (``xs``), columns across the floor
(``NCOL`` of them), the floor's height a function of (x, y), vertical walls at the
floor's edges up to a flat roof ``ROOF_M`` above the floor's middle; the ends are left
open (portals). Bends map the strip onto an arc. Everything is built here, from
formulas, so that a test knows the geometry it checks against.
"""

from __future__ import annotations

import numpy as np

NCOL = 12
ROOF_M = 2.5


def strip(xs, half_width, floor_z=None, roof_m=ROOF_M, ncol=NCOL):
    """A corridor along x: vertices (n, 3), faces (m, 3).

    xs : (k,) increasing stations; half_width(x) -> (k,) half widths; floor_z(x, y) ->
    floor heights (vectorised); the roof is flat, ``roof_m`` above the middle of the
    floor at that station, and the walls run from the floor's edge to the roof."""
    xs = np.asarray(xs, dtype=np.float64)
    hw = np.broadcast_to(np.asarray(half_width(xs), dtype=np.float64), xs.shape)
    fz = (lambda x, y: 0.0 * x) if floor_z is None else floor_z
    u = np.linspace(-1.0, 1.0, ncol + 1)
    X = np.repeat(xs[:, None], ncol + 1, axis=1)
    Y = u[None, :] * hw[:, None]
    Z = np.asarray(fz(X, Y), dtype=np.float64) + 0 * X
    roof = np.asarray(fz(xs, 0 * xs), dtype=np.float64) + roof_m + 0 * xs
    k = len(xs)
    floor = np.stack([X, Y, Z], axis=2).reshape(-1, 3)
    top = np.stack([X, Y, np.repeat(roof[:, None], ncol + 1, axis=1)], axis=2).reshape(-1, 3)
    v = np.vstack([floor, top])
    off = len(floor)

    def idx(i, j, t=0):
        return t * off + i * (ncol + 1) + j

    f = []
    for i in range(k - 1):
        for j in range(ncol):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            f += [[a, b, c], [a, c, d]]                                  # floor, up
            a, b, c, d = (idx(i, j, 1), idx(i + 1, j, 1), idx(i + 1, j + 1, 1),
                          idx(i, j + 1, 1))
            f += [[a, c, b], [a, d, c]]                                  # roof, down
        for j, flip in ((0, False), (ncol, True)):                        # walls
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j, 1), idx(i, j, 1)
            f += [[a, c, b], [a, d, c]] if not flip else [[a, b, c], [a, c, d]]
    return v, np.asarray(f, dtype=np.int64)


def bend(v, radius_m):
    """The strip's vertices mapped onto an arc turning left: x -> angle x / radius,
    y -> radius - y from the centre (radius_m, ...) (a straight strip along x from 0)."""
    x, y, z = np.asarray(v, dtype=np.float64).T
    th = x / radius_m
    return np.column_stack([(radius_m - y) * np.sin(th), radius_m - (radius_m - y) *
                            np.cos(th), z])


def rough_floor_steps(seed=0, full_width=False, length_m=12.0, step_m=(0.10, 0.20)):
    """A 3 m wide corridor whose floor has blocks 10-20 cm high between x = 4 and 8 m:
    on its left 65 % (a robot can pass on the right), or across its whole width
    (``full_width``: a single step of ``step_m[1]`` up, then down, at x = 5 and 7 m).
    Steps are near-vertical faces (1 mm long stations)."""
    rng = np.random.default_rng(seed)
    eps = 1e-3
    if full_width:
        h = step_m[1]
        xs = np.unique(np.concatenate([np.arange(0, length_m + 1e-9, 0.25),
                                       [5 - eps, 5, 7 - eps, 7]]))

        def fz(x, y):
            return np.where((x >= 5) & (x < 7 - eps / 2), h, 0.0) + 0 * y
        return strip(xs, lambda x: 1.5 + 0 * x, fz)
    edges = np.arange(4.0, 8.0 + 1e-9, 0.5)
    hts = rng.uniform(*step_m, size=len(edges) - 1)
    xs = np.unique(np.concatenate([np.arange(0, length_m + 1e-9, 0.25), edges - eps,
                                   edges]))

    def fz(x, y):
        k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(hts) - 1)
        inside = (x >= edges[0]) & (x < edges[-1] - eps / 2)
        # the left 65 % of the floor (y > -0.45 m): 1.05 m of level floor on the right
        return np.where(inside & (y > -0.45 + 1e-9), hts[k], 0.0)
    return strip(xs, lambda x: 1.5 + 0 * x, fz, ncol=40)


def narrowing(min_width_m, length_m=12.0):
    """A 3 m wide corridor narrowing (over 2 m each way) to ``min_width_m`` for 1 m
    around x = 6 m."""
    xs = np.arange(0.0, length_m + 1e-9, 0.1)

    def hw(x):
        d = np.clip((np.abs(x - 6.0) - 0.5) / 2.0, 0.0, 1.0)
        return 0.5 * min_width_m + d * (1.5 - 0.5 * min_width_m)
    return strip(xs, hw)


def ramp(grade_deg, length_m=14.0, start_m=4.0, ramp_m=6.0):
    """A 3 m wide corridor, level, then rising at ``grade_deg`` for ``ramp_m``, then
    level again (kinks at x = start_m and start_m + ramp_m)."""
    g = np.tan(np.radians(grade_deg))
    xs = np.arange(0.0, length_m + 1e-9, 0.25)

    def fz(x, y):
        return g * np.clip(x - start_m, 0.0, ramp_m) + 0 * y
    return strip(xs, lambda x: 1.5 + 0 * x, fz)


def rough_bend(seed=0, radius_m=4.0, floor_sigma_m=0.03, wall_sigma_m=0.08):
    """A rough 90 degree bend: a 3 m corridor along a quarter circle of ``radius_m``
    with 2 m straights before and after, its floor rough (Gaussian, ``floor_sigma_m``,
    uncorrelated between stations 0.2 m apart) and its walls pushed in and out by up
    to ``wall_sigma_m`` per station: a SubT-style tile."""
    rng = np.random.default_rng(seed)
    arc = 0.5 * np.pi * radius_m
    total = arc + 4.0
    xs = np.arange(0.0, total + 1e-9, 0.2)
    wob = rng.normal(0.0, wall_sigma_m, size=len(xs))
    bumps = rng.normal(0.0, floor_sigma_m, size=(len(xs), NCOL + 1))

    def fz(x, y):
        if np.ndim(x) == 2:
            return bumps[:x.shape[0]]
        return 0 * x
    v, f = strip(xs, lambda x: 1.5 + np.interp(x, xs, wob), fz)
    # straight 2 m, then the arc (left) about (2, radius_m), then straight 2 m
    x, y, z = v.T
    th = np.clip(x - 2.0, 0.0, arc) / radius_m
    px = np.where(x < 2.0, x, 2.0 + (radius_m - y) * np.sin(th))
    py = np.where(x < 2.0, y, radius_m - (radius_m - y) * np.cos(th)
                  + np.maximum(x - 2.0 - arc, 0.0))
    return np.column_stack([px, py, z]), f


def branching_mine(cell_m=0.5):
    """A mine of 1.5 m drives (3 cells) on a 0.5 m grid: a main drive 12 m along x with
    two side drives that end blind (dead ends, 4 m and 2.5 m) and a cross-cut; open at
    both ends of the main drive."""
    plan = np.zeros((24, 18), dtype=bool)
    plan[:, 6:9] = True            # main drive along x
    plan[5:8, 9:17] = True         # dead end to +y, 4 m
    plan[15:18, 1:6] = True        # dead end to -y, 2.5 m
    plan[10:13, 9:12] = True       # a short stub
    return plan


def unmerged_tiles(v, f, n_tiles=3, gap_m=0.002, seed=0):
    """The mesh cut into ``n_tiles`` pieces along x, each with its own copy of the
    vertices (an artist's tiles: nothing merged), the pieces pulled ``gap_m`` apart at
    every seam (a slit) and their faces shuffled."""
    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f, dtype=np.int64)
    c = v[f].mean(axis=1)[:, 0]
    cuts = np.quantile(c, np.linspace(0, 1, n_tiles + 1)[1:-1])
    tile = np.searchsorted(cuts, c)
    vs, fs, n = [], [], 0
    for k in range(n_tiles):
        ff = f[tile == k]
        used, inv = np.unique(ff, return_inverse=True)
        vv = v[used].copy()
        vv[:, 0] += k * gap_m
        vs.append(vv)
        fs.append(inv.reshape(-1, 3) + n)
        n += len(vv)
    faces = np.vstack(fs)
    rng = np.random.default_rng(seed)
    return np.vstack(vs), faces[rng.permutation(len(faces))]
