"""The import layering holds: schemas <- models <- augment <- workflows, and Ray only in workflows."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LAYERS = ["schemas", "models", "augment", "workflows"]
# Inside ``augment/``: its sub-packages and top modules, lowest first; each may import only those before it.
AUGMENT_ORDER = [
    "io",  # atomic files
    "device",  # torch device choice
    "diffusion",  # noise schedule, samplers, inpainting (no networks)
    "motion",  # rotations, kinematics, features, BVH, batches
    "metrics",  # scores on arrays (accuracy, FMD, foot skating)
    "text",  # caption tokens and revision
    "corpus",  # corpus formats, import, style examples
    "synth",  # the procedural style corpus
    "outputs",  # run folders, shards, export
    "render",  # previews and the 3D viewer of a run or a corpus
    "training",  # pre-training the base models
    "methods",  # the style transfer methods
    "eval",  # run evaluation, reports, the held-out protocol
]
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


def _augment_unit(module: str) -> str | None:
    """``motionaug.augment.motion.features`` -> ``motion``; None outside ``augment``."""
    parts = module.split(".")
    return parts[2] if parts[:2] == ["motionaug", "augment"] and len(parts) > 2 else None


def test_augment_units_import_only_lower_units() -> None:
    """The order inside ``augment/`` is written once (``AUGMENT_ORDER``); no import runs upward, late ones included."""
    units = {p.stem if p.is_file() else p.name for p in (REPO / "augment").iterdir() if p.suffix == ".py" or p.is_dir()}
    units -= {"__init__", "__pycache__"}
    assert units == set(AUGMENT_ORDER), "AUGMENT_ORDER lists every sub-package and top module of augment/"
    offenders = []
    for path in (REPO / "augment").rglob("*.py"):
        rel = path.relative_to(REPO / "augment")
        own = rel.parts[0].removesuffix(".py")
        if own == "__init__":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = (
                    [node.module] + [f"{node.module}.{a.name}" for a in node.names]
                    if node.module == "motionaug.augment"
                    else [node.module]
                )
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for name in names:
                unit = _augment_unit(name)
                if unit and unit != own and AUGMENT_ORDER.index(unit) > AUGMENT_ORDER.index(own):
                    offenders.append(f"augment/{rel.as_posix()} imports {name}")
    assert not offenders, offenders


def test_the_package_never_imports_lab() -> None:
    """``lab/`` is research code beside the package; the product must install and run without it."""
    lab_modules = {p.stem for p in (REPO / "lab").glob("*.py")} | {"lab"}
    offenders = {
        f"{path.relative_to(REPO)} imports {sorted(hit)}"
        for layer in LAYERS
        for path in (REPO / layer).rglob("*.py")
        if (hit := _bare_imports(path) & lab_modules)
    }
    assert not offenders, sorted(offenders)


def test_bench_scripts_use_the_public_api_only() -> None:
    """A benchmark imports no other script (no ``sys.path`` tricks, no ``bench_*`` modules) and no private name."""
    scripts = {p.stem for p in (REPO / "bench").glob("*.py")}
    offenders = []
    for path in (REPO / "bench").glob("*.py"):
        text = path.read_text(encoding="utf-8")
        if "sys.path" in text:
            offenders.append(f"{path.name} edits sys.path")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ImportFrom) and node.module:
                if node.module.split(".")[0] in scripts:
                    offenders.append(f"{path.name} imports the script {node.module}")
                if node.module.startswith("motionaug") and any(a.name.startswith("_") for a in node.names):
                    offenders.append(f"{path.name} imports a private name from {node.module}")
            elif isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
                offenders.append(f"{path.name}:{node.lineno} reads the private {node.attr}")
    assert not offenders, offenders


def test_module_docstrings_say_what_and_why_in_at_most_ten_lines() -> None:
    """Design notes longer than that belong in docs/ (docs/internals.md), not at the top of a module."""
    long = {}
    for layer in LAYERS:
        for path in sorted((REPO / layer).rglob("*.py")):
            doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8")), clean=True)
            if doc and len(doc.strip().splitlines()) > 10:
                long[str(path.relative_to(REPO))] = len(doc.strip().splitlines())
    assert not long, long
