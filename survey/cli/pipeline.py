"""Pipelines: a TOML file that runs ``tunnelsim`` steps in order, in one output folder.

    [pipeline]
    name = "my study"
    seed = 0                     # given to every step that takes --seed

    [[steps]]
    name = "tunnel"              # label in the progress line and the report
    command = "tunnel"           # any tunnelsim command but run and demo
    about = "Lining of {edge-length:cm} triangles."   # one line for the report
    args = []                    # positional arguments
    expect_s = 3                 # estimate for the progress line (optional)
    figures = ["coverage.png"]   # files the report shows (optional)
    tables = ["plan/plan.md"]    # Markdown files the report includes (optional)
    requires = "slam"            # run only when this optional extra is installed (optional)
    unless = "slam"              # run only when it is not: the fallback (optional)
    [steps.options]              # --key value; true -> --key; a list -> repeated
    output = "tunnel.ply"
    edge-length = 0.1
    [steps.quick]                # option overrides for --quick (optional)
    edge-length = 0.25

Each step runs through the command registry (``survey.cli.registry``): its options are
checked against the options its command registered, parsed by the command's own parser
(so a pipeline accepts exactly what the command line accepts), and its function is
called directly. Paths (the options a command registered as files or folders) are
relative to the output folder. A failing step raises ``PipelineError`` naming it.

``about`` is a template filled from the options the step runs (its ``[steps.quick]``
overrides applied with ``--quick``, the command's defaults for the rest), so the report
never describes other numbers than the ones it ran: ``{speed:g}``, ``{cell[0]:cm}``
(a number list is indexed), and the forms ``cm``, ``mm`` and ``%`` (the value times
100, 1000, 100 with the unit), ``range`` ("5,60" -> "5-60") and ``list`` ("0,1,3" ->
"0, 1 and 3"). Write ``{{`` and ``}}`` for braces.

``requires`` and ``unless`` name an optional extra (``EXTRAS``: ``slam``, installed when
``genz_icp`` can be imported; the demo's odometry): a pipeline carries a step that needs the extra and its
fallback, and runs one of them (``active_steps``). The report numbers and lists the
steps that ran; every step, run or not, is checked when the pipeline is loaded.
"""

from __future__ import annotations

import importlib.util
import re
import statistics
import string
import time
import tomllib
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar

from survey.cli.common import NUMBER_LIST, Command, UsageError, out_dir, run_command
from survey.errors import PipelineError, TunnelsimError

_STEP_KEYS = {"name", "command", "about", "args", "options", "quick", "expect_s", "figures",
              "tables", "requires", "unless"}

#: Optional extras a step may name in ``requires`` / ``unless``, and the module whose
#: presence means the extra is installed (pyproject's ``[project.optional-dependencies]``).
EXTRAS = {"slam": "genz_icp"}


def extra_available(name: str) -> bool:
    """Whether the optional extra ``name`` (a key of ``EXTRAS``) is installed: its module
    can be found (not imported: finding it is cheap and has no side effects)."""
    if name not in EXTRAS:
        raise PipelineError(f"Expected an optional extra ({', '.join(sorted(EXTRAS))}), got "
                            f"{name!r}.")
    try:
        return importlib.util.find_spec(EXTRAS[name]) is not None
    except (ImportError, ValueError):   # a broken install counts as none
        return False


def step_runs(step: dict, available: Callable[[str], bool] | None = None) -> bool:
    """Whether a step runs: its ``requires`` extra is installed and its ``unless`` extra
    is not (``available`` tells; default ``extra_available``)."""
    have = extra_available if available is None else available
    if "requires" in step and not have(step["requires"]):
        return False
    return not ("unless" in step and have(step["unless"]))


def active_steps(pipe: dict, *, available: Callable[[str], bool] | None = None) -> list[dict]:
    """The steps of a loaded pipeline that run here, in order (``step_runs``): the ones
    the report numbers and lists."""
    return [st for st in pipe["steps"] if step_runs(st, available)]


