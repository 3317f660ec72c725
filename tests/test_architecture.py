"""The package's architecture stays as docs/data_model.md and the README describe it.

- The layers contract in pyproject.toml (import-linter): each sub-package imports only the
  ones below it, so the CLI is a leaf and the library never drives it.
- No import cycles between the package's modules, and no function-local imports between them
  (they hid a cycle batch -> workflow -> cli -> batch); optional heavy dependencies (fmpy,
  matplotlib, dask, netCDF4) may still be deferred.
- Nothing in the repository points at files outside it.
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "sysid"


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _own_imports(path: Path):
    """Yield ``(module imported, is_top_level, line)`` for every import of ``sysid.*``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    top_level = {id(node) for node in tree.body}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            if name == "sysid" or name.startswith("sysid."):
                yield name, id(node) in top_level, node.lineno


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in PACKAGE.rglob("*.py")}


def test_layers_contract_holds():
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) \
        or shutil.which("lint-imports")
    if exe is None:
        pytest.fail("lint-imports (import-linter, a test dependency) is not installed")
    run = subprocess.run([exe, "--config", str(ROOT / "pyproject.toml")], cwd=ROOT,
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


def test_no_function_local_imports_between_own_modules():
    local = [f"{p.relative_to(ROOT)}:{line} imports {name}"
             for p in PACKAGE.rglob("*.py")
             for name, top, line in _own_imports(p) if not top]
    assert not local, "function-local imports of the package's own modules:\n" + "\n".join(local)


def test_no_import_cycles():
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        targets = set()
        for imported, _, _ in _own_imports(path):
            # `from sysid.x import y` names module sysid.x.y when it exists, else sysid.x.
            target = imported if imported in modules else imported.rsplit(".", 1)[0]
            if target in modules and target != name:
                targets.add(target)
        graph[name] = targets
    # A package's __init__ importing its own submodules is how it re-exports them, and a
    # submodule importing its package's __init__ is then a cycle: report every cycle found.
    state: dict[str, int] = {}
    cycles = []

    def visit(node, stack):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join(stack[stack.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


#: Names of files outside the repository that older versions cited (the workspace's shared
#: folder and its reference texts), joined here so that this file does not cite them itself.
NEEDLES = tuple("".join(parts) for parts in (("..", "/shared"), ("shared", "/reference"),
                                             ("DESIGN", ".md"), ("paper", ".md"),
                                             ("helicopter", ".md")))


def test_nothing_refers_outside_the_repository():
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True)
    if tracked.returncode != 0:
        pytest.skip("not a git checkout")
    offenders = []
    for rel in tracked.stdout.split():
        path = ROOT / rel
        if path.suffix not in {".py", ".md", ".toml", ".c", ".h", ".csv", ".txt", ""} \
                or not path.is_file() or rel == "tests/test_architecture.py":
            continue
        text = path.read_text(errors="replace")
        for needle in NEEDLES:
            if needle in text:
                offenders.append(f"{rel}: {needle}")
    assert not offenders, "references to files outside the repository:\n" + "\n".join(offenders)
