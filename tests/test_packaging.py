"""The repository contract: pyproject.toml and environment.yml list the same dependencies,
the README quickstart and .ci/run agree, and the pinned simulator stack imports."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _pyproject_requirements() -> set[str]:
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    reqs = set(data["project"]["dependencies"])
    for extra in data["project"]["optional-dependencies"].values():
        reqs |= set(extra)
    return {r.replace(" ", "") for r in reqs}


def _environment_pip_requirements() -> set[str]:
    lines = (ROOT / "environment.yml").read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == "- pip:")
    reqs = set()
    for line in lines[start + 1 :]:
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if not stripped.startswith("- "):
            break
        reqs.add(stripped[2:].replace(" ", ""))
    return reqs


def test_environment_yml_lists_the_pyproject_requirements():
    env = _environment_pip_requirements() - {"-e.", "torch==2.13.0"}
    assert env == _pyproject_requirements()


def test_torch_pin_satisfies_the_pyproject_range():
    from packaging.requirements import Requirement

    (torch_req,) = [Requirement(r) for r in _pyproject_requirements() if r.startswith("torch")]
    assert torch_req.specifier.contains("2.13.0")
    assert "torch==2.13.0" in _environment_pip_requirements()


def test_ci_installs_as_the_readme_says_and_runs_its_test_command():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    install = re.search(
        r"^(pip install torch==2\.13\.0 && pip install -e .+)$", readme, re.M
    ).group(1)
    test_cmd = re.search(r"^(python -m pytest.*)$", readme, re.M).group(1)
    assert install.replace("pip install", "python -m pip install") in ci
    assert re.search(rf"^{re.escape(test_cmd)}$", ci, re.M)
    assert "set -euo pipefail" in ci  # pytest's exit 5 (no tests) is not hidden


def test_pinned_simulator_stack_works():
    """dm-control 1.0.50 needs mujoco < 4 (4.0.0 lacks MjModel.flex_vertedge)."""
    import mujoco
    from dm_control import mjcf

    assert mujoco.__version__ == "3.17.0"
    model = mjcf.RootElement()
    body = model.worldbody.add("body", name="b")
    body.add("joint", name="j", type="hinge")
    body.add("geom", type="sphere", size=[0.1], mass=1.0)
    physics = mjcf.Physics.from_mjcf_model(model)
    physics.step()
    assert physics.model.nq == 1
