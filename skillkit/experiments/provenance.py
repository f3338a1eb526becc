"""Provenance of a result: which code made it, and whether that code has changed since.

``result.json`` records ``git`` (commit and dirty flag), ``code_fingerprint`` (a hash of the
experiment's module and every skillkit module it imports, transitively, without
:data:`EXCLUDED` code, as token streams without comments, docstrings or blank lines, plus the
shipped demonstrations they name) and, for quick and paper runs, a ``witness``: the
:func:`measurements` of a smoke run of the same id and seed by the same code.

A result whose fingerprint equals today's is *current*; when the code changed, a fresh witness
equal to the stored one within round-off (:func:`compare_witness`) *carries* it (recorded in
``result.json``); otherwise it is *stale*.
"""

from __future__ import annotations

import ast
import hashlib
import io
import json
import math
import subprocess
import tokenize
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Any

from skillkit.experiments.judge import JUDGEMENT_KEYS

PACKAGE_ROOT = Path(__file__).resolve().parent.parent
"""The ``skillkit`` package folder."""

EXCLUDED = (
    "skillkit.viz",
    "skillkit.cli",
    "skillkit.experiments.timings",
    "skillkit.experiments.judge",
)
"""Modules (and packages) whose code cannot change an experiment's numbers: figures, the
viewer, the command line, the measured-time table and the claims engine."""

NOT_FOLLOWED = ("skillkit.experiments",)
"""Packages whose ``__init__`` is hashed but not followed (``skillkit.experiments`` imports
every experiment to register it); their imports of their own submodules are not hashed."""

_SKIPPED_TOKENS = {tokenize.COMMENT, tokenize.NL, tokenize.ENCODING, tokenize.ENDMARKER}


