"""The shape of the package: imports point one way, and generic code names no method."""

import ast
import pathlib

import pytest

import hgjax

PACKAGE = pathlib.Path(hgjax.__file__).parent
GENERIC = ["engine.py", "tiles.py", "_tiling.py", "select.py", "cli.py", "_cli_common.py", "_cli_batch.py",
           "_cli_survey.py", "_cli_compare.py", "_cli_signals.py", "__main__.py", "survey.py", "pipeline.py"]


def _module(path: pathlib.Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: pathlib.Path, modules: set) -> set:
    """The hgjax modules ``path`` imports, at module level or inside functions (a lazy import is still an arrow)."""
    me = _module(path)
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
        else:
            continue
        for name in names:
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
