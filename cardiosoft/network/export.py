"""``cardiosoft export --svzerod SCENE``: a scene written as an svZeroDSolver model.

A closed loop is written here; an open loop with a Windkessel by
:mod:`cardiosoft.network.export_open_loop` (each kind's ``svzerod_model``); the command is
:mod:`cardiosoft.network.export_cli`.

The loop (:class:`~cardiosoft.network.closed_loop.ClosedLoop`) becomes svZeroDSolver's blocks:

- each vessel a ``BloodVesselCRL`` (the capacitor at its inlet, then R and L: the notes' RLC
  compartment), joined to what follows it by a ``NORMAL_JUNCTION`` ``J_<up>_<down>``;
- each native chamber a ``LinearElastanceChamber`` (``Epass`` = E_B, ``Emax`` = E_A,
  ``Vrest`` = V_0) with a ``piecewise_cosine`` activation. svZeroDSolver folds time with
  ``fmod``, so a window that wraps past the end of the beat (the atria's relaxation) starts
  one period early, at a negative time: the activation is then the scene's from t = 0 on;
- two extension blocks, which svZeroDSolver itself does not have and cardiosoft's reader takes:
  ``ArctanValve`` (Regazzoni's valve law, ``Rmin``, ``Rmax``, ``sharpness``) and the chamber
  ``SoftPump`` (the pump, :mod:`cardiosoft.network.pump_in_model`; its ``values`` hold its
  design, its pull, its surrogate and the file's ``units``).

The start is the scene's (``initial_condition``, ``steady_initial`` false) and the run
``--beats`` beats of 401 points. Read back (``cardiosoft simulate --scene FILE``) the file gives
the scene's beats (``tests/test_network_loop.py``).
"""

from __future__ import annotations

import dataclasses

OUTPUT_POINTS = 401
"""Points a beat in the written model: the closed loop's own samples (``LOOP_SAMPLES``)."""


def to_svzerod(scene, units: str = "cgs", beats: int = 10, pump=None) -> dict:
    """The closed-loop ``scene`` (a :class:`~cardiosoft.network.loop_scene.LoopScene`) as an
    svZeroDSolver model in ``units`` (:data:`~cardiosoft.network.pump_in_model.UNIT_SYSTEMS`),
    run for ``beats`` beats from the scene's start. ``pump``: its pumps' surrogate (default
    the scene's). Raises ``ValueError`` for a scene this writer cannot express."""
    from cardiosoft.network.closed_loop import CHAMBERS, VALVES, VESSELS
    from cardiosoft.network.loop_components import PumpChamber
    from cardiosoft.network.loop_scene import loop_circuit
    from cardiosoft.network.pump_in_model import UNIT_SYSTEMS
    from cardiosoft.pump import load
    from cardiosoft.valves import ArctanValve

    if units not in UNIT_SYSTEMS:
        raise ValueError(f"--units {units!r} is not one of {', '.join(UNIT_SYSTEMS)}")
    if scene.valve_law != "regazzoni":
        raise ValueError(
            f"scene {scene.name}: only the arctan valves (valve law 'regazzoni') are written"
        )
    loop = loop_circuit(scene, load(pump or scene.pump) if scene.pumps else None)
    p, v = UNIT_SYSTEMS[units][:2]
    period = float(loop.period)
    start = loop.init()
    resistance, compliance = v / p, p / v  # SI -> the model's units

    def number(x, scale=1.0):
        return float(x) * scale

    junction = {  # vessel -> the junction after it
        "ar_sys": ("ar_sys", "ven_sys"),
        "ven_sys": ("ven_sys", "ra"),
        "ar_pul": ("ar_pul", "ven_pul"),
        "ven_pul": ("ven_pul", "la"),
    }
    inlet = {"ar_sys": "aortic", "ven_sys": None, "ar_pul": "pulmonary", "ven_pul": None}
    initial = {}
    vessels = []
    for k, name in enumerate(VESSELS):
        vessel = getattr(loop, name)
        up, down = junction[name]
        into = inlet[name] or next(f"J_{a}_{b}" for a, b in junction.values() if b == name)
        initial[f"pressure:{into}:{name}"] = number(start[name]["pressure"], 1 / p)
        initial[f"flow:{name}:J_{up}_{down}"] = number(start[name]["flow"], 1 / v)
        vessels.append(
            {
                "vessel_id": k,
                "vessel_name": name,
                "vessel_length": 1.0,
                "zero_d_element_type": "BloodVesselCRL",
                "zero_d_element_values": {
                    "R_poiseuille": number(vessel.resistance, resistance),
                    "C": number(vessel.compliance, compliance),
                    "L": number(vessel.inertance, resistance),
                },
            }
        )
    junctions = [
        {
            "junction_name": f"J_{up}_{down}",
            "junction_type": "NORMAL_JUNCTION",
            "inlet_blocks": [up],
            "outlet_blocks": [down],
        }
        for up, down in junction.values()
    ]
    valves = []
    for name, (up, down) in VALVES.items():
        law = getattr(loop, name)
        if not isinstance(law, ArctanValve):
            raise ValueError(f"scene {scene.name}: valve {name} is not an arctan valve")
        params = {
            "Rmin": number(law.min_resistance, resistance),
            "Rmax": number(law.max_resistance, resistance),
            "sharpness": number(law.sharpness, p),
            "upstream_block": up,
            "downstream_block": down,
        }
        valves.append({"type": "ArctanValve", "name": name, "params": params})
    chambers = []
    for name in CHAMBERS:
        law = getattr(loop, name)
        initial[f"Vc:{name}"] = number(start[name]["volume"], 1 / v)
        if isinstance(law, PumpChamber):
            chambers.append(_pump_entry(name, law, scene, pump, units))
            continue
        chambers.append(
            {
                "type": "LinearElastanceChamber",
                "name": name,
                "values": {
                    "Emax": number(law.active_elastance, resistance),
                    "Epass": number(law.passive_elastance, resistance),
                    "Vrest": number(law.rest_volume, 1 / v),
                },
                "activation_function": _activation(law.activation, period),
            }
        )
    parts = {"vessels": vessels, "junctions": junctions, "valves": valves, "chambers": chambers}
    extensions = ("ArctanValve", "SoftPump") if scene.pumps else ("ArctanValve",)
    return model_file(scene.name, units, period, beats, extensions, parts, initial)


