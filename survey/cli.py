"""The ``tunnelsim`` command.

Errors a user can fix (``TunnelsimError`` and bad arguments) print one line on stderr and
exit with status 2; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import platform
import sys
from importlib import metadata

from raytrace.errors import TunnelsimError

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line (and exit 2), like every other
    error of the command."""

    def error(self, message):  # noqa: D401 - argparse API
        raise _UsageError(f"{self.prog}: {message} (see '{self.prog} --help')")


class _UsageError(Exception):
    pass


def _version() -> str:
    try:
        return metadata.version("tunnelsim")
    except metadata.PackageNotFoundError:  # running from a source tree
        return "0+unknown"


def _cmd_info(args) -> int:
    from raytrace.config import threading_info

    lines = [f"tunnelsim {_version()}",
             f"python {platform.python_version()} ({platform.machine()}, {platform.system()})"]
    for pkg in ("numpy", "numba", "scipy", "trimesh", "laspy", "lazrs", "pyproj", "pye57",
                "embreex", "open3d"):
        try:
            lines.append(f"{pkg} {metadata.version(pkg)}")
        except metadata.PackageNotFoundError:
            lines.append(f"{pkg} (not installed)")
    info = threading_info()
    lines.append(f"numba threading layer: {info['threading_layer']}")
    lines.append(f"numba threads: {info['threads']} of {info['max_threads']}")
    print("\n".join(lines))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="tunnelsim",
        description="Tunnel digital twins: meshes from laser scans, simulated scanners.",
        epilog="Example: tunnelsim info",
    )
    parser.add_argument("--version", action="version", version=f"tunnelsim {_version()}")
    parser.add_argument("--debug", action="store_true",
                        help="show tracebacks instead of one-line errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    p = sub.add_parser("info", help="versions, Numba threading layer and thread count",
                       description="Print versions of tunnelsim and its dependencies, the "
                                   "Numba threading layer and thread count.",
                       epilog="Example: tunnelsim info")
    p.set_defaults(func=_cmd_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    debug = "--debug" in argv
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return EXIT_USAGE
        return int(args.func(args) or 0)
    except (TunnelsimError, _UsageError) as exc:
        if debug:
            raise
        print(f"tunnelsim: error: {exc}" if isinstance(exc, TunnelsimError) else str(exc),
              file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        if debug:
            raise
        print("tunnelsim: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
