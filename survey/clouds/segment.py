"""Segmentation of a tunnel cloud into lining, floor, attachments and noise.

The lining is the outermost surface around the axis. Points are unrolled about the
centreline as in ``survey.reconstruct`` (chainage s, angle phi from the crown, radius
rho about the profile centre), cells of ``cell_m`` x ``cell_rad`` take the
``LINING_QUANTILE`` quantile of their radii as the local lining radius R (the lining is
outermost, so attachments in front of it pull a median in and a high quantile much
less), gaps are filled around the rings and along the axis. Each point's residual
rho - R then classifies it:

- |residual| <= ``tol_m``: lining, or floor where the lining's outward normal (from
  the cell radii around the ring) points down within 30 deg (the generator's rule);
- residual < -tol_m and > -``attachment_m``: attachment (cables, pipes, plates, signs);
- residual <= -attachment_m: an object inside the tunnel (people, vehicles);
- residual > tol_m: behind the lining surface: part of a recess (niche, drainage
  channel; classed lining or floor) when at least ``RECESS_SHARE`` of its cell is
  behind too, else noise (multipath, mixed pixels).

The cell radii are smoothed by a running median over ``SMOOTH_CELLS`` so that narrow
attachments (a cable hides the wall behind it) do not define the lining.

Cells need a few points each (``min_points``, default 3; emptier cells are
interpolated): a 2 cm voxelised MLS cloud has tens per 0.25 m x 2 deg cell.

Terrain (issue 18): where the lining ends is found from the data
(``survey.clouds.axis.lining_extent``: per ring, the share of sectors whose radius
agrees with the neighbouring rings' lining drops at a portal); points beyond a portal
end, and points farther out than the lining within ``PORTAL_BAND_M`` of it (the portal
face around the opening), are terrain: the ground in front of a portal, the slope,
vegetation. The lining's radii are estimated from the other points only, so terrain
never defines the lining.

LAS classification codes (written by ``tunnelsim preprocess --segment``): floor 2
(ground), lining 64, attachment 65, object 66, terrain 67 (user-definable range of LAS
1.4), noise 7 (low point, noise).

# DECISION: terrain gets its own code, not 2 (ground: already the tunnel floor, which a
# lining consumer takes with 64) nor 1 (unclassified) or 3-5 (vegetation): ground,
# slope and vegetation outside are not told apart here, and a user who wants only the
# tunnel drops one code.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.clouds.axis import cell_runs, fill_gaps, lining_extent, unroll_extended
from survey.errors import ReconstructionError
from survey.world.alignment import Alignment

#: Class codes (LAS 1.4 classification values).
FLOOR, LINING, ATTACHMENT, OBJECT, TERRAIN, NOISE = 2, 64, 65, 66, 67, 7
CLASS_NAMES = {FLOOR: "floor", LINING: "lining", ATTACHMENT: "attachment",
               OBJECT: "object", TERRAIN: "terrain", NOISE: "noise"}
#: Quantile of the radii in a cell taken as the lining radius.
LINING_QUANTILE = 0.5
#: Running-median window of the lining radius (cells along the axis, around).
SMOOTH_CELLS = (3, 5)
#: A cell with at least this share of its points behind the lining is a recess.
RECESS_SHARE = 0.3
#: Outward normals within this angle of straight down mark the floor.
FLOOR_TILT_RAD = np.deg2rad(30.0)


def segment_tunnel(points: ArrayLike, *, alignment: Alignment | None = None,
                   centre_height_m: float | None = None, cell_m: float = 0.25,
                   cell_rad: float = np.deg2rad(2.0), tol_m: float = 0.02,
                   attachment_m: float = 0.5, min_points: int = 3,
                   portals: bool = True) -> NDArray[np.uint8]:
    """Class code (n,) uint8 per point of a cloud (n, 3) float64 (see module doc).

    Chainages beyond the alignment's ends are measured along the end tangents
    (``extend_chainage``). ``portals``: find where the lining ends and class what lies
    beyond as terrain (False: every point is tunnel, as before issue 18).
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0 or not np.isfinite(p).all():
        raise ReconstructionError(f"Expected a non-empty finite cloud of shape (n, 3), got "
                                  f"{p.shape}.")
    alignment, hc, s, phi, rho = unroll_extended(p, alignment, centre_height_m)
    terrain = (lining_extent(s, phi, rho, ring_m=cell_m).terrain(s, phi, rho) if portals
               else np.zeros(len(p), dtype=bool))
    # The lining's radii come from the tunnel's points only.
    tun = ~terrain
    s_t = s[tun]
    s_lo, s_hi = s_t.min(), s_t.max()
    n_s = max(1, int(np.ceil((s_hi - s_lo) / cell_m)))
    n_a = max(8, int(np.round(2 * np.pi / cell_rad)))
    i = np.clip(((s - s_lo) / max(s_hi - s_lo, 1e-9) * n_s).astype(np.int64), 0, n_s - 1)
    j = np.mod(np.floor((phi + np.pi) / (2 * np.pi / n_a)).astype(np.int64), n_a)
    cell = i * n_a + j
    # Quantile of the radii per cell.
    ids, rs, starts, counts = cell_runs(cell[tun], rho[tun])
    q = rs[starts + np.minimum(counts - 1, (LINING_QUANTILE * counts).astype(np.int64))]
    grid = np.full(n_s * n_a, np.nan)
    ok = counts >= min_points
    grid[ids[ok]] = q[ok]
    grid = fill_gaps(grid.reshape(n_s, n_a), np.arange(n_s, dtype=np.float64))
    if not np.isfinite(grid).all():
        raise ReconstructionError("Expected points around the whole lining, got too few "
                                  "to estimate it; use larger cells.")
    # A running median over SMOOTH_CELLS (axis x around) keeps attachments narrower
    # than half the window (cables, plates) from defining the lining where they hide it.
    from scipy.ndimage import median_filter

    ka = SMOOTH_CELLS[1] // 2
    padded = np.concatenate([grid[:, -ka:], grid, grid[:, :ka]], axis=1)
    grid = median_filter(padded, size=SMOOTH_CELLS, mode="nearest")[:, ka:ka + n_a]
    # Outward normal of the lining around each ring, from neighbouring cell points.
    ac = -np.pi + (np.arange(n_a) + 0.5) * 2 * np.pi / n_a
    yo = grid * np.sin(ac)
    zo = grid * np.cos(ac)
    ty = np.roll(yo, -1, axis=1) - np.roll(yo, 1, axis=1)
    tz = np.roll(zo, -1, axis=1) - np.roll(zo, 1, axis=1)
    ny, nz = tz, -ty
    flip = ny * yo + nz * zo < 0                      # make it point away from the axis
    ny, nz = np.where(flip, -ny, ny), np.where(flip, -nz, nz)
    floor_cell = nz / np.maximum(np.hypot(ny, nz), 1e-12) < -np.cos(FLOOR_TILT_RAD)
    # The lining radius at each point's own angle (linear between cell centres around
    # the ring): a flat floor seen obliquely changes radius by centimetres within a cell.
    a = (phi + np.pi) / (2 * np.pi / n_a) - 0.5
    j0 = np.floor(a).astype(np.int64)
    f = a - j0
    r_at = (1 - f) * grid[i, np.mod(j0, n_a)] + f * grid[i, np.mod(j0 + 1, n_a)]
    res = rho - r_at
    out = np.full(len(p), LINING, dtype=np.uint8)
    out[floor_cell.reshape(-1)[cell]] = FLOOR
    out[res < -tol_m] = ATTACHMENT
    out[res <= -attachment_m] = OBJECT
    # Behind the lining: a recess (niche, drainage channel) when a good share of its
    # cell is behind too (a surface), else noise.
    behind = res > tol_m
    share = np.bincount(cell[tun], weights=behind[tun], minlength=n_s * n_a) / \
        np.maximum(np.bincount(cell[tun], minlength=n_s * n_a), 1)
    out[behind & (share[cell] < RECESS_SHARE)] = NOISE
    out[terrain] = TERRAIN
    return out


__all__ = ["ATTACHMENT", "CLASS_NAMES", "FLOOR", "FLOOR_TILT_RAD", "LINING", "LINING_QUANTILE",
           "NOISE", "OBJECT", "RECESS_SHARE", "SMOOTH_CELLS", "TERRAIN", "segment_tunnel"]
