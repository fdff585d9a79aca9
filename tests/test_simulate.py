"""``cardiosoft.experiment.run``: conservation, robustness, the paper's bench, periodic steady
states, metrics, failure reporting, compilation and derivatives.

Numbers are checked against independent sources: the paper's Fig. 10 values (read from the
dataset, not typed in), closed forms of the Windkessel (mass balance of the capacitor in a
periodic steady state; exponential decay while the outlet valve is shut), quadratures of the
traces with scipy, one more beat integrated with ``cardiosoft.solve.integrate``, and central
finite differences. Results are shared through module-scoped fixtures: one compile per scene
structure.
"""

import dataclasses
import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import trapezoid

from cardiosoft import batch, static
from cardiosoft.batch import PULL_SAMPLES, scene_circuit, solve_beats
from cardiosoft.datasets import load_paper_data
from cardiosoft.experiment import run
from cardiosoft.pump import load
from cardiosoft.results import RunResult, member_results, summary_records
from cardiosoft.scene import load_scene
from cardiosoft.solve import SolverConfig, integrate, preset

ML = 1e-6  # m^3
MMHG = 133.322387415  # Pa
DYNAMIC_SCENES = ("bench-dynamic", "lv-systemic", "rv-pulmonary")


@pytest.fixture(scope="module")
def bench():
    """The shipped bench run to its periodic steady state (the default path), with its energy
    account: the cable's work integrated by the solver with the states, a second way to the
    mechanical work than the metric's trapezoid over the force samples."""
    return run("bench-dynamic", energy=True)


@pytest.fixture(scope="module")
def twenty_beats():
    """Exactly 20 beats of each dynamic scene (lv and rv share one compiled structure)."""
    return {name: run(name, beats=20) for name in DYNAMIC_SCENES}


def pull_phase(result, member):
    """Samples of the pull (first part of the beat, up to pull_fraction * period)."""
    tr = member.traces
    t_pull = result.scene.pull_fraction * 60.0 / result.scene.bpm
    return tr["time"] <= t_pull * (1 + 1e-12)


def finite_metrics(member):
    """Every metric finite, or set to NaN on purpose and flagged (an efficiency that is not one;
    the EF of a pump swung below zero volume)."""
    flagged = {f.split(" P_a SV / M")[0].replace(" ", "_") for f in member.flags}
    if any("EF (SV / EDV" in f for f in member.flags):
        flagged.add("ejection_fraction")
    return all(math.isfinite(v) or k in flagged for k, v in member.metrics.items())


# ---------------------------------------------------------------------------- conservation


@pytest.mark.parametrize("name", DYNAMIC_SCENES)
def test_volume_is_conserved_over_twenty_beats(twenty_beats, name):
    result = twenty_beats[name]
    assert result.ok, [m.message for m in result.members]
    for m in result.members:
        assert m.beats == 20
        assert 0.0 <= m.volume_drift <= 1e-9


def test_bench_pump_plus_column_volume_is_constant_within_the_beat(twenty_beats):
    """Independent of volume_drift (beat ends only): every sample of the last beat."""
    result = twenty_beats["bench-dynamic"]
    for m in result.members:
        v0 = float(scene_circuit(result.scene, load(), m.afterload).init()["volume"])
        total = m.traces["volume"] + m.traces["column_volume"]
        np.testing.assert_allclose(total, v0, rtol=1e-9)


# ---------------------------------------------------------------------------- no NaN


# 180 bpm is slow (40 s): CI keeps its 20-minute budget; tests/test_batch.py shoots the
# bench to its orbit in CI.
@pytest.mark.parametrize("bpm", [30, pytest.param(180, marks=pytest.mark.slow)])
def test_bench_is_finite_and_steady_at_extreme_rates_and_afterloads(bench, bpm):
    """At 180 bpm the calibrated bench rings (its column sloshes near 0.4-0.5 Hz, fit/bench.py):
    beat after beat is still 0.09 ml a beat off at 150 mmHg after 40 beats, so the orbit is
    found by Newton shooting there (issue #14, item 6); at 30 bpm beat after beat."""
    steady = "shooting" if bpm > 60 else "beats"
    result = run("bench-dynamic", bpm=bpm, afterload=[0, 75, 150], steady=steady)
    assert [m.afterload / MMHG for m in result.members] == pytest.approx([0, 75, 150])
    for m in result.members:
        assert m.ok, m.message
        assert finite_metrics(m), m.metrics
        assert all(np.all(np.isfinite(v)) for v in m.traces.values())
        assert m.metrics["stroke_volume"] > 0


