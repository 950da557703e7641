"""What validation/bench_md.py and validation/bench_lammps.py share: the
scene (LJ argon, its constants and its fcc start), timing helpers, the
statistics of several processes per figure, and the markdown table printer."""

import platform
import resource
import time

import numpy as np
from ase.build import bulk
from ase.md.velocitydistribution import Stationary

try:
    from ase.md.velocitydistribution import thermalize_momenta   # ase >= 3.29
except ImportError:
    from ase.md.velocitydistribution import MaxwellBoltzmannDistribution as thermalize_momenta

SIGMA, EPS, RC, SKIN = 3.405, 0.0104, 8.5, 1.0   # Å, eV, Å, Å
LATTICE, MASS = 5.72, 39.948                     # Å, amu
T_K, DT_FS = 90.0, 5.0                           # K, fs
MOVE = 0.01                                      # Å rms, the "small move"
P_BAR, TDAMP_FS, PDAMP_FS = 1.0, 100.0, 1000.0   # NPT settings


def cpu_model():
    """The CPU a figure was measured on, as the kernel's speed depends on it
    (issue 24.3: the same pair kernel ran at 0.94x LAMMPS's Pair on one
    x86-64 and 1.30x on another): lscpu's model name, family and model, the
    SIMD flags the compiler may use, and the CPU LLVM (numba) compiles for."""
    fields = {}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f.read().split("\n\n")[0].splitlines():
                if ":" in line:
                    k, v = line.split(":", 1)
                    fields[k.strip()] = v.strip()
    except OSError:
        pass
    flags = set(fields.get("flags", "").split())
    simd = [x for x in ("avx2", "fma", "avx512f", "avx512vl") if x in flags]
    try:
        import llvmlite.binding as llvm
        target = llvm.get_host_cpu_name()
    except Exception:  # noqa: BLE001 -- a description, never a failure
        target = "?"
    return (f"{fields.get('model name', platform.processor() or '?')} (family "
            f"{fields.get('cpu family', '?')} model {fields.get('model', '?')}; "
            f"{' '.join(simd) or 'no AVX2'}; LLVM target {target})")


# --------------------------------------------------------------------- scenes

def fcc_argon(natoms, seed=0):
    """fcc argon near ``natoms`` atoms, 90 K momenta, indices shuffled."""
    m = round((fcc_argon_size(natoms) / 4) ** (1 / 3))
    atoms = bulk("Ar", "fcc", a=LATTICE, cubic=True).repeat(m)
    rng = np.random.default_rng(seed)
    atoms.positions += rng.normal(scale=0.05, size=atoms.positions.shape)
    atoms.wrap()
    thermalize_momenta(atoms, temperature_K=T_K, rng=rng)
    Stationary(atoms)
    return atoms[rng.permutation(len(atoms))]


def fcc_argon_size(natoms):
    """The atom count of ``fcc_argon(natoms)``."""
    return 4 * max(1, int(round((natoms / 4) ** (1 / 3)))) ** 3


# ------------------------------------------------------------ timing helpers

def now():
    return time.perf_counter()


def maxrss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def time_md(run, steps, repeats):
    """Mean ms per step over ``repeats`` blocks of ``run(steps)``: a mean,
    not a median of blocks, so that pair-list rebuilds are paid in full."""
    t = now()
    for _ in range(repeats):
        run(steps)
    return 1e3 * (now() - t) / (steps * repeats)


# ------------------------------------------- several processes per figure

def ok(r):
    return r is not None and "error" not in r


def pooled(results, key):
    """All values of list ``key`` across the processes' results."""
    return [x for r in results if ok(r) for x in (r.get(key) or [])]


def median_of(results, key):
    """Median over processes of a per-process number (None: none had it)."""
    xs = [r[key] for r in results if ok(r) and r.get(key) is not None]
    return float(np.median(xs)) if xs else None


def spread(xs):
    """p90 / p10 of ``xs`` (None below 2 values)."""
    if len(xs) < 2:
        return None
    p10, p90 = np.percentile(xs, [10, 90])
    return float(p90 / p10) if p10 > 0 else None


def distinct(results, key):
    """The distinct values of ``key`` across processes, joined ("tbb",
    "1/2"): one value when every process agreed."""
    vals = []
    for r in results:
        v = r.get(key) if ok(r) else None
        if v is not None and v not in vals:
            vals.append(v)
    return "/".join(str(v) for v in vals) if vals else None


def first_error(results):
    return next((r["error"] for r in results if r is not None and "error" in r), None)


# ------------------------------------------------------------------ printing

def fmt(x, digits=2):
    if x is None:
        return "—"
    if isinstance(x, str):
        return x
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(x)
    if x != 0 and (abs(x) < 10 ** -digits or abs(x) >= 1e6):
        return f"{x:.1e}"
    return f"{x:.{digits}f}" if abs(x) < 100 else f"{x:.0f}"


def ratio(a, b):
    return None if a is None or b is None or b == 0 else f"{a / b:.2f}x"


def table(title, headers, rows, notes=()):
    """The one table printer: a markdown table with a title and notes."""
    print(f"\n### {title}\n")
    print("| " + " | ".join(headers) + " |")
    print("|" + "|".join("---" for _ in headers) + "|")
    for row in rows:
        print("| " + " | ".join(fmt(c) for c in row) + " |")
    for note in notes:
        print(f"\n{note}")
