"""The import graph of ``skillkit/`` has no cycles, and no module imports another's private names.

Every module is parsed (nothing is imported) and each import, at module level or inside a
function, is an edge to the module it names: ``from skillkit.pkg import name`` goes to the
submodule ``skillkit.pkg.name`` when there is one, else to ``skillkit.pkg`` (its
``__init__``). Python runs a package's ``__init__`` before any of its submodules, but that
is not an edge: the importer's code does not use it, and counting it would make every
package that imports its own submodules a cycle.

A name with a leading underscore (``_name``, not ``__dunder__``) imported from another module
is that module's private business: a name several modules share is part of the package's
internal API and gets a public name. Private *modules* (``skillkit._validation``) are the
package's own and may be imported anywhere inside it.
"""

from __future__ import annotations

import ast
from collections import deque
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "skillkit"


# ---------------------------------------------------------------------------- the checker
def module_files(root: Path) -> dict[str, Path]:
    """``{dotted module name: file}`` of every module of the package folder ``root``."""
    modules = {}
    for path in sorted(root.rglob("*.py")):
        parts = [root.name, *path.relative_to(root).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


def _imports(module: str, path: Path, modules: dict[str, Path]):
    """``(target module, line, imported names)`` of each import of ``module`` that stays inside
    the package; ``names`` is empty for ``import a.b`` and for a submodule imported by name."""
    package = module.split(".")[0]
    here = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in modules:
                    yield alias.name, node.lineno, []
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = here[: len(here) - (node.level - 1)]
                base = ".".join([*up, base] if base else up)
            if base.split(".")[0] != package:
                continue
            names = []
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                if sub in modules:
                    yield sub, node.lineno, []
                else:
                    names.append(alias.name)
            if names and base in modules:
                yield base, node.lineno, names


def import_graph(root: Path) -> dict[str, dict[str, str]]:
    """``{module: {imported module: "file:line" of the first such import}}`` of the package
    folder ``root``, imports inside functions included."""
    modules = module_files(root)
    graph: dict[str, dict[str, str]] = {m: {} for m in modules}
    for module, path in modules.items():
        for target, line, _ in _imports(module, path, modules):
            if target != module:
                where = f"{path.relative_to(root.parent)}:{line}"
                graph[module].setdefault(target, where)
    return graph


def _components(graph: dict[str, dict[str, str]]) -> list[list[str]]:
    """Strongly connected components of ``graph`` (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def find_cycles(graph: dict[str, dict[str, str]]) -> list[str]:
    """One cycle per group of modules that import each other, as
    ``"a -> b (file:line) -> a (file:line)"``: the shortest cycle through the group's first
    module. Empty when the graph is acyclic."""
    cycles = []
    for component in _components(graph):
        if len(component) < 2:
            continue
        inside, start = set(component), component[0]
        parent: dict[str, str] = {}
        queue = deque([start])
        while queue:
            v = queue.popleft()
            if start in graph[v]:
                path = [v]
                while path[-1] != start:
                    path.append(parent[path[-1]])
                path = [start, *reversed(path[:-1]), start] if v != start else [start, start]
                steps = [f"{b} ({graph[a][b]})" for a, b in zip(path, path[1:], strict=False)]
                cycles.append(" -> ".join([start, *steps]))
                break
            for w in sorted(graph[v]):
                if w in inside and w not in parent and w != start:
                    parent[w] = v
                    queue.append(w)
    return cycles


def private_imports(root: Path) -> list[str]:
    """``"file:line: from module import _name"`` for each private name (leading underscore,
    dunders aside) one module of the package folder ``root`` imports from another."""
    modules = module_files(root)
    found = []
    for module, path in modules.items():
        for target, line, names in _imports(module, path, modules):
            hidden = [n for n in names if n.startswith("_") and not n.startswith("__")]
            if hidden and target != module:
                where = f"{path.relative_to(root.parent)}:{line}"
                found.append(f"{where}: from {target} import {', '.join(hidden)}")
    return found


# ---------------------------------------------------------------------------- the package
def test_the_import_graph_has_no_cycles():
    graph = import_graph(ROOT)
    assert len(graph) > 50 and sum(map(len, graph.values())) > 200  # it did read the package
    cycles = find_cycles(graph)
    assert not cycles, "modules that import each other:\n" + "\n".join(cycles)


def test_no_module_imports_private_names_of_another():
    found = private_imports(ROOT)
    assert not found, "private names imported from another module:\n" + "\n".join(found)


# ---------------------------------------------------------------------------- the checker
def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "pkg"
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


CLEAN = {
    "__init__.py": "from pkg.low import VALUE\n__version__ = '1'\n",
    "_private.py": "def helper():\n    return 1\n",
    "low.py": "from pkg._private import helper\nVALUE = helper()\n_SECRET = 2\n",
    "sub/__init__.py": "",
    "sub/mid.py": "from .. import low\n",
    "sub/top.py": "import pkg.sub.mid\n\ndef f():\n    from pkg.sub import mid\n    return mid\n",
    "sub/version.py": "from pkg import __version__\n",
}


def test_the_checker_passes_a_clean_tree(tmp_path):
    root = _tree(tmp_path, CLEAN)
    graph = import_graph(root)
    assert graph["pkg.sub.mid"] == {"pkg.low": "pkg/sub/mid.py:1"}
    assert graph["pkg.sub.version"] == {"pkg": "pkg/sub/version.py:1"}
    assert graph["pkg.sub.top"] == {"pkg.sub.mid": "pkg/sub/top.py:1"}
    assert graph["pkg.low"] == {"pkg._private": "pkg/low.py:1"}
    assert find_cycles(graph) == []
    assert private_imports(root) == []


def test_the_checker_finds_a_cycle_through_a_function_level_import(tmp_path):
    files = {
        **CLEAN,
        "low.py": CLEAN["low.py"] + "\ndef g():\n    from .sub import top\n    return top\n",
    }
    cycles = find_cycles(import_graph(_tree(tmp_path, files)))
    assert cycles == [
        "pkg.low -> pkg.sub.top (pkg/low.py:6) -> pkg.sub.mid (pkg/sub/top.py:1)"
        " -> pkg.low (pkg/sub/mid.py:1)"
    ]


def test_the_checker_finds_a_two_module_cycle_and_a_private_import(tmp_path):
    files = {
        **CLEAN,
        "a.py": "from pkg.b import _helper, public\n",
        "b.py": "import pkg.a\n\ndef public():\n    pass\n\ndef _helper():\n    pass\n",
        "c.py": "from . import low\nfrom .low import _SECRET\n",
    }
    root = _tree(tmp_path, files)
    assert find_cycles(import_graph(root)) == ["pkg.a -> pkg.b (pkg/a.py:1) -> pkg.a (pkg/b.py:1)"]
    assert private_imports(root) == [
        "pkg/a.py:1: from pkg.b import _helper",
        "pkg/c.py:2: from pkg.low import _SECRET",
    ]
