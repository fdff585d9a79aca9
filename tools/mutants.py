"""Physics mutants: does the fast test suite notice a 2 % error in the physics?

    nice -n 10 python tools/mutants.py              # every mutant; one test suite per mutant (slow)
    python tools/mutants.py --list                  # the mutants and where they apply
    python tools/mutants.py valve-law wk-capacitor  # some of them
    python tools/mutants.py valve-law --tests tests/test_valve_scenes.py   # a narrower suite

Each mutant is a patch ``(file, exact original text, mutated text)``: a 2 % error in a metric,
a pressure law, the pump's energy, a valve law or the water column's head. For each one the
repository (its tracked and untracked, not ignored files, as ``git ls-files`` lists them) is
copied to a temporary folder, the patch applied there (never to the working tree), and
``pytest -m "not slow" -x`` run in the copy with xdist, the copy first on ``PYTHONPATH`` (its
command-line tests' subprocesses import the mutated package too; checked before each run). A
mutant is *killed* when a test fails; the failing tests are printed. Last, the killing tests are
run once more on an unmutated copy: a test that fails there too did not kill anything (it is
reported as broken, and its mutant as not killed).

Every patch is checked before anything runs: its original text must occur exactly once in its
file, or the script stops and names the mutant. The code changes under the mutants; re-target
one by editing its ``original`` and ``mutated`` strings in :data:`MUTANTS` (one line each).

Exit status: 0 when every mutant run was killed, 1 when one survived (or was killed only by a
test that fails without it), 2 for bad arguments or a patch that no longer applies.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclasses.dataclass(frozen=True)
class Mutant:
    name: str
    file: str
    original: str
    mutated: str
    what: str


MUTANTS = (
    # metrics (cardiosoft/metrics.py)
    Mutant("stroke-volume", "cardiosoft/metrics.py",
           "sv = edv - esv", "sv = 1.02 * (edv - esv)",
           "the stroke volume EDV - ESV 2 % high (and EF, CO, P_a SV with it)"),
    Mutant("cardiac-output", "cardiosoft/metrics.py",
           "cardiac_output=sv / period,", "cardiac_output=1.02 * sv / period,",
           "the cardiac output 2 % high"),
    Mutant("efficiency", "cardiosoft/metrics.py",
           "efficiency=h_paper / mech,", "efficiency=1.02 * h_paper / mech,",
           "the paper's efficiency P_a SV / M 2 % high"),
    Mutant("mech-work", "cardiosoft/metrics.py",
           "mech = trapezoid(force, pull)", "mech = 1.02 * trapezoid(force, pull)",
           "the dynamic mechanical work M 2 % high"),
    Mutant("static-sv", "cardiosoft/static.py",
           "sv = v0 - volume[-1]", "sv = 1.02 * (v0 - volume[-1])",
           "the quasi-static stroke volume 2 % high"),
    # pressure laws
    Mutant("chamber-pressure", "cardiosoft/pump.py",
           "return _elementwise_derivative(self.energy, V)",
           "return 1.02 * _elementwise_derivative(self.energy, V)",
           "the chamber pressure 2 % above dU/dV"),
    Mutant("wk-capacitor", "cardiosoft/circulation.py",
           'return {"pc": (q - q_out) / C, "drained_volume": q_out}',
           'return {"pc": (q - q_out) / (1.02 * C), "drained_volume": q_out}',
           "a Windkessel's capacitor 2 % larger in its pressure law than in its volume"),
    Mutant("column-head", "cardiosoft/circulation.py",
           "return self.rho * self.g * self.height(y)",
           "return 1.02 * self.rho * self.g * self.height(y)",
           "the water column's head rho g h 2 % high"),
    Mutant("tube-resistance", "cardiosoft/circulation.py",
           "return 8.0 * self.mu * self.length / (jnp.pi * (0.5 * self.diameter) ** 4)",
           "return 8.16 * self.mu * self.length / (jnp.pi * (0.5 * self.diameter) ** 4)",
           "the tube's Poiseuille resistance 2 % high"),
    # the pump's energy
    Mutant("shell-energy", "cardiosoft/pump.py",
           "return 0.5 * k * x**2 * phi", "return 0.51 * k * x**2 * phi",
           "the shell's zero-pressure strain energy W(x) 2 % high"),
    Mutant("chamber-energy", "cardiosoft/pump.py",
           "return self.elastance / beta**2 * (jnp.cosh(beta * self.strain(V)) - 1.0)",
           "return 1.02 * self.elastance / beta**2 * (jnp.cosh(beta * self.strain(V)) - 1.0)",
           "the chamber's energy U_c(V) 2 % high (its pressure and force with it)"),
    # valve law
    Mutant("valve-law", "cardiosoft/valves.py",
           "return dp * jax.nn.sigmoid(dp / self.smoothing) / R",
           "return 1.02 * dp * jax.nn.sigmoid(dp / self.smoothing) / R",
           "the smooth valve passes 2 % more flow for a given pressure drop"),
)

FAILED = re.compile(r"^(?:FAILED|ERROR) (\S+?)(?: - .*)?$", re.MULTILINE)


def check(mutants) -> None:
    """Every patch applies to the working tree's files: exactly one match, or exit 2."""
    problems = []
    for m in mutants:
        path = ROOT / m.file
        count = path.read_text(encoding="utf-8").count(m.original) if path.exists() else -1
        if count != 1:
            where = "missing" if count < 0 else f"found {count} times, not once"
            problems.append(
                f"mutant {m.name}: the original text {m.original!r} of {m.file} is {where}; "
                "the code changed under it: re-target it in tools/mutants.py (MUTANTS)"
            )
    if problems:
        raise SystemExit("\n".join(problems))


