"""svZeroDSolver's JSON models, read into a :class:`~cardiosoft.network.network.Network`.

The reader follows svZeroDSolver's own definitions (``src/solve/SimulationParameters.cpp`` and
``src/solve/Solver.cpp`` of ``SimVascular/svZeroDSolver``; ``notes/svzerod.md``):

- connections are made in svZeroDSolver's order (vessels, junctions); each is one node
  ``UP:DOWN`` with the unknowns ``pressure:UP:DOWN`` and ``flow:UP:DOWN``;
- the period comes from the time tables (all must agree), else from
  ``simulation_parameters.cardiac_period`` (which must agree with the tables), else it is 1;
- ``initial_condition`` sets any variable by name; ``pressure_all`` fills every unnamed
  ``pressure:`` and ``P_c:`` one, ``flow_all`` every unnamed ``flow:`` one; the rest start at 0;
- ``steady_initial`` (default true) starts from the steady state of the model with each table
  replaced by the mean of its samples. svZeroDSolver marches towards that state by 31 steps of
  a tenth of a period; this reader solves for it (the two differ by what 3.1 periods of a
  backward-Euler-like march leave of the slowest transient, which the beats that follow damp).

A block type, a simulation option or a parameter this reader does not support is refused in one
line (:class:`UnsupportedModel`) that names it. Keys that start with ``_`` are comments.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import jax.numpy as jnp

from cardiosoft.network.blocks import (
    RCR,
    BloodVessel,
    FlowSource,
    Junction,
    PressureSource,
    Resistance,
    TimeTable,
    VesselJunction,
)
from cardiosoft.network.network import Network, reduce_index

SUPPORTED_BLOCKS = (
    "BloodVessel",
    "FLOW",
    "PRESSURE",
    "RESISTANCE",
    "RCR",
    "NORMAL_JUNCTION",
    "BloodVesselJunction",
)
"""svZeroDSolver block types the reader takes."""

UNSUPPORTED_OPTIONS = (
    "use_cycle_to_cycle_error",
    "coupled_simulation",
    "output_mean_only",
    "output_derivative",
)
"""svZeroDSolver simulation options the reader refuses when they are switched on."""


class UnsupportedModel(ValueError):
    """A model the reader cannot take, or that svZeroDSolver itself would refuse."""


@dataclass(frozen=True)
class Simulation:
    """svZeroDSolver's ``simulation_parameters`` that the run uses."""

    cycles: int
    points_per_cycle: int
    steady_initial: bool = True
    output_all_cycles: bool = False

    @property
    def steps_per_cycle(self) -> int:
        return self.points_per_cycle - 1


@dataclass(frozen=True)
class Model:
    """A read svZeroDSolver model: the network, its simulation settings and its initial values
    (every variable by svZeroDSolver name)."""

    network: Network
    simulation: Simulation
    initial: dict
    name: str = "model"

    def initial_states(self) -> jnp.ndarray:
        """The blocks' states from the model's initial values."""
        net, initial = self.network, self.initial
        x = []
        for b in net.blocks:
            nodes = [f"{up}:{down}" for up, down in (net.nodes[i] for i in b.ports)]
            values = {
                "P": [initial[f"pressure:{n}"] for n in nodes],
                "Q": [initial[f"flow:{n}"] for n in nodes],
                **{k: initial[k] for k in b.internal_names()},
            }
            x += b.states_from(values)
        return jnp.asarray(x, dtype=float)

    def variables(self) -> list[str]:
        """svZeroDSolver's variable names: each node's pressure and flow, then internal ones."""
        names = []
        for up, down in self.network.nodes:
            names += [f"pressure:{up}:{down}", f"flow:{up}:{down}"]
        for b in self.network.blocks:
            names += list(b.internal_names())
        return names


def _values(params: dict, where: str, required: tuple, optional: tuple = (), tables=()) -> dict:
    """The block's parameters, with unknown ones refused and optional ones defaulting to 0."""
    given = {k: v for k, v in params.items() if not k.startswith("_")}
    unknown = sorted(set(given) - set(required) - set(optional) - {"t"})
    if unknown:
        raise UnsupportedModel(f"{where}: unknown parameter {unknown[0]!r}")
    missing = [k for k in required if k not in given]
    if missing:
        raise UnsupportedModel(f"{where}: parameter {missing[0]!r} is required")
    out = {k: given.get(k, 0.0) for k in (*required, *optional)}
    for k in tables:
        value = out[k]
        if isinstance(value, list) and len(value) > 1:
            if "t" not in given or len(given["t"]) != len(value):
                raise UnsupportedModel(
                    f"{where}: parameter {k!r} needs a time table 't' of as many samples"
                )
            out[k] = TimeTable(given["t"], value)
        else:
            out[k] = TimeTable([0.0], [value[0] if isinstance(value, list) else value])
    return out


