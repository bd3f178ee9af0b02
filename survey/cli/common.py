"""What every ``tunnelsim`` command shares: the parser class and its one-line usage
errors, option parsing helpers, output files and folders, the progress bar (the
library's ``survey.report.progress.Progress``, loaded on first use), and the
command registry.

The registry records, per command, the options it registered (their names, whether they
take a value, which are paths read or written) and the function that runs it. The
parser is built from it, the pipeline checks a step's options against it, and
``run_command`` runs a parsed command: threads first, then the function, and on failure
it removes the files and folders the command had begun to create.

Only the standard library, ``raytrace.errors`` (via ``survey.errors``) and
``survey.errors`` are imported here: every ``tunnelsim`` start reads this module.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import re
import shutil
import sys
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from survey.errors import TunnelsimCLIError

#: Exit status of every error a user can fix (bad arguments, bad files).
EXIT_USAGE = 2
#: Exit status after Ctrl-C (128 + SIGINT), as shells report it.
EXIT_INTERRUPTED = 130

#: A value that is a number or a list of numbers separated by commas or colons, which
#: may start with a minus sign: "-3.2,10,1.5", "-5", "-1e3:2".
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
NUMBER_LIST = re.compile(rf"^{_NUMBER}(?:[,:]\s*{_NUMBER})*$")


class UsageError(TunnelsimCLIError):
    """A command line the parser refuses (unknown option, missing or bad value)."""


class Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line (a ``UsageError``, exit 2 in
    ``main``) and that takes a number list beginning with a minus sign as the value of
    the option before it.

    argparse reads "-3.2,10,1.5" as an option because it starts with "-" and is not a
    plain negative number; ``--at=-3.2,10,1.5`` always worked, ``--at -3.2,10,1.5``
    did not. Here a number list that follows an option taking a value is joined to it
    ("--at=-3.2,10,1.5") before argparse sees the line.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.value_flags: set[str] = set()    # options that take a value
        self.all_flags: set[str] = set()

    def error(self, message: str):
        raise UsageError(f"{message} (see '{self.prog} --help')")

    def parse_known_args(self, args=None, namespace=None):
        args = sys.argv[1:] if args is None else list(args)
        return super().parse_known_args(self._join_negative_values(args), namespace)

    def _flag_of(self, token: str) -> str | None:
        """The option a token names: itself, or the one flag it abbreviates."""
        if token in self.all_flags:
            return token
        if token.startswith("--") and self.allow_abbrev:
            hits = [f for f in self.all_flags if f.startswith(token)]
            if len(hits) == 1:
                return hits[0]
        return None

    def _join_negative_values(self, args: list[str]) -> list[str]:
        out: list[str] = []
        i = 0
        while i < len(args):
            tok = args[i]
            if tok == "--":          # everything after is positional
                out += args[i:]
                break
            flag = self._flag_of(tok) if tok.startswith("-") and "=" not in tok else None
            nxt = args[i + 1] if i + 1 < len(args) else None
            if flag in self.value_flags and nxt is not None and nxt.startswith("-") and \
                    NUMBER_LIST.match(nxt):
                out.append(f"{tok}={nxt}")
                i += 2
                continue
            out.append(tok)
            i += 1
        return out


# ---------------------------------------------------------------------------- registry
@dataclass(frozen=True)
class Option:
    """One option (or positional argument) of a command.

    ``name`` is the long flag without its dashes ("edge-length", the key of a pipeline
    step's options) or a positional's name; ``dest`` the attribute of the parsed
    namespace; ``path`` says whether the value is a file or folder the command reads
    ("in"), writes ("out"), or reads when it ends in ".toml" ("toml": sensor names).
    """

    name: str
    dest: str
    flags: tuple[str, ...]
    takes_value: bool
    repeatable: bool = False
    path: str | None = None
    metavar: str | None = None

    @property
    def positional(self) -> bool:
        return not self.flags

    def is_path(self, value: object) -> bool:
        """Whether ``value`` of this option names a file or folder."""
        if self.path == "toml":
            return str(value).lower().endswith(".toml")
        return self.path in ("in", "out")


_PATH_KINDS = (None, "in", "out", "toml")
_FLAG_ACTIONS = ("store_true", "store_false", "store_const", "count", "help", "version")


@dataclass
class Command:
    """A ``tunnelsim`` command: its parser, the options it registered, and ``func``
    (parsed namespace -> exit status; raises ``TunnelsimError`` on bad input)."""

    name: str
    func: Callable[[argparse.Namespace], int]
    parser: Parser
    seeded: bool = False
    printing: bool = False
    options: dict[str, Option] = field(default_factory=dict)
    #: Options one of which --workers / --scheduler need (drive: "window-s", compare:
    #: "tile-m", scan: "chainages" or "plan"); a pipeline run on a cluster hands its
    #: scheduler only to steps that take it and set one of them (``cluster_options``).
    cluster_needs: tuple[str, ...] = ()

    def option(self, *flags: str, path: str | None = None, group: Any = None,
               **kwargs: Any) -> Option:
        """Add an option (``add_argument`` arguments) and record it; ``group`` is a
        group from ``exclusive``; ``path`` as in ``Option``."""
        if path not in _PATH_KINDS:
            raise ValueError(f"Expected path in {_PATH_KINDS}, got {path!r}.")
        action = (group or self.parser).add_argument(*flags, **kwargs)
        longs = [f for f in action.option_strings if f.startswith("--")]
        name = longs[0][2:] if longs else action.dest
        takes = kwargs.get("action") not in _FLAG_ACTIONS
        opt = Option(name, action.dest, tuple(action.option_strings), takes,
                     kwargs.get("action") == "append", path, kwargs.get("metavar"))
        self.options[name] = opt
        self.parser.all_flags.update(opt.flags)
        if takes:
            self.parser.value_flags.update(opt.flags)
        return opt

    def exclusive(self, required: bool = False):
        """A mutually exclusive group to pass as ``option(..., group=g)``."""
        return self.parser.add_mutually_exclusive_group(required=required)

    @property
    def positionals(self) -> list[Option]:
        return [o for o in self.options.values() if o.positional]

    def parse(self, argv: list[str]) -> argparse.Namespace:
        """The namespace of this command's arguments (``argv`` without the command
        name); ``UsageError`` when the parser refuses them."""
        return self.parser.parse_args(argv)

    def outputs(self, args: argparse.Namespace) -> list[Path]:
        """The files and folders this command writes, as named by ``args``."""
        out = []
        for o in self.options.values():
            if o.path != "out":
                continue
            v = getattr(args, o.dest, None)
            for x in (v if isinstance(v, list) else [v]):
                if x is not None and not isinstance(x, bool):
                    out.append(Path(x))
        return out


class CommandSet:
    """The commands of one parser, in the order their modules registered them. A
    command module's ``register(commands)`` calls ``add`` and ``Command.option``."""

    def __init__(self, subparsers: Any) -> None:
        self._sub = subparsers
        self.commands: dict[str, Command] = {}

    def add(self, name: str, func: Callable[[argparse.Namespace], int], *, help: str,
            description: str, epilog: str, seeded: bool = False,
            printing: bool = False) -> Command:
        if name in self.commands:
            raise ValueError(f"Expected a new command name, got {name!r} twice.")
        parser = self._sub.add_parser(name, help=help, description=description,
                                      epilog=epilog)
        cmd = Command(name, func, parser, seeded=seeded, printing=printing)
        self.commands[name] = cmd
        return cmd

    def finish(self) -> dict[str, Command]:
        """Add the options every command shares where it did not define them: --debug
        everywhere; --quiet and --threads wherever work is done (not the printing
        commands); --seed wherever random numbers are drawn. Returns the commands."""
        for cmd in self.commands.values():
            have = cmd.options
            if "debug" not in have:
                cmd.option("--debug", action="store_true",
                           help="show tracebacks instead of one-line errors")
            if cmd.printing:
                continue
            if "quiet" not in have:
                cmd.option("--quiet", action="store_true", help="print nothing on success")
            if "threads" not in have:
                cmd.option("--threads", type=int, metavar="N",
                           help="Numba threads (default: all cores)")
            if cmd.seeded and "seed" not in have:
                cmd.option("--seed", type=int, default=0, help="random seed (default 0)")
        return self.commands


