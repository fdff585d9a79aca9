"""``cardiosoft export --svzerod SCENE`` of an open-loop scene: the pump between an atrium and a
3-element Windkessel (``lv-systemic``, ``rv-pulmonary``), or the paper's dynamic bench
(``bench-dynamic``).

A scene with a Windkessel (:class:`~cardiosoft.scene.Scene`, its
:class:`~cardiosoft.circuit.PumpCircuit`) becomes, in the file's units:

- the atrium a ``PRESSURE`` boundary condition ``preload`` at the scene's constant filling
  pressure;
- the Windkessel an ``RCR`` boundary condition ``afterload`` (C, Rd, Pd = the venous
  pressure) with ``Rp = 0``: the scene's outlet line is one law, the valve's smooth switch
  acting on the whole drop from the pump to the capacitor with the valve's resistance and Rp
  in series (:func:`cardiosoft.circuit.line_outflow`), so the file's outlet valve carries
  ``R = R_valve + Rp``. (An RCR with its own Rp behind the valve would switch on the valve's
  drop alone: a different, if close, law.);
- the valves ``inlet_valve`` and ``outlet_valve`` the extension block ``SmoothValve`` (the
  scene's smooth law :class:`~cardiosoft.valves.Valve`, ``q = dp sigmoid(dp / w) / R``;
  ``R``, ``smoothing`` w);
- the pump the extension chamber ``SoftPump`` named ``pump``
  (:func:`cardiosoft.network.export.pump_entry`).

The bench becomes the ``SoftPump`` ``pump`` with the shell's effects the scene names (the
crosshead's ramp, the shell's viscoelasticity, the cables' friction:
:class:`~cardiosoft.network.pump_in_model.PumpPlacement`), joined by a ``NORMAL_JUNCTION``
``J_pump_column`` to the extension boundary condition ``WaterColumn`` ``column``, the tube into
the open column (:mod:`cardiosoft.network.water_column`), at one of the scene's column heads
(its first unless the scene is narrowed to another, ``cardiosoft export --afterload``).

The start is the scene's rest (the pump filled at the atrial pressure, or the column's head, at
zero pull; the capacitor at the venous pressure; the column at its first level, the line at
rest), without svZeroDSolver's steady start-up. Read back (``cardiosoft simulate --scene FILE``)
the file gives the scene's beats (``tests/test_network_export.py``). The static bench has no
beat to step, and the cables' slack and the wall's contact no block of the file carries
(:func:`refusal`).
"""

from __future__ import annotations


def refusal(scene) -> str | None:
    """Why the open-loop ``scene`` is not written, or None
    (:func:`cardiosoft.open_loop_tools.unsupported`)."""
    if scene.static:
        return (
            "is static: a quasi-static pull, with no beat for a model to step (write the "
            "dynamic bench, bench-dynamic)"
        )
    for effect in ("cable_slack", "wall_contact"):
        if scene.has(effect):
            return f"has the shell effect {effect!r}, which no block of the file carries"
    return None


def to_svzerod(scene, units: str = "cgs", beats: int = 10, pump=None) -> dict:
    """The open-loop ``scene`` with a Windkessel as an svZeroDSolver model in ``units``
    (:data:`~cardiosoft.network.pump_in_model.UNIT_SYSTEMS`), run for ``beats`` beats from the
    scene's rest. ``pump``: its surrogate's name or path (default the scene's). Raises
    ``ValueError`` for a scene this writer cannot express, naming what."""
    from cardiosoft.network.export import model_file, pump_entry
    from cardiosoft.network.pump_in_model import UNIT_SYSTEMS, pump_law
    from cardiosoft.scene import SHELL_EFFECTS
    from cardiosoft.units import bpm

    if units not in UNIT_SYSTEMS:
        raise ValueError(f"--units {units!r} is not one of {', '.join(UNIT_SYSTEMS)}")
    reason = refusal(scene)
    if reason is not None:
        raise ValueError(f"scene {scene.name} {reason}")
    if scene.afterload.has_heads:
        return _bench(scene, units, beats, pump)
    shell = [e for e in scene.effects if e in SHELL_EFFECTS]
    if shell:
        raise ValueError(
            f"scene {scene.name}: the shell effect {shell[0]!r} has no svZeroDSolver block "
            "(the file's SoftPump with a Windkessel is the surrogate's chamber law alone)"
        )
    if scene.valve_kind != "smooth":
        raise ValueError(
            f"scene {scene.name}: valve kind {scene.valve_kind!r} is not written (only the "
            "smooth valves: SmoothValve)"
        )
    if scene.ramp_time > 0:
        raise ValueError(
            f"scene {scene.name}: actuation.ramp_time_s = {scene.ramp_time:g} s is not written "
            "with a Windkessel (its SoftPump's pull has no ramp)"
        )
    parts = scene.afterload.blocks(scene)
    windkessel, preload = parts["afterload"], parts["preload"]
    p, v = UNIT_SYSTEMS[units][:2]
    resistance = v / p  # SI -> the model's units, for a resistance
    period = 1.0 / (scene.bpm * bpm)
    placement = _placement(scene, units, pump)
    start_volume = pump_law(placement, period).start_volume(preload.p_atrial)

    def valve(name, law, up, down, series=0.0):
        params = {
            "R": float(law.resistance + series) * resistance,
            "smoothing": float(law.smoothing) / p,
            "upstream_block": up,
            "downstream_block": down,
        }
        return {"type": "SmoothValve", "name": name, "params": params}

    boundary_conditions = [
        {
            "bc_name": "preload",
            "bc_type": "PRESSURE",
            "bc_values": {"P": float(preload.p_atrial) / p},
        },
        {
            "bc_name": "afterload",
            "bc_type": "RCR",
            "bc_values": {
                "Rp": 0.0,
                "C": float(windkessel.C) * p / v,
                "Rd": float(windkessel.Rd) * resistance,
                "Pd": float(windkessel.p_venous) / p,
            },
        },
    ]
    valves = [
        valve("inlet_valve", parts["inlet_valve"], "preload", "pump"),
        valve("outlet_valve", parts["outlet_valve"], "pump", "afterload", windkessel.Rp),
    ]
    initial = {
        "Vc:pump": float(start_volume) / v,
        "pressure_c:afterload": float(windkessel.p_venous) / p,
    }
    parts = {
        "boundary_conditions": boundary_conditions,
        "valves": valves,
        "chambers": [pump_entry(placement)],
    }
    return model_file(scene.name, units, period, beats, ("SmoothValve", "SoftPump"), parts, initial)


