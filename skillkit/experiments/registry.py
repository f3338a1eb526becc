"""Experiment registry: every figure/table id of the thesis that skillkit reproduces.

An :class:`Experiment` is data plus three functions, so the runner (and its executors) can
run trials anywhere:

* ``run_trial(settings, rng, trial) -> dict`` runs one independent trial and returns
  JSON-able numbers and numpy arrays (curves, errors, ...); ``trial`` is the trial's
  :class:`~skillkit.trial.TrialContext` (progress bar and mid-trial checkpoints).
* ``summarize(settings, trials) -> (series, summary)`` turns the list of trial results into
  the plotted :class:`Series` and a ``summary`` dict of what was measured (numbers and
  per-trial arrays). How those numbers are judged is data: the claims spec read by
  :mod:`skillkit.experiments.judge`, which puts its verdict in front of the summary.

``settings`` is an instance of the experiment's frozen settings dataclass
(:mod:`skillkit.experiments.settings`), one per scale: ``smoke`` (seconds, for tests and
notebook CI), ``quick`` (faithful but small, minutes on 2 cores) and ``paper`` (the thesis
setting).

The chapter modules register their experiments when they are imported. Importing this module
imports the package :mod:`skillkit.experiments` first, whose ``__init__`` imports every chapter
module, so :func:`get` and :func:`ids` always see all of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from skillkit.experiments.settings import Settings, apply_overrides
from skillkit.series import Series, mean_band  # noqa: F401  (re-exported for experiments)

SCALES = ("smoke", "quick", "paper")
"""Settings scales, smallest first."""


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
        ``summarize(settings, trials) -> (list[Series], dict)``: the plotted series and the
        measurements.
    trials : dict
        Default number of trials per scale.
    claim : str
        The claim in plain words; filled from the claims spec (``plain``) at registration
        when empty. An experiment registered outside this package must give it.
    """

    id: str
    title: str
    settings_class: type[Settings]
    settings: dict[str, Settings]
    run_trial: Callable[..., dict]
    summarize: Callable[..., tuple[list[Series], dict]]
    trials: dict[str, int] = field(default_factory=lambda: dict.fromkeys(SCALES, 1))
    claim: str = ""

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
        from skillkit.experiments.judge import specs

        claim = specs().get(experiment.id)
        if claim is None:
            raise ValueError(f"claim: experiment {experiment.id!r} has no claim in the spec")
        experiment.claim = claim.plain
    _EXPERIMENTS[experiment.id] = experiment
    return experiment


def get(exp_id: str) -> Experiment:
    """The experiment registered under ``exp_id``."""
    if exp_id not in _EXPERIMENTS:
        raise ValueError(f"id: unknown experiment {exp_id!r}; known: {', '.join(ids())}")
    return _EXPERIMENTS[exp_id]


def ids() -> list[str]:
    """All registered experiment ids, in thesis order; ids without a number (experiments
    beyond the thesis, such as ``cmp.methods``) last."""

    def key(i: str):
        head = "".join(c for c in i if c.isalpha())
        nums = [
            int(p) if p.isdigit() else 0
            for p in "".join(c if c.isdigit() else " " for c in i).split()
        ]
        return (not nums, nums, head)

    return sorted(_EXPERIMENTS, key=key)