@pytest.mark.parametrize("bpm", [30, 180])
@pytest.mark.parametrize("name", ["lv-systemic", "rv-pulmonary"])
def test_windkessel_scenes_are_finite_at_extreme_rates(twenty_beats, name, bpm):
    result = run(name, bpm=bpm, beats=20)  # same compiled structure as twenty_beats
    (m,) = result.members
    assert m.ok, m.message
    assert finite_metrics(m), m.metrics
    assert all(np.all(np.isfinite(v)) for v in m.traces.values())
    assert m.metrics["stroke_volume"] > 0


@pytest.mark.slow
@pytest.mark.parametrize("bpm", [30, 60, 120, 180, 240, 300])
@pytest.mark.parametrize("name", DYNAMIC_SCENES)
def test_every_dynamic_scene_is_finite_over_the_rate_range(name, bpm):
    kwargs = {"afterload": [0, 75, 150]} if name.startswith("bench") else {}
    result = run(name, bpm=bpm, **kwargs)
    for m in result.members:
        assert "solver failed" not in m.message, m.message
        assert finite_metrics(m), m.metrics
        assert all(np.all(np.isfinite(v)) for v in m.traces.values())


# ---------------------------------------------------------------------------- the paper


def test_bench_matches_the_papers_30_bpm_stroke_volumes(bench):
    paper = load_paper_data().fig10_bench
    assert bench.scene.bpm == 30
    heads = [m.afterload / MMHG for m in bench.members]
    assert heads == pytest.approx(list(paper["afterload_mmHg"]))
    for i, m in enumerate(bench.members):
        assert m.ok, m.message
        dynamic = m.metrics["stroke_volume"] / ML
        static = m.metrics["static_stroke_volume"] / ML
        assert abs(dynamic - paper["dynamic_sv_ml"][i]) <= paper["dynamic_sv_sd_ml"][i], dynamic
        assert abs(static - paper["static_sv_ml"][i]) <= paper["static_sv_sd_ml"][i], static


# ---------------------------------------------------------------------------- periodicity

PERIODIC = {
    "volume": "volume",
    "flow": "outflow",
    "column_volume": "column_volume",
    "relaxation": "relaxation",
}


def end_state(member, index=-1):
    tr = member.traces
    return {
        "afterload": {"column_volume": jnp.asarray(tr["column_volume"][index])},
        "flow": jnp.asarray(tr["outflow"][index]),
        "volume": jnp.asarray(tr["volume"][index]),
        "relaxation": jnp.asarray(tr["relaxation"][index]),
    }


def test_bench_stops_at_its_steady_state(bench):
    tol = bench.scene.steady_tol
    for m in bench.members:
        assert m.ok, m.message
        assert 1 < m.beats < bench.scene.max_beats
        assert 0 <= m.residual <= tol
        # the residual is the change over the last beat, recomputed from its first/last sample
        change = max(abs(m.traces[key][-1] - m.traces[key][0]) / ML for key in PERIODIC.values())
        assert change == pytest.approx(m.residual, rel=1e-9, abs=1e-12)


def test_one_more_beat_from_the_returned_state_repeats_it(bench):
    scene = bench.scene
    tol = scene.steady_tol
    period = 60.0 / scene.bpm
    for m in bench.members:
        assert m.traces["time"][-1] == pytest.approx(period)
        circuit = scene_circuit(scene, load(), m.afterload)
        y_end = end_state(m)
        assert set(y_end) == set(circuit.init())
        sol = integrate(
            circuit,
            y_end,
            0.0,
            period,
            jump_ts=circuit.actuation.kink_times(1),
            config=preset(scene.accuracy),
        )
        assert sol.result == diffrax.RESULTS.successful
        y_next = jax.tree_util.tree_map(lambda a: float(a[-1]), sol.ys)
        change = (
            max(
                abs(y_next["volume"] - float(y_end["volume"])),
                abs(y_next["flow"] - float(y_end["flow"])),
                abs(
                    y_next["afterload"]["column_volume"]
                    - float(y_end["afterload"]["column_volume"])
                ),
                abs(y_next["relaxation"] - float(y_end["relaxation"])),
            )
            / ML
        )
        # still periodic to the scene's tolerance one beat later. (Not necessarily below the last
        # change: the shell's relaxation makes the approach to the cycle oscillate a little.)
        assert change <= tol, (m.label, change, m.residual)


