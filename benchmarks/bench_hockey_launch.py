"""Hockey GPREPS model choices measured on the stored paper runs' own shots.

Run ``OMP_NUM_THREADS=1 python benchmarks/bench_hockey_launch.py``. It reads the training sets
of trial 0's GPs of the ``fig4.10`` and ``fig4.11`` paper runs stored at commit 8fccd66
(``benchmarks/data/hockey_training_sets.npz``, see :data:`DATA`) and reports:

1. **launch targets**: 5-fold cross-validated error of the launch GP's predictive mean on the
   shots (the thesis's ~120-shot budget) for the targets [p_y, v_x, v_y, t_0] ("velocity"),
   [p_y, heading, speed, t_0] ("heading") and [p_y, heading, log speed, t_0];
2. **displacement model** (fig4.11's real setting): 5-fold CV RMSE of the target puck's
   displacement vector and of its length for a constant predictor, one GP on all approaches
   (``displacement="gp"``) and the hit/miss classifier with a GP on the hits
   (``"hit_gp"``; point prediction P(hit) × the GP's mean), and the classifier's accuracy;
3. **refit cost**: the launch GP refitted on all shots from the fit on all but the last 10,
   cold vs best-of-both, wall time and log marginal likelihood.

Folds are drawn with a fixed seed; one fit per fold (cold start, L-BFGS, 100 steps).
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np

from skillkit.models.gp import ExactGP
from skillkit.models.reward import refit_gp
from skillkit.tasks.hockey.model import DisplacementModel, LaunchTargets, approach_frame

DATA = Path(__file__).resolve().parent / "data" / "hockey_training_sets.npz"
"""Trial 0's training sets of the fig4.10 and fig4.11 paper runs stored at commit 8fccd66 (with
velocity launch targets and the world-frame displacement GP), from their reward models:
``<run>__<gp>__X`` and ``__Y`` (targets de-standardised, so they carry the fit's small additive
noise, α·1% of their spread). Launch targets are [p_y, v_x, v_y, t_0]."""


def stored_training_sets(run: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{GP name: (X, Y)} of ``run`` ("fig4.10" or "fig4.11") from :data:`DATA`."""
    with np.load(DATA) as z:
        names = {k.split("__")[1] for k in z.files if k.startswith(f"{run}__")}
        return {n: (z[f"{run}__{n}__X"], z[f"{run}__{n}__Y"]) for n in sorted(names)}


def _folds(n: int, k: int = 5, seed: int = 0) -> list[np.ndarray]:
    return np.array_split(np.random.default_rng(seed).permutation(n), k)


def _fit(x, y, seed=0):
    return ExactGP(n_steps=100).fit(x, y, np.random.default_rng(seed))


def launch_cv(X: np.ndarray, state: np.ndarray) -> dict[str, dict[str, float]]:
    """5-fold CV errors of heading (°), speed (m/s), p_y (mm), t_0 (ms) per target choice;
    ``state`` is [p_y, v_x, v_y, t_0] (N, 4)."""
    truth = LaunchTargets("heading").encode(state)
    out = {}
    for name in ("velocity", "heading", "heading_logspeed"):
        kind = "heading" if name == "heading_logspeed" else name
        targets = LaunchTargets(kind).encode(state)
        if name == "heading_logspeed":
            targets[:, 2] = np.log(targets[:, 2])
        pred = np.zeros_like(targets)
        t0 = time.perf_counter()
        for te in _folds(len(X)):
            tr = np.setdiff1d(np.arange(len(X)), te)
            pred[te] = _fit(X[tr], targets[tr]).predict(X[te])[0]
        if name == "heading_logspeed":
            pred[:, 2] = np.exp(pred[:, 2])
        p = LaunchTargets("heading").encode(LaunchTargets(kind).decode(pred))
        rms = np.sqrt(np.mean((p - truth) ** 2, axis=0))
        out[name] = {
            "heading_deg": float(np.degrees(rms[1])),
            "speed": float(rms[2]),
            "p_y_mm": float(1e3 * rms[0]),
            "t0_ms": float(1e3 * rms[3]),
            "seconds": time.perf_counter() - t0,
        }
    return out


