"""What an experiment plots: :class:`Series` (one named curve, band, heatmap or bar set of a
figure panel) and :func:`mean_band` (mean and band over trials). The figures in
:mod:`skillkit.viz.plots` draw lists of series; experiments build them in ``summarize`` and
store them in ``result.json`` (``Series.to_dict``). The format is documented in
``docs/formats.md``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = ["Series", "mean_band"]


@dataclass
class Series:
    """One plotted series.

    Attributes
    ----------
    name : str
        Legend label.
    x, y : list of float
        Coordinates (for ``kind="heatmap"``: the grid axes, with values in ``z``).
    panel : str
        Subplot the series belongs to (series with the same panel share axes).
    kind : {"line", "markers", "lines+markers", "heatmap", "bar"}
        How to draw it.
    lower, upper : list of float, optional
        A band around ``y`` (e.g. mean ± std or a 95% interval).
    band : str, optional
        What the band is, in words (e.g. ``"mean ± std over 20 trials"``, ``"95% interval of
        the mean"``); figures show it in the legend. None: the band is drawn unlabelled.
    z : list of list of float, optional
        Heatmap values, shape (len(y), len(x)).
    xlabel, ylabel : str
        Axis labels of the panel.
    log_x, log_y : bool
        Logarithmic axes.
    zmin, zmax : float, optional
        Colour range of a heatmap (give panels compared by eye the same range).
    """

    name: str
    x: list
    y: list
    panel: str = ""
    kind: str = "line"
    lower: list | None = None
    upper: list | None = None
    band: str | None = None
    z: list | None = None
    xlabel: str = ""
    ylabel: str = ""
    log_x: bool = False
    log_y: bool = False
    zmin: float | None = None
    zmax: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}


def mean_band(curves: np.ndarray, kind: str = "std") -> tuple[list, list, list]:
    """Mean and a band over trials for curves of shape (n_trials, n_points).

    ``kind="std"`` gives mean ± one standard deviation; ``kind="ci95"`` the 95% interval of
    the mean (normal approximation).
    """
    curves = np.asarray(curves, dtype=float)
    m = curves.mean(axis=0)
    sd = curves.std(axis=0, ddof=1) if curves.shape[0] > 1 else np.zeros_like(m)
    half = sd if kind == "std" else 1.96 * sd / np.sqrt(max(curves.shape[0], 1))
    return m.tolist(), (m - half).tolist(), (m + half).tolist()
