"""COPC output: a LAZ 1.4 file whose points are stored as a clustered octree, one
variable-size LAZ chunk per node, so that viewers (potree, QGIS, the copc.io viewer)
and range readers (``laspy.CopcReader``, copc-lib, PDAL) fetch only the nodes of a
region or a level of detail.

The format (COPC 1.0, https://copc.io, Hobu 2021; cited below as "COPC"):

- LAS 1.4, point format 6, 7 or 8, LAZ with variable-size chunks (LASzip VLR chunk
  size 0xFFFFFFFF; the chunk table after the points holds each chunk's point count and
  byte size);
- the ``info`` VLR (user "copc", record 1, 160 bytes) first, at byte 375: octree center
  and half size (world units), root spacing, offset and size of the root hierarchy
  page, GPS time min and max;
- the ``hierarchy`` EVLR (user "copc", record 1000): pages of 32-byte entries
  (level, x, y, z, offset, byte size, point count), here one page.

laspy reads COPC but cannot write it; ``CopcWriter`` writes the octree, the chunks,
the chunk table and the hierarchy itself and lets lazrs compress each node.

The octree (the sampling rule is EPT's and untwine's, stated here exactly so that a
test can recompute it by brute force):

- The cube: the integer (LAS) coordinates' bounding box, grown to a power of two;
  every node boundary lies half a LAS unit between two integer coordinates, so no
  point lies on a boundary and float rounding in a reader cannot move a point to
  another node (laspy and copc-lib compute node bounds from center and half size).
- A node at level l covers 1/2^l of the cube per axis and is divided into a
  ``GRID`` x ``GRID`` x ``GRID`` grid (spacing = node size / ``GRID``).
- Points are taken top-down, in the order they were written: a node whose remaining
  points (those no ancestor took) number at most ``leaf_points`` takes them all (a
  leaf); otherwise it takes the first remaining point of each grid cell and passes the
  rest to its 8 children. At the deepest level (grid cells one LAS unit wide) a node
  takes all it is given (only coincident points get there).
- So level 0 is a 1/``GRID`` overview of the whole cloud, each level doubles the
  density, and every point is stored once.

Memory stays bounded for any number of points: ``write_points`` appends the records
to a spill file (in ``spill_dir``, default the output's folder); ``close`` then builds
the octree one subtree at a time. A node with more than ``max_memory_points`` points
is split by streaming its file: its own points (at most GRID^3) go to its chunk, the
rest to one file per child; a subtree that fits is built in memory. Peak memory is
about ``MEMORY_BYTES_PER_POINT`` x ``max_memory_points`` (pieces read from files and
compression batches are capped by it too), whatever the number of points; peak disk
about twice the raw records (spill + split files) plus the output. Coincident points
beyond ``max_memory_points`` in one deepest cell are streamed through the compressor.
"""

from __future__ import annotations

import contextlib
import copy
import io
import itertools
import os
import shutil
import struct
import tempfile
from pathlib import Path
from typing import IO, Any

import numpy as np

from raytrace.fileio import atomic_writer

from sensors.io.errors import PointFileError
from .las import COPC_USER
from .stream import Stream, deferred_interrupt

__all__ = ["COPC_FORMATS", "GRID", "LEAF_POINTS", "MAX_MEMORY_POINTS", "CopcWriter",
           "assign_levels", "copc_info"]

