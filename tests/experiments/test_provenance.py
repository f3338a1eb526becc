"""Provenance: the code fingerprint follows code, not documentation; stale results are found."""

import ast
import json
import os
import shutil
import subprocess
import sys

import pytest

from skillkit.experiments import provenance
from skillkit.experiments.registry import get, ids

MODULE = '''"""Module doc."""
from skillkit.search import ContextualREPS


def f(x):
    """Function doc."""
    # a comment
    return x + 1
'''


def _fingerprint(tmp_path, text):
    path = tmp_path / "m.py"
    path.write_text(text)
    return provenance.code_fingerprint(path)


def test_fingerprint_ignores_comments_docstrings_and_blank_lines_but_not_code(tmp_path):
    before = _fingerprint(tmp_path, MODULE)
    docs = MODULE.replace("Function doc.", "Other words.").replace("a comment", "more\n\n")
    assert _fingerprint(tmp_path, docs) == before
    assert _fingerprint(tmp_path, MODULE.replace("x + 1", "x + 2")) != before
    # a string that is not a docstring is code
    assert _fingerprint(tmp_path, MODULE + 'NAME = "a"\n') != _fingerprint(
        tmp_path, MODULE + 'NAME = "b"\n'
    )


def test_closure_follows_a_reexported_name_to_its_module_only(tmp_path):
    path = tmp_path / "m.py"
    path.write_text(MODULE)
    closure = provenance.source_closure(path)
    assert path.resolve() in closure
    root = provenance.PACKAGE_ROOT
    names = {str(f.relative_to(root)) for f in closure if f.is_relative_to(root)}
    assert "search/reps.py" in names  # ContextualREPS is defined there
    assert "search/__init__.py" in names  # runs on import: hashed
    assert "search/pilco.py" not in names  # re-exported by search/__init__, not used
    assert not any(n.startswith("viz/") for n in names)


def test_every_registered_experiment_has_a_fingerprint_and_its_module_in_the_closure():
    for exp_id in ids():
        fp = provenance.code_fingerprint(exp_id)
        assert len(fp) == 16 and int(fp, 16) >= 0
        module = get(exp_id).run_trial.__module__.rsplit(".", 1)[-1] + ".py"
        source = provenance._source_file(get(exp_id).run_trial)
        assert any(f.name == module for f in provenance.source_closure(source))


def test_check_results_marks_changed_missing_and_unknown_provenance(tmp_path):
    exp_id = "fig2.10"
    current = provenance.code_fingerprint(exp_id)
    cases = {
        "current": {"id": exp_id, "code_fingerprint": current, "git": {"commit": "abc"}},
        "changed": {"id": exp_id, "code_fingerprint": "0" * 16, "git": {"commit": "abc1234"}},
        "missing": {"id": exp_id},
        "unknown": {"id": "fig9.9", "code_fingerprint": current},
    }
    for name, result in cases.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "result.json").write_text(json.dumps(result))
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "result.json").write_text("[1, 2]")  # not a run: skipped
    rows = {r["path"].rsplit("/", 1)[-1]: r for r in provenance.check_results(tmp_path)}
    assert set(rows) == set(cases)
    assert not rows["current"]["stale"] and rows["current"]["reason"] == "current"
    assert rows["changed"]["stale"] and "abc1234" in rows["changed"]["reason"]
    assert rows["missing"]["stale"] and "no code fingerprint" in rows["missing"]["reason"]
    assert rows["unknown"]["stale"] and "not registered" in rows["unknown"]["reason"]


def test_git_state_outside_a_checkout_is_unknown(tmp_path):
    assert provenance.git_state(tmp_path) == {"commit": None, "dirty": None}


def test_a_function_without_source_is_refused_by_name():
    with pytest.raises(ValueError, match="obj"):
        provenance.code_fingerprint(len)


