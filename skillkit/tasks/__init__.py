"""Robot tasks (Appendix C) behind one contract; see :mod:`skillkit.tasks.base`.

Importing this package registers every task; :func:`make` builds one by name.
"""

from skillkit.tasks.base import ModelSignals, SimulationFailure, Task
from skillkit.tasks.registry import make, names, register, tags

# Task modules register themselves on import (one line per module).
from skillkit.tasks import pendulum  # noqa: E402,F401  isort: skip
from skillkit.tasks import hockey  # noqa: E402,F401  isort: skip
from skillkit.tasks import table_tennis  # noqa: E402,F401  isort: skip
from skillkit.tasks import planar  # noqa: E402,F401  isort: skip
from skillkit.tasks import balancing  # noqa: E402,F401  isort: skip

__all__ = ["ModelSignals", "SimulationFailure", "Task", "make", "names", "register", "tags"]
