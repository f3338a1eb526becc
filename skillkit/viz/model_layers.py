"""GPREPS reward models in the viewer: their files, and their predictions as prediction layers.

A GPREPS reward model (e.g. the hockey and table-tennis models of :mod:`skillkit.search`)
chains several learned models. For the viewer it implements one method, this module's
contract::

    def prediction_layers(self, context, omega, n_samples: int, rng=None) -> dict[str, dict]:
        '''For one (s, ω) pair: {layer_name: {"trajectories": ndarray (L, T, 3) world points,
        "color": (r, g, b) 0–255, "times": ndarray (T,) optional}}; one layer per learned
        model; the names are descriptive and serve as the legend.'''

:func:`model_layers` turns the answer into keyword dicts for
:meth:`skillkit.viz.viewer.Viewer.add_prediction_layer`; :func:`save_reward_model` and
:func:`load_reward_model` write and read a fitted model (one per trial of a GPREPS run folder,
at :func:`reward_model_path`, for ``skillkit view TASK --gpreps RUN_DIR --trial K``).

File format
-----------
1. the line ``skillkit-reward-model-v1`` (ASCII, ending in ``\\n``): the format and version;
2. one line of JSON: ``{"class": "<module>.<qualname>", "skillkit": "<version>",
   "task": "<task name or empty>"}``;
3. the model, pickled (:mod:`pickle`, highest protocol).

The header is read without unpickling, so another format or version (the message names both)
is refused before any of its code runs. A change an existing reader would misread gets a new
version string; new header keys do not.

.. warning::
   Unpickling runs code named by the file. Load only reward-model files you trust (ones you
   or your own runs wrote); :func:`load_reward_model` checks the header, not the pickle.
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
_MAGIC_PREFIX = b"skillkit-reward-model-"
_MAX_LINE = 4096


def _class_path(obj) -> str:
    cls = type(obj)
    return f"{cls.__module__}.{cls.__qualname__}"


def _model_task_name(model) -> str:
    """The name of the task the model was fitted on ("" if it does not say)."""
    name = getattr(getattr(model, "task", None), "name", "")
    return name if isinstance(name, str) else ""


def check_has_layers(model, argname: str = "model") -> None:
    if not callable(getattr(model, "prediction_layers", None)):
        raise ValueError(
            f"{argname}: a {type(model).__name__} has no prediction_layers(context, omega, "
            "n_samples, rng) method (see skillkit.viz.model_layers)"
        )


def reward_model_path(run_dir, trial: int = 0) -> Path:
    """Where a GPREPS run folder keeps the reward model of trial ``trial``.

    Parameters
    ----------
    run_dir : str or Path
        A ``skillkit reproduce`` run folder (``DIR/<id>-<scale>-s<seed>``).
    trial : int
        Trial index (≥ 0).

    Returns
    -------
    Path
        ``run_dir / f"reward_model_trial{trial}.pkl"``: the model fitted at the trial's last
        update.
    """
    return Path(run_dir) / f"reward_model_trial{check_count(trial, 'trial', minimum=0)}.pkl"


def save_reward_model(path, model) -> Path:
    """Write a fitted reward model (format in the module docstring).

    Parameters
    ----------
    path : str or Path
        Output file (its folder must exist); conventionally :func:`reward_model_path`.
    model : object
        A picklable model with a ``prediction_layers`` method (the module's contract). If it
        has ``task.name``, the header records it.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ValueError
        The model has no ``prediction_layers`` method or cannot be pickled (argument
        ``model``).
    """
    data = dumps_reward_model(model)
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)
    return path


def load_reward_model(path):
    """Read a reward model written by :func:`save_reward_model`.

    .. warning::
       This unpickles the file, which runs code it names: load only files you trust.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    object
        The model (it has a ``prediction_layers`` method).

    Raises
    ------
    ValueError
        Missing file, not a reward-model file, another format version, a header that is not
        JSON, a pickle that does not load (e.g. its class is gone from this skillkit), or an
        object other than the header's class (argument ``model``).
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"model: no such file {path}")
    return loads_reward_model(path.read_bytes(), str(path))


