"""Each block's record of an svZeroDSolver model (:mod:`cardiosoft.network.block_metrics`): a
vessel's pressures and flow against a closed form, a chamber's and the pump's beat against the
closed loop's own metrics of the same scene (a second implementation)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import diffrax
import numpy as np
import pytest

import cardiosoft as cs
from cardiosoft.network import read, simulate
from cardiosoft.network.block_metrics import block_metrics, closed_integral
from cardiosoft.network.export import to_svzerod
from cardiosoft.network.loop_batch import solve_loop
from cardiosoft.network.loop_records import loop_block_records
from cardiosoft.network.pump_in_model import UNIT_SYSTEMS, PumpPlacement, pump_metrics
from cardiosoft.solve import preset
from cardiosoft.units import l_per_min, ml, mmHg

CASE = Path(__file__).parent / "data" / "svzerod" / "pulsatileFlow_R_RCR.json"


def test_a_vessels_record_holds_the_rcr_closed_form_at_the_periodic_steady_state(tmp_path):
    """``simulate --scene pulsatileFlow_R_RCR.json --steady``: at the periodic steady state
    the RCR's capacitor pressure has the mean Rd <Q> (``C dPc/dt = Q - Pc / Rd`` over a beat),
    so the RCR's inlet has the mean (Rp + Rd) <Q> and the vessel's R <Q> more (Pd = 0); each
    mean flow is <Q>, the inflow table's mean (piecewise linear, its knots on the output
    times: exact). Bound: the trapezoid rule's error on the capacitor's pressure, h^2 / 12
    max |P''| over the beat (estimated from the samples' second differences), plus the
    integration's 1e-6 of the largest pressure."""
    from cardiosoft.simulate import main

    out = tmp_path / "run"
    assert main(["--scene", str(CASE), "--steady", "--out", str(out), "--quiet"]) == 0
    blocks = json.loads((out / "summary.json").read_text())["blocks"]
    config = json.loads(CASE.read_text())
    table = config["boundary_conditions"][0]["bc_values"]
    rcr = config["boundary_conditions"][1]["bc_values"]
    R = config["vessels"][0]["zero_d_element_values"]["R_poiseuille"]
    t, q = np.asarray(table["t"]), np.asarray(table["Q"])
    mean_q = np.sum(0.5 * (q[1:] + q[:-1]) * np.diff(t)) / (t[-1] - t[0])

    header = (out / "traces.csv").read_text().splitlines()[0].split(",")
    columns = np.loadtxt(out / "traces.csv", delimiter=",", skiprows=1).T
    traces = dict(zip(header, columns, strict=True))
    p_out = traces["pressure:branch0_seg0:OUT"]
    capacitor = p_out - rcr["Rp"] * np.interp(traces["time"], t, q)
    bound = np.max(np.abs(np.diff(capacitor, 2))) / 12 + 1e-6 * np.max(np.abs(p_out))

    expected_rcr = (rcr["Rp"] + rcr["Rd"]) * mean_q + rcr["Pd"]
    assert blocks["OUT"]["pressure_mean"] == pytest.approx(expected_rcr, abs=bound)
    vessel = blocks["branch0_seg0"]
    assert vessel["pressure_mean"] == pytest.approx(expected_rcr + R * mean_q, abs=bound)
    for record in (vessel, blocks["OUT"]):
        assert record["flow_mean"] == pytest.approx(mean_q, rel=1e-9)
        assert record["pressure_diastolic"] < record["pressure_mean"] < record["pressure_systolic"]


def _exported(name, units="cgs", beats=3):
    """The scene after ``beats`` beats from its start, solved as ``cardiosoft export`` writes it
    (read back, the network's run) and by ``solve_loop``, both at the reference preset."""
    scene = cs.load_scene(name)
    model = read(json.loads(json.dumps(to_svzerod(scene, units, beats))))
    traces = simulate(model, "reference")
    config = dataclasses.replace(preset("reference"), adjoint=diffrax.ForwardMode())
    solution = solve_loop(scene, beats=beats, save="traces", config=config)
    own = {k: np.asarray(v)[0] for k, v in solution.traces.items()}
    return scene, model, traces, solution.metrics, own


P_CGS, V_CGS = UNIT_SYSTEMS["cgs"][:2]
RECORD_KEYS = {  # the loop's record key: the model's key, the scale to the loop's units, size
    "edv_ml": ("edv", V_CGS / ml, "edv"),
    "esv_ml": ("esv", V_CGS / ml, "edv"),
    "stroke_volume_ml": ("stroke_volume", V_CGS / ml, "edv"),
    "ejection_fraction": ("ejection_fraction", 1.0, "one"),
    "pressure_mean_mmHg": ("pressure_mean", P_CGS / mmHg, "systolic"),
    "pressure_systolic_mmHg": ("pressure_systolic", P_CGS / mmHg, "systolic"),
    "pressure_diastolic_mmHg": ("pressure_diastolic", P_CGS / mmHg, "systolic"),
    "flow_mean_l_min": ("flow_mean", V_CGS / l_per_min, "flow"),
}


def _agree(ours, theirs, scale):
    """Two solves of three beats at the reference preset's rtol 1e-10 on the same output
    times: 1e-6 of the value's scale, as the exported scene's traces agree
    (``tests/test_network_loop.py``)."""
    assert abs(ours - float(np.ravel(theirs)[0])) <= 1e-6 * scale


def test_a_chambers_and_a_vessels_record_equal_the_closed_loops_metrics():
    """``heart`` written as an svZeroDSolver model and read back: the left ventricle's EDV,
    ESV, SV and EF and the systemic arteries' mean, systolic and diastolic pressure equal the
    closed loop's own metrics (``SideMetrics``, computed in JAX from its samples), and every
    chamber's and vessel's record equals the closed loop's own (``loop_block_records``,
    ``summary.json``'s ``blocks``) to the two solves' 1e-6."""
    _, model, traces, metrics, own = _exported("heart")
    blocks = block_metrics(model.network, traces)
    p, v = UNIT_SYSTEMS["cgs"][:2]
    left = metrics.left
    lv = blocks["lv"]
    for key in ("edv", "esv", "stroke_volume"):
        _agree(lv[key] * v, getattr(left, key), float(np.ravel(left.edv)[0]))
    _agree(lv["ejection_fraction"], left.ejection_fraction, 1.0)
    aorta = blocks["ar_sys"]
    scale = float(np.ravel(left.arterial_systolic)[0])
    _agree(aorta["pressure_mean"] * p, left.arterial_mean, scale)
    _agree(aorta["pressure_systolic"] * p, left.arterial_systolic, scale)
    _agree(aorta["pressure_diastolic"] * p, left.arterial_diastolic, scale)
    assert set(blocks) == {"la", "lv", "ra", "rv", "ar_sys", "ven_sys", "ar_pul", "ven_pul"}
    # the closed loop's own records (summary.json's blocks) of the same beat, in user units
    records = loop_block_records(own)
    assert set(records) == set(blocks)
    largest_flow = max(np.max(np.abs(own[k])) for k in own if k.endswith("_flow")) / l_per_min
    for name, record in records.items():
        for key, value in record.items():
            theirs, scale, size = RECORD_KEYS[key]
            size = {"edv": record.get("edv_ml"), "systolic": record.get(
                "pressure_systolic_mmHg"), "flow": largest_flow, "one": 1.0}[size]
            assert abs(blocks[name][theirs] * scale - value) <= 1e-6 * size, (name, key)


@pytest.mark.slow
def test_the_pumps_work_and_efficiency_equal_the_closed_loops():
    """``soft-lv`` written and read back: the pump's cable work (closed integral of F dx) and
    stroke work (-(closed integral of p dV)) equal the closed loop's ``cable_work`` and
    ``stroke_work``, and their ratio its ``efficiency``."""
    scene, model, traces, metrics, _ = _exported("soft-lv", units="mmHg")
    placement = PumpPlacement("lv", "mmHg", scene.lv.omega, scene.lv.shortening)
    pump = pump_metrics(traces, placement, model.network.nodes)
    left = metrics.left
    scale = abs(float(np.ravel(left.cable_work)[0]))
    _agree(pump["cable_work_J"], left.cable_work, scale)
    _agree(pump["stroke_work_J"], left.stroke_work, scale)
    _agree(pump["stroke_volume_ml"] * 1e-6, left.stroke_volume, float(np.ravel(left.edv)[0]))
    _agree(pump["efficiency"], left.efficiency, 1.0)
    assert pump["efficiency"] == pytest.approx(pump["stroke_work_J"] / pump["cable_work_J"])
    assert 0.0 < pump["efficiency"] < 1.0


def test_the_combined_heart_block_has_a_record_per_chamber():
    """svZeroDSolver's ``ClosedLoopHeartAndPulmonary`` holds four chambers: each has its own
    record, read from its own volume variable (``V_LV:NAME`` ...), the beat's extremes."""
    case = CASE.parent / "closedLoopHeart_singleVessel.json"
    model = read(case)
    traces = simulate(model)
    blocks = block_metrics(model.network, traces)
    for chamber in ("RA", "RV", "LA", "LV"):
        volume = traces.values[f"V_{chamber}:CLH"]
        record = blocks[f"CLH:{chamber}"]
        assert (record["edv"], record["esv"]) == (np.max(volume), np.min(volume))


def test_the_records_describe_the_last_beat_when_every_beat_is_output(tmp_path):
    """An RCR charged from rest (time constant Rd C = 10 s) over 30 beats, every beat output:
    the records are the last beat's (its extremes and means), not the run's."""
    from cardiosoft.simulate import main

    config = json.loads((CASE.parent / "steadyFlow_R_RCR.json").read_text())
    config["boundary_conditions"][1]["bc_values"]["C"] = 0.01
    config["simulation_parameters"] |= {"steady_initial": False, "output_all_cycles": True}
    path = tmp_path / "charging_rcr.json"
    path.write_text(json.dumps(config))
    out = tmp_path / "run"
    assert main(["--scene", str(path), "--out", str(out), "--quiet"]) == 0
    record = json.loads((out / "summary.json").read_text())["blocks"]["OUT"]
    header = (out / "traces.csv").read_text().splitlines()[0].split(",")
    table = np.loadtxt(out / "traces.csv", delimiter=",", skiprows=1)
    points = config["simulation_parameters"]["number_of_time_pts_per_cardiac_cycle"]
    assert table.shape[0] == 30 * (points - 1) + 1  # every beat in traces.csv
    pressure = table[-points:, header.index("pressure:branch0_seg0:OUT")]
    assert record["pressure_diastolic"] == pytest.approx(pressure.min(), rel=1e-9)
    assert record["pressure_systolic"] == pytest.approx(pressure.max(), rel=1e-9)
    # the run's own lowest: Rp Q = 5,000 at rest, the capacitor empty
    assert np.min(table[:, header.index("pressure:branch0_seg0:OUT")]) < 0.6 * pressure.min()


def test_a_pump_that_does_no_cable_work_has_no_efficiency():
    """A beat whose pull does not move (zero cable work): the efficiency is None (null in
    ``summary.json``), not a division by zero."""
    from types import SimpleNamespace

    t = np.linspace(0.0, 1.0, 11)
    values = {
        "Vc:lv": 1e-4 * (1.5 + np.cos(2 * np.pi * t)),  # m^3 ("si")
        "cable_force:lv": np.full_like(t, 10.0),
        "pull:lv": np.full_like(t, 0.01),
        "pressure:a:lv": 1e3 * (1.0 + np.sin(2 * np.pi * t)),
    }
    record = pump_metrics(
        SimpleNamespace(values=values), PumpPlacement("lv", "si"), [("a", "lv"), ("lv", "b")]
    )
    assert record["cable_work_J"] == 0.0 and record["efficiency"] is None
    assert record["stroke_volume_ml"] == pytest.approx(200.0)


def _halving_error(y, x):
    """|T(h) - T(2h)|, the trapezoid rule on every sample against every other: its error on a
    kinked signal (first order) and three times Richardson's estimate on a smooth one (second
    order), so a bound of T(h)'s error in both."""
    return abs(closed_integral(y, x) - closed_integral(y[::2], x[::2]))


def test_an_open_loops_afterload_record_holds_the_windkessels_balance():
    """``lv-systemic``'s ``blocks``: the Windkessel's record at its capacitor (``C dpc/dt = q -
    (pc - p_venous) / Rd``) has the mean inflow (mean pc - p_venous) / Rd + C (pc(T) - pc(0)) /
    T over the beat. Bound: both means' trapezoid error (:func:`_halving_error`) through the
    balance."""
    result = cs.run("lv-systemic")
    record = cs.summary_records(result)[0]
    afterload, pump = record["blocks"]["afterload"], record["blocks"]["pump"]
    _, c, rd = result.scene.windkessel  # SI
    p_venous = result.scene.venous_pressure
    traces = result.members[0].traces
    t, pc, q = traces["time"], traces["pc"], traces["outflow"]
    period = t[-1] - t[0]
    balance = ((afterload["pressure_mean_mmHg"] * mmHg - p_venous) / rd
               + c * (pc[-1] - pc[0]) / period)  # fmt: skip
    bound = (_halving_error(pc, t) / rd + _halving_error(q, t)) / period
    assert abs(afterload["flow_mean_l_min"] * l_per_min - balance) <= bound
    assert afterload["pressure_diastolic_mmHg"] < afterload["pressure_mean_mmHg"]
    assert pump["stroke_volume_ml"] == pytest.approx(record["edv_ml"] - record["esv_ml"])


def test_an_open_loops_pump_record_has_the_cable_work_of_the_energy_account():
    """The bench's ``blocks``' pump: its cable work (the trapezoid rule's closed integral of F dx
    over the beat's samples) equals the energy account's work in (``energy=True``: F dx/dt
    integrated by the solver with the state), at each afterload. Bound: the trapezoid's error
    (:func:`_halving_error`) plus 10 rtol of the work, the solver's."""
    result = cs.run("bench-dynamic", energy=True)
    rtol = cs.scene_tools.tools(result.scene).preset(result.scene).rtol
    for member, record in zip(result.members, cs.summary_records(result), strict=True):
        pump = record["blocks"]["pump"]
        work_in = member.metrics["work_in"]
        bound = _halving_error(member.traces["cable_force"], member.traces["pull"])
        assert abs(pump["cable_work_J"] - work_in) <= bound + 10 * rtol * abs(work_in)
        assert pump["peak_force_N"] == record["peak_force_N"]


def test_a_closed_loops_pump_block_has_the_pumps_numbers():
    """``soft-lv``'s ``blocks``: the pump in place of the left ventricle has a pump's record (its
    forces and works, :func:`~cardiosoft.network.block_metrics.pump_record`), equal to the
    side's numbers the closed loop computes in JAX from the same samples; the native chambers
    keep a chamber's record."""
    record = cs.summary_records(cs.run("soft-lv"))[0]
    lv, rv = record["blocks"]["lv"], record["blocks"]["rv"]
    for key, side in (("peak_force_N", "peak_force_N"), ("cable_work_J", "cable_work_J"),
                      ("stroke_work_J", "stroke_work_J"), ("efficiency", "efficiency"),
                      ("stroke_volume_ml", "sv_ml")):  # fmt: skip
        assert lv[key] == pytest.approx(record[f"left_{side}"], rel=1e-9), key
    assert "peak_force_N" not in rv and set(rv) >= {"edv_ml", "stroke_volume_ml"}
