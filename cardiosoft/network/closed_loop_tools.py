"""What the tools do with a closed-loop scene (:class:`~cardiosoft.network.loop_scene.LoopScene`):
the same namespace as the open-loop scenes' (:mod:`cardiosoft.open_loop_tools`, which lists its
names), answered by the closed loop's modules (:mod:`cardiosoft.scene_tools` picks it)."""

from __future__ import annotations

import numpy as np

from cardiosoft.network.closed_loop import DEFAULT_ENGINE
from cardiosoft.network.loop_batch import loop_config as preset
from cardiosoft.network.loop_batch import solve_loop
from cardiosoft.network.loop_records import (
    banded_keys,
    loop_band_table,
    loop_table,
    loop_trace_columns,
    record_numbers,
)
from cardiosoft.network.loop_records import loop_summary_records as summary_records
from cardiosoft.network.loop_results import configure_loop as configure
from cardiosoft.network.loop_results import (
    flat_metrics,
    loop_flags,
    loop_member_results,
    pump_sides,
    run_loop,
)
from cardiosoft.network.loop_scene import LoopScene
from cardiosoft.pump import DEFAULT_ARTIFACT, load
from cardiosoft.results import RunResult
from cardiosoft.solve import rerun_settings

__all__ = [
    "addable_effects", "column_heads", "configure", "design", "heading", "member_count",
    "plot", "preset", "run", "simulate_members", "solve_beats", "summary_records",
    "svzerod_model", "sweep_flags", "sweep_panels", "sweep_variables", "table",
    "trace_columns", "uncertainty", "unsupported", "verified", "verify_rerun",
]  # fmt: skip

_UNSUPPORTED = {
    "compare_paper": "is not the paper's bench",
    "energy": "is a closed loop, which keeps no energy account yet",
    "bench_bands": "is a closed loop: its --uncertainty bands are its pump's posterior draws "
    "alone (simulate's), which --explain and sweep's bands do not take yet",
    "pump_design": "is a closed loop: cardiosoft.design.loop.optimise_loop designs its pumps",
}


def unsupported(scene: LoopScene, what: str) -> str | None:
    if what == "uncertainty" and not scene.pumps:
        return "has no soft pump, whose posterior draws the bands would hold"
    return _UNSUPPORTED.get(what)


def _refuse(scene: LoopScene, what: str, option: str) -> None:
    raise ValueError(f"{option}: scene {scene.name} {unsupported(scene, what)}")


def addable_effects(scene: LoopScene) -> tuple[str, ...]:
    return ()


def svzerod_model(scene: LoopScene, units: str, beats: int, pump=None) -> dict:
    from cardiosoft.network.export import to_svzerod

    return to_svzerod(scene, units, beats, pump)


def member_count(scene: LoopScene) -> int:
    return 1


def run(scene: LoopScene, *, beats=None, steady="beats", energy=False, config=None, pump=None):
    """One member, the scene itself (:func:`~cardiosoft.network.loop_results.run_loop`)."""
    if energy:
        _refuse(scene, "energy", "energy")
    return run_loop(scene, beats=beats, steady=steady, config=config, pump=pump)


def simulate_members(
    scene: LoopScene, labels, members, beats, steady, pump=None, energy=False, config=None
) -> RunResult:
    """The members of :func:`cardiosoft.run_designs` (``omega`` and ``shortening`` set every
    pump), solved in one batch and labelled."""
    if energy:
        _refuse(scene, "energy", "energy")
    pump = load(scene.pump) if pump is None else pump
    solution = solve_loop(
        scene, **members, beats=beats, steady=steady, pump=pump, config=config
    )  # fmt: skip
    return RunResult(scene, loop_member_results(scene, labels, solution, pump.domain))


def solve_beats(
    scene: LoopScene,
    *,
    omega=None,
    shortening=None,
    bpm=None,
    afterload=None,
    beats=None,
    save="traces",
    steady="beats",
    energy=False,
    pump=None,
    config=None,
    scene_draws=None,
    engine=DEFAULT_ENGINE,
):
    """:func:`cardiosoft.batch.solve_beats` of a closed loop:
    :func:`~cardiosoft.network.loop_batch.solve_loop`, ``omega`` and ``shortening`` setting
    every pump."""
    if afterload is not None:
        raise ValueError(f"afterload: scene {scene.name} is a closed loop, with no column head")
    if energy:
        _refuse(scene, "energy", "energy")
    if scene_draws is not None:
        _refuse(scene, "uncertainty", "scene_draws")
    return solve_loop(
        scene,
        bpm=bpm,
        omega=omega,
        shortening=shortening,
        beats=beats,
        save=save,
        steady=steady,
        pump=pump,
        config=config,
        engine=engine,
    )


def table(scene: LoopScene, records, paper=None, *, bands: bool = False) -> str:
    return loop_band_table(records) if bands else loop_table(records)


def trace_columns(result) -> list[tuple[str, str, float]]:
    return loop_trace_columns(result.members[0].traces)


def plot(result, path, records) -> None:
    from cardiosoft.plots import plot_closed_loop

    plot_closed_loop(result, path)