def demo_text() -> str:
    """The shipped demo pipeline (TOML text)."""
    return resources.files("survey").joinpath("pipelines/demo.toml").read_text()


def _commands(commands: dict[str, Command] | None) -> dict[str, Command]:
    if commands is not None:
        return commands
    from survey.cli.registry import step_commands

    return step_commands()


def load_pipeline(text: str, source: str = "<pipeline>", *,
                  commands: dict[str, Command] | None = None) -> dict:
    """Parse and check a pipeline; returns {"pipeline": {...}, "steps": [...]}. Every
    step's command, options and ``about`` template are checked here."""
    commands = _commands(commands)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise PipelineError(f"Expected a TOML pipeline in {source}, got a syntax error: "
                            f"{exc}.") from exc
    steps = data.get("steps")
    if not isinstance(steps, list) or not steps:
        raise PipelineError(f"Expected [[steps]] tables in {source}, got none.")
    for i, st in enumerate(steps, 1):
        where = f"{source}, step {i}"
        if not isinstance(st, dict) or "command" not in st:
            raise PipelineError(f"Expected a 'command' in {where}, got {st!r}.")
        bad = set(st) - _STEP_KEYS
        if bad:
            raise PipelineError(f"Expected only {sorted(_STEP_KEYS)} in {where}, got "
                                f"{sorted(bad)}.")
        if st["command"] not in commands:
            raise PipelineError(f"Expected a tunnelsim command in {where} "
                                f"({', '.join(sorted(commands))}), got {st['command']!r}.")
        for key in ("requires", "unless"):
            if key in st and not (isinstance(st[key], str) and st[key] in EXTRAS):
                raise PipelineError(f"Expected '{key}' to name an optional extra "
                                    f"({', '.join(sorted(EXTRAS))}) in {where}, got "
                                    f"{st[key]!r}.")
        st.setdefault("name", st["command"])
        for quick in (False, True):
            step_argv(st, quick=quick, commands=commands)
            step_about(st, quick=quick, commands=commands)
    return {"pipeline": data.get("pipeline", {}), "steps": steps}


def step_options(step: dict, *, quick: bool = False) -> dict:
    """The step's options, with its ``[steps.quick]`` overrides when ``quick``."""
    opts = dict(step.get("options", {}))
    if quick:
        opts.update(step.get("quick", {}))
    return opts


def _value(opt, v: Any, base: Path | None) -> str:
    text = str(v)
    if base is not None and opt is not None and opt.is_path(text) and \
            not Path(text).is_absolute():
        return str(base / text)
    return text


def step_argv(step: dict, *, quick: bool = False, seed: int | None = None,
              threads: int | None = None, quiet: bool = True, force: bool = False,
              base: Path | None = None, commands: dict[str, Command] | None = None,
              scheduler: str | None = None) -> list[str]:
    """The command line of one step (options merged with its quick overrides), checked
    against the options its command registered. ``seed`` and ``threads`` go to the steps
    that take them unless a step sets its own; ``quiet`` and ``force`` (a rerun into the
    same folder replaces the steps' folders too) to those that take them. ``scheduler``
    (the pipeline's cluster) goes as --scheduler to the steps that fan out: those whose
    command takes it and that set one of the options it needs
    (``Command.cluster_needs``: --window-s, --tile-m, --chainages...), unless a step
    names its own --workers or --scheduler. With ``base``, relative paths are resolved
    against that folder (what runs); without, they stay as written (what the report
    shows)."""
    cmd = _commands(commands)[step["command"]]
    name = step.get("name", step["command"])
    pos = cmd.positionals
    argv = [step["command"]]
    for k, a in enumerate(step.get("args", [])):
        argv.append(_value(pos[min(k, len(pos) - 1)] if pos else None, a, base))
    for k, v in step_options(step, quick=quick).items():
        opt = cmd.options.get(k)
        if opt is None or opt.positional:
            raise PipelineError(f"Expected options of 'tunnelsim {step['command']}' in step "
                                f"'{name}', got '--{k}' (see 'tunnelsim {step['command']} "
                                "--help').")
        flag = f"--{k}"
        if isinstance(v, dict):
            raise PipelineError(f"Expected a value, true or a list for '{flag}' in step "
                                f"'{name}', got a table.")
        if v is True:
            argv.append(flag)
        elif v is False or v is None:
            continue
        elif isinstance(v, list):
            for x in v:
                argv += [flag, _value(opt, x, base)]
        else:
            argv += [flag, _value(opt, v, base)]
    for key, val in (("seed", seed), ("threads", threads)):
        if val is not None and key in cmd.options and f"--{key}" not in argv:
            argv += [f"--{key}", str(val)]
    for key, on in (("quiet", quiet), ("force", force)):
        if on and key in cmd.options and f"--{key}" not in argv:
            argv.append(f"--{key}")
    if scheduler is not None and "scheduler" in cmd.options \
            and not {"--workers", "--scheduler"} & set(argv) \
            and (not cmd.cluster_needs
                 or any(f"--{k}" in argv for k in cmd.cluster_needs)):
        argv += ["--scheduler", scheduler]
    return argv


