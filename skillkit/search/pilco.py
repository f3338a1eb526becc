r"""PILCO (Deisenroth & Rasmussen 2011), the model-based baseline of Table 4.2 (Sec. 4.3.1).

PILCO learns the balancing task's linear feedback u = G (x − x_up) (ω = vec G, row-major,
4 × 8). Each :meth:`PILCO.update` fits a sparse GP (FITC, Sec. 4.2; or a
:class:`~skillkit.models.linear.LinearGaussianModel`) of the dynamics on every real transition,
propagates N(m_0, S_0) by moment matching (Sec. 2.1.2), and maximises the closed-form expected
return (:func:`expected_return`) by L-BFGS-B (:func:`optimize_gain`). The first batch comes
from ``initial_policy``; afterwards the policy is the deterministic, unsquashed G.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize
import torch

from skillkit._repr import number
from skillkit._validation import as_generator, check_array, check_count, check_positive, check_type
from skillkit.models.gp import DTYPE, ForwardModel
from skillkit.models.moment_matching import (
    RoundoffEstimate,
    check_roundoff,
    moment_match_step,
    with_linear_mean,
)
from skillkit.policies.gaussian import GaussianPolicy
from skillkit.search.base import Batch, as_batch, check_settings
from skillkit.search.gpreps import TrajectoryRewardModel

#: ``step(mean_z (D,), cov_z (D, D)) -> (mean_x' (n,), cov_x' (n, n))``, torch float64.
MomentStep = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]


def _sym(S: torch.Tensor) -> torch.Tensor:
    return 0.5 * (S + S.T)


# --------------------------------------------------------------------------- dynamics steps
def model_moment_step(model, roundoff: bool = True) -> MomentStep:
    """The Gaussian transition of a fitted forward model: :class:`GPMomentStep` for a GP, the
    exact :func:`linear_gaussian_step` for a :class:`~skillkit.models.linear.LinearGaussianModel`.
    """
    from skillkit.models.linear import LinearGaussianModel

    if isinstance(model, LinearGaussianModel):
        model._check_fitted()
        return linear_gaussian_step(model.A, model.B, model.noise_cov, model.c)
    return GPMomentStep(model, roundoff)


class GPMomentStep:
    """The moment-matching transition (Sec. 2.1.2) of a fitted GP forward model (SE kernel).

    With a Δx model x' = x + Δ the mean is m_x + E[Δ] and the covariance S_x + cov(Δ) + C + Cᵀ,
    C = cov(x, Δ); a ``mean="linear"`` model's linear part is added exactly. ``roundoff`` keeps
    the largest round-off bound of the steps since construction or :meth:`reset` (``None`` with
    ``roundoff=False``).
    """

    def __init__(self, model: ForwardModel, roundoff: bool = True):
        check_type(model, ForwardModel, "model", "a fitted ForwardModel")
        self.model = model
        self.predictor = model.predictor.to("cpu", DTYPE)
        self.track = bool(roundoff)
        self.roundoff: RoundoffEstimate | None = None

    def reset(self) -> None:
        """Forget the steps taken so far."""
        self.roundoff = None

    def __call__(
        self, mean_z: torch.Tensor, cov_z: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        g = moment_match_step(self.predictor, mean_z, cov_z, strict=True, roundoff=self.track)
        if self.track:
            self.roundoff = RoundoffEstimate.worst([self.roundoff, g.roundoff])
        g = with_linear_mean(self.model, g, mean_z, cov_z)
        if not self.model.delta:
            return g.mean, g.cov
        n_x = self.model.state_dim
        c = g.input_output_cov[:n_x]  # cov(x, Δ)
        return mean_z[:n_x] + g.mean, cov_z[:n_x, :n_x] + g.cov + c + c.T

    def __repr__(self) -> str:
        worst = "none" if self.roundoff is None else f"{self.roundoff.relative_error:.1e}"
        return f"GPMomentStep(model={type(self.model.gp).__name__}, worst round-off {worst})"


def linear_gaussian_step(A, B, noise_cov, offset=None) -> MomentStep:
    """The exact transition of x' = A x + B u + c + w, w ~ N(0, Σ_w): mean [A B] m_z + c,
    covariance [A B] S_z [A B]ᵀ + Σ_w (A (n, n), B (n, m), Σ_w = ``noise_cov`` symmetric PSD,
    c = ``offset`` default 0)."""
    a = check_array(A, "A", ndim=2)
    if a.shape[0] != a.shape[1]:
        raise ValueError(f"A: expected a square matrix, got shape {a.shape}")
    b = check_array(B, "B", shape=(a.shape[0], None))
    w = check_array(noise_cov, "noise_cov", shape=a.shape)
    if np.abs(w - w.T).max() > 1e-12 * (1.0 + np.abs(w).max()):
        raise ValueError("noise_cov: expected a symmetric matrix")
    if np.linalg.eigvalsh(w).min() < -1e-12 * (1.0 + np.abs(w).max()):
        raise ValueError("noise_cov: expected a positive semi-definite matrix")
    F = torch.as_tensor(np.hstack([a, b]), dtype=DTYPE)
    W = torch.as_tensor(w, dtype=DTYPE)
    if offset is not None:
        offset = torch.as_tensor(check_array(offset, "offset", shape=(a.shape[0],)), dtype=DTYPE)

    def step(mean_z: torch.Tensor, cov_z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean = F @ mean_z
        return (mean if offset is None else mean + offset), F @ cov_z @ F.T + W

    return step


# --------------------------------------------------------------------------- the objective
def expected_return(
    step: MomentStep,
    gain: torch.Tensor,
    mean0,
    cov0,
    horizon: int,
    target,
    state_weights,
    control_weight: float = 0.0,
    score_initial: bool = False,
) -> torch.Tensor:
    r"""PILCO's expected return J(G) of the feedback u = G (x − x_target), differentiable in G.

    Propagates N(m_0, S_0) through ``step`` and sums the expected stage rewards

    .. math:: -\mathbb{E}[\tilde x^\top Q \tilde x + r_u u^\top u]
              = -\big(\mathrm{tr}(Q S) + d^\top Q d + r_u(\mathrm{tr}(G S G^\top)
              + \lVert G d\rVert^2)\big)

    over t = 1..T (and t = 0 with ``score_initial``).

    Parameters
    ----------
    step : MomentStep
    gain : Tensor, shape (m, n)
        G, float64.
    mean0, cov0, target, state_weights : array_like
        m_0 (n,), S_0 (n, n), x_target (n,) and Q (n, n).
    horizon : int
        T ≥ 1.
    control_weight : float
        r_u ≥ 0.
    score_initial : bool
    """
    T = check_count(horizon, "horizon", 1)
    if not isinstance(gain, torch.Tensor) or gain.ndim != 2:
        raise ValueError("gain: expected a 2-D torch Tensor G of shape (m, n)")
    n = gain.shape[1]
    m = torch.as_tensor(check_array(mean0, "mean0", shape=(n,)), dtype=DTYPE)
    S = torch.as_tensor(check_array(cov0, "cov0", shape=(n, n)), dtype=DTYPE)
    x_t = torch.as_tensor(check_array(target, "target", shape=(n,)), dtype=DTYPE)
    Q = torch.as_tensor(check_array(state_weights, "state_weights", shape=(n, n)), dtype=DTYPE)
    r_u = check_positive(control_weight, "control_weight", allow_zero=True)
    G = gain.to(DTYPE)

    def stage(m: torch.Tensor, S: torch.Tensor) -> torch.Tensor:
        d = m - x_t
        cost = (Q * S).sum() + d @ Q @ d
        if r_u:
            Gd = G @ d
            cost = cost + r_u * ((G @ S * G).sum() + Gd @ Gd)
        return cost

    total = stage(m, S) if score_initial else torch.zeros((), dtype=DTYPE)
    for _ in range(T):
        SG = S @ G.T
        mean_z = torch.cat([m, G @ (m - x_t)])
        cov_z = torch.cat([torch.cat([S, SG], 1), torch.cat([SG.T, G @ SG], 1)], 0)
        m, S = step(mean_z, _sym(cov_z))
        S = _sym(S)
        total = total + stage(m, S)
        if not bool(torch.isfinite(total)):  # a failed step: later ones cannot be computed
            return -total
    return -total


def optimize_gain(
    objective: Callable[[torch.Tensor], torch.Tensor],
    gain0,
    max_iterations: int = 100,
    tolerance: float = 1e-9,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Maximise ``objective(G)`` by L-BFGS-B from ``gain0`` with torch autograd gradients.

    Returns the best of G₀ and the accepted iterates (never a line-search trial) and ``info``
    (``value0``, ``value``, ``n_iterations``, ``n_evaluations``, ``message``). A non-finite
    objective or a failed Cholesky counts as a very large cost with zero gradient;
    ``tolerance`` is L-BFGS-B's ``ftol``.
    """
    g0 = check_array(gain0, "gain0", ndim=2)
    max_iterations = check_count(max_iterations, "max_iterations", 1)
    check_positive(tolerance, "tolerance")
    shape = g0.shape
    n_eval = 0
    values: dict[bytes, float] = {}

    def fun(flat: np.ndarray) -> tuple[float, np.ndarray]:
        nonlocal n_eval
        n_eval += 1
        G = torch.tensor(flat.reshape(shape), dtype=DTYPE, requires_grad=True)
        try:
            value = objective(G)
        except torch.linalg.LinAlgError:  # a covariance that lost definiteness: no prediction
            value = torch.full((), float("nan"), dtype=DTYPE)
        if not torch.isfinite(value):
            values[flat.tobytes()] = -np.inf
            return 1e300, np.zeros_like(flat)
        (grad,) = torch.autograd.grad(value, G)
        values[flat.tobytes()] = float(value.detach())
        return -values[flat.tobytes()], -grad.numpy().ravel()

    iterates: list[np.ndarray] = []
    res = scipy.optimize.minimize(
        fun,
        g0.ravel(),
        jac=True,
        method="L-BFGS-B",
        callback=lambda xk: iterates.append(np.array(xk)),
        options={"maxiter": max_iterations, "ftol": tolerance, "gtol": 0.0},
    )
    value0 = values[g0.ravel().tobytes()]
    best, best_value = g0.ravel(), value0
    for x in iterates:
        v = values.get(x.tobytes())
        if v is not None and v > best_value:
            best, best_value = x, v
    return best.reshape(shape), {
        "value0": value0,
        "value": best_value,
        "n_iterations": len(iterates),
        "n_evaluations": n_eval,
        "message": str(res.message),
    }


