"""Numerical stability at the extremes (issue 7): the report of the tests.

Runs the extreme cases of ``tests/test_extremes.py::test_extreme`` under
pytest, collects what each measured (the ``result`` it records with
``record_property``), and writes the table ``validation/reports/extremes.md``.
From the repository root, after ``pip install -e .``::

    python validation/extremes.py

With pytest arguments (e.g. ``-k faces``) it runs those cases only and
prints their table instead of writing the report.

``EXTREMES_BIG_N`` sets the size of the big energy sum (default 1e6 atoms
here, 108,000 in the test suite).
"""

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TESTS = ROOT / "tests" / "test_extremes.py"
REPORT = ROOT / "validation" / "reports" / "extremes.md"


class Collector:
    """pytest plugin: one row (group, extreme, status, details, seconds) per
    ``test_extreme`` case, from the properties the test records."""

    def __init__(self):
        self.rows = []

    def pytest_runtest_logreport(self, report):
        props = dict(report.user_properties)
        if report.when != "call" or "extreme" not in props:
            return
        group, name = props["extreme"]
        if report.passed:
            details = props["result"]
            status = "clear error" if details.startswith("clear error") else "pass"
        else:  # failed, or xfailed (a known failure)
            status = "FAILURE"
            crash = getattr(report.longrepr, "reprcrash", None)
            details = " ".join(str(crash.message if crash else report.longrepr).split())[:300]
            if hasattr(report, "wasxfail"):
                details += " -- known: " + report.wasxfail
        self.rows.append((group, name, status, details, report.duration))


def markdown(rows):
    """The report: how to regenerate it, a summary, one table row a case."""
    count = {s: sum(r[2] == s for r in rows) for s in ("pass", "clear error", "FAILURE")}
    lines = [
        "# Numerical stability at the extremes (issue 7)",
        "",
        "Regenerate (repository root, after `pip install -e .`; EXTREMES_BIG_N sets "
        "the size of the big energy sum, default 1e6 atoms):",
        "",
        "    python validation/extremes.py",
        "",
        "Every extreme tried, compared with ASE (`ase.neighborlist.neighbor_list`, "
        "`ase.calculators.lj.LennardJones`) or brute force.  Result: **pass** "
        "(agrees), **clear error** (a `ValueError`/`TypeError` naming the argument "
        "or atom, no numba traceback), or **FAILURE** (details).  Each row is a case "
        "of `tests/test_extremes.py::test_extreme` (defined in `tests/extreme_cases.py` "
        "and `tests/bad_input_cases.py`); details are what it measured.",
        "",
        f"Summary: {len(rows)} checks: {count['pass']} pass, {count['clear error']} "
        f"clear error, {count['FAILURE']} failure (a failure fails the test suite too; "
        "its details are in its row).",
        "",
        "| group | extreme | result | details | time (s) |",
        "|---|---|---|---|---|",
    ]
    for group, name, status, details, seconds in rows:
        details = details.replace("|", "\\|")
        lines.append(f"| {group} | {name} | {status} | {details} | {seconds:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    args = sys.argv[1:] if argv is None else argv
    os.environ.setdefault("EXTREMES_BIG_N", "1000000")
    collector = Collector()
    code = pytest.main([f"{TESTS}::test_extreme", "-q", "-p", "no:cacheprovider",
                        *args], plugins=[collector])
    if not collector.rows:
        return int(code) or 1
    if args:
        print(markdown(collector.rows))
    else:
        REPORT.write_text(markdown(collector.rows))
        print(f"wrote {REPORT.relative_to(ROOT)} ({len(collector.rows)} cases)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
