"""The Run object: reading run folders, its verdict line, its Jupyter card, path-likeness."""

from __future__ import annotations

import json
import os

import pytest

from skillkit.experiments.judge import judge
from skillkit.experiments.registry import ids
from skillkit.experiments.run import Run, load_run, results_root, stored_run


def _write(folder, **summary):
    folder.mkdir(parents=True, exist_ok=True)
    result = {
        "id": "figX",
        "title": "A title",
        "scale": "smoke",
        "seed": 3,
        "trials": 2,
        "settings": {"n": 1},
        "series": [{"name": "a", "x": [0, 1], "y": [1.0, 2.0]}],
        "summary": summary,
    }
    (folder / "result.json").write_text(json.dumps(result))
    return result


def test_load_run_reads_result_and_is_path_like(tmp_path):
    result = _write(
        tmp_path / "r", claim="c", holds=False, statement="ours is 2.5, thesis 1", x=2.5
    )
    run = load_run(tmp_path / "r")
    assert run.result == result and load_run(tmp_path / "r" / "result.json").result == result
    assert (
        os.fspath(run) == str(tmp_path / "r")
        and run / "result.json" == tmp_path / "r" / "result.json"
    )
    assert run.id == "figX" and run.settings == {"n": 1} and run.holds is False
    assert run.verdict == "ours is 2.5, thesis 1"  # an id the claims spec does not judge


def test_card_and_repr_show_claim_verdict_and_details(tmp_path):
    _write(
        tmp_path / "r", claim="REPS reaches 5 cm", holds=True, statement="4.1 cm here", err=0.041
    )
    run = load_run(tmp_path / "r")
    card = run._repr_markdown_()
    for text in ("figX", "REPS reaches 5 cm", "4.1 cm here", "<details>"):
        assert text in card
    assert run.card == "figX: REPS reaches 5 cm\n4.1 cm here"
    assert len(repr(run)) < 300 and "4.1 cm here" in repr(run)


def test_old_summaries_without_a_verdict(tmp_path):
    _write(tmp_path / "r", rmse=0.1)
    run = load_run(tmp_path / "r")
    assert run.holds is None and run.verdict == "no verdict recorded"


def test_missing_or_broken_folders_are_reported(tmp_path):
    with pytest.raises(FileNotFoundError, match="path: no result.json"):
        load_run(tmp_path)
    (tmp_path / "result.json").write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_run(tmp_path)
    with pytest.raises(FileNotFoundError, match="png: no figure.png"):
        Run(tmp_path, {}).png()
    with pytest.raises(FileNotFoundError, match="exp_id: no stored"):
        stored_run("nope")


def test_every_experiment_has_a_stored_paper_run():
    root = results_root()
    for exp_id in ids():
        run = stored_run(exp_id)
        assert run.id == exp_id and run.scale == "paper" and run.path.parent == root


def test_reproduce_returns_the_run_it_wrote(tmp_path):
    from skillkit.experiments import reproduce

    run = reproduce("fig2.10", scale="smoke", out=tmp_path, progress=False, html=False)
    assert isinstance(run, Run) and run.path == tmp_path / "fig2.10-smoke-s0"
    assert run.result == load_run(run.path).result and run.holds is None  # smoke: not judged
    # the claims spec's reading of the same numbers, judged as if at paper scale
    assert judge("fig2.10", run.summary, "paper", run.settings).outcome == "holds"
    assert run.summary["claim"] in run._repr_markdown_()
    assert len(run.figure().data) == len(run.series)
