"""``cardiosoft export --svzerod SCENE`` of an open-loop scene with a Windkessel afterload
(``lv-systemic``, ``rv-pulmonary``): the pump between an atrium and a 3-element Windkessel.

The scene (:class:`~cardiosoft.scene.Scene`, its :class:`~cardiosoft.circuit.PumpCircuit`)
becomes, in the file's units:

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

The start is the scene's rest (the pump filled at the atrial pressure at zero pull, the
capacitor at the venous pressure), without svZeroDSolver's steady start-up. Read back
(``cardiosoft simulate --scene FILE``) the file gives the scene's beats
(``tests/test_network_export.py``). A water-column bench has no svZeroDSolver form
(:data:`UNSUPPORTED`), nor has a shell effect, whose law no block of the file carries.
"""

from __future__ import annotations

UNSUPPORTED = (
    "has a water column behind a tube, which has no svZeroDSolver block (only the Windkessel "
    "scenes lv-systemic and rv-pulmonary are written)"
)
"""Why a bench scene is not written (:func:`cardiosoft.open_loop_tools.unsupported`)."""


def to_svzerod(scene, units: str = "cgs", beats: int = 10, pump=None) -> dict:
    """The open-loop ``scene`` with a Windkessel as an svZeroDSolver model in ``units``
    (:data:`~cardiosoft.network.pump_in_model.UNIT_SYSTEMS`), run for ``beats`` beats from the
    scene's rest. ``pump``: its surrogate's name or path (default the scene's). Raises
    ``ValueError`` for a scene this writer cannot express, naming what."""
    from cardiosoft.network.export import model_file, pump_entry
    from cardiosoft.network.pump_in_model import UNIT_SYSTEMS, PumpPlacement, pump_law
    from cardiosoft.scene import SHELL_EFFECTS
    from cardiosoft.units import bpm

    if units not in UNIT_SYSTEMS:
        raise ValueError(f"--units {units!r} is not one of {', '.join(UNIT_SYSTEMS)}")
    if scene.afterload.has_heads:
        raise ValueError(f"scene {scene.name} {UNSUPPORTED}")
    shell = [e for e in scene.effects if e in SHELL_EFFECTS]
    if shell:
        raise ValueError(
            f"scene {scene.name}: the shell effect {shell[0]!r} has no svZeroDSolver block "
            "(the file's SoftPump is the surrogate's chamber law alone)"
        )
    if scene.valve_kind != "smooth":
        raise ValueError(
            f"scene {scene.name}: valve kind {scene.valve_kind!r} is not written (only the "
            "smooth valves: SmoothValve)"
        )
    if scene.ramp_time > 0:
        raise ValueError(
            f"scene {scene.name}: actuation.ramp_time_s = {scene.ramp_time:g} s is not written "
            "(SoftPump's pull has no ramp)"
        )
    parts = scene.afterload.blocks(scene)
    windkessel, preload = parts["afterload"], parts["preload"]
    p, v = UNIT_SYSTEMS[units][:2]
    resistance = v / p  # SI -> the model's units, for a resistance
    period = 1.0 / (scene.bpm * bpm)
    placement = PumpPlacement(
        "pump",
        units,
        omega=scene.omega,
        shortening=scene.shortening,
        surrogate=pump or scene.pump,
        shape=scene.shape,
        pull_fraction=scene.pull_fraction,
        hold_fraction=scene.hold_fraction,
        release_fraction=scene.release_fraction,
    )
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
