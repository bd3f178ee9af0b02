"""The command registry: the parser of ``tunnelsim``, built from the command groups.

Each module of ``survey.cli.commands`` registers its own commands (``register``); this
module puts them under one parser and adds the options every command shares. The
pipeline runs its steps through the same registry, so a step accepts exactly the
options the command registered.
"""

from __future__ import annotations

from survey.cli.commands import (adjustment, analysis, axis, cameras, clouds, detectability,
                                 driving, epochs, inspection, scanning, sections, slam,
                                 world)
from survey.cli.common import Command, CommandSet, Parser, version

#: The command groups a pipeline step may use (``run`` and ``demo`` run pipelines and
#: are added by ``survey.cli.main``).
STEP_GROUPS = (world, scanning, driving, slam, adjustment, clouds, analysis, axis, sections,
               epochs, inspection, detectability, cameras)


def build(groups=STEP_GROUPS) -> tuple[Parser, dict[str, Command]]:
    """The ``tunnelsim`` parser with the commands of ``groups`` (modules with a
    ``register(commands)`` function), and those commands by name."""
    parser = Parser(
        prog="tunnelsim",
        description="Tunnel digital twins: meshes from laser scans, simulated scanners.",
        epilog="Example: tunnelsim info",
    )
    parser.add_argument("--version", action="version", version=f"tunnelsim {version()}")
    parser.add_argument("--debug", action="store_true",
                        help="show tracebacks instead of one-line errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    commands = CommandSet(sub)
    for group in groups:
        group.register(commands)
    return parser, commands.finish()


def step_commands() -> dict[str, Command]:
    """The commands a pipeline step may run, by name."""
    return build(STEP_GROUPS)[1]


__all__ = ["STEP_GROUPS", "build", "step_commands"]
