"""Policy search: REPS, GPREPS, PILCO, CrKR, RWR, the peers CMA-ES, C-CMA-ES and BO, and the loop.

Every algorithm holds a ``policy`` (``sample(contexts, rng)``, ``mean_of(contexts)``) and an
``update(batch)`` taking one :class:`Batch` and returning diagnostics, so
:func:`~skillkit.search.loop.learn` runs any of them.
"""

from skillkit.search.base import Batch, extra_context_importance
from skillkit.search.ccmaes import CCMAES, CCMAESDiagnostics, CCMAESSettings
from skillkit.search.crkr import CrKR, CrKRDiagnostics, CrKRPolicy
from skillkit.search.gpreps import (
    GPREPS,
    DirectRewardModel,
    GPREPSDiagnostics,
    GPREPSSettings,
    KnownRewardModel,
    TrajectoryRewardModel,
)
from skillkit.search.loop import Evaluator, LoopState, collect, learn
from skillkit.search.pilco import PILCO, PILCODiagnostics, PILCOSettings
from skillkit.search.reps import (
    ContextualREPS,
    REPSDiagnostics,
    REPSWeights,
    reps_dual,
    reps_weights,
)
from skillkit.search.rwr import RWR, RWRDiagnostics, rwr_beta, rwr_weighting, rwr_weights

#: Imported on first use (PEP 562): BoTorch is slow to import and ``cma`` imports pyplot.
_LAZY = {
    "CMAES": "skillkit.search.cmaes",
    "CMAESDiagnostics": "skillkit.search.cmaes",
    "CMAESPolicy": "skillkit.search.cmaes",
    "CBODiagnostics": "skillkit.search.cbo",
    "CBOPolicy": "skillkit.search.cbo",
    "CBOSettings": "skillkit.search.cbo",
    "ContextualBO": "skillkit.search.cbo",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'skillkit.search' has no attribute {name!r}")


__all__ = [
    "CCMAES",
    "CCMAESDiagnostics",
    "CCMAESSettings",
    "CMAES",
    "CBODiagnostics",
    "CBOPolicy",
    "CBOSettings",
    "CMAESDiagnostics",
    "CMAESPolicy",
    "ContextualBO",
    "RWR",
    "Batch",
    "Evaluator",
    "LoopState",
    "ContextualREPS",
    "CrKR",
    "CrKRDiagnostics",
    "CrKRPolicy",
    "DirectRewardModel",
    "GPREPS",
    "GPREPSDiagnostics",
    "GPREPSSettings",
    "KnownRewardModel",
    "PILCO",
    "PILCODiagnostics",
    "PILCOSettings",
    "REPSDiagnostics",
    "TrajectoryRewardModel",
    "extra_context_importance",
    "REPSWeights",
    "RWRDiagnostics",
    "collect",
    "learn",
    "reps_dual",
    "reps_weights",
    "rwr_beta",
    "rwr_weighting",
    "rwr_weights",
]