def run_command(cmd: Command, args: argparse.Namespace) -> int:
    """Run a parsed command: set the thread count, call its function, and when it
    fails (any exception, Ctrl-C included) remove the outputs it had begun to create.
    Errors propagate; ``main`` turns them into one line."""
    threads = getattr(args, "threads", None)
    if threads is not None:
        from raytrace import set_threads

        try:
            set_threads(threads)
        except ValueError as exc:     # TunnelsimError is a ValueError too
            raise TunnelsimCLIError(f"--threads: {exc}") from exc
    with removed_on_failure(cmd.outputs(args)):
        return int(cmd.func(args) or 0)


# ---------------------------------------------------------------------------- outputs
def _siblings(p: Path) -> set[Path]:
    """Files a command derives from an output's name: ``stem.*`` (a tunnel's .json)
    and ``stem_*`` (a drive's _trajectory.txt, a correction's _report.md), and the
    atomic writers' temporaries ``.name.*.part``."""
    parent = p.parent if str(p.parent) else Path(".")
    if not p.name or p.name in (".", "..") or not parent.is_dir():
        return set()
    stem = p.stem
    found: set[Path] = set()
    for pattern in (f"{stem}.*", f"{stem}_*", f".{p.name}.*.part"):
        found.update(parent.glob(pattern))
    return found