# ---------------------------------------------------------------------------- Windkessel


def test_lv_windkessel_mass_balance_in_the_periodic_steady_state(twenty_beats):
    """Over a periodic beat C * delta(pc) = int q - int (pc - pv)/Rd = 0: the mean outflow is the
    mean drain of the capacitor; and the SV less what flows back through the closing valves."""
    result = twenty_beats["lv-systemic"]
    scene = result.scene
    (m,) = result.members
    assert m.residual <= scene.steady_tol  # 20 beats reach the periodic state
    _, c, rd = scene.windkessel
    assert rd == pytest.approx(1.05 * MMHG / ML)
    assert c == pytest.approx(1.3 * ML / MMHG)
    tr = m.traces
    t, pc = tr["time"], tr["node_pressure"]
    period = 60.0 / scene.bpm
    assert t[-1] - t[0] == pytest.approx(period)
    mean_out = trapezoid(tr["outflow"], t) / period
    mean_drain = trapezoid((pc - scene.venous_pressure) / rd, t) / period
    assert mean_out == pytest.approx(mean_drain, rel=1e-3)
    # (SV and CO against an independent solution of the same equations:
    # tests/test_valve_scenes.py; recomputed here from the volume samples they would only
    # repeat the metric's definition)
    # everything ejected drains through Rd, less what flows back through the valves as they
    # close: the smooth law's backflow, q = dp sigmoid(dp / w) / R < 0 for dp < 0, is at most
    # 0.28 w / R within a few w of closing. Measured: SV 42.79 ml, 42.20 ml drained, 0.97 ml
    # back through the inlet valve and 0.06 ml through the outlet valve over the beat.
    backflow = trapezoid(np.minimum(tr["inflow"], 0) + np.minimum(tr["outflow"], 0), t)
    assert 0.0 <= (m.metrics["cardiac_output"] - mean_drain) * period <= -backflow


def test_lv_windkessel_decays_exponentially_while_the_aortic_valve_is_shut(twenty_beats):
    result = twenty_beats["lv-systemic"]
    scene = result.scene
    (m,) = result.members
    _, c, rd = scene.windkessel
    tr = m.traces
    t, pc, q = tr["time"], tr["node_pressure"], tr["outflow"]
    shut = np.flatnonzero(np.abs(q) < 1e-12 * ML)  # neither forward nor back (closing) flow
    assert shut.size > 50
    # the longest contiguous run of samples with the valve shut (diastole)
    runs = np.split(shut, np.flatnonzero(np.diff(shut) > 1) + 1)
    idx = max(runs, key=len)
    assert t[idx[-1]] - t[idx[0]] > 0.3  # a good part of the 1 s beat
    pv = scene.venous_pressure
    expected = pv + (pc[idx[0]] - pv) * np.exp(-(t[idx] - t[idx[0]]) / (rd * c))
    np.testing.assert_allclose(pc[idx], expected, rtol=1e-5)


# ---------------------------------------------------------------------------- model findings


def test_a_cable_only_pulls(bench):
    for m in bench.members:
        assert m.traces["cable_force"].min() >= 0.0, (m.label, m.traces["cable_force"].min())


def test_dynamic_peak_force_and_efficiency_are_near_the_papers(bench):
    """Peak forces are not used by the bench calibration (SVs and work are): they validate."""
    paper = load_paper_data().fig10_bench
    for i, m in enumerate(bench.members):
        assert m.metrics["peak_force"] == pytest.approx(paper["peak_force_N"][i], rel=0.10)
        assert m.metrics["efficiency"] == pytest.approx(paper["efficiency"][i], abs=0.02)


