"""The thesis quotes behind every experiment id (:mod:`skillkit.experiments.claims`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from skillkit.experiments.claims import (
    NO_RESULT,
    THESIS,
    ThesisClaim,
    normalise_text,
    thesis_quotes,
)
from skillkit.experiments.registry import ids
from skillkit.experiments.run import COMPARISON_PREFIX  # comparisons of ours: nothing to quote

THESIS_TEXT = Path(__file__).resolve().parents[2] / ".." / "shared" / "thesis.txt"


@pytest.fixture(scope="module")
def thesis_text() -> str:
    if not THESIS_TEXT.is_file():
        pytest.skip(
            f"the thesis text {THESIS_TEXT} is absent (an installed copy of skillkit need not "
            "sit beside ../shared/thesis.txt)"
        )
    return normalise_text(THESIS_TEXT.read_text(encoding="utf-8"))


def test_every_registered_id_has_quotes():
    missing = [i for i in ids() if not THESIS.get(i) and not i.startswith(COMPARISON_PREFIX)]
    assert not missing, f"no thesis quotes for {missing}"
    assert not [i for i in THESIS if i.startswith(COMPARISON_PREFIX)]


def test_a_comparison_of_ours_is_never_judged_as_a_thesis_claim():
    from skillkit.experiments.claims import judged
    from skillkit.experiments.registry import get

    comparisons = [i for i in ids() if i.startswith(COMPARISON_PREFIX)]
    assert comparisons  # cmp.methods (issue #34)
    for exp_id in comparisons:
        summary = {"claim": get(exp_id).claim, "holds": None, "statement": "numbers"}
        assert judged(summary, exp_id, "paper")["thesis"] == []
        assert get(exp_id).claim.startswith("Not a thesis claim")


def test_no_quotes_for_unknown_ids():
    assert set(THESIS) <= set(ids()), set(THESIS) - set(ids())
    assert set(NO_RESULT) <= set(THESIS)


@pytest.mark.parametrize("exp_id", sorted(THESIS))
def test_quotes_are_verbatim(exp_id, thesis_text):
    for claim in THESIS[exp_id]:
        assert isinstance(claim, ThesisClaim)
        quote = normalise_text(claim.quote)
        assert quote == claim.quote, f"{exp_id}: quote carries extra whitespace: {claim.quote!r}"
        assert quote in thesis_text, f"{exp_id}: not in the thesis text: {claim.quote!r}"


@pytest.mark.parametrize("exp_id", sorted(THESIS))
def test_locations_are_given(exp_id):
    for claim in THESIS[exp_id]:
        assert claim.location.strip()
        assert claim.quote.strip()


def test_thesis_quotes_is_json_ready_and_fresh():
    quotes = thesis_quotes("fig4.10")
    assert quotes and all(set(q) == {"quote", "location"} for q in quotes)
    assert all(isinstance(v, str) for q in quotes for v in q.values())
    quotes.clear()
    assert thesis_quotes("fig4.10")


def test_thesis_quotes_names_an_unknown_id():
    with pytest.raises(ValueError, match="fig9.99"):
        thesis_quotes("fig9.99")


def test_claim_rejects_empty_fields():
    with pytest.raises(ValueError, match="location"):
        ThesisClaim("a sentence.", " ")
    with pytest.raises(ValueError, match="quote"):
        ThesisClaim("", "Sec. 1")


def test_normalise_text_joins_lines_and_hyphenation():
    assert normalise_text("a reward level rep-\n\nresents\n  a  policy") == (
        "a reward level represents a policy"
    )
    assert normalise_text("model-\nFree") == "model- Free"


def test_judged_withholds_the_verdict_at_smoke_and_where_the_thesis_reports_no_result():
    from skillkit.experiments.claims import NO_RESULT_NOTE, SMOKE_NOTE, judged, own_check

    summary = {"claim": "c", "holds": True, "statement": "s", "thesis": {"x": 1}, "n": 3}
    quick = judged(summary, "fig4.10", "quick")
    assert list(quick) == ["claim", "holds", "statement", "thesis", "n"]
    mine = judged({**summary, "own_checks": {"x": own_check(False, "x < 1")}}, "fig4.10", "paper")
    assert list(mine)[4] == "own_checks" and mine["holds"] is True  # beside, not folded in
    assert quick["holds"] is True and quick["thesis"] == thesis_quotes("fig4.10")
    smoke = judged(summary, "fig4.10", "smoke")
    assert smoke["holds"] is None and smoke["not_judged"] == SMOKE_NOTE
    assert smoke["statement"] == "s" and smoke["n"] == 3
    for scale in ("quick", "paper"):
        none = judged({**summary, "holds": False}, "fig4.8", scale)
        assert none["holds"] is None and none["not_judged"] == NO_RESULT_NOTE
        assert none["own_checks"]["own_criterion"]["holds"] is False
    assert judged(summary, "toy.unknown", "paper")["thesis"] == []
    assert summary["holds"] is True and summary["thesis"] == {"x": 1}  # input untouched


def test_every_smoke_run_is_unjudged_and_quotes_the_thesis(tmp_path):
    from skillkit.experiments import reproduce
    from skillkit.viz.plots import verdict

    run = reproduce("fig2.10", "smoke", trials=1, out=tmp_path, progress=False, html=False)
    summary = run.result["summary"]
    assert summary["holds"] is None and summary["thesis"] == thesis_quotes("fig2.10")
    assert verdict(run.result).word == "not judged (smoke scale)"