@contextlib.contextmanager
def removed_on_failure(paths: list[Path]) -> Iterator[None]:
    """On an exception inside the block, remove what the block created at ``paths``
    (a file, or a folder with everything in it), the new files named after them
    (``_siblings``) and the new entries of an output folder that existed before.
    Nothing that existed before the block is removed.

    DECISION: remove after the fact rather than write into a temporary folder: the
    commands write several files beside their output (a drive's trajectories and
    control points), and folders like ``compare -o DIR --force`` may already hold the
    user's files, which must stay."""
    before = []
    for p in paths:
        existed = p.exists() or p.is_symlink()
        inside = set(p.iterdir()) if p.is_dir() else set()
        before.append((p, existed, inside, _siblings(p)))
    try:
        yield
    except BaseException:
        for p, existed, inside, sibs in before:
            doomed = set(_siblings(p)) - sibs
            if not existed:
                doomed.add(p)
            elif p.is_dir() and not p.is_symlink():
                doomed |= set(p.iterdir()) - inside
            for q in doomed:
                with contextlib.suppress(OSError):
                    if q.is_dir() and not q.is_symlink():
                        shutil.rmtree(q)
                    elif q.exists() or q.is_symlink():
                        q.unlink()
        raise


def out_dir(path: str | Path, force: bool = False) -> Path:
    """An output folder: created when missing; an existing, non-empty one only with
    ``force`` (files in it are then replaced one by one, atomically)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise TunnelsimCLIError(f"Expected an output folder, got '{p}' which is a file; "
                                "choose another name.")
    if p.is_dir() and any(p.iterdir()) and not force:
        raise TunnelsimCLIError(f"Expected a new or empty output folder, got '{p}' which "
                                "holds files; pass --force to replace them.")
    if not p.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing parent folder for '{p}', got none; "
                                "create it first.")
    p.mkdir(exist_ok=True)
    return p


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; the folder must exist."""
    from raytrace.fileio import atomic_writer

    path = Path(path)
    if not path.parent.exists():
        raise TunnelsimCLIError(f"Expected an existing folder for '{path}', got none; "
                                "create it first.")
    with atomic_writer(path, "w") as fh:
        fh.write(text)
    return path


def write_json(path: str | Path, obj: Any) -> Path:
    """Strict JSON (NaN and infinities as ``null``, ``raytrace.fileio.json_text``),
    atomically; the folder must exist."""
    from raytrace.fileio import json_text

    return write_text(path, json_text(obj))


# ---------------------------------------------------------------------------- values
def version() -> str:
    """The installed distribution's version ("0+unknown" in a bare source tree)."""
    try:
        return metadata.version("tunnelsim")
    except metadata.PackageNotFoundError:  # running from a source tree
        return "0+unknown"


def parse_window(text: str, what: str, n: int) -> list[float]:
    """'A:B:C' -> n floats, with a one-line error naming the option (``what``)."""
    parts = text.split(":")
    try:
        vals = [float(v) for v in parts]
    except ValueError:
        vals = []
    if len(vals) != n:
        raise TunnelsimCLIError(f"Expected {what}, got {text!r}.")
    return vals


def numbers(text: str, what: str, n: int) -> list[float]:
    """'A,B,...' (commas or colons) -> n floats, with a one-line error naming the
    option and its form (``what``) and quoting the text as given."""
    try:
        vals = [float(v) for v in re.split(r"[,:]", text)]
    except ValueError:
        vals = []
    if len(vals) != n:
        raise TunnelsimCLIError(f"Expected {what}, got {text!r}.")
    return vals