#: Point formats COPC allows (COPC, "LAS PDRFs 6, 7, or 8").
COPC_FORMATS = (6, 7, 8)
#: Grid cells per node and axis; the root spacing is the cube's size / GRID.
#: ASSUMED: 128, as untwine (PDAL's COPC builder) uses; a power of two (see _Cube).
GRID_BITS = 7
GRID = 1 << GRID_BITS
#: A node with at most this many remaining points keeps them all (no children): fewer,
#: larger chunks than a grid taken down to single points (Entwine's "minimum node
#: size" has the same purpose). ASSUMED: 2^16 (about 1.3 MB of LAZ for full records).
LEAF_POINTS = 1 << 16
#: Default largest subtree built in memory (points).
MAX_MEMORY_POINTS = 1 << 22
#: Peak bytes per point of ``max_memory_points`` while the octree is built, for the
#: 91-byte "full" records: the records and one reordered copy, half-unit coordinates
#: and grid keys (24 bytes each), np.unique's sort, a compression batch. Measured with
#: tracemalloc over ``close`` (2e6 points along a 1 km tunnel): 134 MiB at 2^18, 456
#: MiB at 2^20; peak RSS of a whole 1e7-point run 1.0 GiB at 2^20, 1.8 GiB at 2^22.
MEMORY_BYTES_PER_POINT = 450
#: Raw record bytes compressed in one lazrs call (nodes are compressed in parallel).
COMPRESS_BATCH_BYTES = 1 << 26
#: Records read from a spill file at a time.
READ_POINTS = 1 << 20
#: COPC info VLR layout (COPC, "info VLR"): center x, y, z, halfsize, spacing,
#: root_hier_offset, root_hier_size, gpstime min, max, 11 reserved uint64.
_INFO = struct.Struct("<5d2Q2d88x")
#: Hierarchy entry (COPC, "hierarchy VLR"): VoxelKey (level, x, y, z int32), offset
#: uint64, byteSize int32, pointCount int32.
_ENTRY = struct.Struct("<4iQii")
#: EVLR header (LAS 1.4 R15, table 26): reserved, user id, record id, length, text.
_EVLR = struct.Struct("<H16sHQ32s")
#: A node: (level, x, y, z) as COPC's VoxelKey.
Key = tuple[int, int, int, int]
#: Byte offset of the info VLR's payload: LAS 1.4 header (375) + VLR header (54).
INFO_OFFSET = 375 + 54


class _Cube:
    """The octree cube in integer LAS coordinates, as half-units.

    A point's half-unit coordinate is V = 2 (X - lo) + 1: odd, so that node and grid
    boundaries (even half-units) never hold a point. The cube is [0, 2^h) half-units
    per axis; a node at level l is V >> (h - l), its grid cell V >> (h - l - GRID_BITS).
    The deepest level, ``max_level`` = h - GRID_BITS - 1, has cells 2 half-units (one
    LAS unit) wide: one integer position each.
    """

    def __init__(self, lo: np.ndarray, hi: np.ndarray) -> None:
        self.lo = np.asarray(lo, dtype=np.int64)
        span = int(np.max(np.asarray(hi, dtype=np.int64) - self.lo))
        self.h = max(GRID_BITS + 1, (2 * span + 1).bit_length())
        self.max_level = self.h - GRID_BITS - 1

    def half_units(self, rec: np.ndarray) -> np.ndarray:
        """(n, 3) int64 V of records ``rec`` (fields X, Y, Z)."""
        v = np.empty((len(rec), 3), dtype=np.int64)
        for k, name in enumerate("XYZ"):
            v[:, k] = rec[name]
        v -= self.lo
        v *= 2
        v += 1
        return v

    def world(self, scale: float, offset: np.ndarray) -> tuple[np.ndarray, float]:
        """(center (3,), halfsize) in world units (the cube: 2^(h-1) LAS units wide,
        from lo - 0.5)."""
        halfsize = scale * 2.0 ** (self.h - 2)
        corner = np.asarray(offset, dtype=np.float64) + scale * (self.lo - 0.5)
        return corner + halfsize, halfsize


def _ids(coords: np.ndarray) -> np.ndarray:
    """One int64 id per row of ``coords`` (r, 3) int64 (equal rows, equal ids)."""
    if not len(coords):
        return np.empty(0, dtype=np.int64)
    rel = coords - coords.min(axis=0)
    bits = [int(m).bit_length() for m in rel.max(axis=0)]
    if sum(bits) <= 63:
        return (rel[:, 0] << (bits[1] + bits[2])) | (rel[:, 1] << bits[2]) | rel[:, 2]
    # DECISION: rows too wide to pack (a subtree 21+ levels deep) are numbered by a row
    # sort; slower, and only coincident-point clusters get there.
    return np.unique(rel, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int64)


