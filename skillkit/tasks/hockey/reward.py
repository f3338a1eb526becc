"""The hockey reward (Appendix C.2) and the real-robot puck observation and smoothing."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from skillkit._validation import check_array, check_count, check_positive

OBSERVATION_RATE = 30.0
"""Puck tracking rate of the real-robot setting (Kinect), Hz."""
OBSERVATION_NOISE = 0.01
"""Standard deviation of the observed puck positions in the real-robot setting, m."""
BUTTER_ORDER = 2
BUTTER_CUTOFF = 4.0
"""Butterworth low-pass order and cut-off frequency (Hz) of the real-robot smoothing."""


@dataclass(frozen=True)
class Observation:
    """Puck tracking of the real-robot setting: rate (Hz), noise σ (m), Butterworth filter."""

    rate: float = OBSERVATION_RATE
    noise: float = OBSERVATION_NOISE
    cutoff: float = BUTTER_CUTOFF
    order: int = BUTTER_ORDER

    def __post_init__(self) -> None:
        _filter_settings(self.rate, self.cutoff, self.order)
        check_positive(self.noise, "noise", allow_zero=True)


def _filter_settings(rate, cutoff, order) -> tuple[float, float, int]:
    """Validated Butterworth settings: a cut-off below the Nyquist frequency, an order ≥ 1."""
    rate = check_positive(rate, "rate")
    if check_positive(cutoff, "cutoff") >= rate / 2:
        raise ValueError(f"cutoff: expected < the Nyquist frequency {rate / 2:g} Hz, got {cutoff}")
    return rate, float(cutoff), check_count(order, "order")


def hockey_reward_batch(control_puck, target_puck, contexts) -> np.ndarray:
    """R(τ, s) = −min_t ‖x_t − b‖ − |d_T − d*| (Appendix C.2) of a batch.

    Parameters
    ----------
    control_puck, target_puck : array_like, shape (B, T, 2), (B, T', 2)
        Puck paths x and y (m); d_T = ‖y_{T'} − y_1‖.
    contexts : array_like, shape (B, 3)
        s = [b_x, b_y, d*].

    Returns
    -------
    ndarray, shape (B,)
    """
    x = check_array(control_puck, "control_puck", shape=(None, None, 2))
    y = check_array(target_puck, "target_puck", shape=(x.shape[0], None, 2))
    s = check_array(contexts, "contexts", shape=(x.shape[0], 3))
    if x.shape[1] == 0 or y.shape[1] == 0:
        raise ValueError("control_puck, target_puck: expected at least one sample")
    miss = np.min(np.linalg.norm(x - s[:, None, :2], axis=-1), axis=1)
    displacement = np.array([np.linalg.norm(d) for d in y[:, -1] - y[:, 0]])
    return -miss - np.abs(displacement - s[:, 2])


def butterworth_smooth(
    values, rate: float, cutoff: float = BUTTER_CUTOFF, order: int = BUTTER_ORDER, axis: int = 0
) -> np.ndarray:
    """Zero-phase Butterworth low-pass (``scipy.signal.filtfilt``) of samples along ``axis`` at
    ``rate`` Hz; ValueError for too few samples."""
    x = check_array(values, "values", ndim=(1, 2, 3))
    rate, cutoff, order = _filter_settings(rate, cutoff, order)
    b, a = signal.butter(order, cutoff, btype="low", fs=rate)
    padlen = 3 * max(len(a), len(b))
    if x.shape[axis] <= padlen:
        raise ValueError(f"values: filtfilt needs more than {padlen} samples, got {x.shape[axis]}")
    return signal.filtfilt(b, a, x, axis=axis, padtype="odd", padlen=padlen)
