"""A toy contextual task with a known optimum, for tests, benchmarks and teaching (not
registered; :class:`~skillkit.experiments.sanity.LinearOptimumTask` is its 3-D relative)."""

from __future__ import annotations

import numpy as np

from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.tasks.base import Task
from skillkit.trajectory import Trajectory

__all__ = ["LinearTarget"]


class LinearTarget(Task):
    """R(s, ω) = −‖ω − g s‖² on s ∈ [−1, 1]², ω ∈ R²: the optimal policy mean is ω = g s.

    The trajectory is ω itself and does not depend on s (re-scorable, Sec. 3.4).
    ``gain`` is g.
    """

    name = "linear-target"
    context_dim = 2
    parameter_dim = 2
    context_low = np.array([-1.0, -1.0])
    context_high = np.array([1.0, 1.0])
    trajectory_depends_on_context = False

    def __init__(self, gain: float = 2.0) -> None:
        if not np.isfinite(gain):
            raise ValueError(f"gain: expected a finite number, got {gain!r}")
        self.gain = float(gain)

    def _simulate(self, omega, context, rng) -> Trajectory:
        return Trajectory(np.zeros(1), omega[None, :], np.zeros((1, 0)))

    def _reward(self, trajectory, context) -> float:
        return float(-np.sum((trajectory.states[0] - self.gain * context) ** 2))

    def initial_policy(self) -> LinearGaussianPolicy:
        """N(ω | 0, I), zero gain."""
        return LinearGaussianPolicy(np.zeros(2), np.eye(2), context_dim=2)