def _bench(scene, units: str, beats: int, pump=None) -> dict:
    """The dynamic bench at the scene's first column head (module docstring)."""
    from cardiosoft.batch import scene_circuit
    from cardiosoft.circulation import BENCH_EFFECTS
    from cardiosoft.network.export import model_file, pump_entry
    from cardiosoft.network.pump_in_model import UNIT_SYSTEMS
    from cardiosoft.pump import load
    from cardiosoft.units import bpm, mm, mmHg

    head = scene.afterloads[0]
    start = scene_circuit(scene, load(pump or scene.pump), head).init()
    placement = _placement(scene, units, pump)
    column = {
        "units": units,
        "head_mmHg": head / mmHg,
        "column_diameter_mm": scene.column_diameter / mm,
        "tube_length_mm": scene.tube_length / mm,
        "tube_diameter_mm": scene.tube_diameter / mm,
        "loss_coefficient": scene.loss_coefficient,
        "effects": [e for e in scene.effects if e in BENCH_EFFECTS],
    }
    volume_unit = UNIT_SYSTEMS[units][1]
    initial = {"Vc:pump": float(start["volume"]) / volume_unit, "column_volume:column": 0.0}
    if placement.shell_viscoelasticity is not None:
        initial["Vd:pump"] = float(start["relaxation"]) / volume_unit
    parts = {
        "boundary_conditions": [
            {"bc_name": "column", "bc_type": "WaterColumn", "bc_values": column}
        ],
        "junctions": [
            {
                "junction_name": "J_pump_column",
                "junction_type": "NORMAL_JUNCTION",
                "inlet_blocks": ["pump"],
                "outlet_blocks": ["column"],
            }
        ],
        "chambers": [pump_entry(placement)],
    }
    period = 1.0 / (scene.bpm * bpm)
    blocks = ("SoftPump", "WaterColumn")
    model = model_file(scene.name, units, period, beats, blocks, parts, initial)
    model["description"]["column head"] = (
        f"{head / mmHg:g} mmHg ('cardiosoft export --afterload MMHG' writes another)"
    )
    return model


def _placement(scene, units: str, pump=None):
    """The file's ``SoftPump`` ``pump``: the scene's design, pull and shell effects (each None
    where the scene has none), in ``units``, with ``pump`` (default the scene's surrogate)."""
    from cardiosoft.network.pump_in_model import PumpPlacement

    viscoelastic = scene.has("shell_viscoelasticity")
    return PumpPlacement(
        "pump",
        units,
        omega=scene.omega,
        shortening=scene.shortening,
        surrogate=pump or scene.pump,
        shape=scene.shape,
        pull_fraction=scene.pull_fraction,
        hold_fraction=scene.hold_fraction,
        release_fraction=scene.release_fraction,
        ramp_time=scene.ramp_time,
        shell_viscoelasticity={
            "stiffness_ratio": scene.viscoelastic_ratio,
            "relaxation_time_s": scene.relaxation_time,
        }
        if viscoelastic
        else None,
        cable_friction={"exponent": scene.cable_friction}
        if scene.has("cable_friction")
        else None,
    )