def test_a_reproduced_run_records_its_provenance_and_is_current(tmp_path):
    """result.json names the commit and the code fingerprint; check_results then calls it
    current, and a stored result is stale once its fingerprint differs from today's."""
    from skillkit.experiments import reproduce

    run = reproduce("fig2.10", "smoke", trials=1, out=tmp_path, progress=False, html=False)
    result = json.loads((run.path / "result.json").read_text())
    assert result["code_fingerprint"] == provenance.code_fingerprint("fig2.10")
    assert set(result["git"]) == {"commit", "dirty"}
    # the CPU and torch's SIMD level (what round-off depends on), as torch reports it
    import torch

    assert result["machine"]["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert {"cpu_model", "platform", "cpus"} <= set(result["machine"])
    assert [r["stale"] for r in provenance.check_results(tmp_path)] == [False]
    result["code_fingerprint"] = "0" * 16
    (run.path / "result.json").write_text(json.dumps(result))
    assert [r["stale"] for r in provenance.check_results(tmp_path)] == [True]


def test_a_result_whose_scale_settings_changed_is_stale_naming_the_field(tmp_path, monkeypatch):
    """Today's code, but the scale's settings (with the run's overrides) differ from the ones
    the run stored: stale, with each field's stored and today's value; no smoke witness can
    carry it across a code change."""
    from skillkit.experiments import reproduce, runner

    run = reproduce("fig4.12", "smoke", trials=1, out=tmp_path, progress=False, html=False)
    result = json.loads((run.path / "result.json").read_text())
    assert provenance.settings_changes(result) == ""
    n = result["settings"]["evaluation"]["n_heldout"]
    result["settings"]["evaluation"]["n_heldout"] = n + 7
    stale, reason = provenance.staleness(result)
    assert stale and f"evaluation.n_heldout {n + 7} → {n}" in reason
    result["overrides"] = {"evaluation": {"n_heldout": n + 7}}  # the same run, asked for
    assert provenance.staleness(result) == (False, "current")
    result["overrides"] = {"no_such_setting": 1}
    assert "overrides no longer apply" in provenance.settings_changes(result)
    result["overrides"], result["code_fingerprint"] = {}, "0" * 16
    (run.path / "result.json").write_text(json.dumps(result))
    monkeypatch.setattr(runner, "smoke_witness", lambda *a, **k: pytest.fail("witness run"))
    (row,) = runner.check_witnesses(tmp_path, record=True, progress=False)
    assert row["stale"] and "evaluation.n_heldout" in row["reason"]


def test_readme_scoreboard_is_made_from_the_stored_results():
    """README.md's "What reproduces so far" table is exactly scoreboard() of data/results."""
    from pathlib import Path

    from skillkit.experiments.run import scoreboard

    readme = (Path(__file__).parents[2] / "README.md").read_text()
    table = readme.split("<!-- scoreboard:start -->\n")[1].split("<!-- scoreboard:end -->")[0]
    assert table == scoreboard(), "regenerate the README table with scoreboard()"


def test_data_readme_results_table_is_made_from_the_stored_results():
    """data/README.md's "What is here" table is exactly `skillkit runs data/results
    --markdown`."""
    from pathlib import Path

    from skillkit.cli import results_table

    root = Path(__file__).parents[2]
    text = (root / "data" / "README.md").read_text()
    table = text.split("<!-- results:start -->\n")[1].split("<!-- results:end -->")[0]
    assert table == results_table(root / "data" / "results"), (
        "regenerate data/README.md's table with `skillkit runs data/results --markdown`"
    )


def test_results_table_names_commit_verdict_and_staleness(tmp_path):
    exp_id = "fig2.10"
    current = provenance.code_fingerprint(exp_id)
    cases = {
        "a-current": {
            "id": exp_id,
            "code_fingerprint": current,
            "trials": 3,
            "wall_time_s": 90,
            "git": {"commit": "abcdef123", "dirty": True},
            "executor": "process",
            "workers": 2,
            "summary": {"verdict": "holds"},
        },
        "b-changed": {
            "id": exp_id,
            "code_fingerprint": "0" * 16,
            "trials": 1,
            "git": {"commit": "1234567", "dirty": False},
            "summary": {"verdict": "undecided"},
        },
        "c-missing": {"id": exp_id, "summary": {}},
    }
    for name, result in cases.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "result.json").write_text(json.dumps(result))
    from skillkit.cli import results_table

    rows = results_table(tmp_path).splitlines()[2:]
    assert rows == [
        "| a-current | abcdef1 (dirty) | 3 | process ×2 | 1.5 | holds | unchanged |",
        "| b-changed | 1234567 | 1 | local | not recorded | undecided | stale: code changed "
        "since commit 1234567 |",
        "| c-missing | not recorded | ? | local | not recorded | not recorded | stale: no code "
        "fingerprint |",
    ]


