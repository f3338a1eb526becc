"""Chapter 4, learning with stochastic dynamics (Sec. 4.3.2.2, Fig. 4.8).

``fig4.8``: for one context–parameter pair (s, ω) of the stochastic pendulum, the RMSE against
the Monte Carlo R(s, ω) of averages of L real rollouts (model-free REPS: L = 1) and of L GP
model trajectories (GPREPS, Eq. 4.1). The thesis reports no result; our readings are in
``skillkit/data/claims/ch4.toml``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from skillkit.experiments.registry import Experiment, Series, register
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.models.gp import ExactGP, ForwardModel
from skillkit.search.model_rollouts import predict_trajectories
from skillkit.tasks import make
from skillkit.tasks.pendulum import THESIS_GAINS, Pendulum
from skillkit.trial import TrialContext
from skillkit.viz.series import trial_band

__all__ = ["StochasticRewardSettings", "block_rmse", "commanded_transitions"]

REWARD_LABEL = "trajectory reward R(τ, s) = −Σ_t (α_t² + 0.1 α̇_t²)"
REAL = "real rollouts"
MODEL = "GP model trajectories"


@dataclass(frozen=True)
class StochasticRewardSettings(Settings):
    """Settings of ``fig4.8`` (Sec. 4.3.2.2, Fig. 4.8; the stochastic pendulum)."""

    context: tuple[float, float] = setting(
        (float(np.pi / 2), 0.0), "Context s = [α₀, α̇₀] of the pair (rad, rad/s): horizontal."
    )
    gains: tuple[float, float] = setting(
        tuple(float(g) for g in THESIS_GAINS), "Parameters ω = K of the pair (Sec. 5.4 gains)."
    )
    control_noise: float = setting(1.5, "Std σ_u of the torque noise (N m).")
    horizon: int = setting(30, "Control steps T of every trajectory (Δt = 0.1 s).", minimum=1)
    n_real: int = setting(400, "Real rollouts of the pair (Monte Carlo R(s, ω)).", minimum=1)
    n_shown: int = setting(20, "Real and model trajectories drawn in the left panels.", minimum=1)
    n_train: int = setting(20, "Real rollouts of nearby pairs that train the GP.", minimum=1)
    train_context_halfwidth: tuple[float, float] = setting(
        (0.5, 1.0), "Half-widths of the training contexts' box around s (clipped).", minimum=0
    )
    train_gain_std: tuple[float, float] = setting(
        (0.5, 0.25), "Std of the training gains ω ~ N(K, diag(std²)).", minimum=0
    )
    n_model: int = setting(2000, "Model trajectories of the pair (blocks of L).", minimum=1)
    sample_sizes: tuple[int, ...] = setting(
        (1, 5, 25, 100), "Numbers L of trajectories averaged (Eq. 4.1), increasing."
    )
    n_bins: int = setting(30, "Bins of the reward histograms.", minimum=1)
    n_opt_steps: int = setting(100, "Hyper-parameter optimisation steps of the GP.", minimum=0)
    additive_noise: float = setting(
        1.0, "Additive-noise factor α: σ_add = α 10⁻² std(y) (Sec. 4.2.3).", minimum=0
    )

    def check(self) -> None:
        """Sizes the L-averages need and stochastic dynamics."""
        sizes = self.sample_sizes
        if not sizes or min(sizes) < 1 or list(sizes) != sorted(set(sizes)):
            raise ValueError(f"sample_sizes: expected increasing integers ≥ 1, got {sizes}")
        for name in ("n_model", "n_real"):
            if (n := getattr(self, name)) < 2 * max(sizes):
                raise ValueError(f"{name}: need at least two blocks of L = {max(sizes)}, got {n}")
        if not (noise := self.control_noise) > 0:
            raise ValueError(f"control_noise: the experiment needs stochastic σ_u > 0, got {noise}")


SCALES = scales(
    StochasticRewardSettings(),
    smoke=dict(
        horizon=10,
        n_real=60,
        n_shown=5,
        n_train=4,
        n_model=100,
        sample_sizes=(1, 5, 20),
        n_bins=10,
        n_opt_steps=5,
    ),
    paper=dict(n_real=1000, n_train=30, n_model=5000, n_opt_steps=150),
)


def commanded_transitions(
    task: Pendulum, trajectory, omega: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Transitions X (T, 2), U (T, 1), X_next (T, 2) of ``trajectory`` (a rollout of ``task``
    with gains ``omega`` (2,)), u_t the commanded torque clip(Kᵀx_t, −3, 3): the torque noise
    becomes part of the stochastic transition the model learns."""
    x, _, x_next = task.transitions(trajectory)
    policy = task.controller(np.asarray(omega, dtype=float)[None])
    with torch.no_grad():
        u = policy(0, torch.as_tensor(x), torch.zeros(len(x), dtype=torch.long)).numpy()
    return x, u, x_next


