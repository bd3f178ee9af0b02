"""The protocol every file writer of the project shares, in laspy's shape: write in
chunks, then ``close`` (the file appears at its path) or ``abort`` (nothing appears);
as a context manager, a clean exit closes and an exception aborts.

``AtomicStream`` adds the file itself: a temporary file in the target folder
(``raytrace.fileio.atomic_writer``) renamed into place on close, so that a crash or a
Ctrl-C never leaves a file that looks complete.
"""

from __future__ import annotations

import contextlib
import os
import queue
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any, Self

from raytrace.fileio import atomic_writer

from sensors.io.errors import PointFileError

__all__ = ["AtomicStream", "Background", "Stream", "deferred_interrupt"]


class Stream:
    """Base of the stream writers: subclasses set ``path`` and implement ``_finish``
    (write what ends the file, move it into place) and ``_discard`` (drop it)."""

    path: Path
    _open: bool = True

    def close(self) -> Path:
        """Finish the file and move it into place; returns its path."""
        if self._open:
            self._open = False
            try:
                self._finish()
            except BaseException as exc:
                self._discard(exc)
                raise
        return self.path

    def abort(self) -> None:
        """Drop the file being written (nothing appears at ``path``)."""
        if self._open:
            self._open = False
            self._discard(PointFileError(f"Writing '{self.path}' was aborted."))

    def __enter__(self) -> Self:
        return self

    def __exit__(self, kind: object, exc: BaseException | None, tb: object) -> None:
        if exc is None:
            self.close()
        elif self._open:
            self._open = False
            self._discard(exc)

    def _finish(self) -> None:
        raise NotImplementedError

    def _discard(self, exc: BaseException) -> None:
        raise NotImplementedError


class AtomicStream(Stream):
    """A stream into one file at ``path``, written under a temporary name (``_fh``)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._cm = atomic_writer(self.path)
        self._fh: IO[Any] = self._cm.__enter__()

    def _finish(self) -> None:
        self._cm.__exit__(None, None, None)

    def _discard(self, exc: BaseException) -> None:
        with contextlib.suppress(BaseException):   # the temporary file is gone either way
            self._cm.__exit__(type(exc), exc, exc.__traceback__)


@contextlib.contextmanager
def deferred_interrupt() -> Iterator[None]:
    """Hold a Ctrl-C (SIGINT) that arrives inside the block; raise ``KeyboardInterrupt``
    when the block ends.

    DECISION: lazrs compresses and decompresses in Rust and calls the Python file's
    ``write``/``read`` from there; a KeyboardInterrupt raised inside such a call comes
    back as ``LazrsError("IoError: Failed to call write")``, so Ctrl-C would read as a
    broken file. Holding the signal for one chunk (a fraction of a second) keeps it a
    Ctrl-C. Only in the main thread, and only over Python's default handler (a program
    with its own SIGINT handler keeps it).
    """
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield
        return
    got: list[int] = []
    old = signal.signal(signal.SIGINT, lambda sig, frame: got.append(sig))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
        if got:
            raise KeyboardInterrupt


class Background:
    """Run ``work(item)`` on a worker thread, item by item in order, while the caller
    goes on (a writer thread: the caller simulates the next chunk while this one is
    turned into records and compressed; lazrs, zlib and file writes release the GIL).

    ``put`` blocks while ``depth`` items wait (memory stays bounded); an exception in
    ``work`` stops the worker and is raised again by the next ``put`` or by ``finish``.
    ``finish`` waits for every item; ``cancel`` drops what waits and waits for the item
    under way (a fraction of a second), so that the caller may then discard the file.
    """

    def __init__(self, work: Callable[[Any], None], *, depth: int = 2,
                 name: str = "tunnelsim-writer") -> None:
        self._work = work
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=max(1, int(depth)))
        self._error: BaseException | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _DONE:
                return
            if self._error is not None or self._stop.is_set():
                continue            # drain: the caller is told at its next call
            try:
                self._work(item)
            except BaseException as exc:   # handed to the caller's thread
                self._error = exc

    def _raise(self) -> None:
        if self._error is not None:
            raise self._error

    def put(self, item: Any) -> None:
        """Queue ``item`` (blocks while ``depth`` items wait); raises the worker's
        exception, if it had one."""
        self._raise()
        while True:
            try:
                self._queue.put(item, timeout=0.1)
                return
            except queue.Full:
                self._raise()
                if not self._thread.is_alive():   # cannot happen without an error
                    raise PointFileError("Expected the writer thread to run, got it "
                                         "stopped.") from None

    def finish(self) -> None:
        """Wait until every queued item is done; raises the worker's exception."""
        self._queue.put(_DONE)
        self._thread.join()
        self._raise()

    def cancel(self) -> None:
        """Drop the waiting items and wait for the one under way (no exception)."""
        self._stop.set()
        with contextlib.suppress(queue.Full):
            self._queue.put_nowait(_DONE)
        while self._thread.is_alive():
            # The queue may have been full: drain it so the sentinel gets in.
            with contextlib.suppress(queue.Empty):
                self._queue.get_nowait()
            with contextlib.suppress(queue.Full):
                self._queue.put_nowait(_DONE)
            self._thread.join(timeout=0.05)


#: End of a ``Background`` queue.
_DONE = object()
