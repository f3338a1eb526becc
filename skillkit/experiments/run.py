"""A finished experiment run (:class:`Run`), as :func:`~skillkit.experiments.runner.reproduce`
returns it and :func:`load_run` reads it back, and the tables made of the stored runs."""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skillkit.experiments import judge


@dataclass(frozen=True)
class Run:
    """One finished run: its folder ``path`` and parsed ``result.json``; draws its figure,
    shows itself in Jupyter as a card (claim, verdict, key number) and is path-like."""

    path: Path
    result: dict = field(repr=False)

    @property
    def id(self) -> str:
        return str(self.result.get("id", ""))

    @property
    def title(self) -> str:
        return str(self.result.get("title", ""))

    @property
    def scale(self) -> str:
        return str(self.result.get("scale", ""))

    @property
    def settings(self) -> dict:
        return dict(self.result.get("settings", {}))

    @property
    def series(self) -> list[dict]:
        return list(self.result.get("series", []))

    @property
    def summary(self) -> dict:
        return dict(self.result.get("summary", {}))

    @property
    def holds(self) -> bool | None:
        return self.summary.get("holds")

    @property
    def judgement(self):
        """The :class:`~skillkit.experiments.judge.Judgement` of this run (None: not judged)."""
        if not judge.is_judged(self.id):
            return None
        return judge.judge(self.id, self.summary, self.scale, self.settings)

    @property
    def outcome(self) -> str:
        """ "holds", "does not hold", "undecided", "not judged" or "no verdict recorded"."""
        j = self.judgement
        return "no verdict recorded" if j is None else j.outcome

    @property
    def verdict(self) -> str:
        """The card's second line: key number, 95% interval, the thesis's, outcome."""
        j = self.judgement
        if j is not None:
            return j.verdict_line()
        statement = self.summary.get("statement")  # an id the claims spec does not judge
        return statement if isinstance(statement, str) and statement else "no verdict recorded"

    @property
    def card(self) -> str:
        """The claims engine's card (:meth:`~skillkit.experiments.judge.Judgement.card`)."""
        j = self.judgement
        if j is not None:
            return j.card()
        claim = self.summary.get("claim")
        return f"{self.id}: {claim if isinstance(claim, str) else self.title}\n{self.verdict}"

    def details(self) -> str:
        """Markdown: the judgement's details and which code made the run."""
        j = self.judgement
        body = "" if j is None else j.details()
        git = self.result.get("git") or {}
        made = f"made by {(git.get('commit') or '?')[:7]}"
        stale = self.stale
        made += f"; **stale**: {stale}" if stale else ""
        return (
            f"{body}\n\n{self.scale} scale, {self.result.get('trials')} trial(s), seed "
            f"{self.result.get('seed')}; {made}; `{self.path}`\n"
        )

    @property
    def stale(self) -> str | None:
        """Why today's code would not make this run any more
        (:func:`~skillkit.experiments.provenance.staleness`), or None."""
        from skillkit.experiments.provenance import staleness

        stale, reason = staleness(self.result)
        return reason if stale else None

    def figure(self):
        """The plotly figure of the run (claim and verdict in its subtitle)."""
        from skillkit.viz.plots import plotly_figure

        return plotly_figure(self.result)

    def matplotlib_figure(self):
        """The same figure drawn with matplotlib (a ``Figure``; no pyplot state is touched)."""
        from skillkit.viz.plots import matplotlib_figure

        return matplotlib_figure(self.result)

    def png(self):
        """The stored ``figure.png`` as an ``IPython.display.Image``."""
        path = self.path / "figure.png"
        if not path.exists():
            raise FileNotFoundError(f"png: no figure.png in run folder {self.path}")
        from IPython.display import Image

        return Image(filename=str(path))

    def _repr_markdown_(self) -> str:
        card = "  \n".join(self.card.split("\n"))
        stale = self.stale
        warn = f"\n\n*Stale:* {stale}; today's code may give other numbers." if stale else ""
        details = f"<details><summary>details</summary>\n\n{self.details()}\n</details>"
        return f"{card}{warn}\n\n{details}\n"

    def __repr__(self) -> str:
        return f"Run({self.id!r}, scale={self.scale!r}, {self.verdict!r}, path='{self.path}')"

    def __fspath__(self) -> str:
        return os.fspath(self.path)

    def __truediv__(self, other) -> Path:
        return self.path / other


