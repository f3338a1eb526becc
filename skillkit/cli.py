"""Command line: skillkit list | settings | reproduce | runs | compare | view | demo.

Building the parser imports no torch, numpy or experiment registry (``--help`` answers at
once); each sub-command imports what it needs when it runs.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import textwrap
from pathlib import Path

from skillkit import __version__

SCALES = ("smoke", "quick", "paper")
"""``skillkit.experiments.registry.SCALES``, repeated so the parser need not import it."""

DEMO_IDS = ("fig2.10", "sanity3")
"""What ``skillkit demo`` runs first, at quick scale."""

DEMO_COMPARISON = {
    "tasks": ("throwing",),
    "methods": ("gpreps", "reps"),
    "gpreps_updates": 4,
    "n_artificial": 100,
    "n_trajectories": 3,
    "reps_updates": 16,
    "keep_gpreps_model": True,
}
"""The settings of ``cmp.methods`` ``skillkit demo`` runs beside :data:`DEMO_IDS`."""

DESCRIPTION = """\
Reproduce the figures and tables of Kupcsik's thesis on contextual policy search
(REPS, GPREPS, Gaussian-process forward models, kernel embeddings, DMPs), list and
compare finished runs, and look at the simulated tasks in the browser."""

EPILOG = """\
first steps:
  skillkit demo                two quick experiments and their verdicts (under a minute)
  skillkit list                every experiment id and task
  skillkit settings fig3.3     an experiment's settings and measured run times
  skillkit reproduce fig3.3    run one (--scale smoke, quick or paper)
  skillkit view pendulum       a task's rollouts in the browser
  skillkit SUB --help          the options of a sub-command"""

FILES = ("result.json", "figure.html", "figure.png", "trials.npz")
"""What a run folder holds, in the order the reports list them."""

WIDTH = 100
"""Line width of the verdict reports."""


def _cmd_list(args: argparse.Namespace) -> int:
    from skillkit.experiments import registry
    from skillkit.tasks import names

    print("experiments:")
    for exp_id in registry.ids():
        print(f"  {exp_id:<12} {registry.get(exp_id).title}")
    print("tasks:")
    for name in names():
        print(f"  {name}")
    return 0


def _overrides(pairs: list[str]) -> dict:
    """``KEY=VALUE`` strings to settings overrides (VALUE parsed as JSON, else kept as text; a
    KEY ``block.name`` sets one field of a nested settings block)."""
    out: dict = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ValueError(f"--set: expected KEY=VALUE, got {pair!r}")
        *blocks, name = key.split(".")
        target = out
        for block in blocks:
            target = target.setdefault(block, {})
        try:
            target[name] = json.loads(value)
        except ValueError:
            target[name] = value
    return out


def _report(run) -> list[str]:
    """A finished run in at most 8 lines: what ran, its card, the files and which to open."""
    r = run.result
    n, wall = r.get("trials"), r.get("wall_time_s")
    facts = [f"{run.scale} scale", f"{n} trial{'' if n == 1 else 's'}", f"seed {r.get('seed')}"]
    if isinstance(wall, (int, float)):
        facts.append(f"{wall:.1f} s" if wall < 10 else f"{wall:.0f} s")
    head = f"{run.id} ({', '.join(facts)}): {run.title}"
    lines = textwrap.wrap(head, WIDTH, subsequent_indent="  ", max_lines=2, placeholder=" …")
    lines += ["  " + line for line in run.card.split("\n")]
    written = [name for name in FILES if (run.path / name).exists()]
    lines.append(f"  files:  {run.path}/ ({', '.join(written)})")
    figure = "figure.html" if "figure.html" in written else "figure.png"
    lines.append(f"  open:   {run.path / figure} in a browser")
    return lines


def _print_run(run, as_json: bool) -> None:
    """The run's report, or with ``as_json`` the JSON line ``{id, path, summary}``."""
    if as_json:
        print(json.dumps({"id": run.id, "path": str(run.path), "summary": run.summary}))
    else:
        print("\n".join(_report(run)), flush=True)


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from skillkit.experiments import timings
    from skillkit.experiments.registry import get, ids
    from skillkit.experiments.runner import reproduce

    exp_ids = ids() if args.ids == ["all"] else args.ids
    overrides = _overrides(args.set)
    if overrides and len(exp_ids) > 1:
        raise ValueError("--set: overrides apply to one experiment at a time")
    for exp_id in exp_ids:
        # fail on an unknown id, setting name or type before running anything
        get(exp_id).settings_for(args.scale, **overrides)
    for exp_id in exp_ids:
        estimate = timings.estimate(exp_id, args.scale, args.trials, get(exp_id).trials[args.scale])
        if estimate is not None:
            note = " (for the scale's own settings; --set changes it)" if overrides else ""
            print(f"skillkit: {exp_id} at {args.scale} scale: {estimate}{note}", file=sys.stderr)
        options = ("scale", "trials", "seed", "out", "executor", "workers", "address", "fresh")
        kwargs = {k: getattr(args, k) for k in options}
        run = reproduce(
            exp_id, progress=not args.quiet, html=not args.no_html, **kwargs, **overrides
        )
        _print_run(run, args.json)
    return 0


