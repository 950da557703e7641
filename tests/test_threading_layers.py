"""The threading layer each user choice gets, and the warning with it
(issue 25.5 and 25.8; ase_mlg/parallel.py, docs/design.md §8).

Every check runs in a fresh interpreter (numba's layer is chosen once per
process): each value of ``NUMBA_THREADING_LAYER`` numba accepts, the same
set as ``numba.config.THREADING_LAYER`` in code before ``import ase_mlg``,
numba parallel code that started GNU OpenMP before the import, and (with
numba's ``tbbpool`` made unimportable, as on a platform without the ``tbb``
wheel) the choices that need TBB.  libtbb is loaded by full path for every
choice that can use it, so with the ``tbb`` package installed they all run
TBB; a user's choice is never replaced; GNU OpenMP, which hangs forked
workers, is said once."""

import json
import os
import subprocess
import sys
import textwrap
from importlib.metadata import PackageNotFoundError, distribution

import pytest

try:
    distribution("tbb")
    HAVE_TBB = True
except PackageNotFoundError:
    HAVE_TBB = False

needs_tbb = pytest.mark.skipif(not HAVE_TBB, reason="the tbb package is not installed")

BLOCK_TBB = "import sys; sys.modules['numba.np.ufunc.tbbpool'] = None\n"

PRANGE_FIRST = textwrap.dedent("""
    import numba, numpy as np
    @numba.njit(parallel=True)
    def total(a):
        s = 0.0
        for i in numba.prange(a.size):
            s += a[i]
        return s
    total(np.ones(10))
""")

# what the child reports: the layer numba runs and the one config() names,
# the user's choice, the warnings of the import, and show_config's text
CHILD = textwrap.dedent("""
    import io, json, sys, warnings
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        {before}
        try:
            import ase_mlg
        except ImportError as err:
            print(json.dumps({{"error": str(err)}}))
            sys.exit(0)
    import numba
    c = ase_mlg.parallel.config(probe=False)
    buf = io.StringIO()
    ase_mlg.show_config(file=buf)
    print(json.dumps({{"numba": numba.threading_layer(), "layer": c["threading_layer"],
                      "choice": c.get("user_choice"), "serialised": c["serialised"],
                      "warnings": [[w.category.__name__, str(w.message)] for w in caught],
                      "show": buf.getvalue()}}))
""")


def child(before="", layer=None):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    env["NUMBA_NUM_THREADS"] = "2"
    if layer is not None:
        env["NUMBA_THREADING_LAYER"] = layer
    code = CHILD.format(before=textwrap.indent(before, " " * 4).strip() or "pass")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, env=env)
    assert res.returncode == 0, (res.returncode, res.stderr[-3000:])
    return json.loads(res.stdout.strip().splitlines()[-1])


def fork_warning(got):
    """The one ThreadingLayerWarning about forked workers, else fail."""
    assert len(got["warnings"]) == 1, got["warnings"]
    category, text = got["warnings"][0]
    assert category == "ThreadingLayerWarning", got["warnings"]
    assert "GNU OpenMP" in text and "fork" in text and "hang" in text, text
    assert "spawn" in text, text  # what to do
    assert "fork: " in got["show"], got["show"]
    return text


CHOICES = ["default", "safe", "threadsafe", "forksafe", "tbb", "omp", "workqueue"]
# with TBB installed: the layer each choice runs
RUNS = {"default": "tbb", "safe": "tbb", "threadsafe": "tbb", "forksafe": "tbb",
        "tbb": "tbb", "omp": "omp", "workqueue": "workqueue"}


@needs_tbb
@pytest.mark.parametrize("how", ["env", "code"])
@pytest.mark.parametrize("choice", CHOICES)
def test_each_choice_runs_its_layer(choice, how):
    """Every choice numba accepts, as NUMBA_THREADING_LAYER or set in
    numba.config before the import, runs what numba gives for it with TBB
    loadable; only GNU OpenMP warns (forked workers hang)."""
    if how == "env":
        got = child(layer=choice)
    else:
        got = child(before=f"import numba; numba.config.THREADING_LAYER = {choice!r}")
    assert "error" not in got, got
    want = RUNS[choice]
    assert (got["numba"], got["layer"]) == (want, want), got
    assert got["serialised"] == (want == "workqueue"), got
    if want == "omp":
        text = fork_warning(got)
        assert ("NUMBA_THREADING_LAYER=omp" if how == "env"
                else "numba.config.THREADING_LAYER = 'omp'") in text, text
    else:
        assert got["warnings"] == [], got["warnings"]
    if choice == "default" and how == "code":
        # indistinguishable from no choice: ase-mlg chooses (TBB)
        assert got["choice"] is None, got
    else:
        assert got["choice"] == choice, got
        assert f"user choice: {choice}" in got["show"], got["show"]


def test_no_choice_runs_tbb_without_a_warning():
    got = child()
    want = "tbb" if HAVE_TBB else "workqueue"
    assert (got["numba"], got["layer"]) == (want, want), got
    if HAVE_TBB:
        assert got["warnings"] == [], got["warnings"]
        assert "user choice: none" in got["show"], got["show"]
    assert got["choice"] is None, got


def test_gnu_openmp_started_before_the_import_warns_once():
    """Issue 25.8: parallel code that ran before import ase_mlg started GNU
    OpenMP (the layer is fixed for the process); the import says, once,
    that forked workers will hang and what to do."""
    got = child(before=PRANGE_FIRST)
    assert (got["numba"], got["layer"]) == ("omp", "omp"), got
    text = fork_warning(got)
    assert "before import ase_mlg" in text and "import ase_mlg before" in text, text
    assert "started before import ase_mlg" in got["show"], got["show"]
    assert got["choice"] is None, got


@pytest.mark.parametrize("choice", ["tbb", "safe"])
def test_a_choice_that_needs_tbb_fails_in_one_line_without_it(choice):
    """Without TBB, asking for it is an ImportError naming the problem (not
    numba's 'No threading layer could be loaded', not a fallback)."""
    got = child(before=BLOCK_TBB, layer=choice)
    assert "error" in got, got
    msg = got["error"]
    assert "\n" not in msg and f"NUMBA_THREADING_LAYER={choice}" in msg, msg
    assert "TBB" in msg and "pip install tbb" in msg, msg


@pytest.mark.parametrize("choice, want, warns", [(None, "workqueue", "TBB"),
                                                 ("forksafe", "workqueue", None),
                                                 ("threadsafe", "omp", "GNU OpenMP")])
def test_without_tbb(choice, want, warns):
    """Without TBB: no choice falls back to workqueue with one warning; a
    choice is respected (numba's selection without TBB), with the fork
    warning where that is GNU OpenMP."""
    got = child(before=BLOCK_TBB, layer=choice)
    assert (got["numba"], got["layer"]) == (want, want), got
    assert got["serialised"] == (want == "workqueue"), got
    if warns is None:
        assert got["warnings"] == [], got["warnings"]
    elif want == "omp":
        fork_warning(got)
    else:
        assert len(got["warnings"]) == 1 and warns in got["warnings"][0][1], got["warnings"]
    assert got["choice"] == choice, got
