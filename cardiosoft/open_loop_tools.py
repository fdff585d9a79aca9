"""What the tools do with an open-loop scene (:class:`~cardiosoft.scene.Scene`: the pump with a
water-column or Windkessel afterload): its overrides, run, batch solve, records, table,
``traces.csv`` columns and figure.

Every kind of scene answers the same questions through its own namespace
(:func:`cardiosoft.scene_tools.tools`); the closed loop's is
:mod:`cardiosoft.network.closed_loop_tools`. The namespace's names:

- ``configure(scene, *, omega, shortening, bpm, afterload, accuracy)``: the scene with the
  user's overrides (user units), validated;
- ``addable_effects(scene)``: the effects ``--add-effect`` may switch on;
- ``preset(scene)``: the default :class:`~cardiosoft.solve.SolverConfig`;
- ``run(scene, *, beats, steady, energy, config, pump)``: a
  :class:`~cardiosoft.results.RunResult`;
- ``solve_beats(scene, **options)``: the batch solve (:func:`cardiosoft.batch.solve_beats`'s
  options);
- ``summary_records(result)``, ``table(scene, records, paper, bands)``,
  ``trace_columns(result)``, ``plot(result, path, records)``, ``heading(scene)``,
  ``design(scene)``, ``member_count(scene)``: the run's report;
- ``unsupported(scene, what)``: why this scene cannot do ``what`` (one of :data:`ABILITIES`),
  or None (:func:`cardiosoft.scene_tools.check_supported` raises with it);
- ``simulate_members(scene, labels, members, ...)``: the members of
  :func:`cardiosoft.run_designs`, solved in one batch and labelled;
- ``column_heads(scene, given, action)``: the water-column heads (mmHg) a grid runs at, or
  None; ``sweep_variables(scene)``, ``sweep_panels(scene)``, ``sweep_flags(scene, metrics, n,
  domain)``: a sweep's metric variables, its maps' panels and its flagged points
  (:mod:`cardiosoft.sweep`);
- ``uncertainty(scene, posterior, *, beats, steady)``: ``--uncertainty``'s bands per member
  (``{record key: Band}``), the first failed draw's message per member, the draws solved and
  summary.json's words on the band (``holds``: what it holds).
- ``svzerod_model(scene, units, beats, pump)``: the scene as an svZeroDSolver model (a dict,
  ``cardiosoft export --svzerod``).
- ``verified(scene)``, ``verify_rerun(result, config, *, beats, steady, pump)``: the record numbers
  ``--verify`` checks, ``(key, name, unit)``, and the run's members solved again at ``config``
  (:func:`cardiosoft.verify_run`): the rerun's :class:`~cardiosoft.results.RunResult`, the run's
  and the rerun's settings in words, and whether every member's rerun succeeded.
"""

from __future__ import annotations

import concurrent.futures
import math

import numpy as np

from cardiosoft._validate import check_range
from cardiosoft.batch import default_config, solve_beats, solve_static
from cardiosoft.pump import DEFAULT_ARTIFACT, PumpSurrogate, load
from cardiosoft.results import (
    SWEEP_VARIABLES,
    RunResult,
    flagged_members,
    member_results,
    summary_records,
)
from cardiosoft.scene import ACCURACY, ADDABLE_EFFECTS, RANGES, Scene
from cardiosoft.solve import rerun_settings
from cardiosoft.units import mmHg

__all__ = [
    "ABILITIES", "addable_effects", "column_heads", "configure", "design", "heading",
    "member_count", "plot", "preset", "run", "simulate_members", "solve_beats",
    "summary_records", "svzerod_model", "sweep_flags", "sweep_panels", "sweep_variables",
    "table", "trace_columns", "uncertainty", "unsupported", "verified", "verify_rerun",
]  # fmt: skip
# The namespace's names (every kind answers them). Also here, an open loop's own:
# VERIFIED, STATIC_POINTS, STATIC_GRID_REFINEMENT, fine_static (cardiosoft.verify names them).
ABILITIES = (
    "compare_paper", "verify", "uncertainty", "bench_bands", "designs", "export", "energy",
    "pump_design", "loop_design",
)  # fmt: skip
"""What a tool may ask a scene for besides a run (``unsupported``): ``--compare-paper``,
``--verify``, ``--uncertainty``, :mod:`cardiosoft.posterior`'s bands and ``--explain``,
:func:`cardiosoft.run_designs`, ``cardiosoft export``, the
energy account, :func:`cardiosoft.design.optimise`, :func:`cardiosoft.design.loop.optimise_loop`."""

