"""Where a command's time goes from a fresh process (issue #41): the main job
(``python -m cardiosoft.simulate --bpm 60``), ``--uncertainty``, and a design question per
shipped scene.

    python benchmarks/startup.py [--repeat N]                  # the main job: about 2 minutes
    python benchmarks/startup.py --commands main uncertainty design-bench design-lv \
        design-rv design-soft-lv design-soft-rv design-tah model --repeat 1   # about 15 minutes

The solve itself takes about 30 ms; the rest of a command is start-up: importing JAX and
diffrax, tracing and compiling its programs. This script prints

1. per command (:data:`COMMANDS`), the wall time of N fresh processes (best and median) with a
   cold compile cache (an empty folder: a fresh machine), its store filled from the programs
   shipped with the package (``tools/ship_programs.py``), and the same with nothing shipped
   (``CARDIOSOFT_SHIPPED_PROGRAMS=0``: every program traced); then a warm one (the folder the
   cold run filled; cardiosoft._cli) with the programs loaded from the store
   (cardiosoft.program_store), and a warm one with the programs traced in each process
   (``CARDIOSOFT_PROGRAM_STORE=0``, issue #41's "before"), with the ratios to each other and
   to the issue's targets, and where one more warm run's time goes (:func:`warm_breakdown`):
   imports, the stored programs' lowering and executables' load, the eager operations, and
   the rest (solving and Python);
2. the import time of a fresh process: ``import cardiosoft`` against issue #41's 0.8 s, and
   the modules the solve needs (JAX, diffrax, the engine);
3. the anchor: ``svzerod`` (svZeroDSolver's own build) solving its closed-loop heart case
   from a fresh process, and each timed command's warm median against it;
4. JAX's own log of the main job without the cache (``JAX_LOG_COMPILES``): tracing, lowering
   and XLA compilation per jitted function, largest first. The quasi-static strokes compile on
   a second thread while the dynamic solve traces and compiles, so the entries overlap and do
   not add up to the wall time.

``--against CHECKOUT`` times a change instead (:func:`against`): another checkout of the
repository (``git worktree add /tmp/before <commit>``, with the programs shipped at that
commit) and this one, alternating, each command's round a cold run then two warm ones, each
checkout with its own compile-cache folder; it prints the ranges and the ratio of the medians.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
IMPORT_TARGET_S = 0.8
"""Issue #41's budget for ``import cardiosoft`` (s)."""
SOLVE_IMPORTS = "import cardiosoft.experiment"
"""What the main job imports before it solves (``cardiosoft.run`` and everything under it)."""
DESIGN = ["cardiosoft.design", "--target-sv"]
LOOP_DESIGN = ["cardiosoft.design", "--scene"]
HEART_CASE = REPO / "tests" / "data" / "svzerod" / "closedLoopHeart_singleVessel.json"
"""svZeroDSolver's closed-loop heart case: the anchor (issue #41), run by both solvers."""
SVZEROD = f"import json, svzerod; svzerod.simulate(json.load(open({str(HEART_CASE)!r})))"
"""The anchor from a fresh process: svZeroDSolver's own Python build on its case."""
COMMANDS = {
    "main": (["cardiosoft.simulate", "--bpm", "60"], 1.5, 4.0),
    "uncertainty": (["cardiosoft.simulate", "--bpm", "60", "--uncertainty"], 3.0, None),
    "design-bench": ([*DESIGN, "70", "--afterload", "90", "--bpm", "60"], 3.0, 15.0),
    "design-lv": ([*DESIGN, "40", "--scene", "lv-systemic", "--bpm", "72"], 3.0, 15.0),
    "design-rv": ([*DESIGN, "50", "--scene", "rv-pulmonary"], 3.0, 15.0),
    "design-soft-lv": ([*LOOP_DESIGN, "soft-lv", "--target-co", "4.5"], 3.0, 15.0),
    "design-soft-rv": ([*LOOP_DESIGN, "soft-rv", "--target-co", "4.5"], 3.0, 15.0),
    "model": (["cardiosoft.simulate", "--scene", str(HEART_CASE)], None, None),
    "design-tah": (
        ["cardiosoft.design", "--scene", "tah", "--target-co", "5", "--lap", "8", "--rap", "5"],
        10.0,
        None,
    ),
}
"""What section 1 times: the command, and issue #41's warm and cold targets (s; None: none)."""


def fresh_process(name: str) -> list[str]:
    """The command line of :data:`COMMANDS`' ``name`` as a fresh process runs it."""
    return [sys.executable, "-m", *COMMANDS[name][0], "--quiet"]

LOG_LINE = re.compile(
    r"Finished (tracing|jaxpr to MLIR module conversion|XLA compilation) "
    r"(?:of )?(?:jit\()?([\w<>.]+)\)?.* in ([0-9.e+-]+) sec"
)
PHASES = {
    "tracing": "trace",
    "jaxpr to MLIR module conversion": "lower",
    "XLA compilation": "compile",
}


