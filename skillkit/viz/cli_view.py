"""``skillkit view TASK``: serve a task scene in the browser (:class:`skillkit.viz.viewer.Viewer`),
wired into ``skillkit/cli.py`` by :func:`add_view_parser`; bad input exits with code 2."""

from __future__ import annotations

import argparse
import sys

from skillkit.viz import DEFAULT_HOST, DEFAULT_PORT


def add_view_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``view`` sub-command to an ``argparse`` sub-parsers object and return it."""
    p = subparsers.add_parser(
        "view",
        help="serve a task scene in the browser (viser)",
        description="Serve a task's rollouts, model predictions and learning playback in the "
        "browser. Open the printed URL; Ctrl-C stops the server. File formats: "
        "skillkit.viz.history (--policy), skillkit.viz.predictions (--predictions); --gpreps "
        "unpickles the run's reward model: view only runs you trust.",
    )
    add = p.add_argument
    add("task", help="task name (see `skillkit list`)")
    add("--policy", metavar="FILE", help="policy history .npz or run folder: learning playback")
    add("--gpreps", metavar="RUN_DIR", help="GPREPS run folder: its policies and reward model")
    add("--trial", type=int, default=0, help="trial of a run folder (default 0)")
    add("--samples", type=int, default=10, metavar="L", help="trajectories per learned model")
    add("--context", type=float, nargs="+", metavar="S", help="initial context (default: middle)")
    add("--predictions", metavar="FILE", help="prediction layers .npz to overlay")
    add("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT})")
    add("--host", default=DEFAULT_HOST, help=f"interface to bind (default {DEFAULT_HOST})")
    add("--seed", type=int, default=0, help="episode seed of the rollouts")
    add("--no-envmap", action="store_true", help="no HDRI map: faster in browsers without GPU")
    add("--verbose", action="store_true", help="let viser print its banner and connections")
    p.set_defaults(func=run_view)
    return p


def build_viewer(args: argparse.Namespace, history=None):
    """The :class:`~skillkit.viz.viewer.Viewer` the arguments describe (not started); a
    ``history`` given replaces the one ``--policy`` names."""
    from skillkit.tasks import make
    from skillkit.viz.history import load_policy_history
    from skillkit.viz.viewer import Viewer

    task = make(args.task)
    if history is None and args.policy is not None:
        history = load_policy_history(args.policy, args.trial)
    given = {k: getattr(args, k) for k in ("context", "host", "port", "seed", "verbose")}
    return Viewer(task, history=history, environment=not args.no_envmap, **given)


def run_view(args: argparse.Namespace) -> int:
    """Start the viewer and serve until Ctrl-C; bad input → one-line message, exit code 2."""
    from skillkit.tasks import make
    from skillkit.viz.model_layers import check_model_task, load_gpreps_run
    from skillkit.viz.predictions import load_predictions
    from skillkit.viz.viewer import PortInUseError

    model = history = None
    try:
        if args.gpreps is not None:
            if args.policy is not None:
                raise ValueError("policy: give --policy or --gpreps, not both")
            history, model = load_gpreps_run(args.gpreps, args.trial)
            check_model_task(model, make(args.task).name)  # before the policy's dimensions
        viewer = build_viewer(args, history)
        layers = [] if args.predictions is None else load_predictions(args.predictions)
        viewer.start()
    except (ValueError, PortInUseError) as exc:
        print(f"skillkit view: error: {exc}", file=sys.stderr)
        return 2
    # the server runs: every way out (a Ctrl-C before serve_forever too) stops it
    try:
        stage = "predictions"
        try:
            for spec in layers:
                viewer.add_prediction_layer(**spec)
            stage = "gpreps"
            if model is not None:
                viewer.add_model_layers(model, args.samples, seed=args.seed)
        except ValueError as exc:
            print(f"skillkit view: error: {stage}: {exc}", file=sys.stderr)
            return 2
        msg = f"skillkit view: serving {viewer.task.name} at {viewer.url} (Ctrl-C to stop)"
        print(msg, flush=True)
        viewer.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m skillkit.viz.cli_view TASK ...``: the ``view`` sub-command on its own."""
    parser = argparse.ArgumentParser(prog="skillkit")
    add_view_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["view", *(sys.argv[1:] if argv is None else argv)])
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
