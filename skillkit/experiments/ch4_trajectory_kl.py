"""Sec. 4.2.4: trajectory-KL model learning (Eqs 4.5–4.16, Appendix B) against one-step ML.

``sec4.2.4`` fits a linear-Gaussian model and a FITC pseudo-data GP
(:mod:`skillkit.models.trajectory_kl`) by one-step ML and by the trajectory-KL dual on a
linear system with known truth, the pendulum and the 4-link robot, and scores closed-loop
multi-step errors and log-likelihoods on held-out trajectories.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from skillkit.experiments.registry import Experiment, Series, register
from skillkit.experiments.settings import Settings, scales, setting
from skillkit.experiments.store import flatten
from skillkit.models.trajectory_kl import (
    LinearGaussianTKL,
    PseudoDataGP,
    fit_one_step,
    fit_trajectory_kl,
    one_step_log_likelihood,
    trajectory_kl_objective,
)
from skillkit.tasks import make
from skillkit.tasks.balancing import X_UP
from skillkit.tasks.pendulum import THESIS_GAINS, TORQUE_LIMIT
from skillkit.trial import TrialContext

__all__ = ["TrajectoryKLSettings", "closed_loop_predictions", "linear_system"]

SYSTEMS = ("linear", "pendulum", "balancing")
CLASSES = ("linear", "fitc")
CLASS_LABELS = {"linear": "linear-Gaussian", "fitc": "FITC pseudo-data GP"}
DIVERGED = 100.0  # mean squared error (training-std units) of a diverged prediction

# The linear system with known truth (data come from the model class).
LIN_A = np.array([[0.95, 0.10], [-0.10, 0.90]])
LIN_B = np.array([[0.05], [0.20]])
LIN_C = np.array([0.05, -0.02])
LIN_VAR = np.array([0.01, 0.02])
LIN_K = np.array([[-0.5, -0.3]])


@dataclass(frozen=True)
class TrajectoryKLSettings(Settings):
    """Settings of ``sec4.2.4`` (trajectory-KL model learning, Sec. 4.2.4, App. B)."""

    systems: tuple[str, ...] = setting(
        SYSTEMS, "Data sets: 'linear' (known truth), 'pendulum' (Sec. 5.4), 'balancing'."
    )
    n_train: int = setting(40, "Training trajectories M per data set (Eq. 4.16).", minimum=2)
    n_test: int = setting(40, "Held-out trajectories per data set.", minimum=1)
    horizon: int = setting(20, "Time steps T per trajectory (states x_1 … x_T).", minimum=3)
    linear_excitation: float = setting(0.5, "σ of ξ_t and a_i of the linear system.", minimum=0)
    pendulum_control_noise: float = setting(0.05, "σ_u of the pendulum (Sec. 5.4).", minimum=0)
    balancing_initial_std: float = setting(0.1, "σ of N(x_up, σ² I), as tab4.2.", minimum=0)
    balancing_excitation: float = setting(30.0, "σ_ξ (N m) of the torques, as tab4.2.", minimum=0)
    n_inducing: int = setting(20, "Pseudo-inputs per output of the FITC GP.", minimum=1)
    cross: bool = setting(False, "Quadratic features with x_i x_j (else squares, as B.7).")
    ridges: tuple[float, ...] = setting(
        (0.0, 0.1), "λ of the dual: 0 hard feature constraints (thesis), > 0 soft ones.", minimum=0
    )
    ml_iterations: int = setting(300, "L-BFGS iterations of one-step ML (FITC).", minimum=1)
    tkl_iterations: int = setting(100, "Outer L-BFGS iterations of trajectory KL.", minimum=1)
    inner_iterations: int = setting(100, "Newton iterations of each inner max over γ.", minimum=1)
    n_samples: int = setting(50, "Sampled trajectories per held-out start.", minimum=2)

    def check(self) -> None:
        """Known systems; ridges with 0 first (the claims spec reads λ = 0)."""
        if not self.systems or not set(self.systems) <= set(SYSTEMS):
            raise ValueError(f"systems: expected a subset of {SYSTEMS}, got {self.systems}")
        if not self.ridges or self.ridges[0] != 0.0 or any(r < 0 for r in self.ridges):
            raise ValueError(f"ridges: expected 0 first, then values ≥ 0, got {self.ridges}")


# --------------------------------------------------------------------------- data
@dataclass(frozen=True)
class TrajectoryData:
    """Observed trajectories: states (M, T, n), controls (M, T − 1, m), the feedback gains
    (M, m, n) of κ_i(x) = clip(K_i (x − x_ref) + offset, ±u_limit) (u_limit inf: none) and
    the failed rollouts replaced while collecting."""

    states: np.ndarray
    controls: np.ndarray
    gains: np.ndarray
    x_ref: np.ndarray
    u_limit: float
    n_failed: int = 0

    def transitions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, u, x′) stacked, shapes (M(T−1), n), (M(T−1), m), (M(T−1), n)."""
        X, n = self.states, self.states.shape[-1]
        u = self.controls.reshape(-1, self.controls.shape[-1])
        return X[:, :-1].reshape(-1, n), u, X[:, 1:].reshape(-1, n)


