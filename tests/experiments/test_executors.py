"""The same seeds give the same numbers whatever the executor (local, process pool, Ray)."""

from __future__ import annotations

import pytest

from skillkit.experiments.runner import run_trials

SMALL = {"n_updates": 4}


@pytest.fixture(scope="module")
def local_result():
    return run_trials("sanity3", trials=2, seed=3, progress=False, **SMALL)


def _same(a, b):
    assert a["series"] == b["series"]
    assert a["summary"] == b["summary"]


def test_process_pool_matches_local(local_result):
    result = run_trials(
        "sanity3", trials=2, seed=3, progress=False, executor="process", workers=2, **SMALL
    )
    assert result["executor"] == "process"
    _same(result, local_result)


def test_local_ray_instance_matches_local(local_result):
    pytest.importorskip("ray")
    result = run_trials(
        "sanity3", trials=2, seed=3, progress=False, executor="ray", workers=2, **SMALL
    )
    assert result["executor"] == "ray"
    _same(result, local_result)


def test_bad_executor_arguments():
    with pytest.raises(ValueError, match="executor"):
        run_trials("sanity3", trials=1, progress=False, executor="cluster", **SMALL)
    with pytest.raises(ValueError, match="workers"):
        run_trials("sanity3", trials=1, progress=False, executor="process", workers=0, **SMALL)
