"""The fit (fit/): the shipped artifact against its own card, the data it was fitted on, the
held-out Table II, the command line, and (slow) a refit from scratch.
"""

import dataclasses
import json
import math
import os
import subprocess
import sys
import types
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cardiosoft import datasets
from cardiosoft.files import sha256
from cardiosoft.pump import load, load_card
from fit import fitting, pipeline, report  # the repository root is on pytest's pythonpath

REPO = Path(__file__).resolve().parent.parent

HEADLINE = (
    "table1_mae_ml",
    "table2_mae_ml",
    "table1_loo_mae_ml",
    "static_sv_ml",
    "peak_force_N",
    "mech_work_J",
)

# How closely a refit must reproduce the card (issue #14), from the fit's own sensitivity to
# round-off. Stage 1 (Levenberg-Marquardt to rtol 1e-9) converges: refitted on another CPU its
# metrics moved by 5e-9 at most, so 1e-6. Stage 2 stops after a fixed 3000 Adam steps (the
# last at a learning rate of 3e-4), where round-off leaves it: 20 refits of ss950-v3 on one CPU
# (2026-12-02, `python -m fit.roundoff --refits 20`) with the bench targets or the stage-1
# parameters perturbed by 1e-9 (relative) spread over a range of 1.2-2.2e-3 in the static SVs,
# 1.5-4.7e-3 in the peak forces and 1.5-4.4e-3 in the works (relative, per afterload), and the
# card's values lie inside. Each tolerance is 1.5 times that range (2 significant digits up;
# relative for the metrics and the rig, absolute for the raw parameters). The format-3 fit
# (issue #17) stops less converged than format 2's did (static SVs 1.6-2.0e-4 over 61 refits):
# its swelling parameter moves by 0.11 raw over the refits; its Gauss-Newton spectrum has no
# flat direction (smallest eigenvalue 33.8, against 21.7 for format 2 with the held values).
REFIT_STAGE1_REL = 1e-6
REFIT_REL = {  # headline metrics of stage 2, per afterload
    "static_sv_ml": [3.4e-3, 2.0e-3, 1.8e-3],
    "peak_force_N": [7.1e-3, 5.4e-3, 2.3e-3],
    "mech_work_J": [6.6e-3, 2.3e-3, 5.3e-3],
}
REFIT_RIG_REL = {"cable_friction_exponent": 0.031, "fem_pressure_mmHg": 0.079}
REFIT_PARAMETER_ABS = {  # raw stage-2 parameters of the pump
    "log_stiffness": [0.072, 0.024],
    "softening_exponent": 0.057,
    "log_chamber_elastance": 0.023,
    "log_stiffening": 0.026,
    "swelling_resistance": 0.17,
}


@pytest.fixture(scope="module")
def data():
    return datasets.load_paper_data()


@pytest.fixture(scope="module")
def card():
    return load_card()


