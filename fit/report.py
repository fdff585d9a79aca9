"""Metrics of a fitted surrogate against the paper, and the printed fit report.

Every number here is recomputed from a model and its rig, so ``python -m fit --report`` on the
shipped artifact checks the artifact, not a stored table. The one exception is leave-one-out
cross-validation, which needs 25 refits: it is recorded by the fit and read from the card.
"""

from __future__ import annotations

import numpy as np

from cardiosoft import datasets
from cardiosoft.pump import PumpSurrogate
from cardiosoft.units import ml, mmHg
from fit import pipeline

TARGETS = {
    "table2_mae_ml": ("Table II (held out) mean |error|", "<=", 1.5, "ml"),
    # 1.3 ml (issues #23, #27): Table I is the FEM, which itself misses Table II by 1.62 ml;
    # every law tried that reaches 1.2 on Table I gives >= 1.52 on Table II (EF_SCALE)
    "table1_mae_ml": ("Table I mean |error|", "<=", 1.3, "ml"),
    "table1_loo_mae_ml": ("Table I leave-one-out mean |error|", "<=", 2.0, "ml"),
    "folds_wrong": ("fold counts wrong (Tables I and II)", "<=", 0, ""),
    "static_sv_outside_sd": ("static SV outside the paper's +-", "<=", 0, "of 3"),
    "peak_force_max_rel_error": ("peak force, worst relative error", "<=", 0.05, ""),
    "mech_work_max_rel_error": ("mechanical work, worst relative error", "<=", 0.02, ""),
    "convexity_min_relative_stiffness": (
        "smallest d2U/dV2 over the domain, relative to the unfolded chamber's",
        ">=",
        pipeline.CONVEXITY_MARGIN,
        "",
    ),
}


def _ef_percent(model, omega, shortening):
    x = np.asarray(shortening) * np.asarray(model.cable_length(omega))
    return 100 * (
        1 - np.asarray(model.zero_pressure_volume(x, omega)) / float(model.unloaded_volume)
    )


MEMBRANE_TARGETS = {
    # issue #39's numbers for the membrane-true pump: its quasi-static peak forces within 8 %
    # (#23 measured 8.1 % on its membrane-true chamber), and the swelling at zero pull within
    # 10 % (or 1 ml) of the membrane's, 0-150 mmHg
    "peak_force_max_rel_error": ("peak force, worst relative error", "<=", 0.08, ""),
    "membrane_max_excess": (
        "swelling at zero pull, 0-150 mmHg: worst |error| / max(10 % of it, 1 ml)",
        "<=",
        1.0,
        "",
    ),
}
"""Targets of a surrogate fitted to the membrane inflation (format 4), in place of or beside
:data:`TARGETS`."""
MEMBRANE_TOLERANCE = (0.10, 1.0)  # relative, ml: the acceptance band of MEMBRANE_TARGETS
MEMBRANE_REPORTED_MMHG = (0.0, 150.0)


CONVEXITY_CHECK_GRID = (np.linspace(0.0, 6.0, 61), np.linspace(0.0, 0.65, 131), 200)
"""(Omega, C, n_V) of the dense convexity check: C steps of 0.005, finer than the buckling
step's width in C at Omega 6 (0.15 / 6 = 0.025)."""


def membrane_metrics(model: PumpSurrogate, data: datasets.PaperData) -> dict:
    """The swelling at zero pull against the membrane inflation, 0-150 mmHg (ml), and the
    worst error in units of the acceptance band (:data:`MEMBRANE_TOLERANCE`)."""
    rows = pipeline.membrane_rows(data, *MEMBRANE_REPORTED_MMHG)
    paper = rows["membrane_swelling"] / ml
    model_ml = np.asarray(pipeline.membrane_swelling(model, rows["membrane_pressure"])) / ml
    relative, floor = MEMBRANE_TOLERANCE
    band = np.maximum(relative * paper, floor)
    return {
        "membrane_pressure_mmHg": (rows["membrane_pressure"] / mmHg).round(6).tolist(),
        "membrane_swelling_ml": paper.round(4).tolist(),
        "membrane_swelling_model_ml": model_ml.round(4).tolist(),
        "membrane_max_excess": float(np.max(np.abs(model_ml - paper) / band)),
    }