preset = default_config


def configure(
    scene: Scene, *, omega=None, shortening=None, bpm=None, afterload=None, accuracy=None
) -> Scene:
    """``scene`` with the user's overrides (user units; None keeps the scene's value),
    validated: Omega, C, bpm, the column heads (mmHg) of a water column, the preset."""
    changes = {}
    for name, value, unit, field in (
        ("omega", omega, "", "omega"),
        ("shortening C", shortening, "", "shortening"),
        ("bpm", bpm, "bpm", "bpm"),
    ):
        if value is not None:
            check_range(name, value, unit, *RANGES[field], lo_open=field == "bpm")
            changes[field] = float(value)
    if afterload is not None:
        if not scene.afterload.has_heads:
            raise ValueError(
                f"afterload: scene {scene.name} has a {scene.afterload_type} "
                "afterload; --afterload sets water-column heads"
            )
        values = tuple(float(a) for a in np.atleast_1d(afterload))
        check_range("afterload", values, "mmHg", *RANGES["afterloads"])
        changes["afterloads"] = tuple(v * mmHg for v in values)
    if accuracy is not None:
        if accuracy not in ACCURACY:
            raise ValueError(f"accuracy = {accuracy!r}: allowed {', '.join(ACCURACY)}")
        changes["accuracy"] = accuracy
    return scene.replace(**changes) if changes else scene


def addable_effects(scene: Scene) -> tuple[str, ...]:
    return () if scene.static else ADDABLE_EFFECTS


def unsupported(scene: Scene, what: str) -> str | None:
    if what == "compare_paper" and not scene.afterload.has_heads:
        return "is not the paper's bench"
    if what == "uncertainty" and scene.static:
        return (
            "is static; the posterior's ensemble runs on the dynamic pump scenes "
            "(bench-dynamic, lv-systemic, rv-pulmonary or your own)"
        )
    if what == "export":
        from cardiosoft.network.export_open_loop import refusal

        return refusal(scene)
    if what == "loop_design":
        return "is not a closed loop: cardiosoft.design.optimise designs its pump"
    return None


def svzerod_model(scene: Scene, units: str, beats: int, pump=None) -> dict:
    from cardiosoft.network.export_open_loop import to_svzerod

    return to_svzerod(scene, units, beats, pump)


def member_count(scene: Scene) -> int:
    return max(1, len(scene.afterloads))


def run(scene: Scene, *, beats=None, steady="beats", energy=False, config=None, pump=None):
    """Every afterload of the scene (or the scene itself, with a Windkessel), labelled."""
    if scene.afterload.has_heads:
        labels = [f"{h / mmHg:g} mmHg" for h in scene.afterloads]
    else:
        labels = [scene.name]
    return simulate_members(scene, labels, {}, beats, steady, pump, energy, config)


def simulate_members(
    scene: Scene, labels, members, beats, steady, pump: PumpSurrogate | None, energy=False,
    config=None,
) -> RunResult:  # fmt: skip
    """Solve the members (all the scene's afterloads by default) and label the records."""
    pump = load(scene.pump) if pump is None else pump
    options = dict(beats=beats, steady=steady, energy=energy, pump=pump, config=config)
    if scene.static:
        static = solve_static(scene, **members, pump=pump)
        return RunResult(scene, member_results(labels, None, static, pump.domain))
    if not scene.afterload.has_heads:
        dynamic = solve_beats(scene, **members, **options)
        return RunResult(scene, member_results(labels, dynamic, None, pump.domain))
    # Compiling the dynamic solve takes seconds; the quasi-static strokes compile on a second
    # thread meanwhile (JAX traces and compiles thread-safely).
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        pending = pool.submit(solve_static, scene, **members, pump=pump)
        dynamic = solve_beats(scene, **members, **options)
        static = pending.result()
    return RunResult(scene, member_results(labels, dynamic, static, pump.domain))


