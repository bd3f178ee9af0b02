"""Write the API reference's listing pages from the packages' ``__all__`` at build time.

One page per package (``raytrace``, ``sensors``, ``sensors.io`` and its public modules,
``survey`` and every public sub-package), each with the package docstring and
``autosummary`` tables of its public names grouped by kind; autosummary then writes one
page per name. Nothing here is a hand-kept list of names: a name added to or removed
from an ``__all__`` appears or disappears at the next build.

DECISION: each object is documented once (Sphinx warns on a duplicate description, and
``-W`` makes that an error). Most names are exported at several levels (``survey``,
``survey.analysis``, the defining module); the canonical page is the listed package or
module whose name is the longest prefix of the object's ``__module__`` (where it is
defined), else the first listing page that exports it; a constant (which has no
``__module__``) goes where a ``#:`` comment describes it, else to the deepest module
that exports it. Other pages that export it link to the canonical entry under "Also
available here". A name whose attribute on the package is a sub-module (a sub-module
imported under the name of the function it defines) is not listed on that package.

DECISION: the pages are written when the configuration is read (``config-inited``),
before Sphinx looks for source files, so autosummary finds their tables like those of
any committed page. They go to ``api/generated/`` (ignored by git, rebuilt each time).
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import shutil
from collections.abc import Iterator
from pathlib import Path

# Listing pages, in reading order: lowest layer first. A package followed by "*" also
# gets a page for each of its public (not ``_``-prefixed) sub-modules or sub-packages.
ROOTS = ("raytrace", "sensors", "sensors.io*", "survey*")

KINDS = (("exception", "Errors"), ("class", "Classes"), ("function", "Functions"),
         ("data", "Constants and data"))


def _public_children(name: str) -> Iterator[str]:
    mod = importlib.import_module(name)
    for info in pkgutil.iter_modules(getattr(mod, "__path__", [])):
        if not info.name.startswith("_"):
            yield f"{name}.{info.name}"


def listing_modules() -> list[str]:
    """Every package or module that gets a listing page, in order."""
    out: list[str] = []
    for root in ROOTS:
        name = root.rstrip("*")
        out.append(name)
        if root.endswith("*"):
            out.extend(sorted(_public_children(name)))
    return out


def public_names(modname: str) -> list[str]:
    """The module's ``__all__`` (which may be empty), or where it has none, the
    functions and classes it defines whose names do not start with ``_``."""
    mod = importlib.import_module(modname)
    names = getattr(mod, "__all__", None)
    if names is not None:
        return [n for n in names if n != "__version__"
                and not inspect.ismodule(getattr(mod, n, None))]
    return sorted(n for n, v in vars(mod).items() if not n.startswith("_")
                  and (inspect.isfunction(v) or inspect.isclass(v))
                  and getattr(v, "__module__", None) == modname)


def kind_of(obj: object) -> str:
    if inspect.isclass(obj):
        return "exception" if issubclass(obj, BaseException) else "class"
    if callable(obj):
        return "function"
    return "data"


def _key(name: str, obj: object) -> tuple[int, str]:
    # Functions and classes are the same thing under any name; a constant is keyed by
    # name too, since equal small numbers and strings are one shared object in CPython.
    return id(obj), ("" if kind_of(obj) != "data" else name)


def _has_attr_doc(modname: str, name: str) -> bool:
    from sphinx.pycode import ModuleAnalyzer, PycodeError

    try:
        return ("", name) in ModuleAnalyzer.for_module(modname).find_attr_docs()
    except PycodeError:
        return False


def plan() -> tuple[list[str], dict[str, dict[str, list[str]]], dict[str, list[str]]]:
    """(listing modules, {module: {kind: names documented there}}, {module: full names
    of the objects it also exports, documented elsewhere})."""
    modules = listing_modules()
    exported = {m: [(n, getattr(importlib.import_module(m), n)) for n in public_names(m)]
                for m in modules}
    where: dict[tuple[int, str], list[tuple[str, str]]] = {}
    for m in modules:
        for n, obj in exported[m]:
            where.setdefault(_key(n, obj), []).append((m, n))
    canonical: dict[tuple[int, str], str] = {}
    for key, places in where.items():
        m0, n0 = places[0]
        obj = dict(exported[m0])[n0]
        if kind_of(obj) == "data":
            # A constant has no __module__: document it where a ``#:`` comment
            # describes it, else in the deepest module that exports it.
            described = [(m, n) for m, n in places if _has_attr_doc(m, n)]
            m, n = (described or sorted(places, key=lambda p: -len(p[0])))[0]
        else:
            home = getattr(obj, "__module__", None)
            inside = [(m, n) for m, n in places
                      if home is not None and (home == m or home.startswith(m + "."))]
            m, n = max(inside, key=lambda p: len(p[0])) if inside else places[0]
        canonical[key] = f"{m}.{n}"
    own: dict[str, dict[str, list[str]]] = {m: {k: [] for k, _ in KINDS} for m in modules}
    also: dict[str, list[str]] = {m: [] for m in modules}
    for m in modules:
        for n, obj in exported[m]:
            full = canonical[_key(n, obj)]
            if full == f"{m}.{n}":
                own[m][kind_of(obj)].append(n)
            else:
                also[m].append(full)
    return modules, own, also


def filename_map(own: dict[str, dict[str, list[str]]]) -> dict[str, str]:
    """Stub file names for full names that differ only in case (``M3C2`` and ``m3c2``):
    the later one gets a suffix, so the pages do not overwrite each other on macOS's
    and Windows' case-insensitive file systems."""
    seen: set[str] = set()
    out: dict[str, str] = {}
    for m, kinds in own.items():
        for kind, names in kinds.items():
            for n in names:
                full = f"{m}.{n}"
                if full.lower() in seen:
                    out[full] = f"{full}-{kind}"
                seen.add(full.lower())
    return out


