"""The execution layer: independent tasks run in this process, on a LocalCluster, or on
an existing ``dask.distributed`` cluster, with the same results.

``open_executor(workers=N)`` starts a LocalCluster of N worker processes (one task at a
time each, Numba threads = cores / N), ``open_executor(scheduler="tcp://host:8786")``
connects to a running scheduler, and ``open_executor()`` runs every task here, one after
another, as the commands always did. ``Executor.map(fn, items)`` returns ``fn(item)``
for every item in the items' order, whatever the order the tasks finished in.

The scene ships once: ``Executor.share_scene`` saves it (``raytrace.Scene.save``) into
the output folder, which the workers must see anyway since they write the outputs, and
each worker process loads it once and keeps it for the tasks that follow
(``SceneRef.load``). dask is imported only here and only when a cluster is asked for
(the optional extra ``cluster``).
"""

from __future__ import annotations

import contextlib
import os
import threading
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from raytrace.errors import TunnelsimError
from survey.errors import ClusterError
from survey.report.progress import Progress

__all__ = ["CLUSTER_HINT", "DaskExecutor", "Executor", "InProcess",
           "SceneRef", "TaskProgress", "numba_threads_per_worker", "open_executor"]

T = TypeVar("T")
R = TypeVar("R")

#: How to install what a cluster run needs.
CLUSTER_HINT = "pip install 'tunnelsim[cluster]'"
#: Seconds to wait for a scheduler before calling it unreachable. ASSUMED: a scheduler
#: on the same network answers within a second; 10 s leaves room for a busy one.
CONNECT_TIMEOUT_S = 10.0
#: Scene files loaded and kept per worker process (a campaign uses one; two let a
#: pipeline alternate between two meshes without reloading).
SCENES_KEPT = 2


