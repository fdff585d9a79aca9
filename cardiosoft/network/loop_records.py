"""The records of a closed-loop run in user units: ``summary.json``, the printed table and
the columns of ``traces.csv`` (:mod:`cardiosoft.network.loop_results` makes the records)."""

from __future__ import annotations

from cardiosoft.files import json_ready
from cardiosoft.network.block_metrics import chamber_record, pump_record, vessel_record_si
from cardiosoft.units import l_per_min, ml, mm, mmHg

__all__ = [
    "LOOP_NUMBERS", "PUMP_NUMBERS", "SIDE_NUMBERS", "banded_keys", "loop_band_table",
    "loop_block_records", "loop_summary_records", "loop_table", "loop_trace_columns",
    "record_numbers",
]  # fmt: skip


# One record's numbers, each once: (record key with {side}, {artery}, {atrium}; the side's
# LoopMetrics field; scale to the unit; unit; long name). summary.json's records and a sweep's
# variables (closed_loop_tools.sweep_variables) are both made from them.
SIDE_NUMBERS = (
    ("{side}_sv_ml", "stroke_volume", ml, "ml", "stroke volume EDV - ESV"),
    ("{side}_edv_ml", "edv", ml, "ml", "end-diastolic (largest) ventricular volume"),
    ("{side}_esv_ml", "esv", ml, "ml", "end-systolic (smallest) ventricular volume"),
    ("{side}_ef", "ejection_fraction", 1.0, "1", "ejection fraction SV / EDV"),
    ("{side}_co_l_min", "cardiac_output", l_per_min, "l/min", "cardiac output SV / period"),
    ("{side}_net_output_l_min", "net_output", l_per_min, "l/min",
     "mean flow out of the arterial compartment into the circulation"),
    ("{artery}_systolic_mmHg", "arterial_systolic", mmHg, "mmHg", "largest arterial pressure"),
    ("{artery}_diastolic_mmHg", "arterial_diastolic", mmHg, "mmHg",
     "smallest arterial pressure"),
    ("{artery}_mean_mmHg", "arterial_mean", mmHg, "mmHg", "time mean of the arterial pressure"),
    ("{atrium}_mean_mmHg", "atrial_mean", mmHg, "mmHg", "time mean of the atrial pressure"),
    ("{side}_peak_force_N", "peak_force", 1.0, "N", "a pump's largest cable force"),
    ("{side}_stroke_work_J", "stroke_work", 1.0, "J",
     "the ventricle's stroke work, the pressure-volume loop's area"),
    ("{side}_cable_work_J", "cable_work", 1.0, "J", "a pump's net cable work over the beat"),
    ("{side}_efficiency", "efficiency", 1.0, "1", "a pump's stroke work over its cable work"),
)  # fmt: skip
PUMP_NUMBERS = frozenset({"peak_force", "cable_work", "efficiency"})
"""The fields of :data:`SIDE_NUMBERS` a native ventricle has not (NaN, ``None`` in records)."""
LOOP_NUMBERS = (
    ("pulmonary_volume_ml", "pulmonary_volume", ml, "ml", "mean pulmonary blood volume"),
    ("systemic_volume_ml", "systemic_volume", ml, "ml", "mean systemic blood volume"),
    ("total_volume_ml", "total_volume", ml, "ml", "blood volume of the loop"),
)
_VESSELS = {"left": ("aortic", "la"), "right": ("pulmonary", "ra")}


def record_numbers(sides=("left", "right"), *, pumps=("left", "right")) -> dict:
    """``{record key: (path in LoopMetrics, scale to the unit, unit, long name)}`` of the
    ``sides``; a pump's numbers only for the sides in ``pumps``."""
    out = {}
    for side in sides:
        artery, atrium = _VESSELS[side]
        for key, field, scale, unit, long_name in SIDE_NUMBERS:
            if field in PUMP_NUMBERS and side not in pumps:
                continue
            name = key.format(side=side, artery=artery, atrium=atrium)
            out[name] = (f"{side}.{field}", scale, unit, f"{side} side: {long_name}")
    for key, field, scale, unit, long_name in LOOP_NUMBERS:
        out[key] = (field, scale, unit, long_name)
    return out


def loop_block_records(traces: dict) -> dict[str, dict]:
    """Each chamber's and vessel's record of one member's reported beat (``traces``: its
    signals, SI), as an svZeroDSolver model's (:func:`cardiosoft.network.block_metrics.
    block_metrics`) but in user units: a chamber's EDV, ESV, SV (ml) and EF, a soft pump's with
    its forces and works too (:func:`~cardiosoft.network.block_metrics.pump_record`); a vessel's
    mean, systolic and diastolic pressure (mmHg) and its inlet's mean flow (l/min: the valve's or
    vessel's before it)."""
    from cardiosoft.network.closed_loop import CHAMBERS, NODES, VESSELS

    out = {}
    for c in CHAMBERS:
        if f"{c}_cable_force" in traces:  # a soft pump
            signals = (f"{c}_pressure", f"{c}_volume", f"{c}_cable_force", f"{c}_pull")
            out[c] = pump_record(*(traces[k] for k in signals))
            continue
        beat = chamber_record(traces[f"{c}_volume"] / ml)
        out[c] = {f"{k}_ml" if k != "ejection_fraction" else k: v for k, v in beat.items()}
    for v in VESSELS:
        inlet = next(up for up, down in NODES if down == v)
        pressure, flow = traces[f"{v}_pressure"], traces[f"{inlet}_flow"]
        out[v] = vessel_record_si(pressure, flow, traces["time"])
    return out