@pytest.fixture(scope="module")
def report_proc():
    """``python -m fit --report``, started by the first test so that it runs beside the others."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "fit", "--report"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    yield proc
    if proc.poll() is None:
        proc.kill()
        proc.wait()


@pytest.fixture(scope="module")
def report_run(report_proc):
    out, err = report_proc.communicate(timeout=300)
    return types.SimpleNamespace(returncode=report_proc.returncode, stdout=out, stderr=err)


def _assert_same(actual, expected, key, rel):
    if isinstance(expected, list):
        assert isinstance(actual, list) and len(actual) == len(expected), key
        for a, e in zip(actual, expected, strict=True):
            _assert_same(a, e, key, rel)
    elif isinstance(expected, float):
        assert actual == pytest.approx(expected, rel=rel, abs=rel), key
    else:
        assert actual == expected, key


# ------------------------------------------------------------------- the artifact and its card
@pytest.fixture(scope="module")
def shipped_metrics(data, card):
    """The fit report's metrics recomputed from the shipped weights and the data files (not
    read from the card): what the card and the acceptance bounds below are checked on."""
    # the same functions compiled whole instead of op by op (saves ~10 s; `python -m fit
    # --report` runs them eagerly)
    jitted = {n: jax.jit(getattr(pipeline, n)) for n in ("bench_prediction", "fem_prediction")}
    with pytest.MonkeyPatch.context() as mp:
        for name, fn in jitted.items():
            mp.setattr(pipeline, name, fn)
        return report.metrics(load(), fitting.rig_from_card(card), data)


def test_artifact_reproduces_its_card(card, shipped_metrics, report_proc):
    m = shipped_metrics
    shared = sorted(set(m) & set(card["metrics"]))
    assert len(shared) >= 20
    # recorded by the fit: 25 refits of stage 1, one of stage 2 without the 60-mmHg force
    assert set(card["metrics"]) - set(m) == {"table1_loo_mae_ml", "peak_force_left_out"}
    for key in shared:
        _assert_same(m[key], card["metrics"][key], key, 1e-6)


# ----------------------------------------------- the shipped artifact against the paper's data
def _paper_fem_error_on_table2(data):
    """The paper's FEM (Table I) against its experiments (Table II), mean |error| in ml of the
    108.6-ml cavity: the bar the surrogate must pass on the same held-out cells."""
    t1, t2 = data.table1_fem, data.table2_experiment
    fem = [float(t1["ef_percent"][(t1["omega"] == o) & (t1["shortening"] == c)][0])
           for o, c in zip(t2["omega"], t2["shortening"], strict=True)]
    a, b, h = 60.0, 30.0, 50.0  # mm: the cavity below the apex plane, pi B^2 (h - h^3 / 3A^2)
    vu_ml = np.pi * b**2 * (h - h**3 / (3 * a**2)) / 1e3
    return float(np.mean(np.abs(np.asarray(fem) - t2["ef_percent"])) / 100 * vu_ml)


def test_table_two_held_out_within_1_5_ml_and_below_the_papers_fem(data, shipped_metrics):
    """Table II (experiments) is never fitted: the surrogate, fitted to the FEM (Table I, whose
    grid the experiments sit on), is judged on the experiments."""
    assert shipped_metrics["table2_mae_ml"] <= 1.5
    assert shipped_metrics["table2_mae_ml"] < _paper_fem_error_on_table2(data)


def test_table_one_within_1_3_ml_and_every_fold_count(shipped_metrics):
    assert shipped_metrics["table1_mae_ml"] <= 1.3
    assert shipped_metrics["folds_wrong"] == 0  # of 34 cells, Tables I and II


def test_static_stroke_volumes_within_the_papers_sd(data, shipped_metrics):
    bench = data.fig10_bench
    sv = np.asarray(shipped_metrics["static_sv_ml"])
    assert np.all(np.abs(sv - bench["static_sv_ml"]) <= bench["static_sv_sd_ml"]), sv


def test_quasi_static_peak_forces_within_5_percent(data, shipped_metrics):
    force = np.asarray(shipped_metrics["peak_force_N"])
    assert np.all(np.abs(force / data.fig10_bench["peak_force_N"] - 1) <= 0.05), force


def test_mechanical_work_within_2_percent(data, shipped_metrics):
    """The paper's M = P_a SV_dyn / e (section II-F) from the data files, against the
    quasi-static pull's work (its energy balance)."""
    b = data.fig10_bench
    paper = b["afterload_mmHg"] * 133.322387415 * b["dynamic_sv_ml"] * 1e-6 / b["efficiency"]
    work = np.asarray(shipped_metrics["mech_work_J"])
    assert np.all(np.abs(work / paper - 1) <= 0.02), work / paper - 1


def test_fem_efficiencies_within_0_02(data, shipped_metrics):
    """The FEM's efficiencies of helical and longitudinal pulls (section III-C) within 0.02:
    the third printed digit of the paper's 0.442 and 0.331 plus the model's own error of the
    pressure at which the FEM evaluated them (not given; fitted)."""
    fem = data.fem_comparisons
    for omega, key in ((4.0, "fem_efficiency_helical"), (0.0, "fem_efficiency_longitudinal")):
        row = (fem["quantity"] == "efficiency") & (fem["omega"] == omega)
        assert abs(shipped_metrics[key] - float(fem["value"][row][0])) <= 0.02, key


def test_the_potential_is_convex_in_volume_over_the_domain(shipped_metrics):
    assert shipped_metrics["convexity_min_relative_stiffness"] >= pipeline.CONVEXITY_MARGIN


