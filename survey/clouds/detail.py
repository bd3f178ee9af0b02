"""Detail layer: thin attachments along the wall (cables, pipes) as closed tubes.

The tunnel-aware mesh keeps the lining only; a cable 3 cm from the wall is a median
outlier there (the seed study's meshes lost all four cables). Here the points that
``survey.segment`` classes as attachments are grouped in the unrolled lining frame
(chainage s, offset, height): points within ``link_m`` of each other in the cross-
section plane and overlapping along the axis form one attachment. Each one with enough
length becomes a tube: per ``slab_m`` of chainage, a least-squares circle through its points in
the cross-section (the scanner sees the front half of a round cable), smoothed along
the axis by a running median, swept with ``sides`` sides and capped (a closed solid,
faces outward).

``with_detail_layer`` adds those tubes to a reconstructed lining (``survey.clouds.
reconstruct``): the attachments are found by ``segment_tunnel`` on the same alignment,
and the tubes' vertices carry support -1 so a viewer can tell them from the lining.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import median_filter
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from survey.clouds.reconstruct import ReconstructedTunnel
from survey.clouds.segment import ATTACHMENT, segment_tunnel
from survey.world.alignment import Alignment
from survey.world.generator import fan_faces, grid_faces

#: Support of the detail layer's vertices (the lining's are >= 0).
DETAIL_SUPPORT = -1.0


def attachment_tubes(points: ArrayLike, alignment: Alignment, *, link_m: float = 0.03,
                     slab_m: float = 0.25, min_length_m: float = 2.0, min_points: int = 50,
                     sides: int = 8) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Tubes (vertices (n, 3), faces (m, 3)) for attachment points (k, 3); empty
    arrays when none qualifies."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) < min_points:
        return np.empty((0, 3)), np.empty((0, 3), dtype=np.int64)
    s, o, h = alignment.to_local(p)
    # Link points close in the cross-section and within two slabs along the axis.
    q = np.stack([s / (2.0 * slab_m) * link_m, o, h], 1)
    pairs = cKDTree(q).query_pairs(link_m, output_type="ndarray")
    from scipy.sparse import coo_matrix

    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(p), len(p)))
    _, comp = connected_components(g, directed=False)
    verts, faces, n = [], [], 0
    for c in np.unique(comp):
        m = comp == c
        if m.sum() < min_points or np.ptp(s[m]) < min_length_m:
            continue
        slab = np.floor((s[m] - s[m].min()) / slab_m).astype(np.int64)
        rows = np.unique(slab)
        if len(rows) < 3:
            continue
        fits = np.array([_circle(o[m][slab == r], h[m][slab == r]) for r in rows])
        cen, rad = fits[:, :2], fits[:, 2]
        cen = median_filter(cen, size=(5, 1), mode="nearest")
        rad = np.maximum(median_filter(rad, size=5, mode="nearest"), 0.002)
        sc = s[m].min() + (rows + 0.5) * slab_m
        ang = 2 * np.pi * np.arange(sides) / sides
        yo = cen[:, :1] + rad[:, None] * np.cos(ang)[None, :]
        zo = cen[:, 1:] + rad[:, None] * np.sin(ang)[None, :]
        ring = alignment.to_world(np.broadcast_to(sc[:, None], yo.shape), yo, zo)
        ends = alignment.to_world(sc[[0, -1]], cen[[0, -1], 0], cen[[0, -1], 1])
        v = np.concatenate([ring.reshape(-1, 3), ends])
        nr = len(rows) * sides
        f = np.concatenate([grid_faces(len(rows), sides, 0, outward=True),
                            fan_faces(nr, np.arange(sides), False),
                            fan_faces(nr + 1, (len(rows) - 1) * sides + np.arange(sides), True)])
        verts.append(v)
        faces.append(f + n)
        n += len(v)
    if not verts:
        return np.empty((0, 3)), np.empty((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64)


def _circle(y, z, max_radius_m: float = 0.15):
    """(cy, cz, r): algebraic least-squares circle (Kasa 1976) through the visible arc of
    a cable's section (a median of the points would sit 2r/pi in front of the true
    centre); the points' median and spread where the fit is ill-posed."""
    if len(y) >= 5:
        a = np.stack([2 * y, 2 * z, np.ones_like(y)], 1)
        sol, *_ = np.linalg.lstsq(a, y * y + z * z, rcond=None)
        r2 = sol[2] + sol[0] ** 2 + sol[1] ** 2
        if r2 > 0 and np.sqrt(r2) < max_radius_m:
            return np.array([sol[0], sol[1], np.sqrt(r2)])
    cy, cz = np.median(y), np.median(z)
    return np.array([cy, cz, np.quantile(np.hypot(y - cy, z - cz), 0.9) if len(y) else 0])


@dataclass(repr=False)
class DetailedMesh:
    """A reconstructed lining with its detail layer: vertices (n, 3) float64, faces
    (m, 3) int64, support (n,) float64 (points per cell; 0 interpolated;
    ``DETAIL_SUPPORT`` on the tubes) and ``detail_faces``, the number of tube faces
    (the last ones)."""

    vertices: np.ndarray
    faces: np.ndarray
    support: np.ndarray
    detail_faces: int

    def __repr__(self) -> str:
        return (f"DetailedMesh({len(self.vertices):,} vertices, {len(self.faces):,} faces, "
                f"{self.detail_faces:,} of them attachment tubes)")

    def write(self, path: str | Path) -> Path:
        """Binary PLY with a ``support`` vertex property; atomic."""
        from survey.world.mesh import write_ply

        return write_ply(path, self.vertices, self.faces,
                         vertex_fields={"support": self.support})


def with_detail_layer(reconstruction: ReconstructedTunnel, points: ArrayLike,
                      **tubes: Any) -> DetailedMesh:
    """The lining of ``reconstruction`` (a ``ReconstructedTunnel``) plus its points'
    attachments as closed tubes.

    Parameters
    ----------
    reconstruction : ReconstructedTunnel
        Vertices, faces, support, alignment and centre height of the lining.
    points : (n, 3) float64
        The cloud it was made from; ``segment_tunnel`` on the reconstruction's alignment
        picks the attachments.
    **tubes
        Options of ``attachment_tubes`` (``link_m``, ``slab_m``...).
    """
    p = np.asarray(points, dtype=np.float64)
    rec = reconstruction
    cls = segment_tunnel(p, alignment=rec.alignment, centre_height_m=rec.centre_height_m)
    tv, tf = attachment_tubes(p[cls == ATTACHMENT], rec.alignment, **tubes)
    return DetailedMesh(np.concatenate([rec.vertices, tv]),
                        np.concatenate([rec.faces, tf + len(rec.vertices)]).astype(np.int64),
                        np.concatenate([rec.support.astype(np.float64),
                                        np.full(len(tv), DETAIL_SUPPORT)]),
                        len(tf))


__all__ = ["DETAIL_SUPPORT", "DetailedMesh", "attachment_tubes", "with_detail_layer"]
