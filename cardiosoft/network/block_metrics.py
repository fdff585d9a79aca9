"""Each block's record over the reported beat of an svZeroDSolver model (issue #40: one result
record with per-block metrics), from its traces, in the model's own units.

- A chamber (a block with a chamber volume, :meth:`~cardiosoft.network.blocks.Block.
  chamber_volumes`: ``Vc:NAME``, the combined heart's four ``V_LV:NAME`` ...): its end-diastolic
  and end-systolic volumes (the beat's largest and smallest), stroke volume and ejection
  fraction.
- A vessel (:attr:`~cardiosoft.network.blocks.Block.vessel`: a vessel, an outlet's resistance,
  RCR or coronary bed): its inlet's pressure, mean, systolic (largest) and diastolic
  (smallest), and its inlet's mean flow.

Means are the trapezoid rule's over the reported time, divided by its span: over one whole beat
(svZeroDSolver reports the last beat, both ends included), the time mean of the beat. A closed
loop's coronaries inside its combined heart block have no record of their own. The soft pump's
own numbers are :func:`pump_record`'s, the same in every kind of scene.
"""

from __future__ import annotations

import numpy as np

CHAMBER_KEYS = ("edv", "esv", "stroke_volume", "ejection_fraction")
VESSEL_KEYS = ("pressure_mean", "pressure_systolic", "pressure_diastolic", "flow_mean")


def closed_integral(y, x) -> float:
    """The trapezoid rule's integral of samples ``y`` over ``x`` (numpy arrays)."""
    y, x = np.asarray(y, dtype=float), np.asarray(x, dtype=float)
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(x)))


def time_mean(values, time) -> float:
    """The trapezoid rule's mean of samples ``values`` at times ``time`` (the span's mean)."""
    return closed_integral(values, time) / float(time[-1] - time[0])


def chamber_record(volume) -> dict:
    """A chamber's beat from its volume samples: EDV, ESV, SV (its units) and EF."""
    volume = np.asarray(volume, dtype=float)
    edv, esv = float(volume.max()), float(volume.min())
    return dict(zip(CHAMBER_KEYS, (edv, esv, edv - esv, (edv - esv) / edv), strict=True))


def vessel_record(pressure, flow, time) -> dict:
    """A vessel's beat from its inlet's pressure and flow samples at ``time``: the mean,
    systolic (largest) and diastolic (smallest) pressure and the mean flow (their units)."""
    pressure = np.asarray(pressure, dtype=float)
    numbers = (time_mean(pressure, time), pressure.max(), pressure.min(), time_mean(flow, time))
    return dict(zip(VESSEL_KEYS, map(float, numbers), strict=True))


def vessel_record_si(pressure, flow, time) -> dict:
    """:func:`vessel_record` of SI samples (Pa, m^3/s, s) in user units, each key naming its
    unit: ``pressure_mean_mmHg``, ``pressure_systolic_mmHg``, ``pressure_diastolic_mmHg``,
    ``flow_mean_l_min``."""
    from cardiosoft.units import l_per_min, mmHg

    record = vessel_record(np.asarray(pressure) / mmHg, np.asarray(flow) / l_per_min, time)
    units = ("mmHg", "mmHg", "mmHg", "l_min")
    return {f"{k}_{unit}": v for (k, v), unit in zip(record.items(), units, strict=True)}


def pump_record(pressure, volume, force, pull) -> dict:
    """A soft pump's beat from its samples over one whole beat (both ends), SI: ``pressure``
    (Pa), ``volume`` (m^3), cable ``force`` (N) and ``pull`` (m). In user units: its end-diastolic
    and end-systolic volumes and stroke volume (ml), ejection fraction, peak and lowest cable
    force (N), lowest and highest pressure (mmHg), the cables' net work over the beat (the closed
    integral of F dx, J), the stroke work (the pressure-volume loop's area, -(closed integral of
    p dV), J) and their ratio, the pump's efficiency (hydraulic work out over the cables' work in;
    None when the cables do no work). Every kind of scene makes its pump's record here."""
    from cardiosoft.units import ml, mmHg

    pressure, force = np.asarray(pressure, dtype=float), np.asarray(force, dtype=float)
    beat = chamber_record(np.asarray(volume, dtype=float) / ml)
    cable_work = closed_integral(force, pull)
    stroke_work = -closed_integral(pressure, volume)
    return {
        "edv_ml": beat["edv"],
        "esv_ml": beat["esv"],
        "stroke_volume_ml": beat["stroke_volume"],
        "ejection_fraction": beat["ejection_fraction"],
        "peak_force_N": float(force.max()),
        "min_force_N": float(force.min()),
        "min_pressure_mmHg": float(pressure.min() / mmHg),
        "max_pressure_mmHg": float(pressure.max() / mmHg),
        "cable_work_J": cable_work,
        "stroke_work_J": stroke_work,
        "efficiency": stroke_work / cable_work if cable_work else None,
    }


def block_metrics(network, traces) -> dict[str, dict]:
    """``{name: record}`` of every chamber and vessel of ``network`` (a
    :class:`~cardiosoft.network.network.Network`) from ``traces``
    (:class:`~cardiosoft.network.run.Traces` of one model, not a batch of variants), in the
    order of the blocks; the module docstring says which and what."""
    values, time = traces.values, traces.time
    out = {}
    for block in network.blocks:
        for name, volume in block.chamber_volumes().items():
            out[name] = chamber_record(values[volume])
        if not block.vessel:
            continue
        inlet = next(
            (network.nodes[i] for i in block.ports if network.nodes[i][1] == block.name), None
        )
        if inlet is None:  # a vessel with no inlet node (fed by a flow source inside it)
            continue
        node = "{}:{}".format(*inlet)
        out[block.name] = vessel_record(values[f"pressure:{node}"], values[f"flow:{node}"], time)
    return out


def block_table(records: dict[str, dict]) -> str:
    """The records as two tables, chambers then vessels (the model's units)."""
    chambers = {k: r for k, r in records.items() if "edv" in r}
    vessels = {k: r for k, r in records.items() if "pressure_mean" in r}
    rows = []
    if chambers:
        rows.append(f"{'chamber':24s} {'EDV':>12s} {'ESV':>12s} {'SV':>12s} {'EF':>6s}")
        rows += [
            f"{k:24s} {r['edv']:12.5g} {r['esv']:12.5g} {r['stroke_volume']:12.5g} "
            f"{r['ejection_fraction']:6.3f}"
            for k, r in chambers.items()
        ]
    if vessels:
        rows.append(
            f"{'vessel (inlet)':24s} {'mean P':>12s} {'systolic P':>12s} {'diastolic P':>12s} "
            f"{'mean flow':>12s}"
        )
        rows += [
            f"{k:24s} {r['pressure_mean']:12.5g} {r['pressure_systolic']:12.5g} "
            f"{r['pressure_diastolic']:12.5g} {r['flow_mean']:12.5g}"
            for k, r in vessels.items()
        ]
    return "\n".join(rows)
