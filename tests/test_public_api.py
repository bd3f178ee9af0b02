"""The public API is discoverable: every public module declares ``__all__``, every name in
it imports, every package has a ``__version__`` (the distribution's), every public error
is exported from its package and from the root, and ``dir()`` shows no stray imports."""

from __future__ import annotations

import ast
import importlib
import inspect
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("raytrace", "sensors", "survey")


def _public_modules() -> list[str]:
    out = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if any(p.startswith("_") and p != "__init__" for p in parts):
                continue  # private modules (_kernels, _helpers) and __main__
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out.append(".".join(parts))
    return out


MODULES = _public_modules()


def _declares_all(mod: str) -> bool:
    path = ROOT / Path(*mod.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    tree = ast.parse(path.read_text())
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else \
            [node.target] if isinstance(node, ast.AnnAssign) else []
        for t in targets:
            names = [t] if isinstance(t, ast.Name) else \
                list(t.elts) if isinstance(t, ast.Tuple) else []
            if any(isinstance(n, ast.Name) and n.id == "__all__" for n in names):
                return True
    return False


def test_modules_found():
    assert len(MODULES) > 40 and "survey.world.alignment" in MODULES


@pytest.mark.parametrize("mod", MODULES)
def test_every_public_module_declares_all(mod):
    assert _declares_all(mod), f"{mod} has no __all__"


@pytest.mark.parametrize("mod", [m for m in MODULES if m != "survey.cli.__main__"])
def test_every_name_in_all_imports(mod):
    m = importlib.import_module(mod)
    names = list(getattr(m, "__all__", []))
    assert len(names) == len(set(names)), f"{mod}.__all__ repeats a name"
    missing = [n for n in names if not hasattr(m, n)]
    assert not missing, f"{mod}.__all__ names {missing}, which it does not define"


@pytest.mark.parametrize("pkg", PACKAGES)
def test_version_is_the_distributions(pkg):
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert importlib.import_module(pkg).__version__ == meta["project"]["version"]


def test_every_public_error_is_exported_from_its_package_and_the_root():
    import survey
    from raytrace.errors import TunnelsimError

    for pkg in (*PACKAGES, "sensors.io"):
        errors = importlib.import_module(f"{pkg}.errors")
        classes = [c for _n, c in inspect.getmembers(errors, inspect.isclass)
                   if issubclass(c, TunnelsimError)]
        assert len(classes) >= 2
        for c in classes:
            assert issubclass(c, ValueError) or c is TunnelsimError, c
            assert getattr(importlib.import_module(pkg.split(".")[0]), c.__name__) is c, \
                (pkg, c)
            if pkg.startswith(("survey", "sensors.io")):
                assert getattr(survey, c.__name__) is c


def test_dir_of_a_package_shows_its_api_only():
    import survey

    shown = set(dir(survey))
    assert {"fit_helmert", "cloud_to_mesh", "preset", "make_tunnel", "world"} <= shown
    assert not shown & {"np", "importlib", "TYPE_CHECKING", "lazy_exports"}


def test_lazy_names_are_the_defining_modules_objects():
    import survey
    from survey.analysis.compare import cloud_to_mesh

    assert survey.cloud_to_mesh is cloud_to_mesh
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        survey.nonexistent  # noqa: B018


FACADES = sorted(str(p.relative_to(ROOT)) for pkg in PACKAGES
                 for p in (ROOT / pkg).rglob("__init__.py")
                 if "TYPE_CHECKING" in p.read_text())


def test_facades_are_found():
    assert {"survey/__init__.py", "sensors/__init__.py", "survey/world/__init__.py",
            "survey/analysis/__init__.py"} <= set(FACADES)


@pytest.mark.parametrize("path", FACADES)
def test_a_facade_lists_its_names_once(path):
    """Issue 32: a package's public names are written once, as the imports of its
    ``if TYPE_CHECKING:`` block; ``__all__`` is built from them (no second list to
    fall out of step), and each name is the defining module's object."""
    from raytrace.lazy import type_checking_imports

    mod = str(Path(path).parent).replace("/", ".")
    tree = ast.parse((ROOT / path).read_text())
    literal_lists = [n.lineno for n in tree.body if isinstance(n, (ast.Assign, ast.AnnAssign))
                     and "__all__" in ast.unparse(n) and isinstance(n.value, (ast.List,
                                                                              ast.Tuple))]
    assert not literal_lists, f"{path}:{literal_lists[0]} spells __all__ out a second time"
    listed = {n for names in type_checking_imports(mod, ROOT / path).values() for n in names}
    m = importlib.import_module(mod)
    assert listed <= set(m.__all__)
    assert set(m.__all__) - listed <= {"__version__", *getattr(m, "SUBPACKAGES", ())}


@pytest.mark.parametrize("path", FACADES)
def test_no_facade_name_is_shadowed_by_a_submodule(path):
    """A façade name equal to one of its package's modules would be replaced by the
    module as soon as anything imports that module (``survey.analysis.m3c2`` the
    function vs the module)."""
    import pkgutil

    mod = str(Path(path).parent).replace("/", ".")
    m = importlib.import_module(mod)
    subs = {i.name for i in pkgutil.iter_modules(m.__path__)}
    clash = subs & set(m.__all__) - set(getattr(m, "SUBPACKAGES", ()))
    assert not clash, f"{mod} exports {sorted(clash)}, which are also its modules"


def _reexports(mod: str) -> list[str]:
    """Names ``mod``'s ``__all__`` lists but imports from another module."""
    path = ROOT / (mod.replace(".", "/") + ".py")
    tree = ast.parse(path.read_text())
    imported = {a.asname or a.name for n in tree.body if isinstance(n, ast.ImportFrom)
                for a in n.names}
    for n in tree.body:
        if isinstance(n, (ast.Assign, ast.AnnAssign)) and "__all__" in ast.unparse(
                n.targets[0] if isinstance(n, ast.Assign) else n.target):
            return [x for x in ast.literal_eval(n.value) if x in imported
                    and x != "TunnelsimError"]
    return []


@pytest.mark.parametrize("mod", [m for m in MODULES if (ROOT / (m.replace(".", "/") +
                                                                 ".py")).is_file()])
def test_a_module_lists_only_what_it_defines(mod):
    """Issue 32: no module re-exports another's names (the splits used to leave their
    old names behind): one name, one home; the package façades are the exception."""
    assert not _reexports(mod), f"{mod}.__all__ re-exports {_reexports(mod)}"


def test_the_reexport_rule_catches_one(tmp_path, monkeypatch):
    fake = tmp_path / "fake.py"
    fake.write_text("from os.path import join\n__all__ = ['join', 'mine']\nmine = 1\n")
    monkeypatch.setattr(__import__(__name__, fromlist=["ROOT"]), "ROOT", tmp_path)
    assert _reexports("fake") == ["join"]
