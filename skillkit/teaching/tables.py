"""Tables for the notebooks (pandas): the chapter's claims beside our verdicts.

>>> claims_table(["fig3.3", "fig3.5"])          # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Iterable


def _known(ids: str | Iterable[str]) -> list[str]:
    """``ids`` as a list, or a ``ValueError`` naming the unregistered ones."""
    from skillkit.experiments.registry import ids as registered

    ids = [ids] if isinstance(ids, str) else list(ids)
    unknown = sorted(set(ids) - set(registered()))
    if unknown:
        raise ValueError(f"ids: unknown experiment id(s) {unknown}")
    return ids


def claims_table(ids: Iterable[str] | None = None, root=None):
    """The README scoreboard's rows (:func:`skillkit.experiments.run.claim_rows`) of ``ids``
    (default all) under ``root``: claim, verdict, ours [95% interval], thesis, made by."""
    import pandas as pd

    from skillkit.experiments.run import claim_rows

    rows = claim_rows(root, None if ids is None else _known(ids))
    names = [f"{r['id']} ({r['variant']})" if r["variant"] else r["id"] for r in rows]
    columns = {"claim": "claim", "verdict": "verdict", "ours [95% interval]": "ours"}
    columns |= {"thesis": "thesis", "made by": "made"}
    data = {column: [r[key] for r in rows] for column, key in columns.items()}
    return pd.DataFrame(data, index=pd.Index(names, name="id"))


def live_run_times(ids: Iterable[str], scale: str):
    """How long re-running ``ids`` at ``scale`` takes (measured, or the stored paper run's
    trial times), a row per id and ``all``: ``seconds`` (NaN: unknown) and ``expected``."""
    import json

    import numpy as np
    import pandas as pd

    from skillkit._validation import check_choice
    from skillkit.experiments import timings
    from skillkit.experiments.registry import SCALES
    from skillkit.experiments.run import stored_run

    check_choice(scale, "scale", list(SCALES))
    ids = _known(ids)
    seconds = []
    for exp_id in ids:
        value = timings.measured_seconds(exp_id, scale) if scale != "paper" else None
        if scale == "paper":
            try:
                result = json.loads((stored_run(exp_id).path / "result.json").read_text())
                value = float(np.sum(result.get("trial_time_s") or np.nan))
            except (FileNotFoundError, ValueError, TypeError):
                value = None
        seconds.append(np.nan if value is None or not np.isfinite(value) else value)
    total = float(np.nansum(seconds)) if not np.all(np.isnan(seconds)) else np.nan
    words = [timings.format_seconds(None if np.isnan(s) else s) for s in [*seconds, total]]
    table = pd.DataFrame(
        {"id": [*ids, "all"], "seconds": [*seconds, total], "expected": words}
    ).set_index("id")
    table.attrs["machine"] = timings.machine_note()
    return table


def experiments_table():
    """Every registered experiment: title, trials per scale, smoke and quick wall times."""
    import pandas as pd

    from skillkit.experiments import timings
    from skillkit.experiments.registry import SCALES, get, ids

    rows, scales = [], ("smoke", "quick")
    for exp_id in ids():
        exp = get(exp_id)
        trials = " / ".join(str(exp.trials[s]) for s in SCALES)
        rows.append(
            {
                "id": exp_id,
                "title": exp.title,
                "trials (smoke / quick / paper)": trials,
                **{s: timings.format_seconds(timings.measured_seconds(exp_id, s)) for s in scales},
            }
        )
    return pd.DataFrame(rows).set_index("id")


def method_comparison_table(run):
    """A ``cmp.methods`` run's README rows, one per (task, method)."""
    import pandas as pd

    from skillkit.experiments.run import comparison_rows

    if run.id != "cmp.methods":
        raise ValueError(f"run: expected a cmp.methods run, got {run.id!r}")
    return pd.DataFrame(comparison_rows(run.summary)).set_index(["task", "method"]).fillna("")
