"""Points spilled to disk in square x, y tiles with a halo, for analyses of clouds
larger than memory that run tile by tile (in this process or as tasks on a cluster):
M3C2 (``survey.analysis.m3c2_tiles``), cloud-to-reference comparisons.

``TileSpill`` takes points chunk by chunk (``add``) and appends each to the file of
its own tile and of every tile whose box grown by ``halo_m`` contains it, so a tile's
file holds the tile and its halo: a query of reach <= ``halo_m`` about a point of the
tile finds there every point it would find in the whole cloud. Memory is bounded by
the chunk, not by the cloud. z is not tiled (tunnels are long and flat).

Layout on disk (one folder, removed by ``close``; raw native-endian binary, appended):

    <i>_<j>.f8    (n, 3 + extra) float64   x, y, z, then the extra columns  (24+ B/pt)
    <i>_<j>.i8    (n,) int64               the running index of each point   (8 B/pt)
                                           (only when ``add`` is given indices)

Tile (i, j) is the box [ax + i t, ax + (i+1) t) x [ay + j t, ay + (j+1) t) for the
anchor (ax, ay) and tile edge t; a point's own tile is (floor((x - ax) / t),
floor((y - ay) / t)). Within a tile's file points keep their input order (chunk after
chunk, and the input order within a chunk): analyses whose sums run in input order
get the same bits tiled as whole.

A task on another process reads a tile through ``TileRef`` (picklable: the folder and
the key), so the folder must be one every worker sees (a local cluster: any local
folder; a cluster on several machines: a shared file system).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import positive
from survey.errors import ClusterError

__all__ = ["TileData", "TileRef", "TileSpill", "tile_key_text"]

Key = tuple[int, int]
Floats = NDArray[np.float64]

#: Prefix of the folders a spill makes (inside ``folder`` when one is given).
SPILL_PREFIX = ".tunnelsim-tiles-"


def tile_key_text(key: Key) -> str:
    """The file stem of tile ``key``: "i_j" (negative indices keep their sign)."""
    return f"{int(key[0])}_{int(key[1])}"


def _positive(value: Any, name: str, zero: bool = False) -> float:
    return positive(value, name, ClusterError, zero=zero)


@dataclass(frozen=True)
class TileData:
    """One tile's points (its own and its halo's), in input order.

    Attributes
    ----------
    xyz : (n, 3) float64, m
    index : (n,) int64 or None; the running index ``add`` was given
    extra : (n, k) float64 or None; the extra columns
    """

    xyz: Floats
    index: NDArray[np.int64] | None
    extra: Floats | None

    def __len__(self) -> int:
        return len(self.xyz)


@dataclass(frozen=True)
class TileRef:
    """What a task needs to read one tile: the spill folder, the key and the layout.
    Picklable (strings and numbers only)."""

    folder: str
    key: Key
    extra: int = 0
    indexed: bool = False

    def read(self) -> TileData:
        """The tile's points (``TileData``); empty arrays for a tile without points."""
        stem = Path(self.folder) / tile_key_text(self.key)
        width = 3 + self.extra
        f8 = stem.with_suffix(".f8")
        rows = np.fromfile(f8, dtype=np.float64).reshape(-1, width) if f8.exists() \
            else np.empty((0, width))
        idx = None
        if self.indexed:
            i8 = stem.with_suffix(".i8")
            idx = np.fromfile(i8, dtype=np.int64) if i8.exists() else \
                np.empty(0, np.int64)
            if len(idx) != len(rows):
                raise ClusterError(f"Expected as many indices as points in tile "
                                   f"{self.key} of '{self.folder}', got {len(idx)} and "
                                   f"{len(rows)}; the spill was cut short.")
        xyz = np.ascontiguousarray(rows[:, :3])
        extra = np.ascontiguousarray(rows[:, 3:]) if self.extra else None
        return TileData(xyz, idx, extra)


