"""Command line: ``skillkit list | settings | reproduce | runs | compare | view | demo``."""

from __future__ import annotations

import argparse
import json
import sys


def _cmd_list(args: argparse.Namespace) -> int:
    from skillkit.experiments import registry
    from skillkit.tasks import names

    print("experiments:")
    for exp_id in registry.ids():
        exp = registry.get(exp_id)
        print(f"  {exp_id:<12} {exp.title}")
    print("tasks:")
    for name in names():
        print(f"  {name}")
    return 0


def _overrides(pairs: list[str]) -> dict:
    """``KEY=VALUE`` strings to settings overrides (VALUE parsed as JSON, else kept as text).

    Names and types are checked by the experiment's settings class
    (:meth:`~skillkit.experiments.registry.Experiment.settings_for`), not here.
    """
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ValueError(f"--set: expected KEY=VALUE, got {pair!r}")
        try:
            out[key] = json.loads(value)
        except ValueError:
            out[key] = value
    return out


def _cmd_reproduce(args: argparse.Namespace) -> int:
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
        run = reproduce(
            exp_id,
            scale=args.scale,
            trials=args.trials,
            seed=args.seed,
            out=args.out,
            progress=not args.quiet,
            executor=args.executor,
            workers=args.workers,
            address=args.address,
            fresh=args.fresh,
            html=not args.no_html,
            **overrides,
        )
        figures = "figure.png" if args.no_html else "figure.html, figure.png"
        print(f"wrote {run.path}/result.json, {figures}, trials.npz")
        print(json.dumps(run.summary, indent=1))
    return 0


def _cmd_settings(args: argparse.Namespace) -> int:
    from skillkit.experiments.registry import SCALES, get
    from skillkit.experiments.runner import to_jsonable
    from skillkit.experiments.settings import describe

    exp = get(args.id)
    values = {scale: to_jsonable(exp.settings[scale].to_dict()) for scale in SCALES}
    print(f"{exp.id}: {exp.title}")
    print(f"settings class {exp.settings_class.__name__}; trials per scale: {exp.trials}")
    for name, kind, doc in describe(exp.settings_class):
        print(f"\n  {name} ({kind})\n      {doc}")
        for scale in SCALES:
            print(f"      {scale:<6} {json.dumps(values[scale][name])}")
    return 0


def _cmd_runs(args: argparse.Namespace) -> int:
    from skillkit.experiments.store import list_runs

    runs = list_runs(args.root)
    if not runs:
        print(f"no runs under {args.root}")
    for r in runs:
        wall = r["wall_time_s"]
        wall_s = f"{wall:9.1f}s" if isinstance(wall, (int, float)) else "         ?"
        # a result.json without some key (None) shows "?" there
        v = {k: "?" if r[k] is None else str(r[k]) for k in ("id", "scale", "seed", "trials")}
        print(
            f"{r['path']:<50} {v['id']:<10} {v['scale']:<6} seed={v['seed']:<4} "
            f"trials={v['trials']:<3} {r['executor']!s:<8}{wall_s}"
        )
    return 0


def _cell(v) -> str:
    """A right-aligned table cell: numbers with 6 significant digits, anything else as text."""
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return f"{v:18.6g}"
    return f"{v!s:>18}"


def _cmd_compare(args: argparse.Namespace) -> int:
    from pathlib import Path

    from skillkit.experiments.store import compare
    from skillkit.viz.plots import write_figures

    rows, merged = compare(args.run_a, args.run_b)
    width = max([len(k) for k, _, _ in rows] + [10])
    print(f"{'':<{width}}  {'A':>18}  {'B':>18}")
    for key, va, vb in rows:
        print(f"{key:<{width}}  {_cell(va)}  {_cell(vb)}")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_figures(merged, out)
        print(f"wrote {out}/figure.html and figure.png")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from skillkit.experiments.runner import reproduce

    for exp_id in ("fig2.10", "sanity3"):
        run = reproduce(
            exp_id, scale="quick", seed=args.seed, out=args.out, progress=not args.quiet
        )
        print(f"{exp_id}: wrote {run.path}")
        print(f"  {run.verdict}")
        print(json.dumps(run.summary, indent=1))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from skillkit.experiments.registry import SCALES

    parser = argparse.ArgumentParser(prog="skillkit", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("list", help="list experiment ids and tasks")
    p.set_defaults(func=_cmd_list)

    p = sub.add_parser("settings", help="an experiment's settings: meaning, type, values")
    p.add_argument("id", metavar="ID", help="experiment id, e.g. fig3.3")
    p.set_defaults(func=_cmd_settings)

    p = sub.add_parser("reproduce", help="reproduce a thesis figure or table")
    p.add_argument(
        "ids",
        nargs="+",
        metavar="ID",
        help="experiment id(s), e.g. fig2.10 (see `skillkit list`), or `all`",
    )
    p.add_argument(
        "--scale",
        choices=SCALES,
        default="quick",
        help="smoke (seconds), quick (minutes, faithful) or paper (the thesis setting)",
    )
    p.add_argument(
        "--trials", type=int, default=None, help="independent trials (default: per experiment)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs", help="output folder (default: runs/)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument(
        "--executor",
        choices=("local", "process", "ray"),
        default="local",
        help="run trials sequentially, on all cores, or on Ray (default: local)",
    )
    p.add_argument(
        "--workers", type=int, default=None, help="processes / Ray CPUs (default: all cores)"
    )
    p.add_argument("--address", default=None, help="address of an existing Ray cluster")
    p.add_argument(
        "--fresh", action="store_true", help="discard this run's checkpoints and start over"
    )
    p.add_argument("--no-html", action="store_true", help="skip the self-contained HTML figure")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one setting of the scale (repeatable; VALUE is JSON), e.g. --set "
        "n_updates=50; names and types are checked first, and the run gets its own folder "
        "<id>-<scale>-s<seed>-<hash> (see `skillkit settings ID`)",
    )
    p.set_defaults(func=_cmd_reproduce)

    p = sub.add_parser("runs", help="list finished runs in the results store")
    p.add_argument("--root", default="runs", help="results folder (default: runs/)")
    p.set_defaults(func=_cmd_runs)

    p = sub.add_parser("compare", help="two runs' summaries and curves side by side")
    p.add_argument("run_a", help="run folder (or its result.json)")
    p.add_argument("run_b", help="run folder (or its result.json)")
    p.add_argument("--out", default=None, help="also write an overlay figure into this folder")
    p.set_defaults(func=_cmd_compare)

    p = sub.add_parser("demo", help="run the quick fig2.10 and sanity3 experiments")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_demo)

    from skillkit.viz.cli_view import add_view_parser

    add_view_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from skillkit.experiments.checkpoint import CheckpointError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError, CheckpointError) as exc:
        print(f"skillkit: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("skillkit: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