def numba_threads_per_worker(workers: int, cores: int | None = None) -> int:
    """Numba threads for each of ``workers`` processes sharing ``cores`` (default: this
    machine's): ``cores // workers``, at least 1."""
    cores = (os.cpu_count() or 1) if cores is None else cores
    return max(1, int(cores) // max(1, int(workers)))


# ---------------------------------------------------------------------------- the scene
#: Scenes loaded in this process, by file: (path, reflectivity path) -> (scene, refl).
_LOADED: dict[tuple[str, str | None], tuple[Any, NDArray[np.float64] | None]] = {}
_LOADED_LOCK = threading.Lock()


@dataclass(frozen=True)
class SceneRef:
    """The scene a task casts into: the objects themselves (in-process), or the file
    ``Scene.save`` wrote and the per-face reflectivity beside it (``.npy``), which each
    worker process loads once (``load``).

    Attributes
    ----------
    path : str or None
        The saved scene (.npz); None when ``scene`` is held.
    reflectivity_path : str or None
        (n_faces,) float64 reflectivity saved with ``np.save``; None when the mesh has
        none.
    """

    path: str | None = None
    reflectivity_path: str | None = None
    scene: Any = field(default=None, compare=False, repr=False)
    reflectivity: NDArray[np.float64] | None = field(default=None, compare=False,
                                                     repr=False)

    def __reduce__(self) -> tuple[Any, ...]:
        # Only the file names travel: a held scene is for this process only.
        if self.path is None:
            raise ClusterError("Expected a saved scene to send to a worker, got one held "
                               "in memory; use Executor.share_scene.")
        return (SceneRef, (self.path, self.reflectivity_path))

    def load(self) -> tuple[Any, NDArray[np.float64] | None]:
        """(raytrace.Scene, reflectivity (n_faces,) float64 or None), read at most once
        per process and file."""
        if self.path is None:
            return self.scene, self.reflectivity
        key = (self.path, self.reflectivity_path)
        with _LOADED_LOCK:
            if key not in _LOADED:
                from raytrace import Scene

                # Mapped, not read: the workers on one machine share the file's pages,
                # and a task touches only the nodes its rays visit.
                refl = None if self.reflectivity_path is None else \
                    np.load(self.reflectivity_path, mmap_mode="r")
                while len(_LOADED) >= SCENES_KEPT:
                    _LOADED.pop(next(iter(_LOADED)))
                _LOADED[key] = (Scene.load(self.path, mmap=True), refl)
            return _LOADED[key]


@dataclass(frozen=True)
class Shared:
    """An object every task of a run uses (a planner, a study: whatever holds a scene
    and its prepared cells), sent once: held here (in-process), or pickled into a file
    by ``Executor.share`` that each worker process reads once (``load``).

    Attributes
    ----------
    path : str or None
        The pickle file; None when ``obj`` is held.
    """

    path: str | None = None
    obj: Any = field(default=None, compare=False, repr=False)

    def __reduce__(self) -> tuple[Any, ...]:
        if self.path is None:
            raise ClusterError("Expected a shared object saved for the workers, got one "
                               "held in memory; use Executor.share.")
        return (Shared, (self.path,))

    def load(self) -> Any:
        """The object, unpickled at most once per process and file."""
        if self.path is None:
            return self.obj
        key = (self.path, None)
        with _LOADED_LOCK:
            if key not in _LOADED:
                import pickle

                while len(_LOADED) >= SCENES_KEPT:
                    _LOADED.pop(next(iter(_LOADED)))
                # Our own file, written by Executor.share for this run.
                with open(self.path, "rb") as fh:
                    _LOADED[key] = (pickle.load(fh), None)  # noqa: S301
            return _LOADED[key][0]


def call_shared(job: tuple[Shared, str, tuple[Any, ...]]) -> Any:
    """Task: ``getattr(shared object, method)(*args)`` for a job (Shared, method, args)."""
    ref, method, args = job
    return getattr(ref.load(), method)(*args)


# ---------------------------------------------------------------------------- progress
class TaskProgress(Progress):
    """A one-line bar over tasks on stderr (a line a minute off a terminal): call it with
    (done, total) as tasks finish and ``close`` it at the end. The one reporter
    (``survey.report.progress.Progress``) counting whole tasks."""

    def __init__(self, quiet: bool, unit: str = "tasks") -> None:
        super().__init__(quiet, unit, style="count")


# ---------------------------------------------------------------------------- executors
#: One task at a time per process: Numba's default (workqueue) threading layer must not
#: run two parallel regions at once, and a task already uses every thread it is given.
_TASK_LOCK = threading.Lock()


def run_task(fn: Callable[[T], R], item: T) -> R:
    """Run ``fn(item)`` on a worker: one task at a time per process, with every Numba
    thread the process was given (``NUMBA_NUM_THREADS``; a LocalCluster sets it to
    cores / workers)."""
    from raytrace import set_threads

    with _TASK_LOCK:
        # Numba's thread count is per calling thread; dask runs tasks on its own.
        set_threads(None)
        return fn(item)


class Executor:
    """Runs independent tasks; this base class runs them in this process, in order.

    Attributes
    ----------
    kind : str
        "in-process", "local cluster" or "cluster".
    workers : int
        Worker processes (1 in-process).
    dashboard : str or None
        The dask dashboard's address, when there is one.
    """

    kind = "in-process"
    workers = 1
    dashboard: str | None = None
    #: The scheduler's address ("tcp://host:port"), None in-process.
    address: str | None = None

    def map(self, fn: Callable[[T], R], items: Sequence[T], *,
            progress: Callable[[int, int], None] | None = None) -> list[R]:
        """``[fn(item) for item in items]``, in the items' order; ``progress(done,
        total)`` after each task. ``fn`` must be a module-level function and the items
        picklable (they travel to the workers)."""
        out = []
        for i, item in enumerate(items):
            out.append(fn(item))
            if progress is not None:
                progress(i + 1, len(items))
        return out

    def share_scene(self, scene: Any, reflectivity: NDArray[np.float64] | None,
                    folder: str | os.PathLike[str]) -> SceneRef:
        """The scene as tasks receive it: held here (in-process)."""
        return SceneRef(scene=scene, reflectivity=None if reflectivity is None
                        else np.asarray(reflectivity, dtype=np.float64))

    def share(self, obj: Any, folder: str | os.PathLike[str]) -> Shared:
        """``obj`` as tasks receive it (``Shared``, for ``call_shared``): held here."""
        return Shared(obj=obj)

    def describe(self) -> str:
        """One line saying where the tasks run."""
        return "in-process"

    def close(self) -> None:
        """Release the workers and remove the shared files."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


InProcess = Executor


class DaskExecutor(Executor):
    """Tasks on a ``dask.distributed`` cluster (made by ``open_executor``).

    Parameters
    ----------
    client : distributed.Client
    cluster : distributed.LocalCluster or None
        The cluster this executor started (closed with it); None for an existing one.
    """

    def __init__(self, client: Any, cluster: Any = None) -> None:
        self.client, self.cluster = client, cluster
        self.kind = "cluster" if cluster is None else "local cluster"
        self.workers = len(client.scheduler_info().get("workers", {}))
        self.dashboard = _dashboard(client)
        self.address = getattr(client.scheduler, "address", None)
        self._shared: list[Path] = []

    def warm_up(self) -> None:
        """Import the simulation on every worker now, while nothing waits for it (and
        Numba loads its cached kernels on the first task)."""
        self.client.run(_import_simulation)

    def describe(self) -> str:
        addr = self.client.scheduler.address
        board = f", dashboard {self.dashboard}" if self.dashboard else \
            " (dashboard: pip install bokeh)"
        return f"{self.kind} {addr}, {self.workers} workers{board}"

    def map(self, fn: Callable[[T], R], items: Sequence[T], *,
            progress: Callable[[int, int], None] | None = None) -> list[R]:
        from distributed import as_completed

        token = uuid.uuid4().hex[:8]
        name = getattr(fn, "__name__", "task")
        # DECISION: pure=False and one key per item: a rerun of the same campaign must
        # run again (the files may have been deleted), and a task lost with a killed
        # worker is rerun by the scheduler under the same key.
        futures = [self.client.submit(run_task, fn, item, key=f"{name}-{token}-{i}",
                                      pure=False) for i, item in enumerate(items)]
        index = {f.key: i for i, f in enumerate(futures)}
        out: list[Any] = [None] * len(items)
        try:
            for done, fut in enumerate(as_completed(futures), 1):
                try:
                    out[index[fut.key]] = fut.result()
                except TunnelsimError:
                    raise
                except Exception as exc:
                    if type(exc).__name__ == "KilledWorker":
                        raise ClusterError(f"Expected the cluster to finish every task, "
                                           f"got task {index[fut.key]} lost with workers "
                                           f"that died ({exc}); check the workers' "
                                           "memory and logs.") from exc
                    raise
                if progress is not None:
                    progress(done, len(items))
        except BaseException:
            self.client.cancel(futures)
            raise
        return out

    def share_scene(self, scene: Any, reflectivity: NDArray[np.float64] | None,
                    folder: str | os.PathLike[str]) -> SceneRef:
        """Save the scene (and reflectivity) into ``folder`` for the workers to load
        once each; removed by ``close``. The folder must be one every worker sees (the
        output folder: they write there too)."""
        folder = Path(folder)
        stem = folder / f".tunnelsim-scene-{uuid.uuid4().hex[:12]}"
        path = scene.save(stem.with_suffix(".npz"))
        self._shared.append(path)
        refl = None
        if reflectivity is not None:
            refl = stem.with_suffix(".reflectivity.npy")
            np.save(refl, np.asarray(reflectivity, dtype=np.float64))
            self._shared.append(refl)
        return SceneRef(str(path.resolve()), None if refl is None else str(refl.resolve()))

    def share(self, obj: Any, folder: str | os.PathLike[str]) -> Shared:
        """Pickle ``obj`` (its scene with it) into ``folder`` for each worker to read
        once; removed by ``close``. The folder must be one every worker sees."""
        import pickle

        from raytrace.fileio import atomic_writer

        path = Path(folder) / f".tunnelsim-shared-{uuid.uuid4().hex[:12]}.pkl"
        with atomic_writer(path) as fh:
            pickle.dump(obj, fh, protocol=pickle.HIGHEST_PROTOCOL)
        self._shared.append(path)
        return Shared(str(path.resolve()))

    def close(self) -> None:
        for p in self._shared:
            with contextlib.suppress(OSError):
                p.unlink()
        self._shared = []
        with contextlib.suppress(Exception):
            self.client.close()
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close()


def _import_simulation() -> None:
    import sensors.simulate  # noqa: F401

    import raytrace.scene  # noqa: F401


def _dashboard(client: Any) -> str | None:
    """The dashboard's address, or None when the scheduler serves none (no bokeh)."""
    try:
        import bokeh  # noqa: F401  - the dashboard needs it
    except ImportError:
        return None
    with contextlib.suppress(Exception):
        link = client.dashboard_link
        return str(link) if link else None
    return None


def _distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise ClusterError(f"Expected dask.distributed for --workers / --scheduler, got "
                           f"it not installed; {CLUSTER_HINT}.") from None
    return distributed


def open_executor(workers: int | None = None, scheduler: str | None = None, *,
                  cores: int | None = None, dashboard_address: str = ":0",
                  quiet_logs: bool = True, connect_timeout_s: float | None = None
                  ) -> Executor:
    """Where tasks run: a new LocalCluster of ``workers`` processes, the cluster whose
    scheduler is at ``scheduler`` ("tcp://host:8786"), or this process (neither).

    Parameters
    ----------
    workers : int >= 1, optional
        Worker processes of a LocalCluster, each running one task at a time with
        ``cores // workers`` Numba threads (``numba_threads_per_worker``).
    scheduler : str, optional
        Address of a running scheduler (``dask scheduler`` prints it).
    cores : int, optional
        Cores the LocalCluster shares (default: this machine's).
    dashboard_address : str
        Where the LocalCluster serves its dashboard (default ":0", a free port).
    quiet_logs : bool
        Keep dask's informational logging off the terminal.
    connect_timeout_s : float, optional
        How long to wait for ``scheduler`` (default ``CONNECT_TIMEOUT_S``).

    Returns
    -------
    Executor
        Use it as a context manager; closing it stops a LocalCluster it started.

    Raises
    ------
    ClusterError
        Both or a bad value given, dask not installed, or the scheduler unreachable.
    """
    if workers is not None and scheduler is not None:
        raise ClusterError(f"Expected --workers or --scheduler, got both ({workers} "
                           f"workers, scheduler {scheduler!r}); give one.")
    if workers is None and scheduler is None:
        return Executor()
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ClusterError(f"Expected a positive whole number of workers, got {workers!r}.")
    distributed = _distributed()
    if quiet_logs:
        import logging

        for name in ("distributed", "bokeh", "tornado"):
            logging.getLogger(name).setLevel(logging.ERROR)
    if scheduler is not None:
        wait = CONNECT_TIMEOUT_S if connect_timeout_s is None else connect_timeout_s
        try:
            client = distributed.Client(scheduler, timeout=wait)
        except ValueError as exc:
            raise ClusterError(f"Expected a scheduler address such as "
                               f"tcp://host:8786, got {scheduler!r} ({exc}).") from None
        except (OSError, TimeoutError) as exc:
            raise ClusterError(f"Expected a dask scheduler at {scheduler!r}, got none "
                               f"reachable within {wait:g} s ({type(exc).__name__}); "
                               "start one with 'dask scheduler' and give the address "
                               "it prints.") from None
        return DaskExecutor(client)
    assert workers is not None
    threads = numba_threads_per_worker(workers, cores)
    # DECISION: processes with one dask thread each (one task at a time, see
    # _TASK_LOCK); the Numba pool of each is sized before it starts (NUMBA_NUM_THREADS
    # is read once, at import), so that N workers share the cores without
    # oversubscription.
    try:
        cluster = distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True,
            dashboard_address=dashboard_address, env={"NUMBA_NUM_THREADS": str(threads)},
            silence_logs=40 if quiet_logs else 30)
    except RuntimeError as exc:       # "Nanny failed to start", with the cause chained
        cause = exc.__cause__ or exc
        raise ClusterError(f"Expected a local cluster of {workers} workers, got none "
                           f"started ({type(cause).__name__}: {cause}); run with --debug "
                           "for dask's log.") from exc
    try:
        client = distributed.Client(cluster)
    except BaseException:
        cluster.close()
        raise
    ex = DaskExecutor(client, cluster)
    ex.warm_up()
    return ex
