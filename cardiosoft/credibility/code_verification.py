"""Code verification (ASME V&V 40): does the code solve its equations right?

Three kinds of evidence, recomputed:

1. the solver's **observed order of convergence** on the real vector field of shipped scenes,
   against Tsit5's nominal order 5 (Richardson: no reference solution needed);
2. **conservation**: the energy account of a beat closes to what the solver's tolerance allows,
   and the total fluid volume (a linear invariant) stays constant to round-off;
3. the **closed-form and peer checks** of the blocks (the project's own test files, rerun):
   closed forms, scipy second implementations, svZeroDSolver.

All states are SI inside; differences of the final state are reported in the units of
:data:`cardiosoft.periodic.PERIODIC_SCALES` (ml, ml/s, mmHg).
"""

from __future__ import annotations

import itertools
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp

import cardiosoft
from cardiosoft.credibility.evidence import Check, Section, source_root
from cardiosoft.periodic import PERIODIC_SCALES, in_phase
from cardiosoft.solve import SolverConfig, integrate, preset

__all__ = ["code_verification", "convergence"]

NOMINAL_ORDER = 5
"""Tsit5's order."""
ORDER_BAND = (4.5, 5.5)
"""Accepted observed order. With error C h^5 (1 + D h), the Richardson estimate is
5 + log2((1 + D h) / (1 + D h / 2)): +-0.5 allows the next term to be up to ~40 % of the
leading one at the coarser step, which is what "in the asymptotic range" means here."""
BASE_STEPS = 200
"""N of the sequence N, 2N, 4N, 8N equal steps a beat. Below ~100 the valve scene's explicit
solve is unstable (its valves are stiff); at 8N = 1600 the last difference (~1e-9 ml) is still
~50x the round-off floor measured at 3200 steps (~2e-11 ml), so no estimate is round-off."""
REFINEMENTS = (1, 2, 4, 8)
ORDER_SCENES = ("bench-dynamic", "lv-systemic")
ENERGY_SCENES = ("bench-dynamic", "lv-systemic")
LOOP_SCENES = ("heart", "tah")
VOLUME_BOUND = 1e-12
"""Relative drift of the total volume. The total is a linear function of the state, which
every Runge-Kutta method conserves exactly; only round-off is left (eps 2.2e-16 per step,
~1e2 steps a beat): 1e-12 is ~1e4 eps, and 1e6 below the relative tolerance (1e-6)."""
TEST_GROUPS = {
    "closed forms of the blocks": (
        "tests/test_circulation.py", "tests/test_actuation.py",
        "tests/test_geometry.py", "tests/test_units.py",
    ),
    "second implementations (scipy)": ("tests/test_valve_scenes.py", "tests/test_closed_loop.py"),
    "svZeroDSolver, the peer": (
        "tests/test_network.py", "tests/test_network_random.py",
        "tests/test_network_steady.py", "tests/test_network_loop.py",
        "tests/test_network_gen_alpha.py",
    ),
}  # fmt: skip
"""The test files that hold each kind of check (``tests/README.md`` writes the closed forms out)."""
SOURCE = "python -m cardiosoft.credibility"


@eqx.filter_jit
def _stretch(circuit, y, s0, s1, solver, steps: int):
    """The state at phase s1 from y at s0, in ``steps`` equal steps (cut at the pull's kinks)."""
    period = circuit.actuation.period
    sol = integrate(
        in_phase, y, s0, s1, args=(circuit, period),
        jump_ts=circuit.actuation.kink_times(1) / period,
        config=SolverConfig(solver, fixed_steps=steps),
    )  # fmt: skip
    return jax.tree_util.tree_map(lambda a: a[-1], sol.ys), sol.result


def _difference(a: dict, b: dict) -> float:
    """Largest difference of two states' periodic leaves, each in its PERIODIC_SCALES unit."""
    worst = 0.0
    for (path, x), z in zip(
        jax.tree_util.tree_flatten_with_path(a)[0], jax.tree_util.tree_leaves(b), strict=True
    ):
        name = path[-1].key
        if name in PERIODIC_SCALES:  # accumulators (drained volume...) are not states of a beat
            worst = max(worst, abs(float(x - z)) / PERIODIC_SCALES[name])
    return worst


def convergence(name: str, solver=None, base: int = BASE_STEPS) -> dict:
    """One beat of ``name``'s first member from rest with base * k equal steps, k in
    :data:`REFINEMENTS`. The k N steps are run as k stretches of N steps (the same grid as
    ``fixed_steps=kN`` over the beat): one compile serves every k.

    Returns ``steps``, ``differences`` |y_kN - y_2kN| (ml, ml/s, mmHg) and ``orders``
    log2 of the ratio of successive differences (Richardson)."""
    solver = diffrax.Tsit5() if solver is None else solver
    scene = cardiosoft.load_scene(name)
    circuit = cardiosoft.scene_circuit(scene, cardiosoft.load_pump(scene.pump))
    ends = []
    for k in REFINEMENTS:
        y = circuit.init()
        for j in range(k):
            s0, s1 = jnp.asarray(j / k), jnp.asarray((j + 1) / k)  # arrays: no recompile
            y, result = _stretch(circuit, y, s0, s1, solver, base)
            if not diffrax.is_successful(result):
                raise RuntimeError(f"{name}: the fixed-step solve with {k * base} steps failed")
        ends.append(y)
    diffs = [_difference(a, b) for a, b in itertools.pairwise(ends)]
    orders = [math.log2(a / b) for a, b in itertools.pairwise(diffs)]
    return {"steps": [k * base for k in REFINEMENTS], "differences": diffs, "orders": orders}


