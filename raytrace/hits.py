"""``Hits``: the closest hits of a batch of rays, as ``Scene.cast`` returns them.

Everything is per ray, in input order; a miss is ``inf`` / ``-1`` / NaN, never ``None``.
Lengths are in the units of the scene's vertices (metres in tunnelsim), angles in
radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ._kernels.normals import hit_normals
from ._kernels.rays import unit_directions

__all__ = ["Hits"]


class Hits:
    """Closest hit of each of n rays (built by ``Scene.cast``, not by hand).

    Attributes
    ----------
    t : (n,) float64
        Distance from the origin along the normalised direction; ``inf`` on a miss.
    triangle : (n,) int64
        Row of the hit face in the ``faces`` array given to the scene; -1 on a miss.
    u, v : (n,) float64
        Barycentric coordinates: the hit is (1 - u - v) p0 + u p1 + v p2 of the face's
        vertices in their given order (Embree's convention); 0 on a miss.

    Notes
    -----
    Properties ``hit``, ``points``, ``normals`` and ``incidence_rad`` are derived from
    these (the last three computed on first access and kept). Like ``points``, which
    uses the origins passed to ``Scene.cast`` (no copy when they are float64),
    ``directions`` of an (n, 3) float64 batch are normalised on first access from the
    array that was passed: change it in place only after reading what you need.
    """

    def __init__(self, t: NDArray[np.float64], triangle: NDArray[np.int64],
                 u: NDArray[np.float64], v: NDArray[np.float64], *,
                 origins: NDArray[np.float64], directions: NDArray[np.float64],
                 slots: NDArray[np.int64], records: NDArray[np.float64],
                 unit: bool = True) -> None:
        """``origins`` (1, 3) or (n, 3) and unit ``directions`` (n, 3) are the rays as
        cast (world frame); ``slots`` (n,) the hit rows of the scene's triangle
        ``records`` (m, 9), -1 on a miss. ``unit`` False: ``directions`` are the
        caller's checked (finite, non-zero) directions, normalised on first use as the
        cast normalised them (``checks.prepare_rays``)."""
        self.t = t
        self.triangle = triangle
        self.u = u
        self.v = v
        self._origins = origins
        self._directions = directions
        self._unit = unit
        self._slots = slots
        self._records = records
        self._points: NDArray[np.float64] | None = None
        self._normals: NDArray[np.float64] | None = None
        self._incidence: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def __repr__(self) -> str:
        return f"Hits({len(self):,} rays, {int(self.hit.sum()):,} hit)"

    @property
    def hit(self) -> NDArray[np.bool_]:
        """(n,) bool: True where the ray hit a triangle."""
        return self.triangle >= 0

    @property
    def directions(self) -> NDArray[np.float64]:
        """(n, 3) float64: the rays' unit directions, as cast (read-only)."""
        d = self._unit_directions().view()
        d.flags.writeable = False
        return d

    def _unit_directions(self) -> NDArray[np.float64]:
        """The unit directions, normalised on first use (and kept) when the cast left
        that to the traversal. DECISION: the cast keeps the caller's array (as it keeps
        the caller's origins for ``points``) rather than writing 24 bytes a ray that a
        drive's casts never read."""
        if not self._unit:
            u = np.empty_like(self._directions)
            unit_directions(self._directions, u)
            self._directions = u
            self._unit = True
        return self._directions

    @property
    def points(self) -> NDArray[np.float64]:
        """(n, 3) float64: world coordinates of the hits, origin + t * direction; NaN
        on a miss."""
        if self._points is None:
            with np.errstate(invalid="ignore"):
                p = self._origins + self.t[:, None] * self._unit_directions()
            p[~self.hit] = np.nan
            self._points = p
        return self._points

    @property
    def normals(self) -> NDArray[np.float64]:
        """(n, 3) float64: unit geometric normals, (p1 - p0) x (p2 - p0) normalised.

        They follow the faces' winding, not the ray: a ray can meet the back of a face.
        NaN on a miss.
        """
        if self._normals is None:
            nrm = np.empty((len(self), 3))
            hit_normals(self._records, self._slots, nrm)
            self._normals = nrm
        return self._normals

    @property
    def incidence_rad(self) -> NDArray[np.float64]:
        """(n,) float64: angle of incidence in radians, in [0, pi/2]; NaN on a miss.

        The angle between the ray and the surface normal, whichever side of the face
        the ray meets: 0 for a ray square to the surface, pi/2 for a grazing one.
        """
        if self._incidence is None:
            nrm = self.normals
            d = self._unit_directions()
            # arctan2(|d x n|, |d . n|) rather than arccos(|d . n|): accurate at normal
            # incidence too, where arccos loses half the digits (~1e-8 rad).
            cos = np.abs(np.einsum("ij,ij->i", d, nrm))
            sin = np.linalg.norm(np.cross(d, nrm), axis=1)
            self._incidence = np.arctan2(sin, cos)
        return self._incidence
