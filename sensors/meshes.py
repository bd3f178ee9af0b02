"""Loading a mesh for simulation: the ``raytrace.Scene`` and the per-face reflectivity
(PLY face property ``reflectivity``, as written by the tunnel generator), if any."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from raytrace import Scene
from raytrace.errors import SceneFileError

__all__ = ["load_mesh"]


def load_mesh(path: str | os.PathLike[str]) -> tuple[Scene, NDArray[np.float64] | None]:
    """A mesh file as a ``raytrace.Scene`` and its per-face reflectivity.

    Parameters
    ----------
    path : str or path
        A PLY file (its face property ``reflectivity`` is read, if present) or any
        format ``Scene.from_file`` reads.

    Returns
    -------
    scene : raytrace.Scene
    reflectivity : (n_faces,) float64 or None
        One value in [0, 1] per input face, or None if the file has none.

    Raises
    ------
    raytrace.SceneFileError
        For a missing or unreadable file.
    """
    path = Path(path)
    if not path.is_file():
        raise SceneFileError(f"Expected a mesh file, got '{path}' which does not exist.")
    if path.suffix.lower() != ".ply":
        return Scene.from_file(path), None
    import trimesh

    try:
        mesh: Any = trimesh.load(str(path), force="mesh", process=False)
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
