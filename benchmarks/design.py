"""What a design answer costs on every shipped scene (issues #13 and #25), and whether the
optimiser recovers a known design.

    python benchmarks/design.py                   # about 15 minutes on 2 CPU cores
    python benchmarks/design.py --scenes bench    # one scene; --repeat N fresh processes each

Issue #25 asks for a design answer in under 30 s from a fresh process with an empty compile
cache on every shipped scene (2 cores, median of 3), and a further target in the same process
under 1 s. This script prints, without asserting anything about time:

1. per scene, fresh ``cardiosoft design`` processes (:data:`QUESTIONS`): with a cold compile
   cache (an empty folder), then a warm one (the folder the cold run filled): wall time, the
   process's CPU time (both its threads; on a machine that other work loads, CPU seconds are
   the number to compare), the load average around the run, and where the time went from the
   ``timings`` of ``design.json`` (start-up and imports; tracing, and tracing plus compiling,
   of the search's two programs; the grid; the refinement; the verifying ``run()``, compiled
   meanwhile on a second thread from the start design);
2. per scene, JAX's own log of one cold run (``JAX_LOG_COMPILES``): tracing, lowering and XLA
   compilation per jitted program, largest first (the programs compile on threads at once:
   the entries overlap and are wall seconds, not CPU);
3. per scene, in one process through the Python API: the first target (compile included), then
   further targets of the same shape (compiled);
4. recovery: ``run()`` of Omega 3.2, C 0.45 at 30/60/90 mmHg and 60 bpm gives three stroke
   volumes; the optimiser, from the default design (Omega 4, C 0.4), is asked for them at once.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from startup import LOG_LINE, PHASES  # benchmarks/startup.py: JAX's compile log

REPO = Path(__file__).resolve().parent.parent
TARGET_FRESH_S = 30.0
TARGET_FURTHER_S = 1.0
QUESTIONS = {
    "bench": ["--target-sv", "70", "--afterload", "90", "--bpm", "60"],
    "lv": ["--scene", "lv-systemic", "--bpm", "72", "--target-sv", "40"],
    "rv": ["--scene", "rv-pulmonary", "--target-sv", "50"],
}
"""The question asked on each shipped dynamic scene (the bench's is the README's)."""
FURTHER = {
    "bench": [dict(target_sv=v, afterload=90, bpm=60) for v in (70, 60, 80, 55)],
    "lv": [dict(target_sv=v, bpm=72) for v in (40, 35, 45, 30)],
    "rv": [dict(target_sv=v) for v in (50, 45, 55, 40)],
}
"""The in-process targets (the first compiles, the others reuse it)."""
SCENES = {"bench": "bench-dynamic", "lv": "lv-systemic", "rv": "rv-pulmonary"}
ENV = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
"""The fresh processes' environment: the command line's own XLA settings."""
SPLIT = ("trace_s", "compile_s", "grid_s", "refine_s", "prewarm_wait_s", "verify_s")


def _load() -> float:
    return os.getloadavg()[0]


def _split(timings: dict) -> str:
    calls = f"{timings['calls']} calls of the compiled search"
    return ", ".join(f"{k[:-2]} {timings[k]:.2f}" for k in SPLIT) + (
        f"; {calls}, median {timings['call_median_s']:.3f}"
    )


def _design(question, cache, extra_env=None):
    """One fresh ``python -m cardiosoft.design`` process: (wall s, CPU s, load before, load
    after, design.json, stderr)."""
    env = {**ENV, "CARDIOSOFT_COMPILE_CACHE": cache, **(extra_env or {})}
    with tempfile.TemporaryDirectory() as tmp:
        before, load = os.times(), _load()
        start = time.perf_counter()
        out = subprocess.run(
            [sys.executable, "-m", "cardiosoft.design", *question, "--out", tmp, "--no-plot"],
            env=env,
            cwd=REPO,
            capture_output=True,
            text=True,
        )
        wall = time.perf_counter() - start
        after = os.times()
        cpu = (after.children_user - before.children_user) + (
            after.children_system - before.children_system
        )
        if out.returncode not in (0, 1):
            print(out.stderr)
            raise SystemExit(f"cardiosoft design exited {out.returncode}")
        record = json.loads((Path(tmp) / "design.json").read_text())
    return wall, cpu, load, _load(), record, out.stderr


def fresh(name: str, repeat: int) -> dict:
    question = QUESTIONS[name]
    print(f"\n1. {SCENES[name]}: fresh processes, cardiosoft design {' '.join(question)}")
    out = {"cold": [], "warm": []}
    for i in range(repeat):
        cache = tempfile.mkdtemp(prefix="cardiosoft-bench-cache-")
        try:
            for kind in ("cold", "warm"):
                wall, cpu, load0, load1, record, _ = _design(question, cache)
                out[kind].append((wall, cpu, load0, load1))
                t = record["timings"]
                (target, *_) = record["targets"]
                print(
                    f"   run {i + 1}, {kind} cache: {wall:.1f} s wall ({wall / TARGET_FRESH_S:.2f} "
                    f"of {TARGET_FRESH_S:g} s), {cpu:.1f} s CPU, load {load0:.1f} -> {load1:.1f}; "
                    f"reached {record['reached']}: Omega {record['omega']:.4f}, C "
                    f"{record['shortening']:.4f}, SV {target['sv_ml']:.2f} ml, "
                    f"{record['iterations']} rounds"
                )
                print(
                    f"      start-up + imports {wall - t['total_s']:.1f} s, optimise() "
                    f"{t['total_s']:.1f} s: {_split(t)}; the verifying run() compiled on a "
                    f"second thread in {t['prewarm_s']:.1f} s"
                )
        finally:
            shutil.rmtree(cache, ignore_errors=True)
    for kind, runs in out.items():
        wall, cpu = (statistics.median(r[k] for r in runs) for k in (0, 1))
        loads = [x for r in runs for x in r[2:]]
        print(
            f"   {kind} cache, median of {len(runs)}: {wall:.1f} s wall, {cpu:.1f} s CPU "
            f"(load {min(loads):.1f}-{max(loads):.1f})"
        )
    return out


def compile_log(name: str) -> None:
    print(f"\n2. {SCENES[name]}: JAX's log of one cold run (wall s per program; they overlap)")
    log_env = {"JAX_LOG_COMPILES": "1"}
    *_, stderr = _design(QUESTIONS[name], "0", log_env)
    totals: dict = defaultdict(float)
    for phase, program, sec in LOG_LINE.findall(stderr):
        totals[(program, PHASES[phase])] += float(sec)
    rows = sorted(totals.items(), key=lambda kv: -kv[1])
    for (program, phase), sec in rows[:10]:
        print(f"   {program:24s} {phase:8s} {sec:7.2f}")
    print(f"   everything else         {sum(s for _, s in rows[10:]):7.2f}")


def in_process(name: str) -> None:
    import jax

    jax.config.update("jax_enable_x64", True)
    from cardiosoft.design import optimise

    print(f"\n3. {SCENES[name]}: one process, the Python API: the first target, then further ones")
    for i, kwargs in enumerate(FURTHER[name]):
        start, cpu = time.perf_counter(), time.process_time()
        r = optimise(SCENES[name], **kwargs)
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu
        (t, *_) = r.targets
        what = "first (compile included)" if i == 0 else "further (compiled)"
        limit = TARGET_FURTHER_S if i else TARGET_FRESH_S
        print(
            f"   {what:25s} {t.target_sv_ml:5.1f} ml: {wall:6.2f} s wall ({wall / limit:.2f} of "
            f"{limit:g} s), {cpu:.2f} s CPU, load {_load():.1f}; reached {r.reached}, SV "
            f"{t.sv_ml:.2f} ml, Omega {r.omega:.3f}, C {r.shortening:.4f}, {r.iterations} rounds"
        )
        print(f"      {_split(r.timings)}")


def recovery() -> None:
    import cardiosoft as cs
    from cardiosoft.design import optimise
    from cardiosoft.units import ml

    heads = [30, 60, 90]
    known = {"omega": 3.2, "shortening": 0.45}
    print(f"\n4. recovery: Omega {known['omega']}, C {known['shortening']} at {heads} mmHg, 60 bpm")
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="fresh processes per scene (3)")
    parser.add_argument("--scenes", nargs="+", choices=QUESTIONS, default=list(QUESTIONS))
    parser.add_argument(
        "--skip", nargs="+", default=[], choices=("fresh", "log", "api", "recovery")
    )
    args = parser.parse_args(argv)
    print("cardiosoft design benchmark (issues #13, #25)")
    print(f"machine: os.cpu_count() = {os.cpu_count()}, load average {_load():.2f}")
    start = time.perf_counter()
    for name in args.scenes:
        if "fresh" not in args.skip:
            fresh(name, args.repeat)
        if "log" not in args.skip:
            compile_log(name)
        if "api" not in args.skip:
            in_process(name)
    if "recovery" not in args.skip:
        recovery()
    print(f"\ntotal wall time {time.perf_counter() - start:.0f} s; load average now {_load():.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
