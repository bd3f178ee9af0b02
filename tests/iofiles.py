"""Point-cloud files in the shapes other writers make, and the damage a file takes on
the way (cut short, zeroed, re-counted, byte-flipped), for the I/O tests.

Built with laspy, pye57 and plain bytes, never with tunnelsim's own writers, so that
the readers are checked against files they did not make.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

#: Byte offsets in a LAS public header block (LAS 1.4 R15, table 3).
LAS_LEGACY_COUNT = 107
LAS_BOUNDS = 179           # max x, min x, max y, min y, max z, min z (float64)
LAS_COUNT_14 = 247


def _vlr_list(items):
    from laspy.vlrs.vlrlist import VLRList

    return VLRList(items)


def tunnel_points(n: int = 600, seed: int = 0, origin=(2_600_000.0, 1_200_000.0, 400.0)
                  ) -> np.ndarray:
    """(n, 3) points on a 3 m radius tube along x (20 m long) around ``origin``."""
    rng = np.random.default_rng(seed)
    s = rng.uniform(0.0, 20.0, n)
    a = rng.uniform(0.0, 2 * np.pi, n)
    r = 3.0 + rng.normal(0.0, 0.002, n)
    return np.stack([s, r * np.cos(a), 1.5 + r * np.sin(a)], 1) + np.asarray(origin)


def las_file(path, xyz=None, *, version: str = "1.4", point_format: int = 6,
             scale: float = 0.001, extra: bool = False, vlr: bool = False,
             evlr: bool = False, seed: int = 0):
    """A LAS/LAZ (by suffix) written by laspy; returns the ``laspy.LasData``.

    ``extra`` adds extra bytes (a float32 and a 3-element uint16 dimension), ``vlr`` a
    custom VLR, ``evlr`` a custom EVLR (LAS 1.4). Intensity, GPS time (where the
    format has it), classification and RGB (where it has it) are filled.
    """
    import laspy

    xyz = tunnel_points(seed=seed) if xyz is None else np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    rng = np.random.default_rng(seed + 1)
    head = laspy.LasHeader(point_format=point_format, version=version)
    head.scales = np.full(3, scale)
    head.offsets = np.round(xyz.min(axis=0)) if n else np.zeros(3)
    head.system_identifier = "other writer"
    head.generating_software = "tests/iofiles.py"
    if extra:
        head.add_extra_dims([laspy.ExtraBytesParams(name="amplitude", type=np.float32),
                             laspy.ExtraBytesParams(name="rgb16", type="3u2")])
    if vlr:
        head.vlrs.append(laspy.VLR(user_id="OtherWriter", record_id=42,
                                   description="custom", record_data=b"keep me, please"))
    las = laspy.LasData(head)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.intensity = rng.integers(0, 65535, n)
    las.classification = rng.integers(0, 20, n)
    dims = las.point_format.dimension_names
    if "gps_time" in dims:
        las.gps_time = np.sort(rng.uniform(1e5, 1e5 + 60.0, n))
    if "red" in dims:
        las.red, las.green, las.blue = rng.integers(0, 65535, (3, n))
    if extra:
        las.amplitude = rng.normal(0, 1, n).astype(np.float32)
        las.rgb16 = rng.integers(0, 65535, (n, 3)).astype(np.uint16)
    if evlr:
        las.evlrs = _vlr_list([laspy.VLR(user_id="OtherWriter", record_id=7,
                                             description="big custom",
                                             record_data=bytes(range(256)) * 300)])
    las.write(str(path))
    return las


def copc_file(path, xyz=None):
    """A LAZ 1.4 (format 6) carrying a COPC info VLR and a hierarchy EVLR, as PDAL's
    ``.copc.laz`` does (the octree itself is not needed to read the points)."""
    import laspy

    xyz = tunnel_points(seed=3) if xyz is None else xyz
    head = laspy.LasHeader(point_format=6, version="1.4")
    head.scales = np.full(3, 0.001)
    head.offsets = np.round(xyz.min(axis=0))
    head.vlrs.insert(0, laspy.VLR(user_id="copc", record_id=1, description="copc info",
                                  record_data=bytes(160)))
    las = laspy.LasData(head)
    las.x, las.y, las.z = xyz.T
    las.gps_time = np.linspace(0.0, 1.0, len(xyz))
    las.evlrs = _vlr_list([laspy.VLR(user_id="copc", record_id=1000,
                                         description="EPT hierarchy",
                                         record_data=bytes(32))])
    las.write(str(path), do_compress=True)
    return las


def waveform_las13(path, xyz=None):
    """A LAS 1.3, point format 4, with internal waveform data: one EVLR after the
    points (LASF_Spec 65535) that the header points at and the points index into."""
    import laspy

    xyz = tunnel_points(n=50, seed=4) if xyz is None else xyz
    n = len(xyz)
    head = laspy.LasHeader(point_format=4, version="1.3")
    head.scales = np.full(3, 0.001)
    head.offsets = np.round(xyz.min(axis=0))
    head.global_encoding.waveform_data_packets_internal = True
    las = laspy.LasData(head)
    las.x, las.y, las.z = xyz.T
    las.gps_time = np.arange(n, dtype=float)
    las.wavepacket_index = np.ones(n, dtype=np.uint8)
    las.wavepacket_offset = 60 + np.arange(n) * 16
    las.wavepacket_size = np.full(n, 16, dtype=np.uint32)
    las.write(str(path))
    packets = bytes((i * 7) % 256 for i in range(16 * n))
    with open(path, "r+b") as fh:
        pos = fh.seek(0, 2)
        fh.write(struct.pack("<H16sHQ32s", 0, b"LASF_Spec", 65535, len(packets),
                             b"waveform packets"))
        fh.write(packets)
        fh.seek(227)
        fh.write(struct.pack("<Q", pos))
    return packets


def set_las_count(path, n: int) -> None:
    """Make a LAS header claim ``n`` points (both counts of LAS 1.4)."""
    with open(path, "r+b") as fh:
        fh.seek(24)
        minor = fh.read(2)[1]
        fh.seek(LAS_LEGACY_COUNT)
        fh.write(struct.pack("<I", min(n, 2**32 - 1) if minor < 4 else 0))
        if minor >= 4:
            fh.seek(LAS_COUNT_14)
            fh.write(struct.pack("<Q", n))


def scale_las_bounds(path, factor: float) -> None:
    """Multiply the header's stored bounds by ``factor`` (the points stay)."""
    with open(path, "r+b") as fh:
        fh.seek(LAS_BOUNDS)
        b = np.frombuffer(fh.read(48), dtype="<f8") * factor
        fh.seek(LAS_BOUNDS)
        fh.write(b.astype("<f8").tobytes())


