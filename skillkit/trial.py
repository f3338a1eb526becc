"""The trial context an experiment's ``run_trial(settings, rng, trial)`` reports progress to
and checkpoints through (:class:`TrialContext`; ``TrialContext()`` is the null context)."""

from __future__ import annotations

import pickle
import time
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np

from skillkit._validation import check_positive, check_type

#: A saved state: the pickled payload and the generator's ``bit_generator.state`` at the save.
Snapshot = tuple[bytes, dict]

#: ``writer(snapshots, seconds)``: persist every key's latest snapshot; ``seconds`` is the
#: compute time spent on the trial so far (:attr:`TrialContext.seconds`).
Writer = Callable[[Mapping[str, Snapshot], float], None]


class ProgressBar(Protocol):
    """What a :class:`TrialContext` forwards progress to (a subset of tqdm's interface)."""

    def reset(self, total: int | None = None) -> Any: ...

    def update(self, n: int = 1) -> Any: ...

    def set_postfix(self, *args: Any, **kwargs: Any) -> Any: ...

    def close(self) -> Any: ...


class NumericalEvents(Protocol):
    """The interface of :class:`skillkit.models.gp.NumericalEvents` (without importing it)."""

    @classmethod
    def from_dict(cls, counts: Mapping) -> NumericalEvents: ...

    def copy(self) -> NumericalEvents: ...

    def since(self, mark: NumericalEvents) -> NumericalEvents: ...

    def update(self, other: NumericalEvents) -> NumericalEvents: ...

    def to_dict(self) -> dict: ...


class NullBar(ProgressBar):
    """A progress bar that shows nothing (the bar of a context without one)."""

    def __repr__(self) -> str:
        return "NullBar()"


class TrialContext:
    """Progress reporting and checkpointing for one trial.

    Work that should survive an interruption calls :meth:`resume` with a key when it starts
    and :meth:`save` with the same key after every unit of work; several keys share a context.
    With ``events`` it also keeps, per key, the numerical events of the work saved under it
    and adds them back when the key resumes, so a resumed trial counts what an uninterrupted
    one counts.

    Parameters
    ----------
    bar : ProgressBar, optional
        Where :meth:`reset`, :meth:`update` and :meth:`set_postfix` go (default: nowhere).
    states : mapping of str to (bytes, dict), optional
        Snapshots to resume from (:attr:`snapshots`).
    writer : callable, optional
        ``writer(snapshots, seconds)``, called after every :meth:`save`.
    seconds : float
        Compute time (s, ≥ 0) of earlier, interrupted runs of this trial.
    events, saved_events : NumericalEvents, mapping of str to dict, optional
        The trial's record of numerical events, and per key the events of earlier runs.

    Examples
    --------
    >>> import numpy as np
    >>> trial, rng = TrialContext(), np.random.default_rng(0)
    >>> trial.save("walk", {"k": 3}, rng)
    >>> x = rng.normal()
    >>> trial.resume("walk", rng), rng.normal() == x
    ({'k': 3}, True)
    """

    def __init__(
        self,
        bar: ProgressBar | None = None,
        *,
        states: Mapping[str, Snapshot] | None = None,
        writer: Writer | None = None,
        seconds: float = 0.0,
        events: NumericalEvents | None = None,
        saved_events: Mapping[str, Mapping] | None = None,
    ):
        self.bar: ProgressBar = NullBar() if bar is None else bar
        self._writer = writer
        self._snapshots: dict[str, Snapshot] = {}
        for key, snap in (states or {}).items():
            if not (isinstance(snap, tuple) and len(snap) == 2 and isinstance(snap[0], bytes)):
                raise ValueError(
                    f"states: expected (pickled bytes, generator state) for key {key!r}, "
                    f"got {type(snap).__name__}"
                )
            self._snapshots[str(key)] = snap
        self._seconds_before = check_positive(seconds, "seconds", allow_zero=True)
        self._started = time.perf_counter()
        self._events = events
        self._key_events: dict[str, NumericalEvents] = {}
        self._carried: set[str] = set()  # keys whose saved events are not in ``events`` yet
        if events is not None:
            for key, counts in (saved_events or {}).items():
                self._key_events[str(key)] = type(events).from_dict(counts)
                self._carried.add(str(key))
            self._mark = events.copy()

    def reset(self, total: int | None = None) -> None:
        """Restart the bar at 0 with ``total`` units of work."""
        self.bar.reset(total=total)

    def update(self, n: int = 1) -> None:
        """Advance the bar by ``n`` units of work."""
        self.bar.update(n)

    def set_postfix(self, *args: Any, **kwargs: Any) -> None:
        """Show values beside the bar (tqdm's ``set_postfix``)."""
        self.bar.set_postfix(*args, **kwargs)

    def save(self, key: str, state: Any, rng: np.random.Generator) -> None:
        """Snapshot ``state`` (any picklable object) and ``rng``'s state under ``key``, then
        hand every key's latest snapshot to the writer."""
        check_type(rng, np.random.Generator, "rng", "a numpy Generator")
        body = pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)
        self._snapshots[str(key)] = (body, rng.bit_generator.state)
        if self._events is not None:  # the events since the last resume or save belong to key
            key = str(key)
            new = self._events.since(self._mark)
            old = None if key in self._carried else self._key_events.get(key)
            self._carried.discard(key)
            self._key_events[key] = new if old is None else old.update(new)
            self._mark = self._events.copy()
        if self._writer is not None:
            self._writer(dict(self._snapshots), self.seconds)

    def resume(self, key: str, rng: np.random.Generator) -> Any | None:
        """The state last saved under ``key``, restoring ``rng`` to its state then; else None."""
        found = key in self._snapshots
        if found and not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng: expected a numpy Generator, got {type(rng).__name__}")
        if self._events is not None:  # the work of key starts (or continues) here
            if found and str(key) in self._carried:
                self._events.update(self._key_events[str(key)])  # counted by earlier runs
            self._carried.discard(str(key))
            self._mark = self._events.copy()
        if not found:
            return None
        body, rng_state = self._snapshots[key]
        rng.bit_generator.state = rng_state
        return pickle.loads(body)

    @property
    def snapshots(self) -> dict[str, Snapshot]:
        """Every key's latest snapshot (a copy; pass it as ``states`` to resume elsewhere)."""
        return dict(self._snapshots)

    @property
    def saved_events(self) -> dict[str, dict]:
        """Per key, the events of the work saved under it (summed over runs), as dicts."""
        return {key: ev.to_dict() for key, ev in self._key_events.items()}

    @property
    def seconds(self) -> float:
        """Compute time spent on this trial: earlier runs up to their last save, plus this one."""
        return self._seconds_before + time.perf_counter() - self._started

    def __repr__(self) -> str:
        keys = ", ".join(sorted(self._snapshots)) or "none"
        persisted = "" if self._writer is None else ", persisted"
        return f"{type(self).__name__}(saved keys: {keys}{persisted}, {self.seconds:.1f} s)"