def linear_system(n: int, horizon: int, excitation: float, rng: np.random.Generator):
    """``n`` trajectories (:class:`TrajectoryData`) of the linear-Gaussian system with known
    truth (LIN_*): u_t = K x_t + a_i s_t + ξ_t with s_t = sin(2πt/7) + cos(2πt/11.3),
    a_i ~ N(1, σ²), ξ_t ~ N(0, σ²) (σ = ``excitation``), x_1 ~ N(0, I); the common
    multi-sine makes A, B and c identifiable from feature averages."""
    T = horizon
    s = np.sin(2 * np.pi * np.arange(T) / 7) + np.cos(2 * np.pi * np.arange(T) / 11.3)
    X = np.zeros((n, T, 2))
    U = np.zeros((n, T - 1, 1))
    X[:, 0] = rng.standard_normal((n, 2))
    a = 1.0 + excitation * rng.standard_normal(n)
    for t in range(T - 1):
        U[:, t] = X[:, t] @ LIN_K.T + (a * s[t])[:, None] + excitation * rng.standard_normal((n, 1))
        w = np.sqrt(LIN_VAR) * rng.standard_normal((n, 2))
        X[:, t + 1] = X[:, t] @ LIN_A.T + U[:, t] @ LIN_B.T + LIN_C + w
    return TrajectoryData(X, U, np.broadcast_to(LIN_K, (n, 1, 2)).copy(), np.zeros(2), np.inf)


def _data(system: str, n: int, st: TrajectoryKLSettings, rng) -> TrajectoryData:
    """``n`` trajectories of ``system`` (rollouts that topple the robot are replaced, counted)."""
    if system == "linear":
        return linear_system(n, st.horizon, st.linear_excitation, rng)
    if system == "pendulum":
        task = make("pendulum", horizon=st.horizon - 1, control_noise=st.pendulum_control_noise)
        G, x_ref, u_limit = THESIS_GAINS[None], np.zeros(2), TORQUE_LIMIT

        def rollout():
            return task.rollout(THESIS_GAINS, task.sample_context(rng), rng)
    else:
        task = make(
            "balancing",
            initial_std=st.balancing_initial_std,
            excitation_std=st.balancing_excitation,
            n_steps=st.horizon - 1,
        )
        G, x_ref, u_limit = task.pd_gain(), X_UP.copy(), np.inf

        def rollout():
            return task.rollout(G.ravel(), rng=rng)

    X, U, failed = [], [], 0
    while len(X) < n:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            traj = rollout()
        if traj.failed:
            failed += 1
            if failed > n:
                raise RuntimeError(f"{system}: {failed} rollouts failed for {len(X)} kept")
            continue
        X.append(traj.states)
        U.append(traj.controls[:-1])
    gains = np.broadcast_to(G, (n, *G.shape)).copy()
    return TrajectoryData(np.array(X), np.array(U), gains, x_ref, u_limit, failed)


