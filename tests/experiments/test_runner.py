"""The experiment runner and CLI: registry, result.json contents, determinism, bad input."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from skillkit.cli import main
from skillkit.experiments import registry
from skillkit.experiments.registry import Experiment, Series, mean_band
from skillkit.experiments.runner import reproduce, run_folder, run_trials
from skillkit.experiments.settings import Settings, apply_overrides, setting

CRASH = {"at": None}


class Crash(Exception):
    pass


@dataclass(frozen=True)
class WalkSettings(Settings):
    n: int = setting(5, "Steps of the random walk.")


def _trial(settings, rng, progress):
    """A random walk that checkpoints after every step (like a policy update)."""
    progress.reset(total=settings.n)
    state = progress.resume("walk", rng) or {"k": 0, "steps": []}
    for k in range(state["k"], settings.n):
        state["steps"].append(float(rng.normal()))
        state["k"] = k + 1
        progress.save("walk", state, rng)
        progress.update()
        if CRASH["at"] == k:
            CRASH["at"] = None
            raise Crash
    walk = np.cumsum(state["steps"])
    return {"walk": walk, "last": float(walk[-1])}


def _summarize(settings, trials):
    curves = np.array([t["walk"] for t in trials])
    m, lo, hi = mean_band(curves)
    series = [Series("walk", list(range(settings.n)), m, lower=lo, upper=hi, panel="a", xlabel="t")]
    summary = {"mean_last": float(np.mean([t["last"] for t in trials]))}
    return series, summary


@pytest.fixture
def toy(monkeypatch):
    quick = WalkSettings()
    exp = Experiment(
        "toy1.1",
        "random walk",
        WalkSettings,
        {"smoke": replace(quick, n=2), "quick": quick, "paper": replace(quick, n=50)},
        _trial,
        _summarize,
        trials={"smoke": 1, "quick": 3, "paper": 2},
        claim="walks wander",
    )
    monkeypatch.setitem(registry._EXPERIMENTS, exp.id, exp)
    return exp


def test_same_seed_same_series_and_different_seed_differs(toy):
    a = run_trials("toy1.1", seed=3, progress=False)
    b = run_trials("toy1.1", seed=3, progress=False)
    c = run_trials("toy1.1", seed=4, progress=False)
    assert a["series"] == b["series"] and a["summary"] == b["summary"]
    assert a["series"] != c["series"]
    assert a["trials"] == 3 and a["settings"] == {"n": 5}


def test_trials_are_independent_of_how_many_run(toy):
    """Trial i uses the i-th child seed, so running more trials keeps the first ones."""
    two = run_trials("toy1.1", trials=2, seed=0, progress=False)["_trials"]
    three = run_trials("toy1.1", trials=3, seed=0, progress=False)["_trials"]
    np.testing.assert_array_equal(two[1]["walk"], three[1]["walk"])


def test_reproduce_writes_result_figures_and_arrays(toy, tmp_path):
    folder = reproduce("toy1.1", scale="paper", seed=1, out=tmp_path, progress=False)
    result = json.loads((folder / "result.json").read_text())
    assert result["id"] == "toy1.1" and result["scale"] == "paper" and result["trials"] == 2
    assert {
        "settings",
        "seed",
        "versions",
        "series",
        "summary",
        "wall_time_s",
        "claim",
    } <= result.keys()
    assert result["versions"]["numpy"] == np.__version__
    assert len(result["series"][0]["y"]) == 50
    assert (folder / "figure.html").stat().st_size > 10_000
    assert (folder / "figure.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with np.load(folder / "trials.npz") as arrays:
        np.testing.assert_allclose(arrays["trial1__walk"][-1], arrays["trial1__last"])


def test_overrides_and_bad_arguments(toy):
    result = run_trials("toy1.1", n=2, progress=False)
    assert result["settings"] == {"n": 2} and result["overrides"] == {"n": 2}
    assert run_trials("toy1.1", "smoke", progress=False)["overrides"] == {}
    with pytest.raises(ValueError, match="nope: not a setting of WalkSettings .*settings: n"):
        run_trials("toy1.1", nope=1, progress=False)
    with pytest.raises(ValueError, match="n: expected int, got 2.0"):
        run_trials("toy1.1", n=2.0, progress=False)
    with pytest.raises(ValueError, match="scale"):
        run_trials("toy1.1", scale="huge", progress=False)
    with pytest.raises(ValueError, match="trials"):
        run_trials("toy1.1", trials=0, progress=False)
    with pytest.raises(ValueError, match="seed"):
        run_trials("toy1.1", seed=-1, progress=False)
    with pytest.raises(ValueError, match="unknown experiment"):
        run_trials("fig99.9", progress=False)


def test_runs_with_overrides_get_their_own_folder(toy, tmp_path):
    standard = run_folder("toy1.1", "quick", 1, tmp_path)
    assert standard == tmp_path / "toy1.1-quick-s1"
    assert run_folder("toy1.1", "quick", 1, tmp_path, {"n": 5}) == standard  # the quick value
    other = run_folder("toy1.1", "quick", 1, tmp_path, {"n": 7})
    assert other.name.startswith("toy1.1-quick-s1-") and len(other.name) == len(standard.name) + 9
    assert run_folder("toy1.1", "quick", 1, tmp_path, {"n": 7}) == other  # stable
    assert run_folder("toy1.1", "quick", 1, tmp_path, {"n": 8}) != other
    folder = reproduce("toy1.1", seed=1, out=tmp_path, progress=False, html=False, n=7)
    assert folder.path == other and not standard.exists()
    assert json.loads((folder / "result.json").read_text())["overrides"] == {"n": 7}
    with pytest.raises(ValueError, match="n: expected int"):
        reproduce("toy1.1", seed=1, out=tmp_path, progress=False, fresh=True, n="7")
    assert (folder / "trials").exists()  # a refused override deletes nothing


def test_registration_needs_every_scale_and_a_claim(toy):
    with pytest.raises(ValueError, match="smoke"):
        registry.register(replace(toy, id="toy1.2", settings={"quick": toy.settings["quick"]}))
    with pytest.raises(ValueError, match="claim"):
        registry.register(replace(toy, id="toy1.3", claim=""))
    with pytest.raises(ValueError, match="settings_class"):
        registry.register(replace(toy, id="toy1.4", settings_class=dict))


def test_duplicate_registration_is_refused(toy):
    with pytest.raises(ValueError, match="already registered"):
        registry.register(toy)


def test_mean_band_matches_numpy():
    curves = np.random.default_rng(0).normal(size=(4, 6))
    m, lo, hi = mean_band(curves)
    np.testing.assert_allclose(m, curves.mean(0))
    np.testing.assert_allclose(np.array(hi) - np.array(m), curves.std(0, ddof=1))
    _, lo95, hi95 = mean_band(curves, kind="ci95")
    np.testing.assert_allclose(
        np.array(hi95) - np.array(lo95), 2 * 1.96 * curves.std(0, ddof=1) / 2
    )


def test_cli_list_reproduce_and_errors(toy, tmp_path, capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "toy1.1" in out and "pendulum" in out
    assert main(["reproduce", "toy1.1", "--out", str(tmp_path), "--quiet", "--seed", "2"]) == 0
    assert json.loads((tmp_path / "toy1.1-quick-s2" / "result.json").read_text())["seed"] == 2
    assert main(["reproduce", "nope", "--out", str(tmp_path), "--quiet"]) == 2
    assert "unknown experiment" in capsys.readouterr().err
    for bad, message in (("n=2.5", "n: expected int"), ("m=2", "m: not a setting")):
        args = ["reproduce", "toy1.1", "--out", str(tmp_path / "bad"), "--set", bad]
        assert main(args + ["--quiet"]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
    assert main(["reproduce", "toy1.1", "--scale", "smoke", "--out", str(tmp_path), "--quiet"]) == 0
    assert (tmp_path / "toy1.1-smoke-s0" / "result.json").exists()
    assert main(["settings", "toy1.1"]) == 0
    out = capsys.readouterr().out
    assert "Steps of the random walk." in out and "paper  50" in out


def test_interrupted_run_resumes_to_identical_numbers(toy, tmp_path):
    clean = reproduce("toy1.1", scale="paper", seed=5, out=tmp_path / "clean", progress=False)
    CRASH["at"] = 17  # crash in trial 0 after 18 of 50 steps
    with pytest.raises(Crash):
        reproduce("toy1.1", scale="paper", seed=5, out=tmp_path / "resumed", progress=False)
    assert (tmp_path / "resumed" / "toy1.1-paper-s5" / "trials" / "trial_000.ckpt").exists()
    resumed = reproduce("toy1.1", scale="paper", seed=5, out=tmp_path / "resumed", progress=False)
    a = json.loads((clean / "result.json").read_text())
    b = json.loads((resumed / "result.json").read_text())
    assert a["series"] == b["series"] and a["summary"] == b["summary"]
    assert a["resumed_trials"] == 0 and b["resumed_trials"] == 1  # trial 0 continued
    assert all(t > 0 for t in b["trial_time_s"])


def test_finished_trials_are_not_rerun_and_fresh_starts_over(toy, tmp_path, monkeypatch):
    first = reproduce("toy1.1", seed=1, out=tmp_path, progress=False)
    meta = json.loads((first / "result.json").read_text())
    assert meta["resumed_trials"] == 0 and meta["workers"] == 1
    assert len(meta["trial_time_s"]) == 3 and all(t > 0 for t in meta["trial_time_s"])
    calls = []
    original = toy.run_trial
    monkeypatch.setattr(toy, "run_trial", lambda *a: calls.append(1) or original(*a))
    again = reproduce("toy1.1", seed=1, out=tmp_path, progress=False)
    assert calls == []
    times = meta["trial_time_s"]
    meta = json.loads((again / "result.json").read_text())
    assert meta["resumed_trials"] == 3 and meta["trial_time_s"] == times  # kept in checkpoints
    reproduce("toy1.1", seed=1, out=tmp_path, progress=False, fresh=True)
    assert len(calls) == 3


def test_foreign_or_corrupt_checkpoint_is_reported(toy, tmp_path, capsys):
    folder = reproduce("toy1.1", seed=1, out=tmp_path, progress=False)
    ckpt = folder / "trials" / "trial_001.ckpt"
    ckpt.write_bytes(ckpt.read_bytes()[:-5])
    assert main(["reproduce", "toy1.1", "--seed", "1", "--out", str(tmp_path), "--quiet"]) == 2
    assert "trial_001.ckpt" in capsys.readouterr().err
    # Other settings written into the same folder are refused too.
    assert (
        main(["reproduce", "toy1.1", "--seed", "1", "--out", str(tmp_path), "--quiet", "--fresh"])
        == 0
    )
    from skillkit.experiments import checkpoint
    from skillkit.experiments.checkpoint import CheckpointError

    ident = checkpoint.identity("toy1.1", {"n": 6}, 0, 1, checkpoint.code_fingerprint(_trial))
    with pytest.raises(CheckpointError, match="settings"):
        checkpoint.load(folder / "trials" / "trial_000.ckpt", ident)


def test_runs_and_compare(toy, tmp_path, capsys):
    reproduce("toy1.1", seed=1, out=tmp_path, progress=False)
    reproduce("toy1.1", seed=2, out=tmp_path, progress=False)
    assert main(["runs", "--root", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "toy1.1-quick-s1" in out and "toy1.1-quick-s2" in out
    a, b = tmp_path / "toy1.1-quick-s1", tmp_path / "toy1.1-quick-s2"
    assert main(["compare", str(a), str(b), "--out", str(tmp_path / "cmp")]) == 0
    out = capsys.readouterr().out
    ra = json.loads((a / "result.json").read_text())["summary"]["mean_last"]
    line = next(l for l in out.splitlines() if l.startswith("summary.mean_last"))
    assert float(line.split()[1]) == pytest.approx(ra, rel=1e-5)
    assert (tmp_path / "cmp" / "figure.png").exists()
    assert main(["compare", str(a), str(tmp_path / "missing")]) == 2


def test_kill_9_mid_run_then_resume_gives_identical_numbers(tmp_path):
    """A real ``kill -9`` of ``skillkit reproduce`` mid-trial, then a rerun of the same command."""
    import os
    import signal
    import subprocess
    import sys
    import time

    args = [
        "reproduce",
        "sanity3",
        "--trials",
        "1",
        "--seed",
        "9",
        "--quiet",
        "--set",
        "n_updates=120",  # 3 algorithms × 120 updates: seconds of work after the first save
    ]
    assert main(args + ["--out", str(tmp_path / "clean")]) == 0
    cmd = [sys.executable, "-m", "skillkit.cli"] + args + ["--out", str(tmp_path / "killed")]
    killed = run_folder("sanity3", "quick", 9, tmp_path / "killed", {"n_updates": 120})
    ckpt = killed / "trials" / "trial_000.ckpt"
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be killed"
    time.sleep(0.3)  # let it get a few updates further, well before the end
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (ckpt.parent.parent / "result.json").exists()
    from skillkit.experiments import checkpoint as ck

    raw = ckpt.read_bytes()
    assert raw.startswith(ck.MAGIC)
    assert main(args + ["--out", str(tmp_path / "killed")]) == 0
    clean = run_folder("sanity3", "quick", 9, tmp_path / "clean", {"n_updates": 120})
    a = json.loads((clean / "result.json").read_text())
    b = json.loads((killed / "result.json").read_text())
    assert a["series"] == b["series"]
    assert a["summary"] == b["summary"]


def _children(pid: int) -> set[int]:
    """PIDs whose parent is ``pid`` (Linux /proc)."""
    from pathlib import Path

    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.add(int(stat.parent.name))
    return out


@pytest.mark.skipif(not __import__("os").path.exists("/proc/self/stat"), reason="reads /proc")
def test_killing_a_process_pool_run_leaves_no_workers_computing(tmp_path):
    """``kill -9`` of ``reproduce --executor process``: its workers end too (and the rerun
    would resume from their checkpoints)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    cmd = [sys.executable, "-m", "skillkit.cli", "reproduce", "sanity3", "--trials", "2"]
    cmd += ["--seed", "9", "--quiet", "--executor", "process", "--workers", "2"]
    cmd += ["--set", "n_updates=5000", "--out", str(tmp_path)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    trials = run_folder("sanity3", "quick", 9, tmp_path, {"n_updates": 5000}) / "trials"
    deadline = time.monotonic() + 300
    while len(list(trials.glob("trial_*.ckpt"))) < 2 and time.monotonic() < deadline:
        assert proc.poll() is None, "the run ended before both workers checkpointed"
        time.sleep(0.1)
    workers = _children(proc.pid)
    assert len(workers) >= 2  # two workers (and multiprocessing's resource tracker)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()

    def running(pid: int) -> bool:  # exists and is not a zombie waiting to be reaped
        try:
            return open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0] != "Z"
        except OSError:
            return False

    deadline = time.monotonic() + 30
    while any(map(running, workers)) and time.monotonic() < deadline:
        time.sleep(0.2)
    alive = [w for w in workers if running(w)]
    for w in alive:  # do not leave them running if the check fails
        os.kill(w, signal.SIGKILL)
    assert not alive, f"workers {alive} outlived the killed run"


