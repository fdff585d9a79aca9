"""Validation: every comparison of the model with the paper, with the comparator's own
uncertainty, the model's predictive band where it has one, and whether the comparison was
fitted or held out.

The numbers are those of the project's own checks, recomputed: ``python -m fit --report``
(:func:`fit.report.artifact_metrics`, its targets :data:`fit.report.TARGETS`) and
``python -m fit.posterior --check`` (:mod:`fit.posterior.check`, whose bounds are issue #24's:
at least 8 of Table II's 9 held-out experiments and all of the 30-bpm bench inside their 95 %
bands). The leave-one-afterload-out check refits the posterior three times; it is read from the
posterior's card, where ``--check`` recorded it, and so is the bench's with ``quick``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

from cardiosoft.credibility.evidence import Check, Section

__all__ = [
    "BENCH_BOUNDS", "PosteriorEvidence", "bench_checks", "fit_checks", "posterior_checks",
    "validation",
]

FIT_REPORT = "python -m fit --report"
POSTERIOR_CHECK = "python -m fit.posterior --check"
GEOMETRY = "python -m cardiosoft.geometry"

BASIS = {
    "table2_mae_ml": "held out",
    "table1_mae_ml": "fitted",
    "table1_loo_mae_ml": "held out",  # each row predicted by the fit without it
    "folds_wrong": "fitted",  # Table I's folds fitted; Table II's counted with them
    "static_sv_outside_sd": "fitted",
    "peak_force_max_rel_error": "fitted",
    "mech_work_max_rel_error": "fitted",
    "convexity_min_relative_stiffness": "verification",  # a property of the potential
}
"""Whether each of the fit report's targets compares with data the fit saw."""

# The paper's printed geometry (section III-B, appendix A3) and the precision it is printed to.
PAPER_GEOMETRY = {
    "cavity volume": (108.6, "ml"),
    "apex axial motion at Omega 4, C 0.4": (19.8, "mm"),
    "apex rotation at Omega 4, C 0.4": (99.8, "deg"),
}
PRINTED_HALF_DIGIT = 0.05  # a value printed to one decimal is known to +-0.05


def _geometry() -> dict[str, tuple[float, float, str]]:
    """``{name: (paper, model, unit)}`` of :data:`PAPER_GEOMETRY`."""
    import math

    from cardiosoft.geometry import Shell, apex_motion, cavity_volume
    from cardiosoft.units import ml, mm

    motion = apex_motion(Shell(), 4.0, 0.4)
    model = {
        "cavity volume": float(cavity_volume(Shell())) / ml,
        "apex axial motion at Omega 4, C 0.4": abs(float(motion.dz)) / mm,
        "apex rotation at Omega 4, C 0.4": math.degrees(abs(float(motion.dalpha))),
    }
    return {name: (paper, model[name], unit) for name, (paper, unit) in PAPER_GEOMETRY.items()}


def _geometry_checks(geometry) -> list[Check]:
    checks = []
    for name, (paper, model, unit) in geometry.items():
        checks.append(Check(
            f"Fig. 7(a) geometry: {name}", f"{paper:g} +- {PRINTED_HALF_DIGIT:g} {unit}",
            f"{model:.2f} {unit}", "held out",
            abs(model - paper) <= PRINTED_HALF_DIGIT, GEOMETRY,
        ))  # fmt: skip
    return checks


BENCH_BOUNDS = (
    ("dynamic SV within the paper's SD", "dynamic_sv_ml", "ml", "sd", "fitted"),
    ("dynamic peak force within 10 %", "peak_force_N", "N", 0.10, "held out"),
    ("dynamic peak force within 5 %", "peak_force_N", "N", 0.05, "held out"),
    ("efficiency within 0.02", "efficiency", "", 0.02, "fitted"),
)
"""Fig. 10 at 30 bpm, the dynamic bench run as ``cardiosoft simulate --bpm 30`` runs it: (name,
summary key, unit, bound, basis), the bounds of ``tests/test_simulate.py`` (the SD and the
efficiency's 0.02 absolute: the bench's tube is calibrated to the dynamic SVs and the work; the
peak forces are not seen by that calibration: 10 % relative, and 5 %, the target its strict
xfail records as not met)."""