def _cmd_settings(args: argparse.Namespace) -> int:
    from skillkit.experiments import timings
    from skillkit.experiments.registry import SCALES, get
    from skillkit.experiments.runner import to_jsonable
    from skillkit.experiments.settings import describe

    exp = get(args.id)
    values = {scale: to_jsonable(exp.settings[scale].to_dict()) for scale in SCALES}
    print(f"{exp.id}: {exp.title}")
    measured = {scale: timings.measured_seconds(exp.id, scale) for scale in ("smoke", "quick")}
    times = ", ".join(f"{s} {timings.format_seconds(t)}" for s, t in measured.items())
    where = f" ({timings.machine_note()})" if any(t is not None for t in measured.values()) else ""
    print(f"measured wall time (default trials, local executor): {times}{where}")
    print(f"settings class {exp.settings_class.__name__}; trials per scale: {exp.trials}")
    for name, kind, doc in describe(exp.settings_class):
        print(f"\n  {name} ({kind})\n      {doc}")
        for scale in SCALES:
            print(f"      {scale:<6} {json.dumps(values[scale][name])}")
    return 0


def _remeasure_runs(root: Path) -> int:
    """``runs --remeasure`` (:func:`skillkit.experiments.runner.remeasure`); 1 if one differs."""
    from skillkit.experiments.run import rejudged
    from skillkit.experiments.runner import remeasure, write_result

    failed = 0
    for path in sorted(root.rglob("result.json")):
        folder = path.parent
        try:
            added = remeasure(folder, write=True) if (folder / "trials.npz").exists() else []
            note = f"{len(added)} measurements added" if added else "nothing to add"
        except ValueError as exc:
            failed += "differs" in str(exc)
            note = str(exc).split(": ", 1)[1]
        write_result(folder, rejudged(json.loads(path.read_text())))
        print(f"{folder.name}: {note}; judged again")
    return int(failed > 0)


def _check_runs(root: Path, record: bool, progress: bool) -> int:
    """``runs --check`` (:func:`skillkit.experiments.runner.check_witnesses`); 1 if one is
    stale."""
    from skillkit.experiments.runner import check_witnesses

    if not root.exists():
        raise ValueError(f"--root: no results folder at {root}")
    rows = check_witnesses(root, record=record, progress=progress)
    for status in ("carried", "stale"):
        for r in rows:
            if r["status"] == status:
                print(f"{status:<8} {r['path']:<45} {r['id']:<10} {r['reason']}")
    counts = {s: sum(r["status"] == s for r in rows) for s in ("current", "carried", "stale")}
    tally = ", ".join(f"{n} {s}" for s, n in counts.items())
    print(f"{len(rows)} results under {root}: {tally}")
    return 1 if counts["stale"] else 0


