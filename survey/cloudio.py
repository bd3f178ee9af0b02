"""Rewriting point clouds chunk by chunk with new coordinates (Helmert transforms,
drift corrections): LAS/LAZ through laspy's chunk reader and writer, binary PLY
through a memory map. Every other field is kept; output is written atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from raytrace.errors import TunnelsimError
from raytrace.fileio import atomic_writer

CHUNK = 1 << 20
LAS_SCALE = 1e-4


class CloudFileError(TunnelsimError, ValueError):
    """A point cloud cannot be read or rewritten."""


def map_cloud(src, dst, fn, *, chunk: int = CHUNK) -> int:
    """Write ``dst`` = ``src`` with x, y, z replaced by ``fn(xyz (n, 3), time (n,) or
    None)``. LAS/LAZ (by suffix) or binary little-endian PLY. Returns the point count."""
    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise CloudFileError(f"Expected a point cloud, got '{src}' which does not exist.")
    if not dst.parent.exists():
        raise CloudFileError(f"Expected an existing output folder, got '{dst.parent}'.")
    kind = src.suffix.lower()
    if kind in (".las", ".laz"):
        if dst.suffix.lower() not in (".las", ".laz"):
            raise CloudFileError(f"Expected a .las/.laz output for '{src}', got '{dst}'.")
        return _map_las(src, dst, fn, chunk)
    if kind == ".ply":
        if dst.suffix.lower() != ".ply":
            raise CloudFileError(f"Expected a .ply output for '{src}', got '{dst}'.")
        return _map_ply(src, dst, fn, chunk)
    raise CloudFileError(f"Expected a .las, .laz or .ply cloud, got '{src}'.")


def _map_las(src, dst, fn, chunk):
    import laspy

    n = 0
    with laspy.open(src) as reader:
        head = reader.header
        has_time = "gps_time" in head.point_format.dimension_names
        writer = None
        with atomic_writer(dst) as fh:
            try:
                for pts in reader.chunk_iterator(chunk):
                    xyz = np.stack([np.asarray(pts.x), np.asarray(pts.y),
                                    np.asarray(pts.z)], 1)
                    new = np.asarray(fn(xyz, np.asarray(pts.gps_time) if has_time else None),
                                     dtype=np.float64)
                    if writer is None:
                        out_head = laspy.LasHeader(point_format=head.point_format,
                                                   version=head.version)
                        out_head.vlrs.extend(v for v in head.vlrs
                                             if not isinstance(v, laspy.vlrs.known.ExtraBytesVlr))
                        out_head.scales = np.full(3, min(LAS_SCALE, float(head.scales[0])))
                        first = new[0] if len(new) else np.zeros(3)
                        out_head.offsets = np.round(first / 1000.0) * 1000.0
                        writer = laspy.open(fh, mode="w", header=out_head, closefd=False,
                                            do_compress=dst.suffix.lower() == ".laz")
                    rec = laspy.ScaleAwarePointRecord(pts.array.copy(), head.point_format,
                                                      writer.header.scales,
                                                      writer.header.offsets)
                    for k, name in enumerate("XYZ"):
                        rec.array[name] = np.round((new[:, k] - writer.header.offsets[k]) /
                                                   writer.header.scales[k])
                    writer.write_points(rec)
                    n += len(new)
                if writer is None:
                    writer = laspy.open(fh, mode="w", header=laspy.LasHeader(
                        point_format=head.point_format, version=head.version), closefd=False,
                        do_compress=dst.suffix.lower() == ".laz")
            finally:
                if writer is not None:
                    writer.close()
    return n


_PLY = {"double": "<f8", "float": "<f4", "float64": "<f8", "float32": "<f4", "int": "<i4",
        "uint": "<u4", "uchar": "u1", "char": "i1", "short": "<i2", "ushort": "<u2",
        "int32": "<i4", "uint32": "<u4", "uint8": "u1", "int8": "i1", "int16": "<i2",
        "uint16": "<u2"}


def _map_ply(src, dst, fn, chunk):
    with open(src, "rb") as fh:
        head = []
        while True:
            line = fh.readline()
            if not line:
                raise CloudFileError(f"Expected a PLY header in '{src}'.")
            head.append(line)
            if line.strip() == b"end_header":
                break
        start = fh.tell()
    text = [h.decode("ascii", "replace").split() for h in head]
    if ["format", "binary_little_endian", "1.0"] not in text:
        raise CloudFileError(f"Expected a binary little-endian PLY, got '{src}'.")
    elems = [t for t in text if t and t[0] == "element"]
    if len(elems) != 1 or elems[0][1] != "vertex":
        raise CloudFileError(f"Expected a point-cloud PLY (vertex element only), got "
                             f"'{src}'; transform meshes with their own tools.")
    n = int(elems[0][2])
    fields = [(t[2], _PLY[t[1]]) for t in text if t and t[0] == "property"]
    dt = np.dtype(fields)
    data = np.memmap(src, dtype=dt, mode="r", offset=start, shape=(n,))
    has_time = "time" in dt.names
    with atomic_writer(dst) as out:
        out.write(b"".join(head))
        for i in range(0, n, chunk):
            c = np.array(data[i:i + chunk])
            xyz = np.stack([c["x"], c["y"], c["z"]], 1).astype(np.float64)
            new = np.asarray(fn(xyz, c["time"] if has_time else None), dtype=np.float64)
            c["x"], c["y"], c["z"] = new.T
            out.write(c.tobytes())
    del data
    return n