def bench_checks(records: list[dict]) -> list[Check]:
    """:data:`BENCH_BOUNDS` on the summary records (:func:`cardiosoft.summary_records`) of the
    dynamic bench at 30 bpm, one member per head of Fig. 10 in its order."""
    from cardiosoft import datasets

    paper = datasets.load_paper_data().fig10_bench
    heads = ", ".join(f"{float(h):g}" for h in paper["afterload_mmHg"])
    checks = []
    for name, key, unit, bound, basis in BENCH_BOUNDS:
        model = [r[key] for r in records]
        means = [float(v) for v in paper[key]]
        if bound == "sd":
            sds = [float(v) for v in paper[key.replace("_ml", "_sd_ml")]]
            misses = [abs(a - b) / sd for a, b, sd in zip(model, means, sds, strict=True)]
            target, met = "|model - paper| <= SD at each head", max(misses) <= 1.0
            worst = f"worst {max(misses):.2f} SD"
        elif unit:
            misses = [abs(a / b - 1) for a, b in zip(model, means, strict=True)]
            target, met = f"<= {bound:.0%} at each head", max(misses) <= bound
            worst = f"worst {max(misses):.1%}"
        else:
            misses = [abs(a - b) for a, b in zip(model, means, strict=True)]
            target, met = f"|model - paper| <= {bound:g} at each head", max(misses) <= bound
            worst = f"worst {max(misses):.3f}"
        pairs = ", ".join(f"{a:.3g}/{b:.3g}" for a, b in zip(model, means, strict=True))
        checks.append(Check(
            f"Fig. 10, 30 bpm: {name}", target,
            f"{pairs}{' ' + unit if unit else ''} (model/paper at {heads} mmHg); {worst}",
            basis, met, "cardiosoft simulate --bpm 30 --compare-paper",
        ))  # fmt: skip
    return checks


def _bench_run() -> list[dict]:
    from cardiosoft import datasets
    from cardiosoft.experiment import run
    from cardiosoft.results import summary_records

    heads = [float(h) for h in datasets.load_paper_data().fig10_bench["afterload_mmHg"]]
    return summary_records(run("bench-dynamic", bpm=30.0, afterload=heads))


def fit_checks(m: dict) -> list[Check]:
    """The fit report's targets (:data:`fit.report.TARGETS`) on its metrics ``m`` as checks,
    in its order and with its labels."""
    from fit import report

    met = report.verdicts(m)
    checks = []
    for key, (label, op, bound, unit) in report.targets_of(m).items():
        if key not in m:
            continue
        value = m[key]
        shown = f"{value:.3g} {unit}".strip() if isinstance(value, float) else f"{value} {unit}"
        checks.append(Check(
            label, f"{op} {bound:g} {unit}".strip(), shown.strip(), BASIS.get(key, "fitted"),
            met[key], FIT_REPORT,
        ))  # fmt: skip
    return checks


def _untargeted(m: dict) -> list[Check]:
    """The comparisons the fit reports with no bound: the FEM's efficiencies and work ratios
    (section III-A) and, for a surrogate not fitted to it, the membrane inflation."""
    from cardiosoft.credibility.comparisons import FEM_COMPARISONS

    checks = [
        Check(label, f"paper {value:g}", f"{m[key]:.3g}", "no bound", None, FIT_REPORT)
        for key, (label, value, _) in FEM_COMPARISONS.items()
        if key in m
    ]
    if "membrane_max_excess_untargeted" in m:
        checks.append(Check(
            "membrane inflation (the paper's Yeoh shell), worst error over max(10 %, 1 ml)",
            "not a target of this surrogate (issue #39)",
            f"{m['membrane_max_excess_untargeted']:.3g} x the band", "no bound", None,
            FIT_REPORT,
        ))  # fmt: skip
    return checks


def _coverage_check(name, summary, bound, basis) -> Check:
    inside, of = summary["inside"], summary["of"]
    lo, hi = summary["wilson_95"]
    width = summary["mean_width"]
    value = f"{inside} of {of} (Wilson 95 %: {lo:.2f}-{hi:.2f}; mean width {width:.3g})"
    if bound is None:
        return Check(name, "no bound set (issue #24)", value, "no bound", None, POSTERIOR_CHECK)
    return Check(name, f">= {bound} of {of} inside", value, basis, inside >= bound,
                 POSTERIOR_CHECK)  # fmt: skip


class PosteriorEvidence(NamedTuple):
    """What ``fit.posterior --check`` says, as the report has it: the checks, a sentence on
    where each number comes from, and the bands of the comparisons table."""

    checks: list[Check]
    text: str
    table1: object  # fit.posterior.check.Coverage of Table I
    table2: object  # ... of Table II
    bench_bands: tuple  # per head {metric: Band}; () when read from the card
    repeatability_ml: float  # the measurement sd Table II's bands add (the card's sigmas)


