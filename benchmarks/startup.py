"""Where the main job's time goes: ``python -m cardiosoft.simulate --bpm 60`` from a fresh process.

    python benchmarks/startup.py [--repeat N]     # about 1 minute on 2 CPU cores

Issue #4 asks for the main job, compile included, in under 15 s on a 2-core CPU. Nearly all of
it is start-up: importing JAX and diffrax, tracing and compiling the one vmapped solve (the
solve itself takes about 30 ms). This script prints

1. the wall time of N fresh ``python -m cardiosoft.simulate --bpm 60 --quiet`` processes (best
   and median) and its ratio to the 15 s target, each with a cold compile cache (an empty
   folder), then a warm one (the folder the cold run filled; cardiosoft._cli) with the
   programs traced again (``CARDIOSOFT_PROGRAM_STORE=0``) and with them loaded from the store
   (cardiosoft.program_store), side by side;
2. the import time of a fresh process: ``import cardiosoft`` against issue #41's 0.8 s, and
   the modules the solve needs (JAX, diffrax, the engine);
3. JAX's own log of one run without the cache (``JAX_LOG_COMPILES``): tracing, lowering and
   XLA compilation per jitted function, largest first. The quasi-static strokes compile on a
   second thread while the dynamic solve traces and compiles, so the entries overlap and do not
   add up to the wall time.
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
TARGET_S = 15.0
WARM_TARGET_S, COLD_TARGET_S = 1.5, 4.0
"""Issue #41's targets for the main job from a fresh process, warm and cold cache (s)."""
IMPORT_TARGET_S = 0.8
"""Issue #41's budget for ``import cardiosoft`` (s)."""
SOLVE_IMPORTS = "import cardiosoft.experiment"
"""What the main job imports before it solves (``cardiosoft.run`` and everything under it)."""
MAIN_JOB = [sys.executable, "-m", "cardiosoft.simulate", "--bpm", "60", "--quiet"]
LOG_LINE = re.compile(
    r"Finished (tracing|jaxpr to MLIR module conversion|XLA compilation) "
    r"(?:of )?(?:jit\()?([\w<>.]+)\)?.* in ([0-9.e+-]+) sec"
)
PHASES = {
    "tracing": "trace",
    "jaxpr to MLIR module conversion": "lower",
    "XLA compilation": "compile",
}


def _wall(cmd, env=None) -> float:
    start = time.perf_counter()
    subprocess.run(cmd, cwd=REPO, env=env, check=True, capture_output=True)
    return time.perf_counter() - start


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="fresh processes to time (3)")
    args = parser.parse_args(argv)
    print(f"cardiosoft start-up benchmark: {' '.join(MAIN_JOB[1:])}")
    print(f"machine: os.cpu_count() = {os.cpu_count()}, load average {os.getloadavg()[0]:.2f}")

    walls = {"cold": [], "warm": [], "warm, traced": []}
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as other:
            env = {**os.environ, "CARDIOSOFT_COMPILE_CACHE": cache}
            walls["cold"].append(_wall(MAIN_JOB, env))  # fills the empty cache folder
            walls["warm"].append(_wall(MAIN_JOB, env))  # the stored programs, not traced
            # the compile cache alone, the programs traced in each process (issue #41's
            # "before"); a folder of its own, filled by a traced run (the stored programs
            # compile to other executables)
            traced = {**env, "CARDIOSOFT_COMPILE_CACHE": other, "CARDIOSOFT_PROGRAM_STORE": "0"}
            _wall(MAIN_JOB, traced)
            walls["warm, traced"].append(_wall(MAIN_JOB, traced))
    print(f"\n1. main job, {args.repeat} fresh processes each (target {TARGET_S:g} s; issue #41:")
    print(f"   {WARM_TARGET_S:g} s warm, {COLD_TARGET_S:g} s cold):")
    for kind, w in walls.items():
        print(
            f"   {kind + ':':<14} best {min(w):.1f} s, median {statistics.median(w):.1f} s"
            f" ({', '.join(f'{x:.1f}' for x in w)}); best / target {min(w) / TARGET_S:.2f}"
        )
    best = min(walls["cold"])
    median = {kind: statistics.median(w) for kind, w in walls.items()}
    print(
        f"   warm / cold (medians): {median['warm'] / median['cold']:.2f}; warm / warm traced:"
        f" {median['warm'] / median['warm, traced']:.2f}; warm / issue #41's "
        f"{WARM_TARGET_S:g} s: {median['warm'] / WARM_TARGET_S:.2f}"
    )

    package = [_wall([sys.executable, "-c", "import cardiosoft"]) for _ in range(args.repeat)]
    print(
        f"2. imports: `import cardiosoft` best {min(package):.2f} s, best / target "
        f"{min(package) / IMPORT_TARGET_S:.2f} (issue #41: {IMPORT_TARGET_S:g} s; its public "
        "names load on first use)"
    )
    solve = [_wall([sys.executable, "-c", SOLVE_IMPORTS]) for _ in range(args.repeat)]
    print(
        f"   the solve's modules (jax, diffrax, equinox, cardiosoft.experiment): best "
        f"{min(solve):.1f} s = {min(solve) / best:.0%} of the best cold run"
    )

    env = {**os.environ, "JAX_LOG_COMPILES": "1", "CARDIOSOFT_COMPILE_CACHE": "0"}
    log = subprocess.run(MAIN_JOB, cwd=REPO, env=env, capture_output=True, text=True).stderr
    seconds = defaultdict(float)
    count = defaultdict(int)
    for phase, name, sec in LOG_LINE.findall(log):
        seconds[(name, PHASES[phase])] += float(sec)
        count[(name, PHASES[phase])] += 1
    print("3. JAX's log of one run (s; largest first; the two big jits overlap on two threads):")
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