def _order_figure(folder: Path, runs: dict) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for name, run in runs.items():
        n = run["steps"][:-1]
        ax.loglog(n, run["differences"], "o-", label=name)
        guide = [run["differences"][0] * (n[0] / m) ** NOMINAL_ORDER for m in n]
        ax.loglog(n, guide, "k:", lw=1)
    ax.plot([], [], "k:", label="slope -5 (nominal)")
    ax.set_xlabel("equal steps per beat N")
    ax.set_ylabel("|y_N - y_2N| (ml, ml/s, mmHg)")
    ax.set_title("Tsit5 on the scenes' vector fields")
    ax.legend()
    fig.tight_layout()
    fig.savefig(folder / "code_verification_order.png", dpi=120)
    plt.close(fig)
    return "code_verification_order.png"


def _energy_bound(name: str, out) -> tuple[float, float]:
    """(energy_residual, its bound) of the member nearest its bound. The bound, from the
    tolerance: each step may err by atol + rtol V (m^3) in the volume, which the account
    prices at the largest pump pressure (Pa), so over the beat's steps the closure error is at
    most steps (atol + rtol EDV) max|p|, relative to the work put in (J)."""
    config = preset(cardiosoft.load_scene(name).accuracy)  # the tolerances the solve used
    m = out.metrics
    per_step = float(config.atol) + float(config.rtol) * m.edv
    p = jnp.maximum(jnp.abs(m.max_pump_pressure), jnp.abs(m.min_pump_pressure))
    bound = out.num_steps * per_step * p / jnp.abs(m.work_in)
    worst = int(jnp.argmax(m.energy_residual / bound))  # the member nearest its own bound
    return float(m.energy_residual[worst]), float(bound[worst])


def _run_tests(root: Path, files: tuple[str, ...]) -> tuple[int, int, float]:
    """(passed, failed + errors, seconds) of pytest's run of ``files`` from ``root``."""
    start = time.perf_counter()
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "not slow"]
    proc = subprocess.run([*cmd, *files], cwd=root, capture_output=True, text=True)
    summary = (proc.stdout.strip().splitlines() or [""])[-1]
    count = {w: int(n) for n, w in re.findall(r"(\d+) (passed|failed|error)", summary)}
    failed = count.get("failed", 0) + count.get("error", 0)
    return count.get("passed", 0), failed, time.perf_counter() - start


