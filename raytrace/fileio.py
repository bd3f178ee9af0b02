"""Atomic output files: written under a temporary name in the target folder and renamed
into place only when complete, so a crash or Ctrl-C never leaves a half-written file
that looks complete. Used by every writer of the project."""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any


@contextlib.contextmanager
def atomic_writer(path: str | os.PathLike[str], mode: str = "wb") -> Iterator[IO[Any]]:
    """Context manager yielding an open file whose contents appear at ``path`` on a
    clean exit (``os.replace``, atomic on POSIX) and are deleted on any exception.

    Parameters
    ----------
    path : str or path-like
        The final file; its folder must exist (the temporary file is made there).
    mode : str
        ``open`` mode: "wb" (default) or "w" for text.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=".part", dir=folder)
    try:
        # mkstemp creates 0600; give the file the mode a plain open() would.
        os.chmod(tmp, 0o666 & ~_umask())
        with os.fdopen(fd, mode) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _finite(obj: Any) -> Any:
    """A copy of a JSON-ready structure with NaN and ±inf as None (JSON ``null``)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if hasattr(obj, "tolist") and hasattr(obj, "dtype"):  # NumPy scalars and arrays
        return _finite(obj.tolist())
    return obj


def json_text(obj: Any, *, indent: int | None = 2) -> str:
    """Strict JSON (RFC 8259) of ``obj``: NaN and ±inf become ``null``, so jq, JavaScript
    and ``json.loads(..., parse_constant=...)`` read every file the project writes.
    DECISION: ``null`` rather than a string such as "NaN": a missing number is what a
    NaN stands for here (e.g. line spacing at 0 m/s)."""
    return json.dumps(_finite(obj), indent=indent, allow_nan=False) + "\n"


def write_json(path: str | os.PathLike[str], obj: Any, *, indent: int | None = 2) -> Path:
    """Write ``json_text(obj)`` to ``path`` atomically; returns the path."""
    with atomic_writer(path, "w") as fh:
        fh.write(json_text(obj, indent=indent))
    return Path(path)


__all__ = ["atomic_writer", "json_text", "write_json", "npz_memmap", "savez_aligned"]


def npz_memmap(path: str | os.PathLike[str], names: tuple[str, ...]
               ) -> dict[str, Any]:
    """Memory-map arrays of an uncompressed ``.npz`` (``np.savez``) without reading them.

    A stored (not deflated) zip member is the ``.npy`` file verbatim, so each array is a
    ``np.memmap`` at the member's data offset: the local file header (30 bytes, then the
    name and the extra field, whose lengths it gives; PKWARE APPNOTE 4.3.7) and the
    ``.npy`` header (NEP 1). Pages are read when first touched and shared by every process
    mapping the same file (copy-on-write: writes stay private).

    Parameters
    ----------
    path : str or path-like
        A file ``np.savez`` wrote.
    names : tuple of str
        Arrays to map.

    Returns
    -------
    dict
        name -> np.memmap (mode "c"); a 0-size array is an ordinary empty array.

    Raises
    ------
    ValueError
        A member missing, deflated (``np.savez_compressed``), or holding objects.
    """
    import struct
    import zipfile

    import numpy as np

    out: dict[str, Any] = {}
    with zipfile.ZipFile(path) as zf, open(path, "rb") as fh:
        for name in names:
            info = zf.getinfo(name + ".npy")
            if info.compress_type != zipfile.ZIP_STORED:
                raise ValueError(f"Expected '{name}' stored uncompressed (np.savez), got "
                                 "a compressed member; save with np.savez.")
            fh.seek(info.header_offset)
            local = fh.read(30)
            if local[:4] != b"PK\x03\x04":
                raise ValueError(f"Expected a zip local header for '{name}', got "
                                 f"{local[:4]!r}.")
            n_name, n_extra = struct.unpack("<HH", local[26:30])
            fh.seek(info.header_offset + 30 + n_name + n_extra)
            version = np.lib.format.read_magic(fh)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, fortran, dtype = read_header(fh)
            if dtype.hasobject:
                raise ValueError(f"Expected a numeric array '{name}', got objects.")
            if int(np.prod(shape)) == 0:
                out[name] = np.empty(shape, dtype=dtype, order="F" if fortran else "C")
                continue
            out[name] = np.memmap(path, dtype=dtype, mode="c", offset=fh.tell(),
                                  shape=shape, order="F" if fortran else "C")
    return out


#: Header ID of the zip extra field that pads a member's local header so that its data
#: starts on an aligned offset: the ID Android's ``zipalign`` uses (any ID a reader does
#: not know is skipped, PKWARE APPNOTE 4.5.1).
_ALIGN_EXTRA_ID = 0xD935


def savez_aligned(fh: IO[bytes], arrays: dict[str, Any], align: int = 64) -> None:
    """Write ``arrays`` as an uncompressed ``.npz`` (what ``np.savez`` writes, read back
    by ``np.load`` and ``npz_memmap``) in which every array's data starts at a multiple
    of ``align`` bytes in the file, so that a memory map of it starts on a cache line.

    Each member's local header gets an extra field of padding (as Android's
    ``zipalign`` does); the ``.npy`` header that follows is a multiple of 64 bytes
    long (NEP 1 pads it so), so the data lands on the boundary. ``fh``: a seekable
    binary file open for writing.
    """
    import io
    import struct
    import zipfile

    import numpy as np

    if align <= 0 or 64 % align:
        raise ValueError(f"Expected `align` to be a power of two up to 64, got {align}; "
                         "use 64 (a cache line).")
    with zipfile.ZipFile(fh, mode="w", compression=zipfile.ZIP_STORED,
                         allowZip64=True) as zf:
        for name, value in arrays.items():
            a = np.asarray(value)
            if not a.flags.c_contiguous:  # (ascontiguousarray would make 0-d 1-d)
                a = a.copy(order="C")
            head = io.BytesIO()
            np.lib.format.write_array_header_1_0(
                head, np.lib.format.header_data_from_array_1_0(a))
            header = head.getvalue()
            if len(header) % align:  # NumPy pads the header to 64 bytes (ARRAY_ALIGN)
                raise AssertionError("unexpected .npy header length")
            info = zipfile.ZipInfo(name + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_STORED
            info.file_size = len(header) + a.nbytes
            # Local header: 30 bytes, the name, our extra field, then the ZIP64 field
            # (20 bytes) that zipfile appends when forced.
            start = fh.tell() + 30 + len(info.filename.encode()) + 4 + 20
            pad = (-start) % align
            info.extra = struct.pack("<HH", _ALIGN_EXTRA_ID, pad) + bytes(pad)
            with zf.open(info, mode="w", force_zip64=True) as out:
                out.write(header)
                out.write(a.reshape(-1).view(np.uint8).data)
