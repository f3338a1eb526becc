"""Chapter 5 experiments: kernel embeddings versus GP models (Sec. 5.4).

``fig5.3``–``fig5.5``: on the pendulum (15 trajectories of 20 steps, K = [−3, −1]) a
conditional embedding x → x' fitted by the cross-validated error of Eq. 5.16 and a GP
forward model predict E[x'] (``fig5.3`` e_α, ``fig5.4`` e_α̇) and the 20-step trajectory
(``fig5.5``) on a grid of query states against a Monte Carlo truth. ``fig5.6``, ``fig5.7``:
on the balancing 4-link robot (T = 40) GP sampling and embeddings over z = [x, u]
(Table 5.2) fitted by Eq. 5.19 or 5.23 predict R_i = E[R | x₀ᵢ]; e_r = mean_i (R̂_i − R_i)².
Open setup choices are in ``skillkit/data/claims/ch5.toml``.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import torch

import skillkit.tasks.planar  # noqa: F401  (registers the balancing tasks)
from skillkit.experiments.registry import Experiment, Series, register
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.models.embedding import ConditionalEmbedding
from skillkit.models.embedding_prediction import predict
from skillkit.models.embedding_training import (
    fit_hyperparameters,
    kfold_splits,
    state_embedding_loss,
    step_reward_loss,
    trajectory_reward_loss,
    transitions,
)
from skillkit.models.gp import ExactGP, ForwardModel, HyperCurb
from skillkit.models.kernels import Linear, SquaredExponential
from skillkit.models.sampling import sample_trajectories
from skillkit.tasks import make
from skillkit.tasks.balancing import X_UP, feedback_policy
from skillkit.tasks.pendulum import THESIS_GAINS, feedback_torque, pendulum_dynamics
from skillkit.trial import TrialContext
from skillkit.viz.series import trial_band

_DIAGNOSTICS = ("max_lengthscale_ratio", "max_signal_to_noise", "curb_penalty")


def _initial_lengthscales(x: np.ndarray) -> np.ndarray:
    sd = x.std(axis=0)
    return np.where(sd > 0, sd, 1.0)


def _gp(settings) -> ForwardModel:
    curb = HyperCurb() if settings.gp_curb else None
    return ForwardModel(ExactGP(n_steps=settings.gp_steps, curb=curb), target=settings.gp_target)


# =========================================================================== pendulum
@dataclass(frozen=True)
class PendulumSettings(Settings):
    """Settings of ``fig5.3``, ``fig5.4`` and ``fig5.5`` (pendulum, Sec. 5.4)."""

    n_trajectories: int = setting(15, "Observed trajectories (thesis: 15).", minimum=2)
    horizon: int = setting(20, "Steps per observed and predicted trajectory.", minimum=1)
    control_noise: float = setting(0.05, "Std σ_u of the controls (N m; thesis: 0.05).", minimum=0)
    grid: int = setting(17, "Query grid points per axis over the context range.", minimum=1)
    truth_samples: int = setting(200, "Monte Carlo successors per query (single step).", minimum=2)
    truth_rollouts: int = setting(50, "Monte Carlo 20-step rollouts per query (fig5.5).", minimum=2)
    gp_samples: int = setting(30, "Trajectories sampled from the GP per query (fig5.5).", minimum=1)
    cv_folds: int = setting(10, "Cross-validation folds of Eq. 5.16 (thesis: 10).", minimum=2)
    max_iter: int = setting(50, "L-BFGS-B iterations of the embedding.", minimum=1)
    lam0: float = setting(1e-3, "Initial regulariser λ of the embedding (Eq. 5.3).", above=0)
    lam_min: float = setting(1e-6, "Lower bound of the learned λ (fig5.5: 1e-3).", above=0)
    gp_steps: int = setting(150, "Marginal-likelihood steps of the GP (Eq. 2.28).", minimum=0)
    gp_target: Literal["delta", "next"] = setting("next", "What the GP learns: x' (next) or Δx.")
    gp_curb: bool = setting(True, "PILCO's hyper-parameter penalty (HyperCurb) on the GP.")
    target_kernel: Literal["se", "linear"] = setting("se", "Target kernel of Eq. 5.16.")


SCALES_PENDULUM = scales(
    PendulumSettings(),
    smoke=dict(
        n_trajectories=3,
        horizon=4,
        grid=4,
        truth_samples=20,
        truth_rollouts=5,
        gp_samples=4,
        cv_folds=3,
        max_iter=3,
        gp_steps=3,
    ),
    paper=dict(grid=41, truth_samples=1000, truth_rollouts=200, gp_samples=100, max_iter=100),
)


def _pendulum_trial(
    settings: PendulumSettings, rng: np.random.Generator, trial: TrialContext, multi_step: bool
) -> dict:
    task = make("pendulum", horizon=settings.horizon, control_noise=settings.control_noise)
    n_traj, horizon = settings.n_trajectories, settings.horizon
    trial.reset(total=5)
    # Observed data: 15 trajectories from random initial states with the thesis controller.
    contexts = task.sample_context(rng, n_traj)
    states = np.stack([task.rollout(THESIS_GAINS, s, rng).states for s in contexts])
    x, xn, groups = transitions(states)
    trial.update()

    # Embedding: Eq. 5.16 with k-fold cross-validation over trajectories and a fixed target
    # kernel, linear or SE with the targets' stds as length-scales.
    folds = kfold_splits(len(x), min(settings.cv_folds, n_traj), rng, groups=groups)
    target = SquaredExponential(2, lengthscale=_initial_lengthscales(xn))
    if settings.target_kernel == "linear":
        target = Linear()
    loss = state_embedding_loss(x, xn, folds, target)
    lam0 = max(settings.lam0, settings.lam_min)
    opts = dict(lam_bounds=(settings.lam_min, 1.0), max_iter=settings.max_iter)
    fit = fit_hyperparameters(loss, _initial_lengthscales(x), lam0, **opts)
    emb = ConditionalEmbedding(x, xn, SquaredExponential(2, lengthscale=fit.lengthscale), fit.lam)
    trial.update()

    gp = _gp(settings)  # on the same transitions; the policy is fixed: no control input
    gp.fit(x, np.zeros((len(x), 0)), xn, rng=rng)
    trial.update()

    n = settings.grid
    a_axis = np.linspace(task.context_low[0], task.context_high[0], n)
    ad_axis = np.linspace(task.context_low[1], task.context_high[1], n)
    query = np.stack(np.meshgrid(a_axis, ad_axis), axis=-1).reshape(-1, 2)  # row i: ad_axis[i // n]
    gains, sigma, dt = THESIS_GAINS, task.control_noise, task.dt
    out = {
        "alpha": a_axis,
        "alpha_dot": ad_axis,
        "observed_states": states,
        "emb_lengthscale": fit.lengthscale,
        "emb_lam": fit.lam,
        "emb_cv_loss": fit.loss,
        "emb_cv_initial_loss": fit.initial_loss,
        "emb_fit_success": fit.success,
        "gp_lengthscale": gp.gp.hyperparameters["lengthscale"],
        "gp_diagnostics": {k: gp.gp.diagnostics.get(k) for k in _DIAGNOSTICS},
    }

    if multi_step:  # the truth: Monte Carlo rollouts through the true dynamics
        r = settings.truth_rollouts
        xs = np.broadcast_to(query, (r,) + query.shape).copy()
        truth, floor = [query], np.zeros(len(query))
        for _ in range(horizon):
            xs = pendulum_dynamics(
                xs, feedback_torque(xs, gains, sigma * rng.standard_normal(xs.shape[:-1])), dt
            )
            truth.append(xs.mean(axis=0))
            floor += xs.var(axis=0, ddof=1).sum(axis=-1) / r  # MC variance of the truth, Σ_t
        truth = np.stack(truth)  # (T+1, G, 2)
        out["floor_e_traj"] = floor.reshape(n, n)
        trial.update()
        t0 = time.perf_counter()
        traj = predict(emb, query, horizon + 1)
        pre, lin = traj.preimages(emb), traj.means(emb)
        out["time_embedding"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        no_u = lambda t, xt, p: xt.new_zeros((xt.shape[0], 0))  # noqa: E731
        sampled = sample_trajectories(gp, query, no_u, horizon, settings.gp_samples, rng)
        gp_mean = sampled.states.mean(dim=1).numpy().transpose(1, 0, 2)  # (T+1, G, 2)
        out["time_gp"] = time.perf_counter() - t0
        # Constant predictor: the mean observed state at each step (ignores the start state).
        const = np.broadcast_to(states.mean(axis=0)[:, None], truth.shape)
    else:
        xq = np.broadcast_to(query, (settings.truth_samples,) + query.shape)
        noise = sigma * rng.standard_normal(xq.shape[:-1])
        samples = pendulum_dynamics(xq, feedback_torque(xq, gains, noise), dt)
        truth = samples.mean(axis=0)
        floor = samples.var(axis=0, ddof=1) / settings.truth_samples  # MC variance of truth
        out["floor_e_alpha"] = floor[:, 0].reshape(n, n)
        out["floor_e_alpha_dot"] = floor[:, 1].reshape(n, n)
        t0 = time.perf_counter()
        beta = emb.weights(query)
        pre, lin = emb.preimage(beta), emb.mean(beta)
        out["time_embedding"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        gp_mean = gp.predict(query, np.zeros((len(query), 0)))[0]
        out["time_gp"] = time.perf_counter() - t0
        trial.update()
        const = np.broadcast_to(xn.mean(axis=0), truth.shape)  # mean observed successor
    for name, pred in (("emb", lin), ("emb_preimage", pre), ("gp", gp_mean), ("const", const)):
        err = (pred - truth) ** 2
        if multi_step:
            out[f"{name}_e_traj"] = err[1:].sum(axis=(0, 2)).reshape(n, n)
        else:
            out[f"{name}_e_alpha"] = err[:, 0].reshape(n, n)
            out[f"{name}_e_alpha_dot"] = err[:, 1].reshape(n, n)
    trial.update()
    return out


def _near_data(t0: dict, n: int) -> np.ndarray:
    """(n, n) bool: cells within 10% of the grid's span of an observed state on both axes."""
    a, ad = np.asarray(t0["alpha"]), np.asarray(t0["alpha_dot"])
    span = np.array([np.ptp(a), np.ptp(ad)])
    cells = np.stack(np.meshgrid(a, ad), axis=-1).reshape(-1, 2) / span
    obs = np.asarray(t0["observed_states"]).reshape(-1, 2) / span
    nearest = np.abs(cells[:, None] - obs[None]).max(axis=-1).min(axis=1)
    return (nearest <= 0.1).reshape(n, n)


