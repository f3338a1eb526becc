"""Chapter 4, GPREPS with discrete-event models on table tennis (Sec. 4.3.4).

The shared GPREPS plumbing (data schedule, scales, learning-curve and held-out evaluators) is
:mod:`skillkit.experiments.ch4_events`'s; this module holds table tennis's part.

* ``fig4.12`` — table tennis: GPREPS with the five models of 4.3.4
  (:class:`~skillkit.search.table_tennis_model.TableTennisRewardModel`, with the reward schedule
  of Eq. 4.17), GP direct, and contextual REPS with ``fig3.7``'s settings (and the fit
  regularisation of the stored run, ``ch3_table_tennis.REGULARISED``).
* ``fig4.13`` — table tennis: the five models, learned from 100 rollouts, against the
  simulator on held-out rollouts (10 sampled trajectories each).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from typing import Literal

import numpy as np

from skillkit.experiments.ch3_table_tennis import (
    REGULARISED,
    TableTennisSettings,
    make_reps,
    shot_scores,
)
from skillkit.experiments.ch4_events import (
    VIEWER_NOTE,
    EventGPREPSSettings,
    _curves,
    _final_stats,
    _gpreps_run,
    _gpreps_stats,
    _reps_run,
    _scales,
)
from skillkit.experiments.ch4_gpreps import rollouts_to_reach
from skillkit.experiments.claims import (
    NOT_RECORDED,
    conjunction,
    finite_or_none,
    is_less,
    own_check,
    parts_note,
)
from skillkit.experiments.registry import Experiment, Series, Verdict, fmt, register, with_verdict
from skillkit.experiments.settings import Settings, setting
from skillkit.models.gp import ExactGP
from skillkit.search.gpreps import DirectRewardModel
from skillkit.tasks import make
from skillkit.trial import TrialContext

__all__ = [
    "ModelAccuracySettings",
    "TableTennisGPREPSSettings",
    "TableTennisModelSettings",
    "table_tennis_reward_model",
]

THESIS_412 = {"gpreps_rollouts": 150, "gpreps_landing_error_m": 0.30, "reps_rollouts": 4000}
CLAIM_412 = (
    "On table tennis GPREPS with the five models consistently learns within 150 rollouts to "
    "return the ball within 30 cm of the target while avoiding the net; GP direct gets stuck "
    "(net, misses); REPS needs at least 4000 rollouts (Sec. 4.3.4, Fig. 4.12)."
)
CLAIM_413 = (
    "Learned from 100 rollouts, the five table-tennis models predict the incoming ball, the "
    "racket path and the returned landing points accurately against the simulator "
    "(Sec. 4.3.4, Fig. 4.13)."
)


# --------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class TableTennisModelSettings(Settings):
    """Model 5 and the refit of :class:`~skillkit.search.table_tennis_model.TableTennisRewardModel`
    as fig4.12 and fig4.13 use them (see :data:`TT_SETUP` for why)."""

    contact_features: Literal["thesis", "extended"] = setting(
        "extended",
        "Contact-model inputs: the thesis's ten (relative velocity, racket position and "
        "quaternion) or ours, with the ball's position relative to the racket and the distance "
        "(measured: the thesis's ten do not separate hits from misses here; TT_SETUP).",
    )
    contact_score: Literal["probability", "decision", "margin"] = setting(
        "probability",
        "Contact weight of a sampled path in its reward: the SVM's Platt-calibrated hit "
        "probability, its hard decision, or the decision softened inside its margin.",
    )
    refit: Literal["cold", "warm", "best"] = setting(
        "best",
        "GP hyper-parameters after each data collection (Sec. 4.1): cold, warm, or both "
        "keeping the larger marginal likelihood.",
    )


@dataclass(frozen=True)
class TableTennisGPREPSSettings(EventGPREPSSettings, TableTennisModelSettings):
    """Settings of ``fig4.12`` (table tennis; REPS with ``fig3.7``'s settings and the fit
    regularisation it was stored with,
    :data:`~skillkit.experiments.ch3_table_tennis.REGULARISED`)."""

    n_updates: int = setting(130, "GPREPS / GP-direct updates (N₀ + K = 150 rollouts).", minimum=1)
    schedule: Literal["auto", "hitting", "returning"] = setting(
        "auto",
        "Reward schedule of Eq. 4.17: 'auto' switches c₁ = c₂ once the contact model "
        "is good (see TableTennisRewardModel), or a forced 'hitting' / 'returning'.",
    )
    reps_updates: int = setting(
        80, "REPS updates (× 50 rollouts = 4000, the thesis's count).", minimum=1
    )


@dataclass(frozen=True)
class ModelAccuracySettings(TableTennisModelSettings):
    """Settings of ``fig4.13`` (the five table-tennis models against the simulator)."""

    n_rollouts: int = setting(
        100, "Rollouts of the initial policy the models learn from.", minimum=1
    )
    n_heldout: int = setting(20, "Held-out rollouts the predictions are compared with.", minimum=1)
    n_samples: int = setting(10, "Sampled trajectories per held-out (s, ω) (Fig. 4.13).", minimum=1)
    n_shown: int = setting(3, "Held-out rollouts drawn in the figure (hits first).", minimum=1)
    gp_steps: int = setting(100, "L-BFGS iterations of every GP's hyper-parameter fit.", minimum=0)


# --------------------------------------------------------------------------- models
def table_tennis_reward_model(task, st, schedule: str = "auto"):
    """The table-tennis reward model of GPREPS (Sec. 4.3.4) with ``st``'s GP fits and contact
    features, and the c₁ / c₂ ``schedule``
    (:class:`~skillkit.search.table_tennis_model.TableTennisRewardModel`)."""
    from skillkit.search.table_tennis_model import TableTennisRewardModel

    gp = partial(ExactGP, n_steps=st.gp_steps)
    return TableTennisRewardModel(
        task,
        make_landing_model=gp,
        make_bounce_model=gp,
        make_racket_model=gp,
        make_return_model=gp,
        schedule=schedule,
        contact_features=st.contact_features,
        contact_score=st.contact_score,
        refit=st.refit,
    )


# --------------------------------------------------------------------------- table tennis
def run_trial_412(st: TableTennisGPREPSSettings, rng: np.random.Generator, trial: TrialContext):
    """GPREPS (five models), GP direct and REPS on ``table-tennis`` from the imitation policy."""
    task = make("table-tennis")
    heldout = task.sample_context(rng, n=st.n_heldout)
    eval_contexts = task.sample_context(rng, n=st.n_eval_contexts)
    heldout_seed = int(rng.integers(2**63))
    seeds = rng.spawn(3)
    trial.reset(total=2 * st.n_updates + st.reps_updates)

    def score(policy) -> dict:
        return shot_scores(task, policy, heldout, heldout_seed)[0]

    out: dict = {}
    out.update(_gpreps_run(task, st, "gpreps", table_tennis_reward_model(task, st, st.schedule),
                           seeds[0], trial, eval_contexts, score, keep_model=True))  # fmt: skip
    direct = DirectRewardModel(ExactGP(n_steps=st.gp_steps))
    out.update(_gpreps_run(task, st, "direct", direct, seeds[1], trial, eval_contexts, score))
    # fig3.7's REPS with the fit regularisation the stored fig4.12 result was made with
    tt = replace(TableTennisSettings(), **REGULARISED)
    reps = make_reps(task, tt)
    every = max(1, st.reps_updates // 5)
    out.update(_reps_run(task, reps, "reps", st.reps_updates, tt.rollouts_per_update, seeds[2],
                         trial, eval_contexts, score, every))  # fmt: skip
    return out


TT_SCORES = ("reward", "returned", "net", "missed", "landing_error")


def summarize_412(st: TableTennisGPREPSSettings, trials: list[dict]):
    keys = ("gpreps", "direct", "reps")
    labels = {"gpreps": "GPREPS", "direct": "GP direct", "reps": "REPS (ε = 0.6)"}
    series = []
    for key in keys:
        series.append(_curves(trials, key, "rollouts", "mean_reward", labels[key],
                              "learning curves", "reward of the policy mean"))  # fmt: skip
        series.append(_curves(trials, key, "heldout_rollouts", "heldout_landing_error",
                              labels[key], "held-out landing error", "‖b − p‖ (m)"))  # fmt: skip
    summary: dict = {"n_trials": len(trials), "thesis_numbers": dict(THESIS_412)}
    for key in keys:
        summary[key] = _final_stats(trials, key, TT_SCORES)
    for key in ("gpreps", "direct"):
        summary[key].update(_gpreps_stats(trials, key))
    summary["reps_rollouts_to_gpreps_final_reward"] = rollouts_to_reach(
        trials, "reps", summary["gpreps"]["final_reward"], "heldout_reward", "heldout_rollouts"
    )
    summary["setup"] = _tt_setup(st)
    summary["variants"] = TT_VARIANTS
    summary["viewer"] = VIEWER_NOTE
    summary["claim_parts"] = claim_parts_412(summary)
    summary["own_checks"] = own_checks_412(summary)
    return series, with_verdict(summary, verdict_412(st, summary))


NET_412 = 0.05
"""The largest share of held-out shots into the net that counts as "avoiding hitting the ball
into the net" (fixed before the stored run)."""


