"""Time every experiment id at the ``smoke`` and ``quick`` scales.

Each (id, scale) runs ``reproduce(id, scale=..., out=tmpdir, progress=False, html=False,
fresh=True)`` in a fresh Python subprocess (so imports and caches do not leak from one id to
the next), with the experiment's default number of trials and the default (local,
sequential) executor, exactly as ``skillkit reproduce ID --scale SCALE`` runs it. The
subprocess gets ``OMP_NUM_THREADS=1`` (what ``conftest.py`` and the README recommend) unless
``--threads`` says otherwise. Both the subprocess's wall time (interpreter start, imports,
``reproduce`` and figure writing) and the in-process ``reproduce`` time are recorded; the table
and ``skillkit/data/scale_times.json`` use the subprocess wall time, what a user waits for.
The subprocess's CPU seconds (user + system) are recorded too and shown beside the wall time:
with ``OMP_NUM_THREADS=1`` a run is one busy thread, so on a shared machine (load above the
core count) its CPU time is what the wall time would be with nothing else running;
``--cpu-times`` stores those in the JSON instead (``"time_kind": "cpu"``). The 1-minute load
average before each run is recorded with it.

``--probe SECONDS`` estimates an over-long run instead of waiting for it: the subprocess runs
with a recording progress bar in place of tqdm, is stopped after SECONDS, and the total is
extrapolated from the fraction of the work done (trials finished plus the current trial's
``done / total`` units, :class:`skillkit.trial.TrialContext` progress). Units are not all the
same size (a model-based update grows with its data), so a probe is an estimate, marked
``~`` in the table and ``"estimated": true`` in the JSON.

Examples::

    python benchmarks/bench_scales.py --scales smoke                 # every id at smoke
    python benchmarks/bench_scales.py --ids fig4.6 fig4.10 --scales quick --probe 60
    python benchmarks/bench_scales.py --scales smoke quick --timeout 900 --write
    python benchmarks/bench_scales.py --scales quick --json q.json      # keep the raw records
    python benchmarks/bench_scales.py --from-json q.json s.json --write --cpu-times

``--write`` merges the measured entries into ``skillkit/data/scale_times.json`` (the format
is documented in :mod:`skillkit.experiments.timings`): only the measured (id, scale) entries
change; the machine, cores, load before the run, commit and date are those of this run.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TIMES_FILE = ROOT / "skillkit" / "data" / "scale_times.json"

# --------------------------------------------------------------------------- child process


class _RecordingBar:
    """A tqdm stand-in that appends every change to a JSON-lines file (for ``--probe``)."""

    path: str = ""
    _t0: float = 0.0

    def __init__(self, *args, total=None, desc="", disable=False, **kwargs):
        self.desc, self.total, self.n, self.disable = desc, total, 0, disable
        self._log("start")

    def _log(self, event: str) -> None:
        if self.disable or not self.path:
            return
        rec = {
            "t": time.perf_counter() - self._t0,
            "event": event,
            "desc": self.desc,
            "n": self.n,
            "total": self.total,
        }
        with open(self.path, "a") as fh:
            fh.write(json.dumps(rec) + "\n")

    def reset(self, total=None):
        self.n, self.total = 0, total
        self._log("reset")

    def update(self, n=1):
        self.n += n
        self._log("update")

    def set_postfix(self, *args, **kwargs):
        pass

    def close(self):
        self._log("close")


def _child(exp_id: str, scale: str, out: str, result_path: str, progress_path: str | None) -> None:
    """Run one ``reproduce`` and write its in-process time to ``result_path``."""
    t0 = time.perf_counter()
    from skillkit.experiments import runner

    if progress_path:
        _RecordingBar.path, _RecordingBar._t0 = progress_path, t0
        runner.tqdm = _RecordingBar
    start = time.perf_counter()
    runner.reproduce(
        exp_id, scale=scale, out=out, progress=bool(progress_path), html=False, fresh=True
    )
    done = time.perf_counter()
    Path(result_path).write_text(json.dumps({"reproduce_s": done - start, "import_s": start - t0}))


# --------------------------------------------------------------------------- parent process


def machine() -> str:
    """The CPU's model name (``lscpu``), or the platform's processor string."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        for line in out.splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except (OSError, subprocess.CalledProcessError):
        pass
    return platform.processor() or platform.machine()


def commit() -> str:
    """The working tree's short commit hash (``+dirty`` when files differ from it)."""
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=ROOT,
            capture_output=True,
            text=True,
        ).stdout.strip()
        return rev + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _estimate(progress_path: Path, n_trials: int) -> dict | None:
    """Extrapolate a run's total time from its recorded progress, or None without any."""
    if not progress_path.exists():
        return None
    events = [json.loads(line) for line in progress_path.read_text().splitlines() if line]
    trial_events = [e for e in events if " trial " in e["desc"]]
    if not trial_events:
        return None
    first = trial_events[0]["t"]  # first trial's bar appears: imports and set-up done
    finished = sum(1 for e in trial_events if e["event"] == "close")
    last = trial_events[-1]
    current = 0.0
    if last["event"] != "close" and last["total"]:
        current = min(last["n"] / last["total"], 1.0)
    done = finished + current
    if done <= 0:
        return {"fraction": 0.0, "seconds": None}
    per_trial = (last["t"] - first) / done
    units = [[round(e["t"], 1), e["n"], e["total"]] for e in trial_events if e["event"] == "update"]
    return {
        "fraction": done / n_trials,
        "seconds": first + per_trial * n_trials,
        "trials_done": finished,
        "current_trial_fraction": current,
        "units": units,
    }


