"""``reproduce``: run an experiment's trials (locally, on all cores or on Ray), checkpoint and
resume them, and write ``result.json``, ``figure.html``, ``figure.png`` and ``trials.npz``.

Trial ``i`` of root seed ``seed`` uses the ``i``-th child of ``SeedSequence(seed)``, so the
numbers depend neither on the executor nor on interruptions: finished trials and mid-trial
states (:meth:`~skillkit.trial.TrialContext.save`) are checkpointed under ``<run
folder>/trials/`` and a rerun resumes there. Each trial counts its numerical events
(:func:`~skillkit.models.gp.record_numerical_events`); warnings go above the progress bars, a
worker's are issued again here. Quick and paper runs store a smoke *witness*
(:mod:`skillkit.experiments.provenance`).
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import shutil
import sys
import time
import warnings
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from multiprocessing import get_context
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from tqdm.auto import tqdm

from skillkit._validation import check_count
from skillkit.experiments import checkpoint
from skillkit.experiments.judge import apply as judged
from skillkit.experiments.provenance import (
    WITNESS_SCALE,
    carried_reason,
    check_results,
    code_fingerprint,
    compare_witness,
    measurements,
    provenance,
    series_measurements,
    settings_changes,
    unstable_paths,
)
from skillkit.experiments.registry import get, ids
from skillkit.experiments.run import Run
from skillkit.experiments.settings import Settings
from skillkit.models.gp import NumericalEvents, record_numerical_events
from skillkit.trial import TrialContext

EXECUTORS = ("local", "process", "ray")

WITNESSED_SCALES = ("quick", "paper")
"""Scales whose results :func:`reproduce` stores with a smoke witness."""

WITNESS_REPEATS = 2
"""Smoke runs a stored witness is made from (what differs between them is ``unstable``)."""


def versions() -> dict[str, str]:
    """Versions of Python, skillkit and the numerical libraries the results depend on."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for pkg in "skillkit numpy scipy torch gpytorch mujoco dm-control pymunk".split():
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return out


def to_jsonable(obj):
    """Convert numpy containers and scalars to plain JSON types (NaN/inf become None)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if np.isfinite(v) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


class _Finished(NamedTuple):
    """A finished trial's checkpoint payload (``kind="result"``)."""

    result: dict
    numerical_events: dict


class _Partial(NamedTuple):
    """A mid-trial checkpoint payload (``kind="state"``)."""

    states: dict
    saved_events: dict


def _show_above_bars(message, category, filename, lineno, file=None, line=None) -> None:
    text = warnings.formatwarning(message, category, filename, lineno, line)
    tqdm.write(text.rstrip("\n"), file=file or sys.stderr)


@contextmanager
def _trial_warnings(how: str) -> Iterator[list[tuple]]:
    """Warnings as usual (``"pass"``), above the bars (``"bars"``) or into the yielded list
    as ``(message, category, filename, lineno)`` (``"collect"``)."""
    if how == "pass":
        yield []
        return
    with warnings.catch_warnings(record=how == "collect") as caught:
        if how == "bars":
            warnings.showwarning = _show_above_bars
        out: list[tuple] = []
        try:
            yield out
        finally:
            out += [(str(w.message), w.category, w.filename, w.lineno) for w in caught or ()]


def _replay_warnings(records: list[tuple], progress: bool) -> None:
    """Issue the warnings a worker collected in this process."""
    if not records:
        return
    with _trial_warnings("bars" if progress else "pass"):
        for message, category, filename, lineno in records:
            warnings.warn_explicit(message, category, filename, lineno)


