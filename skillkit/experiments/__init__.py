"""Thesis experiments: one module per chapter, each registering its figure/table ids."""

from skillkit.experiments.registry import (
    SCALES,
    Experiment,
    Series,
    get,
    ids,
    register,
)
from skillkit.experiments.run import Run, load_run, stored_run
from skillkit.experiments.runner import reproduce, run_trials
from skillkit.experiments.settings import Settings, setting

# Chapter modules register their experiments on import (one line per module).
from skillkit.experiments import ch2  # noqa: E402,F401  isort: skip
from skillkit.experiments import sanity  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch3_throwing  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch3_table_tennis  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch3_hockey  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch2_gp  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch4_models  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch4_stochastic  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch4_gpreps  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch4_events  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch4_table_tennis  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch4_balancing  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch4_trajectory_kl  # noqa: E402,F401  isort: skip
from skillkit.experiments import ch5  # noqa: E402,F401  isort: skip
from skillkit.experiments import cmp_methods  # noqa: E402,F401  isort: skip

__all__ = [
    "SCALES",
    "Experiment",
    "Run",
    "Series",
    "Settings",
    "get",
    "ids",
    "load_run",
    "register",
    "reproduce",
    "run_trials",
    "setting",
    "stored_run",
]
