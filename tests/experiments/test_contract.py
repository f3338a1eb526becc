"""The experiment contract, over every registered id at the smoke scale (dm_control
``suite_test`` style): an experiment gets these checks by registering.

Each id must give a strict-JSON result whose ``summary`` starts with the verdict schema
(``claim``, ``holds``, ``statement``) recomputable from the summary alone; the same seed must
give the same numbers and (where the experiment is random) another seed other numbers; its
settings must be a frozen dataclass with every field described, checked by name and type
before anything runs; and its figures must build.
"""

from __future__ import annotations

import dataclasses
import json
import re
import warnings
from pathlib import Path

import pytest

from skillkit.cli import main
from skillkit.experiments.claims import SMOKE_NOTE, judged, thesis_quotes
from skillkit.experiments.provenance import staleness
from skillkit.experiments.registry import SCALES, VERDICT_KEYS, get, ids
from skillkit.experiments.run import COMPARISON_PREFIX
from skillkit.experiments.runner import run_trials, to_jsonable
from skillkit.experiments.settings import Settings, apply_overrides, describe

IDS = ids()
DETERMINISTIC = {"fig2.10"}
"""Experiments that use no randomness (the seed changes nothing)."""
TIMED = {"fig4.4"}
"""Experiments whose numbers are all wall-clock measurements (they differ between runs)."""
TIMED_VERDICT = {"tab4.2"}
"""Experiments whose verdict compares wall-clock measurements (the rest is deterministic)."""
DATA = Path(__file__).resolve().parents[2] / "data" / "results"

_CACHE: dict[tuple[str, int], dict] = {}


def _run(exp_id: str, seed: int = 0) -> dict:
    """The smoke-scale result of ``exp_id`` with ``seed``, computed once per test session."""
    if (exp_id, seed) not in _CACHE:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            _CACHE[exp_id, seed] = run_trials(exp_id, "smoke", seed=seed, progress=False)
    return _CACHE[exp_id, seed]


def _numbers(result: dict, exp_id: str):
    """Series and summary as JSON, without wall-clock measurements (keys with "time" or
    "gflops"; all numbers of a TIMED experiment, and the verdict drawn from them; the verdict
    of a TIMED_VERDICT experiment)."""
    timed = exp_id in TIMED
    verdict_timed = timed or exp_id in TIMED_VERDICT

    def strip(obj):
        if isinstance(obj, dict):
            return {
                k: strip(v)
                for k, v in obj.items()
                if "time" not in k
                and "gflops" not in k
                and not (timed and k in ("y", "lower", "upper"))
                and not (verdict_timed and k in ("holds", "statement"))
            }
        if isinstance(obj, list):
            return [strip(v) for v in obj]
        return obj

    return strip(to_jsonable({"series": result["series"], "summary": result["summary"]}))


@pytest.mark.parametrize("exp_id", IDS)
def test_result_is_strict_json(exp_id):
    result = {k: v for k, v in _run(exp_id).items() if k != "_trials"}
    text = json.dumps(to_jsonable(result), allow_nan=False)
    back = json.loads(text)
    assert back["id"] == exp_id and back["scale"] == "smoke"
    assert back["settings"] == json.loads(json.dumps(get(exp_id).settings["smoke"].to_dict()))
    assert back["overrides"] == {} and back["trials"] == get(exp_id).trials["smoke"]
    assert back["series"], "an experiment plots at least one series"


@pytest.mark.parametrize("exp_id", IDS)
def test_summary_follows_the_verdict_schema(exp_id):
    exp = get(exp_id)
    summary = _run(exp_id)["summary"]
    assert list(summary)[:4] == [*VERDICT_KEYS, "thesis"]
    assert isinstance(summary["claim"], str) and summary["claim"].strip()
    assert summary["claim"] == exp.claim
    # the sentences the verdict judges; a comparison of ours (cmp.*) quotes none
    ours = exp_id.startswith(COMPARISON_PREFIX)
    assert summary["thesis"] == ([] if ours else thesis_quotes(exp_id))
    # Smoke runs are not judged: holds is withheld and not_judged says why.
    assert summary["holds"] is None and summary["not_judged"] == SMOKE_NOTE
    assert isinstance(summary["statement"], str) and re.search(r"\d", summary["statement"])
    # a missing number is said in words (issue #33): smoke runs miss many (no hit, no return)
    assert not re.search(r"\bn/a\b|\bNone\b|\bnan\b", summary["statement"]), summary["statement"]
    assert "claim_holds" not in summary  # the old form is gone
    # A function of the stored numbers: the same verdict from the JSON summary alone.
    stored = json.loads(json.dumps(to_jsonable(summary)))
    own = exp.verdict(exp.settings["smoke"], stored)
    assert own.holds in (True, False, None) and own.statement == summary["statement"]
    again = judged({**stored, **own.as_dict()}, exp_id, "smoke")
    assert again == stored
    # Our own checks: recomputable from the numbers, each a verdict of its own.
    checks = {k: v for k, v in stored.get("own_checks", {}).items() if k != "own_criterion"}
    if exp.own_checks is not None:
        assert checks == exp.own_checks(exp.settings["smoke"], stored)
    assert all(set(v) == {"holds", "criterion"} for v in stored.get("own_checks", {}).values())


