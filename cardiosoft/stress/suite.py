"""The suite: which batches a run takes (:func:`plan`: the full suite, or the CI's quick
subset) and running them (:func:`run_suite`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor

from cardiosoft.scene import LOOP_SCENE_NAMES, SCENE_NAMES, load_scene
from cardiosoft.solve import ACCURACY_PRESETS
from cardiosoft.stress.cases import (
    GRID_BPMS,
    GROUPS,
    PROPERTY_EXAMPLES,
    QUICK_BPMS,
    QUICK_STIFF,
    Batch,
    dynamic_scenes,
    grid_batches,
    long_batches,
    preload_batches,
    shooting_batches,
    stiff_batches,
    valve_batches,
    windkessel_scenes,
)
from cardiosoft.stress.checks import STATUSES, Outcome
from cardiosoft.stress.draws import property_batches
from cardiosoft.stress.loop_cases import LOOP_BPMS, LoopBatch, loop_batches, quick_loop_batches
from cardiosoft.stress.model_cases import ModelBatch, model_batches
from cardiosoft.stress.report import SuiteReport
from cardiosoft.stress.runner import Runner, energy_available

__all__ = ["plan", "run_suite"]


def plan(
    *,
    quick: bool = False,
    scenes: Sequence[str] | None = None,
    groups: Sequence[str] | None = None,
    presets: Sequence[str] | None = None,
    bpms: Sequence[float] | None = None,
    examples: int | None = None,
    seed: int = 14,
) -> list[Batch | LoopBatch | ModelBatch]:
    """The batches of a run, in order. ``quick``: the CI subset (one compile per scene
    structure, plus the command line's). The other arguments narrow the full suite; the
    closed-loop scenes (:data:`~cardiosoft.scene.LOOP_SCENE_NAMES`) run in group
    ``closed_loop`` only, at :data:`~cardiosoft.stress.LOOP_BPMS` unless ``bpms`` is given."""
    every = SCENE_NAMES + LOOP_SCENE_NAMES
    scenes = list(every if scenes is None else scenes)
    for name in scenes:
        if name not in every:
            raise ValueError(f"scene = {name!r}: allowed {', '.join(every)}")
    groups = list(GROUPS if groups is None else groups)
    for g in groups:
        if g not in GROUPS:
            raise ValueError(f"group = {g!r}: allowed {', '.join(GROUPS)}")
    loops = [s for s in scenes if s in LOOP_SCENE_NAMES] if "closed_loop" in groups else []
    models = model_batches(scenes, quick) if "models" in groups else []
    scenes = [s for s in scenes if s in SCENE_NAMES]
    presets = list(ACCURACY_PRESETS if presets is None else presets)
    loop_bpms = [float(b) for b in (LOOP_BPMS if bpms is None else bpms)]
    bpms = [float(b) for b in (GRID_BPMS if bpms is None else bpms)]
    out: list[Batch | LoopBatch | ModelBatch] = []
    if quick:
        # One compiled solve per scene structure (the bench, a Windkessel, the static strokes);
        # the command line only for the static scene: each dynamic one compiles its own solve.
        cli = "cli" in groups
        if "grid" in groups:
            for name in scenes:
                if load_scene(name).static:
                    out += grid_batches([name], [], [], cli_at=("default", 60.0) if cli else None)
                elif load_scene(name).afterload.has_heads:
                    out += grid_batches([name], ["default"], [60.0, 300.0])
                else:
                    out += grid_batches([name], ["default"], [60.0])
        if "stiff" in groups:
            out += [b for b in stiff_batches(scenes, [60.0]) if b.title in QUICK_STIFF]
        if "valves" in groups:
            out += valve_batches(windkessel_scenes(scenes)[-1:], [60.0], ideal=False)
        if "preload" in groups:
            out += preload_batches(windkessel_scenes(scenes)[:1], [60.0])
        if "property" in groups:
            n = 1 if examples is None else examples
            # The static scene's draws, numbers and all; the dynamic scenes' members only, at
            # the grid's rates. A member whose rate or numbers are drawn from the whole range
            # (1e-308 up) may run its 16384 steps a beat, minutes for its batch: the full run.
            static = [s for s in scenes if load_scene(s).static]
            out += property_batches(static, n, seed, skip_minimal=True)
            out += property_batches(
                dynamic_scenes(scenes), n, seed, skip_minimal=True, numbers=False, bpms=QUICK_BPMS
            )
        return out + quick_loop_batches(loops) + models
    if "grid" in groups:
        out += grid_batches(
            scenes, presets, bpms, cli_at=("default", 60.0) if "cli" in groups else None
        )
    if "stiff" in groups:
        out += stiff_batches(scenes, [b for b in bpms if b in (10.0, 60.0, 300.0)] or bpms[:1])
    if "valves" in groups:
        out += valve_batches(scenes, [b for b in bpms if b in (60.0, 180.0)] or bpms[:1])
    if "preload" in groups:
        out += preload_batches(scenes, [b for b in bpms if b in (60.0, 180.0)] or bpms[:1])
    if "long" in groups:
        out += long_batches(scenes, [b for b in bpms if b in (60.0, 300.0)] or bpms[:1])
    if "shooting" in groups:
        out += shooting_batches(scenes, [b for b in bpms if b >= 240.0] or bpms[-1:])
    if "property" in groups:
        n = PROPERTY_EXAMPLES if examples is None else examples
        out += property_batches(scenes, n, seed, numbers=False)
        out += property_batches(scenes, n, seed)
    return out + loop_batches(loops, loop_bpms) + models


def run_suite(
    batches: Sequence[Batch | LoopBatch | ModelBatch], log: Callable[[str], None] = print
) -> SuiteReport:
    """Run ``batches`` (:func:`plan`), one progress line each; returns the report.

    The command-line checks run on a second thread beside the batches: each compiles the
    CLI's own solve, which a second core can do meanwhile (JAX compiles thread-safely)."""
    energy = energy_available()
    report = SuiteReport(energy=energy)
    if not energy:
        report.notes.append(
            "energy balance: not available (this cardiosoft has no energy account: "
            "solve_beats(energy=True) and BeatMetrics.energy_residual); not checked"
        )
        log(report.notes[-1])
    runner = Runner(energy)
    total = len(batches) + sum(b.cli for b in batches)
    width = max([8, *(len(b.group) for b in batches)])  # the group column of the progress lines
    done = 0

    def record(group: str, title: str, outcomes: list[Outcome], seconds: float):
        nonlocal done
        done += 1
        report.outcomes.extend(outcomes)
        report.times[group] = report.times.get(group, 0.0) + seconds
        c = dict.fromkeys(STATUSES, 0)
        for o in outcomes:
            c[o.status] += 1
        log(
            f"[{done:>3}/{total}] {group:<{width}} {title}: {len(outcomes)} cases, "
            + ", ".join(f"{c[s]} {s}" for s in STATUSES if c[s] or s != "known")
            + f" ({seconds:.1f} s)"
        )

    def timed(work, batch):
        start = time.perf_counter()
        outcomes = work(batch)
        return outcomes, time.perf_counter() - start

    pending = []
    with ThreadPoolExecutor(1) as pool:
        for batch in batches:
            if batch.cli:
                pending.append((batch, pool.submit(timed, runner.cli, batch)))
            record(batch.group, batch.title, *timed(runner.run, batch))
            for item in [p for p in pending if p[1].done()]:
                pending.remove(item)
                record("cli", f"{item[0].title} via the CLI", *item[1].result())
        for batch, future in pending:
            record("cli", f"{batch.title} via the CLI", *future.result())
    return report
