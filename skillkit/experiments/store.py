"""The results store: finished runs under ``runs/`` (or any folder), listed and compared."""

from __future__ import annotations

import json
from pathlib import Path

from skillkit.experiments.registry import Series
from skillkit.experiments.run import load_run


def list_runs(root: str | Path = "runs") -> list[dict]:
    """Every finished run below ``root`` (a folder holding ``result.json``), newest first.

    Files that are not valid JSON or hold no JSON object are skipped; a missing key reads as
    None.

    Returns
    -------
    list of dict
        ``path``, ``id``, ``scale``, ``seed``, ``trials``, ``executor``, ``wall_time_s`` and the
        ``summary`` of each run.
    """
    root = Path(root)
    if not root.exists():
        raise ValueError(f"root: no results folder at {root}")
    runs = []
    for path in sorted(root.rglob("result.json"), key=lambda p: p.stat().st_mtime, reverse=True):
        try:
            r = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(r, dict):  # some other tool's result.json: not a run
            continue
        runs.append(
            {
                "path": str(path.parent),
                "id": r.get("id"),
                "scale": r.get("scale"),
                "seed": r.get("seed"),
                "trials": r.get("trials"),
                "executor": r.get("executor", "local"),
                "wall_time_s": r.get("wall_time_s"),
                "summary": r.get("summary", {}),
            }
        )
    return runs


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def compare(
    path_a: str | Path, path_b: str | Path
) -> tuple[list[tuple[str, object, object]], dict]:
    """Two runs side by side.

    Returns
    -------
    rows : list of (key, value_a, value_b)
        The flattened ``summary`` entries of both runs, plus their settings, trial count,
        executor, workers, resumed trials and wall time.
    result : dict
        A result-like dict whose series overlay both runs' curves (names suffixed `` [A]``
        and `` [B]``), ready for :func:`skillkit.viz.plots.write_figures`.
    """
    a, b = load_run(path_a).result, load_run(path_b).result
    run_keys = ("trials", "executor", "workers", "resumed_trials", "wall_time_s")
    fa, fb = (
        _flatten(
            {
                "summary": r.get("summary", {}),
                "settings": r.get("settings", {}),
                **{k: r.get(k) for k in run_keys},
            }
        )
        for r in (a, b)
    )
    rows = [(k, fa.get(k), fb.get(k)) for k in sorted(set(fa) | set(fb))]
    series = []
    for tag, r in (("A", a), ("B", b)):
        for s in r.get("series", []):
            fields = {k: v for k, v in s.items() if k in Series.__dataclass_fields__}
            fields["name"] = f"{s['name']} [{tag}]"
            series.append(fields)
    merged = {
        "id": f"{a.get('id')} vs {b.get('id')}",
        "title": "comparison",
        "scale": "",
        "series": series,
    }
    return rows, merged
