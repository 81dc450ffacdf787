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


# Lowest first. A module belongs to the first layer with a matching prefix; every module must
# belong to one (a new module states its layer here).
LAYERS = (
    ("core", ("fgcal.errors", "fgcal.fields", "fgcal.units", "fgcal.strict_json", "fgcal.parameters", "fgcal.se3",
              "fgcal.noise", "fgcal.outputs", "fgcal.console", "fgcal.memory", "fgcal.compiled")),
    (
        "model",
        ("fgcal.chain_kernel", "fgcal.ets", "fgcal.joints", "fgcal.motion", "fgcal.kinematics", "fgcal.robot",
         "fgcal.robot_io", "fgcal.urdf_io", "fgcal.urdf_export", "fgcal.rigid_fit", "fgcal.ik", "fgcal.camera",
         "fgcal.boards"),
    ),
    ("data", ("fgcal.dataset", "fgcal.truth", "fgcal.faro", "fgcal.csv_import", "fgcal.compensation", "fgcal.programs",
              "fgcal.program_filter", "fgcal.ur_kinematics")),
    ("factors and simulation", ("fgcal.factors", "fgcal.simulation", "fgcal.markers")),
    ("calibration", ("fgcal.calibration",)),
    ("online and planning", ("fgcal.online", "fgcal.planning")),
    ("reports and commands", ("fgcal.reports", "fgcal.bench", "fgcal.bench_kernel", "fgcal.cli", "fgcal.__main__",
                              "fgcal.api")),
)  # fmt: skip


def _layer(module: str) -> int:
    for rank, (_, prefixes) in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return rank
    raise AssertionError(f"{module} belongs to no layer: add it to LAYERS in tests/test_layout.py")


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