_MODELS = (("embedding", "emb"), ("gp", "gp"))  # name in the summary, key of the error maps

_PENDULUM_PANELS = (
    ("emb", "(a) kernel embedding"),
    ("gp", "(b) GP regression"),
    ("const", "(c) constant predictor"),
    ("floor", "(d) noise floor"),
)


def _medians(maps: dict, near: np.ndarray) -> dict:
    """Median error per model near (``near``) and away from the observed states."""
    return {
        where: {
            name: float(np.median(maps[m][cells])) if cells.any() else None for name, m in _MODELS
        }
        for where, cells in (("near_data", near), ("far_from_data", ~near))
    }


def _per_trial_medians(trials: list[dict], key: str) -> dict:
    """Each trial's median errors near and away from its own observed states."""
    near = [_near_data(t, np.shape(t[f"emb_{key}"])[0]) for t in trials]
    per = [
        _medians({m: np.asarray(t[f"{m}_{key}"]) for _, m in _MODELS}, c)
        for t, c in zip(trials, near, strict=True)
    ]
    out: dict = {"per_trial_fraction_of_grid_near_data": [float(np.mean(c)) for c in near]}
    for where in ("near_data", "far_from_data"):
        out[f"per_trial_median_error_{where}"] = {n: [p[where][n] for p in per] for n, _ in _MODELS}
    return out