def _execute_trial(
    exp_id: str,
    settings: Settings,
    seed_seq: np.random.SeedSequence,
    index: int,
    ckpt_path: str | None,
    ident: dict | None,
    show_progress: bool,
    in_worker: bool = False,
) -> tuple[dict, dict]:
    """Run (or resume) one trial and checkpoint it: the result and ``{"seconds" (compute time
    over all runs), "resumed", "numerical_events" (each piece of work once), "warnings" (a
    worker's)}``."""
    exp = get(exp_id)
    states, seconds, saved = None, 0.0, {}
    found = None if ckpt_path is None else checkpoint.load(ckpt_path, ident)
    if found is not None and found.kind == "result":
        info = {"seconds": found.seconds, "resumed": True, "warnings": []}
        return found.payload.result, {**info, "numerical_events": found.payload.numerical_events}
    if found is not None:
        part = found.payload
        states, seconds, saved = part.states, found.seconds or 0.0, part.saved_events

    def write(snapshots, secs: float) -> None:
        payload = _Partial(dict(snapshots), ctx.saved_events)
        checkpoint.save(ckpt_path, ident, payload, kind="state", seconds=secs)

    how = "collect" if in_worker else "bars" if show_progress else "pass"
    with _trial_warnings(how) as caught, record_numerical_events() as events:
        writer = None if ckpt_path is None else write
        ctx = TrialContext(
            states=states, writer=writer, seconds=seconds, events=events, saved_events=saved
        )
        if show_progress:
            ctx.bar = tqdm(desc=f"{exp_id} trial {index + 1}", leave=False)
        try:
            result = exp.run_trial(settings, np.random.default_rng(seed_seq), ctx)
        finally:
            ctx.bar.close()
    seconds, counts = ctx.seconds, events.to_dict()
    if ckpt_path is not None:
        checkpoint.save(ckpt_path, ident, _Finished(result, counts), kind="result", seconds=seconds)
    info = {"seconds": seconds, "resumed": states is not None, "numerical_events": counts}
    return result, {**info, "warnings": caught}


def _start_ray(ray, kwargs: dict, attempts: int = 3) -> None:
    """``ray.init`` with retries: a local Ray node can time out starting on a busy machine."""
    for attempt in range(1, attempts + 1):
        try:
            ray.init(include_dashboard=False, log_to_driver=False, **kwargs)
            return
        except Exception as exc:  # Ray raises a bare Exception for a start-up time-out
            if "timed out during startup" not in str(exc) or attempt == attempts:
                raise
            ray.shutdown()
            msg = f"Ray start-up timed out (attempt {attempt}/{attempts}); retrying"
            warnings.warn(msg, RuntimeWarning, stacklevel=2)


def _exit_with_parent(parent: int, interval: float = 1.0) -> None:
    """Process-pool initializer: end this worker when the process that started it is gone."""
    import threading

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(interval)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel a process pool's queued trials and end its workers now (their checkpoints stay)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        proc.terminate()
    for proc in processes:
        proc.join(timeout=10)


def _run_pending(exp_id, settings, jobs, executor, workers, address, progress) -> dict[int, tuple]:
    """Run jobs = [(index, seed_seq, ckpt_path, ident)]; {index: (result, info)}."""
    results: dict[int, tuple] = {}
    if executor == "local" or not jobs:
        for i, seq, path, ident in jobs:
            results[i] = _execute_trial(exp_id, settings, seq, i, path, ident, progress)
        return results
    calls = {
        i: (exp_id, settings, seq, i, path, ident, False, True) for i, seq, path, ident in jobs
    }
    outer = tqdm(total=len(jobs), desc=f"{exp_id} trials ({executor})", disable=not progress)

    def done(i: int, got: tuple) -> None:
        results[i] = got
        _replay_warnings(got[1]["warnings"], progress)
        outer.update()

    try:
        if executor == "process":
            pool = ProcessPoolExecutor(
                max_workers=workers or os.cpu_count() or 1,
                mp_context=get_context("spawn"),
                initializer=_exit_with_parent,
                initargs=(os.getpid(),),
            )
            try:
                futures = {pool.submit(_execute_trial, *args): i for i, args in calls.items()}
                for fut in as_completed(futures):
                    done(futures[fut], fut.result())
            except BaseException:  # Ctrl-C or a failed trial: stop now, not after every trial
                _stop_pool(pool)
                raise
            pool.shutdown()
            return results
        try:
            import ray
        except ImportError:
            raise ValueError(
                "executor: 'ray' needs the ray extra (pip install -e '.[ray]')"
            ) from None
        started = not ray.is_initialized()
        if started:
            _start_ray(
                ray, {"address": address} if address else {"num_cpus": workers or os.cpu_count()}
            )
        try:
            remote = ray.remote(_execute_trial)
            refs = {remote.remote(*args): i for i, args in calls.items()}
            pending = list(refs)
            while pending:
                finished, pending = ray.wait(pending, num_returns=1)
                done(refs[finished[0]], ray.get(finished[0]))
        finally:
            if started:
                ray.shutdown()
    finally:
        outer.close()
    return results


