"""The one progress reporter (issue 32): ``survey.report.progress.Progress`` draws the
bars of the command line, the pipeline and the cluster code. Checked: the counts it
shows against the counts given (parsed back from the text), the bar's length against
floor(width * done / total), the rate and time left against a clock the test drives,
nothing drawn when quiet, a whole line a minute off a terminal, and the pipeline's step
lines through the real ``tunnelsim run``."""

from __future__ import annotations

import io
import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from survey.report.progress import BAR_WIDTH, LINE_BAR_WIDTH, LOG_EVERY_S, Progress


class _Terminal(io.StringIO):
    """A stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


class _Clock:
    """Seconds the test sets."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _frames(text: str) -> list[str]:
    return [f for f in text.split("\r") if f]


def test_rate_style_shows_millions_rate_and_time_left():
    clock = _Clock()
    out = _Terminal()
    bar = Progress(unit="rays", stream=out, clock=clock)
    clock.now += 4.0                        # 4 s for 1.2 M of 4.8 M rays
    bar(1_200_000, 4_800_000)
    bar.close()
    # 25 %: 7 of 30 characters; rate 0.3 M/s; 4 s / 0.25 - 4 s = 12 s left.
    assert out.getvalue() == ("\r[#######                       ]  25.0 %  1.2M/4.8M rays  "
                              "0.30 Mrays/s  ETA 12 s \n")


def test_count_style_shows_whole_counts():
    clock = _Clock()
    out = _Terminal()
    bar = Progress(unit="tiles", style="count", stream=out, clock=clock)
    for done, t in ((1, 3.0), (2, 6.0), (4, 12.0)):
        clock.now = 100.0 + t
        bar(done, 4)
    bar.close()
    frames = _frames(out.getvalue())
    assert frames == ["[#######                       ] 1/4 tiles  3 s, ETA 9 s ",
                      "[###############               ] 2/4 tiles  6 s, ETA 6 s ",
                      "[##############################] 4/4 tiles  12 s, ETA 0 s \n"]
    assert (bar.calls, bar.done, bar.total) == (3, 4, 4)


@given(total=st.integers(1, 10**9), data=st.data())
def test_the_bar_shows_the_counts_it_was_given(total, data):
    done = data.draw(st.integers(0, total))
    clock = _Clock()
    for style in ("rate", "count"):
        out = _Terminal()
        bar = Progress(unit="points", style=style, stream=out, clock=clock)
        clock.now += 1.0
        bar(done, total)
        text = out.getvalue()
        m = re.fullmatch(r"\r\[(#*) *\] (.*)", text)
        assert m is not None and len(text) - len(m.group(2)) == BAR_WIDTH + 4
        # Exact reference in integers; the float product may land one below a whole
        # number of characters exactly at a boundary.
        ref, at_edge = divmod(BAR_WIDTH * done, total)
        assert len(m.group(1)) == ref or (at_edge == 0 and len(m.group(1)) == ref - 1)
        if style == "count":
            assert m.group(2).startswith(f"{done}/{total} points  ")
        else:
            pct, d, t = re.match(r"\s*([\d.]+) %  ([\d.]+)M/([\d.]+)M points",
                                 m.group(2)).groups()
            assert abs(float(pct) - 100 * done / total) <= 0.05 + 1e-9
            assert abs(float(d) - done / 1e6) <= 0.05 + 1e-9
            assert abs(float(t) - total / 1e6) <= 0.05 + 1e-9


def test_quiet_and_non_terminal_draw_nothing_but_count():
    for quiet, stream in ((True, _Terminal()), (False, io.StringIO())):
        bar = Progress(quiet, unit="tasks", style="count", stream=stream, clock=_Clock())
        for i in range(5):
            bar(i + 1, 5)
        bar.close()
        assert stream.getvalue() == "" and not bar.on
        assert (bar.calls, bar.done, bar.total) == (5, 5, 5)
    quiet = _Terminal()
    Progress(True, stream=quiet).line(0.5, "step")
    assert quiet.getvalue() == ""


@given(st.lists(st.floats(0.0, 400.0), min_size=1, max_size=40), st.booleans())
def test_off_a_terminal_a_whole_line_each_minute(times, quiet):
    """A log file or a pipe gets the bar's text as whole lines, one each time
    LOG_EVERY_S have passed since the last (the count the bar was given), nothing in
    between, no carriage returns, and nothing at all when quiet."""
    clock = _Clock()
    out = io.StringIO()
    bar = Progress(quiet, unit="rays", stream=out, clock=clock)
    want, last = [], 100.0
    for i, t in enumerate(sorted(times)):
        clock.now = 100.0 + t
        bar((i + 1) * 1_000_000, len(times) * 1_000_000)
        if clock.now - last >= LOG_EVERY_S:
            last = clock.now
            want.append(i + 1)
    bar.close()
    text = out.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    if quiet:
        assert text == ""
        return
    assert len(lines) == len(want)
    for line, done in zip(lines, want):
        got = re.search(r"(\d+\.\d)M/(\d+\.\d)M rays", line)
        assert got is not None and float(got.group(1)) == pytest.approx(done, abs=0.05)


def test_a_line_is_written_off_a_terminal_too():
    out = io.StringIO()
    bar = Progress(stream=out)
    for frac in (0.0, 0.26, 1.0, 1.7):
        bar.line(frac, "x")
    assert out.getvalue().splitlines() == [
        "[" + "#" * n + " " * (LINE_BAR_WIDTH - n) + "] x" for n in (0, 5, 20, 20)]


def test_bad_style_is_refused():
    with pytest.raises(ValueError, match="Expected style in"):
        Progress(style="bar")


def test_cli_pipeline_and_cluster_use_the_one_reporter(monkeypatch):
    from survey.cli import common
    from survey.cluster import InProcess, TaskProgress

    assert common.Progress is Progress
    assert issubclass(TaskProgress, Progress)
    out = _Terminal()
    monkeypatch.setattr("sys.stderr", out)
    bar = TaskProgress(False, "stations")
    assert InProcess().map(lambda x: x * x, [1, 2, 3], progress=bar) == [1, 4, 9]
    bar.close()
    frames = _frames(out.getvalue())
    assert [re.match(r"\[#* *\] (\d+/\d+ stations)", f).group(1) for f in frames] == \
        ["1/3 stations", "2/3 stations", "3/3 stations"]
    assert frames[-1].endswith("\n")


def test_run_prints_one_line_per_step(tmp_path, capsys):
    """``tunnelsim run`` without --quiet: one line per step on stderr; the first states
    the sum of the expected times (4 + 8 s) with an empty bar; after it, the time left
    is the expected time of the last step scaled by the median of (1, actual / 4 s)."""
    from survey.cli.main import main

    (tmp_path / "p.toml").write_text('''
[[steps]]
name = "first"
command = "tunnel"
expect_s = 4
[steps.options]
output = "t.ply"
preset = "tbm"
edge-length = 0.75

[[steps]]
name = "second"
command = "tunnel"
expect_s = 8
[steps.options]
output = "u.ply"
preset = "tbm"
edge-length = 0.75
''')
    assert main(["run", str(tmp_path / "p.toml"), "-o", str(tmp_path / "o")]) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("[")]
    assert lines[0] == "[" + " " * LINE_BAR_WIDTH + "] 1/2 first: tunnel (about 12 s left)"
    m = re.fullmatch(r"\[(#*) *\] 2/2 second: tunnel \(about (\d+) s left\)", lines[1])
    assert m is not None and len(lines) == 2
