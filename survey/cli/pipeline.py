"""Pipelines: a TOML file that runs ``tunnelsim`` steps in order, in one output folder.

    [pipeline]
    name = "my study"
    seed = 0                     # given to every step that takes --seed

    [[steps]]
    name = "tunnel"              # label in the progress line and the report
    command = "tunnel"           # any tunnelsim subcommand
    about = "one line for the report"
    args = []                    # positional arguments
    expect_s = 3                 # estimate for the progress line (optional)
    figures = ["coverage.png"]   # files the report shows (optional)
    tables = ["plan/plan.md"]    # Markdown files the report includes (optional)
    [steps.options]              # --key value; true -> --key; a list -> repeated
    output = "tunnel.ply"
    edge-length = 0.1
    [steps.quick]                # option overrides for --quick (optional)
    edge-length = 0.25

Paths inside steps are relative to the output folder. Each step is parsed by the same
parser as the command line, so a pipeline accepts exactly what the CLI accepts.
"""

from __future__ import annotations

import os
import sys
import time
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from survey.errors import PipelineError


_STEP_KEYS = {"name", "command", "about", "args", "options", "quick", "expect_s", "figures",
              "tables"}


def demo_text() -> str:
    """The shipped demo pipeline (TOML text)."""
    return resources.files("survey").joinpath("pipelines/demo.toml").read_text()


def load_pipeline(text: str, source: str = "<pipeline>") -> dict:
    """Parse and check a pipeline; returns {"pipeline": {...}, "steps": [...]}."""
    from survey.cli.main import build_parser

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise PipelineError(f"Expected a TOML pipeline in {source}, got a syntax error: "
                            f"{exc}.") from exc
    steps = data.get("steps")
    if not isinstance(steps, list) or not steps:
        raise PipelineError(f"Expected [[steps]] tables in {source}, got none.")
    commands = _commands(build_parser())
    for i, st in enumerate(steps, 1):
        where = f"{source}, step {i}"
        if not isinstance(st, dict) or "command" not in st:
            raise PipelineError(f"Expected a 'command' in {where}, got {st!r}.")
        bad = set(st) - _STEP_KEYS
        if bad:
            raise PipelineError(f"Expected only {sorted(_STEP_KEYS)} in {where}, got "
                                f"{sorted(bad)}.")
        if st["command"] not in commands or st["command"] in ("run", "demo"):
            raise PipelineError(f"Expected a tunnelsim command in {where} "
                                f"({', '.join(sorted(c for c in commands if c not in ('run', 'demo')))}), "
                                f"got {st['command']!r}.")
        st.setdefault("name", st["command"])
    return {"pipeline": data.get("pipeline", {}), "steps": steps}


def _commands(parser):
    for a in parser._actions:
        if a.__class__.__name__ == "_SubParsersAction":
            return a.choices
    return {}


def step_argv(step: dict, *, quick=False, seed=None, threads=None, quiet=True) -> list:
    """The command line of one step (options merged with its quick overrides)."""
    from survey.cli.main import build_parser

    opts = dict(step.get("options", {}))
    if quick:
        opts.update(step.get("quick", {}))
    sub = _commands(build_parser())[step["command"]]
    known = {s for a in sub._actions for s in a.option_strings}
    argv = [step["command"], *[str(a) for a in step.get("args", [])]]
    for k, v in opts.items():
        flag = f"--{k}"
        if flag not in known:
            raise PipelineError(f"Expected options of 'tunnelsim {step['command']}' in step "
                                f"'{step['name']}', got '{flag}' (see 'tunnelsim "
                                f"{step['command']} --help').")
        if v is True:
            argv.append(flag)
        elif v is False or v is None:
            continue
        elif isinstance(v, list):
            for x in v:
                argv += [flag, str(x)]
        else:
            argv += [flag, str(v)]
    for flag, val in (("--seed", seed), ("--threads", threads)):
        if val is not None and flag in known and flag not in argv:
            argv += [flag, str(val)]
    if quiet and "--quiet" in known and "--quiet" not in argv:
        argv.append("--quiet")
    return argv