def _check_run_arguments(trials, seed, executor, workers, address) -> None:
    """ValueError naming a bad argument, or workers / an address the executor would ignore."""
    if trials is not None:
        check_count(trials, "trials")
    check_count(seed, "seed", minimum=0)
    if executor not in EXECUTORS:
        raise ValueError(f"executor: expected one of {EXECUTORS}, got {executor!r}")
    if workers is not None:
        check_count(workers, "workers")
        if executor == "local":
            raise ValueError(
                "workers: the 'local' executor runs trials one after another; use executor "
                "'process' or 'ray' for workers"
            )
    if address is not None and executor != "ray":
        raise ValueError(f"address: only the 'ray' executor uses it, not {executor!r}")


def run_trials(
    exp_id: str,
    scale: str = "quick",
    trials: int | None = None,
    seed: int = 0,
    progress: bool = True,
    *,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    checkpoint_dir: str | Path | None = None,
    **overrides,
) -> dict:
    """Run the trials of an experiment and return the result dict.

    Parameters
    ----------
    exp_id, scale : str
        Experiment id (``skillkit list``) and settings scale ("smoke", "quick" or "paper").
    trials : int, optional
        Independent trials (default: the experiment's default for the scale).
    seed : int
        Root seed; trial ``i`` uses the ``i``-th child of ``SeedSequence(seed)``.
    progress : bool
        Show tqdm progress bars.
    executor : {"local", "process", "ray"}
        Trials one after another, in a pool of processes or as Ray tasks.
    workers : int, optional
        Processes / Ray CPUs (default: all cores); not with ``executor="local"``.
    address : str, optional
        Address of an existing Ray cluster (``executor="ray"`` only).
    checkpoint_dir : path, optional
        Where trial checkpoints live; existing ones are resumed from (after validation).
    **overrides
        Settings to replace, checked before any work starts.
    """
    exp = get(exp_id)
    settings = exp.settings_for(scale, **overrides)
    _check_run_arguments(trials, seed, executor, workers, address)
    n_trials = exp.trials[scale] if trials is None else int(trials)
    children = np.random.SeedSequence(int(seed)).spawn(n_trials)
    code = checkpoint.code_fingerprint(exp.run_trial)
    jobs = []
    for i, child in enumerate(children):
        path = ident = None
        if checkpoint_dir is not None:
            path = str(Path(checkpoint_dir) / f"trial_{i:03d}.ckpt")
            ident = checkpoint.identity(exp.id, settings.to_dict(), i, int(seed), code)
        jobs.append((i, child, path, ident))
    made_by = provenance(exp.id)  # before the trials run: the code imported is the code on disk
    t0 = time.perf_counter()
    load_before = _load_average()
    done = _run_pending(exp.id, settings, jobs, executor, workers, address, progress)
    results = [done[i][0] for i in range(n_trials)]
    timing = [done[i][1] for i in range(n_trials)]
    series, summary = exp.summarize(settings, results)
    summary = judged(summary, exp.id, scale, to_jsonable(settings.to_dict()))
    total = NumericalEvents()
    for t in timing:
        total.update(t["numerical_events"])
    events = {"per_trial": [t["numerical_events"] for t in timing], "total": total.to_dict()}
    # not "numerical_events": fig4.5's summary has its own, per model, under that name
    summary = {**summary, "handled_numerical_events": dict(events["total"])}
    # CPUs used: None on an existing Ray cluster (address is only given with executor "ray")
    used = 1 if executor == "local" else None if address else workers or os.cpu_count()
    return {
        "id": exp.id,
        "title": exp.title,
        "claim": exp.claim,
        "scale": scale,
        "settings": to_jsonable(settings.to_dict()),
        "overrides": to_jsonable(exp.overrides(scale, settings)),
        "seed": int(seed),
        "trials": n_trials,
        "executor": executor,
        "workers": used,
        "git": made_by["git"],
        "code_fingerprint": made_by["code_fingerprint"],
        "versions": versions(),
        "machine": _machine(load_before),
        "wall_time_s": time.perf_counter() - t0,
        "trial_time_s": [t["seconds"] for t in timing],
        "resumed_trials": sum(t["resumed"] for t in timing),
        "numerical_events": events,
        "series": [to_jsonable(s.to_dict()) for s in series],
        "summary": to_jsonable(summary),
        "_trials": results,
    }