def block_rmse(samples: np.ndarray, L: int, target: float) -> float:
    """RMSE of the average of L samples as an estimate of ``target``:
    sqrt(mean_b (mean(block_b) − target)²) over the ⌊n / L⌋ consecutive blocks of L of
    ``samples`` (n,), 1 ≤ L ≤ n (ValueError otherwise)."""
    samples = np.asarray(samples, dtype=float)
    if samples.ndim != 1:
        raise ValueError(f"samples: expected a 1-D array, got shape {samples.shape}")
    if isinstance(L, bool) or int(L) != L or not 1 <= L <= samples.size:
        raise ValueError(f"L: expected an integer in [1, {samples.size}], got {L!r}")
    L = int(L)
    n_blocks = samples.size // L
    means = samples[: n_blocks * L].reshape(n_blocks, L).mean(1)
    return float(np.sqrt(np.mean((means - target) ** 2)))


def _run_trial(
    settings: StochasticRewardSettings, rng: np.random.Generator, trial: TrialContext
) -> dict:
    T = settings.horizon
    task = make("pendulum-stochastic", horizon=T, control_noise=settings.control_noise)
    s = task.check_context(settings.context, "context")
    omega = task.check_omega(settings.gains, "gains")
    trial.reset(total=3)
    # 1. the real reward distribution of the pair
    real_rewards = np.empty(settings.n_real)
    shown = []
    for i in range(settings.n_real):
        r, traj = task.evaluate(omega, s, rng)
        real_rewards[i] = r
        if i < settings.n_shown:
            shown.append(traj.states[:, 0])
    trial.update()
    # 2. the GP forward model from rollouts of nearby pairs
    hw = np.asarray(settings.train_context_halfwidth)
    lo = np.maximum(s - hw, task.context_low)
    hi = np.minimum(s + hw, task.context_high)
    X, U, Xn = [], [], []
    for _ in range(settings.n_train):
        s_i = lo + (hi - lo) * rng.random(2)
        w_i = omega + np.asarray(settings.train_gain_std) * rng.standard_normal(2)
        x, u, xn = commanded_transitions(task, task.rollout(w_i, s_i, rng), w_i)
        X.append(x), U.append(u), Xn.append(xn)
    gp = ExactGP(additive_noise=settings.additive_noise, n_steps=settings.n_opt_steps)
    model = ForwardModel(gp, target="delta")
    model.fit(np.concatenate(X), np.concatenate(U), np.concatenate(Xn), rng=rng)
    trial.update()
    # 3. model trajectories of the pair (Eq. 4.1)
    pred = predict_trajectories(
        task, model, omega[None], s[None], horizon=T, n_samples=settings.n_model, rng=rng
    )
    model_rewards = pred.rewards[0]
    r_mc = float(real_rewards.mean())
    trial.update()
    return {
        "times": task.dt * np.arange(T + 1),
        "real_alpha": np.array(shown),
        "model_alpha": pred.states[0, : settings.n_shown, :, 0],
        "real_rewards": real_rewards,
        "model_rewards": model_rewards,
        "rmse_real": np.array([block_rmse(real_rewards, L, r_mc) for L in settings.sample_sizes]),
        "rmse_model": np.array([block_rmse(model_rewards, L, r_mc) for L in settings.sample_sizes]),
        "n_data": int(sum(len(x) for x in X)),
        "noise_std": (  # the GP's noise std per output Δα, Δα̇, in raw units
            torch.sqrt(model.predictor.noise) * model.predictor.y_scale
        ).numpy(),
        "n_variance_clamped": int(pred.sampled.n_variance_clamped),
        "n_saturated": int(pred.sampled.n_saturated),
        "model_jitter": model.gp.diagnostics["jitter"],
        "model_stopped_early": model.gp.diagnostics["stopped_early"] or "",
    }


def _histogram(values: np.ndarray, edges: np.ndarray) -> list[float]:
    """Density of ``values`` on the bins ``edges``, values outside counted in the outer bins."""
    counts, _ = np.histogram(np.clip(values, edges[0], edges[-1]), bins=edges)
    return (counts / (values.size * np.diff(edges))).tolist()


def _paths(times: np.ndarray, curves: np.ndarray) -> tuple[list, list]:
    """Many curves as one series, separated by NaN gaps (one legend entry)."""
    x, y = [], []
    for c in curves:
        x += list(times) + [np.nan]
        y += list(c) + [np.nan]
    return x, y