class TileSpill:
    """Points streamed into square x, y tiles with a halo, on disk (module doc).

    Parameters
    ----------
    tile_m : float > 0
        Tile edge in x and y, m.
    halo_m : float >= 0
        A point also goes to every tile whose box grown by ``halo_m`` (in x and in y)
        contains it, m.
    folder : path, optional
        Where the spill folder is made (a new hidden folder inside it, removed by
        ``close``); default: the system's temporary folder. It must be one every
        worker sees when tasks read the tiles elsewhere.
    extra : int >= 0
        Extra float64 columns each point carries (``add(..., extra=)``).
    anchor : (2,) array_like of float
        Corner of tile (0, 0), m (default (0, 0); pass a point near the data to keep
        the indices small).

    Attributes
    ----------
    folder : Path
        The spill folder.
    count : int
        Points added (each once, however many tiles it went to).
    bounds : (2, 3) float64
        (min, max) of the points added (inf / -inf rows before any).
    """

    def __init__(self, tile_m: float, halo_m: float = 0.0, *,
                 folder: str | os.PathLike[str] | None = None, extra: int = 0,
                 anchor: ArrayLike = (0.0, 0.0)) -> None:
        self.tile_m = _positive(tile_m, "tile_m")
        self.halo_m = _positive(halo_m, "halo_m", zero=True)
        if isinstance(extra, bool) or not isinstance(extra, int | np.integer) or extra < 0:
            raise ClusterError(f"Expected `extra` as a whole number >= 0, got {extra!r}.")
        self.extra = int(extra)
        a = np.asarray(anchor, dtype=np.float64).reshape(-1)
        if a.shape != (2,) or not np.isfinite(a).all():
            raise ClusterError(f"Expected `anchor` as a finite (2,) point, got "
                               f"{np.asarray(anchor).tolist()!r}.")
        self.anchor = a
        if folder is not None and not Path(folder).is_dir():
            raise ClusterError(f"Expected an existing folder for the tiles, got "
                               f"'{folder}'.")
        self.folder = Path(tempfile.mkdtemp(prefix=SPILL_PREFIX, dir=folder))
        self.count = 0
        self.bounds = np.stack([np.full(3, np.inf), np.full(3, -np.inf)])
        self._sizes: dict[Key, int] = {}
        self._indexed: bool | None = None

    def __repr__(self) -> str:
        return (f"TileSpill({self.count:,} points in {len(self._sizes)} tiles of "
                f"{self.tile_m:g} m, halo {self.halo_m:g} m, '{self.folder}')")

    # ------------------------------------------------------------------ writing
    def _tile_index(self, v: Floats, axis: int) -> NDArray[np.int64]:
        return np.floor((v - self.anchor[axis]) / self.tile_m).astype(np.int64)

    def _edges(self, i: NDArray[np.int64], axis: int) -> tuple[Floats, Floats]:
        """The nominal box [lo, hi) of tile indices i along one axis (``box``)."""
        a, t = self.anchor[axis], self.tile_m
        return a + i * t, a + (i + 1) * t

    def _members(self, v: Floats, axis: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(point, tile index) pairs along one axis: the point's own tile, and every
        tile with lo - halo <= v <= hi + halo (exactly, on ``_edges``)."""
        own = self._tile_index(v, axis)
        if self.halo_m == 0.0:
            return np.arange(len(v)), own
        first = self._tile_index(v - self.halo_m, axis) - 1      # one more each side:
        last = self._tile_index(v + self.halo_m, axis) + 1       # rounding of the floor
        pts, tiles = [], []
        for off in range(int((last - first).max()) + 1):
            i = first + off
            lo, hi = self._edges(i, axis)
            ok = (i <= last) & (((lo - self.halo_m <= v) & (v <= hi + self.halo_m))
                                | (i == own))
            pts.append(np.flatnonzero(ok))
            tiles.append(i[ok])
        return np.concatenate(pts), np.concatenate(tiles)

    def add(self, xyz: ArrayLike, index: ArrayLike | None = None,
            extra: ArrayLike | None = None) -> None:
        """Append points to their tiles (and the halos they fall in).

        Parameters
        ----------
        xyz : (n, 3) array_like of float
            World coordinates, m (finite).
        index : (n,) array_like of int, optional
            A running index to keep with each point (e.g. its row in the input); give
            it on every call or on none.
        extra : (n, k) array_like of float, optional
            The ``extra`` columns (k = ``extra``), kept with each point.
        """
        p = np.asarray(xyz, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ClusterError(f"Expected `xyz` to have shape (n, 3), got {p.shape}.")
        if not np.isfinite(p).all():
            raise ClusterError("Expected finite coordinates in `xyz`, got NaN or inf.")
        if (index is not None) != bool(self._indexed) and self._indexed is not None:
            raise ClusterError(f"Expected `index` on every call or on none, got it "
                               f"{'now only' if index is not None else 'before, not now'}.")
        self._indexed = index is not None
        idx = None
        if index is not None:
            idx = np.asarray(index).reshape(-1)
            if len(idx) != len(p) or not np.issubdtype(idx.dtype, np.integer):
                raise ClusterError(f"Expected `index` as ({len(p)},) integers, got "
                                   f"{idx.shape} {idx.dtype}.")
            idx = idx.astype(np.int64)
        rows = p
        if self.extra:
            if extra is None:
                raise ClusterError(f"Expected `extra` ({len(p)}, {self.extra}), got none.")
            e = np.asarray(extra, dtype=np.float64).reshape(len(p), -1)
            if e.shape[1] != self.extra:
                raise ClusterError(f"Expected `extra` ({len(p)}, {self.extra}), got "
                                   f"{np.asarray(extra).shape}.")
            rows = np.concatenate([p, e], axis=1)
        elif extra is not None:
            raise ClusterError("Expected no `extra` (the spill was made with extra=0), "
                               "got columns.")
        if len(p) == 0:
            return
        self.bounds = np.stack([np.minimum(self.bounds[0], p.min(axis=0)),
                                np.maximum(self.bounds[1], p.max(axis=0))])
        self.count += len(p)
        # The (point, tile) pairs: x members times y members of each point.
        px, ix = self._members(p[:, 0], 0)
        py, iy = self._members(p[:, 1], 1)
        ox, oy = np.argsort(px, kind="stable"), np.argsort(py, kind="stable")
        px, ix, py, iy = px[ox], ix[ox], py[oy], iy[oy]
        cx, cy = np.bincount(px, minlength=len(p)), np.bincount(py, minlength=len(p))
        sx, sy = np.cumsum(cx) - cx, np.cumsum(cy) - cy
        # Pair every x member of a point with every y member of it.
        reps = cx * cy
        pt = np.repeat(np.arange(len(p)), reps)
        k = np.arange(len(pt)) - np.repeat(np.cumsum(reps) - reps, reps)
        ki, kj = ix[sx[pt] + k // cy[pt]], iy[sy[pt] + k % cy[pt]]
        # DECISION: sort by tile then by point (lexsort is stable): each tile gets its
        # points in input order, which the bit-identity of tiled analyses needs.
        order = np.lexsort((pt, kj, ki))
        pt, ki, kj = pt[order], ki[order], kj[order]
        cut = np.flatnonzero((np.diff(ki) != 0) | (np.diff(kj) != 0)) + 1
        for a, b in zip(np.r_[0, cut], np.r_[cut, len(pt)]):
            key = (int(ki[a]), int(kj[a]))
            sel = pt[a:b]
            stem = self.folder / tile_key_text(key)
            with open(stem.with_suffix(".f8"), "ab") as fh:
                rows[sel].tofile(fh)
            if idx is not None:
                with open(stem.with_suffix(".i8"), "ab") as fh:
                    idx[sel].tofile(fh)
            self._sizes[key] = self._sizes.get(key, 0) + len(sel)

    # ------------------------------------------------------------------ reading
    def keys(self) -> list[Key]:
        """The tiles holding points (own or halo), sorted."""
        return sorted(self._sizes)

    def size(self, key: Key) -> int:
        """Points in tile ``key``'s file (its own and its halo's); 0 for none."""
        return self._sizes.get((int(key[0]), int(key[1])), 0)

    def ref(self, key: Key) -> TileRef:
        """A picklable handle a task reads tile ``key`` through (``TileRef.read``)."""
        return TileRef(str(self.folder), (int(key[0]), int(key[1])), self.extra,
                       bool(self._indexed))

    def read(self, key: Key) -> TileData:
        """Tile ``key``'s points, its own and its halo's, in input order."""
        return self.ref(key).read()

    def box(self, key: Key) -> Floats:
        """The tile's own box (2, 2): rows (x_min, y_min), (x_max, y_max), m."""
        i = np.array([key[0], key[1]], dtype=np.int64)
        lo = np.array([self._edges(i[0:1], 0)[0][0], self._edges(i[1:2], 1)[0][0]])
        hi = np.array([self._edges(i[0:1], 0)[1][0], self._edges(i[1:2], 1)[1][0]])
        return np.stack([lo, hi])

    def own(self, xyz: ArrayLike) -> NDArray[np.int64]:
        """The own tile (i, j) of each point (n, 3), (n, 2) int64."""
        p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        return np.stack([self._tile_index(p[:, 0], 0), self._tile_index(p[:, 1], 1)], 1)

    # ------------------------------------------------------------------ cleanup
    def close(self) -> None:
        """Remove the spill folder (and every tile file)."""
        with contextlib.suppress(OSError):
            shutil.rmtree(self.folder)
        self._sizes = {}

    def __enter__(self) -> TileSpill:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
