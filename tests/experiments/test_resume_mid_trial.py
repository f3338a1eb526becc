"""Experiments whose single trials are long checkpoint mid-trial: resuming from any saved state
gives the same result as the uninterrupted trial (contract over those experiments)."""

from __future__ import annotations

import copy
import warnings

import numpy as np
import pytest

from skillkit.experiments import get
from skillkit.trial import TrialContext

# run at the smoke scale; the model-free ones checkpoint through skillkit.search.loop.learn
MID_TRIAL = ("fig4.3", "fig4.5", "fig5.6", "fig5.7", "sanity3", "fig3.3", "fig3.7", "fig4.6")


class _Recorder(TrialContext):
    """An in-memory trial context that keeps every key's snapshots after every save."""

    def __init__(self, states=None):
        super().__init__(states=states)
        self.history: list[dict] = []

    def save(self, key, state, rng):
        super().save(key, state, rng)
        self.history.append(copy.deepcopy(self.snapshots))


def _run(exp_id: str, ctx: TrialContext) -> dict:
    exp = get(exp_id)
    settings = exp.settings_for("smoke")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return exp.run_trial(settings, np.random.default_rng(11), ctx)


def _assert_same(a, b, where="result"):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            if "time" in str(k):  # wall-clock measurements differ between runs
                continue
            _assert_same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, (np.ndarray, float, np.floating)):
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, where


@pytest.mark.parametrize("exp_id", MID_TRIAL)
def test_resuming_from_every_saved_state_gives_the_uninterrupted_result(exp_id):
    full = _Recorder()
    reference = _run(exp_id, full)
    assert len(full.history) >= 2, "the trial must checkpoint more than once"
    # the first snapshot (setup done) and one from the middle of the work
    for k in sorted({0, len(full.history) // 2}):
        resumed = _run(exp_id, _Recorder(states=copy.deepcopy(full.history[k])))
        _assert_same(reference, resumed, f"{exp_id} resumed from save {k + 1}")
