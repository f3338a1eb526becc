"""The thesis's own sentences behind every experiment id: what ``summary["thesis"]`` quotes.

Every experiment's ``summary`` carries ``thesis``, the sentence(s) of the thesis the claim
rests on with their location, and ``holds``, which judges exactly those sentences (see
``DESIGN.md``, "Contracts"). This module is the one place those sentences live:
:data:`THESIS` maps each registered experiment id to a tuple of :class:`ThesisClaim`, each a
verbatim quote of ``../shared/thesis.txt`` (the thesis as text) and where it stands.

A quote is copied character for character from the thesis text, LaTeX and Markdown markup
included, except for whitespace: the text file breaks lines (and pages) inside sentences and
hyphenates at line ends, so a quote matches the text after :func:`normalise_text` (line breaks
joined with single spaces, end-of-line hyphenation undone). Figure captions are quoted without
their ``FIGURE x.y:`` label. The thesis text carries no page numbers, so a location names the
section and the figure or table (``"Sec. 4.3.3, text on Fig. 4.10"``, ``"Fig. 4.10
caption"``).

Only sentences that state a *result* are quoted: what a figure or table shows and how the
text reads it. Where the thesis reports no result for what an experiment measures
(``sanity3``, our own problem; ``fig4.8``, an illustration; ``sec4.2.4``, a proposal the
thesis reports it could not make work for GPs), the quote is the sentence the experiment
rests on and the location says that no result is reported there; such an experiment's
``holds`` is ``None``.

Examples
--------
>>> from skillkit.experiments.claims import thesis_quotes
>>> thesis_quotes("fig4.10")[0]["location"]
'Fig. 4.10 caption'
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = [
    "NO_RESULT",
    "SMOKE_NOTE",
    "THESIS",
    "ThesisClaim",
    "NOT_RECORDED",
    "conjunction",
    "finite_or_none",
    "is_less",
    "judged",
    "parts_note",
    "own_check",
    "normalise_text",
    "thesis_quotes",
]


@dataclass(frozen=True)
class ThesisClaim:
    """One quoted passage of the thesis and where it stands.

    Attributes
    ----------
    quote : str
        One or more consecutive sentences copied verbatim from the thesis text (whitespace
        normalised as by :func:`normalise_text`).
    location : str
        Section and figure or table as the thesis numbers them, e.g.
        ``"Sec. 4.3.3, text on Fig. 4.10"`` or ``"Fig. 4.10 caption"``.
    """

    quote: str
    location: str

    def __post_init__(self) -> None:
        for name in ("quote", "location"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value.strip():
                raise ValueError(f"{name}: expected a non-empty string, got {value!r}")


def normalise_text(text: str) -> str:
    """``text`` with end-of-line hyphenation undone and every run of whitespace one space.

    A hyphen that ends a line and is followed (after any blank lines) by a lowercase letter
    joins the two parts ("rep-\\nresents" → "represents"); then line breaks, tabs and repeated
    spaces collapse to single spaces, and the ends are stripped. Quotes in :data:`THESIS`
    appear in ``normalise_text(thesis_text)`` verbatim.

    Parameters
    ----------
    text : str
        Thesis text or a quote.

    Returns
    -------
    str
        The normalised text.
    """
    text = re.sub(r"(\w)-[ \t]*\n\s*(?=[a-z])", r"\1", text)
    return " ".join(text.split())


def _c(quote: str, location: str) -> ThesisClaim:
    return ThesisClaim(quote=quote, location=location)


NO_RESULT = frozenset({"sanity3", "sec4.2.4", "fig4.8"})
"""Ids whose quoted passage reports no result the experiment could confirm or refute
(``holds`` is ``None``): ``sanity3`` is our own problem with a known optimum, ``sec4.2.4`` a
method the thesis proposes and reports it "failed to apply ... with success for GP models",
``fig4.8`` an illustration ("We show such an example")."""

_FIG5_3_4 = (
    _c(
        "In Figures 5.3 and 5.4, we show the single step prediction errors with the kernel "
        "embedding and the GP modeling approach with the colored contours. The kernel "
        "embedding approach consistently provides more accurate predictions and it "
        "generalizes better in less explored parts of the state space.",
        "Sec. 5.4, text on Figs. 5.3 and 5.4",
    ),
    _c(
        "The models typically provide better predictions in the vicinity of the observed "
        "trajectories.",
        "Sec. 5.4, text on Figs. 5.3 and 5.4",
    ),
)

THESIS: dict[str, tuple[ThesisClaim, ...]] = {
    # ------------------------------------------------------------------ chapter 2
    "fig2.7": (
        _c(
            "In our example, the linearization gave a good approximation of the model only in "
            "a narrow region, and thus, we could only obtain a poor approximation of the real "
            "successor state distribution.",
            "Sec. 2.1.2, text on Fig. 2.6 (linearisation)",
        ),
        _c(
            "We illustrate this prediction technique in Fig. 2.7. Although the moment matching "
            "approach gives a more accurate prediction compared to linearization, computing "
            "the first and second moment are computationally involved.",
            "Sec. 2.1.2, text on Fig. 2.7",
        ),
    ),
    "fig2.10": (
        _c(
            "As we can clearly see, the forcing function changes the shape of the trajectory, "
            "but the final angular position g remains unaltered.",
            "Sec. 2.2.1, text on Fig. 2.10",
        ),
        _c(
            "The robot arm reaches the same angular position g , but the shape of the "
            "trajectory is altered so that it matches the demonstration.",
            "Fig. 2.10 caption",
        ),
        _c(
            "The DMP accurately captured the demonstration using only 10 parameters.",
            "Fig. 2.11 caption",
        ),
    ),
    "fig2.12": (
        _c(
            "As we can see, without observing any samples (represented with **black** dots), "
            "the prediction variance is high. However, after observing an increasing amount of "
            "samples, the variance rapidly reduces and the sample functions converge to the "
            "real underlying function.",
            "Sec. 2.3, text on Fig. 2.12",
        ),
    ),
    # ------------------------------------------------------------------ chapter 3
    "sanity3": (
        _c(
            "In our experiments, contextual REPS has proven to be highly efficient in learning "
            "upper-level policies $\\pi(\\omega|\\mathbf{s})$, which condition on the observed "
            "context \\mathbf{s} to choose parametrization ω .",
            "Sec. 3.5 (discussion; the thesis reports no result on sanity3's problem, "
            "which is ours)",
        ),
    ),
    "fig3.3": (
        _c(
            "Fig. 3.3 shows that REPS converged to a good solution after 5000 skill "
            "evaluations in most cases. In a few instances, however, we observed premature "
            "convergence resulting in suboptimal performance. The performance of REPS could be "
            "improved by using extra samples generated with the known reward model (*extra "
            "context*). In this case, REPS always converged to good solutions.",
            "Sec. 3.4.1, text on Fig. 3.3",
        ),
        _c(
            "The absolute displacement error for targets further away from the robot's base "
            "(with context $\\mathbf{s} \\leq [13, 3]^T$ m) could raise up to 0.5 m, otherwise "
            "the maximal error was smaller than 10 cm.",
            "Sec. 3.4.1, text on the learnt policy (Fig. 3.2)",
        ),
    ),
    "fig3.5": (
        _c(
            "The results show that CrKR could not compete with model-free contextual REPS.",
            "Sec. 3.4.2, text on the learning curves (printed as Fig. 3.4; they are Fig. 3.5)",
        ),
        _c(
            "By the end of the learning process, contextual REPS always provided policies, "
            "which were able to hit the target puck for 95% of the experiments and the "
            "displacement error remained below 20cm. However, CrKR provided policies that could "
            "hit the target puck only with a lower probability and displacement errors are "
            "considerably higher compared to REPS.",
            "Sec. 3.4.2, text on Fig. 3.5",
        ),
    ),
    "fig3.7": (
        _c(
            "REPS is able to learn a good policy after 4000 evaluations, but it sometimes "
            "learns a sub-optimal policy that hits the ball in the net.",
            "Fig. 3.7 caption",
        ),
        _c(
            "While contextual REPS consistently provided good learning performance, we "
            "sometimes observed policies, which produced hitting skills that landed the ball in "
            "the net. This is a suboptimal solution with a reward in interval "
            "$[-0.05, -0.02]$. However, for most of the evaluations high quality policies were "
            "found after observing 4000 rollouts, which landed the ball in 20 – 30cm radius of "
            "the target location with a reward above -0.02 .",
            "Sec. 3.4.3, text on Fig. 3.7",
        ),
    ),
    # ------------------------------------------------------------------ chapter 4
    "tab4.2": (
        _c(
            "Required experience to achieve reward limits for a 4-link balancing problem. "
            "Higher rewards require better policies.",
            "Table 4.2 caption (PILCO 10.18 / 11.46 / 12.18 s, GPREPS 10.68 / 20.52 / "
            "38.50 s, REPS 1425 / 2300 / 4075 s to reach −100 / −10 / −1.5)",
        ),
        _c(
            "As shown in the table, GPREPS requires two orders of magnitude fewer trials than "
            "REPS to converge to the optimal solution. PILCO achieved faster convergence as the "
            "gradient-based optimizer computes greedy updates while GPREPS continued to "
            "explore.",
            "Sec. 4.3.1, text on Table 4.2",
        ),
        _c(
            "Despite the fact that PILCO was the most data-efficient learning algorithm, it "
            "required at least twice as much computation time to achieve the same reward "
            "levels as GPREPS, which was highly parallelized.",
            "Sec. 4.3.1, text on Table 4.2",
        ),
    ),
    "sec4.2.4": (
        _c(
            "Thus, the resulting algorithm will provide model parametrization that aims to "
            "reduce the long-term prediction error instead of greedily maximizing the "
            "likelihood of individual state transitions.",
            "Sec. 4.2.4, after Eq. (4.14) (a proposal; no experiment reported)",
        ),
        _c(
            "For example, for GP models these constraints are often difficult to satisfy due "
            "to the fixed set of training data and the kernel function. Due to these "
            "challenges, in our experiments we failed to apply the above training approach "
            "with success for GP models.",
            "Sec. 4.2.4, after Eq. (4.16) (no result reported)",
        ),
    ),
    "fig4.3": (
        _c(
            "As the figure shows, the best 95% of the experiments required approximately 50 "
            "sample trajectories to reach the accuracy of the moment matching approach. "
            "However, in most cases (top 75%), it was enough to sample not more than 20 "
            "trajectories to reach the moment matching performance.",
            "Sec. 4.2.2, text on Fig. 4.3",
        ),
        _c(
            "In most of our experiments (top 95%), the accuracy of moment matching is met by "
            "sampling only 50 samples per prediction. However, in most cases it was enough to "
            "sample 20 trajectories to reach the moment matching performance.",
            "Fig. 4.3 caption",
        ),
    ),
    "fig4.4": (
        _c(
            "As shown in Figure 4.4, already the single CPU core implementation outperforms "
            "moment matching and can produce approximately 1000 samples in the same "
            "computation time.",
            "Sec. 4.2.2, text on Fig. 4.4 (Intel i5-3570k, one core)",
        ),
    ),
    "fig4.5": (
        _c(
            "With increasing additive noise factor we gain more numerical stability, but the "
            "accuracy of reward prediction decreases slightly. However, we observed that the "
            "sparse method often overfits the data, which results in the worse performance "
            "with higher additive noise factor.",
            "Sec. 4.2.3, text on Fig. 4.5 (additive-noise panel)",
        ),
        _c(
            "When comparing the amount of hyper-parameter optimization steps, we can conclude "
            "that after only 50 optimization steps we can already obtain accurate models. "
            "However, we also see a small overfitting effect for the sparse models as we "
            "continue the optimization.",
            "Sec. 4.2.3, text on Fig. 4.5 (optimisation-steps panel)",
        ),
        _c(
            "When we add additional control input noise to the system, the standard GP "
            "approach could capture the uncertainty well. However, just as with the additive "
            "noise experiment, the sparse method tends to overfit the data and produces "
            "inaccurate predictions.",
            "Sec. 4.2.3, text on Fig. 4.5 (control-noise panel)",
        ),
        _c(
            "Finally, an increasing number of sample trajectories clearly has a positive effect "
            "on the prediction accuracy.",
            "Sec. 4.2.3, text on Fig. 4.5 (training-trajectories panel)",
        ),
    ),
    "fig4.6": (
        _c(
            "While we observed relatively good learning performance, the final result is of "
            "lower quality and has higher variance compared to REPS and GPREPS. On the other "
            "hand, GPREPS required only 30 – 40 evaluations to converge to the highest quality "
            "solution. Furthermore, the variance of the final policy is negligible.",
            "Sec. 4.3.2, text on Fig. 4.6 (the first sentence on GP direct)",
        ),
        _c(
            "GPREPS not only provides higher quality solutions compared to model-free REPS, but "
            "also requires two orders of magnitude less interactions with the robot.",
            "Sec. 4.3.2, text on Fig. 4.6",
        ),
    ),
    "fig4.7": (
        _c(
            "As the figure shows, increasing the amount of artificial samples always has a "
            "positive influence on the learning performance. However, we do not see much "
            "difference above using 500 samples. Using a lower number of artificial samples "
            "resulted in lower quality final policies with highly varying performance.",
            "Sec. 4.3.2.1, text on Fig. 4.7",
        ),
    ),
    "fig4.8": (
        _c(
            "For learning problems where the dynamics of the robot and its environment is "
            "stochastic, the variance of the resulting trajectory τ and hence the reward "
            "$R(\\tau, \\mathbf{s})$ might be considerably large. We show such an example in "
            "Fig. 4.8 with a single link pendulum.",
            "Sec. 4.3.2.2, text on Fig. 4.8 (an illustration; no result reported)",
        ),
        _c(
            "GPREPS avoids this problem by averaging over multiple samples for the same "
            "context-parameter pair, as in Eq. (4.1).",
            "Sec. 4.3.2.2 (the method, not a measured result)",
        ),
    ),
    "fig4.9": (
        _c(
            "At the end of the learning, the policy optimized with the noisy environment "
            "attains an expected reward of -1086 , while the policy learned with the "
            "deterministic dynamics has a final reward of -715 .",
            "Fig. 4.9(a) caption (REPS)",
        ),
        _c(
            "At the end of the learning, the policy optimized with the noisy environment "
            "attains an expected reward of -68 , while the policy learned with the "
            "deterministic dynamics has a final reward of -64 .",
            "Fig. 4.9(b) caption (GPREPS)",
        ),
        _c(
            "However, we can see significant differences in the performance of the final "
            "policy. While GPREPS is able to learn a policy of similar quality with stochastic "
            "dynamics as with deterministic, the bias in model-free REPS prevents the algorithm "
            "from finding the final policy of similar quality.",
            "Sec. 4.3.2.2, text on Fig. 4.9",
        ),
    ),
    "fig4.10": (
        _c(
            "Learning curves on the robot hockey task. GPREPS was able to learn the task within "
            "120 interactions with the environment.",
            "Fig. 4.10 caption",
        ),
        _c(
            "GPREPS learned the task already after 120 interactions with the environment, while "
            "the model-free version of REPS needed approximately 10,000 interactions. Moreover, "
            "the policies learnt by model-free REPS were of lower quality. After 100 "
            "evaluations, GPREPS placed the target puck accurately at the desired distance with "
            "a displacement error less than 5 cm.",
            "Sec. 4.3.3, text on Fig. 4.10",
        ),
    ),
    "fig4.11": (
        _c(
            "The GPREPS learning curve on the real robot arm. The shaded area represents the 95% "
            "confidence interval of the result after 5 independent evaluations.",
            "Fig. 4.11 caption",
        ),
        _c(
            "As we can see, the robot adapts the lower-level policy parameters towards the "
            "optimum within a low number of interactions with the real environment.",
            "Sec. 4.3.3, text on Fig. 4.11",
        ),
    ),
    "fig4.12": (
        _c(
            "GPREPS always provided a consistent performance, and the final policy was able to "
            "return the ball within 30cm of the target position, while avoiding hitting the ball "
            "into the net. This behavior could be learned within 150 evaluations.",
            "Fig. 4.12 caption",
        ),
        _c(
            "We can clearly see that GPREPS outperforms the other two algorithms. GPREPS "
            "consistently provides high quality policies after only 150 evaluations. The final "
            "policy avoids hitting the ball into the net and the displacement from the desired "
            "target position remains below 30cm.",
            "Sec. 4.3.4, text on Fig. 4.12",
        ),
        _c(
            "When using the *GP direct* approach that does not use the prior knowledge of the "
            "structure of the experiment, we obtain policies that often get stuck in a local "
            "optima. Typically we observe policies that hit the ball to the net, or even miss "
            "the ball.",
            "Sec. 4.3.4, text on Fig. 4.12 (GP direct)",
        ),
        _c(
            "Model-free REPS requires at least 4000 evaluations on average to learn a policy "
            "that consistently returns the ball, with only a few instances of hitting the ball "
            "into the net.",
            "Sec. 4.3.4, text on Fig. 4.12 (REPS)",
        ),
    ),
    "fig4.13": (
        _c(
            "When we compare the predictions with the real experiment trajectories (**red** and "
            "**green** lines), we can see the high accuracy of the predictions. The models are "
            "learned from 100 experiment rollouts, we sample 10 trajectories to capture the "
            "stochasticity.",
            "Fig. 4.13 caption",
        ),
    ),
    # ------------------------------------------------------------------ chapter 5
    "fig5.3": _FIG5_3_4,
    "fig5.4": _FIG5_3_4,
    "fig5.5": (
        _c(
            "In the trajectory prediction experiment, the kernel embedding approach "
            "significantly outperforms GP modeling (Fig. 5.5).",
            "Sec. 5.4, text on Fig. 5.5",
        ),
    ),
    "fig5.6": (
        _c(
            "As the figure shows, the kernel embedding approach provides an order of magnitude "
            "lower reward prediction error compared to the GP approach. For a lower amount of "
            "observed trajectories, the GP model provides less confident predictions, which "
            "leads to higher prediction variance, and thus, larger reward prediction error. The "
            "kernel embedding approach consistently provides accurate reward predictions, even "
            "for a lower amount of observed trajectories.",
            "Sec. 5.4, text on Fig. 5.6",
        ),
        _c(
            "The figure shows that directly maximizing the long term prediction error in Eq. "
            "(5.23) (denoted by *trajectory-based*) clearly has a positive effect on the "
            "predictive performance compared to the *step-based* approach (Eq. (5.17)).",
            "Sec. 5.4, text on Fig. 5.6",
        ),
    ),
    "fig5.7": (
        _c(
            "As we can see, the GP modeling tends to provide higher prediction error due to the "
            "less confident predictions. However, with the kernel embedding approach we barely "
            "see any difference in the prediction performance.",
            "Sec. 5.4, text on Fig. 5.7",
        ),
        _c(
            "This experiment concludes that the kernel embedding approach provides better "
            "generalization and prediction results, even with more complex dynamics, compared "
            "to GP models.",
            "Sec. 5.4, conclusion of the balancing experiments (Figs. 5.6 and 5.7)",
        ),
    ),
}
"""Experiment id → the thesis's sentences its claim rests on, in reading order."""


