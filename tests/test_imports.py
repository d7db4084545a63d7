"""Who imports whom, read from the source (ast): no import circle anywhere, and imports flow one way
between the rooms — ``neuenh`` <- ``storage`` <- ``orchestrator`` <- ``workers`` <- ``api`` <- ``cli``
(the rooms that start things may use the ones before them) — with the heavy dependencies where they
belong: ``neuenh`` imports neither Ray, FastAPI (nor its server) nor SQL; only ``workers`` imports
Ray; only ``api`` imports FastAPI.

Every import counts, a lazy one inside a function too: a circle hidden in a function is still a
circle. ``from package import name`` is an edge to ``package.name`` when that is a module, else to
``package``; importing a module is not counted as importing its parent packages (an ``__init__``
that imports its own submodules is no circle).
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# room -> (folder, importable name); in import order: a room may import only rooms before it
ROOMS = {"neuenh": (ROOT / "neuenh", "neuenh"),
         "storage": (ROOT / "storage", "neuenh_service.storage"),
         "orchestrator": (ROOT / "orchestrator", "neuenh_service.orchestrator"),
         "workers": (ROOT / "workers", "neuenh_service.workers"),
         "api": (ROOT / "api", "neuenh_service.api"),
         "cli": (ROOT / "cli", "neuenh_service.cli")}
# third-party packages a room must not import
FORBIDDEN = {"neuenh": {"ray", "fastapi", "starlette", "uvicorn", "sqlite3"},
             "storage": {"ray", "fastapi", "starlette", "uvicorn"},
             "orchestrator": {"ray", "fastapi", "starlette", "uvicorn"},
             "workers": {"fastapi", "starlette", "uvicorn", "sqlite3"},
             "api": {"ray"},
             "cli": {"ray", "fastapi", "starlette"}}


@functools.cache
def modules() -> dict[str, tuple[str, Path]]:
    """Importable module name -> (room, file) of every module of every room."""
    out = {}
    for room, (folder, name) in ROOMS.items():
        for path in sorted(folder.rglob("*.py")):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join([name, *parts])] = (room, path)
    return out


def imports_of(module: str, path: Path, known: set[str]) -> tuple[set[str], set[str]]:
    """(the project's modules ``module`` imports, the top-level names of everything it imports)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    internal, top = set(), set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            names = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base for alias in node.names]
        else:
            continue
        for name in names:
            top.add(name.split(".")[0])
            while name and name not in known:  # ``import a.b.c``: the deepest of the project's modules
                name = name.rpartition(".")[0]
            if name and name != module:
                internal.add(name)
    return internal, top


@functools.cache
def graph() -> dict[str, tuple[set[str], set[str]]]:
    """Module -> ``imports_of`` it, read once by the process that runs these tests (not at collection)."""
    known = set(modules())
    return {name: imports_of(name, path, known) for name, (_, path) in modules().items()}


def test_the_graph_sees_the_rooms():
    """The walk finds what it must: every room, and an edge known to exist."""
    rooms = {room for room, _ in modules().values()}
    assert rooms == set(ROOMS)
    assert "neuenh.params" in graph()["neuenh.materials"][0]


def test_no_import_circle():
    """Depth-first search for a back edge; the circle found is named in full."""
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []

    def visit(name: str) -> None:
        state[name] = 1
        stack.append(name)
        for target in sorted(graph()[name][0]):
            if state.get(target) == 1:
                circle = stack[stack.index(target):] + [target]
                pytest.fail("import circle: " + " -> ".join(circle))
            if target not in state:
                visit(target)
        stack.pop()
        state[name] = 2

    for name in sorted(graph()):
        if name not in state:
            visit(name)


@pytest.mark.parametrize("room", ROOMS)
def test_imports_flow_one_way_between_rooms(room):
    order = list(ROOMS)
    where = modules()
    wrong = sorted(f"{name} imports {target}" for name, (internal, _) in graph().items() if where[name][0] == room
                   for target in internal if order.index(where[target][0]) > order.index(room))
    assert not wrong, f"{room} imports a room after it: {wrong}"
    heavy = sorted(f"{name} imports {top}" for name, (_, tops) in graph().items() if where[name][0] == room
                   for top in tops & FORBIDDEN[room])
    assert not heavy, f"{room} imports what it must not: {heavy}"