def test_bad_run_arguments_delete_no_checkpoints_and_are_not_truncated(toy, tmp_path):
    """``fresh=True`` with a bad trial count, seed or worker count refuses before deleting
    anything; a fractional trial or worker count is refused, not truncated; workers or an
    address the executor would ignore are refused."""
    folder = reproduce("toy1.1", seed=1, out=tmp_path, progress=False, html=False)
    before = sorted(p.name for p in (folder / "trials").iterdir())
    assert len(before) == 3
    bad = (
        ({"trials": 0}, "trials"),
        ({"trials": 2.5}, "trials"),
        ({"trials": "2"}, "trials"),
        ({"workers": 0, "executor": "process"}, "workers"),
        ({"workers": 1.5, "executor": "process"}, "workers"),
        ({"executor": "cluster"}, "executor"),
        ({"workers": 2}, "workers"),  # the local executor would ignore it
        ({"address": "auto", "executor": "process"}, "address"),
    )
    for kwargs, name in bad:
        with pytest.raises(ValueError, match=f"^{name}: (expected|the 'local'|only the 'ray')"):
            reproduce("toy1.1", seed=1, out=tmp_path, progress=False, fresh=True, **kwargs)
        assert sorted(p.name for p in (folder / "trials").iterdir()) == before, kwargs
    with pytest.raises(ValueError, match="^seed: expected"):
        run_trials("toy1.1", seed=1.0, progress=False)
    with pytest.raises(ValueError, match="^workers: the 'local' executor"):
        run_trials("toy1.1", workers=4, progress=False)
    with pytest.raises(ValueError, match="^trials: expected"):
        run_trials("toy1.1", trials=True, progress=False)


