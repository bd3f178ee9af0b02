"""M3C2 on epochs larger than memory: spatial tiles with a halo, each a task (issues 17
and 19), with the same bits as ``survey.analysis.m3c2.M3C2`` on the whole epochs.

``m3c2_files`` streams both epochs chunk by chunk into ``TileSpill``s (``survey.
cluster.tiles``) whose halo is the largest reach of any query plus a margin, and the
core points into one without halo (with their running index); then, for each tile
holding core points, a task (``Executor.map``: in-process, a LocalCluster or a dask
cluster) builds the two epochs' grids from the tile's files and computes M3C2 at its
core points, writing the result beside the tiles; the results are then scattered into
a ``M3C2Store`` on disk, in the core points' input order.

Why the bits are the same as the untiled run:

- every tile uses the global origin and each epoch's global grid lattice (the corner,
  the cell and the cell counts of ``EpochGrid.lattice_of`` on the epoch's bounds, which
  the spill tracks), so a point gets the same local coordinates and cell key;
- a tile's file keeps input order and the grid sorts stably by key, so a tile's grid
  is the whole grid with the points beyond the halo left out;
- a query visits the same cells in the same order (same lattice) and tests each point
  with the same arithmetic; the points left out lie beyond the query's reach and fail
  the test anyway. The sums (covariances, means, standard deviations) and the sorted
  projections (medians) therefore run over the same values in the same order.

One exception: ``towards`` as a function (the tunnel axis) is evaluated per tile
instead of per chunk, and ``Alignment.to_local`` iterates until a whole batch has
converged, so its last bits can differ; it decides only the sign of a normal, which
changes only for a normal perpendicular to the direction to the axis.

Memory: a chunk of an epoch while spilling, one tile and its halo (both epochs) per
task; the results are on disk (``M3C2Store``: 105 bytes per core point).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from raytrace.checks import as_points
from survey.analysis.compare import check_overlap
from survey.analysis.m3c2 import CHUNK, M3C2, EpochGrid, M3C2Params, M3C2Result
from survey.cluster.execution import Executor
from survey.cluster.tiles import TileRef, TileSpill, tile_key_text
from survey.errors import CompareError

__all__ = ["HALO_MARGIN_M", "M3C2Store", "halo_of", "iter_subsample", "m3c2_files",
           "run_m3c2_tile"]

Floats = NDArray[np.float64]
Source = str | os.PathLike[str] | ArrayLike

#: Added to the largest query reach to make the halo, m. ASSUMED: covers the rounding
#: of a core point's tile (a few ulps of UTM coordinates, ~1e-9 m) many times over,
#: and costs a 1 cm band of extra points per tile edge.
HALO_MARGIN_M = 0.01
#: Epoch points per chunk while spilling (24 MB of coordinates).
SPILL_CHUNK = 1 << 20

#: The columns of a ``M3C2Store``: name -> (dtype, columns); the M3C2Result fields and
#: the core points' coordinates.
STORE_COLUMNS: dict[str, tuple[type, int]] = {
    "xyz": (np.float64, 3), "distance": (np.float64, 1), "lod": (np.float64, 1),
    "significant": (np.bool_, 1), "spread1": (np.float64, 1),
    "spread2": (np.float64, 1), "n1": (np.int64, 1), "n2": (np.int64, 1),
    "normal": (np.float64, 3), "normal_radius": (np.float64, 1)}


def halo_of(params: M3C2Params, margin_m: float = HALO_MARGIN_M) -> float:
    """The largest distance in x, y from a core point to an epoch point any query can
    take, plus ``margin_m``, m: the normal balls (the largest normal radius) and the
    cylinder (a point in it lies within sqrt(r^2 + L^2) of the core point)."""
    reach = float(np.hypot(params.cyl_radius_m, params.half_length_m))
    return max([reach, *params.normal_radii_m]) + float(margin_m)


def _chunks(src: Source, chunk: int) -> Iterator[Floats]:
    """(k, 3) float64 chunks of a cloud file (``iter_points``) or of an array."""
    if isinstance(src, str | os.PathLike):
        from sensors.io.cloudread import iter_points

        yield from iter_points(src, chunk=chunk)
        return
    p, _ = as_points(src, "points", CompareError)
    for a in range(0, len(p), chunk):
        yield p[a:a + chunk]


def iter_subsample(chunks: Iterable[ArrayLike], spacing_m: float, lo: ArrayLike,
                   hi: ArrayLike) -> Iterator[Floats]:
    """``survey.analysis.m3c2.subsample`` over chunks: the first point (in input order)
    of each cubic cell of edge ``spacing_m`` from the corner ``lo`` (3,) (the cloud's
    minimum; ``hi`` (3,) its maximum), chunk by chunk; the concatenated chunks equal
    ``subsample`` of the whole cloud. Holds one int64 per core point."""
    h = float(spacing_m)
    if not (np.isfinite(h) and h > 0):
        raise CompareError(f"Expected a positive finite `spacing_m`, got {spacing_m!r}.")
    lo_ = np.asarray(lo, dtype=np.float64).reshape(3)
    dims = np.floor((np.asarray(hi, dtype=np.float64).reshape(3) - lo_) / h
                    ).astype(np.int64) + 1
    if float(np.prod(dims.astype(np.float64))) >= 2.0 ** 62:
        raise CompareError(f"Expected fewer than 2^62 cells of {h:g} m over the cloud, "
                           f"got {dims.tolist()} per axis; use a larger spacing.")
    seen = np.empty(0, np.int64)
    for ch in chunks:
        p = np.asarray(ch, dtype=np.float64).reshape(-1, 3)
        cell = np.floor((p - lo_) / h).astype(np.int64)
        key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
        uniq, first = np.unique(key, return_index=True)
        new = ~np.isin(uniq, seen, assume_unique=True)
        seen = np.union1d(seen, uniq[new])
        yield p[np.sort(first[new])]


# ---------------------------------------------------------------------------- the store
class M3C2Store:
    """M3C2 results of n core points on disk, in the core points' order: one raw file
    per column (``STORE_COLUMNS``), read as memory maps or in chunks.

    Attributes
    ----------
    folder : Path
        The store's folder (removed by ``close``, with everything in it).
    n : int
        Core points.
    """

    def __init__(self, folder: Path, n: int) -> None:
        self.folder, self.n = folder, int(n)
        for name, (dt, k) in STORE_COLUMNS.items():
            with open(self.path(name), "wb") as fh:
                fh.truncate(self.n * k * np.dtype(dt).itemsize)

    def __len__(self) -> int:
        return self.n

    def __repr__(self) -> str:
        return f"M3C2Store({self.n:,} core points, '{self.folder}')"

    def path(self, name: str) -> Path:
        """The file of column ``name``."""
        return self.folder / f"{name}.bin"

    def column(self, name: str) -> np.memmap:
        """Column ``name`` as a read-only memory map, (n,) or (n, 3)."""
        dt, k = STORE_COLUMNS[name]
        return np.memmap(self.path(name), dtype=dt, mode="r",
                         shape=(self.n, k) if k > 1 else (self.n,))

    def scatter(self, index: NDArray[np.int64], values: dict[str, np.ndarray]) -> None:
        """Write rows ``index`` (k,) of each column {name: (k,) or (k, 3)}."""
        for name, v in values.items():
            dt, k = STORE_COLUMNS[name]
            mm = np.memmap(self.path(name), dtype=dt, mode="r+",
                           shape=(self.n, k) if k > 1 else (self.n,))
            mm[index] = v
            # DECISION: no flush (msync, ~3 ms a file here): the shared mapping writes
            # into the page cache, which every later read of the file sees; unmapped
            # at once, the pages do not stay in this process's memory.
            del mm

    def xyz(self, start: int, stop: int) -> Floats:
        """Core points [start, stop) (k, 3)."""
        return self._rows("xyz", start, stop)

    def _rows(self, name: str, start: int, stop: int) -> np.ndarray:
        dt, k = STORE_COLUMNS[name]
        size = np.dtype(dt).itemsize * k
        a, b = max(0, int(start)), min(self.n, int(stop))
        out: np.ndarray = np.fromfile(self.path(name), dtype=dt, count=max(0, b - a) * k,
                          offset=a * size)
        return out.reshape(-1, k) if k > 1 else out

    def result(self, start: int, stop: int) -> M3C2Result:
        """The results at core points [start, stop)."""
        return M3C2Result(*(self._rows(n, start, stop) for n in
                            ("distance", "lod", "significant", "spread1", "spread2",
                             "n1", "n2", "normal", "normal_radius")))

    def chunks(self, size: int = CHUNK) -> Iterator[tuple[Floats, M3C2Result]]:
        """(core points (k, 3), M3C2Result) for consecutive chunks of ``size``."""
        for a in range(0, self.n, max(1, int(size))):
            yield self.xyz(a, a + size), self.result(a, a + size)

    def las_fields(self, size: int = CHUNK) -> dict[str, np.memmap]:
        """``M3C2Result.fields`` of every core point as read-only memory maps, (n,)
        each (written beside the columns, chunk by chunk, on the first call)."""
        names = list(M3C2Result.fields(self.result(0, 0)))
        dts = {k: v.dtype for k, v in M3C2Result.fields(self.result(0, 0)).items()}
        paths = {k: self.folder / f"las_{k}.bin" for k in names}
        if not all(p.exists() for p in paths.values()):
            with contextlib.ExitStack() as stack:
                fhs = {k: stack.enter_context(open(paths[k], "wb")) for k in names}
                for a in range(0, self.n, size):
                    for k, v in self.result(a, a + size).fields().items():
                        v.tofile(fhs[k])
        return {k: np.memmap(paths[k], dtype=dts[k], mode="r", shape=(self.n,))
                for k in names}

    def close(self) -> None:
        """Remove the store's folder."""
        with contextlib.suppress(OSError):
            shutil.rmtree(self.folder)

    def __enter__(self) -> M3C2Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------------- tasks
