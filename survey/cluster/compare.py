"""Cloud-to-cloud and cloud-to-mesh distances tile by tile, for clouds larger than memory
and for clusters (``tunnelsim compare --tile-m``), with the same bits as the whole run.

The compared cloud is spilled into x, y tiles (``TileSpill``, with each point's row);
a reference *cloud* is spilled into the same tiles with a halo of ``max_distance_m``:
a point's nearest reference point within that distance lies within it in x and y, so it
is in the point's tile file. Farther points are clamped to ``max_distance_m`` in both
runs, so a tile's answer equals the whole cloud's. Every tile's k-d tree works about
the whole reference's origin (``ReferenceCloud(origin=)``): the same coordinates, the
same distances to the last bit. A reference *mesh* is not tiled (meshes are compact):
it is sent once to each worker (``Executor.share``).

Each tile is a task (``tile_distances``); the distances land by row in arrays on disk
(``np.memmap``) that a second pass writes into the output in the input's order.
Memory: the chunk being spilled, one tile (its points and its reference with halo) per
worker, and 8 bytes per compared point on disk (32 with ``split``).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from survey.analysis.compare import ReferenceCloud
from survey.cluster.execution import Executor, Shared
from survey.cluster.tiles import TileRef, TileSpill
from survey.errors import CompareError

__all__ = ["TiledDistances", "spill_cloud", "tile_distances", "tiled_distances"]

Floats = NDArray[np.float64]


def spill_cloud(chunks: Iterable[Floats], tile_m: float, halo_m: float, *,
                folder: str | os.PathLike[str] | None = None, indexed: bool = False
                ) -> TileSpill:
    """Spill chunks of points (n, 3) into tiles of ``tile_m`` with ``halo_m`` (anchor at
    (0, 0), so that spills of one run share their tiles); ``indexed``: keep each point's
    running row. The caller closes the spill."""
    spill = TileSpill(tile_m, halo_m, folder=folder)
    try:
        row = 0
        for xyz in chunks:
            spill.add(xyz, index=np.arange(row, row + len(xyz)) if indexed else None)
            row += len(xyz)
    except BaseException:
        spill.close()
        raise
    return spill


@dataclass(frozen=True)
class _TileJob:
    compared: TileRef
    reference: TileRef | None
    mesh: Shared | None
    origin: tuple[float, float, float]
    max_distance_m: float | None
    split: bool


def tile_distances(job: _TileJob) -> tuple[NDArray[np.int64], Floats, Floats | None]:
    """Task: (rows (n,), distances (n,), compared - nearest (n, 3) with ``split`` else
    None) for the compared points of one tile."""
    tile = job.compared.read()
    rows = tile.index if tile.index is not None else np.arange(len(tile))
    if job.mesh is not None:
        d = job.mesh.load().distances(tile.xyz, max_distance_m=job.max_distance_m)
        return rows, d.distance, None
    assert job.reference is not None and job.max_distance_m is not None
    ref = job.reference.read()
    if len(ref) == 0:                  # no reference point within reach: all clamped
        diff = np.full((len(rows), 3), np.nan) if job.split else None
        return rows, np.full(len(rows), job.max_distance_m), diff
    d = ReferenceCloud(ref.xyz, origin=job.origin).distances(
        tile.xyz, max_distance_m=job.max_distance_m, split=job.split)
    diff = None
    if job.split:
        assert d.dx is not None and d.dy is not None and d.dz is not None
        diff = np.column_stack([d.dx, d.dy, d.dz])
    return rows, d.distance, diff


@dataclass
class TiledDistances:
    """Distances by row of the compared cloud, on disk.

    Attributes
    ----------
    distance : (n,) float64 memmap, m
    diff : (n, 3) float64 memmap or None; compared - nearest (``split``)
    tiles : int, the tasks run (one per tile)
    """

    distance: Floats
    diff: Floats | None
    tiles: int
    _folder: Path

    def close(self) -> None:
        """Remove the arrays' files."""
        import shutil

        self.distance = self.diff = None  # type: ignore[assignment]
        shutil.rmtree(self._folder, ignore_errors=True)