def _cmd_runs(args: argparse.Namespace) -> int:
    from skillkit.experiments.store import find_root, list_runs

    if args.folder is not None and args.root is not None and args.folder != args.root:
        raise SystemExit(
            f"runs: give the folder once, not {args.folder!r} and --root {args.root!r}"
        )
    given = args.folder if args.folder is not None else args.root
    root = find_root() if given is None else Path(given)
    if args.record and not args.check:
        raise SystemExit("runs: --record goes with --check")
    if args.check:
        return _check_runs(root, args.record, not args.quiet)
    if args.remeasure:
        return _remeasure_runs(root)
    if args.markdown:
        print(results_table(root), end="")
        return 0
    runs = list_runs(root)
    if not runs:
        print(f"no runs (no result.json) under {root.resolve()}")
    for r in runs:
        wall = r["wall_time_s"]
        wall_s = f"{wall:9.1f}s" if isinstance(wall, (int, float)) else "         ?"
        v = {k: "?" if r[k] is None else str(r[k]) for k in ("id", "scale", "seed", "trials")}
        print(
            f"{r['path']:<50} {v['id']:<10} {v['scale']:<6} seed={v['seed']:<4} "
            f"trials={v['trials']:<3} {r['executor']!s:<8}{wall_s}"
        )
    return 0


