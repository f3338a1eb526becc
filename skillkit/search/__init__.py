"""Policy search: REPS (episode-based and contextual), CrKR, RWR and the model-free learning loop.

Every algorithm holds a current ``policy`` (with ``sample(contexts, rng)`` and
``mean_of(contexts)``) and an ``update(contexts, omegas, rewards)`` returning diagnostics, so
:func:`skillkit.search.loop.learn` runs any of them.
"""

from skillkit.search.crkr import CrKR, CrKRDiagnostics, CrKRPolicy
from skillkit.search.loop import learn
from skillkit.search.reps import (
    ContextualREPS,
    REPSDiagnostics,
    REPSWeights,
    reps_dual,
    reps_weights,
)
from skillkit.search.rwr import RWR, RWRDiagnostics, rwr_beta, rwr_weighting, rwr_weights

__all__ = [
    "RWR",
    "ContextualREPS",
    "CrKR",
    "CrKRDiagnostics",
    "CrKRPolicy",
    "REPSDiagnostics",
    "REPSWeights",
    "RWRDiagnostics",
    "learn",
    "reps_dual",
    "reps_weights",
    "rwr_beta",
    "rwr_weighting",
    "rwr_weights",
]
