"""The layout is the architecture: imports only point down, no cycles, no private names
borrowed across modules.

Every module of the three packages is parsed with ``ast`` (nothing is imported), and
every import, module-level or inside a function, becomes an edge of the module graph.

Layers, lowest first::

    raytrace  <  sensors.io  <  sensors  <  survey
    inside survey:  errors, _kernels  <  world  <  adjust, clouds  <  analysis
                    <  report, export, cluster  <  workflows  <  cli

``sensors.io`` is the file-format layer: every reader and writer of a format, the one
mesh loader and the file errors; it imports only ``raytrace`` and itself, and both
``sensors`` and ``survey`` read and write files through it.

A module may import its own layer or any lower one. The package façades
(``survey/__init__.py`` etc.) only name what lies below them and are exempt from the
layer rule, not from the cycle rule.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("raytrace", "sensors", "survey")
PACKAGE_RANK = {"raytrace": 0, "sensors": 2, "survey": 3}
FORMAT_LAYER = ("sensors", "io")   # rank 1: between raytrace and the rest of sensors
SURVEY_RANK = {"errors": 0, "_kernels": 0, "world": 1, "adjust": 2, "clouds": 2,
               "analysis": 3, "report": 4, "export": 4, "cluster": 4, "workflows": 5,
               "cli": 6}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _is_package(mod: str) -> bool:
    return MODULES[mod].name == "__init__.py"


def _resolve(mod: str, node: ast.ImportFrom) -> str | None:
    """Absolute name of the module an ImportFrom reads from."""
    if node.level == 0:
        return node.module
    base = mod.split(".")
    if not _is_package(mod):
        base = base[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(mod: str) -> list[tuple[str, str | None, int]]:
    """(imported module, imported name or None, line) for every import in ``mod``."""
    tree = ast.parse(MODULES[mod].read_text(), filename=str(MODULES[mod]))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                out.append((a.name, None, node.lineno))
        elif isinstance(node, ast.ImportFrom):
            src = _resolve(mod, node)
            if src is None:
                continue
            for a in node.names:
                sub = f"{src}.{a.name}"
                if sub in MODULES:  # "from pkg import module"
                    out.append((sub, None, node.lineno))
                else:
                    out.append((src, a.name, node.lineno))
    return [(m, n, ln) for m, n, ln in out if m.split(".")[0] in PACKAGES]


EDGES = {mod: _imports(mod) for mod in MODULES}


def _rank(mod: str) -> tuple[int, int]:
    parts = mod.split(".")
    if tuple(parts[:2]) == FORMAT_LAYER:
        return 1, 0
    inner = SURVEY_RANK.get(parts[1], 0) if parts[0] == "survey" and len(parts) > 1 else 0
    return PACKAGE_RANK[parts[0]], inner


def _facade(mod: str) -> bool:
    return mod in PACKAGES


def test_every_module_is_seen():
    # A guard for the test itself: if the walk found nothing, every rule below would pass.
    assert {"raytrace.scene", "sensors.simulate", "survey.cli.main",
            "survey.world.alignment"} <= set(MODULES)
    assert sum(len(e) for e in EDGES.values()) > 100


def test_imports_point_down():
    bad = []
    for mod, edges in EDGES.items():
        if _facade(mod):
            continue
        for target, _name, line in edges:
            tgt = target if target in MODULES else target.rsplit(".", 1)[0]
            if tgt not in MODULES:
                bad.append(f"{mod}:{line} imports {target}, which does not exist")
            elif not _facade(tgt) and _rank(tgt) > _rank(mod):
                bad.append(f"{mod}:{line} imports {target} from a higher layer")
            elif _facade(tgt) and tgt != mod.split(".")[0] and \
                    PACKAGE_RANK[tgt] > PACKAGE_RANK[mod.split(".")[0]]:
                bad.append(f"{mod}:{line} imports the higher package {target}")
    assert not bad, "\n".join(bad)


def test_the_cli_is_a_leaf():
    users = [f"{mod}:{line}" for mod, edges in EDGES.items() for t, _n, line in edges
             if t.startswith("survey.cli") and not mod.startswith("survey.cli")]
    assert not users, "only survey.cli may import survey.cli: " + ", ".join(users)


def test_the_format_layer_reads_nothing_above_it():
    """``sensors.io`` imports only ``raytrace`` and ``sensors.io`` (not even the
    ``sensors`` façade, which would load the simulation)."""
    bad = [f"{mod}:{line} imports {target}"
           for mod, edges in EDGES.items() if tuple(mod.split(".")[:2]) == FORMAT_LAYER
           for target, _name, line in edges
           if not (target.startswith("raytrace") or target.startswith("sensors.io"))]
    assert not bad, "\n".join(bad)


def test_no_import_cycles():
    graph = {mod: {t for t, _n, _l in edges if t in MODULES and t != mod}
             for mod, edges in EDGES.items()}
    # Tarjan's strongly connected components (Tarjan 1972), iteratively.
    index, low, on, stack, sccs, counter = {}, {}, set(), [], [], [0]

    def strong(v):
        work = [(v, iter(sorted(graph[v])))]
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        while work:
            node, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[node] = min(low[node], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    if len(comp) > 1:
                        sccs.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    assert not sccs, "import cycles: " + "; ".join(" <-> ".join(c) for c in sccs)


def test_no_private_names_across_modules():
    bad = [f"{mod}:{line} imports {name} from {target}"
           for mod, edges in EDGES.items() for target, name, line in edges
           if name and name.startswith("_") and target != mod]
    assert not bad, "\n".join(bad)


def test_no_private_modules_across_packages():
    """``_kernels`` and ``_checks`` are their package's own business: another package
    goes through public modules."""
    bad = [f"{mod}:{line} imports {target}"
           for mod, edges in EDGES.items() for target, _name, line in edges
           if any(p.startswith("_") for p in target.split(".")[1:])
           and target.split(".")[0] != mod.split(".")[0]]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("rule", ["cycle", "layer", "private", "format"])
def test_the_rules_catch_a_violation(rule, monkeypatch):
    """Each rule fails on a module that breaks it (so a passing run means something)."""
    fake = {
        "cycle": {"survey.world.alignment": [("survey.world.profiles", None, 1)],
                  "survey.world.profiles": [("survey.world.alignment", None, 1)]},
        "layer": {"survey.world.alignment": [("survey.analysis.compare", "x", 1)]},
        "private": {"survey.world.alignment": [("survey.world.profiles", "_hidden", 1)]},
        "format": {"sensors.io.las": [("sensors.spec", "load_sensor", 1)]},
    }[rule]
    edges = {m: list(e) for m, e in EDGES.items()}
    for m, extra in fake.items():
        edges[m] = edges[m] + extra
    monkeypatch.setattr(__import__(__name__, fromlist=["EDGES"]), "EDGES", edges)
    check = {"cycle": test_no_import_cycles, "layer": test_imports_point_down,
             "private": test_no_private_names_across_modules,
             "format": test_the_format_layer_reads_nothing_above_it}[rule]
    with pytest.raises(AssertionError):
        check()


def test_one_mesh_loader():
    """Mesh files are read in one place, ``sensors.io.meshes`` (issue 32: five places
    called ``trimesh.load`` and two defined ``read_ply``)."""
    bad = []
    for mod, path in MODULES.items():
        if mod == "sensors.io.meshes":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr in ("load", "load_mesh") \
                    and isinstance(node.value, ast.Name) and node.value.id == "trimesh":
                bad.append(f"{mod}:{node.lineno} calls trimesh.{node.attr}")
    assert not bad, "\n".join(bad)


#: Packages the command line may not import (the numeric and file work is the library's).
CLI_FORBIDDEN = ("numpy", "scipy", "trimesh", "laspy", "open3d", "matplotlib", "pyproj")
#: Longest function of a command module, def line to last line (``register`` functions,
#: which only declare options, are exempt).
CLI_MAX_LINES = 60


def _cli_modules() -> dict[str, Path]:
    return {m: p for m, p in MODULES.items() if m.startswith("survey.cli")}


def test_the_cli_is_thin():
    """Issue 32: a command parses, calls one library function and prints. The rule, as
    the code can check it: no module of ``survey.cli`` imports NumPy, SciPy, trimesh,
    laspy, Open3D, Matplotlib or pyproj (at module level or in a function), and no
    function of ``survey.cli.commands`` but a ``register`` is longer than 60 lines."""
    bad = []
    for mod, path in _cli_modules().items():
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level \
                else []
            bad += [f"{mod}:{node.lineno} imports {n}" for n in names
                    if n.split(".")[0] in CLI_FORBIDDEN]
            if mod.startswith("survey.cli.commands") and \
                    isinstance(node, ast.FunctionDef) and node.name != "register":
                length = (node.end_lineno or node.lineno) - node.lineno + 1
                if length > CLI_MAX_LINES:
                    bad.append(f"{mod}:{node.lineno} {node.name} is {length} lines long "
                               f"(> {CLI_MAX_LINES}): move its work into survey.workflows")
    assert not bad, "\n".join(bad)


def test_the_thin_cli_rule_catches_a_violation(tmp_path, monkeypatch):
    fat = tmp_path / "fat.py"
    fat.write_text("def cmd_x(args):\n    import numpy as np\n" + "    x = 1\n" * 70)
    monkeypatch.setitem(MODULES, "survey.cli.commands.fat", fat)
    with pytest.raises(AssertionError, match=r"imports numpy[\s\S]*cmd_x is 72 lines"):
        test_the_cli_is_thin()
