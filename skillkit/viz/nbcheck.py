"""Checks of an executed notebook (the root ``conftest.py`` applies them to every notebook
nbmake executes): which cells wrote to stderr, and how long each cell ran."""

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
        for out in cell.get("outputs", []) if cell.get("cell_type") == "code" else []:
            if out.get("output_type") == "stream" and out.get("name") == "stderr":
                text = out.get("text", "")
                text = "".join(text) if isinstance(text, list) else str(text)
                found.append((i, next((ln for ln in text.splitlines() if ln.strip()), "")))
    return found


def execution_seconds(nb: Mapping) -> dict[int, float]:
    """Seconds each code cell ran, by cell index, from the ``execution`` timestamps nbclient
    records with ``record_timing=True``, for the cells that carry both."""
    times = {}
    for i, cell in enumerate(_cells(nb)):
        stamps = cell.get("metadata", {}).get("execution", {})
        start, end = stamps.get("iopub.execute_input"), stamps.get("shell.execute_reply")
        if cell.get("cell_type") == "code" and start and end:
            times[i] = (datetime.fromisoformat(end) - datetime.fromisoformat(start)).total_seconds()
    return times