@dataclass(frozen=True)
class _RealSettings(Settings):
    x: float = setting(1.0, "A real number.")
    xs: tuple[float, ...] = setting((1.0, 2.0), "Real numbers.")
    maybe: float | None = setting(None, "A real number or null.")


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), np.float64("nan")])
def test_non_finite_settings_are_refused(bad):
    for name, value in (("x", bad), ("xs", (1.0, bad)), ("maybe", bad)):
        with pytest.raises(ValueError, match=f"^{name}: expected .*finite float"):
            apply_overrides(_RealSettings(), {name: value})
        with pytest.raises(ValueError, match=f"^{name}: expected .*finite float"):
            _RealSettings(**{name: value})
    assert apply_overrides(_RealSettings(), {"x": 2, "maybe": -3.5}).maybe == -3.5


@dataclass(frozen=True)
class _BoundedSettings(Settings):
    n: int = setting(3, "A count.", minimum=1)
    eps: float = setting(0.5, "A KL bound.", above=0.0)
    p: float = setting(0.5, "A probability.", minimum=0.0, maximum=1.0)
    ns: tuple[int | None, ...] = setting((1, None, 4), "Counts or null.", minimum=1)
    free: float = setting(-2.0, "Unbounded.")


@pytest.mark.parametrize(
    ("name", "value", "expected"),
    [
        ("n", 0, "≥ 1"),
        ("n", -1, "≥ 1"),
        ("eps", 0.0, "> 0"),
        ("eps", -1e-9, "> 0"),
        ("p", 1.5, "≥ 0 and ≤ 1"),
        ("p", -0.1, "≥ 0 and ≤ 1"),
        ("ns", (1, None, 0), r"≥ 1 \(every entry\)"),
    ],
)
def test_settings_out_of_their_declared_range_are_refused(name, value, expected):
    with pytest.raises(ValueError, match=f"^{name}: expected {expected}, got"):
        _BoundedSettings(**{name: value})
    with pytest.raises(ValueError, match=f"^{name}: expected {expected}, got"):
        apply_overrides(_BoundedSettings(), {name: value})


