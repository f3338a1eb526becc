"""Is trajectory-KL training consistent where the truth is known: sec4.2.4's linear system?

Fits ``LinearGaussianTKL`` to M trajectories (T = 20) of ``sec4.2.4``'s linear system (data
from the model class) by one-step ML (least squares) and by trajectory-KL (λ = 0, the hard
feature constraints, and the soft λ = 0.1 variant), for M = 50 … 3200 and 8 seeds, with the
squares-only features (the experiment's default) and with the products (the unit test's). Run
from the repository root (≈ 2.5 min on one core)::

    OMP_NUM_THREADS=1 python benchmarks/bench_tkl_consistency.py

Printed per feature set, each cell the median [min–max] over seeds:

* ``max |ΔA|``, ``|ΔB|``, ``|Δc|``, ``|Δlogσ²|``: the largest absolute parameter error of each
  fit per M, the TKL λ = 0 / ML ratio of the medians, and the log-log slope of the medians
  against M (a consistent estimator's errors fall like 1/√M: −0.5);
* the multi-step excess: the closed-loop multi-step MSE over the true model's on 500 held-out
  trajectories, in % of it (quadratic in the parameter error: slope −1);
* the sample feature constraints (λ = 0): the RMS residual of
  r_t = mean_i φ(x_{i,t+1}) − mean_i ψ_{i,t}(θ) with uniform weights (standardised units) at the
  truth, the ML fit and the TKL fit, and √M times the truth's; the TKL fit's own (reweighted)
  residual; M·D(θ) at the truth and at the TKL fit (O(1) for a consistent fit; a limit other
  than the truth makes it grow ∝ M); the mean signed Δlog σ² of TKL and ML;
* σ²: √M times the RMS relative error of σ² predicted from the uniform-weight residual of the
  E[x′²] constraint, TKL's and ML's, and the correlation of the prediction with TKL's error;
  then RMS |μ| per state dimension and √2·RMS|μ|/σ, the predicted ratio of TKL's σ² error
  fluctuation (2 |μ| σ/√M) to ML's (σ²√2/√M).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from skillkit.experiments.ch4_trajectory_kl import (
    LIN_A,
    LIN_B,
    LIN_C,
    LIN_VAR,
    closed_loop_predictions,
    linear_system,
)
from skillkit.models.trajectory_kl import (
    LinearGaussianTKL,
    fit_trajectory_kl,
    gaussian_expected_features,
    state_features,
    trajectory_kl_objective,
)

SIZES = (50, 100, 200, 400, 800, 1600, 3200)
SEEDS = tuple(range(8))
HORIZON, EXCITATION, N_TEST = 20, 0.5, 500
METHODS = ("ML", "TKL λ=0", "TKL λ=0.1")
ERRORS = ("A", "B", "c", "logσ²", "excess%")


def parameter_errors(model: LinearGaussianTKL, theta: np.ndarray) -> list[float]:
    """Largest absolute errors of A, B, c and log σ² against the truth."""
    A, B, c, v = model.unpack(theta)
    return [
        float(np.max(np.abs(A - LIN_A))),
        float(np.max(np.abs(B - LIN_B))),
        float(np.max(np.abs(c - LIN_C))),
        float(np.max(np.abs(np.log(v / LIN_VAR)))),
    ]


def uniform_residual(model, theta, data, cross: bool) -> float:
    """RMS over t, features of mean_i φ(x_{i,t+1}) − mean_i ψ_{i,t}(θ) (uniform weights),
    in the dual's standardised feature units (the constraint 4.12 with p_t = q_t)."""
    phi = state_features(data.states, cross)  # (M, T, F)
    flat = phi.reshape(-1, phi.shape[-1])
    scale = np.where(flat.std(0) > 0, flat.std(0), 1.0)
    M, T, n = data.states.shape
    mean, var, _ = model.moments(
        theta, data.states[:, :-1].reshape(-1, n), data.controls.reshape(M * (T - 1), -1)
    )
    psi = gaussian_expected_features(mean, var, cross).reshape(M, T - 1, -1)
    r = (phi[:, 1:].mean(0) - psi.mean(0)) / scale
    return float(np.sqrt(np.mean(r**2)))