# --------------------------------------------------------------------------- evaluation
def closed_loop_predictions(model, theta, data: TrajectoryData, n_samples: int, rng):
    """Mean prediction x̂_t (M, T, n) and ``n_samples`` sampled trajectories (L, M, T, n) of
    ``model`` at ``theta`` from each observed x₁, the feedback acting on the predicted state
    and the recorded excitation replayed: û_t = clip(K_i(x̂_t − x_ref) + ξ_{i,t}, ±u_limit).
    """
    X = data.states  # the replayed excitation ξ_{i,t} = u_{i,t} − K_i (x_{i,t} − x_ref):
    xi = data.controls - np.einsum("imn,itn->itm", data.gains, X[:, :-1] - data.x_ref)
    M, T, n = X.shape

    def control(x, t, rows):
        u = np.einsum("imn,in->im", data.gains[rows], x - data.x_ref) + xi[rows, t]
        return np.clip(u, -data.u_limit, data.u_limit)

    rows = np.arange(M)
    mean = np.empty_like(X)
    mean[:, 0] = X[:, 0]
    samples = np.empty((n_samples, M, T, n))
    samples[:, :, 0] = X[None, :, 0]
    rows_s = np.tile(rows, n_samples)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for t in range(T - 1):
            xm = np.nan_to_num(mean[:, t], nan=1e6, posinf=1e6, neginf=-1e6).clip(-1e6, 1e6)
            mu, _, _ = model.moments(theta, xm, control(xm, t, rows))
            mean[:, t + 1] = mu
            xs = samples[:, :, t].reshape(-1, n)
            xs = np.nan_to_num(xs, nan=1e6, posinf=1e6, neginf=-1e6).clip(-1e6, 1e6)
            mu, var, _ = model.moments(theta, xs, control(xs, t, rows_s))
            draw = mu + np.sqrt(var) * rng.standard_normal(mu.shape)
            samples[:, :, t + 1] = draw.reshape(n_samples, M, n)
    return mean, samples


def _scores(model, theta, data: TrajectoryData, scale: np.ndarray, n_samples: int, rng) -> dict:
    """Multi-step error per step, trajectory and one-step log-likelihoods of one θ."""
    mean, samples = closed_loop_predictions(model, theta, data, n_samples, rng)
    return _score_predictions(mean, samples, data, scale) | {
        "one_step_ll": one_step_log_likelihood(model, theta, *data.transitions())
    }


def _score_predictions(mean, samples, data: TrajectoryData, scale) -> dict:
    X = data.states
    with np.errstate(all="ignore"):
        err = np.mean(((mean - X) / scale) ** 2, axis=-1)  # (M, T)
        per_step = np.mean(err, axis=0)[1:]
        err_value = float(np.mean(err[:, 1:]))
        per_traj = np.nan_to_num(np.mean(err[:, 1:], axis=1), nan=np.inf)
        out = {
            "multistep_error": err_value if np.isfinite(err_value) else float("inf"),
            "multistep_error_median": float(np.median(per_traj)),
            "diverged": int(np.sum(per_traj > DIVERGED)),
            "final_error": float(per_step[-1]) if np.isfinite(per_step[-1]) else float("inf"),
            "error_per_step": np.where(np.isfinite(per_step), per_step, np.inf),
        }
        if samples is None:
            return out
        m = samples.mean(0)
        v = samples.var(0, ddof=1) + 1e-12 * scale**2
        ll = -0.5 * (np.log(2 * np.pi * v) + (X - m) ** 2 / v)  # (M, T, n)
        ll = float(np.mean(ll[:, 1:].sum(axis=(1, 2))))
    out["trajectory_ll"] = ll if np.isfinite(ll) else float("-inf")
    return out


