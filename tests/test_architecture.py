"""The structure holds: layer order, short functions, no private names across modules.

Layers, lowest first (docs/architecture.md): kernels -> foundation -> physics -> shapes -> controller
-> designer -> I/O -> command line and benchmarks. A module may import project modules of its own
layer or below, at module level and inside functions; below the I/O layer nothing imports an I/O
library (USD, rerun, matplotlib) or the I/O package. The project's import graph (every import: module
level, inside functions and under ``TYPE_CHECKING``) has no circle, and imports inside functions do not
grow in number.
"""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_FUNCTION_LINES = 80

#: (module prefix, layer); the longest matching prefix wins
LAYERS = [
    ("warp_shape.kernels", 0),
    ("warp_shape.errors", 1), ("warp_shape.interrupts", 1), ("warp_shape.registry", 1), ("warp_shape.simulation_settings", 1),
    ("warp_shape.material", 1), ("warp_shape.mesh", 1), ("warp_shape.limits", 1),
    ("warp_shape.force_family", 2), ("warp_shape.display", 2), ("warp_shape.model", 2), ("warp_shape.physics", 2), ("warp_shape.forces", 2),
    ("warp_shape.integrators", 2), ("warp_shape.crossing", 2), ("warp_shape.stability", 2), ("warp_shape.step_plan", 2),
    ("warp_shape.static_settle", 2),
    ("warp_shape.simulator", 2),
    ("warp_shape.targets", 3), ("warp_shape.sampling", 3), ("warp_shape.scan", 3), ("warp_shape.objectives", 3),
    ("warp_shape.controller", 4), ("warp_shape.gradients", 4), ("warp_shape.feel", 4),
    ("warp_shape.designer", 5), ("warp_shape.scenarios", 5), ("warp_shape.molds", 5),
    ("warp_shape.calibration", 5), ("warp_shape.calibration.files", 6),
    ("warp_shape.io", 6),
    ("warp_shape.sweeps", 7),
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


def imported_from(module: str, path: Path, node: ast.ImportFrom) -> str:
    """The absolute name of the module a ``from ... import`` reads, relative imports resolved."""
    if not node.level:
        return node.module
    base = module.split(".")
    base = base[: len(base) - node.level + (1 if path.name == "__init__.py" else 0)]
    return ".".join(base + ([node.module] if node.module else []))


def imported_modules(module: str, path: Path, tree: ast.AST):
    """(line, imported module) for every import in the file, relative imports resolved."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            name = imported_from(module, path, node)
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


# ------------------------------------------------------------------------------------ the import graph
#: Import circles known and being removed, each as its set of modules: none.
KNOWN_CIRCLES: list[set] = []


def import_graph() -> dict[str, dict[str, int]]:
    """{module: {project module it imports: first line}} over every import of every project module
    (module level, inside functions, under TYPE_CHECKING); ``from package import submodule`` is an
    edge to the submodule."""
    graph = {}
    for module, path in FILES:
        edges = graph.setdefault(module, {})
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = imported_from(module, path, node)
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names]
            else:
                continue
            for name in names:
                target = project_module(name) if name.startswith("warp_shape") else None
                if target is not None and target != module:
                    edges.setdefault(target, node.lineno)
    return graph


def circles(graph: dict[str, dict]) -> list[list[str]]:
    """One circle (a list of modules, each importing the next and the last the first) per strongly
    connected group of modules in ``graph`` (Tarjan's algorithm, iterative)."""
    index, low, on_stack, stack, groups = {}, {}, set(), [], []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(graph.get(root, ())))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(graph.get(w, ()))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    group = set()
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        group.add(w)
                        if w == v:
                            break
                    if len(group) > 1:
                        groups.append(group)
    return [circle_in(graph, group) for group in groups]


def circle_in(graph: dict[str, dict], group: set[str]) -> list[str]:
    """A shortest circle through the alphabetically first module of a strongly connected group."""
    start = min(group)
    previous, frontier = {start: None}, [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in graph.get(v, ()):
                if w == start:
                    path = [v]
                    while previous[path[-1]] is not None:
                        path.append(previous[path[-1]])
                    return path[::-1]
                if w in group and w not in previous:
                    previous[w] = v
                    nxt.append(w)
        frontier = nxt
    raise AssertionError(f"{sorted(group)} is not strongly connected")


def describe(graph: dict[str, dict], circle: list[str]) -> str:
    paths = dict(FILES)
    steps = [f"{a} ({paths[a].relative_to(ROOT)}:{graph[a][b]})" for a, b in zip(circle, circle[1:] + circle[:1])]
    return " -> ".join(steps + [circle[0]])


def test_circles_are_found():
    graph = {"a": {"b": 1}, "b": {"c": 1, "d": 1}, "c": {"a": 1}, "d": {}, "e": {"e": 1, "d": 1}}
    assert [sorted(c) for c in circles(graph)] == [["a", "b", "c"]]
    assert circles({"x": {"y": 1}, "y": {"z": 1}, "z": {}}) == []
    assert circle_in({"a": {"b": 1, "c": 1}, "b": {"c": 1}, "c": {"a": 1}}, {"a", "b", "c"}) == ["a", "c"]


def test_import_graph_resolves_relative_and_function_level_imports():
    graph = import_graph()
    assert "warp_shape.io.atomic" in graph["warp_shape.io.valve"]  # from .atomic import ...
    assert "warp_shape.simulator" in graph["warp_shape.controller.loop"]  # inside a function
    assert "warp_shape.model" in graph["warp_shape.physics.bending"]  # under TYPE_CHECKING


def test_no_import_circle():
    graph = import_graph()
    found = circles(graph)
    known = [c for c in found if set(c) in KNOWN_CIRCLES]
    new = [describe(graph, c) for c in found if set(c) not in KNOWN_CIRCLES]
    assert not new, "import circles (move the shared piece below both, or import in one direction only):\n" + \
        "\n".join(new)
    gone = [sorted(k) for k in KNOWN_CIRCLES if k not in [set(c) for c in known]]
    assert not gone, f"the known circle {gone} is gone: remove it from KNOWN_CIRCLES"


def test_host_design_imports_no_kernel():
    """``Design`` (the host-side description) and what it imports, their packages included, reach no
    Warp kernel module: the float64 laws it uses live in kernel-free modules of their family."""
    graph = import_graph()
    seen, todo = set(), ["warp_shape.display"]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        parents = [".".join(m.split(".")[:n]) for n in range(2, m.count(".") + 1)]
        todo += [t for t in list(graph.get(m, ())) + parents if t in MODULES]
    kernels = sorted(m for m in seen if layer_of(m) == 0)
    assert not kernels, f"warp_shape.display reaches the kernel modules {kernels}"


# ------------------------------------------------------------------------------------ imports inside functions
#: Project imports inside functions, at most. Imports belong at module top; the ones left inside
#: functions keep `warp-shape`'s start-up quick (the benchmarks and the sweep package, imported by
#: the subcommands that run them) or are the controller's two Simulator constructions. Lower this
#: number when you move one up; never raise it.
MAX_FUNCTION_LEVEL_IMPORTS = 11


def function_level_imports() -> list[str]:
    """``path:line module`` of every project import inside a function, over every project module."""
    found = []
    for module, path in FILES:
        def visit(node, in_function):
            for child in ast.iter_child_nodes(node):
                inside = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
                if in_function and isinstance(child, ast.ImportFrom):
                    name = imported_from(module, path, child)
                    if name.startswith("warp_shape"):
                        found.append(f"{path.relative_to(ROOT)}:{child.lineno} {name}")
                elif in_function and isinstance(child, ast.Import):
                    found.extend(f"{path.relative_to(ROOT)}:{child.lineno} {a.name}" for a in child.names
                                 if a.name.startswith("warp_shape"))
                visit(child, inside)

        visit(ast.parse(path.read_text()), False)
    return found


def test_function_level_imports_do_not_grow():
    found = function_level_imports()
    assert len(found) <= MAX_FUNCTION_LEVEL_IMPORTS, (
        f"{len(found)} project imports inside functions (at most {MAX_FUNCTION_LEVEL_IMPORTS}); move new ones to "
        f"the module's top:\n" + "\n".join(found))


def test_no_two_modules_share_a_name():
    """A module's name says what it holds: the names that once meant three things (three ``replay``,
    two ``equilibrium``, three ``settings``) are one module or none, and no top-level module has the
    name of a public function (``import warp_shape.design`` gave the ``ws.design`` function)."""
    import warp_shape as ws

    stems = {}
    for path in (ROOT / "warp_shape").rglob("*.py"):
        if path.name != "__init__.py" and "cli" not in path.relative_to(ROOT / "warp_shape").parts:
            stems.setdefault(path.stem, []).append(path.relative_to(ROOT).as_posix())
    for name in ("replay", "equilibrium", "settings"):
        assert len(stems.get(name, [])) <= 1, f"{name}: {stems[name]}"
    functions = [n for n in dir(ws) if not n.startswith("_") and inspect.isfunction(getattr(ws, n))]
    assert "design" in functions
    shadowed = [n for n in functions if (ROOT / "warp_shape" / f"{n}.py").exists()
                or (ROOT / "warp_shape" / n / "__init__.py").exists()]
    assert not shadowed, f"modules named as public functions: {shadowed}"
