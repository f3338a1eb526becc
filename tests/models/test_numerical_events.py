"""Handled numerical events: counted inside a recorder, warned about once
outside it, kept per fit, per trial (across interrupted and resumed runs and worker
processes) and in a run's summary; remaining warnings never go through a progress bar."""

from __future__ import annotations

import json
import pickle
import re
import warnings
from dataclasses import dataclass, replace

import numpy as np
import pytest

from skillkit.experiments import registry
from skillkit.experiments.registry import Experiment, Series
from skillkit.experiments.runner import (
    _execute_trial,
    _replay_warnings,
    reproduce,
    run_trials,
)
from skillkit.experiments.settings import Settings, setting
from skillkit.models.gp import (
    EVENT_KINDS,
    ExactGP,
    GPNumericalWarning,
    NumericalEvents,
    record_numerical_events,
    report_event,
)
from skillkit.trial import TrialContext


def _jitter_fit() -> ExactGP:
    """A fit that needs jitter exactly once, deterministically: every input three times, the
    noise (1e-20) below float64's resolution of the unit diagonal, so K + noise·I is exactly
    singular (its factorisation fails at the second copy of the first input) and 1e-12 is
    the jitter that works. No optimisation (n_steps=0), noise well above its floor."""
    X = np.repeat(np.array([[0.0], [1.0], [2.0]]), 3, axis=0)
    gp = ExactGP(
        lengthscale=1.0,
        outputscale=1.0,
        noise=1e-20,
        noise_floor=1e-21,
        n_steps=0,
        additive_noise=0.0,
        standardize=False,
    )
    return gp.fit(X, np.sin(X[:, 0]))


def _gp_warnings(caught) -> list[str]:
    return [str(w.message) for w in caught if issubclass(w.category, GPNumericalWarning)]


def test_a_handled_event_inside_a_recorder_is_counted_not_warned():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with record_numerical_events() as events:
            gp = _jitter_fit()
    assert _gp_warnings(caught) == []
    assert events.counts == {**dict.fromkeys(EVENT_KINDS, 0), "jitter_increased": 1}
    assert events.total == 1 and events.max_jitter == 1e-12
    assert gp.diagnostics["jitter"] == 1e-12
    assert gp.diagnostics["numerical_events"] == events.to_dict()


def test_the_same_fit_outside_a_recorder_warns_once():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gp = _jitter_fit()
    assert len(_gp_warnings(caught)) == 1
    assert "added jitter 1e-12" in _gp_warnings(caught)[0]
    assert gp.diagnostics["numerical_events"]["jitter_increased"] == 1  # the fit's own record


def test_recorders_nest_and_quiet_decides_the_warning():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with record_numerical_events() as outer:
            report_event("restored_iterate", "first")
            with record_numerical_events() as inner:
                report_event("noise_at_floor", "second")
                with record_numerical_events(quiet=False) as observer:
                    report_event("jitter_increased", "third", jitter=1e-8)
            report_event("restored_iterate", "fourth")
        assert _gp_warnings(caught) == []  # every event had a quiet recorder around it
        assert outer.counts["restored_iterate"] == 2 and outer.total == 4
        assert outer.max_jitter == 1e-8
        assert inner.total == 2 and inner.counts["noise_at_floor"] == 1
        assert observer.total == 1 and observer.counts["jitter_increased"] == 1
        with record_numerical_events(quiet=False) as alone:  # counts and warns
            report_event("negative_variance_clipped", "fifth")
        assert alone.total == 1 and _gp_warnings(caught) == ["fifth"]
        report_event("negative_variance_clipped", "sixth")  # outside: warns, nobody counts
        assert _gp_warnings(caught) == ["fifth", "sixth"] and outer.total == 4


def test_events_record_arithmetic_and_bad_kinds():
    a = NumericalEvents()
    a.add("jitter_increased", 1e-10)
    mark = a.copy()
    a.add("jitter_increased", 1e-8)
    a.add("restored_iterate")
    delta = a.since(mark)
    assert delta.counts["jitter_increased"] == 1 and delta.counts["restored_iterate"] == 1
    assert delta.max_jitter == 1e-8 and a.since(a.copy()).max_jitter == 0.0
    assert NumericalEvents.from_dict(a.to_dict()) == a
    assert json.loads(json.dumps(a.to_dict())) == a.to_dict()
    b = NumericalEvents().update(a).update(a.to_dict())
    assert b.counts["jitter_increased"] == 4 and b.max_jitter == 1e-8
    assert "jitter_increased=2" in repr(a) and repr(NumericalEvents()) == "NumericalEvents(none)"
    with pytest.raises(ValueError, match="kind: expected one of"):
        report_event("jitter", "typo")
    with pytest.raises(ValueError, match="kind: expected one of"):
        NumericalEvents.from_dict({"nope": 1})


