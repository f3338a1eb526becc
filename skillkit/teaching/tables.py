"""Tables for the notebooks (pandas): the chapter's claims beside our verdicts.

>>> claims_table(["fig3.3", "fig3.5"])          # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Iterable

__all__ = ["claims_table"]


def claims_table(ids: Iterable[str] | None = None, root=None):
    """One row per stored result: the thesis's sentences (with where they stand), our verdict
    of exactly those sentences, our numbers, and whether the stored result is current.

    Made by :func:`skillkit.experiments.run.claim_rows`, the same rows as the README's table.

    Parameters
    ----------
    ids : iterable of str, optional
        Experiment ids (default: every stored result).
    root : path, optional
        Results folder (default: ``data/results``, see
        :func:`skillkit.experiments.run.results_root`).

    Returns
    -------
    pandas.DataFrame
        Index ``id``; columns ``the thesis says``, ``verdict``, ``our numbers``, ``made by``.

    Raises
    ------
    ValueError
        When an id is not a registered experiment.
    """
    import pandas as pd

    from skillkit.experiments.registry import ids as registered
    from skillkit.experiments.run import claim_rows

    if ids is not None:
        ids = [ids] if isinstance(ids, str) else list(ids)
        unknown = sorted(set(ids) - set(registered()))
        if unknown:
            raise ValueError(f"ids: unknown experiment id(s) {unknown}")
    rows = claim_rows(root, ids)
    table = pd.DataFrame(
        {
            "id": [r["id"] for r in rows],
            "the thesis says": [r["thesis"] or r["where"] for r in rows],
            "verdict": [r["verdict"] for r in rows],
            "our numbers": [r["statement"] for r in rows],
            "made by": [r["made"] for r in rows],
        }
    )
    return table.set_index("id")
