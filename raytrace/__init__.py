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

from raytrace.lazy import lazy_exports_of

__version__ = "0.2.0"

# Public names are imported on first use: ``import raytrace.errors`` (which every
# command-line start does) must not compile or load Numba.
# The one list of public names: type checkers and IDEs import them here; the
# façade reads this block (raytrace.lazy.lazy_exports_of) and imports each on first use.
if TYPE_CHECKING:
    from raytrace.scene import Scene
    from raytrace.hits import Hits
    from raytrace.closest import ClosestPoints
    from raytrace.errors import (TunnelsimError, ConfigError, MeshError, RayError,
        SceneFileError)
    from raytrace.config import max_threads, set_threads, threading_info, threads

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__)
