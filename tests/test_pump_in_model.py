"""The soft pump in place of a chamber of a user's svZeroDSolver model (``--pump-chamber``).

The physics must not depend on the units the model is written in: one small circulation,
written in mmHg-ml-s and in SI, with the pump in place of its ventricle, must give the same beat.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from cardiosoft.network import read, simulate
from cardiosoft.network.pump_in_model import UNIT_SYSTEMS, PumpPlacement
from cardiosoft.units import ml, mmHg


def small_circulation(units: str) -> dict:
    """A left atrium at 10 mmHg, its veins (R, C), a mitral valve, a ventricle, an aortic
    valve, an aorta (R, C) and a peripheral resistance, written in ``units``
    (:data:`UNIT_SYSTEMS`). Each valve sits between two pressures the states set, so that
    its law gives its flow directly."""
    p, v = UNIT_SYSTEMS[units][:2]
    P, V = mmHg / p, ml / v  # 1 mmHg and 1 ml in the model's units
    # an open valve of 0.05 mmHg s/ml: against the pump's stiffness at full pull (up to about
    # 100 mmHg/ml) a time constant of 0.5 ms, which an explicit solver steps through
    valve = {"Rmax": 1e4 * P / V, "Rmin": 0.05 * P / V, "Steepness": 1.0 / P}
    return {
        "simulation_parameters": {
            "number_of_cardiac_cycles": 2,
            "number_of_time_pts_per_cardiac_cycle": 101,
            "steady_initial": False,
            "cardiac_period": 1.0,
        },
        "boundary_conditions": [
            {"bc_name": "LAP", "bc_type": "PRESSURE", "bc_values": {"P": 10.0 * P}},
            {"bc_name": "OUT", "bc_type": "RESISTANCE", "bc_values": {"R": P / V, "Pd": 0.0}},
        ],
        "vessels": [
            {
                "vessel_id": 0,
                "vessel_name": "inflow",
                "boundary_conditions": {"inlet": "LAP"},
                "zero_d_element_type": "BloodVessel",
                "zero_d_element_values": {"R_poiseuille": 0.01 * P / V, "C": V / P},
            },
            {
                "vessel_id": 1,
                "vessel_name": "aorta",
                "boundary_conditions": {"outlet": "OUT"},
                "zero_d_element_type": "BloodVessel",
                "zero_d_element_values": {"R_poiseuille": 0.05 * P / V, "C": 1.3 * V / P},
            },
        ],
        "junctions": [],
        "valves": [
            {
                "type": "ValveTanh",
                "name": "MV",
                "params": valve | {"upstream_block": "inflow", "downstream_block": "LV"},
            },
            {
                "type": "ValveTanh",
                "name": "AV",
                "params": valve | {"upstream_block": "LV", "downstream_block": "aorta"},
            },
        ],
        "chambers": [
            {
                "type": "LinearElastanceChamber",
                "name": "LV",
                "values": {"Emax": 2.0 * P / V, "Epass": 0.1 * P / V, "Vrest": 5.0 * V},
                "activation_function": {"type": "half_cosine", "t_active": 0.0, "t_twitch": 0.3},
            }
        ],
        "initial_condition": {"Vc:LV": 100.0 * V, "pressure_all": 10.0 * P},
    }


@pytest.mark.parametrize("units", ["mmHg", pytest.param("cgs", marks=pytest.mark.slow)])
def test_the_pumps_beat_is_the_same_in_any_units(units):
    """The circulation in ``units`` and in SI, the pump in place of LV: volumes, pressures and
    flows equal after conversion, to 1e-6 of each variable's range: the same equations, scaled,
    each solved at the reference preset (rtol 1e-10, absolute tolerances that scale with
    them), so that what is left is the solvers' error over two beats (measured 3e-5 at the
    default preset's rtol 1e-6); a wrong conversion is off by a factor of 133 or 1e6."""
    runs = {}
    for u in ("si", units):
        model = read(small_circulation(u), pump=PumpPlacement("LV", u))
        traces = simulate(model, "reference")
        assert traces.solved
        p, v = UNIT_SYSTEMS[u][:2]
        runs[u] = {
            k: np.asarray(a) * (p if k.startswith("pressure:") else v)
            for k, a in traces.values.items()
            if k.startswith(("pressure:", "flow:", "Vc:"))
        }
    assert set(runs["si"]) == set(runs[units])
    for k, a in runs["si"].items():
        # plus the round-off of converting (a constant's range is 0)
        bound = 1e-6 * np.ptp(a) + 1e-12 * np.max(np.abs(a))
        assert np.max(np.abs(runs[units][k] - a)) <= bound, k
    volume = runs["si"]["Vc:LV"] / ml
    assert 10.0 < np.ptp(volume) < 100.0  # the pump ejects: a stroke of tens of ml