def loop_summary_records(result) -> list[dict]:
    """One JSON-ready record per member of a closed loop's
    :class:`~cardiosoft.results.RunResult` in user units (``summary.json``): per side SV, EDV,
    ESV, EF, CO, the net output, arterial pressures, mean atrial pressure, the stroke work, a
    pump's peak force, cable work and efficiency (:data:`SIDE_NUMBERS`); the pulmonary and
    systemic volumes; the run's state and flags; with traces, ``blocks``: each chamber's and
    vessel's record (:func:`loop_block_records`)."""
    numbers = record_numbers().items()
    records = []
    for m in result.members:
        x = m.metrics
        record = {"label": m.label, "bpm": result.scene.bpm}
        record |= {key: x[path.replace(".", "_")] / scale for key, (path, scale, *_) in numbers}
        record |= {
            "beats": m.beats,
            "steady_residual": m.residual,
            "volume_drift": m.volume_drift,
            "ok": m.ok,
            "message": m.message,
            "flags": list(m.flags),
        }
        if m.traces is not None:
            record["blocks"] = loop_block_records(m.traces)
        records.append(record)
    return json_ready(records)


def banded_keys(pump_sides) -> tuple[str, ...]:
    """The record keys a closed loop's ``--uncertainty`` bands: each pump side's SV, EF, CO and
    peak force, and the mean arterial and atrial pressures."""
    pumps = tuple(
        f"{side}_{name}" for side in pump_sides for name in ("sv_ml", "ef", "co_l_min",
                                                              "peak_force_N")
    )  # fmt: skip
    means = ("aortic_mean_mmHg", "pulmonary_mean_mmHg", "la_mean_mmHg", "ra_mean_mmHg")
    return pumps + means


def loop_band_table(records: list[dict]) -> str:
    """Each member's banded numbers (``<key>_band`` in its record; the key names the unit):
    its value and its 95 % band."""
    lines = [f"  {'':<22} {'value':>8}   {'95 % band':>15}"]
    for record in records:
        lines.append(f"{record['label']}:")
        for key in record:
            if not key.endswith("_band"):
                continue
            name = key[: -len("_band")]
            low, high = record[key]
            value = record.get(name)
            shown = "-" if value is None else f"{value:.3g}"
            band = "-" if low is None else f"{low:.3g}-{high:.3g}"
            lines.append(f"  {name:<22} {shown:>8}   {band:>15}")
    return "\n".join(lines)


_COLUMNS = (  # header, unit, record key with {side}, {artery}, {atrium}; format
    ("SV", "ml", "{side}_sv_ml", ".1f"),
    ("EDV", "ml", "{side}_edv_ml", ".1f"),
    ("ESV", "ml", "{side}_esv_ml", ".1f"),
    ("EF", "-", "{side}_ef", ".2f"),
    ("CO", "l/min", "{side}_co_l_min", ".2f"),
    ("arterial sys/dia", "mmHg", "{artery}_systolic_mmHg|{artery}_diastolic_mmHg", ".0f"),
    ("mean", "mmHg", "{artery}_mean_mmHg", ".1f"),
    ("atrial mean", "mmHg", "{atrium}_mean_mmHg", ".1f"),
    ("peak force", "N", "{side}_peak_force_N", ".1f"),
)


def loop_table(records: list[dict]) -> str:
    """The printed table: a row per side of each member (left: aorta, LA; right: pulmonary
    artery, RA)."""

    def cell(record, key, fmt):
        values = [record.get(k) for k in key.split("|")]
        return "/".join("-" if v is None else format(v, fmt) for v in values)

    head = ["side", *(c[0] for c in _COLUMNS)]
    units = ["", *(c[1] for c in _COLUMNS)]
    rows = []
    for r in records:
        for side, artery, atrium in (("left", "aortic", "la"), ("right", "pulmonary", "ra")):
            keys = [c[2].format(side=side, artery=artery, atrium=atrium) for c in _COLUMNS]
            rows.append([side, *(cell(r, k, c[3]) for k, c in zip(keys, _COLUMNS, strict=True))])
    widths = [max(len(x) for x in col) for col in zip(head, units, *rows, strict=True)]
    lines = [head, units, *rows]
    return "\n".join(
        "  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in lines
    )


def loop_trace_columns(traces: dict) -> list[tuple[str, str, float]]:
    """``traces.csv`` columns of a closed-loop member: (header, trace key, unit scale)."""
    out = [("time_s", "time", 1.0)]
    for key in sorted(k for k in traces if k != "time"):
        if key.endswith("_pressure"):
            out.append((f"{key}_mmHg", key, mmHg))
        elif key.endswith("_volume"):
            out.append((f"{key}_ml", key, ml))
        elif key.endswith("_flow"):
            out.append((f"{key}_ml_per_s", key, ml))
        elif key.endswith("_pull"):
            out.append((f"{key}_mm", key, mm))
        elif key.endswith("_cable_force"):
            out.append((f"{key}_N", key, 1.0))
    return out
