"""The records of a closed-loop run in user units: ``summary.json``, the printed table and
the columns of ``traces.csv`` (:mod:`cardiosoft.network.loop_results` makes the records)."""

from __future__ import annotations

import math

from cardiosoft.units import ml, mm, mmHg

__all__ = ["loop_summary_records", "loop_table", "loop_trace_columns"]


def _none_if_nan(value):
    return None if isinstance(value, float) and not math.isfinite(value) else value


def loop_summary_records(result) -> list[dict]:
    """One JSON-ready record per member of a closed loop's
    :class:`~cardiosoft.results.RunResult` in user units (``summary.json``): per side SV, EDV,
    ESV, EF, CO, the net output, arterial pressures, mean atrial pressure, a pump's peak force
    and cable work; the pulmonary and systemic volumes; the run's state and flags."""
    records = []
    for m in result.members:
        x = m.metrics
        record = {"label": m.label, "bpm": result.scene.bpm}
        for side, artery, atrium in (("left", "aortic", "la"), ("right", "pulmonary", "ra")):
            record |= {
                f"{side}_sv_ml": x[f"{side}_stroke_volume"] / ml,
                f"{side}_edv_ml": x[f"{side}_edv"] / ml,
                f"{side}_esv_ml": x[f"{side}_esv"] / ml,
                f"{side}_ef": x[f"{side}_ejection_fraction"],
                f"{side}_co_l_min": x[f"{side}_cardiac_output"] / ml * 60 / 1000,
                f"{side}_net_output_l_min": x[f"{side}_net_output"] / ml * 60 / 1000,
                f"{artery}_systolic_mmHg": x[f"{side}_arterial_systolic"] / mmHg,
                f"{artery}_diastolic_mmHg": x[f"{side}_arterial_diastolic"] / mmHg,
                f"{artery}_mean_mmHg": x[f"{side}_arterial_mean"] / mmHg,
                f"{atrium}_mean_mmHg": x[f"{side}_atrial_mean"] / mmHg,
                f"{side}_peak_force_N": x[f"{side}_peak_force"],
                f"{side}_cable_work_J": x[f"{side}_cable_work"],
            }
        record |= {
            "pulmonary_volume_ml": x["pulmonary_volume"] / ml,
            "systemic_volume_ml": x["systemic_volume"] / ml,
            "total_volume_ml": x["total_volume"] / ml,
            "beats": m.beats,
            "steady_residual": m.residual,
            "volume_drift": m.volume_drift,
            "ok": m.ok,
            "message": m.message,
            "flags": list(m.flags),
        }
        records.append({k: _none_if_nan(v) for k, v in record.items()})
    return records


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