def heading(scene: LoopScene) -> str:
    # the surrogate is named when it is not the default, which every other run uses
    surrogate = [] if scene.pump == DEFAULT_ARTIFACT else [f"pump {scene.pump}"]
    pumps = [
        f"{c.upper()} pump Omega {getattr(scene, c).omega:g}, C {getattr(scene, c).shortening:g}"
        for c in scene.pumps
    ]
    return ", ".join([f"{scene.name} (closed loop) at {scene.bpm:g} bpm", *pumps, *surrogate])


def design(scene: LoopScene) -> dict:
    """The design of ``summary.json``: each pump's Omega and C."""
    pumps = {c: getattr(scene, c) for c in scene.pumps}
    return {"pumps": {c: {"omega": p.omega, "shortening": p.shortening} for c, p in pumps.items()}}


def sweep_variables(scene: LoopScene) -> dict:
    """A sweep's metric variables (:mod:`cardiosoft.sweep`; every pump gets the point's
    design): ``{name: (path in the metrics, scale to the unit, unit, long name)}``, named as
    ``summary.json``'s records (:func:`~cardiosoft.network.loop_records.record_numbers`)."""
    return record_numbers(pumps=pump_sides(scene))


def sweep_panels(scene: LoopScene) -> tuple:
    """A sweep map's three panels (``(variable, label, colour map)``): the first pump's stroke
    volume, the cardiac output (the best design is the one that maximises it) and the first
    pump's peak force."""
    side = pump_sides(scene)[0]
    return (
        (f"{side}_sv_ml", f"{side} pump stroke volume [ml]", "viridis"),
        ("left_co_l_min", "cardiac output [l/min]", "magma"),
        (f"{side}_peak_force_N", f"{side} pump peak cable force [N]", "cividis"),
    )


def sweep_flags(scene: LoopScene, metrics, n: int, domain) -> np.ndarray:
    """Whether :func:`~cardiosoft.network.loop_results.loop_flags` flags each of the first ``n``
    members of a batch's metrics."""
    sides = pump_sides(scene)
    return np.array(
        [bool(loop_flags(flat_metrics(metrics, i), sides, domain)) for i in range(n)], bool
    )


def column_heads(scene: LoopScene, given, action: str):
    """A closed loop has no water column: None, and ``given`` heads are refused."""
    if given is not None:
        raise ValueError(
            f"afterload: scene {scene.name} is a closed loop, which has no column head to {action}"
        )
    return None


UNCERTAINTY = (
    "the pump's posterior draws alone: the model discrepancy was measured on the bench, not in "
    "a circulation, and is not added"
)
"""What a closed loop's ``--uncertainty`` band holds."""


def uncertainty(scene: LoopScene, posterior, *, beats=None, steady="beats"):
    """``--uncertainty`` of a closed loop: the pump's posterior draws (``posterior.pump``, an
    ensemble) solved in one call (:func:`~cardiosoft.network.loop_batch.solve_loop`), and per
    member ``{record key: Band}`` of the pump sides' SV, EF, CO and peak force and the mean
    pressures (:func:`~cardiosoft.network.loop_records.banded_keys`): the 95 % band of the draws
    that solved (and settled, unless ``beats``). Returns the bands, per member the first
    failed draw's message (or ""), the draws and what the band holds (:data:`UNCERTAINTY`)."""
    from cardiosoft.metrics import field_at
    from cardiosoft.posterior import band

    sides = pump_sides(scene)
    out = solve_loop(scene, pump=posterior.pump, beats=beats, steady=steady, save="metrics")
    ok = np.asarray(out.succeeded) & (np.asarray(out.steady) | (beats is not None))
    numbers = record_numbers(pumps=sides)
    bands, messages = [], []
    for i in range(ok.shape[1]):
        good, failed = ok[:, i], int((~ok[:, i]).sum())
        member = {}
        for key in banded_keys(sides):
            path, scale = numbers[key][:2]
            values = np.asarray(field_at(out.metrics, path))[good, i] / scale
            member[key] = band(values, values, failed)  # no discrepancy: the draws alone
        bands.append(member)
        bad = np.flatnonzero(~good)
        messages.append(out.message((int(bad[0]), i)) if bad.size else "")
    return bands, messages, int(ok.shape[0]), {"holds": UNCERTAINTY}


def verified(scene: LoopScene) -> tuple[tuple[str, str, str], ...]:
    """The record numbers ``--verify`` checks, ``(key, name, unit)``: every number of the
    loop's record (:func:`~cardiosoft.network.loop_records.record_numbers`, a pump's only on
    its side)."""
    numbers = record_numbers(pumps=pump_sides(scene))
    return tuple((key, long_name, unit)
                 for key, (_, _, unit, long_name) in numbers.items())  # fmt: skip


def verify_rerun(result: RunResult, config, *, beats=None, steady="beats", pump=None):
    """The loop solved again at ``config`` (:func:`cardiosoft.verify_run`): the rerun, the
    run's and the rerun's settings in words, whether it succeeded."""
    scene = result.scene
    if len(result.members) != 1:
        raise ValueError(
            "verify: result is not a cardiosoft.run() of its scene (one member); a "
            "run_designs() of several designs is not supported"
        )
    solution = solve_loop(scene, beats=beats, steady=steady, pump=pump, config=config)
    reference = RunResult(scene, loop_member_results(scene, [scene.name], solution))
    settings = rerun_settings(scene.accuracy, preset(scene), config)
    return reference, *settings, bool(np.all(np.asarray(solution.succeeded)))
