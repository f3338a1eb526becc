"""Provenance of a result: which code made it, and whether that code has changed since.

Two records go into every ``result.json``:

* ``git``: the commit of the working tree that made the run and whether the tree had
  uncommitted changes to tracked files (None outside a git checkout, e.g. an installed wheel);
* ``code_fingerprint``: a hash of the code that can change the experiment's numbers — the
  experiment's module and every skillkit module it imports, directly or inside functions,
  transitively (found by reading the sources, not by importing them; a name imported from a
  package's ``__init__`` is followed to the module that defines it), and the shipped
  demonstrations those modules name. Not part of it: the plotting and viewer code of
  :mod:`skillkit.viz`, the command line, and the runner (its trial seeding and executors
  are held fixed by tests: same seed, same numbers, whichever executor). Each source file
  enters as its token stream without comments, docstrings or blank lines, so editing
  documentation or formatting leaves the fingerprint unchanged, while any change to code
  does change it.

:func:`check_results` recomputes the fingerprint of each stored result's experiment with the
code installed now; a result whose fingerprint differs (or that has none) is *stale*: it may
not be what today's code would produce. ``skillkit runs --check DIR`` prints those.
"""

from __future__ import annotations

import ast
import hashlib
import io
import json
import subprocess
import tokenize
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Any

PACKAGE_ROOT = Path(__file__).resolve().parent.parent
"""The ``skillkit`` package folder."""

EXCLUDED = ("skillkit.viz", "skillkit.cli", "skillkit.experiments.timings")
"""Modules (and packages) whose code cannot change an experiment's numbers: figures, the
viewer, the command line and the measured-time table."""

NOT_FOLLOWED = ("skillkit.experiments",)
"""Packages whose ``__init__`` is hashed but not followed: ``skillkit.experiments`` imports
every experiment module to register it, which is not code one experiment runs. Their
top-level imports of their own submodules (``from skillkit.experiments import ch2``) are left
out of the hash too (:func:`_registration_lines`): registering another experiment changes no
number of this one, and a submodule this experiment does use enters as its own file."""

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


def _imports(path: Path, own_name: str | None) -> dict[str, bool]:
    stat = path.stat()
    return _imports_cached(path, own_name, stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=512)
def _imports_cached(path: Path, own_name: str | None, mtime_ns: int, size: int) -> dict[str, bool]:
    """skillkit modules imported anywhere in ``path`` (top level or inside functions).

    Returns ``{module: follow}``: ``follow`` is False for a package that is only imported as
    the parent of a submodule (``from skillkit.models import gp`` runs ``skillkit/models/
    __init__.py``, whose code is hashed, but what that ``__init__`` imports in turn — e.g. a
    registry importing every experiment — is not what this file uses).
    """
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
    """``{name: module}`` for the names a skillkit package's ``__init__`` imports from its
    own modules (``from skillkit.search.reps import ContextualREPS``) or exports lazily
    through a module-level ``_LAZY = {"name": "module", ...}`` dict read by its
    ``__getattr__`` (PEP 562)."""
    file = _module_file(package)
    if file is None or file.name != "__init__.py":
        return {}
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
    """The module that ``from base import name`` runs for ``name``: the submodule
    ``base.name``, the module a package re-exports ``name`` from, or ``base`` itself."""
    if _module_file(f"{base}.{name}") is not None:
        return f"{base}.{name}"
    source = _reexports(base).get(name)
    if source and source != base and source.startswith("skillkit"):
        return _defining_module(source, name) if _module_file(source) else base
    return base


def source_closure(path: str | Path) -> list[Path]:
    """``path`` and every skillkit source file it imports, transitively, sorted.

    Parameters
    ----------
    path : path
        A Python source file (an experiment module, or any module whose skillkit imports
        should be followed).

    Returns
    -------
    list of Path
        The files, excluding :data:`EXCLUDED` modules (unless ``path`` itself is one).
    """
    start = Path(path).resolve()
    hashed = {start}
    followed = {start}
    todo = [start]
    while todo:
        current = todo.pop()
        for name, follow in _imports(current, _module_name(current)).items():
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
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if (
                body
                and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)
            ):
                lines.update(range(body[0].lineno, (body[0].end_lineno or body[0].lineno) + 1))
    return lines