def claim_parts_412(summary: dict) -> dict[str, bool | None]:
    """The thesis's sentences on Fig. 4.12 (Sec. 4.3.4), part by part, from ``summary``.

    * ``gpreps_within_150`` — "This behavior could be learned within 150 evaluations": GPREPS
      ends after N₀ + K ≤ 150 real rollouts;
    * ``gpreps_always_within_30cm`` — "GPREPS *always* provided a consistent performance, and
      the final policy was able to return the ball within 30cm of the target position" /
      "*consistently* provides high quality policies": in every trial the final policy mean's
      held-out landing error is below 30 cm;
    * ``gpreps_always_avoids_net`` — "while avoiding hitting the ball into the net": in every
      trial at most 5% of its held-out shots go into the net (:data:`NET_412`);
    * ``gpreps_outperforms_gp_direct`` — "GPREPS outperforms the other two algorithms": its
      final held-out reward is above GP direct's after as many rollouts;
    * ``gpreps_outperforms_reps`` — the same against REPS, on the figure's axis of
      evaluations: REPS needs more rollouts than GPREPS to reach GPREPS's final held-out
      reward (or never does);
    * ``gp_direct_stuck_net_or_miss`` — GP direct's policies "often get stuck in a local
      optima. Typically we observe policies that hit the ball to the net, or even miss the
      ball": GP direct's final share of shots into the net or missed is above GPREPS's.

    "Model-free REPS requires at least 4000 evaluations on average to learn a policy that
    consistently returns the ball" is reported (REPS's outcome after its rollouts), not judged:
    the thesis does not say what "consistently returns" is. A part is None where the summary
    lacks its numbers.
    """
    g, d = summary["gpreps"], summary["direct"]

    def every_trial(key: str, bound: float, strict: bool) -> bool | None:
        values = g.get(f"final_{key}_per_trial")
        if values is None:
            return None
        ok = [finite_or_none(v) for v in values]
        return bool(all(v is not None and (v < bound if strict else v <= bound) for v in ok))

    if "reps_rollouts_to_gpreps_final_reward" in summary:
        reached = summary["reps_rollouts_to_gpreps_final_reward"]
        beats_reps = reached is None or bool(reached > g["rollouts"])
    else:
        beats_reps = None
    return {
        "gpreps_within_150": bool(g["rollouts"] <= THESIS_412["gpreps_rollouts"]),
        "gpreps_always_within_30cm": every_trial(
            "landing_error", THESIS_412["gpreps_landing_error_m"], strict=True
        ),
        "gpreps_always_avoids_net": every_trial("net", NET_412, strict=False),
        "gpreps_outperforms_gp_direct": is_less(d["final_reward"], g["final_reward"]),
        "gpreps_outperforms_reps": beats_reps,
        "gp_direct_stuck_net_or_miss": is_less(
            g["final_net"] + g["final_missed"], d["final_net"] + d["final_missed"]
        ),
    }


