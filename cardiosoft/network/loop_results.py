"""Runs of closed-loop scenes: their records and flags, :func:`run_loop` (issue 26).

:func:`cardiosoft.run` hands a :class:`~cardiosoft.network.loop_scene.LoopScene` to
:func:`run_loop`;
:func:`cardiosoft.summary_records` hands its result to
:func:`cardiosoft.network.loop_records.loop_summary_records`. A member's
``metrics`` are the :class:`~cardiosoft.network.loop_batch.LoopMetrics` flattened to
``"{side}_{field}"`` (``"left_stroke_volume"``) and ``pulmonary_volume``,
``systemic_volume``, ``total_volume`` (SI).

**Flags** (:func:`loop_flags`), each band with its source:

- **pulmonary congestion**: mean left-atrial pressure above :data:`LA_CONGESTION` (18 mmHg: the
  pulmonary capillary wedge pressure that separates the congested from the uncongested
  haemodynamic subsets, Forrester et al. 1976, N. Engl. J. Med. 295, 1356);
- **systemic venous congestion**: mean right-atrial pressure above :data:`RA_CONGESTION`
  (10 mmHg: elevated in Brinkley et al. 2018, Am. Heart J. 199, 31, whose RA >= 10 mmHg was
  associated with in-hospital mortality);
- **a collapsing atrium**: an atrial pressure below 0 at any time of the beat, i.e. the atrium
  below its unstressed volume V_0 (the model's own ``p = E(t)(V - V_0)``): a thin-walled
  atrium and the veins feeding it collapse rather than hold suction (the suction events of
  ventricular assist devices);
- **volume piled up on one side**: the pulmonary vessels' share of the blood volume outside
  :data:`PULMONARY_SHARE_BAND` times the native ``heart`` scene's share
  (:data:`NATIVE_PULMONARY_SHARE`): the lungs' blood volume ranges "from as little as one-half
  normal up to twice normal" (Guyton and Hall, Textbook of Medical Physiology, ch. 39);
- for each soft pump, what :func:`cardiosoft.results.flags` says of the pump scenes: its
  pressure outside the surrogate's fitted range, a cable that would push.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from cardiosoft.beat_solution import BeatSolution
from cardiosoft.network.loop_batch import SIDES, loop_members, solve_loop
from cardiosoft.network.loop_scene import LoopScene
from cardiosoft.pump import Domain, PumpSurrogate, load
from cardiosoft.results import MemberResult, RunResult, flags
from cardiosoft.solve import SolverConfig
from cardiosoft.units import mmHg

__all__ = [
    "LA_CONGESTION",
    "NATIVE_PULMONARY_SHARE",
    "PULMONARY_SHARE_BAND",
    "RA_CONGESTION",
    "configure_loop",
    "flat_metrics",
    "loop_flags",
    "pump_sides",
    "run_loop",
]

LA_CONGESTION = 18.0 * mmHg
"""Mean left-atrial pressure (Pa) above which the lungs are congested (module docstring)."""
RA_CONGESTION = 10.0 * mmHg
"""Mean right-atrial pressure (Pa) above which the systemic veins are congested."""
NATIVE_PULMONARY_SHARE = 0.2449
"""Mean share of the blood volume in the pulmonary vessels of the ``heart`` scene at its
periodic steady state (740.8 of 3025 ml; measured 2026-12, checked by
tests/test_closed_loop.py)."""
PULMONARY_SHARE_BAND = (0.5, 2.0)
"""The pulmonary share allowed, relative to :data:`NATIVE_PULMONARY_SHARE`."""
_ATRIA = {"left": "left atrium", "right": "right atrium"}


def flat_metrics(metrics, i: int) -> dict[str, float]:
    """Member ``i`` of a batch's :class:`~cardiosoft.network.loop_batch.LoopMetrics`, flattened to
    ``"{side}_{field}"`` and the volumes (SI; the module docstring)."""
    out = {}
    for side in SIDES:
        m = getattr(metrics, side)
        out |= {f"{side}_{f.name}": float(getattr(m, f.name)[i]) for f in dataclasses.fields(m)}
    for name in ("pulmonary_volume", "systemic_volume", "total_volume"):
        out[name] = float(getattr(metrics, name)[i])
    return out


def loop_flags(metrics: dict[str, float], pumps, domain: Domain) -> tuple[str, ...]:
    """What of a member's numbers lies outside its band (module docstring), in words.

    ``metrics``: a member's flat metrics (SI); ``pumps``: the sides with a soft pump."""
    out = []
    la, ra = metrics["left_atrial_mean"], metrics["right_atrial_mean"]
    if la > LA_CONGESTION:
        out.append(
            f"pulmonary congestion: mean left-atrial pressure {la / mmHg:.1f} mmHg, above "
            f"{LA_CONGESTION / mmHg:g} mmHg"
        )
    if ra > RA_CONGESTION:
        out.append(
            f"systemic venous congestion: mean right-atrial pressure {ra / mmHg:.1f} mmHg, above "
            f"{RA_CONGESTION / mmHg:g} mmHg"
        )
    for side, atrium in _ATRIA.items():
        low = metrics[f"{side}_atrial_min"]
        if low < 0.0:
            out.append(
                f"collapsing {atrium}: its pressure falls to {low / mmHg:.1f} mmHg (below its "
                "unstressed volume); a real atrium collapses rather than hold suction"
            )
    share = metrics["pulmonary_volume"] / metrics["total_volume"]
    lo, hi = (b * NATIVE_PULMONARY_SHARE for b in PULMONARY_SHARE_BAND)
    if not lo <= share <= hi:
        where = "lungs" if share > hi else "systemic circulation"
        native = NATIVE_PULMONARY_SHARE
        out.append(
            f"blood piled up in the {where}: the pulmonary vessels hold {share:.1%} of it, "
            f"outside {lo:.1%}-{hi:.1%} (one-half to twice the native heart's {native:.1%})"
        )
    for side in pumps:
        pump_metrics = {
            "min_pump_pressure": metrics[f"{side}_ventricle_min_pressure"],
            "max_pump_pressure": metrics[f"{side}_ventricle_max_pressure"],
            "min_cable_force": metrics[f"{side}_min_cable_force"],
        }
        out += [f"{side} pump: {reason}" for reason in flags(pump_metrics, domain)]
    return tuple(out)