def thesis_quotes(exp_id: str) -> list[dict[str, str]]:
    """The ``thesis`` entry of ``exp_id``'s summary: its quotes with their locations.

    Parameters
    ----------
    exp_id : str
        A registered experiment id, e.g. ``"fig4.10"``.

    Returns
    -------
    list of dict
        ``[{"quote": ..., "location": ...}, ...]`` in reading order (JSON-able; a fresh list
        on every call).

    Raises
    ------
    ValueError
        If :data:`THESIS` has no entry for ``exp_id`` (the message names it and lists the
        known ids).
    """
    if exp_id not in THESIS:
        raise ValueError(
            f"exp_id: no thesis quotes for experiment {exp_id!r}; known: {', '.join(THESIS)}"
        )
    return [asdict(claim) for claim in THESIS[exp_id]]


SMOKE_NOTE = (
    "smoke scale: a smoke run checks that the code runs, on too little data for its numbers "
    "to decide the claim; quick and paper runs are judged"
)
"""``summary["not_judged"]`` of a smoke-scale run (the short reason, then why)."""

NO_RESULT_NOTE = "no thesis result: the thesis reports no result for this to be compared with"
"""``summary["not_judged"]`` of an experiment in :data:`NO_RESULT`."""


def own_check(holds: bool | None, criterion: str) -> dict[str, Any]:
    """One entry of ``summary["own_checks"]``: a condition of ours, beyond the thesis's
    sentence, with its own verdict (shown beside ``holds``, never folded into it).

    Parameters
    ----------
    holds : bool or None
        Whether our condition is met (None: it cannot be decided from this run's numbers).
    criterion : str
        The condition in words, with its bound (e.g. ``"every trial within both bounds at
        every target"``).

    Returns
    -------
    dict
        ``{"holds": holds, "criterion": criterion}``.
    """
    if isinstance(holds, np.bool_):
        holds = bool(holds)
    if not (holds is None or isinstance(holds, bool)):
        raise ValueError(f"holds: expected True, False or None, got {holds!r}")
    if not isinstance(criterion, str) or not criterion.strip():
        raise ValueError(f"criterion: expected a non-empty string, got {criterion!r}")
    return {"holds": holds, "criterion": criterion}