def _wall(cmd, env=None, cwd=REPO) -> float:
    start = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, env=env, check=True, capture_output=True)
    return time.perf_counter() - start


IMPORT_LINE = re.compile(r"import time:\s+\d+ \|\s+(\d+) \| (\s*)\S")
STORED = re.compile(r"_solve|strokes|orbit|derivative")
"""The stored programs' names in JAX's log (the batch and loop solves, the quasi-static strokes,
design's orbits and their derivatives); every other jitted name is an eager operation."""


def warm_breakdown(cmd, env) -> dict[str, float]:
    """Where one warm run of ``cmd`` (its cache in ``env``, already filled) spends its wall
    time, from ``python -X importtime`` and JAX's own log (``JAX_LOG_COMPILES``), s: the
    imports; the stored programs' lowering again and their executables' load from the compile
    cache (JAX logs that load as "XLA compilation"); the eager operations (tracing, lowering
    and loading each); and the rest: solving, Python, the interpreter's start and exit. The
    parts are approximate: ``-X importtime`` slows the imports it times, and the main job
    loads its two programs on two threads at once, so that the rest can come out near zero or
    below."""
    env = {**env, "JAX_LOG_COMPILES": "1"}
    start = time.perf_counter()
    run = subprocess.run(
        [cmd[0], "-X", "importtime", *cmd[1:]], cwd=REPO, env=env, capture_output=True,
        text=True, check=True,
    )  # fmt: skip
    wall = time.perf_counter() - start
    out = {"wall": wall, "imports": 0.0, "stored: lower": 0.0, "stored: load": 0.0, "eager": 0.0}
    eager = 0
    for line in run.stderr.splitlines():
        found = IMPORT_LINE.search(line)
        if found and not found.group(2):  # a top-level import: its cumulative time
            out["imports"] += int(found.group(1)) * 1e-6
            continue
        found = LOG_LINE.search(line)
        if not found:
            continue
        phase, name, sec = found.groups()
        if STORED.search(name):  # its tracing is of the call of the exported program
            out["stored: load" if PHASES[phase] == "compile" else "stored: lower"] += float(sec)
        else:
            out["eager"] += float(sec)
            eager += phase == "tracing"
    out["rest"] = wall - sum(v for k, v in out.items() if k != "wall")
    out["eager operations"] = eager
    return out


def _cold_warm_traced(cmd, repeat: int) -> dict[str, list[float]]:
    walls = {"cold": [], "cold, traced": [], "warm": [], "warm, traced": []}
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as other:
            env = {**os.environ, "CARDIOSOFT_COMPILE_CACHE": cache}
            # a fresh machine: nothing traced or compiled yet, nothing shipped (tracing) ...
            nothing = {
                **env, "CARDIOSOFT_COMPILE_CACHE": os.path.join(other, "cold"),
                "CARDIOSOFT_SHIPPED_PROGRAMS": "0",
            }  # fmt: skip
            walls["cold, traced"].append(_wall(cmd, nothing))
            # ... and with the programs shipped with the package (tools/ship_programs.py)
            walls["cold"].append(_wall(cmd, env))  # fills the empty cache folder
            walls["warm"].append(_wall(cmd, env))  # the stored programs, not traced
            # the compile cache alone, the programs traced in each process; a folder of its
            # own, filled by a traced run (the stored programs compile to other executables)
            traced = {**env, "CARDIOSOFT_COMPILE_CACHE": other, "CARDIOSOFT_PROGRAM_STORE": "0"}
            _wall(cmd, traced)
            walls["warm, traced"].append(_wall(cmd, traced))
            walls["breakdown"] = warm_breakdown(cmd, env)  # the last repeat's
    return walls


