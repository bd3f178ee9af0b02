"""The one mesh loader: every triangle-mesh file tunnelsim reads comes through
``read_mesh`` (arrays and named per-vertex/per-face fields) or ``load_mesh`` (a
``raytrace.Scene`` ready to cast and the per-face reflectivity); every mesh it writes
goes through ``write_mesh`` (binary PLY, float64 vertices, named fields).

Formats: PLY, binary (read by ``sensors.io.ply``, every property kept) or ASCII (through
trimesh); OBJ, STL, OFF, glTF/GLB and Collada (through trimesh; Collada needs the
optional ``pycollada``). Every problem is a ``MeshFileError`` that names the file and
what to do: a missing file, an unreadable or cut-short one, a PLY without faces (a
point cloud), faces that are not triangles, vertex indices out of range, non-finite
vertices.

>>> import numpy as np, tempfile, pathlib
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> v = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); f = np.array([[0, 1, 2]])
>>> _ = write_mesh(d / "t.ply", v, f, face_fields={"reflectivity": np.float32([0.4])})
>>> m = read_mesh(d / "t.ply")
>>> m.faces.tolist(), m.face_fields["reflectivity"].tolist()
([[0, 1, 2]], [0.4000000059604645])
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from raytrace import Scene

from .errors import MeshFileError, PointFileError
from .ply import read_ply, read_ply_header, write_ply

__all__ = ["MESH_SUFFIXES", "MeshData", "load_mesh", "read_mesh", "write_mesh"]

#: File suffixes ``read_mesh`` reads (PLY by our own reader, the others by trimesh).
MESH_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".glb", ".gltf", ".dae")


@dataclass(frozen=True)
class MeshData:
    """A triangle mesh as read from a file.

    Attributes
    ----------
    vertices : (n, 3) float64
        Vertex coordinates as stored (metres for tunnelsim's own files).
    faces : (m, 3) int64
        Vertex indices of each triangle, in file order.
    vertex_fields, face_fields : dict of str to ndarray
        Every other per-vertex / per-face property of a PLY by name (length n / m:
        ``reflectivity``, ``label``, ``displacement``, ``chainage``, colours ...);
        empty for the formats read through trimesh.
    path : Path
        The file read.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    vertex_fields: dict[str, np.ndarray] = field(default_factory=dict)
    face_fields: dict[str, np.ndarray] = field(default_factory=dict)
    path: Path = Path()


def read_mesh(path: str | os.PathLike[str]) -> MeshData:
    """Read a triangle-mesh file.

    Parameters
    ----------
    path : str or path
        A PLY (binary or ASCII), OBJ, STL, OFF, glTF/GLB or Collada (.dae) file.

    Returns
    -------
    MeshData
        Vertices (n, 3) float64, faces (m, 3) int64 and, for a binary PLY, every other
        vertex and face property by name.

    Raises
    ------
    MeshFileError
        A missing, unreadable or cut-short file, a file without triangles, faces that
        are not triangles, vertex indices out of range, or non-finite vertices.
    """
    path = Path(path)
    if not path.is_file():
        raise MeshFileError(f"Expected a mesh file, got '{path}' which does not exist; "
                            "check the path.")
    if path.suffix.lower() == ".ply" and not _ascii_ply(path):
        mesh = _read_binary_ply(path)
    else:
        mesh = _read_trimesh(path)
    if not np.isfinite(mesh.vertices).all():
        bad = int(np.flatnonzero(~np.isfinite(mesh.vertices).all(axis=1))[0])
        raise MeshFileError(f"Expected finite vertex coordinates in '{path}', got "
                            f"{mesh.vertices[bad].tolist()} at vertex {bad}; repair the mesh "
                            "(CloudCompare, MeshLab) first.")
    return mesh


def load_mesh(path: str | os.PathLike[str]) -> tuple[Scene, NDArray[np.float64] | None]:
    """A mesh file as a ``raytrace.Scene`` and its per-face reflectivity.

    Parameters
    ----------
    path : str or path
        Any file ``read_mesh`` reads; a PLY's face property ``reflectivity`` (as the
        tunnel generator writes it) is returned.

    Returns
    -------
    scene : raytrace.Scene
    reflectivity : (n_faces,) float64 or None
        One value in [0, 1] per input face, or None if the file has none.

    Raises
    ------
    MeshFileError
        As ``read_mesh``.
    """
    mesh = read_mesh(path)
    refl = mesh.face_fields.get("reflectivity")
    if refl is not None:
        refl = np.asarray(refl, dtype=np.float64).reshape(-1)
    return Scene(mesh.vertices, mesh.faces), refl


def _ascii_ply(path: Path) -> bool:
    with open(path, "rb") as fh:
        return b"format ascii" in fh.read(512)


def _read_binary_ply(path: Path) -> MeshData:
    """A binary PLY by ``sensors.io.ply``: the reason for a corrupt or cut-short file
    (records promised and held) rather than a mesh library's."""
    try:
        header = read_ply_header(path)
    except PointFileError as exc:
        raise MeshFileError(str(exc)) from None
    faces_el = [e for e in header.elements if e.name == "face"]
    if not faces_el or faces_el[0].count == 0:
        n = sum(e.count for e in header.elements if e.name == "vertex")
        raise MeshFileError(f"Expected a triangle mesh in '{path}', got a PLY with {n:,} "
                            "vertices and no faces (a point cloud?); pass a mesh with "
                            "faces (PLY, OBJ, STL), or reconstruct one with 'tunnelsim "
                            "mesh'.")
    try:
        elements = read_ply(path)
    except PointFileError as exc:
        raise MeshFileError(str(exc)) from exc
    vert = elements.get("vertex")
    if vert is None or not {"x", "y", "z"} <= set(vert.dtype.names or ()):
        raise MeshFileError(f"Expected a triangle mesh ('vertex' with x, y, z, and "
                            f"'face') in '{path}', got elements {list(elements)}.")
    rec = elements["face"]
    lists = [n for n in rec.dtype.names or () if rec.dtype[n].shape]
    if len(lists) != 1 or rec.dtype[lists[0]].shape != (3,):
        raise MeshFileError(f"Expected triangles only (one list of 3 vertex indices per "
                            f"face) in '{path}'; triangulate it first (MeshLab, Blender, "
                            "CloudCompare).")
    faces = rec[lists[0]].astype(np.int64)
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vert)):
        raise MeshFileError(f"Expected vertex indices in [0, {len(vert)}) in '{path}', got "
                            f"{faces.min()} to {faces.max()}; the file is corrupt.")
    vertices = np.stack([vert["x"], vert["y"], vert["z"]], 1).astype(np.float64)
    vf = {n: vert[n] for n in vert.dtype.names or () if n not in ("x", "y", "z")
          and not vert.dtype[n].shape}
    ff = {n: rec[n] for n in rec.dtype.names or () if n not in lists}
    return MeshData(vertices, faces, vf, ff, path)