def set_las_offset_nan(path) -> None:
    """Give the header a NaN x offset (every x would be NaN)."""
    with open(path, "r+b") as fh:
        fh.seek(155)
        fh.write(struct.pack("<d", float("nan")))


def ply_cloud(path, xyz, *, big_endian: bool = False, extra: dict | None = None) -> None:
    """A binary PLY point cloud with double x, y, z (+ ``extra`` float32 fields)."""
    order = ">" if big_endian else "<"
    fields = [("x", order + "f8"), ("y", order + "f8"), ("z", order + "f8")]
    fields += [(k, order + "f4") for k in (extra or {})]
    rec = np.empty(len(xyz), dtype=fields)
    rec["x"], rec["y"], rec["z"] = np.asarray(xyz, dtype=np.float64).T
    for k, v in (extra or {}).items():
        rec[k] = v
    names = {"f8": "double", "f4": "float"}
    head = ["ply", f"format binary_{'big' if big_endian else 'little'}_endian 1.0",
            "comment other writer", f"element vertex {len(xyz)}"]
    head += [f"property {names[t[1:]]} {n}" for n, t in fields]
    head.append("end_header")
    Path(path).write_bytes(("\n".join(head) + "\n").encode() + rec.tobytes())


def ply_mesh(path, vertices, faces) -> None:
    """A binary little-endian PLY triangle mesh (float x, y, z; int indices)."""
    v = np.asarray(vertices, dtype="<f4")
    f = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    f["n"], f["i"] = 3, faces
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(v)}",
            "property float x", "property float y", "property float z",
            f"element face {len(f)}", "property list uchar int vertex_indices",
            "end_header"]
    Path(path).write_bytes(("\n".join(head) + "\n").encode() + v.tobytes() + f.tobytes())


