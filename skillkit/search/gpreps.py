r"""Gaussian Process REPS (GPREPS, Sec. 4.1, Table 4.1) and its reward models.

GPREPS is contextual REPS on *artificial* samples. Each :meth:`GPREPS.update` takes a batch of
real rollouts and runs the three steps of Table 4.1:

1. **Train the model** on all real data so far (:meth:`RewardModel.fit`).
2. **Predict rewards**: estimate the context distribution μ̂(s) from the observed contexts
   (a Gaussian, a uniform box, or the task's own μ(s)), draw M contexts s^[j] ~ μ̂(s) and
   parameters ω^[j] ~ π(ω|s^[j]), and predict the expected reward of each pair with the model,

   .. math:: \mathcal{R}_{s\omega}^{[j]} = \frac{1}{L} \sum_{l=1}^{L} R(\tau^{[j,l]}, s^{[j]}),
             \quad \tau^{[j,l]} \sim p_{\text{model}}(\tau \mid \omega^{[j]}, s^{[j]}) \quad (4.1)

3. **Update the policy** with the REPS weights (dual 3.9, weights 3.10) and the weighted
   maximum-likelihood fit (3.11–3.13) on the M artificial samples *only* — the real rewards
   never enter the dual. This is the code path of
   :class:`~skillkit.search.reps.ContextualREPS` itself: GPREPS holds one with
   ``n_reuse_batches=1`` and feeds it a :class:`~skillkit.search.base.Batch` of the artificial
   samples, so model-free REPS and GPREPS share one dual and one fit.

Reward models (:class:`RewardModel`):

* :class:`TrajectoryRewardModel` — a forward model of the task's state (e.g. a sparse GP,
  Sec. 4.2) fitted on the real transitions; rewards from L sampled trajectories per pair
  through the task's own controller and reward (:func:`~skillkit.search.model_rollouts.
  predict_trajectories`, Eqs. 4.1–4.3). For step-based tasks (balancing, pendulum).
* :class:`DirectRewardModel` — "GP direct" (Sec. 4.3.2): one GP from [s, ω] to R, whose mean is
  the predicted expected reward (no trajectories, L unused).
* :class:`KnownRewardModel` — an *oracle for tests*: the true expected reward function, which
  ignores the data. Not a learning method.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import torch

from skillkit._repr import number
from skillkit._validation import as_generator, check_array, check_count, check_positive
from skillkit.models.gp import ExactGP, ForwardModel, GPRegression
from skillkit.models.reward import (
    RewardModel,
    check_sample_dtype,
    gp_stats,
    warm_start_hypers,
)
from skillkit.policies.features import FeatureName, check_feature_name
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.base import Batch, SampleBuffer, as_batch
from skillkit.search.reps import ContextualREPS, REPSDiagnostics
from skillkit.tasks.base import Task
from skillkit.trajectory import Trajectory

__all__ = [
    "CONTEXT_MODELS",
    "DirectRewardModel",
    "GPREPS",
    "GPREPSDiagnostics",
    "GPREPSSettings",
    "KnownRewardModel",
    "RewardModel",
    "TrajectoryRewardModel",
]

ContextModel = Literal["gaussian", "uniform", "prior"]
#: The context distributions μ̂(s) GPREPS can fit (Sec. 4.1).
CONTEXT_MODELS: tuple[str, ...] = ("gaussian", "uniform", "prior")


# --------------------------------------------------------------------------- reward models
class DirectRewardModel(RewardModel):
    r""" "GP direct" (Sec. 4.3.2): a GP regression from z = [s, ω] to the reward R.

    :meth:`expected_rewards` returns the GP's predictive mean E[R | s, ω] (Eq. 2.26), so L is
    not used and no randomness is consumed. Each :meth:`fit` starts the hyper-parameter
    optimisation (2.28) at the previous fit's values (warm start) when ``warm_start``.

    Parameters
    ----------
    gp : ExactGP, FITC or VFE, optional
        The unfitted GP regression to use (default ``ExactGP()``, the thesis's settings). It
        is trained and queried on its own ``device`` (e.g. ``ExactGP(device="cuda")``).
    warm_start : bool
        Start each refit at the previous hyper-parameters.
    """

    def __init__(self, gp: GPRegression | None = None, warm_start: bool = True):
        gp = ExactGP() if gp is None else gp
        if not isinstance(gp, GPRegression):
            raise ValueError(f"gp: expected an ExactGP, FITC or VFE, got {type(gp).__name__}")
        self.gp = gp
        self.warm_start = bool(warm_start)
        self.hyperparameters: dict[str, np.ndarray] | None = None
        self.n_data = 0

    def fit(self, contexts, omegas, rewards, trajectories=None, rng=None) -> dict[str, Any]:
        """Fit the GP on inputs [s_i, ω_i] (N, context_dim + d) and targets R_i (N,).

        Returns
        -------
        dict
            ``n_data``, ``log_ml`` (log marginal likelihood 2.28), ``iterations``,
            ``noise_var_max``, ``numerical_events`` (what the fit handled, by kind).
        """
        s = check_array(contexts, "contexts", ndim=2)
        w = check_array(omegas, "omegas", shape=(s.shape[0], None))
        r = check_array(rewards, "rewards", shape=(s.shape[0],))
        z = np.hstack([s, w])
        if self.warm_start:
            warm_start_hypers(self.gp, self.hyperparameters, z)
        self.gp.fit(z, r, as_generator(rng))
        self.hyperparameters = self.gp.hyperparameters
        self.n_data = int(r.shape[0])
        return gp_stats(self.gp, r.shape[0])

    def expected_rewards(self, contexts, omegas, n_trajectories=1, rng=None) -> np.ndarray:
        """GP mean of R at [s_j, ω_j], shape (M,); ``n_trajectories`` and ``rng`` are unused."""
        s = check_array(contexts, "contexts", ndim=2)
        w = check_array(omegas, "omegas", shape=(s.shape[0], None))
        mean, _ = self.gp.predict(np.hstack([s, w]))
        return np.asarray(mean, dtype=np.float64).reshape(-1)

    def __repr__(self) -> str:
        return f"DirectRewardModel(n_data={self.n_data}, gp={self.gp!r})"


class TrajectoryRewardModel(RewardModel):
    """A learned forward model of the task's state, scored through predicted trajectories.

    :meth:`fit` fits ``make_model()`` (a fresh model each time, warm-started at the previous
    hyper-parameters when it is a :class:`~skillkit.models.gp.ForwardModel`) on
    ``task.transitions`` of every non-failed real trajectory; :meth:`expected_rewards` samples
    L trajectories per pair with :func:`~skillkit.search.model_rollouts.predict_trajectories`
    (start states p(x₀; s) Eq. 4.3, the task's controller and ``reward_batch``; a path the
    task's simulator would stop as failed scores ``task.worst_reward``, as a real rollout does)
    and averages their rewards (Eq. 4.1).

    Parameters
    ----------
    task : Task
        A task with ``supports_model_rollout`` (balancing, pendulum).
    make_model : callable, optional
        ``make_model()`` returns an unfitted forward model with ``fit(states, controls,
        next_states, rng=)`` and the :class:`~skillkit.models.sampling.StepModel` interface
        (default: ``ForwardModel(FITC(n_inducing=100, curb=HyperCurb()))``: x′ targets, the
        sparse GP of Sec. 4.2 with PILCO's hyper-parameter curb). It is
        part of the checkpointed state: use a class or a module-level function (or a
        ``functools.partial`` of one), not a lambda, where checkpoints are taken.
    horizon : int, optional
        T, predicted transitions per trajectory (default: that of the first real trajectory).
    warm_start : bool
        Start each GP refit at the previous hyper-parameters.
    prior_trajectories : sequence of Trajectory, optional
        Real experience collected before the search (e.g. the random-policy rollouts that
        start the models of Sec. 4.3.1); every fit learns their transitions too.
    device : str or torch.device, optional
        Where trajectories are sampled. The forward model is trained on its own GP's
        ``device`` (e.g. a ``make_model`` returning
        ``ForwardModel(FITC(n_inducing=100, device="cuda"))``); give the same device here so
        that the predictor is not copied between devices for sampling.
    dtype : torch.dtype
        Precision of the sampled trajectories: ``torch.float64`` (default) or
        ``torch.float32``, the faster path of
        :func:`~skillkit.models.sampling.sample_trajectories` (its notes give the accuracy);
        rewards are computed in float64 either way.
    common_start_states : bool
        Start the L predicted trajectories of every pair of one :meth:`expected_rewards` call
        from the same L start states x₀ ~ p(x₀) (common random numbers; context-free tasks
        only). Each Eq. (4.1) estimate of E_{x₀}[R | ω] stays unbiased, and the start state's
        effect cancels from the comparison across the M samples — useful where rollouts vary
        more between start states than between nearby parameters (balancing).
    """

    dtype: torch.dtype = torch.float64  # class default for instances pickled without it
    common_start_states: bool = False  # likewise
    #: Fraction of the last :meth:`expected_rewards` call's predicted trajectories that the
    #: task's divergence rule stopped (scored ``task.worst_reward``); None before one.
    last_failed_fraction: float | None = None

    def __init__(
        self,
        task: Task,
        make_model: Callable[[], Any] | None = None,
        horizon: int | None = None,
        warm_start: bool = True,
        device=None,
        prior_trajectories: Sequence[Trajectory] = (),
        dtype: torch.dtype = torch.float64,
        common_start_states: bool = False,
    ):
        if not isinstance(task, Task):
            raise ValueError(f"task: expected a Task, got {type(task).__name__}")
        if not task.supports_model_rollout:
            raise ValueError(
                f"task: {task.name!r} has no step-based model rollouts: "
                f"{task.no_model_rollout_reason}"
            )
        if make_model is not None and not callable(make_model):
            raise ValueError(f"make_model: expected a callable, got {type(make_model).__name__}")
        if horizon is not None:
            check_count(horizon, "horizon")
        if common_start_states and task.context_dim:
            raise ValueError(
                "common_start_states: needs a context-free task (start states depend on the "
                f"context), got {task.name!r} with context_dim={task.context_dim}"
            )
        self.common_start_states = bool(common_start_states)
        self.task = task
        self.make_model = _default_forward_model if make_model is None else make_model
        self.horizon = None if horizon is None else int(horizon)
        self.warm_start = bool(warm_start)
        self.device = device
        self.dtype = check_sample_dtype(dtype)
        self.prior_trajectories = list(prior_trajectories)
        if not all(isinstance(t, Trajectory) for t in self.prior_trajectories):
            raise ValueError("prior_trajectories: expected a sequence of Trajectory objects")
        self.model: Any = None
        self.hyperparameters: dict[str, np.ndarray] | None = None
        self.n_data = 0

    def fit(self, contexts, omegas, rewards, trajectories, rng=None) -> dict[str, Any]:
        """Fit a fresh forward model on the transitions of ``trajectories`` and of the
        ``prior_trajectories``: every working rollout's, and a failed rollout's up to its
        failure where it kept them (:attr:`~skillkit.trajectory.Trajectory.has_transitions`;
        a balancing robot that falls shows the model where a bad gain leads, as PILCO's
        rollouts do).

        Returns
        -------
        dict
            ``n_data`` (transitions), ``n_trajectories``, and for a GP ``log_ml``,
            ``iterations``, ``noise_var_max``, ``numerical_events``.
        """
        if trajectories is None:
            raise ValueError("trajectories: a TrajectoryRewardModel learns from trajectories")
        ok = [t for t in [*self.prior_trajectories, *trajectories] if t.has_transitions]
        if not ok:
            raise ValueError("trajectories: every trajectory failed; nothing to learn from")
        if self.horizon is None:
            whole = [t for t in ok if not t.failed]
            if not whole:
                raise ValueError(
                    "trajectories: every trajectory failed; the horizon of model rollouts "
                    "is unknown (pass horizon=)"
                )
            self.horizon = int(whole[0].states.shape[0] - 1)
        # A trajectory re-scored in extra contexts appears in several rows: learn it once.
        unique = list({id(t): t for t in ok}.values())
        parts = [self.task.transitions(t) for t in unique]
        x, u, xn = (np.concatenate(p) for p in zip(*parts, strict=True))
        model = self.make_model()
        gp = getattr(model, "gp", None)
        if self.warm_start and isinstance(gp, GPRegression):
            warm_start_hypers(gp, self.hyperparameters, np.hstack([x, u]))
        model.fit(x, u, xn, rng=as_generator(rng))
        self.model = model
        stats: dict[str, Any] = {"n_data": int(x.shape[0]), "n_trajectories": len(unique)}
        if isinstance(gp, GPRegression):
            self.hyperparameters = gp.hyperparameters
            stats.update(gp_stats(gp, x.shape[0]))
        self.n_data = int(x.shape[0])
        return stats

    def start_states(self, n_pairs: int, n_trajectories: int, rng) -> np.ndarray:
        """Common start states x₀ (n_pairs, L, n_x): L draws of the task's start distribution,
        the same for every pair (``common_start_states``)."""
        x0 = self.task.initial_states(None, n_trajectories, as_generator(rng))
        return np.repeat(x0[None], n_pairs, axis=0)

    def expected_rewards(self, contexts, omegas, n_trajectories, rng=None) -> np.ndarray:
        """Mean reward of L predicted trajectories per pair (Eq. 4.1), shape (M,); from common
        start states when ``common_start_states`` (drawn from ``rng`` first)."""
        from skillkit.search import model_rollouts

        if self.model is None:
            raise RuntimeError("TrajectoryRewardModel: call fit() before predicting")
        rng = as_generator(rng)
        x0 = None
        if self.common_start_states:
            n_pairs = np.atleast_2d(np.asarray(omegas, dtype=float)).shape[0]
            x0 = self.start_states(n_pairs, n_trajectories, rng)
        out = model_rollouts.predict_trajectories(
            self.task,
            self.model,
            omegas,
            contexts if self.task.context_dim else None,
            horizon=self.horizon,
            n_samples=n_trajectories,
            rng=rng,
            x0=x0,
            device=self.device,
            dtype=self.dtype,
        )
        self.last_failed_fraction = float(out.failed.mean())
        return out.expected_rewards

    def __repr__(self) -> str:
        return (
            f"TrajectoryRewardModel(task={self.task.name!r}, horizon={self.horizon}, "
            f"n_data={self.n_data}, model={'unfitted' if self.model is None else self.model!r})"
        )


def _default_forward_model() -> ForwardModel:
    from skillkit.models.gp import HyperCurb
    from skillkit.models.sparse import FITC

    return ForwardModel(FITC(n_inducing=100, curb=HyperCurb()))


class KnownRewardModel(RewardModel):
    """**Test oracle**, not a learning method: the true expected reward, ignoring the data.

    Parameters
    ----------
    expected_reward : callable
        ``expected_reward(contexts (M, context_dim), omegas (M, d)) -> (M,)``, the exact
        E[R | s, ω] of the system (e.g. −‖ω − a* − A* s‖²_W for
        :class:`~skillkit.experiments.sanity.LinearOptimumTask`).
    """

    def __init__(self, expected_reward: Callable[[np.ndarray, np.ndarray], np.ndarray]):
        if not callable(expected_reward):
            raise ValueError(
                f"expected_reward: expected a callable, got {type(expected_reward).__name__}"
            )
        self.expected_reward = expected_reward

    def fit(self, contexts, omegas, rewards, trajectories=None, rng=None) -> dict[str, Any]:
        """Nothing to learn; returns ``{"n_data": N}``."""
        return {"n_data": int(np.shape(rewards)[0])}

    def expected_rewards(self, contexts, omegas, n_trajectories=1, rng=None) -> np.ndarray:
        """The true E[R | s_j, ω_j], shape (M,)."""
        return np.asarray(self.expected_reward(contexts, omegas), dtype=np.float64).reshape(-1)

    def __repr__(self) -> str:
        return "KnownRewardModel(oracle for tests)"


# --------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class GPREPSSettings:
    """Settings of :class:`GPREPS` (defaults: the thesis's throwing setting, Sec. 4.3.1).

    Attributes
    ----------
    epsilon : float
        KL bound ε > 0 of the REPS update (Eq. 3.4); 1 in the thesis (the dual sees M samples,
        so its Lagrangian parameters are well estimated).
    n_artificial : int
        M ≥ 2, artificial (s, ω) pairs per update (500 in the thesis).
    n_trajectories : int
        L ≥ 1, predicted trajectories per pair averaged in Eq. (4.1) (25 in the thesis;
        unused by :class:`DirectRewardModel`).
    context_model : {"gaussian", "uniform", "prior"}
        μ̂(s): a Gaussian fitted to the observed contexts (mean, covariance), the smallest box
        holding them (uniform), or the task's own μ(s) (``task.sample_context``; needs
        ``task``).
    baseline_features : {"linear", "quadratic"}
        Features φ(s) of the REPS baseline V(s) = γᵀφ(s) (constraint 3.5).
    ridge, cov_shrinkage, cov_floor, min_effective_samples
        Regularisation of the weighted ML fit (3.11–3.13), passed to the same fit as
        :class:`~skillkit.search.reps.ContextualREPS`.
    """

    epsilon: float = 1.0
    n_artificial: int = 500
    n_trajectories: int = 25
    context_model: ContextModel = "gaussian"
    baseline_features: FeatureName = "quadratic"
    ridge: float = 1e-6
    cov_shrinkage: float = 0.0
    cov_floor: float = 1e-4
    min_effective_samples: float | None = None

    def __post_init__(self):
        check_positive(self.epsilon, "epsilon")
        check_count(self.n_artificial, "n_artificial", 2)
        check_count(self.n_trajectories, "n_trajectories")
        if self.context_model not in CONTEXT_MODELS:
            raise ValueError(
                f"context_model: expected one of {CONTEXT_MODELS}, got {self.context_model!r}"
            )
        check_feature_name(self.baseline_features, "baseline_features")


# --------------------------------------------------------------------------- diagnostics
@dataclass(frozen=True, repr=False)
class GPREPSDiagnostics:
    """What one :meth:`GPREPS.update` did.

    Attributes
    ----------
    reps : REPSDiagnostics
        The REPS update on the artificial samples (η, KL vs ε, ESS; ``reps.n_samples`` = M).
    n_real : int
        Real samples the model was fitted on (all so far).
    predicted_real_reward : float or None
        Mean model prediction of the new batch's real (s, ω), made *before* refitting
        (``None`` at the first update, when there is no model yet).
    real_reward : float
        Mean real reward of the new batch.
    prediction_bias : float or None
        ``predicted_real_reward − real_reward`` (the model's bias on unseen data).
    prediction_rmse : float or None
        Root mean squared error of those predictions per sample.
    model_fit : dict
        The reward model's fit statistics (:meth:`RewardModel.fit`).
    artificial_reward_mean : float
        Mean predicted reward R̂ of the M artificial samples.
    time_training, time_prediction, time_policy : float
        Seconds spent refitting the model, predicting the artificial rewards (and the real
        batch's), and in the REPS weighting and weighted ML fit.
    """

    reps: REPSDiagnostics
    n_real: int
    predicted_real_reward: float | None
    real_reward: float
    prediction_bias: float | None
    prediction_rmse: float | None
    model_fit: dict = field(default_factory=dict)
    artificial_reward_mean: float = float("nan")
    time_training: float = 0.0
    time_prediction: float = 0.0
    time_policy: float = 0.0

    def __repr__(self) -> str:
        r = self.reps
        bias = "n/a" if self.prediction_bias is None else number(self.prediction_bias, ".4g")
        return (
            f"GPREPSDiagnostics(M={r.n_samples}, n_real={self.n_real}, eta={r.eta:.4g}, "
            f"kl={r.kl:.4g} (epsilon={r.epsilon:.4g}), ess={r.ess:.4g}, "
            f"real_reward={self.real_reward:.4g}, bias={bias}, "
            f"time train/predict/policy={self.time_training:.3g}/"
            f"{self.time_prediction:.3g}/{self.time_policy:.3g} s)"
        )


# --------------------------------------------------------------------------- algorithm
class GPREPS:
    """Gaussian Process REPS (Table 4.1): contextual REPS on model-predicted artificial samples.

    Parameters
    ----------
    policy : LinearGaussianPolicy
        Initial upper-level policy π(ω|s).
    reward_model : RewardModel
        E.g. :class:`TrajectoryRewardModel` or :class:`DirectRewardModel`; refitted on all real
        data at every update (it is part of this object's state, so it is checkpointed).
    settings : GPREPSSettings, optional
    rng : Generator, int or None
        GPREPS's own stream for the model fits, artificial contexts, parameters and predicted
        trajectories (the real rollouts come from the loop's stream). Same seed ⇒ same numbers.
    task : Task, optional
        Needed for ``context_model="prior"`` (μ̂ = the task's μ(s)).

    Notes
    -----
    Order of draws from ``rng`` in one update: the prediction of the new batch (from the
    second update on), the model fit, M contexts (``"gaussian"``/``"uniform"``/``"prior"``),
    M parameters ω ~ π(ω|s), the M × L predicted trajectories.
    """

    def __init__(
        self,
        policy: LinearGaussianPolicy,
        reward_model: RewardModel,
        settings: GPREPSSettings | None = None,
        rng: np.random.Generator | int | None = None,
        task: Task | None = None,
    ):
        settings = GPREPSSettings() if settings is None else settings
        if not isinstance(settings, GPREPSSettings):
            raise ValueError(f"settings: expected GPREPSSettings, got {type(settings).__name__}")
        if not isinstance(reward_model, RewardModel):
            raise ValueError(
                "reward_model: expected a skillkit.models.reward.RewardModel (fit and "
                f"expected_rewards), got {type(reward_model).__name__}"
            )
        if settings.context_model == "prior" and not isinstance(task, Task):
            raise ValueError("task: context_model='prior' needs the task (its μ(s))")
        if task is not None and not isinstance(task, Task):
            raise ValueError(f"task: expected a Task or None, got {type(task).__name__}")
        self.settings = settings
        self.reward_model = reward_model
        self.task = task
        self._reps = ContextualREPS(
            policy,
            settings.epsilon,
            n_reuse_batches=1,
            baseline_features=settings.baseline_features,
            ridge=settings.ridge,
            cov_shrinkage=settings.cov_shrinkage,
            cov_floor=settings.cov_floor,
            min_effective_samples=settings.min_effective_samples,
        )
        self._rng = as_generator(rng)
        self._real = SampleBuffer(None)  # every real batch (GPREPS refits on all data)
        self._trajectories: list[Trajectory] | None = []
        self.n_updates = 0

    @property
    def policy(self) -> LinearGaussianPolicy:
        """The current upper-level policy."""
        return self._reps.policy

    @property
    def n_real(self) -> int:
        """Real samples collected so far."""
        return len(self._real)

    def real_data(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All real samples so far: contexts (N, context_dim), omegas (N, d), rewards (N,)."""
        if not len(self._real):
            pol = self.policy
            return np.zeros((0, pol.context_dim)), np.zeros((0, pol.dim)), np.zeros(0)
        return self._real.arrays()

    def sample_contexts(self, n: int) -> np.ndarray:
        """n contexts from μ̂(s) fitted to the observed contexts, shape (n, context_dim).

        ``"gaussian"``: N(mean, cov + 1e-10 I) of the observed contexts; ``"uniform"``: the
        box [min, max] of each coordinate; ``"prior"``: ``task.sample_context``.
        """
        pol, rng = self.policy, self._rng
        if pol.context_dim == 0:
            return np.zeros((n, 0))
        kind = self.settings.context_model
        if kind == "prior":
            return np.asarray(self.task.sample_context(rng, n=n), dtype=np.float64).reshape(n, -1)
        s = self._real.arrays()[0]
        if kind == "uniform":
            return rng.uniform(s.min(axis=0), s.max(axis=0), size=(n, s.shape[1]))
        mean = s.mean(axis=0)
        cov = np.atleast_2d(np.cov(s, rowvar=False)) if s.shape[0] > 1 else np.zeros((1, 1))
        cov = cov + 1e-10 * np.eye(s.shape[1])
        return rng.multivariate_normal(mean, cov, size=n, method="cholesky")

    def update(self, batch: Batch) -> GPREPSDiagnostics:
        """One GPREPS iteration (Table 4.1) after observing a batch of real rollouts.

        Parameters
        ----------
        batch : Batch
            Real samples (s_i, ω_i, R_i) and, for a :class:`TrajectoryRewardModel`, their
            trajectories τ_i. After one batch without trajectories none are kept any more
            (also not from later batches): the model sees every trajectory or none.

        Returns
        -------
        GPREPSDiagnostics
        """
        pol, st, rng = self.policy, self.settings, self._rng
        batch = as_batch(batch, pol.dim, pol.context_dim)
        if self._trajectories is not None and batch.trajectories is None:
            self._trajectories = None  # from now on the model sees no trajectories
        t0 = time.perf_counter()
        predicted = None
        if self.n_updates:  # the model's bias on the new, unseen real rollouts
            predicted = self.reward_model.expected_rewards(
                batch.contexts, batch.omegas, st.n_trajectories, rng
            )
            # Shape only (dtype kept): a non-finite prediction is reported in the diagnostics.
            predicted = check_array(
                predicted,
                "reward_model.expected_rewards",
                shape=(len(batch),),
                finite=False,
                dtype=None,
            )
        t_pred0 = time.perf_counter() - t0

        self._real.add(batch.contexts, batch.omegas, batch.rewards)
        if self._trajectories is not None:
            self._trajectories.extend(batch.trajectories)
        s_real, w_real, r_real = self.real_data()
        t1 = time.perf_counter()
        fit_stats = self.reward_model.fit(s_real, w_real, r_real, self._trajectories, rng)
        t_train = time.perf_counter() - t1

        t2 = time.perf_counter()
        s_art = self.sample_contexts(st.n_artificial)
        w_art = pol.sample(s_art, rng)  # s_art is (M, 0) for a context-free policy
        r_art = self.reward_model.expected_rewards(s_art, w_art, st.n_trajectories, rng)
        r_art = check_array(r_art, "reward_model.expected_rewards", shape=(st.n_artificial,))
        t_pred = t_pred0 + time.perf_counter() - t2

        t3 = time.perf_counter()
        reps = self._reps.update(Batch(s_art, w_art, r_art))
        t_policy = time.perf_counter() - t3
        self.n_updates += 1
        real_mean = float(batch.rewards.mean())
        return GPREPSDiagnostics(
            reps=reps,
            n_real=int(r_real.shape[0]),
            predicted_real_reward=None if predicted is None else float(predicted.mean()),
            real_reward=real_mean,
            prediction_bias=None if predicted is None else float(predicted.mean() - real_mean),
            prediction_rmse=(
                None
                if predicted is None
                else float(np.sqrt(np.mean((predicted - batch.rewards) ** 2)))
            ),
            model_fit=dict(fit_stats),
            artificial_reward_mean=float(r_art.mean()),
            time_training=t_train,
            time_prediction=t_pred,
            time_policy=t_policy,
        )

    def __repr__(self) -> str:
        st, pol = self.settings, self.policy
        return (
            f"GPREPS(epsilon={st.epsilon:.4g}, M={st.n_artificial}, L={st.n_trajectories}, "
            f"context_model={st.context_model!r}, dim={pol.dim}, context_dim={pol.context_dim}, "
            f"model={type(self.reward_model).__name__}, {self.n_updates} updates, "
            f"{self.n_real} real samples)"
        )
