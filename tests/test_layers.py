"""No module under ``skillkit/`` imports from a layer above its own.

The layers, bottom to top (DESIGN.md): the foundations (validation, trajectories, the trial
context), policies and models, tasks, search, viz, experiments, and the command line. The test
parses every module's imports (also those inside functions), so a lazy import that runs back up
the layers fails it too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import skillkit

ROOT = Path(skillkit.__file__).parent
LAYERS = {
    "_validation": 0,
    "_repr": 0,
    "trajectory": 0,
    "trial": 0,
    "series": 0,  # what an experiment plots and the bands it computes: plain data
    "policies": 1,
    "models": 1,
    "tasks": 2,
    "search": 3,
    "viz": 4,
    "experiments": 5,
    "teaching": 6,  # what the notebooks call: above the experiments, imported by nothing
    "cli": 6,
    "__init__": 0,  # the package root holds only the foundations and __version__
    "__main__": 6,
}


def _layer(module: str) -> int:
    """Layer of a dotted module path inside skillkit (``skillkit.tasks.base`` → 2)."""
    parts = module.split(".")
    assert parts[0] == "skillkit", module
    if len(parts) == 1:
        return LAYERS["__init__"]
    if parts[1] not in LAYERS:
        raise AssertionError(f"module skillkit.{parts[1]} has no layer: add it to LAYERS")
    return LAYERS[parts[1]]


def _modules() -> list[Path]:
    return sorted(p for p in ROOT.rglob("*.py") if "__pycache__" not in p.parts)


def _name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    return ".".join(parts)


def _imports(path: Path, package: str | None = None) -> list[tuple[int, str]]:
    """(line, absolute module) of every skillkit import in a file, relative ones resolved
    against ``package`` (default: the file's own package)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    if package is None:
        package = _name(path).rsplit(".", 1)[0] if path.name != "__init__.py" else _name(path)
        package = package.removesuffix(".__init__")
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if a.name.startswith("skillkit")]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            if module.startswith("skillkit"):
                found.append((node.lineno, module))
    return sorted(found)


def test_every_module_has_a_layer():
    for path in _modules():
        _layer(_name(path).removesuffix(".__init__") or "skillkit")


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_import_from_a_layer_above(path):
    own = _layer(_name(path).removesuffix(".__init__"))
    upward = [
        f"line {line}: {module} (layer {_layer(module)})"
        for line, module in _imports(path)
        if _layer(module) > own
    ]
    assert not upward, f"{_name(path)} (layer {own}) imports from above: {upward}"


def test_the_check_catches_an_upward_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(
        "def f():\n    from skillkit.experiments import runner\n\nfrom ..viz import plots\n"
    )
    assert _imports(bad, "skillkit.tasks") == [(2, "skillkit.experiments"), (4, "skillkit.viz")]
    assert _layer("skillkit.experiments") > _layer("skillkit.tasks.base")
