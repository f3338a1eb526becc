"""Experiment registry: every figure/table id of the thesis that skillkit reproduces.

An :class:`Experiment` is data plus three functions, so the runner (and its executors) can
run trials anywhere:

* ``run_trial(settings, rng, trial) -> dict`` runs one independent trial and returns
  JSON-able numbers and numpy arrays (curves, errors, ...); ``trial`` is the trial's
  :class:`~skillkit.trial.TrialContext` (progress bar and mid-trial checkpoints).
* ``summarize(settings, trials) -> (series, summary)`` turns the list of trial results into
  the plotted :class:`Series` and a ``summary`` dict of headline numbers, which always
  starts with the experiment's :class:`Verdict` (``claim``, ``holds``, ``statement``).
* ``verdict(settings, summary) -> Verdict`` computes that verdict from the summary's numbers
  alone, so stored results can be re-judged without recomputing.

``settings`` is an instance of the experiment's frozen settings dataclass
(:mod:`skillkit.experiments.settings`), one per scale: ``smoke`` (seconds, for tests and
notebook CI), ``quick`` (faithful but small, minutes on 2 cores) and ``paper`` (the thesis
setting).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skillkit.experiments.settings import Settings, apply_overrides
from skillkit.viz.series import Series, mean_band  # noqa: F401  (re-exported for experiments)

SCALES = ("smoke", "quick", "paper")
"""Settings scales, smallest first."""


@dataclass(frozen=True)
class Verdict:
    """Whether the thesis's claim holds in a run: the first three keys of every ``summary``.

    Attributes
    ----------
    claim : str
        The thesis's claim, in words (with its section or figure).
    holds : bool or None
        True or False as the run's numbers say; None where the experiment makes no claim
        that numbers could decide.
    statement : str
        One sentence with our numbers beside the thesis's.
    """

    claim: str
    holds: bool | None
    statement: str

    def __post_init__(self) -> None:
        if not isinstance(self.claim, str) or not self.claim.strip():
            raise ValueError("claim: expected a non-empty string")
        if isinstance(self.holds, np.bool_):
            object.__setattr__(self, "holds", bool(self.holds))
        if not (self.holds is None or isinstance(self.holds, bool)):
            raise ValueError(f"holds: expected True, False or None, got {self.holds!r}")
        if not isinstance(self.statement, str) or not self.statement.strip():
            raise ValueError("statement: expected a non-empty string")

    def as_dict(self) -> dict[str, Any]:
        """``{"claim": ..., "holds": ..., "statement": ...}``."""
        return {"claim": self.claim, "holds": self.holds, "statement": self.statement}


VERDICT_KEYS = ("claim", "holds", "statement")


def fmt(value: Any, spec: str = ".3g") -> str:
    """A number for a verdict's statement: ``format(value, spec)``, or ``"n/a"`` for a
    missing value (None, as NaN is stored in ``result.json``, or NaN itself)."""
    if value is None or (isinstance(value, (float, np.floating)) and not np.isfinite(value)):
        return "n/a"
    return format(value, spec)


def with_verdict(summary: Mapping[str, Any], verdict: Verdict) -> dict[str, Any]:
    """``summary`` with the verdict's keys first (replacing any earlier ones)."""
    rest = {k: v for k, v in summary.items() if k not in VERDICT_KEYS}
    return {**verdict.as_dict(), **rest}


