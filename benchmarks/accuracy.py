"""What accuracy costs in time on the paper's bench (scene "bench-dynamic", 60 bpm).

    python benchmarks/accuracy.py

Prints three sections of tables and asserts nothing about time (DESIGN.md section 4;
notes/diffrax-practice.md section 6: EQX_ON_ERROR=nan, float64, compile once, then
``min(timeit.repeat(...))`` around ``jax.block_until_ready``):

1. the accuracy presets ("fast", "default", "reference") on the 3 afterloads of the scene,
   vmapped to the periodic steady state as ``cardiosoft.run`` does: compile and run time, solver
   steps, and the error of the dynamic SV and the peak force against "reference"; then a
   work-precision sweep (steps vs SV error) over rtol at a fixed 5 beats, and where the time
   goes (the same beats with the two save modes, ``save="traces"`` and ``save="metrics"``);
2. batch throughput: one vmapped call over B afterloads against B separate calls;
3. a second method: scipy ``solve_ivp`` (RK45, LSODA) on the same vector field, piecewise between
   the actuation kinks, against diffrax for one afterload and 5 beats.

Only public names of cardiosoft are used. The solver call timed is the public batch solve
``cardiosoft.solve_beats`` with the configuration ``run()`` gives it
(``cardiosoft.batch.default_config``: the scene's preset, ``diffrax.ForwardMode``). It is jitted
inside: a timed call includes its small Python set-up (checking and stacking the members), but
not ``run()``'s result records (``run()`` itself is timed once in section 3 for comparison).
"""

from __future__ import annotations

import os

os.environ.setdefault("EQX_ON_ERROR", "nan")  # before equinox/diffrax are imported

import dataclasses
import itertools
import time
import timeit

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy  # noqa: E402
from jax.flatten_util import ravel_pytree  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

import cardiosoft  # noqa: E402
from cardiosoft import load_pump, load_scene, run, scene_circuit, solve_beats  # noqa: E402
from cardiosoft.batch import SAMPLES_PER_BEAT, SAVE_MODES, default_config  # noqa: E402
from cardiosoft.solve import solver_name  # noqa: E402
from cardiosoft.units import ml, mmHg  # noqa: E402

SCENE = "bench-dynamic"
BPM = 60.0
PRESETS = ("fast", "default", "reference")
BATCHES = (3, 12, 48)
SWEEP_RTOL = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9)
SWEEP_BEATS = 5
SCIPY_AFTERLOAD = 60.0  # mmHg
SCIPY_BEATS = 5
REPEAT = 5  # timed samples per call, of >= 0.2 s each (timeit autorange)


