"""Result records of a run: one per member, plain numbers in SI, and their user-unit summary.

:func:`cardiosoft.run` and :func:`cardiosoft.sweep` return a :class:`RunResult`; the command
line prints and writes its :func:`summary_records`.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np

from cardiosoft.batch import BeatSolution, StaticSolution
from cardiosoft.files import json_ready
from cardiosoft.metrics import BeatMetrics
from cardiosoft.pump import Domain
from cardiosoft.scene import Scene
from cardiosoft.units import ml, mmHg

__all__ = [
    "ENERGY_ROUNDOFF",
    "STORED_CHANGE_TOL",
    "SWEEP_VARIABLES",
    "MemberResult",
    "RunResult",
    "flagged_members",
    "flags",
    "member_results",
    "summary_records",
]

ENERGY_ROUNDOFF = 64 * float(np.finfo(np.float64).eps)
"""Round-off of the energy account relative to the shell's strain energy U (1.4e-14): the
account subtracts U at the beat's ends, each evaluated to some ulp of U (measured: a stroke
of C 1.9e-97 carries 6.5e-16 J of noise, 6 ulp of U = 0.56 J). A beat that carries less than
this many ulp of U (1e-14 J for U ~ 1 J; a stroke of C below ~1e-14) has an energy residual
and efficiency that are round-off over round-off (1e80 was seen): both are reported as none."""
SLOSHING_TOL = 0.025
"""How far the dynamic SV (the column's peak rise, EDV - ESV) may exceed the pump's own ejection
(its volume at the pull's start less its smallest) before :func:`flags` says so, as a fraction of
the SV: the paper's largest relative SD of a dynamic SV (1.7 ml of 66.9, Sec. III-D), below which
the difference is within what the bench resolved."""
STORED_CHANGE_TOL = 1e-3
"""Largest |stored_change| / work_in at which ``energy_efficiency`` is reported. delivered =
in - lost - stored, so a beat that is not periodic in the shell's energy moves the efficiency by
stored / in: 1e-3 keeps it to its third decimal. Measured (bench-dynamic, Omega 4, 150 mmHg, 60
bpm, 'default'): 3e-6 at C 0.4, 1.5e-4 at C 0.1, both steady; a 0.04-ml stroke (Omega 0, C 0.01)
that passes the steady tolerance of 0.01 ml still stores 8 % of the work in each beat."""


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
    flags: tuple[str, ...] = ()
    """Why a number of this member is not to be trusted as it is, in words: the surrogate
    extrapolated (which quantity, how far), a cable that would push, a metric that is not
    meaningful here (and was set to NaN). Empty when there is none."""


@dataclasses.dataclass(frozen=True)
class RunResult:
    """What :func:`cardiosoft.run` returns: the scene as run and one record per member."""

    scene: Scene
    members: tuple[MemberResult, ...]

    @property
    def ok(self) -> bool:
        """Every member solved, at its periodic steady state."""
        return all(m.ok for m in self.members)

    @property
    def flagged(self) -> bool:
        """Some member has :attr:`MemberResult.flags`."""
        return any(m.flags for m in self.members)


def _static_metrics(static: StaticSolution, i: int) -> dict[str, float]:
    return {
        "static_stroke_volume": float(static.stroke_volume[i]),
        "static_peak_force": float(static.peak_force[i]),
        "static_mech_work": float(static.mech_work[i]),
        "static_efficiency": float(static.efficiency[i]),
        "static_max_pressure": float(static.max_pressure[i]),
    }


SWEEP_VARIABLES = {
    "stroke_volume_ml": (
        "stroke_volume",
        ml,
        "ml",
        "stroke volume EDV - ESV (the bench: the peak column rise, the paper's dynamic SV)",
    ),
    "ejection_fraction": ("ejection_fraction", 1.0, "1", "ejection fraction SV / EDV"),
    "peak_force_N": ("peak_force", 1.0, "N", "largest measured cable force during the pull"),
    "mech_work_J": (
        "mech_work",
        1.0,
        "J",
        "mechanical work: the cable force integrated over the pull (the paper's M)",
    ),
    "efficiency": ("efficiency", 1.0, "1", "the paper's efficiency P_a SV / M"),
    "hydraulic_work_J": ("hydraulic_work_paper", 1.0, "J", "the paper's hydraulic work P_a SV"),
    "stroke_work_J": ("stroke_work", 1.0, "J", "area of the pressure-volume loop"),
    "edv_ml": ("edv", ml, "ml", "end-diastolic (largest) pump volume"),
    "esv_ml": ("esv", ml, "ml", "end-systolic (smallest) pump volume"),
    "cardiac_output_l_min": (
        "cardiac_output",
        1000 * ml / 60.0,
        "l/min",
        "cardiac output SV / period",
    ),
}
"""A sweep's metric variables of an open-loop scene (:mod:`cardiosoft.sweep`), ``{name:
(BeatMetrics field, scale to the unit, unit, long name)}``: every one is in the last beat of
the member."""


def flagged_members(metrics, n: int, domain) -> np.ndarray:
    """Whether :func:`flags` flags each of the first ``n`` members of a batch
    solve's :class:`~cardiosoft.metrics.BeatMetrics` (on a copy: nothing is changed)."""
    fields = {
        f.name: np.asarray(getattr(metrics, f.name))[:n]
        for f in dataclasses.fields(metrics)
        if getattr(metrics, f.name) is not None
    }
    return np.array(
        [bool(flags({k: float(v[i]) for k, v in fields.items()}, domain)) for i in range(n)],
        dtype=bool,
    )


def flags(metrics: dict[str, float], domain: Domain) -> tuple[str, ...]:
    """What of a member's numbers lies outside the surrogate's fitted domain or is unphysical.

    Sets a paper's efficiency ``P_a SV / M`` that is not meaningful (outside [0, 1], no
    mechanical work, or a pull that does no net work on the fluid) to NaN in ``metrics``: the
    paper's definition holds for a quasi-static pull against a steady head; a fast beat whose
    column oscillates, or a stroke so small that the pressure's own work dominates, gives
    numbers like 1.06 that are not efficiencies. ``energy_efficiency`` (``energy=True``) is the
    one that holds at any rate.

    - the chamber pressure outside ``domain.pressure_mmHg`` (the pressures the surrogate was
      fitted on): its volumes, forces and every metric derived from them are extrapolated;
    - the quasi-static stroke's largest pressure (``static_max_pressure``: the head plus the
      column's rise) above the fitted range: its static SV, force and efficiency are
      extrapolated (a stroke starts at the head, >= 0 mmHg: it cannot fall below the range);
    - the energy account's ratios where they are not meaningful (:func:`_energy_flags`): set
      to NaN;
    - a negative cable force: the prescribed pull would need the cables to push. A real cable
      goes slack instead and the shell then moves by itself: a scene without the effect
      ``cable_slack`` (:class:`~cardiosoft.circuit.CableSlack`) does not simulate that, and the
      result is reported, flagged, not corrected;
    - a pump volume below zero (a beat whose column swings the chamber empty and on): the
      surrogate has no floor where the shell's walls meet (the effect ``wall_contact``,
      :class:`~cardiosoft.circuit.WallContact`, adds one), so the beat's volumes are not
      physical, and the ejection fraction, which would exceed 1, is set to NaN;
    - the dynamic SV (EDV - ESV: the paper's, the column's peak rise) above the pump's own
      ejection (``ejected_volume``) by more than :data:`SLOSHING_TOL`: the line's fluid still
      flowed in after the pull began (the column sloshing), and the SV and EF count that inflow.
    """
    out = []
    lo, hi = domain.pressure_mmHg
    if "min_pump_pressure" in metrics:
        p_lo, p_hi = metrics["min_pump_pressure"] / mmHg, metrics["max_pump_pressure"] / mmHg
        if p_lo < lo:
            out.append(f"pump pressure down to {p_lo:.1f} mmHg, below the fitted {lo:g} mmHg")
        if p_hi > hi:
            out.append(f"pump pressure up to {p_hi:.1f} mmHg, above the fitted {hi:g} mmHg")
    if metrics.get("static_max_pressure", -math.inf) / mmHg > hi:
        p_hi = metrics["static_max_pressure"] / mmHg
        out.append(
            f"static pressure up to {p_hi:.2f} mmHg (head + column rise), {p_hi - hi:.2g} mmHg "
            f"above the fitted {hi:g} mmHg"
        )
    if metrics.get("min_cable_force", 0.0) < 0.0:
        out.append(
            f"cable force down to {metrics['min_cable_force']:.1f} N: the pull needs a cable that "
            "pushes (a real cable goes slack: add the effect cable_slack, --add-effect cable_slack)"
        )
    if metrics.get("esv", 0.0) < 0.0:
        ef = metrics.get("ejection_fraction", math.nan)
        metrics["ejection_fraction"] = math.nan
        out.append(
            f"pump volume down to {metrics['esv'] / ml:.1f} ml, below zero: the beat's volumes "
            f"are not physical (a chamber without the effect wall_contact has no floor where "
            f"the shell's walls meet); EF (SV / EDV = {ef:.3g}) reported as none"
        )
    sv, ejected = metrics.get("stroke_volume", 0.0), metrics.get("ejected_volume", math.inf)
    if sv - ejected > SLOSHING_TOL * sv:
        out.append(
            f"dynamic SV (the column's peak rise) {sv / ml:.1f} ml exceeds the pump's own "
            f"ejection from the pull's start, {ejected / ml:.1f} ml: the line's fluid still "
            "flowed in after the pull began (the column sloshing), and SV and EF count it"
        )
    _energy_flags(metrics, out)
    for key in ("efficiency", "static_efficiency"):
        e = metrics.get(key)
        work = metrics.get("mech_work" if key == "efficiency" else "static_mech_work", 0.0)
        # a pull that does no net work on the fluid (a fast beat, the column swinging back)
        pushed = metrics.get("hydraulic_work_pull", 1.0) > 0.0 if key == "efficiency" else True
        if e is not None and not (pushed and work > 0.0 and 0.0 <= e <= 1.0):
            metrics[key] = math.nan
            out.append(
                f"{key.replace('_', ' ')} P_a SV / M = {e:.3g} with M = {work:.3g} J is not "
                "meaningful here (the paper's definition holds for a quasi-static pull against "
                "a steady head); reported as none"
            )
    return tuple(out)


def _energy_flags(metrics: dict[str, float], out: list[str]) -> None:
    """The energy account's ratios (``energy=True``) where they are not meaningful: set to NaN
    in ``metrics``, the reason appended to ``out``. The ratios are a small difference over a
    small energy in two cases:

    - a vanishing stroke: the beat carries no more than :data:`ENERGY_ROUNDOFF` of the shell's
      strain energy (residual and efficiency);
    - a beat whose stored energy changes by more than :data:`STORED_CHANGE_TOL` of the work in
      (a transient; a small stroke that meets the steady tolerance, absolute in ml, before its
      shell's energy is periodic): the efficiency only. The residual still holds: the account
      includes the stored change.
    """
    if "work_in" not in metrics:
        return
    work_in, stored = metrics["work_in"], metrics["stored_change"]
    terms = (work_in, metrics["work_delivered"], metrics["work_lost"], stored)
    carried = 0.5 * sum(abs(t) for t in terms)
    floor = ENERGY_ROUNDOFF * abs(metrics["stored_energy"])
    if not carried > floor:
        metrics["energy_residual"] = metrics["energy_efficiency"] = math.nan
        out.append(
            f"energy account: the beat carries {carried:.3g} J, within the round-off of the "
            f"shell's stored energy ({floor:.3g} J); energy residual and efficiency reported as "
            "none"
        )
    elif not (work_in > 0.0 and abs(stored) <= STORED_CHANGE_TOL * work_in):
        e = metrics["energy_efficiency"]
        metrics["energy_efficiency"] = math.nan
        out.append(
            f"energy efficiency delivered / in = {e:.3g} is not meaningful here: the shell's "
            f"stored energy changes by {stored:.3g} J over the beat against {work_in:.3g} J put "
            f"in (more than {STORED_CHANGE_TOL:g} of it: not a periodic beat); reported as none"
        )


def member_results(
    labels,
    dynamic: BeatSolution | None,
    static: StaticSolution | None,
    domain: Domain | None = None,
) -> tuple[MemberResult, ...]:
    """Records from a batch solve and/or the quasi-static strokes of the same members.

    ``domain``: the surrogate's fitted domain (default: :class:`~cardiosoft.pump.Domain`), for
    :func:`flags`.
    """
    domain = Domain() if domain is None else domain
    # read from the device once: indexing a JAX array member by member is a small program each
    dynamic, static = jax.device_get((dynamic, static))
    members = (dynamic if dynamic is not None else static).members
    heads = np.asarray(members["afterload"])
    out = []
    for i, label in enumerate(labels):
        head = None if math.isnan(heads[i]) else float(heads[i])
        m = {} if static is None else _static_metrics(static, i)
        if dynamic is None:
            reasons = flags(m, domain)
            out.append(
                MemberResult(label, head, True, "quasi-static", 0, 0.0, 0.0, m, {}, reasons)
            )
            continue
        m = {
            f.name: float(getattr(dynamic.metrics, f.name)[i])
            for f in dataclasses.fields(BeatMetrics)
            if getattr(dynamic.metrics, f.name) is not None  # the energy account is opt-in
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
                flags(m, domain),
            )
        )
    return tuple(out)