def measure(exp_id: str, scale: str, timeout: float, probe: float | None, threads: int) -> dict:
    """Run one (id, scale) in a subprocess; return its timing record."""
    from skillkit.experiments.registry import get

    n_trials = int(get(exp_id).trials[scale])
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench_scales_") as tmp:
        tmp_path = Path(tmp)
        result_path = tmp_path / "child.json"
        progress_path = tmp_path / "progress.jsonl" if probe else None
        cmd = [
            sys.executable,
            __file__,
            "--child",
            exp_id,
            scale,
            str(tmp_path / "runs"),
            str(result_path),
            str(progress_path or ""),
        ]
        env = dict(os.environ)
        env["OMP_NUM_THREADS"] = env["MKL_NUM_THREADS"] = str(threads)
        limit = min(probe, timeout) if probe else timeout
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        proc = subprocess.Popen(
            cmd,
            env=env,
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        try:
            _, err = proc.communicate(timeout=limit)
            timed_out = False
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            _, err = proc.communicate()
            timed_out = True
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime + after.ru_stime) - (usage.ru_utime + usage.ru_stime)
        record: dict = {
            "id": exp_id,
            "scale": scale,
            "trials": n_trials,
            "load": load,
            "load_after": os.getloadavg()[0],
            "wall_s": None,
            "cpu_s": cpu,
            "reproduce_s": None,
            "estimated": False,
            "timeout": False,
            "error": None,
        }
        if not timed_out:
            if proc.returncode != 0:
                record["error"] = (err or "").strip().splitlines()[-1:] or [f"rc {proc.returncode}"]
                record["error"] = record["error"][0]
                return record
            record["wall_s"] = wall
            record["reproduce_s"] = json.loads(result_path.read_text())["reproduce_s"]
            return record
        if probe and wall < timeout:
            est = _estimate(progress_path, n_trials) if progress_path else None
            record["probe_s"] = wall
            if est and est["seconds"] is not None:
                record.update(
                    wall_s=est["seconds"],
                    cpu_estimate_s=cpu / est["fraction"] if est["fraction"] > 0 else None,
                    estimated=True,
                    fraction=est["fraction"],
                    units=est["units"],
                )
                return record
        record["timeout"] = True
        record["wall_s"] = wall
        return record


def _cell(rec: dict | None) -> str:
    if rec is None:
        return ""
    if rec.get("error"):
        return "error"
    if rec.get("timeout"):
        return f">{rec['wall_s']:.0f}"
    if rec.get("estimated"):
        cpu = rec.get("cpu_estimate_s")
        cpu = f", cpu ~{cpu:.0f}" if cpu is not None else ""
        return f"~{rec['wall_s']:.0f} ({100 * rec['fraction']:.0f}% in {rec['probe_s']:.0f} s{cpu})"
    cpu = f" (cpu {rec['cpu_s']:.0f})" if rec.get("cpu_s") is not None else ""
    return f"{rec['wall_s']:.1f}{cpu}"


def table(records: list[dict], scales: list[str]) -> str:
    """The markdown table: id | <scale> s ... | load (1-min load average before each run)."""
    by_id: dict[str, dict[str, dict]] = {}
    for rec in records:
        by_id.setdefault(rec["id"], {})[rec["scale"]] = rec
    head = "| id | " + " | ".join(f"{s} s" for s in scales) + " | load |"
    lines = [head, "|---|" + "---:|" * len(scales) + "---|"]
    for exp_id, recs in sorted(by_id.items(), key=lambda kv: _id_key(kv[0])):
        loads = "/".join(f"{recs[s]['load']:.1f}" for s in scales if s in recs)
        cells = " | ".join(_cell(recs.get(s)) for s in scales)
        lines.append(f"| {exp_id} | {cells} | {loads} |")
    return "\n".join(lines)


