"""The claims engine (:mod:`skillkit.experiments.judge`): statistics against independent
computations, the three outcomes, readings changed in the spec without re-running anything."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from skillkit.experiments import judge
from skillkit.experiments.judge import normalise_text
from skillkit.experiments.registry import ids

EPS = np.finfo(float).eps
THESIS_TEXT = Path(__file__).resolve().parents[2] / ".." / "shared" / "thesis.txt"
DATA = Path(__file__).resolve().parents[2] / "data" / "results"


def _part(**kw) -> judge.Part:
    base = dict(
        label="x",
        quantity="x",
        statistic="mean",
        op="<",
        threshold=0.0,
        thesis="< 0",
        reason="r",
        fixed="before",
    )
    return judge._part({**base, **kw}, "test")


def _close(a: float, b: float, scale: float = 1.0) -> bool:
    """Equal up to float64 round-off of a short sum (64 ulps of the data's scale)."""
    return abs(a - b) <= 64 * EPS * max(abs(a), abs(b), scale)


# ------------------------------------------------------------------------ the spec itself
def test_every_registered_id_has_a_claim_and_every_claim_an_id():
    table = judge.specs()
    assert set(table) == set(ids())


@pytest.mark.parametrize("exp_id", sorted(judge.specs()))
def test_a_claim_with_a_thesis_result_has_thesis_parts(exp_id):
    claim = judge.spec(exp_id)
    assert claim.no_result or [p for p in claim.parts if not p.own], exp_id
    assert len(claim.plain.split()) <= 12 and "TODO" not in claim.plain
    for p in claim.parts:
        assert p.reason.strip() and p.fixed in ("before", "after")


@pytest.fixture(scope="module")
def thesis_text() -> str:
    if not THESIS_TEXT.is_file():
        pytest.skip(f"the thesis text {THESIS_TEXT} is absent (an installed copy)")
    return normalise_text(THESIS_TEXT.read_text(encoding="utf-8"))


@pytest.mark.parametrize("exp_id", sorted(judge.specs()))
def test_quotes_are_verbatim(exp_id, thesis_text):
    for q in judge.spec(exp_id).quotes:
        assert normalise_text(q.text) == q.text, f"{exp_id}: extra whitespace in {q.text!r}"
        assert q.text in thesis_text, f"{exp_id}: not in the thesis: {q.text[:80]!r}"
        assert q.location.strip()


def test_malformed_parts_are_refused_naming_the_field():
    with pytest.raises(ValueError, match="statistic: expected one of"):
        _part(statistic="median")
    with pytest.raises(ValueError, match="op: expected one of"):
        _part(op="=<")
    with pytest.raises(ValueError, match="fixed: expected 'before' or 'after'"):
        _part(fixed="later")
    with pytest.raises(ValueError, match="needs 'minus'"):
        _part(statistic="paired")
    with pytest.raises(ValueError, match="unknown field"):
        _part(treshold=1.0)


# --------------------------------------------------------------------------- statistics
def test_mean_is_a_student_t_interval_over_trials():
    x = [0.052, 0.041, 0.088, 0.042, 0.085]
    r = judge.read(_part(threshold=0.05), {"x": x})
    lo, hi = stats.t.interval(0.95, len(x) - 1, loc=np.mean(x), scale=stats.sem(x))
    assert _close(r.estimate, np.mean(x)) and _close(r.lower, lo) and _close(r.upper, hi)
    assert r.outcome == "undecided" and "trials would decide it" in r.needed
    # the trials it names do decide it: the half-width with that many trials, same spread
    n = int(r.needed.split()[1])
    half = stats.t.ppf(0.975, n - 1) * np.std(x, ddof=1) / math.sqrt(n)
    assert half < abs(np.mean(x) - 0.05)


def test_the_three_outcomes():
    x = np.array([1.0, 1.2, 0.9, 1.1])
    assert judge.read(_part(op=">", threshold=0.0), {"x": x}).outcome == "holds"
    assert judge.read(_part(op="<", threshold=0.0), {"x": x}).outcome == "does not hold"
    assert judge.read(_part(op="<", threshold=1.05), {"x": x}).outcome == "undecided"
    missing = judge.read(_part(quantity="y"), {"x": x})
    assert missing.outcome == "not measured" and missing.estimate is None


def test_paired_reads_per_trial_differences():
    a, b = [1.0, 2.0, 3.5, 4.0], [0.5, 1.0, 3.0, 3.0]
    r = judge.read(_part(statistic="paired", minus="b", op=">", threshold=0.0), {"x": a, "b": b})
    d = np.subtract(a, b)
    lo, hi = stats.t.interval(0.95, 3, loc=d.mean(), scale=stats.sem(d))
    assert _close(r.lower, lo) and _close(r.upper, hi) and r.outcome == "holds"


def test_rate_is_a_wilson_interval_on_pooled_counts():
    rates, count = [0.04, 0.08, 0.02, 0.0, 0.04], 50
    r = judge.read(_part(statistic="rate", count=count, op="<=", threshold=0.05), {"x": rates})
    k = round(sum(rates) * count)
    ci = stats.binomtest(k, count * len(rates)).proportion_ci(0.95, method="wilson")
    assert _close(r.lower, ci.low) and _close(r.upper, ci.high)
    assert r.n == 250 and r.outcome == "undecided" and "items would decide it" in r.needed


def test_rate_count_from_the_settings():
    part = _part(statistic="rate", count="settings.n", op=">", threshold=0.5)
    r = judge.read(part, {"x": [0.9, 1.0]}, {"n": 100})
    assert r.n == 200 and r.outcome == "holds"


def test_fraction_counts_trials_meeting_the_condition():
    part = _part(statistic="fraction", each_op=">", each_threshold=-0.02, op=">", threshold=0.5)
    x = [-0.01, -0.03, -0.015, -0.019, -0.05, -0.001, -0.012, -0.018, -0.011, -0.03]
    r = judge.read(part, {"x": x})
    ci = stats.binomtest(7, 10).proportion_ci(0.95, method="wilson")
    assert _close(r.estimate, 0.7) and _close(r.lower, ci.low) and _close(r.upper, ci.high)
    assert r.outcome == "undecided"


def test_ratio_bootstrap_interval_brackets_the_ratio_of_means():
    rng = np.random.default_rng(3)
    a, b = rng.normal(10, 1, 8), rng.normal(4, 0.5, 8)
    r = judge.read(_part(statistic="ratio", over="b", op=">", threshold=1.5), {"x": a, "b": b})
    assert _close(r.estimate, a.mean() / b.mean())
    assert r.lower < r.estimate < r.upper and r.outcome == "holds"


def test_one_trial_gives_no_interval_and_is_undecided():
    r = judge.read(_part(threshold=1.0), {"x": [0.2]})
    assert r.outcome == "undecided" and r.lower is None and "≥ 2" in r.needed


def test_value_is_judged_on_the_number_itself():
    assert judge.read(_part(statistic="value", threshold=1.0), {"x": 0.2}).outcome == "holds"
    with pytest.raises(ValueError, match="one number"):
        judge.read(_part(statistic="value"), {"x": [0.2, 0.3]})


# ------------------------------------------------------------------- verdicts and cards
def _claim(*parts: judge.Part) -> judge.Claim:
    return judge.Claim("fig0.0", "a claim", (judge.Quote("q", "l"),), parts)


def test_a_verdict_fails_on_one_failing_thesis_part_and_own_checks_never_decide(monkeypatch):
    holds = _part(label="a", op=">", threshold=0.0)
    fails = _part(label="b", op="<", threshold=0.0)
    own_fails = _part(label="c", op="<", threshold=0.0, own=True)
    summary = {"x": [1.0, 1.1, 0.9], "n_trials": 3}
    for parts, want in [
        ((holds,), "holds"),
        ((holds, fails), "does not hold"),
        ((holds, own_fails), "holds"),
    ]:
        monkeypatch.setattr(judge, "spec", lambda _id, p=parts: _claim(*p))
        j = judge.judge("fig0.0", summary, "paper")
        assert j.outcome == want
        assert judge.card_lines_ok(j.card())
    smoke = judge.judge("fig0.0", summary, "smoke")
    assert smoke.outcome == "not judged" and "smoke scale: not judged" in smoke.card()


def test_a_key_the_run_lacks_leaves_the_verdict_undecided_unless_a_part_fails(monkeypatch):
    """A part read from a summary key a stored run does not record yet is "not measured": the
    verdict is undecided (a failing part still decides it), the card names the part."""
    holds = _part(label="a", op=">", threshold=0.0)
    fails = _part(label="b", op="<", threshold=0.0)
    missing = _part(label="new key", quantity="per_trial.new", minus="x", statistic="paired")
    summary = {"x": [1.0, 1.1, 0.9], "n_trials": 3}
    for parts, want, key in [
        ((holds, missing), "undecided", "new key"),
        ((missing, fails), "does not hold", "b"),
    ]:
        monkeypatch.setattr(judge, "spec", lambda _id, p=parts: _claim(*p))
        j = judge.judge("fig0.0", summary, "paper")
        assert j.outcome == want and judge.card_lines_ok(j.card())
        assert [r.outcome for r in j.readings if r.part.label == "new key"] == ["not measured"]
        assert j.key().part.label == key and j.verdict_line().endswith(f": {want}")


def test_changing_a_reading_in_the_spec_changes_the_verdict_without_a_rerun(tmp_path, monkeypatch):
    """fig4.10's placed-puck error is read against 5 cm; a copy of the spec with 20 cm judges
    the same stored numbers again at load: no trial runs."""
    from skillkit.experiments import run as run_module
    from skillkit.experiments import runner

    if not (DATA / "fig4.10-paper-s0").is_dir():
        pytest.skip("no stored fig4.10 result")
    monkeypatch.setattr(runner, "run_trials", lambda *a, **k: pytest.fail("a trial ran"))
    before = run_module.load_run(DATA / "fig4.10-paper-s0")
    label = "placed-puck error"  # read against 5 cm
    folder = tmp_path / "claims"
    shutil.copytree(judge.SPEC_DIR, folder)
    text = (folder / "ch4.toml").read_text()
    head, tail = text.split(f'label = "{label}"', 1)
    tail = tail.replace("threshold = 0.05\n", "threshold = 0.2\n", 1)
    (folder / "ch4.toml").write_text(head + f'label = "{label}"' + tail)
    monkeypatch.setattr(judge, "SPEC_DIR", folder)
    judge.specs.cache_clear()
    try:
        after = run_module.load_run(DATA / "fig4.10-paper-s0")
    finally:
        judge.specs.cache_clear()
    read = {r["label"]: r for r in after.summary["judgement"]["readings"]}
    old = {r["label"]: r for r in before.summary["judgement"]["readings"]}
    assert old[label]["outcome"] != "holds" and read[label]["outcome"] == "holds"
    assert read[label]["estimate"] == old[label]["estimate"]  # the same measurement
    stored = json.loads((DATA / "fig4.10-paper-s0" / "result.json").read_text())
    assert stored["summary"]["gpreps"] == after.summary["gpreps"]
