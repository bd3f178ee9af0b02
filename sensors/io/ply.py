"""Binary PLY files (Turk 1994), read and written in one place for the whole project:
simulated point clouds (``sensors.writers``), tunnel meshes (``survey.world.mesh``) and
rewritten clouds (``sensors.io.cloudread``, ``sensors.io.cloudmap``).

Supported: ``binary_little_endian`` and ``binary_big_endian``, scalar properties of the
eight PLY types (and their ``int32``-style aliases), and list properties with one fixed
length per element (triangle faces). ASCII PLY and ragged lists are refused with a hint
to convert the file (trimesh, CloudCompare, PDAL read them).

A list property is a sub-array field in NumPy (``("vertex_indices", "<i4", (3,))``); the
writer adds the ``uchar`` count PLY stores before each list, the reader checks and drops
it. Every problem with a file is a ``PointFileError`` naming the file and what is wrong:
a file shorter than its header promises says how many records it promised and how many
whole ones it holds.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from sensors.io.errors import PointFileError
from .stream import AtomicStream

__all__ = ["PlyElement", "PlyHeader", "PlyWriter", "ply_element", "read_ply",
           "read_ply_header", "write_ply"]

#: PLY scalar type names (with the sized aliases of newer writers) -> NumPy codes.
TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4",
         "uint": "u4", "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1",
         "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4", "float32": "f4",
         "float64": "f8"}
#: NumPy codes -> the PLY type name the writer uses.
NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
         "u4": "uint", "f4": "float", "f8": "double"}
#: Longest header read before a file is declared not to be a PLY (bytes).
MAX_HEADER_BYTES = 1 << 20
#: Longest list property read (items per record).
MAX_LIST = 1 << 16
#: Width of an element count the writer patches in when the stream closes.
_COUNT_WIDTH = 20


@dataclass(frozen=True)
class PlyElement:
    """One element of a PLY header: ``name``, ``count`` records of ``dtype`` (the
    record as stored: list counts included, file byte order) at ``offset`` bytes from
    the start of the file."""

    name: str
    count: int
    dtype: np.dtype
    offset: int

    @property
    def nbytes(self) -> int:
        return self.count * self.dtype.itemsize


@dataclass(frozen=True)
class PlyHeader:
    """A parsed PLY header: ``elements`` in file order, the ``comments`` (and
    ``obj_info`` lines) and the file ``size`` in bytes."""

    path: Path
    elements: tuple[PlyElement, ...]
    comments: tuple[str, ...]
    size: int

    def element(self, name: str) -> PlyElement:
        for e in self.elements:
            if e.name == name:
                return e
        raise PointFileError(f"Expected an element '{name}' in the PLY '{self.path}', got "
                             f"{[e.name for e in self.elements]}.")


def _fail(path, what) -> PointFileError:
    return PointFileError(f"Expected a binary PLY file, got '{path}' {what}.")


def _header_lines(path: Path, fh: IO[bytes]) -> tuple[list[list[str]], int]:
    first = fh.readline(16)
    if not first:
        raise _fail(path, "which is empty (0 bytes)")
    if first.rstrip(b"\r\n") != b"ply":
        raise _fail(path, "without the 'ply' magic line")
    lines: list[list[str]] = []
    while True:
        line = fh.readline(MAX_HEADER_BYTES)
        if not line or fh.tell() > MAX_HEADER_BYTES:
            raise _fail(path, "whose header has no 'end_header' line (cut short, or not "
                              "a PLY)")
        words = line.decode("ascii", "replace").split()
        if words == ["end_header"]:
            return lines, fh.tell()
        if words:
            lines.append(words)


def _element_dtype(path, fh, name, count, props, order, offset):
    """The stored record dtype of one element; a list property takes its length from
    the element's first record (PLY allows ragged lists; tunnelsim reads fixed ones)."""
    fields: list[tuple[Any, ...]] = []
    for p in props:
        if p[0] == "list":
            count_t, item_t, pname = TYPES[p[1]], TYPES[p[2]], p[3]
            prefix = np.dtype([(f[0], order + f[1], *f[2:]) for f in fields]).itemsize \
                if fields else 0
            fh.seek(offset + prefix)
            raw = fh.read(np.dtype(count_t).itemsize) if count else b""
            k = int(np.frombuffer(raw, dtype=order + count_t)[0]) if len(raw) == \
                np.dtype(count_t).itemsize else 3
            if not 0 <= k <= MAX_LIST:
                raise _fail(path, f"whose first '{name}' record has a list of {k} items "
                                  f"(expected 0 to {MAX_LIST})")
            fields += [(f"__n_{pname}", count_t), (pname, item_t, (k,))]
        else:
            fields.append((p[1], TYPES[p[0]]))
    names = [f[0] for f in fields]
    if len(set(names)) != len(names):
        raise _fail(path, f"whose element '{name}' names a property twice")
    return np.dtype([(f[0], order + f[1] if np.dtype(f[1]).itemsize > 1 else f[1], *f[2:])
                     for f in fields])