def metrics(
    model: PumpSurrogate, rig: pipeline.Rig, data: datasets.PaperData, membrane: bool = False
) -> dict:
    """All fit metrics as plain floats/lists (JSON-ready). The swelling against the membrane
    is reported for every surrogate; ``membrane`` (format 4) makes it a target."""
    vu_ml = float(model.unloaded_volume) / ml
    t1, t2, bench = data.table1_fem, data.table2_experiment, data.fig10_bench
    ef1 = _ef_percent(model, np.asarray(t1["omega"]), np.asarray(t1["shortening"]))
    ef2 = _ef_percent(model, np.asarray(t2["omega"]), np.asarray(t2["shortening"]))
    err1 = (ef1 - t1["ef_percent"]) / 100 * vu_ml
    err2 = (ef2 - t2["ef_percent"]) / 100 * vu_ml
    fem_on_t2 = np.array(
        [
            float(t1["ef_percent"][(t1["omega"] == o) & (t1["shortening"] == c)][0])
            for o, c in zip(t2["omega"], t2["shortening"], strict=True)
        ]
    )
    folds1 = np.asarray(model.folds(np.asarray(t1["omega"]), np.asarray(t1["shortening"])))
    folds2 = np.asarray(model.folds(np.asarray(t2["omega"]), np.asarray(t2["shortening"])))
    t = pipeline.targets(data)
    b = pipeline.bench_prediction(model, rig, t.afterload)
    fem = pipeline.fem_prediction(model, rig)
    sv = np.asarray(b.static_sv) / ml
    force = np.asarray(b.peak_force)
    work = np.asarray(b.mech_work)
    swelling = membrane_metrics(model, data)
    if not membrane:
        swelling["membrane_max_excess_untargeted"] = swelling.pop("membrane_max_excess")
    return swelling | {
        "table1_ef_model_percent": ef1.round(3).tolist(),
        "table1_error_ml": err1.round(3).tolist(),
        "table1_mae_ml": float(np.mean(np.abs(err1))),
        "table2_ef_model_percent": ef2.round(3).tolist(),
        "table2_error_ml": err2.round(3).tolist(),
        "table2_mae_ml": float(np.mean(np.abs(err2))),
        "table2_paper_fem_mae_ml": float(
            np.mean(np.abs(fem_on_t2 - t2["ef_percent"])) / 100 * vu_ml
        ),
        "table2_paper_reported_error_mean_ml": float(np.mean(t2["error_ml"])),
        "table1_folds_model": folds1.tolist(),
        "table2_folds_model": folds2.tolist(),
        "folds_wrong": int(np.sum(folds1 != t1["folds"]) + np.sum(folds2 != t2["folds"])),
        "afterload_mmHg": (t.afterload / mmHg).round(6).tolist(),
        "static_sv_ml": sv.round(4).tolist(),
        "static_sv_outside_sd": int(
            np.sum(np.abs(sv - bench["static_sv_ml"]) > bench["static_sv_sd_ml"])
        ),
        "peak_force_N": force.round(4).tolist(),
        "peak_force_max_rel_error": float(np.max(np.abs(force / t.peak_force - 1))),
        "mech_work_J": work.round(5).tolist(),
        "mech_work_paper_J": t.mech_work.round(5).tolist(),
        "mech_work_max_rel_error": float(np.max(np.abs(work / t.mech_work - 1))),
        "fem_efficiency_helical": float(fem.efficiency_helical),
        "fem_efficiency_longitudinal": float(fem.efficiency_longitudinal),
        "fem_mech_work_ratio": float(fem.mech_ratio),
        "fem_hydraulic_work_ratio": float(fem.hydraulic_ratio),
        "convexity_min_relative_stiffness": float(
            np.min(pipeline.stiffness_grid(model, *CONVEXITY_CHECK_GRID))
        ),
    }


