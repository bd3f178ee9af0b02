"""Two markup habits of the tunnelsim docstrings, read the way their authors meant them,
in the modules listed in ``PENDING`` only (a stopgap until their docstrings are fixed).

Runs on ``autodoc-process-docstring`` before numpydoc (priority 100 < its 500). Each
rewrite changes only what reStructuredText would otherwise misread. Every docstring
that needs it is listed by ``python docs/_ext/docstrings.py``, with whether it is
rewritten (its module is pending) or not (then the ``-W`` build fails on it).

1. ``|d|`` written for an absolute value. reST reads ``|name|`` as a substitution
   reference and fails ("Undefined substitution referenced"); the bars are escaped,
   outside ````literal```` spans. In the source, write ````|d|```` or "abs(d)".
2. Numpydoc fields without their section header: a class docstring listing
   ``name : type, meaning`` lines (or a function its arguments) with no
   ``Attributes`` / ``Parameters`` heading above them. reST reads those lines as a
   paragraph with stray indentation ("Unexpected indentation"); the heading numpydoc
   needs is inserted above the first such line (``Attributes`` in a class, else
   ``Parameters``), and a paragraph after the list goes under ``Notes``. In the
   source, write the heading (and its dashes) and the ``Notes`` heading.

DECISION (issue 32): the other modules' docstrings were fixed in the source, and they
are no longer rewritten: a new ``|x|`` or an unheaded field list there fails the build
(Sphinx's warning, an error under ``-W``) instead of being silently patched. A module
leaves ``PENDING`` when its docstrings are fixed; when ``PENDING`` is empty,
``escape_bars``, ``add_headers`` and ``rewrite`` can go, and ``process`` keeps only
the constant handling described next.

It also drops the docstring a constant inherits from its type (a ``dict`` or a NumPy
``dtype`` would otherwise show ``dict``'s or ``dtype``'s own documentation), and leaves
the fields of dataclasses and named tuples out of a class's member list (its Attributes
section describes them; listed again, each would be an empty entry). Both apply to
every module.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import re
from typing import Any

SECTION = re.compile(r"^(Parameters|Other Parameters|Attributes|Returns|Yields|Receives|"
                     r"Raises|Warns|Warnings|See Also|Notes|References|Examples|"
                     r"Methods)\s*$")
FIELD = re.compile(r"^[A-Za-z_]\w*(, [A-Za-z_]\w*)* : \S")
BARS = re.compile(r"(?<![\w\\|`])\|([A-Za-z_](?:[\w.()+\- ]*?[\w)])?)\|(?![\w|`])")

#: Modules (or packages: their sub-modules too) whose docstrings are still rewritten,
#: owned by other work when issue 32 fixed the rest (see the module doc).
PENDING: tuple[str, ...] = ()


def home_module(obj: object, name: str = "") -> str:
    """The module that defines ``obj``: a module's own name, a function's or class's
    ``__module__`` (a property's getter's); for a constant, which carries none of its
    own (an ``int`` would answer "builtins"), the documented full ``name``."""
    if inspect.ismodule(obj):
        return obj.__name__
    if isinstance(obj, property):
        obj = obj.fget
    elif isinstance(obj, functools.cached_property):
        obj = obj.func
    elif isinstance(obj, (classmethod, staticmethod)):
        obj = obj.__func__
    if inspect.isclass(obj) or inspect.isroutine(obj):
        mod = getattr(obj, "__module__", None)
        if isinstance(mod, str) and mod:
            return mod
    return name


def pending(module: str) -> bool:
    return any(module == p or module.startswith(p + ".") for p in PENDING)


def escape_bars(line: str) -> str:
    parts = line.split("``")
    for i in range(0, len(parts), 2):            # outside ``literal`` spans only
        parts[i] = BARS.sub(r"\\|\1\\|", parts[i])
    return "``".join(parts)


def add_headers(lines: list[str], what: str) -> list[str]:
    """Insert the numpydoc heading above an unheaded field list (see module doc)."""
    first = None
    for i, line in enumerate(lines):
        if SECTION.match(line) and i + 1 < len(lines) and lines[i + 1].startswith("---"):
            return lines                            # the author gave sections
        if i > 0 and FIELD.match(line) and lines[i - 1].strip() == "":
            first = i
            break
    if first is None:
        return lines
    title = "Attributes" if what in ("class", "exception") else "Parameters"
    out = lines[:first] + [title, "-" * len(title)]
    i = first
    while i < len(lines):
        line = lines[i]
        if line.strip() == "" and i + 1 < len(lines) and lines[i + 1].strip() \
                and not lines[i + 1].startswith(" ") and not FIELD.match(lines[i + 1]):
            out += ["", "Notes", "-----"]
            out += lines[i + 1:]
            return out
        out.append(line)
        i += 1
    return out


def process(app, what, name, obj, options, lines) -> None:
    if what in ("class", "exception"):
        _CURRENT_FIELDS[0] = _field_names(obj)
    if what in ("data", "attribute") and not inspect.isclass(obj) and lines and \
            "\n".join(lines).strip() == (inspect.getdoc(type(obj)) or "").strip():
        lines[:] = []
        return
    if not pending(home_module(obj, name)):
        return
    lines[:] = rewrite(lines, what)


def rewrite(lines: list[str], what: str) -> list[str]:
    """The docstring ``lines`` with both habits rewritten (see module doc)."""
    new = [escape_bars(line) for line in lines]
    if what in ("class", "exception", "function", "method"):
        new = add_headers(new, what)
    return new


def _field_names(cls: object) -> tuple[str, ...]:
    if dataclasses.is_dataclass(cls):
        return tuple(f.name for f in dataclasses.fields(cls))
    return tuple(getattr(cls, "_fields", ()))                   # a named tuple


# autodoc processes a class's docstring, then filters its members: the fields of the
# class being documented are remembered between the two events (one reader at a time
# per process, also under ``-j``).
_CURRENT_FIELDS: list[tuple[str, ...]] = [()]


def skip_fields(app, what, name, obj, skip, options):
    """Leave the fields of dataclasses and named tuples out of a class page's members:
    the class docstring's Attributes section describes them, and listed again each
    would be an empty entry."""
    if what in ("class", "exception") and name in _CURRENT_FIELDS[0]:
        return True
    return None


def setup(app):
    app.connect("autodoc-process-docstring", process, priority=100)
    app.connect("autodoc-skip-member", skip_fields)
    return {"parallel_read_safe": True, "parallel_write_safe": True}


def _documented() -> list[tuple[str, Any, str]]:
    """(full name, object, autodoc's ``what``) of every documented docstring: the
    listing pages' module docstrings, the names they own and those names' public
    methods and properties (autodoc's ``:members:``)."""
    import importlib
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    import apipages

    modules, own, _ = apipages.plan()
    out: list[tuple[str, Any, str]] = []
    for m in modules:
        mod = importlib.import_module(m)
        out.append((m, mod, "module"))
        for kind, names in own[m].items():
            for n in names:
                obj = getattr(mod, n)
                out.append((f"{m}.{n}", obj, kind))
                if not inspect.isclass(obj):
                    continue
                for k, v in vars(obj).items():
                    if k.startswith("_"):
                        continue
                    if isinstance(v, (classmethod, staticmethod)):
                        v = v.__func__
                    if inspect.isfunction(v):
                        out.append((f"{m}.{n}.{k}", v, "method"))
                    elif isinstance(v, property):
                        out.append((f"{m}.{n}.{k}", v, "property"))
    return out


def _touched() -> list[str]:
    """'file:line: name: fix [state]' for every documented docstring that needs a
    rewrite: "rewritten" where its module is pending, else "NOT rewritten" (the
    ``-W`` build fails on it: fix the docstring)."""
    out = []
    for full, o, what in _documented():
        if what == "data":
            continue
        doc = inspect.getdoc(o)
        if not doc:
            continue
        lines = doc.splitlines()
        escaped = [escape_bars(x) for x in lines]
        bars = escaped != lines
        headed = what in ("class", "exception", "function", "method") and \
            add_headers(escaped, what) != escaped
        if not (bars or headed):
            continue
        src = getattr(o, "fget", o)
        try:
            where = f"{inspect.getsourcefile(src)}:{inspect.getsourcelines(src)[1]}"
        except (TypeError, OSError):
            where = full
        fix = " and ".join(
            ([r"write |x| as ``|x|`` (reST substitution)"] if bars else [])
            + (["add the numpydoc heading above the field list"] if headed else []))
        state = "rewritten" if pending(home_module(o, full)) else "NOT rewritten"
        out.append(f"{where}: {full}: {fix} [{state}]")
    return sorted(set(out))


if __name__ == "__main__":
    print("\n".join(_touched()) or "no docstring needs a rewrite")