def test_a_stored_run_says_when_it_is_stale(tmp_path):
    from skillkit.experiments import load_run, reproduce

    run = reproduce("fig2.10", "smoke", trials=1, out=tmp_path, progress=False, html=False)
    assert run.stale is None and "*Stale:*" not in run._repr_markdown_()
    result = json.loads((run.path / "result.json").read_text())
    del result["code_fingerprint"]  # as a result made before provenance was recorded
    (run.path / "result.json").write_text(json.dumps(result))
    old = load_run(run.path)
    assert "no code fingerprint" in old.stale and "*Stale:*" in old._repr_markdown_()


def test_registering_an_experiment_changes_no_other_experiments_fingerprint():
    """``skillkit.experiments``' ``__init__`` imports every experiment module to register it;
    those lines are left out of its hash, its other code is not."""
    package = "skillkit.experiments"
    text = (
        "from skillkit.experiments.registry import get\n"
        "from skillkit.experiments import ch2  # registers\n"
        "from skillkit.experiments import (\n    ch5,\n)\n"
        "from skillkit.experiments import registry, not_a_module\n"
    )
    assert provenance._registration_lines(ast.parse(text), package) == {2, 3, 4, 5}
    init = provenance.PACKAGE_ROOT / "experiments" / "__init__.py"
    stat = init.stat()
    tokens = provenance._normalised(init, stat.st_mtime_ns, stat.st_size).decode().split("\n")
    assert "1:registry" in tokens and "1:reproduce" in tokens  # code that stays hashed
    registered = {get(i).run_trial.__module__.rsplit(".", 1)[-1] for i in ids()}
    assert "cmp_methods" in registered and "ch2" in registered
    assert not registered & {t.partition(":")[2] for t in tokens}


def test_closure_follows_a_lazily_exported_name_to_its_module(tmp_path):
    """``skillkit.search`` exports CMA-ES and BO through ``__getattr__``; a module importing
    them from the package has their defining modules in its closure."""
    path = tmp_path / "m.py"
    path.write_text("from skillkit.search import CMAES, ContextualBO\n")
    root = provenance.PACKAGE_ROOT
    names = {
        str(f.relative_to(root)) for f in provenance.source_closure(path) if f.is_relative_to(root)
    }
    assert {"search/cmaes.py", "search/cbo.py", "search/__init__.py"} <= names
    import skillkit.search

    assert all(
        getattr(skillkit.search, name).__module__ == module
        for name, module in skillkit.search._LAZY.items()
    )


# ---------------------------------------------------------------------------- the witness
def _witness(summary, fingerprint="f" * 16, series=(), **extra):
    return {
        "scale": "smoke",
        "seed": 0,
        "trials": 1,
        "commit": "abc1234",
        "code_fingerprint": fingerprint,
        "summary": provenance.measurements(summary),
        "series": provenance.series_measurements(list(series)),
        "unstable": [],
        **extra,
    }


def test_measurements_keep_numbers_and_drop_judgement_and_text():
    summary = {
        "claim": "c",
        "holds": True,
        "statement": "ours 1.0",
        "thesis": [{"quote": "q", "location": "p. 1"}],
        "own_checks": {"x": {"holds": False, "criterion": "t"}},
        "err": 0.5,
        "per_arm": {"reps": {"n": 3, "ok": True, "note": "text", "holds": None, "gap": None}},
        "curve": [1.0, 2.0],
        "labels": ["a", "b"],
        "words": {"only": "text"},
        "empty": {},
    }
    assert provenance.measurements(summary) == {
        "err": 0.5,
        "per_arm": {"reps": {"n": 3, "ok": True, "gap": None}},
        "curve": [1.0, 2.0],
        "empty": {},
    }
    assert {"claim", "holds", "statement", "thesis", "own_checks"} <= provenance.JUDGEMENT_KEYS


def test_compare_witness_equal_within_round_off_and_names_a_changed_number():
    rtol, atol = provenance.WITNESS_RTOL, provenance.WITNESS_ATOL
    curve = [{"x": [0, 1], "y": [1.0, 3.0]}]
    stored = _witness({"a": {"b": 2.0}, "z": 0.0, "n": None}, series=curve)
    near = _witness(
        {"a": {"b": 2.0 * (1 + 0.5 * rtol)}, "z": 0.5 * atol, "n": float("nan")},
        series=[{"x": [0, 1], "y": [1.0, 3.0 * (1 - 0.5 * rtol)]}],
    )
    assert provenance.compare_witness(stored, near) == (True, [])
    far = _witness(
        {"a": {"b": 2.0 * (1 + 2 * rtol)}, "z": 0.0, "n": None},
        series=[{"x": [0, 1], "y": [1.0, 3.5]}],
    )
    equal, differences = provenance.compare_witness(stored, far)
    assert not equal and len(differences) == 2
    assert differences[0].startswith("summary.a.b: 2.0 -> 2.000004")
    assert differences[1] == "series[0].y: 1 of 2 values differ, first [1]: 3.0 -> 3.5"
    missing = _witness({"a": {}, "z": 0.0, "n": None}, series=[{"x": [0, 1], "y": [1.0]}])
    equal, differences = provenance.compare_witness(stored, missing)
    assert not equal and differences == [
        "summary.a.b: missing (stored 2.0)",
        "series[0].y: length 2 -> 1",
    ]