def read_ply_header(path: str | os.PathLike[str]) -> PlyHeader:
    """Parse and check a binary PLY's header, and that the file holds every record it
    promises.

    Raises ``PointFileError`` for an empty file, a missing magic line or
    ``end_header``, an ASCII or unknown format, a malformed element or property line,
    and a file shorter than its elements (naming the records promised and held). Bytes
    after the last element give a warning (they are not read).
    """
    path = Path(path)
    if not path.is_file():
        raise PointFileError(f"Expected a PLY file, got '{path}' which does not exist.")
    size = path.stat().st_size
    with open(path, "rb") as fh:
        lines, start = _header_lines(path, fh)
        fmt = [w for w in lines if w[0] == "format"]
        if len(fmt) != 1 or len(fmt[0]) != 3:
            raise _fail(path, "without one 'format' line")
        order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt[0][1])
        if order is None:
            raise PointFileError(f"Expected a binary PLY, got format '{fmt[0][1]}' in "
                                 f"'{path}'; convert it to binary (CloudCompare, trimesh "
                                 "or PDAL can).")
        raw: list[tuple[str, int, list[list[str]]]] = []
        comments = []
        for w in lines:
            if w[0] in ("comment", "obj_info"):
                comments.append(" ".join(w))
            elif w[0] == "element":
                if len(w) != 3 or not w[2].isdigit():
                    raise _fail(path, f"with a malformed line '{' '.join(w)}' (expected "
                                      "'element NAME COUNT')")
                raw.append((w[1], int(w[2]), []))
            elif w[0] == "property":
                ok = raw and ((len(w) == 3 and w[1] in TYPES) or
                              (len(w) == 5 and w[1] == "list" and w[2] in TYPES and
                               w[3] in TYPES and TYPES[w[2]][0] in "iu"))
                if not ok:
                    raise _fail(path, f"with a malformed line '{' '.join(w)}' (expected "
                                      "'property TYPE NAME' after an element line)")
                raw[-1][2].append(w[1:])
            elif w[0] != "format":
                raise _fail(path, f"with an unknown header line '{' '.join(w[:4])}'")
        elements = []
        offset = start
        for name, count, props in raw:
            if not props:
                raise _fail(path, f"whose element '{name}' has no properties")
            dt = _element_dtype(path, fh, name, count, props, order, offset)
            elements.append(PlyElement(name, count, dt, offset))
            offset += count * dt.itemsize
    head = PlyHeader(path, tuple(elements), tuple(comments), size)
    _check_size(head, start)
    return head


def _check_size(head: PlyHeader, start: int) -> None:
    left = head.size - start
    for e in head.elements:
        if left < e.nbytes:
            whole = max(left, 0) // e.dtype.itemsize
            raise PointFileError(
                f"Expected {e.count:,} {e.name} records in '{head.path}' (its header says "
                f"so), got {whole:,} whole ones: the file is cut short (an interrupted copy "
                "or download?); copy or export it again.")
        left -= e.nbytes
    if left > 0:
        warnings.warn(f"'{head.path}' holds {left:,} bytes after the records its header "
                      "announces; they are not read.", UserWarning, stacklevel=3)


def _check_lists(head: PlyHeader, e: PlyElement, rec: np.ndarray) -> None:
    for name in e.dtype.names or ():
        if name.startswith("__n_"):
            k = e.dtype[name[4:]].shape[0]
            if len(rec) and (rec[name] != k).any():
                raise PointFileError(f"Expected lists of one length ({k}) in property "
                                     f"'{name[4:]}' of '{head.path}', got several; "
                                     "triangulate the mesh first.")


def ply_element(path: str | os.PathLike[str], name: str = "vertex",
                header: PlyHeader | None = None) -> np.ndarray:
    """A read-only memory map of one element's records (list counts checked and kept
    as ``__n_<name>`` fields); the header is parsed and checked unless given."""
    head = read_ply_header(path) if header is None else header
    e = head.element(name)
    if e.count == 0:
        return np.empty(0, dtype=e.dtype)
    rec = np.memmap(head.path, dtype=e.dtype, mode="r", offset=e.offset, shape=(e.count,))
    _check_lists(head, e, rec)
    return rec


