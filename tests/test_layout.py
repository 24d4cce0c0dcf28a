"""The package's imports only point down the data flow: hand -> sim -> envs -> datasets ->
perception -> learning -> tools, real -> cli. A module may import its own layer and below."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "tacgnn"
# Top-level helpers (configs, files, provenance, runtime settings, user errors) sit under everything.
LAYERS = {"config": 0, "files": 0, "provenance": 0, "runtime": 0, "user_errors": 0, "__init__": 0,
          "hand": 1, "sim": 2, "envs": 3, "datasets": 4, "perception": 5, "learning": 6,
          "tools": 7, "real": 7, "cli": 8}


def _layer(module: str) -> int:
    return LAYERS[module.split(".")[0]]


def _imports(path: Path) -> set[str]:
    """tacgnn modules `path` imports, at the top or inside functions."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        found |= {n.split(".", 1)[1] for n in names if n.startswith("tacgnn.")}
        if isinstance(node, ast.ImportFrom) and node.module == "tacgnn":  # from tacgnn import x
            found |= {a.name if a.name in LAYERS else "__init__" for a in node.names}
    return found


def test_every_package_folder_has_a_layer():
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and not p.name.startswith("__") and p.name != "assets"}
    modules = {p.stem for p in PACKAGE.glob("*.py")}
    assert folders | modules <= set(LAYERS), sorted((folders | modules) - set(LAYERS))


def test_imports_point_down_the_data_flow():
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        own = ".".join(path.relative_to(PACKAGE).with_suffix("").parts)
        for target in _imports(path):
            if _layer(target) > _layer(own):
                upward.append(f"{own} -> {target}")
    assert not upward, upward