RETURNED_412 = 0.9
"""Our own check's least share of held-out shots GPREPS returns in every trial (fixed before
the issue-#31 paper runs)."""


def own_checks_412(summary: dict) -> dict[str, dict]:
    """Our conditions beyond the thesis's sentences on Fig. 4.12 (shown beside the verdict,
    never deciding it; fixed before the issue-#31 paper runs):

    * ``gpreps_switched_every_trial`` — the reward schedule switched to c₁ = c₂ (the contact
      model became "good", :class:`~skillkit.search.table_tennis_model.TableTennisRewardModel`)
      in every trial: without the switch GPREPS never optimised the return;
    * ``gpreps_returns_90pct_every_trial`` — "consistently": in every trial GPREPS's final
      policy mean returns at least 90% of the held-out balls onto the opponent's half
      (:data:`RETURNED_412`).
    """
    g = summary["gpreps"]
    switched = g.get("switched_to_returning_at_update")  # _gpreps_stats (ch4_events)
    returned = g.get("final_returned_per_trial")
    return {
        "gpreps_switched_every_trial": own_check(
            None if switched is None else all(k is not None for k in switched),
            "the reward schedule switched to c₁ = c₂ in every trial (ours: the thesis's "
            "'after collecting enough samples to learn a good contact model' decided by "
            "the contact model's cross-validated accuracy)",
        ),
        "gpreps_returns_90pct_every_trial": own_check(
            None
            if returned is None
            else all(v is not None and np.isfinite(v) and v >= RETURNED_412 for v in returned),
            "in every trial GPREPS's final policy mean returns ≥ 90% of the held-out balls "
            "(ours: a bound for 'consistently')",
        ),
    }


def verdict_412(st: TableTennisGPREPSSettings, summary: dict) -> Verdict:
    """Judges the thesis's sentences on Fig. 4.12 (claims.THESIS["fig4.12"]).

    Criteria, fixed before the issue-#31 paper runs (the same as after issue #32; before that
    the landing error and the net share were means over trials, and REPS and GP direct's net
    or miss were not judged): holds if every part of :func:`claim_parts_412` holds —

    1. GPREPS ends after N₀ + K ≤ 150 real rollouts ("learned within 150 evaluations");
    2. in *every* trial its final policy mean's held-out landing error ‖b − p‖ (mean over
       the held-out contexts) is below 30 cm ("always … within 30cm of the target");
    3. in every trial at most 5% of its held-out shots go into the net (:data:`NET_412`;
       "avoiding hitting the ball into the net");
    4. its final held-out reward (mean over trials) is above GP direct's after as many
       rollouts, and REPS reaches it only after more rollouts than GPREPS used, or never
       ("outperforms the other two algorithms");
    5. GP direct's final share of held-out shots into the net or missed is above GPREPS's
       ("policies that hit the ball to the net, or even miss the ball").

    None if a part's numbers are missing and no other part fails. REPS's "at least 4000
    evaluations" is reported, not judged. Our stricter conditions are
    :func:`own_checks_412`. Reads ``summary`` only."""
    g, d, r = summary["gpreps"], summary["direct"], summary["reps"]

    def missing(v) -> bool:  # a landing error of no returned shot
        return v is None or not np.isfinite(v)

    def shots(s: dict) -> str:
        err = s["final_landing_error"]
        landing = "no shot returned" if missing(err) else f"landing error {100 * err:.0f} cm"
        return (
            f"{fmt(100 * s['final_returned'], '.0f')}% returned, "
            f"{fmt(100 * s['final_net'], '.0f')}% net, {fmt(100 * s['final_missed'], '.0f')}% "
            f"missed, {landing}, reward {fmt(s['final_reward'])}"
        )

    def per_trial(key: str, unit: str) -> str:
        values = g.get(f"final_{key}_per_trial")
        if values is None:
            return NOT_RECORDED
        return ", ".join("none" if missing(v) else f"{100 * v:.0f}" for v in values) + unit

    reached = summary.get("reps_rollouts_to_gpreps_final_reward", NOT_RECORDED)
    if reached is None:
        reached = "never reaching GPREPS's final reward"
    elif reached == NOT_RECORDED:
        reached = f"when it reaches GPREPS's final reward {NOT_RECORDED}"
    else:
        reached = f"reaching GPREPS's final reward after {fmt(reached, '.0f')} rollouts"
    parts = claim_parts_412(summary)
    return Verdict(
        CLAIM_412,
        conjunction(parts.values()),
        f"Held-out shots ({summary['n_trials']} trials): GPREPS after {g['rollouts']} "
        f"rollouts {shots(g)} (per trial: landing error {per_trial('landing_error', ' cm')}, "
        f"net {per_trial('net', '%')}); GP direct after {d['rollouts']} {shots(d)}; REPS after "
        f"{r['rollouts']} {shots(r)}, {reached} "
        "(thesis: GPREPS always within 30 cm and out of the net after 150, outperforming GP "
        "direct, which hits the net or misses, and REPS, which needs ≥ 4000)." + parts_note(parts),
    )