def _read_trimesh(path: Path) -> MeshData:
    import trimesh

    if path.suffix.lower() == ".dae":
        try:
            import collada  # noqa: F401  (trimesh reads Collada through pycollada)
        except ImportError:
            raise MeshFileError(f"Expected pycollada to read the Collada file '{path}', "
                                "got it missing; pip install 'tunnelsim[collada]'.") from None
    try:
        mesh: Any = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise MeshFileError(
            f"Expected a mesh file trimesh can read, got '{path}' which failed with "
            f"{type(exc).__name__}: {exc}; convert it to PLY or OBJ.") from exc
    faces = getattr(mesh, "faces", None)
    if faces is None or len(faces) == 0:
        raise MeshFileError(f"Expected triangles in '{path}', got none; is it a point "
                            "cloud? Pass a mesh with faces, or reconstruct one with "
                            "'tunnelsim mesh'.")
    return MeshData(np.asarray(mesh.vertices, dtype=np.float64),
                    np.asarray(faces, dtype=np.int64), {}, {}, path)


def write_mesh(path: str | os.PathLike[str], vertices: NDArray[np.float64],
               faces: NDArray[np.integer[Any]], *,
               vertex_fields: dict[str, np.ndarray] | None = None,
               face_fields: dict[str, np.ndarray] | None = None,
               comments: tuple[str, ...] = ()) -> Path:
    """Write a binary little-endian PLY mesh atomically (a crash leaves no file).

    Parameters
    ----------
    path : str or path
        The ``.ply`` to write.
    vertices : (n, 3) float64
        Stored as float64 (``double``): UTM-sized coordinates keep their millimetres.
    faces : (m, 3) int
        Vertex indices, stored as ``int`` (int32): fewer than 2**31 vertices.
    vertex_fields, face_fields : dict of str to (n,) / (m,) array, optional
        Extra scalar properties, stored with each array's own dtype.
    comments : tuple of str
        Header comment lines.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    MeshFileError
        Bad shapes, too many vertices, or a field of the wrong length or type.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise MeshFileError(f"Expected vertices (n, 3) and faces (m, 3), got {v.shape} "
                            f"and {f.shape}.")
    if len(v) >= 2**31:
        raise MeshFileError(f"Expected fewer than 2**31 vertices for PLY int indices, "
                            f"got {len(v)}.")
    elements = {"vertex": _record(v, (("x", "<f8"), ("y", "<f8"), ("z", "<f8")),
                                  vertex_fields or {}, "vertex"),
                "face": _record(f, (("vertex_indices", "<i4", (3,)),), face_fields or {},
                                "face")}
    try:
        return write_ply(path, elements, comments=comments)
    except PointFileError as exc:
        raise MeshFileError(str(exc)) from exc


def _record(first: np.ndarray, head: tuple[tuple[Any, ...], ...],
            fields: dict[str, np.ndarray], what: str) -> np.ndarray:
    """A structured array of ``first`` (as the ``head`` fields) and ``fields``."""
    arrays = {k: np.asarray(a) for k, a in fields.items()}
    for k, a in arrays.items():
        if a.shape != (len(first),):
            raise MeshFileError(f"Expected the {what} field '{k}' as ({len(first)},), got "
                                f"shape {a.shape}.")
    rec = np.empty(len(first), dtype=[*head, *((k, a.dtype.newbyteorder("<"))
                                               for k, a in arrays.items())])
    if len(head) == 3:
        rec["x"], rec["y"], rec["z"] = first.T
    else:
        rec[head[0][0]] = first
    for k, a in arrays.items():
        rec[k] = a
    return rec
