"""Sweeps of the soft pump's design in a user's svZeroDSolver model (issue #40, "Tools":
``sweep`` on any network; :mod:`cardiosoft.sweep.model`)."""

from __future__ import annotations

from pathlib import Path

import pytest
import xarray as xr

from cardiosoft.cli import main
from cardiosoft.design.model import metric_values
from cardiosoft.network import read, simulate
from cardiosoft.network.pump_in_model import PumpPlacement, placed_records
from cardiosoft.sweep.model import model_sweep

MODEL = Path(__file__).parent / "data" / "svzerod" / "closed_loop_two_hill.json"
STEADY_AGREEMENT = 1e-3
"""A point of the sweep against the same design solved alone, relative: a batch runs until
every variant is steady, so a point may run a beat more than alone, and at the steady state a
beat moves no state by more than 1e-3 of its scale (``cardiosoft.network.run``'s steady test,
1,000 times the default preset's tolerance). Measured: at most 7e-5 (the pump's SV at Omega 5,
29 beats alone, 30 in the batch)."""


def test_each_point_of_a_model_sweep_is_its_design_solved_alone(tmp_path):
    """Four designs in two chunks of three (the second padded): each point's pump SV and peak
    force and each vessel's mean pressure equal the model read with the pump at that design
    and run to its steady state on its own (``simulate --scene model.json --steady``); the
    Dataset is written whole, with its map."""
    placement = PumpPlacement("LV", "si")
    omegas, shortenings = (3.0, 5.0), (0.35, 0.45)
    ds = model_sweep(
        MODEL, placement, omega=list(omegas), shortening=list(shortenings), chunk=3,
        out=tmp_path, progress=False,
    )  # fmt: skip
    assert bool(ds["steady"].all())
    written = xr.open_dataset(tmp_path / "sweep.nc", engine="h5netcdf")
    assert (tmp_path / "map-87bpm.png").is_file()
    keys = ["LV.stroke_volume_ml", "LV.peak_force_N"]
    keys += [k for k in ds.data_vars if k.endswith(".pressure_mean")]
    assert len(keys) == 6  # the pump's two and the four vessels'
    for omega, shortening in ((3.0, 0.45), (5.0, 0.35)):
        alone = PumpPlacement("LV", "si", omega=omega, shortening=shortening)
        model = read(MODEL, pump=alone)
        values = metric_values(placed_records(model, alone, simulate(model, steady=True)))
        point = written.sel(omega=omega, shortening=shortening).squeeze("bpm")
        for key in keys:
            assert float(point[key]) == pytest.approx(values[key], rel=STEADY_AGREEMENT), key
    written.close()


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--pump-chamber", "LV", "--units", "si", "--bpm", "60"], "--bpm: not taken"),
        (["--units", "si"], "--pump-chamber: missing"),
        (["--pump-chamber", "XX", "--units", "si"], "no such chamber"),
    ],
)
def test_a_model_sweep_refuses_in_one_line_and_writes_nothing(tmp_path, capsys, extra, words):
    out = tmp_path / "maps"
    argv = ["sweep", "--scene", str(MODEL), "--omega", "3:5:2", "--shortening", "0.4", "--out"]
    assert main([*argv, str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_a_scene_sweep_refuses_a_models_option(capsys):
    argv = ["sweep", "--scene", "lv-systemic", "--omega", "3", "--shortening", "0.4"]
    assert main([*argv, "--pump-chamber", "LV"]) == 2
    assert "--pump-chamber: only with an svZeroDSolver model" in capsys.readouterr().err