def assign_levels(v: np.ndarray, level0: int, h: int, leaf_points: int) -> np.ndarray:
    """The octree level of each point (n,) int32 of a subtree, by the module's rule.

    Parameters
    ----------
    v : (n, 3) int64
        Half-unit coordinates (``_Cube.half_units``) of the subtree's points, in the
        order they were written; all inside one node at ``level0``.
    level0 : int
        The subtree root's level.
    h : int
        The cube's size exponent (half-units).
    leaf_points : int
        A node with at most this many remaining points takes them all.
    """
    n = len(v)
    level = np.full(n, -1, dtype=np.int32)
    rem = np.arange(n)
    max_level = h - GRID_BITS - 1
    for lev in range(level0, max_level + 1):
        if not len(rem):
            break
        if lev == max_level:
            take = np.ones(len(rem), dtype=bool)
        else:
            cells = v[rem] >> (h - lev - GRID_BITS)
            _, inv, counts = np.unique(_ids(cells >> GRID_BITS), return_inverse=True,
                                       return_counts=True)
            take = counts[inv.reshape(-1)] <= leaf_points
            # np.unique's return_index is the first occurrence: the first point of
            # each cell in written order (rem is increasing).
            take[np.unique(_ids(cells), return_index=True)[1]] = True
        level[rem[take]] = lev
        rem = rem[~take]
    return level


def _preorder(node: Key, level0: int) -> tuple[list[int], int]:
    """Sort key of a node for a depth-first preorder below level ``level0``: its child
    directions from the top (x bit 0, y bit 1, z bit 2, as laspy's ``VoxelKey.child``),
    then its level (an ancestor before its first descendant)."""
    lev, x, y, z = node
    path = [((x >> s) & 1) | (((y >> s) & 1) << 1) | (((z >> s) & 1) << 2)
            for s in range(lev - level0 - 1, -1, -1)]
    return path, lev


def _bytes(records: np.ndarray) -> np.ndarray:
    """The raw bytes of contiguous records, as the uint8 buffer lazrs takes."""
    return np.ascontiguousarray(records).view(np.uint8)


