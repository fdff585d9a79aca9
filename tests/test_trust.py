"""Every result says whether it can be trusted (issue #14): steady or not, inside the
surrogate's fitted range or not, a cable that would push, an efficiency that is not one; and
edge inputs get an answer or one clear line, never a traceback or invalid JSON."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from cardiosoft.experiment import run, run_designs
from cardiosoft.pump import Domain
from cardiosoft.results import MemberResult, RunResult, flags, summary_records
from cardiosoft.scene import load_scene
from cardiosoft.units import mmHg


def beat(**changes) -> dict[str, float]:
    """A member's metrics as :func:`cardiosoft.results.member_results` hands them to ``flags``:
    numbers built for each test (SI), plausible for the bench at 60 mmHg and changed where a
    test says so. Built, not simulated: a flag is tested on its own numbers, not on whichever
    defect today's surrogate shows at some rate (the 180-bpm cable that pushed)."""
    ml = 1e-6
    metrics = {
        "stroke_volume": 60 * ml, "ejected_volume": 60 * ml, "edv": 100 * ml, "esv": 40 * ml,
        "ejection_fraction": 0.6,
        "cardiac_output": 30 * ml, "peak_force": 80.0, "mech_work": 2.0,
        "reference_pressure": 60 * mmHg, "hydraulic_work_paper": 60 * mmHg * 60 * ml,
        "hydraulic_work_pull": 0.5, "stroke_work": 0.5, "efficiency": 60 * mmHg * 60 * ml / 2.0,
        "min_pump_pressure": 0.0, "max_pump_pressure": 100 * mmHg, "min_cable_force": 0.0,
    }
    return metrics | changes


def record(metrics: dict) -> dict:
    """The summary record of one bench member with these metrics and their flags."""
    reasons = flags(metrics, Domain())
    member = MemberResult("m", 60 * mmHg, True, "ok", 5, 0.0, 0.0, metrics, {}, reasons)
    result = RunResult(load_scene("bench-dynamic"), (member,))
    assert result.flagged == bool(reasons)
    (out,) = summary_records(result)
    json.loads(json.dumps(out, allow_nan=False))  # no NaN reaches the JSON
    assert out["flags"] == list(reasons)
    return out


def test_a_member_inside_the_fitted_range_has_no_flags():
    assert flags(beat(), Domain()) == ()


@pytest.mark.parametrize("edge", ["inside", "outside"])
def test_leaving_the_fitted_range_is_flagged(edge):
    """The chamber pressure's extremes against the fitted range, at its edges: exactly on them
    no flag, 0.1 mmHg past them one flag each, with the pressure and the limit."""
    lo, hi = Domain().pressure_mmHg
    past = 0.0 if edge == "inside" else 0.1
    metrics = beat(min_pump_pressure=(lo - past) * mmHg, max_pump_pressure=(hi + past) * mmHg)
    text = " | ".join(record(metrics)["flags"])
    below, above = f"below the fitted {lo:g} mmHg", f"above the fitted {hi:g} mmHg"
    if edge == "inside":
        assert text == ""
    else:
        assert f"down to {lo - past:.1f} mmHg, {below}" in text
        assert f"up to {hi + past:.1f} mmHg, {above}" in text


def test_a_cable_that_would_push_is_flagged():
    assert flags(beat(min_cable_force=0.0), Domain()) == ()
    (flag,) = record(beat(min_cable_force=-3.25))["flags"]
    assert flag.startswith("cable force down to -3.2 N") and "cable that pushes" in flag


def test_a_pump_emptied_below_zero_is_flagged_and_reports_no_ejection_fraction():
    """At 120 bpm the ss950-v3 bench swung the chamber to -8.3 ml and printed EF 1.05: a
    volume below zero is flagged and its EF, SV / EDV above 1, reported as none; at zero and
    above, the EF stands."""
    ml = 1e-6
    assert flags(beat(esv=0.0, edv=60 * ml, ejection_fraction=1.0), Domain()) == ()
    metrics = beat(esv=-8.3 * ml, edv=165.3 * ml, stroke_volume=173.6 * ml,
                   ejected_volume=173.6 * ml, ejection_fraction=173.6 / 165.3)
    out = record(metrics)
    assert math.isnan(metrics["ejection_fraction"]) and out["ef"] is None
    (flag,) = out["flags"]
    assert flag.startswith("pump volume down to -8.3 ml, below zero") and "1.05" in flag


