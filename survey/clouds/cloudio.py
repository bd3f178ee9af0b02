"""Rewriting point clouds chunk by chunk with new coordinates (Helmert transforms,
drift corrections): LAS/LAZ through laspy's chunk reader and writer, binary PLY
through a memory map. Every other field is kept; output is written atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from raytrace.fileio import atomic_writer
from survey.errors import CloudFileError

CHUNK = 1 << 20
LAS_SCALE = 1e-4


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
    data, head = _ply_memmap(src)
    text = [h.decode("ascii", "replace").split() for h in head]
    if len([t for t in text if t and t[0] == "element"]) != 1:
        raise CloudFileError(f"Expected a point-cloud PLY (vertex element only), got "
                             f"'{src}'; transform meshes with their own tools.")
    n = len(data)
    dt = data.dtype
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


def cloud_bounds(path, *, chunk: int = CHUNK):
    """(min (3,), max (3,), count) of a cloud; from the LAS header when it has one."""
    path = Path(path)
    if not path.is_file():
        raise CloudFileError(f"Expected a point cloud, got '{path}' which does not exist.")
    if path.suffix.lower() in (".las", ".laz"):
        import laspy

        with laspy.open(path) as r:
            h = r.header
            _check_las_scale(h, path)
            if h.point_count == 0:
                raise CloudFileError(f"Expected points in '{path}', got an empty cloud.")
            return np.asarray(h.mins, float), np.asarray(h.maxs, float), int(h.point_count)
    lo, hi, n = np.full(3, np.inf), np.full(3, -np.inf), 0
    for xyz in iter_points(path, chunk=chunk):
        lo = np.minimum(lo, xyz.min(axis=0))
        hi = np.maximum(hi, xyz.max(axis=0))
        n += len(xyz)
    if n == 0:
        raise CloudFileError(f"Expected points in '{path}', got an empty cloud.")
    return lo, hi, n


#: Coarsest LAS coordinate scale accepted for tunnel work (m).
MAX_LAS_SCALE = 0.01


def _check_las_scale(header, path):
    sc = np.asarray(header.scales, dtype=np.float64)
    if not (np.isfinite(sc).all() and (sc > 0).all() and (sc <= MAX_LAS_SCALE).all()):
        raise CloudFileError(f"Expected LAS coordinate scales between 0 and "
                             f"{MAX_LAS_SCALE} m, got {sc.tolist()} in '{path}'; the "
                             "coordinates are too coarse (or broken) for tunnel work: "
                             "re-export with a scale of 0.001 m or finer.")


def iter_points(path, *, chunk: int = CHUNK):
    """Coordinates (n, 3) float64 of a cloud, chunk by chunk: LAS/LAZ (laspy chunks),
    binary PLY (memory map), XYZ/TXT/CSV text (x y z in the first three columns),
    NPZ (tunnelsim's fields x, y, z) and E57 (pye57, whole scans: not chunked)."""
    path = Path(path)
    if not path.is_file():
        raise CloudFileError(f"Expected a point cloud, got '{path}' which does not exist.")
    kind = path.suffix.lower()
    if kind in (".las", ".laz"):
        import laspy

        with laspy.open(path) as r:
            _check_las_scale(r.header, path)
            for pts in r.chunk_iterator(chunk):
                yield np.stack([np.asarray(pts.x), np.asarray(pts.y), np.asarray(pts.z)], 1)
    elif kind == ".ply":
        data, _ = _ply_memmap(path)
        for i in range(0, len(data), chunk):
            c = data[i:i + chunk]
            yield np.stack([c["x"], c["y"], c["z"]], 1).astype(np.float64)
    elif kind in (".xyz", ".txt", ".csv"):
        delim = "," if kind == ".csv" else None
        with open(path) as fh:
            while True:
                try:
                    a = np.loadtxt(fh, delimiter=delim, max_rows=chunk, ndmin=2,
                                   usecols=(0, 1, 2), comments="#")
                except ValueError as exc:
                    raise CloudFileError(f"Expected numeric x y z columns in '{path}', got "
                                         f"unreadable text ({exc}).") from exc
                if len(a) == 0:
                    break
                yield a
    elif kind == ".npz":
        d = np.load(path)
        for i in range(0, len(d["x"]), chunk):
            yield np.stack([d["x"][i:i + chunk], d["y"][i:i + chunk],
                            d["z"][i:i + chunk]], 1)
    elif kind == ".e57":
        import pye57

        e = pye57.E57(str(path))
        for s_ in range(e.scan_count):
            d = e.read_scan(s_, ignore_missing_fields=True)   # world frame (pose applied)
            yield np.stack([d["cartesianX"], d["cartesianY"], d["cartesianZ"]], 1)
    else:
        raise CloudFileError(f"Expected a .las, .laz, .ply, .xyz, .txt, .csv, .npz or .e57 "
                             f"cloud, got '{path}'.")


def _ply_memmap(src):
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
    if not elems or elems[0][1] != "vertex":
        raise CloudFileError(f"Expected a PLY whose first element is 'vertex', got '{src}'.")
    n = int(elems[0][2])
    fields = []
    for t in text:
        if t and t[0] == "element" and t[1] != "vertex":
            break
        if t and t[0] == "property":
            if t[1] == "list":
                raise CloudFileError(f"Expected scalar vertex properties in '{src}'.")
            fields.append((t[2], _PLY[t[1]]))
    return np.memmap(src, dtype=np.dtype(fields), mode="r", offset=start, shape=(n,)), head


def write_points_las(path, xyz, extra=None, classification=None):
    """Write points (n, 3) as LAS/LAZ 1.4 (format 6, 0.1 mm scale, offset near the data)
    with optional extra dimensions {name: (n,) array} and classification codes (n,);
    atomic."""
    import laspy

    path = Path(path)
    xyz = np.asarray(xyz, dtype=np.float64)
    head = laspy.LasHeader(point_format=6, version="1.4")
    head.scales = np.full(3, LAS_SCALE)
    head.offsets = np.round((xyz[0] if len(xyz) else np.zeros(3)) / 1000.0) * 1000.0
    extra = extra or {}
    head.add_extra_dims([laspy.ExtraBytesParams(name=k, type=np.asarray(v).dtype)
                         for k, v in extra.items()])
    with atomic_writer(path) as fh:
        with laspy.open(fh, mode="w", header=head, closefd=False,
                        do_compress=path.suffix.lower() == ".laz") as w:
            for i in range(0, max(len(xyz), 1), CHUNK):
                rec = laspy.ScaleAwarePointRecord.zeros(len(xyz[i:i + CHUNK]), header=head)
                for k, name in enumerate("XYZ"):
                    rec.array[name] = np.round((xyz[i:i + CHUNK, k] - head.offsets[k]) /
                                               LAS_SCALE)
                rec.array["bit_fields"] = 0x11
                if classification is not None:
                    rec.array["classification"] = np.asarray(classification)[i:i + CHUNK]
                for k, v in extra.items():
                    rec.array[k] = np.asarray(v)[i:i + CHUNK]
                w.write_points(rec)
    return path


def annotate_las(src, dst, fn, *, chunk: int = CHUNK) -> int:
    """Write ``dst`` = LAS/LAZ ``src`` with every point record kept (coordinates, intensity,
    GPS time, classification, extra bytes, VLRs) plus the extra dimensions that
    ``fn(xyz (n, 3))`` returns as {name: (n,) array}, chunk by chunk; an input extra
    dimension of the same name is replaced. Atomic. Returns the point count."""
    import laspy

    src, dst = Path(src), Path(dst)
    if src.suffix.lower() not in (".las", ".laz") or dst.suffix.lower() not in (".las",
                                                                                 ".laz"):
        raise CloudFileError(f"Expected .las/.laz input and output, got '{src}' -> '{dst}'.")
    n = 0
    with laspy.open(src) as reader:
        head = reader.header
        _check_las_scale(head, src)
        writer = None
        with atomic_writer(dst) as fh:
            try:
                for pts in reader.chunk_iterator(chunk):
                    xyz = np.stack([np.asarray(pts.x), np.asarray(pts.y),
                                    np.asarray(pts.z)], 1)
                    extra = {k: np.asarray(v) for k, v in fn(xyz).items()}
                    if writer is None:
                        keep = [e for e in head.point_format.extra_dimension_names
                                if e not in extra]
                        fmt = laspy.PointFormat(head.point_format.id)
                        out_head = laspy.LasHeader(point_format=fmt, version=head.version)
                        out_head.vlrs.extend(v for v in head.vlrs if not isinstance(
                            v, laspy.vlrs.known.ExtraBytesVlr))
                        out_head.scales, out_head.offsets = head.scales, head.offsets
                        dims = [laspy.ExtraBytesParams(name=e, type=pts.array.dtype[e])
                                for e in keep]
                        dims += [laspy.ExtraBytesParams(name=k, type=v.dtype)
                                 for k, v in extra.items()]
                        out_head.add_extra_dims(dims)
                        writer = laspy.open(fh, mode="w", header=out_head, closefd=False,
                                            do_compress=dst.suffix.lower() == ".laz")
                    rec = laspy.ScaleAwarePointRecord.zeros(len(xyz), header=writer.header)
                    for name in rec.array.dtype.names:
                        if name in extra:
                            rec.array[name] = extra[name]
                        elif name in pts.array.dtype.names:
                            rec.array[name] = pts.array[name]
                    writer.write_points(rec)
                    n += len(xyz)
                if writer is None:
                    raise CloudFileError(f"Expected points in '{src}', got none.")
            finally:
                if writer is not None:
                    writer.close()
    return n