class _Chunks:
    """The point-data section of the output: node chunks compressed by lazrs, appended
    after the 8-byte chunk-table offset, with the chunk table and hierarchy entries
    kept for the end.

    Nodes are compressed in batches of about ``COMPRESS_BATCH_BYTES`` with
    ``lazrs.ParLasZipCompressor.compress_chunks`` (one variable-size chunk per list
    item, chunks compressed in parallel) into memory; the LAZ stream it returns (offset
    to chunk table, chunks, chunk table; LAZ spec, "chunk table") gives each chunk's
    bytes, which are copied to the file.
    """

    def __init__(self, fh: IO[bytes], laz_vlr: Any, batch_bytes: int, piece: int) -> None:
        self.fh = fh
        self.batch_bytes, self.piece = batch_bytes, piece
        self.vlr = laz_vlr
        self._start = fh.tell() - 8            # the point data: offset, chunks, table
        #: (level, x, y, z, offset, byte size, point count) per node, in file order.
        self.entries: list[tuple[int, int, int, int, int, int, int]] = []
        self._batch: list[tuple[Key, np.ndarray]] = []
        self._batch_bytes = 0

    def add(self, key: Key, records: np.ndarray) -> None:
        """Queue one node's records (a contiguous structured array)."""
        self._batch.append((key, records))
        self._batch_bytes += records.nbytes
        if self._batch_bytes >= self.batch_bytes:
            self.flush()

    def flush(self) -> None:
        import lazrs

        if not self._batch:
            return
        out = io.BytesIO()
        with deferred_interrupt():
            comp = lazrs.ParLasZipCompressor(out, self.vlr)
            comp.compress_chunks([_bytes(r) for _, r in self._batch])
            comp.done()
        self._store([k for k, _ in self._batch], out.getbuffer())
        self._batch, self._batch_bytes = [], 0

    def add_file(self, key: Key, path: Path, dtype: np.dtype,
                 count: int) -> None:
        """One node's records from a raw file, compressed piece by piece into one chunk
        (memory: one piece and the compressed chunk)."""
        import lazrs

        if count <= self.piece:
            self.add(key, np.fromfile(path, dtype=dtype))
            return
        self.flush()
        out = io.BytesIO()
        with deferred_interrupt(), open(path, "rb") as src:
            comp = lazrs.LasZipCompressor(out, self.vlr)
            while len(piece := np.fromfile(src, dtype=dtype, count=self.piece)):
                comp.compress_many(_bytes(piece))
            comp.done()
        self._store([key], out.getbuffer())

    def _store(self, keys: list[Key], laz: memoryview) -> None:
        import lazrs

        table_at = struct.unpack_from("<q", laz, 0)[0]
        table = lazrs.read_chunk_table_only(io.BytesIO(laz[table_at:]), self.vlr)
        if len(table) != len(keys) or 8 + sum(s for _, s in table) != table_at:
            raise PointFileError(f"Expected {len(keys)} LAZ chunks from lazrs, got "
                                 f"{len(table)}; update lazrs.")
        pos = self.fh.tell()
        self.fh.write(laz[8:table_at])
        for key, (count, size) in zip(keys, table):
            self.entries.append((*key, pos, int(size), int(count)))
            pos += int(size)

    def finish(self) -> None:
        """Write the chunk table after the chunks and point the 8-byte offset at the
        start of the point data to it."""
        import lazrs

        self.flush()
        table_at = self.fh.tell()
        lazrs.write_chunk_table(self.fh, [(e[6], e[5]) for e in self.entries], self.vlr)
        self.fh.seek(0, os.SEEK_END)
        end = self.fh.tell()
        self.fh.seek(self._start)
        self.fh.write(struct.pack("<q", table_at))
        self.fh.seek(end)


