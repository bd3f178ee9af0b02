"""``ClosestPoints``: the nearest triangle of a batch of points, as ``Scene.closest``
returns it.

Everything is per point, in input order. Lengths are in the units of the scene's
vertices (metres in tunnelsim).

>>> from raytrace import Scene
>>> scene = Scene([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
>>> near = scene.closest([0.25, 0.25, -2.0])
>>> near.distance, near.triangle, near.points
(array([2.]), array([0]), array([[0.25, 0.25, 0.  ]]))
>>> near.signed_distance
array([-2.])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["ClosestPoints"]


@dataclass(frozen=True, eq=False)
class ClosestPoints:
    """Nearest triangle of each of n points (built by ``Scene.closest``, not by hand).

    Attributes
    ----------
    distance : (n,) float64
        Euclidean distance from the point to the mesh, >= 0.
    triangle : (n,) int64
        Row of the nearest face in the ``faces`` array given to the scene; of several
        at exactly the same distance, the lowest row.
    points : (n, 3) float64
        The closest point of that face, world frame (``point - offset``).
    offset : (n, 3) float64
        ``point - closest point``, computed in the scene's local frame (exact for a
        point that is a vertex: zeros); its norm is ``distance``.
    side : (n,) float64
        +1.0 where ``offset`` points to the side of the face's normal
        (b - a) x (c - a) (vertices in their given order) or lies in its plane (a point
        on the surface), -1.0 where it points against it: the sign of a signed
        cloud-to-mesh distance.
    """

    distance: NDArray[np.float64]
    triangle: NDArray[np.int64]
    points: NDArray[np.float64]
    offset: NDArray[np.float64]
    side: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.distance.shape[0])

    def __repr__(self) -> str:
        return f"ClosestPoints({len(self):,} points)"

    @property
    def signed_distance(self) -> NDArray[np.float64]:
        """(n,) float64: ``side * distance``, positive on the normal's side."""
        return np.asarray(self.side * self.distance)
