"""The structure holds: layer order, short functions, no private names across modules.

Layers, lowest first (docs/architecture.md): kernels -> foundation -> physics -> shapes -> controller
-> designer -> I/O -> command line and benchmarks. A module may import project modules of its own
layer or below, at module level and inside functions; below the I/O layer nothing imports an I/O
library (USD, rerun, matplotlib) or the I/O package.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_FUNCTION_LINES = 80

#: (module prefix, layer); the longest matching prefix wins
LAYERS = [
    ("warp_shape.kernels", 0),
    ("warp_shape.errors", 1), ("warp_shape.settings", 1), ("warp_shape.material", 1), ("warp_shape.mesh", 1),
    ("warp_shape.design", 2), ("warp_shape.model", 2), ("warp_shape.physics", 2), ("warp_shape.forces", 2),
    ("warp_shape.integrators", 2), ("warp_shape.stability", 2), ("warp_shape.step_plan", 2),
    ("warp_shape.simulator", 2),
    ("warp_shape.targets", 3), ("warp_shape.sampling", 3), ("warp_shape.scan", 3),
    ("warp_shape.controller", 4),
    ("warp_shape.designer", 5), ("warp_shape.scenarios", 5), ("warp_shape.molds", 5),
    ("warp_shape.io", 6),
    ("warp_shape.sweep", 7),
    ("warp_shape.cli", 8), ("warp_shape.benchmarks", 8),
]
TOP = 8  # the package's face, warp_shape/__init__.py
IO_LAYER = 6
IO_LIBRARIES = ("pxr", "rerun", "matplotlib")


def source_files():
    """(module name, path) of every project module: the package, its kernels and its benchmarks."""
    roots = [(ROOT / "warp_shape", "warp_shape"), (ROOT / "kernels", "warp_shape.kernels"),
             (ROOT / "benchmarks", "warp_shape.benchmarks")]
    out = []
    for folder, package in roots:
        for path in sorted(folder.rglob("*.py")):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out.append((".".join([package, *parts]), path))
    return out


def layer_of(module: str) -> int | None:
    if module == "warp_shape":
        return TOP
    best = None
    for prefix, layer in LAYERS:
        if (module == prefix or module.startswith(prefix + ".")) and (best is None or len(prefix) > len(best[0])):
            best = (prefix, layer)
    return None if best is None else best[1]


def imported_modules(module: str, path: Path, tree: ast.AST):
    """(line, imported module) for every import in the file, relative imports resolved."""
    is_package = path.name == "__init__.py"
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base[: len(base) - node.level + (1 if is_package else 0)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module
            yield node.lineno, name
            for alias in node.names:  # `from package import submodule`
                yield node.lineno, f"{name}.{alias.name}"


FILES = source_files()
MODULES = {m for m, _ in FILES}


def project_module(name: str) -> str | None:
    """The project module an imported name refers to (``warp_shape.a.b.symbol`` -> ``warp_shape.a.b``)."""
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in MODULES:
            return ".".join(parts[:n])
    return None


def test_project_modules_are_found():
    names = {m for m, _ in FILES}
    assert {"warp_shape.simulator", "warp_shape.kernels.hinge", "warp_shape.io.scene_read",
            "warp_shape.controller.loop", "warp_shape.benchmarks.sim"} <= names


@pytest.mark.parametrize("module,path", FILES, ids=[m for m, _ in FILES])
def test_layer_order(module, path):
    tree = ast.parse(path.read_text())
    own = layer_of(module)
    assert own is not None, f"{module} has no layer: add it to LAYERS and docs/architecture.md"
    for line, name in imported_modules(module, path, tree):
        if own < IO_LAYER and name.split(".")[0] in IO_LIBRARIES:
            pytest.fail(f"{path.relative_to(ROOT)}:{line} imports {name}: only the I/O layer may use I/O libraries")
        if own < IO_LAYER and name.startswith("warp_shape.io"):
            pytest.fail(f"{path.relative_to(ROOT)}:{line} imports {name}: the I/O layer is above layer {own}")
        target_module = project_module(name) if name.startswith("warp_shape") else None
        if target_module is None:
            continue
        target = layer_of(target_module)
        if target is None or target > own:
            pytest.fail(f"{path.relative_to(ROOT)}:{line} imports {target_module} (layer {target}) from layer {own}")


def python_files_outside_kernels():
    for folder in ("warp_shape", "benchmarks", "examples", "scripts", "tests"):
        yield from sorted((ROOT / folder).rglob("*.py"))


def test_no_function_over_80_lines():
    long = []
    for path in python_files_outside_kernels():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({n} lines)")
    assert not long, "functions over 80 lines:\n" + "\n".join(long)


def is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def test_no_private_name_crosses_a_module():
    found = []
    for path in list(python_files_outside_kernels()) + sorted((ROOT / "kernels").glob("*.py")):
        tree = ast.parse(path.read_text())
        modules = set()  # local names bound to project modules
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                project = node.level > 0 or (node.module or "").startswith(("warp_shape", "reference"))
                for alias in node.names:
                    if project and is_private(alias.name):
                        found.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {alias.name}")
                    if project:
                        modules.add(alias.asname or alias.name)
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.startswith("warp_shape") or alias.name == "reference":
                        modules.add(alias.asname or alias.name.split(".")[0])
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and is_private(node.attr):
                base = node.value
                while isinstance(base, ast.Attribute):
                    base = base.value
                if isinstance(base, ast.Name) and base.id in modules and base.id not in ("self", "cls"):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} uses {ast.unparse(node)}")
    assert not found, "private names used across modules:\n" + "\n".join(found)
