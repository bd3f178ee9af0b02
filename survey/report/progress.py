"""The one progress reporter: a bar on stderr that the command line, the pipeline and
the cluster code all draw with.

A ``Progress`` is the ``progress(done, total)`` callback the library functions take:
call it after each chunk, task or tile, and ``close`` it at the end. On a terminal it
redraws one line in place; off one (a log file, a pipe, a job scheduler's output) it
writes the same text as a whole line once every ``LOG_EVERY_S`` seconds, so that a long
run started from a script still says how far it is; nothing at all when ``quiet``. Two
styles of count:

- ``"rate"`` (rays, points): millions done of the total, the rate in millions per
  second and the time left, for work counted in millions;
- ``"count"`` (tasks, stations, tiles): whole counts, the time so far and left.

``Progress.line`` writes a whole line instead (a pipeline's step: "[####    ] 2/5
drive: ... (about 40 s left)"): a log line, written to a terminal and a file alike
unless ``quiet``.

Only the standard library is imported here.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["BAR_WIDTH", "LINE_BAR_WIDTH", "LOG_EVERY_S", "PROGRESS_STYLES", "Progress"]

#: Characters of the in-place bar (``__call__``).
BAR_WIDTH = 30
#: Characters of the bar that starts a log line (``line``).
LINE_BAR_WIDTH = 20
#: Seconds between the whole lines ``__call__`` writes off a terminal. DECISION: a
#: minute: a 20-minute drive run from a script gets ~20 lines, a run under a minute
#: none (its summary says the rest).
LOG_EVERY_S = 60.0
#: How ``__call__`` counts: millions and a rate, or whole counts.
PROGRESS_STYLES = ("rate", "count")


class Progress:
    """A one-line progress bar on a stream (stderr by default), redrawn in place on a
    terminal, written as a whole line every ``LOG_EVERY_S`` seconds off one, never when
    ``quiet``.

    Parameters
    ----------
    quiet : bool
        Draw nothing (``--quiet``). ``line`` writes nothing either.
    unit : str
        What is counted ("rays", "points", "tasks", "tiles of a.laz").
    style : {"rate", "count"}
        ``"rate"``: "12.5 %  1.2M/10.0M rays  3.10 Mrays/s  ETA 3 s"; ``"count"``:
        "3/10 tasks  2 s, ETA 5 s".
    stream : text stream, optional
        Where to draw (default ``sys.stderr`` as it is when the bar is made).
    clock : callable () -> float, optional
        Seconds, for the rate and the time left (default ``time.perf_counter``).

    Attributes
    ----------
    on : bool
        Whether ``__call__`` redraws in place: not quiet and the stream is a terminal.
    logs : bool
        Whether ``__call__`` writes log lines instead: not quiet, not a terminal.
    calls : int
        How many times ``__call__`` was called (drawn or not).
    done, total : int
        The counts of the last call (0 before the first).

    Examples
    --------
    >>> import io
    >>> out = io.StringIO()            # not a terminal: a line a minute at most
    >>> bar = Progress(unit="tasks", style="count", stream=out)
    >>> for i in range(3):
    ...     bar(i + 1, 3)
    >>> bar.close()
    >>> out.getvalue(), bar.on, bar.logs, bar.done, bar.total
    ('', False, True, 3, 3)
    >>> bar.line(0.5, "2/4 mesh: 1 cm")
    >>> out.getvalue()
    '[##########          ] 2/4 mesh: 1 cm\\n'
    """

    def __init__(self, quiet: bool = False, unit: str = "rays", *, style: str = "rate",
                 stream: TextIO | None = None,
                 clock: Callable[[], float] | None = None) -> None:
        if style not in PROGRESS_STYLES:
            raise ValueError(f"Expected style in {PROGRESS_STYLES}, got {style!r}.")
        self.stream = sys.stderr if stream is None else stream
        self.quiet = bool(quiet)
        # DECISION: redraw with "\r" only on a terminal: in a log file each redraw
        # would be a fragment of a line, thousands per run.
        isatty = getattr(self.stream, "isatty", None)
        self.on = not self.quiet and bool(isatty is not None and isatty())
        self.logs = not self.quiet and not self.on
        self.unit = unit
        self.style = style
        self.clock = time.perf_counter if clock is None else clock
        self.t0 = self.clock()
        self._logged = self.t0
        self.calls = 0
        self.done = 0
        self.total = 0

    def text(self, done: int, total: int) -> str:
        """The bar for ``done`` of ``total`` as drawn now (without the leading "\\r")."""
        dt = self.clock() - self.t0
        frac = done / max(total, 1)
        eta = dt / frac - dt if frac > 0 else 0.0
        bar = f"[{'#' * int(BAR_WIDTH * frac):<{BAR_WIDTH}}]"
        u = self.unit
        if self.style == "count":
            return f"{bar} {done}/{total} {u}  {dt:.0f} s, ETA {eta:.0f} s "
        return (f"{bar} {100 * frac:5.1f} %  {done / 1e6:.1f}M/{total / 1e6:.1f}M {u}  "
                f"{done / max(dt, 1e-9) / 1e6:.2f} M{u}/s  ETA {eta:.0f} s ")

    def __call__(self, done: int, total: int) -> None:
        """Record ``done`` of ``total`` and redraw the bar (on a terminal), or write it
        as a line when ``LOG_EVERY_S`` have passed since the last one (off a terminal)."""
        self.calls += 1
        self.done, self.total = int(done), int(total)
        if not self.on:
            if self.logs:
                now = self.clock()
                if now - self._logged >= LOG_EVERY_S:
                    self._logged = now
                    print(self.text(done, total).rstrip(), file=self.stream, flush=True)
            return
        self.stream.write("\r" + self.text(done, total))
        self.stream.flush()

    def close(self) -> None:
        """End the bar's line (on a terminal)."""
        if self.on:
            self.stream.write("\n")

    def line(self, frac: float, text: str) -> None:
        """Write one whole line: a bar of ``frac`` (0..1) of the work, then ``text``;
        on a terminal or not, unless quiet."""
        if self.quiet:
            return
        n = int(LINE_BAR_WIDTH * min(max(frac, 0.0), 1.0))
        print(f"[{'#' * n:<{LINE_BAR_WIDTH}}] {text}", file=self.stream, flush=True)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
