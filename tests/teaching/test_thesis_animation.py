"""skillkit.teaching.animation: Figs 3.2 and 3.8 from the stored paper runs' final policies."""

from __future__ import annotations

import numpy as np
import pytest

from skillkit.experiments import stored_run
from skillkit.teaching.animation import stored_final_policy, thesis_animation


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="figure"):
        thesis_animation("fig9.9")
    with pytest.raises(ValueError, match="trial"):
        stored_final_policy("fig3.3", trial=-1)


def test_stored_final_policy_is_the_last_row_of_the_stored_history():
    policy = stored_final_policy("fig3.3", trial=1)
    assert policy is not None and (policy.dim, policy.context_dim) == (41, 2)
    with np.load(stored_run("fig3.3") / "trials.npz") as data:
        assert np.array_equal(policy.mean, data["trial1__policy_mean"][-1])
        assert np.array_equal(policy.gain, data["trial1__policy_gain"][-1])
    policy = stored_final_policy("fig3.7")
    assert policy is not None and (policy.dim, policy.context_dim) == (17, 5)
    with np.load(stored_run("fig3.7") / "trials.npz") as data:
        assert np.array_equal(policy.cov, data["trial0__policy_cov"][-1])
    assert stored_final_policy("no-such-figure") is None


def test_thesis_animation_says_which_policy_it_plays(monkeypatch):
    import skillkit.teaching.animation as animation

    fig = thesis_animation("fig3.2", n_frames=5)
    assert "stored fig3.3 run" in fig.layout.title.text and len(fig.frames) == 5
    fig = thesis_animation("fig3.8", n_frames=5)
    assert "stored fig3.7 run" in fig.layout.title.text and len(fig.frames) == 5
    monkeypatch.setattr(animation, "stored_final_policy", lambda *a, **k: None)
    fig = thesis_animation("fig3.8", n_frames=5)  # without a stored run: the demonstration
    assert "initial policy" in fig.layout.title.text
