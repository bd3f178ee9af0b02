"""Two markup habits of the tunnelsim docstrings, read the way their authors meant them.

Runs on ``autodoc-process-docstring`` before numpydoc (priority 100 < its 500). Each
rewrite changes only what reStructuredText would otherwise misread, and every docstring
it touches is listed by ``python docs/_ext/docstrings.py`` (the list handed to whoever
fixes them in the source; when it is empty this module can go).

1. ``|d|`` written for an absolute value. reST reads ``|name|`` as a substitution
   reference and fails ("Undefined substitution referenced"); the bars are escaped,
   outside ````literal```` spans.
2. Numpydoc fields without their section header: a class docstring listing
   ``name : type, meaning`` lines (or a function its arguments) with no
   ``Attributes`` / ``Parameters`` heading above them. reST reads those lines as a
   paragraph with stray indentation ("Unexpected indentation"); the heading numpydoc
   needs is inserted above the first such line (``Attributes`` in a class, else
   ``Parameters``), and a paragraph after the list goes under ``Notes``.

It also drops the docstring a constant inherits from its type (a ``dict`` or a NumPy
``dtype`` would otherwise show ``dict``'s or ``dtype``'s own documentation), and leaves
the fields of dataclasses and named tuples out of a class's member list (its Attributes
section describes them; listed again, each would be an empty entry).
"""

from __future__ import annotations

import dataclasses
import inspect
import re

SECTION = re.compile(r"^(Parameters|Other Parameters|Attributes|Returns|Yields|Receives|"
                     r"Raises|Warns|Warnings|See Also|Notes|References|Examples|"
                     r"Methods)\s*$")
FIELD = re.compile(r"^[A-Za-z_]\w*(, [A-Za-z_]\w*)* : \S")
BARS = re.compile(r"(?<![\w\\|`])\|([A-Za-z_](?:[\w.()+\- ]*?[\w)])?)\|(?![\w|`])")


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
    new = [escape_bars(line) for line in lines]
    if what in ("class", "exception", "function", "method"):
        new = add_headers(new, what)
    lines[:] = new


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


def _touched() -> list[str]:
    """'file:line: name: what' for every documented docstring this module rewrites."""
    import importlib
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    import apipages

    modules, own, _ = apipages.plan()
    out = []
    for m in modules:
        mod = importlib.import_module(m)
        for kind, names in own[m].items():
            for n in names:
                obj = getattr(mod, n)
                items = [(n, obj, kind)]
                if inspect.isclass(obj):
                    items += [(f"{n}.{k}", v, "method") for k, v in vars(obj).items()
                              if not k.startswith("_") and inspect.isfunction(v)]
                for full, o, what in items:
                    doc = inspect.getdoc(o)
                    if not doc or what == "data":
                        continue
                    lines = doc.splitlines()
                    new = [escape_bars(x) for x in lines]
                    bars = new != lines
                    headed = add_headers(new, what) != new
                    if bars or headed:
                        try:
                            where = f"{inspect.getsourcefile(o)}:{inspect.getsourcelines(o)[1]}"
                        except (TypeError, OSError):
                            where = m
                        fix = " and ".join(
                            ([r"write |x| as ``|x|`` (reST substitution)"] if bars else [])
                            + (["add the numpydoc heading above the field list"]
                               if headed else []))
                        out.append(f"{where}: {m}.{full}: {fix}")
    return sorted(set(out))


if __name__ == "__main__":
    print("\n".join(_touched()) or "no docstring needs a rewrite")
