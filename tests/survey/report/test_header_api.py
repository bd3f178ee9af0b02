"""The report header as a library call (issue 32): ``survey.report.header``'s
``report_header`` and ``write_headed_report`` take plain values. Checked: the
checksums against hashlib, the CRS read from a file's ``# crs:`` line against pyproj's
name for it, the user's words and settings in the table, ``formats`` writing exactly
the files asked, ``title`` changing the HTML's title, and the CLI's adapters
(``survey.cli.common``) writing what the library writes."""

from __future__ import annotations

import argparse
import hashlib
import re

import pytest

from survey.report.header import (ReportHeader, header_lines, report_header,
                                  write_headed_report)

TEXT = "# Distances\n\n| a | b |\n|---|---:|\n| 1 | 2 |\n"
STAMP = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ")


def test_report_header_from_plain_values(tmp_path):
    f = tmp_path / "in.csv"
    f.write_bytes(b"x,y,z\n1,2,3\n")
    h = report_header([("cloud", f, "comma"), ("envelope", "box:4,5", ""),
                       ("missing", None, "")], project="Lot 3", instrument="TS16",
                      settings=[("cell", "0.1 m")])
    assert [(i.role, i.sha256, i.note) for i in h.inputs] == [
        ("cloud", hashlib.sha256(b"x,y,z\n1,2,3\n").hexdigest(), "comma"),
        ("envelope", "–", "not a file")]
    lines = header_lines(h)
    assert "| project | Lot 3 |" in lines and "| instrument | TS16 |" in lines
    assert "| cell | 0.1 m |" in lines
    assert "| coordinate reference system | none stated |" in lines


def test_crs_is_read_from_the_files_given(tmp_path):
    pyproj = pytest.importorskip("pyproj")
    d = tmp_path
    (d / "a.csv").write_text("x,y,z\n1,2,3\n")
    (d / "b.csv").write_text("# crs: EPSG:2056\nx,y,z\n1,2,3\n")
    h = report_header([], crs_from=[None, d / "a.csv", d / "b.csv"])
    assert h.crs is not None and pyproj.CRS.from_epsg(2056).name in h.crs
    assert report_header([], crs="given", crs_from=[d / "b.csv"]).crs == "given"


@pytest.mark.parametrize("formats", [("md",), ("html",), ("html", "md")])
def test_formats_write_exactly_the_files_asked(tmp_path, formats):
    got = write_headed_report(tmp_path / "r.md", TEXT, formats=formats, project="P")
    assert [p.suffix[1:] for p in got] == list(formats)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"r.{f}" for f in formats)


def test_title_is_the_html_title(tmp_path):
    _, a = write_headed_report(tmp_path / "a.md", TEXT)
    _, b = write_headed_report(tmp_path / "b.md", TEXT, title="Lot 3: distances")
    assert "<title>Distances</title>" in a.read_text(encoding="utf-8")
    assert "<title>Lot 3: distances</title>" in b.read_text(encoding="utf-8")


def test_bad_formats_and_doubled_header_are_refused(tmp_path):
    for bad in ((), ("pdf",), ("md", "md")):
        with pytest.raises(ValueError, match="Expected formats as distinct values"):
            write_headed_report(tmp_path / "r.md", TEXT, formats=bad)
    with pytest.raises(ValueError, match="either header= or"):
        write_headed_report(tmp_path / "r.md", TEXT, header=ReportHeader(), project="P")
    assert not list(tmp_path.iterdir())


def test_cli_adapter_writes_what_the_library_writes(tmp_path):
    from survey.cli.common import write_headed_report as cli_write

    f = tmp_path / "in.csv"
    f.write_text("x,y,z\n1,2,3\n")
    args = argparse.Namespace(project="Gotthard lot 3", instrument=None)
    cli_write(args, tmp_path / "cli.md", TEXT, [("cloud", f, "")], crs_from=[f],
              settings=[("k", "6")])
    write_headed_report(tmp_path / "lib.md", TEXT, inputs=[("cloud", f, "")],
                        crs_from=[f], settings=[("k", "6")], project="Gotthard lot 3")
    for suffix in (".md", ".html"):
        a = (tmp_path / f"cli{suffix}").read_text(encoding="utf-8")
        b = (tmp_path / f"lib{suffix}").read_text(encoding="utf-8")
        assert STAMP.sub("T", a) == STAMP.sub("T", b)
        assert "Gotthard lot 3" in a and "not given (--instrument)" in a