def artifact_metrics(artifact=None, data: datasets.PaperData | None = None) -> tuple[dict, dict]:
    """The metrics of a stored surrogate (``artifact``: a shipped name or a path; default the
    shipped one) recomputed from it and its rig, with the leave-one-out values its fit recorded
    in its card (25 refits): (metrics, card). What ``python -m fit --report`` prints."""
    from cardiosoft.pump import load, load_card
    from fit import fitting

    data = datasets.load_paper_data() if data is None else data
    model, card = load(artifact), load_card(artifact)
    rig = fitting.rig_from_card(card)
    m = metrics(model, rig, data, membrane=card["format_version"] >= 4)
    for key in ("table1_loo_mae_ml", "peak_force_left_out"):
        m[key] = card["metrics"][key]
    return m, card


def affine_force_bound(afterload, force) -> float:
    """The smallest worst-case relative error of any force law affine in the afterload.

    ``min over (a, b) of max_i |a + b P_i - F_i| / F_i``, a linear programme. On measured
    peak forces it tells how much of a model's miss is owed to its force growing at one rate
    with afterload where the measurements' rate changes.
    """
    from scipy.optimize import linprog

    p, f = np.asarray(afterload, float), np.asarray(force, float)
    ones = np.ones_like(p)
    # unknowns (a, b, t): minimise t subject to +-(a + b P - F) <= t F
    a_ub = np.concatenate([np.stack([ones, p, -f], 1), np.stack([-ones, -p, -f], 1)])
    b_ub = np.concatenate([f, -f])
    sol = linprog([0.0, 0.0, 1.0], A_ub=a_ub, b_ub=b_ub, bounds=[(None, None)] * 3)
    if not sol.success:
        raise RuntimeError(f"affine_force_bound: {sol.message}")
    return float(sol.x[2])


def targets_of(m: dict) -> dict:
    """The targets of the surrogate whose metrics are ``m``: a format-4 one's (fitted to the
    membrane: ``m`` holds ``membrane_max_excess``) or a format-3 one's."""
    return TARGETS | MEMBRANE_TARGETS if "membrane_max_excess" in m else TARGETS


def verdicts(m: dict) -> dict[str, bool]:
    """Target name -> met."""
    return {
        key: m[key] <= bound if op == "<=" else m[key] >= bound
        for key, (_, op, bound, _) in targets_of(m).items()
        if key in m
    }


