"""Commands for cameras: render (one frame from the mesh), cameras (the models)."""

from __future__ import annotations

from survey.cli.common import CommandSet


def register(commands: CommandSet) -> None:
    """Add render and cameras (filled in by issue 35's work)."""
