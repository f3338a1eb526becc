"""``reproduce``: run an experiment's trials (locally, on all cores or on Ray), checkpoint and
resume them, and write ``result.json``, ``figure.html``, ``figure.png`` and ``trials.npz``.

Trial ``i`` of a run with root seed ``seed`` uses the ``i``-th child of ``SeedSequence(seed)``,
so the numbers depend neither on the executor nor on interruptions: finished trials and
mid-trial states (:meth:`~skillkit.trial.TrialContext.save`) are checkpointed atomically under
``<run folder>/trials/`` and a rerun resumes from there. Each trial runs inside
:func:`~skillkit.models.gp.record_numerical_events` (counts in ``numerical_events`` and
``summary["handled_numerical_events"]``); remaining warnings are written above the progress
bars, and those of worker processes are issued again by the process that started them.
Quick and paper runs store a smoke *witness* (:func:`smoke_witness`, see
:mod:`skillkit.experiments.provenance`).
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
from collections.abc import Callable, Iterator
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
    unstable_paths,
)
from skillkit.experiments.registry import get, ids
from skillkit.experiments.run import Run
from skillkit.experiments.settings import Settings
from skillkit.models.gp import NumericalEvents, record_numerical_events
from skillkit.trial import TrialContext, Writer

EXECUTORS = ("local", "process", "ray")


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
    """The payload of a finished trial's checkpoint (``kind="result"``)."""

    result: dict
    numerical_events: dict  # NumericalEvents.to_dict() of the whole trial


class _Partial(NamedTuple):
    """The payload of a mid-trial checkpoint (``kind="state"``)."""

    states: dict
    saved_events: dict  # TrialContext.saved_events at the save


def _state_writer(path: str, ident: dict | None, saved_events: Callable[[], dict]) -> Writer:
    """A :class:`~skillkit.trial.TrialContext` writer checkpointing mid-trial states to ``path``
    with the numerical events of the saved work (``saved_events()``)."""

    def write(snapshots, seconds: float) -> None:
        payload = _Partial(dict(snapshots), saved_events())
        checkpoint.save(path, ident, payload, kind="state", seconds=seconds)

    return write