def read_ply(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Every element of a binary PLY as {name: structured array} in native byte
    order, list counts dropped (a face's ``vertex_indices`` is an (m, k) field)."""
    head = read_ply_header(path)
    out = {}
    for e in head.elements:
        rec = ply_element(head.path, e.name, head)
        keep = [n for n in e.dtype.names or () if not n.startswith("__n_")]
        dt = np.dtype([(n, e.dtype[n].base.newbyteorder("="), e.dtype[n].shape)
                       for n in keep])
        arr = np.empty(len(rec), dtype=dt)
        for n in keep:
            arr[n] = rec[n]
        out[e.name] = arr
        del rec
    return out


def _disk_dtype(dtype: np.dtype) -> np.dtype:
    """The little-endian record stored for ``dtype``: a sub-array field becomes a PLY
    list, preceded by its uchar count."""
    fields: list[tuple[Any, ...]] = []
    for name in dtype.names or ():
        base, shape = dtype[name].base, dtype[name].shape
        code = base.str[1:]
        if code not in NAMES:
            raise PointFileError(f"Expected PLY property types {sorted(NAMES)}, got "
                                 f"{base} for '{name}'; cast it first.")
        if shape:
            if len(shape) != 1 or shape[0] > 255:
                raise PointFileError(f"Expected a list property of at most 255 items, got "
                                     f"shape {shape} for '{name}'.")
            fields += [(f"__n_{name}", "u1"), (name, "<" + code, shape)]
        else:
            fields.append((name, "<" + code))
    return np.dtype(fields)


class PlyWriter(AtomicStream):
    """A binary little-endian PLY written as a stream, atomically.

    ``elements`` is a sequence of (name, dtype, count or None); records are written
    element by element, in that order, with ``write``. A count of None is patched into
    the header on ``close`` (a stream of unknown length); a given count is checked.
    Use as a context manager: a clean exit closes (the file appears at ``path``), an
    exception aborts (nothing is left).
    """

    def __init__(self, path: str | os.PathLike[str],
                 elements: Sequence[tuple[str, np.dtype, int | None]], *,
                 comments: Iterable[str] = ()) -> None:
        self._elements = [(n, np.dtype(dt), c) for n, dt, c in elements]
        self._disk = [_disk_dtype(dt) for _, dt, _ in self._elements]
        self._counts = [0] * len(self._elements)
        self._current = 0
        lines = ["ply", "format binary_little_endian 1.0"]
        lines += [c if c.split()[:1] in (["comment"], ["obj_info"]) else f"comment {c}"
                  for c in comments]
        self._patch: list[tuple[int, int]] = []   # (element index, byte offset of count)
        for i, ((name, _, count), disk) in enumerate(zip(self._elements, self._disk)):
            text = f"element {name} "
            if count is None:
                self._patch.append((i, len("\n".join(lines).encode()) + 1 + len(text)))
                text += " " * _COUNT_WIDTH
            else:
                text += str(int(count))
            lines.append(text)
            for field in disk.names or ():
                if field.startswith("__n_"):
                    continue
                ty = NAMES[disk[field].base.str[1:]]
                lines.append(f"property list uchar {ty} {field}" if disk[field].shape
                             else f"property {ty} {field}")
        lines.append("end_header")
        header = "\n".join(lines) + "\n"
        if not header.isascii():
            bad = next(line for line in lines if not line.isascii())
            raise PointFileError(f"Expected ASCII PLY element and property names and "
                                 f"comments, got {bad!r}; the source file's header is "
                                 "damaged.")
        super().__init__(path)
        self._fh.write(header.encode("ascii"))

    def write(self, name: str, records: np.ndarray) -> None:
        """Append ``records`` (structured, with at least the element's fields) to
        element ``name``."""
        while self._elements[self._current][0] != name:
            self._finish_element()
        dt, disk = self._elements[self._current][1], self._disk[self._current]
        rec = np.asarray(records)
        if rec.dtype == disk:
            # Already the stored layout (a packed little-endian record without lists,
            # as sensors.io.fields.FILE_DTYPE): written as it lies, without a copy.
            self._fh.write(np.ascontiguousarray(rec).data)
            self._counts[self._current] += len(rec)
            return
        out = np.empty(len(rec), dtype=disk)
        for field in dt.names or ():
            out[field] = rec[field]
            if dt[field].shape:
                out[f"__n_{field}"] = dt[field].shape[0]
        self._fh.write(out.tobytes())
        self._counts[self._current] += len(rec)

    def _check_count(self, i: int) -> None:
        name, _, count = self._elements[i]
        if count is not None and self._counts[i] != count:
            raise PointFileError(f"Expected {count:,} {name} records for '{self.path}', "
                                 f"got {self._counts[i]:,}.")

    def _finish_element(self) -> None:
        self._check_count(self._current)
        self._current += 1
        if self._current >= len(self._elements):
            raise PointFileError(f"Expected elements {[e[0] for e in self._elements]} in "
                                 f"this order for '{self.path}'.")

    def _finish(self) -> None:
        """Check and patch the counts, then move the file into place."""
        while self._current < len(self._elements) - 1:
            self._finish_element()
        self._check_count(len(self._elements) - 1)
        for i, pos in self._patch:
            self._fh.seek(pos)
            self._fh.write(str(self._counts[i]).ljust(_COUNT_WIDTH).encode("ascii"))
        super()._finish()


#: Records written per call when a whole array is given (keeps temporary copies small).
WRITE_CHUNK = 1 << 20


def write_ply(path: str | os.PathLike[str], elements: dict[str, np.ndarray], *,
              comments: Iterable[str] = ()) -> Path:
    """Write whole arrays {element name: structured records} as a binary PLY,
    atomically; a sub-array field becomes a list property. Returns the path."""
    spec = [(name, rec.dtype, len(rec)) for name, rec in elements.items()]
    with PlyWriter(path, spec, comments=comments) as w:
        for name, rec in elements.items():
            for i in range(0, len(rec), WRITE_CHUNK):
                w.write(name, rec[i:i + WRITE_CHUNK])
    return Path(path)
