"""Experiment registry: every figure/table id of the thesis that skillkit reproduces.

An :class:`Experiment` is data plus two functions, so the runner (and later executors) can
run trials anywhere:

* ``run_trial(settings, rng, progress) -> dict`` runs one independent trial and returns
  JSON-able numbers and numpy arrays (curves, errors, ...); ``progress`` is the trial's
  :class:`~skillkit.trial.TrialContext` (progress bar and mid-trial checkpoints).
* ``summarize(settings, trials) -> (series, summary)`` turns the list of trial results into
  the plotted :class:`Series` and a ``summary`` dict of headline numbers (with the thesis's
  claims and whether they hold here).

Settings come in two scales: ``quick`` (faithful but small, minutes on 2 cores) and
``paper`` (the thesis setting).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

SCALES = ("quick", "paper")


@dataclass
class Series:
    """One plotted series.

    Attributes
    ----------
    name : str
        Legend label.
    x, y : list of float
        Coordinates (for ``kind="heatmap"``: the grid axes, with values in ``z``).
    panel : str
        Subplot the series belongs to (series with the same panel share axes).
    kind : {"line", "markers", "lines+markers", "heatmap", "bar"}
        How to draw it.
    lower, upper : list of float, optional
        A band around ``y`` (e.g. mean ± std or a 95% interval).
    band : str, optional
        What the band is, in words (e.g. ``"mean ± std over 20 trials"``, ``"95% interval of
        the mean"``); figures show it in the legend. None: the band is drawn unlabelled.
    z : list of list of float, optional
        Heatmap values, shape (len(y), len(x)).
    xlabel, ylabel : str
        Axis labels of the panel.
    log_x, log_y : bool
        Logarithmic axes.
    zmin, zmax : float, optional
        Colour range of a heatmap (give panels compared by eye the same range).
    """

    name: str
    x: list
    y: list
    panel: str = ""
    kind: str = "line"
    lower: list | None = None
    upper: list | None = None
    band: str | None = None
    z: list | None = None
    xlabel: str = ""
    ylabel: str = ""
    log_x: bool = False
    log_y: bool = False
    zmin: float | None = None
    zmax: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}


@dataclass
class Experiment:
    """A reproducible figure or table of the thesis.

    Attributes
    ----------
    id : str
        Thesis id, e.g. ``"fig3.3"``.
    title : str
        What it shows.
    settings : dict
        ``{"quick": {...}, "paper": {...}}``: JSON-able settings per scale.
    run_trial : callable
        ``run_trial(settings, rng, progress) -> dict`` (one independent trial; ``progress``
        is a :class:`~skillkit.trial.TrialContext`: ``reset(total=...)``, ``update()``, and
        ``save``/``resume`` for mid-trial checkpoints).
    summarize : callable
        ``summarize(settings, trials) -> (list[Series], dict)``.
    trials : dict
        Default number of trials per scale.
    claim : str
        The thesis's claim the experiment checks, in one sentence.
    """

    id: str
    title: str
    settings: dict[str, dict]
    run_trial: Callable[..., dict]
    summarize: Callable[..., tuple[list[Series], dict]]
    trials: dict[str, int] = field(default_factory=lambda: {"quick": 1, "paper": 1})
    claim: str = ""

    def settings_for(self, scale: str, **overrides) -> dict:
        if scale not in SCALES:
            raise ValueError(f"scale: expected one of {SCALES}, got {scale!r}")
        s = dict(self.settings[scale])
        for k, v in overrides.items():
            if k not in s:
                raise ValueError(
                    f"{k}: not a setting of experiment {self.id!r} (settings: {sorted(s)})"
                )
            s[k] = v
        return s


_EXPERIMENTS: dict[str, Experiment] = {}


def register(experiment: Experiment) -> Experiment:
    """Add an experiment to the registry (ids are unique)."""
    if experiment.id in _EXPERIMENTS:
        raise ValueError(f"id: experiment {experiment.id!r} is already registered")
    for scale in SCALES:
        if scale not in experiment.settings:
            raise ValueError(f"settings: experiment {experiment.id!r} lacks the {scale!r} scale")
    _EXPERIMENTS[experiment.id] = experiment
    return experiment


def get(exp_id: str) -> Experiment:
    """The experiment registered under ``exp_id``."""
    _load_all()
    if exp_id not in _EXPERIMENTS:
        raise ValueError(f"id: unknown experiment {exp_id!r}; known: {', '.join(ids())}")
    return _EXPERIMENTS[exp_id]


def ids() -> list[str]:
    """All registered experiment ids, in thesis order."""
    _load_all()

    def key(i: str):
        head = "".join(c for c in i if c.isalpha())
        nums = [
            int(p) if p.isdigit() else 0
            for p in "".join(c if c.isdigit() else " " for c in i).split()
        ]
        return (nums, head)

    return sorted(_EXPERIMENTS, key=key)


def _load_all() -> None:
    # Importing the chapter modules registers their experiments.
    import skillkit.experiments  # noqa: F401


def mean_band(curves: np.ndarray, kind: str = "std") -> tuple[list, list, list]:
    """Mean and a band over trials for curves of shape (n_trials, n_points).

    ``kind="std"`` gives mean ± one standard deviation; ``kind="ci95"`` the 95% interval of
    the mean (normal approximation).
    """
    curves = np.asarray(curves, dtype=float)
    m = curves.mean(axis=0)
    sd = curves.std(axis=0, ddof=1) if curves.shape[0] > 1 else np.zeros_like(m)
    half = sd if kind == "std" else 1.96 * sd / np.sqrt(max(curves.shape[0], 1))
    return m.tolist(), (m - half).tolist(), (m + half).tolist()