def first_call(fn):
    """Seconds of the first call (compile + run)."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t0


def steady(fns: dict, repeat=REPEAT) -> dict:
    """Steady seconds per call of each (already compiled) function: ``min(timeit.repeat)``.

    The samples of the functions are interleaved (round robin), so that load from other
    processes on a shared machine falls on all of them alike rather than on one.
    """
    timers, numbers = {}, {}
    for key, fn in fns.items():
        timers[key] = timeit.Timer(lambda fn=fn: jax.block_until_ready(fn()))
        numbers[key] = timers[key].autorange()[0]  # calls per sample: a sample lasts >= 0.2 s
    best = dict.fromkeys(fns, float("inf"))
    for _ in range(repeat):
        for key in fns:
            t = timers[key].timeit(numbers[key]) / numbers[key]
            best[key] = min(best[key], t)
    return best


def scene_config(scene, name: str):
    """The configuration ``run()`` uses for ``scene`` at accuracy ``name``."""
    return default_config(scene.replace(accuracy=name))


def member_stats(out):
    """Per member of a :class:`cardiosoft.BeatSolution`: SV (ml), peak force, steps, beats, ok."""
    return {
        "sv": np.asarray(out.metrics.stroke_volume) / ml,
        "force": np.asarray(out.metrics.peak_force),
        "steps": np.asarray(out.num_steps),
        "beats": np.asarray(out.beats),
        "ok": np.asarray(out.succeeded),
    }


def header():
    print(f"cardiosoft accuracy benchmark: scene {SCENE}, {BPM:g} bpm")
    print(
        f"machine: os.cpu_count() = {os.cpu_count()}, jax.devices() = {jax.devices()}, "
        f"float64 = {jax.config.jax_enable_x64}, load average {os.getloadavg()[0]:.2f} "
        "(other processes on the machine inflate timings)"
    )
    import diffrax
    import equinox

    print(
        f"jax {jax.__version__}, diffrax {diffrax.__version__}, equinox {equinox.__version__}, "
        f"scipy {scipy.__version__}, cardiosoft {getattr(cardiosoft, '__version__', '?')}, "
        f"EQX_ON_ERROR={os.environ['EQX_ON_ERROR']}"
    )


def section_presets(scene, pump):
    heads = jnp.asarray(scene.afterloads)
    max_beats, tol = int(scene.max_beats), scene.steady_tol  # what solve_beats stops at
    rows, seen, calls = {}, [], {}
    for name in ("reference", "default", "fast"):  # reference first: the others compare to it
        config = scene_config(scene, name)
        static_key = (solver_name(config), config.max_steps, config.dt0)
        calls[name] = lambda c=config: solve_beats(scene, afterload=heads, pump=pump, config=c)
        first = first_call(calls[name])
        rows[name] = dict(
            config=config,
            first=first,
            shared=static_key in seen,
            **member_stats(calls[name]()),
        )
        seen.append(static_key)
    times = steady(calls)
    for name, r in rows.items():
        r["run"] = times[name]
        r["compile"] = r["first"] - r["run"]

    ref = rows["reference"]
    print()
    print(
        f"1. Accuracy presets: {heads.size} afterloads "
        f"({', '.join(f'{h / mmHg:g}' for h in scene.afterloads)} mmHg) vmapped in one "
        f"solve_beats call (save='traces', as run()), beats to the steady state (tol {tol:g}, "
        f"at most {max_beats})"
    )
    print("   errors: largest over the afterloads, against 'reference'")
    print(
        f"{'preset':>9} {'rtol':>6} {'atol':>6} {'compile':>8} {'run':>8} {'run/':>6} "
        f"{'beats':>7} {'steps':>6} {'|dSV|':>8} {'rel':>8} {'|dF|':>8} {'rel':>8}"
    )
    print(
        f"{'':>9} {'':>6} {'':>6} {'s':>8} {'ms':>8} {'default':>6} "
        f"{'':>7} {'last':>6} {'ml':>8} {'':>8} {'N':>8} {'':>8}"
    )
    for name in PRESETS:
        r = rows[name]
        d_sv = np.max(np.abs(r["sv"] - ref["sv"]))
        r_sv = np.max(np.abs(r["sv"] - ref["sv"]) / ref["sv"])
        d_f = np.max(np.abs(r["force"] - ref["force"]))
        r_f = np.max(np.abs(r["force"] - ref["force"]) / ref["force"])
        beats = "/".join(str(b) for b in r["beats"])
        compile_s = f"{max(r['compile'], 0.0):.2f}" + ("*" if r["shared"] else " ")
        print(
            f"{name:>9} {float(r['config'].rtol):>6.0e} {float(r['config'].atol):>6.0e} "
            f"{compile_s:>8} {1e3 * r['run']:>8.2f} {r['run'] / rows['default']['run']:>6.2f} "
            f"{beats:>7} {int(r['steps'].sum()):>6} {d_sv:>8.1e} {r_sv:>8.1e} "
            f"{d_f:>8.1e} {r_f:>8.1e}" + ("" if r["ok"].all() else "  (a member FAILED)")
        )
    print(
        "   compile = first call - steady call; * = no new compile: rtol/atol are array leaves, "
        "so a preset with the same solver and max_steps reuses the compiled call"
    )
    print(
        "   run = one solve_beats call, its Python set-up included; steps = solver steps of the "
        "last beat, summed over the afterloads"
    )
    print(
        "   work-precision (presets, steps -> max |dSV|): "
        + "; ".join(
            f"{n} {int(rows[n]['steps'].sum())} -> "
            f"{np.max(np.abs(rows[n]['sv'] - ref['sv'])):.1e} ml"
            for n in ("fast", "default")
        )
    )

    # Work-precision at a fixed number of beats (no steady-state stopping in the error): one
    # compile for all tolerances (array leaves), reference = Tsit5 at rtol 1e-11. Only the
    # metrics are needed: save="metrics" (a compile of its own, not shared with section 3).
    def sweep_config(rtol):
        return dataclasses.replace(scene_config(scene, "default"), rtol=rtol, atol=rtol * 1e-3)

    def sweep_call(rtol):
        return solve_beats(
            scene,
            afterload=heads,
            beats=SWEEP_BEATS,
            save="metrics",
            pump=pump,
            config=sweep_config(rtol),
        )

    t0 = time.perf_counter()
    truth = member_stats(sweep_call(1e-11))
    compile_sweep = time.perf_counter() - t0
    print(
        f"   work-precision sweep, Tsit5, atol = 1e-3 rtol, exactly {SWEEP_BEATS} beats, "
        f"save='metrics', against rtol 1e-11 (one compile, {compile_sweep:.1f} s):"
    )
    print(f"   {'rtol':>6} {'steps':>6} {'run ms':>8} {'|dSV| ml':>9} {'|dF| N':>9}")
    times = steady({r: (lambda r=r: sweep_call(r)) for r in SWEEP_RTOL}, repeat=3)
    for rtol in SWEEP_RTOL:
        s = member_stats(sweep_call(rtol))
        print(
            f"   {rtol:>6.0e} {int(s['steps'].sum()):>6} {1e3 * times[rtol]:>8.2f} "
            f"{np.max(np.abs(s['sv'] - truth['sv'])):>9.1e} "
            f"{np.max(np.abs(s['force'] - truth['force'])):>9.1e}"
            + ("" if s["ok"].all() and truth["ok"].all() else "  (a member FAILED)")
        )

    # Where the time goes: the same beats to the steady state in the two save modes. Both
    # interpolate SAMPLES_PER_BEAT samples in every beat; "traces" carries them through the beat
    # loop and computes signals and metrics of the last beat once after it, "metrics" reduces
    # every beat to its metrics inside the loop. One compile per save mode.
    levels = {
        "fast": scene_config(scene, "fast"),
        "default": scene_config(scene, "default"),
        "reference": dataclasses.replace(scene_config(scene, "default"), rtol=1e-10, atol=1e-13),
    }
    calls, beats = {}, {}
    for save in SAVE_MODES:
        for name, config in levels.items():
            calls[name, save] = lambda s=save, c=config: solve_beats(
                scene, afterload=heads, save=s, pump=pump, config=c
            )
        first_call(calls["default", save])  # "traces": compiled above already
    for name in levels:
        beats[name] = "/".join(str(b) for b in member_stats(calls[name, "metrics"]())["beats"])
    times = steady(calls, repeat=3)
    print(
        f"   where the time goes (ms; the same beats to the steady state; 'reference' tolerances "
        f"at the default max_steps {levels['reference'].max_steps}): every beat interpolates "
        f"{SAMPLES_PER_BEAT} samples;"
    )
    print(
        "   save='traces' keeps them through the beat loop and computes signals + metrics of the "
        "last beat once after it; save='metrics' computes signals + metrics of every beat inside "
        "the loop and keeps only those"
    )
    print(f"   {'':>9} {'beats':>7} {'traces':>8} {'metrics':>8} {'metrics/':>9}")
    print(f"   {'':>9} {'':>7} {'ms':>8} {'ms':>8} {'traces':>9}")
    for name in levels:
        t_tr, t_me = times[name, "traces"], times[name, "metrics"]
        print(
            f"   {name:>9} {beats[name]:>7} {1e3 * t_tr:>8.2f} {1e3 * t_me:>8.2f} "
            f"{t_me / t_tr:>9.2f}"
        )
    return rows


def section_batch(scene, pump):
    config = scene_config(scene, "default")
    print()
    print(
        "2. Batch throughput, 'default': one solve_beats call over B afterloads (linspace 0..150 "
        "mmHg) vs B separate calls (each a batch of 1, compiled once)"
    )
    print(
        f"{'B':>4} {'compile':>8} {'batched':>9} {'per mbr':>8} {'separate':>9} {'per mbr':>8} "
        f"{'speedup':>8} {'beats':>6} {'steps/mbr':>10}"
    )
    print(
        f"{'':>4} {'s':>8} {'ms':>9} {'ms':>8} {'ms':>9} {'ms':>8} {'':>8} {'min-max':>6} "
        f"{'min-max':>10}"
    )
    compiled_single = False
    for b in BATCHES:
        heads = np.linspace(0.0, 150.0, b) * mmHg

        def batch(heads=heads):
            return solve_beats(scene, afterload=heads, pump=pump, config=config)

        def separate(heads=heads):  # dispatch all, then wait
            return [
                solve_beats(scene, afterload=heads[i : i + 1], pump=pump, config=config)
                for i in range(heads.size)
            ]

        first = first_call(batch)
        stats = member_stats(batch())
        if not compiled_single:
            first_call(lambda h=heads[:1]: batch(h))  # the batch of 1 of `separate`
            compiled_single = True
        times = steady({"batch": batch, "separate": separate}, repeat=3)
        t_batch, t_sep = times["batch"], times["separate"]
        print(
            f"{b:>4} {max(first - t_batch, 0.0):>8.2f} {1e3 * t_batch:>9.2f} "
            f"{1e3 * t_batch / b:>8.3f} "
            f"{1e3 * t_sep:>9.2f} {1e3 * t_sep / b:>8.3f} {t_sep / t_batch:>8.2f} "
            f"{stats['beats'].min():>2}-{stats['beats'].max():<3} "
            f"{stats['steps'].min():>4}-{stats['steps'].max():<5}"
        )
    print(
        "   speedup = separate / batched; a batch runs its while loops until its slowest member "
        "is done (most beats, most steps); every call includes solve_beats's Python set-up; "
        "compile of B = 3 is shared with section 1"
    )


def section_scipy(scene, pump):
    head = SCIPY_AFTERLOAD * mmHg
    config = scene_config(scene, "default")
    rtol, atol = float(config.rtol), float(config.atol)
    print()
    print(
        f"3. scipy solve_ivp vs diffrax Tsit5: {SCIPY_AFTERLOAD:g} mmHg, exactly {SCIPY_BEATS} "
        f"beats from rest, rtol {rtol:g}, atol {atol:g} ('default')"
    )

    # diffrax: run() for the answer, then its one solve_beats call for the time
    def run_once():
        return run(scene, afterload=[SCIPY_AFTERLOAD], beats=SCIPY_BEATS, pump=pump)

    first_run = first_call(run_once)
    v_diffrax = float(run_once().members[0].traces["volume"][-1])

    def simulate():
        return solve_beats(
            scene, afterload=jnp.asarray([head]), beats=SCIPY_BEATS, pump=pump, config=config
        )

    first_call(simulate)  # compiled by run() already: same static arguments
    diffrax_steps = int(member_stats(simulate())["steps"][0])

    # scipy: the same circuit's field, flattened, jitted numpy-in/numpy-out
    circuit = scene_circuit(scene, pump, head)
    y0, unravel = ravel_pytree(circuit.init())
    i_volume = int(unravel(jnp.arange(y0.size, dtype=y0.dtype))["volume"])  # its flat index

    def flat(t, x):
        return ravel_pytree(circuit(t, unravel(x)))[0]

    f_jit = jax.jit(flat)
    jac_jit = jax.jit(jax.jacfwd(flat, argnums=1))

    def fun(t, x):
        return np.asarray(f_jit(t, x))

    def jac(t, x):
        return np.asarray(jac_jit(t, x))

    y0 = np.asarray(y0)
    fun(0.0, y0), jac(0.0, y0)  # compile
    kinks = np.unique(np.asarray(circuit.actuation.kink_times(SCIPY_BEATS)))
    period = float(circuit.actuation.period)

    def solve(method, rtol, atol):
        y, steps, nfev, njev, last_beat_steps = y0, 0, 0, 0, 0
        kw = {"jac": jac} if method in ("LSODA", "BDF", "Radau") else {}
        for a, b in itertools.pairwise(kinks):
            sol = solve_ivp(fun, (a, b), y, method=method, rtol=rtol, atol=atol, **kw)
            if not sol.success:
                raise RuntimeError(f"{method} failed on [{a}, {b}]: {sol.message}")
            y = sol.y[:, -1]
            steps += sol.t.size - 1
            nfev, njev = nfev + sol.nfev, njev + sol.njev
            if a >= (SCIPY_BEATS - 1) * period - 1e-12:
                last_beat_steps += sol.t.size - 1
        return y, steps, last_beat_steps, nfev, njev

    solved = {m: solve(m, rtol, atol) for m in ("RK45", "LSODA")}
    times = steady(
        {
            "diffrax": simulate,
            "run()": run_once,
            "field call": lambda: fun(0.1, y0),
            **{m: (lambda m=m: solve(m, rtol, atol)) for m in solved},
        },
        repeat=3,
    )
    t_diffrax, t_run, t_call = times["diffrax"], times["run()"], times["field call"]
    y_tight = solve("DOP853", 1e-12, 1e-15)[0]
    v_tight = float(y_tight[i_volume])
    print(
        f"   diffrax: {1e3 * t_diffrax:.2f} ms the solve_beats call ({diffrax_steps} steps in the "
        f"last beat), {1e3 * t_run:.1f} ms the whole run() (first run() with compile: "
        f"{first_run:.1f} s)"
    )
    print(
        f"   volume errors against scipy DOP853 at rtol 1e-12, atol 1e-15: diffrax "
        f"{abs(v_diffrax - v_tight) / ml:.1e} ml"
    )
    print(
        f"{'method':>8} {'run ms':>8} {'/diffrax':>9} {'steps':>6} {'last beat':>9} {'nfev':>6} "
        f"{'njev':>5} {'V_end ml':>12} {'|V - V_diffrax|':>16} {'|V - V_tight|':>14}"
    )
    print(
        f"{'diffrax':>8} {1e3 * t_diffrax:>8.2f} {1.0:>9.1f} {'':>6} {diffrax_steps:>9} "
        f"{'':>6} {'':>5} {v_diffrax / ml:>12.6f} {'':>16} {abs(v_diffrax - v_tight) / ml:>14.1e}"
    )
    for method, (y, steps, last, nfev, njev) in solved.items():
        t = times[method]
        v = float(y[i_volume])
        print(
            f"{method:>8} {1e3 * t:>8.2f} {t / t_diffrax:>9.1f} {steps:>6} {last:>9} {nfev:>6} "
            f"{njev:>5} {v / ml:>12.6f} {abs(v - v_diffrax) / ml:>16.1e} "
            f"{abs(v - v_tight) / ml:>14.1e}"
        )
    print(
        f"   one jitted field call from Python costs {1e6 * t_call:.1f} us, "
        f"x nfev = {1e3 * t_call * solved['RK45'][3]:.1f} ms of RK45's "
        f"{1e3 * times['RK45']:.1f} ms (state of {y0.size} numbers)"
    )
    print(
        f"   scipy integrates piecewise over the {kinks.size - 1} intervals between actuation "
        "kinks; diffrax clips its steps to the same kinks (jump_ts)"
    )


def main():
    t_start = time.perf_counter()
    header()
    jax.block_until_ready(jnp.ones(3) + 1.0)  # backend start-up out of the first timing
    scene = load_scene(SCENE).replace(bpm=BPM)
    pump = load_pump()
    section_presets(scene, pump)
    section_batch(scene, pump)
    section_scipy(scene, pump)
    print()
    print(f"total wall time {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