Lattice = tuple[Floats, float, NDArray[np.int64]]


@dataclass(frozen=True)
class M3C2TileTask:
    """One tile's M3C2, as a worker receives it (picklable: file handles and numbers).

    epoch1, epoch2, core : TileRef
        The tile's files (epochs with the halo; core points with their index).
    lattices : (Lattice, Lattice)
        Each epoch's global grid (``EpochGrid.lattice_of``).
    origin : (3,) float64
        The global local origin.
    params : M3C2Params
    normal_epoch : int
    orientation : (3,) tuple of float
    towards : callable or (3,) tuple or None
        Orient normals towards ``towards(core xyz (k, 3)) -> (k, 3)`` (a module-level
        function or a ``functools.partial`` of one), or towards one point.
    out : str
        The result file to write (``np.save`` of a structured array).
    """

    epoch1: TileRef
    epoch2: TileRef
    core: TileRef
    lattices: tuple[Lattice, Lattice]
    origin: tuple[float, float, float]
    params: M3C2Params
    normal_epoch: int
    orientation: tuple[float, ...]
    towards: Any
    out: str


def run_m3c2_tile(task: M3C2TileTask) -> int:
    """M3C2 at one tile's core points (a task): writes ``task.out`` (.npy, a structured
    array with ``index`` and the M3C2Result fields) and returns the core count."""
    origin = np.asarray(task.origin, dtype=np.float64)
    h = M3C2.cell_m(task.params)
    e1, e2 = task.epoch1.read(), task.epoch2.read()
    job = M3C2.from_grids(EpochGrid(e1.xyz, origin, h, lattice=task.lattices[0]),
                          EpochGrid(e2.xyz, origin, h, lattice=task.lattices[1]),
                          task.params, normal_epoch=task.normal_epoch)
    del e1, e2
    core = task.core.read()
    tw = task.towards(core.xyz) if callable(task.towards) else task.towards
    res = job.compute(core.xyz, orientation=task.orientation, towards=tw)
    dt = [("index", np.int64)] + [(n, STORE_COLUMNS[n][0], (3,)) if STORE_COLUMNS[n][1] > 1
                                  else (n, STORE_COLUMNS[n][0])
                                  for n in STORE_COLUMNS if n != "xyz"]
    rec = np.empty(len(core), dtype=dt)
    rec["index"] = core.index
    for name in STORE_COLUMNS:
        if name != "xyz":
            rec[name] = getattr(res, name)
    tmp = Path(task.out + ".part.npy")
    np.save(tmp, rec)
    os.replace(tmp, task.out)
    return len(core)


