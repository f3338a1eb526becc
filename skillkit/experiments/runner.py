"""``reproduce``: run an experiment's trials (locally, on all cores or on Ray), checkpoint and
resume them, and write ``result.json``, ``figure.html``, ``figure.png`` and ``trials.npz``.

Trial ``i`` of a run with root seed ``seed`` always uses the ``i``-th child of
``SeedSequence(seed)``, so the numbers do not depend on the executor, on how many trials run
at once, or on interruptions: every finished trial, and every state an experiment saves
mid-trial through :meth:`~skillkit.trial.TrialContext.save`, is checkpointed atomically under
``<run folder>/trials/`` (:func:`run_folder`), and rerunning the same command resumes from
there.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import shutil
import time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from skillkit._validation import check_count
from skillkit.experiments import checkpoint
from skillkit.experiments.registry import get
from skillkit.experiments.run import Run
from skillkit.experiments.settings import Settings
from skillkit.trial import TrialContext, Writer

EXECUTORS = ("local", "process", "ray")


def versions() -> dict[str, str]:
    """Versions of Python, skillkit and the numerical libraries the results depend on."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for pkg in (
        "skillkit",
        "numpy",
        "scipy",
        "torch",
        "gpytorch",
        "mujoco",
        "dm-control",
        "pymunk",
    ):
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


def _state_writer(path: str, ident: dict | None) -> Writer:
    """A :class:`~skillkit.trial.TrialContext` writer that checkpoints mid-trial states to
    ``path`` atomically (:func:`skillkit.experiments.checkpoint.save`, ``kind="state"``)."""

    def write(snapshots, seconds: float) -> None:
        checkpoint.save(path, ident, dict(snapshots), kind="state", seconds=seconds)

    return write


def _execute_trial(
    exp_id: str,
    settings: Settings,
    seed_seq: np.random.SeedSequence,
    index: int,
    ckpt_path: str | None,
    ident: dict | None,
    show_progress: bool,
) -> tuple[dict, dict]:
    """Run (or resume) one trial; checkpoint its result. Module-level so workers can pickle it.

    Returns the trial's result and whether and how it ran: ``{"seconds": compute time summed
    over all runs of this trial (None if a checkpoint predates the record), "resumed": True if
    it continued from a checkpoint}``.
    """
    exp = get(exp_id)
    states, seconds = None, 0.0
    if ckpt_path is not None:
        found = checkpoint.load(ckpt_path, ident)
        if found is not None:
            if found.kind == "result":
                return found.payload, {"seconds": found.seconds, "resumed": True}
            states, seconds = found.payload, found.seconds or 0.0
    writer = None if ckpt_path is None else _state_writer(ckpt_path, ident)
    try:
        ctx = TrialContext(states=states, writer=writer, seconds=seconds)
    except ValueError as exc:  # mid-trial states in an older format
        raise checkpoint.CheckpointError(f"{ckpt_path}: {exc}; use --fresh to start over") from None
    if show_progress:
        ctx.bar = tqdm(desc=f"{exp_id} trial {index + 1}", leave=False)
    try:
        result = exp.run_trial(settings, np.random.default_rng(seed_seq), ctx)
    finally:
        ctx.bar.close()
    seconds = ctx.seconds
    if ckpt_path is not None:
        checkpoint.save(ckpt_path, ident, result, kind="result", seconds=seconds)
    return result, {"seconds": seconds, "resumed": states is not None}


def _start_ray(ray, kwargs: dict, attempts: int = 3) -> None:
    """``ray.init`` with retries: a local Ray node can time out while starting on a busy
    machine (its raylet waits a fixed 15 s for the metrics agent; ray-project/ray#65983)."""
    for attempt in range(1, attempts + 1):
        try:
            ray.init(include_dashboard=False, log_to_driver=False, **kwargs)
            return
        except Exception as exc:  # Ray raises a bare Exception for a start-up time-out
            if "timed out during startup" not in str(exc) or attempt == attempts:
                raise
            ray.shutdown()
            warnings.warn(
                f"Ray start-up timed out (attempt {attempt}/{attempts}); retrying",
                RuntimeWarning,
                stacklevel=2,
            )