def judged(summary: Mapping[str, Any], exp_id: str, scale: str) -> dict[str, Any]:
    """A run's summary as stored: the verdict, the thesis's sentences it judges, then our own
    checks.

    The experiment's own verdict (``claim``, ``holds``, ``statement``) judges the sentences
    of :data:`THESIS`; this adds them as ``thesis`` right after the verdict, moves
    ``own_checks`` (conditions of ours beyond the thesis, :func:`own_check`) after them, and
    withholds the verdict where there is nothing to judge:

    * at ``scale == "smoke"`` ``holds`` is None and ``not_judged`` says why
      (:data:`SMOKE_NOTE`): smoke settings exist to run the code in seconds;
    * for an id in :data:`NO_RESULT` ``holds`` is None at every scale (:data:`NO_RESULT_NOTE`);
      what the experiment's criterion decided is kept as ``own_checks["own_criterion"]``.

    The statement (our numbers) is kept in every case.

    Parameters
    ----------
    summary : mapping
        The experiment's summary (``claim``, ``holds``, ``statement`` first).
    exp_id : str
        Its experiment id; an id without an entry in :data:`THESIS` (an experiment registered
        outside this package) gets ``thesis = []``.
    scale : str
        The run's scale.

    Returns
    -------
    dict
        ``claim``, ``holds``, ``statement``, ``thesis`` (list of ``{"quote", "location"}``),
        ``not_judged`` (only when ``holds`` was withheld), ``own_checks`` (when any), then
        the rest of ``summary`` in its order.
    """
    head = {k: summary[k] for k in ("claim", "holds", "statement") if k in summary}
    own = dict(summary.get("own_checks") or {})
    rest = {
        k: v
        for k, v in summary.items()
        if k not in ("claim", "holds", "statement", "thesis", "not_judged", "own_checks")
    }
    head["thesis"] = thesis_quotes(exp_id) if exp_id in THESIS else []
    if exp_id in NO_RESULT:
        criterion = "the experiment's own criterion, in the statement"
        own.pop("own_criterion", None)  # today's verdict decides it, not a stored value
        own = {"own_criterion": own_check(summary.get("holds"), criterion), **own}
        head["holds"], head["not_judged"] = None, NO_RESULT_NOTE
    if scale == "smoke":
        head["holds"], head["not_judged"] = None, SMOKE_NOTE
    return {**head, **({"own_checks": own} if own else {}), **rest}