class _CompactPickler(pickle.Pickler):
    """Pickles a fitted GP (:class:`~skillkit.models.gp.GPRegression`) without its derived
    caches ``predictor`` and ``cholesky``; :func:`_rebuilt_gp` remakes them when it loads."""

    def reducer_override(self, obj):
        from skillkit.models.gp import GPRegression

        if isinstance(obj, GPRegression) and getattr(obj, "predictor", None) is not None:
            state = {k: v for k, v in vars(obj).items() if k not in ("predictor", "cholesky")}
            return _rebuilt_gp, (type(obj), state)
        return NotImplemented


def _rebuilt_gp(cls, state: dict):
    """A fitted GP from its state without the caches: the fit's last step (the predictor from
    the stored data and hyper-parameters) made again."""
    import torch

    gp = cls.__new__(cls)
    gp.__dict__.update(state)
    gp.predictor = None
    with torch.no_grad():
        gp.predictor, _ = gp._make_predictor()
    return gp


def dumps_reward_model(model) -> bytes:
    """The bytes :func:`save_reward_model` writes (header lines and the pickled model).

    A run keeps them in ``trials.npz`` as the uint8 array ``trial<K>__reward_model``
    (:func:`load_gpreps_run`). A fitted GP inside is stored without what its fit derives from data
    and hyper-parameters (Cholesky factor, K⁻¹, prediction weights: N² numbers each, most of its
    size); reading it back recomputes them (:func:`_rebuilt_gp`).

    Raises
    ------
    ValueError
        The model has no ``prediction_layers`` method or cannot be pickled (argument
        ``model``).
    """
    import skillkit

    check_has_layers(model)
    try:
        buffer = io.BytesIO()
        _CompactPickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(model)
        payload = buffer.getvalue()
    except (pickle.PicklingError, TypeError, AttributeError) as exc:
        raise ValueError(f"model: a {type(model).__name__} cannot be pickled ({exc})") from None
    header = {
        "class": _class_path(model),
        "skillkit": skillkit.__version__,
        "task": _model_task_name(model),
    }
    return (
        REWARD_MODEL_FORMAT.encode("ascii")
        + b"\n"
        + json.dumps(header).encode("utf-8")
        + b"\n"
        + payload
    )


def loads_reward_model(data: bytes, source: str = "the data"):
    """Read a reward model from the bytes of :func:`dumps_reward_model` (``source`` names them
    in errors). Same checks and warning as :func:`load_reward_model`."""
    f = io.BytesIO(bytes(data))
    path = source
    first = f.readline(_MAX_LINE).rstrip(b"\n")
    if first != REWARD_MODEL_FORMAT.encode("ascii"):
        if first.startswith(_MAGIC_PREFIX):
            found = first.decode("ascii", "replace")
            raise ValueError(
                f"model: {path} has format {found!r}, expected {REWARD_MODEL_FORMAT!r}"
            )
        raise ValueError(
            f"model: {path} is not a skillkit reward-model file (it does not start with "
            f"{REWARD_MODEL_FORMAT!r}; see skillkit.viz.model_layers)"
        )
    try:
        header = json.loads(f.readline(_MAX_LINE).decode("utf-8"))
        cls = str(header["class"])
    except (ValueError, UnicodeDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"model: {path} has a malformed header ({exc})") from None
    version = header.get("skillkit", "?")
    try:
        model = pickle.load(f)
    except Exception as exc:  # any failure of the pickled code: report, don't crash
        raise ValueError(
            f"model: {path} holds a {cls} (skillkit {version}) that does not load here "
            f"({type(exc).__name__}: {exc})"
        ) from None
    if _class_path(model) != cls:
        raise ValueError(f"model: {path} promises a {cls} but holds a {_class_path(model)}")
    check_has_layers(model)
    return model


def check_model_task(model, task_name: str) -> None:
    """Refuse a model fitted on another task than ``task_name``.

    Models that do not say (no ``task.name``) pass.

    Raises
    ------
    ValueError
        ``model.task.name`` differs from ``task_name`` (argument ``model``).
    """
    fitted = _model_task_name(model)
    if fitted and fitted != task_name:
        raise ValueError(
            f"model: the reward model was fitted on task {fitted!r}, not {task_name!r}"
        )