def _exit_with_parent(parent: int, interval: float = 1.0) -> None:
    """Process-pool initializer: end this worker when the process that started it is gone.

    Without it, killing ``skillkit reproduce`` (SIGTERM, ``kill -9``) leaves its workers
    computing trials nobody collects. Their checkpoints are kept: a rerun resumes.
    """
    import threading

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(interval)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel a process pool's queued trials and end its running workers at once.

    ``ProcessPoolExecutor.__exit__`` would wait for every submitted trial, so Ctrl-C or a
    failed trial would return only after all the others had finished. What the stopped
    trials saved (finished results, mid-trial states) stays in their checkpoints: a rerun
    resumes from there, as after ``kill -9``.
    """
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        proc.terminate()
    for proc in processes:
        proc.join(timeout=10)


def _run_pending(exp_id, settings, jobs, executor, workers, address, progress) -> dict[int, tuple]:
    """Run jobs = [(index, seed_seq, ckpt_path, ident)] with the chosen executor; returns
    {index: (result, timing)} as :func:`_execute_trial`."""
    results: dict[int, tuple] = {}
    if not jobs:
        return results
    if executor == "local":
        for i, seq, path, ident in jobs:
            results[i] = _execute_trial(exp_id, settings, seq, i, path, ident, progress)
        return results
    outer = tqdm(total=len(jobs), desc=f"{exp_id} trials ({executor})", disable=not progress)
    try:
        if executor == "process":
            n = workers or os.cpu_count() or 1
            pool = ProcessPoolExecutor(
                max_workers=n,
                mp_context=get_context("spawn"),
                initializer=_exit_with_parent,
                initargs=(os.getpid(),),
            )
            try:
                futures = {
                    pool.submit(_execute_trial, exp_id, settings, seq, i, path, ident, False): i
                    for i, seq, path, ident in jobs
                }
                for fut in as_completed(futures):
                    results[futures[fut]] = fut.result()
                    outer.update()
            except BaseException:  # Ctrl-C or a failed trial: stop now, not after every trial
                _stop_pool(pool)
                raise
            pool.shutdown()
        else:
            try:
                import ray
            except ImportError:
                raise ValueError(
                    "executor: 'ray' needs the ray extra (pip install -e '.[ray]')"
                ) from None
            started = not ray.is_initialized()
            if started:
                kwargs = (
                    {"address": address} if address else {"num_cpus": workers or os.cpu_count()}
                )
                _start_ray(ray, kwargs)
            try:
                remote = ray.remote(_execute_trial)
                refs = {
                    remote.remote(exp_id, settings, seq, i, path, ident, False): i
                    for i, seq, path, ident in jobs
                }
                pending = list(refs)
                while pending:
                    done, pending = ray.wait(pending, num_returns=1)
                    results[refs[done[0]]] = ray.get(done[0])
                    outer.update()
            finally:
                if started:
                    ray.shutdown()
    finally:
        outer.close()
    return results


def _check_run_arguments(trials, seed, executor, workers, address) -> None:
    """Raise ``ValueError`` naming the argument for a bad trial count, seed, executor or
    worker count, or for workers / an address the executor would ignore (checked before any
    trial runs or any checkpoint is deleted)."""
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
    exp_id : str
        Experiment id (``skillkit list`` shows them).
    scale : {"smoke", "quick", "paper"}
        Settings scale.
    trials : int, optional
        Number of independent trials (default: the experiment's default for the scale).
    seed : int
        Root seed; trial ``i`` uses the ``i``-th child of ``SeedSequence(seed)``.
    progress : bool
        Show tqdm progress bars.
    executor : {"local", "process", "ray"}
        Run trials one after another, in a pool of processes (all cores by default) or as Ray
        tasks (a local Ray instance, or the cluster at ``address``).
    workers : int, optional
        Number of processes / Ray CPUs (default: all cores); not with ``executor="local"``.
    address : str, optional
        Address of an existing Ray cluster (``executor="ray"`` only).
    checkpoint_dir : path, optional
        Where trial checkpoints live; existing ones are resumed from (after validation).
    **overrides
        Replace individual settings: names and types are checked before any work starts
        (:meth:`~skillkit.experiments.registry.Experiment.settings_for`).
    """
    exp = get(exp_id)
    settings = exp.settings_for(scale, **overrides)
    _check_run_arguments(trials, seed, executor, workers, address)
    n_trials = exp.trials[scale] if trials is None else int(trials)
    children = np.random.SeedSequence(int(seed)).spawn(n_trials)
    code = checkpoint.code_fingerprint(exp.run_trial)
    jobs = []
    for i, child in enumerate(children):
        if checkpoint_dir is None:
            jobs.append((i, child, None, None))
        else:
            path = str(Path(checkpoint_dir) / f"trial_{i:03d}.ckpt")
            ident = checkpoint.identity(exp.id, settings.to_dict(), i, int(seed), code)
            jobs.append((i, child, path, ident))
    t0 = time.perf_counter()
    load_before = _load_average()
    done = _run_pending(exp.id, settings, jobs, executor, workers, address, progress)
    results = [done[i][0] for i in range(n_trials)]
    timing = [done[i][1] for i in range(n_trials)]
    series, summary = exp.summarize(settings, results)
    if executor == "local":
        used = 1
    elif executor == "ray" and address:
        used = None  # an existing cluster's own CPUs
    else:
        used = workers or os.cpu_count()
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
        "versions": versions(),
        "machine": {
            "platform": platform.platform(),
            "processor": platform.machine(),
            "cpus": os.cpu_count(),
            "load_average_before": load_before,
            "load_average_after": _load_average(),
        },
        "wall_time_s": time.perf_counter() - t0,
        # compute time of each trial, summed over interrupted and resumed runs (None: its
        # checkpoint predates this record); trials that continued from a checkpoint
        "trial_time_s": [t["seconds"] for t in timing],
        "resumed_trials": sum(t["resumed"] for t in timing),
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