# ----------------------------------------------------------------- verdicts of many parts
NOT_RECORDED = "not recorded in this run"
"""What a verdict's statement says of a number its criterion needs that a stored summary (made
before the criterion was) lacks."""


def conjunction(parts) -> bool | None:
    """Kleene's AND of a claim's parts: False if any part is False, else None if any part is
    undecided (a number not recorded in the run), else True.

    Parameters
    ----------
    parts : iterable of bool or None

    Returns
    -------
    bool or None
    """
    parts = list(parts)
    if any(p is False for p in parts):
        return False
    return None if any(p is None for p in parts) else True


def parts_note(parts: dict[str, bool | None]) -> str:
    """The end of a verdict's statement: which of the claim's parts failed and which could not
    be decided (``""`` when every part holds).

    Parameters
    ----------
    parts : dict
        Part name → True, False or None (as :func:`conjunction` reads them).

    Returns
    -------
    str
        E.g. ``" Not met: gp_direct_learns. Not decided (not recorded in this run):
        reps_always_95pct_below_20cm."``
    """
    failed = [k for k, v in parts.items() if v is False]
    undecided = [k for k, v in parts.items() if v is None]
    note = f" Not met: {', '.join(failed)}." if failed else ""
    if undecided:
        note += f" Not decided ({NOT_RECORDED} or not measurable): {', '.join(undecided)}."
    return note


def finite_or_none(value) -> float | None:
    """``value`` as a float, or None for a missing or non-finite number (NaN is stored as
    None in ``result.json``).

    Parameters
    ----------
    value : float, None or a number-like

    Returns
    -------
    float or None
    """
    if value is None:
        return None
    value = float(value)
    return value if np.isfinite(value) else None


def is_less(a, b) -> bool | None:
    """``a < b``; None where either is missing (None or NaN: not recorded in the run, or a
    mean over no values).

    Parameters
    ----------
    a, b : float or None

    Returns
    -------
    bool or None
    """
    a, b = finite_or_none(a), finite_or_none(b)
    return None if a is None or b is None else bool(a < b)