def test_sparse_fit_and_gpreps_model_stats_carry_the_events():
    from skillkit.models.reward import gp_stats
    from skillkit.models.sparse import FITC

    rng = np.random.default_rng(0)
    X = rng.uniform(-1, 1, size=(30, 2))
    gp = FITC(n_inducing=8, n_steps=3).fit(X, np.sin(X).sum(1), rng=0)
    assert set(gp.diagnostics["numerical_events"]) == {*EVENT_KINDS, "max_jitter"}
    assert gp_stats(gp, 30)["numerical_events"] == gp.diagnostics["numerical_events"]


# ------------------------------------------------------------------ trials: resume, workers
def _unit_of_work(k: int) -> None:
    """Stands in for a model fit that handles one event."""
    report_event("restored_iterate", f"step {k}")


def _walk(trial: TrialContext, rng, n: int, crash_at: int | None) -> None:
    """Set-up before the resume (done again by every run), then saved units of work."""
    report_event("jitter_increased", "set-up", jitter=1e-10)
    state = trial.resume("walk", rng) or {"k": 0}
    for k in range(state["k"], n):
        _unit_of_work(k)
        state["k"] = k + 1
        trial.save("walk", state, rng)
        if k == crash_at:
            raise RuntimeError("crash")
    report_event("noise_at_floor", "after the last save")  # done again by a resumed run


def test_a_resumed_trial_counts_what_an_uninterrupted_one_counts():
    rng = np.random.default_rng(0)
    with record_numerical_events() as clean:
        _walk(TrialContext(events=clean), rng, 5, None)
    assert clean.counts["restored_iterate"] == 5 and clean.total == 7

    written = []
    with record_numerical_events() as first:
        ctx = TrialContext(events=first, writer=lambda s, t: written.append(1))
        with pytest.raises(RuntimeError, match="crash"):
            _walk(ctx, rng, 5, crash_at=2)
    assert ctx.saved_events["walk"]["restored_iterate"] == 3  # set-up not attributed
    assert ctx.saved_events["walk"]["jitter_increased"] == 0 and len(written) == 3
    states, saved = ctx.snapshots, json.loads(json.dumps(ctx.saved_events))
    with record_numerical_events() as resumed:
        again = TrialContext(states=states, events=resumed, saved_events=saved)
        _walk(again, rng, 5, None)
    assert resumed == clean
    assert again.saved_events["walk"]["restored_iterate"] == 5
    assert TrialContext().saved_events == {}  # no record, nothing kept


@dataclass(frozen=True)
class _EventSettings(Settings):
    n: int = setting(4, "Units of work of the trial.")


CRASH: dict = {"at": None}


def _trial(settings, rng, trial):
    trial.reset(total=settings.n)
    crash, CRASH["at"] = CRASH["at"], None
    _walk(trial, rng, settings.n, crash)
    warnings.warn("a warning a user must act on", RuntimeWarning, stacklevel=1)
    return {"x": float(rng.normal())}


def _summarize(settings, trials):
    xs = [t["x"] for t in trials]
    summary = {"mean_x": float(np.mean(xs))}
    series = [Series("x", list(range(len(xs))), xs, panel="a", xlabel="trial")]
    return series, summary


@pytest.fixture
def events_exp(monkeypatch):
    quick = _EventSettings()
    exp = Experiment(
        "toy30.3",
        "numerical events",
        _EventSettings,
        {"smoke": replace(quick, n=2), "quick": quick, "paper": replace(quick, n=6)},
        _trial,
        _summarize,
        trials={"smoke": 1, "quick": 2, "paper": 2},
        claim="events are counted",
    )
    monkeypatch.setitem(registry._EXPERIMENTS, exp.id, exp)
    return exp


EXPECTED = {
    "restored_iterate": 4,
    "jitter_increased": 1,
    "noise_at_floor": 1,
    "negative_variance_clipped": 0,
    "max_jitter": 1e-10,
}


