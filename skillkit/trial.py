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
        if self._writer is not None:
            self._writer(dict(self._snapshots), self.seconds)

    def resume(self, key: str, rng: np.random.Generator) -> Any | None:
        """The state last saved under ``key`` (restoring ``rng`` to where it was then), or
        ``None`` (``rng`` untouched) when nothing was saved under it."""
        if key not in self._snapshots:
            return None
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng: expected a numpy Generator, got {type(rng).__name__}")
        body, rng_state = self._snapshots[key]
        rng.bit_generator.state = rng_state
        return pickle.loads(body)

    @property
    def snapshots(self) -> dict[str, Snapshot]:
        """Every key's latest snapshot (a copy; pass it as ``states`` to resume elsewhere)."""
        return dict(self._snapshots)

    @property
    def seconds(self) -> float:
        """Compute time spent on this trial: earlier runs up to their last save, plus this one."""
        return self._seconds_before + time.perf_counter() - self._started

    def __repr__(self) -> str:
        keys = ", ".join(sorted(self._snapshots)) or "none"
        persisted = "" if self._writer is None else ", persisted"
        return f"{type(self).__name__}(saved keys: {keys}{persisted}, {self.seconds:.1f} s)"