def pump_sides(scene: LoopScene) -> tuple[str, ...]:
    """The sides (``"left"``, ``"right"``) whose ventricle is a soft pump."""
    return tuple(side for side, (_, ventricle, _, _) in SIDES.items() if ventricle in scene.pumps)


def loop_member_results(
    scene: LoopScene, labels, solution: BeatSolution, domain: Domain | None = None
) -> tuple[MemberResult, ...]:
    """Records of a :func:`~cardiosoft.network.loop_batch.solve_loop` solution, one per member."""
    domain = Domain() if domain is None else domain
    out = []
    for i, label in enumerate(labels):
        metrics = flat_metrics(solution.metrics, i)
        traces = (
            {}
            if solution.traces is None
            else {k: np.asarray(v[i]) for k, v in solution.traces.items()}
        )
        message = solution.message(i)
        out.append(
            MemberResult(
                label,
                None,
                message == "ok",
                message,
                int(solution.beats[i]),
                float(solution.residual[i]),
                float(solution.volume_drift[i]),
                metrics,
                traces,
                loop_flags(metrics, pump_sides(scene), domain),
            )
        )
    return tuple(out)


def configure_loop(
    scene: LoopScene, *, omega=None, shortening=None, bpm=None, afterload=None, accuracy=None
) -> LoopScene:
    """The closed-loop scene with the user's overrides (user units): ``bpm``; ``omega`` and
    ``shortening`` set every soft pump's design; ``accuracy`` the preset."""
    if afterload is not None:
        raise ValueError(
            f"afterload: scene {scene.name} is a closed loop, whose afterload is its own "
            "circulation; --afterload sets water-column heads"
        )
    numbers = {"bpm": bpm} if bpm is not None else {}
    for name, value in (("omega", omega), ("shortening", shortening)):
        if value is not None:
            if not scene.pumps:
                raise ValueError(f"{name}: scene {scene.name} has no soft pump to design")
            numbers |= {f"{c}.{name}": float(value) for c in scene.pumps}
    if numbers:
        numbers = {k: float(v) for k, v in numbers.items()}
        loop_members(scene, numbers)  # checks the ranges, naming the number's path
        scene = scene.with_numbers(numbers)
    if accuracy is not None:
        scene = scene.replace(accuracy=accuracy)
    return scene


def run_loop(
    scene: LoopScene,
    *,
    beats=None,
    steady="beats",
    config: SolverConfig | None = None,
    pump: PumpSurrogate | None = None,
) -> RunResult:
    """Simulate a closed-loop scene, one member, and its records: what :func:`cardiosoft.run`
    does with one (it validates the arguments, :func:`configure_loop` the overrides)."""
    pump = load(scene.pump) if pump is None else pump
    solution = solve_loop(scene, beats=beats, steady=steady, pump=pump, config=config)
    return RunResult(scene, loop_member_results(scene, [scene.name], solution, pump.domain))
