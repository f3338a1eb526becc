"""The chapter notebooks as files: stored without outputs, one scale knob, every figure shown.

(nbmake executes them as part of ``python -m pytest``; see pyproject.toml and conftest.py.)
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from skillkit.experiments import ids

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
CHAPTERS = ("ch2_preliminaries", "ch3_contextual_reps", "ch4_gpreps", "ch5_kernel_embeddings")
#: Notebooks hold no logic of their own, except the reader's own skill in the tutorial that
#: writes one from scratch: its functions live in cells tagged OWN_CODE_TAG, and only there.
OWN_CODE_TAG = "your-skill"
OWN_CODE_NOTEBOOKS = ("06_your_own_skill",)
#: A teaching cell shows an algorithm as plain code (it may define functions); the next code
#: cell checks it against the library and fails loudly (an ``assert``) when they differ.
TEACHING_TAG = "teaching"


def _load(name: str) -> dict:
    return json.loads((NOTEBOOKS / f"{name}.ipynb").read_text())


def _own(cell: dict) -> bool:
    tags = cell.get("metadata", {}).get("tags", [])
    return OWN_CODE_TAG in tags or TEACHING_TAG in tags


def _teaching(cell: dict) -> bool:
    return TEACHING_TAG in cell.get("metadata", {}).get("tags", [])


def _code(nb: dict, own: bool = True) -> list[str]:
    """The code cells' sources (without the cells of the reader's own code unless ``own``)."""
    return [
        "".join(c["source"])
        for c in nb["cells"]
        if c["cell_type"] == "code" and (own or not _own(c))
    ]


@pytest.mark.parametrize("path", sorted(NOTEBOOKS.glob("*.ipynb")), ids=lambda p: p.name)
def test_stored_without_outputs_and_scaled_by_one_variable(path):
    nb = json.loads(path.read_text())
    ids = [cell.get("id") for cell in nb["cells"]]  # nbformat ≥ 4.5: every cell has a unique id
    assert (nb["nbformat"], nb["nbformat_minor"]) >= (4, 5) and None not in ids, path.name
    assert len(set(ids)) == len(ids), path.name
    for cell in nb["cells"]:
        if cell["cell_type"] == "code":
            assert cell["outputs"] == [] and cell["execution_count"] is None, path.name
    code = "\n".join(_code(nb))
    assert 'os.environ.get("SKILLKIT_SCALE", "smoke")' in code
    assert "matplotlib.use" not in code and "class " not in code
    assert "def " not in "\n".join(_code(nb, own=False)), path.name
    if path.stem not in OWN_CODE_NOTEBOOKS:
        own = [c for c in nb["cells"] if OWN_CODE_TAG in c.get("metadata", {}).get("tags", [])]
        assert not own, path.name
    code_cells = [c for c in nb["cells"] if c["cell_type"] == "code"]
    for i, cell in enumerate(code_cells):
        if _teaching(cell):  # a teaching cell is followed by its check against the library
            after = code_cells[i + 1] if i + 1 < len(code_cells) else None
            assert after is not None and "assert " in "".join(after["source"]), (
                f"{path.name}: teaching cell {cell['id']} is not followed by a check cell"
            )


def test_every_chapter_exists_and_every_experiment_is_shown_stored_and_live():
    shown_stored, shown_live = set(), set()
    for name in (*CHAPTERS, *OWN_CODE_NOTEBOOKS):  # the tutorial shows cmp.methods
        code = "\n".join(_code(_load(name)))
        shown_stored |= set(re.findall(r'stored_run\("([^"]+)"[,)]', code))
        shown_live |= set(re.findall(r'reproduce\("([^"]+)", scale=SCALE', code))
    assert set(ids()) - {"sanity3"} <= shown_stored & shown_live


def test_chapters_state_their_equations():
    for name, eqs in {
        "ch2_preliminaries": ("(2.21", "(2.23)", "(2.26, 2.27)"),
        "ch3_contextual_reps": ("(3.7)", "(3.9)"),
        "ch4_gpreps": ("(4.1)", "(4.3)"),
        "ch5_kernel_embeddings": ("(5.7, 5.8)",),
        "06_your_own_skill": ("(3.9)", "(3.10)", "(4.1)", "(4.3)"),
    }.items():
        text = "\n".join("".join(c["source"]) for c in _load(name)["cells"])
        for eq in eqs:
            assert eq in text, (name, eq)
