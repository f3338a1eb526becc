"""skillkit.teaching.tables.claims_table: the README's rows as a pandas table."""

from __future__ import annotations

import pytest

from skillkit.experiments.run import claim_rows
from skillkit.teaching.tables import claims_table


def test_claims_table_has_one_row_per_stored_result_with_its_verdict_and_interval():
    rows = claim_rows(ids=["fig3.3", "fig4.10"])
    table = claims_table(["fig3.3", "fig4.10"])
    assert list(table.index) == [r["id"] for r in rows] == ["fig3.3", "fig4.10"]
    assert list(table.columns) == ["claim", "verdict", "ours [95% interval]", "thesis", "made by"]
    for r in rows:
        assert table.loc[r["id"], "verdict"] == r["verdict"]
        assert table.loc[r["id"], "verdict"] in ("holds", "does not hold", "undecided")
        assert table.loc[r["id"], "ours [95% interval]"] == r["ours"]
        assert len(table.loc[r["id"], "claim"]) <= 100


def test_unknown_id_is_named():
    with pytest.raises(ValueError, match=r"ids: unknown experiment id\(s\) \['fig9.9'\]"):
        claims_table(["fig3.3", "fig9.9"])


def test_live_run_times_sum_the_measured_table_and_the_stored_paper_compute():
    import json

    import numpy as np

    from skillkit.experiments import stored_run, timings
    from skillkit.teaching.tables import live_run_times

    quick = live_run_times(["fig4.3", "fig4.6"], "quick")
    expected = [timings.measured_seconds(i, "quick") for i in ("fig4.3", "fig4.6")]
    assert np.allclose(quick["seconds"].iloc[:2], expected)
    assert quick.loc["all", "seconds"] == pytest.approx(sum(expected), rel=4 * np.finfo(float).eps)
    paper = live_run_times(["fig3.7"], "paper")
    stored = json.loads((stored_run("fig3.7").path / "result.json").read_text())
    assert paper.loc["fig3.7", "seconds"] == pytest.approx(sum(stored["trial_time_s"]))
    assert list(paper.index) == ["fig3.7", "all"]


def test_live_run_times_name_bad_input():
    from skillkit.teaching.tables import live_run_times

    with pytest.raises(ValueError, match="scale: expected one of"):
        live_run_times(["fig3.3"], "huge")
    with pytest.raises(ValueError, match="ids: unknown"):
        live_run_times(["fig9.9"], "smoke")


def test_experiments_table_lists_every_registered_id_with_its_trials():
    from skillkit.experiments.registry import get, ids
    from skillkit.teaching.tables import experiments_table

    table = experiments_table()
    assert list(table.index) == list(ids())
    for exp_id in ids():
        t = get(exp_id).trials
        assert table.loc[exp_id, "trials (smoke / quick / paper)"] == (
            f"{t['smoke']} / {t['quick']} / {t['paper']}"
        )
        assert table.loc[exp_id, "title"] == get(exp_id).title
