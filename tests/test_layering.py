"""The import layering holds: schemas <- models <- augment <- workflows, and Ray only in workflows."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LAYERS = ["schemas", "models", "augment", "workflows"]
FORBIDDEN_EXTERNAL = {"schemas": {"torch", "ray"}, "models": {"ray"}, "augment": {"ray"}}


def root_of(module: str) -> str:
    """``motionaug.augment.corpus`` -> ``augment`` (a layer); ``torch.nn`` -> ``torch``."""
    parts = module.split(".")
    return parts[1] if parts[0] == "motionaug" and len(parts) > 1 else parts[0]


def imported_roots(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots.update(root_of(alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            roots.add(root_of(node.module))
    return roots


@pytest.mark.parametrize("layer", LAYERS)
def test_no_upward_imports(layer: str) -> None:
    above = set(LAYERS[LAYERS.index(layer) + 1 :]) | FORBIDDEN_EXTERNAL.get(layer, set())
    offenders = {
        f"{path.relative_to(REPO)} imports {sorted(imported_roots(path) & above)}"
        for path in (REPO / layer).rglob("*.py")
        if imported_roots(path) & above
    }
    assert not offenders, sorted(offenders)


def test_layers_import_through_the_namespace_only() -> None:
    """``import augment`` would work from the repo root but not from an installed package."""
    offenders = {
        f"{path.relative_to(REPO)} imports {sorted(bare)}"
        for layer in LAYERS
        for path in (REPO / layer).rglob("*.py")
        if (bare := _bare_imports(path) & set(LAYERS))
    }
    assert not offenders, sorted(offenders)


def _bare_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {
        n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module and n.level == 0
    }
    return names


def test_every_package_folder_is_installed() -> None:
    """pyproject's explicit package list (needed by the package-dir mapping) names every folder with code."""
    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]["packages"])
    found = {
        "motionaug." + init.parent.relative_to(REPO).as_posix().replace("/", ".")
        for layer in LAYERS
        for init in (REPO / layer).rglob("__init__.py")
    }
    assert listed == found