def load_run(path: str | os.PathLike) -> Run:
    """Read a run folder (or its ``result.json``), judged by today's claims spec.

    Raises
    ------
    FileNotFoundError
        No ``result.json`` at ``path``.
    ValueError
        ``result.json`` is not a JSON object.
    """
    p = Path(path)
    folder = p.parent if p.name == "result.json" else p
    file = folder / "result.json"
    if not file.exists():
        raise FileNotFoundError(f"path: no result.json in {folder}")
    try:
        result = json.loads(file.read_text())
    except ValueError as exc:
        raise ValueError(f"path: {file} is not valid JSON ({exc})") from None
    if not isinstance(result, dict):
        raise ValueError(
            f"path: {file} holds no run (expected a JSON object, got {type(result).__name__})"
        )
    return Run(folder, rejudged(result))


def rejudged(result: dict) -> dict:
    """``result`` with its summary judged again by today's claims spec."""
    summary = result.get("summary")
    if not isinstance(summary, dict):
        return result
    settings = result.get("settings") if isinstance(result.get("settings"), dict) else {}
    exp_id, scale = str(result.get("id", "")), str(result.get("scale", ""))
    summary = judge.apply(summary, exp_id, scale, settings)
    claim = summary.get("claim", result.get("claim"))
    return {**result, **({"claim": claim} if "claim" in result else {}), "summary": summary}


def results_root() -> Path:
    """The folder named by ``SKILLKIT_RESULTS``, else the repository's ``data/results``."""
    env = os.environ.get("SKILLKIT_RESULTS")
    candidates = [Path(env)] if env else []
    candidates.append(Path(__file__).resolve().parents[2] / "data" / "results")
    for c in candidates:
        if c.is_dir():
            return c
    raise FileNotFoundError(
        "results: no data/results folder found (looked in "
        + ", ".join(str(c) for c in candidates)
        + "); set SKILLKIT_RESULTS to a folder of stored runs"
    )


def stored_run(exp_id: str, scale: str = "paper", seed: int = 0) -> Run:
    """The stored run of ``exp_id`` in :func:`results_root`."""
    folder = results_root() / f"{exp_id}-{scale}-s{seed}"
    if not (folder / "result.json").exists():
        raise FileNotFoundError(f"exp_id: no stored {scale}-scale run of {exp_id!r} in {folder}")
    return load_run(folder)


def claim_rows(root: str | os.PathLike | None = None, ids: Any = None) -> list[dict[str, Any]]:
    """The stored results' claims and verdicts, one dict per ``result.json``, in thesis order.

    Parameters
    ----------
    root : path, optional
        Folder searched for ``result.json`` files (default :func:`results_root`).
    ids : iterable of str, optional
        Only these experiment ids (default: all).

    Returns
    -------
    list of dict
        ``id``, ``variant`` (overridden settings), ``claim``, ``verdict``, ``ours`` (key
        reading with its interval), ``thesis``, ``card``, ``made`` (commit and status),
        ``stale`` and ``path``.
    """
    from skillkit.experiments.provenance import check_results
    from skillkit.experiments.registry import ids as registered

    root = Path(root) if root is not None else results_root()
    wanted = None if ids is None else {str(i) for i in ids}
    order = {exp_id: i for i, exp_id in enumerate(registered())}
    found = [r for r in check_results(root) if wanted is None or r["id"] in wanted]
    rows = []
    for row in sorted(found, key=lambda r: (order.get(r["id"], len(order)), r["path"])):
        run = load_run(row["path"])
        j = run.judgement
        key = None if j is None else j.key()
        commit = ((run.result.get("git") or {}).get("commit") or "?")[:7]
        overrides = run.result.get("overrides") or {}
        rows.append(
            {
                "id": run.id,
                "variant": ", ".join(f"{k} = {v}" for k, v in overrides.items()),
                "claim": run.summary.get("claim", ""),
                "verdict": run.outcome,
                "ours": "" if key is None else f"{key.part.label} {key.number()}",
                "thesis": "" if key is None else key.part.thesis,
                "card": run.card,
                "made": f"{commit}, {row['status']}",
                "stale": bool(row["stale"]),
                "path": row["path"],
            }
        )
    return rows