# --------------------------------------------------------------------------- the algorithm
class DeterministicPolicy:
    """A context-free point-mass policy ω = μ, shape (d,): what PILCO learns."""

    context_dim = 0

    def __init__(self, mean):
        self.mean = check_array(mean, "mean", ndim=1)
        self.dim = int(self.mean.shape[0])

    def sample(self, contexts=None, rng=None) -> np.ndarray:
        """μ per context: shape (n, d) for contexts (n, 0), (d,) for ``None``."""
        if contexts is None or np.ndim(contexts) == 1:
            return self.mean.copy()
        contexts = np.asarray(contexts)
        if contexts.ndim != 2 or contexts.shape[1] != 0:
            raise ValueError(f"contexts: expected shape (n, 0), got {contexts.shape}")
        return np.tile(self.mean, (contexts.shape[0], 1))

    #: μ, as :meth:`sample`.
    mean_of = sample

    def __repr__(self) -> str:
        return f"DeterministicPolicy(dim={self.dim})"


@dataclass(frozen=True)
class PILCOSettings:
    """Settings of :class:`PILCO`: L-BFGS-B's iterations per policy optimisation and relative
    ``ftol``, the horizon T of the predicted return (default: the task's ``n_steps``), and
    ``strict``: raise :class:`~skillkit.models.moment_matching.MomentPrecisionError` instead of
    warning when the optimised gain's round-off bound exceeds
    :data:`~skillkit.models.moment_matching.ROUNDOFF_TOL`."""

    policy_iterations: int = 100
    tolerance: float = 1e-9
    horizon: int | None = None
    strict: bool = False

    def __post_init__(self):
        check_count(self.policy_iterations, "policy_iterations", 1)
        check_positive(self.tolerance, "tolerance")
        if self.horizon is not None:
            check_count(self.horizon, "horizon", 1)


