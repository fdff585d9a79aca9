"""What the predictive bands cost: ``simulate --bpm 60 --uncertainty`` against the plain run.

    python benchmarks/uncertainty.py [--repeat N] [--draws 16 32 64]    # a few minutes, 2 cores

Issue #24 asks for ``python -m cardiosoft.simulate --bpm 60 --uncertainty`` from a fresh process
in at most 3 times the plain run's wall time on 2 cores. This script times N fresh processes of
each (cold compile cache: an empty folder per process, as a first run on a new machine; then
warm: the folder a cold run filled), for each number of posterior draws, and prints the medians
and their ratio to the plain run's. The ensemble runs every draw at every afterload beat after
beat until the slowest is steady (at least ``cardiosoft.posterior.ENSEMBLE_MAX_BEATS`` allowed),
so its cost grows with the draws and with the slowest draw's transient.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TARGET_RATIO = 3.0
MAIN_JOB = [sys.executable, "-m", "cardiosoft.simulate", "--bpm", "60", "--quiet"]


def wall(args: list[str], cache: str) -> float:
    env = {**os.environ, "CARDIOSOFT_COMPILE_CACHE": cache}
    start = time.perf_counter()
    done = subprocess.run(MAIN_JOB + args, cwd=REPO, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode not in (0,):
        sys.exit(f"{' '.join(MAIN_JOB + args)} exited {done.returncode}:\n{done.stderr[-2000:]}")
    return seconds


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=2, help="fresh processes per case")
    parser.add_argument("--draws", type=int, nargs="+", default=[16, 32, 64])
    args = parser.parse_args(argv)
    print(f"{os.cpu_count()} CPU cores; {args.repeat} fresh process(es) per case; "
          f"target: at most {TARGET_RATIO:g}x the plain run")
    cases = [("plain", [])] + [
        (f"--uncertainty --draws {n}", ["--uncertainty", "--draws", str(n)]) for n in args.draws
    ]
    rows = []
    for label, extra in cases:
        cold, warm = [], []
        for _ in range(args.repeat):
            with tempfile.TemporaryDirectory() as cache:
                cold.append(wall(extra, cache))
                warm.append(wall(extra, cache))
        rows.append((label, statistics.median(cold), statistics.median(warm)))
        print(f"  {label:28s} cold {rows[-1][1]:6.1f} s   warm {rows[-1][2]:6.1f} s", flush=True)
    base_cold, base_warm = rows[0][1], rows[0][2]
    print(f"{'case':30s} {'cold':>7s} {'ratio':>6s} {'warm':>7s} {'ratio':>6s}")
    for label, cold, warm in rows:
        print(f"{label:30s} {cold:6.1f}s {cold / base_cold:5.2f}x {warm:6.1f}s "
              f"{warm / base_warm:5.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