@pytest.mark.xfail(
    strict=True,
    reason="MODEL: dynamic peak force 53.8/81.8/99.0 N at 30 bpm against the paper's "
    "54.4/84.2/93.3 N (Fig. 10(d)): 6.2 % high at 90 mmHg. The quasi-static forces are within "
    "4.5 % (python -m fit --report); the bench calibration (python -m fit.bench) does not see "
    "the forces, and its tube and shell relaxation are left on a flat valley by the data",
)
def test_dynamic_peak_force_within_five_percent(bench):
    paper = load_paper_data().fig10_bench
    for i, m in enumerate(bench.members):
        assert m.metrics["peak_force"] == pytest.approx(paper["peak_force_N"][i], rel=0.05)


def test_the_credibility_report_says_what_these_tests_say(bench):
    """Issue #42: the report's Fig. 10 lines have the verdicts of the three tests above: the
    SVs within the SD, the forces within 10 % and the efficiencies within 0.02 met, the 5 %
    force target not (the strict xfail)."""
    from cardiosoft.credibility.validation import bench_checks

    verdicts = [c.met for c in bench_checks(summary_records(bench))]
    assert verdicts == [True, True, False, True]


# ---------------------------------------------------------------------------- metrics


def test_metrics_agree_with_the_traces_integrated_another_way(bench):
    """Each metric against a quantity the solver integrated on its own, not recomputed from the
    samples the metric used:

    - SV (the pump's EDV - ESV) against the column's rise, the paper's dynamic SV: the column's
      volume is a state of its own (dV_col/dt = q, the pump's dV/dt = -q); a Runge-Kutta
      method keeps the linear invariant, so the two agree to round-off (1e-8 allowed);
    - CO x period against the same rise;
    - the mechanical work M (the trapezoid over the 201 force samples of the pull) against the
      cable's work F_cable dx/dt integrated by the solver as a state of the energy account;
      they differ by the trapezoid's error, estimated here from every other sample
      (Richardson, (T_h - T_2h) / 3), plus the solver's (rtol 1e-6);
    - the efficiency against P_a x (column rise) / (that work), with P_a the head before the
      pull (the bench's definition)."""
    scene = bench.scene
    for m in bench.members:
        tr, x = m.traces, m.metrics
        column = tr["column_volume"]
        rise = column.max() - column.min()
        assert x["stroke_volume"] == pytest.approx(rise, rel=1e-8)
        assert x["cardiac_output"] * 60.0 / scene.bpm == pytest.approx(rise, rel=1e-8)
        assert 0 < x["ejection_fraction"] < 1

        pull = pull_phase(bench, m)
        assert pull.sum() == PULL_SAMPLES
        assert np.all(np.diff(tr["pull"][pull]) > 0)
        force, position = tr["cable_force"][pull], tr["pull"][pull]
        integrated = tr["cable_in"][pull][-1] - tr["cable_in"][pull][0]
        rule = abs(trapezoid(force, position) - trapezoid(force[::2], position[::2])) / 3
        assert abs(x["mech_work"] - integrated) <= 2 * rule + 1e-6 * integrated
        assert x["reference_pressure"] == pytest.approx(m.afterload, rel=1e-12)
        work_tol = (2 * rule + 1e-6 * integrated) / integrated
        assert x["efficiency"] == pytest.approx(
            m.afterload * rise / integrated, rel=work_tol + 1e-8
        )
        assert 0 < x["efficiency"] < 1


def test_summary_records_are_in_user_units(bench):
    records = summary_records(bench)
    for r, m in zip(records, bench.members, strict=True):
        assert r["afterload_mmHg"] == pytest.approx(m.afterload / MMHG)
        assert r["dynamic_sv_ml"] == pytest.approx(m.metrics["stroke_volume"] / ML)
        assert r["static_sv_ml"] == pytest.approx(m.metrics["static_stroke_volume"] / ML)
        assert r["cardiac_output_l_min"] == pytest.approx(m.metrics["cardiac_output"] * 60.0 / 1e-3)
        assert r["beats"] == m.beats and r["ok"] is True


# ---------------------------------------------------------------------------- failures