def _load_average() -> list[float] | None:
    """1-, 5- and 15-minute load averages (None where the platform has none)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def _machine(load_before: list[float] | None) -> dict[str, Any]:
    """Platform, CPU model, torch's SIMD level, cores and load averages of this machine."""
    import torch

    cpu_model = None
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            names = [line.split(":", 1)[1].strip() for line in f if line.startswith("model name")]
        cpu_model = names[0] if names else None
    except OSError:
        pass
    try:
        capability = str(torch.backends.cpu.get_cpu_capability())
    except (AttributeError, RuntimeError):
        capability = None
    return {
        "platform": platform.platform(),
        "processor": platform.machine(),
        "cpu_model": platform.processor() or None if cpu_model is None else cpu_model,
        "torch_cpu_capability": capability,
        "cpus": os.cpu_count(),
        "load_average_before": load_before,
        "load_average_after": _load_average(),
    }


def run_folder(
    exp_id: str, scale: str, seed: int, out: str | Path, overrides: dict | None = None
) -> Path:
    """``<out>/<id>-<scale>-s<seed>``, with ``-<hash>`` (8 hex digits of the SHA-256 of the
    overridden fields as sorted JSON) when the settings differ from the scale's; ValueError
    for an unknown experiment, scale or override."""
    exp = get(exp_id)
    changed = exp.overrides(scale, exp.settings_for(scale, **(overrides or {})))
    name = f"{exp.id}-{scale}-s{seed}"
    if changed:
        text = json.dumps(to_jsonable(changed), sort_keys=True)
        name += "-" + hashlib.sha256(text.encode()).hexdigest()[:8]
    return Path(out) / name


def reproduce(
    exp_id: str,
    scale: str = "quick",
    trials: int | None = None,
    seed: int = 0,
    out: str | Path = "runs",
    progress: bool = True,
    *,
    executor: str = "local",
    workers: int | None = None,
    address: str | None = None,
    fresh: bool = False,
    html: bool = True,
    witness: bool = True,
    **overrides,
) -> Run:
    """Run an experiment, resuming from its checkpoints, and write its files into
    :func:`run_folder`.

    ``fresh=True`` deletes earlier checkpoints first, ``html=False`` skips the HTML figure, and
    quick and paper results get their :func:`smoke_witness` unless ``witness=False``. Other
    arguments as in :func:`run_trials`; all are checked before anything runs or is deleted.
    """
    from skillkit.viz.plots import write_figures

    _check_run_arguments(trials, seed, executor, workers, address)
    folder = run_folder(exp_id, scale, seed, out, overrides)
    ckpt_dir = folder / "trials"
    if fresh and ckpt_dir.exists():
        shutil.rmtree(ckpt_dir)
    result = run_trials(
        exp_id,
        scale,
        trials,
        seed,
        progress,
        executor=executor,
        workers=workers,
        address=address,
        checkpoint_dir=ckpt_dir,
        **overrides,
    )
    folder.mkdir(parents=True, exist_ok=True)
    trial_arrays = {}
    for i, tr in enumerate(result.pop("_trials")):
        for k, v in tr.items():
            try:
                arr = np.asarray(v)
            except ValueError:  # ragged
                continue
            if arr.dtype != object:
                trial_arrays[f"trial{i}__{k}"] = arr
    np.savez_compressed(folder / "trials.npz", **trial_arrays)
    try:  # the witness stored before result.json is rewritten
        previous = json.loads((folder / "result.json").read_text())["witness"]
    except (OSError, ValueError, KeyError, TypeError):
        previous = None
    text = write_result(folder, result)
    write_figures(result, folder, html=html)
    if witness and scale in WITNESSED_SCALES:
        result = json.loads(text)
        made = _witness_for(result, previous if isinstance(previous, dict) else None, progress)
        if made is not None:
            result["witness"] = made
            text = write_result(folder, result)
    return Run(folder, json.loads(text))  # exactly what result.json holds, without rereading it


def write_result(folder: str | Path, result: dict) -> str:
    """Write ``result`` as ``folder/result.json`` atomically and return the text written."""
    folder = Path(folder)
    text = json.dumps(result, indent=1)
    tmp = folder / "result.json.tmp"
    tmp.write_text(text)
    tmp.replace(folder / "result.json")
    return text