def tiled_distances(compared: Iterable[Floats], n_points: int, *,
                    tile_m: float, reference: TileSpill | None = None,
                    mesh: Any = None, max_distance_m: float | None = None,
                    split: bool = False, executor: Executor | None = None,
                    folder: str | os.PathLike[str] | None = None,
                    progress: Callable[[int, int], None] | None = None
                    ) -> TiledDistances:
    """Distances of a compared cloud to a tiled reference cloud or to a mesh, tile by
    tile (module doc).

    Parameters
    ----------
    compared : iterable of (k, 3) float64 arrays
        The compared cloud, chunk by chunk, m.
    n_points : int
        Its point count (the arrays on disk are made before the spill).
    tile_m : float > 0
        Tile edge, m (``reference`` must use the same).
    reference : TileSpill, optional
        The reference cloud spilled with ``spill_cloud`` (halo = ``max_distance_m``).
    mesh : survey.analysis.compare.ReferenceMesh, optional
        The reference mesh instead.
    max_distance_m : float, optional
        Clamp; required with a reference cloud (it is the halo).
    split : bool
        Also the components compared - nearest (reference cloud only).
    executor : Executor, optional
        Where the tiles run (default: this process).
    folder : path, optional
        Where the spill and the arrays go (one every worker sees); default: the
        system's temporary folder.
    progress : callable(done, total), optional

    Returns
    -------
    TiledDistances
        Close it when done (its files are removed).
    """
    if (reference is None) == (mesh is None):
        raise CompareError("Expected a tiled reference cloud or a mesh, got "
                           f"{'both' if reference is not None else 'neither'}.")
    if reference is not None:
        if max_distance_m is None:
            raise CompareError("Expected a maximum distance to compare tile by tile with "
                               "a reference cloud (it is the tiles' halo), got none; give "
                               "--max-dist.")
        if reference.halo_m < max_distance_m or reference.tile_m != tile_m:
            raise CompareError(f"Expected the reference spilled in tiles of {tile_m:g} m "
                               f"with a halo >= {max_distance_m:g} m, got tiles of "
                               f"{reference.tile_m:g} m, halo {reference.halo_m:g} m.")
    elif split:
        raise CompareError("Expected split components only against a reference cloud, "
                           "got a mesh.")
    ex = executor if executor is not None else Executor()
    work = Path(tempfile.mkdtemp(prefix=".tunnelsim-compare-", dir=folder))
    try:
        dist = np.lib.format.open_memmap(work / "distance.npy", mode="w+",
                                         dtype=np.float64, shape=(n_points,))
        diff = np.lib.format.open_memmap(work / "diff.npy", mode="w+", dtype=np.float64,
                                         shape=(n_points, 3)) if split else None
        with spill_cloud(compared, tile_m, 0.0, folder=work, indexed=True) as cs:
            if cs.count != n_points:
                raise CompareError(f"Expected {n_points:,} compared points, got "
                                   f"{cs.count:,}.")
            origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
            shared = None
            if reference is not None:
                b = reference.bounds
                origin = tuple(np.round(0.5 * (b[0] + b[1])).tolist())
            else:
                shared = ex.share(mesh, work)
            jobs = [_TileJob(cs.ref(k), None if reference is None else reference.ref(k),
                             shared, origin, max_distance_m, split) for k in cs.keys()]
            # In waves, so that the results held at once stay a few tiles' worth.
            wave = max(8, 4 * ex.workers)
            for a in range(0, len(jobs), wave):
                def step(done: int, _: int, a: int = a) -> None:
                    if progress is not None:
                        progress(a + done, len(jobs))
                for rows, d, dd in ex.map(tile_distances, jobs[a:a + wave],
                                          progress=step):
                    dist[rows] = d
                    if diff is not None and dd is not None:
                        diff[rows] = dd
        dist.flush()
        return TiledDistances(dist, diff, len(jobs), work)
    except BaseException:
        import shutil

        shutil.rmtree(work, ignore_errors=True)
        raise
