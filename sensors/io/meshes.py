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

from sensors.io.errors import PointFileError
from .ply import read_ply_header

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
    _check_ply_mesh(path)
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


def _check_ply_mesh(path: Path) -> None:
    """Refuse a binary PLY that is cut short, corrupt or has no faces, with the reason
    (records promised and held) rather than the mesh library's; ASCII PLY is left to
    trimesh, which reads it."""
    with open(path, "rb") as fh:
        head = fh.read(512)
    if b"format ascii" in head:
        return
    try:
        header = read_ply_header(path)
    except PointFileError as exc:
        raise SceneFileError(str(exc)) from None
    faces = [e for e in header.elements if e.name == "face"]
    if not faces or faces[0].count == 0:
        n = sum(e.count for e in header.elements if e.name == "vertex")
        raise SceneFileError(f"Expected a triangle mesh in '{path}', got a PLY with {n:,} "
                             "vertices and no faces (a point cloud?); pass a mesh with "
                             "faces (PLY, OBJ, STL), or reconstruct one with 'tunnelsim "
                             "mesh'.")