def _module_file(name: str) -> Path | None:
    """The source file of skillkit module ``name`` (a package's ``__init__.py``), or None."""
    parts = name.split(".")
    if parts[0] != "skillkit":
        return None
    base = PACKAGE_ROOT.joinpath(*parts[1:])
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _module_name(path: Path) -> str | None:
    """The dotted name of a file inside the skillkit package, or None outside it."""
    try:
        rel = path.resolve().relative_to(PACKAGE_ROOT)
    except ValueError:
        return None
    parts = ["skillkit", *rel.with_suffix("").parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_excluded(name: str) -> bool:
    return any(name == e or name.startswith(e + ".") for e in EXCLUDED)


@lru_cache(maxsize=512)
def _imports(path: Path, own_name: str | None, mtime_ns: int, size: int) -> dict[str, bool]:
    """``{module: follow}`` of the skillkit modules ``path`` imports (``follow`` False for a
    package only imported as the parent of a submodule)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    explicit: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            explicit.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative import: resolve against this module's package
                if own_name is None:
                    continue
                package = own_name.split(".")
                if not is_package:
                    package = package[:-1]
                package = package[: len(package) - (node.level - 1)]
                base = ".".join(package + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            for alias in node.names:
                explicit.add(_defining_module(base, alias.name))
    modules: dict[str, bool] = {}
    for name in explicit:
        if not name.startswith("skillkit"):
            continue
        parts = name.split(".")
        for i in range(1, len(parts) + 1):  # importing a.b.c runs a, a.b and a.b.c
            prefix = ".".join(parts[:i])
            if _module_file(prefix) is None or _is_excluded(prefix):
                continue
            follow = prefix == name and prefix not in NOT_FOLLOWED
            modules[prefix] = modules.get(prefix, False) or follow
    return modules


@lru_cache(maxsize=256)
def _reexports(package: str) -> dict[str, str]:
    """``{name: module}`` of the names a package's ``__init__`` imports or exports lazily
    (``_LAZY``, PEP 562), or an :data:`EXCLUDED` module re-exports."""
    file = _module_file(package)
    if file is None:
        return {}
    if file.name != "__init__.py":
        if not _is_excluded(package):
            return {}
        package = package.rsplit(".", 1)[0]  # relative imports resolve in the parent package
    out = {}
    for node in ast.parse(file.read_text(encoding="utf-8")).body:
        if (
            isinstance(node, ast.Assign)
            and [getattr(t, "id", None) for t in node.targets] == ["_LAZY"]
            and isinstance(node.value, ast.Dict)
        ):
            for key, value in zip(node.value.keys, node.value.values, strict=True):
                if isinstance(key, ast.Constant) and isinstance(value, ast.Constant):
                    out[str(key.value)] = str(value.value)
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = ".".join([package] + ([node.module] if node.module else []))
                base = ".".join(base.split(".")[: len(base.split(".")) - (node.level - 1)])
            else:
                base = node.module or ""
            for alias in node.names:
                out[alias.asname or alias.name] = base
    return out


def _defining_module(base: str, name: str) -> str:
    """The module ``from base import name`` runs: ``base.name``, the re-exporting source, or
    ``base``."""
    if _module_file(f"{base}.{name}") is not None:
        return f"{base}.{name}"
    source = _reexports(base).get(name)
    if source and source != base and source.startswith("skillkit"):
        return _defining_module(source, name) if _module_file(source) else base
    return base


def source_closure(path: str | Path) -> list[Path]:
    """``path`` and every skillkit source file it imports, transitively, sorted (without
    :data:`EXCLUDED` modules unless ``path`` is one)."""
    start = Path(path).resolve()
    hashed = {start}
    followed = {start}
    todo = [start]
    while todo:
        current = todo.pop()
        stat = current.stat()
        for name, follow in _imports(
            current, _module_name(current), stat.st_mtime_ns, stat.st_size
        ).items():
            file = _module_file(name)
            if file is None:
                continue
            hashed.add(file)
            if follow and file not in followed:
                followed.add(file)
                todo.append(file)
    return sorted(hashed)


def _docstring_lines(tree: ast.AST) -> set[int]:
    lines: set[int] = set()
    kinds = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
    for node in ast.walk(tree):
        if isinstance(node, kinds) and ast.get_docstring(node, clean=False) is not None:
            first = node.body[0]
            lines.update(range(first.lineno, (first.end_lineno or first.lineno) + 1))
    return lines


def _registration_lines(tree: ast.Module, package: str) -> set[int]:
    """Lines of a package ``__init__``'s imports of its own submodules."""
    lines: set[int] = set()
    for node in tree.body:
        if (
            isinstance(node, ast.ImportFrom)
            and not node.level
            and node.module == package
            and all(_module_file(f"{package}.{a.name}") is not None for a in node.names)
        ):
            lines.update(range(node.lineno, (node.end_lineno or node.lineno) + 1))
    return lines


@lru_cache(maxsize=512)
def _normalised(path: Path, mtime_ns: int, size: int) -> bytes:
    """The file's code as a token stream without comments, docstrings and blank lines (and
    a :data:`NOT_FOLLOWED` package's submodule imports)."""
    text = path.read_text(encoding="utf-8")
    tree = ast.parse(text, filename=str(path))
    skip = _docstring_lines(tree)
    name = _module_name(path)
    dropped = set()
    if path.name == "__init__.py" and name in NOT_FOLLOWED:
        dropped = _registration_lines(tree, name)
    out = []
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        line = tok.start[0]
        docstring = tok.type in (tokenize.STRING, tokenize.NEWLINE) and line in skip
        if not (tok.type in _SKIPPED_TOKENS or line in dropped or docstring):
            out.append(f"{tok.type}:{tok.string}")
    return "\n".join(out).encode()


DATA_FOLDER = PACKAGE_ROOT / "data" / "demonstrations"
"""Shipped data; a file enters a fingerprint (its bytes) when a closure file names it."""


def fingerprint_files(files: list[Path]) -> str:
    """SHA-256 (16 hex digits) of the normalised sources of ``files``, their names and the
    shipped data files they name."""
    digest = hashlib.sha256()
    for file in sorted(files):
        name = _module_name(file) or file.name
        stat = file.stat()
        digest.update(name.encode() + b"\0")
        digest.update(hashlib.sha256(_normalised(file, stat.st_mtime_ns, stat.st_size)).digest())
    shipped = sorted(DATA_FOLDER.glob("*")) if DATA_FOLDER.is_dir() else []
    texts = [f.read_text(encoding="utf-8") for f in files]
    for data in (d for d in shipped if any(d.name in text for text in texts)):
        digest.update(f"data/{data.name}".encode() + b"\0")
        digest.update(hashlib.sha256(data.read_bytes()).digest())
    return digest.hexdigest()[:16]


def code_fingerprint(obj: Callable | str | Path) -> str:
    """Fingerprint (16 hex digits) of the code that can change the numbers of ``obj``: a
    function (its module is followed), a registered experiment id, or a source file."""
    if isinstance(obj, Path) or (isinstance(obj, str) and obj.endswith(".py")):
        path = Path(obj)
    elif isinstance(obj, str):
        from skillkit.experiments.registry import get

        path = Path(_source_file(get(obj).run_trial))
    else:
        path = Path(_source_file(obj))
    return fingerprint_files(source_closure(path))


def _source_file(func: Callable) -> str:
    import inspect

    try:
        file = inspect.getsourcefile(func)
    except TypeError:
        file = None
    if file is None:
        raise ValueError(f"obj: no source file for {func!r}")
    return file


def git_state(path: str | Path | None = None) -> dict[str, Any]:
    """``{"commit", "dirty"}`` of the checkout holding ``path`` (default: the package);
    both None outside a git checkout."""
    where = Path(path) if path is not None else PACKAGE_ROOT

    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", *args], cwd=where, capture_output=True, text=True, timeout=30)

    try:
        commit = git("rev-parse", "HEAD")
        if commit.returncode != 0:
            return {"commit": None, "dirty": None}
        status = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}
    dirty = bool(status.stdout.strip()) if status.returncode == 0 else None
    return {"commit": commit.stdout.strip(), "dirty": dirty}