def _pendulum_summary(key: str, label: str, unit: str):
    """``summarize`` of the pendulum error map ``key`` (``label`` in ``unit``)."""

    def summarize(settings: PendulumSettings, trials: list[dict]) -> tuple[list[Series], dict]:
        maps = {
            m: np.mean([t[f"{m}_{key}"] for t in trials], axis=0)
            for m in ("emb", "emb_preimage", "gp", "const", "floor")
        }
        # Exact zeros are drawn at 10⁻³⁰, below the colour ranges, which come from the
        # positive values: (a)–(c) share one, (d) has its own.
        logs = {m: np.log10(np.maximum(v, 1e-30)) for m, v in maps.items()}
        pos = {m: logs[m][maps[m] > 0] for m in maps}
        finite = np.concatenate([pos[m] for m in ("emb", "gp", "const")])
        zmin, zmax = float(finite.min()), float(finite.max())
        fl = pos["floor"] if pos["floor"].size else np.array([-30.0])
        t0 = trials[0]
        obs = np.asarray(t0["observed_states"])
        xs = np.concatenate([np.append(tr[:, 0], np.nan) for tr in obs])
        ys = np.concatenate([np.append(tr[:, 1], np.nan) for tr in obs])
        series: list[Series] = []
        for m, title in _PENDULUM_PANELS:
            kw = dict(panel=f"{title}: log10 {label} ({label} in {unit})", xlabel="α (rad)")
            kw["ylabel"] = "α̇ (rad/s)"
            lo, hi = (zmin, zmax) if m != "floor" else (float(fl.min()), float(fl.max()))
            hm = dict(z=logs[m], kind="heatmap", zmin=lo, zmax=hi, **kw)
            series += [
                Series(f"log10 {label}, {title[4:]}", t0["alpha"], t0["alpha_dot"], **hm),
                Series("observed trajectories", xs, ys, kind="line", **kw),
            ]
        better_map = maps["emb"] < maps["gp"]
        near = _near_data(t0, better_map.shape[0])
        medians = _medians(maps, near)

        def fraction(cells):
            return float(np.mean(better_map[cells])) if cells.any() else None

        def below(a: str, b: str) -> float:  # fraction of the grid where a's error is lower
            return float(np.mean(maps[a] < maps[b]))

        summary = {
            "n_trials": len(trials),
            "error": label,
            "mean_error_embedding": float(np.mean(maps["emb"])),
            "mean_error_gp": float(np.mean(maps["gp"])),
            "mean_error_constant": float(np.mean(maps["const"])),
            "mean_noise_floor": float(np.mean(maps["floor"])),
            "mean_error_embedding_preimage": float(np.mean(maps["emb_preimage"])),
            "fraction_of_grid_where_embedding_preimage_better": below("emb_preimage", "gp"),
            "median_log10_error_embedding": float(np.median(logs["emb"])),
            "median_log10_error_gp": float(np.median(logs["gp"])),
            "fraction_of_grid_where_embedding_better": float(np.mean(better_map)),
            "fraction_of_grid_near_data": float(np.mean(near)),
            "fraction_embedding_better_near_data": fraction(near),
            "fraction_embedding_better_far_from_data": fraction(~near),
            "median_error_near_data": medians["near_data"],
            "median_error_far_from_data": medians["far_from_data"],
            "fraction_of_grid_where_embedding_beats_constant": below("emb", "const"),
            "fraction_of_grid_where_gp_beats_constant": below("gp", "const"),
            "per_trial_mean_error": {
                m: [float(np.mean(t[f"{m}_{key}"])) for t in trials] for m in maps
            },
            **_per_trial_medians(trials, key),
            "shared_colour_range_log10": [zmin, zmax],
            "embedding_lengthscale": [np.asarray(t["emb_lengthscale"]).tolist() for t in trials],
            "embedding_lam": [t["emb_lam"] for t in trials],
            "gp_lengthscale": [np.asarray(t["gp_lengthscale"]).tolist() for t in trials],
            "gp_diagnostics": [t.get("gp_diagnostics") for t in trials],
            "prediction_time_s": {
                "embedding": [t["time_embedding"] for t in trials],
                "gp": [t["time_gp"] for t in trials],
            },
        }
        return series, summary

    return summarize


