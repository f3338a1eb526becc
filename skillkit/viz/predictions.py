"""Prediction-layer files: models' predicted trajectories for ``skillkit view --predictions``.

:func:`save_predictions` writes, and :func:`load_predictions` reads, trajectories a model
predicted (e.g. L samples from :mod:`skillkit.models.sampling`, or embedding pre-images) for
:meth:`skillkit.viz.viewer.Viewer.add_prediction_layer`, one switchable layer per model.

File format
-----------
A NumPy ``.npz`` archive (``np.savez_compressed``; read with ``allow_pickle=False``). For each
layer ``<name>`` (non-empty, without ``"__"``; L trajectories of T steps, n numbers a step):

======================  =========  =======  ==================================================
key                     shape      dtype    meaning
======================  =========  =======  ==================================================
``<name>``              (L, T, n)  float64  the predicted trajectories (time-major per sample)
``<name>__space``       ()         str      ``"state"`` (n = the task's state dimension, drawn
                                            at the scene's point of a state) or ``"points"``
                                            (n = 3, world-frame points)
``<name>__color``       (3,)       float64  optional: RGB, 0–255
``<name>__opacity``     ()         float64  optional: opacity of the samples, in (0, 1]
``<name>__times``       (T,)       float64  optional: time stamps [s], non-decreasing
``__format__``          ()         str      ``"skillkit-predictions-v1"``
======================  =========  =======  ==================================================

A file without ``__format__`` is read as v1, another version refused.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from skillkit._validation import check_array, check_choice
from skillkit.viz.history import read_npz

__all__ = ["PREDICTIONS_FORMAT", "load_predictions", "save_predictions"]

PREDICTIONS_FORMAT = "skillkit-predictions-v1"
"""The ``__format__`` entry of a prediction-layer file (see the module docstring)."""
_FORMAT_KEY = "__format__"


def save_predictions(
    path,
    layers: Mapping[str, np.ndarray],
    *,
    colors: Mapping | None = None,
    opacities: Mapping | None = None,
    times: Mapping | None = None,
    space: str = "state",
) -> Path:
    """Write layers ``{name: (L, T, n)}`` (names non-empty, without ``"__"``) with optional
    ``colors`` (3,), ``opacities`` and ``times`` (T,) by name and the ``space`` of all ("state"
    or "points") to ``path`` (``.npz`` appended if missing); returns the file written."""
    check_choice(space, "space", ("state", "points"))
    arrays = {_FORMAT_KEY: np.asarray(PREDICTIONS_FORMAT)}
    for name, value in layers.items():
        if not isinstance(name, str) or "__" in name or not name:
            raise ValueError(f"layers: layer names must be non-empty without '__', got {name!r}")
        arrays[name] = check_array(value, f"layers[{name!r}]", ndim=3)
        arrays[f"{name}__space"] = np.asarray(space)
        for key, table in (("color", colors), ("opacity", opacities), ("times", times)):
            if table and name in table:
                arrays[f"{name}__{key}"] = np.asarray(table[name], dtype=np.float64)
    path = Path(path)
    np.savez_compressed(path, **arrays)
    return path if path.suffix == ".npz" else path.with_name(path.name + ".npz")


def load_predictions(path) -> list[dict]:
    """Read a prediction-layer file: one keyword dict per layer, sorted by name, for
    :meth:`skillkit.viz.viewer.Viewer.add_prediction_layer` (``name``, ``trajectories`` and
    those of ``color``, ``opacity``, ``times``, ``space`` the file holds). ``ValueError``
    (argument ``predictions``): unreadable file, another format version, or no layers."""
    path = Path(path)
    arrays = read_npz(path, "predictions", _FORMAT_KEY, PREDICTIONS_FORMAT)
    layers = []
    for name in sorted(k for k in arrays if "__" not in k):
        spec = {"name": name, "trajectories": arrays[name]}
        for key in ("color", "opacity", "times"):
            if f"{name}__{key}" in arrays:
                spec[key] = arrays[f"{name}__{key}"]
        if f"{name}__space" in arrays:
            spec["space"] = str(arrays[f"{name}__space"])
        layers.append(spec)
    if not layers:
        raise ValueError(f"predictions: {path} holds no layers")
    return layers