def run_folder(
    exp_id: str, scale: str, seed: int, out: str | Path, overrides: dict | None = None
) -> Path:
    """The folder a run writes to.

    ``<out>/<id>-<scale>-s<seed>`` for the scale's own settings, and
    ``<out>/<id>-<scale>-s<seed>-<hash>`` for a run whose settings differ from the scale's:
    ``<hash>`` is the first 8 hex digits of the SHA-256 of the differing fields and their
    values (JSON, sorted keys), so a run with overrides never writes into a standard run's
    folder and the same overrides always find their own folder (and checkpoints) again.
    Overrides equal to the scale's values change nothing, so they give the standard folder.

    Raises
    ------
    ValueError
        An unknown experiment or scale, or an override of an unknown name or a wrong type.
    """
    exp = get(exp_id)
    settings = exp.settings_for(scale, **(overrides or {}))
    changed = exp.overrides(scale, settings)
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
    **overrides,
) -> Run:
    """Run an experiment, resuming from its checkpoints, and write its results.

    Writes ``result.json``, ``figure.html``, ``figure.png`` and ``trials.npz`` into
    :func:`run_folder` (its own folder for a run with ``overrides``) and returns the finished
    :class:`~skillkit.experiments.run.Run`: its settings, series and summary (claim, verdict,
    headline numbers), ``.figure()`` and ``.png()``; in Jupyter it shows itself as a card. It is
    path-like (``run.path`` is the folder; ``os.fspath(run)`` and ``run / "result.json"`` work).
    ``fresh=True`` deletes earlier checkpoints of this run first; ``html=False`` skips the
    (4–5 MB, self-contained) HTML figure. Other arguments as in :func:`run_trials`; they
    and the overrides are checked before anything runs or is deleted.
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
    tmp = folder / "result.json.tmp"
    text = json.dumps(result, indent=1)
    tmp.write_text(text)
    tmp.replace(folder / "result.json")
    write_figures(result, folder, html=html)
    return Run(folder, json.loads(text))  # exactly what result.json holds, without rereading it
