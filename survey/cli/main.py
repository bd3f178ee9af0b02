"""The ``tunnelsim`` command.

Errors a user can fix (``TunnelsimError``, bad arguments) print one line on stderr,
"tunnelsim: error: ...", and exit with status 2; ``--debug`` shows the traceback
instead. A failed command leaves none of its outputs behind (``run_command``).
"""

from __future__ import annotations

import argparse
import sys
import warnings

from survey.cli import registry
from survey.cli.commands import runner
from survey.cli.common import (
    EXIT_INTERRUPTED,
    EXIT_USAGE,
    Command,
    UsageError,
    run_command,
)
from survey.errors import TunnelsimError

#: Every command group of the command line: the pipeline steps' and the runners.
GROUPS = (*registry.STEP_GROUPS, runner)


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, Command]]:
    """The full ``tunnelsim`` parser and its commands by name."""
    return registry.build(GROUPS)


def main(argv: list[str] | None = None) -> int:
    """Run ``tunnelsim`` with ``argv`` (default ``sys.argv[1:]``); returns the exit
    status (0, 2 for an error a user can fix, 130 after Ctrl-C)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv
    with warnings.catch_warnings():
        if not debug:
            warnings.showwarning = _one_line_warning
        return _main(argv, debug)


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as the command prints it: one line, no source path."""
    text = " ".join(str(message).split())
    print(f"tunnelsim: warning: {text}", file=sys.stderr if file is None else file)


def _main(argv: list[str], debug: bool) -> int:
    parser, commands = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        cmd = commands.get(getattr(args, "command", None) or "")
        if extra:
            where = f"tunnelsim {cmd.name}" if cmd else "tunnelsim"
            raise UsageError(f"unrecognized arguments: {' '.join(extra)} (see '{where} "
                             "--help')")
        if cmd is None:
            parser.print_help()
            return EXIT_USAGE
        return run_command(cmd, args)
    except TunnelsimError as exc:
        if debug:
            raise
        text = " ".join(str(exc).split())     # one line, whatever the message holds
        print(f"tunnelsim: error: {text}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        if debug:
            raise
        print("tunnelsim: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


__all__ = ["GROUPS", "build_parser", "main"]

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
