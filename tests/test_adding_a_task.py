"""docs/adding_a_task.md works as written: its code blocks, copied into the files they name,
make a task that GPREPS learns and an experiment that runs; nothing inside skillkit/ is edited
(the task registers itself from its own package)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "adding_a_task.md"
BLOCK = re.compile(r"```python\n# (?P<path>\S+)\n(?P<code>.*?)```", re.DOTALL)


def guide_files() -> dict[str, str]:
    """File name → code of every ```python block that starts with a ``# <file>`` line."""
    return {m["path"]: m["code"] for m in BLOCK.finditer(GUIDE.read_text())}


def test_the_guide_names_at_most_five_files_of_the_new_task():
    files = [p for p in guide_files() if p.startswith("mytask/")]
    assert set(files) >= {"mytask/task.py", "mytask/model.py", "mytask/__init__.py"}
    assert "mytask/experiment.py" in files
    assert len(files) <= 5, files


def test_the_guides_steps_register_a_task_that_gpreps_learns(tmp_path, monkeypatch):
    for name, code in guide_files().items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(code)
    monkeypatch.syspath_prepend(str(tmp_path))
    for module in [m for m in sys.modules if m == "mytask" or m.startswith("mytask.")]:
        monkeypatch.delitem(sys.modules, module)
    monkeypatch.chdir(tmp_path)
    from skillkit.tasks import make, names, registry

    # The task registers for this test only.
    monkeypatch.setattr(registry, "_FACTORIES", dict(registry._FACTORIES))
    monkeypatch.setattr(registry, "_TAGS", dict(registry._TAGS))
    from skillkit.experiments import registry as experiments

    monkeypatch.setattr(experiments, "_EXPERIMENTS", dict(experiments._EXPERIMENTS))

    namespace: dict = {"__name__": "run"}
    exec(compile((tmp_path / "run.py").read_text(), "run.py", "exec"), namespace)
    assert "point-reach" in names()
    task = make("point-reach")
    history = namespace["history"]
    gpreps = namespace["gpreps"]
    # N₀ = 10 initial rollouts, then 5 per later update: 10 + 2 × 5 real rollouts in all.
    assert history["rollouts"][-1] == 20
    assert np.all(np.isfinite(history["mean_reward"]))
    assert history["mean_reward"][-1] > history["mean_reward"][0]
    # The model ranks the learned policy above the initial one, as the simulator does.
    s = np.array([[1.0]])
    rng = np.random.default_rng(1)
    predicted, real = [], []
    for policy in (task.initial_policy(), gpreps.policy):
        omega = policy.mean_of(s)
        predicted.append(gpreps.reward_model.expected_rewards(s, omega, 20, rng)[0])
        returns = np.array([task.evaluate(omega[0], s[0], rng)[0] for _ in range(20)])
        real.append((returns.mean(), returns.std(ddof=1) / np.sqrt(returns.size)))
    (initial, se_initial), (learned, se_learned) = real
    assert learned - initial > 4 * np.hypot(se_initial, se_learned)
    assert predicted[1] > predicted[0]


def test_the_guides_experiment_entry_runs_at_smoke(tmp_path, monkeypatch):
    """The experiment of step 3 runs through the runner like a thesis id."""
    test_the_guides_steps_register_a_task_that_gpreps_learns(tmp_path, monkeypatch)
    from skillkit.experiments import registry as experiments
    from skillkit.experiments.runner import reproduce

    assert "mytask.curves" in experiments.ids()
    run = reproduce(
        "mytask.curves", scale="smoke", out=tmp_path / "runs", html=False, progress=False
    )
    summary = run.summary
    for method in ("reps", "gpreps"):
        assert summary[method]["real_rollouts"] > 0
        assert set(summary[method]["rollouts_to_reach"]) == {"-0.1", "-0.01"}


@pytest.mark.parametrize("name", ["mytask/task.py", "mytask/model.py"])
def test_each_guide_file_is_ruff_clean(tmp_path, name):
    path = tmp_path / Path(name).name
    path.write_text(guide_files()[name])
    out = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--isolated", "--line-length", "100", str(path)],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stdout
