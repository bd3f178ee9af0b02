"""Workflows: one typed library function for every ``tunnelsim`` command.

Each takes paths or arrays and keyword options, writes the same files as its command,
and returns a frozen result object with the paths written and the numbers the command
prints; the command line only parses, calls one of these, and prints. They never print.
"""

__all__: list[str] = []
