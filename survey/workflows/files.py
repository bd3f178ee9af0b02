"""What every workflow does with its outputs: the output folder (new or empty, or
replaced with ``force``), text files written atomically, and the executor its tasks
run on.

The messages are the command line's (they name ``--force``): the workflows write what
the commands write, and the commands print these messages unchanged.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from raytrace.fileio import atomic_writer
from survey.errors import CompareError, TunnelsimError

__all__ = ["ExecutorArg", "opened_executor", "output_folder", "write_text_file"]

PathLike = str | os.PathLike[str]
#: What a workflow runs tasks on: an executor, a function opening one when the tasks
#: start (closed when they are done), or None (this process).
ExecutorArg = Any


def output_folder(path: PathLike, *, force: bool = False,
                  error: type[TunnelsimError] = CompareError) -> Path:
    """An output folder: created when missing; an existing, non-empty one only with
    ``force`` (its files are then replaced one by one, atomically).

    Parameters
    ----------
    path : str or path
        The folder.
    force : bool
        Accept a folder that holds files.
    error : type of TunnelsimError
        The class raised (each workflow raises its own kind).

    Returns
    -------
    Path
        The folder, existing.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise error(f"Expected an output folder, got '{p}' which is a file; choose "
                    "another name.")
    if p.is_dir() and any(p.iterdir()) and not force:
        raise error(f"Expected a new or empty output folder, got '{p}' which holds "
                    "files; pass --force to replace them.")
    if not p.parent.exists():
        raise error(f"Expected an existing parent folder for '{p}', got none; create it "
                    "first.")
    p.mkdir(exist_ok=True)
    return p


def write_text_file(path: Path, text: str) -> Path:
    """``text`` to ``path``, atomically (the folder exists); returns ``path``."""
    with atomic_writer(path, "w") as fh:
        fh.write(text)
    return path


@contextmanager
def opened_executor(executor: ExecutorArg) -> Iterator[Any]:
    """The executor to run tasks on: ``executor`` itself (left open), the one a
    callable returns (closed at the end), or this process (None)."""
    from survey.cluster import Executor

    if executor is None:
        yield Executor()
    elif isinstance(executor, Executor):
        yield executor
    else:
        with executor() as ex:
            yield ex