def _registration_lines(tree: ast.Module, package: str) -> set[int]:
    """Lines of a package ``__init__``'s top-level statements that only import its own
    submodules (``from package import submodule``, each name a module file)."""
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
    """The file's code as a token stream without comments, docstrings and blank lines (and,
    for a :data:`NOT_FOLLOWED` package's ``__init__``, without its submodule imports)."""
    text = path.read_text(encoding="utf-8")
    tree = ast.parse(text, filename=str(path))
    skip = _docstring_lines(tree)
    name = _module_name(path)
    dropped = set()
    if path.name == "__init__.py" and name in NOT_FOLLOWED:
        dropped = _registration_lines(tree, name)
    out = []
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type in _SKIPPED_TOKENS or tok.start[0] in dropped:
            continue
        if tok.type == tokenize.STRING and tok.start[0] in skip:
            continue
        if tok.type == tokenize.NEWLINE and tok.start[0] in skip:
            continue
        out.append(f"{tok.type}:{tok.string}")
    return "\n".join(out).encode()


DATA_FOLDER = PACKAGE_ROOT / "data" / "demonstrations"
"""Shipped data that code reads by file name; a file enters a fingerprint (as its bytes)
when a source file of the closure names it."""


def _data_files(files: list[Path]) -> list[Path]:
    shipped = sorted(DATA_FOLDER.glob("*")) if DATA_FOLDER.is_dir() else []
    texts = [f.read_text(encoding="utf-8") for f in files]
    return [d for d in shipped if any(d.name in text for text in texts)]


def fingerprint_files(files: list[Path]) -> str:
    """SHA-256 (16 hex digits) of the normalised sources of ``files``, their names, and the
    bytes of the shipped data files they name."""
    digest = hashlib.sha256()
    for file in sorted(files):
        name = _module_name(file) or file.name
        stat = file.stat()
        digest.update(name.encode() + b"\0")
        digest.update(hashlib.sha256(_normalised(file, stat.st_mtime_ns, stat.st_size)).digest())
    for data in _data_files(files):
        digest.update(f"data/{data.name}".encode() + b"\0")
        digest.update(hashlib.sha256(data.read_bytes()).digest())
    return digest.hexdigest()[:16]


def code_fingerprint(obj: Callable | str | Path) -> str:
    """Fingerprint of the code that can change the numbers of ``obj``.

    Parameters
    ----------
    obj : callable, str or path
        A function (its defining module is followed), an experiment id registered in
        :mod:`skillkit.experiments.registry`, or a source file.

    Returns
    -------
    str
        16 hex digits; equal for two trees whose code (ignoring comments, docstrings and
        formatting) in the closure is equal.
    """
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
    """The git commit of the checkout holding ``path`` (default: the package) and whether it
    has uncommitted changes to tracked files.

    Returns
    -------
    dict
        ``{"commit": str or None, "dirty": bool or None}``; both None when the package is not
        inside a git checkout or git is not installed.
    """
    where = Path(path) if path is not None else PACKAGE_ROOT
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True, timeout=30
        )
        if commit.returncode != 0:
            return {"commit": None, "dirty": None}
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=where,
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}
    dirty = bool(status.stdout.strip()) if status.returncode == 0 else None
    return {"commit": commit.stdout.strip(), "dirty": dirty}


def provenance(exp_id: str) -> dict[str, Any]:
    """What ``result.json`` records about the code that made a run of ``exp_id``:
    ``{"git": git_state(), "code_fingerprint": str or None}`` (None when the experiment's
    trial function has no source file, e.g. one built in an interactive session: such a run
    is listed as stale by :func:`check_results`)."""
    try:
        fingerprint = code_fingerprint(exp_id)
    except ValueError:
        fingerprint = None
    return {"git": git_state(), "code_fingerprint": fingerprint}


def staleness(result: dict[str, Any], known: set[str] | None = None) -> tuple[bool, str]:
    """Whether today's code would still make ``result`` (a ``result.json`` as a dict).

    Parameters
    ----------
    result : dict
        The run's record (``id``, and ``code_fingerprint`` / ``git`` when it has provenance).
    known : set of str, optional
        The registered ids (looked up when not given).

    Returns
    -------
    stale : bool
        True when the result has no fingerprint (made before provenance was recorded), its id
        is not registered, or the fingerprint of its experiment's code has changed.
    reason : str
        Why it is stale, or ``"current"``.
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
    now = code_fingerprint(exp_id)
    if now == stored:
        return False, "current"
    commit = (result.get("git") or {}).get("commit") or "?"
    return True, f"code changed since commit {commit[:7]} (fingerprint {stored} -> {now})"


def check_results(root: str | Path) -> list[dict[str, Any]]:
    """Every ``result.json`` under ``root`` with whether today's code would still make it.

    Returns
    -------
    list of dict
        ``path``, ``id``, ``stale`` (bool) and ``reason`` (why it is stale, or "current"),
        in path order. A result without a fingerprint, or of an id no longer registered, is
        stale.
    """
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
        exp_id = result["id"]
        rows.append({"path": str(path.parent), "id": exp_id, "stale": stale, "reason": reason})
    return rows
