"""The package's layout: its layers, each importing only its own and lower ones, and no import
circles between fgcal's modules. Every import counts: lazy ones inside functions and typed ones
under TYPE_CHECKING alike, so a dependency cannot hide in an annotation."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _modules() -> dict[str, Path]:
    """Module name -> file, with factors/ installed as fgcal.factors."""
    modules = {}
    for root, package in ((REPO / "fgcal", "fgcal"), (REPO / "factors", "fgcal.factors")):
        for path in root.rglob("*.py"):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join([package, *parts])] = path
    return modules


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                target = f"{base}.{node.module}" if node.module else base
            else:
                target = node.module or ""
            candidates = [target] + [f"{target}.{alias.name}" for alias in node.names]
        elif isinstance(node, ast.Import):
            candidates = [alias.name for alias in node.names]
        else:
            continue
        found |= {c for c in candidates if c in modules and c != name}
    return found


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_circles():
    modules = _modules()
    # A package's __init__ re-exports its modules; the circles that matter are between modules.
    graph = {
        name: {m for m in _imports(name, path, modules) if modules[m].name != "__init__.py"}
        for name, path in modules.items()
        if path.name != "__init__.py"
    }
    assert _cycles(graph) == []


# Lowest first: each layer is one package (or two side by side), and a module belongs to the
# layer of the package it lives in. Only the package's entry points stay at the top.
LAYERS = (
    ("core", ("fgcal.core",)),
    ("model", ("fgcal.model",)),
    ("data", ("fgcal.data",)),
    ("factors and simulation", ("fgcal.factors", "fgcal.simulation")),
    ("calibration", ("fgcal.calibration",)),
    ("online and planning", ("fgcal.online", "fgcal.planning")),
    ("reports", ("fgcal.reports",)),
    ("commands", ("fgcal.commands", "fgcal.bench", "fgcal.__main__", "fgcal.api")),
)
TOP_LEVEL = {"fgcal", "fgcal.__main__", "fgcal.api"}


def _layer(module: str) -> int:
    for rank, (_, prefixes) in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return rank
    raise AssertionError(f"{module} is in no layer's package: move it into one (docs/architecture.md)")


def test_layers_import_only_downward():
    modules = {name: path for name, path in _modules().items() if name != "fgcal"}
    upward = []
    for name, path in modules.items():
        for target in _imports(name, path, modules):
            if target != "fgcal" and _layer(target) > _layer(name):
                upward.append(f"{name} ({LAYERS[_layer(name)][0]}) imports {target} ({LAYERS[_layer(target)][0]})")
    assert upward == []


def test_the_layer_test_sees_typed_imports(tmp_path):
    """An import under TYPE_CHECKING is an import: the check that fails on it, works."""
    path = tmp_path / "m.py"
    path.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from fgcal.reports import calibration\n")
    modules = {**_modules(), "fgcal.calibration.m": path}
    assert "fgcal.reports.calibration" in _imports("fgcal.calibration.m", path, modules)


def test_every_module_lives_in_its_layers_package():
    """At most three modules at the top (``__init__``, ``__main__``, ``api``); every other module
    is inside the package of its layer, so the folder tree shows the architecture."""
    modules = _modules()
    top = {name for name, path in modules.items() if path.parent in (REPO / "fgcal",) and path.suffix == ".py"}
    assert top <= TOP_LEVEL, f"modules directly in fgcal/ besides the entry points: {sorted(top - TOP_LEVEL)}"
    outside = []
    for name in modules:
        if name in TOP_LEVEL:
            continue
        try:
            _layer(name)
        except AssertionError as exc:
            outside.append(str(exc))
    assert outside == []


def test_the_layout_test_fails_on_a_module_outside_the_packages(tmp_path):
    """A module dropped beside the entry points belongs to no layer: the check that fails on it, works."""
    try:
        _layer("fgcal.stray")
    except AssertionError as exc:
        assert "fgcal.stray" in str(exc)
    else:
        raise AssertionError("a module outside every layer's package was accepted")


# Packages that reach formulations only through their protocol (Formulation, Planning): no
# module in them names a registered formulation, its class, an instrument or a Planning kind.
PROTOCOL_ONLY = ("planning", "online")


def _formulation_words() -> tuple[set[str], set[str]]:
    """(strings, identifiers) that single out a formulation: registered names and instruments;
    the formulation classes and the Planning implementations."""
    from fgcal.calibration.formulations import REGISTRY
    from fgcal.calibration.plan_model import Planning
    from fgcal.simulation.cell import INSTRUMENTS

    strings = set(REGISTRY) | set(INSTRUMENTS) | {cls.instrument for cls in REGISTRY.values()}
    identifiers = {cls.__name__ for cls in REGISTRY.values()} | {cls.__name__ for cls in Planning.__subclasses__()}
    return strings, identifiers


def _branches_on_a_formulation(source: str) -> list[str]:
    """Where a module's code (docstrings aside) names a formulation or an instrument: a string
    constant (compared, tested for membership, matched, a key, an argument) or a formulation's
    or Planning implementation's class."""
    strings, identifiers = _formulation_words()
    tree = ast.parse(source)
    documented = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, documented) and node.body and isinstance(node.body[0], ast.Expr)
    }
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and node.value in strings and id(node) not in docstrings:
            found.append(f"line {node.lineno}: {node.value!r}")
        elif isinstance(node, ast.Name) and node.id in identifiers:
            found.append(f"line {node.lineno}: {node.id}")
        elif isinstance(node, ast.Attribute) and node.attr in identifiers:
            found.append(f"line {node.lineno}: .{node.attr}")
        elif isinstance(node, ast.alias) and node.name.rsplit(".", 1)[-1] in identifiers:
            found.append(f"line {node.lineno}: import {node.name}")
    return found


def test_planning_asks_the_formulation():
    """Planning reads what a formulation measures through ``Formulation.planning`` (docs/
    architecture.md), online recalibration through ``online_observations`` and
    ``measurement_sets`` (issue 41): no module of fgcal/planning or fgcal/online branches on a
    formulation's name or instrument, or picks a formulation's or a Planning's class."""
    found = []
    for package in PROTOCOL_ONLY:
        for path in sorted((REPO / "fgcal" / package).rglob("*.py")):
            found += [f"{path.relative_to(REPO)} {where}" for where in _branches_on_a_formulation(path.read_text())]
    assert found == []


def test_the_protocol_test_sees_a_branch_on_a_formulation():
    """The branches this replaced, and their variants: the check that fails on them, works."""
    planted = [
        'if formulation.instrument == "tracker":\n    pass\n',
        'PLANNED = {n: c.instrument for n, c in R.items() if c.instrument in ("camera", "tracker")}\n',
        'match name:\n    case "pairs":\n        pass\n',
        "from fgcal.calibration.plan_model import Reflectors\n",
        "ok = isinstance(planning, plan_model.FlangeCamera)\n",
    ]
    for source in planted:
        assert _branches_on_a_formulation(source), source
    assert _branches_on_a_formulation('def f():\n    """camera"""\n    return "tracker point"\n') == []
