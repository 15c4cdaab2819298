"""The library's layout (README, Layout): unique module names, layers that import only the layers
above them, services that never import the command line, and no import cycle at import time.

Imports are read from the source with ``ast``, so the test sees every module, imported or not.
"""

from __future__ import annotations

import ast
import sys
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ROOT / "shared" / "bintrack"
SERVICES = ROOT / "services"

# A module may import modules of its own rank or a lower one (the README's order, top to bottom).
RANKS = {"sim": 1, "trackers": 2, "evaluation": 3, "pipeline": 4, "live": 5, "client": 5, "view": 5,
         "cli": 6, "services": 6, "mqtt": 5, "hosts": 5}
GROUND = 0


def module_files() -> dict[str, Path]:
    """Dotted module name -> file, for the library and the services."""
    files = {}
    for path in sorted(LIBRARY.rglob("*.py")):
        parts = ("bintrack", *path.relative_to(LIBRARY).with_suffix("").parts)
        files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    for path in sorted(SERVICES.glob("*.py")):
        name = "bintrack.services" if path.stem == "__init__" else f"bintrack.services.{path.stem}"
        files[name] = path
    return files


def rank(module: str) -> int:
    parts = module.split(".")
    return RANKS.get(parts[1], GROUND) if len(parts) > 1 else GROUND


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def imports(path: Path, name: str, known: set[str], *, import_time: bool) -> set[str]:
    """The bintrack modules ``path`` imports: every import, or (``import_time``) only those run
    when the module is imported (module level, not under ``if TYPE_CHECKING``)."""
    package = name if path.stem == "__init__" else name.rpartition(".")[0]
    found: set[str] = set()

    def add(target: str, names: list[str]) -> None:
        for n in names:  # "from pkg import module" imports the module
            if f"{target}.{n}" in known:
                found.add(f"{target}.{n}")
                continue
            found.add(target)

    def visit(nodes, top: bool) -> None:
        for node in nodes:
            if isinstance(node, ast.If) and _is_type_checking(node):
                if not import_time:
                    visit(node.body, top)
                visit(node.orelse, top)
                continue
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name.startswith("bintrack"))
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    pkg = package.split(".")
                    base = ".".join(pkg[: len(pkg) - node.level + 1] + ([base] if base else []))
                if base.startswith("bintrack"):
                    add(base, [a.name for a in node.names])
            body_fields = ("body", "orelse", "finalbody", "handlers")
            is_def = isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
            if import_time and isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for f in body_fields:
                child = getattr(node, f, None)
                if isinstance(child, list) and child and isinstance(child[0], (ast.stmt, ast.excepthandler)):
                    visit(child, top and not is_def)

    visit(ast.parse(path.read_text()).body, True)
    found.discard(name)
    return {m for m in found if m in known}


@pytest.fixture(scope="module")
def graph() -> dict[str, dict[str, set[str]]]:
    files = module_files()
    known = set(files)
    return {kind: {name: imports(path, name, known, import_time=kind == "import_time") for name, path in files.items()}
            for kind in ("all", "import_time")}


def test_module_names_are_unique():
    names = Counter(p.name for p in LIBRARY.rglob("*.py") if p.name not in ("__init__.py", "__main__.py", "tracker.py"))
    assert [n for n, c in names.items() if c > 1] == []


def test_layers_import_only_layers_above(graph):
    wrong = sorted(f"{a} -> {b}" for a, targets in graph["all"].items() for b in targets if rank(b) > rank(a))
    assert wrong == []


def test_services_never_import_the_command_line(graph):
    wrong = sorted(f"{a} -> {b}" for a, targets in graph["all"].items() if a.startswith("bintrack.services")
                   for b in targets if b.startswith("bintrack.cli"))
    assert wrong == []


def test_no_import_cycle_at_import_time(graph):
    edges = graph["import_time"]
    sys.setrecursionlimit(10_000)
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def dfs(node: str, stack: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(edges[node]):
            # a package's __init__ importing its own submodules is how packages load, not a cycle
            if nxt.startswith(node + "."):
                continue
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                dfs(nxt, [*stack, nxt])
        state[node] = 2

    for node in sorted(edges):
        if node not in state:
            dfs(node, [node])
    assert cycles == []


def test_the_checker_sees_a_cycle(tmp_path):
    """The import reader finds module-level imports and skips TYPE_CHECKING ones (so the cycle
    test above can fail)."""
    a = tmp_path / "a.py"
    a.write_text("from typing import TYPE_CHECKING\nfrom bintrack.b import x\nif TYPE_CHECKING:\n    from bintrack.c import y\n"
                 "def f():\n    from bintrack.d import z\n")
    known = {"bintrack.a", "bintrack.b", "bintrack.c", "bintrack.d"}
    assert imports(a, "bintrack.a", known, import_time=True) == {"bintrack.b"}
    assert imports(a, "bintrack.a", known, import_time=False) == {"bintrack.b", "bintrack.c", "bintrack.d"}
