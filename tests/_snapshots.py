"""A TrialContext that records its checkpoints, for resume tests (shared by several test
directories: add to it, do not rename)."""

from skillkit.trial import TrialContext


class Snapshots(TrialContext):
    """Keeps every key's snapshots after every save (``history``: one dict per save)."""

    def __init__(self, states=None):
        super().__init__(states=states)
        self.history = []

    def save(self, key, state, rng):
        super().save(key, state, rng)
        self.history.append(self.snapshots)
