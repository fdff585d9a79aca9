"""``cardiosoft export --svzerod`` of the open-loop scenes with a Windkessel (issue #40, "writing"):
the file, read back by the network's reader, gives the scene's own beats."""

from __future__ import annotations

import dataclasses
import json

import diffrax
import numpy as np
import pytest

import cardiosoft as cs
from cardiosoft.batch import solve_beats
from cardiosoft.network import read, simulate
from cardiosoft.network.export_open_loop import to_svzerod
from cardiosoft.network.pump_in_model import UNIT_SYSTEMS
from cardiosoft.solve import preset

GRID = 4000
"""Intervals a beat of the read-back run's output: a multiple of 200 / 0.35 and 200 / 0.65
beats, so that every sample of the scene's own grid (201 over the pull, 0.35 of the beat,
and 200 over the rest) is one of its points."""
SIGNALS = {
    "volume": ("Vc:pump", "volume"),
    "pump_pressure": ("pressure:inlet_valve:pump", "pressure"),
    "inflow": ("flow:inlet_valve:pump", "volume"),
    "outflow": ("flow:pump:outlet_valve", "volume"),
    "node_pressure": ("pressure_c:afterload", "pressure"),
    "cable_force": ("cable_force:pump", None),
}
"""Each of the scene's traces and the file's variable it is, with its unit's kind."""


@pytest.mark.parametrize(
    "name, units",
    [("lv-systemic", "cgs"), pytest.param("rv-pulmonary", "mmHg", marks=pytest.mark.slow)],
)
def test_an_exported_windkessel_scene_read_back_gives_the_scenes_beats(name, units):
    """After 3 beats from rest, the pump's volume, pressure, inflow, outflow and cable force and
    the Windkessel's capacitor pressure equal the scene's own solve (``solve_beats``) at every
    sample of its last beat, to 1e-6 of the signal's range plus 1e-8 of its size: the two runs
    step Tsit5 at the reference preset (rtol 1e-10) through different step sequences (measured:
    at most 7e-8 of the range on lv-systemic, the inflow as the inlet valve opens)."""
    scene = cs.load_scene(name)
    model = to_svzerod(scene, units, beats=3)
    model["simulation_parameters"]["number_of_time_pts_per_cardiac_cycle"] = GRID + 1
    traces = simulate(read(json.loads(json.dumps(model))), "reference").values
    config = dataclasses.replace(preset("reference"), adjoint=diffrax.ForwardMode())
    own = solve_beats(scene, beats=3, save="traces", config=config).traces
    time = np.asarray(own["time"])[0]
    index = np.rint(time / time[-1] * GRID).astype(int)
    assert np.allclose(index * time[-1] / GRID, time, rtol=0.0, atol=1e-12)
    pressure_unit, volume_unit = UNIT_SYSTEMS[units][:2]
    scale = {"pressure": pressure_unit, "volume": volume_unit, None: 1.0}
    for key, (variable, kind) in SIGNALS.items():
        value = np.asarray(own[key])[0]
        ours = np.asarray(traces[variable])[index] * scale[kind]
        bound = 1e-6 * np.ptp(value) + 1e-8 * np.max(np.abs(value))
        assert np.max(np.abs(ours - value)) <= bound, key


def test_export_writes_a_windkessel_scene_with_its_blocks(tmp_path):
    from cardiosoft.cli import main

    out = tmp_path / "lv.json"
    assert main(["export", "--svzerod", "lv-systemic", "--out", str(out), "--units", "mmHg"]) == 0
    model = json.loads(out.read_text())
    assert [c["type"] for c in model["chambers"]] == ["SoftPump"]
    assert [v["type"] for v in model["valves"]] == ["SmoothValve"] * 2
    bcs = {bc["bc_name"]: bc for bc in model["boundary_conditions"]}
    assert bcs["preload"]["bc_values"]["P"] == pytest.approx(10.0)  # the scene's atrium, mmHg
    # the Windkessel's Rp moves into the outlet valve (module docstring): 0.005 + 0.05 mmHg s/ml
    assert bcs["afterload"]["bc_values"]["Rp"] == 0.0
    outlet = next(v for v in model["valves"] if v["name"] == "outlet_valve")
    assert outlet["params"]["R"] == pytest.approx(0.055)


@pytest.mark.parametrize(
    "change, words",
    [
        (
            dict(effects=("valves", "preload", "cable_friction"), cable_friction=0.5),
            "'cable_friction'",
        ),
        (dict(valve_kind="ideal"), "valve kind 'ideal'"),
    ],
)
def test_an_open_loop_the_file_cannot_express_is_refused(change, words):
    scene = dataclasses.replace(cs.load_scene("lv-systemic"), **change)
    with pytest.raises(ValueError, match=words):
        to_svzerod(scene)
