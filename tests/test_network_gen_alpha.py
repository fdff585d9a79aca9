"""svZeroDSolver's own stepping (issue #40, "a generalized-alpha stepper with svZeroDSolver's
settings reproduces the stored references to their own 1e-7 (1 + |y|)"):
``cardiosoft.network.gen_alpha.step_as_svzerod`` against ``svzerod`` itself run at the model's
own step, every variable at every output time.

The bound is the issue's, 1e-7 (1 + |y|) in the model's units. What it leaves room for:
svZeroDSolver stops Newton once its residuals are below ``absolute_tolerance`` (1e-8 or
1e-9 in the upstream cases), the stepper here at convergence. Measured, the cases agree to
3e-15-1.7e-9, the decomposed closed-loop heart (nonlinear valves, 1e-8) to 4.1e-8; the
converged answer (``cardiosoft.network.simulate``) is 0.9-3 % of 1 + |y| away from
svZeroDSolver's stepping on the pulsatile cases at their steps (1.1 % on the two-hill loop).
"""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from cardiosoft.network import UnsupportedModel, read, run_svzerod, simulate, step_as_svzerod
from cardiosoft.network.gen_alpha import coefficients
from cardiosoft.simulate import main

CASES = Path(__file__).parent / "data" / "svzerod"
BOUND = 1e-7
"""The issue's bound on |ours - svzerod| / (1 + |svzerod|)."""
STEPPED = (
    "closedLoopHeart_singleVessel_decomposed", "closed_loop_two_hill",
    "pulsatileFlow_R_RCR", "pulsatileFlow_R_RCR_mean", "pulsatileFlow_R_RCR_mean_variable",
    "pulsatileFlow_R_RCR_variable", "pulsatileFlow_R_coronary", "pulsatileFlow_R_coronary_varres",
    "pulsatileFlow_CRL", "steadyFlow_RL_R", "chamber_elastance_inductor",
    "piecewise_Chamber_and_Valve", "pulsatileFlow_R_RCR_derivative",
    "pulsatileFlow_R_RCR_derivative_variable", "pulsatileFlow_R_RCR_mean_derivative",
    "pulsatileFlow_R_RCR_mean_derivative_variable",
    "pulsatileFlow_bifurcationR_RCR_cycle_error", "steadyFlow_RC_R", "steadyFlow_RLC_R",
    "steadyFlow_R_R", "steadyFlow_R_RCR", "steadyFlow_R_coronary", "steadyFlow_R_steadyPressure",
    "steadyFlow_bifurcationR_R1", "steadyFlow_bifurcationR_R1_blockNames",
    "steadyFlow_bifurcationR_R2", "steadyFlow_blood_vessel_junction", "steadyFlow_confluenceR_R",
    "steadyFlow_stenosis_R", "valve_tanh",
)  # fmt: skip
"""The vendored cases it steps: all those the reader takes, less the refused below (and
``chamber_sphere``, which ``svzerod`` cannot run: checked against upstream's stored result).
``pulsatileFlow_CRL`` and ``steadyFlow_RL_R`` are index-2 systems (a source pins a capacitor,
an inductor): stepped on the network's residuals as they are, not on the reduced ones, as
svZeroDSolver steps them. ``chamber_elastance_inductor`` and ``piecewise_Chamber_and_Valve``
start from svZeroDSolver's steady start-up marched through their chambers' activation. The
``_derivative`` cases compare every variable's rate (``ydot:NAME``) too: the scheme's, from the
marched start-up's (the RCR's capacitor switched off in it, as svZeroDSolver does)."""
QUICK = ("valve_tanh",)
"""A nonlinear valve and its status under a time table (each case compiles for 5-10 s); the
rest run with the slow tests: a Windkessel's state, a closed loop started from its initial
values as given, ..."""


def _config(case: str) -> dict:
    return json.loads((CASES / f"{case}.json").read_text())


def _worst(values: dict, reference: dict) -> tuple[float, str]:
    assert set(values) == set(reference), set(values) ^ set(reference)
    errors = {
        k: float(np.max(np.abs(np.asarray(values[k]) - v) / (1.0 + np.abs(v))))
        for k, v in reference.items()
    }
    name = max(errors, key=errors.get)
    return errors[name], name


@pytest.mark.parametrize(
    "case", [pytest.param(c, marks=() if c in QUICK else pytest.mark.slow) for c in STEPPED]
)
def test_a_model_stepped_as_svzerod_steps_it_gives_svzerods_digits(case):
    config = _config(case)
    traces = step_as_svzerod(read(config, name=case))
    assert traces.solved
    worst, name = _worst(traces.values, run_svzerod(config))
    assert worst <= BOUND, f"{name}: {worst:.2e} of 1 + |y|"


