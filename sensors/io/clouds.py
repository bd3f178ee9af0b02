"""Point clouds in and out, chunk by chunk, for the survey commands: one name for the
reading side (``sensors.io.cloudread``: ``iter_points``, ``read_points``,
``read_reference``, ``cloud_bounds``, ``cloud_crs``) and the rewriting side
(``sensors.io.cloudmap``: ``map_cloud``, ``annotate_las``, ``write_points_las``).

Reading takes LAS/LAZ, binary PLY, XYZ/TXT/CSV text, NPZ and E57; a rewrite keeps
every field, VLR and EVLR of its input and is written atomically. Every problem with a
file is a ``PointFileError`` naming the file and the problem. The two modules'
docstrings hold the details (CRS, station poses, field names).
"""

from __future__ import annotations

from sensors.io.cloudmap import (
    E57_KEEP_TOL_M,
    KEEP_CRS,
    LAS_SCALE,
    PoseFn,
    XyzFn,
    annotate_las,
    map_cloud,
    write_points_las,
)
from sensors.io.cloudread import (
    CHUNK,
    INFO_USER,
    MAX_LAS_SCALE,
    SUFFIXES,
    TRIMESH_SUFFIXES,
    cloud_bounds,
    cloud_crs,
    cloud_crs_text,
    iter_points,
    read_points,
    read_reference,
)

__all__ = ["CHUNK", "E57_KEEP_TOL_M", "INFO_USER", "KEEP_CRS", "LAS_SCALE",
           "MAX_LAS_SCALE", "SUFFIXES", "TRIMESH_SUFFIXES", "PoseFn", "XyzFn",
           "annotate_las", "cloud_bounds", "cloud_crs", "cloud_crs_text", "iter_points",
           "map_cloud", "read_points", "read_reference", "write_points_las"]