def provenance(exp_id: str) -> dict[str, Any]:
    """``{"git", "code_fingerprint"}`` of a run of ``exp_id`` (fingerprint None when the
    trial function has no source file)."""
    try:
        fingerprint = code_fingerprint(exp_id)
    except ValueError:
        fingerprint = None
    return {"git": git_state(), "code_fingerprint": fingerprint}


# ---------------------------------------------------------------------------- the witness
SERIES_MEASURED = ("x", "y", "lower", "upper", "z")
"""The fields of a stored series that hold measured numbers (the others are presentation)."""

WITNESS_RTOL = 1e-6
"""Relative part of the round-off tolerance of :func:`compare_witness`:
|a − b| ≤ WITNESS_RTOL · max(|a|, |b|) + WITNESS_ATOL."""

WITNESS_ATOL = 1e-12
"""Absolute part of the round-off tolerance (:data:`WITNESS_RTOL`)."""

WITNESS_SCALE = "smoke"
"""The scale a witness runs at."""

_DROPPED = object()


def _measured(value: Any) -> Any:
    """``value`` without judgement keys and text (:data:`_DROPPED` when nothing is left)."""
    if isinstance(value, dict):
        out = {}
        for key, item in value.items():
            if key in JUDGEMENT_KEYS:
                continue
            kept = _measured(item)
            if kept is not _DROPPED:
                out[str(key)] = kept
        return out if out or not value else _DROPPED
    if isinstance(value, (list, tuple)):
        items = [m for m in (_measured(v) for v in value) if m is not _DROPPED]
        return items if items or not value else _DROPPED
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):  # numpy
        return _measured(value.tolist())
    if value is None or isinstance(value, bool):
        return value
    if isinstance(value, (int, float)):
        return value if math.isfinite(value) else None  # as result.json stores NaN and inf
    return _DROPPED


def measurements(summary: dict[str, Any]) -> dict[str, Any]:
    """The measured numbers of a run's ``summary`` (what a witness compares): the tree
    without :data:`JUDGEMENT_KEYS` and text, numeric leaves only (int, float, bool, None; a
    non-finite float becomes None)."""
    kept = _measured(summary)
    return kept if isinstance(kept, dict) else {}