def results_table(root) -> str:
    """data/README.md's Markdown table of the results under ``root`` (``skillkit runs
    --markdown``): folder, commit, trials, executor, wall time, verdict and staleness."""
    from skillkit.experiments.judge import markdown_row
    from skillkit.experiments.provenance import check_results

    lines = [
        "| folder | commit | trials | executor | wall time (min) | verdict | code since |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in check_results(root):
        result = json.loads((Path(row["path"]) / "result.json").read_text())
        git = result.get("git") or {}
        commit = str(git["commit"])[:7] if git.get("commit") else "not recorded"
        if git.get("dirty"):
            commit += " (dirty)"
        executor = str(result.get("executor", "local"))
        if result.get("workers"):
            executor += f" ×{result['workers']}"
        wall = result.get("wall_time_s")
        wall_min = f"{wall / 60:.1f}" if isinstance(wall, (int, float)) else "not recorded"
        verdict = str((result.get("summary") or {}).get("verdict", "not recorded"))
        since = {"current": "unchanged", "carried": "carried (witness equal)"}.get(
            row["status"], f"stale: {row['reason'].split(' (')[0]}"
        )
        trials = str(result.get("trials", "?"))
        cells = [Path(row["path"]).name, commit, trials, executor, wall_min, verdict, since]
        lines.append(markdown_row(cells))
    return "\n".join(lines) + "\n"


def _cell(v) -> str:
    """A right-aligned table cell (numbers with 6 significant digits)."""
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return f"{v:18.6g}"
    return f"{v!s:>18}"


def _cmd_compare(args: argparse.Namespace) -> int:
    from skillkit.experiments.store import compare

    rows, merged = compare(args.run_a, args.run_b)
    width = max([len(k) for k, _, _ in rows] + [10])
    print(f"{'':<{width}}  {'A':>18}  {'B':>18}")
    for key, va, vb in rows:
        print(f"{key:<{width}}  {_cell(va)}  {_cell(vb)}")
    if args.out:
        from skillkit.viz.plots import write_figures

        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_figures(merged, out)
        print(f"wrote {out}/figure.html and figure.png")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    # small problems: one BLAS / OpenMP thread unless the caller chose (numpy is not loaded yet)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from skillkit.experiments import timings
    from skillkit.experiments.run import load_run
    from skillkit.experiments.runner import reproduce

    seconds = [timings.measured_seconds(exp_id, "quick") for exp_id in DEMO_IDS]
    if all(s is not None for s in seconds):
        took = f"about {timings.format_seconds(sum(seconds))} ({timings.machine_note()})"
    else:
        took = "under a minute on 2 cores"
    print(f"skillkit demo: {' and '.join(DEMO_IDS)} at quick scale, {took}", file=sys.stderr)
    # a core each: the first experiments in a second process, the comparison in this one
    with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
        first = pool.submit(_demo_runs, DEMO_IDS, args.seed, args.out)
        comparison = None
        if DEMO_COMPARISON is not None:
            note = "GPREPS against REPS on throwing (cmp.methods), beside them"
            print(f"skillkit demo: {note}", file=sys.stderr)
            options = {"scale": "quick", "seed": args.seed, "out": args.out}
            comparison = reproduce(
                "cmp.methods", progress=not args.quiet, **options, **DEMO_COMPARISON
            )
        paths = first.result()
    for path in paths:
        _print_run(load_run(path), args.json)
        if not args.json:
            print()
    if comparison is not None and args.json:
        _print_run(comparison, True)
    elif comparison is not None:
        print("\n".join(_comparison_lines(comparison)) + "\n", flush=True)
    if not args.json:
        following = (
            "next: `skillkit list` (every experiment), `skillkit reproduce ID`, "
            f"`skillkit runs --root {args.out}`, `skillkit view pendulum` (a task in the "
            "browser); in Python, skillkit.experiments.load_run(FOLDER) shows a run."
        )
        print("\n".join(textwrap.wrap(following, WIDTH, subsequent_indent="      ")))
    return 0


def _demo_runs(exp_ids, seed: int, out: str) -> list[str]:
    """Run ``exp_ids`` at quick scale without progress bars; their run folders."""
    from skillkit.experiments.runner import reproduce

    return [
        str(reproduce(i, scale="quick", seed=seed, out=out, progress=False).path) for i in exp_ids
    ]


def _comparison_lines(run) -> list[str]:
    """The demo comparison's real throws and rewards per method, and how to watch it."""
    import numpy as np

    lines = [
        f"{run.id}: GPREPS against REPS on throwing ({run.scale} scale, seed {run.result['seed']})"
    ]
    for name, task in run.summary["tasks"].items():
        for method, row in task["methods"].items():
            lines.append(
                f"  {method:>7}: {row['real_rollouts']:5.0f} real throws, reward of the policy "
                f"mean {row['initial_reward']:.4g} -> {row['final_reward_mean']:.4g} "
                f"({row['time_s_mean']:.0f} s)"
            )
        lines.append(
            "  (reward ≈ −100 × the ball's distance to the target in m; the thesis: GPREPS needs "
            "two orders of magnitude fewer throws than REPS, Sec. 4.3.2)"
        )
        with np.load(run.path / "trials.npz") as stored:
            option = "--gpreps" if "trial0__reward_model" in stored.files else "--policy"
        lines.append(f"  watch GPREPS learn: skillkit view {name} {option} {run.path}")
    return lines


def _cmd_site(args: argparse.Namespace) -> int:
    from skillkit.viz.site import build_site

    notebooks = sorted(Path(args.notebooks).glob("*.ipynb"))
    if not notebooks:
        raise ValueError(f"--notebooks: no .ipynb file in {args.notebooks!r}")
    index = build_site(notebooks, args.out, execute=not args.executed, timeout=args.timeout)
    print(f"{len(notebooks)} notebooks: {index}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The ``skillkit`` argument parser (cheap: imports no experiment, torch or numpy)."""
    parser = argparse.ArgumentParser(
        prog="skillkit",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    version = f"skillkit {__version__}"
    parser.add_argument("-V", "--version", action="version", version=version)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add(name, func, line: str, description: str | None = None) -> argparse.ArgumentParser:
        """A sub-command with its one-line help (also its description, unless given)."""
        p = sub.add_parser(name, help=line, description=description or f"{line.capitalize()}.")
        p.set_defaults(func=func)
        return p

    def runs_options(p: argparse.ArgumentParser) -> None:
        """The options ``reproduce`` and ``demo`` share."""
        p.add_argument("--seed", type=int, default=0, help="root seed; trial i uses child i")
        p.add_argument("--out", default="runs", help="output folder (default: runs/)")
        p.add_argument("--quiet", action="store_true", help="no progress bars")
        p.add_argument("--json", action="store_true", help="a JSON line {id, path, summary} a run")

    add("list", _cmd_list, "list experiment ids and tasks")
    p = add(
        "settings",
        _cmd_settings,
        "an experiment's settings: meaning, type, values",
        "An experiment's settings at each scale (meaning, unit, type, range, values) and its "
        "measured wall time at smoke and quick scale.",
    )
    p.add_argument("id", metavar="ID", help="experiment id, e.g. fig3.3 (see `skillkit list`)")

    p = add(
        "reproduce",
        _cmd_reproduce,
        "reproduce a thesis figure or table",
        "Run an experiment and write result.json, figure.html, figure.png and trials.npz into "
        "its run folder; print the thesis's claim, our verdict and where the files are. A rerun "
        "of the same command resumes from the run's checkpoints.",
    )
    arg = p.add_argument
    arg("ids", nargs="+", metavar="ID", help="experiment id(s) (see `skillkit list`), or `all`")
    scales = "smoke (seconds), quick (minutes, faithful; default) or paper (the thesis's)"
    arg("--scale", choices=SCALES, default="quick", help=scales)
    arg("--trials", type=int, help="independent trials (default: per experiment)")
    runs_options(p)
    executors = "trials one by one, on all cores or on Ray (default: local)"
    arg("--executor", choices=("local", "process", "ray"), default="local", help=executors)
    arg("--workers", type=int, help="processes / Ray CPUs (default: all cores)")
    arg("--address", help="address of an existing Ray cluster")
    arg("--fresh", action="store_true", help="discard this run's checkpoints and start over")
    arg("--no-html", action="store_true", help="skip the self-contained HTML figure")
    arg(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one setting (repeatable; VALUE is JSON; block.name for a field of a "
        "block), e.g. --set reps.n_updates=50; checked first, the run gets its own folder "
        "<id>-<scale>-s<seed>-<hash>",
    )

    p = add("runs", _cmd_runs, "list finished runs (folders holding result.json), newest first")
    arg = p.add_argument
    arg("folder", nargs="?", help="results folder, e.g. data/results (the same as --root)")
    arg("--root", help="results folder (default: runs/ if here, else this folder)")
    check = "whether today's code would still make each result (current, carried or stale)"
    arg("--check", action="store_true", help=check)
    arg("--record", action="store_true", help="with --check: write carry records into result.json")
    arg("--quiet", action="store_true", help="with --check: no progress bar over witness runs")
    remeasure = "summarise each stored trials.npz again, add what its summary lacks, judge it again"
    arg("--remeasure", action="store_true", help=remeasure)
    arg("--markdown", action="store_true", help="a Markdown table of them, as in data/README.md")

    p = add("compare", _cmd_compare, "two runs' summaries, settings and run times side by side")
    p.add_argument("run_a", help="run folder (or its result.json)")
    p.add_argument("run_b", help="run folder (or its result.json)")
    p.add_argument("--out", help="also write an overlay figure into this folder")

    p = add(
        "demo",
        _cmd_demo,
        "GPREPS against REPS on throwing, beside the quick fig2.10 and sanity3 experiments",
        "Run at quick scale, in about a minute on 2 cores: GPREPS against REPS on throwing "
        "(cmp.methods) and, in a second process, the DMP imitation figure (fig2.10) and "
        "contextual REPS, RWR and CrKR with a known optimum (sanity3). Prints each one's claim, "
        "verdict and files, and how to open the GPREPS run in the viewer.",
    )
    runs_options(p)

    p = add(
        "site",
        _cmd_site,
        "the notebooks as a browsable HTML site",
        "Execute the notebooks (at SKILLKIT_SCALE, default smoke) and export them as linked "
        "HTML pages with an index.html; equations typeset offline, figures without a kernel.",
    )
    arg = p.add_argument
    arg("out", metavar="OUT", help="output folder")
    arg("--notebooks", default="notebooks", help="folder of .ipynb files (default: notebooks/)")
    arg("--executed", action="store_true", help="the notebooks are executed: export only")
    arg("--timeout", type=int, default=600, help="seconds per cell (default 600)")

    from skillkit.viz.cli_view import add_view_parser

    add_view_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"skillkit: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("skillkit: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `skillkit settings ID | head`: stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except RuntimeError as exc:
        # a CheckpointError needs the checkpoint module, which --help must not import
        checkpoint = sys.modules.get("skillkit.experiments.checkpoint")
        if checkpoint is None or not isinstance(exc, checkpoint.CheckpointError):
            raise
        print(f"skillkit: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