@pytest.mark.parametrize("exp_id", IDS)
def test_same_seed_same_numbers_other_seed_other_numbers(exp_id):
    first = _numbers(_run(exp_id, 0), exp_id)
    _CACHE.pop((exp_id, 0))
    assert _numbers(_run(exp_id, 0), exp_id) == first
    if exp_id in TIMED:
        return  # nothing but measurements to compare
    other = _numbers(_run(exp_id, 1), exp_id)
    if exp_id in DETERMINISTIC:
        assert other == first
    else:
        assert other["series"] != first["series"]


@pytest.mark.parametrize("exp_id", IDS)
def test_settings_are_frozen_documented_and_typed(exp_id):
    exp = get(exp_id)
    cls = exp.settings_class
    assert issubclass(cls, Settings) and dataclasses.is_dataclass(cls)
    assert cls.__dataclass_params__.frozen
    assert set(exp.settings) == set(SCALES) and set(exp.trials) >= set(SCALES)
    for scale in SCALES:
        s = exp.settings[scale]
        assert type(s) is cls and exp.settings_for(scale) == s
        hash(s)  # immutable all the way down (tuples, nested frozen settings)
        with pytest.raises(dataclasses.FrozenInstanceError):
            s.__setattr__(dataclasses.fields(s)[0].name, None)
        assert json.loads(json.dumps(to_jsonable(s.to_dict()), allow_nan=False)) is not None
        assert apply_overrides(s, s.to_dict()) == s  # its own values pass the checks
    for c in _settings_classes(cls):
        for name, _, doc in describe(c):
            assert len(doc) > 10, f"{c.__name__}.{name} has no description"


def _settings_classes(cls):
    """``cls`` and the classes of its nested settings fields."""
    out = [cls]
    for f in dataclasses.fields(cls):
        if isinstance(f.default, Settings):
            out += _settings_classes(type(f.default))
    return out


def _wrong_value(value):
    """A value of the wrong type for a field holding ``value``."""
    if isinstance(value, str):
        return 3
    if isinstance(value, bool):
        return "yes"
    if isinstance(value, int):
        return 1.5
    if isinstance(value, tuple):
        return ["not a number"] if value and not isinstance(value[0], str) else [3]
    return "text"


@pytest.mark.parametrize("exp_id", IDS)
def test_overrides_are_checked_by_name_and_type(exp_id, tmp_path, capsys):
    exp = get(exp_id)
    names = [f.name for f in dataclasses.fields(exp.settings_class)]
    with pytest.raises(ValueError, match=f"no_such_setting: not a setting.*{names[0]}"):
        exp.settings_for("smoke", no_such_setting=1)
    for name in names:
        value = getattr(exp.settings["smoke"], name)
        with pytest.raises(ValueError, match=f"^{name}\\b.*expected"):
            exp.settings_for("smoke", **{name: _wrong_value(value)})
    # the CLI refuses before anything runs or is written
    out = tmp_path / "out"
    bad = f"{names[0]}={json.dumps(_wrong_value(getattr(exp.settings['smoke'], names[0])))}"
    assert main(["reproduce", exp_id, "--scale", "smoke", "--out", str(out), "--set", bad]) == 2
    assert f"{names[0]}: expected" in capsys.readouterr().err
    assert main(["reproduce", exp_id, "--out", str(out), "--set", "no_such_setting=1"]) == 2
    assert "no_such_setting: not a setting" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("exp_id", IDS)
def test_figures_build(exp_id, tmp_path):
    from skillkit.viz.plots import plotly_figure, write_figures

    result = json.loads(json.dumps(to_jsonable({k: v for k, v in _run(exp_id).items()})))
    result.pop("_trials")
    assert plotly_figure(result).data
    write_figures(result, tmp_path, html=True)
    assert (tmp_path / "figure.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "figure.html").stat().st_size > 1000


@pytest.mark.parametrize("path", sorted(DATA.glob("*/result.json")), ids=lambda p: p.parent.name)
def test_stored_results_carry_the_current_verdict(path):
    """``data/results`` summaries are migrated (data/migrate_summaries.py) and agree with
    each experiment's verdict function on their own numbers."""
    result = json.loads(path.read_text())
    exp = get(result["id"])
    summary = result["summary"]
    assert list(summary)[:3] == list(VERDICT_KEYS) and "claim_holds" not in summary
    settings = apply_overrides(exp.settings[result["scale"]], result["settings"])
    stale, _ = staleness(result)
    if not stale:  # a stale run's overrides are relative to the defaults of the code that made it
        assert result["overrides"] == json.loads(
            json.dumps(to_jsonable(exp.overrides(result["scale"], settings)))
        )
    verdict = exp.verdict(settings, summary)
    again = judged({**summary, **verdict.as_dict()}, result["id"], result["scale"])
    assert again == summary
    if exp.own_checks is not None:
        checks = {k: v for k, v in summary["own_checks"].items() if k != "own_criterion"}
        assert checks == json.loads(json.dumps(to_jsonable(exp.own_checks(settings, summary))))