def copy_repository(target: Path) -> None:
    """The repository's tracked and untracked, not ignored files (no .venv, no caches)."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT, capture_output=True, check=True,
    ).stdout.decode().split("\0")
    for name in filter(None, listed):
        source = ROOT / name
        if source.is_file():  # a file deleted but not yet staged is listed too
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target / name)


def environment(copy: Path) -> dict[str, str]:
    """The copy first on the import path, for pytest and for the processes its tests start."""
    path = os.pathsep.join(filter(None, [str(copy), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "PYTHONPATH": path}


def imports_from(copy: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-c", "import cardiosoft; print(cardiosoft.__file__)"],
        cwd=copy, env=environment(copy), capture_output=True, text=True, check=True,
    )
    if not Path(out.stdout.strip()).resolve().is_relative_to(copy.resolve()):
        raise SystemExit(f"the copy imports cardiosoft from {out.stdout.strip()}, not {copy}")


def pytest(copy: Path, args, timeout) -> tuple[int, str]:
    command = [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", *args]
    try:
        out = subprocess.run(
            command, cwd=copy, env=environment(copy), capture_output=True, text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired as err:
        return -1, f"timed out after {timeout} s\n{err.stdout or ''}"
    return out.returncode, out.stdout + out.stderr


def run_mutant(mutant: Mutant, tests, workers: int, timeout) -> dict:
    with tempfile.TemporaryDirectory(prefix=f"mutant-{mutant.name}-") as tmp:
        copy = Path(tmp)
        copy_repository(copy)
        path = copy / mutant.file
        path.write_text(
            path.read_text(encoding="utf-8").replace(mutant.original, mutant.mutated),
            encoding="utf-8",
        )
        imports_from(copy)
        start = time.monotonic()
        args = ["-m", "not slow", "-x", "-q", "-n", str(workers), "--dist", "loadfile", *tests]
        status, output = pytest(copy, args, timeout)
        failed = sorted(set(FAILED.findall(output)))
    # 1: tests failed; 2: xdist's -x interrupts the session after the first failure
    verdict = (
        "killed" if status in (1, 2) and failed
        else "survived" if status == 0
        else f"error ({status})"
    )
    return {
        "mutant": mutant,
        "verdict": verdict,
        "tests": failed,
        "seconds": time.monotonic() - start,
        "tail": output[-3000:],
    }


def confirm(results, timeout) -> None:
    """Run the killing tests on an unmutated copy: a test that fails there killed nothing."""
    killers = sorted({t for r in results if r["verdict"] == "killed" for t in r["tests"]})
    if not killers:
        return
    with tempfile.TemporaryDirectory(prefix="mutant-none-") as tmp:
        copy = Path(tmp)
        copy_repository(copy)
        imports_from(copy)
        _, output = pytest(copy, ["-q", "-n", "0", *killers], timeout)
    broken = set(FAILED.findall(output))
    for r in results:
        if r["verdict"] == "killed" and set(r["tests"]) <= broken:
            r["verdict"] = "not killed (its tests fail unmutated too)"
        r["tests"] = [t + (" (fails unmutated too)" if t in broken else "") for t in r["tests"]]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python tools/mutants.py", description=__doc__.split("\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("names", nargs="*", help="mutants to run (default: all; see --list)")
    p.add_argument("--list", action="store_true", help="list the mutants and exit")
    p.add_argument("--tests", nargs="+", default=[], metavar="PATH",
                   help="test files or ids to run (default: the whole suite, tests/); "
                   "give the mutants' names before it")
    p.add_argument("--workers", type=int, default=2, help="pytest-xdist workers (default 2)")
    p.add_argument("--timeout", type=float, default=3600.0,
                   help="seconds allowed to one mutant's test run (default 3600)")
    args = p.parse_args(argv)
    by_name = {m.name: m for m in MUTANTS}
    unknown = [n for n in args.names if n not in by_name]
    if unknown:
        p.error(f"unknown mutant(s) {', '.join(unknown)}; known: {', '.join(by_name)}")
    chosen = [by_name[n] for n in args.names] if args.names else list(MUTANTS)
    check(chosen)
    if args.list:
        for m in chosen:
            print(f"{m.name:17} {m.file:26} {m.what}")
        return 0
    results = []
    for m in chosen:
        print(f"{m.name}: {m.what} ...", flush=True)
        r = run_mutant(m, args.tests, args.workers, args.timeout)
        results.append(r)
        print(f"{m.name}: {r['verdict']} in {r['seconds']:.0f} s {', '.join(r['tests'])}",
              flush=True)
        if r["verdict"].startswith("error"):
            print(r["tail"], flush=True)
    confirm(results, args.timeout)
    print("\nmutant             verdict    killed by")
    for r in results:
        print(f"{r['mutant'].name:18} {r['verdict']:10} {', '.join(r['tests']) or '-'}")
    return int(any(r["verdict"] != "killed" for r in results))


if __name__ == "__main__":
    sys.exit(main())
