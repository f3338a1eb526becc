"""skillkit.teaching.tables.claims_table: the README's rows as a pandas table."""

from __future__ import annotations

import pytest

from skillkit.experiments.run import claim_rows
from skillkit.teaching.tables import claims_table


def test_claims_table_has_one_row_per_stored_result_with_its_thesis_sentence():
    rows = claim_rows(ids=["fig3.3", "fig4.10"])
    table = claims_table(["fig3.3", "fig4.10"])
    assert list(table.index) == [r["id"] for r in rows] == ["fig3.3", "fig4.10"]
    assert list(table.columns) == ["the thesis says", "verdict", "our numbers", "made by"]
    for r in rows:
        assert table.loc[r["id"], "verdict"] == r["verdict"]
        assert (
            "(Sec. " in table.loc[r["id"], "the thesis says"]
            or "caption" in table.loc[r["id"], "the thesis says"]
        )


def test_unknown_id_is_named():
    with pytest.raises(ValueError, match=r"ids: unknown experiment id\(s\) \['fig9.9'\]"):
        claims_table(["fig3.3", "fig9.9"])