def model_layers(model, context, omega, n_samples: int = 10, rng=None) -> list[dict]:
    """The model's predicted paths for one (s, ω) pair, as prediction layers.

    Parameters
    ----------
    model : object
        Has ``prediction_layers(context, omega, n_samples, rng)`` (module docstring).
    context : array_like, shape (context_dim,)
        The context s.
    omega : array_like, shape (dim,)
        The lower-level policy parameters ω.
    n_samples : int
        L, the number of trajectories each learned model samples.
    rng : Generator, int or None
        Passed on to the model.

    Returns
    -------
    list of dict
        One keyword dict per layer, in the model's order, for
        :meth:`skillkit.viz.viewer.Viewer.add_prediction_layer`: ``name`` (the descriptive
        name made a scene-path component, e.g. ``"sliding model: control puck"`` →
        ``"sliding_model_control_puck"``; made unique), ``label`` (the descriptive name, for
        the checkbox and the legend), ``trajectories`` (L, T, 3) with T ≥ 1, ``color``,
        ``space="points"`` and, if the model gave them, ``times`` (T,) and ``opacity``.

    Raises
    ------
    ValueError
        The model has no ``prediction_layers``, or its answer is not a mapping of non-empty
        names to dicts with finite ``trajectories`` of shape (L, T, 3) (L, T ≥ 1), an RGB
        ``color`` in 0–255, and non-decreasing ``times`` of shape (T,); each message names
        the layer.
    """
    check_has_layers(model)
    n_samples = check_count(n_samples, "n_samples")
    answer = model.prediction_layers(
        np.asarray(context, dtype=np.float64),
        np.asarray(omega, dtype=np.float64),
        n_samples,
        rng=rng,
    )
    if not isinstance(answer, Mapping):
        raise ValueError(
            f"model: prediction_layers returned a {type(answer).__name__}, expected a dict "
            "{layer name: {'trajectories': (L, T, 3), 'color': (r, g, b), 'times': (T,)}}"
        )
    specs, used = [], set()
    for label, layer in answer.items():
        if not isinstance(label, str) or not label.strip():
            raise ValueError(f"model: layer names must be non-empty strings, got {label!r}")
        where = f"model layer {label!r}"
        if not isinstance(layer, Mapping) or "trajectories" not in layer:
            raise ValueError(f"{where}: expected a dict with 'trajectories', got {layer!r:.80}")
        x = check_array(layer["trajectories"], f"{where}: trajectories", ndim=3)
        if x.shape[0] < 1 or x.shape[1] < 1 or x.shape[2] != 3:
            raise ValueError(
                f"{where}: trajectories: expected world points of shape (L, T, 3) with "
                f"L, T >= 1, got {x.shape}"
            )
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
    """The policy history and the reward model of one trial of a GPREPS run folder.

    What ``skillkit view TASK --gpreps RUN_DIR --trial K`` shows.

    .. warning::
       This unpickles the reward model (:func:`load_reward_model`): load only runs you trust.

    Parameters
    ----------
    run_dir : str or Path
        A ``skillkit reproduce`` folder of a GPREPS experiment: ``trials.npz`` with the trial's
        policy history (:func:`skillkit.viz.history.load_policy_history`) and the model, either
        in the file at :func:`reward_model_path` or as the uint8 array
        ``trial<K>__reward_model`` in ``trials.npz`` (:func:`dumps_reward_model`; what the
        experiments ``fig4.10``–``fig4.12`` store).
    trial : int

    Returns
    -------
    history : PolicyHistory
    model : object
        The reward model of the trial's last update.

    Raises
    ------
    ValueError
        No such folder (argument ``gpreps``), no reward model for the trial, or the errors of
        :func:`~skillkit.viz.history.load_policy_history` and :func:`load_reward_model`.
    """
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
            raise ValueError(
                f"gpreps: {run_dir} has no reward model of trial {trial} (neither {file.name} "
                f"nor {key} in trials.npz; a GPREPS event-model run stores it)"
            )
        model = loads_reward_model(stored, f"{npz}[{key}]")
    history = load_policy_history(run_dir, trial)
    return history, model
