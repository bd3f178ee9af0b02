"""The header block every report opens with: what was computed from what, where, when
and by which software, so that a report handed to a client can be checked against the
files it came from (SHA-256 of each input) and read in the right coordinate system.

``ReportHeader`` holds it; ``header_lines`` writes it as Markdown (the HTML report is
made from the same Markdown, ``survey.report.html``).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

__all__ = ["ReportHeader", "ReportInput", "file_sha256", "header_lines", "software_version",
           "with_header"]

#: Bytes read at a time when hashing an input.
HASH_CHUNK = 1 << 20


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes as 64 hex digits (read in chunks)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(HASH_CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def software_version() -> str:
    """``tunnelsim <version>`` of the installed distribution ("0+unknown" from a bare
    source tree)."""
    try:
        return f"tunnelsim {metadata.version('tunnelsim')}"
    except metadata.PackageNotFoundError:  # running from a source tree
        return "tunnelsim 0+unknown"


@dataclass(frozen=True)
class ReportInput:
    """One input file: its ``role`` in the computation ("source", "epoch 1"), its
    ``path``, its SHA-256 and (optional) how it was read (``note``: the table dialect)."""

    role: str
    path: str
    sha256: str
    note: str = ""

    @classmethod
    def of(cls, role: str, path: str | Path, note: str = "") -> ReportInput:
        """The input ``path`` with its checksum computed now."""
        return cls(role, str(path), file_sha256(path), note)


@dataclass(frozen=True)
class ReportHeader:
    """What a report states before its results.

    inputs : the files it was computed from
    crs : the coordinate reference system in words, or None ("none stated")
    project, instrument : the user's words (``--project``, ``--instrument``), or None
    date_utc : ISO 8601 time of the computation, UTC (default: now)
    software : ``software_version()`` (default)
    settings : [(name, value with unit)]: the settings the results depend on
    """

    inputs: Sequence[ReportInput] = ()
    crs: str | None = None
    project: str | None = None
    instrument: str | None = None
    date_utc: str = field(default_factory=lambda: datetime.now(timezone.utc).strftime(
        "%Y-%m-%dT%H:%M:%SZ"))
    software: str = field(default_factory=software_version)
    settings: Sequence[tuple[str, str]] = ()


def _cell(text: str) -> str:
    """Text safe inside a Markdown table cell."""
    return str(text).replace("|", "\\|").replace("\n", " ")


def header_lines(h: ReportHeader) -> list[str]:
    """The header block as Markdown lines (a table of facts, then one of inputs)."""
    rows = [("project", h.project or "not given (--project)"),
            ("instrument", h.instrument or "not given (--instrument)"),
            ("coordinate reference system", h.crs or "none stated"),
            ("software", h.software), ("computed (UTC)", h.date_utc)]
    rows += list(h.settings)
    lines = ["| report | |", "|---|---|"]
    lines += [f"| {_cell(k)} | {_cell(v)} |" for k, v in rows]
    if h.inputs:
        lines += ["", "| input | file | SHA-256 | read as |", "|---|---|---|---|"]
        lines += [f"| {_cell(i.role)} | `{_cell(i.path)}` | `{i.sha256}` | "
                  f"{_cell(i.note) or '–'} |" for i in h.inputs]
    return lines + [""]


def with_header(text: str, header: ReportHeader | None) -> str:
    """Report Markdown ``text`` with the header block below its first heading (at the
    top when it has none); ``text`` unchanged for None. For the report writers that
    take no ``header`` argument."""
    if header is None:
        return text
    lines = text.splitlines()
    at = next((i + 1 for i, ln in enumerate(lines) if ln.startswith("# ")), 0)
    block = ([""] if at else []) + header_lines(header)
    return "\n".join(lines[:at] + block + lines[at:]).rstrip("\n") + "\n"