def _new_witness(exp_id: str, seed: int, fingerprint: str, progress: bool) -> dict:
    """:func:`smoke_witness` of :data:`WITNESS_REPEATS` runs by the code of ``fingerprint``
    (ValueError when the code changed meanwhile)."""
    made = smoke_witness(exp_id, seed, repeats=WITNESS_REPEATS, progress=progress)
    if made["code_fingerprint"] != fingerprint:
        raise ValueError(
            f"the code of {exp_id} changed meanwhile (fingerprint {fingerprint} -> "
            f"{made['code_fingerprint']})"
        )
    return made


def _witness_for(result: dict, previous: dict | None, progress: bool) -> dict | None:
    """``previous`` when the same code made it for the same seed, else a new witness; None,
    with a warning, when that fails or the code changed."""
    fingerprint, seed = result.get("code_fingerprint"), result["seed"]
    if fingerprint is None:
        return None
    if (
        previous is not None
        and previous.get("code_fingerprint") == fingerprint
        and previous.get("seed") == seed
    ):
        return previous
    try:
        return _new_witness(result["id"], seed, fingerprint, progress)
    except Exception as exc:  # the result stays valid without a witness
        msg = f"{result['id']}: stored without a witness ({type(exc).__name__}: {exc})"
        warnings.warn(msg, RuntimeWarning, stacklevel=3)
        return None


def smoke_witness(
    exp_id: str,
    seed: int = 0,
    *,
    trials: int | None = None,
    repeats: int = 1,
    progress: bool = False,
) -> dict:
    """The measurements of a smoke run of ``exp_id`` by today's code (local executor, one torch
    thread, no checkpoints or figures, warnings silenced).

    Parameters
    ----------
    exp_id, seed, trials
        Experiment id, root seed and trials (default: the smoke default).
    repeats : int
        Smoke runs to make; what differs between them is listed under ``unstable``.
    progress : bool
        Show the trials' progress bars.

    Returns
    -------
    dict
        ``scale``, ``seed``, ``trials``, ``commit``, ``code_fingerprint``, ``summary``,
        ``series`` and ``unstable``.
    """
    import torch

    check_count(repeats, "repeats")
    made = []
    threads = torch.get_num_threads()
    for _ in range(repeats):
        # one torch thread, as the witnesses are recorded (a parallel reduction sums in
        # another order); restored afterwards
        torch.set_num_threads(1)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                result = run_trials(exp_id, WITNESS_SCALE, trials, seed, progress, executor="local")
        finally:
            torch.set_num_threads(threads)
        made.append(
            {
                "scale": WITNESS_SCALE,
                "seed": int(seed),
                "trials": result["trials"],
                "commit": (result.get("git") or {}).get("commit"),
                "code_fingerprint": result["code_fingerprint"],
                "summary": measurements(result["summary"]),
                "series": series_measurements(result["series"]),
            }
        )
    unstable = sorted({p for other in made[1:] for p in unstable_paths(made[0], other)})
    return {**made[0], "unstable": unstable}


def check_witnesses(
    root: str | Path, *, record: bool = False, progress: bool = True
) -> list[dict[str, Any]]:
    """:func:`~skillkit.experiments.provenance.check_results` of ``root``, where a result whose
    code changed has its smoke witness run and compared: equal is carried (``record`` writes
    a carry record into its ``result.json``)."""
    from datetime import date

    known = set(ids())
    rows, todo = check_results(root), []
    for row in rows:
        path = Path(row["path"]) / "result.json"
        if row["stale"] and row["id"] in known:
            result = json.loads(path.read_text())
            if result.get("code_fingerprint") and not settings_changes(result):
                todo.append((row, path, result))  # a changed setting no witness can carry
    fresh: dict[tuple[str, int], dict | str] = {}
    with tqdm(total=len(todo), desc="witnesses", disable=not progress or not todo) as bar:
        for row, path, result in todo:
            bar.update()
            stored, made = result.get("witness"), result["code_fingerprint"]
            if not isinstance(stored, dict):
                row["reason"] += "; no witness to compare"
                continue
            if stored.get("code_fingerprint") != made:
                ran = stored.get("code_fingerprint")
                row["reason"] = f"witness made by other code ({ran}) than the result ({made})"
                continue
            key = (result["id"], int(stored.get("seed", result.get("seed", 0))))
            if key not in fresh:
                bar.set_postfix_str(key[0])
                try:
                    fresh[key] = smoke_witness(key[0], key[1], trials=stored.get("trials"))
                except Exception as exc:  # a failing run is a finding, not a crash
                    fresh[key] = f"the witness run failed ({type(exc).__name__}: {exc})"
            now = fresh[key]
            if isinstance(now, str):
                row["reason"] = now
                continue
            equal, differences = compare_witness(stored, now)
            if not equal:
                more = f" (and {len(differences) - 3} more)" if len(differences) > 3 else ""
                row["reason"] = f"witness differs: {'; '.join(differences[:3])}{more}"
                continue
            carry = {
                "code_fingerprint": now["code_fingerprint"],
                "commit": now.get("commit"),
                "checked": date.today().isoformat(),
            }
            row.update(stale=False, status="carried", reason=carried_reason(carry))
            if record:
                result["carried"] = [*(result.get("carried") or []), carry]
                write_result(path.parent, result)
    return rows