def pair(text: str, what: str) -> list[float]:
    """'A,B' (or 'A:B') -> two floats; ``what`` names the option and its form."""
    return numbers(text, what, 2)


def xyz(text: str, what: str) -> list[float]:
    """'X,Y,Z' (or 'X:Y:Z') in metres -> three floats."""
    return numbers(text, f"{what} as X,Y,Z in metres", 3)


def floats(text: str, what: str) -> list[float]:
    """'A,B,...' -> one or more floats."""
    try:
        vals = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        vals = []
    if not vals:
        raise TunnelsimCLIError(f"Expected {what} as comma-separated numbers, got {text!r}.")
    return vals


def say(args: argparse.Namespace, text: str) -> None:
    """Print unless --quiet."""
    if not getattr(args, "quiet", False):
        print(text)


def physics_options(cmd: Command) -> None:
    """The options of the simulating commands (scan, drive): physics switches, seed,
    threads, quiet, fields and the output."""
    p = cmd.option
    p("--ideal", action="store_true",
      help="exact geometry: no noise, no jitter, every return detected")
    p("--no-noise", action="store_true", help="no range noise, no angle jitter")
    p("--no-detection", action="store_true",
      help="keep every return within range (no detection probability)")
    p("--beam-subrays", type=int, default=1, choices=[1, 7, 19],
      help="sub-rays per pulse for beam divergence (default 1: off)")
    p("--mixed", default="average", choices=["average", "strongest"],
      help="how sub-returns combine (default average)")
    p("--attenuation", type=float, default=0.0, metavar="PER_M",
      help="dust/fog extinction coefficient in 1/m (default 0)")
    p("--particles", type=float, default=0.0, metavar="PER_M",
      help="rate of airborne-particle returns per metre (default 0)")
    p("--reflectivity", type=float, default=0.5,
      help="reflectivity where the mesh has none (default 0.5)")
    p("--returns", choices=["strongest", "last", "first", "dual", "all"],
      help="multiple returns: simulate each pulse's waveform and write the echoes this "
           "return mode reports (one of the sensor's [returns] modes; LAS return "
           "numbers, echo_width and echo_amplitude); default: one return per pulse")
    p("--seed", type=int, default=0, help="random seed (default 0)")
    p("--threads", type=int, help="Numba threads (default: all cores)")
    p("--quiet", action="store_true", help="no progress bar or summary")
    p("--fields", choices=["compact", "full"],
      help="LAS/LAZ extra bytes: compact (stations' default) or full (every field; "
           "moving platforms' default)")
    p("-o", "--output", required=True, path="out",
      help="output points: .laz, .las, .ply, .npz (or .e57 for stations)")


#: Tolerance (rad) of ``radian_like``: a value typed to 3 or more decimals (0.524,
#: 0.5236) matches its multiple of pi/12; one of 2 decimals (0.52) does not.
RADIAN_TOL = 1e-3


def radian_like(value_deg: float) -> int | None:
    """The angle in whole degrees (a multiple of 15) whose radian value ``value_deg``
    seems to be, or None.

    DECISION: a degree value looks like radians when it is not a whole number, lies
    within 2 pi of 0 and is within ``RADIAN_TOL`` of k pi / 12, k != 0 (pi/6 = 0.5236,
    pi/4, pi/3, pi/2, pi...: the radian values people type). Any other radian value
    (an atan2 output) cannot be told from degrees, and whole degrees never warn. A
    degree value of 3+ decimals lands this close to k pi / 12 by chance for about
    0.8 % of values below 2 pi (2 * 1e-3 / (pi / 12)).
    """
    v = float(value_deg)
    if not math.isfinite(v) or v == round(v) or abs(v) > 2 * math.pi + RADIAN_TOL:
        return None
    k = round(v / (math.pi / 12))
    return 15 * k if k != 0 and abs(v - k * math.pi / 12) <= RADIAN_TOL else None


def warn_radian_like(value_deg: float | None, flag: str) -> None:
    """The CLI's one-line warning when option ``flag``'s degree value looks like
    radians (``radian_like``)."""
    deg = None if value_deg is None else radian_like(value_deg)
    if deg is not None:
        warnings.warn(f"{flag} {value_deg:g} looks like radians ({deg} deg); the option "
                      f"takes degrees: give {flag} {deg} if {deg} deg was meant.",
                      UserWarning, stacklevel=2)


