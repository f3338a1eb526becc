"""Provenance: the code fingerprint follows code, not documentation; stale results are found."""

import ast
import json

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
        "a-current": {"id": exp_id, "code_fingerprint": current, "trials": 3, "wall_time_s": 90,
                      "git": {"commit": "abcdef123", "dirty": True}, "executor": "process",
                      "workers": 2, "summary": {"holds": True}},
        "b-changed": {"id": exp_id, "code_fingerprint": "0" * 16, "trials": 1,
                      "git": {"commit": "1234567", "dirty": False}, "summary": {"holds": None}},
        "c-missing": {"id": exp_id, "summary": {"holds": False}},
    }  # fmt: skip
    for name, result in cases.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "result.json").write_text(json.dumps(result))
    from skillkit.cli import results_table

    rows = results_table(tmp_path).splitlines()[2:]
    assert rows == [
        "| a-current | abcdef1 (dirty) | 3 | process ×2 | 1.5 | true | unchanged |",
        "| b-changed | 1234567 | 1 | local | not recorded | null | stale: code changed since "
        "commit 1234567 |",
        "| c-missing | not recorded | ? | local | not recorded | false | stale: no code "
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