TT_SETUP = [
    {
        "item": "controller",
        "thesis": "DMP + tracking controller of the 8-DoF BioRob (SL)",
        "ours": "DMP + PD with bias compensation (MuJoCo), the task of fig3.7",
        "why": "the task of fig3.7",
    },
    {
        "item": "return zone",
        "thesis": "uniform on the opponent's side (C.3)",
        "ours": "the whole opponent's half (table-tennis)",
        "why": "as the thesis",
    },
    {
        "item": "models",
        "thesis": "five: incoming landing; bounce trajectory; racket position and quaternion "
        "(40 basis functions, GP ω → weights); linear SVM contact + GP landing point",
        "ours": "the same five (TableTennisRewardModel; scikit-learn's linear SVM)",
        "why": "as the thesis",
    },
    {
        "item": "contact event",
        "thesis": "'The input to the classifier is … at the time when the absolute distance "
        "between the racket and the ball is minimal' (Sec. 4.3.4)",
        "ours": "one function (contact_event) for real and predicted paths: the incoming ball "
        "ends where it first reaches the racket face (a real hit ends there; a predicted "
        "ball, without contact physics, would fly through); inputs at the minimal distance "
        "before that",
        "why": "before issue #31 predicted paths were read at the closest approach of the "
        "flown-through path, real ones before the hit (ball's x offset +0.11 cm vs +2.84 cm); "
        "measured on the stored trial 0's policies, model 5 from 30 rollouts: final policy "
        "predicted hit rate 0.83 (was 0.48, real 1.00), update-10 majority-vote contact "
        "accuracy 0.80 (was 0.43) (variants)",
    },
    {
        "item": "contact inputs",
        "thesis": "'the relative velocity of the ball and the racket, the position and "
        "orientation of the racket' (Sec. 4.3.4)",
        "ours": "contact_features='extended' (ours): these ten and the ball's position relative "
        "to the racket and the distance; 'thesis' is an option (the model's default)",
        "why": "here a hit is decided by where the ball passes the 8 cm disc, which the ten "
        "inputs do not contain: 5-fold balanced SVM accuracy 0.64–0.69 with the ten against "
        "0.93 extended (150 rollouts of the stored trials' policies); with the ten the "
        "contact model never passes the 0.8 switching test, so c₁ = c₂ would never be set "
        "(variants)",
    },
    {
        "item": "contact score",
        "thesis": "'the fifth model predicts the landing position of the returned ball in case "
        "of a contact, which is detected by a … SVM' (Sec. 4.3.4)",
        "ours": "contact_score='probability': a sampled path's ‖b − p‖ is "
        "w ‖b − p̂‖ + (1 − w) max‖b − p‖ with w the SVM's Platt-calibrated hit probability "
        "(scikit-learn CalibratedClassifierCV); 'decision' (w ∈ {0, 1}, before issue #31) and "
        "'margin' are options",
        "why": "the expected reward over the contact keeps the classifier's confidence where "
        "the hard decision charges the full penalty to every doubtful path; measured "
        "correlations of predicted and real rewards in the variants",
    },
    {
        "item": "reward schedule",
        "thesis": "'at the beginning of the learning c₂ is negligible compared to c₁, but we "
        "add an extra constant penalty … After collecting enough samples to learn a good "
        "contact model, we set c₁ = c₂' (Sec. 4.3.4); model-free always c₁ = c₂",
        "ours": "the same; 'good' (ours) = ≥ 15 hits and 15 misses, 5-fold balanced SVM "
        "accuracy ≥ 0.8 and landing-GP CV RMSE ≤ 30 cm; the switch is never undone",
        "why": "the thesis does not say how 'good' is decided",
    },
    {
        "item": "refit",
        "thesis": "'After each data collection step, we update the GP model hyper-parameters' "
        "(Sec. 4.1)",
        "ours": "refit='best': every GP's hyper-parameters optimised from the default start and "
        "from the previous update's, keeping the larger marginal likelihood (refit_gp; fit "
        "stats record the kept start and both log MLs)",
        "why": "a chain of warm starts can stay in a poor optimum (issue #31, hockey)",
    },
    {
        "item": "M, L, ε, data",
        "thesis": "'M = 500' artificial samples, L = 25 trajectories (Table 4.1, throwing), "
        "ε = 1; 'a higher N in the first iteration, e.g. N = 20', then 1",
        "ours": "M = 500, L = 10 (ours), ε = 0.5 (ours); N₀ = 20 then 1",
        "why": "L = 10 keeps an update affordable on 2 cores (the thesis gives no L for table "
        "tennis); ε = 0.5, the low end of the thesis's 'ε ∈ [0.5, 1]' (Sec. 3.4), since issue "
        "#31's stored runs: with ε = 1 the search's spread fell to 0.2–0.7% of its start by "
        "update 130 while the model placed the returns within 2 cm of the real ones (variants); "
        "chosen after those runs",
    },
    {
        "item": "REPS",
        "thesis": "≥ 4000 rollouts",
        "ours": "fig3.7's REPS (ε = 0.6, 50 per update, the last 200 reused), 4000 rollouts",
        "why": "the same model-free baseline as fig3.7",
    },
]


def _tt_setup(st: TableTennisGPREPSSettings) -> list[dict]:
    """:data:`TT_SETUP` with the run's own model options."""
    row = {
        "item": "this run's model options",
        "thesis": "contact inputs of Sec. 4.3.4, hard contact decision, refit after each step",
        "ours": f"contact_features={st.contact_features!r}, contact_score={st.contact_score!r}, "
        f"refit={st.refit!r}, L = {st.n_trajectories}, ε = {st.epsilon:g}",
        "why": "see the rows above",
    }
    return [*TT_SETUP, row]