__all__ = ["EXIT_INTERRUPTED", "EXIT_USAGE", "NUMBER_LIST", "RADIAN_TOL", "Command",
           "CommandSet", "cluster_options", "open_cluster", "radian_like",
           "warn_radian_like",
           "Option", "Parser", "Progress", "UsageError", "floats", "numbers", "out_dir", "pair",
           "parse_window", "physics_options", "removed_on_failure", "run_command", "say",
           "version", "write_json", "write_text", "xyz", "report_header", "report_options",
           "crs_words", "header_values", "write_headed_report"]


def __getattr__(name: str) -> Any:
    """``Progress``: the one progress reporter (``survey.report.progress.Progress``),
    imported when a command first asks for it, so that starting ``tunnelsim`` does not
    load the library."""
    if name == "Progress":
        from survey.report.progress import Progress

        return Progress
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def cluster_options(c: Command, needs: tuple[str, ...] = ()) -> None:
    """--workers and --scheduler: where the tasks of a command run (``survey.cluster``);
    neither: in this process. ``needs``: the options that split the command into tasks,
    one of which the command wants with them (``Command.cluster_needs``)."""
    c.cluster_needs = needs
    g = c.exclusive()
    c.option("--workers", type=int, group=g, metavar="N",
             help="run on a local dask cluster of N worker processes, each with "
                  "cores / N Numba threads (needs the extra 'cluster')")
    c.option("--scheduler", group=g, metavar="ADDRESS",
             help="run on an existing dask cluster (the address 'dask scheduler' "
                  "prints, e.g. tcp://10.0.0.5:8786); the output folder must be one "
                  "every worker sees")


def open_cluster(args: argparse.Namespace) -> Any:
    """The executor --workers / --scheduler ask for (in-process without either), its
    address and dashboard printed unless --quiet."""
    from survey.cluster import open_executor

    cores = getattr(args, "threads", None)
    ex = open_executor(args.workers, args.scheduler, cores=cores)
    if ex.kind != "in-process" and not args.quiet:
        print(f"cluster: {ex.describe()}")
    return ex


def report_options(c: Command) -> None:
    """--project and --instrument: the user's words the report header states
    (``survey.report.header``)."""
    c.option("--project", metavar="TEXT",
             help="project name the report header states (e.g. 'Gotthard lot 3')")
    c.option("--instrument", metavar="TEXT",
             help="instrument the report header states (e.g. 'Leica TS16 SN 123456')")


def crs_words(paths) -> str | None:
    """The CRS the first of ``paths`` that states one states, in words (None: none
    stated). Kept for the commands: ``survey.report.header.crs_words``."""
    from survey.report.header import crs_words as library_crs_words

    return library_crs_words(paths)


def header_values(args: argparse.Namespace) -> dict[str, str | None]:
    """The report header's user words from --project and --instrument, as the
    keywords of ``survey.report.header.report_header`` / ``write_headed_report``."""
    return {"project": getattr(args, "project", None),
            "instrument": getattr(args, "instrument", None)}


def write_headed_report(args: argparse.Namespace, path: Path, text: str,
                        inputs: list[tuple[str, Any, str]], *, crs_from=(),
                        settings: list[tuple[str, str]] | None = None) -> None:
    """Write a report's Markdown and its self-contained HTML (``path`` .md and .html)
    with the header block below its title (the CRS read from the files ``crs_from``):
    ``survey.report.header.write_headed_report`` with --project and --instrument."""
    from survey.report.header import write_headed_report as library_write

    words = header_values(args)
    library_write(path, text, inputs=inputs, crs_from=crs_from, settings=settings,
                  project=words["project"], instrument=words["instrument"])


def report_header(args: argparse.Namespace, inputs: list[tuple[str, Any, str]],
                  crs: str | None = None, settings: list[tuple[str, str]] | None = None
                  ) -> Any:
    """The ``ReportHeader`` of a command's report (``survey.report.header.report_header``
    with --project and --instrument)."""
    from survey.report.header import report_header as library_header

    words = header_values(args)
    return library_header(inputs, crs=crs, settings=settings, project=words["project"],
                          instrument=words["instrument"])
