"""What the design optimiser costs (issue #13), and whether it recovers a known design.

    python benchmarks/design.py      # about 4 minutes on 2 busy CPU cores

Issue #13 asks for one target to 0.5 ml from a fresh process, compile included, in under 30 s
on a 2-core CPU, and a further target in the same (compiled) process in under 3 s. This script
prints, without asserting anything about time:

1. the wall time of fresh ``python -m cardiosoft.design --target-sv 70 --afterload 90 --bpm 60``
   processes (the researcher's question: 70 ml at 60 bpm against 90 mmHg), and where it went,
   from the ``timings`` of the ``design.json`` they write: start-up and imports, tracing and
   compiling the search's two programs (the orbits, then their implicit derivatives; they
   compile at once on two threads), the grid, the refinement rounds, the verifying
   ``run()`` (compiled meanwhile on a second thread from the start design); the CPU time of
   the process (both threads). Each run with a cold compile cache (an empty folder), then
   again with the warm one it filled (cardiosoft._cli), and the warm / cold ratio; then one
   with ``--steady beats`` (orbits beat after beat instead of by Newton shooting: a lighter
   compile);
2. in one process, through the Python API (XLA's default settings, or the caller's
   ``XLA_FLAGS``): the first target (compile included), then further targets of the same shape
   (compiled), each with its split;
3. recovery: ``run()`` of Omega 3.2, C 0.45 at 30/60/90 mmHg and 60 bpm gives three stroke
   volumes; the optimiser, from the default design (Omega 4, C 0.4), is asked for them at once
   and the verifying run's stroke volumes are compared with them (the design itself need not be
   unique).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TARGET_FRESH_S = 30.0
TARGET_FURTHER_S = 3.0
QUESTION = ["--target-sv", "70", "--afterload", "90", "--bpm", "60"]
ENV = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
"""The fresh processes' environment: the command line's own XLA setting (optimisation level 0)."""
SPLIT = ("trace_s", "compile_s", "grid_s", "refine_s", "prewarm_wait_s", "verify_s")


def _split(timings: dict) -> str:
    calls = f"{timings['calls']} calls of the compiled search"
    return ", ".join(f"{k[:-2]} {timings[k]:.2f}" for k in SPLIT) + (
        f"; {calls}, median {timings['call_median_s']:.3f}"
    )


def fresh(repeat: int) -> None:
    print(f"\n1. fresh processes: python -m cardiosoft.design {' '.join(QUESTION)}")
    shooting = [("shooting, cold cache", [], "cold"), ("shooting, warm cache", [], "warm")]
    runs = shooting * repeat + [("--steady beats, cold cache", ["--steady", "beats"], "cold")]
    walls = {"cold": [], "warm": []}
    cache, caches = None, []
    for i, (label, extra, kind) in enumerate(runs):
        if kind == "cold":  # a new, empty cache folder; the warm run after it reuses it
            cache = tempfile.mkdtemp(prefix="cardiosoft-bench-cache-")
            caches.append(cache)
        env = {**ENV, "CARDIOSOFT_COMPILE_CACHE": cache}
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            cpu = os.times()
            command = [sys.executable, "-m", "cardiosoft.design", *QUESTION, *extra]
            out = subprocess.run(
                [*command, "--out", tmp, "--no-plot"],
                env=env,
                cwd=REPO,
                capture_output=True,
                text=True,
            )
            wall = time.perf_counter() - start
            after = os.times()
            cpu_s = after.children_user - cpu.children_user
            cpu_s += after.children_system - cpu.children_system
            if out.returncode not in (0, 3):
                print(out.stderr)
                raise SystemExit(f"python -m cardiosoft.design exited {out.returncode}")
            record = json.loads((Path(tmp) / "design.json").read_text())
        if not extra:
            walls[kind].append(wall)
        t = record["timings"]
        (target,) = record["targets"]
        print(
            f"   run {i + 1}, {label}: {wall:.1f} s wall ({wall / TARGET_FRESH_S:.2f} of "
            f"{TARGET_FRESH_S:g} s), {cpu_s:.1f} s CPU"
            f"; reached {record['reached']}: Omega {record['omega']:.4f}, C "
            f"{record['shortening']:.4f}, SV {target['sv_ml']:.2f} ml, {record['iterations']} "
            f"rounds"
        )
        print(
            f"      start-up + imports {wall - t['total_s']:.1f} s, optimise() {t['total_s']:.1f} s"
            f": {_split(t)}"
        )
        print(f"      (the verifying run() compiled on a second thread: {t['prewarm_s']:.1f} s)")
    for folder in caches:
        shutil.rmtree(folder, ignore_errors=True)
    cold, warm = (sum(walls[k]) / len(walls[k]) for k in ("cold", "warm"))
    print(
        f"   shooting, mean wall: cold cache {cold:.1f} s, warm cache {warm:.1f} s; warm / cold "
        f"{warm / cold:.2f}"
    )


def in_process() -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    from cardiosoft.design import optimise

    print("\n2. one process, the Python API: 70 ml at 90 mmHg, 60 bpm, then further targets")
    for i, (sv, head) in enumerate(((70, 90), (60, 90), (80, 60), (50, 30), (75, 90))):
        start = time.perf_counter()
        r = optimise("bench-dynamic", target_sv=sv, afterload=head, bpm=60)
        wall = time.perf_counter() - start
        (t,) = r.targets
        what = "first (compile included)" if i == 0 else "further (compiled)"
        limit = TARGET_FURTHER_S if i else TARGET_FRESH_S
        print(
            f"   {what:25s} {sv:3d} ml at {head:2d} mmHg: {wall:6.2f} s ({wall / limit:.2f} of "
            f"{limit:g} s); reached {r.reached}, SV {t.sv_ml:.2f} ml, Omega {r.omega:.3f}, C "
            f"{r.shortening:.4f}, {r.iterations} rounds"
        )
        print(f"      {_split(r.timings)}")


def recovery() -> None:
    import cardiosoft as cs
    from cardiosoft.design import optimise
    from cardiosoft.units import ml

    heads = [30, 60, 90]
    known = {"omega": 3.2, "shortening": 0.45}
    print(f"\n3. recovery: Omega {known['omega']}, C {known['shortening']} at {heads} mmHg, 60 bpm")
    runs = cs.run("bench-dynamic", bpm=60, afterload=heads, **known)
    svs = [m.metrics["stroke_volume"] / ml for m in runs.members]
    print(f"   its stroke volumes (run()): {', '.join(f'{v:.3f}' for v in svs)} ml")
    start = time.perf_counter()
    r = optimise("bench-dynamic", target_sv=svs, afterload=heads, bpm=60)
    wall = time.perf_counter() - start
    print(
        f"   optimised from Omega 4, C 0.4 in {wall:.1f} s ({r.iterations} rounds; compile "
        f"{r.timings['compile_s']:.1f} s): Omega {r.omega:.4f}, C {r.shortening:.4f}, reached "
        f"{r.reached}"
    )
    for t in r.targets:
        print(
            f"   {t.afterload_mmHg:3.0f} mmHg: target {t.target_sv_ml:.3f} ml, run() "
            f"{t.sv_ml:.3f} ml, residual {t.residual_ml:+.3f} ml"
        )
    worst = max(abs(t.residual_ml) for t in r.targets)
    print(f"   largest |residual| {worst:.3f} ml (tolerance 0.5 ml)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=2, help="fresh processes to time (2)")
    args = parser.parse_args(argv)
    print("cardiosoft design benchmark (issue #13)")
    print(f"machine: os.cpu_count() = {os.cpu_count()}, load average {os.getloadavg()[0]:.2f}")
    start = time.perf_counter()
    fresh(args.repeat)
    in_process()
    recovery()
    print(
        f"\ntotal wall time {time.perf_counter() - start:.0f} s; load average now "
        f"{os.getloadavg()[0]:.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