def series_measurements(series: list) -> list[dict[str, Any]]:
    """Per series, the numeric leaves of its :data:`SERIES_MEASURED` fields."""
    out = []
    for s in series:
        fields = s.to_dict() if hasattr(s, "to_dict") else dict(s)
        kept = {k: _measured(fields[k]) for k in SERIES_MEASURED if k in fields}
        out.append({k: v for k, v in kept.items() if v is not _DROPPED})
    return out


def _is_leaf(value: Any) -> bool:
    return not isinstance(value, (dict, list))


def _equal(a: Any, b: Any) -> bool:
    """Leaves equal within the round-off tolerance (None equals NaN; bools only bools)."""
    a_none = a is None or (isinstance(a, float) and math.isnan(a))
    b_none = b is None or (isinstance(b, float) and math.isnan(b))
    if a_none or b_none:
        return a_none and b_none
    if isinstance(a, bool) or isinstance(b, bool):
        return isinstance(a, bool) and isinstance(b, bool) and a == b
    if not isinstance(a, (int, float)) or not isinstance(b, (int, float)):
        return a == b
    if math.isinf(a) or math.isinf(b):
        return a == b
    return abs(a - b) <= WITNESS_RTOL * max(abs(a), abs(b)) + WITNESS_ATOL


def _short(value: Any) -> str:
    if isinstance(value, dict):
        return f"an object of {len(value)} keys"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    return repr(value)


def walk_differences(
    stored: Any, fresh: Any, path: str, skip: set[str], out: list[tuple[str, str]]
):
    """Append ``(path, text)`` per difference of ``fresh`` from ``stored`` (``"added: ..."``
    for what only ``fresh`` has)."""
    if path in skip:
        return
    if isinstance(stored, dict) and isinstance(fresh, dict):
        for key, value in stored.items():
            where = f"{path}.{key}"
            if key not in fresh:
                if where not in skip:
                    out.append((where, f"{where}: missing (stored {_short(value)})"))
                continue
            walk_differences(value, fresh[key], where, skip, out)
        for key in fresh.keys() - stored.keys():
            where = f"{path}.{key}"
            out.append((where, f"added: {where} = {_short(fresh[key])}"))
        return
    if isinstance(stored, list) and isinstance(fresh, list):
        if all(_is_leaf(v) for v in stored + fresh):  # an array: one measurement
            if len(stored) != len(fresh):
                out.append((path, f"{path}: length {len(stored)} -> {len(fresh)}"))
                return
            bad = [i for i, a in enumerate(stored) if not _equal(a, fresh[i])]
            if bad:
                i, n = bad[0], len(stored)
                first = f"first [{i}]: {stored[i]!r} -> {fresh[i]!r}"
                out.append((path, f"{path}: {len(bad)} of {n} values differ, {first}"))
            return
        for i, value in enumerate(stored):  # records: new ones may follow
            where = f"{path}[{i}]"
            if i >= len(fresh):
                out.append((where, f"{where}: missing (stored {_short(value)})"))
            else:
                walk_differences(value, fresh[i], where, skip, out)
        for i in range(len(stored), len(fresh)):
            where = f"{path}[{i}]"
            out.append((where, f"added: {where} = {_short(fresh[i])}"))
        return
    if _is_leaf(stored) and _is_leaf(fresh):
        if not _equal(stored, fresh):
            out.append((path, f"{path}: {stored!r} -> {fresh!r}"))
        return
    out.append((path, f"{path}: {_short(stored)} -> {_short(fresh)}"))


def _differences(stored: dict, fresh: dict, skip: set[str] = frozenset()) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    for part in ("summary", "series"):
        walk_differences(
            stored.get(part, {} if part == "summary" else []), fresh.get(part), part, skip, out
        )
    return out


def unstable_paths(first: dict[str, Any], second: dict[str, Any]) -> list[str]:
    """Paths of the measurements that differ between two witnesses of the same code and seed
    (listed under ``unstable``, skipped by :func:`compare_witness`)."""
    return sorted({path for path, _ in _differences(first, second)})