@dataclass(frozen=True, repr=False)
class PILCODiagnostics:
    """What one :meth:`PILCO.update` did: the model fit (``n_data`` transitions, ``model_fit``
    statistics), the previous model's J of the gain just rolled out (``None`` at first) against
    the batch's real reward, the new model's J before and after the L-BFGS-B optimisation
    (iterations, evaluations, message), the seconds spent, and the optimised gain's round-off
    bound (``None`` for a linear-Gaussian model)."""

    n_data: int
    model_fit: dict
    predicted_real_reward: float | None
    real_reward: float
    return_before: float
    return_after: float
    n_iterations: int
    n_evaluations: int
    message: str
    time_training: float
    time_policy: float
    roundoff: float | None = None

    def __repr__(self) -> str:
        return (
            f"PILCODiagnostics(n_data={self.n_data}, J {number(self.return_before)} -> "
            f"{number(self.return_after)} in {self.n_iterations} iterations, "
            f"real reward {number(self.real_reward)})"
        )


class PILCO:
    """PILCO for the balancing task: a linear feedback gain optimised through moment matching.

    Parameters
    ----------
    task : Balancing
    initial_policy : GaussianPolicy
        The random policy of the first rollouts over the 32 gains; its mean is the starting gain.
    make_model : callable, optional
        As :class:`~skillkit.search.gpreps.TrajectoryRewardModel`'s.
    settings : PILCOSettings, optional
    rng : Generator, int or None
        The model fits' randomness.
    prior_trajectories : sequence of Trajectory, optional
        Real experience from before learning, learned by every fit.
    """

    def __init__(
        self,
        task,
        initial_policy: GaussianPolicy,
        make_model: Callable[[], Any] | None = None,
        settings: PILCOSettings | None = None,
        rng=None,
        prior_trajectories=(),
    ):
        from skillkit.tasks.balancing import X_UP, Balancing

        check_type(task, Balancing, "task", "a Balancing task")
        if not isinstance(initial_policy, GaussianPolicy) or initial_policy.dim != 32:
            raise ValueError("initial_policy: expected a GaussianPolicy over the 32 gains")
        self.settings = check_settings(settings, PILCOSettings)
        self.task = task
        self.model = TrajectoryRewardModel(
            task, make_model=make_model, prior_trajectories=prior_trajectories
        )
        self.horizon = self.settings.horizon or task.n_steps
        self.mean0 = X_UP.copy()
        self.cov0 = task.initial_std**2 * np.eye(8)
        self._random_policy: GaussianPolicy | None = initial_policy
        self.gain = initial_policy.mean.reshape(4, 8).copy()
        self.trajectories: list = []
        self.rng = as_generator(rng)

    @property
    def policy(self):
        """The random initial policy until the first update, then the learned gain."""
        if self._random_policy is not None:
            return self._random_policy
        return DeterministicPolicy(self.gain.ravel())

    def expected_return(self, gain) -> float:
        """J(G) under the current model for G of shape (4, 8), its round-off checked."""
        value, roundoff = self._predict(gain)
        check_roundoff(roundoff, "PILCO.expected_return", self.settings.strict)
        return value

    def _predict(self, gain, roundoff: bool = True) -> tuple[float, RoundoffEstimate | None]:
        """J(G) and the largest round-off bound of its steps."""
        if self.model.model is None:
            raise RuntimeError("PILCO: call update() before predicting")
        G = torch.as_tensor(check_array(gain, "gain", shape=(4, 8)), dtype=DTYPE)
        step = model_moment_step(self.model.model, roundoff)
        with torch.no_grad():
            value = float(self._objective(step)(G))
        return value, getattr(step, "roundoff", None)

    def _objective(self, step: MomentStep) -> Callable[[torch.Tensor], torch.Tensor]:
        from skillkit.tasks.balancing import X_UP

        task = self.task
        args = (self.mean0, self.cov0, self.horizon, X_UP, task.state_weights, task.control_weight)
        return lambda G: expected_return(step, G, *args)

    def update(self, batch: Batch) -> PILCODiagnostics:
        """Learn the model on all real data, then optimise the gain on it."""
        batch = as_batch(batch, 32, 0)
        if batch.trajectories is None:
            raise ValueError("batch: PILCO learns from trajectories; the batch has none")
        predicted = None
        if self.model.model is not None and self._random_policy is None:
            predicted = self._predict(self.gain, roundoff=False)[0]  # checked when optimised
        self.trajectories.extend(batch.trajectories)

        t0 = time.perf_counter()
        n = len(self.trajectories)
        fit = self.model.fit(
            np.zeros((n, 0)), np.zeros((n, 32)), np.zeros(n), self.trajectories, self.rng
        )
        t1 = time.perf_counter()

        objective = self._objective(model_moment_step(self.model.model, roundoff=False))
        gain, info = optimize_gain(
            objective, self.gain, self.settings.policy_iterations, self.settings.tolerance
        )
        t2 = time.perf_counter()
        roundoff = self._predict(gain)[1]
        check_roundoff(roundoff, "PILCO.update", self.settings.strict)
        self.gain = gain
        self._random_policy = None
        return PILCODiagnostics(
            n_data=int(fit["n_data"]),
            model_fit=fit,
            predicted_real_reward=predicted,
            real_reward=float(np.mean(batch.rewards)),
            return_before=info["value0"],
            return_after=info["value"],
            n_iterations=info["n_iterations"],
            n_evaluations=info["n_evaluations"],
            message=info["message"],
            time_training=t1 - t0,
            time_policy=t2 - t1,
            roundoff=None if roundoff is None else roundoff.relative_error,
        )

    def __repr__(self) -> str:
        state = "random initial policy" if self._random_policy is not None else "learned gain"
        return (
            f"PILCO(task={self.task.name!r}, horizon={self.horizon}, "
            f"{len(self.trajectories)} rollouts, {state})"
        )