# fig5.5's scales: λ ≥ 1e-3 for the 20-step propagation.
SCALES_PENDULUM_MULTI = {k: replace(v, lam_min=1e-3) for k, v in SCALES_PENDULUM.items()}

for _id, _key, _label, _unit, _what in (
    ("fig5.3", "e_alpha", "e_α", "rad²", "single-step prediction error of α"),
    ("fig5.4", "e_alpha_dot", "e_α̇", "(rad/s)²", "single-step prediction error of α̇"),
    ("fig5.5", "e_traj", "Σ_t e_x_t", "rad² + (rad/s)²", "20-step trajectory prediction error"),
):
    _multi = _key == "e_traj"
    register(
        Experiment(
            id=_id,
            title=f"Pendulum: {_what}, kernel embedding vs GP",
            settings_class=PendulumSettings,
            settings=SCALES_PENDULUM_MULTI if _multi else SCALES_PENDULUM,
            run_trial=(lambda m: lambda s, rng, trial: _pendulum_trial(s, rng, trial, m))(_multi),
            summarize=_pendulum_summary(_key, _label, _unit),
            trials={"smoke": 1, "quick": 1, "paper": 5},
        )
    )


# =========================================================================== balancing
def _rollouts_from(task, gain: np.ndarray, x0: np.ndarray, n: int, rng) -> tuple:
    """``n`` real rollouts from ``x0``: states, controls (NaN where diverged) and failed (n,)."""
    T1 = task.n_steps + 1
    states = np.full((n, T1, 8), np.nan)
    controls = np.full((n, T1, 4), np.nan)
    failed = np.zeros(n, dtype=bool)
    for k in range(n):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a failed rollout warns
            traj = task.rollout_from(np.asarray(gain).ravel(), x0, rng=rng)
        if traj.failed:
            failed[k] = True
            continue
        states[k], controls[k] = traj.states, traj.controls
    return states, controls, failed


def _balancing_truth(task, gain, starts: np.ndarray, settings, rng) -> dict:
    """R_i = E[R | x₀ᵢ] from real rollouts, its Monte Carlo variance and Var(R | x₀ᵢ)."""
    n_roll = settings.truth_rollouts
    returns = np.empty((len(starts), n_roll))
    for i, x0 in enumerate(starts):
        xs, us, failed = _rollouts_from(task, gain, x0, n_roll, rng)
        r = task.immediate_reward(xs, us)[:, 1:].sum(axis=1)
        returns[i] = np.where(failed, np.nan, r)
    n_ok = np.sum(np.isfinite(returns), axis=1)
    var = np.nanvar(returns, axis=1, ddof=1)
    return {
        "truth": np.nanmean(returns, axis=1),
        "truth_mc_var": var / n_ok,
        "truth_rollout_var": var,
        "failed": int(np.sum(np.isnan(returns))),
    }