# (header, unit, summary record key, format): one spec per table, so that headers, units and
# cells cannot drift apart. The paper's rows reuse the bench spec with the same keys.
_BENCH_COLUMNS = (
    ("afterload", "mmHg", "afterload_mmHg", ".0f"),
    ("static SV", "ml", "static_sv_ml", ".1f"),
    ("dynamic SV", "ml", "dynamic_sv_ml", ".1f"),
    ("peak force", "N", "peak_force_N", ".1f"),
    ("mech. work", "J", "mech_work_J", ".2f"),
    ("efficiency", "-", "efficiency", ".3f"),
    ("EF", "-", "ef", ".2f"),
    ("beats", "", "beats", "d"),
)
_CIRCULATION_COLUMNS = (
    ("scene", "", "label", "s"),
    ("SV", "ml", "dynamic_sv_ml", ".1f"),
    ("EDV", "ml", "edv_ml", ".1f"),
    ("ESV", "ml", "esv_ml", ".1f"),
    ("EF", "-", "ef", ".2f"),
    ("CO", "l/min", "cardiac_output_l_min", ".2f"),
    ("peak force", "N", "peak_force_N", ".1f"),
    ("mech. work", "J", "mech_work_J", ".2f"),
    ("beats", "", "beats", "d"),
)


def table(scene: Scene, records, paper=None, *, bands: bool = False) -> str:
    """The run's table; ``paper``: the paper's rows by column head (mmHg), printed under
    ours; with ``bands``, only the metrics with a ``<key>_band`` (and the member column), each
    cell the best estimate and its band ``[low, high]``."""
    from cardiosoft.console import fmt
    from cardiosoft.console import table as aligned

    columns = _BENCH_COLUMNS if scene.afterload.has_heads else _CIRCULATION_COLUMNS
    if bands:
        member = ("afterload_mmHg", "label")
        columns = [c for c in columns if c[2] in member or f"{c[2]}_band" in records[0]]

    def cell(r, key, spec):
        band = r.get(f"{key}_band") if bands else None
        text = fmt(r.get(key), spec)
        return text if band is None else f"{text} [{fmt(band[0], spec)}, {fmt(band[1], spec)}]"

    rows = []
    for r in records:
        rows.append([cell(r, key, spec) for _, _, key, spec in columns])
        if paper is not None and r.get("afterload_mmHg") in paper:
            p = {**paper[r["afterload_mmHg"]], "afterload_mmHg": None}
            rows.append(["  paper", *[fmt(p.get(key), spec) for _, _, key, spec in columns[1:]]])
    return aligned([c[0] for c in columns], [c[1] for c in columns], rows)


_TRACE_COLUMNS = (
    ("time_s", "time", 1.0),
    ("pull_mm", "pull", "mm"),
    ("volume_ml", "volume", "ml"),
    ("pump_pressure_mmHg", "pump_pressure", "mmHg"),
    ("afterload_pressure_mmHg", "node_pressure", "mmHg"),
    ("outflow_ml_per_s", "outflow", "ml"),
    ("cable_force_N", "cable_force", 1.0),
    ("column_volume_ml", "column_volume", "ml"),
    ("shell_pull_mm", "shell_pull", "mm"),
)
"""traces.csv's columns: (header, trace, scale: 1 or the name of a cardiosoft.units unit)."""


def trace_columns(result: RunResult) -> list[tuple[str, str, float]]:
    """``traces.csv`` columns: (header, trace key, unit scale)."""
    from cardiosoft import units

    return [
        (head, key, getattr(units, scale) if isinstance(scale, str) else scale)
        for head, key, scale in _TRACE_COLUMNS
    ]


def plot(result: RunResult, path, records) -> None:
    from cardiosoft.plots import plot_fig10

    plot_fig10(result, path, records=records)


def heading(scene: Scene) -> str:
    # the surrogate is named when it is not the default, which every other run uses
    surrogate = [] if scene.pump == DEFAULT_ARTIFACT else [f"pump {scene.pump}"]
    design = f"Omega {scene.omega:g}, C {scene.shortening:g}"
    return ", ".join([f"{scene.name} at {scene.bpm:g} bpm", design, *surrogate])


def design(scene: Scene) -> dict:
    """The design of ``summary.json``."""
    return {"omega": scene.omega, "shortening": scene.shortening}


def column_heads(scene: Scene, given, action: str):
    """The water-column heads (mmHg) of a grid: ``given`` or the scene's; None without a
    column (:meth:`~cardiosoft.scene.Scene.column_heads_mmHg`)."""
    return scene.column_heads_mmHg(given, action=action)


def sweep_variables(scene: Scene) -> dict:
    """A sweep's metric variables (:data:`cardiosoft.results.SWEEP_VARIABLES`)."""
    return SWEEP_VARIABLES


def sweep_panels(scene: Scene) -> tuple:
    """A sweep map's panels (:data:`cardiosoft.sweep.maps.PANELS`)."""
    from cardiosoft.sweep.maps import PANELS

    return PANELS


