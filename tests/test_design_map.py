"""docs/design.md §1's module map is the package's real import graph.

The map is the table of §1: one row a module (``name.py``, the package's
own ``__init__.py``) or a subpackage (``name/``, all its modules), low
layers first.  The doc claims that a module imports only from the rows
above its own (a subpackage's modules also import each other), that a
range of rows it names (the core) never imports ASE, and it names the rows
that do.  Here: every module of the package is in exactly one row and every
row is in the package, and these claims hold on the imports
``tests/test_layout.py`` reads from the source (any depth, relative and
absolute).  ``test_layout.py`` checks the graph for circles; this file
checks it against the doc.
"""

import ast
import re

import pytest

from test_layout import PACKAGE, ROOT, _graph, _modules

DESIGN = ROOT / "docs" / "design.md"
# the claims of §1 this file checks, as the doc words them
ORDER_RULE = "a module imports only from the rows above its own in this table"
# "The core, from `geometry.py` to `verletlist.py` except `scenes.py` and
# `potentials.py`, never imports ASE: ... The layout:" (the rows that import
# ASE are named in the rest of that text)
ASE_RULE = re.compile(r"The core, from `([^`]+)` to `([^`]+)` except "
                      r"((?:`[^`]+`(?:, | and )?)+), never imports ASE(.*?)The layout:")
ROW = re.compile(r"\| `(__init__\.py|[a-z_][a-z0-9_]*\.py|[a-z_][a-z0-9_]*/)` \| [^|]+ \|")


def _section(text):
    """§1 of the design text: from its heading to the next one."""
    parts = re.split(r"^## ", text, flags=re.M)
    (sec,) = [p for p in parts if p.startswith("§1 ")]
    return sec


def parse_map(text):
    """The rows of §1's module map, in order.  Strict: the section holds
    one table, ``| module | holds |``, and each of its rows is one
    backticked module or subpackage and its description."""
    lines = _section(text).splitlines()
    table = [k for k, line in enumerate(lines) if line.startswith("|")]
    assert table, "§1 has no module map"
    assert table == list(range(table[0], table[-1] + 1)), "§1 holds one table"
    head, rule, *rows = (lines[k] for k in table)
    assert head == "| module | holds |" and rule == "|---|---|", (head, rule)
    names = []
    for line in rows:
        m = ROW.fullmatch(line)
        assert m, f"not a module-map row: {line!r}"
        names.append(m.group(1))
    assert len(set(names)) == len(names), "a row is listed twice"
    return names


def _row_of(modules, rows):
    """module name -> index of the map row holding it."""
    index = {}
    for k, row in enumerate(rows):
        if row == "__init__.py":
            index[k] = ["ase_mlg"]
        elif row.endswith(".py"):
            index[k] = [f"ase_mlg.{row[:-3]}"]
        else:
            pkg = f"ase_mlg.{row[:-1]}"
            index[k] = [m for m in modules if m == pkg or m.startswith(pkg + ".")]
    out = {}
    for k, mods in index.items():
        for m in mods:
            assert m not in out, f"{m} is in two rows"
            out[m] = k
    return out, index


def _text():
    return DESIGN.read_text(encoding="utf-8")


def _flat(text):
    return " ".join(_section(text).split())


def test_parser_is_strict():
    good = ("## §1 Data flow\n\ntext\n\n| module | holds |\n|---|---|\n"
            "| `geometry.py` | cells |\n| `md/` | integrators |\n\nmore\n\n## §2 x\n")
    assert parse_map(good) == ["geometry.py", "md/"]
    for bad in (good.replace("`md/`", "md/"),                      # not backticked
                good.replace("`md/`", "`md`"),                     # neither .py nor /
                good.replace("| integrators |", "| integrators"),  # broken row
                good.replace("| `md/` |", "| `geometry.py` |"),     # listed twice
                good.replace("|---|---|\n", "|---|---|\n\n"),      # two tables
                good.replace("| module | holds |\n|---|---|\n", "")):  # no header
        with pytest.raises(AssertionError):
            parse_map(bad)


def test_every_module_is_in_the_map_once_and_every_row_is_a_module():
    rows = parse_map(_text())
    modules = _modules()
    row_of, index = _row_of(modules, rows)
    assert sorted(set(modules) - set(row_of)) == [], "modules missing from the map"
    assert sorted(m for m in row_of if m not in modules) == [], "rows of no module"
    assert [rows[k] for k, mods in index.items() if not mods] == [], "empty rows"
    for row in rows:  # a package row is a package, a module row a module
        path = PACKAGE / row / "__init__.py" if row.endswith("/") else PACKAGE / row
        assert path.is_file(), row


def test_modules_import_only_rows_above_their_own():
    text = _text()
    assert ORDER_RULE in _flat(text)  # the claim checked here is the doc's
    rows = parse_map(text)
    graph = _graph()
    row_of, _ = _row_of(graph, rows)
    wrong = []
    for m, deps in sorted(graph.items()):
        for t in sorted(deps):
            same_package = row_of[t] == row_of[m] and rows[row_of[m]].endswith("/")
            if not (row_of[t] < row_of[m] or same_package):
                wrong.append(f"{m} ({rows[row_of[m]]}) imports {t} ({rows[row_of[t]]})")
    assert wrong == [], "imports against the map's order:\n" + "\n".join(wrong)


def _imports_ase(path):
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level:
            names = [node.module or ""]
        else:
            continue
        if any(n == "ase" or n.startswith("ase.") for n in names):
            return True
    return False


def test_only_the_rows_named_import_ase():
    text = _text()
    m = ASE_RULE.search(_flat(text))
    assert m, "§1 states which modules import ASE"
    first, last, excepted, rest = m.groups()
    rows = parse_map(text)
    excepted = re.findall(r"`([^`]+)`", excepted)
    assert {first, last, *excepted} <= set(rows)
    core = set(rows[rows.index(first):rows.index(last) + 1]) - set(excepted)
    modules = _modules()
    row_of, _ = _row_of(modules, rows)
    ase_rows = {rows[row_of[mod]] for mod, path in modules.items() if _imports_ase(path)}
    assert "calculator.py" in ase_rows  # the scan sees ASE where it is imported
    assert sorted(ase_rows & core) == [], "the core imports ASE"
    named = set(re.findall(r"`([^`]+)`", rest))
    assert sorted(ase_rows - named) == [], "rows that import ASE, not named in §1"
