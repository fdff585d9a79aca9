"""What the closed-loop design question costs from a fresh process (issue #26: under 60 s on
2 cores).

    python benchmarks/design_loop.py              # 3 cold + 3 warm runs, about 5 minutes
    python benchmarks/design_loop.py --repeat 1

Each run is a fresh ``python -m cardiosoft.design --scene tah --target-co 5 --lap 8 --rap 5
--out DIR``: with an empty compile cache (cold), then with the cache the cold runs filled
(warm). Printed per run: wall time, the process's CPU time, the load average before it, and
from ``design.json`` the search's own seconds and the first call's (compile included). Nothing
is asserted about time; the ratio to the target is printed.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TARGET_S = 60.0
QUESTION = ["--scene", "tah", "--target-co", "5", "--lap", "8", "--rap", "5", "--quiet"]


def one_run(cache: Path, out: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["CARDIOSOFT_COMPILE_CACHE"] = str(cache)
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "cardiosoft.design", *QUESTION, "--out", str(out)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode not in (0, 1):
        sys.exit(f"design exited {proc.returncode}:\n{proc.stderr}")
    record = json.loads((out / "design.json").read_text())
    return dict(
        wall=wall,
        cpu=cpu,
        load=load,
        search=record["seconds"],
        first_call=record["compile_seconds"],
        reached=record["reached"],
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3, help="runs of each kind (default 3)")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "cache"
        rows = {"cold": [], "warm": []}
        for kind in ("cold", "warm"):
            for i in range(args.repeat):
                if kind == "cold":  # an empty cache for every cold run
                    cache = Path(tmp) / f"cache{i}"
                row = one_run(cache, Path(tmp) / f"{kind}{i}")
                rows[kind].append(row)
                print(
                    f"{kind} {i + 1}: wall {row['wall']:.1f} s, CPU {row['cpu']:.1f} s, load "
                    f"{row['load']:.1f}; search {row['search']:.1f} s (first call, compile "
                    f"included, {row['first_call']:.1f} s); reached {row['reached']}",
                    flush=True,
                )
        for kind, runs in rows.items():
            median = statistics.median(r["wall"] for r in runs)
            print(
                f"{kind}: median wall {median:.1f} s over {len(runs)} runs = "
                f"{median / TARGET_S:.2f} x the {TARGET_S:.0f} s target"
            )


if __name__ == "__main__":
    main()