# ---------------------------------------------------------------------------- about
def _number(v: Any) -> str:
    return f"{v:g}" if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)


class _AboutFormatter(string.Formatter):
    """str.format with the pipeline's forms: cm, mm, % (scaled, with the unit), range,
    list; floats without a form print as ``g``."""

    SCALE: ClassVar[dict[str, tuple[float, str]]] = {
        "cm": (100.0, " cm"), "mm": (1000.0, " mm"), "%": (100.0, " %")}

    def format_field(self, value: Any, format_spec: str) -> str:
        vals = value if isinstance(value, tuple) else (value,)
        if format_spec in self.SCALE:
            k, unit = self.SCALE[format_spec]
            return "-".join(f"{k * v:g}" for v in vals) + unit
        if format_spec == "range":
            return "-".join(_number(v) for v in vals)
        if format_spec == "list":
            words = [_number(v) for v in vals]
            return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]
        if not format_spec:
            return ",".join(_number(v) for v in vals)
        return super().format_field(value, format_spec)


def _about_value(v: Any) -> Any:
    """A number list ("5,60", "8,2.0") as a tuple of floats, a number as a float; any
    other value as it is."""
    if isinstance(v, str) and NUMBER_LIST.match(v.strip()):
        parts = [float(x) for x in v.replace(":", ",").split(",")]
        return parts[0] if len(parts) == 1 else tuple(parts)
    return v


def step_about(step: dict, *, quick: bool = False,
               commands: dict[str, Command] | None = None) -> str:
    """The step's ``about`` text filled from the options it runs (see the module doc)."""
    about = step.get("about", "")
    if "{" not in about and "}" not in about:
        return about
    cmd = _commands(commands)[step["command"]]
    argv = step_argv(step, quick=quick, commands=commands)
    try:
        ns = cmd.parse(argv[1:])
        values = {o.name: getattr(ns, o.dest, None) for o in cmd.options.values()}
    except UsageError:   # the run reports it; describe what the step gives
        values = dict(step_options(step, quick=quick))
    values = {k: _about_value(v) for k, v in values.items()}
    try:
        return _AboutFormatter().vformat(about, (), values)
    except (KeyError, IndexError, ValueError, TypeError) as exc:
        raise PipelineError(f"Expected the 'about' of step '{step.get('name')}' to name "
                            f"options of 'tunnelsim {step['command']}' ({{speed:g}}, "
                            f"{{cell[0]:cm}}...), got {about!r} ({type(exc).__name__}: "
                            f"{exc}).") from exc