def posterior_checks(quick: bool, progress) -> PosteriorEvidence:
    """The posterior's checks (``python -m fit.posterior --check``, issue #24's bounds): Table
    II recomputed; the 30-bpm bench recomputed (``quick``: read from the posterior's card,
    where ``--check`` recorded it); leave one afterload out read from the card (three refits).
    Table I's bands are computed too, for the comparisons table (no bound)."""
    from cardiosoft import datasets
    from cardiosoft.pump import artifact_path, load_posterior
    from fit.posterior import artifact, check

    post = load_posterior()
    _, card_path = artifact.posterior_paths(artifact_path(None))
    stored = json.loads(Path(card_path).read_text()).get("checks", {})
    data = datasets.load_paper_data()
    progress("validation: Tables I and II against the posterior's bands ...")
    t1, t2 = check.table1(post, data), check.table2(post, data)
    bench_bands = ()
    if quick:
        sv, force = stored["bench_dynamic_sv"], stored["bench_peak_force"]
        where = "read from the posterior's card (recorded by `--check`)"
    else:
        progress("validation: the 30-bpm bench's draws, one batched solve ...")
        b = check.bench(post, data, artifact.bench_scene(post.card["surrogate"]))
        sv, force = b.dynamic_sv.summary(), b.peak_force.summary()
        bench_bands = b.bands
        where = "recomputed"
    n_bench = sv["of"]
    checks = [
        _coverage_check("Table II (experiments) inside the 95 % bands", t2.summary(), 8,
                        "held out"),
        _coverage_check("30-bpm bench dynamic SV inside the 95 % bands", sv, n_bench, "fitted"),
        _coverage_check(
            "30-bpm bench peak force inside the 95 % bands", force, n_bench, "held out"
        ),
        _coverage_check("leave one afterload out: dynamic SV inside",
                        stored["leave_one_afterload_out_dynamic_sv"], None, "held out"),
        _coverage_check("leave one afterload out: peak force inside",
                        stored["leave_one_afterload_out_peak_force"], None, "held out"),
    ]  # fmt: skip
    text = (
        f"The posterior's checks (`{POSTERIOR_CHECK}`): Table II recomputed, the 30-bpm "
        f"bench {where}, the leave-one-afterload-out check read from the card (three refits)."
    )
    repeatability = post.card["sigmas"]["table2_measurement_ml"]
    return PosteriorEvidence(checks, text, t1, t2, bench_bands, repeatability)


def validation(folder: Path, quick: bool, progress) -> Section:
    """The validation section (module docstring). ``folder``: unused (no figures: the
    notebooks draw the comparisons, and the text links them)."""
    from cardiosoft import datasets
    from cardiosoft.credibility.comparisons import comparisons_table
    from fit import report

    progress("validation: the fit report's metrics of the shipped surrogate ...")
    m, card = report.artifact_metrics()
    fitted = fit_checks(m)
    posterior = posterior_checks(quick, progress)
    progress("validation: the dynamic bench at 30 bpm against Fig. 10 ...")
    records = _bench_run()
    bench = bench_checks(records)
    geometry = _geometry()
    checks = [*_geometry_checks(geometry), *fitted, *bench, *posterior.checks, *_untargeted(m)]
    table = comparisons_table(
        geometry=geometry, metrics=m, records=records,
        paper=datasets.load_paper_data().fig10_bench, bench_bands=posterior.bench_bands,
        table1=posterior.table1, table2=posterior.table2,
        repeatability_ml=posterior.repeatability_ml,
    )  # fmt: skip
    text = "\n".join([
        f"The shipped surrogate `{card['name']}` against the paper. *Fitted*: the data the fit "
        "saw (Table I's FEM sweep, the 30-bpm bench's static SVs, peak forces and work); *held "
        "out*: data it never saw (Table II's experiments, the geometry's printed values, each "
        "Table I row in leave-one-out, the peak forces in the posterior's bands).",
        "",
        f"- The fit's targets (`{FIT_REPORT}`): {sum(c.met for c in fitted)} of "
        f"{len(fitted)} met. The paper's SDs enter through the static-SV target (within "
        "the paper's +- SD) and through the bands below.",
        "- Fig. 10's dynamic bench at the paper's 30 bpm (`cardiosoft simulate --bpm 30 "
        "--compare-paper`): its SVs and efficiencies were fitted by the bench's calibration, "
        "its peak forces were not; the 5 % force target is the one recorded as not met "
        "(issue #39: the dynamic force runs 6 % high at 90 mmHg).",
        f"- {posterior.text}",
        "- The figures of these comparisons are in the notebooks: "
        "[Fig. 7(a)](../notebooks/fig7_apex_motion.ipynb), "
        "[Tables I and II](../notebooks/tables_fit.ipynb), "
        "[Fig. 10](../notebooks/fig10_bench.ipynb), "
        "[the bands](../notebooks/uncertainty.ipynb).",
        "",
        "Each comparison: the paper's value and its own uncertainty, the model's, and the "
        "model's 95 % predictive band (the posterior's draws and the model discrepancy, "
        "`simulate --uncertainty`'s bands; the coverage checks above widen them by the "
        "paper's SD, as a new measurement would scatter). The bench's lines are at 30 bpm; the "
        "quasi-static lines and the static SV are the fit report's.",
        "",
        table,
    ])  # fmt: skip
    return Section("validation", "Validation", text, tuple(checks))