def test_settings_ranges_admit_their_bounds_and_are_described():
    from skillkit.experiments.settings import describe

    edge = _BoundedSettings(n=1, eps=1e-300, p=1.0, ns=(None, 1), free=-1e300)
    assert (edge.n, edge.p, edge.ns) == (1, 1.0, (None, 1))
    kinds = {name: kind for name, kind, _ in describe(_BoundedSettings)}
    assert kinds == {
        "n": "int ≥ 1",
        "eps": "finite float > 0",
        "p": "finite float ≥ 0 and ≤ 1",
        "ns": "list of int or null ≥ 1",
        "free": "finite float",
    }
    with pytest.raises(ValueError, match="minimum: expected a finite number"):
        setting(1, "A count.", minimum=float("nan"))


def test_cli_refuses_nan_and_infinity_settings(tmp_path, capsys):
    """``--set`` parses VALUE as JSON, which accepts NaN and Infinity: refused up front."""
    for pair in ("threshold=NaN", "epsilon=Infinity", "epsilon=-Infinity"):
        args = ["reproduce", "sanity3", "--scale", "smoke", "--out", str(tmp_path), "--quiet"]
        assert main(args + ["--set", pair]) == 2
        assert "expected finite float" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_cli_refuses_settings_outside_their_range_and_lists_the_ranges(tmp_path, capsys):
    """``sanity3 --set threshold=-1`` used to run and report "error < -1" in 0 trials."""
    for pair, expected in (
        ("threshold=-1", "threshold: expected > 0, got -1"),
        ("n_updates=0", "n_updates: expected ≥ 1, got 0"),
    ):
        args = ["reproduce", "sanity3", "--scale", "smoke", "--out", str(tmp_path), "--quiet"]
        assert main(args + ["--set", pair]) == 2
        assert expected in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
    assert main(["settings", "sanity3"]) == 0
    out = capsys.readouterr().out
    assert "threshold (finite float > 0)" in out and "n_updates (int ≥ 1)" in out


