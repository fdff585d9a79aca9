"""The validation section's comparisons, one line each: the paper's value with its own
uncertainty, the model's value, the model's 95 % predictive band where it has one, and whether
the fit saw the comparator (issue #42).

The bands are the shipped posterior's:

- the zero-pressure tables (Tables I and II, contracted volumes ``V_u (1 - EF)``): the EF
  law's draws and its discrepancy, plus a new measurement's sd for the experiments
  (:func:`fit.posterior.check.table1`, :func:`~fit.posterior.check.table2`); a table is
  summarised by how many of its cells its bands cover and their mean width;
- the 30-bpm bench of Fig. 10 at each head: its draws solved as one ensemble and the model
  discrepancy (:func:`cardiosoft.posterior.predictive_bands`, ``simulate --uncertainty``'s
  bands), for the static and dynamic SV, the dynamic peak force and the efficiency.

Where a line has no band, it says why: the geometry has no fitted parameter, and the posterior
draws the rig and the surrogate on the bench, not the quasi-static pull's force and work or the
FEM's loadings.
"""

from __future__ import annotations

__all__ = ["BENCH_LINES", "FEM_COMPARISONS", "comparisons_table"]

BENCH_LINES = (
    ("Fig. 10 static SV", "static_sv_ml", "ml", "static_sv_sd_ml", "fitted"),
    ("Fig. 10 dynamic SV, 30 bpm", "dynamic_sv_ml", "ml", "dynamic_sv_sd_ml", "fitted"),
    ("Fig. 10 dynamic peak force, 30 bpm", "peak_force_N", "N", "peak_force_sd_N", "held out"),
    ("Fig. 10 efficiency, 30 bpm", "efficiency", "", None, "fitted"),
)
"""The bench's lines: (comparison, summary key, unit, the paper's SD column, basis). The
efficiency is printed to three decimals with no SD (Sec. III-D)."""

FEM_COMPARISONS = {
    "fem_efficiency_helical": ("FEM efficiency, helical (Omega 4)", 0.442, 3),
    "fem_efficiency_longitudinal": ("FEM efficiency, longitudinal (Omega 0)", 0.331, 3),
    "fem_mech_work_ratio": ("FEM mechanical-work ratio, helical / longitudinal", 2.8, 2),
    "fem_hydraulic_work_ratio": ("FEM hydraulic-work ratio, helical / longitudinal", 3.7, 2),
}
"""The paper's FEM comparisons (section III-A) the fit report computes: ``{metric key:
(label, the paper's value, decimals shown)}``."""

NO_BAND = {
    "geometry": "none: no fitted parameter (eqs. 1-7)",
    "quasi-static": "none: the posterior's bands are the dynamic run's",
    "fem": "not computed: the posterior is drawn on the bench, not the FEM's loadings",
    "quick": "not computed by --quick",
}


def _band(band, digits: int) -> str:
    return f"[{band.low:.{digits}f}, {band.high:.{digits}f}]"


def _coverage(cov, what: str) -> str:
    s = cov.summary()
    return f"{s['inside']} of {s['of']} cover {what}; mean width {s['mean_width']:.1f} ml"


def comparisons_table(
    *, geometry, metrics, records, paper, bench_bands, table1, table2, repeatability_ml
) -> str:
    """Markdown: one line per comparison. ``geometry``: ``{name: (paper, model, unit)}``;
    ``metrics``: the fit report's (:func:`fit.report.artifact_metrics`); ``records``: the
    30-bpm bench's summary records, one per head of ``paper`` (the Fig. 10 dataset);
    ``bench_bands``: per head ``{metric: Band}``, or () when not computed; ``table1``,
    ``table2``: the zero-pressure tables' coverages; ``repeatability_ml``: the sd Table II's
    bands add for a new measurement (the posterior's card)."""
    lines = [
        "| comparison | at | paper (its uncertainty) | model | model's 95 % band | basis |",
        "|---|---|---|---|---|---|",
    ]
    for name, (value, model, unit) in geometry.items():
        lines.append(f"| Fig. 7(a) geometry: {name} | - | {value:g} {unit} (printed to 0.1) | "
                     f"{model:.2f} {unit} | {NO_BAND['geometry']} | held out |")  # fmt: skip
    for label, cov, mae, basis, what, comparator in (
        ("Table I, 25 FEM designs: contracted volume", table1, "table1_mae_ml", "fitted",
         "the FEM", "the paper's FEM: no uncertainty stated"),
        ("Table II, 9 shells: contracted volume", table2, "table2_mae_ml", "held out",
         "the measurement (with its sd)", "measured; no SD printed (the bands add a "
         f"repeatability of {repeatability_ml:.1f} ml, the pooled SD of Fig. 10's static "
         "triplicates)"),
    ):  # fmt: skip
        lines.append(f"| {label} | every row | {comparator} | mean \\|error\\| "
                     f"{metrics[mae]:.2f} ml | {_coverage(cov, what)} | {basis} |")  # fmt: skip
    heads = [f"{float(h):g} mmHg" for h in paper["afterload_mmHg"]]
    for label, key, unit, sd_key, basis in BENCH_LINES:
        digits = 1 if unit else 3
        model = metrics["static_sv_ml"] if key == "static_sv_ml" else [r[key] for r in records]
        for i, at in enumerate(heads):
            value = float(paper[key][i])
            uncertainty = f"+- {float(paper[sd_key][i]):g}" if sd_key else "no SD printed"
            band = _band(bench_bands[i][key], digits) if bench_bands else NO_BAND["quick"]
            shown = " ".join(f"{value:.{digits}f} {unit}".split())
            lines.append(f"| {label} | {at} | {shown} ({uncertainty}) | "
                         f"{' '.join(f'{model[i]:.{digits}f} {unit}'.split())} | {band} | "
                         f"{basis} |")  # fmt: skip
    for label, model, value, uncertainty, unit in (
        ("quasi-static peak force", metrics["peak_force_N"], paper["peak_force_N"],
         [f"+- {sd:g}" for sd in paper["peak_force_sd_N"]], "N"),
        ("quasi-static mechanical work", metrics["mech_work_J"], metrics["mech_work_paper_J"],
         ["derived from its SV and efficiency"] * len(heads), "J"),
    ):  # fmt: skip
        for i, at in enumerate(heads):
            lines.append(f"| Fig. 10 {label} | {at} | {float(value[i]):.3g} {unit} "
                         f"({uncertainty[i]}) | {float(model[i]):.3g} {unit} | "
                         f"{NO_BAND['quasi-static']} | fitted |")  # fmt: skip
    for key, (label, value, digits) in FEM_COMPARISONS.items():
        if key in metrics:
            lines.append(f"| {label} | C 0.4 | {value:g} (the paper's FEM: none stated) | "
                         f"{metrics[key]:.{digits}f} | {NO_BAND['fem']} | fitted |")
    if "membrane_max_excess_untargeted" in metrics:
        lines.append(
            "| membrane inflation at zero pull | 0-150 mmHg | the paper's Yeoh shell, computed "
            "(`python -m fit.membrane`): no uncertainty | worst error "
            f"{metrics['membrane_max_excess_untargeted']:.3g} x max(10 %, 1 ml) | "
            f"{NO_BAND['fem']} | held out (not a target of this surrogate, issue #39) |"
        )
    return "\n".join(lines)