class _Builder:
    """Collects connections and blocks in svZeroDSolver's order."""

    def __init__(self):
        self.connections: list[tuple[str, str]] = []
        self.specs: list[tuple[str, str, dict]] = []  # (name, type, parameters)

    def ports(self, name):
        inlets = [i for i, (_, down) in enumerate(self.connections) if down == name]
        outlets = [i for i, (up, _) in enumerate(self.connections) if up == name]
        return inlets, outlets


def _table_period(tables) -> float | None:
    periods = {float(t.period) for t in tables if t.values.shape[0] > 1}
    if len(periods) > 1:
        raise UnsupportedModel(
            "inconsistent cardiac cycle period defined in the time tables: "
            + ", ".join(f"{p:g}" for p in sorted(periods))
        )
    return periods.pop() if periods else None


def read(source, name: str | None = None) -> Model:
    """Read an svZeroDSolver model from a path or an already parsed dict."""
    if isinstance(source, str | Path):
        path = Path(source)
        with path.open() as f:
            config = json.load(f)
        name = name or path.stem
    else:
        config = source
    if not isinstance(config, dict) or "simulation_parameters" not in config:
        raise UnsupportedModel("not an svZeroDSolver model: 'simulation_parameters' is missing")
    for key in ("closed_loop_blocks", "valves", "chambers", "external_solver_coupling_blocks"):
        for entry in config.get(key) or []:
            kind = entry.get("closed_loop_type") or entry.get("type") or key
            raise UnsupportedModel(f"block type {kind!r} ({key}) is not supported yet")
    b = _Builder()
    vessel_names = {}
    vessels = {}
    for v in config.get("vessels", []):
        vname = v["vessel_name"]
        kind = v.get("zero_d_element_type", "BloodVessel")
        if kind != "BloodVessel":
            raise UnsupportedModel(f"block type {kind!r} (vessel {vname}) is not supported")
        vessel_names[v["vessel_id"]] = vname
        vessels[vname] = _values(
            v.get("zero_d_element_values", {}),
            f"BloodVessel {vname}",
            ("R_poiseuille",),
            ("C", "L", "stenosis_coefficient"),
        )
        bcs = v.get("boundary_conditions", {})
        if "inlet" in bcs:
            b.connections.append((bcs["inlet"], vname))
        if "outlet" in bcs:
            b.connections.append((vname, bcs["outlet"]))
    bcs = {}
    for bc in config["boundary_conditions"]:
        bname, kind, params = bc["bc_name"], bc["bc_type"], bc.get("bc_values", {})
        where = f"{kind} {bname}"
        if kind == "FLOW":
            bcs[bname] = (FlowSource, _values(params, where, ("Q",), tables=("Q",)))
        elif kind == "PRESSURE":
            bcs[bname] = (PressureSource, _values(params, where, ("P",), tables=("P",)))
        elif kind == "RESISTANCE":
            bcs[bname] = (Resistance, _values(params, where, ("R", "Pd"), tables=("R", "Pd")))
        elif kind == "RCR":
            bcs[bname] = (
                RCR,
                _values(params, where, ("Rp", "C", "Rd"), ("Pd",), ("Rp", "C", "Rd", "Pd")),
            )
        else:
            raise UnsupportedModel(
                f"block type {kind!r} (boundary condition {bname}) is not supported"
            )
    junctions = {}
    for j in config.get("junctions", []):
        jname, kind = j["junction_name"], j.get("junction_type", "NORMAL_JUNCTION")
        if kind not in ("NORMAL_JUNCTION", "BloodVesselJunction"):
            raise UnsupportedModel(f"block type {kind!r} (junction {jname}) is not supported")
        if "inlet_vessels" in j and "outlet_vessels" in j:
            ins = [vessel_names[i] for i in j["inlet_vessels"]]
            outs = [vessel_names[i] for i in j["outlet_vessels"]]
        else:
            ins, outs = j["inlet_blocks"], j["outlet_blocks"]
        b.connections += [(i, jname) for i in ins] + [(jname, o) for o in outs]
        if kind == "BloodVesselJunction":
            if len(ins) != 1:
                raise UnsupportedModel(f"BloodVesselJunction {jname}: one inlet, not {len(ins)}")
            params = _values(
                j.get("junction_values", {}),
                f"{kind} {jname}",
                ("R_poiseuille", "L", "stenosis_coefficient"),
            )
            junctions[jname] = (kind, params)
        else:
            junctions[jname] = (kind, {})

    tables = [t for _, p in bcs.values() for t in p.values()]
    period = _table_period(tables)
    sim = config["simulation_parameters"]
    given_period = sim.get("cardiac_period")
    if given_period is not None and period is not None and given_period != period:
        raise UnsupportedModel(
            f"inconsistent cardiac cycle period: {given_period:g} in simulation_parameters, "
            f"{period:g} in the time tables"
        )
    period = period or given_period or 1.0
    for option in UNSUPPORTED_OPTIONS:
        if sim.get(option):
            raise UnsupportedModel(f"simulation option {option!r} is not supported")
    if sim.get("output_interval", 1) != 1:
        raise UnsupportedModel("simulation option 'output_interval' other than 1 is not supported")
    simulation = Simulation(
        cycles=int(sim["number_of_cardiac_cycles"]),
        points_per_cycle=int(sim["number_of_time_pts_per_cardiac_cycle"]),
        steady_initial=bool(sim.get("steady_initial", True)),
        output_all_cycles=bool(sim.get("output_all_cycles", False)),
    )

    blocks = []
    for vname, p in vessels.items():
        ins, outs = b.ports(vname)
        if len(ins) != 1 or len(outs) != 1:
            raise UnsupportedModel(
                f"BloodVessel {vname}: needs one inlet and one outlet connection, "
                f"has {len(ins)} and {len(outs)}"
            )
        R, C, L, S = (float(p[k]) for k in ("R_poiseuille", "C", "L", "stenosis_coefficient"))
        blocks.append(
            BloodVessel(
                vname,
                (ins[0], outs[0]),
                jnp.asarray(R),
                jnp.asarray(C),
                jnp.asarray(L),
                jnp.asarray(S),
                C != 0,
                L != 0,
                S != 0,
            )
        )
    for bname, (cls, p) in bcs.items():
        ins, outs = b.ports(bname)
        if len(ins) + len(outs) != 1:
            raise UnsupportedModel(
                f"boundary condition {bname}: connected to {len(ins) + len(outs)} blocks, not 1"
            )
        blocks.append(cls(bname, tuple(ins + outs), **p))
    for jname, (kind, p) in junctions.items():
        ins, outs = b.ports(jname)
        if kind == "NORMAL_JUNCTION":
            blocks.append(Junction(jname, tuple(ins + outs), len(ins)))
        else:
            R, L, S = (
                jnp.asarray(p[k], dtype=float)
                for k in ("R_poiseuille", "L", "stenosis_coefficient")
            )
            if not R.shape == L.shape == S.shape == (len(outs),):
                raise UnsupportedModel(
                    f"BloodVesselJunction {jname}: one value per outlet in R_poiseuille, L "
                    "and stenosis_coefficient"
                )
            has_L = tuple(bool(v != 0) for v in L)
            blocks.append(
                VesselJunction(jname, tuple(ins + outs), R, L, S, has_L, bool(jnp.any(S != 0)))
            )
    named = {x for c in b.connections for x in c}
    known = set(vessels) | set(bcs) | set(junctions)
    if named - known:
        raise UnsupportedModel(f"connection to an unknown block {sorted(named - known)[0]!r}")

    network = Network(tuple(blocks), tuple(b.connections), float(period))
    model = Model(network, simulation, {}, name or "model")
    model = Model(
        network,
        simulation,
        _initial(config.get("initial_condition", {}), model.variables()),
        model.name,
    )
    try:
        network = reduce_index(network, model.initial_states())
    except ValueError as error:
        raise UnsupportedModel(f"{model.name}: {error}") from None
    return Model(network, simulation, model.initial, model.name)


def _initial(given: dict, names: list[str]) -> dict:
    """Every variable's initial value by svZeroDSolver's rules (``load_initial_condition``)."""
    values = {}
    for name in names:
        default = 0.0
        if name.startswith(("pressure:", "P_c:")) and "pressure_all" in given:
            default = given["pressure_all"]
        elif name.startswith("flow:") and "flow_all" in given:
            default = given["flow_all"]
        values[name] = float(given.get(name, default))
    return values