def _cold_warm(cmd, checkout: Path) -> tuple[float, list[float]]:
    """A cold run of ``cmd`` in ``checkout`` (its package first on the path), then two warm."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "CARDIOSOFT_COMPILE_CACHE": cache, "PYTHONPATH": str(checkout)}
        walls = [_wall(cmd, env, cwd=checkout) for _ in range(3)]
    return walls[0], walls[1:]


def against(before: Path, names, rounds: int) -> None:
    """Each command of ``names`` from fresh processes in the checkout ``before`` and in this
    one, alternating, ``rounds`` times: cold and warm ranges, and after / before medians."""
    print(f"   before: {before}; after: {REPO}; {rounds} rounds, each a cold run and two warm")
    for name in names:
        walls = {side: {"cold": [], "warm": []} for side in ("before", "after")}
        for _ in range(rounds):
            for side, checkout in (("before", before), ("after", REPO)):
                cold, warm = _cold_warm(fresh_process(name), checkout)
                walls[side]["cold"].append(cold)
                walls[side]["warm"].extend(warm)
        print(f"   {name}: python -m {' '.join(COMMANDS[name][0])}")
        for kind in ("cold", "warm"):
            b, a = walls["before"][kind], walls["after"][kind]
            print(
                f"     {kind}: {min(b):.1f}-{max(b):.1f} -> {min(a):.1f}-{max(a):.1f} s, "
                f"after / before {statistics.median(a) / statistics.median(b):.2f} (medians)"
            )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="fresh processes to time (3)")
    parser.add_argument(
        "--commands", nargs="+", choices=COMMANDS, default=["main"],
        help="what to time (default: main; all of them take about 25 minutes)",
    )  # fmt: skip
    parser.add_argument(
        "--against", type=Path, metavar="CHECKOUT",
        help="time the commands here against another checkout instead (rounds: --repeat)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    if args.against is not None and not (args.against / "cardiosoft" / "__init__.py").is_file():
        parser.error(f"--against {args.against}: not a checkout of cardiosoft")
    print(f"cardiosoft start-up benchmark: {', '.join(args.commands)}")
    print(f"machine: os.cpu_count() = {os.cpu_count()}, load average {os.getloadavg()[0]:.2f}")
    if args.against is not None:
        against(args.against.resolve(), args.commands, args.repeat)
        return 0
    print(
        f"\n1. fresh processes, {args.repeat} each: cold compile cache, warm (the programs "
        "loaded from the store), warm traced (CARDIOSOFT_PROGRAM_STORE=0; issue #41's before)"
    )
    best, warm = None, {}
    for name in args.commands:
        command, warm_target, cold_target = COMMANDS[name]
        walls = _cold_warm_traced(fresh_process(name), args.repeat)
        breakdown = walls.pop("breakdown")
        median = {kind: statistics.median(w) for kind, w in walls.items()}
        print(f"   {name}: python -m {' '.join(command)}")
        for kind, w in walls.items():
            print(
                f"     {kind + ':':<14} best {min(w):5.1f} s, median {median[kind]:5.1f} s"
                f" ({', '.join(f'{x:.1f}' for x in w)})"
            )
        ratios = [
            f"cold / cold traced {median['cold'] / median['cold, traced']:.2f}",
            f"warm / warm traced {median['warm'] / median['warm, traced']:.2f}",
        ]
        if warm_target:
            ratio = median["warm"] / warm_target
            ratios.append(f"warm / issue #41's {warm_target:g} s: {ratio:.2f}")
        if cold_target:
            ratios.append(f"cold / its {cold_target:g} s: {median['cold'] / cold_target:.2f}")
        print(f"     {'; '.join(ratios)}")
        print(
            "     one more warm run, where its time goes (s; JAX's log, -X importtime): "
            + ", ".join(
                f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}"
                for k, v in breakdown.items()
            )
        )
        warm[name] = median["warm"]
        if name == "main":
            best = min(walls["cold"])

    package = [_wall([sys.executable, "-c", "import cardiosoft"]) for _ in range(args.repeat)]
    print(
        f"2. imports: `import cardiosoft` best {min(package):.2f} s, best / target "
        f"{min(package) / IMPORT_TARGET_S:.2f} (issue #41: {IMPORT_TARGET_S:g} s; its public "
        "names load on first use)"
    )
    solve = [_wall([sys.executable, "-c", SOLVE_IMPORTS]) for _ in range(args.repeat)]
    print(
        f"   the solve's modules (jax, diffrax, equinox, cardiosoft.experiment): best "
        f"{min(solve):.1f} s"
        + (f" = {min(solve) / best:.0%} of the main job's best cold run" if best else "")
    )

    anchor = [_wall([sys.executable, "-c", SVZEROD]) for _ in range(args.repeat)]
    print(
        f"3. the anchor: svzerod (svZeroDSolver) on {HEART_CASE.name} from a fresh process, "
        f"best {min(anchor):.2f} s"
        + "".join(f"; {name} warm / it: {t / min(anchor):.1f}" for name, t in warm.items())
    )

    env = {**os.environ, "JAX_LOG_COMPILES": "1", "CARDIOSOFT_COMPILE_CACHE": "0"}
    main_job = fresh_process("main")
    log = subprocess.run(main_job, cwd=REPO, env=env, capture_output=True, text=True).stderr
    seconds = defaultdict(float)
    count = defaultdict(int)
    for phase, name, sec in LOG_LINE.findall(log):
        seconds[(name, PHASES[phase])] += float(sec)
        count[(name, PHASES[phase])] += 1
    print("4. JAX's log of one run (s; largest first; the two big jits overlap on two threads):")
    print(f"   {'function':<24}{'phase':<9}{'s':>7}{'count':>7}")
    ranked = sorted(seconds.items(), key=lambda kv: -kv[1])
    for (name, phase), sec in ranked[:8]:
        print(f"   {name:<24}{phase:<9}{sec:7.2f}{count[(name, phase)]:7d}")
    rest = ranked[8:]
    print(
        f"   {'everything else':<24}{'':<9}{sum(s for _, s in rest):7.2f}"
        f"{sum(count[k] for k, _ in rest):7d}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
