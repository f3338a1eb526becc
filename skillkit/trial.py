"""The trial context: what one experiment trial reports progress to and checkpoints through.

An experiment's ``run_trial(settings, rng, trial)`` receives a :class:`TrialContext`, and
:func:`skillkit.search.loop.learn` takes one as ``trial=``. It is two things in one object:

* a **progress bar**: :meth:`~TrialContext.reset`, :meth:`~TrialContext.update`,
  :meth:`~TrialContext.set_postfix` (forwarded to a tqdm-like bar, or dropped);
* a **checkpoint store**: :meth:`~TrialContext.save` a picklable state and the generator's
  state under a key after each unit of work, and :meth:`~TrialContext.resume` it when the work
  starts again. States are kept as pickled snapshots, so what :meth:`~TrialContext.resume`
  returns is the state as it was when saved, whatever happened to the object afterwards.

The context keeps its snapshots in memory; a ``writer`` persists them (the experiment runner
writes them atomically to the trial's checkpoint file, :mod:`skillkit.experiments.runner`).
``TrialContext()`` — no bar, no writer — is the null context for library use and tests.

Given the trial's record of numerical events (``events``, a
:class:`~skillkit.models.gp.NumericalEvents` that a
:func:`~skillkit.models.gp.record_numerical_events` block fills), the context also keeps, per
key, the events of the work saved under it (:attr:`~TrialContext.saved_events`): those counted
between the key's :meth:`~TrialContext.resume` (or the previous save) and each save. A run
that resumes the key adds them back to its record, so a resumed trial counts what a trial run
without interruption counts: work restored from a snapshot is counted once (from the saved
counts), work done again (set-up before a resume, work after the last save) once (live).
"""

from __future__ import annotations

import pickle
import time
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np

from skillkit._validation import check_positive

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
    """The event record a :class:`TrialContext` keeps per key (the interface of
    :class:`skillkit.models.gp.NumericalEvents`; declared here so this foundation layer does
    not import the models)."""

    @classmethod
    def from_dict(cls, counts: Mapping) -> NumericalEvents: ...

    def copy(self) -> NumericalEvents: ...

    def since(self, mark: NumericalEvents) -> NumericalEvents: ...

    def update(self, other: NumericalEvents) -> NumericalEvents: ...

    def to_dict(self) -> dict: ...


class NullBar:
    """A progress bar that shows nothing (the bar of a context without one)."""

    def reset(self, total: int | None = None) -> None:
        """Do nothing."""

    def update(self, n: int = 1) -> None:
        """Do nothing."""

    def set_postfix(self, *args: Any, **kwargs: Any) -> None:
        """Do nothing."""

    def close(self) -> None:
        """Do nothing."""

    def __repr__(self) -> str:
        return "NullBar()"


class TrialContext:
    """Progress reporting and checkpointing for one trial.

    Work that should survive an interruption calls :meth:`resume` with a key when it starts
    (restoring the generator and returning the state last saved under that key, or ``None``)
    and :meth:`save` with the same key after every unit of work (e.g. every policy update).
    Several keys (e.g. one per algorithm learning in the trial) share one context; each save
    hands the latest snapshot of every key to ``writer``.

    Parameters
    ----------
    bar : ProgressBar, optional
        Where :meth:`reset`, :meth:`update` and :meth:`set_postfix` go (default: nowhere).
    states : mapping of str to (bytes, dict), optional
        Snapshots to resume from, as a ``writer`` received them (:attr:`snapshots`).
    writer : callable, optional
        ``writer(snapshots, seconds)``, called after every :meth:`save` (e.g. to write a
        checkpoint file). Without one, snapshots live in memory only.
    seconds : float
        Compute time of earlier, interrupted runs of this trial (added to :attr:`seconds`;
        finite, ≥ 0).
    events : NumericalEvents, optional
        The record the trial's numerical events are counted in (the runner's
        :func:`~skillkit.models.gp.record_numerical_events`); with it the context keeps
        :attr:`saved_events`. Without it (default), no events are kept.
    saved_events : mapping of str to dict, optional
        Per key, the events of the work saved under it in earlier runs (:attr:`saved_events`
        as the writer's caller received it); added to ``events`` when the key is resumed.

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

    # ------------------------------------------------------------------ progress
    def reset(self, total: int | None = None) -> None:
        """Restart the bar at 0 with ``total`` units of work."""
        self.bar.reset(total=total)

    def update(self, n: int = 1) -> None:
        """Advance the bar by ``n`` units of work."""
        self.bar.update(n)

    def set_postfix(self, *args: Any, **kwargs: Any) -> None:
        """Show values beside the bar (tqdm's ``set_postfix``)."""
        self.bar.set_postfix(*args, **kwargs)

    # ------------------------------------------------------------------ checkpoints
    def save(self, key: str, state: Any, rng: np.random.Generator) -> None:
        """Snapshot ``state`` (any picklable object) and ``rng``'s state under ``key``, then
        hand every key's latest snapshot to the writer."""
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng: expected a numpy Generator, got {type(rng).__name__}")
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
        """The state last saved under ``key`` (restoring ``rng`` to where it was then), or
        ``None`` (``rng`` untouched) when nothing was saved under it."""
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
        """Per key, the numerical events of the work saved under it (summed over runs), as
        :meth:`~skillkit.models.gp.NumericalEvents.to_dict`; empty without ``events``."""
        return {key: ev.to_dict() for key, ev in self._key_events.items()}

    @property
    def seconds(self) -> float:
        """Compute time spent on this trial: earlier runs up to their last save, plus this one."""
        return self._seconds_before + time.perf_counter() - self._started

    def __repr__(self) -> str:
        keys = ", ".join(sorted(self._snapshots)) or "none"
        persisted = "" if self._writer is None else ", persisted"
        return f"{type(self).__name__}(saved keys: {keys}{persisted}, {self.seconds:.1f} s)"