class _Bar:
    """One progress line per step on stderr: a bar of the work done and an estimate of
    the time left, from the steps' expected times scaled by how the finished steps
    compared with theirs."""

    def __init__(self, steps, quick, quiet):
        self.expect = [float(s.get("expect_s", 10.0)) * (0.25 if quick else 1.0)
                       for s in steps]
        self.actual = []
        self.quiet = quiet

    def start(self, i, step):
        if self.quiet:
            return
        done = sum(self.actual)
        # Median of the finished steps' actual/expected ratios, with a prior of 1: one
        # slow step (the first run compiling the Numba kernels) does not swing it.
        ratios = [1.0] + [a / e for a, e in zip(self.actual, self.expect) if e > 0]
        left = float(np.median(ratios)) * sum(self.expect[i:])
        frac = done / (done + left) if done + left > 0 else 0.0
        bar = "#" * int(20 * frac)
        print(f"[{bar:<20}] {i + 1}/{len(self.expect)} {step['name']}: "
              f"{step.get('about', step['command'])} (about {left:.0f} s left)",
              file=sys.stderr, flush=True)

    def end(self, i, seconds):
        self.actual.append(seconds)


def run_pipeline(pipe: dict, out_dir, *, quick=False, seed=None, threads=None,
                 quiet=False, force=False) -> list:
    """Run every step in ``out_dir`` (created; a non-empty one only with ``force``).
    Returns [(step, argv, seconds)]. A failing step raises ``PipelineError`` naming it."""
    from survey.cli.main import main
    from survey.cli.commands.analysis import out_dir as _out_dir

    out = _out_dir(out_dir, force)
    seed = pipe["pipeline"].get("seed") if seed is None else seed
    steps = pipe["steps"]
    bar = _Bar(steps, quick, quiet)
    done = []
    cwd = os.getcwd()
    os.chdir(out)
    try:
        for i, st in enumerate(steps):
            argv = step_argv(st, quick=quick, seed=seed, threads=threads, quiet=True)
            bar.start(i, st)
            t = time.perf_counter()
            rc = main(argv)
            dt = time.perf_counter() - t
            if rc != 0:
                raise PipelineError(f"Expected step {i + 1} '{st['name']}' to succeed, got "
                                    f"exit status {rc} from: tunnelsim {' '.join(argv)} "
                                    f"(in {out}).")
            bar.end(i, dt)
            done.append((st, argv, dt))
    finally:
        os.chdir(cwd)
    return done


def pipeline_report(pipe: dict, done: list, out_dir, *, intro: str = "") -> str:
    """report.md text: per step what it does, its command, time, tables and figures
    (links relative to the folder; only files that exist)."""
    out = Path(out_dir)
    total = sum(d for _, _, d in done)
    lines = [f"# {pipe['pipeline'].get('name', 'tunnelsim pipeline')}", ""]
    if intro:
        lines += [intro.rstrip(), ""]
    lines += [f"{len(done)} steps in {total:.0f} s.", ""]
    for i, (st, argv, dt) in enumerate(done, 1):
        lines += [f"## {i}. {st['name']}", ""]
        if st.get("about"):
            lines += [st["about"], ""]
        lines += ["```", "tunnelsim " + " ".join(argv), "```", f"({dt:.1f} s)", ""]
        for t in st.get("tables", []):
            p = out / t
            if p.is_file():
                text = p.read_text()
                # Nested headings one level down, under the step's own.
                lines += [("##" + ln if ln.startswith("#") else ln)
                          for ln in text.rstrip().splitlines()] + [""]
        for f in st.get("figures", []):
            if (out / f).is_file():
                lines += [f"![{Path(f).stem}]({f})", ""]
    return "\n".join(lines) + "\n"