def test_compare_witness_allows_added_measurements_and_ignores_text_and_unstable_ones():
    base = {"claim": "c", "statement": "ours 1", "err": 1.0, "time_s": 3.2}
    curve = [{"name": "a", "x": [0], "y": [1.0]}]
    stored = _witness(base, series=curve, unstable=["summary.time_s"])
    fresh = _witness(
        {**base, "statement": "other words", "holds": False, "time_s": 9.9, "new": 4},
        series=[{"name": "renamed", "x": [0], "y": [1.0], "band": "b"}, {"x": [0], "y": [2.0]}],
    )
    equal, differences = provenance.compare_witness(stored, fresh)
    assert equal
    assert differences == ["added: summary.new = 4", "added: series[1] = an object of 2 keys"]


def _result(folder, exp_id, fingerprint, seed, witness=None):
    folder.mkdir(parents=True)
    result = {
        "id": exp_id,
        "seed": seed,
        "code_fingerprint": fingerprint,
        "git": {"commit": "abc1234", "dirty": False},
        "summary": {"holds": True},
    }
    if witness is not None:
        result["witness"] = witness
    (folder / "result.json").write_text(json.dumps(result, indent=1))
    return result


def test_check_results_counts_and_a_recorded_carry_needs_no_run(tmp_path, monkeypatch):
    from skillkit.experiments import runner

    exp_id = "fig2.12"
    now = provenance.code_fingerprint(exp_id)
    old = "0" * 16
    _result(tmp_path / "a-current", exp_id, now, 0, _witness({"e": 1.0}, fingerprint=now))
    _result(tmp_path / "b-carried", exp_id, old, 1, _witness({"e": 1.0}, old, seed=1))
    _result(tmp_path / "c-differs", exp_id, old, 2, _witness({"e": 2.0}, old, seed=2))
    _result(tmp_path / "d-none", exp_id, old, 3)
    calls = []

    def fake(exp, seed=0, *, trials=None, repeats=1, progress=False):
        calls.append(seed)
        return {**_witness({"e": 1.0, "new": 3}, fingerprint=now), "seed": seed}

    monkeypatch.setattr(runner, "smoke_witness", fake)
    rows = runner.check_witnesses(tmp_path, record=True, progress=False)
    status = {r["path"].rsplit("/", 1)[-1]: (r["status"], r["reason"]) for r in rows}
    assert status["a-current"] == ("current", "current")
    assert status["b-carried"] == ("carried", "carried (code changed at abc1234, witness equal)")
    assert status["c-differs"][0] == "stale"
    assert (
        status["c-differs"][1] == "witness differs: summary.e: 2.0 -> 1.0; added: summary.new = 3"
    )
    assert status["d-none"][0] == "stale" and "no witness" in status["d-none"][1]
    assert sorted(calls) == [1, 2]
    carried = json.loads((tmp_path / "b-carried" / "result.json").read_text())
    assert [set(c) for c in carried["carried"]] == [{"code_fingerprint", "commit", "checked"}]
    assert carried["carried"][0]["code_fingerprint"] == now
    assert "carried" not in json.loads((tmp_path / "c-differs" / "result.json").read_text())
    # the record makes the next check of b instant, and staleness() reads it too
    calls.clear()
    rows = runner.check_witnesses(tmp_path, progress=False)
    assert [r["status"] for r in rows] == ["current", "carried", "stale", "stale"]
    assert calls == [2]
    assert provenance.staleness(carried) == (False, status["b-carried"][1])
    assert [r["status"] for r in provenance.check_results(tmp_path)] == [
        "current",
        "carried",
        "stale",
        "stale",
    ]
    assert calls == [2]  # check_results runs nothing


def test_add_witness_refuses_a_result_made_by_other_code(tmp_path):
    from skillkit.experiments.runner import add_witness

    _result(tmp_path / "r", "fig2.12", "0" * 16, 0)
    with pytest.raises(ValueError, match="a witness must come from the code that made"):
        add_witness(tmp_path / "r")


