"""The ``tunnelsim`` command: a leaf over the library (nothing in survey imports it)."""

from survey.cli.main import main

__all__ = ["main"]
