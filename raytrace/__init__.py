"""raytrace: exact ray casting against triangle meshes (binned SAH BVH, Möller–Trumbore),
in NumPy + Numba. Knows nothing about sensors.

>>> import numpy as np
>>> from raytrace import Scene
>>> scene = Scene([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
>>> hits = scene.cast([0.25, 0.25, 1.0], [[0, 0, -1]])
>>> float(hits.t[0]), int(hits.triangle[0])
(1.0, 0)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports

__version__ = "0.2.0"

# Public names are imported on first use: ``import raytrace.errors`` (which every
# command-line start does) must not compile or load Numba.
_EXPORTS = {
    "raytrace.scene": ("Scene", "Hits"),
    "raytrace.errors": ("TunnelsimError", "MeshError", "RayError", "SceneFileError"),
    "raytrace.config": ("set_threads", "threads"),
}


if TYPE_CHECKING:  # the same names, eagerly, for type checkers and IDEs
    from raytrace.scene import Scene, Hits
    from raytrace.errors import TunnelsimError, MeshError, RayError, SceneFileError
    from raytrace.config import set_threads, threads

__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
