"""The package's imports only point down the data flow: hand -> sim -> envs -> datasets ->
perception -> learning -> tools -> real -> cli, and no modules import each other in a circle.

The graph is read from the source (AST), imports inside functions and under TYPE_CHECKING
included: an import deferred into a function still ties the two modules together, and
hiding a circle that way is how one grows unnoticed. A module may import its own layer and
below; within a layer the modules' graph has no circle.
"""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "tacgnn"
# Top-level helpers (configs, files, provenance, runtime settings, user errors) sit under everything.
LAYERS = {"config": 0, "files": 0, "provenance": 0, "runtime": 0, "user_errors": 0, "tacgnn": 0,
          "hand": 1, "sim": 2, "envs": 3, "datasets": 4, "perception": 5, "learning": 6,
          "tools": 7, "real": 8, "cli": 9}


def _module_name(path: Path, root: Path = PACKAGE) -> str:
    """'real/bag.py' -> 'real.bag', 'real/__init__.py' -> 'real', the package's own __init__ -> 'tacgnn'."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts) or "tacgnn"


def _resolve(name: str, modules: set[str]) -> str:
    """The module a dotted name inside the package lands on: itself, or the nearest package above
    it (`from tacgnn.real import BlindController` imports the package `real`)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or "tacgnn"


def _imports(module: str, source: str, modules: set[str], is_package: bool = False) -> set[str]:
    """The package's modules that `source` imports, anywhere in it (top level, functions, TYPE_CHECKING)."""
    found = set()
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names if a.name == "tacgnn" or a.name.startswith("tacgnn.")]
            found |= {_resolve(n.removeprefix("tacgnn").lstrip("."), modules) for n in names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the importing module's package, up level - 1
                base = package.split(".") if package and package != "tacgnn" else []
                base = base[:len(base) - (node.level - 1)] if node.level > 1 else base
                parent = ".".join(base + ([node.module] if node.module else []))
            elif node.module == "tacgnn" or (node.module or "").startswith("tacgnn."):
                parent = node.module.removeprefix("tacgnn").lstrip(".")
            else:
                continue
            for alias in node.names:  # `from x import y`: y is a module if there is one by that name
                full = f"{parent}.{alias.name}" if parent else alias.name
                found.add(full if full in modules else _resolve(parent, modules))
    found.discard(module)
    return found


def import_graph(sources: dict[str, tuple[str, bool]]) -> dict[str, set[str]]:
    """module -> the modules it imports, from {module: (source, is_package)}."""
    modules = set(sources)
    return {m: _imports(m, src, modules, is_package) for m, (src, is_package) in sources.items()}


def package_sources() -> dict[str, tuple[str, bool]]:
    return {_module_name(p): (p.read_text(), p.name == "__init__.py") for p in sorted(PACKAGE.rglob("*.py"))}


def _layer(module: str) -> int:
    return LAYERS[module.split(".")[0]]


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    return sorted(f"{m} -> {t}" for m, targets in graph.items() for t in targets if _layer(t) > _layer(m))


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The graph's circles: each strongly connected set of two or more modules (Tarjan), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
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
                cycles.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(cycles)


@pytest.fixture(scope="module")
def graph():
    return import_graph(package_sources())


def test_every_package_folder_has_a_layer():
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and not p.name.startswith("__") and p.name != "assets"}
    modules = {p.stem for p in PACKAGE.glob("*.py") if p.name != "__init__.py"}
    assert folders | modules <= set(LAYERS), sorted((folders | modules) - set(LAYERS))


def test_imports_point_down_the_data_flow(graph):
    assert not upward_imports(graph)


def test_no_modules_import_each_other_in_a_circle(graph):
    assert not import_cycles(graph)


def test_the_checks_see_imports_inside_functions_and_from_packages():
    """The checker itself, on a small made-up package: a circle closed by an import inside a
    function, one closed through a package's __init__, and an arrow up from tools to real."""
    sources = {
        "tacgnn": ("", True),
        "real": ("from tacgnn.real.skin import calibrate\n", True),
        "real.bag": ("def read():\n    from tacgnn.real import ros\n", False),
        "real.ros": ("from tacgnn.real.bag import read\n", False),
        "real.skin": ("import numpy\n\ndef load():\n    from tacgnn.real import BlindController\n", False),
        "tools": ("", True),
        "tools.render": ("def f():\n    from tacgnn.real.bag import read\n", False),
        "hand.allegro": ("from . import skin_layout\nfrom ..config import check\n", False),
        "hand.skin_layout": ("", False),
        "hand": ("", True),
        "config": ("", False),
    }
    graph = import_graph(sources)
    assert graph["real.bag"] == {"real.ros"} and graph["real.skin"] == {"real"}
    assert graph["hand.allegro"] == {"hand.skin_layout", "config"}
    assert import_cycles(graph) == [["real", "real.skin"], ["real.bag", "real.ros"]]
    assert upward_imports(graph) == ["tools.render -> real.bag"]