def test_a_failing_member_is_reported_by_name_and_spares_the_others(bench):
    """One member's column head is NaN (traced, past the eager checks): its solve exhausts
    max_steps; the batch must not raise and the other members must not notice."""
    scene = bench.scene
    heads = jnp.asarray(scene.afterloads).at[1].set(jnp.nan)
    out = jax.jit(lambda h: solve_beats(scene, afterload=h, energy=True))(heads)  # as `bench`
    labels = ["30 mmHg", "60 mmHg", "90 mmHg"]
    members = member_results(labels, out, None)
    by_label = {m.label: m for m in members}
    failed = by_label["60 mmHg"]
    assert not failed.ok
    assert failed.message.startswith("solver failed in beat 1")
    assert "maximum number of solver steps" in failed.message
    for label in ("30 mmHg", "90 mmHg"):
        good = by_label[label]
        reference = next(m for m in bench.members if m.label == label)
        assert good.ok, good.message
        assert good.beats == reference.beats
        assert good.metrics["stroke_volume"] == pytest.approx(
            reference.metrics["stroke_volume"], rel=1e-9
        )
    records = summary_records(RunResult(scene, members))  # reporting a failure does not raise
    assert [r["ok"] for r in records] == [True, False, True]


@pytest.mark.slow
def test_every_member_fails_with_a_tiny_step_budget(monkeypatch):
    monkeypatch.setattr(batch, "preset", lambda name, stiff=False: SolverConfig(max_steps=5))
    result = run("bench-dynamic", accuracy="fast", beats=2)
    assert len(result.members) == 3
    for m in result.members:
        assert not m.ok
        assert "solver failed in beat 1" in m.message
        assert "maximum number of solver steps" in m.message


# ---------------------------------------------------------------------------- compilation


def test_new_parameter_values_do_not_recompile(bench, monkeypatch):
    """Afterloads, bpm, Omega, C and the tolerances of a preset are data, not structure."""
    traces = {"periodic_beats_batch": 0, "quasi_static_stroke": 0}
    for module, name in ((batch, "periodic_beats_batch"), (static, "quasi_static_stroke")):
        original = getattr(module, name)

        def spy(*args, _name=name, _original=original, **kwargs):
            traces[_name] += 1
            return _original(*args, **kwargs)

        monkeypatch.setattr(module, name, spy)
    first = run("bench-dynamic")  # compiled already by `bench` (or now, once)
    assert all(n <= 1 for n in traces.values())
    seen = dict(traces)
    variants = [
        {"afterload": [10, 20, 40]},
        {"bpm": 45},
        {"omega": 3.5},
        {"shortening": 0.3},
        {"accuracy": "fast"},
        {"bpm": 75, "omega": 5.0, "afterload": [15, 45, 120]},
    ]
    results = [run("bench-dynamic", **kwargs) for kwargs in variants]
    assert traces == seen
    # the new values were used, not cached results
    svs = {round(r.members[0].metrics["stroke_volume"] / ML, 6) for r in [first, *results]}
    assert len(svs) == len(variants) + 1
    # the spies are wired: a new batch size is a new structure and does retrace (static part only,
    # which is cheap)
    # (a batch of seven, which no other test of this worker's process compiles)
    run("bench-static", afterload=[11, 22, 33, 44, 55, 66, 77])
    assert traces["quasi_static_stroke"] == seen["quasi_static_stroke"] + 1


# ---------------------------------------------------------------------------- gradient


def test_stroke_volume_tangent_wrt_tube_length_matches_finite_differences():
    """Any number of the scene is a leaf of the public solve: d SV / d tube length, forward mode."""
    scene = load_scene("bench-dynamic")
    config = dataclasses.replace(preset("reference"), adjoint=diffrax.ForwardMode())
    head = scene.afterloads[1]

    @jax.jit
    def sv_and_tangent(length):
        def stroke_volume(length):
            out = solve_beats(
                scene.replace(tube_length=length), afterload=head, beats=2, config=config,
                save="metrics",
            )
            return out.metrics.stroke_volume[0], out.succeeded[0]

        (sv, ok), (dsv, _) = jax.jvp(stroke_volume, (length,), (jnp.ones_like(length),))
        return sv, ok, dsv

    length = jnp.asarray(scene.tube_length)
    _, ok, tangent = sv_and_tangent(length)
    assert bool(ok)
    assert np.isfinite(float(tangent)) and float(tangent) != 0.0
    h = 1e-4 * scene.tube_length
    sv_plus, _, _ = sv_and_tangent(length + h)
    sv_minus, _, _ = sv_and_tangent(length - h)
    central = (float(sv_plus) - float(sv_minus)) / (2 * h)
    assert float(tangent) == pytest.approx(central, rel=1e-3)
