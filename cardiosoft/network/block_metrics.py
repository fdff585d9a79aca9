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
own numbers (its force and work, in SI) are :func:`cardiosoft.network.pump_in_model.
pump_metrics`'.
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