def test_a_column_rise_above_the_pump_s_own_ejection_is_flagged():
    """The paper's dynamic SV is the column's peak rise (EDV - ESV); where the line's fluid still
    flows in after the pull has begun, it exceeds the pump's own ejection from the pull's start
    (the 30-bpm bench at 90 mmHg: 66.6 against 59.9 ml). Within the paper's largest relative SD
    of a dynamic SV (2.5 %) the two are the same number; beyond it, flagged with both."""
    from cardiosoft.results import SLOSHING_TOL

    ml = 1e-6
    within = beat(stroke_volume=60 * ml, ejected_volume=60 * (1 - 0.99 * SLOSHING_TOL) * ml)
    assert flags(within, Domain()) == ()
    (flag,) = record(beat(stroke_volume=66.6 * ml, ejected_volume=59.9 * ml))["flags"]
    assert flag.startswith("dynamic SV (the column's peak rise) 66.6 ml exceeds the pump's own "
                           "ejection from the pull's start, 59.9 ml")


@pytest.mark.parametrize(
    ("changes", "why"),
    [
        ({"hydraulic_work_pull": -0.1, "efficiency": 0.535}, "no net work on the fluid"),
        ({"efficiency": 1.06}, "above 1"),
        ({"efficiency": -0.2}, "below 0"),
        ({"mech_work": 0.0, "efficiency": math.inf}, "no mechanical work"),
    ],
)
def test_an_efficiency_that_is_not_one_is_not_reported(changes, why):
    """The paper's P_a SV / M is reported only for a pull that does work on the fluid and
    within [0, 1]: at 180 bpm the ss950-v3 bench gave 0.535 while its pull did negative
    hydraulic work (the column swinging back); otherwise none, flagged."""
    metrics = beat(**changes)
    out = record(metrics)
    assert math.isnan(metrics["efficiency"]), why
    assert out["efficiency"] is None
    assert any(f.startswith("efficiency P_a SV / M") for f in out["flags"])
    assert record(beat())["efficiency"] == pytest.approx(60 * mmHg * 60e-6 / 2.0)


def test_a_tiny_stroke_against_a_high_head_reports_no_efficiency_above_one():
    result = run("bench-static", shortening=0.001, afterload=[150])
    (record,) = summary_records(result)
    assert record["efficiency"] is None or 0 <= record["efficiency"] <= 1


def test_a_quasi_static_stroke_above_the_fitted_range_is_flagged():
    """From a 150-mmHg head the column's rise takes the quasi-static stroke above the fitted
    150 mmHg (to 152.54 at Omega 4, C 0.4: the hard-case suite's number); at 60 mmHg it
    stays inside. The flag gives the pressure, head + rho g SV / A_col, and how far."""
    from cardiosoft.scene import load_scene
    from cardiosoft.static import column_stiffness
    from cardiosoft.units import RHO_WATER, G

    result = run("bench-static", afterload=[60, 150])
    scene = load_scene("bench-static")
    k = float(column_stiffness(0.25 * math.pi * scene.column_diameter**2, RHO_WATER, G))
    low, high = result.members
    assert not any("static pressure" in f for f in low.flags)
    p = (high.afterload + k * high.metrics["static_stroke_volume"]) / mmHg
    assert p > Domain().pressure_mmHg[1]
    (flag,) = [f for f in high.flags if f.startswith("static pressure")]
    assert f"up to {p:.2f} mmHg" in flag and "above the fitted 150 mmHg" in flag


def test_zero_shortening_gives_zero_stroke_and_valid_json():
    result = run("bench-static", shortening=0.0, afterload=[0, 150])
    records = summary_records(result)
    json.loads(json.dumps(records, allow_nan=False))  # no NaN in the JSON
    for r in records:
        assert abs(r["static_sv_ml"]) < 1e-9
        assert r["efficiency"] is None