@pytest.mark.xfail(
    strict=True,
    reason="MODEL (issues #23, #39): the default, format 3, swells 41 ml at 90 mmHg at zero "
    "pull; the shell's own inflation from the paper's Yeoh material "
    "(fit/data/membrane_inflation.csv) gives about 14. Format 4 (ss950-v4) fits it and ships "
    "selectable (its tests below); it is not the default while its 30-bpm peak forces miss",
)
def test_the_shells_swelling_follows_its_own_inflation(data):
    """The surrogate at zero pull against the Yeoh membrane's inflation of the same shell,
    0 to 150 mmHg: within 10 % or 1 ml (issue #23)."""
    m = data.membrane_inflation
    pump = load()
    rest = float(pump.unloaded_volume)
    inside = np.asarray(m["pressure_mmHg"]) <= 150.0
    for p_mmHg, truth in zip(m["pressure_mmHg"][inside], m["swelling_ml"][inside], strict=True):
        v = float(pump.volume(jnp.asarray(p_mmHg * 133.322387415), 0.0, jnp.asarray(4.0)))
        assert abs((v - rest) / 1e-6 - truth) <= max(0.1 * truth, 1.0), p_mmHg


# ------------------------------------------ the membrane-true surrogate, ss950-v4 (format 4)
@pytest.fixture(scope="module")
def card_v4():
    return load_card("ss950-v4")


@pytest.fixture(scope="module")
def metrics_v4(data, card_v4):
    """ss950-v4's report metrics recomputed from its weights and the data files."""
    jitted = {n: jax.jit(getattr(pipeline, n)) for n in ("bench_prediction", "fem_prediction")}
    with pytest.MonkeyPatch.context() as mp:
        for name, fn in jitted.items():
            mp.setattr(pipeline, name, fn)
        return report.metrics(
            load("ss950-v4"), fitting.rig_from_card(card_v4), data, membrane=True
        )


def test_v4_reproduces_its_card_and_holds_nothing(card_v4, metrics_v4):
    """Format 4 is fitted to the membrane too, and that frees what format 3 held: its card
    lists no held value, hashes the membrane file it read, and its metrics recompute."""
    assert card_v4["format_version"] == 4 and card_v4["name"] == "ss950-v4"
    assert card_v4["held"] == {}
    data_dir = REPO / "fit" / "data"
    assert sorted(card_v4["data_sha256"]) == sorted(p.name for p in data_dir.glob("*.csv"))
    for name, digest in card_v4["data_sha256"].items():
        assert sha256(data_dir / name) == digest, name
    assert set(card_v4["metrics"]) - set(metrics_v4) == {"table1_loo_mae_ml", "peak_force_left_out"}
    for key in sorted(set(metrics_v4) & set(card_v4["metrics"])):
        _assert_same(metrics_v4[key], card_v4["metrics"][key], key, 1e-6)


def test_v4_meets_the_papers_data_and_its_material(data, metrics_v4):
    """Issue #39's numbers that the fit reaches on ss950-v4: the membrane within 10 % (or 1
    ml), Table I <= 1.3 ml, Table II (held out) <= 1.5 ml, folds 34/34, static SVs within the
    paper's SD, the work within 2 %, the FEM efficiencies within 0.02, convex over the domain."""
    m = metrics_v4
    assert m["membrane_max_excess"] <= 1.0
    assert m["table1_mae_ml"] <= 1.3 and m["table2_mae_ml"] <= 1.5 and m["folds_wrong"] == 0
    bench = data.fig10_bench
    sv = np.asarray(m["static_sv_ml"])
    assert np.all(np.abs(sv - bench["static_sv_ml"]) <= bench["static_sv_sd_ml"]), sv
    assert m["mech_work_max_rel_error"] <= 0.02
    assert abs(m["fem_efficiency_helical"] - 0.442) <= 0.02
    assert abs(m["fem_efficiency_longitudinal"] - 0.331) <= 0.02
    assert m["convexity_min_relative_stiffness"] >= pipeline.CONVEXITY_MARGIN


@pytest.mark.xfail(
    strict=True,
    reason="MODEL (issue #39): 8.03 % at 60 mmHg. With the membrane-stiff chamber the shell "
    "swells too little at the bench for the folds' yield (k) to bend the force's rise with the "
    "afterload: 0.72 then 0.67 N/mmHg against the paper's 0.99 then 0.30 (#23 measured 8.1 %)",
)
def test_v4_quasi_static_peak_forces_within_8_percent(data, metrics_v4):
    force = np.asarray(metrics_v4["peak_force_N"])
    assert np.all(np.abs(force / data.fig10_bench["peak_force_N"] - 1) <= 0.08), force