def _feedback(gain: np.ndarray):
    """The policy u = G (x − x_up) on embedding states (B, K, 8)."""
    return lambda s, t: np.einsum("ij,bkj->bki", gain, s - X_UP)


def _expected_rewards(
    model: ConditionalEmbedding, x0: np.ndarray, gain: np.ndarray, horizon: int, reward
) -> tuple[np.ndarray, np.ndarray]:
    """Σ_{t=1}^T E[r_t] of u = G (x − x_up) from starts ``x0`` (B, 8) by Table 5.2 with Eq.
    (5.9)'s first step, and max_t ‖β_t‖₁ (B,) (far above 1: the propagation is unstable)."""
    traj = predict(
        model, x0, horizon + 1, policy=_feedback(gain), reward=reward, time_invariant=True
    )
    return traj.rewards[1:].sum(axis=0), np.abs(traj.betas).sum(axis=1).max(axis=0)


@dataclass(frozen=True)
class BalancingSettings(Settings):
    """Settings shared by ``fig5.6`` and ``fig5.7`` (balancing the 4-link robot, Sec. 5.4)."""

    horizon: int = setting(40, "Steps T of every trajectory (thesis: 40).", minimum=1)
    initial_std: float = setting(0.3, "Std of the initial state (thesis: 0.3).", minimum=0)
    pd_frequency: float = setting(3.0, "ω of the PD controller (rad/s).", above=0)
    pd_damping: float = setting(1.5, "Damping ratio ζ of the PD controller.", above=0)
    gp_samples: int = setting(100, "GP trajectories M per test start (thesis: 100).", minimum=1)
    cv_folds: int = setting(10, "Cross-validation folds over trajectories (thesis: 10).", minimum=2)
    lam0: float = setting(1e-3, "Initial regulariser λ of the embeddings (Eq. 5.3).", above=0)
    lam_min: float = setting(1e-3, "Lower bound of λ in both embedding fits.", above=0)
    test_pairs: int = setting(40, "Test start states x₀ᵢ.", minimum=1)
    truth_rollouts: int = setting(30, "Real rollouts per test start (thesis: 100).", minimum=2)
    max_iter: int = setting(40, "L-BFGS-B iterations of the embeddings.", minimum=1)
    gp_steps: int = setting(100, "Marginal-likelihood steps of the GP (Eq. 2.28).", minimum=0)
    trajectory_start: Literal["both", "step", "default"] = setting(
        "both", "Start of the Eq. 5.23 fit: the step-based fit's initial values or optimum."
    )
    gp_target: Literal["delta", "next"] = setting("next", "What the GP learns: x' (next) or Δx.")
    gp_curb: bool = setting(True, "PILCO's hyper-parameter penalty (HyperCurb) on the GP.")


@dataclass(frozen=True)
class RewardVsDataSettings(BalancingSettings):
    """Settings of ``fig5.6``: the error against the number of observed trajectories."""

    torque_noise: float = setting(4.0, "Std of the torque noise (N m; thesis: 4).", minimum=0)
    n_trajectories: tuple[int, ...] = setting((3, 8), "Observed trajectories (x).", minimum=2)


@dataclass(frozen=True)
class RewardVsNoiseSettings(BalancingSettings):
    """Settings of ``fig5.7``: the error against the torque noise."""

    torque_noise: tuple[float, ...] = setting((1.0, 4.0, 8.0), "Torque-noise stds (x).", minimum=0)
    n_trajectories: int = setting(5, "Observed trajectories the models learn from.", minimum=2)


_BALANCING_PAPER = dict(test_pairs=200, truth_rollouts=100, max_iter=30, gp_steps=150)
_BALANCING_SMOKE = dict(
    horizon=5, gp_samples=4, test_pairs=3, truth_rollouts=3, max_iter=2, gp_steps=2
)
SCALES_5_6 = scales(
    RewardVsDataSettings(),
    smoke={**_BALANCING_SMOKE, "n_trajectories": (2, 3)},
    paper={**_BALANCING_PAPER, "n_trajectories": (2, 4, 6, 10)},
)
SCALES_5_7 = scales(
    RewardVsNoiseSettings(),
    smoke={**_BALANCING_SMOKE, "n_trajectories": 2, "torque_noise": (1.0, 4.0)},
    paper={
        **_BALANCING_PAPER,
        "test_pairs": 100,
        "truth_rollouts": 50,
        "n_trajectories": 6,
        "torque_noise": (1.0, 2.0, 4.0, 8.0),
    },
)