def one_data_set(M: int, seed: int, cross: bool) -> dict:
    """Errors of the three fits and the constraint diagnostics on one training set."""
    model = LinearGaussianTKL(2, 1)
    rng = np.random.default_rng(seed)
    train = linear_system(M, HORIZON, EXCITATION, rng)
    test = linear_system(N_TEST, HORIZON, EXCITATION, rng)
    truth = model.pack(LIN_A, LIN_B, LIN_C, LIN_VAR)
    th_ml = model.init_theta(*train.transitions())
    fits = {"ML": th_ml}
    info = {}
    for lam in (0.0, 0.1):
        f = fit_trajectory_kl(
            model, th_ml, train.states, train.controls, cross=cross, ridge=lam, maxiter=200
        )
        fits[f"TKL λ={lam:g}"] = f.theta
        info[lam] = f

    # Excess multi-step error, free of the held-out noise: the true model's closed-loop mean
    # μ*_t sees the same starts and replayed excitation, and x_t − μ*_t (process noise) is
    # independent of μ̂_t − μ*_t, so E‖x − μ̂‖² = E‖x − μ*‖² + E‖μ̂ − μ*‖².
    def mean_path(theta):
        return closed_loop_predictions(model, theta, test, 1, np.random.default_rng(0))[0][:, 1:]

    star = mean_path(truth)
    floor = float(np.mean((test.states[:, 1:] - star) ** 2))

    def excess(theta):
        return 100 * float(np.mean((mean_path(theta) - star) ** 2)) / floor

    out = {k: parameter_errors(model, th) + [excess(th)] for k, th in fits.items()}
    d_truth = trajectory_kl_objective(model, truth, train.states, train.controls, cross=cross)[0]
    out["diag"] = [
        uniform_residual(model, truth, train, cross),
        uniform_residual(model, th_ml, train, cross),
        uniform_residual(model, info[0.0].theta, train, cross),
        info[0.0].feature_residual,
        M * d_truth,
        M * info[0.0].objective,
        float(np.log(model.unpack(info[0.0].theta)[3] / LIN_VAR).mean()),
        float(np.log(model.unpack(th_ml)[3] / LIN_VAR).mean()),
    ]
    # σ² enters only E[x′_k²] = E[μ_k²] + σ_k²: at the truth the uniform-weight residual of
    # that constraint, averaged over t, is the noise TKL's σ_k² has to absorb.
    mean, _, _ = model.moments(truth, train.states[:, :-1].reshape(-1, 2),
                               train.controls.reshape(-1, 1))  # fmt: skip
    mean = mean.reshape(M, HORIZON - 1, 2)
    r_sq = (train.states[:, 1:] ** 2).mean(0) - (mean**2).mean(0) - LIN_VAR  # (T−1, n)
    out["sigma"] = np.stack([
        r_sq.mean(0) / LIN_VAR,  # predicted relative error of σ² (uniform over t)
        model.unpack(info[0.0].theta)[3] / LIN_VAR - 1,  # TKL's
        model.unpack(th_ml)[3] / LIN_VAR - 1,  # ML's
        np.sqrt((mean**2).mean((0, 1))),  # RMS predicted mean per dimension
    ])  # fmt: skip
    return out


def cell(values) -> str:
    v = np.asarray(values)
    return f"{np.median(v):.4f} [{v.min():.4f}–{v.max():.4f}]"


def main() -> None:
    t0 = time.time()
    for cross in (False, True):
        feats = "squares + products" if cross else "squares only (sec4.2.4 default)"
        print(f"\n=== features: {feats}; T = {HORIZON}, {len(SEEDS)} seeds, "
              f"median [min–max] ===")  # fmt: skip
        res = {M: [one_data_set(M, s, cross) for s in SEEDS] for M in SIZES}
        medians = {}
        for e, name in enumerate(ERRORS):
            print(f"\n  max |Δ{name}|" if e < 4 else "\n  multi-step excess over truth (%)")
            print(f"  {'M':>5}  " + "  ".join(f"{m:>26}" for m in METHODS) + "  TKL0/ML")
            for M in SIZES:
                vals = {m: [r[m][e] for r in res[M]] for m in METHODS}
                for m in METHODS:
                    medians[(m, e, M)] = float(np.median(vals[m]))
                ratio = medians[("TKL λ=0", e, M)] / max(medians[("ML", e, M)], 1e-12)
                print(f"  {M:>5}  " + "  ".join(f"{cell(vals[m]):>26}" for m in METHODS)
                      + f"  {ratio:6.2f}")  # fmt: skip
            slopes = []
            for m in METHODS:
                y = np.log([max(medians[(m, e, M)], 1e-12) for M in SIZES])
                slopes.append(f"{m} {np.polyfit(np.log(SIZES), y, 1)[0]:+.2f}")
            print("  log-log slope vs M: " + ", ".join(slopes))
        print(
            "\n  sample constraints (λ = 0): RMS uniform-weight residual (std units) at truth /"
            " ML / TKL; TKL weighted residual; M·D(truth), M·D(TKL); mean Δlog σ² TKL, ML"
        )
        for M in SIZES:
            d = np.array([r["diag"] for r in res[M]])
            med = np.median(d, axis=0)
            print(f"  {M:>5}  r: {med[0]:.4f} / {med[1]:.4f} / {med[2]:.4f}  "
                  f"√M·r_truth {np.sqrt(M) * med[0]:.3f}  weighted {np.max(d[:, 3]):.0e}  "
                  f"M·D {med[4]:.2f}, {med[5]:.2f}  "
                  f"Δlogσ² {cell(d[:, 6])}, {cell(d[:, 7])}")  # fmt: skip
        sg = {M: np.array([r["sigma"] for r in res[M]]) for M in SIZES}  # (seeds, 4, n)
        print(
            "\n  σ² (λ = 0): √M·RMS over seeds and dims of the relative error of σ²: uniform-"
            "residual prediction, TKL, ML; corr(prediction, TKL)"
        )
        for M in SIZES:
            rel = sg[M]
            rms = np.sqrt(np.mean(rel[:, :3] ** 2, axis=(0, 2))) * np.sqrt(M)
            c = np.corrcoef(rel[:, 0].ravel(), rel[:, 1].ravel())[0, 1]
            print(f"  {M:>5}  {rms[0]:.2f}  {rms[1]:.2f}  {rms[2]:.2f}  corr {c:+.2f}")
        allp = np.concatenate([sg[M][:, 0].ravel() for M in SIZES])
        allt = np.concatenate([sg[M][:, 1].ravel() for M in SIZES])
        rmsmu = np.mean([sg[M][:, 3] for M in SIZES], axis=(0, 1))
        ratio = np.sqrt(2) * rmsmu / np.sqrt(LIN_VAR)
        print(f"  pooled corr {np.corrcoef(allp, allt)[0, 1]:+.2f}; RMS |μ| per dim "
              f"{rmsmu.round(2)}; √2·RMS|μ|/σ = {ratio.round(1)}")  # fmt: skip
        sys.stdout.flush()
    print(f"\n{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