def test_card_metrics_are_consistent_with_the_tables(data, card):
    """Recompute the error summaries from the card's per-cell values and the CSV files."""
    m = card["metrics"]
    a, b, h = 60.0, 30.0, 50.0  # mm: the cavity below the apex plane, pi B^2 (h - h^3 / 3A^2)
    vu_ml = np.pi * b**2 * (h - h**3 / (3 * a**2)) / 1e3
    for table, prefix in ((data.table1_fem, "table1"), (data.table2_experiment, "table2")):
        model_ef = np.asarray(m[f"{prefix}_ef_model_percent"])
        err = (model_ef - np.asarray(table["ef_percent"])) / 100 * vu_ml
        np.testing.assert_allclose(m[f"{prefix}_error_ml"], err, rtol=2e-3, atol=2e-3)
        assert m[f"{prefix}_mae_ml"] == pytest.approx(np.mean(np.abs(err)), rel=2e-3)
        np.testing.assert_array_equal(m[f"{prefix}_folds_model"], table["folds"])
    assert m["folds_wrong"] == 0
    assert m["table2_paper_reported_error_mean_ml"] == pytest.approx(
        float(np.mean(data.table2_experiment["error_ml"])), rel=1e-12
    )


def test_rig_round_trips_through_the_card(card):
    rig = fitting.rig_from_card(card)
    assert float(rig.column_diameter) * 1e3 == pytest.approx(card["rig"]["column_diameter_mm"],
                                                             rel=1e-12)
    assert float(rig.cable_friction) == pytest.approx(card["rig"]["cable_friction_exponent"],
                                                      rel=1e-12)
    assert float(rig.fem_pressure) / 133.322387415 == pytest.approx(
        card["rig"]["fem_pressure_mmHg"], rel=1e-12
    )


def test_card_states_what_the_fit_holds(card):
    """The held parameters (issue #14): in the card as the fit writes them, and in the weights."""
    assert card["held"] == json.loads(json.dumps(pipeline.HELD))
    held = card["held"]
    assert float(load().fold_compliance) == held["fold_compliance"]["raw"]
    assert float(jax.nn.softplus(held["fold_compliance"]["raw"])) == pytest.approx(
        held["fold_compliance"]["kappa"], rel=1e-15
    )
    assert card["rig"]["column_diameter_mm"] == held["column_diameter_mm"]["value"]
    # stage 2 starts from the held values and frees neither
    assert float(pipeline.mechanics_start(load()).fold_compliance) == held["fold_compliance"]["raw"]
    rig = fitting.rig_from_card(card)
    assert float(pipeline.Rig().column_diameter) == float(rig.column_diameter)
    assert "fold_compliance" not in pipeline.MECHANICS_FIELDS
    assert "log_column_diameter" not in pipeline.RIG_FIELDS
    assert "held, not fitted" in card["parameters"]["fold_compliance"]


def test_card_records_the_data_it_was_fitted_on(card):
    data_dir = REPO / "fit" / "data"
    # membrane_inflation.csv (python -m fit.membrane) came after format 3's fit, which does
    # not read it: the swelling branch that fits it is issue #23's format 4
    csvs = sorted(p.name for p in data_dir.glob("*.csv") if p.name != "membrane_inflation.csv")
    assert sorted(card["data_sha256"]) == csvs
    for name, digest in card["data_sha256"].items():
        assert sha256(data_dir / name) == digest, name
    # and the weights next to it are the ones the card names
    weights = REPO / "surrogates" / card["weights_file"]
    assert sha256(weights) == card["weights_sha256"]
    assert card["held_out"] == ["table2_experiment.csv"]
    assert card["format_version"] == 3


class _Untouchable:
    """Stands in for Table II: any use of it fails the test."""

    def __getattr__(self, name):
        raise AssertionError(f"Table II was read (attribute {name!r})")

    def __getitem__(self, name):
        raise AssertionError(f"Table II was read (column {name!r})")

    def __len__(self):
        raise AssertionError("Table II was read (len)")

    def __iter__(self):
        raise AssertionError("Table II was read (iter)")


