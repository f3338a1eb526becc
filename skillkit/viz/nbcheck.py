"""Checks of an executed notebook: which cells wrote to stderr, and how long each cell ran.

The test suite applies both to every notebook nbmake executes (the root ``conftest.py``)::

    nb = nbformat.read("executed.ipynb", as_version=4)
    stderr_outputs(nb)        # [(cell index, first line of the text), ...]
    execution_seconds(nb)     # {cell index: seconds}, from nbclient's record_timing
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import datetime

__all__ = ["execution_seconds", "stderr_outputs"]


def _cells(nb: Mapping) -> list:
    cells = nb.get("cells") if isinstance(nb, Mapping) else None
    if not isinstance(cells, list):
        raise ValueError("nb: expected a notebook (a mapping with a 'cells' list)")
    return cells


def stderr_outputs(nb: Mapping) -> list[tuple[int, str]]:
    """(cell index, the text's first non-empty line) of each ``stderr`` stream output of an
    executed nbformat 4 notebook (``NotebookNode`` or the parsed JSON), in order."""
    found = []
    for i, cell in enumerate(_cells(nb)):
        if cell.get("cell_type") != "code":
            continue
        for out in cell.get("outputs", []):
            if out.get("output_type") == "stream" and out.get("name") == "stderr":
                text = out.get("text", "")
                text = "".join(text) if isinstance(text, list) else str(text)
                lines = [line for line in text.splitlines() if line.strip()]
                found.append((i, lines[0] if lines else ""))
    return found


def _time(value: str) -> datetime:
    return datetime.fromisoformat(value.replace("Z", "+00:00"))


def execution_seconds(nb: Mapping) -> dict[int, float]:
    """Seconds each code cell ran, by cell index, from the ``execution`` timestamps nbclient
    records with ``record_timing=True``, for the cells that carry both."""
    times = {}
    for i, cell in enumerate(_cells(nb)):
        stamps = cell.get("metadata", {}).get("execution", {})
        start, end = stamps.get("iopub.execute_input"), stamps.get("shell.execute_reply")
        if cell.get("cell_type") == "code" and start and end:
            times[i] = (_time(end) - _time(start)).total_seconds()
    return times
