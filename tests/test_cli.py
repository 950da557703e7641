"""The command line: the demo runs end to end; bad input is one line, exit 2.

The commands run in this process through :func:`ase_mlg.cli.main` (output
captured by pytest, files in a temporary directory), except one smoke test
per command that runs the installed ``ase-mlg`` in a process of its own
(the demo's on a terminal: its progress bars need one).
"""

import inspect
import io
import json
import os
import re
import subprocess
import sys

import pytest

import ase_mlg
from ase_mlg.cli import _parser, demo, main


def _main(*argv):
    """``ase-mlg ARGV`` in this process: its exit status, returned by
    :func:`main` or raised by argparse (``-h``, ``--version``, bad usage)."""
    try:
        return main(list(argv))
    except SystemExit as exc:
        return 0 if exc.code is None else exc.code


def test_demo_runs_and_reports():
    rec = demo(natoms=500, steps=30, out=io.StringIO(), md_steps=20)
    assert rec["monotone"]
    assert set(rec["sweeps"]) == {"mean", "min", "max"} and 7 in rec["template_quality"]
    assert rec["template_quality"][7] > 0.95


def test_cli_bad_argument_is_one_line(capfd):
    assert _main("demo", "--natoms", "-3") == 2
    err = capfd.readouterr().err
    assert "natoms" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_main_returns_zero():
    assert main(["demo", "--natoms", "100", "--steps", "2"]) == 0


def test_demo_md_agrees_with_ase():
    md = demo(natoms=256, steps=2, out=io.StringIO(), md_steps=30)["md"]
    assert md["energy_rel_diff"] < 1e-10
    assert abs(md["drift"]) < 1e-4
    # the demo validates its own trajectory against MDAnalysis and ASE
    check = md["trajectory"]
    assert check["rdf_identical"]
    assert check["nl_identical"]
    assert check["verdict"] == "PASS"


def test_demo_says_what_it_does_before_the_slow_steps(monkeypatch):
    """Each slow step (building the grid, the MD's first force call, which
    loads the compiled kernels, and the trajectory's RDF) starts right after
    a line of narration is written, not before."""
    from ase_mlg import MLG, MLGCalculator
    from ase_mlg.analysis import RDF
    events = []

    class Narration(io.StringIO):
        def write(self, text):
            events.append("say")
            return super().write(text)

    def logged(name, func):
        def call(*args, **kwargs):
            events.append(name)
            return func(*args, **kwargs)
        return call

    monkeypatch.setattr(MLG, "from_atoms", logged("grid", MLG.from_atoms))
    monkeypatch.setattr(MLGCalculator, "calculate",
                        logged("md", MLGCalculator.calculate))
    monkeypatch.setattr(RDF, "run", logged("rdf", RDF.run))
    demo(natoms=256, steps=20, out=Narration(), md_steps=10)
    for step in ("grid", "md", "rdf"):
        assert step in events
        assert events[events.index(step) - 1] == "say", (step, events)


# --------------------------------------------------------------------------
# the CLI a newcomer meets (issue 12, item 6)
# --------------------------------------------------------------------------

def test_bare_command_lists_commands(capfd):
    assert _main() == 0
    out, err = capfd.readouterr()
    for command in ("demo", "rdf", "tradeoff"):
        assert f"\n    {command} " in out
    assert "--version" in out and err == ""


def test_version(capfd):
    from importlib.metadata import version
    assert _main("--version") == 0
    assert capfd.readouterr().out.strip() == f"ase-mlg {ase_mlg.__version__}"
    assert ase_mlg.__version__ == version("ase-mlg")


def test_unknown_command_is_one_line(capfd):
    assert _main("demolish") == 2
    err = capfd.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "demolish" in err


@pytest.mark.parametrize("command", ["demo", "tradeoff"])
def test_every_option_has_help(command, capfd):
    parser = _parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert sub.choices.keys() >= {"demo", "rdf", "tradeoff"}
    for p in (parser, sub.choices[command]):
        for action in p._actions:
            if action.dest == "command":
                continue
            assert action.help and len(action.help) > 8, \
                f"{command}: {action.option_strings or action.dest} has no help"
            # a stated default is the real one
            if "%(default)s" in (action.help or ""):
                assert action.default is not None
    assert _main(command, "-h") == 0
    assert "default" in capfd.readouterr().out


def test_tradeoff_skin_default_is_the_calculators():
    from ase_mlg.calculator import MLGCalculator
    calc_skin = inspect.signature(MLGCalculator.__init__).parameters["skin"].default
    args = _parser().parse_args(["tradeoff"])
    assert float(args.skin) == calc_skin == 1.0
    assert args.scene is None and args.structure is None and args.cutoff is None