# ---------------------------------------------------------------------------- driver
def m3c2_files(epoch1: Source, epoch2: Source, core: Source | float | None,
               params: M3C2Params, *, tile_m: float,
               orientation: ArrayLike = (0.0, 0.0, 1.0),
               towards: Callable[[Floats], Floats] | ArrayLike | None = None,
               normal_epoch: int = 1, origin: ArrayLike | None = None,
               check_frames: bool = True, executor: Executor | None = None,
               spill_dir: str | os.PathLike[str] | None = None, chunk: int = SPILL_CHUNK,
               progress: Callable[[int, int], None] | None = None) -> M3C2Store:
    """M3C2 tile by tile (module doc), the same bits as ``M3C2(epoch1, epoch2, params)
    .compute(core)``.

    Parameters
    ----------
    epoch1, epoch2 : path or (n, 3) array_like of float
        The earlier and the later epoch: cloud files (read chunk by chunk,
        ``iter_points``) or arrays, metres, one frame.
    core : path, (m, 3) array_like, float or None
        Core points: a cloud file or an array; a float: epoch 1 subsampled to one point
        per cell of that many metres (``subsample``, streamed); None: epoch 1.
    params : M3C2Params
        With ``normal_radii_m`` (the normals are computed per tile).
    tile_m : float > 0
        Tile edge in x and y, m (any size: a tile smaller than the halo only costs
        more copies of the halo).
    orientation, towards
        As ``M3C2.compute``; ``towards`` one point (3,) or a picklable function of
        the core points (k, 3) -> (k, 3) (e.g. ``functools.partial(towards_axis,
        alignment, centre=c)``).
    normal_epoch : {1, 2}
    origin : (3,) array_like, optional
        Local origin (default: ``M3C2.default_origin`` of epoch 1, as untiled).
    check_frames : bool
        Refuse epochs whose bounds lie apart (``check_overlap``, on the whole epochs).
    executor : Executor, optional
        Where the tile tasks run (default: this process).
    spill_dir : path, optional
        Folder for the tiles and the results (default: the temporary folder); every
        worker must see it. Needs about 24 B x (1 + halo share) per epoch point.
    chunk : int
        Points per chunk while spilling.
    progress : callable, optional
        ``progress(done, total)`` over the tile tasks.

    Returns
    -------
    M3C2Store
        The results in the core points' order, on disk in ``spill_dir``; close it (or
        use it as a context manager) to remove them.

    Raises
    ------
    CompareError
        Bad parameters, an empty epoch, epochs in different frames, no core points.
    """
    if not isinstance(params, M3C2Params):
        raise CompareError(f"Expected `params` as M3C2Params, got {type(params).__name__}.")
    try:
        t = float(tile_m)
    except (TypeError, ValueError):
        t = float("nan")
    if not (np.isfinite(t) and t > 0):
        raise CompareError(f"Expected a positive finite `tile_m`, got {tile_m!r}.")
    if not params.normal_radii_m:
        raise CompareError("Expected `normal_radii_m` in the parameters (tiles compute "
                           "their normals), got none.")
    if normal_epoch not in (1, 2):
        raise CompareError(f"Expected `normal_epoch` 1 or 2, got {normal_epoch!r}.")
    orient = tuple(float(v) for v in np.asarray(orientation, dtype=np.float64).reshape(-1))
    tw = towards if (towards is None or callable(towards)) else \
        tuple(as_points(towards, "towards", CompareError)[0].reshape(-1))
    if not callable(tw) and tw is not None and len(tw) != 3:
        raise CompareError("Expected `towards` as one point (3,) or a function of the "
                           "core points, got several points; pass a function.")
    ex = Executor() if executor is None else executor
    chunk = max(1, int(chunk))
    halo = halo_of(params)
    base = Path(tempfile.mkdtemp(prefix=".tunnelsim-m3c2-", dir=spill_dir))
    spills: list[TileSpill] = []
    try:
        anchor, anchored = np.zeros(2), False
        for name, src in (("epoch1", epoch1), ("epoch2", epoch2)):
            spill = None
            for ch in _chunks(src, chunk):
                if not len(ch):
                    continue
                if not anchored:                 # small tile indices at UTM coordinates
                    anchor, anchored = np.round(ch[0, :2] / t) * t, True
                if spill is None:
                    spill = TileSpill(t, halo, folder=base, anchor=anchor)
                    spills.append(spill)
                spill.add(ch)
            if spill is None or spill.count == 0:
                raise CompareError(f"Expected `{name}` with points, got none.")
        s1, s2 = spills
        if check_frames:
            check_overlap(s2.bounds, s1.bounds, names=("epoch 2", "epoch 1"))
        o = M3C2.default_origin(s1.bounds) if origin is None else \
            np.asarray(origin, dtype=np.float64).reshape(3)
        h = M3C2.cell_m(params)
        lattices = (EpochGrid.lattice_of(s1.bounds, o, h),
                    EpochGrid.lattice_of(s2.bounds, o, h))
        # Core points: spilled without halo, with their running index, and written in
        # order for the store.
        sc = TileSpill(t, 0.0, folder=base, anchor=anchor)
        spills.append(sc)
        if core is None:
            cores: Iterable[Floats] = _chunks(epoch1, chunk)
        elif isinstance(core, float | int) and not isinstance(core, bool):
            cores = iter_subsample(_chunks(epoch1, chunk), float(core), s1.bounds[0],
                                   s1.bounds[1])
        else:
            cores = _chunks(core, chunk)
        xyz_part = base / "core_xyz.part"
        with open(xyz_part, "wb") as fh:
            for ch in cores:
                sc.add(ch, index=np.arange(sc.count, sc.count + len(ch)))
                np.ascontiguousarray(ch, dtype=np.float64).tofile(fh)
        if sc.count == 0:
            raise CompareError("Expected core points, got none.")
        store = M3C2Store(base, sc.count)
        os.replace(xyz_part, store.path("xyz"))
        keys = sc.keys()
        tasks = [M3C2TileTask(s1.ref(k), s2.ref(k), sc.ref(k), lattices,
                              (float(o[0]), float(o[1]), float(o[2])), params,
                              normal_epoch, orient, tw,
                              str(base / f"result_{tile_key_text(k)}.npy"))
                 for k in keys]
        counts = ex.map(run_m3c2_tile, tasks, progress=progress)
        done = 0
        for task, n in zip(tasks, counts):
            rec = np.load(task.out)
            if len(rec) != n:
                raise CompareError(f"Expected {n} results in '{task.out}', got {len(rec)}.")
            store.scatter(rec["index"], {c: rec[c] for c in STORE_COLUMNS if c != "xyz"})
            Path(task.out).unlink()
            done += n
        if done != store.n:
            raise CompareError(f"Expected a result for each of {store.n:,} core points, "
                               f"got {done:,}.")
    except BaseException:
        shutil.rmtree(base, ignore_errors=True)
        raise
    finally:
        for s in spills:
            s.close()
    return store