def write_pages(outdir: Path) -> dict[str, str]:
    """Write one ``<module>.rst`` listing page per module into ``outdir`` (emptied
    first) and an ``index.rst`` with their toctree; return autosummary's filename map."""
    modules, own, also = plan()
    if outdir.exists():
        shutil.rmtree(outdir)
    outdir.mkdir(parents=True)
    for m in modules:
        lines = [m, "=" * len(m), "", f".. automodule:: {m}", "   :no-members:", "",
                 f".. currentmodule:: {m}", ""]
        children = [c for c in modules if c.rpartition(".")[0] == m]
        if children:
            lines += [".. rubric:: Sub-packages and modules", "", ".. toctree::",
                      "   :maxdepth: 1", ""]
            lines += [f"   {c}" for c in children]
            lines.append("")
        for kind, title in KINDS:
            names = own[m][kind]
            if names:
                lines += [f".. rubric:: {title}", "", ".. autosummary::",
                          "   :toctree: .", "   :nosignatures:", ""]
                lines += [f"   {n}" for n in names]
                lines.append("")
        if also[m]:
            lines += [".. rubric:: Also available here", "",
                      f"Documented where they are defined; ``from {m} import ...`` "
                      "works for each.", ""]
            lines += [", ".join(f":py:obj:`~{full}`" for full in also[m]), ""]
        if not children and not any(own[m].values()) and not also[m]:
            lines += ["This module exports no names yet.", ""]
        (outdir / f"{m}.rst").write_text("\n".join(lines), encoding="utf-8")
    top = [m for m in modules if "." not in m]
    index = ["Packages", "========", "", ".. toctree::", "   :maxdepth: 2", ""]
    index += [f"   {m}" for m in top]
    (outdir / "index.rst").write_text("\n".join(index) + "\n", encoding="utf-8")
    return filename_map(own)


def _on_config(app, config) -> None:
    # Only a source tree with an API section gets the pages (the docs test builds small
    # trees with this configuration to check that broken links fail the build).
    api = Path(app.srcdir) / "api"
    if (api / "index.md").is_file():
        mapping = write_pages(api / "generated")
        config.autosummary_filename_map = {**config.autosummary_filename_map, **mapping}


def setup(app):
    app.connect("config-inited", _on_config)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