@dataclass
class Experiment:
    """A reproducible figure or table of the thesis.

    Attributes
    ----------
    id : str
        Thesis id, e.g. ``"fig3.3"``.
    title : str
        What it shows.
    settings_class : type
        The experiment's frozen :class:`~skillkit.experiments.settings.Settings` dataclass.
    settings : dict
        ``{"smoke": ..., "quick": ..., "paper": ...}``: one instance of ``settings_class``
        per scale.
    run_trial : callable
        ``run_trial(settings, rng, trial) -> dict`` (one independent trial; ``trial`` is a
        :class:`~skillkit.trial.TrialContext`: ``reset(total=...)``, ``update()``, and
        ``save``/``resume`` for mid-trial checkpoints).
    summarize : callable
        ``summarize(settings, trials) -> (list[Series], dict)``; the dict starts with
        ``verdict(settings, summary)``'s keys.
    verdict : callable
        ``verdict(settings, summary) -> Verdict``, a function of the summary's numbers.
    trials : dict
        Default number of trials per scale.
    claim : str
        The thesis's claim the experiment checks (the verdict's ``claim``).
    own_checks : callable, optional
        ``own_checks(settings, summary) -> dict``: our conditions beyond the thesis's
        sentences (name → :func:`~skillkit.experiments.claims.own_check`), from the summary's
        numbers alone, as ``summarize`` stores them in ``summary["own_checks"]``; shown beside
        the verdict, never deciding it. Kept here so a stored summary can be checked again
        (``data/migrate_summaries.py``). None: the experiment has none.
    """

    id: str
    title: str
    settings_class: type[Settings]
    settings: dict[str, Settings]
    run_trial: Callable[..., dict]
    summarize: Callable[..., tuple[list[Series], dict]]
    verdict: Callable[[Settings, dict], Verdict]
    trials: dict[str, int] = field(default_factory=lambda: dict.fromkeys(SCALES, 1))
    claim: str = ""
    own_checks: Callable[[Settings, dict], dict] | None = None

    def settings_for(self, scale: str, **overrides) -> Settings:
        """The settings of ``scale`` with ``overrides`` applied, names and types checked.

        Raises
        ------
        ValueError
            An unknown scale, an unknown setting name (the message lists the valid ones) or
            a value of the wrong type (the message names the field and the expected type).
        """
        if scale not in SCALES:
            raise ValueError(f"scale: expected one of {SCALES}, got {scale!r}")
        try:
            return apply_overrides(self.settings[scale], overrides)
        except ValueError as exc:
            raise ValueError(f"{exc} [experiment {self.id!r}]") from None

    def overrides(self, scale: str, settings: Settings) -> dict[str, Any]:
        """The fields in which ``settings`` differ from the ``scale``'s (as plain values)."""
        base, ours = self.settings[scale].to_dict(), settings.to_dict()
        return {k: v for k, v in ours.items() if base[k] != v}


_EXPERIMENTS: dict[str, Experiment] = {}


def register(experiment: Experiment) -> Experiment:
    """Add an experiment to the registry (ids are unique; every scale has settings of the
    experiment's settings class and a default trial count)."""
    if experiment.id in _EXPERIMENTS:
        raise ValueError(f"id: experiment {experiment.id!r} is already registered")
    cls = experiment.settings_class
    if not (isinstance(cls, type) and issubclass(cls, Settings)):
        raise ValueError(f"settings_class: experiment {experiment.id!r} needs a Settings class")
    for scale in SCALES:
        if not isinstance(experiment.settings.get(scale), cls):
            raise ValueError(
                f"settings: experiment {experiment.id!r} lacks {cls.__name__} settings for "
                f"the {scale!r} scale"
            )
        if int(experiment.trials.get(scale, 0)) < 1:
            raise ValueError(
                f"trials: experiment {experiment.id!r} lacks a trial count for {scale!r}"
            )
    if not experiment.claim:
        raise ValueError(f"claim: experiment {experiment.id!r} states no claim")
    _EXPERIMENTS[experiment.id] = experiment
    return experiment


def get(exp_id: str) -> Experiment:
    """The experiment registered under ``exp_id``."""
    _load_all()
    if exp_id not in _EXPERIMENTS:
        raise ValueError(f"id: unknown experiment {exp_id!r}; known: {', '.join(ids())}")
    return _EXPERIMENTS[exp_id]


def ids() -> list[str]:
    """All registered experiment ids, in thesis order; ids without a number (experiments
    beyond the thesis, such as ``cmp.methods``) last."""
    _load_all()

    def key(i: str):
        head = "".join(c for c in i if c.isalpha())
        nums = [
            int(p) if p.isdigit() else 0
            for p in "".join(c if c.isdigit() else " " for c in i).split()
        ]
        return (not nums, nums, head)

    return sorted(_EXPERIMENTS, key=key)


def _load_all() -> None:
    # Importing the chapter modules registers their experiments.
    import skillkit.experiments  # noqa: F401
