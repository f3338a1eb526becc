"""sec4.2.4 (trajectory-KL model learning): the summary's per-trial arrays and the own parts
of the claims spec on the stored paper run."""

from __future__ import annotations

import numpy as np
from _tolerances import fp_tol
from scipy import stats

from skillkit.experiments.judge import card_lines_ok, judge, read, spec
from skillkit.experiments.run import stored_run
from skillkit.experiments.runner import run_trials

CELLS = [
    ("pendulum", "linear"),
    ("pendulum", "fitc"),
    ("balancing", "linear"),
    ("balancing", "fitc"),
]


def _per_trial(run, system: str, cls: str, method: str) -> list[float]:
    with np.load(run / "trials.npz") as z:
        n = run.summary["n_trials"]
        return [float(z[f"trial{i}__{system}.{cls}.{method}.multistep_error"]) for i in range(n)]


def test_smoke_summary_keeps_per_trial_errors_and_is_not_judged():
    r = run_trials("sec4.2.4", "smoke", seed=0, progress=False)
    s = r["summary"]
    for system in r["settings"]["systems"]:
        for cls in ("linear", "fitc"):
            for method in ("ml", "tkl_0"):
                cell = s["cells"][system][cls][method]
                per = cell["multistep_error_per_trial"]
                assert len(per) == s["n_trials"] == 1
                assert per[0] == cell["multistep_error"]
    j = judge("sec4.2.4", s, "smoke")
    assert j.outcome == "not judged" and card_lines_ok(j.card())
    assert s["holds"] is None


def test_own_parts_are_paired_t_intervals_over_the_stored_trials():
    """With the per-trial arrays from trials.npz (the stored run was remeasured from them, and
    this test rebuilds them independently), each own part is the Student-t interval of the
    per-trial differences TKL − ML, and every cell is undecided."""
    run = stored_run("sec4.2.4")
    s = run.summary
    parts = [p for p in spec("sec4.2.4").parts if p.own]
    assert len(parts) == len(CELLS)
    assert all(read(p, s).n == s["n_trials"] for p in parts)  # remeasured: all measured
    assert run.outcome == "not judged"
    cells = {k: dict(v) for k, v in s["cells"].items()}
    for system, cls in CELLS:
        cell = {m: dict(cells[system][cls][m]) for m in ("ml", "tkl_0")}
        for m in cell:
            cell[m]["multistep_error_per_trial"] = _per_trial(run, system, cls, m)
        cells[system] = {**cells[system], cls: {**cells[system][cls], **cell}}
    full = {**s, "cells": cells}
    for part, (system, cls) in zip(parts, CELLS, strict=True):
        d = np.subtract(
            cells[system][cls]["tkl_0"]["multistep_error_per_trial"],
            cells[system][cls]["ml"]["multistep_error_per_trial"],
        )
        lo, hi = stats.t.interval(0.95, d.size - 1, loc=d.mean(), scale=stats.sem(d))
        r = read(part, full)
        scale = float(np.max(np.abs(d)))
        assert abs(r.estimate - d.mean()) <= fp_tol(d.size, scale=scale)
        assert abs(r.lower - lo) <= fp_tol(4 * d.size, scale=scale)
        assert abs(r.upper - hi) <= fp_tol(4 * d.size, scale=scale)
        assert r.outcome == "undecided"
        # the stored mean is the mean of the per-trial errors
        ml = cells[system][cls]["ml"]
        assert abs(np.mean(ml["multistep_error_per_trial"]) - ml["multistep_error"]) <= fp_tol(
            d.size, scale=ml["multistep_error"]
        )