def test_a_windkessel_scene_has_no_static_stroke_volume_in_its_summary():
    result = run("lv-systemic", beats=2)
    (record,) = summary_records(result)
    assert record["static_sv_ml"] is None
    json.loads(json.dumps(record, allow_nan=False))


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: run("bench-dynamic", beats=2.5), "beats = 2.5"),
        (lambda: run_designs("bench-dynamic", designs=[]), "designs = "),
        (lambda: run_designs("bench-dynamic", designs=[(4.0,)]), "designs = "),
        (lambda: run("bench-dynamic", steady="newton"), "steady = 'newton'"),
    ],
)
def test_bad_arguments_name_themselves(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize("out", ["{file}/sub", "{file}"])
def test_an_unwritable_out_is_refused_before_simulating(tmp_path, out):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a folder")
    proc = subprocess.run(
        [sys.executable, "-m", "cardiosoft.simulate", "--out", out.format(file=a_file)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("error: --out")
    assert "Traceback" not in proc.stderr
    assert a_file.read_text() == "not a folder"


@pytest.mark.parametrize("name", ["bench-dynamic", "lv-systemic"])
def test_the_energy_account_closes_every_beat(name):
    """Work in (cables, filling source) = delivered past the outlet + lost (friction, shell
    viscosity, valves) + change of the shell's strain energy, per beat, whether or not the
    beat is steady (3 beats from rest). At the reference preset (rtol 1e-10) the account,
    integrated by the solver with the states, closes to ~1e-9 (measured 1e-9 to 5e-8, the
    latter at 180 bpm); 1e-6 is the issue's bar. The efficiency delivered / in is in [0, 1]."""
    from cardiosoft.batch import solve_beats
    from cardiosoft.scene import load_scene

    scene = load_scene(name).replace(accuracy="reference")
    out = solve_beats(scene, beats=3, energy=True, save="metrics")
    m = out.metrics
    assert bool(out.succeeded.all())
    assert float(m.energy_residual.max()) < 1e-6
    assert float(m.energy_efficiency.min()) >= 0.0 and float(m.energy_efficiency.max()) <= 1.0
    assert float(m.work_lost.min()) >= 0.0


# slow (68 s): CI keeps its 20-minute budget; the energy account of lv-systemic above still
# checks in CI that the loss (valves included) is >= 0 and the efficiency in [0, 1].
@pytest.mark.slow
def test_the_valves_only_dissipate():
    """lv-systemic at its steady state: the valves' loss over a beat (P_up - P_down) q >= 0
    and delivered <= work in. With the earlier smooth law w softplus(dp / w) / R (69 ml/s at
    dp = 0) a small stroke (Omega 4, C 0.01) had a valve loss of -1.66e-3 J and an energy
    efficiency of 1.119 (measured); now 3.4e-4 J and 0.971."""
    from cardiosoft.batch import solve_beats

    out = solve_beats(
        "lv-systemic", omega=4.0, shortening=[0.01, 0.4], energy=True, save="traces"
    )
    m, valves = out.metrics, out.traces["valves"]
    assert bool(out.steady.all())
    assert (valves[:, -1] - valves[:, 0] >= 0.0).all()
    assert (m.work_lost >= 0.0).all()
    assert (m.energy_efficiency >= 0.0).all() and (m.energy_efficiency <= 1.0).all()


# slow (31 s): a draw of the hard-case suite, which the slow suite runs; CI keeps its budget.
@pytest.mark.slow
def test_energy_ratios_are_none_where_they_are_not_meaningful():
    """bench-dynamic ('default'). C 1.9e-97 (Omega 3.88, 111.6 mmHg, 298.9 bpm: a hypothesis
    draw of the hard-case suite): the beat carries 6.8e-16 J, round-off of the shell's 0.34 J,
    and the residual was 1.5e80, the efficiency -3.2e80: both reported as none, flagged.
    Omega 0, C 0.4 is reported, in [0, 1]. (A beat whose shell still stores energy:
    test_an_energy_efficiency_of_a_beat_that_stores_energy_is_not_reported.)"""
    from cardiosoft.batch import solve_beats
    from cardiosoft.results import member_results

    out = solve_beats(
        "bench-dynamic",
        omega=[3.8763409659652757, 0.0],
        shortening=[1.914530883185141e-97, 0.4],
        afterload=np.asarray([111.61406296567601, 150.0]) * mmHg,
        bpm=[298.8540726443747, 60.0],
        energy=True,
        save="metrics",
    )
    vanishing, full = member_results(["a", "b"], out, None)
    assert math.isnan(vanishing.metrics["energy_residual"])
    assert math.isnan(vanishing.metrics["energy_efficiency"])
    assert any(f.startswith("energy account") for f in vanishing.flags)
    assert 0.0 <= full.metrics["energy_efficiency"] <= 1.0
    assert not any(f.startswith("energy") for f in full.flags)
    records = summary_records(RunResult(load_scene("bench-dynamic"), (vanishing, full)))
    json.loads(json.dumps(records, allow_nan=False))
    assert [r["energy_efficiency"] is None for r in records] == [True, False]


@pytest.mark.parametrize("stored", [0.0, 0.9e-3, 1.1e-3, -1.1e-3])
def test_an_energy_efficiency_of_a_beat_that_stores_energy_is_not_reported(stored):
    """delivered / in is an efficiency only for a beat periodic in the shell's energy: one
    whose shell stores more than STORED_CHANGE_TOL (1e-3) of the work in gets none, flagged, its
    residual kept (the account includes the stored change). Built numbers (J): the ss950-v3
    bench at Omega 0, C 0.01, 150 mmHg, 60 bpm was such a beat (8 %), steady to 0.01 ml."""
    from cardiosoft.results import STORED_CHANGE_TOL

    work_in = 2.0
    change = stored * work_in
    delivered = 0.5 * (work_in - change)
    metrics = beat(
        work_in=work_in, work_delivered=delivered, work_lost=work_in - change - delivered,
        stored_change=change, stored_energy=1.0, energy_residual=1e-9,
        energy_efficiency=delivered / work_in,
    )
    out = record(metrics)
    assert out["energy_residual"] == 1e-9
    if abs(stored) <= STORED_CHANGE_TOL:
        assert out["energy_efficiency"] == pytest.approx(delivered / work_in)
        assert not any(f.startswith("energy") for f in out["flags"])
    else:
        assert out["energy_efficiency"] is None
        assert any(f.startswith("energy efficiency") for f in out["flags"])


def test_a_compliance_below_the_validated_minimum_is_refused():
    """1e-6 ml/mmHg passed validation and then ran out of steps in beat 1."""
    from cardiosoft.scene import load_scene
    from cardiosoft.units import ml_per_mmHg

    scene = load_scene("lv-systemic")
    rp, _, rd = scene.windkessel
    with pytest.raises(ValueError, match=r"C_ml_per_mmHg' = 1e-06 ml/mmHg: allowed \[0.01"):
        scene.replace(windkessel=(rp, 1e-6 * ml_per_mmHg, rd))


def test_running_out_of_steps_says_how_to_raise_the_limit():
    result = run("bench-dynamic", afterload=[60], beats=1, max_steps=100, accuracy="reference")
    (m,) = result.members
    assert not m.ok
    assert "maximum number of solver steps" in m.message
    assert "100 per beat now" in m.message and "--max-steps" in m.message
    with pytest.raises(ValueError, match="max_steps = 5 steps"):
        run("bench-dynamic", max_steps=5)


# slow (57 s): CI keeps its 20-minute budget; in CI, tests/test_stress.py runs the hard-case
# suite's cli group in process (bench-static), which compares the CLI's records with the API's.
@pytest.mark.slow
def test_the_cli_and_the_api_agree_on_the_bench(tmp_path):
    """The dynamic bench at 30 bpm, 60 mmHg.
    Both find the orbit itself by Newton shooting, so they differ only by the round-off of two
    compilations (the CLI's at XLA level 0, equinox's checks as NaN) carried through adaptive
    steps, which the 'default' preset's own error bounds: here its SV is 6.7e-4 ml and its peak
    force 5.0e-4 N from the 'reference' preset's (measured). Allowed: three times that."""
    proc = subprocess.run(
        [
            sys.executable, "-m", "cardiosoft.simulate", "--bpm", "30", "--afterload", "60",
            "--steady", "shooting", "--out", str(tmp_path), "--no-plot", "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "CARDIOSOFT_COMPILE_CACHE": "0"},
    )
    assert proc.returncode == 0, proc.stderr
    (cli,) = json.loads((tmp_path / "summary.json").read_text())["records"]
    (api,) = summary_records(run("bench-dynamic", bpm=30, afterload=[60], steady="shooting"))
    assert cli["dynamic_sv_ml"] == pytest.approx(api["dynamic_sv_ml"], abs=2e-3)
    assert cli["peak_force_N"] == pytest.approx(api["peak_force_N"], abs=1.5e-3)


# slow (40 s): CI keeps the time budget; in CI, tests/test_stress.py runs the hard-case
# suite's cli group in process (bench-static), which compares the CLI's records with the API's.
@pytest.mark.slow
def test_the_cli_and_the_api_agree_on_a_valve_scene(tmp_path):
    """lv-systemic at 60 bpm: the CLI compiles at XLA optimisation level 0 (and resolves
    equinox's checks to NaN for its compile cache), the API at the default; they used to
    differ by 0.3 ml. Beat after beat, each stops within the steady tolerance (0.01 ml) of a
    cycle change, not of the orbit, and a beat more or less moves the SV by up to that much
    (measured 0.011 ml apart). So both find the orbit itself, by Newton shooting (cycle change
    ~1e-10 ml): then they differ by the compilers' round-off carried through the adaptive
    steps (measured 0.0015 ml), which the 'default' preset's accuracy on this scene bounds:
    its SV is 0.016 ml from Kvaerno5 at rtol 1e-10 (notebooks/accuracy.ipynb, rtol 1e-06)."""

    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "cardiosoft.simulate",
            "--scene",
            "lv-systemic",
            "--bpm",
            "60",
            "--steady",
            "shooting",
            "--out",
            str(tmp_path),
            "--no-plot",
            "--quiet",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    cli = json.loads((tmp_path / "summary.json").read_text())["records"][0]["dynamic_sv_ml"]
    (api,) = summary_records(run("lv-systemic", bpm=60, steady="shooting"))
    assert cli == pytest.approx(api["dynamic_sv_ml"], abs=0.016)