def test_targets_never_read_table_two(data):
    blind = dataclasses.replace(data, table2_experiment=_Untouchable())
    t_blind, t = pipeline.targets(blind), pipeline.targets(data)
    for a, b in zip(t_blind, t, strict=True):
        np.testing.assert_array_equal(a, b)
    # no Table II number appears among the targets (EF in percent -> fraction)
    table2_ef = set(np.round(np.asarray(data.table2_experiment["ef_percent"]) / 100, 6))
    table1_ef = set(np.round(t.t1_ef, 6))
    for value in np.round(np.concatenate([np.ravel(np.asarray(v, float)) for v in t]), 6):
        assert value not in table2_ef - table1_ef


def test_three_fold_boundary_from_table_one(data):
    assert fitting.three_fold_boundary(data.table1_fem) == pytest.approx((1.5, 0.35), abs=1e-12)
    # the recorded boundary of the shipped model is the same
    np.testing.assert_allclose(np.asarray(load().three_fold_boundary), [1.5, 0.35], atol=1e-12)


def test_stage_one_refit_reproduces_the_shipped_ef_law(data):
    """The refit's cheap stage in CI (issue #27): stage 1, the zero-pressure EF law fitted to
    Table I by Levenberg-Marquardt from the fit's deterministic multi-start, against the shipped
    weights. Stage 1 converges (rtol 1e-9; refitted on another CPU its metrics moved by 5e-9),
    so REFIT_STAGE1_REL; the whole refit (stage 2 too) is the slow test below."""
    t = pipeline.targets(data)
    start = eqx.tree_at(
        lambda m: m.three_fold_boundary,
        fitting.initial_model(),
        jnp.asarray(fitting.three_fold_boundary(data.table1_fem)),
    )
    params, _ = pipeline.fit_zero_pressure_law(start, t, jnp.ones((1, len(t.t1_ef))))
    shipped = load()
    for field in pipeline.EF_FIELDS:
        refit = np.asarray(getattr(params, field))[0]
        np.testing.assert_allclose(
            refit, np.asarray(getattr(shipped, field)), rtol=REFIT_STAGE1_REL, atol=1e-9,
            err_msg=field,
        )


def test_three_fold_boundary_separates_the_classes(data):
    t1 = data.table1_fem
    o, c, f = (np.asarray(t1[k], float) for k in ("omega", "shortening", "folds"))
    omega_c, c_c = fitting.three_fold_boundary(t1)
    np.testing.assert_array_equal((o < omega_c) & (c > c_c), f == 3)


def test_affine_force_bound_is_zero_for_affine_data():
    p = np.array([30.0, 60.0, 90.0])
    assert report.affine_force_bound(p, 20.0 + 0.8 * p) == pytest.approx(0.0, abs=1e-9)


def test_affine_force_bound_agrees_with_a_grid_search(data):
    """The linear programme against brute force over (a, b) on the paper's Fig. 10 forces."""
    bench = data.fig10_bench
    p, f = np.asarray(bench["afterload_mmHg"], float), np.asarray(bench["peak_force_N"], float)
    a, b = np.meshgrid(np.linspace(20, 50, 1201), np.linspace(0.4, 1.0, 1201), indexing="ij")
    worst = np.max(np.abs(a[..., None] + b[..., None] * p - f) / f, axis=-1)
    bound = report.affine_force_bound(p, f)
    assert bound <= worst.min() + 1e-12
    assert bound == pytest.approx(worst.min(), abs=2e-4)
    assert bound > 0.05  # the 5 % is out of reach of any force affine in afterload


# ------------------------------------------------------------------------------ command line
def test_report_cli_verdicts_and_exit_code(report_run, card):
    m = dict(card["metrics"])  # the report recomputes all but the LOO value, which it reads
    verdicts = report.verdicts(m)
    assert len(verdicts) == len(report.TARGETS)
    # every target met by the shipped artifact, so the report exits 0; a missed one exits 1
    assert all(verdicts.values()), [k for k, ok in verdicts.items() if not ok]
    assert report_run.returncode == 0, report_run.stdout[-2000:] + report_run.stderr[-2000:]
    out = report_run.stdout
    assert "HELD OUT" in out
    assert "no force law affine in the afterload gets closer than 6.5 %" in out
    assert f"mean |error|: model {m['table2_mae_ml']:.2f} ml" in out
    # one [met]/[NOT MET] line per target, agreeing with the verdicts
    for key, (label, *_rest) in report.TARGETS.items():
        line = next(s for s in out.splitlines() if label in s and s.strip().startswith("["))
        assert line.strip().startswith("[met]" if verdicts[key] else "[NOT MET]"), line