def set_ply_count(path, n: int) -> None:
    """Make a PLY header claim ``n`` vertices."""
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode().split("\n")
    lines = [f"element vertex {n}" if ln.startswith("element vertex") else ln
             for ln in lines]
    Path(path).write_bytes("\n".join(lines).encode() + data[end:])


def e57_file(path, scans, poses=None) -> None:
    """An E57 (pye57) with one scan per (n, 3) array in ``scans``; ``poses`` (w, x, y, z
    quaternion, translation) per scan, identity by default."""
    import pye57

    e = pye57.E57(str(path), mode="w")
    for i, xyz in enumerate(scans):
        rot, tr = (np.array([1.0, 0, 0, 0]), np.zeros(3)) if poses is None else poses[i]
        xyz = np.asarray(xyz, dtype=np.float64)
        e.write_scan_raw({"cartesianX": xyz[:, 0], "cartesianY": xyz[:, 1],
                          "cartesianZ": xyz[:, 2]}, name=f"scan {i}", rotation=rot,
                         translation=tr)
    e.close()


def e57_empty_scan(path) -> None:
    """An E57 whose only scan holds no points (libE57Format cannot read it back)."""
    import pye57
    from pye57 import libe57

    e = pye57.E57(str(path), mode="w")
    f = e.image_file
    scan = libe57.StructureNode(f)
    scan.set("guid", libe57.StringNode(f, "{00000000-0000-0000-0000-00000000e057}"))
    proto = libe57.StructureNode(f)
    for c in ("cartesianX", "cartesianY", "cartesianZ"):
        proto.set(c, libe57.FloatNode(f, 0.0, libe57.E57_DOUBLE))
    points = libe57.CompressedVectorNode(f, proto, libe57.VectorNode(f, True))
    scan.set("points", points)
    e.data3d.append(scan)
    _, buffers = e.make_buffers(["cartesianX", "cartesianY", "cartesianZ"], 1)
    points.writer(buffers).close()
    e.close()


def truncate(path, keep: float) -> None:
    """Cut a file to ``keep`` bytes (int) or to that share of its size (float)."""
    data = Path(path).read_bytes()
    n = int(len(data) * keep) if isinstance(keep, float) else keep
    Path(path).write_bytes(data[:n])


def zeros_after_signature(path, n: int = 400) -> None:
    """``LASF`` followed by zeros (a header that was never filled in)."""
    Path(path).write_bytes(b"LASF" + bytes(n))


def report_body(path) -> list[str]:
    """A report's lines less its header's "computed (UTC)" line: the one line two runs
    of the same computation may write differently (survey.report.header)."""
    from pathlib import Path

    return [ln for ln in Path(path).read_text(encoding="utf-8").splitlines()
            if "computed (UTC)" not in ln]


def mesh_fields(path) -> dict:
    """A mesh file as one dict: ``vertices``, ``faces`` and every vertex and face
    property by name (the shape the mesh tests compare), read by the one mesh loader
    ``sensors.io.meshes.read_mesh``."""
    from sensors.io.meshes import read_mesh

    m = read_mesh(path)
    return {"vertices": m.vertices, "faces": m.faces, **m.vertex_fields, **m.face_fields}
