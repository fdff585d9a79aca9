"""Throughput of metric-only sweeps (issue #15): beats per second, where the time goes, scipy.

    python benchmarks/sweep_throughput.py            # about 6 minutes on 2 CPU cores
    python benchmarks/sweep_throughput.py --quick    # sections 1-3 at one batch size

Scene ``bench-dynamic`` (the paper's bench, its 30 bpm), at 60 mmHg, designs drawn uniformly
from Omega in [1, 5] x C in [0.2, 0.6], a fixed number of beats from rest. Prints, asserting
nothing about time (DESIGN.md section 4; ``notes/diffrax-practice.md`` section 6: EQX_ON_ERROR=nan,
float64, compile excluded, ``min(timeit.repeat)`` around ``jax.block_until_ready``):

1. the public batch solve as ``cardiosoft.sweep`` calls it (``solve_beats(save="metrics",
   beats=N)``) over batch sizes B: compile time, wall time and process CPU time of a steady
   call, beats per second (wall) and per CPU-second, against the issue's 100,000 beats/s;
2. where the time goes, per member and beat, at B = 1024: the same beats built from public
   pieces (``cardiosoft.periodic.periodic_beats`` on ``cardiosoft.scene_circuit``): the solver's
   steps alone (each beat's end state), then with the last beat integrated once more with its
   401 samples, signals and metrics (what ``save="metrics"`` does); one vector-field
   evaluation;
3. scipy ``solve_ivp`` (RK45, the same vector field flattened and jitted, the same rtol/atol,
   piecewise between the actuation kinks) for one member, per beat, against section 1, side by
   side in this run;
4. float32 and two XLA host devices (the batch sharded over both cores), each in a fresh
   process of this script, with the float32 stroke volumes against float64's;
5. ``python -m cardiosoft.sweep`` over a 64 x 64 grid at one afterload from a fresh process
   (to the steady state, compile included), against the issue's 60 s.

Wall times on a shared machine are inflated by other processes (the load average is printed at
the start of each section); CPU time of this process is not, and shows what the work costs.
"""

from __future__ import annotations

import os

os.environ.setdefault("EQX_ON_ERROR", "nan")  # before equinox/diffrax are imported

import argparse
import dataclasses
import itertools
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", os.environ.get("SWEEP_BENCH_FLOAT32") != "1")

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.flatten_util import ravel_pytree  # noqa: E402

import cardiosoft  # noqa: E402
from cardiosoft import load_pump, load_scene, scene_circuit, solve_beats  # noqa: E402
from cardiosoft.batch import PULL_SAMPLES, SAMPLES_PER_BEAT, default_config  # noqa: E402
from cardiosoft.metrics import beat_metrics  # noqa: E402
from cardiosoft.periodic import periodic_beats  # noqa: E402
from cardiosoft.units import ml, mmHg  # noqa: E402

SCENE = "bench-dynamic"
AFTERLOAD = 60.0  # mmHg
BEATS = 5
BATCHES = (256, 1024, 4096)
PROFILE_BATCH = 1024
TARGET = 100_000  # beats/s, issue #15
REPEAT = 3
ROOT = Path(__file__).resolve().parent.parent


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (5 min {five:.2f})"


