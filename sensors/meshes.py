"""Loading a mesh for simulation: the ``raytrace.Scene`` and the per-face reflectivity
(PLY face property ``reflectivity``, as written by the tunnel generator), if any."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from raytrace import Scene
from raytrace.errors import SceneFileError


def load_mesh(path):
    """(Scene, reflectivity (m,) float64 or None) from a mesh file."""
    path = Path(path)
    if not path.is_file():
        raise SceneFileError(f"Expected a mesh file, got '{path}' which does not exist.")
    if path.suffix.lower() != ".ply":
        return Scene.from_file(path), None
    import trimesh

    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise SceneFileError(f"Expected a PLY mesh trimesh can read, got '{path}' which "
                             f"failed with: {exc}") from exc
    raw = mesh.metadata.get("_ply_raw", {}).get("face", {}).get("data")
    refl = None
    if raw is not None and raw.dtype.names and "reflectivity" in raw.dtype.names:
        refl = np.asarray(raw["reflectivity"], dtype=np.float64).reshape(-1)
        if len(refl) != len(mesh.faces):
            refl = None
    return Scene(np.asarray(mesh.vertices), np.asarray(mesh.faces)), refl