def test_the_spherical_chamber_stepped_as_svzerod_gives_upstreams_stored_result():
    """``chamber_sphere`` (ChamberSphere between two tanh valves, from initial values that are
    not consistent): every variable at every output time equals svZeroDSolver's own stored
    result of the case (``tests/data/svzerod/results``; measured 3.3e-12 of 1 + |y|). Upstream
    stops Newton at its ``absolute_tolerance`` 1e-9."""
    stored = json.loads(gzip.decompress((CASES / "results" / "result_chamber_sphere.json.gz")
                                        .read_bytes()))  # fmt: skip
    reference: dict = {}
    for row, name in stored["name"].items():
        reference.setdefault(name, []).append(stored["y"][row])
    traces = step_as_svzerod(read(_config("chamber_sphere")))
    assert traces.solved
    reference = {name: np.asarray(values) for name, values in reference.items()}
    worst, name = _worst(traces.values, reference)
    assert worst <= BOUND, f"{name}: {worst:.2e} of 1 + |y|"


@pytest.mark.slow
def test_the_converged_answer_is_not_svzerods_digits():
    """The bound is far tighter than the scheme's own error: the adaptive solve's converged
    answer misses svZeroDSolver's stepping by many times it (so the test above can fail)."""
    config = _config("closed_loop_two_hill")
    worst, _ = _worst(simulate(read(config)).values, run_svzerod(config))
    assert worst > 100 * BOUND


def test_the_schemes_coefficients_are_svzerods():
    """``Integrator.cpp``: rho_infty 0.5 gives alpha_m 5/6, alpha_f 2/3, gamma 2/3; rho 1 the
    trapezoidal rule (1/2, 1/2, 1/2)."""
    np.testing.assert_allclose(coefficients(0.5), (5 / 6, 2 / 3, 2 / 3), rtol=1e-15)
    np.testing.assert_allclose(coefficients(1.0), (0.5, 0.5, 0.5), rtol=1e-15)


@pytest.mark.parametrize(
    "case, message",
    [
        ("closedLoopHeart_singleVessel", "block type 'ClosedLoopHeartAndPulmonary'"),
        ("pulsatileFlow_CStenosis_steadyPressure", "a stenosis ahead of its capacitor"),
        ("pulsatileFlow_R_coronary_cycle_error", "'use_cycle_to_cycle_error'"),
    ],
)
def test_what_it_cannot_step_as_svzerod_is_refused_naming_why(case, message):
    with pytest.raises(UnsupportedModel, match=message):
        step_as_svzerod(read(_config(case)))


def test_the_start_up_switches_a_windkessels_capacitor_off_as_svzerod_does():
    """svZeroDSolver's start-up marches with every RCR's C set to 0 (``Model::to_steady``). With
    ``pulsatileFlow_R_RCR``'s C 100 times larger (Rd C 10 beats, against the start-up's 3.1)
    a march with C on would leave the capacitor far from its steady state (measured: 0.73 of
    1 + |y| off svzerod); with C off every beat, the first included, is svzerod's."""
    config = _config("pulsatileFlow_R_RCR")
    config["simulation_parameters"]["output_all_cycles"] = True
    for bc in config["boundary_conditions"]:
        if bc["bc_type"] == "RCR":
            bc["bc_values"]["C"] *= 100
    worst, name = _worst(step_as_svzerod(read(config)).values, run_svzerod(config))
    assert worst <= BOUND, f"{name}: {worst:.2e} of 1 + |y|"


def test_rates_from_a_start_up_that_is_solved_not_marched_are_refused():
    """A coronary's start-up is solved for here (its steady equations give its steady state
    only), so the rates a run would start from are not svZeroDSolver's."""
    config = _config("pulsatileFlow_R_coronary")
    config["simulation_parameters"]["output_derivative"] = True
    with pytest.raises(UnsupportedModel, match="'output_derivative' with the steady start-up"):
        step_as_svzerod(read(config))


def test_the_command_writes_svzerods_digits(tmp_path, capsys):
    out = tmp_path / "out"
    scene = str(CASES / "valve_tanh.json")
    assert main(["--scene", scene, "--as-svzerod", "--out", str(out), "--quiet"]) == 0
    table = np.genfromtxt(out / "traces.csv", delimiter=",", names=True, deletechars="")
    written = {k: table[k] for k in table.dtype.names if k != "time"}
    worst, name = _worst(written, run_svzerod(_config("valve_tanh")))
    assert worst <= BOUND, f"{name}: {worst:.2e}"  # traces.csv keeps 10 significant digits
    summary = json.loads((out / "summary.json").read_text())
    assert summary["accuracy"].startswith("stepped as svZeroDSolver steps it"), summary

    assert main(["--scene", scene, "--as-svzerod", "--steady", "--quiet"]) == 2
    assert "--as-svzerod: not with --steady" in capsys.readouterr().err
    assert main(["--as-svzerod", "--quiet"]) == 2
    assert "--as-svzerod: only with an svZeroDSolver model" in capsys.readouterr().err