def test_the_credibility_report_says_what_the_fit_report_says(report_run, card):
    """Issue #42: the credibility report's verdict on each of the fit's targets is the one
    ``python -m fit --report`` prints (its [met] / [NOT MET] lines), label for label."""
    from cardiosoft.credibility.validation import fit_checks

    printed = {}
    for line in report_run.stdout.splitlines():
        verdict, _, rest = line.strip().partition("] ")
        if verdict in ("[met", "[NOT MET"):
            printed[rest.rsplit(": ", 1)[0]] = verdict == "[met"
    checks = {c.name: c.met for c in fit_checks(dict(card["metrics"]))}
    assert printed and checks == printed


def test_out_refuses_to_overwrite(tmp_path):
    out = tmp_path / "artifact.eqx"
    out.write_bytes(b"precious")
    before = out.stat()
    proc = subprocess.run(
        [sys.executable, "-m", "fit", "--out", str(tmp_path / "artifact")],
        cwd=REPO, capture_output=True, text=True, timeout=300,
        env={**os.environ, "JAX_PLATFORMS": "cpu"},
    )
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("error:") and "--force" in lines[0] and str(out) in lines[0]
    assert out.read_bytes() == b"precious"
    assert out.stat().st_mtime_ns == before.st_mtime_ns
    assert not (tmp_path / "artifact.json").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["artifact.eqx"]


# ------------------------------------------------------------------------------------- refit
def _corrupted_table2(data):
    t2 = data.table2_experiment
    cols = dict(t2.columns)
    cols["ef_percent"] = np.asarray(cols["ef_percent"]) * 0.5 + 7.0
    cols["error_ml"] = np.asarray(cols["error_ml"]) + 10.0
    cols["folds"] = 7 - np.asarray(cols["folds"])
    return dataclasses.replace(t2, columns=cols)


@pytest.fixture(scope="module")
def refit(data):
    return fitting.fit(data, progress=lambda _msg: None)


@pytest.fixture(scope="module")
def refit_blind(data):
    blind = dataclasses.replace(data, table2_experiment=_corrupted_table2(data))
    return fitting.fit(blind, progress=lambda _msg: None)


def _assert_within(actual, expected, tol, key, relative):
    """Elementwise ``|actual - expected| <= tol`` (times ``|expected|`` if ``relative``)."""
    actual, expected = np.atleast_1d(actual), np.atleast_1d(expected)
    bound = np.broadcast_to(tol, expected.shape) * (np.abs(expected) if relative else 1.0)
    deviation = np.abs(actual - expected)
    assert actual.shape == expected.shape and np.all(deviation <= bound), (
        f"{key}: refit {actual.tolist()} against the card's {expected.tolist()}, deviation "
        f"{deviation.tolist()} beyond {bound.tolist()}"
    )


