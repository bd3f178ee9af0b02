"""The header block every report opens with: what was computed from what, where, when
and by which software, so that a report handed to a client can be checked against the
files it came from (SHA-256 of each input) and read in the right coordinate system.

``ReportHeader`` holds it; ``header_lines`` writes it as Markdown (the HTML report is
made from the same Markdown, ``survey.report.html``). ``report_header`` builds one from
plain values (inputs as (role, path, how it was read), the CRS in words or the files to
read it from, settings, project, instrument) and ``write_headed_report`` writes a
report's Markdown and HTML with it: what every command that writes a report calls, from
the command line or from Python.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Any

__all__ = ["REPORT_FORMATS", "ReportHeader", "ReportInput", "crs_words", "file_sha256",
           "header_lines", "input_entry", "report_header", "software_version",
           "with_header", "write_headed_report"]

#: The files a report can be written as: Markdown and self-contained HTML.
REPORT_FORMATS = ("md", "html")

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

    Attributes
    ----------
    inputs : sequence of ReportInput, the files it was computed from
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


# ------------------------------------------------------------------- from plain values
#: A path or a value given where a path is expected (None: no such input).
PathLike = str | os.PathLike[str]


def crs_words(paths: Iterable[PathLike | None]) -> str | None:
    """The CRS that the first of ``paths`` stating one states, in words.

    Parameters
    ----------
    paths : iterable of path-like or None
        Point clouds (LAS/LAZ/COPC/E57/PLY: the CRS in the file's header) and text
        tables (.csv/.txt: a ``# crs:`` comment line); None and ``.json`` entries
        are skipped.

    Returns
    -------
    str or None
        The CRS in words (``sensors.io.crs.crs_label``); None when no file states one
        (the header then says "none stated").
    """
    from sensors.io.cloudread import cloud_crs_text
    from sensors.io.crs import crs_label, parse_crs, text_file_crs

    for p in paths:
        if p is None:
            continue
        suffix = Path(p).suffix.lower()
        if suffix == ".json":
            continue
        text = text_file_crs(p) if suffix in (".csv", ".txt") else cloud_crs_text(p)
        if text is not None:
            return crs_label(parse_crs(text, metric=False))
    return None


def input_entry(role: str, path: Any, note: str = "") -> ReportInput:
    """One input of a report: the file ``path`` with its SHA-256, or, where ``path``
    names no file, the value as given.

    DECISION: an option's value may name a file with a fragment (``design.xml#NAME``)
    or be no file at all (an envelope given as ``box:W,H``): the file is checksummed
    where there is one, else the value is stated with the checksum "–" and the note
    "not a file" (or ``note`` when given).
    """
    p = Path(str(path).split("#", 1)[0])
    if p.is_file():
        return ReportInput.of(role, path, note)
    return ReportInput(role, str(path), "–", note or "not a file")


def report_header(inputs: Iterable[tuple[str, Any, str]] = (), *, crs: str | None = None,
                  crs_from: Iterable[PathLike | None] = (), project: str | None = None,
                  instrument: str | None = None,
                  settings: Sequence[tuple[str, str]] | None = None) -> ReportHeader:
    """The header of a report, from plain values.

    Parameters
    ----------
    inputs : iterable of (role, path, note)
        The files the report was computed from: its role ("source", "epoch 1"), the
        path (or the value given where a path may be: ``input_entry``), how it was
        read ("" when there is nothing to say). Entries whose path is None are left
        out (an optional input not given).
    crs : str or None
        The CRS in words. When None, it is read from the files ``crs_from``
        (``crs_words``); with neither, the header says "none stated".
    crs_from : iterable of path-like or None
        Files to read the CRS from when ``crs`` is None.
    project, instrument : str or None
        The user's words (``--project``, ``--instrument`` on the command line).
    settings : sequence of (name, value with unit), optional
        The settings the results depend on, stated below the facts.

    Returns
    -------
    ReportHeader
        Dated now (UTC), with this software's version.

    Raises
    ------
    OSError
        When an input file cannot be read for its checksum.
    sensors.io.errors.FileFormatError
        When a file of ``crs_from`` states a CRS that cannot be read.

    Examples
    --------
    >>> h = report_header([("design", "box:6,5", "")], project="Lot 3",
    ...                   settings=[("tolerance", "0.05 m")])
    >>> h.inputs[0].sha256, h.inputs[0].note, h.crs
    ('–', 'not a file', None)
    >>> header_lines(h)[2]
    '| project | Lot 3 |'
    """
    if crs is None:
        crs = crs_words(crs_from)
    return ReportHeader(inputs=[input_entry(r, p, note) for r, p, note in inputs
                                if p is not None],
                        crs=crs, project=project, instrument=instrument,
                        settings=list(settings or []))


def write_headed_report(path: PathLike, text: str, *,
                        inputs: Iterable[tuple[str, Any, str]] = (),
                        crs: str | None = None, crs_from: Iterable[PathLike | None] = (),
                        project: str | None = None, instrument: str | None = None,
                        settings: Sequence[tuple[str, str]] | None = None,
                        header: ReportHeader | None = None, title: str | None = None,
                        formats: Sequence[str] = REPORT_FORMATS) -> tuple[Path, ...]:
    """Write a report with its header block below its title, as Markdown and/or
    self-contained HTML (``survey.report.html.write_report``).

    Parameters
    ----------
    path : path-like
        The Markdown file; the HTML is ``path`` with suffix ``.html``. Its folder must
        exist, and so must the figures the Markdown links (they are embedded in the
        HTML from this folder).
    text : str
        The report's Markdown, starting with its ``# title``.
    inputs, crs, crs_from, project, instrument, settings
        The header's values, as in ``report_header``.
    header : ReportHeader, optional
        A header made already; then the values above must not be given.
    title : str, optional
        The HTML document's ``<title>`` (default: the report's first heading).
    formats : sequence of {"md", "html"}
        The files to write (default both).

    Returns
    -------
    tuple of Path
        The files written, in the order of ``formats``.

    Raises
    ------
    ValueError
        For an unknown or empty ``formats``, or header values given with ``header``.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> md, html = write_headed_report(d / "r.md", "# Result\\n\\nall fine\\n",
    ...                                project="Lot 3")
    >>> md.read_text(encoding="utf-8").splitlines()[:5]
    ['# Result', '', '| report | |', '|---|---|', '| project | Lot 3 |']
    >>> html.name
    'r.html'
    """
    from survey.report.html import write_report

    fmts = tuple(formats)
    bad = [f for f in fmts if f not in REPORT_FORMATS]
    if bad or not fmts or len(set(fmts)) != len(fmts):
        raise ValueError(f"Expected formats as distinct values of {REPORT_FORMATS}, "
                         f"got {fmts!r}.")
    if header is None:
        header = report_header(inputs, crs=crs, crs_from=crs_from, project=project,
                               instrument=instrument, settings=settings)
    elif any(v for v in (tuple(inputs), crs, tuple(crs_from), project, instrument,
                         settings)):
        raise ValueError("Expected either header= or the header's values (inputs=, "
                         "crs=, crs_from=, project=, instrument=, settings=), got both.")
    return write_report(path, with_header(text, header), title=title, formats=fmts)
