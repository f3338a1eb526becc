"""Helpers for tests that read the claims spec against stored runs."""

from __future__ import annotations

import math

import pytest
from scipy import stats

from skillkit.experiments.judge import Part, spec
from skillkit.experiments.run import Run, stored_run


def part(exp_id: str, label: str) -> Part:
    """The part of ``exp_id``'s claim with ``label`` (exactly one)."""
    (found,) = [p for p in spec(exp_id).parts if p.label == label]
    return found


def stored(exp_id: str) -> Run:
    """The stored paper run of ``exp_id``; the test is skipped where there is none (an
    installed package without data/results)."""
    try:
        return stored_run(exp_id)
    except FileNotFoundError as exc:
        pytest.skip(str(exc))


def wilson(k: float, n: float) -> tuple[float, float]:
    """The 95% Wilson score interval in its count form (k ± ...) / (n + z²), written apart from
    the engine's rate form."""
    z = stats.norm.isf(0.025)
    centre, half = k + z * z / 2, z * math.sqrt(k * (n - k) / n + z * z / 4)
    return (centre - half) / (n + z * z), (centre + half) / (n + z * z)


def resummarised(exp_id: str) -> tuple[Run, dict]:
    """The stored paper run of ``exp_id`` and today's summary of its stored trials
    (``trials.npz``; no trial re-run)."""
    from skillkit.experiments.registry import get
    from skillkit.experiments.runner import load_trials
    from skillkit.experiments.settings import apply_overrides

    run = stored(exp_id)
    exp = get(exp_id)
    settings = apply_overrides(exp.settings[run.scale], run.settings)
    return run, exp.summarize(settings, load_trials(run.path))[1]
