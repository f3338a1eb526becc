"""GPREPS reward models in the viewer: their files, and their predictions as prediction layers.

A GPREPS reward model (the hockey and table-tennis models of :mod:`skillkit.search`) chains
several learned models. For the viewer it implements one method, this module's contract::

    def prediction_layers(self, context, omega, n_samples: int, rng=None) -> dict[str, dict]:
        '''For one (s, ω) pair: {layer_name: {"trajectories": ndarray (L, T, 3) world points,
        "color": (r, g, b) 0–255, "times": ndarray (T,) optional}}, one layer per learned
        model, the descriptive names as the legend.'''

File format: the line ``skillkit-reward-model-v1``; one line of JSON ``{"class":
"<module>.<qualname>", "skillkit": "<version>", "task": "<task name or empty>"}``; the model,
pickled. The header is read without unpickling, so another format or version is refused before
any of its code runs; the pickle runs code named by the file: load only files you trust.
"""

from __future__ import annotations

import io
import json
import pickle
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from skillkit._validation import check_array, check_count
from skillkit.viz.scenes import check_rgb, node_name

__all__ = [
    "REWARD_MODEL_FORMAT",
    "check_model_task",
    "dumps_reward_model",
    "load_gpreps_run",
    "load_reward_model",
    "loads_reward_model",
    "model_layers",
    "reward_model_path",
    "save_reward_model",
]

REWARD_MODEL_FORMAT = "skillkit-reward-model-v1"
"""The first line of a reward-model file (see the module docstring)."""
_MAX_LINE = 4096


def _class_path(obj) -> str:
    cls = type(obj)
    return f"{cls.__module__}.{cls.__qualname__}"


def _model_task_name(model) -> str:
    """The name of the task the model was fitted on ("" if it does not say)."""
    name = getattr(getattr(model, "task", None), "name", "")
    return name if isinstance(name, str) else ""


def check_has_layers(model) -> None:
    if not callable(getattr(model, "prediction_layers", None)):
        raise ValueError(f"model: a {type(model).__name__} has no prediction_layers method")


def reward_model_path(run_dir, trial: int = 0) -> Path:
    """Where a GPREPS run folder (``DIR/<id>-<scale>-s<seed>``) keeps the reward model fitted
    at the last update of trial ``trial`` ≥ 0: ``run_dir / f"reward_model_trial{trial}.pkl"``."""
    return Path(run_dir) / f"reward_model_trial{check_count(trial, 'trial', minimum=0)}.pkl"


def save_reward_model(path, model) -> Path:
    """Write a fitted, picklable reward model (with ``prediction_layers``; its ``task.name``
    goes into the header) to ``path`` (conventionally :func:`reward_model_path`); returns the
    path. ``ValueError`` (argument ``model``) if it has no such method or cannot be pickled."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(dumps_reward_model(model))
    tmp.replace(path)
    return path


def load_reward_model(path):
    """Read a reward model written by :func:`save_reward_model` (it unpickles the file: load
    only files you trust). ``ValueError`` (argument ``model``): missing file, another format,
    a malformed header, a pickle that does not load here, or not the header's class."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"model: no such file {path}")
    return loads_reward_model(path.read_bytes(), str(path))


class _CompactPickler(pickle.Pickler):
    """Pickles a fitted GP without its derived caches (:func:`_rebuilt_gp` remakes them)."""

    def reducer_override(self, obj):
        from skillkit.models.gp import GPRegression

        if isinstance(obj, GPRegression) and getattr(obj, "predictor", None) is not None:
            state = {k: v for k, v in vars(obj).items() if k not in ("predictor", "cholesky")}
            return _rebuilt_gp, (type(obj), state)
        return NotImplemented


def _rebuilt_gp(cls, state: dict):
    """A fitted GP from its state without the caches: the fit's last step made again."""
    import torch

    gp = cls.__new__(cls)
    gp.__dict__.update(state)
    gp.predictor = None
    with torch.no_grad():
        gp.predictor, _ = gp._make_predictor()
    return gp


def dumps_reward_model(model) -> bytes:
    """The bytes :func:`save_reward_model` writes (header lines and the pickled model); a run
    keeps them in ``trials.npz`` as the uint8 array ``trial<K>__reward_model``. A fitted GP is
    stored without its Cholesky factor and prediction weights, recomputed on reading."""
    import skillkit

    check_has_layers(model)
    try:
        buffer = io.BytesIO()
        _CompactPickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(model)
        payload = buffer.getvalue()
    except (pickle.PicklingError, TypeError, AttributeError) as exc:
        raise ValueError(f"model: a {type(model).__name__} cannot be pickled ({exc})") from None
    header = {"class": _class_path(model), "skillkit": skillkit.__version__}
    header["task"] = _model_task_name(model)
    return (
        b"%s\n%s\n" % (REWARD_MODEL_FORMAT.encode("ascii"), json.dumps(header).encode()) + payload
    )