def _fit_and_score(system, cls, train, test, scale, st, rng, trial) -> dict:
    x, u, y = train.transitions()
    n, m = x.shape[1], u.shape[1]
    if cls == "linear":
        model = LinearGaussianTKL(n, m)
    else:  # prior mean: the least-squares linear fit (fixed, shared by ML and TKL)
        W, *_ = np.linalg.lstsq(np.hstack([x, u, np.ones((x.shape[0], 1))]), y, rcond=None)
        model = PseudoDataGP(n, m, min(st.n_inducing, x.shape[0]), mean_weights=W)
    t0 = time.perf_counter()
    theta0 = model.init_theta(x, u, y, rng)
    if cls == "linear":  # closed form: least squares and residual variances are the MLE
        theta_ml, ml_iters = theta0, 0
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            fit = fit_one_step(model, theta0, x, u, y, maxiter=st.ml_iterations)
        theta_ml, ml_iters = fit.theta, fit.n_iterations
    out: dict = {"ml": {"time_s": time.perf_counter() - t0, "iterations": ml_iters}}
    out["ml"].update(_scores(model, theta_ml, test, scale, st.n_samples, rng))
    out["ml"] |= {"dual_objective": _objective(model, theta_ml, train, st, 0.0), "theta": theta_ml}
    trial.update()
    for ridge in st.ridges:
        key = _tkl_key(ridge)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            fit = fit_trajectory_kl(
                model, theta_ml, ridge=ridge, maxiter=st.tkl_iterations, **_dual_args(train, st)
            )
        out[key] = {
            "time_s": time.perf_counter() - t0,
            "iterations": fit.n_iterations,
            "objective": fit.objective,
            "objective_at_ml": _objective(model, theta_ml, train, st, ridge),
            "dual_objective": _objective(model, fit.theta, train, st, 0.0),
            "kl_total": float(np.sum(fit.kl)),
            "feature_residual": fit.feature_residual,
            "moved": float(np.max(np.abs(fit.theta - theta_ml))),
            "theta": fit.theta,
            "message": fit.message,
        }
        out[key].update(_scores(model, fit.theta, test, scale, st.n_samples, rng))
        trial.update()
    if system == "linear" and cls == "linear":
        truth = model.pack(LIN_A, LIN_B, LIN_C, LIN_VAR)
        out["truth"] = _scores(model, truth, test, scale, st.n_samples, rng)
        out["truth"]["dual_objective"] = _objective(model, truth, train, st, 0.0)
        for key in _methods(st):
            out[key].update(_parameter_error(model, out[key]["theta"]))
    for key in out:
        out[key].pop("theta", None)
    return out


def _objective(model, theta, data: TrajectoryData, st: TrajectoryKLSettings, ridge) -> float:
    """D(θ) = max_γ g on the training trajectories (inf when the inner maximum diverges)."""
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        value = trajectory_kl_objective(model, theta, ridge=ridge, **_dual_args(data, st))[0]
    return float(value) if np.isfinite(value) and value < 1e6 else float("inf")


def _dual_args(d: TrajectoryData, st: TrajectoryKLSettings) -> dict:
    """Trajectories and fixed options of the dual of Eq. 4.16."""
    return dict(
        states=d.states, controls=d.controls, cross=st.cross, inner_maxiter=st.inner_iterations
    )


def _parameter_error(model: LinearGaussianTKL, theta) -> dict:
    A, B, c, v = model.unpack(theta)
    dyn = np.concatenate([(A - LIN_A).ravel(), (B - LIN_B).ravel(), c - LIN_C])
    return {
        "dynamics_error_max": float(np.max(np.abs(dyn))),
        "noise_log_var_error_max": float(np.max(np.abs(np.log(v / LIN_VAR)))),
    }


def run_trial(st: TrajectoryKLSettings, rng: np.random.Generator, trial: TrialContext) -> dict:
    """Every data set (one checkpoint each): data, the trivial predictor, and per model class
    one-step ML and trajectory-KL training for every λ, scored on held-out trajectories."""
    per_system = len(CLASSES) * (1 + len(st.ridges))
    trial.reset(total=len(st.systems) * per_system)
    done = dict(trial.resume("sec4.2.4", rng) or {})
    trial.update(len(done) * per_system)
    for system in st.systems:
        if system in done:
            continue
        train = _data(system, st.n_train, st, rng)
        test = _data(system, st.n_test, st, rng)
        scale = train.states.reshape(-1, train.states.shape[-1]).std(0)
        scale = np.where(scale > 0, scale, 1.0)
        mean_traj = np.broadcast_to(train.states.mean(0), test.states.shape)
        res: dict = {
            "trivial": _score_predictions(mean_traj, None, test, scale),
            "n_failed_rollouts": train.n_failed + test.n_failed,
        }
        for cls in CLASSES:
            trial.set_postfix(system=system, model=cls)
            res[cls] = _fit_and_score(system, cls, train, test, scale, st, rng, trial)
        done[system] = res
        trial.save("sec4.2.4", done, rng)
    return flatten(done)


def _unflatten(flat: dict) -> dict:
    """The inverse of :func:`skillkit.experiments.store.flatten`."""
    tree: dict = {}
    for name, value in flat.items():
        *path, leaf = name.split(".")
        node = tree
        for part in path:
            node = node.setdefault(part, {})
        node[leaf] = value
    return tree