TT_VARIANTS: list[dict] = [
    {
        "variant": "event=face, features=thesis, score=decision",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.638,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 0.997,
            "update10_vote_accuracy": 0.875,
            "update10_reward_correlation": 0.679,
            "initial_vote_accuracy": 0.425,
            "initial_false_hits": 0.697,
            "initial_reward_correlation": 0.317,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.09,
            "final_mean_contact_weight": 0.09,
            "final_reward_correlation": 0.061,
            "update10_vote_accuracy": 0.25,
            "update10_reward_correlation": -0.05,
            "initial_vote_accuracy": 0.775,
            "initial_false_hits": 0.061,
            "initial_reward_correlation": 0.348,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.685,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 1.0,
            "update10_vote_accuracy": 0.825,
            "update10_reward_correlation": 0.339,
            "initial_vote_accuracy": 0.425,
            "initial_false_hits": 0.697,
            "initial_reward_correlation": 0.257,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.13,
            "final_mean_contact_weight": 0.13,
            "final_reward_correlation": -0.043,
            "update10_vote_accuracy": 0.075,
            "update10_reward_correlation": 0.13,
            "initial_vote_accuracy": 0.825,
            "initial_false_hits": 0.0,
            "initial_reward_correlation": 0.316,
        },
    },
    {
        "variant": "event=face, features=thesis, score=probability",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.638,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 0.85,
            "final_reward_correlation": 0.994,
            "update10_vote_accuracy": 0.875,
            "update10_reward_correlation": 0.581,
            "initial_vote_accuracy": 0.425,
            "initial_false_hits": 0.697,
            "initial_reward_correlation": 0.282,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.09,
            "final_mean_contact_weight": 0.35,
            "final_reward_correlation": 0.571,
            "update10_vote_accuracy": 0.25,
            "update10_reward_correlation": 0.16,
            "initial_vote_accuracy": 0.775,
            "initial_false_hits": 0.061,
            "initial_reward_correlation": 0.448,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.685,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 0.89,
            "final_reward_correlation": 0.99,
            "update10_vote_accuracy": 0.825,
            "update10_reward_correlation": 0.499,
            "initial_vote_accuracy": 0.425,
            "initial_false_hits": 0.697,
            "initial_reward_correlation": 0.299,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.13,
            "final_mean_contact_weight": 0.34,
            "final_reward_correlation": 0.574,
            "update10_vote_accuracy": 0.075,
            "update10_reward_correlation": 0.375,
            "initial_vote_accuracy": 0.825,
            "initial_false_hits": 0.0,
            "initial_reward_correlation": 0.26,
        },
    },
    {
        "variant": "event=face, features=thesis, score=margin",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.638,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 0.998,
            "update10_vote_accuracy": 0.875,
            "update10_reward_correlation": 0.555,
            "initial_vote_accuracy": 0.425,
            "initial_false_hits": 0.697,
            "initial_reward_correlation": 0.298,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.09,
            "final_mean_contact_weight": 0.14,
            "final_reward_correlation": 0.029,
            "update10_vote_accuracy": 0.25,
            "update10_reward_correlation": -0.039,
            "initial_vote_accuracy": 0.775,
            "initial_false_hits": 0.061,
            "initial_reward_correlation": 0.313,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.685,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 1.0,
            "update10_vote_accuracy": 0.825,
            "update10_reward_correlation": 0.42,
            "initial_vote_accuracy": 0.425,
            "initial_false_hits": 0.697,
            "initial_reward_correlation": 0.248,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.13,
            "final_mean_contact_weight": 0.18,
            "final_reward_correlation": 0.008,
            "update10_vote_accuracy": 0.075,
            "update10_reward_correlation": 0.197,
            "initial_vote_accuracy": 0.825,
            "initial_false_hits": 0.0,
            "initial_reward_correlation": 0.375,
        },
    },
    {
        "variant": "event=face, features=extended, score=decision",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.925,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 0.997,
            "update10_vote_accuracy": 0.875,
            "update10_reward_correlation": 0.722,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.212,
            "initial_reward_correlation": 0.487,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.83,
            "final_mean_contact_weight": 0.83,
            "final_reward_correlation": 0.56,
            "update10_vote_accuracy": 0.8,
            "update10_reward_correlation": 0.336,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.212,
            "initial_reward_correlation": 0.505,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.95,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 1.0,
            "update10_vote_accuracy": 1.0,
            "update10_reward_correlation": 0.952,
            "initial_vote_accuracy": 0.85,
            "initial_false_hits": 0.121,
            "initial_reward_correlation": 0.604,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.21,
            "final_mean_contact_weight": 0.21,
            "final_reward_correlation": 0.068,
            "update10_vote_accuracy": 0.125,
            "update10_reward_correlation": 0.195,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.091,
            "initial_reward_correlation": 0.185,
        },
    },
    {
        "variant": "event=face, features=extended, score=probability",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.925,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 0.95,
            "final_reward_correlation": 0.97,
            "update10_vote_accuracy": 0.875,
            "update10_reward_correlation": 0.812,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.212,
            "initial_reward_correlation": 0.635,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.83,
            "final_mean_contact_weight": 0.58,
            "final_reward_correlation": 0.638,
            "update10_vote_accuracy": 0.8,
            "update10_reward_correlation": 0.275,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.212,
            "initial_reward_correlation": 0.574,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.95,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 0.95,
            "final_reward_correlation": 0.997,
            "update10_vote_accuracy": 1.0,
            "update10_reward_correlation": 0.847,
            "initial_vote_accuracy": 0.85,
            "initial_false_hits": 0.121,
            "initial_reward_correlation": 0.625,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.21,
            "final_mean_contact_weight": 0.32,
            "final_reward_correlation": 0.286,
            "update10_vote_accuracy": 0.125,
            "update10_reward_correlation": 0.164,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.091,
            "initial_reward_correlation": 0.243,
        },
    },
    {
        "variant": "event=face, features=extended, score=margin",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.925,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 0.993,
            "update10_vote_accuracy": 0.875,
            "update10_reward_correlation": 0.732,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.212,
            "initial_reward_correlation": 0.591,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.83,
            "final_mean_contact_weight": 0.8,
            "final_reward_correlation": 0.555,
            "update10_vote_accuracy": 0.8,
            "update10_reward_correlation": 0.273,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.212,
            "initial_reward_correlation": 0.539,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.95,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 1.0,
            "update10_vote_accuracy": 1.0,
            "update10_reward_correlation": 0.858,
            "initial_vote_accuracy": 0.85,
            "initial_false_hits": 0.121,
            "initial_reward_correlation": 0.666,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.21,
            "final_mean_contact_weight": 0.23,
            "final_reward_correlation": 0.072,
            "update10_vote_accuracy": 0.125,
            "update10_reward_correlation": 0.131,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.091,
            "initial_reward_correlation": 0.262,
        },
    },
    {
        "variant": "event=closest, features=thesis, score=decision",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.588,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 0.992,
            "update10_vote_accuracy": 0.875,
            "update10_reward_correlation": 0.677,
            "initial_vote_accuracy": 0.45,
            "initial_false_hits": 0.667,
            "initial_reward_correlation": 0.325,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.09,
            "final_mean_contact_weight": 0.09,
            "final_reward_correlation": 0.027,
            "update10_vote_accuracy": 0.25,
            "update10_reward_correlation": -0.05,
            "initial_vote_accuracy": 0.775,
            "initial_false_hits": 0.061,
            "initial_reward_correlation": 0.359,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.66,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 0.997,
            "update10_vote_accuracy": 0.7,
            "update10_reward_correlation": 0.342,
            "initial_vote_accuracy": 0.6,
            "initial_false_hits": 0.455,
            "initial_reward_correlation": 0.326,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.17,
            "final_mean_contact_weight": 0.17,
            "final_reward_correlation": -0.126,
            "update10_vote_accuracy": 0.075,
            "update10_reward_correlation": 0.159,
            "initial_vote_accuracy": 0.85,
            "initial_false_hits": 0.0,
            "initial_reward_correlation": 0.468,
        },
    },
    {
        "variant": "event=closest, features=thesis, score=probability",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.588,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 0.85,
            "final_reward_correlation": 0.988,
            "update10_vote_accuracy": 0.875,
            "update10_reward_correlation": 0.546,
            "initial_vote_accuracy": 0.45,
            "initial_false_hits": 0.667,
            "initial_reward_correlation": 0.325,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.09,
            "final_mean_contact_weight": 0.35,
            "final_reward_correlation": 0.55,
            "update10_vote_accuracy": 0.25,
            "update10_reward_correlation": 0.164,
            "initial_vote_accuracy": 0.775,
            "initial_false_hits": 0.061,
            "initial_reward_correlation": 0.463,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.66,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 0.89,
            "final_reward_correlation": 0.977,
            "update10_vote_accuracy": 0.7,
            "update10_reward_correlation": 0.512,
            "initial_vote_accuracy": 0.6,
            "initial_false_hits": 0.455,
            "initial_reward_correlation": 0.362,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.17,
            "final_mean_contact_weight": 0.35,
            "final_reward_correlation": 0.599,
            "update10_vote_accuracy": 0.075,
            "update10_reward_correlation": 0.402,
            "initial_vote_accuracy": 0.85,
            "initial_false_hits": 0.0,
            "initial_reward_correlation": 0.256,
        },
    },
    {
        "variant": "event=closest, features=thesis, score=margin",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.588,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 0.992,
            "update10_vote_accuracy": 0.875,
            "update10_reward_correlation": 0.54,
            "initial_vote_accuracy": 0.45,
            "initial_false_hits": 0.667,
            "initial_reward_correlation": 0.325,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.09,
            "final_mean_contact_weight": 0.14,
            "final_reward_correlation": 0.033,
            "update10_vote_accuracy": 0.25,
            "update10_reward_correlation": -0.033,
            "initial_vote_accuracy": 0.775,
            "initial_false_hits": 0.061,
            "initial_reward_correlation": 0.304,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.66,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 0.997,
            "update10_vote_accuracy": 0.7,
            "update10_reward_correlation": 0.296,
            "initial_vote_accuracy": 0.6,
            "initial_false_hits": 0.455,
            "initial_reward_correlation": 0.265,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.17,
            "final_mean_contact_weight": 0.2,
            "final_reward_correlation": -0.068,
            "update10_vote_accuracy": 0.075,
            "update10_reward_correlation": 0.164,
            "initial_vote_accuracy": 0.85,
            "initial_false_hits": 0.0,
            "initial_reward_correlation": 0.379,
        },
    },
    {
        "variant": "event=closest, features=extended, score=decision",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.95,
            "final_predicted_hit_rate": 0.98,
            "final_mean_contact_weight": 0.98,
            "final_reward_correlation": 0.848,
            "update10_vote_accuracy": 0.8,
            "update10_reward_correlation": 0.598,
            "initial_vote_accuracy": 0.85,
            "initial_false_hits": 0.091,
            "initial_reward_correlation": 0.458,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.48,
            "final_mean_contact_weight": 0.48,
            "final_reward_correlation": 0.466,
            "update10_vote_accuracy": 0.425,
            "update10_reward_correlation": 0.213,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.061,
            "initial_reward_correlation": 0.53,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.95,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 1.0,
            "final_reward_correlation": 0.993,
            "update10_vote_accuracy": 0.7,
            "update10_reward_correlation": 0.504,
            "initial_vote_accuracy": 0.875,
            "initial_false_hits": 0.03,
            "initial_reward_correlation": 0.588,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.06,
            "final_mean_contact_weight": 0.06,
            "final_reward_correlation": 0.099,
            "update10_vote_accuracy": 0.05,
            "update10_reward_correlation": 0.091,
            "initial_vote_accuracy": 0.825,
            "initial_false_hits": 0.0,
            "initial_reward_correlation": 0.312,
        },
    },
    {
        "variant": "event=closest, features=extended, score=probability",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.95,
            "final_predicted_hit_rate": 0.98,
            "final_mean_contact_weight": 0.82,
            "final_reward_correlation": 0.927,
            "update10_vote_accuracy": 0.8,
            "update10_reward_correlation": 0.78,
            "initial_vote_accuracy": 0.85,
            "initial_false_hits": 0.091,
            "initial_reward_correlation": 0.602,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.48,
            "final_mean_contact_weight": 0.43,
            "final_reward_correlation": 0.673,
            "update10_vote_accuracy": 0.425,
            "update10_reward_correlation": 0.281,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.061,
            "initial_reward_correlation": 0.595,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.95,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 0.87,
            "final_reward_correlation": 0.982,
            "update10_vote_accuracy": 0.7,
            "update10_reward_correlation": 0.743,
            "initial_vote_accuracy": 0.875,
            "initial_false_hits": 0.03,
            "initial_reward_correlation": 0.563,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.06,
            "final_mean_contact_weight": 0.27,
            "final_reward_correlation": 0.344,
            "update10_vote_accuracy": 0.05,
            "update10_reward_correlation": 0.144,
            "initial_vote_accuracy": 0.825,
            "initial_false_hits": 0.0,
            "initial_reward_correlation": 0.269,
        },
    },
    {
        "variant": "event=closest, features=extended, score=margin",
        "trial 0, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.95,
            "final_predicted_hit_rate": 0.98,
            "final_mean_contact_weight": 0.78,
            "final_reward_correlation": 0.829,
            "update10_vote_accuracy": 0.8,
            "update10_reward_correlation": 0.659,
            "initial_vote_accuracy": 0.85,
            "initial_false_hits": 0.091,
            "initial_reward_correlation": 0.529,
        },
        "trial 0, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.48,
            "final_mean_contact_weight": 0.47,
            "final_reward_correlation": 0.564,
            "update10_vote_accuracy": 0.425,
            "update10_reward_correlation": 0.24,
            "initial_vote_accuracy": 0.8,
            "initial_false_hits": 0.061,
            "initial_reward_correlation": 0.542,
        },
        "trial 1, 150 rollouts": {
            "svm_cv_balanced_accuracy": 0.95,
            "final_predicted_hit_rate": 1.0,
            "final_mean_contact_weight": 0.82,
            "final_reward_correlation": 0.877,
            "update10_vote_accuracy": 0.7,
            "update10_reward_correlation": 0.6,
            "initial_vote_accuracy": 0.875,
            "initial_false_hits": 0.03,
            "initial_reward_correlation": 0.535,
        },
        "trial 1, 30 rollouts": {
            "svm_cv_balanced_accuracy": None,
            "final_predicted_hit_rate": 0.06,
            "final_mean_contact_weight": 0.1,
            "final_reward_correlation": 0.182,
            "update10_vote_accuracy": 0.05,
            "update10_reward_correlation": 0.081,
            "initial_vote_accuracy": 0.825,
            "initial_false_hits": 0.0,
            "initial_reward_correlation": 0.306,
        },
    },
    {
        "variant": "search: ε = 1, throwing's KL bound (the setting before 2026-12-04)",
        "settings": "epsilon=1.0",
        "measured": "paper scale, 5 trials at 65bc574: landing error 43 / 45 / 45 / 27 / 52 cm, "
        "89% returned, 6% net, reward -0.0453; every update at KL = 1, √tr Σ at 12–21% of its "
        "start after 32 updates and 0.2–0.7% after 130; the final models place the returns "
        "within a median 1.4–2.7 cm of the real landing points and predict the error they "
        "leave (benchmarks/bench_gpreps_limits.py)",
        "kept": False,
    },
    {
        "variant": "search: ε = 0.5 (kept; chosen after the ε = 1 runs, the only other value "
        "tried)",
        "settings": "epsilon=0.5 (--set epsilon=0.5 --set reps_updates=1 --trials 1)",
        "measured": "trial 0 (seed 0): landing error 10 cm (ε = 1: 43 cm), 98% returned (88%), "
        "2% net (8%), reward -0.0133 (-0.0464); every update at KL = 0.5, √tr Σ at 28% of its "
        "start after 32 updates and 3.6% after 130; 24.8 min on a shared core",
        "kept": True,
    },
]
"""Every variant tried for issue #31, with its numbers, the worse ones too: model 5's
(contact event, inputs and score) and, last, the search's KL bound.

How they were measured (/tmp script of the issue-#31 session, OMP_NUM_THREADS=1): the stored
``fig4.12-paper-s0`` trials 0 and 1's policy histories; training rollouts made again as GPREPS
collects them (20 of π₀, then one of each later policy: 150, or the first 30 = the data at
update 10); the four other models fitted once (ExactGP, 60 L-BFGS steps, returning stage),
model 5 fitted per variant on the same rollouts. Evaluated on 40 fresh rollouts at each of π₀
("initial"), the update-10 and the final policy, L = 10 predicted strokes each:
``*_predicted_hit_rate`` (share of sampled paths the SVM calls hits; every real shot of the
final policies hit), ``*_mean_contact_weight`` (mean w of the score), ``*_vote_accuracy``
(majority vote of the L paths against the real hit / miss), ``initial_false_hits`` (share of
real misses voted hits), ``*_reward_correlation`` (Pearson, predicted expected reward of the
returning stage against the real reward), ``svm_cv_balanced_accuracy`` (the switching test's
5-fold balanced accuracy; None below 15 hits and 15 misses). ``event=closest`` is the rule
before issue #31 (predicted paths at their closest approach, flown through the racket)."""


