"""The package's house rules, checked on its source (docs/design.md §1).

Data flows one way (positions -> geometry -> grid -> query -> neighbour
list | potentials | RDF), so the package's import graph has no cycle; no
module outgrows one idea (800 lines); the command line is a leaf that no
library module imports; the repository names no machine-local path.
"""

import ast
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "ase_mlg"
MAX_LINES = 800


def _module_name(path):
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules():
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _imports(name, path, known):
    """Package modules that ``name`` imports, at any depth of its code
    (imports inside functions count: they run too)."""
    is_package = path.name == "__init__.py"
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                base = base[:len(base) - node.level + (1 if is_package else 0)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            # `from . import x` and `from .cli import rdf` may name modules:
            # then the module, else a name that ``mod`` itself defines
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in known else mod
                       for a in node.names]
        else:
            continue
        for t in targets:
            # the deepest package module the name refers to
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def _graph():
    mods = _modules()
    return {m: _imports(m, p, mods) for m, p in mods.items()}


def _cycle(graph):
    """One import cycle as a list of modules, or None (depth-first search;
    a package's own ``__init__`` importing its submodules is not a cycle
    unless a submodule imports the package back)."""
    state = {}
    stack = []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return stack[stack.index(n):] + [n]
            if n not in state:
                found = visit(n)
                if found:
                    return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def test_import_graph_has_no_cycle():
    graph = _graph()
    assert len(graph) > 20  # the walk found the package
    assert {"ase_mlg.geometry", "ase_mlg.sweeps"} <= graph["ase_mlg.grid"]
    cycle = _cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_imports_are_read_as_python_resolves_them(tmp_path):
    """Relative and absolute imports, at any depth; ``from P import x``
    imports the module P.x where there is one, else P itself."""
    (tmp_path / "sub").mkdir()
    path = tmp_path / "sub" / "mod.py"
    path.write_text("from .. import grid, __version__\n"
                    "from . import other\n"
                    "def f():\n"
                    "    import ase_mlg.query\n"
                    "    from ..blocks import BlockIndex\n")
    known = {"ase_mlg", "ase_mlg.grid", "ase_mlg.query", "ase_mlg.blocks",
             "ase_mlg.sub", "ase_mlg.sub.mod", "ase_mlg.sub.other"}
    assert _imports("ase_mlg.sub.mod", path, known) == {
        "ase_mlg", "ase_mlg.grid", "ase_mlg.sub.other", "ase_mlg.query", "ase_mlg.blocks"}
    path.write_text("from .. import grid\n")
    assert _imports("ase_mlg.sub.mod", path, known) == {"ase_mlg.grid"}


def test_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_library_never_imports_the_command_line():
    graph = _graph()
    offenders = {m: sorted(n for n in deps if n.startswith("ase_mlg.cli"))
                 for m, deps in graph.items() if not m.startswith("ase_mlg.cli")}
    assert {m: d for m, d in offenders.items() if d} == {}


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_module_holds_one_idea(path):
    n = len(path.read_text().splitlines())
    assert n <= MAX_LINES, f"{path.name}: {n} lines (split it by idea)"


def test_no_machine_local_paths():
    try:
        files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                               check=True).stdout.decode().split("\0")
    except (OSError, subprocess.CalledProcessError):
        pytest.fail("the repository's files are listed by git; run from a checkout")
    # spelled in pieces so that this file does not match itself
    patterns = ["/" + "work/", "/" + "home/", "/" + "Users/"]
    hits = []
    for f in files:
        p = ROOT / f
        if not f or not p.is_file() or p.suffix in {".png", ".json"}:
            continue
        try:
            text = p.read_text()
        except UnicodeDecodeError:
            continue
        for k, line in enumerate(text.splitlines(), 1):
            if any(s in line for s in patterns):
                hits.append(f"{f}:{k}")
    assert hits == []


# -- the house rules of issue 19: state by name, not by position ------------

MAX_PARAMETERS = 12
MAX_UNPACKED = 8
CALCULATOR_LINES = 200


def _house_rule_breaches(tree, where):
    """Functions over MAX_PARAMETERS parameters, tuples of more than
    MAX_UNPACKED fields unpacked by position, private names imported from
    another module of the package, and calls that splat a slice of a tuple
    (``f(*args[:-2])``: arguments known by position only)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            a = node.args
            n = (len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs)
                 + bool(a.vararg) + bool(a.kwarg))
            if n > MAX_PARAMETERS:
                out.append(f"{where}:{node.lineno} {getattr(node, 'name', 'lambda')} "
                           f"takes {n} parameters")
        targets = (node.targets if isinstance(node, ast.Assign)
                   else [node.target] if isinstance(node, ast.For) else [])
        for t in targets:
            if isinstance(t, ast.Tuple) and len(t.elts) > MAX_UNPACKED:
                out.append(f"{where}:{node.lineno} unpacks {len(t.elts)} fields by position")
        if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "")
                                                 .startswith("ase_mlg")):
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__"):
                    out.append(f"{where}:{node.lineno} imports private {alias.name}")
        if isinstance(node, ast.Call):
            for arg in node.args:
                if isinstance(arg, ast.Starred) and isinstance(arg.value, ast.Subscript):
                    out.append(f"{where}:{node.lineno} splats *{ast.unparse(arg.value)}")
    return out


def test_house_rules_hold():
    breaches = []
    for path in sorted(PACKAGE.rglob("*.py")):
        breaches += _house_rule_breaches(ast.parse(path.read_text()),
                                         str(path.relative_to(ROOT)))
    assert not breaches, "\n".join(breaches)
    lines = len((PACKAGE / "calculator.py").read_text().splitlines())
    assert lines <= CALCULATOR_LINES, f"calculator.py has {lines} lines"


def test_house_rules_catch_what_they_name():
    src = ("from ._x import _private\n"
           "def f(a, b, c, d, e, f, g, h, i, j, k, l, m):\n"
           "    (a, b, c, d, e, f, g, h, i) = m\n"
           "    return g(*m[:-2])\n")
    found = " | ".join(_house_rule_breaches(ast.parse(src), "x.py"))
    for what in ("private _private", "takes 13 parameters", "unpacks 9 fields", "splats *m[:-2]"):
        assert what in found, found