@pytest.mark.slow
def test_refit_reproduces_the_shipped_card(refit, card):
    """Tolerances: REFIT_* above, from the fit's own round-off sensitivity (issue #14). Marked
    slow since the format-3 fit (its refit takes 104 s of CI's 15 minutes, which the suite
    reached); `pytest -m slow` runs it, and test_artifact_reproduces_its_card checks the
    shipped artifact against its card in CI."""
    model, _rig, new_card = refit
    for key in HEADLINE:
        if key in REFIT_REL:
            _assert_within(new_card["metrics"][key], card["metrics"][key], REFIT_REL[key], key,
                           relative=True)
        else:
            _assert_same(new_card["metrics"][key], card["metrics"][key], key, REFIT_STAGE1_REL)
    for key, rel in REFIT_RIG_REL.items():
        _assert_within(new_card["rig"][key], card["rig"][key], rel, key, relative=True)
    # the held values are kept exactly
    assert new_card["held"] == card["held"]
    assert new_card["rig"]["column_diameter_mm"] == card["rig"]["column_diameter_mm"]
    # the same input files; a refit also hashes membrane_inflation.csv, which format 3's fit
    # does not read (issue #23's format 4 does)
    assert {k: new_card["data_sha256"].get(k) for k in card["data_sha256"]} == card["data_sha256"]
    assert set(new_card["data_sha256"]) - set(card["data_sha256"]) <= {"membrane_inflation.csv"}
    assert new_card["held_out"] == card["held_out"]
    # the refit model is the shipped one (same data, deterministic fit)
    shipped = load()
    for field in REFIT_PARAMETER_ABS:
        _assert_within(getattr(model, field), getattr(shipped, field), REFIT_PARAMETER_ABS[field],
                       field, relative=False)
    others = [f.name for f in dataclasses.fields(shipped) if f.name not in REFIT_PARAMETER_ABS]
    for a, b in zip(jax.tree_util.tree_leaves(eqx.filter([getattr(model, f) for f in others],
                                                         eqx.is_array)),
                    jax.tree_util.tree_leaves(eqx.filter([getattr(shipped, f) for f in others],
                                                         eqx.is_array)), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-3, atol=1e-6)
    assert float(model.fold_compliance) == float(shipped.fold_compliance)  # held


@pytest.mark.slow
def test_refit_ignores_table_two(refit, refit_blind, data):
    model, rig, _ = refit
    model_b, rig_b, card_b = refit_blind
    # the fitted pump and rig do not depend on Table II at all
    assert bool(eqx.tree_equal(model, model_b))
    assert bool(eqx.tree_equal(rig, rig_b))
    # ... while the metrics of the corrupted run did see the corrupted table
    m = report.metrics(model_b, rig_b, data)
    assert card_b["metrics"]["table2_mae_ml"] != pytest.approx(m["table2_mae_ml"])
    assert card_b["metrics"]["table1_mae_ml"] == m["table1_mae_ml"]
    assert math.isfinite(card_b["metrics"]["table1_loo_mae_ml"])
    json.dumps(card_b)  # the card is JSON-ready


def test_the_fit_refuses_an_ef_law_that_falls_with_the_pull():
    """The three-fold switch is monotone only if d_3 exceeds the four-fold step there."""
    from fit.fitting import check_volume_decreases

    shipped = load()
    check_volume_decreases(shipped)  # the shipped law passes
    # three-fold depth ~0 and a deep four-fold step: EF_0 drops where Omega-1 shells turn 3-fold
    shallow = eqx.tree_at(
        lambda m: (m.three_fold_depth, m.fold_depth),
        shipped,
        (jnp.asarray(-20.0), jnp.asarray([3.0, 3.0])),
    )
    with pytest.raises(RuntimeError, match="falls with C at Omega"):
        check_volume_decreases(shallow)


def test_the_fit_refuses_a_potential_that_is_not_convex_in_volume(card):
    """Convexity in V is a hard constraint (issue #17): the shipped artifact passes the dense
    check with the margin recorded in its card, and a swelling strong enough to unfold the
    chamber faster than it distends (k 20) is refused."""
    from fit.fitting import check_convexity
    from fit.pipeline import CONVEXITY_MARGIN

    shipped = load()
    smallest = check_convexity(shipped)
    assert smallest >= CONVEXITY_MARGIN
    assert smallest == pytest.approx(card["metrics"]["convexity_min_relative_stiffness"], rel=1e-9)
    strong = eqx.tree_at(lambda m: m.swelling_resistance, shipped, jnp.asarray(20.0))
    with pytest.raises(RuntimeError, match="not convex enough in V"):
        check_convexity(strong)


def test_the_60_mmHg_force_left_out_is_predicted_not_fitted(card):
    """The afterload validation of issue #17 is recorded: the fit without the 60-mmHg peak
    force predicts it, and the prediction is not the fitted value."""
    loo = card["metrics"]["peak_force_left_out"]
    assert loo["afterload_mmHg"] == 60.0
    assert loo["paper_N"] == 84.2
    fitted = card["metrics"]["peak_force_N"][1]
    assert abs(loo["predicted_N"] - fitted) > 1.0  # a different fit, not a copy
    assert loo["relative_error"] == pytest.approx(loo["predicted_N"] / 84.2 - 1.0)