# --------------------------------------------------------------------------- fig4.13
def run_trial_413(st: ModelAccuracySettings, rng: np.random.Generator, trial: TrialContext):
    """Fit the five models on ``n_rollouts`` rollouts of the initial policy; compare their
    samples with the simulator on ``n_heldout`` fresh (s, ω) pairs."""
    task = make("table-tennis")
    policy = task.initial_policy()
    trial.reset(total=3)

    def rollouts(n: int):
        s = task.sample_context(rng, n=n)
        w = policy.sample(s, rng)
        trajs = [task.rollout(wi, si, rng=rng) for wi, si in zip(w, s, strict=True)]
        return s, w, trajs

    s_tr, w_tr, t_tr = rollouts(st.n_rollouts)
    trial.update()
    model = table_tennis_reward_model(task, st, "returning")
    r_tr = np.array([task.reward(t, s) for t, s in zip(t_tr, s_tr, strict=True)])
    model.fit(s_tr, w_tr, r_tr, t_tr, rng)
    trial.update()
    s_te, w_te, t_te = rollouts(st.n_heldout)
    errors = model.heldout_errors(s_te, w_te, t_te, st.n_samples, rng)
    trial.update()
    hits = [i for i, t in enumerate(t_te) if t.info["hit"]]
    shown = (hits + [i for i in range(len(t_te)) if i not in hits])[: st.n_shown]
    pred = model.predict(s_te[shown], w_te[shown], st.n_samples, rng)
    out = {f"accuracy_{k}": np.asarray(v, dtype=float) for k, v in errors.items()}
    out["shown_ball_predicted"] = pred.ball
    out["shown_racket_predicted"] = pred.racket
    out["shown_landing_predicted"] = pred.landing
    out["shown_ball_real"] = np.stack([t_te[i].signals["ball"] for i in shown])
    out["shown_racket_real"] = np.stack([t_te[i].signals["racket"] for i in shown])
    out["shown_landing_real"] = np.array(
        [t_te[i].info["landing_point"] if t_te[i].info["hit"] else [np.nan] * 2 for i in shown]
    )
    return out