@pytest.mark.skipif(not __import__("os").path.exists("/proc/self/stat"), reason="reads /proc")
def test_ctrl_c_stops_a_process_pool_run_at_once(tmp_path):
    """Ctrl-C (SIGINT to the whole process group) of ``reproduce --executor process`` ends the
    run within seconds with exit code 130 and keeps the checkpoints, instead of waiting for
    every queued trial (``ProcessPoolExecutor.__exit__`` waits for all of them)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    cmd = [sys.executable, "-m", "skillkit.cli", "reproduce", "sanity3", "--scale", "smoke"]
    cmd += ["--trials", "3", "--seed", "9", "--quiet", "--executor", "process", "--workers", "1"]
    cmd += ["--no-html", "--set", "n_updates=20000", "--out", str(tmp_path)]
    trials = run_folder("sanity3", "smoke", 9, tmp_path, {"n_updates": 20000}) / "trials"
    proc = subprocess.Popen(  # SIGINT's default action in the child: a test run may ignore it
        cmd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        deadline = time.monotonic() + 300
        while not (trials / "trial_000.ckpt").exists() and time.monotonic() < deadline:
            assert proc.poll() is None, "the run ended before its first checkpoint"
            time.sleep(0.1)
        os.killpg(proc.pid, signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            pytest.fail("reproduce --executor process kept running 60 s after Ctrl-C")
        assert proc.returncode == 130, err
        assert "interrupted" in err.decode()
        assert (trials / "trial_000.ckpt").exists()
        assert not (trials.parent / "result.json").exists()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def test_runs_and_compare_survive_foreign_result_files(toy, tmp_path, capsys):
    """``skillkit runs`` lists a result.json lacking keys with "?" and skips one that is not a
    JSON object; ``compare`` refuses the latter with a one-line error (no traceback)."""
    reproduce("toy1.1", seed=1, out=tmp_path, progress=False, html=False)
    (tmp_path / "bare").mkdir()
    (tmp_path / "bare" / "result.json").write_text("{}")
    (tmp_path / "list").mkdir()
    (tmp_path / "list" / "result.json").write_text("[1, 2]")
    assert main(["runs", "--root", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "toy1.1-quick-s1" in out and "bare" in out and "list" not in out
    bare = next(line for line in out.splitlines() if "bare" in line)
    assert "seed=?" in bare and "trials=?" in bare
    assert main(["compare", str(tmp_path / "list"), str(tmp_path / "bare")]) == 2
    err = capsys.readouterr().err
    assert "holds no run (expected a JSON object, got list)" in err and "Traceback" not in err


def test_remeasure_adds_what_todays_summary_makes_and_refuses_a_changed_measurement(tmp_path):
    """A stored run missing a measurement gets it back from its own trials.npz (recorded as
    ``remeasured``); a stored measurement today's summary does not reproduce is refused and
    nothing is written."""
    import shutil

    from skillkit.experiments.runner import remeasure

    src = Path(__file__).resolve().parents[2] / "data" / "results" / "fig3.7-paper-s0"
    if not src.is_dir():
        pytest.skip("no stored fig3.7 result")
    folder = tmp_path / "fig3.7-paper-s0"
    shutil.copytree(src, folder)
    path = folder / "result.json"
    result = json.loads(path.read_text())
    kept = result["summary"].pop("final_reward_per_trial")
    path.write_text(json.dumps(result))
    assert remeasure(folder, write=True) == ["final_reward_per_trial"]
    back = json.loads(path.read_text())
    assert back["summary"]["final_reward_per_trial"] == kept
    assert back["remeasured"]["added"] == ["summary.final_reward_per_trial"]
    back["summary"]["final_reward_mean"] += 1.0  # a number today's code would not make
    path.write_text(json.dumps(back))
    with pytest.raises(ValueError, match="final_reward_mean"):
        remeasure(folder, write=True)
    assert json.loads(path.read_text()) == back


def test_a_witness_runs_on_one_torch_thread_whatever_the_callers_setting():
    """fig2.12's sample spreads depend on the order of a parallel reduction: the witness of a
    caller at two torch threads equals the stored one (made at one), and the caller keeps two."""
    import json
    from pathlib import Path

    import torch

    from skillkit.experiments.provenance import compare_witness
    from skillkit.experiments.runner import smoke_witness

    stored = json.loads(
        (Path(__file__).parents[2] / "data/results/fig2.12-paper-s0/result.json").read_text()
    )["witness"]
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        fresh = smoke_witness("fig2.12", int(stored["seed"]), trials=stored["trials"])
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    equal, differences = compare_witness(stored, fresh)
    assert equal, differences[:3]