def test_tradeoff_runs_with_defaults(capfd):
    """No scene, no cutoff: the LJ argon liquid at rc = 2.5 sigma (a small
    one and one timed repeat here, to stay fast), MD with the calculator's
    skin."""
    assert _main("tradeoff", "--natoms", "256", "--repeats", "1", "--widths", "3,5",
                 "--md", "3", "--json") == 0
    meta = json.loads(capfd.readouterr().out)["meta"]
    assert meta["scene"] == "liquid"
    assert meta["cutoff"] == pytest.approx(2.5 * 3.405)
    assert "LennardJones" in meta["potential"]
    assert meta["skin"] == 1.0
    assert meta["md_steps"] == 3
    # Morse's default cutoff is ASE's, 2.7 r0
    assert _main("tradeoff", "--natoms", "256", "--repeats", "1", "--widths", "3",
                 "--potential", "morse", "--json") == 0
    assert json.loads(capfd.readouterr().out)["meta"]["cutoff"] == pytest.approx(2.7 * 2.55)


def test_tradeoff_bad_default_override_is_one_line(capfd):
    assert _main("tradeoff", "--sigma", "-1") == 2
    err = capfd.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--sigma" in err


DEMO = ("demo", "--natoms", "256", "--steps", "20", "--md-steps", "10")


def test_demo_draws_no_bars_into_a_pipe(capfd):
    """Exit status 0 (the demo's own checks passed: a failed verdict
    raises) and no progress bars (tqdm's or MDAnalysis's) when not a
    terminal."""
    assert _main(*DEMO) == 0
    out, err = capfd.readouterr()
    assert "LJ argon liquid" in out  # the narration went to stdout
    for stream in (out, err):
        assert "\r" not in stream and "%|" not in stream and "it/s" not in stream


# --------------------------------------------------------------------------
# one smoke test per command: the installed script in a process of its own
# --------------------------------------------------------------------------

def _command():
    """The installed ``ase-mlg`` script of this Python's environment (the
    module where there is none, e.g. an uninstalled checkout)."""
    exe = os.path.join(os.path.dirname(sys.executable), "ase-mlg")
    return [exe] if os.path.isfile(exe) else [sys.executable, "-m", "ase_mlg.cli"]


def _cli(*args, cwd, timeout=300):
    """Run ``ase-mlg ARGS`` in ``cwd`` with output to pipes: not a terminal."""
    return subprocess.run(_command() + list(args), capture_output=True, cwd=cwd,
                          text=True, timeout=timeout, stdin=subprocess.DEVNULL)


def _rdf_smoke():
    from MDAnalysisTests import datafiles
    return ("rdf", datafiles.PSF_TRICLINIC, datafiles.DCD_TRICLINIC, "--select", "name OH2",
            "--exclude-self", "--rmax", "8", "--nbins", "16", "--stop", "3")


def _rdf_ok(out):
    rows = [line.split() for line in out.splitlines() if line and not line.startswith("#")]
    return len(rows) == 16 and all(len(r) == 3 for r in rows)


SMOKE = {  # command -> (its arguments, a check of its stdout)
    "rdf": (_rdf_smoke, _rdf_ok),
    "tradeoff": (lambda: ("tradeoff", "--natoms", "256", "--repeats", "1", "--widths", "3",
                          "--json"),
                 lambda out: json.loads(out)["meta"]["scene"] == "liquid"),
    "info": (lambda: ("info",),
             lambda out: out.startswith(f"ase-mlg {ase_mlg.__version__} ")
             and "threading layer: " in out),
}


def test_every_command_has_a_smoke_test():
    sub = next(a for a in _parser()._actions if a.dest == "command")
    assert set(sub.choices) == set(SMOKE) | {"demo"}  # demo's: on a terminal, below


@pytest.mark.parametrize("command", sorted(SMOKE))
def test_installed_command_runs(command, tmp_path):
    argv, ok = SMOKE[command]
    res = _cli(*argv(), cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "Traceback" not in res.stderr
    assert ok(res.stdout), res.stdout[-3000:]
    assert list(tmp_path.iterdir()) == []  # it wrote no file


def test_demo_draws_progress_bars_on_a_terminal(tmp_path):
    """The demo's smoke test: the installed script on a terminal."""
    import pty
    import select
    import fcntl
    import struct
    import termios
    master, slave = pty.openpty()
    # a terminal 100 columns wide (a fresh pty has size 0 x 0)
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 100, 0, 0))
    cmd = _command() + list(DEMO)
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=slave,
                            stderr=slave, close_fds=True, cwd=tmp_path)
    os.close(slave)
    chunks = []
    while True:
        ready, _, _ = select.select([master], [], [], 1.0)
        if ready:
            try:
                data = os.read(master, 65536)
            except OSError:  # the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        elif proc.poll() is not None:
            break
    proc.wait(timeout=300)
    os.close(master)
    text = b"".join(chunks).decode(errors="replace")
    assert proc.returncode == 0, text[-2000:]  # a failed verdict raises
    # the bars, told apart by their labels: ours (tqdm's) for the walk and
    # the MD, MDAnalysis's (no label) for both RDF runs of the trajectory check
    bars = [s.strip() for s in re.split("[\r\n]", text) if "%|" in s]
    assert any(b.startswith("moving atoms") for b in bars)
    assert any(b.startswith("NVE MD (5 fs)") for b in bars)
    unlabelled = [b for b in bars if not b.startswith(("moving atoms", "NVE MD (5 fs)"))]
    assert len(unlabelled) >= 2
    assert list(tmp_path.iterdir()) == []  # the demo's trajectory went with it
