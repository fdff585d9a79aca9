"""svZeroDSolver's models through cardiosoft's network, checked against svZeroDSolver itself.

svZeroDSolver steps a fixed-step second-order generalized-alpha scheme, so its answer depends on
its step. Each check runs ``svzerod`` at the case's own step and at 2x and 4x finer, measures the
observed order p from the three, and estimates the error left at the finest step as
``|y_4 - y_2| / (2^p - 1)`` (Richardson). Our adaptive solve (preset "reference", rtol 1e-10)
must lie within twice that estimate of the finest ``svzerod`` answer, plus 1e-7 of each
variable's range: svZeroDSolver's own Newton stops at an absolute 1e-8 or 1e-9 in the model's
units. The tolerance is therefore the case's own, printed on failure.
"""

import json
from pathlib import Path

import numpy as np
import pytest
import svzerod

from cardiosoft import network

CASES = Path(__file__).parent / "data" / "svzerod"
SUPPORTED = sorted(
    p.stem
    for p in CASES.glob("*.json")
    if p.stem not in ("valve_tanh", "pulsatileFlow_R_RCR_mismatchPeriod")
)
FAST = ("pulsatileFlow_R_RCR",)
"""In CI: a pulsatile RCR. An index-2 model and pure algebra through a junction are checked
against their upstream closed forms below."""


def _svzerod(config: dict, refine: int) -> dict:
    config = json.loads(json.dumps(config))
    sim = config["simulation_parameters"]
    sim["output_variable_based"] = True
    sim["number_of_time_pts_per_cardiac_cycle"] = (
        sim["number_of_time_pts_per_cardiac_cycle"] - 1
    ) * refine + 1
    frame = svzerod.simulate(config)
    return {name: group["y"].to_numpy()[::refine] for name, group in frame.groupby("name")}


def check_against_svzerod(name: str) -> None:
    config = json.loads((CASES / f"{name}.json").read_text())
    traces = network.simulate(network.read(config), "reference")
    assert traces.solved and traces.steady_start in (True, None)
    y1, y2, y4 = (_svzerod(config, r) for r in (1, 2, 4))
    assert set(traces.values) == set(y4), "svZeroDSolver's variable names"
    for var, ours in traces.values.items():
        scale = np.ptp(y4[var]) + np.max(np.abs(y4[var])) * 1e-3 + 1e-300
        e12, e24 = np.max(np.abs(y1[var] - y2[var])), np.max(np.abs(y2[var] - y4[var]))
        order = np.clip(np.log2(e12 / e24), 1.0, 3.0) if e24 > 1e-9 * scale else 2.0
        left = e24 / (2**order - 1)
        tolerance = 2 * left + 1e-7 * scale
        error = np.max(np.abs(ours - y4[var]))
        assert error <= tolerance, (
            f"{name} {var}: {error:.3g} > {tolerance:.3g} "
            f"(svzerod's error left {left:.3g}, order {order:.2f})"
        )


@pytest.mark.parametrize("name", FAST)
def test_vendored_case_agrees_with_converged_svzerod(name):
    check_against_svzerod(name)


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in SUPPORTED if n not in FAST])
def test_every_supported_vendored_case_agrees_with_converged_svzerod(name):
    check_against_svzerod(name)


def test_junction_case_has_the_stated_analytic_solution():
    """The upstream case's own closed form: Q1 = Q2 = 2.5, outlets at 350, junction 600,
    inlet 1100."""
    traces = network.simulate(network.read(CASES / "steadyFlow_bifurcationR_R1.json"))
    v = traces.values
    np.testing.assert_allclose(v["flow:branch1_seg0:OUT1"], 2.5, rtol=1e-12)
    np.testing.assert_allclose(v["pressure:branch1_seg0:OUT1"], 350.0, rtol=1e-12)
    np.testing.assert_allclose(v["pressure:J0:branch2_seg0"], 600.0, rtol=1e-12)
    np.testing.assert_allclose(v["pressure:INFLOW:branch0_seg0"], 1100.0, rtol=1e-12)


def test_pinned_state_is_reduced_and_its_constraint_holds():
    """In steadyFlow_RL_R the inductor's flow is the source's: the network finds that one
    constraint (an index-2 DAE) and differentiates it, so the inlet pressure is determined.
    The upstream case's closed form: outlet at 600, inlet at 1100, flow 5."""
    model = network.read(CASES / "steadyFlow_RL_R.json")
    assert model.network.n_constraints == 1
    v = network.simulate(model).values
    np.testing.assert_allclose(v["flow:branch0_seg0:OUT"], 5.0, rtol=1e-12)
    np.testing.assert_allclose(v["pressure:branch0_seg0:OUT"], 600.0, rtol=1e-12)
    np.testing.assert_allclose(v["pressure:INFLOW:branch0_seg0"], 1100.0, rtol=1e-12)


def test_unsupported_block_is_refused_in_one_line_naming_it():
    with pytest.raises(network.UnsupportedModel, match="'ValveTanh'") as error:
        network.read(CASES / "valve_tanh.json")
    assert "\n" not in str(error.value)


def test_period_that_disagrees_with_the_tables_is_refused_as_svzerod_does():
    with pytest.raises(network.UnsupportedModel, match="inconsistent cardiac cycle period"):
        network.read(CASES / "pulsatileFlow_R_RCR_mismatchPeriod.json")
    with pytest.raises(Exception, match="Inconsistent cardiac cycle period"):
        svzerod.simulate(
            json.loads((CASES / "pulsatileFlow_R_RCR_mismatchPeriod.json").read_text())
        )


def test_unknown_parameter_is_refused_naming_block_and_parameter():
    config = json.loads((CASES / "steadyFlow_R_R.json").read_text())
    config["vessels"][0]["zero_d_element_values"]["Rp"] = 1.0
    with pytest.raises(
        network.UnsupportedModel, match="BloodVessel branch0_seg0: unknown parameter 'Rp'"
    ):
        network.read(config)


def test_simulate_command_writes_traces_under_svzerod_names(tmp_path):
    """``simulate --scene model.json --out DIR``: exit 0, ``traces.csv`` with ``time`` and every
    svZeroDSolver variable under its own name, equal to the library's traces; a second run
    without --force refuses (exit 2) and leaves the files as they were."""
    from cardiosoft.simulate import main

    case = CASES / "steadyFlow_bifurcationR_R1.json"
    assert main(["--scene", str(case), "--out", str(tmp_path), "--quiet"]) == 0
    header = (tmp_path / "traces.csv").read_text().splitlines()[0].split(",")
    table = np.loadtxt(tmp_path / "traces.csv", delimiter=",", skiprows=1)
    config = json.loads(case.read_text())
    assert header[0] == "time" and set(header[1:]) == set(_svzerod(config, 1))
    traces = network.simulate(network.read(case))
    for i, name in enumerate(header[1:], start=1):
        np.testing.assert_allclose(table[:, i], traces.values[name], rtol=1e-9)
    before = (tmp_path / "traces.csv").read_bytes()
    assert main(["--scene", str(case), "--out", str(tmp_path), "--quiet"]) == 2
    assert (tmp_path / "traces.csv").read_bytes() == before


@pytest.mark.parametrize(
    "extra, message",
    [((), "'ValveTanh'"), (("--bpm", "60"), "--bpm does not apply")],
)
def test_simulate_command_refuses_in_one_line(capsys, extra, message):
    from cardiosoft.simulate import main

    case = CASES / ("valve_tanh.json" if not extra else "steadyFlow_R_R.json")
    assert main(["--scene", str(case), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