def loads_reward_model(data: bytes, source: str = "the data"):
    """Read a reward model from the bytes of :func:`dumps_reward_model` (``source`` names them
    in errors). Same checks and warning as :func:`load_reward_model`."""
    f, path = io.BytesIO(bytes(data)), source
    first = f.readline(_MAX_LINE).rstrip(b"\n")
    if first != REWARD_MODEL_FORMAT.encode("ascii"):
        found = first[:40].decode("ascii", "replace")
        msg = f"model: {path} is not a skillkit reward-model file: expected {REWARD_MODEL_FORMAT!r}"
        raise ValueError(f"{msg}, found format {found!r}")
    try:
        header = json.loads(f.readline(_MAX_LINE).decode("utf-8"))
        cls = str(header["class"])
    except (ValueError, UnicodeDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"model: {path} has a malformed header ({exc})") from None
    version = header.get("skillkit", "?")
    try:
        model = pickle.load(f)
    except Exception as exc:  # any failure of the pickled code: report, don't crash
        msg = f"model: {path} holds a {cls} (skillkit {version}) that does not load here"
        raise ValueError(f"{msg} ({type(exc).__name__}: {exc})") from None
    if _class_path(model) != cls:
        raise ValueError(f"model: {path} promises a {cls} but holds a {_class_path(model)}")
    check_has_layers(model)
    return model


def check_model_task(model, task_name: str) -> None:
    """Raise ``ValueError`` (argument ``model``) for a model fitted on another task than
    ``task_name``; models that do not say (no ``task.name``) pass."""
    fitted = _model_task_name(model)
    if fitted and fitted != task_name:
        raise ValueError(f"model: fitted on task {fitted!r}, not {task_name!r}")


def model_layers(model, context, omega, n_samples: int = 10, rng=None) -> list[dict]:
    """``model.prediction_layers`` (module docstring) for one (s, ω), L = ``n_samples``: a
    keyword dict per layer, in order, for :meth:`~skillkit.viz.viewer.Viewer.add_prediction_layer`
    with ``name`` (the label as a unique path component: ``"sliding model: puck"`` →
    ``"sliding_model_puck"``), ``label``, ``trajectories`` (L, T, 3), ``space="points"`` and
    ``color``, ``times`` (T,), ``opacity`` if given.

    Raises
    ------
    ValueError
        No ``prediction_layers``, or an answer breaking the contract (naming the layer).
    """
    check_has_layers(model)
    n_samples = check_count(n_samples, "n_samples")
    s, w = np.asarray(context, dtype=np.float64), np.asarray(omega, dtype=np.float64)
    answer = model.prediction_layers(s, w, n_samples, rng=rng)
    if not isinstance(answer, Mapping):
        got = type(answer).__name__
        raise ValueError(f"model: prediction_layers returned a {got}, expected a dict of layers")
    specs, used = [], set()
    for label, layer in answer.items():
        if not isinstance(label, str) or not label.strip():
            raise ValueError(f"model: layer names must be non-empty strings, got {label!r}")
        where = f"model layer {label!r}"
        if not isinstance(layer, Mapping) or "trajectories" not in layer:
            raise ValueError(f"{where}: expected a dict with 'trajectories', got {layer!r:.80}")
        x = check_array(layer["trajectories"], f"{where}: trajectories", ndim=3)
        if x.shape[0] < 1 or x.shape[1] < 1 or x.shape[2] != 3:
            msg = f"{where}: trajectories: expected shape (L, T, 3) with L, T >= 1, got {x.shape}"
            raise ValueError(msg)
        name = base = re.sub("_+", "_", node_name(label.strip())).strip("_") or "layer"
        k = 2
        while name in used:
            name, k = f"{base}-{k}", k + 1
        used.add(name)
        spec = {"name": name, "label": label, "trajectories": x, "space": "points"}
        if layer.get("color") is not None:
            spec["color"] = check_rgb(layer["color"], f"{where}: color")
        if layer.get("times") is not None:
            times = check_array(layer["times"], f"{where}: times", shape=(x.shape[1],))
            if np.any(np.diff(times) < 0):
                raise ValueError(f"{where}: times: expected non-decreasing time stamps")
            spec["times"] = times
        if layer.get("opacity") is not None:
            spec["opacity"] = float(layer["opacity"])
        specs.append(spec)
    return specs


def load_gpreps_run(run_dir, trial: int = 0):
    """(history, reward model) of trial ``trial`` of a GPREPS run folder: the history from
    ``trials.npz``, the model from :func:`reward_model_path` or the array
    ``trial<K>__reward_model`` in ``trials.npz``. ``ValueError`` (argument ``gpreps``): no such
    folder or no reward model for the trial."""
    from skillkit.viz.history import load_policy_history

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ValueError(f"gpreps: no such run folder {run_dir}")
    file = reward_model_path(run_dir, trial)
    if file.exists():
        model = load_reward_model(file)
    else:
        key = f"trial{int(trial)}__reward_model"
        npz = run_dir / "trials.npz"
        stored = None
        if npz.is_file():
            with np.load(npz, allow_pickle=False) as arrays:
                stored = arrays[key].tobytes() if key in arrays else None
        if stored is None:
            msg = f"gpreps: {run_dir} has no reward model of trial {trial}"
            raise ValueError(f"{msg} (neither {file.name} nor {key} in trials.npz)")
        model = loads_reward_model(stored, f"{npz}[{key}]")
    return load_policy_history(run_dir, trial), model
