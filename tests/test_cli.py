"""The command line: the demo runs end to end; bad input is one line, exit 2."""

import io
import re
import subprocess
import sys

from ase_mlg.cli import demo, main


def test_demo_runs_and_reports():
    rec = demo(natoms=500, steps=30, out=io.StringIO(), md_steps=20)
    assert rec["monotone"]
    assert set(rec["sweeps"]) == {"mean", "min", "max"} and 7 in rec["template_quality"]
    assert rec["template_quality"][7] > 0.95


def test_cli_bad_argument_is_one_line():
    res = subprocess.run([sys.executable, "-m", "ase_mlg.cli", "demo", "--natoms", "-3"],
                         capture_output=True, text=True)
    assert res.returncode == 2
    assert "natoms" in res.stderr and "Traceback" not in res.stderr


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
# the CLI a newcomer meets (issue 12, item 6): subprocess tests
# --------------------------------------------------------------------------

import inspect  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402

import pytest  # noqa: E402

import ase_mlg  # noqa: E402


def _command():
    """The installed ``ase-mlg`` script of this Python's environment (the
    module where there is none, e.g. an uninstalled checkout)."""
    exe = os.path.join(os.path.dirname(sys.executable), "ase-mlg")
    return [exe] if os.path.isfile(exe) else [sys.executable, "-m", "ase_mlg.cli"]


def _cli(*args, timeout=300):
    """Run ``ase-mlg ARGS`` with output to pipes: not a terminal."""
    return subprocess.run(_command() + list(args), capture_output=True,
                          text=True, timeout=timeout, stdin=subprocess.DEVNULL)


def test_bare_command_lists_commands():
    res = _cli()
    assert res.returncode == 0, res.stderr
    for command in ("demo", "rdf", "tradeoff"):
        assert f"\n    {command} " in res.stdout
    assert "--version" in res.stdout and res.stderr == ""


def test_version():
    from importlib.metadata import version
    res = _cli("--version")
    assert res.returncode == 0
    assert res.stdout.strip() == f"ase-mlg {ase_mlg.__version__}"
    assert ase_mlg.__version__ == version("ase-mlg")


def test_unknown_command_is_one_line():
    res = _cli("demolish")
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "demolish" in res.stderr


@pytest.mark.parametrize("command", ["demo", "tradeoff"])
def test_every_option_has_help(command):
    from ase_mlg.cli import _parser
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
    res = _cli(command, "-h")
    assert res.returncode == 0 and "default" in res.stdout


def test_tradeoff_skin_default_is_the_calculators():
    from ase_mlg.calculator import MLGCalculator
    from ase_mlg.cli import _parser
    calc_skin = inspect.signature(MLGCalculator.__init__).parameters["skin"].default
    args = _parser().parse_args(["tradeoff"])
    assert float(args.skin) == calc_skin == 1.0
    assert args.scene is None and args.structure is None and args.cutoff is None


def test_tradeoff_runs_with_defaults():
    """No scene, no cutoff: the LJ argon liquid at rc = 2.5 sigma (a small
    one and one timed repeat here, to stay fast), MD with the calculator's
    skin."""
    res = _cli("tradeoff", "--natoms", "256", "--repeats", "1", "--widths", "3,5",
               "--md", "3", "--json")
    assert res.returncode == 0, res.stderr
    meta = json.loads(res.stdout)["meta"]
    assert meta["scene"] == "liquid"
    assert meta["cutoff"] == pytest.approx(2.5 * 3.405)
    assert "LennardJones" in meta["potential"]
    assert meta["skin"] == 1.0
    assert meta["md_steps"] == 3
    # Morse's default cutoff is ASE's, 2.7 r0
    res = _cli("tradeoff", "--natoms", "256", "--repeats", "1", "--widths", "3",
               "--potential", "morse", "--json")
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["meta"]["cutoff"] == pytest.approx(2.7 * 2.55)


def test_tradeoff_bad_default_override_is_one_line():
    res = _cli("tradeoff", "--sigma", "-1")
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "--sigma" in res.stderr


DEMO = ("demo", "--natoms", "256", "--steps", "20", "--md-steps", "10")


def test_demo_draws_no_bars_into_a_pipe():
    """Exit status 0 (the demo's own checks passed: a failed verdict
    raises) and no progress bars (tqdm's or MDAnalysis's) when not a
    terminal."""
    res = _cli(*DEMO)
    assert res.returncode == 0, res.stderr
    for stream in (res.stdout, res.stderr):
        assert "\r" not in stream and "%|" not in stream and "it/s" not in stream


def test_demo_draws_progress_bars_on_a_terminal():
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
                            stderr=slave, close_fds=True)
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
