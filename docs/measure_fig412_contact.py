"""Why fig4.12's GPREPS stops improving: the table-tennis model at GPREPS's final policy.

For each trial of a fig4.12 run folder (``skillkit reproduce fig4.12 … --out RUN_ROOT``; its
``trials.npz`` keeps each trial's last reward model and policy history), roll the final policy
mean out on 40 fresh contexts and compare the last fitted :class:`TableTennisRewardModel` with
the simulator (:meth:`~skillkit.search.table_tennis_model.TableTennisRewardModel.heldout_errors`),
plus the correlation of the predicted expected rewards (L = 10) with the real rewards. Run from
the repository root::

    OMP_NUM_THREADS=1 python docs/measure_fig412_contact.py /work/runs/fig4.12-paper-s0

Measured on the paper run of issue #14 (3 trials, all in the "returning" stage):

* every one of the 40 final shots per trial hits the ball (contact SVM on the recorded inputs:
  100% right); bounce point 0.1 cm, racket 0.2 cm RMSE, incoming path 0.4 cm;
* model 5's landing point from the recorded contact inputs: 0.7 / 31 / 22 cm (median), and
  through the whole chain of predicted paths 1.8 / 26 / 23 cm — while the real shots land
  60 / 73 / 99 cm (median) from their targets;
* but the SVM applied to the *predicted* paths calls most of the 10 sampled strokes misses for
  25% / 20% / 50% of the 40 pairs (all real hits), each miss scored with the full penalty
  ‖b − p‖ = P = 2.29 m; the predicted
  expected rewards of the 40 final (s, ω) pairs correlate −0.09 / 0.16 / 0.33 with the real
  rewards, so they no longer rank the aiming that the remaining landing error needs.
"""

from __future__ import annotations

import sys
import warnings

import numpy as np

from skillkit.tasks import make
from skillkit.viz.model_layers import load_gpreps_run


def main(run_dir: str, n_contexts: int = 40, seed: int = 5) -> None:
    warnings.filterwarnings("ignore")
    task = make("table-tennis")
    for k in range(3):
        history, model = load_gpreps_run(run_dir, k)
        rng = np.random.default_rng(seed)
        s = task.sample_context(rng, n=n_contexts)
        w = np.atleast_2d(history.policies[-1].mean_of(s))
        trajs = [task.rollout(wi, si, rng=rng) for wi, si in zip(w, s, strict=True)]
        errors = model.heldout_errors(s, w, trajs, 10, rng)
        real = np.array([task.reward(t, si) for t, si in zip(trajs, s, strict=True)])
        pred = model.predict(s, w, 10, rng)
        p_real = np.array([t.info["landing_point"] for t in trajs])
        hit = np.array([t.info["hit"] for t in trajs])
        chain = np.linalg.norm(np.nanmean(pred.landing, axis=1) - p_real, axis=1)[hit]
        print(
            f"trial {k} ({model.stage}):",
            {name: round(float(v), 3) for name, v in errors.items()},
            f"chained landing error {np.nanmedian(chain):.3f} m,",
            f"real ‖b − p‖ {np.median(np.linalg.norm(p_real - s[:, 3:5], axis=1)):.3f} m,",
            f"corr(predicted, real reward) {np.corrcoef(pred.expected_rewards, real)[0, 1]:.3f}",
        )


if __name__ == "__main__":
    main(sys.argv[1])
