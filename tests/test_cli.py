"""The command line (skillkit.cli): fast help, help texts, where ``runs`` looks, ``compare``'s
refusals, the verdict reports of ``demo`` and ``reproduce``, and the measured wall times."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import warnings

import pytest

from skillkit import cli
from skillkit.cli import build_parser, main
from skillkit.experiments import timings
from skillkit.experiments.registry import get
from skillkit.experiments.runner import to_jsonable

HEAVY = ("torch", "numpy", "scipy", "gpytorch", "plotly", "matplotlib", "skillkit.experiments")


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_parser_and_help_import_nothing_heavy():
    """``skillkit --help`` took ~9 s because building the parser loaded every experiment (and
    torch); now neither building it nor any ``--help`` imports torch, numpy or the registry."""
    code = f"""
import json, sys
import skillkit.cli as cli
parser = cli.build_parser()
for argv in [["--help"]] + [[name, "--help"] for name in {sorted(_subparsers(build_parser()))!r}]:
    try:
        cli.main(argv)
    except SystemExit as exc:
        assert exc.code == 0, (argv, exc.code)
print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))
"""
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    assert json.loads(proc.stdout.splitlines()[-1]) == []


def test_scales_match_the_registry():
    from skillkit.experiments.registry import SCALES

    assert cli.SCALES == SCALES


def test_top_level_help_is_plain_text(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "``" not in out and ":class:" not in out
    assert "skillkit demo" in out and "reproduce" in out


def test_every_option_of_every_subcommand_has_help():
    parser = build_parser()
    subparsers = _subparsers(parser)
    choices = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert {a.dest for a in choices._choices_actions if a.help} == set(subparsers)
    missing = [
        f"{name} {action.option_strings or action.dest}"
        for name, sub in subparsers.items()
        for action in sub._actions
        if not isinstance(action, argparse._HelpAction) and not (action.help or "").strip()
    ]
    assert missing == []
    assert all(sub.description for sub in subparsers.values())


# ------------------------------------------------------------------------------------- runs
def _write_run(folder, exp_id="fig2.10", seed=0, **extra):
    folder.mkdir(parents=True)
    result = {
        "id": exp_id,
        "scale": "quick",
        "seed": seed,
        "trials": 1,
        "summary": {"claim": "c", "holds": True, "statement": "s", "err": 0.5 + seed},
        "settings": json.loads(json.dumps(to_jsonable(get(exp_id).settings["quick"].to_dict()))),
        "series": [{"name": "curve", "x": [0, 1], "y": [1.0, 0.5]}],
        **extra,
    }
    (folder / "result.json").write_text(json.dumps(result))
    return folder


def test_runs_defaults_to_runs_folder_or_the_current_one(tmp_path, monkeypatch, capsys):
    _write_run(tmp_path / "runs" / "fig2.10-quick-s1", seed=1)
    _write_run(tmp_path / "runs" / "sanity3-quick-s2", "sanity3", seed=2)
    monkeypatch.chdir(tmp_path)  # a folder holding runs/
    assert main(["runs"]) == 0
    out = capsys.readouterr().out
    assert "runs/fig2.10-quick-s1" in out and "runs/sanity3-quick-s2" in out
    monkeypatch.chdir(tmp_path / "runs")  # inside the runs folder
    assert main(["runs"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert {line.split()[0] for line in lines} == {"fig2.10-quick-s1", "sanity3-quick-s2"}
    monkeypatch.chdir(tmp_path / "runs" / "sanity3-quick-s2")  # inside one run's folder
    assert main(["runs"]) == 0
    assert "sanity3" in capsys.readouterr().out
    assert main(["runs", "--root", str(tmp_path / "runs" / "fig2.10-quick-s1")]) == 0
    assert "fig2.10" in capsys.readouterr().out


def test_runs_says_where_it_looked_when_nothing_is_found(tmp_path, monkeypatch, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.chdir(empty)
    assert main(["runs"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.startswith("skillkit: error: no runs found") and "\n" not in err
    assert f"no runs/ folder in {empty.resolve()}" in err and "no result.json below" in err
    assert captured.out == ""
    assert main(["runs", "--root", "nowhere"]) == 2
    assert "no results folder at nowhere" in capsys.readouterr().err
    (empty / "runs").mkdir()
    assert main(["runs"]) == 0
    assert f"no runs (no result.json) under {(empty / 'runs').resolve()}" in capsys.readouterr().out


# ---------------------------------------------------------------------------------- compare
def test_compare_two_good_runs_and_either_as_result_json(tmp_path, capsys):
    a = _write_run(tmp_path / "a", seed=1)
    b = _write_run(tmp_path / "b", seed=2)
    assert main(["compare", str(a), str(b / "result.json")]) == 0
    out = capsys.readouterr().out
    err_line = next(line for line in out.splitlines() if line.startswith("summary.err"))
    assert err_line.split()[1:] == ["1.5", "2.5"]


BAD = {
    "not JSON": ("{", "result.json: not valid JSON"),
    "a list": ("[1, 2]", "holds no run (expected a JSON object, got list)"),
    "only an id": ({"id": "fig3.3"}, "result.json: holds no run (no summary and no series)"),
    "no series": ({"id": "x", "summary": {}}, "result.json: series: missing"),
    "summary a list": ({"summary": [1], "series": []}, "summary: expected an object, got a list"),
    "settings a string": (
        {"summary": {}, "settings": "n=3", "series": []},
        "settings: expected an object, got a string",
    ),
    "series an object": ({"summary": {}, "series": {}}, "series: expected a list, got an object"),
    "entry a string": ({"series": ["curve"]}, "series[0]: expected an object, got a string"),
    "entry without name": (
        {"series": [{"name": "a", "x": [], "y": []}] * 2 + [{"x": [], "y": []}]},
        "series[2].name: expected a string, missing",
    ),
    "name a number": (
        {"series": [{"name": 3, "x": [], "y": []}]},
        "series[0].name: expected a string, got a number",
    ),
    "x a string": (
        {"series": [{"name": "a", "x": "0 1", "y": []}]},
        "series[0].x: expected a list, got a string",
    ),
    "y missing": ({"series": [{"name": "a", "x": []}]}, "series[0].y: expected a list, missing"),
    "y null": (
        {"series": [{"name": "a", "x": [], "y": None}]},
        "series[0].y: expected a list, got null",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
@pytest.mark.parametrize("position", [0, 1])
def test_compare_refuses_a_malformed_result_in_one_line(case, position, tmp_path, capsys):
    content, message = BAD[case]
    bad = tmp_path / "bad"
    bad.mkdir()
    text = content if isinstance(content, str) else json.dumps(content)
    (bad / "result.json").write_text(text)
    good = _write_run(tmp_path / "good")
    args = [str(good), str(bad)] if position else [str(bad), str(good)]
    assert main(["compare", *args]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.startswith("skillkit: error: ") and "\n" not in err, err
    assert f"{bad / 'result.json'}: " in err and message in err
    assert "Traceback" not in err and captured.out == ""


def test_compare_names_a_file_that_is_not_a_result_json(tmp_path, capsys):
    good = _write_run(tmp_path / "good")
    other = tmp_path / "figure.json"
    other.write_text((good / "result.json").read_text())
    for path, message in (
        (other, f"{other}: not a result.json (expected a run folder or its result.json"),
        (tmp_path / "missing", f"{tmp_path / 'missing'}: no such file or folder"),
        (tmp_path, f"{tmp_path}: no result.json in this folder"),
    ):
        assert main(["compare", str(path), str(good)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("skillkit: error: ") and message in err and "\n" not in err


# ------------------------------------------------------------------- reports and timings
@pytest.fixture
def times_file(tmp_path, monkeypatch):
    """A measured-times table in a temporary file (``None`` content: no file at all)."""

    def use(content):
        path = tmp_path / ("absent.json" if content is None else "scale_times.json")
        if content is not None:
            path.write_text(json.dumps(content))
        monkeypatch.setattr(timings, "TIMES_FILE", path)
        timings._table.cache_clear()

    yield use
    timings._table.cache_clear()


TABLE = {"cores": 2, "load_before": 0.1, "commit": "abcdef0123", "times": {}}
TABLE["times"]["fig2.10"] = {"smoke": 2.0, "quick": 3.0}
TABLE["times"]["sanity3"] = {"smoke": 4.0, "quick": 40.0}


def test_settings_shows_measured_times_or_not_measured(times_file, capsys):
    times_file(TABLE)
    assert main(["settings", "sanity3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].startswith("measured wall time") and "smoke 4 s, quick 40 s" in lines[1]
    assert "2 cores, load 0.1 before, commit abcdef0" in lines[1]
    times_file(None)
    assert main(["settings", "sanity3"]) == 0
    line = capsys.readouterr().out.splitlines()[1]
    assert line.endswith("smoke not measured, quick not measured")


def test_reproduce_prints_the_estimate_and_the_verdict_not_json(times_file, tmp_path, capsys):
    from skillkit.experiments.run import load_run as get_run

    times_file(TABLE)
    args = ["reproduce", "fig2.10", "--scale", "smoke", "--out", str(tmp_path), "--quiet"]
    assert main([*args, "--no-html", "--trials", "2"]) == 0
    captured = capsys.readouterr()
    assert "fig2.10 at smoke scale: expected wall time about 4 s" in captured.err  # 2 × 2 s
    out = captured.out.splitlines()
    assert out[0].startswith("fig2.10 (smoke scale, 2 trials, seed 0, ")
    card = get_run(tmp_path / "fig2.10-smoke-s0").card.split("\n")
    start = out.index("  " + card[0])
    assert out[start : start + 3] == ["  " + line for line in card]  # the card, as in Jupyter
    assert card[0].startswith("fig2.10: ") and card[1].startswith("smoke scale: not judged")
    folder = tmp_path / "fig2.10-smoke-s0"
    assert f"  files:  {folder}/ (result.json, figure.png, trials.npz)" in out
    assert f"{folder / 'figure.png'}" in out[-1] and len(out) <= 12
    assert "{" not in captured.out
    times_file(None)
    assert main([*args, "--no-html", "--json"]) == 0
    captured = capsys.readouterr()
    assert "expected wall time" not in captured.err
    line = json.loads(captured.out)
    assert line["id"] == "fig2.10" and "holds" in line["summary"]
    assert line["path"] == str(folder)


def test_demo_prints_a_short_report_per_experiment(tmp_path, monkeypatch, capsys):
    from skillkit.experiments.registry import ids

    assert set(cli.DEMO_IDS) <= set(ids())
    monkeypatch.setattr(cli, "DEMO_IDS", ("fig2.10",))  # the real demo takes a minute
    monkeypatch.setattr(cli, "DEMO_COMPARISON", None)  # tested on its own below
    assert main(["demo", "--out", str(tmp_path), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "skillkit demo: fig2.10 at quick scale" in captured.err
    report, _, rest = captured.out.partition("\n\n")
    lines = report.splitlines()
    assert len(lines) <= 12 and lines[0].startswith("fig2.10 (quick scale, 1 trial, seed 0, ")
    assert any(line.startswith("  ") and line.endswith(": holds") for line in lines)
    assert f"{tmp_path / 'fig2.10-quick-s0' / 'figure.html'} in a browser" in report
    assert rest.startswith("next: ")
    assert main(["demo", "--out", str(tmp_path), "--quiet", "--json"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [json.loads(line)["summary"]["holds"] for line in out] == [True]


def test_runs_check_lists_stale_results_and_exits_non_zero(tmp_path, capsys):
    from skillkit.experiments.provenance import code_fingerprint

    current = {"id": "fig2.10", "code_fingerprint": code_fingerprint("fig2.10")}
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "result.json").write_text(json.dumps(current))
    assert main(["runs", "--check", "--root", str(tmp_path)]) == 0
    assert "1 results under" in capsys.readouterr().out
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "result.json").write_text(json.dumps({"id": "fig2.10"}))
    assert main(["runs", "--check", str(tmp_path), "--quiet"]) == 1  # the folder as a positional
    out = capsys.readouterr().out
    assert "stale" in out and "no code fingerprint" in out
    assert out.splitlines()[-1].endswith(": 1 current, 0 carried, 1 stale")
    with pytest.raises(SystemExit, match="give the folder once"):
        main(["runs", str(tmp_path), "--root", str(tmp_path / "a")])
    with pytest.raises(SystemExit, match="--record goes with --check"):
        main(["runs", str(tmp_path), "--record"])


def test_runs_check_record_carries_a_result_whose_witness_is_equal(tmp_path, monkeypatch, capsys):
    """The code changed (another fingerprint) but the smoke witness of today's code equals the
    stored one: carried; ``--record`` writes the carry record, and the next check runs
    nothing."""
    from skillkit.experiments import runner
    from skillkit.experiments.provenance import code_fingerprint

    old, now = "0" * 16, code_fingerprint("fig2.10")
    witness = {
        "seed": 0,
        "trials": 1,
        "code_fingerprint": old,
        "summary": {"e": 1.0},
        "series": [{"y": [1.0, 2.0]}],
        "unstable": [],
    }
    result = {"id": "fig2.10", "seed": 0, "code_fingerprint": old, "witness": witness}
    _write_run(tmp_path / "fig2.10-paper-s0", **result)
    calls = []

    def fake(exp_id, seed=0, **kwargs):
        calls.append(exp_id)
        return {**witness, "code_fingerprint": now, "commit": "feedbee"}

    monkeypatch.setattr(runner, "smoke_witness", fake)
    assert main(["runs", "--check", "--record", str(tmp_path), "--quiet"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("carried ") and "code changed at feedbee, witness equal" in out[0]
    assert out[-1].endswith(": 0 current, 1 carried, 0 stale") and calls == ["fig2.10"]
    stored = json.loads((tmp_path / "fig2.10-paper-s0" / "result.json").read_text())
    assert stored["carried"][0]["code_fingerprint"] == now
    assert main(["runs", "--check", str(tmp_path), "--quiet"]) == 0
    assert calls == ["fig2.10"]  # recorded: nothing ran
    capsys.readouterr()
    assert main(["runs", str(tmp_path), "--markdown"]) == 0
    assert "| carried (witness equal) |" in capsys.readouterr().out


def test_demo_comparison_reports_gpreps_against_reps_and_opens_in_the_viewer(tmp_path):
    from skillkit.experiments import get, reproduce
    from skillkit.viz.history import load_policy_history
    from skillkit.viz.model_layers import load_gpreps_run

    demo = dict(cli.DEMO_COMPARISON)
    get("cmp.methods").settings_for("quick", **demo)  # the demo's settings are valid
    assert demo["methods"] == ("gpreps", "reps") and demo["tasks"] == ("throwing",)
    demo["tasks"] = ("hockey",)  # the same report from a run of seconds
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        run = reproduce(
            "cmp.methods", scale="smoke", out=tmp_path, progress=False, html=False, **demo
        )
    lines = cli._comparison_lines(run)
    rows = run.summary["tasks"]["hockey"]["methods"]
    assert [line.split(":")[0].strip() for line in lines[1:3]] == ["gpreps", "reps"]
    assert f"{rows['gpreps']['real_rollouts']:5.0f} real throws" in lines[1]
    assert lines[-1] == f"  watch GPREPS learn: skillkit view hockey --gpreps {run.path}"
    history, model = load_gpreps_run(run.path, 0)  # what that command loads
    assert len(history.policies) == demo["gpreps_updates"] + 1 and model.task.name == "hockey"
    # throwing's reward model draws no prediction layers: the viewer plays the policy back
    demo["tasks"] = ("throwing",)
    demo.update(n_artificial=4, n_trajectories=1, gpreps_updates=1, reps_updates=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        run = reproduce(
            "cmp.methods", scale="smoke", out=tmp_path, progress=False, html=False, **demo
        )
    line = cli._comparison_lines(run)[-1]
    assert line == f"  watch GPREPS learn: skillkit view throwing --policy {run.path}"
    assert len(load_policy_history(run.path, 0).policies) == 2


def test_set_changes_one_field_of_a_nested_settings_block():
    from skillkit.cli import _overrides
    from skillkit.experiments.registry import get

    got = _overrides(["reps.n_updates=80", "reps.epsilon=0.5", "grid_y=[1, 3]"])
    assert got == {"reps": {"n_updates": 80, "epsilon": 0.5}, "grid_y": [1, 3]}
    quick = get("fig3.3").settings["quick"]
    st = get("fig3.3").settings_for("quick", **_overrides(["reps.n_updates=80"]))
    assert st.reps.n_updates == 80 and st.reps.n_reuse_batches == quick.reps.n_reuse_batches
    with pytest.raises(ValueError, match="reps.no_such"):
        get("fig3.3").settings_for("quick", **_overrides(["reps.no_such=1"]))