COMPARISON_PREFIX = "cmp."
"""Ids of comparisons of ours (no thesis claim; shown by :func:`comparison_markdown`)."""


def comparison_rows(summary: dict) -> list[dict[str, Any]]:
    """One row per task and method of a ``cmp.methods`` summary.

    Returns
    -------
    list of dict
        ``task``, ``method``, ``real rollouts``, ``reward π₀``, ``final reward`` (mean ± std
        over the evaluation rollouts that did not fail, "—" where all failed), ``eval failed``
        (their final share), ``to R ≥ level`` per threshold (rollouts until the mean curve
        reaches it without a failed evaluation, "—" never; trials whose curve did),
        ``compute s`` and ``failed`` (exploration rollouts).
    """
    from skillkit.experiments.cmp_methods import LABELS

    n = summary["n_trials"]
    rows = []
    for task, t in summary["tasks"].items():
        for method, m in t["methods"].items():
            row = {
                "task": task,
                "method": LABELS.get(method, method),
                "real rollouts": _count(m["real_rollouts"]),
                "reward π₀": _num(m["initial_reward"], ".3g"),
                "final reward": _num(m["final_reward_mean"], ".3g")
                + f" ± {m['final_reward_std']:.2g}",
                "eval failed": _num(m.get("final_eval_failure_rate"), ".0%"),
            }
            for level, r in m["thresholds"].items():
                at = r["rollouts_mean_curve"]
                row[f"to R ≥ {level}"] = (
                    "—" if at is None else _count(at)
                ) + f" ({r['n_reached']}/{n})"
            row["compute s"] = f"{m['time_s_mean']:.0f}"
            row["failed"] = str(m["failed_rollouts"])
            rows.append(row)
    return rows


def _num(x: float | None, fmt: str) -> str:
    """``x`` formatted, "—" for None or NaN."""
    return "—" if x is None or not math.isfinite(x) else format(x, fmt)


def _count(x: float) -> str:
    """A count of rollouts: whole numbers in full, other means with one decimal."""
    return f"{round(x):d}" if float(x).is_integer() else f"{x:.1f}"


def comparison_section(run: Run) -> str:
    """README's comparison section of a stored ``cmp.methods`` run: which run, its trials,
    scale and commit (and why it is stale), then :func:`comparison_markdown`."""
    stale = run.stale
    status = f"; **stale**: {stale}" if stale else ""
    return (
        f"Stored: `{run.path.name}` ({run.result['trials']} trials at {run.scale} scale, "
        f"commit {run.result['git']['commit'][:7]}{status}).\n\n"
        + comparison_markdown(run.summary)
        + "\n"
    )


def comparison_markdown(summary: dict) -> str:
    """:func:`comparison_rows` as one Markdown table per task (their thresholds differ), each
    with the threshold's source below it."""
    out, every = [], comparison_rows(summary)
    for task, t in summary["tasks"].items():
        rows = [r for r in every if r["task"] == task]
        cols = [c for c in rows[0] if c != "task"]
        out.append(f"**{task}** (REPS and GPREPS as in {t['thesis_settings']})\n")
        out.append(judge.markdown_row(cols))
        out.append("|" + "---|" * len(cols))
        out.extend(judge.markdown_row([r[c] for c in cols]) for r in rows)
        out.append(f"\nThresholds: {t['thresholds_source']}.\n")
    return "\n".join(out)


def scoreboard(root: str | os.PathLike | None = None) -> str:
    """The README's scoreboard: a Markdown table with one line per stored result
    (:func:`claim_rows`, without ``cmp.*``), ending in a newline."""
    lines = [
        "| id | claim | verdict | ours [95% interval] | thesis | made by |",
        "|---|---|---|---|---|---|",
    ]
    for row in claim_rows(root):
        if row["id"].startswith(COMPARISON_PREFIX):  # not a thesis claim: its own table
            continue
        name = f"{row['id']} ({row['variant']})" if row["variant"] else row["id"]
        verdict = f"**{row['verdict']}**" if row["verdict"] != "not judged" else row["verdict"]
        cells = [name, row["claim"], verdict, row["ours"], row["thesis"], row["made"]]
        lines.append(judge.markdown_row(cells))
    return "\n".join(lines) + "\n"
