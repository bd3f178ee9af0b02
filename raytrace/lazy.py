"""Package façades whose public names are imported on first use (PEP 562).

``import raytrace.errors`` (which every ``tunnelsim`` start does) must not compile or
load Numba, SciPy or Matplotlib; a façade built here maps each public name to the
module that defines it and imports that module only when the name is first read.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Mapping


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


__all__ = ["lazy_exports"]