def format_report(m: dict, data: datasets.PaperData, rig_card: dict) -> str:
    """The human-readable fit report."""
    t1, t2, bench = data.table1_fem, data.table2_experiment, data.fig10_bench
    out = []
    add = out.append
    add("Table I (FEM, zero pressure; training)  EF [%]: paper -> model (error ml), folds")
    for i in range(len(t1)):
        add(
            f"  Omega {t1['omega'][i]:g}  C {t1['shortening'][i]:.1f}: "
            f"{t1['ef_percent'][i]:5.1f} -> {m['table1_ef_model_percent'][i]:5.1f} "
            f"({m['table1_error_ml'][i]:+5.2f} ml)  folds {t1['folds'][i]} -> "
            f"{m['table1_folds_model'][i]}"
        )
    add("")
    add("Table II (experiments; HELD OUT, never seen by the fit)  EF [%]: experiment -> model")
    for i in range(len(t2)):
        add(
            f"  Omega {t2['omega'][i]:g}  C {t2['shortening'][i]:.1f}: "
            f"{t2['ef_percent'][i]:5.1f} -> {m['table2_ef_model_percent'][i]:5.1f} "
            f"({m['table2_error_ml'][i]:+5.2f} ml; paper FEM error {t2['error_ml'][i]:.1f} ml)"
            f"  folds {t2['folds'][i]} -> {m['table2_folds_model'][i]}"
        )
    add(
        f"  mean |error|: model {m['table2_mae_ml']:.2f} ml; paper's FEM "
        f"{m['table2_paper_fem_mae_ml']:.2f} ml from the two tables' EF "
        f"({m['table2_paper_reported_error_mean_ml']:.2f} ml as Table II reports it)"
    )
    add("")
    add("Fig. 10 bench (Omega 4, C 0.4, water column rising; quasi-static):")
    add("  afterload   static SV [ml]           peak force [N]          mech. work [J]")
    for i, p in enumerate(m["afterload_mmHg"]):
        add(
            f"  {p:5.0f} mmHg  {m['static_sv_ml'][i]:5.1f} (paper {bench['static_sv_ml'][i]:.1f}"
            f" +- {bench['static_sv_sd_ml'][i]:.1f})   {m['peak_force_N'][i]:5.1f} (paper "
            f"{bench['peak_force_N'][i]:.1f})   {m['mech_work_J'][i]:.2f} (paper "
            f"{m['mech_work_paper_J'][i]:.2f})"
        )
    add("  (paper's mechanical work M = P_a * dynamic SV / efficiency, section II-F)")
    p_a, f_paper = np.asarray(m["afterload_mmHg"]), np.asarray(bench["peak_force_N"], float)
    slopes = " and ".join(
        f"{p_a[i]:.0f}-{p_a[i + 1]:.0f} mmHg: {s_model:.2f} (paper {s_paper:.2f})"
        for i, (s_model, s_paper) in enumerate(
            zip(
                np.diff(m["peak_force_N"]) / np.diff(p_a),
                np.diff(f_paper) / np.diff(p_a),
                strict=True,
            )
        )
    )
    add(f"  peak-force rise [N/mmHg] {slopes};")
    add(
        f"  no force law affine in the afterload gets closer than "
        f"{100 * affine_force_bound(p_a, f_paper):.1f} % to all {len(p_a)} paper forces"
    )
    loo = m.get("peak_force_left_out")
    if loo is not None:
        add(
            f"  validation: fitted without the {loo['afterload_mmHg']:.0f}-mmHg peak force, the "
            f"model predicts {loo['predicted_N']:.1f} N there (paper {loo['paper_N']:.1f}, "
            f"{100 * loo['relative_error']:+.1f} %)"
        )
    add(
        f"  convexity: d2U/dV2 >= {m['convexity_min_relative_stiffness']:.3f} E_u over the "
        "domain (one volume per pull and pressure)"
    )
    add("")
    add("Membrane inflation at zero pull (computed from the paper's Yeoh material):")
    add("  pressure [mmHg]   swelling [ml]: membrane -> model")
    for p, paper, model_ml in zip(
        m["membrane_pressure_mmHg"],
        m["membrane_swelling_ml"],
        m["membrane_swelling_model_ml"],
        strict=True,
    ):
        if p % 30 == 0:
            add(f"  {p:5.0f}            {paper:6.2f} -> {model_ml:6.2f}")
    if "membrane_max_excess_untargeted" in m:
        add(
            f"  (not fitted to it: worst error {m['membrane_max_excess_untargeted']:.2f} times "
            "the band max(10 %, 1 ml))"
        )
    add("")
    add("FEM comparisons at C = 0.4 (helical Omega 4 vs longitudinal Omega 0):")
    add(
        f"  efficiency helical {m['fem_efficiency_helical']:.3f} (paper 0.442), longitudinal "
        f"{m['fem_efficiency_longitudinal']:.3f} (paper 0.331)"
    )
    add(
        f"  mechanical-work ratio {m['fem_mech_work_ratio']:.2f} (paper 2.8), hydraulic-work "
        f"ratio {m['fem_hydraulic_work_ratio']:.2f} (paper 3.7)"
    )
    add("  42 % vs 12 % volume drop at equal strain energy 1 J: not modelled (apex rotation vs")
    add("  axial displacement loads, section II-A, are not cable pulls)")
    add("")
    add("Rig parameters not given in the paper (fitted with the surrogate; held ones: the card):")
    add(
        f"  water-column diameter {rig_card['column_diameter_mm']:.1f} mm; cable friction "
        f"exp(mu theta) = {np.exp(rig_card['cable_friction_exponent']):.2f}; FEM efficiency "
        f"pressure {rig_card['fem_pressure_mmHg']:.0f} mmHg"
    )
    add("")
    add("Targets:")
    met = verdicts(m)
    for key, (label, op, bound, unit) in targets_of(m).items():
        if key not in m:
            continue
        value = m[key]
        shown = f"{value:.3f}" if isinstance(value, float) else str(value)
        add(f"  [{'met' if met[key] else 'NOT MET'}] {label}: {shown} {op} {bound:g} {unit}")
    return "\n".join(out)
