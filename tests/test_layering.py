"""The import layering holds: schemas <- models <- augment <- workflows, and Ray only in workflows."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LAYERS = ["schemas", "models", "augment", "workflows"]
FORBIDDEN_EXTERNAL = {"schemas": {"torch", "ray"}, "models": {"ray"}, "augment": {"ray"}}


def imported_roots(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            roots.add(node.module.split(".")[0])
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