# --------------------------------------------------------------------------- summary
METRICS = tuple(
    "multistep_error multistep_error_median diverged final_error trajectory_ll one_step_ll "
    "dual_objective time_s iterations dynamics_error_max noise_log_var_error_max kl_total "
    "feature_residual moved objective objective_at_ml".split()
)


def _methods(st: TrajectoryKLSettings) -> dict[str, str]:
    """The compared trainings: key → label."""
    out = {"ml": "one-step ML"}
    for r in st.ridges:
        out[_tkl_key(r)] = (
            "trajectory-KL (λ = 0, thesis)" if r == 0 else f"trajectory-KL (λ = {r:g})"
        )
    return out


def _tkl_key(ridge: float) -> str:
    """``tkl_0``, ``tkl_0p1``, … (no dots: the per-trial numbers are flattened on dots)."""
    return f"tkl_{ridge:g}".replace(".", "p")


def _mean(values) -> float | None:
    arr = np.asarray([np.nan if v is None else v for v in values], dtype=float)
    if arr.size == 0 or np.all(np.isnan(arr)):
        return None
    value = float(np.nanmean(arr))
    return value if np.isfinite(value) else None


def summarize(st: TrajectoryKLSettings, trials: list[dict]):
    series: list[Series] = []
    summary: dict = {"n_trials": len(trials), "cells": {}}
    T = st.horizon
    for system in st.systems:
        runs = [_unflatten(t)[system] for t in trials]
        trivial = _mean([r["trivial"]["multistep_error"] for r in runs])
        cell_sys: dict = {"trivial_multistep_error": trivial}
        panel = f"{system}: multi-step error on held-out trajectories"
        kw = dict(panel=panel, xlabel="time step t", ylabel="squared error (training std² units)")
        for cls in CLASSES:
            cell: dict = {}
            labels = _methods(st) | ({"truth": "true model"} if "truth" in runs[0][cls] else {})
            for key, label in labels.items():
                cell[key] = {
                    m: _mean([r[cls][key].get(m) for r in runs])
                    for m in METRICS
                    if m in runs[0][cls][key]
                }
                cell[key]["multistep_error_per_trial"] = [
                    None if v is None or not np.isfinite(v) else float(v)
                    for v in (r[cls][key].get("multistep_error") for r in runs)
                ]
                curve = np.mean([r[cls][key]["error_per_step"] for r in runs], axis=0)
                y = [float(v) if np.isfinite(v) else None for v in curve]
                name = f"{CLASS_LABELS[cls]}, {label}"
                series.append(Series(name, list(range(2, T + 1)), y, log_y=True, **kw))
            ml, tkl = cell["ml"]["multistep_error"], cell["tkl_0"]["multistep_error"]
            cell["tkl_over_ml"] = None if ml is None or tkl is None or ml == 0 else tkl / ml
            lower = [
                r[cls]["tkl_0"]["multistep_error"] < r[cls]["ml"]["multistep_error"] for r in runs
            ]
            cell["tkl_lower_trials"] = int(sum(lower))
            cell_sys[cls] = cell
        cell_sys["failed_rollouts_replaced"] = int(sum(r["n_failed_rollouts"] for r in runs))
        series.append(
            Series("trivial: training mean trajectory", [2, T], [trivial, trivial], panel=panel)
        )
        summary["cells"][system] = cell_sys
    return series, summary


# --------------------------------------------------------------------------- registration
# The thesis reports no experiment for Sec. 4.2.4: paper is our largest setting.
_SCALES = scales(
    TrajectoryKLSettings(),
    smoke=dict(
        n_train=6,
        n_test=4,
        horizon=6,
        n_inducing=5,
        ml_iterations=20,
        tkl_iterations=5,
        inner_iterations=50,
        n_samples=5,
        ridges=(0.0, 0.1),
    ),
    paper=dict(n_train=100, n_test=100),
)

register(
    Experiment(
        id="sec4.2.4",
        title="Trajectory-KL model learning (4.10–4.16, App. B) vs one-step ML",
        settings_class=TrajectoryKLSettings,
        settings=_SCALES,
        run_trial=run_trial,
        summarize=summarize,
        trials={"smoke": 1, "quick": 1, "paper": 5},
    )
)
