"""The shape of the package: imports point one way, each room is entered by its door, and generic code names
no method.

The rooms: :mod:`hgjax.engine` (plan, tiles, runners, selection, survey, the run's composition) and
:mod:`hgjax.cli` (the command line) are packages whose modules are private; the rest of the package
imports ``hgjax.engine`` and ``hgjax.cli`` themselves (and the engine's public :mod:`hgjax.engine.select`),
never a private module of theirs. The top level holds the public face (``hgjax``, ``tiles``, ``survey``,
``samplers``, ...) and the floors every room stands on (``_validate``, ``_method``, ``_names``, ...)."""

import ast
import importlib
import pathlib

import pytest

import hgjax

PACKAGE = pathlib.Path(hgjax.__file__).parent
ROOMS = ("hgjax.engine", "hgjax.cli")
GENERIC = sorted([str(p.relative_to(PACKAGE)) for room in ("engine", "cli") for p in (PACKAGE / room).glob("*.py")]
                 + ["tiles.py", "survey.py", "__main__.py"])


def _module(path: pathlib.Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _doors() -> dict:
    """{room: {name: the private module that defines it}} of each room's door (its ``_EXPORTS``)."""
    return {room: _source(room) for room in ROOMS}


def _source(room: str) -> dict:
    """{name: the private module of ``room`` that defines it}, from the room's ``_EXPORTS``."""
    exports = importlib.import_module(room)._EXPORTS
    return {name: f"{room}.{module}" for module, names in exports.items() for name in names}


def _imported(tree: ast.Module) -> list:
    """The dotted names ``tree`` imports (``from a import b`` gives ``a.b`` and ``a``), and the rooms' names it
    reads through a door (``engine.run`` of ``from hgjax import engine`` gives ``hgjax.engine.run``)."""
    names, aliases = [], {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
            aliases.update((a.asname, a.name) for a in node.names if a.asname)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names += [f"{node.module}.{a.name}" for a in node.names] + [node.module]
            aliases.update((a.asname or a.name, f"{node.module}.{a.name}") for a in node.names)
    names += [f"{aliases[n.value.id]}.{n.attr}" for n in ast.walk(tree)
              if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and aliases.get(n.value.id) in ROOMS]
    return names


def _imports(path: pathlib.Path, modules: set) -> set:
    """The hgjax modules ``path`` imports, at module level or inside functions (a lazy import is still an arrow);
    a name read through a room's door is an arrow to the module that defines it."""
    me = _module(path)
    found = set()
    doors = _doors()
    for name in _imported(ast.parse(path.read_text())):
        room, _, rest = name.rpartition(".")
        if rest in doors.get(room, {}):
            name = doors[room][rest]
        while name and name not in modules:
            name = name.rpartition(".")[0]
        if name and name != me and name.startswith("hgjax"):
            found.add(name)
    return found


def _graph() -> dict:
    paths = sorted(PACKAGE.rglob("*.py"))
    modules = {_module(p) for p in paths}
    graph = {_module(p): _imports(p, modules) for p in paths}
    # a package's __init__ that imports its own submodules is their facade, not an arrow back up
    for pkg in [m for m in graph if (PACKAGE.parent / m.replace(".", "/") / "__init__.py").exists()]:
        graph[pkg] = {m for m in graph[pkg] if not m.startswith(pkg + ".")}
    return graph


def _cycle(graph: dict):
    """One import cycle of ``graph`` as a list of modules, or None. The top-level facade ``hgjax``
    (imported lazily by the command line and the evaluation for the public names) is left out."""
    graph = {m: {d for d in deps if d != "hgjax"} for m, deps in graph.items() if m != "hgjax"}
    state, stack = {}, []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state:
                found = visit(d)
                if found:
                    return found
        state[m] = 2
        stack.pop()
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def test_no_import_cycle():
    assert _cycle(_graph()) is None, " -> ".join(_cycle(_graph()))


@pytest.mark.parametrize("room", ROOMS)
def test_nothing_outside_a_room_imports_its_private_modules(room):
    """A room is entered by its door: outside ``hgjax.engine``, no module imports ``hgjax.engine._grid`` and
    the like (nor ``hgjax.cli._main`` outside ``hgjax.cli``)."""
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        me = _module(path)
        if me == room or me.startswith(room + "."):
            continue
        private = sorted({n for n in _imported(ast.parse(path.read_text())) if n.startswith(room + "._")})
        if private:
            found[me] = private
    assert not found, found


def test_the_door_check_sees_a_private_import():
    tree = ast.parse("from hgjax.engine import _grid\nfrom hgjax import engine\nengine.run(engine.Plan)\n")
    assert {"hgjax.engine._grid", "hgjax.engine.run", "hgjax.engine.Plan"} <= set(_imported(tree))


@pytest.mark.parametrize("room", ROOMS)
def test_every_name_of_a_door_is_defined_where_it_says(room):
    door, source = importlib.import_module(room), _source(room)
    missing = sorted(n for n, module in source.items() if not hasattr(importlib.import_module(module), n))
    assert not missing and sorted(door.__all__) == sorted(source), missing


def test_the_cycle_check_finds_a_cycle():
    assert _cycle({"hgjax.a": {"hgjax.b"}, "hgjax.b": {"hgjax.c"}, "hgjax.c": {"hgjax.a"}}) == [
        "hgjax.a", "hgjax.b", "hgjax.c", "hgjax.a"]


def _code_strings(path: pathlib.Path) -> list:
    """The string constants of ``path`` outside docstrings."""
    tree = ast.parse(path.read_text())
    docs = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docs.add(id(body[0].value))
    return [n.value for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs]


@pytest.mark.parametrize("name", GENERIC)
def test_generic_code_names_no_method(name):
    """A capability is declared by the method (its entry's ``tiling``, ``bytes_per_sample``, ...): generic
    code never asks for a method by name or branches on its neighbourhood kind."""
    path = PACKAGE / name
    named = sorted({s for s in _code_strings(path) if s in hgjax.METHODS})
    assert not named, f"{name} names methods {named}"
    kinds = [n.lineno for n in ast.walk(ast.parse(path.read_text()))
             if isinstance(n, ast.Attribute) and n.attr == "kind" and not isinstance(n.ctx, ast.Store)]
    assert not kinds, f"{name} reads a method's kind at lines {kinds}"


def test_the_name_check_sees_code_strings(tmp_path):
    src = tmp_path / "m.py"
    src.write_text('"""Mentions "hkc" in a docstring."""\n\ndef f(m):\n    """As "ea" does."""\n    return m == "gfr"\n')
    assert [s for s in _code_strings(src) if s in hgjax.METHODS] == ["gfr"]