# ---------------------------------------------------------------------------- running
class _Bar:
    """One progress line per step on stderr (``survey.report.progress.Progress.line``):
    a bar of the work done and an estimate of the time left, from the steps' expected
    times scaled by how the finished steps compared with theirs."""

    def __init__(self, steps, quick, quiet):
        from survey.report.progress import Progress

        self.expect = [float(s.get("expect_s", 10.0)) * (0.25 if quick else 1.0)
                       for s in steps]
        self.actual: list[float] = []
        self.quiet = quiet
        self.progress = Progress(quiet, unit="steps", style="count")

    def start(self, i, name, about):
        if self.quiet:
            return
        done = sum(self.actual)
        # Median of the finished steps' actual/expected ratios, with a prior of 1: one
        # slow step (the first run compiling the Numba kernels) does not swing it.
        ratios = [1.0] + [a / e for a, e in zip(self.actual, self.expect) if e > 0]
        left = statistics.median(ratios) * sum(self.expect[i:])
        frac = done / (done + left) if done + left > 0 else 0.0
        self.progress.line(frac, f"{i + 1}/{len(self.expect)} {name}: {about} "
                                 f"(about {left:.0f} s left)")

    def end(self, seconds):
        self.actual.append(seconds)


def run_pipeline(pipe: dict, out_dir_path, *, quick=False, seed=None, threads=None,
                 quiet=False, force=False, commands: dict[str, Command] | None = None,
                 available: Callable[[str], bool] | None = None,
                 scheduler: str | None = None) -> list:
    """Run the steps that run here (``active_steps``; ``available`` as there) in
    ``out_dir_path`` (created; a non-empty one only with ``force``). Returns
    [(step, argv, seconds)] with each step's ``about`` filled in and its command line as
    the report shows it. A failing step raises ``PipelineError`` naming it (numbered as
    the report numbers the steps that run). ``scheduler``: the address of the dask
    cluster the steps that fan out use (``step_argv``)."""
    commands = _commands(commands)
    out = out_dir(out_dir_path, force)
    base = out.resolve()
    seed = pipe["pipeline"].get("seed") if seed is None else seed
    steps = active_steps(pipe, available=available)
    bar = _Bar(steps, quick, quiet)
    done = []
    for i, st in enumerate(steps):
        name = st.get("name", st["command"])
        cmd = commands[st["command"]]
        shown = step_argv(st, quick=quick, seed=seed, threads=threads, force=force,
                          commands=commands, scheduler=scheduler)
        about = step_about(st, quick=quick, commands=commands) or st["command"]
        bar.start(i, name, about)
        t = time.perf_counter()
        try:
            args = cmd.parse(step_argv(st, quick=quick, seed=seed, threads=threads,
                                       force=force, base=base, commands=commands,
                                       scheduler=scheduler)[1:])
            run_command(cmd, args)
        except TunnelsimError as exc:
            text = " ".join(str(exc).split())
            raise PipelineError(f"Expected step {i + 1} '{name}' to succeed, got: {text} "
                                f"[tunnelsim {' '.join(shown)}, in {out}]") from exc
        dt = time.perf_counter() - t
        bar.end(dt)
        done.append((dict(st, about=about), shown, dt))
    return done


def pipeline_report(pipe: dict, done: list, out_dir_path, *, intro: str = "") -> str:
    """report.md text: per step that ran (``done``, from ``run_pipeline``) what it does,
    its command, time, tables and figures (links relative to the folder; only files that
    exist). Steps left out by ``requires`` / ``unless`` are not in it."""
    out = Path(out_dir_path)
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
                text = p.read_text(encoding="utf-8")
                # Figures the table links sit beside it: their links made relative to
                # this report's folder.
                here = Path(t).parent.as_posix()
                if here not in ("", "."):
                    text = re.sub(r"(!\[[^\]]*\]\()(?![a-z]+:|/)([^)]+\))",
                                  lambda m: m.group(1) + here + "/" + m.group(2), text)
                # Nested headings one level down, under the step's own.
                lines += [("##" + ln if ln.startswith("#") else ln)
                          for ln in text.rstrip().splitlines()] + [""]
        for f in st.get("figures", []):
            if (out / f).is_file():
                lines += [f"![{Path(f).stem}]({f})", ""]
    return "\n".join(lines) + "\n"


__all__ = ["EXTRAS", "active_steps", "demo_text", "extra_available", "load_pipeline",
           "pipeline_report", "run_pipeline", "step_about", "step_argv", "step_options",
           "step_runs"]
