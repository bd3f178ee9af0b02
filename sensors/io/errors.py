"""Errors of the file-format layer: one class per kind of file problem.

Every class is a ``TunnelsimError`` (the root shared by raytrace, sensors and survey)
and a ``ValueError``; all of them are ``FileFormatError``, so that a caller that only
wants to know "the file is bad" catches one class. Messages follow the house pattern:
what was expected, what was got, what to do.

=====================  ==========================================================
``PointFileError``     a point cloud (LAS/LAZ, COPC, PLY, E57, XYZ/TXT/CSV, NPZ,
                       ROS 2 bag) cannot be read or written as asked
``MeshFileError``      a triangle-mesh file (PLY, OBJ, STL, glTF, DAE ...) cannot be
                       read as a mesh
``TableFileError``     a text table (control points, trajectories) cannot be read
``TunnelFileError``    a tunnel file (tunnel JSON, LandXML, axis CSV) is missing,
                       unreadable or not one of ours
=====================  ==========================================================

``raytrace.SceneFileError`` (the engine's own cache format) sits below this layer and
is not a ``FileFormatError``.
"""

from __future__ import annotations

from raytrace.errors import TunnelsimError

__all__ = ["FileFormatError", "MeshFileError", "PointFileError", "TableFileError",
           "TunnelFileError"]


class FileFormatError(TunnelsimError, ValueError):
    """A file cannot be read or written as asked (the root of the file errors)."""


class PointFileError(FileFormatError):
    """A point-cloud file cannot be written or read as asked."""


class MeshFileError(FileFormatError):
    """A triangle-mesh file is missing, unreadable, empty or holds no triangles."""


class TableFileError(FileFormatError):
    """A text table (control points, a trajectory) cannot be read as asked."""


class TunnelFileError(FileFormatError):
    """A tunnel file is missing, unreadable or not one of ours."""