def add_witness(folder: str | Path, *, progress: bool = False) -> dict:
    """Give a stored run folder (or its ``result.json``) its smoke witness and return it;
    ValueError when today's code is not the code that made the result."""
    folder = Path(folder)
    if folder.name == "result.json":
        folder = folder.parent
    result = json.loads((folder / "result.json").read_text())
    exp_id, made_by = result.get("id"), result.get("code_fingerprint")
    now = code_fingerprint(exp_id)
    if made_by != now:
        raise ValueError(
            f"{folder}: the result was made by code of fingerprint {made_by}, today's code of "
            f"{exp_id} has {now}: a witness must come from the code that made the result "
            "(check out that code, or reproduce the result again)"
        )
    result["witness"] = _new_witness(exp_id, int(result.get("seed", 0)), made_by, progress)
    write_result(folder, result)
    return result["witness"]


def load_trials(folder: str | Path) -> list[dict[str, np.ndarray]]:
    """The per-trial arrays of a run folder's ``trials.npz``, one dict per trial."""
    with np.load(Path(folder) / "trials.npz", allow_pickle=False) as z:
        trials: dict[int, dict] = {}
        for key in z.files:
            head, _, name = key.partition("__")
            value = z[key]
            trials.setdefault(int(head.removeprefix("trial")), {})[name] = (
                value.item() if value.ndim == 0 else value
            )
    return [trials[i] for i in sorted(trials)]


def _merge_added(stored: dict, fresh: dict) -> list[str]:
    """Add to ``stored`` (in place) the keys of ``fresh`` it lacks, recursively; the paths."""
    added = []
    for key, value in fresh.items():
        if key not in stored:
            stored[key] = value
            added.append(key)
        elif isinstance(stored[key], dict) and isinstance(value, dict):
            added += [f"{key}.{p}" for p in _merge_added(stored[key], value)]
    return added


def remeasure(folder: str | Path, *, write: bool = False) -> list[str]:
    """Summarise a stored run's ``trials.npz`` again with today's code, add the measurements
    its summary lacks (every shared one must agree) and judge it again; the paths added
    (``write=False`` only reports them).

    Raises
    ------
    ValueError
        Today's summary disagrees with a stored one (naming the paths) or cannot be made.
    """
    from datetime import date

    from skillkit.experiments.provenance import git_state, walk_differences
    from skillkit.experiments.settings import apply_overrides

    folder = Path(folder)
    result = json.loads((folder / "result.json").read_text())
    exp = get(result["id"])
    settings = apply_overrides(exp.settings[result["scale"]], result["settings"])
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _, fresh = exp.summarize(settings, load_trials(folder))
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        msg = f"{folder}: today's summarize cannot read the stored trials ({exc!r})"
        raise ValueError(msg) from None
    fresh = measurements(json.loads(json.dumps(to_jsonable(fresh))))
    found: list[tuple[str, str]] = []
    walk_differences(measurements(result["summary"]), fresh, "summary", set(), found)
    # kept: what only today's summary has, or what it cannot make from the stored arrays
    changed = [
        t
        for _, t in found
        if not t.startswith("added: ")
        and ": missing (stored" not in t
        and not t.endswith("-> None")
    ]
    if changed:
        raise ValueError(f"{folder}: today's summary differs from the stored one: {changed[:3]}")
    summary = dict(result["summary"])
    added = _merge_added(summary, fresh)
    if write and added:
        result["summary"] = judged(summary, exp.id, result["scale"], result["settings"])
        result["remeasured"] = {
            "commit": git_state()["commit"],
            "checked": date.today().isoformat(),
            "added": [f"summary.{p}" for p in added],
        }
        write_result(folder, result)
    return added
