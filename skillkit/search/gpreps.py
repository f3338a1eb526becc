r"""Gaussian Process REPS (GPREPS, Sec. 4.1, Table 4.1) and its reward models.

Each :meth:`GPREPS.update` takes a batch of real rollouts and runs Table 4.1: (1) refit the
reward model on all real data; (2) draw M contexts s^[j] from μ̂(s) (a Gaussian or box fitted
to the observed contexts, or the task's μ(s)) and ω^[j] ~ π(ω|s^[j]), and predict

.. math:: \mathcal{R}_{s\omega}^{[j]} = \frac{1}{L} \sum_{l=1}^{L} R(\tau^{[j,l]}, s^{[j]}),
          \quad \tau^{[j,l]} \sim p_{\text{model}}(\tau \mid \omega^{[j]}, s^{[j]}) \quad (4.1)

(3) update the policy with :class:`~skillkit.search.reps.ContextualREPS` on the M artificial
samples only. Reward models: :class:`TrajectoryRewardModel` (a forward model of the state,
Sec. 4.2, scored through predicted trajectories), :class:`DirectRewardModel` ("GP direct",
Sec. 4.3.2) and :class:`KnownRewardModel` (a test oracle).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Literal, get_args

import numpy as np
import torch

from skillkit._repr import number
from skillkit._validation import (
    as_generator,
    check_array,
    check_choice,
    check_count,
    check_positive,
    check_type,
)
from skillkit.models.gp import DTYPE, ExactGP, ForwardModel, GPRegression, check_dtype
from skillkit.models.reward import RewardModel, gp_stats, warm_start_hypers
from skillkit.models.sampling import sampling_dtype
from skillkit.policies.features import FeatureName, check_feature_name
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.base import Batch, SampleBuffer, as_batch, check_settings
from skillkit.search.reps import ContextualREPS, REPSDiagnostics
from skillkit.tasks.base import Task
from skillkit.trajectory import Trajectory

ContextModel = Literal["gaussian", "uniform", "prior"]


# --------------------------------------------------------------------------- reward models
class DirectRewardModel(RewardModel):
    """ "GP direct" (Sec. 4.3.2): a GP regression from z = [s, ω] to R.

    :meth:`expected_rewards` is the GP's predictive mean (Eq. 2.26); L is unused.

    Parameters
    ----------
    gp : ExactGP, FITC or VFE, optional
        The unfitted GP (default ``ExactGP()``), trained and queried on its own ``device``.
    warm_start : bool
        Start each refit's hyper-parameter optimisation (2.28) at the previous values.
    """

    def __init__(self, gp: GPRegression | None = None, warm_start: bool = True):
        gp = ExactGP() if gp is None else gp
        check_type(gp, GPRegression, "gp", "an ExactGP, FITC or VFE")
        self.gp = gp
        self.warm_start = bool(warm_start)
        self.hyperparameters: dict[str, np.ndarray] | None = None
        self.n_data = 0

    @staticmethod
    def _inputs(contexts, omegas) -> np.ndarray:
        """z = [s, ω], shape (N, context_dim + d)."""
        s = check_array(contexts, "contexts", ndim=2)
        return np.hstack([s, check_array(omegas, "omegas", shape=(s.shape[0], None))])

    def fit(self, contexts, omegas, rewards, trajectories=None, rng=None) -> dict[str, Any]:
        """Fit the GP on [s_i, ω_i] → R_i; returns its fit statistics (``n_data``, ``log_ml``)."""
        z = self._inputs(contexts, omegas)
        r = check_array(rewards, "rewards", shape=(z.shape[0],))
        if self.warm_start:
            warm_start_hypers(self.gp, self.hyperparameters, z)
        self.gp.fit(z, r, as_generator(rng))
        self.hyperparameters = self.gp.hyperparameters
        self.n_data = int(r.shape[0])
        return gp_stats(self.gp, r.shape[0])

    def expected_rewards(self, contexts, omegas, n_trajectories=1, rng=None) -> np.ndarray:
        """GP mean of R at [s_j, ω_j], shape (M,)."""
        mean, _ = self.gp.predict(self._inputs(contexts, omegas))
        return np.asarray(mean, dtype=np.float64).reshape(-1)

    def __repr__(self) -> str:
        return f"DirectRewardModel(n_data={self.n_data}, gp={self.gp!r})"


class TrajectoryRewardModel(RewardModel):
    """A learned forward model of the task's state, scored through predicted trajectories.

    :meth:`fit` fits a fresh ``make_model()`` on the transitions of the real trajectories;
    :meth:`expected_rewards` averages the task's reward over L trajectories per pair predicted by
    :func:`~skillkit.search.model_rollouts.predict_trajectories` (Eqs. 4.1–4.3).

    Parameters
    ----------
    task : Task
        A task with ``supports_model_rollout``.
    make_model : callable, optional
        Returns an unfitted forward model (default ``ForwardModel(FITC(n_inducing=100,
        curb=HyperCurb()))``); checkpointed, so not a lambda.
    horizon : int, optional
        T (default: that of the first real trajectory).
    warm_start : bool
        Start each GP refit at the previous hyper-parameters.
    device, dtype
        Where and in which precision (float64, float32 or None) trajectories are sampled;
        None: float32 if the model passes :func:`~skillkit.models.sampling.sampling_dtype` at
        its training inputs, else float64 (at each fit; in its statistics). Default float64:
        visited states can be worse conditioned than the training inputs.
    prior_trajectories : sequence of Trajectory, optional
        Real experience from before the search, learned by every fit.
    common_start_states : bool
        The same L start states for every pair of one call (context-free tasks only).
    """

    #: Fraction of the last call's predicted trajectories stopped as failed.
    last_failed_fraction: float | None = None

    def __init__(
        self,
        task: Task,
        make_model: Callable[[], Any] | None = None,
        horizon: int | None = None,
        warm_start: bool = True,
        device=None,
        prior_trajectories: Sequence[Trajectory] = (),
        dtype: torch.dtype | None = DTYPE,
        common_start_states: bool = False,
    ):
        check_type(task, Task, "task", "a Task")
        if not task.supports_model_rollout:
            raise ValueError(f"task: no step-based model rollouts: {task.no_model_rollout_reason}")
        if make_model is not None and not callable(make_model):
            raise ValueError(f"make_model: expected a callable, got {type(make_model).__name__}")
        if common_start_states and task.context_dim:
            raise ValueError(f"common_start_states: needs a context-free task, got {task.name!r}")
        self.common_start_states = bool(common_start_states)
        self.task = task
        self.make_model = _default_forward_model if make_model is None else make_model
        self.horizon = None if horizon is None else check_count(horizon, "horizon")
        self.warm_start = bool(warm_start)
        self.device = device
        self.dtype = self.sample_dtype = None if dtype is None else check_dtype(dtype)
        self.prior_trajectories = list(prior_trajectories)
        if not all(isinstance(t, Trajectory) for t in self.prior_trajectories):
            raise ValueError("prior_trajectories: expected a sequence of Trajectory objects")
        self.model: Any = None
        self.hyperparameters: dict[str, np.ndarray] | None = None
        self.n_data = 0

    def fit(self, contexts, omegas, rewards, trajectories, rng=None) -> dict[str, Any]:
        """Fit a fresh forward model on the transitions of ``trajectories`` and of the prior ones
        (a failed rollout's up to its failure, where kept); returns its fit statistics."""
        if trajectories is None:
            raise ValueError("trajectories: a TrajectoryRewardModel learns from trajectories")
        ok = [t for t in [*self.prior_trajectories, *trajectories] if t.has_transitions]
        if not ok:
            raise ValueError("trajectories: every trajectory failed; nothing to learn from")
        if self.horizon is None:
            whole = [t for t in ok if not t.failed]
            if not whole:
                raise ValueError("trajectories: every one failed, so pass the horizon")
            self.horizon = int(whole[0].states.shape[0] - 1)
        # A trajectory re-scored in extra contexts appears in several rows.
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
        self.sample_dtype, error = sampling_dtype(model, x, u, self.device, self.dtype)
        stats.update(sampling_dtype=str(self.sample_dtype)[6:], precision_error=error)
        return stats

    def expected_rewards(self, contexts, omegas, n_trajectories, rng=None) -> np.ndarray:
        """Mean reward of L predicted trajectories per pair (Eq. 4.1), shape (M,)."""
        from skillkit.search import model_rollouts

        if self.model is None:
            raise RuntimeError("TrajectoryRewardModel: call fit() before predicting")
        rng = as_generator(rng)
        x0 = None
        if self.common_start_states:  # the same L start states for every pair
            n_pairs = np.atleast_2d(np.asarray(omegas, dtype=float)).shape[0]
            x0 = np.repeat(self.task.initial_states(None, n_trajectories, rng)[None], n_pairs, 0)
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
            dtype=self.sample_dtype,
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
        ``expected_reward(contexts (M, context_dim), omegas (M, d)) -> (M,)``.
    """

    def __init__(self, expected_reward: Callable[[np.ndarray, np.ndarray], np.ndarray]):
        if not callable(expected_reward):
            raise ValueError(f"expected_reward: expected a callable, got {expected_reward!r}")
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
        KL bound ε > 0 (Eq. 3.4).
    n_artificial, n_trajectories : int
        M ≥ 2 artificial samples per update, L ≥ 1 predicted trajectories each (Eq. 4.1).
    context_model : {"gaussian", "uniform", "prior"}
        μ̂(s): a Gaussian fitted to the observed contexts, their bounding box, or the task's μ(s).
    baseline_features, ridge, cov_shrinkage, cov_floor, min_effective_samples
        As :class:`~skillkit.search.reps.ContextualREPS`.
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
        check_choice(self.context_model, "context_model", get_args(ContextModel))
        check_feature_name(self.baseline_features, "baseline_features")


# --------------------------------------------------------------------------- diagnostics
@dataclass(frozen=True, repr=False)
class GPREPSDiagnostics:
    """What one :meth:`GPREPS.update` did.

    ``reps`` is the REPS update on the M artificial samples; ``n_real`` the real samples the model
    was fitted on (``model_fit``: its statistics); ``predicted_real_reward``, ``prediction_bias``
    and ``prediction_rmse`` compare the model's prediction for the new batch, made before
    refitting (``None`` at the first update), with its ``real_reward``; ``time_*`` are seconds.
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
        Refitted on all real data at every update.
    settings : GPREPSSettings, optional
    rng : Generator, int or None
        GPREPS's own stream. Draws per update: the new batch's prediction (from the second
        update), the model fit, M contexts, M parameters, the M × L predicted trajectories.
    task : Task, optional
        Needed for ``context_model="prior"``.
    """

    def __init__(
        self,
        policy: LinearGaussianPolicy,
        reward_model: RewardModel,
        settings: GPREPSSettings | None = None,
        rng: np.random.Generator | int | None = None,
        task: Task | None = None,
    ):
        settings = check_settings(settings, GPREPSSettings)
        if not isinstance(reward_model, RewardModel):
            raise ValueError(f"reward_model: expected a RewardModel, got {reward_model!r}")
        if settings.context_model == "prior" and not isinstance(task, Task):
            raise ValueError("task: context_model='prior' needs the task (its μ(s))")
        if task is not None and not isinstance(task, Task):
            raise ValueError(f"task: expected a Task or None, got {type(task).__name__}")
        self.settings = settings
        self.reward_model = reward_model
        self.task = task
        kwargs = {f.name: getattr(settings, f.name) for f in fields(settings)[4:]}  # REPS's fields
        self._reps = ContextualREPS(policy, settings.epsilon, n_reuse_batches=1, **kwargs)
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

    def sample_contexts(self, n: int) -> np.ndarray:
        """n contexts from μ̂(s), shape (n, context_dim) (``"gaussian"``: covariance + 1e-10 I)."""
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
        """One GPREPS iteration (Table 4.1) after a batch of real rollouts.

        After one batch without trajectories none are kept any more: the model sees all or none.
        """
        pol, st, rng = self.policy, self.settings, self._rng
        batch = as_batch(batch, pol.dim, pol.context_dim)
        if self._trajectories is not None and batch.trajectories is None:
            self._trajectories = None  # the model sees all trajectories or none
        t0 = time.perf_counter()
        predicted = None
        if self.n_updates:  # the model's bias on the new, unseen real rollouts
            predicted = self.reward_model.expected_rewards(
                batch.contexts, batch.omegas, st.n_trajectories, rng
            )
            name = "reward_model.expected_rewards"
            predicted = check_array(predicted, name, shape=(len(batch),), finite=False, dtype=None)
        t_pred0 = time.perf_counter() - t0

        self._real.add(batch.contexts, batch.omegas, batch.rewards)
        if self._trajectories is not None:
            self._trajectories.extend(batch.trajectories)
        s_real, w_real, r_real = self._real.arrays()
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
        sq_err = None if predicted is None else (predicted - batch.rewards) ** 2
        return GPREPSDiagnostics(
            reps=reps,
            n_real=int(r_real.shape[0]),
            predicted_real_reward=None if predicted is None else float(predicted.mean()),
            real_reward=real_mean,
            prediction_bias=None if predicted is None else float(predicted.mean() - real_mean),
            prediction_rmse=None if sq_err is None else float(np.sqrt(np.mean(sq_err))),
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