def _show_above_bars(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` through ``tqdm.write``: above the progress bars."""
    text = warnings.formatwarning(message, category, filename, lineno, line)
    tqdm.write(text.rstrip("\n"), file=file or sys.stderr)


@contextmanager
def _trial_warnings(how: str) -> Iterator[list[tuple]]:
    """Where warnings go: ``"pass"`` as usual, ``"bars"`` above the progress bars,
    ``"collect"`` into the yielded list as ``(message, category, filename, lineno)``."""
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
    """Issue the warnings a worker collected (:func:`_trial_warnings`) in this process."""
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
    """Run (or resume) one trial and checkpoint its result (module-level: workers pickle it).

    Returns the result and ``{"seconds": compute time over all runs of the trial, "resumed",
    "numerical_events": counts of the trial's work, each piece once over resumed runs,
    "warnings": collected in a worker}``.
    """
    exp = get(exp_id)
    states, seconds, saved = None, 0.0, {}
    if ckpt_path is not None:
        found = checkpoint.load(ckpt_path, ident)
        if found is not None:
            if found.kind == "result":
                done = found.payload
                info = {"seconds": found.seconds, "resumed": True, "warnings": []}
                return done.result, {**info, "numerical_events": done.numerical_events}
            part = found.payload
            states, seconds, saved = part.states, found.seconds or 0.0, part.saved_events
    how = "collect" if in_worker else "bars" if show_progress else "pass"
    with _trial_warnings(how) as caught, record_numerical_events() as events:
        writer = (
            None if ckpt_path is None else _state_writer(ckpt_path, ident, lambda: ctx.saved_events)
        )
        ctx = TrialContext(
            states=states, writer=writer, seconds=seconds, events=events, saved_events=saved
        )
        if show_progress:
            ctx.bar = tqdm(desc=f"{exp_id} trial {index + 1}", leave=False)
        try:
            result = exp.run_trial(settings, np.random.default_rng(seed_seq), ctx)
        finally:
            ctx.bar.close()
    seconds = ctx.seconds
    counts = events.to_dict()
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
            warnings.warn(
                f"Ray start-up timed out (attempt {attempt}/{attempts}); retrying",
                RuntimeWarning,
                stacklevel=2,
            )


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
                    pool.submit(
                        _execute_trial, exp_id, settings, seq, i, path, ident, False, True
                    ): i
                    for i, seq, path, ident in jobs
                }
                for fut in as_completed(futures):
                    results[futures[fut]] = fut.result()
                    _replay_warnings(results[futures[fut]][1]["warnings"], progress)
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
                    remote.remote(exp_id, settings, seq, i, path, ident, False, True): i
                    for i, seq, path, ident in jobs
                }
                pending = list(refs)
                while pending:
                    done, pending = ray.wait(pending, num_returns=1)
                    results[refs[done[0]]] = ray.get(done[0])
                    _replay_warnings(results[refs[done[0]]][1]["warnings"], progress)
                    outer.update()
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
    # read before the trials run: the code imported is the code on disk now
    made_by = provenance(exp.id)
    t0 = time.perf_counter()
    load_before = _load_average()
    done = _run_pending(exp.id, settings, jobs, executor, workers, address, progress)
    results = [done[i][0] for i in range(n_trials)]
    timing = [done[i][1] for i in range(n_trials)]
    series, summary = exp.summarize(settings, results)
    summary = judged(summary, exp.id, scale, to_jsonable(settings.to_dict()))
    events = _event_totals([t["numerical_events"] for t in timing])
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
        "machine": {
            "platform": platform.platform(),
            "processor": platform.machine(),
            "cpu_model": _cpu_model(),
            "torch_cpu_capability": _torch_cpu_capability(),
            "cpus": os.cpu_count(),
            "load_average_before": load_before,
            "load_average_after": _load_average(),
        },
        "wall_time_s": time.perf_counter() - t0,
        "trial_time_s": [t["seconds"] for t in timing],
        "resumed_trials": sum(t["resumed"] for t in timing),
        "numerical_events": events,
        "series": [to_jsonable(s.to_dict()) for s in series],
        "summary": to_jsonable(summary),
        "_trials": results,
    }


def _event_totals(per_trial: list[dict]) -> dict:
    """``{"per_trial", "total"}`` of the trials' numerical events."""
    total = NumericalEvents()
    for counts in per_trial:
        total.update(counts)
    return {"per_trial": per_trial, "total": total.to_dict()}


def _cpu_model() -> str | None:
    """The CPU's model name (``/proc/cpuinfo``, else :func:`platform.processor`) or None."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def _torch_cpu_capability() -> str | None:
    """The SIMD level torch's CPU kernels use."""
    import torch

    try:
        return str(torch.backends.cpu.get_cpu_capability())
    except (AttributeError, RuntimeError):
        return None


def _load_average() -> list[float] | None:
    """1-, 5- and 15-minute load averages (None where the platform has none)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def run_folder(
    exp_id: str, scale: str, seed: int, out: str | Path, overrides: dict | None = None
) -> Path:
    """The folder a run writes to: ``<out>/<id>-<scale>-s<seed>``, with ``-<hash>`` appended
    when the settings differ from the scale's (the first 8 hex digits of the SHA-256 of the
    differing fields as sorted JSON).

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
    witness: bool = True,
    **overrides,
) -> Run:
    """Run an experiment, resuming from its checkpoints, and write its results.

    Writes ``result.json``, ``figure.html``, ``figure.png`` and ``trials.npz`` into
    :func:`run_folder` and returns the :class:`~skillkit.experiments.run.Run`. ``fresh=True``
    deletes earlier checkpoints first; ``html=False`` skips the HTML figure; at ``quick`` and
    ``paper`` scale the result gets its witness (:func:`smoke_witness`, kept from the folder's
    earlier result when the same code made it) unless ``witness=False``. Other arguments as in
    :func:`run_trials`; all are checked before anything runs or is deleted.
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
    previous = _stored_witness(folder)
    text = write_result(folder, result)
    write_figures(result, folder, html=html)
    if witness and scale in WITNESSED_SCALES:
        result = json.loads(text)
        made = _witness_for(result, previous, progress)
        if made is not None:
            result["witness"] = made
            text = write_result(folder, result)
    return Run(folder, json.loads(text))  # exactly what result.json holds, without rereading it


def write_result(folder: str | Path, result: dict) -> str:
    """Write ``result`` as ``folder/result.json`` atomically (``json.dumps(result,
    indent=1)``, no trailing newline) and return the text written."""
    folder = Path(folder)
    text = json.dumps(result, indent=1)
    tmp = folder / "result.json.tmp"
    tmp.write_text(text)
    tmp.replace(folder / "result.json")
    return text


def _stored_witness(folder: Path) -> dict | None:
    """The witness in ``folder/result.json`` before it is rewritten, or None."""
    try:
        old = json.loads((folder / "result.json").read_text())
    except (OSError, ValueError):
        return None
    made = old.get("witness") if isinstance(old, dict) else None
    return made if isinstance(made, dict) else None


def _witness_for(result: dict, previous: dict | None, progress: bool) -> dict | None:
    """``previous`` when the same code made it for the same seed, else a new
    :func:`smoke_witness`; None, with a warning, when that fails or the code changed."""
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
        made = smoke_witness(result["id"], seed, repeats=WITNESS_REPEATS, progress=progress)
    except Exception as exc:  # the result stays valid without a witness
        warnings.warn(
            f"{result['id']}: the smoke witness run failed ({type(exc).__name__}: {exc}); the "
            "result is stored without a witness",
            RuntimeWarning,
            stacklevel=3,
        )
        return None
    if made["code_fingerprint"] != fingerprint:
        warnings.warn(
            f"{result['id']}: the code changed while the run ran (fingerprint {fingerprint} -> "
            f"{made['code_fingerprint']}); the result is stored without a witness",
            RuntimeWarning,
            stacklevel=3,
        )
        return None
    return made


WITNESSED_SCALES = ("quick", "paper")
"""Scales whose results :func:`reproduce` stores with a smoke witness."""

WITNESS_REPEATS = 2
"""Smoke runs a stored witness is made from (what differs between them is ``unstable``)."""


def smoke_witness(
    exp_id: str,
    seed: int = 0,
    *,
    trials: int | None = None,
    repeats: int = 1,
    progress: bool = False,
) -> dict:
    """The measurements of a smoke run of ``exp_id`` by today's code (local executor, one torch
    thread, no checkpoints, no figures, warnings silenced).

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
        ``scale``, ``seed``, ``trials``, ``commit``, ``code_fingerprint``, ``summary`` and
        ``series`` (their measurements) and ``unstable`` (paths).
    """
    import torch

    check_count(repeats, "repeats")
    made = []
    threads = torch.get_num_threads()
    for _ in range(repeats):
        # one torch thread, as the witnesses are recorded: a parallel reduction sums in another
        # order (fig2.12's sample spreads move by 1e-5 with two threads); restored afterwards
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
    """Every ``result.json`` under ``root`` with whether today's code would still make it
    (``skillkit runs --check DIR``): as :func:`~skillkit.experiments.provenance.check_results`,
    and a result whose code changed without a carry record has its smoke witness run and
    compared (:func:`~skillkit.experiments.provenance.compare_witness`): equal is carried.

    ``record`` writes a carry record (``code_fingerprint``, ``commit``, ``checked`` date)
    into each carried ``result.json``; ``progress`` shows a bar over the witness runs.
    Returns the rows of :func:`~skillkit.experiments.provenance.check_results`, updated.
    """
    from datetime import date

    known = set(ids())
    rows, todo = check_results(root), []
    for row in rows:
        path = Path(row["path"]) / "result.json"
        if row["stale"] and row["id"] in known:
            result = json.loads(path.read_text())
            if result.get("code_fingerprint"):
                todo.append((row, path, result))
    fresh: dict[tuple[str, int], dict | str] = {}
    bar = tqdm(total=len(todo), desc="witnesses", disable=not progress or not todo)
    try:
        for row, path, result in todo:
            stored = result.get("witness")
            if not isinstance(stored, dict):
                row["reason"] += "; no witness to compare"
                bar.update()
                continue
            if stored.get("code_fingerprint") != result["code_fingerprint"]:
                made, ran = result["code_fingerprint"], stored.get("code_fingerprint")
                row["reason"] = f"witness made by other code ({ran}) than the result ({made})"
                bar.update()
                continue
            key = (result["id"], int(stored.get("seed", result.get("seed", 0))))
            if key not in fresh:
                bar.set_postfix_str(key[0])
                try:
                    fresh[key] = smoke_witness(key[0], key[1], trials=stored.get("trials"))
                except Exception as exc:  # a failing run is a finding, not a crash of the check
                    fresh[key] = f"the witness run failed ({type(exc).__name__}: {exc})"
            bar.update()
            now = fresh[key]
            if isinstance(now, str):
                row["reason"] = now
                continue
            equal, differences = compare_witness(stored, now)
            if not equal:
                shown = "; ".join(differences[:3])
                more = f" (and {len(differences) - 3} more)" if len(differences) > 3 else ""
                row["reason"] = f"witness differs: {shown}{more}"
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
    finally:
        bar.close()
    return rows


def add_witness(folder: str | Path, *, progress: bool = False) -> dict:
    """Give a stored run folder (or its ``result.json``) its smoke witness, written as
    ``"witness"`` (every other key kept), and return it.

    Raises
    ------
    ValueError
        Today's code fingerprint is not the result's, or the code changed meanwhile.
    """
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
    seed = int(result.get("seed", 0))
    made = smoke_witness(exp_id, seed, repeats=WITNESS_REPEATS, progress=progress)
    if made["code_fingerprint"] != made_by:
        raise ValueError(
            f"{folder}: the code of {exp_id} changed while its witness ran (fingerprint "
            f"{made_by} -> {made['code_fingerprint']}); no witness written"
        )
    result["witness"] = made
    write_result(folder, result)
    return made


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
    """Summarise a stored run's ``trials.npz`` again with today's code and add the
    measurements its summary lacks.

    Today's summary must reproduce every measurement both have (the witness tolerance), else
    nothing is written; what it cannot make from the stored arrays is kept as stored. The
    judgement is made again; the run records ``remeasured`` (commit, date, paths added).

    Returns the summary paths added; ``write=False`` only reports them.

    Raises
    ------
    ValueError
        Today's summary disagrees with a stored one (naming the paths) or cannot be made.
    """
    from datetime import date

    from skillkit.experiments.provenance import git_state, measurements, walk_differences
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
    stored = measurements(result["summary"])
    found: list[tuple[str, str]] = []
    walk_differences(stored, fresh, "summary", set(), found)
    kept = ("added: ", ": missing (stored")  # new; or not made from the stored arrays
    changed = [t for _, t in found if not t.startswith(kept[0]) and kept[1] not in t]
    changed = [t for t in changed if not t.endswith("-> None")]
    if changed:
        raise ValueError(f"{folder}: today's summary differs from the stored one: {changed[:3]}")
    summary = {k: v for k, v in result["summary"].items()}
    added = _merge_added(summary, fresh)
    if write and added:
        settings_dict = result["settings"]
        result["summary"] = judged(summary, exp.id, result["scale"], settings_dict)
        result["remeasured"] = {
            "commit": git_state()["commit"],
            "checked": date.today().isoformat(),
            "added": [f"summary.{p}" for p in added],
        }
        write_result(folder, result)
    return added