MODEL_ERRORS = {
    "bounce_position_error_m": 0.05,
    "racket_position_rmse_m": 0.03,
    "contact_accuracy": 0.9,
    "return_landing_error_m": 0.30,
}
"""fig4.13's thresholds, fixed before any run: median bounce-point error, racket-position RMSE
(over the stroke), held-out hit/miss accuracy of the contact SVM, median error of the returned
landing point (the thesis's 30 cm)."""


def _nan_joined(paths: np.ndarray, cols) -> tuple[list, list]:
    """Paths (n, T, 3) as one polyline with NaN breaks, on the columns ``cols``."""
    xs, ys = [], []
    for p in paths:
        xs += p[:, cols[0]].tolist() + [float("nan")]
        ys += p[:, cols[1]].tolist() + [float("nan")]
    return xs, ys


def summarize_413(st: ModelAccuracySettings, trials: list[dict]):
    t0 = trials[0]
    series = []
    for view, cols, ylabel in (("side view (x–z)", (0, 2), "z (m)"),
                               ("top view (x–y)", (0, 1), "y (m)")):  # fmt: skip
        for name, key, kind in (
            ("incoming ball, models 1–2 (10 samples)", "shown_ball_predicted", "line"),
            ("racket, models 3–4 (10 samples)", "shown_racket_predicted", "line"),
        ):
            pred = np.asarray(t0[key], dtype=float)
            x, y = _nan_joined(pred.reshape(-1, *pred.shape[2:]), cols)
            series.append(Series(name, x, y, view, kind, xlabel="x (m)", ylabel=ylabel))
        for name, key in (("ball, simulator", "shown_ball_real"),
                          ("racket, simulator", "shown_racket_real")):  # fmt: skip
            x, y = _nan_joined(np.asarray(t0[key], dtype=float), cols)
            series.append(Series(name, x, y, view, "line", xlabel="x (m)", ylabel=ylabel))
    lp = np.asarray(t0["shown_landing_predicted"], dtype=float).reshape(-1, 2)
    lr = np.asarray(t0["shown_landing_real"], dtype=float)
    series.append(Series("returned landing point, model 5", lp[:, 0].tolist(),
                         lp[:, 1].tolist(), "top view (x–y)", "markers", xlabel="x (m)",
                         ylabel="y (m)"))  # fmt: skip
    series.append(Series("returned landing point (hits), simulator", lr[:, 0].tolist(),
                         lr[:, 1].tolist(), "top view (x–y)", "markers", xlabel="x (m)",
                         ylabel="y (m)"))  # fmt: skip
    errors = {
        k[len("accuracy_") :]: float(np.mean([t[k] for t in trials]))
        for k in t0
        if k.startswith("accuracy_")
    }
    summary: dict = {"n_trials": len(trials), "errors": errors,
                     "thresholds": dict(MODEL_ERRORS)}  # fmt: skip
    return series, with_verdict(summary, verdict_413(st, summary))