def test_runner_reports_events_per_trial_and_in_the_summary(events_exp, tmp_path):
    with pytest.warns(RuntimeWarning, match="must act"):  # the remaining warning stays one
        run = reproduce("toy30.3", seed=2, out=tmp_path, progress=False, html=False)
    result = json.loads((run.path / "result.json").read_text())
    assert result["numerical_events"] == {
        "per_trial": [EXPECTED, EXPECTED],
        "total": {**{k: 2 * n for k, n in EXPECTED.items()}, "max_jitter": 1e-10},
    }
    summary = result["summary"]
    assert "verdict" not in summary  # an id the claims spec does not judge keeps its summary
    assert list(summary)[-1] == "handled_numerical_events"
    assert summary["handled_numerical_events"] == result["numerical_events"]["total"]
    # finished trials come back from their checkpoints with their counts
    with warnings.catch_warnings(record=True) as none:
        warnings.simplefilter("always")
        again = reproduce("toy30.3", seed=2, out=tmp_path, progress=False, html=False)
    assert not [w for w in none if "must act" in str(w.message)]  # nothing was rerun
    assert again.summary == summary and again.result["resumed_trials"] == 2


def test_an_interrupted_trial_resumes_without_losing_or_doubling_events(events_exp, tmp_path):
    CRASH["at"] = 2  # trial 0 stops after saving 3 of 6 units of work
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with pytest.raises(RuntimeError, match="crash"):
            reproduce("toy30.3", "paper", seed=1, out=tmp_path, progress=False, html=False)
        run = reproduce("toy30.3", "paper", seed=1, out=tmp_path, progress=False, html=False)
    assert run.result["resumed_trials"] == 1
    per_trial = run.result["numerical_events"]["per_trial"]
    assert per_trial[0] == per_trial[1] == {**EXPECTED, "restored_iterate": 6}


def test_a_worker_returns_its_counts_and_warnings_for_the_caller(events_exp):
    exp = events_exp
    settings = exp.settings_for("smoke")
    seq = np.random.SeedSequence(0)
    with warnings.catch_warnings(record=True) as shown:
        warnings.simplefilter("always")
        result, info = _execute_trial("toy30.3", settings, seq, 0, None, None, False, True)
    assert shown == []  # collected, not shown in the worker
    assert info["numerical_events"] == {**EXPECTED, "restored_iterate": 2}
    assert [(m, c) for m, c, *_ in info["warnings"]] == [
        ("a warning a user must act on", RuntimeWarning)
    ]
    pickle.loads(pickle.dumps((result, info)))  # what a process pool or Ray sends back
    with pytest.warns(RuntimeWarning, match="must act"):
        _replay_warnings(info["warnings"], progress=False)


def test_counts_come_back_from_a_process_pool():
    """fig2.12 factorises rank-deficient posterior covariances (jitter): its counts, made in a
    worker process, are those of the same trial run here. (The summaries' numbers are not
    compared bit for bit: with more than one torch thread the worker may reduce in another
    order, and the hyper-parameter optimiser amplifies that round-off; the executors' own tests
    check same seed ⇒ same result.)"""
    local = run_trials("fig2.12", "smoke", trials=1, progress=False)
    pool = run_trials("fig2.12", "smoke", trials=1, progress=False, executor="process", workers=1)
    assert local["numerical_events"]["total"]["jitter_increased"] > 0
    assert pool["numerical_events"] == local["numerical_events"]
    assert pool["summary"].keys() == local["summary"].keys()


def test_remaining_warnings_are_written_above_the_progress_bar(events_exp, capsys):
    before = warnings.showwarning
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        run_trials("toy30.3", "smoke", seed=0, progress=True)
    assert warnings.showwarning is before  # the runner's redirection ended with the trial
    err = capsys.readouterr().err
    lines = [s for s in re.split(r"[\r\n]", err) if "RuntimeWarning: a warning" in s]
    assert len(lines) == 1 and lines[0].startswith(__file__)  # on a line of its own:
    assert "toy30.3 trial" in err  # the bar was cleared and redrawn, not written through
    assert "GPNumericalWarning" not in err


@pytest.mark.filterwarnings("error::skillkit.models.gp.GPNumericalWarning")
def test_smoke_reproduce_of_gp_fits_prints_no_numerical_warning(tmp_path):
    """fig4.6 at smoke scale: the events are counted, and no GPNumericalWarning goes through
    the progress bar; FITC noise variances at their floor whose gap diag(K_nn − Q_nn) carries
    the added target noise are no event."""
    run = reproduce("fig4.6", "smoke", trials=1, out=tmp_path, progress=False, html=False)
    result = json.loads((run.path / "result.json").read_text())
    counts = result["summary"]["handled_numerical_events"]
    assert set(counts) == {*EVENT_KINDS, "max_jitter"}
    assert counts["noise_at_floor"] == 0
    assert result["numerical_events"]["total"] == counts
    assert result["numerical_events"]["per_trial"] == [counts]