_METHODS = (
    ("gp", "GP sampling (M={gp_samples})"),
    ("step", "embedding, step-based (5.17)"),
    ("trajectory", "embedding, trajectory-based (5.23)"),
)
_COMPARED = ("gp", "step", "trajectory", "constant")  # whose e_r is kept per trial
_FITS = ("step", "trajectory")  # the embeddings' two fits (Eqs 5.17 and 5.23)
_FLOORS = (
    ("constant", "constant predictor (mean observed reward)"),
    ("noise", "noise floor: mean Var(R | x₀ᵢ) / truth rollouts"),
)


def _task(settings: BalancingSettings, noise: float):
    return make(
        "balancing-noisy",
        torque_noise_std=float(noise),
        initial_std=settings.initial_std,
        n_steps=settings.horizon,
    )


def _observed(task, gain, n_traj: int, rng) -> tuple[np.ndarray, np.ndarray, int]:
    """``n_traj`` working PD rollouts: states, commanded controls and the number redrawn."""
    runs, failed = [], 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        while len(runs) < n_traj:
            if failed > 5 * n_traj + 10:  # the controller does not balance this task
                raise RuntimeError(f"balancing: {failed} PD rollouts diverged collecting {n_traj}")
            tr = task.rollout(gain.ravel(), None, rng)
            if tr.failed:
                failed += 1
                continue
            runs.append(tr)
    return np.stack([tr.states for tr in runs]), np.stack([tr.controls for tr in runs]), failed


def _balancing_case(task, gain, n_traj: int, starts, truth, settings, rng, trial) -> dict:
    """Train the three predictors on ``n_traj`` PD trajectories; score them on ``starts``."""
    reward = task.immediate_reward
    states, controls, redrawn = _observed(task, gain, n_traj, rng)
    rewards = reward(states, controls)  # (M, T+1)
    z, xn, groups = transitions(states, controls)
    r_next = rewards[:, 1:].ravel()
    horizon = states.shape[1] - 1

    folds_traj = kfold_splits(n_traj, min(settings.cv_folds, n_traj), rng)
    folds_step = [
        (np.flatnonzero(np.isin(groups, tr)), np.flatnonzero(np.isin(groups, va)))
        for tr, va in folds_traj
    ]
    ls0 = _initial_lengthscales(z)
    fit = dict(lam_bounds=(settings.lam_min, 1.0), max_iter=settings.max_iter)
    lam0 = max(settings.lam0, settings.lam_min)
    fits = {"step": fit_hyperparameters(step_reward_loss(z, r_next, folds_step), ls0, lam0, **fit)}
    # Eq. 5.23 from the step-based fit's initial values and from its optimum (trajectory_start
    # "both" keeps the lower cross-validated loss; "default" / "step" use one start only).
    loss = trajectory_reward_loss(states, controls, rewards, _feedback(gain), reward, folds_traj)
    starts_ = {"default": (ls0, lam0), "step": (fits["step"].lengthscale, fits["step"].lam)}
    keys = ["default", "step"] if settings.trajectory_start == "both" else []
    tried = {
        key: fit_hyperparameters(loss, *starts_[key], lengthscale_reference=ls0, **fit)
        for key in keys or [settings.trajectory_start]
    }
    best = min(tried, key=lambda k_: tried[k_].loss)
    fits["trajectory"] = tried[best]
    trial.update()

    constant = float(rewards[:, 1:].sum(axis=1).mean())
    out = {
        "redrawn_observed": redrawn,
        "n_transitions": len(z),
        "e_r_constant": float(np.mean((constant - truth) ** 2)),
        "observed_reward_mean": constant,
        "trajectory_start": best,
        "trajectory_per_start": {},
    }

    def score(f) -> dict:
        emb = ConditionalEmbedding(z, xn, SquaredExponential(12, lengthscale=f.lengthscale), f.lam)
        t0 = time.perf_counter()
        pred, beta_l1 = _expected_rewards(emb, starts, gain, horizon, reward)
        return dict(
            time=time.perf_counter() - t0,
            e_r=float(np.mean((pred - truth) ** 2)),
            median_sq_err=float(np.median((pred - truth) ** 2)),
            pred_mean=float(np.mean(pred)),
            beta_l1_max=float(np.max(beta_l1)),
            lengthscale=f.lengthscale,
            lam=f.lam,
            cv_loss=f.loss,
            cv_initial_loss=f.initial_loss,
            fit_success=f.success,
            fit_at_bound=f.at_bound,
        )

    for key, f in tried.items():  # every start's fit, scored (evidence of the β ≈ 0 plateau)
        m = score(f)
        per_start = {k: m[k] for k in ("cv_loss", "e_r", "pred_mean", "beta_l1_max", "lam")}
        out["trajectory_per_start"][key] = per_start | {"n_at_bound": len(f.at_bound)}
    for name, f in fits.items():
        out.update({f"{k}_{name}": v for k, v in score(f).items()})
    trial.update()

    gp = _gp(settings)
    gp.fit(z[:, :8], z[:, 8:], xn, rng=rng)
    gains = torch.from_numpy(np.broadcast_to(gain, (len(starts), 4, 8)).copy())
    t0 = time.perf_counter()
    policy = feedback_policy(gains)
    sampled = sample_trajectories(gp, starts, policy, horizon, settings.gp_samples, rng)
    xs = sampled.states.numpy()  # (B, M, T+1, 8)
    us = np.einsum("ij,bmtj->bmti", gain, xs - X_UP)  # commanded torques
    gp_pred = reward(xs, us)[:, :, 1:].sum(axis=-1).mean(axis=1)
    out["time_gp"] = time.perf_counter() - t0
    finite = np.isfinite(gp_pred)
    out["gp_nonfinite_predictions"] = int(np.sum(~finite))
    sq = (gp_pred[finite] - truth[finite]) ** 2
    any_ = finite.any()
    out["e_r_gp"] = float(np.mean(sq)) if any_ else np.nan
    out["median_sq_err_gp"] = float(np.median(sq)) if any_ else np.nan
    out["pred_mean_gp"] = float(np.mean(gp_pred[finite])) if any_ else np.nan
    out["gp_diagnostics"] = {k: gp.gp.diagnostics.get(k) for k in _DIAGNOSTICS}
    trial.update()
    return out