def displacement_cv(X: np.ndarray, Y: np.ndarray) -> dict[str, dict[str, float]]:
    """5-fold CV RMSE of the target displacement vector and its length (m) per model."""
    out = {}
    for name in ("constant", "gp", "hit_gp"):
        pred = np.zeros((len(X), 2))
        correct = []
        for te in _folds(len(X)):
            tr = np.setdiff1d(np.arange(len(X)), te)
            if name == "constant":
                pred[te] = Y[tr, :2].mean(axis=0)
                continue
            m = DisplacementModel(name)
            m.fit_classifier(X[tr], Y[tr])
            gx, gy = m.gp_data(X[tr], Y[tr])
            m.gp = _fit(gx, gy)
            if name == "gp":
                pred[te] = m.gp.predict(X[te])[0][:, :2]
                continue
            p = m.hit_probability(X[te])
            correct.append((p > 0.5) == m.hits(Y[te]))
            feats, R = approach_frame(X[te])
            local = m.gp.predict(feats)[0][:, :2]
            pred[te] = p[:, None] * np.einsum("nji,nj->ni", R, local)
        err = np.linalg.norm(pred - Y[:, :2], axis=1)
        err_len = np.linalg.norm(pred, axis=1) - np.linalg.norm(Y[:, :2], axis=1)
        out[name] = {
            "rmse_vector": float(np.sqrt(np.mean(err**2))),
            "mean_error": float(err.mean()),
            "rmse_length": float(np.sqrt(np.mean(err_len**2))),
        }
        if correct:
            out[name]["hit_accuracy"] = float(np.mean(np.concatenate(correct)))
    return out


def refit_cost(X: np.ndarray, targets: np.ndarray, repeats: int = 3) -> dict[str, dict]:
    """Wall time and log ML of refitting the launch GP on all shots after a fit on all but
    the last 10 (the previous update's hyper-parameters), cold vs best; median of repeats."""
    prev = _fit(X[:-10], targets[:-10]).hyperparameters
    out = {}
    for mode in ("cold", "best"):
        times = []
        for i in range(repeats):
            t0 = time.perf_counter()
            _, record = refit_gp(
                lambda: ExactGP(n_steps=100), X, targets, np.random.default_rng(i), prev, mode
            )
            times.append(time.perf_counter() - t0)
        out[mode] = {"seconds": float(np.median(times)), **record}
    return out


def main() -> None:
    warnings.simplefilter("ignore")
    for run in ("fig4.10", "fig4.11"):
        data = stored_training_sets(run)
        X, state = data["launch"]
        print(f"{run}: launch GP, {len(X)} shots, 5-fold CV (RMS)")
        for name, r in launch_cv(X, state).items():
            print(
                f"  {name:17s} heading {r['heading_deg']:.2f}°  speed {r['speed']:.3f} m/s  "
                f"p_y {r['p_y_mm']:.1f} mm  t0 {r['t0_ms']:.1f} ms  ({r['seconds']:.1f} s)"
            )
        targets = LaunchTargets("heading").encode(state)
        for mode, r in refit_cost(X, targets).items():
            print(
                f"  refit {mode}: {r['seconds']:.2f} s, kept {r['start']}, log ML cold "
                f"{r['log_ml_cold']}, warm {r['log_ml_warm']}"
            )
        if "displacement" in data:
            X, Y = data["displacement"]
            print(f"{run}: displacement model, {len(X)} approaches, 5-fold CV")
            for name, r in displacement_cv(X, Y).items():
                acc = f"  hit accuracy {r['hit_accuracy']:.2f}" if "hit_accuracy" in r else ""
                print(
                    f"  {name:9s} RMSE {r['rmse_vector']:.3f} m (mean {r['mean_error']:.3f}), "
                    f"length RMSE {r['rmse_length']:.3f} m{acc}"
                )


if __name__ == "__main__":
    main()
