"""Result records of a run: one per member, plain numbers in SI, and their user-unit summary.

:func:`cardiosoft.run` and :func:`cardiosoft.sweep` return a :class:`RunResult`; the command
line prints and writes its :func:`summary_records`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from cardiosoft.batch import BeatSolution, StaticSolution
from cardiosoft.metrics import BeatMetrics
from cardiosoft.scene import Scene
from cardiosoft.units import ml, mmHg

__all__ = ["MemberResult", "RunResult", "member_results", "summary_records"]


@dataclasses.dataclass(frozen=True)
class MemberResult:
    """One member of a run (an afterload, a design). Metrics and traces are SI."""

    label: str
    afterload: float | None
    """Column head (Pa) for the bench; None for a Windkessel scene."""
    ok: bool
    """The solver succeeded and the member is at its periodic steady state."""
    message: str
    beats: int
    residual: float
    """Cycle-to-cycle change of the last beat (ml, ml/s or mmHg)."""
    volume_drift: float
    """Largest relative drift of the total fluid volume over the run."""
    metrics: dict[str, float]
    """:class:`~cardiosoft.metrics.BeatMetrics` fields, plus ``static_*`` for the bench."""
    traces: dict[str, np.ndarray]
    """Last beat: time, pull, volume, pressures, flows, forces (SI); empty when not saved."""


@dataclasses.dataclass(frozen=True)
class RunResult:
    """What :func:`cardiosoft.run` returns: the scene as run and one record per member."""

    scene: Scene
    members: tuple[MemberResult, ...]

    @property
    def ok(self) -> bool:
        return all(m.ok for m in self.members)


def _static_metrics(static: StaticSolution, i: int) -> dict[str, float]:
    return {
        "static_stroke_volume": float(static.stroke_volume[i]),
        "static_peak_force": float(static.peak_force[i]),
        "static_mech_work": float(static.mech_work[i]),
        "static_efficiency": float(static.efficiency[i]),
    }


def member_results(
    labels, dynamic: BeatSolution | None, static: StaticSolution | None
) -> tuple[MemberResult, ...]:
    """Records from a batch solve and/or the quasi-static strokes of the same members."""
    members = (dynamic if dynamic is not None else static).members
    heads = np.asarray(members["afterload"])
    out = []
    for i, label in enumerate(labels):
        head = None if math.isnan(heads[i]) else float(heads[i])
        m = {} if static is None else _static_metrics(static, i)
        if dynamic is None:
            out.append(MemberResult(label, head, True, "quasi-static", 0, 0.0, 0.0, m, {}))
            continue
        m = {
            f.name: float(getattr(dynamic.metrics, f.name)[i])
            for f in dataclasses.fields(BeatMetrics)
        } | m
        traces = {} if dynamic.traces is None else {
            k: np.asarray(v[i]) for k, v in dynamic.traces.items()
        }
        message = dynamic.message(i)
        out.append(
            MemberResult(
                label,
                head,
                message == "ok",
                message,
                int(dynamic.beats[i]),
                float(dynamic.residual[i]),
                float(dynamic.volume_drift[i]),
                m,
                traces,
            )
        )
    return tuple(out)


def summary_records(result: RunResult) -> list[dict]:
    """One JSON-ready record per member, in user units (``summary.json``)."""
    records = []
    for m in result.members:
        x = m.metrics
        dynamic = not result.scene.static
        records.append(
            {
                "label": m.label,
                "afterload_mmHg": None if m.afterload is None else m.afterload / mmHg,
                "static_sv_ml": (
                    x["static_stroke_volume"] / ml if "static_stroke_volume" in x else None
                ),
                "dynamic_sv_ml": x["stroke_volume"] / ml if dynamic else None,
                "peak_force_N": x["peak_force"] if dynamic else x["static_peak_force"],
                "mech_work_J": x["mech_work"] if dynamic else x["static_mech_work"],
                "efficiency": x["efficiency"] if dynamic else x["static_efficiency"],
                "ef": x["ejection_fraction"] if dynamic else None,
                "edv_ml": x["edv"] / ml if dynamic else None,
                "esv_ml": x["esv"] / ml if dynamic else None,
                "cardiac_output_l_min": x["cardiac_output"] / ml * 60 / 1000 if dynamic else None,
                "beats": m.beats,
                "steady_residual": m.residual,
                "volume_drift": m.volume_drift,
                "ok": m.ok,
                "message": m.message,
            }
        )
    return records
