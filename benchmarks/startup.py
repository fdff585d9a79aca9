"""Where the main job's time goes: ``python -m cardiosoft.simulate --bpm 60`` from a fresh process.

    python benchmarks/startup.py [--repeat N]     # about 1 minute on 2 CPU cores

Issue #4 asks for the main job, compile included, in under 15 s on a 2-core CPU. Nearly all of
it is start-up: importing JAX and diffrax, tracing and compiling the one vmapped solve (the
solve itself takes about 30 ms). This script prints

1. the wall time of N fresh ``python -m cardiosoft.simulate --bpm 60 --quiet`` processes (best
   and median) and its ratio to the 15 s target;
2. the import time of a fresh process (``import jax`` and ``cardiosoft``);
3. JAX's own log of one run (``JAX_LOG_COMPILES``): tracing, lowering and XLA compilation per
   jitted function, largest first. The quasi-static strokes compile on a second thread while
   the dynamic solve traces and compiles, so the entries overlap and do not add up to the wall
   time.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TARGET_S = 15.0
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

    walls = [_wall(MAIN_JOB) for _ in range(args.repeat)]
    best, median = min(walls), statistics.median(walls)
    print(
        f"\n1. main job, {args.repeat} fresh processes: best {best:.1f} s, median {median:.1f} s"
        f" ({', '.join(f'{w:.1f}' for w in walls)}); best / target {best / TARGET_S:.2f},"
        f" median / target {median / TARGET_S:.2f} (target {TARGET_S:g} s)"
    )

    imports = [
        _wall([sys.executable, "-c", "import jax; import cardiosoft"]) for _ in range(args.repeat)
    ]
    print(
        f"2. imports (jax, diffrax, equinox, cardiosoft): best {min(imports):.1f} s "
        f"= {min(imports) / best:.0%} of the best run"
    )

    env = {**os.environ, "JAX_LOG_COMPILES": "1"}
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
