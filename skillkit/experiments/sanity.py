"""``sanity3``: contextual REPS (Table 3.1), RWR (2.18), CrKR (2.19–2.20) and C-CMA-ES
(:mod:`skillkit.search.ccmaes`) on :class:`LinearOptimumTask`, whose optimal policy is the linear
ω = a* + A* s, each with the same real rollouts; a policy's error is ‖[a, A] − [a*, A*]‖_F of the
least-squares linear fit to its mean on a 5 × 5 grid. No thesis result; our checks:
``skillkit/data/claims/ch3.toml``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skillkit._validation import check_positive
from skillkit.experiments.curves import experiment
from skillkit.experiments.registry import Series
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.models.kernels import Linear
from skillkit.policies.gaussian import LinearGaussianPolicy
from skillkit.search.ccmaes import CCMAES
from skillkit.search.crkr import CrKR
from skillkit.search.loop import learn
from skillkit.search.reps import ContextualREPS
from skillkit.search.rwr import RWR
from skillkit.tasks.base import Task
from skillkit.trajectory import Trajectory
from skillkit.trial import TrialContext
from skillkit.viz.series import trial_band

#: The optimal offset a*, gain A* and the reward metric W of the problem.
A_STAR_OFFSET = np.array([1.0, -0.5, 0.3])
A_STAR_GAIN = np.array([[0.5, -0.3], [0.2, 0.8], [-0.6, 0.1]])
REWARD_METRIC = np.diag([1.0, 2.0, 0.5])
ALGORITHMS = ("REPS", "RWR", "CrKR", "C-CMA-ES")


class LinearOptimumTask(Task):
    """R(s, ω) = −‖ω − (a* + A* s)‖²_W + ν on s ∈ [−1, 1]², ω ∈ R³ (not in the task registry).

    Parameters
    ----------
    noise_std : float
        Standard deviation σ_ν ≥ 0 of the additive reward noise (drawn once per rollout and
        stored in the trajectory, so re-scoring in other contexts keeps it).
    init_std : float
        Standard deviation of the initial policy N(0, init_std² I) (zero gain).
    """

    name = "linear_optimum"
    context_dim = 2
    parameter_dim = 3
    context_low = np.array([-1.0, -1.0])
    context_high = np.array([1.0, 1.0])
    context_names = ("s1", "s2")
    worst_reward = -1e6
    trajectory_depends_on_context = False

    def __init__(self, noise_std: float = 0.0, init_std: float = 0.5):
        self.noise_std = check_positive(noise_std, "noise_std", allow_zero=True)
        self.init_std = check_positive(init_std, "init_std")

    @property
    def optimal_coefficients(self) -> np.ndarray:
        """[a*, A*], shape (3, 3)."""
        return np.column_stack([A_STAR_OFFSET, A_STAR_GAIN])

    def _simulate(self, omega, context, rng) -> Trajectory:
        noise = self.noise_std * rng.standard_normal() if self.noise_std else 0.0
        return Trajectory(
            np.zeros(1), omega[None, :], np.zeros((1, 0)), signals={"reward_noise": [[noise]]}
        )

    def _reward(self, trajectory, context) -> float:
        diff = trajectory.states[0] - A_STAR_OFFSET - A_STAR_GAIN @ context
        return float(-diff @ REWARD_METRIC @ diff + trajectory.signals["reward_noise"][0, 0])

    def initial_policy(self) -> LinearGaussianPolicy:
        return LinearGaussianPolicy(np.zeros(3), self.init_std**2 * np.eye(3), None, context_dim=2)


def context_grid(n: int = 5) -> np.ndarray:
    """An n × n grid over [−1, 1]², shape (n², 2)."""
    g = np.linspace(-1.0, 1.0, n)
    return np.array([[x, y] for x in g for y in g])


def parameter_error(policy, optimum: np.ndarray, grid: np.ndarray) -> float:
    """‖[a, A] − [a*, A*]‖_F of the least-squares linear fit to ``policy.mean_of`` on ``grid``."""
    design = np.column_stack([np.ones(grid.shape[0]), grid])
    coef = np.linalg.lstsq(design, np.atleast_2d(policy.mean_of(grid)), rcond=None)[0].T
    return float(np.linalg.norm(coef - optimum))


@dataclass(frozen=True)
class SanitySettings(Settings):
    """Settings of ``sanity3`` (the learning loop of Table 3.1 on :class:`LinearOptimumTask`)."""

    n_updates: int = setting(120, "Policy updates per algorithm (Table 3.1 loop).", minimum=1)
    rollouts_per_update: int = setting(25, "Rollouts N between updates (Sec. 3.4.1).", minimum=1)
    n_reuse_batches: int = setting(8, "Batches L each update reuses (Sec. 3.4.1).", minimum=1)
    epsilon: float = setting(0.5, "KL bound ε of contextual REPS (Eq. 3.4).", above=0)
    beta_scale: float = setting(
        1.0, "RWR's and CrKR's β = beta_scale / std(R) (Eq. 2.18).", above=0
    )
    crkr_lam: float = setting(0.01, "CrKR's regulariser λ (Eqs. 2.19–2.20).", above=0)
    kernel_variance: float = setting(0.25, "σ² of CrKR's kernel σ² sᵀs' + c.", above=0)
    kernel_bias: float = setting(0.25, "Bias c of CrKR's linear kernel σ² sᵀs' + c.", minimum=0)
    noise_std: float = setting(0.0, "Std σ_ν of the additive reward noise.", minimum=0)
    init_std: float = setting(0.5, "Std of the initial policy N(0, init_std² I).", above=0)
    threshold: float = setting(1e-2, "Parameter error counted as reaching the optimum.", above=0)


SCALES = scales(SanitySettings(), smoke=dict(n_updates=3), paper=dict(n_updates=200))
QUICK = SCALES["quick"]


def make_algorithm(name: str, task: LinearOptimumTask, settings: SanitySettings):
    """Build REPS, RWR, CrKR or C-CMA-ES (its own population per generation) from the settings."""
    init = task.initial_policy()
    reuse = settings.n_reuse_batches
    if name == "REPS":
        return ContextualREPS(init, settings.epsilon, reuse)
    if name == "RWR":
        return RWR(init, settings.beta_scale, reuse)
    if name == "CrKR":
        kernel = Linear(variance=settings.kernel_variance, bias=settings.kernel_bias)
        lam, beta = settings.crkr_lam, settings.beta_scale
        return CrKR(init, kernel, lam=lam, beta_scale=beta, n_reuse_batches=reuse)
    if name == "C-CMA-ES":
        return CCMAES(init)
    raise ValueError(f"name: expected one of {ALGORITHMS}, got {name!r}")


def run_trial(settings: SanitySettings, rng: np.random.Generator, trial: TrialContext) -> dict:
    """One trial: every algorithm learns from its own child stream of ``rng``."""
    task = LinearOptimumTask(settings.noise_std, settings.init_std)
    grid = context_grid()
    optimum = task.optimal_coefficients
    out: dict = {}
    streams = rng.spawn(len(ALGORITHMS))
    trial.reset(total=len(ALGORITHMS) * settings.n_updates)
    budget = settings.n_updates * settings.rollouts_per_update
    for name, stream in zip(ALGORITHMS, streams, strict=True):
        algo = make_algorithm(name, task, settings)
        n = getattr(algo, "rollouts_per_update", settings.rollouts_per_update)
        res = learn(
            task,
            algo,
            -(-budget // n),  # the same real rollouts for every algorithm (whole generations)
            n,
            stream,
            trial=trial,
            eval_contexts=grid,
            callback=lambda k, a: parameter_error(a.policy, optimum, grid),
            checkpoint_key=name,
        )
        out[f"{name}_error"] = errors = np.array(res["callback"])
        below = np.flatnonzero(errors < settings.threshold)
        out[f"{name}_rollouts"] = res["rollouts"]
        out[f"{name}_mean_reward"] = res["mean_reward"]
        out[f"{name}_explore_reward"] = res["explore_reward"]
        out[f"{name}_rollouts_to_threshold"] = int(res["rollouts"][below[0]]) if below.size else -1
    return out


def summarize(settings: SanitySettings, trials: list[dict]) -> tuple[list[Series], dict]:
    series: list[Series] = []
    summary: dict = {
        "threshold": settings.threshold,
        "trials": len(trials),
        "n_trials": len(trials),
    }
    for name in ALGORITHMS:
        x = np.asarray(trials[0][f"{name}_rollouts"]).tolist()
        err = np.array([t[f"{name}_error"] for t in trials])
        y, band = trial_band(err, kind="gstd")
        panel = "parameter error of the policy mean"
        ylabel = "Frobenius error ‖[a, A] − [a*, A*]‖"
        series.append(
            Series(name, x, y, panel, **band, xlabel="rollouts", ylabel=ylabel, log_y=True)
        )
        y, band = trial_band(np.array([t[f"{name}_mean_reward"] for t in trials]))
        panel, ylabel = "reward of the policy mean", "average reward on 25 grid contexts"
        series.append(Series(name, x, y, panel, **band, xlabel="rollouts", ylabel=ylabel))
        hits = [int(t[f"{name}_rollouts_to_threshold"]) for t in trials]
        reached = [h for h in hits if h >= 0]
        summary[name] = {
            "final_error_per_trial": err[:, -1].tolist(),
            "final_error_median": float(np.median(err[:, -1])),
            "final_error_max": float(np.max(err[:, -1])),
            "rollouts_to_threshold_per_trial": [h if h >= 0 else None for h in hits],
            "trials_reaching_threshold": len(reached),
            "rollouts_to_threshold_median": float(np.median(reached)) if reached else None,
            "rollouts_to_threshold_max": max(reached) if len(reached) == len(hits) else None,
            "final_mean_reward_median": float(
                np.median([t[f"{name}_mean_reward"][-1] for t in trials])
            ),
        }
    return series, summary


experiment(
    "sanity3",
    "Contextual policy search with a known optimal linear policy: REPS, RWR, CrKR, C-CMA-ES",
    SCALES,
    run_trial,
    summarize,
    (2, 3, 10),
)
