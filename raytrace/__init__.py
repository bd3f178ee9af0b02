"""raytrace: exact ray casting against triangle meshes (binned SAH BVH, Möller–Trumbore),
in NumPy + Numba. Knows nothing about sensors.

>>> import numpy as np
>>> from raytrace import Scene
>>> scene = Scene([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
>>> hits = scene.cast([0.25, 0.25, 1.0], [[0, 0, -1]])
>>> float(hits.t[0]), int(hits.triangle[0])
(1.0, 0)
"""

from .config import set_threads, threads
from .errors import MeshError, RayError, SceneFileError, TunnelsimError
from .scene import Hits, Scene

__all__ = ["Scene", "Hits", "MeshError", "RayError", "SceneFileError", "TunnelsimError",
           "set_threads", "threads"]
