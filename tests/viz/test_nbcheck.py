"""skillkit.viz.nbcheck on constructed notebooks (the nbmake run applies it to the real ones)."""

from __future__ import annotations

import pytest

from skillkit.viz.nbcheck import execution_seconds, stderr_outputs


def _nb(*cells):
    return {"cells": list(cells), "metadata": {}, "nbformat": 4, "nbformat_minor": 5}


def _code(outputs, execution=None):
    meta = {"execution": execution} if execution else {}
    return {"cell_type": "code", "source": "", "outputs": outputs, "metadata": meta}


def test_stderr_outputs_are_found_with_their_cell_and_first_line():
    nb = _nb(
        {"cell_type": "markdown", "source": "x", "metadata": {}},
        _code([{"output_type": "stream", "name": "stdout", "text": "fine\n"}]),
        _code([{"output_type": "stream", "name": "stderr", "text": ["\n", "UserWarning: x\n"]}]),
        _code([{"output_type": "display_data", "data": {}, "metadata": {}}]),
    )
    assert stderr_outputs(nb) == [(2, "UserWarning: x")]
    assert stderr_outputs(_nb(_code([]))) == []


def test_execution_seconds_is_the_difference_of_the_recorded_stamps():
    stamps = {
        "iopub.execute_input": "2026-12-03T12:00:00.250000Z",
        "shell.execute_reply": "2026-12-03T12:00:02.000000Z",
    }
    nb = _nb(_code([], stamps), _code([]))
    assert execution_seconds(nb) == {0: pytest.approx(1.75, abs=1e-9)}


def test_not_a_notebook_is_named():
    with pytest.raises(ValueError, match="nb: expected a notebook"):
        stderr_outputs({"cells": None})
    with pytest.raises(ValueError, match="nb: expected a notebook"):
        execution_seconds([])
