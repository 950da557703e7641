"""Narration for the test session (issue 18.6).

Collecting the tests imports ase-mlg and ASE's and MDAnalysis's test
files, and on a first run the first tests compile the numba kernels (then
cached on disk): tens of seconds in which pytest alone prints nothing.  One
line says so when the session starts and one how long collection took.
"""

import time

_START = [0.0]


def _say(session, text):
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.write_line(text)


def pytest_sessionstart(session):
    _START[0] = time.perf_counter()
    _say(session, "ase-mlg: collecting; the first tests compile the package's numba "
                  "kernels on a first run (a minute or more before the first dots; "
                  "later runs load them from the disk cache) ...")


def pytest_collection_finish(session):
    _say(session, f"ase-mlg: {len(session.items)} tests collected in "
                  f"{time.perf_counter() - _START[0]:.0f} s")