def _run_test_groups(root: Path, groups: dict[str, tuple[str, ...]]) -> dict[str, tuple]:
    """:func:`_run_tests` of each group, side by side: a pytest process is mostly one thread,
    and together they take about the longest group's time instead of the sum (on 2 cores,
    2 min instead of 3.5)."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(len(groups)) as pool:
        running = {group: pool.submit(_run_tests, root, files) for group, files in groups.items()}
        return {group: future.result() for group, future in running.items()}


def code_verification(folder: Path, quick: bool, progress) -> Section:
    """The code-verification section. ``folder``: where its figure is written (PNG);
    ``quick``: one scene per check and no test rerun (CI runs the tests itself; ~30 s);
    ``progress``: takes one line of text at a time."""
    folder = Path(folder)
    checks, text = [], []

    # 1. observed order of convergence
    runs = {}
    for name in ORDER_SCENES[:1] if quick else ORDER_SCENES:
        progress(f"order of convergence: {name}, {BASE_STEPS} to {8 * BASE_STEPS} steps a beat")
        runs[name] = run = convergence(name)
        p = run["orders"][-1]  # the finest pair: the one in the asymptotic range
        checks.append(Check(
            f"observed order of Tsit5, {name}", f"{ORDER_BAND[0]} to {ORDER_BAND[1]} (nominal 5)",
            f"{p:.2f}", "verification", ORDER_BAND[0] <= p <= ORDER_BAND[1], SOURCE,
        ))  # fmt: skip
    figure = _order_figure(folder, runs)
    rows = "\n".join(
        f"| {name} | {', '.join(f'{d:.2e}' for d in r['differences'])} | "
        f"{', '.join(f'{p:.2f}' for p in r['orders'])} |"
        for name, r in runs.items()
    )
    text.append(
        "### Observed order of convergence\n\n"
        f"One beat of each scene's first member from rest, on the library's own vector field "
        f"(`cardiosoft.scene_circuit`), integrated by Tsit5 (nominal order {NOMINAL_ORDER}) with "
        f"N = {', '.join(str(n) for n in runs[next(iter(runs))]['steps'])} equal steps "
        "(`SolverConfig(fixed_steps=N)`, steps cut at the pull's kinks as the batch solve does). "
        "The observed order is p = log2(|y_N - y_2N| / |y_2N - y_4N|) on the final state "
        "(largest difference over the states, in ml, ml/s and mmHg), so no reference solution "
        "is needed. The check takes the finest estimate; the band "
        f"{ORDER_BAND[0]} to {ORDER_BAND[1]} lets the next term of the error be up to ~40 % of "
        f"the leading one. Below ~100 steps a beat the valve scene's explicit solve is unstable "
        "(stiff valves): the coarse estimate sits above 5 there, not yet asymptotic. The finest "
        "difference (~1e-9) is ~50x the round-off floor.\n\n"
        "| scene | differences (N, 2N, 4N) | observed orders |\n|---|---|---|\n"
        f"{rows}\n\n![Differences of the final state against the steps]({figure})\n"
    )

    # 2. conservation: the energy account, and the volume
    energy_lines = []
    for name in ENERGY_SCENES[:1] if quick else ENERGY_SCENES:
        progress(f"energy account: {name}, to its steady state")
        out = cardiosoft.solve_beats(name, save="metrics", energy=True)
        residual, bound = _energy_bound(name, out)
        drift = float(jnp.max(out.volume_drift))
        checks.append(Check(
            f"energy account closes, {name}", f"<= {bound:.1e} (from the tolerance)",
            f"{residual:.1e}", "verification", residual <= bound, SOURCE,
        ))  # fmt: skip
        checks.append(Check(
            f"volume conserved, {name}", f"<= {VOLUME_BOUND:.0e} relative", f"{drift:.1e}",
            "verification", drift <= VOLUME_BOUND, SOURCE,
        ))  # fmt: skip
        energy_lines.append(f"| {name} | {residual:.1e} | {bound:.1e} | {drift:.1e} |")
    for name in () if quick else LOOP_SCENES:
        progress(f"blood volume of the closed loop: {name}, two beats")
        drift = float(jnp.max(cardiosoft.solve_beats(name, beats=2, save="state").volume_drift))
        checks.append(Check(
            f"blood volume conserved, {name}", f"<= {VOLUME_BOUND:.0e} relative", f"{drift:.1e}",
            "verification", drift <= VOLUME_BOUND, SOURCE,
        ))  # fmt: skip
        energy_lines.append(f"| {name} (closed loop) | | | {drift:.1e} |")
    text.append(
        "### Conservation\n\n"
        "**Energy.** `solve_beats(..., energy=True)` integrates the beat's energy account with "
        "the states; `energy_residual` is |work in - delivered - lost - stored change| over the "
        "energy carried. Its bound comes from the 'default' tolerance: each step may err by "
        "atol + rtol EDV in the volume, which the account prices at the largest pump pressure; "
        "over the beat's steps, relative to the work put in. **Volume.** The total fluid volume "
        "is linear in the state, which every Runge-Kutta method conserves exactly: its drift "
        f"(`volume_drift`) is round-off only, bounded by {VOLUME_BOUND:.0e} relative.\n\n"
        "| scene | energy residual | bound | volume drift |\n|---|---|---|---|\n"
        + "\n".join(energy_lines) + "\n"
    )  # fmt: skip

    # 3. the closed-form and peer checks, rerun
    if quick:
        text.append(
            "### Closed forms and peers\n\nNot rerun in the quick subset: CI runs these test "
            f"files itself ({', '.join(f'`{f}`' for g in TEST_GROUPS.values() for f in g)}).\n"
        )
    else:
        root = source_root()  # the checkout whose tests/ are rerun
        lines = []
        progress(f"rerunning the tests, side by side: {', '.join(TEST_GROUPS)}")
        results = _run_test_groups(root, TEST_GROUPS)
        for group, files in TEST_GROUPS.items():
            passed, failed, seconds = results[group]
            value = f"{passed} passed, {failed} failed"
            checks.append(Check(
                f"tests: {group}", "all pass", value, "verification",
                failed == 0 and passed > 0, f"pytest -m 'not slow' {' '.join(files)}",
            ))  # fmt: skip
            files_md = ", ".join(f"`{f}`" for f in files)
            lines.append(f"| {group} | {files_md} | {value} | {seconds:.0f} s |")
        text.append(
            "### Closed forms and peers\n\nThe project's tests of each block against closed forms "
            "(written out in `tests/README.md`), against second implementations in scipy, and "
            "against svZeroDSolver, rerun with `pytest -m 'not slow'` from "
            "the repository root, the groups side by side (the time: until each finished)."
            "\n\n| group | files | result | time |\n|---|---|---|---|\n"
            + "\n".join(lines) + "\n"
        )  # fmt: skip
    return Section(
        key="code_verification",
        title="Code verification",
        text="\n".join(text),
        checks=tuple(checks),
        figures=(figure,),
    )
