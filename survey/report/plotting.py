"""The one way the survey layer makes figures: matplotlib without a screen (Agg), saved
as PNG atomically (a crash never leaves a half-written image)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

from raytrace.fileio import atomic_writer

__all__ = ["pyplot", "save_png"]

P = TypeVar("P", bound="str | Path")


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig: Any, path: P, **kwargs: Any) -> P:
    """Write ``fig`` to ``path`` as PNG (atomic) and close it; returns ``path``."""
    plt = pyplot()
    try:
        with atomic_writer(path) as fh:
            fig.savefig(fh, format="png", **kwargs)
    finally:
        plt.close(fig)
    return path
