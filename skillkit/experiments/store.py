"""The results store: finished runs under ``runs/`` (or any folder), listed and compared."""

from __future__ import annotations

import json
from pathlib import Path

from skillkit.experiments.registry import Series

EXPECTED = "expected a run folder or its result.json, as written by `skillkit reproduce`"
"""What ``compare`` accepts, in the words of its error messages."""


def find_root(cwd: str | Path | None = None) -> Path:
    """The folder ``skillkit runs`` lists when given none: ``runs/`` in ``cwd`` (default: the
    current folder), else ``cwd`` if a ``result.json`` lies below it."""
    base = Path(".") if cwd is None else Path(cwd)
    if (base / "runs").is_dir():
        return base / "runs"
    if next(base.rglob("result.json"), None) is not None:
        return base
    raise ValueError(
        f"no runs found: there is no runs/ folder in {base.resolve()} and no result.json below "
        "it; give --root FOLDER, or write a run first (`skillkit reproduce ID`, `skillkit demo`)"
    )


def list_runs(root: str | Path = "runs") -> list[dict]:
    """Every run below ``root``, newest first: ``path``, ``id``, ``scale``, ``seed``,
    ``trials``, ``executor``, ``wall_time_s`` and ``summary`` (None where missing)."""
    root = Path(root)
    if not root.exists():
        raise ValueError(f"root: no results folder at {root}")
    runs = []
    for path in sorted(root.rglob("result.json"), key=lambda p: p.stat().st_mtime, reverse=True):
        try:
            r = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(r, dict):  # some other tool's result.json: not a run
            continue
        runs.append(
            {
                "path": str(path.parent),
                **{k: r.get(k) for k in ("id", "scale", "seed", "trials")},
                "executor": r.get("executor", "local"),
                "wall_time_s": r.get("wall_time_s"),
                "summary": r.get("summary", {}),
            }
        )
    return runs


def _kind(value) -> str:
    """The JSON name of a parsed value's type, for error messages."""
    names = {dict: "an object", list: "a list", str: "a string", bool: "a boolean"}
    if value is None:
        return "null"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return "a number"
    return names.get(type(value), type(value).__name__)


def read_result(path: str | Path) -> dict:
    """The ``result.json`` of a run folder (or the file), checked for what :func:`compare` reads.

    Raises
    ------
    FileNotFoundError
        No such path, or a folder without ``result.json``.
    ValueError
        One line naming the file and the field that is not as a run writes it.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file or folder ({EXPECTED})")
    if p.is_dir():
        file = p / "result.json"
        if not file.is_file():
            raise FileNotFoundError(f"{p}: no result.json in this folder ({EXPECTED})")
    elif p.name != "result.json":
        raise ValueError(f"{p}: not a result.json ({EXPECTED})")
    else:
        file = p
    try:
        result = json.loads(file.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{file}: cannot be read ({exc})") from None
    except ValueError as exc:
        raise ValueError(f"{file}: not valid JSON ({exc}); {EXPECTED}") from None
    if not isinstance(result, dict):
        raise ValueError(
            f"{file}: holds no run (expected a JSON object, got {type(result).__name__})"
        )
    if "summary" not in result and "series" not in result:
        raise ValueError(f"{file}: holds no run (no summary and no series)")
    for key in ("summary", "settings"):
        if key in result and not isinstance(result[key], dict):
            raise ValueError(f"{file}: {key}: expected an object, got {_kind(result[key])}")
    if "series" not in result:
        raise ValueError(f"{file}: series: missing (expected a list of curves)")
    series = result["series"]
    if not isinstance(series, list):
        raise ValueError(f"{file}: series: expected a list, got {_kind(series)}")
    for i, s in enumerate(series):
        where = f"{file}: series[{i}]"
        if not isinstance(s, dict):
            raise ValueError(f"{where}: expected an object, got {_kind(s)}")
        for key, kind in (("name", str), ("x", list), ("y", list)):
            if not isinstance(s.get(key), kind):
                got = "missing" if key not in s else f"got {_kind(s[key])}"
                raise ValueError(f"{where}.{key}: expected {_kind(kind())}, {got}")
    return result


def flatten(d: dict, prefix: str = "") -> dict:
    """Nested dicts as one dict with dotted keys."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def compare(
    path_a: str | Path, path_b: str | Path
) -> tuple[list[tuple[str, object, object]], dict]:
    """Two runs side by side (both read by :func:`read_result`).

    Returns
    -------
    rows : list of (key, value_a, value_b)
        The flattened summaries, settings, trial counts, executors, workers, resumed trials
        and wall times.
    result : dict
        A result-like dict whose series overlay both runs' (`` [A]``, `` [B]``).
    """
    a, b = read_result(path_a), read_result(path_b)
    run_keys = ("trials", "executor", "workers", "resumed_trials", "wall_time_s")
    fa, fb = (
        flatten(
            {
                "summary": r.get("summary", {}),
                "settings": r.get("settings", {}),
                **{k: r.get(k) for k in run_keys},
            }
        )
        for r in (a, b)
    )
    rows = [(k, fa.get(k), fb.get(k)) for k in sorted(set(fa) | set(fb))]
    series = []
    for tag, r in (("A", a), ("B", b)):
        for s in r["series"]:
            fields = {k: v for k, v in s.items() if k in Series.__dataclass_fields__}
            fields["name"] = f"{s['name']} [{tag}]"
            series.append(fields)
    return rows, {
        "id": f"{a.get('id')} vs {b.get('id')}",
        "title": "comparison",
        "scale": "",
        "series": series,
    }