def block_records(traces: dict) -> dict[str, dict]:
    """Each block's record of one open-loop member's beat (``traces``: its signals, SI), named
    as the scene's network names its blocks (:mod:`cardiosoft.network.bench`), in the form every
    kind of scene gives: the ``pump``'s
    (:func:`~cardiosoft.network.block_metrics.pump_record`) and the ``afterload``'s, a vessel's
    (:func:`~cardiosoft.network.block_metrics.vessel_record_si`) at its compliant node (the
    water column's base, a Windkessel's capacitor: behind the line's valve, tube and
    resistances) with the mean flow into it."""
    from cardiosoft.network.block_metrics import pump_record, vessel_record_si

    pump = (traces[k] for k in ("pump_pressure", "volume", "cable_force", "pull"))
    node = vessel_record_si(traces["node_pressure"], traces["outflow"], traces["time"])
    return {"pump": pump_record(*pump), "afterload": node}


def summary_records(result: RunResult) -> list[dict]:
    """One JSON-ready record per member of an open-loop scene's run, in user units
    (``summary.json``); with traces, ``blocks``: each block's record (:func:`block_records`).
    :func:`cardiosoft.summary_records` takes any scene's."""
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
                "ejected_ml": x["ejected_volume"] / ml if dynamic else None,
                "edv_ml": x["edv"] / ml if dynamic else None,
                "esv_ml": x["esv"] / ml if dynamic else None,
                "cardiac_output_l_min": x["cardiac_output"] / ml * 60 / 1000 if dynamic else None,
                "beats": m.beats,
                "steady_residual": m.residual,
                "volume_drift": m.volume_drift,
                "ok": m.ok,
                "message": m.message,
                "energy_efficiency": x.get("energy_efficiency"),
                "energy_residual": x.get("energy_residual"),
                "flags": list(m.flags),
            }
        )
        if m.traces:
            records[-1]["blocks"] = block_records(m.traces)
    return json_ready(records)