def write(records: list[dict], load_before: float, kind: str = "wall") -> None:
    """Merge the measured entries into ``skillkit/data/scale_times.json``.

    ``kind="cpu"`` stores the subprocess's CPU seconds instead of its wall time: with
    ``OMP_NUM_THREADS=1`` a run is one busy thread, so on a machine shared with other work its
    CPU time is what its wall time would be with nothing else running.
    """
    try:
        data = json.loads(TIMES_FILE.read_text())
    except (FileNotFoundError, ValueError):
        data = {}
    times = data.setdefault("times", {})
    details = data.setdefault("details", {})
    for rec in records:
        if rec.get("error") or rec.get("timeout") or rec["wall_s"] is None:
            continue
        value = rec["wall_s"]
        if kind == "cpu":
            value = rec.get("cpu_estimate_s") if rec.get("estimated") else rec["cpu_s"]
        times.setdefault(rec["id"], {})[rec["scale"]] = round(value, 1)
        details.setdefault(rec["id"], {})[rec["scale"]] = {
            k: (round(v, 2) if isinstance(v, float) else v)
            for k, v in rec.items()
            if k not in ("id", "scale", "error", "timeout", "units")
        }
    data.update(
        machine=machine(),
        cores=os.cpu_count(),
        load_before=round(load_before, 2),
        commit=commit(),
        date=_dt.date.today().isoformat(),
        threads=int(os.environ.get("BENCH_THREADS", "1")),
        executor="local",
        time_kind=kind,
    )
    ordered = {
        k: data[k]
        for k in (
            "machine",
            "cores",
            "load_before",
            "threads",
            "executor",
            "time_kind",
            "commit",
            "date",
        )
        if k in data
    }
    ordered["times"] = dict(sorted(times.items(), key=lambda kv: _id_key(kv[0])))
    ordered["details"] = dict(sorted(details.items(), key=lambda kv: _id_key(kv[0])))
    TIMES_FILE.parent.mkdir(parents=True, exist_ok=True)
    TIMES_FILE.write_text(json.dumps(ordered, indent=1) + "\n")


def _id_key(exp_id: str):
    from skillkit.experiments.registry import ids

    order = ids()
    return order.index(exp_id) if exp_id in order else len(order)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--child":
        _child(*argv[1:5], argv[5] or None)
        return
    from tqdm.auto import tqdm

    from skillkit.experiments.registry import get, ids

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ids", nargs="+", default=None, help="ids to time (default: all)")
    parser.add_argument(
        "--scales", nargs="+", default=["smoke", "quick"], choices=["smoke", "quick", "paper"]
    )
    parser.add_argument(
        "--timeout",
        type=float,
        default=900.0,
        help="seconds before a run is killed and recorded as '>timeout'",
    )
    parser.add_argument(
        "--probe",
        type=float,
        default=None,
        help="stop each run after this many seconds and extrapolate its total "
        "from the progress made (runs that finish sooner are exact)",
    )
    parser.add_argument("--threads", type=int, default=1, help="OMP_NUM_THREADS of each run")
    parser.add_argument(
        "--write",
        action="store_true",
        help="merge the measured times into skillkit/data/scale_times.json",
    )
    parser.add_argument(
        "--cpu-times",
        action="store_true",
        help="with --write, store CPU seconds instead of wall seconds (a shared machine)",
    )
    parser.add_argument("--json", default=None, help="also write the raw records here")
    parser.add_argument(
        "--from-json",
        nargs="+",
        default=None,
        help="print (and with --write, store) the records of earlier --json files instead "
        "of measuring",
    )
    args = parser.parse_args(argv)
    known = ids()
    chosen = args.ids or known
    unknown = [i for i in chosen if i not in known]
    if unknown:
        parser.error(f"unknown ids {unknown}; known: {known}")
    os.environ["BENCH_THREADS"] = str(args.threads)
    kind = "cpu" if args.cpu_times else "wall"
    if args.from_json:
        records = [r for f in args.from_json for r in json.loads(Path(f).read_text())]
        records = [r for r in records if r["id"] in chosen and r["scale"] in args.scales]
        stale = [r for r in records if r["trials"] != get(r["id"]).trials[r["scale"]]]
        for r in stale:  # measured with another default number of trials
            print(f"skipping {r['id']} {r['scale']}: measured with {r['trials']} trials")
        records = [r for r in records if r not in stale]
        print(table(records, args.scales))
        if args.write:
            write(records, min(r["load"] for r in records), kind)
            print(f"\nwrote {TIMES_FILE.relative_to(ROOT)}")
        return
    load_before = os.getloadavg()[0]
    records = []
    jobs = [(i, s) for i in chosen for s in args.scales]
    bar = tqdm(jobs, desc="bench_scales")
    for exp_id, scale in bar:
        bar.set_postfix(id=exp_id, scale=scale)
        rec = measure(exp_id, scale, args.timeout, args.probe, args.threads)
        records.append(rec)
        tqdm.write(
            f"{exp_id} {scale}: {_cell(rec)} s (load {rec['load']:.2f})"
            + (f" error: {rec['error']}" if rec.get("error") else "")
        )
        if args.json:
            Path(args.json).write_text(json.dumps(records, indent=1))
    bar.close()
    print(
        f"\n{machine()}, {os.cpu_count()} cores, OMP_NUM_THREADS={args.threads}, "
        f"load {load_before:.2f} before, commit {commit()}\n"
    )
    print(table(records, args.scales))
    if args.write:
        write(records, load_before, kind)
        print(f"\nwrote {TIMES_FILE.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
