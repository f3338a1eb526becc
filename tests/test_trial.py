"""The trial context: progress forwarding, snapshot checkpoints, the writer, bad input."""

import numpy as np
import pytest

from skillkit.trial import NullBar, TrialContext


class Bar(NullBar):
    def __init__(self):
        self.calls = []

    def reset(self, total=None):
        self.calls.append(("reset", total))

    def update(self, n=1):
        self.calls.append(("update", n))

    def set_postfix(self, *args, **kwargs):
        self.calls.append(("postfix", kwargs))


def test_progress_goes_to_the_bar():
    bar = Bar()
    trial = TrialContext(bar)
    trial.reset(total=7)
    trial.update()
    trial.update(3)
    trial.set_postfix(loss=1.5)
    assert bar.calls == [("reset", 7), ("update", 1), ("update", 3), ("postfix", {"loss": 1.5})]
    TrialContext().update(5)  # without a bar: nothing happens, nothing fails


def test_resume_returns_the_state_as_saved_and_restores_the_generator():
    trial, rng = TrialContext(), np.random.default_rng(0)
    assert trial.resume("walk", rng) is None
    assert rng.bit_generator.state == np.random.default_rng(0).bit_generator.state  # untouched
    state = {"k": 1, "steps": [0.5]}
    trial.save("walk", state, rng)
    expected = rng.normal(size=3)
    state["steps"].append(9.0)  # changes after the save do not reach the snapshot
    assert trial.resume("walk", rng) == {"k": 1, "steps": [0.5]}
    np.testing.assert_array_equal(rng.normal(size=3), expected)
    # the snapshots carry over to a new context (a resumed process)
    other = TrialContext(states=trial.snapshots)
    assert other.resume("walk", np.random.default_rng(99)) == {"k": 1, "steps": [0.5]}


def test_writer_receives_every_key_after_every_save():
    written = []
    trial = TrialContext(writer=lambda snaps, seconds: written.append((sorted(snaps), seconds)))
    rng = np.random.default_rng(1)
    trial.save("a", 1, rng)
    trial.save("b", 2, rng)
    trial.save("a", 3, rng)
    assert [keys for keys, _ in written] == [["a"], ["a", "b"], ["a", "b"]]
    assert all(s >= 0 for _, s in written)
    assert TrialContext(seconds=12.5).seconds >= 12.5  # earlier runs' time is carried


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match="states"):
        TrialContext(states={"learn": ({"k": 1}, {})})  # not (bytes, generator state)
    with pytest.raises(ValueError, match="rng"):
        TrialContext().save("k", 1, 0)
    for bad in (np.nan, -1.0, "ten"):  # NaN would make every later time NaN
        with pytest.raises(ValueError, match="seconds"):
            TrialContext(seconds=bad)
