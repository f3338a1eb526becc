"""Measured wall times of every experiment id at the ``smoke`` and ``quick`` scales, read from
``skillkit/data/scale_times.json`` (``benchmarks/bench_scales.py`` writes it: ``{"cores",
"load_before", "commit", "date", "times": {id: {scale: seconds}}}``); imports no torch."""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Any

TIMES_FILE = Path(__file__).resolve().parent.parent / "data" / "scale_times.json"
"""Where ``benchmarks/bench_scales.py`` writes the measured table."""


@lru_cache(maxsize=1)
def _table() -> dict[str, Any]:
    try:
        data = json.loads(TIMES_FILE.read_text())
    except (FileNotFoundError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def measured_seconds(exp_id: str, scale: str) -> float | None:
    """The measured seconds of ``reproduce(exp_id, scale=scale)`` with the default trials,
    or None where not measured."""
    entry = _table().get("times", {}).get(exp_id, {})
    value = entry.get(scale) if isinstance(entry, dict) else None
    return float(value) if isinstance(value, (int, float)) and value >= 0 else None


def machine_note() -> str:
    """Where and how the table was measured, e.g. ``"2 cores, load 0.1 before, commit abc1234"``."""
    table = _table()
    if not table:
        return "not measured"
    parts = ["CPU time of a shared machine"] if table.get("time_kind") == "cpu" else []
    if table.get("cores"):
        parts.append(f"{table['cores']} cores")
    if isinstance(table.get("load_before"), (int, float)):
        parts.append(f"load {table['load_before']:.1f} before")
    if table.get("commit"):
        parts.append(f"commit {str(table['commit'])[:7]}")
    if table.get("date"):
        parts.append(str(table["date"]))
    return ", ".join(parts) if parts else "measured"


def format_seconds(seconds: float | None) -> str:
    """``"12 s"``, ``"4.5 min"``, ``"2.1 h"``, or ``"not measured"`` for None."""
    if seconds is None:
        return "not measured"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def estimate(exp_id: str, scale: str, trials: int | None, default_trials: int) -> str | None:
    """A one-line estimate of a run's wall time, linear in the trials (None: not measured)."""
    seconds = measured_seconds(exp_id, scale)
    if seconds is None:
        return None
    n = default_trials if trials is None else trials
    if n != default_trials and default_trials > 0:
        seconds = seconds * n / default_trials
    took = format_seconds(seconds)
    return f"expected wall time about {took} with the local executor ({machine_note()})"
