"""Experiment registry: every figure/table id of the thesis that skillkit reproduces, at the
scales ``smoke`` (seconds, for tests), ``quick`` (faithful but small) and ``paper`` (the
thesis setting). Importing it imports :mod:`skillkit.experiments`, which registers them all.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from skillkit._validation import check_choice
from skillkit.experiments.settings import Settings, apply_overrides
from skillkit.series import Series, mean_band  # noqa: F401  (re-exported for experiments)

SCALES = ("smoke", "quick", "paper")
"""Settings scales, smallest first."""


@dataclass
class Experiment:
    """A reproducible figure or table of the thesis.

    Attributes
    ----------
    id, title : str
        Thesis id (``"fig3.3"``) and what it shows.
    settings_class, settings : type, dict
        The experiment's :class:`~skillkit.experiments.settings.Settings` class and one
        instance of it per scale.
    run_trial : callable
        ``run_trial(settings, rng, trial) -> dict``, ``trial`` a
        :class:`~skillkit.trial.TrialContext`.
    summarize : callable
        ``summarize(settings, trials) -> (list[Series], dict)``.
    trials : dict
        Default number of trials per scale.
    claim : str
        The claim in plain words (default: the spec's ``plain``).
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
        """The settings of ``scale`` with ``overrides`` applied; ValueError for an unknown
        scale or name or a value of the wrong type."""
        check_choice(scale, "scale", SCALES)
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