def _summarize(settings: StochasticRewardSettings, trials: list[dict]) -> tuple[list[Series], dict]:
    sizes = list(settings.sample_sizes)
    real = np.concatenate([np.asarray(t["real_rewards"]) for t in trials])
    model = np.concatenate([np.asarray(t["model_rewards"]) for t in trials])
    r_mc = float(real.mean())
    se = float(real.std(ddof=1) / np.sqrt(real.size))
    sd = float(real.std(ddof=1))
    model_means = np.array([np.mean(t["model_rewards"]) for t in trials])
    times = np.asarray(trials[0]["times"])
    series = []
    for key, name, panel in (
        ("real_alpha", REAL, "real trajectories (same s, ω)"),
        ("model_alpha", MODEL, "model trajectories (same s, ω)"),
    ):
        x, y = _paths(times, np.asarray(trials[0][key]))
        series.append(Series(name, x, y, panel=panel, xlabel="time [s]", ylabel="angle α [rad]"))
    both = np.concatenate([real, model])
    lo_q, hi_q = np.percentile(both, [0.5, 99.5])
    edges = np.linspace(lo_q, hi_q, settings.n_bins + 1)
    centres = (0.5 * (edges[1:] + edges[:-1])).tolist()
    hist = {"real": _histogram(real, edges), "model": _histogram(model, edges)}
    top = max(max(hist["real"]), max(hist["model"]))
    panel = f"reward distribution ({real.size} real, {model.size} model trajectories)"
    hkw = dict(panel=panel, xlabel=REWARD_LABEL, ylabel="density [1/reward]")
    series += [
        Series(REAL, centres, hist["real"], kind="lines+markers", **hkw),
        Series(MODEL, centres, hist["model"], kind="lines+markers", **hkw),
        Series("R(s, ω), Monte Carlo (real)", [r_mc, r_mc], [0.0, top], **hkw),
        Series("R̂(s, ω), model average (Eq. 4.1)", [float(model.mean())] * 2, [0.0, top], **hkw),
    ]
    ekw = dict(panel="error of the L-trajectory average", xlabel="L (trajectories averaged)")
    ekw.update(ylabel="RMSE of the estimate of R(s, ω)", log_x=True, log_y=True)
    for key, name in (
        ("rmse_real", "average of L real rollouts (L = 1: model-free REPS)"),
        ("rmse_model", "average of L GP model trajectories (GPREPS)"),
    ):
        m, band = trial_band(np.array([t[key] for t in trials]))
        series.append(Series(name, sizes, m, kind="lines+markers", **band, **ekw))
    series.append(Series("noise floor: s.e. of R_MC", sizes, [se] * len(sizes), **ekw))
    rmse_real = np.mean([t["rmse_real"] for t in trials], axis=0)
    rmse_model = np.mean([t["rmse_model"] for t in trials], axis=0)
    summary = {
        "context": list(settings.context),
        "gains": list(settings.gains),
        "expected_reward_mc": r_mc,
        "expected_reward_mc_se": se,
        "n_real_rollouts": int(real.size),
        "single_rollout_std": sd,
        "single_rollout_std_over_abs_expected": sd / abs(r_mc),
        "single_rollout_range": [float(real.min()), float(real.max())],
        "model_expected_reward": float(model_means.mean()),
        "model_expected_reward_per_trial": model_means.tolist(),
        "model_expected_reward_error": float(model_means.mean() - r_mc),
        "model_reward_std": float(model.std(ddof=1)),
        "n_model_trajectories": int(model.size),
        "sample_sizes": sizes,
        "rmse_real_L": dict(zip(map(str, sizes), rmse_real.tolist(), strict=True)),
        "rmse_model_L": dict(zip(map(str, sizes), rmse_model.tolist(), strict=True)),
        "n_model_training_transitions": int(trials[0]["n_data"]),
        "model_noise_std": np.asarray(trials[0]["noise_std"]).tolist(),
        "n_variance_clamped": int(sum(t["n_variance_clamped"] for t in trials)),
        "model_stopped_early": [str(t["model_stopped_early"]) or None for t in trials],
        "model_jitter": max(float(t["model_jitter"]) for t in trials),
    }
    return series, summary


register(
    Experiment(
        id="fig4.8",
        title="Stochastic pendulum: single-rollout rewards vs the expected reward",
        settings_class=StochasticRewardSettings,
        settings=SCALES,
        run_trial=_run_trial,
        summarize=_summarize,
    )
)