def model_file(name, units, period, beats, extensions, parts: dict, initial: dict) -> dict:
    """The svZeroDSolver model of the scene ``name``: its ``parts`` (``vessels``, ``valves``,
    ...) run ``beats`` beats of ``period`` (s) from ``initial`` (no steady start-up), in
    ``units``, described with the ``extensions`` (cardiosoft's blocks) it uses."""
    from cardiosoft.network.pump_in_model import UNIT_SYSTEMS

    system = UNIT_SYSTEMS[units]
    return {
        "description": {
            "description of test case": f"cardiosoft scene {name}, written by "
            f"'cardiosoft export --svzerod {name}'; units: {units} ({system[2]}, {system[3]}, "
            f"s). cardiosoft's extension blocks in it: {', '.join(extensions)}.",
        },
        "simulation_parameters": {
            "number_of_cardiac_cycles": int(beats),
            "number_of_time_pts_per_cardiac_cycle": OUTPUT_POINTS,
            "cardiac_period": float(period),
            "steady_initial": False,
            "output_all_cycles": False,
            "output_variable_based": True,
        },
        "boundary_conditions": [],
        **parts,
        "initial_condition": initial,
    }


def _activation(activation, period: float) -> dict:
    """A piecewise_cosine activation equal to ``activation`` from t = 0 (module docstring)."""
    start = float(activation.start) * period
    contract = float(activation.contraction) * period
    relax = float(activation.relaxation) * period
    relax_start = start + contract
    if relax_start >= period:
        relax_start -= period
    if start + contract > period:  # a contraction that wraps past the beat's end
        start -= period
    if relax_start + relax > period:  # a relaxation that wraps
        relax_start -= period
    return {
        "type": "piecewise_cosine",
        "contract_start": start,
        "relax_start": relax_start,
        "contract_duration": contract,
        "relax_duration": relax,
    }


def _pump_entry(name, law, scene, pump, units) -> dict:
    """The ``SoftPump`` extension chamber of a pump chamber ``law``."""
    from cardiosoft.network.pump_in_model import PumpPlacement

    pull = law.actuation
    placement = PumpPlacement(
        name,
        units,
        omega=float(law.omega),
        shortening=float(pull.stroke) / float(law.pump.cable_length(law.omega)),
        surrogate=pump or scene.pump,
        shape=pull.shape,
        pull_fraction=float(pull.pull_fraction),
        hold_fraction=float(pull.hold_fraction),
        release_fraction=float(pull.release_fraction),
        onset=float(law.onset),
    )
    return pump_entry(placement)


def pump_entry(placement) -> dict:
    """The ``SoftPump`` extension chamber of a
    :class:`~cardiosoft.network.pump_in_model.PumpPlacement`: its fields, which the reader
    takes back."""
    values = dataclasses.asdict(placement)
    # the shell's effects are absent unless the scene has them: not written as null or 0
    values = {k: v for k, v in values.items() if v is not None and (k != "ramp_time" or v)}
    return {"type": "SoftPump", "name": values.pop("chamber"), "values": values}
