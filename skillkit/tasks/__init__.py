"""Robot tasks (Appendix C) behind one contract; see :mod:`skillkit.tasks.base`.

Importing this package registers every task; :func:`make` builds one by name. Your own skill
is a :class:`FunctionTask` (a rollout returning the reward) or a :class:`TrajectoryTask` (one
returning a trajectory), built from a few functions (:mod:`skillkit.tasks.functional`).
"""

from skillkit.tasks.base import ModelSignals, SimulationFailure, Task
from skillkit.tasks.functional import FunctionTask, TrajectoryTask
from skillkit.tasks.registry import make, names, register, tags

# Task modules register themselves on import (one line per module).
from skillkit.tasks import pendulum  # noqa: E402,F401  isort: skip
from skillkit.tasks import hockey  # noqa: E402,F401  isort: skip
from skillkit.tasks import table_tennis  # noqa: E402,F401  isort: skip
from skillkit.tasks import planar  # noqa: E402,F401  isort: skip
from skillkit.tasks import balancing  # noqa: E402,F401  isort: skip

__all__ = [
    "FunctionTask",
    "ModelSignals",
    "SimulationFailure",
    "Task",
    "TrajectoryTask",
    "make",
    "names",
    "register",
    "tags",
]
