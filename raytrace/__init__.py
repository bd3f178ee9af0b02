"""raytrace: exact ray casting against triangle meshes (binned SAH BVH, Möller–Trumbore),
in NumPy + Numba. Knows nothing about sensors.

>>> import numpy as np
>>> from raytrace import Scene
>>> scene = Scene([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
>>> hits = scene.cast([0.25, 0.25, 1.0], [[0, 0, -1]])
>>> float(hits.t[0]), int(hits.triangle[0])
(1.0, 0)
>>> hits
Hits(1 rays, 1 hit)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports

__version__ = "0.2.0"

# Public names are imported on first use: ``import raytrace.errors`` (which every
# command-line start does) must not compile or load Numba.
_EXPORTS = {
    "raytrace.scene": ("Scene",),
    "raytrace.hits": ("Hits",),
    "raytrace.closest": ("ClosestPoints",),
    "raytrace.errors": ("TunnelsimError", "ConfigError", "MeshError", "RayError",
                        "SceneFileError"),
    "raytrace.config": ("max_threads", "set_threads", "threading_info", "threads"),
}


if TYPE_CHECKING:  # the same names, eagerly, for type checkers and IDEs
    from raytrace.scene import Scene
    from raytrace.hits import Hits
    from raytrace.closest import ClosestPoints
    from raytrace.errors import (TunnelsimError, ConfigError, MeshError, RayError,
        SceneFileError)
    from raytrace.config import max_threads, set_threads, threading_info, threads

__getattr__, __dir__, __all__ = lazy_exports(__name__, _EXPORTS)