def compare_witness(stored: dict[str, Any], fresh: dict[str, Any]) -> tuple[bool, list[str]]:
    """Whether a fresh witness reproduces a stored one: every numeric leaf of the stored
    ``summary`` and ``series`` (but its ``unstable`` paths) is in the fresh one, equal within
    :data:`WITNESS_RTOL` and :data:`WITNESS_ATOL`; leaves only the fresh one has are allowed.

    Parameters
    ----------
    stored, fresh : dict
        Witnesses (``result.json``'s ``witness``), at least ``summary`` and ``series``.

    Returns
    -------
    equal : bool
        True when nothing but additions differs.
    differences : list of str
        One line per difference (path, stored -> fresh); the ``"added: ..."`` lines last.
    """
    skip = set(stored.get("unstable") or ())
    found = [text for _, text in _differences(stored, fresh, skip)]
    changed = [t for t in found if not t.startswith("added: ")]
    return not changed, changed + [t for t in found if t.startswith("added: ")]


# ---------------------------------------------------------------------------- staleness
def carried_reason(record: dict[str, Any]) -> str:
    """The reason :func:`staleness` gives for a result carried by the carry record ``record``."""
    commit = str(record.get("commit") or "?")[:7]
    return f"carried (code changed at {commit}, witness equal)"


def staleness(result: dict[str, Any], known: set[str] | None = None) -> tuple[bool, str]:
    """Whether today's code would still make ``result``, from fingerprints and carry records.

    Returns
    -------
    stale : bool
        True without a fingerprint, for an unregistered id, or when the fingerprint changed
        and no carry record names today's.
    reason : str
        Why it is stale, ``"current"`` or ``"carried (...)"``.
    """
    if known is None:
        from skillkit.experiments.registry import ids

        known = set(ids())
    exp_id = result.get("id")
    stored = result.get("code_fingerprint")
    if exp_id not in known:
        return True, f"experiment {exp_id!r} is not registered"
    if not stored:
        return True, "no code fingerprint (made before provenance was recorded)"
    changed = settings_changes(result)
    if changed:
        return True, f"settings of its scale changed: {changed}"
    now = code_fingerprint(exp_id)
    if now == stored:
        return False, "current"
    for record in result.get("carried") or ():
        if isinstance(record, dict) and record.get("code_fingerprint") == now:
            return False, carried_reason(record)
    commit = (result.get("git") or {}).get("commit") or "?"
    return True, f"code changed since commit {commit[:7]} (fingerprint {stored} -> {now})"


def settings_changes(result: dict[str, Any]) -> str:
    """The fields (``block.name``: stored → today) where ``result``'s settings differ from
    today's settings of its scale with its ``overrides``; "" where none does (or the result
    records no settings and scale)."""
    from skillkit.experiments.registry import get
    from skillkit.experiments.settings import apply_overrides

    if "settings" not in result or "scale" not in result:
        return ""
    exp = get(result["id"])
    try:
        today = apply_overrides(exp.settings[result["scale"]], result.get("overrides") or {})
    except (KeyError, ValueError) as exc:
        return f"its overrides no longer apply ({exc})"

    def flat(d: Any, prefix: str = "") -> dict[str, Any]:
        if not isinstance(d, dict):
            return {prefix[:-1]: d}
        return {k: v for name, x in d.items() for k, v in flat(x, f"{prefix}{name}.").items()}

    old, new = flat(result.get("settings") or {}), flat(json.loads(json.dumps(today.to_dict())))
    keys = [k for k in new if old.get(k, "absent") != new[k]] + [k for k in old if k not in new]
    return ", ".join(f"{k} {old.get(k, 'absent')} → {new.get(k, 'absent')}" for k in keys)


def check_results(root: str | Path) -> list[dict[str, Any]]:
    """Every ``result.json`` under ``root`` with :func:`staleness`, in path order: ``path``,
    ``id``, ``status`` (current, carried or stale), ``stale`` and ``reason``."""
    from skillkit.experiments.registry import ids

    known = set(ids())
    rows = []
    for path in sorted(Path(root).rglob("result.json")):
        try:
            result = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(result, dict) or "id" not in result:
            continue
        stale, reason = staleness(result, known)
        status = "stale" if stale else "current" if reason == "current" else "carried"
        row = {"path": str(path.parent), "id": result["id"], "status": status}
        rows.append({**row, "stale": stale, "reason": reason})
    return rows