def verdict_413(st: ModelAccuracySettings, summary: dict) -> Verdict:
    """Holds if every error in :data:`MODEL_ERRORS` is within its threshold (accuracy above)."""
    # None: not recorded, or a NaN made JSON (no held-out hit at smoke scale)
    e = {k: float("nan") if v is None else v for k, v in summary["errors"].items()}
    ok = []
    for name, limit in MODEL_ERRORS.items():
        value = e.get(name, float("nan"))
        ok.append(value >= limit if name == "contact_accuracy" else value <= limit)
    return Verdict(
        CLAIM_413,
        bool(all(ok)),
        f"From {st.n_rollouts} rollouts, on {st.n_heldout} held-out rollouts × {st.n_samples} "
        f"samples: bounce point {fmt(100 * e.get('bounce_position_error_m', np.nan), '.1f')} cm "
        f"(median), racket position {fmt(100 * e.get('racket_position_rmse_m', np.nan), '.1f')} "
        f"cm (RMSE), contact accuracy {fmt(100 * e.get('contact_accuracy', np.nan), '.0f')}% "
        f"(majority class {fmt(100 * e.get('contact_majority_rate', np.nan), '.0f')}%), "
        + _returned_landing(e.get("return_landing_error_m", np.nan)),
    )


def _returned_landing(error_m) -> str:
    """fig4.13's last clause: the median returned landing error, or that no held-out shot was
    returned (the error is undefined, NaN)."""
    if error_m is None or not np.isfinite(error_m):
        return "no held-out shot returned, so no returned landing point to compare."
    return f"returned landing point {100 * error_m:.0f} cm (median)."


# --------------------------------------------------------------------------- registry
register(
    Experiment(
        id="fig4.12",
        title="Robot table tennis: GPREPS (five models) vs GP direct vs REPS",
        settings_class=TableTennisGPREPSSettings,
        settings=_scales(
            TableTennisGPREPSSettings,
            smoke={"reps_updates": 1},
            quick={"reps_updates": 10},
        ),
        run_trial=run_trial_412,
        summarize=summarize_412,
        verdict=verdict_412,
        own_checks=lambda _settings, summary: own_checks_412(summary),
        trials={"smoke": 1, "quick": 1, "paper": 5},
        claim=CLAIM_412,
    )
)
register(
    Experiment(
        id="fig4.13",
        title="Robot table tennis: the five models' predictions against the simulator",
        settings_class=ModelAccuracySettings,
        settings={
            "smoke": ModelAccuracySettings(
                n_rollouts=20, n_heldout=3, n_samples=2, n_shown=1, gp_steps=10
            ),
            # quick scales down: held-out rollouts 20→10, L-BFGS iterations 100→60
            "quick": ModelAccuracySettings(n_heldout=10, gp_steps=60),
            "paper": ModelAccuracySettings(),
        },
        run_trial=run_trial_413,
        summarize=summarize_413,
        verdict=verdict_413,
        trials={"smoke": 1, "quick": 1, "paper": 1},
        claim=CLAIM_413,
    )
)
