"""The :class:`Trajectory` record every task rollout and every model prediction produces."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skillkit._repr import number
from skillkit._validation import check_type


@dataclass
class Trajectory:
    """One episode, stored time-major.

    Attributes
    ----------
    times : ndarray, shape (T,)
        Time stamps (s).
    states : ndarray, shape (T, n_x)
        State x_t (e.g. [q_t, q̇_t]) at each time stamp.
    controls : ndarray, shape (T, n_u)
        Control u_t applied from ``times[t]`` on (the last row: the control at the end).
    signals : dict of str to ndarray
        Named task signals, time-major (not necessarily of length T), e.g. ``"ball"`` (T_b, 2).
    info : dict
        JSON-serialisable scalars describing the episode.
    failed : bool
        The simulation broke down (``message`` says why); the task scores it worst. It holds
        the states before the failure, else a one-row placeholder (:attr:`has_transitions`).
    message : str
    """

    times: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    signals: dict[str, np.ndarray] = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    failed: bool = False
    message: str = ""

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=np.float64)
        self.states = np.asarray(self.states, dtype=np.float64)
        self.controls = np.asarray(self.controls, dtype=np.float64)
        if self.times.ndim != 1:
            raise ValueError(f"times: expected shape (T,), got {self.times.shape}")
        n = self.times.shape[0]
        for name in ("states", "controls"):
            arr = getattr(self, name)
            if arr.ndim != 2 or arr.shape[0] != n:
                raise ValueError(f"{name}: expected shape ({n}, ?), got {arr.shape}")
        if not isinstance(self.signals, dict) or not all(isinstance(k, str) for k in self.signals):
            raise ValueError(
                f"signals: expected a dict of str to arrays, got {type(self.signals).__name__}"
            )
        check_type(self.info, dict, "info", "a dict")
        self.signals = {k: np.asarray(v, dtype=np.float64) for k, v in self.signals.items()}

    def __repr__(self) -> str:
        t = self.times
        span = f"{number(t[0])}…{number(t[-1])} s" if t.size else "empty"
        signals = ", ".join(f"{k} {v.shape}" for k, v in self.signals.items())
        text = (
            f"Trajectory(n_steps={self.n_steps}, t={span}, state_dim={self.states.shape[1]}, "
            f"control_dim={self.controls.shape[1]}, signals=[{signals}]"
        )
        if len(text) > 200:  # many signals: their names only
            text = text[: text.index("signals=")] + f"signals={sorted(self.signals)}"
        if self.failed:
            message = self.message if len(self.message) <= 60 else self.message[:59] + "…"
            return f"{text}, failed=True: {message!r})"
        return f"{text}, failed=False)"

    @property
    def n_steps(self) -> int:
        """Number of time stamps T."""
        return int(self.times.shape[0])

    @property
    def has_transitions(self) -> bool:
        """Whether the trajectory holds at least one transition (T ≥ 2)."""
        return self.n_steps >= 2

    def transitions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One-step transitions (x_t, u_t, x_{t+1}), each with T − 1 rows."""
        return self.states[:-1], self.controls[:-1], self.states[1:]

    def save(self, path: str | Path) -> Path:
        """Write the trajectory to a compressed ``.npz`` file (suffix added) and return its path.

        Arrays keep their values exactly; ``info`` goes through JSON (tuples come back as
        lists; ``ValueError`` if it is not JSON-serialisable).
        """
        path = Path(path)
        arrays = {"times": self.times, "states": self.states, "controls": self.controls}
        arrays.update({f"signal__{k}": v for k, v in self.signals.items()})
        meta = {"info": self.info, "failed": self.failed, "message": self.message}
        try:
            text = json.dumps(meta)
        except TypeError as exc:
            raise ValueError(f"info: expected JSON-serialisable values ({exc})") from None
        np.savez_compressed(path, __meta__=np.array(text), **arrays)
        return path if path.suffix == ".npz" else path.with_suffix(path.suffix + ".npz")

    @classmethod
    def load(cls, path: str | Path) -> Trajectory:
        """Read a trajectory written by :meth:`save`."""
        with np.load(Path(path), allow_pickle=False) as data:
            meta = json.loads(str(data["__meta__"]))
            signals = {
                k[len("signal__") :]: data[k] for k in data.files if k.startswith("signal__")
            }
            return cls(
                times=data["times"],
                states=data["states"],
                controls=data["controls"],
                signals=signals,
                info=meta["info"],
                failed=bool(meta["failed"]),
                message=meta["message"],
            )
