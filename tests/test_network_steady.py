"""``--steady`` for svZeroDSolver models: beat after beat to the periodic steady state, checked
against a closed form (:func:`cardiosoft.network.run.simulate`'s ``steady``)."""

import json
from pathlib import Path

import numpy as np
import pytest

from cardiosoft import network
from cardiosoft.network import run
from cardiosoft.solve import PRESETS

CASE = Path(__file__).parent / "data" / "svzerod" / "steadyFlow_R_RCR.json"
Q, R, RP, RD = 5.0, 100.0, 1000.0, 1000.0
"""The case's inflow and resistances (CGS); its closed form: P_out = Q (Rp + Rd), P_in = P_out
+ Q R (Pd = 0)."""
SLOW_C = 0.01
"""A capacitance that makes the RCR's time constant Rd C = 10 s, ten beats: the model's own 30
beats from rest leave about 500 of the outlet's 10,000 missing (10,000 exp(-3)), five times the
steady run's bound."""


def _slow_rcr(tmp_path=None):
    config = json.loads(CASE.read_text())
    config["boundary_conditions"][1]["bc_values"]["C"] = SLOW_C
    config["simulation_parameters"]["steady_initial"] = False  # from rest, as after a step
    if tmp_path is None:
        return config
    path = tmp_path / "slow_rcr.json"
    path.write_text(json.dumps(config))
    return path


def test_steady_run_reaches_the_rcr_closed_form():
    """From rest, the steady run stops when a beat changes no state by more than
    ``STEADY_TOLERANCE`` times its tolerance (rtol 1e-6 of the largest pressure, at most 10,500:
    a change of at most 10.5 a beat). The charge then still missing is a geometric tail,
    ``change * r / (1 - r)`` with ``r = exp(-T / (Rd C))`` the decay over a beat: the
    pressures lie within that of the closed form (plus the integration's own 1e-6)."""
    model = network.read(_slow_rcr())
    traces = network.simulate(model, "default", steady=True)
    assert traces.solved and traces.steady and traces.residual <= 1.0
    out, inlet = Q * (RP + RD), Q * (RP + RD + R)
    r = np.exp(-model.network.period / (RD * SLOW_C))
    change = run.STEADY_TOLERANCE * PRESETS["default"]["rtol"] * inlet
    bound = change * r / (1 - r) + 1e-6 * inlet
    np.testing.assert_allclose(traces.values["pressure:branch0_seg0:OUT"], out, rtol=0, atol=bound)
    np.testing.assert_allclose(
        traces.values["pressure:INFLOW:branch0_seg0"], inlet, rtol=0, atol=bound
    )
    own = network.simulate(model, "default")  # the model's own 30 beats: not there yet
    assert np.max(np.abs(own.values["pressure:branch0_seg0:OUT"] - out)) > bound


def test_simulate_steady_reports_a_steady_state_not_reached(tmp_path, monkeypatch):
    """``simulate --scene model.json --steady``: a run that does not settle in the beats it may
    run exits 1 and says so in ``summary.json``; ``--steady shooting`` is refused (exit 2)."""
    from cardiosoft.simulate import main

    path = _slow_rcr(tmp_path)
    assert main(["--scene", str(path), "--steady", "shooting", "--quiet"]) == 2
    monkeypatch.setattr(run, "STEADY_MAX_BEATS", 3)
    out = tmp_path / "out"
    assert main(["--scene", str(path), "--steady", "--out", str(out), "--quiet"]) == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steady"] is False and summary["beats"] == 3
    assert summary["steady_residual"] > 1.0


CYCLE_CASES = Path(__file__).parent / "data" / "svzerod"


def _beats_svzerod_runs(config) -> int:
    """The beats svzerod itself ran (every beat is output in these cases)."""
    out = network.run_svzerod(config)
    points = config["simulation_parameters"]["number_of_time_pts_per_cardiac_cycle"]
    return (len(next(iter(out.values()))) - 1) // (points - 1)


def test_cycle_to_cycle_error_with_an_rcr_runs_svzerods_count_of_beats():
    """``use_cycle_to_cycle_error`` with RCR outlets: ceil(-max(Rd C) / T ln(error)) beats
    (Pfaller et al. 2021, eq. 21), the model's own count replaced, as svzerod counts them."""
    case = CYCLE_CASES / "pulsatileFlow_bifurcationR_RCR_cycle_error.json"
    config = json.loads(case.read_text())
    model = network.read(config)
    taus = [b["bc_values"]["Rd"] * b["bc_values"]["C"] for b in config["boundary_conditions"]
            if b["bc_type"] == "RCR"]  # fmt: skip
    expected = int(np.ceil(-max(taus) / model.network.period * np.log(0.01)))
    assert model.simulation.cycles == expected == _beats_svzerod_runs(config)
    assert expected != config["simulation_parameters"]["number_of_cardiac_cycles"]
    config["simulation_parameters"]["number_of_cardiac_cycles"] = 1  # svzerod asserts >= 2
    with pytest.raises(network.UnsupportedModel, match="use_cycle_to_cycle_error"):
        network.read(config)


@pytest.mark.slow
def test_cycle_to_cycle_error_without_an_rcr_runs_until_the_caps_settle():
    """Without an RCR, beats go on after the model's own until the inlet cap's mean flow and
    pressure change by at most 1 % a beat: as many as svzerod runs (31 for this coronary, 20
    of them the model's), every beat output."""
    config = json.loads((CYCLE_CASES / "pulsatileFlow_R_coronary_cycle_error.json").read_text())
    traces = network.simulate(network.read(config))
    assert traces.solved and traces.steady and traces.residual <= 1.0
    assert traces.beats == _beats_svzerod_runs(config) > 20
    points = config["simulation_parameters"]["number_of_time_pts_per_cardiac_cycle"]
    assert len(traces.time) == traces.beats * (points - 1) + 1
    # the residual is svZeroDSolver's (get_cycle_to_cycle_errors_in_flow_and_pressure): each
    # of the last two beats' N samples (sharing the sample between them) averaged, at the cap
    # (the vessel's inlet), the relative change over the 1 % error; to round-off
    changes = []
    for kind in ("flow", "pressure"):
        y = traces.values[f"{kind}:INFLOW:branch0_seg0"][-(2 * points - 1) :]
        before, last = y[:points].mean(), y[points - 1 :].mean()
        changes.append(abs((last - before) / before) / 0.01)
    assert traces.residual == pytest.approx(max(changes), rel=1e-9)