def _truth_stats(t: dict) -> dict:
    return {
        "truth_mc_floor": float(np.mean(t["truth_mc_var"])),
        "truth_rollout_var": float(np.mean(t["truth_rollout_var"])),
        "truth_reward_mean": float(np.mean(t["truth"])),
        "truth_reward_var": float(np.var(t["truth"])),
        "failed_truth_rollouts": t["failed"],
    }


def _fig56_trial(
    settings: RewardVsDataSettings, rng: np.random.Generator, trial: TrialContext
) -> dict:
    counts = list(settings.n_trajectories)
    trial.reset(total=1 + 3 * len(counts))
    task = _task(settings, settings.torque_noise)
    gain = task.pd_gain(settings.pd_frequency, settings.pd_damping)
    # Resumable after the ground truth and after every case.
    st = trial.resume("fig5.6", rng)
    if st is None:
        starts = task.initial_states(None, settings.test_pairs, rng)
        truth = _balancing_truth(task, gain, starts, settings, rng)
        st = {"starts": starts, "truth": truth, "cases": []}
        trial.save("fig5.6", st, rng)
    trial.update(1 + 3 * len(st["cases"]))
    truth = st["truth"]["truth"]
    for m in counts[len(st["cases"]) :]:
        case = _balancing_case(task, gain, int(m), st["starts"], truth, settings, rng, trial)
        st["cases"].append(case)
        trial.save("fig5.6", st, rng)
    stats = {k: [v] * len(counts) for k, v in _truth_stats(st["truth"]).items()}
    stats["failed_truth_rollouts"] = [st["truth"]["failed"]]  # one ground truth for all x
    return {"x": counts, "cases": st["cases"], **stats}


def _fig57_trial(
    settings: RewardVsNoiseSettings, rng: np.random.Generator, trial: TrialContext
) -> dict:
    levels = list(settings.torque_noise)
    trial.reset(total=4 * len(levels))
    # Resumable after every noise level; the test start states are shared by all levels.
    st = trial.resume("fig5.7", rng)
    if st is None:
        starts = _task(settings, levels[0]).initial_states(None, settings.test_pairs, rng)
        st = {"starts": starts, "cases": [], "stats": []}
    trial.update(4 * len(st["cases"]))
    for noise in levels[len(st["cases"]) :]:
        task = _task(settings, noise)
        gain = task.pd_gain(settings.pd_frequency, settings.pd_damping)
        truth = _balancing_truth(task, gain, st["starts"], settings, rng)
        st["stats"].append(_truth_stats(truth))
        trial.update()
        m = settings.n_trajectories
        case = _balancing_case(task, gain, m, st["starts"], truth["truth"], settings, rng, trial)
        st["cases"].append(case)
        trial.save("fig5.7", st, rng)
    stats = {k: [s[k] for s in st["stats"]] for k in st["stats"][0]}
    return {"x": levels, "cases": st["cases"], **stats}


def _spread(values: list[float | None]) -> float:
    """max / min of positive errors: inf if the smallest is 0, NaN if one is missing."""
    if not all(v is not None and np.isfinite(v) for v in values):
        return float("nan")
    lo = min(values)
    return float(max(values) / lo) if lo > 0 else float("inf")