def designs(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    return rng.uniform(1.0, 5.0, n), rng.uniform(0.2, 0.6, n)


def timed(fn, repeat=REPEAT):
    """(first call s, best steady wall s, CPU s of that call, last result)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    best, cpu = float("inf"), float("inf")
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = jax.block_until_ready(fn())
        w, c = time.perf_counter() - w, time.process_time() - c
        if w < best:
            best, cpu = w, c
    return first, best, cpu, out


def header():
    model = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import diffrax
    import scipy

    print(f"cardiosoft sweep throughput benchmark: scene {SCENE}, {AFTERLOAD:g} mmHg")
    print(
        f"machine: {platform.machine()} {model}, os.cpu_count() = {os.cpu_count()}, "
        f"jax.devices() = {jax.devices()}, float64 = {jax.config.jax_enable_x64}, {load()}"
    )
    print(
        f"jax {jax.__version__}, diffrax {diffrax.__version__}, equinox {eqx.__version__}, "
        f"scipy {scipy.__version__}, cardiosoft {cardiosoft.__version__}, "
        f"XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r}"
    )


# ------------------------------------------------------------------------------ 1. solve_beats


def throughput(scene, pump, batch: int, beats: int = BEATS) -> dict:
    omega, c = designs(batch)

    def call():
        return solve_beats(
            scene,
            omega=omega,
            shortening=c,
            afterload=AFTERLOAD * mmHg,
            beats=beats,
            save="metrics",
            pump=pump,
        )

    first, wall, cpu, out = timed(call)
    return {
        "batch": batch,
        "compile": first - wall,
        "wall": wall,
        "cpu": cpu,
        "beats_per_s": batch * beats / wall,
        "beats_per_cpu_s": batch * beats / cpu,
        "steps": float(np.mean(out.num_steps)),
        "ok": bool(np.all(out.succeeded)),
        "sv": np.asarray(out.metrics.stroke_volume) / ml,
    }


def print_throughput(rows, title):
    print(title)
    print(
        f"{'B':>6} {'compile':>8} {'wall':>9} {'cpu':>9} {'beats/s':>9} {'/target':>8} "
        f"{'beats/cpu-s':>11} {'steps/beat':>10}"
    )
    print(f"{'':>6} {'s':>8} {'ms':>9} {'ms':>9} {'wall':>9} {'':>8} {'':>11} {'last':>10}")
    for r in rows:
        print(
            f"{r['batch']:>6} {r['compile']:>8.1f} {1e3 * r['wall']:>9.1f} {1e3 * r['cpu']:>9.1f} "
            f"{r['beats_per_s']:>9,.0f} {r['beats_per_s'] / TARGET:>8.3f} "
            f"{r['beats_per_cpu_s']:>11,.0f} {r['steps']:>10.1f}"
            + ("" if r["ok"] else "  (a member FAILED)")
        )


# ------------------------------------------------------------------------------ 2. profile


def save_times(circuit):
    """The samples of a beat as the batch solve takes them: the pull, then the rest."""
    actuation = circuit.actuation
    t_pull = actuation.pull_fraction * actuation.period
    pull = jnp.linspace(0.0, 1.0, PULL_SAMPLES) * t_pull
    n_rest = SAMPLES_PER_BEAT - PULL_SAMPLES
    rest = t_pull + jnp.linspace(0.0, 1.0, n_rest + 1)[1:] * (actuation.period - t_pull)
    return jnp.concatenate([pull, rest])


def metrics(circuit, ts, ys):
    signals = jax.vmap(circuit.signals)(ts, ys)
    reference = circuit.afterload.node_pressure(circuit.afterload.init())
    return beat_metrics(
        ts, ys["volume"], signals, PULL_SAMPLES, circuit.actuation.period, reference
    ).stroke_volume


@eqx.filter_jit
def beats_kept(scene, pump, omega, c, config, mode: str, beats: int):
    """``beats`` beats of each member from rest: ``"steps"`` keeps each beat's end state only;
    ``"metrics"`` then integrates the last beat once more with its samples and metrics, as
    ``solve_beats(save="metrics")`` does."""

    def one(o, s):
        member = dataclasses.replace(scene, omega=o, shortening=s)
        circuit = scene_circuit(member, pump, AFTERLOAD * mmHg)
        period = circuit.actuation.period
        out = periodic_beats(
            circuit,
            circuit.init(),
            period,
            None if mode == "steps" else save_times(circuit),
            jump_ts=circuit.actuation.kink_times(1),
            total_volume=circuit.total_volume,
            max_beats=beats,
            tol=0.0,
            config=config,
            observe=lambda ts, ys: metrics(circuit, ts, ys),
        )
        return (out.y_end["volume"] if mode == "steps" else out.observed), out.num_steps

    return jax.vmap(one)(omega, c)


@eqx.filter_jit
def field_cost(scene, pump, omega, c, n: int):
    """``n`` explicit Euler steps of the vector field per member: its cost per evaluation."""

    def one(o, s):
        member = dataclasses.replace(scene, omega=o, shortening=s)
        circuit = scene_circuit(member, pump, AFTERLOAD * mmHg)
        period = circuit.actuation.period
        dt = period / n

        def body(i, y):
            dy = circuit(i * dt, y)
            return jax.tree_util.tree_map(lambda a, b: a + 1e-3 * dt * b, y, dy)

        return jax.lax.fori_loop(0, n, body, circuit.init())["volume"]

    return jax.vmap(one)(omega, c)


def profile(scene, pump, batch: int = PROFILE_BATCH, beats: int = BEATS) -> dict:
    omega, c = (jnp.asarray(a) for a in designs(batch))
    config = default_config(scene)
    rows = {}
    for mode in ("steps", "metrics"):
        first, wall, cpu, out = timed(
            lambda mode=mode: beats_kept(scene, pump, omega, c, config, mode, beats)
        )
        rows[mode] = {"compile": first - wall, "wall": wall, "cpu": cpu, "steps": out[1]}
    n_eval = 1000
    _, wall, cpu, _ = timed(lambda: field_cost(scene, pump, omega, c, n_eval))
    rows["field"] = {"wall": wall / n_eval, "cpu": cpu / n_eval}
    return rows


def print_profile(rows, batch: int = PROFILE_BATCH, beats: int = BEATS):
    n = batch * beats
    steps = float(np.mean(rows["metrics"]["steps"]))
    field = rows["field"]["cpu"] / batch
    print(
        f"2. Where the time goes: B = {batch}, {beats} beats from rest, per member and beat "
        f"(CPU time; wall in brackets); {steps:.1f} solver steps in the last beat"
    )
    print(f"{'':>44} {'us/beat':>9} {'(wall)':>9} {'beats/cpu-s':>11} {'share':>7}")
    base = rows["metrics"]["cpu"]
    labels = {
        "steps": "steps only (each beat's end state)",
        "metrics": "+ last beat again, sampled (save='metrics')",
    }
    for mode, label in labels.items():
        r = rows[mode]
        print(
            f"{label:>44} {1e6 * r['cpu'] / n:>9.1f} {1e6 * r['wall'] / n:>9.1f} "
            f"{n / r['cpu']:>11,.0f} {r['cpu'] / base:>7.2f}"
        )
    per_step = rows["steps"]["cpu"] / (n * steps)
    sampled = (rows["metrics"]["cpu"] - rows["steps"]["cpu"]) / batch
    beat = rows["steps"]["cpu"] / n
    print(
        f"   the sampled last beat (401 samples, signals, metrics) costs {1e6 * sampled:.0f} us "
        f"per member: {sampled / beat:.1f} beats of steps; its share falls as 1 / beats"
    )
    print(
        f"   one vector-field evaluation: {1e9 * field:.0f} ns per member (CPU); a Tsit5 step "
        f"(6 evaluations, error estimate, step control) costs {1e9 * per_step:.0f} ns, of which "
        f"the 6 evaluations {6 * field / per_step:.0%}"
    )


# ------------------------------------------------------------------------------ 3. scipy


def scipy_per_beat(scene, pump, beats: int = BEATS) -> dict:
    from scipy.integrate import solve_ivp

    config = default_config(scene)
    rtol, atol = float(config.rtol), float(config.atol)
    circuit = scene_circuit(scene.replace(omega=4.0, shortening=0.4), pump, AFTERLOAD * mmHg)
    y0, unravel = ravel_pytree(circuit.init())

    def flat(t, x):
        return ravel_pytree(circuit(t, unravel(x)))[0]

    f_jit = jax.jit(flat)

    def fun(t, x):
        return np.asarray(f_jit(t, x))

    y0 = np.asarray(y0)
    fun(0.0, y0)
    kinks = np.unique(np.asarray(circuit.actuation.kink_times(beats)))

    def solve():
        y, nfev = y0, 0
        for a, b in itertools.pairwise(kinks):
            sol = solve_ivp(fun, (a, b), y, method="RK45", rtol=rtol, atol=atol)
            if not sol.success:
                raise RuntimeError(f"RK45 failed on [{a}, {b}]: {sol.message}")
            y, nfev = sol.y[:, -1], nfev + sol.nfev
        return y, nfev

    _, wall, cpu, (_, nfev) = timed(solve)
    return {
        "wall": wall / beats,
        "cpu": cpu / beats,
        "nfev": nfev / beats,
        "rtol": rtol,
        "atol": atol,
    }


# ------------------------------------------------------------------------------ 4. children


def child(mode: str) -> None:
    """Run in a fresh process (float32 or two devices): print one JSON line of results."""
    scene, pump = load_scene(SCENE), load_pump()
    r = throughput(scene, pump, PROFILE_BATCH)
    result = {k: v for k, v in r.items() if k != "sv"} | {"sv": r["sv"].tolist()}
    if mode == "float32":
        p = profile(scene, pump)
        result["profile"] = {
            k: {"cpu": v["cpu"], "wall": v["wall"]} for k, v in p.items() if k != "field"
        } | {"field": p["field"]}
        result["profile"]["steps"]["steps"] = float(np.mean(p["steps"]["steps"]))
    result["devices"] = len(jax.devices())
    print("RESULT " + json.dumps(result))


def run_child(mode: str, env: dict) -> dict | None:
    out = subprocess.run(
        [sys.executable, __file__, "--child", mode],
        capture_output=True,
        text=True,
        env=os.environ | env,
        timeout=1800,
    )
    for line in out.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line.removeprefix("RESULT "))
    print(f"   {mode}: the child process failed:\n{out.stderr[-2000:]}")
    return None


# ------------------------------------------------------------------------------ 5. 64 x 64


def grid_64(tmp: Path) -> dict:
    out = tmp / "maps"
    t0 = time.perf_counter()
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "cardiosoft.sweep",
            "--omega",
            "1:5:64",
            "--shortening",
            "0.2:0.6:64",
            "--afterload",
            str(AFTERLOAD),
            "--out",
            str(out),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=1800,
    )
    wall = time.perf_counter() - t0
    if run.returncode != 0:
        print(run.stderr[-2000:])
        return {"wall": wall, "ok": False}
    import xarray as xr

    with xr.open_dataset(out / "sweep.nc") as ds:
        beats = int(ds["beats"].sum())
        steady = int(ds["steady"].sum())
        size = int(ds["steady"].size)
        chunk = int(ds.attrs["chunk"])
    return {
        "wall": wall,
        "ok": True,
        "beats": beats,
        "steady": steady,
        "size": size,
        "chunk": chunk,
    }


# ------------------------------------------------------------------------------ main


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="sections 1-3, B = 1024 only")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child:
        child(args.child)
        return
    start = time.perf_counter()
    header()
    scene, pump = load_scene(SCENE), load_pump()
    print()
    print(f"1. solve_beats(save='metrics', beats={BEATS}) as cardiosoft.sweep calls it ({load()})")
    rows = [throughput(scene, pump, b) for b in ((PROFILE_BATCH,) if args.quick else BATCHES)]
    print_throughput(rows, "")
    ref = next(r for r in rows if r["batch"] == PROFILE_BATCH)
    print(
        f"   target {TARGET:,} beats/s on 2 cores; the best batch reaches "
        f"{max(r['beats_per_s'] for r in rows):,.0f} wall, "
        f"{max(r['beats_per_cpu_s'] for r in rows):,.0f} per CPU-second (one core)"
    )

    print()
    print(f"({load()})")
    prof = profile(scene, pump)
    print_profile(prof)

    print()
    sp = scipy_per_beat(scene, pump)
    print(
        f"3. scipy solve_ivp RK45, one member (Omega 4, C 0.4), rtol {sp['rtol']:g}, atol "
        f"{sp['atol']:g}, {BEATS} beats from rest ({load()})"
    )
    t_diffrax = ref["wall"] / (ref["batch"] * BEATS)
    t_steps = prof["steps"]["wall"] / (PROFILE_BATCH * BEATS)
    print(
        f"   RK45: {1e3 * sp['wall']:.2f} ms per beat wall ({1e3 * sp['cpu']:.2f} ms CPU), "
        f"{sp['nfev']:.0f} field calls per beat"
    )
    print(
        f"   diffrax, B = {PROFILE_BATCH} (section 1): {1e6 * t_diffrax:.1f} us per beat wall: "
        f"{sp['wall'] / t_diffrax:,.0f}x RK45 (target 100x); CPU: "
        f"{sp['cpu'] / (ref['cpu'] / (ref['batch'] * BEATS)):,.0f}x"
    )
    print(
        f"   the steps alone (section 2, no samples): {1e6 * t_steps:.1f} us per beat wall: "
        f"{sp['wall'] / t_steps:,.0f}x RK45"
    )
    if args.quick:
        print(f"\ntotal wall time {time.perf_counter() - start:.0f} s")
        return

    print()
    print(f"4. float32 and two XLA host devices, fresh processes, B = {PROFILE_BATCH} ({load()})")
    f32 = run_child("float32", {"SWEEP_BENCH_FLOAT32": "1"})
    flags = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip()
    two = run_child("devices", {"XLA_FLAGS": flags})
    shown = [dict(ref, batch=ref["batch"])]
    print_throughput(shown, "   float64, one device (section 1):")
    if f32 is not None:
        print_throughput([f32], "   float32, one device:")
        d = np.abs(np.asarray(f32["sv"]) - ref["sv"])
        print(
            f"   float32 stroke volume against float64 (same members): largest difference "
            f"{d.max():.2e} ml, median {np.median(d):.2e} ml"
        )
        p32 = f32["profile"]
        for mode in ("steps", "metrics"):
            print(
                f"   float32 {mode:>9}: {PROFILE_BATCH * BEATS / p32[mode]['cpu']:>9,.0f} "
                f"beats/cpu-s (float64 {PROFILE_BATCH * BEATS / prof[mode]['cpu']:,.0f})"
            )
    if two is not None:
        print_throughput([two], f"   float64, {two['devices']} devices (the batch sharded):")

    print()
    print(f"5. python -m cardiosoft.sweep, 64 x 64 grid at {AFTERLOAD:g} mmHg ({load()})")
    with tempfile.TemporaryDirectory() as tmp:
        g = grid_64(Path(tmp))
    if g["ok"]:
        print(
            f"   fresh process, compile included, to the steady state: {g['wall']:.1f} s "
            f"(target 60 s); {g['steady']} of {g['size']} points steady, {g['beats']:,} member "
            f"beats, chunks of {g['chunk']}"
        )
    print(f"\ntotal wall time {time.perf_counter() - start:.0f} s ({load()})")


if __name__ == "__main__":
    main()
