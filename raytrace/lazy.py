"""Package façades whose public names are imported on first use (PEP 562).

``import raytrace.errors`` (which every ``tunnelsim`` start does) must not compile or
load Numba, SciPy or Matplotlib; a façade built here maps each public name to the
module that defines it and imports that module only when the name is first read.

A façade lists its public names once, as the imports of its ``if TYPE_CHECKING:``
block: type checkers and IDEs read those imports, and ``lazy_exports_of`` reads the
same block (with ``ast``, at import, ~1 ms) to build the lazy map::

    if TYPE_CHECKING:
        from survey.world.alignment import Alignment, arc
    __getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__)
"""

from __future__ import annotations

import ast
import importlib
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path


def lazy_exports(package: str, exports: Mapping[str, Iterable[str]], *,
                 modules: Iterable[str] = (), extra: Iterable[str] = ("__version__",)
                 ) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """(``__getattr__``, ``__dir__``, ``__all__``) for the façade ``package``.

    Parameters
    ----------
    exports : {module name: public names defined there}
    modules : sub-modules reachable as attributes (``survey.world``)
    extra : names the façade defines itself, listed in ``__all__``
    """
    where = {name: mod for mod, names in exports.items() for name in names}
    subs = tuple(modules)
    public = [*extra, *subs, *where]

    def __getattr__(name: str) -> object:
        if name in where:
            value = getattr(importlib.import_module(where[name]), name)
        elif name in subs:
            value = importlib.import_module(f"{package}.{name}")
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        vars(importlib.import_module(package))[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(public)

    return __getattr__, __dir__, public


def type_checking_imports(package: str, file: str | Path) -> dict[str, tuple[str, ...]]:
    """{module: names} of the ``from M import ...`` statements inside the top-level
    ``if TYPE_CHECKING:`` block(s) of ``file``, the façade of ``package`` (relative
    module names resolved against it)."""
    tree = ast.parse(Path(file).read_text(encoding="utf-8"))
    out: dict[str, tuple[str, ...]] = {}
    for node in tree.body:
        if not (isinstance(node, ast.If) and isinstance(node.test, ast.Name)
                and node.test.id == "TYPE_CHECKING"):
            continue
        for stmt in node.body:
            if not isinstance(stmt, ast.ImportFrom):
                raise ImportError(f"Expected only 'from M import names' in the "
                                  f"TYPE_CHECKING block of {file}, got line {stmt.lineno}.")
            base = package.split(".")[:len(package.split(".")) - max(stmt.level - 1, 0)]
            mod = ".".join(base + [stmt.module or ""]) if stmt.level else str(stmt.module)
            out[mod.rstrip(".")] = out.get(mod, ()) + tuple(a.asname or a.name
                                                             for a in stmt.names)
    return out


def lazy_exports_of(package: str, file: str | Path, *, modules: Iterable[str] = (),
                    extra: Iterable[str] = ("__version__",)
                    ) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """``lazy_exports`` of the names the façade ``file`` imports under
    ``if TYPE_CHECKING:`` (its one list of public names)."""
    return lazy_exports(package, type_checking_imports(package, file), modules=modules,
                        extra=extra)


__all__ = ["lazy_exports", "lazy_exports_of", "type_checking_imports"]