def test_stored_numbers_computed_in_series_are_in_the_fingerprint():
    """Experiments import ``trial_band`` through ``skillkit.viz.series`` and ``Series`` through
    the registry: both lead to ``skillkit/series.py``, while viz itself stays out."""
    root = provenance.PACKAGE_ROOT
    for exp_id in ("fig3.3", "fig2.12"):
        closure = provenance.source_closure(provenance._source_file(get(exp_id).run_trial))
        names = {str(f.relative_to(root)) for f in closure}
        assert "series.py" in names
        assert not any(n.startswith("viz/") for n in names)


_WITNESS_SCRIPT = """
import json, sys
from pathlib import Path
from skillkit.experiments import provenance, runner
mode, out = sys.argv[1], sys.argv[2]
if mode == "make":
    folder = Path(out) / "fig2.12-paper-s0"
    folder.mkdir(parents=True)
    made = {"id": "fig2.12", "seed": 0, "code_fingerprint": provenance.code_fingerprint("fig2.12")}
    runner.write_result(folder, made)
    print(json.dumps(runner.add_witness(folder)))
else:
    rows = runner.check_witnesses(out, record=True, progress=False)
    print(json.dumps(rows))
"""


def _in_copy(src, *args):
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-c", _WITNESS_SCRIPT, *map(str, args)],
        cwd=src,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def _edit(path, old, new):
    text = path.read_text()
    assert old in text, (path, old)
    path.write_text(text.replace(old, new))


def test_a_pure_refactor_carries_a_result_and_a_numeric_change_stales_it(tmp_path):
    """In a copy of the package: a result of fig2.12 gets its witness; renaming a private
    helper of models/gp.py changes the fingerprint and the fresh witness equals the stored one
    (carried, recorded); changing the jitter levels fig2.12 uses changes its numbers (stale:
    the witness differs)."""
    src = tmp_path / "src"
    shutil.copytree(
        provenance.PACKAGE_ROOT, src / "skillkit", ignore=shutil.ignore_patterns("__pycache__")
    )
    out = tmp_path / "runs"
    witness = _in_copy(src, "make", out)
    assert witness["scale"] == "smoke" and witness["unstable"] == []
    made_by = witness["code_fingerprint"]

    models = src / "skillkit" / "models"
    for name in ("gp.py", "pathwise.py"):
        _edit(models / name, "flush_tiny", "_flush_below_resolution")
    [row] = _in_copy(src, "check", out)
    assert (row["status"], row["stale"]) == ("carried", False), row["reason"]
    stored = out / "fig2.12-paper-s0" / "result.json"
    [record] = json.loads(stored.read_text())["carried"]
    assert record["code_fingerprint"] != made_by

    _edit(models / "gp.py", "_JITTER_LEVELS = (1e-12,", "_JITTER_LEVELS = (1e-10,")
    [row] = _in_copy(src, "check", out)
    assert row["status"] == "stale" and row["reason"].startswith("witness differs: summary."), row
    assert len(json.loads(stored.read_text())["carried"]) == 1


def test_reproduce_stores_the_smoke_witness_of_the_same_code(tmp_path, monkeypatch):
    """A quick run is stored with its witness; fig2.12 has the same settings at every scale,
    so the witness measures what the run measured. A rerun that resumes keeps the witness."""
    import skillkit.viz.plots
    from skillkit.experiments import runner

    monkeypatch.setattr(skillkit.viz.plots, "write_figures", lambda *a, **k: None)
    run = runner.reproduce("fig2.12", "quick", out=tmp_path, progress=False, html=False)
    witness = run.result["witness"]
    assert witness["code_fingerprint"] == run.result["code_fingerprint"]
    assert (witness["scale"], witness["seed"], witness["trials"]) == ("smoke", 0, 1)
    assert witness["summary"] == provenance.measurements(run.summary)
    assert witness["series"] == provenance.series_measurements(run.result["series"])
    assert json.loads((run.path / "result.json").read_text())["witness"] == witness
    calls = []
    monkeypatch.setattr(runner, "smoke_witness", lambda *a, **k: calls.append(a))
    again = runner.reproduce("fig2.12", "quick", out=tmp_path, progress=False, html=False)
    assert again.result["witness"] == witness and calls == []
    smoke = runner.reproduce("fig2.12", "smoke", out=tmp_path, progress=False, html=False)
    assert "witness" not in smoke.result
