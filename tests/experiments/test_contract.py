"""The experiment contract, over every registered id at the smoke scale (dm_control
``suite_test`` style): an experiment gets these checks by registering.

Each id must give a strict-JSON result whose ``summary`` starts with the judgement of the
claims spec (``claim``, ``holds``, ``verdict``, ``statement``, ``thesis``), recomputable from the
measurements alone, and a card of at most three short lines that reads; the same seed must
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
from skillkit.experiments import judge
from skillkit.experiments.provenance import staleness
from skillkit.experiments.registry import SCALES, get, ids
from skillkit.experiments.run import load_run
from skillkit.experiments.runner import run_trials, to_jsonable
from skillkit.experiments.settings import Settings, apply_overrides, describe

IDS = ids()
DETERMINISTIC = {"fig2.10"}
"""Experiments that use no randomness (the seed changes nothing)."""
TIMED = {"fig4.4"}
"""Experiments whose numbers are all wall-clock measurements (they differ between runs)."""
TIMED_VERDICT = {"tab4.2", "fig5.5"}
"""Experiments whose verdict reads wall-clock measurements (the rest is deterministic)."""
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
                and not (verdict_timed and k in judge.JUDGEMENT_KEYS)
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


HEAD = ["claim", "holds", "verdict", "statement", "thesis"]
"""The judgement's keys, first in every summary."""


def assert_card_reads(card: str) -> None:
    """At most three lines of at most 100 characters, every number written out, no doubled
    negation or a word repeated by a template ("no the target puck (no hit) … no hit cm")."""
    lines = card.split("\n")
    assert 2 <= len(lines) <= 3 and all(0 < len(x) <= 100 for x in lines), card
    assert not re.search(r"\bn/a\b|\bNone\b|\bnan\b|\bTODO\b", card), card
    assert not re.search(r"\bno\b[^.;:]*\bno\b", card, re.IGNORECASE), card
    assert not re.search(r"\b(\w+) \1\b", card), card


@pytest.mark.parametrize("exp_id", IDS)
def test_summary_starts_with_the_judgement_of_the_spec(exp_id):
    exp = get(exp_id)
    summary = _run(exp_id)["summary"]
    assert list(summary)[:5] == HEAD
    assert summary["claim"] == exp.claim == judge.spec(exp_id).plain
    assert summary["thesis"] == judge.quotes_of(exp_id)
    # Smoke runs are not judged: holds is withheld and not_judged says why.
    assert summary["holds"] is None and summary["verdict"] == "not judged"
    assert summary["not_judged"] == "smoke scale"
    assert_card_reads(summary["judgement"]["card"])
    # A function of the measurements: judging the stored JSON again gives the same summary.
    stored = json.loads(json.dumps(to_jsonable(summary)))
    settings = json.loads(json.dumps(to_jsonable(exp.settings["smoke"].to_dict())))
    assert judge.apply(stored, exp_id, "smoke", settings) == stored


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
def test_stored_results_are_judged_from_their_measurements(path):
    """A stored paper result is judged by today's spec when it is loaded: its card reads, its
    verdict is one of the four outcomes, and every thesis part of the spec has a reading."""
    run = load_run(path)
    summary = run.summary
    assert list(summary)[:5] == HEAD
    assert summary["verdict"] in ("holds", "does not hold", "undecided", "not judged")
    assert_card_reads(run.card)
    claim = judge.spec(run.id)
    assert len(summary["judgement"]["readings"]) == len(claim.parts)
    stale, _ = staleness(run.result)
    if not stale:  # a stale run's overrides are relative to the defaults of the code that made it
        exp = get(run.id)
        settings = apply_overrides(exp.settings[run.scale], run.settings)
        assert run.result["overrides"] == json.loads(
            json.dumps(to_jsonable(exp.overrides(run.scale, settings)))
        )