def _reward_summary(xlabel: str, fig: str):
    """``summarize`` of ``fig5.6`` / ``fig5.7``: e_r per predictor against ``xlabel``."""

    def summarize(settings: BalancingSettings, trials: list[dict]) -> tuple[list[Series], dict]:
        x = list(trials[0]["x"])
        err = {
            m: np.array([[c[f"e_r_{m}"] for c in t["cases"]] for t in trials]) for m in _COMPARED
        }
        err["noise"] = np.array([t["truth_mc_floor"] for t in trials], dtype=float)
        series = []
        kw = dict(panel="reward prediction error", xlabel=xlabel, log_y=True)
        kw["ylabel"] = "e_r = mean (R̂ − R)² [reward²]"  # the balancing reward is unitless
        for m, label in _METHODS + _FLOORS:
            y, band = trial_band(err[m])
            kind = "lines+markers" if m in dict(_METHODS) else "line"
            name = label.format(gp_samples=settings.gp_samples)
            series.append(Series(name, x, y, **band, kind=kind, **kw))
        mean = {m: err[m].mean(axis=0) for m in err}

        def below(a: str, b: str) -> list[bool]:
            return [bool(u < v) for u, v in zip(mean[a], mean[b], strict=True)]

        def per_case(key):
            return [[c[key] for c in t["cases"]] for t in trials]

        summary = {
            "n_trials": len(trials),
            "x": x,
            "mean_e_r": {m: mean[m].tolist() for m in err},
            "floors": {
                "truth_rollout_var": np.mean([t["truth_rollout_var"] for t in trials], 0).tolist(),
                "truth_reward_var": np.mean([t["truth_reward_var"] for t in trials], 0).tolist(),
            },
            "median_squared_error": {
                m: np.mean(per_case(f"median_sq_err_{m}"), 0).tolist() for m, _ in _METHODS
            },
            "predicted_reward_mean": {
                m: np.mean(per_case(f"pred_mean_{m}"), 0).tolist() for m, _ in _METHODS
            },
            "truth_reward_mean": np.mean([t["truth_reward_mean"] for t in trials], 0).tolist(),
            "embedding_lam": {m: per_case(f"lam_{m}") for m in _FITS},
            "embedding_beta_l1_max": {m: per_case(f"beta_l1_max_{m}") for m in _FITS},
            "embedding_cv_loss": {
                m: {"final": per_case(f"cv_loss_{m}"), "initial": per_case(f"cv_initial_loss_{m}")}
                for m in _FITS
            },
            "fit_at_bound": {
                m: [c for r in per_case(f"fit_at_bound_{m}") for c in r] for m in _FITS
            },
            "gp_diagnostics": per_case("gp_diagnostics"),
            "trajectory_fit_starts": per_case("trajectory_per_start"),
            "gp_over_trajectory_based_ratio": (mean["gp"] / mean["trajectory"]).tolist(),
            "gp_over_step_based_ratio": (mean["gp"] / mean["step"]).tolist(),
            "embedding_below_gp": [
                a and b for a, b in zip(below("step", "gp"), below("trajectory", "gp"), strict=True)
            ],
            "trajectory_based_below_step_based": below("trajectory", "step"),
            "trajectory_based_below_constant": below("trajectory", "constant"),
            "gp_nonfinite_predictions": int(np.sum(per_case("gp_nonfinite_predictions"))),
            "failed_truth_rollouts": int(sum(sum(t["failed_truth_rollouts"]) for t in trials)),
            "redrawn_observed_trajectories": int(np.sum(per_case("redrawn_observed"))),
            "prediction_time_s": {m: float(np.mean(per_case(f"time_{m}"))) for m, _ in _METHODS},
        }
        summary["e_r_per_trial"] = {m: err[m].T.tolist() for m in _COMPARED}
        summary["e_r_mean_over_x_per_trial"] = {m: err[m].mean(axis=1).tolist() for m in _COMPARED}
        if fig == "fig5.7":
            spread = {m: _spread(mean[m].tolist()) for m, _ in _METHODS}
            summary["max_over_min_e_r_across_noise"] = spread
            summary["max_over_min_e_r_across_noise_per_trial"] = {
                m: [_spread(row.tolist()) for row in err[m]] for m, _ in _METHODS
            }
        return series, summary

    return summarize


for _id, _x, _unit, _cls, _scales, _run in (
    ("fig5.6", "observed trajectories", "", RewardVsDataSettings, SCALES_5_6, _fig56_trial),
    ("fig5.7", "torque noise", " std (N m)", RewardVsNoiseSettings, SCALES_5_7, _fig57_trial),
):
    register(
        Experiment(
            id=_id,
            title=f"Balancing: expected-reward error vs {_x}, embedding vs GP",
            settings_class=_cls,
            settings=_scales,
            run_trial=_run,
            summarize=_reward_summary(_x + _unit, _id),
            trials={"smoke": 1, "quick": 1, "paper": 2},
        )
    )