class CopcWriter(Stream):
    """A COPC file written as a stream of point records; the octree is built on
    ``close``, the file appears at ``path`` only when complete.

    Parameters
    ----------
    path : path-like
        The file (conventionally ``*.copc.laz``).
    header : laspy.LasHeader
        LAS 1.4, point format 6, 7 or 8, equal x, y, z scales; scales and offsets are
        final (records are stored in them). Its VLRs are kept (CRS, tunnelsim
        metadata, extra bytes); COPC and LASzip VLRs in it are replaced.
    max_memory_points : int
        Largest subtree built in memory (see the module notes for the memory bound).
    leaf_points : int
        A node with at most this many remaining points keeps them all; at most
        ``max_memory_points``.
    spill_dir : path-like, optional
        Folder of the temporary spill files (default: ``path``'s folder).

    Notes
    -----
    ``write_points`` takes laspy point records of ``header``'s point format (or the
    structured array they hold). The file's bytes depend only on the header and the
    records in written order, not on how they were chunked nor on
    ``max_memory_points``.
    """

    def __init__(self, path: str | os.PathLike[str], header: Any, *,
                 max_memory_points: int = MAX_MEMORY_POINTS,
                 leaf_points: int = LEAF_POINTS,
                 spill_dir: str | os.PathLike[str] | None = None) -> None:
        self.path = Path(path)
        fmt = header.point_format.id
        version = (header.version.major, header.version.minor)
        if version != (1, 4) or fmt not in COPC_FORMATS:
            raise PointFileError(f"Expected a LAS 1.4 header with point format 6, 7 or 8 "
                                 f"for COPC, got LAS {header.version} format {fmt}.")
        scales = np.asarray(header.scales, dtype=np.float64)
        if not (scales[0] > 0 and (scales == scales[0]).all()):
            raise PointFileError(f"Expected equal positive x, y, z scales for COPC (a "
                                 f"cubic octree), got {scales.tolist()}.")
        if not 1 <= int(leaf_points) <= int(max_memory_points):
            raise PointFileError(f"Expected 1 <= leaf_points <= max_memory_points, got "
                                 f"{leaf_points} and {max_memory_points}.")
        folder = Path(spill_dir) if spill_dir is not None else self.path.parent
        if not self.path.parent.is_dir() or not folder.is_dir():
            raise PointFileError(f"Expected existing folders for '{self.path}' and its "
                                 f"spill files, got '{folder}'; create them first.")
        self.header = copy.deepcopy(header)
        self.header.vlrs = [v for v in self.header.vlrs if str(v.user_id).rstrip("\0")
                            != COPC_USER and type(v).__name__ != "LasZipVlr"]
        # DECISION: the WKT bit is set with or without a CRS record: LAS 1.4 makes WKT
        # the CRS form of point formats 6-10 (R15, "Coordinate Reference System
        # Representation"), and copc-lib refuses a COPC file without the bit.
        self.header.global_encoding.wkt = True
        self.dtype = self.header.point_format.dtype()
        self.max_memory_points = int(max_memory_points)
        self.leaf_points = int(leaf_points)
        self.n_points = 0
        self._lo = np.full(3, np.iinfo(np.int64).max, dtype=np.int64)
        self._hi = np.full(3, np.iinfo(np.int64).min, dtype=np.int64)
        self._gps = [np.inf, -np.inf]
        self._returns = np.zeros(16, dtype=np.int64)
        self._tmp = Path(tempfile.mkdtemp(dir=folder, prefix=f".{self.path.name}."))
        # closed by _finish or _discard
        self._spill = open(self._tmp / "points", "wb")  # noqa: SIM115
        self._names = itertools.count()

    def write_points(self, records: Any) -> None:
        """Append point records (laspy ``PackedPointRecord`` or its structured array)."""
        if not self._open:
            raise PointFileError(f"Expected an open writer for '{self.path}', got a "
                                 "closed one.")
        a = np.asarray(getattr(records, "array", records))
        if a.dtype != self.dtype or a.ndim != 1:
            raise PointFileError(f"Expected (n,) records of point format "
                                 f"{self.header.point_format.id} "
                                 f"({self.dtype.itemsize}-byte records), got {a.shape} of "
                                 f"{a.dtype.itemsize}-byte ones.")
        if not len(a):
            return
        for k, name in enumerate("XYZ"):
            self._lo[k] = min(self._lo[k], int(a[name].min()))
            self._hi[k] = max(self._hi[k], int(a[name].max()))
        gps = a["gps_time"]
        self._gps = [min(self._gps[0], float(gps.min())),
                     max(self._gps[1], float(gps.max()))]
        self._returns += np.bincount(a["bit_fields"] & 0x0F, minlength=16)
        self._spill.write(np.ascontiguousarray(a).data)
        self.n_points += len(a)

    def _finish(self) -> None:
        self._spill.close()
        try:
            with atomic_writer(self.path, "w+b") as fh:
                self._write_file(fh)
        finally:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def _discard(self, exc: BaseException) -> None:
        with contextlib.suppress(OSError):
            self._spill.close()
        shutil.rmtree(self._tmp, ignore_errors=True)

    # -- the file -------------------------------------------------------------------

    def _write_file(self, fh: IO[bytes]) -> None:
        import laspy
        import lazrs

        n = self.n_points
        cube = _Cube(self._lo, self._hi) if n else _Cube(np.zeros(3), np.zeros(3))
        head = self.header
        extra = self.dtype.itemsize - laspy.PointFormat(head.point_format.id).size
        laz = lazrs.LazVlr.new_for_compression(head.point_format.id, extra, True)
        info = laspy.VLR(user_id=COPC_USER, record_id=1, description="copc info",
                         record_data=bytes(_INFO.size))
        head.vlrs = [info, *head.vlrs, laspy.vlrs.known.LasZipVlr(laz.record_data())]
        head.are_points_compressed = True
        head.point_count = n
        head.start_of_first_evlr, head.number_of_evlrs = 0, 1
        head.write_to(fh)
        fh.write(bytes(8))                     # offset to the chunk table, set at the end
        # DECISION: pieces and batches no larger than the in-memory subtree, so that
        # max_memory_points bounds every phase (measured: see MEMORY_BYTES_PER_POINT).
        chunks = _Chunks(fh, laz, min(COMPRESS_BATCH_BYTES,
                                      self.max_memory_points * self.dtype.itemsize // 2),
                         self._piece())
        if n:
            self._build(cube, chunks)
        chunks.finish()
        # The hierarchy EVLR: one page, entries sorted by key (COPC, "hierarchy VLR").
        entries = sorted(chunks.entries) or [(0, 0, 0, 0, 0, 0, 0)]
        page = b"".join(_ENTRY.pack(*e) for e in entries)
        evlr_at = fh.seek(0, os.SEEK_END)
        fh.write(_EVLR.pack(0, COPC_USER.encode(), 1000, len(page), b"copc hierarchy"))
        fh.write(page)
        scale = float(head.scales[0])
        offsets = np.asarray(head.offsets, dtype=np.float64)
        center, halfsize = cube.world(scale, offsets)
        gps = self._gps if n else [0.0, 0.0]
        info.record_data = _INFO.pack(*center, halfsize, 2 * halfsize / GRID,
                                      evlr_at + _EVLR.size, len(page), *gps)
        head.start_of_first_evlr = evlr_at
        if n:
            head.mins = offsets + scale * self._lo
            head.maxs = offsets + scale * self._hi
        head.number_of_points_by_return = self._returns[1:].astype(np.uint64)
        fh.seek(0)
        head.write_to(fh, ensure_same_size=True)

    def _piece(self) -> int:
        """Records read from a file at a time."""
        return max(1, min(READ_POINTS, self.max_memory_points))

    def _temp(self) -> Path:
        return self._tmp / f"n{next(self._names)}"

    def _build(self, cube: _Cube, chunks: _Chunks) -> None:
        """Every node into ``chunks``: subtrees too large for memory are split by
        streaming their file (depth first, so at most one split's files wait per
        level)."""
        todo: list[tuple[Key, Path, int]] = [
            ((0, 0, 0, 0), self._tmp / "points", self.n_points)]
        while todo:
            key, path, count = todo.pop()
            if count <= self.max_memory_points:
                self._subtree(cube, key[0], np.fromfile(path, dtype=self.dtype), chunks)
            elif key[0] == cube.max_level:
                chunks.add_file(key, path, self.dtype, count)
            else:
                todo.extend(self._split(cube, key, path, chunks))
            path.unlink()

    def _subtree(self, cube: _Cube, level0: int, rec: np.ndarray, chunks: _Chunks) -> None:
        v = cube.half_units(rec)
        level = assign_levels(v, level0, cube.h, self.leaf_points)
        keys = v >> (cube.h - level)[:, None]
        del v
        order = np.lexsort((keys[:, 2], keys[:, 1], keys[:, 0], level))   # stable
        level, keys, rec = level[order], keys[order], rec[order]
        new = np.ones(len(rec), dtype=bool)
        new[1:] = (level[1:] != level[:-1]) | (keys[1:] != keys[:-1]).any(axis=1)
        starts = np.flatnonzero(new)
        ends = [*starts[1:], len(rec)]
        nodes: list[Key] = [(int(level[s]), int(keys[s, 0]), int(keys[s, 1]),
                             int(keys[s, 2])) for s in starts]
        # DECISION: chunks in depth-first preorder (a node, then its children's
        # subtrees in child order), the order _split writes them in: the file does not
        # depend on which subtrees were built in memory, and a region's nodes lie
        # together (fewer, larger reads for a bounds query).
        for i in sorted(range(len(nodes)), key=lambda i: _preorder(nodes[i], level0)):
            chunks.add(nodes[i], rec[starts[i]:ends[i]])

    def _split(self, cube: _Cube, key: Key, path: Path,
               chunks: _Chunks) -> list[tuple[Key, Path, int]]:
        """Stream the file of node ``key`` (not a leaf: it has more than
        ``max_memory_points`` >= ``leaf_points`` points): its grid's first point per
        cell to its own chunk, the rest to one file per child."""
        lev, corner = key[0], np.asarray(key[1:], dtype=np.int64) << GRID_BITS
        taken = np.zeros(GRID ** 3, dtype=bool)
        own, own_n = self._temp(), 0
        kids: dict[int, tuple[Path, IO[bytes], list[int]]] = {}
        with open(own, "wb") as own_fh, open(path, "rb") as src:
            try:
                while len(piece := np.fromfile(src, dtype=self.dtype,
                                               count=self._piece())):
                    v = cube.half_units(piece)
                    c = (v >> (cube.h - lev - GRID_BITS)) - corner
                    cell = (c[:, 0] << (2 * GRID_BITS)) | (c[:, 1] << GRID_BITS) | c[:, 2]
                    first = np.unique(cell, return_index=True)[1]
                    first = first[~taken[cell[first]]]
                    taken[cell[first]] = True
                    mine = np.zeros(len(piece), dtype=bool)
                    mine[first] = True
                    own_fh.write(piece[mine].data)
                    own_n += len(first)
                    # child direction: x bit 0, y bit 1, z bit 2 (laspy VoxelKey.child)
                    d = (v[~mine] >> (cube.h - lev - 1)) & 1
                    kid = d[:, 0] | (d[:, 1] << 1) | (d[:, 2] << 2)
                    rest = piece[~mine]
                    for k in np.unique(kid):
                        if k not in kids:
                            p = self._temp()
                            kids[k] = (p, open(p, "wb"), [0])  # noqa: SIM115
                        sel = rest[kid == k]
                        kids[k][1].write(sel.data)
                        kids[k][2][0] += len(sel)
            finally:
                for _, f, _ in kids.values():
                    f.close()
        chunks.add_file(key, own, self.dtype, own_n)
        own.unlink()
        out: list[tuple[Key, Path, int]] = []
        for k in sorted(kids, reverse=True):      # popped in child order 0..7
            p, _, cnt = kids[k]
            child = (lev + 1, 2 * key[1] + (k & 1), 2 * key[2] + ((k >> 1) & 1),
                     2 * key[3] + ((k >> 2) & 1))
            out.append((child, p, cnt[0]))
        return out


def copc_info(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The COPC info VLR of a file, read from its bytes (COPC, "Reader Implementation
    Notes"): center (3,), halfsize, spacing, root_hier_offset, root_hier_size,
    gpstime_minimum, gpstime_maximum. Raises ``PointFileError`` for a file that is not
    COPC."""
    with open(path, "rb") as fh:
        head = fh.read(INFO_OFFSET + _INFO.size)
    if len(head) < INFO_OFFSET + _INFO.size or head[:4] != b"LASF" or \
            head[377:381] != b"copc" or head[393:395] != b"\x01\x00":
        raise PointFileError(f"Expected a COPC file (LASF, then the 'copc' info VLR at "
                             f"byte 375), got '{path}' without them.")
    vals = _INFO.unpack_from(head, INFO_OFFSET)
    names = ("halfsize", "spacing", "root_hier_offset", "root_hier_size",
             "gpstime_minimum", "gpstime_maximum")
    return {"center": np.array(vals[:3]), **dict(zip(names, vals[3:]))}
