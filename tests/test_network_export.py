"""``cardiosoft export --svzerod`` of the open-loop scenes, with a Windkessel or on the dynamic
bench (issue #40, "writing"): the file, read back by the network's reader, gives the scene's
own beats."""

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
from cardiosoft.network.pump_in_model import UNIT_SYSTEMS, PumpPlacement
from cardiosoft.network.simulation_parameters import UnsupportedModel
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


BENCH_SIGNALS = {
    "volume": ("Vc:pump", "volume"),
    "relaxation": ("Vd:pump", "volume"),
    "pump_pressure": ("pressure:pump:J_pump_column", "pressure"),
    "outflow": ("flow:J_pump_column:column", "volume"),
    "column_volume": ("column_volume:column", "volume"),
    "cable_force": ("cable_force:pump", None),
}
"""The bench's traces and the file's variables (the pump with the shell's viscoelasticity and
the cables' friction, the line into the column)."""


def assert_read_back_gives_the_scenes_beats(scene, units, signals, beats):
    """The scene written in ``units``, read back and solved for ``beats`` beats from rest, equals
    the scene's own solve (``solve_beats``) at every sample of its last beat, in each of
    ``signals``, to 1e-6 of the signal's range plus 1e-8 of its size: the two runs step Tsit5
    at the reference preset (rtol 1e-10) through different step sequences."""
    model = to_svzerod(scene, units, beats=beats)
    model["simulation_parameters"]["number_of_time_pts_per_cardiac_cycle"] = GRID + 1
    traces = simulate(read(json.loads(json.dumps(model))), "reference").values
    config = dataclasses.replace(preset("reference"), adjoint=diffrax.ForwardMode())
    own = solve_beats(scene, beats=beats, save="traces", config=config).traces
    time = np.asarray(own["time"])[0]
    index = np.rint(time / time[-1] * GRID).astype(int)
    assert np.allclose(index * time[-1] / GRID, time, rtol=0.0, atol=1e-12)
    pressure_unit, volume_unit = UNIT_SYSTEMS[units][:2]
    scale = {"pressure": pressure_unit, "volume": volume_unit, None: 1.0}
    for key, (variable, kind) in signals.items():
        value = np.asarray(own[key])[0]
        ours = np.asarray(traces[variable])[index] * scale[kind]
        bound = 1e-6 * np.ptp(value) + 1e-8 * np.max(np.abs(value))
        assert np.max(np.abs(ours - value)) <= bound, key


@pytest.mark.parametrize(
    "name, units",
    [("lv-systemic", "cgs"), pytest.param("rv-pulmonary", "mmHg", marks=pytest.mark.slow)],
)
def test_an_exported_windkessel_scene_read_back_gives_the_scenes_beats(name, units):
    """The pump's volume, pressure, inflow, outflow and cable force and the Windkessel's
    capacitor pressure over 3 beats (:func:`assert_read_back_gives_the_scenes_beats`; measured:
    at most 7e-8 of the range on lv-systemic, the inflow as the inlet valve opens)."""
    assert_read_back_gives_the_scenes_beats(cs.load_scene(name), units, SIGNALS, beats=3)


@pytest.mark.parametrize(
    "pump, units", [("ss950-v3", "cgs"), pytest.param("ss950-v4", "si", marks=pytest.mark.slow)]
)
def test_the_exported_bench_read_back_gives_the_scenes_beats(pump, units):
    """The dynamic bench at its first column head over 2 beats: the pump's volume, its shell's
    dashpot volume, pressure and cable force (with the cables' friction), the flow into the
    column and the column's rise (:func:`assert_read_back_gives_the_scenes_beats`; measured: at
    most 5e-9 of the range). ``ss950-v4``'s rig pulls with a ramp of 0.05 s."""
    scene = cs.load_scene("bench-dynamic", pump=pump)
    scene = scene.replace(afterloads=scene.afterloads[:1])
    assert_read_back_gives_the_scenes_beats(scene, units, BENCH_SIGNALS, beats=2)


def test_export_writes_the_bench_at_a_chosen_head_with_the_shells_effects(tmp_path, capsys):
    """``--afterload 60``: the column's head; the pump carries the scene's viscoelasticity and
    friction; the file's pump gets a pump's record when the file is simulated."""
    from cardiosoft.cli import main

    out = tmp_path / "bench.json"
    args = ["export", "--svzerod", "bench-dynamic", "--out", str(out), "--units", "mmHg"]
    assert main([*args, "--afterload", "60", "--beats", "2"]) == 0
    model = json.loads(out.read_text())
    scene = cs.load_scene("bench-dynamic")
    (column,) = model["boundary_conditions"]
    assert column["bc_type"] == "WaterColumn" and column["bc_values"]["head_mmHg"] == 60.0
    assert column["bc_values"]["tube_length_mm"] == pytest.approx(scene.tube_length * 1e3)
    (pump,) = model["chambers"]
    assert pump["values"]["shell_viscoelasticity"] == {
        "stiffness_ratio": scene.viscoelastic_ratio,
        "relaxation_time_s": scene.relaxation_time,
    }
    assert pump["values"]["cable_friction"] == {"exponent": scene.cable_friction}
    assert read(model).pumps == (PumpPlacement("pump", "mmHg", **{
        k: v for k, v in pump["values"].items() if k != "units"}),)  # fmt: skip
    run = tmp_path / "run"
    assert main(["simulate", "--scene", str(out), "--out", str(run)]) == 0
    summary = json.loads((run / "summary.json").read_text())
    traces = np.genfromtxt(run / "traces.csv", delimiter=",", names=True)  # the last beat
    record = summary["blocks"]["pump"]
    assert record["peak_force_N"] == pytest.approx(traces["cable_forcepump"].max(), rel=1e-9)
    assert record["stroke_volume_ml"] == pytest.approx(np.ptp(traces["Vcpump"]), rel=1e-9)
    assert "soft pump pump (Omega 4, C 0.4)" in capsys.readouterr().out


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


@pytest.mark.parametrize(
    "scene, change, words",
    [
        ("bench-static", {}, "is static"),
        ("bench-dynamic", dict(effects=("tube_resistance", "cable_slack")), "'cable_slack'"),
    ],
)
def test_a_bench_the_file_cannot_express_is_refused(scene, change, words):
    with pytest.raises(ValueError, match=words):
        to_svzerod(dataclasses.replace(cs.load_scene(scene), **change))


def test_a_water_column_the_reader_cannot_take_is_refused_naming_why():
    """The bench's line needs its sizes, known effects and a law for its flow."""
    model = to_svzerod(cs.load_scene("bench-dynamic"), "mmHg", beats=1)
    values = model["boundary_conditions"][0]["bc_values"]
    for change, words in [
        ({"tube_length_mm": None}, "'tube_length_mm' is required"),
        ({"height_mm": 1.0}, "unknown parameter 'height_mm'"),
        ({"effects": ["column_rise", "tube_friction"]}, "effects"),
        ({"effects": ["column_rise"]}, "flow is undetermined"),
    ]:
        broken = {k: v for k, v in {**values, **change}.items() if v is not None}
        model["boundary_conditions"][0]["bc_values"] = broken
        with pytest.raises(UnsupportedModel, match=words):
            read(model)


def test_a_soft_pumps_shell_effects_are_checked():
    with pytest.raises(ValueError, match="relaxation_time_s"):
        PumpPlacement("pump", shell_viscoelasticity={"stiffness_ratio": 0.2})
    with pytest.raises(ValueError, match=r"cable_friction\.exponent"):
        PumpPlacement("pump", cable_friction={"exponent": -0.5})
