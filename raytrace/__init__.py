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

import importlib
from typing import TYPE_CHECKING

__version__ = "0.2.0"

# Public names are imported on first use: ``import raytrace.errors`` (which every
# command-line start does) must not compile or load Numba.
_EXPORTS = {
    "raytrace.scene": ("Scene", "Hits"),
    "raytrace.errors": ("TunnelsimError", "MeshError", "RayError", "SceneFileError"),
    "raytrace.config": ("set_threads", "threads"),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = ["__version__", *_WHERE]

if TYPE_CHECKING:  # the same names, eagerly, for type checkers and IDEs
    from raytrace.scene import Scene, Hits
    from raytrace.errors import TunnelsimError, MeshError, RayError, SceneFileError
    from raytrace.config import set_threads, threads


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'raytrace' has no attribute {name!r}")
    value = getattr(importlib.import_module(_WHERE[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