def test_a_start_volume_that_cannot_be_in_the_stated_units_is_refused():
    """The SI model read as CGS: its ventricle would start at 1e-4 ml."""
    with pytest.raises(ValueError, match=r"Vc:LV = 0\.0001 .* it would be 100 ml in si"):
        read(small_circulation("si"), pump=PumpPlacement("LV", "cgs"))


def test_the_replaced_chambers_name_and_the_design_are_checked():
    with pytest.raises(ValueError, match=r"no such chamber .*its chambers: LV"):
        read(small_circulation("si"), pump=PumpPlacement("RV", "si"))
    with pytest.raises(ValueError, match=r"cable shortening C = 0\.9"):
        PumpPlacement("LV", "si", shortening=0.9)
    with pytest.raises(ValueError, match="--units 'ml'"):
        PumpPlacement("LV", "ml")


def _simulate(*args):
    return subprocess.run(
        [sys.executable, "-m", "cardiosoft.simulate", *args], capture_output=True, text=True
    )


def test_simulate_puts_the_pump_in_a_model_and_reports_its_beat(tmp_path):
    model = tmp_path / "small.json"
    model.write_text(json.dumps(small_circulation("mmHg")))
    out = tmp_path / "run"
    done = _simulate("--scene", str(model), "--pump-chamber", "LV", "--units", "mmHg",
                     "--out", str(out))  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "soft pump in place of LV" in done.stdout
    summary = json.loads((out / "summary.json").read_text())
    columns = np.genfromtxt(out / "traces.csv", delimiter=",", names=True)
    volume = columns["VcLV"]  # numpy drops the colon of Vc:LV
    assert summary["pump"]["stroke_volume_ml"] == pytest.approx(np.ptp(volume), rel=1e-8)
    assert "cable_forceLV" in columns.dtype.names
    refused = _simulate("--scene", str(model), "--pump-chamber", "LV", "--units", "si")
    assert refused.returncode == 2
    assert refused.stderr.count("\n") == 1 and "pass the model's units" in refused.stderr