def sweep_flags(scene: Scene, metrics, n: int, domain) -> np.ndarray:
    """:func:`cardiosoft.results.flagged_members`."""
    return flagged_members(metrics, n, domain)


def uncertainty(scene: Scene, posterior, *, beats=None, steady="beats"):
    """``--uncertainty``: the posterior's draws solved in one call
    (:func:`cardiosoft.posterior.ensemble_run`) and the predictive bands
    (:func:`cardiosoft.posterior.predictive_bands`: draws plus the model discrepancy)."""
    from cardiosoft.posterior import ensemble_run, predictive_bands

    ens = ensemble_run(scene, posterior, beats=beats, steady=steady)
    bands = predictive_bands(ens, posterior.card)
    about = {
        "holds": "posterior draws plus the model discrepancy",
        "discrepancy": "sd^2 = s0^2 + s1^2 (1 - exp(-d^2)) per output type, "
        "posterior card 'discrepancy'",
    }
    return bands, ens.messages, int(ens.ok.shape[0]), about


VERIFIED = (
    ("static_sv_ml", "static SV", "ml"),
    ("dynamic_sv_ml", "dynamic SV", "ml"),
    ("peak_force_N", "peak force", "N"),
    ("mech_work_J", "mech. work", "J"),
    ("efficiency", "efficiency", "-"),
    ("ef", "EF", "-"),
    ("edv_ml", "EDV", "ml"),
    ("esv_ml", "ESV", "ml"),
    ("cardiac_output_l_min", "cardiac output", "l/min"),
)
"""The numbers of :func:`~cardiosoft.results.summary_records` that ``--verify`` checks:
(key, name, unit)."""
STATIC_POINTS = 401
"""Points of the pull grid of :func:`cardiosoft.solve_static` (its ``quasi_static_stroke``)."""
STATIC_GRID_REFINEMENT = 10
"""The quasi-static check's pull grid: this many times finer than the run's."""


def verified(scene: Scene) -> tuple[tuple[str, str, str], ...]:
    return VERIFIED


def fine_static(scene: Scene, pump, afterload, n_points: int):
    """Quasi-static strokes of ``scene``'s members at ``afterload`` (Pa) on ``n_points``."""
    return solve_static(scene, afterload=afterload, pump=pump, n_points=n_points)


def _check_run_members(result: RunResult) -> None:
    """``result`` must be a :func:`cardiosoft.run` of its scene: one member per afterload."""
    scene = result.scene
    heads = [m.afterload for m in result.members]
    expected = list(scene.afterloads) if scene.afterload.has_heads else [None]
    same = len(heads) == len(expected) and all(
        (h is None and e is None) or (h is not None and e is not None and math.isclose(h, e))
        for h, e in zip(heads, expected, strict=False)
    )
    if not same:
        raise ValueError(
            "verify: result is not a cardiosoft.run() of its scene (one member per afterload); "
            "a run_designs() of several designs is not supported"
        )


def verify_rerun(result: RunResult, config, *, beats=None, steady="beats", pump=None):
    """The members of ``result`` solved again (the namespace's ``verify_rerun``): the dynamic
    beats at ``config``, the quasi-static strokes on a pull grid :data:`STATIC_GRID_REFINEMENT`
    times finer (a water column's members)."""
    import jax

    scene = result.scene
    _check_run_members(result)
    labels = [m.label for m in result.members]
    heads = None
    if scene.afterload.has_heads:
        heads = np.array([m.afterload for m in result.members], dtype=float)
    fine = STATIC_GRID_REFINEMENT * (STATIC_POINTS - 1) + 1
    static = None if heads is None else fine_static(scene, pump, heads, fine)
    if scene.static:
        dynamic = None
        settings = (f"quasi-static pull, {STATIC_POINTS} points",
                    f"quasi-static pull, {fine} points")  # fmt: skip
    else:
        dynamic = solve_beats(
            scene, afterload=heads, beats=beats, steady=steady, pump=pump, config=config
        )
        settings = rerun_settings(scene.accuracy, default_config(scene), config)
        if static is not None:
            settings = (settings[0], f"{settings[1]}; quasi-static pulls on "
                        f"{STATIC_GRID_REFINEMENT}x the points")  # fmt: skip
    jax.block_until_ready((static, dynamic))
    succeeded = dynamic is None or bool(np.all(np.asarray(dynamic.succeeded)))
    reference = RunResult(scene, member_results(labels, dynamic, static))
    return reference, *settings, succeeded