def test_uncertainty_in_a_model_needs_the_pump(tmp_path, capsys):
    """A model's own blocks have no posterior: ``--uncertainty`` is the placed pump's."""
    from cardiosoft.simulate import main

    model = tmp_path / "small.json"
    model.write_text(json.dumps(small_circulation("mmHg")))
    assert main(["--scene", str(model), "--uncertainty"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "--uncertainty: with an svZeroDSolver model, only for the soft pump" in err
    # the number of draws is checked before anything runs (exit 2, one line)
    argv = ["--scene", str(model), "--pump-chamber", "LV", "--units", "mmHg", "--uncertainty"]
    assert main([*argv, "--draws", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "draws = 1: allowed 2 to" in err


@pytest.mark.slow
def test_uncertainty_bands_of_the_placed_pump_are_its_draws_quantiles(tmp_path):
    """``--pump-chamber LV --uncertainty``: each band (the pump's and every block's) is the
    2.5-97.5 % quantile range of the pump's posterior draws, here each draw's pump put into
    the model alone and solved, the quantiles taken with numpy. At the "reference" preset
    (rtol 1e-10) a batch and a single solve, rounding differently, agree to ~1e-9; held to
    1e-8 (as the closed loop's ensembles, tests/test_closed_loop.py)."""
    import dataclasses

    import equinox as eqx

    from cardiosoft.network.pump_in_model import placed_records, pump_index
    from cardiosoft.posterior import first_draws
    from cardiosoft.pump import load_posterior
    from tests.test_closed_loop import one_draw

    path = tmp_path / "small.json"
    path.write_text(json.dumps(small_circulation("mmHg")))
    out = tmp_path / "run"
    done = _simulate("--scene", str(path), "--pump-chamber", "LV", "--units", "mmHg",
                     "--uncertainty", "--draws", "4", "--accuracy", "reference",
                     "--out", str(out), "--quiet")  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert "not added" in summary["uncertainty"]["holds"]
    placement = PumpPlacement("LV", "mmHg")
    model = read(path, pump=placement)
    index = pump_index(model.network, placement)
    pump = first_draws(load_posterior(), 4).pump
    alone = []
    for draw in range(4):
        net = eqx.tree_at(lambda n: n.blocks[index].law.pump, model.network, one_draw(pump, draw))
        traces = simulate(dataclasses.replace(model, network=net), "reference")
        alone.append(placed_records(model, placement, traces))
    records = {"LV": summary["pump"], "aorta": summary["blocks"]["aorta"]}
    for block, key in (("LV", "stroke_volume_ml"), ("LV", "peak_force_N"),
                       ("aorta", "pressure_mean")):  # fmt: skip
        record = records[block]
        values = [a[block][key] for a in alone]
        np.testing.assert_allclose(
            record[f"{key}_band"], np.quantile(values, [0.025, 0.975]), rtol=1e-8, err_msg=key
        )
    assert np.ptp([a["LV"]["stroke_volume_ml"] for a in alone]) > 0.5  # the draws differ


def test_verify_reports_each_records_difference_from_a_reference_rerun(tmp_path):
    """``--verify`` on a model with the pump: ``summary.json``'s ``verification`` holds, per
    record number, the run's value, a rerun's at the reference preset and their difference.
    Checked against the two solves made here (the same programs: to round-off, 1e-9
    relative), so a difference scaled or taken against the wrong run fails; and the default
    preset's error is not zero here (the rerun is a different solve)."""
    from cardiosoft.network.pump_in_model import placed_records
    from cardiosoft.simulate import main

    path = tmp_path / "small.json"
    path.write_text(json.dumps(small_circulation("mmHg")))
    out = tmp_path / "run"
    argv = ["--scene", str(path), "--pump-chamber", "LV", "--units", "mmHg", "--verify",
            "--out", str(out), "--quiet"]  # fmt: skip
    assert main(argv) == 0
    verification = json.loads((out / "summary.json").read_text())["verification"]
    placement = PumpPlacement("LV", "mmHg")
    model = read(path, pump=placement)
    run = placed_records(model, placement, simulate(model))
    reference = placed_records(model, placement, simulate(model, "reference"))
    assert verification["rerun_rtol"] == 1e-10
    for block, key in (("LV", "stroke_volume_ml"), ("LV", "peak_force_N"),
                       ("aorta", "pressure_mean")):  # fmt: skip
        entry = verification["records"][block][key]
        expected = run[block][key] - reference[block][key]
        scale = abs(reference[block][key])
        assert entry["difference"] == pytest.approx(expected, rel=1e-6, abs=1e-9 * scale)
        assert entry["reference"] == pytest.approx(reference[block][key], rel=1e-9)
    assert verification["records"]["LV"]["stroke_volume_ml"]["difference"] != 0.0
