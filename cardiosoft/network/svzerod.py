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
  A model with a chamber has no steady state (its activation keeps time in the start-up): its
  start-up is marched as svZeroDSolver marches it (:func:`~cardiosoft.network.scheme.
  steady_march`), refused beside a coronary or the combined heart, whose start-up equations are
  not reproduced step for step.

A block type, a simulation option or a parameter this reader does not support is refused in one
line (:class:`UnsupportedModel`) that names it. Keys that start with ``_`` are comments.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import jax.numpy as jnp

from cardiosoft.network.blocks import (
    RCR,
    BloodVessel,
    BloodVesselRC,
    ClosedLoopRCR,
    FlowSource,
    Junction,
    PiecewiseValve,
    PressureSource,
    Resistance,
    TimeTable,
    ValveTanh,
    VesselJunction,
)
from cardiosoft.network.coronary_blocks import CORONARIES, coronary, join_coronaries
from cardiosoft.network.heart_blocks import (
    ACTIVATIONS,
    CHAMBER_PARAMETERS,
    HEART_PARAMETERS,
    SPHERE_PARAMETERS,
    Activation,
    Chamber,
    ChamberSphere,
    ClosedLoopHeart,
)
from cardiosoft.network.loop_blocks import LawValve
from cardiosoft.network.network import Network, reduce_index
from cardiosoft.network.ordering import stored_order
from cardiosoft.network.pump_in_model import PumpPlacement, soft_pump
from cardiosoft.network.simulation_parameters import Simulation, UnsupportedModel, read_simulation
from cardiosoft.network.water_column import water_column
from cardiosoft.valves import ArctanValve, Valve

SUPPORTED_BLOCKS = (
    "BloodVessel",
    "BloodVesselCRL",
    "BloodVesselRC",
    "FLOW",
    "PRESSURE",
    "RESISTANCE",
    "RCR",
    "ClosedLoopRCR",
    "CORONARY",
    "CORONARY_VAR_RES",
    "ClosedLoopCoronaryLeft",
    "ClosedLoopCoronaryRight",
    "NORMAL_JUNCTION",
    "BloodVesselJunction",
    "ValveTanh",
    "PiecewiseValve",
    "ClosedLoopHeartAndPulmonary",
    "ChamberElastanceInductor",
    "ChamberElastanceInductorExponential",
    "LinearElastanceChamber",
    "ChamberSphere",
)
"""svZeroDSolver block types the reader takes."""
EXTENSION_BLOCKS = ("ArctanValve", "SmoothValve", "SoftPump", "WaterColumn")
"""cardiosoft's own blocks, which ``cardiosoft export --svzerod`` writes and the reader takes
(two valve laws, a chamber and the bench's line; svZeroDSolver itself has none of them)."""


@dataclass(frozen=True)
class Model:
    """A read svZeroDSolver model: the network, its simulation settings and its initial values
    (every variable by svZeroDSolver name); ``pumps``: the file's own soft pumps (its
    ``SoftPump`` chambers, not one placed by ``--pump-chamber``)."""

    network: Network
    simulation: Simulation
    initial: dict
    name: str = "model"
    pumps: tuple[PumpPlacement, ...] = ()

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
        """svZeroDSolver's variable names (:func:`variable_names`)."""
        return variable_names(self.network)


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


def variable_names(network: Network) -> list[str]:
    """svZeroDSolver's variable names: each node's pressure and flow, then internal ones."""
    names = []
    for up, down in network.nodes:
        names += [f"pressure:{up}:{down}", f"flow:{up}:{down}"]
    for b in network.blocks:
        names += list(b.internal_names())
    return names


def _table_period(tables) -> float | None:
    periods = {float(t.period) for t in tables if t.values.shape[0] > 1}
    if len(periods) > 1:
        raise UnsupportedModel(
            "inconsistent cardiac cycle period defined in the time tables: "
            + ", ".join(f"{p:g}" for p in sorted(periods))
        )
    return periods.pop() if periods else None


def _vessel(kind, name, p, ports):
    """A vessel (``BloodVessel``, ``BloodVesselCRL``): one inlet, one outlet."""
    ins, outs = ports
    if len(ins) != 1 or len(outs) != 1:
        raise UnsupportedModel(
            f"{kind} {name}: needs one inlet and one outlet connection, "
            f"has {len(ins)} and {len(outs)}"
        )
    R, C, L, S = (float(p[k]) for k in ("R_poiseuille", "C", "L", "stenosis_coefficient"))
    arrays = (jnp.asarray(v) for v in (R, C, L, S))
    first = kind == "BloodVessel"
    return BloodVessel(name, (ins[0], outs[0]), *arrays, C != 0, L != 0, S != 0, first)


def _vessel_junction(name, p, ports):
    ins, outs = ports
    if len(ins) != 1:
        raise UnsupportedModel(f"BloodVesselJunction {name}: one inlet, not {len(ins)}")
    R, L, S = (
        jnp.asarray(p[k], dtype=float) for k in ("R_poiseuille", "L", "stenosis_coefficient")
    )
    if not R.shape == L.shape == S.shape == (len(outs),):
        raise UnsupportedModel(
            f"BloodVesselJunction {name}: one value per outlet in R_poiseuille, L "
            "and stenosis_coefficient"
        )
    has_L = tuple(bool(v != 0) for v in L)
    return VesselJunction(name, (*ins, *outs), R, L, S, has_L, bool(jnp.any(S != 0)))


def _one_port(cls, name, kwargs, ports):
    """A boundary condition: connected to exactly one block."""
    nodes = (*ports[0], *ports[1])
    if len(nodes) != 1:
        raise UnsupportedModel(f"{cls.kind} {name}: connected to {len(nodes)} blocks, not 1")
    return cls(name, nodes, **kwargs)


def _two_ports(cls, name, kwargs, ports):
    """A block between one inlet and one outlet node."""
    ins, outs = ports
    if len(ins) != 1 or len(outs) != 1:
        raise UnsupportedModel(f"{cls.kind} {name}: needs one inlet and one outlet connection")
    return cls(name, (ins[0], outs[0]), **kwargs)


def _arrays(p: dict, keys) -> dict:
    return {k: jnp.asarray(p[k], dtype=float) for k in keys}


def _checked(make, *args):
    """``make(*args)``, its ValueError (a wiring or a value it cannot take) refused."""
    try:
        return make(*args)
    except ValueError as error:
        raise UnsupportedModel(str(error)) from None


def _boundary_condition(bc: dict, clock: dict):
    """(name, factory of the block from its ports, its time tables, whether it feeds the heart).
    ``clock["period"]``: the model's period, set before the factories run."""
    name, kind, params = bc["bc_name"], bc["bc_type"], bc.get("bc_values", {})
    where = f"{kind} {name}"
    if kind == "FLOW":
        kwargs, cls = _values(params, where, ("Q",), tables=("Q",)), FlowSource
    elif kind == "PRESSURE":
        kwargs, cls = _values(params, where, ("P",), tables=("P",)), PressureSource
    elif kind == "RESISTANCE":
        kwargs, cls = _values(params, where, ("R", "Pd"), tables=("R", "Pd")), Resistance
    elif kind == "RCR":
        kwargs = _values(params, where, ("Rp", "C", "Rd"), ("Pd",), ("Rp", "C", "Rd", "Pd"))
        cls = RCR
    elif kind == "ClosedLoopRCR":
        p = _values(params, where, ("Rp", "C", "Rd", "closed_loop_outlet"))
        kwargs = _arrays(p, ("Rp", "C", "Rd"))
        return (
            name,
            (lambda ports: _two_ports(ClosedLoopRCR, name, kwargs, ports)),
            [],
            bool(p["closed_loop_outlet"]),
        )
    elif kind in CORONARIES:  # open loop (Pim a table), or closed loop (into the heart)
        is_open = "Pim" in CORONARIES[kind]
        optional, tables = ("closed_loop_outlet",) * is_open, ("Pim",) * is_open
        p = _values(params, where, CORONARIES[kind], optional, tables)
        make = lambda ports: _checked(coronary, kind, name, p, ports, clock)  # noqa: E731
        return name, make, [p["Pim"]] if is_open else [], not is_open
    elif kind == "WaterColumn":  # cardiosoft's extension: the bench's line and column
        return name, (lambda ports: _checked(water_column, name, params, ports)), [], False
    else:
        raise UnsupportedModel(f"block type {kind!r} (boundary condition {name}) is not supported")
    tables = [v for v in kwargs.values() if isinstance(v, TimeTable)]
    return name, (lambda ports: _one_port(cls, name, kwargs, ports)), tables, False


def read(source, name: str | None = None, pump: PumpPlacement | None = None) -> Model:
    """Read an svZeroDSolver model from a path or an already parsed dict; ``pump``: the soft
    pump in place of one of its chambers (:mod:`cardiosoft.network.pump_in_model`)."""
    if isinstance(source, str | Path):
        path = Path(source)
        with path.open() as f:
            config = json.load(f)
        name = name or path.stem
    else:
        config = source
    if not isinstance(config, dict) or "simulation_parameters" not in config:
        raise UnsupportedModel("not an svZeroDSolver model: 'simulation_parameters' is missing")
    for entry in config.get("external_solver_coupling_blocks") or []:
        raise UnsupportedModel(
            f"block type {entry.get('type', 'coupling')!r} (external_solver_coupling_blocks) "
            "is not supported: the network runs a model on its own"
        )
    connections: list[tuple[str, str]] = []
    factories: dict = {}  # block name -> factory of the block from its (inlet, outlet) nodes
    period = None

    # svZeroDSolver's order: vessels, boundary conditions, junctions, closed loop, valves
    vessel_names, clock = {}, {}
    for v in config.get("vessels", []):
        vname, kind = v["vessel_name"], v.get("zero_d_element_type", "BloodVessel")
        vessel_names[v["vessel_id"]] = vname
        values, where = v.get("zero_d_element_values", {}), f"{kind} {vname}"
        if kind in ("BloodVessel", "BloodVesselCRL"):
            params = _values(values, where, ("R_poiseuille",), ("C", "L", "stenosis_coefficient"))
            factories[vname] = lambda ports, kind=kind, vname=vname, p=params: _vessel(
                kind, vname, p, ports
            )
        elif kind == "BloodVesselRC":
            kwargs = _arrays(_values(values, where, ("Rpd", "Cp")), ("Rpd", "Cp"))
            factories[vname] = lambda ports, vname=vname, kw=kwargs: _two_ports(
                BloodVesselRC, vname, kw, ports
            )
        elif kind == "ChamberSphere":
            p = _arrays(_values(values, where, SPHERE_PARAMETERS), SPHERE_PARAMETERS)
            factories[vname] = lambda ports, vname=vname, p=p: _two_ports(
                ChamberSphere, vname, {"p": p, "period": clock["period"]}, ports
            )
        else:
            raise UnsupportedModel(f"block type {kind!r} (vessel {vname}) is not supported")
        ends = v.get("boundary_conditions", {})
        if "inlet" in ends:
            connections.append((ends["inlet"], vname))
        if "outlet" in ends:
            connections.append((vname, ends["outlet"]))
    tables, heart_inlets = [], []
    for bc in config["boundary_conditions"]:
        bname, factory, bc_tables, feeds_heart = _boundary_condition(bc, clock)
        factories[bname] = factory
        tables += bc_tables
        if feeds_heart:
            heart_inlets.append(bname)
    period = _table_period(tables)
    for j in config.get("junctions", []):
        jname, kind = j["junction_name"], j.get("junction_type", "NORMAL_JUNCTION")
        if "inlet_vessels" in j and "outlet_vessels" in j:
            ins = [vessel_names[i] for i in j["inlet_vessels"]]
            outs = [vessel_names[i] for i in j["outlet_vessels"]]
        else:
            ins, outs = j["inlet_blocks"], j["outlet_blocks"]
        connections += [(i, jname) for i in ins] + [(jname, o) for o in outs]
        if kind == "NORMAL_JUNCTION":
            factories[jname] = lambda ports, jname=jname: Junction(
                jname, (*ports[0], *ports[1]), len(ports[0])
            )
        elif kind == "BloodVesselJunction":
            params = _values(
                j.get("junction_values", {}),
                f"{kind} {jname}",
                ("R_poiseuille", "L", "stenosis_coefficient"),
            )
            factories[jname] = lambda ports, jname=jname, p=params: _vessel_junction(
                jname, p, ports
            )
        else:
            raise UnsupportedModel(f"block type {kind!r} (junction {jname}) is not supported")
    for block in config.get("closed_loop_blocks") or []:
        period = _closed_loop(block, period, connections, factories, heart_inlets)
    for valve in config.get("valves") or []:
        vname, kind = valve["name"], valve["type"]
        numbers = {
            "ValveTanh": ("Rmax", "Rmin", "Steepness"),
            "PiecewiseValve": ("Rmax", "Rmin"),
            "ArctanValve": ("Rmax", "Rmin", "sharpness"),
            "SmoothValve": ("R", "smoothing"),
        }
        if kind not in numbers:
            raise UnsupportedModel(f"block type {kind!r} (valve {vname}) is not supported")
        ends = ("upstream_block", "downstream_block")
        p = _values(valve.get("params", {}), f"{kind} {vname}", (*numbers[kind], *ends))
        connections += [(p["upstream_block"], vname), (vname, p["downstream_block"])]
        kwargs = {k.lower() if k == "Steepness" else k: p[k] for k in numbers[kind]}
        if kind == "ArctanValve":  # cardiosoft's extension: Regazzoni's law
            law = ArctanValve(p["Rmin"], p["Rmax"], p["sharpness"])
            cls, kwargs = LawValve, {"law": law}
        elif kind == "SmoothValve":  # cardiosoft's extension: the open loops' valve law
            cls, kwargs = LawValve, {"law": Valve(p["R"], "smooth", p["smoothing"])}
        else:
            cls = ValveTanh if kind == "ValveTanh" else PiecewiseValve
            kwargs = _arrays(kwargs, kwargs)
        factories[vname] = lambda ports, vname=vname, kw=kwargs, cls=cls: _two_ports(
            cls, vname, kw, ports
        )
    chambers = config.get("chambers") or []

    sim = config["simulation_parameters"]
    given_period = sim.get("cardiac_period")
    if given_period is not None and period is not None and given_period != period:
        raise UnsupportedModel(
            f"inconsistent cardiac cycle period: {given_period:g} in simulation_parameters, "
            f"{period:g} in the model's blocks"
        )
    period = clock["period"] = float(period or given_period or 1.0)
    simulation = read_simulation(sim, config, period)
    if pump is not None:
        factories[pump.chamber] = _pump_factory(pump, chambers, config, float(period), simulation)
    pumps = []
    for chamber in chambers:
        if chamber.get("type") == "SoftPump":  # cardiosoft's extension block
            pumps.append(_placement(chamber))
            factories[pumps[-1].chamber] = _pump_factory(
                pumps[-1], chambers, config, float(period), simulation
            )
        elif pump is None or chamber["name"] != pump.chamber:
            factories[chamber["name"]] = _chamber(chamber, float(period))
    named = {x for c in connections for x in c}
    if named - set(factories):
        raise UnsupportedModel(
            f"connection to an unknown block {sorted(named - set(factories))[0]!r}"
        )

    def ports(name):
        inlets = tuple(i for i, (_, down) in enumerate(connections) if down == name)
        outlets = tuple(i for i, (up, _) in enumerate(connections) if up == name)
        return inlets, outlets

    blocks = [make(ports(block_name)) for block_name, make in factories.items()]
    rates = [k for k in config.get("initial_condition_d") or {} if not k.startswith("_")]
    blocks = _checked(join_coronaries, blocks, bool(rates) and not simulation.steady_initial)
    _check_march(blocks, simulation)
    network = Network(tuple(blocks), tuple(connections), float(period))
    initial = _initial(config.get("initial_condition", {}), variable_names(network))
    model = Model(network, simulation, initial, name or "model", tuple(pumps))
    try:
        network = reduce_index(network, model.initial_states())
        network = dataclasses.replace(network, order=stored_order(network, model.initial_states()))
    except ValueError as error:
        raise UnsupportedModel(f"{model.name}: {error}") from None
    return dataclasses.replace(model, network=network)


def _check_march(blocks, simulation: Simulation) -> None:
    """A steady start-up that must be marched (a chamber's activation keeps time in it,
    :func:`cardiosoft.network.scheme.marches`) is refused beside a block whose start-up is
    not reproduced step for step (:attr:`~cardiosoft.network.blocks.Block.marchable`)."""
    timed = [b for b in blocks if b.keeps_time]
    other = [b for b in blocks if not b.marchable]
    if simulation.steady_initial and timed and other:
        raise UnsupportedModel(
            f"{timed[0].kind} {timed[0].name} with steady_initial and the {other[0].kind} "
            f"{other[0].name}: svZeroDSolver marches the start-up through the chamber's "
            f"activation, and the {other[0].kind}'s start-up equations are not reproduced step "
            "for step; set steady_initial to false"
        )


def _chamber(chamber: dict, period: float):
    """The factory of a chamber with an activation (``create_chambers``)."""
    name, kind = chamber["name"], chamber["type"]
    if kind not in CHAMBER_PARAMETERS:
        raise UnsupportedModel(f"block type {kind!r} (chamber {name}) is not supported")
    p = _arrays(
        _values(chamber.get("values", {}), f"{kind} {name}", CHAMBER_PARAMETERS[kind]),
        CHAMBER_PARAMETERS[kind],
    )
    spec = dict(chamber.get("activation_function") or {})
    act = spec.pop("type", None)
    if act not in ACTIVATIONS:
        raise UnsupportedModel(
            f"{kind} {name}: activation_function type {act!r} is not one of "
            + ", ".join(ACTIVATIONS)
        )
    activation = Activation.build(
        act, _values(spec, f"{act} activation of {name}", ACTIVATIONS[act]), period
    )
    has_L = kind != "LinearElastanceChamber" and float(p["Impedance"]) != 0
    return lambda ports: _two_ports(
        Chamber, name, {"p": p, "activation": activation, "law": kind, "has_L": has_L}, ports
    )


def _placement(chamber: dict) -> PumpPlacement:
    """The pump of a ``SoftPump`` chamber entry (:mod:`cardiosoft.network.export`)."""
    fields = {f.name for f in dataclasses.fields(PumpPlacement)} - {"chamber"}
    values = {k: v for k, v in chamber.get("values", {}).items() if not k.startswith("_")}
    unknown = sorted(set(values) - fields)
    if unknown:
        raise UnsupportedModel(f"SoftPump {chamber['name']}: unknown parameter {unknown[0]!r}")
    return PumpPlacement(chamber["name"], **values)


def _pump_factory(pump: PumpPlacement, chambers, config: dict, period: float, simulation):
    """The factory of the soft pump in place of the chamber ``pump.chamber``; the pump is
    built (its design and the model's units checked) at once."""
    names = [c["name"] for c in chambers]
    if pump.chamber not in names:
        have = ", ".join(names) if names else "none"
        raise UnsupportedModel(
            f"--pump-chamber {pump.chamber}: the model has no such chamber (its chambers: {have})"
        )
    if simulation.steady_initial:
        raise UnsupportedModel(
            f"--pump-chamber {pump.chamber} with steady_initial: svZeroDSolver defines no steady "
            "start-up for the pump; set steady_initial to false"
        )
    start = float(config.get("initial_condition", {}).get(f"Vc:{pump.chamber}", 0.0))
    block = soft_pump(pump, (0, 0), period, start)

    def make(ports):
        ins, outs = ports
        if len(ins) > 1 or len(outs) != 1:
            raise UnsupportedModel(
                f"--pump-chamber {pump.chamber}: needs one outlet and at most one inlet"
            )
        return dataclasses.replace(block, ports=(*ins, outs[0]))

    return make


def _closed_loop(block: dict, period, connections, factories, heart_inlets):
    """svZeroDSolver's ``create_closed_loop``: the heart ``CLH`` between the junctions
    ``J_heart_inlet`` (fed by the closed-loop boundary conditions) and ``J_heart_outlet``.
    Returns the period, which the heart sets."""
    kind = block.get("closed_loop_type")
    if kind != "ClosedLoopHeartAndPulmonary":
        raise UnsupportedModel(f"block type {kind!r} (closed_loop_blocks) is not supported")
    if "CLH" in factories:
        raise UnsupportedModel("only one ClosedLoopHeartAndPulmonary can be included")
    heart_period = float(block["cardiac_cycle_period"])
    if period is not None and heart_period != period:
        raise UnsupportedModel(
            f"inconsistent cardiac cycle period: {heart_period:g} in "
            f"ClosedLoopHeartAndPulmonary, {period:g} in the time tables"
        )
    p = _arrays(
        _values(block.get("parameters", {}), f"{kind} CLH", HEART_PARAMETERS), HEART_PARAMETERS
    )
    connections.append(("J_heart_inlet", "CLH"))
    connections += [(bc, "J_heart_inlet") for bc in heart_inlets]
    connections.append(("CLH", "J_heart_outlet"))
    connections += [("J_heart_outlet", out) for out in block["outlet_blocks"]]
    factories["CLH"] = lambda ports: _two_ports(
        ClosedLoopHeart, "CLH", {"p": p, "period": heart_period}, ports
    )
    for junction in ("J_heart_inlet", "J_heart_outlet"):
        factories[junction] = lambda ports, junction=junction: Junction(
            junction, (*ports[0], *ports[1]), len(ports[0])
        )
    return heart_period


def run_svzerod(config: dict, refine: int = 1) -> dict:
    """svZeroDSolver's own answer to ``config`` (its ``svzerod`` package, in cardiosoft's
    ``[test]`` extra): every variable by name, at the model's output times, stepped with
    ``refine`` times as many points a beat (every ``refine``-th sample is kept); with the
    model's ``output_derivative``, each one's ``ydot`` too, as ``ydot:NAME`` (the names of
    :class:`~cardiosoft.network.run.Traces`). Always the samples: ``output_mean_only`` is set
    aside (its means are the samples' means, :meth:`~cardiosoft.network.run.Traces.means`).
    The peer that ``tests/test_network.py`` and ``benchmarks/svzerod_heart.py`` check
    against."""
    try:
        import svzerod
    except ImportError:
        raise ImportError(
            "run_svzerod needs svZeroDSolver's Python build: pip install svzerod "
            "(it comes with cardiosoft's [test] extra)"
        ) from None
    config = json.loads(json.dumps(config))
    sim = config["simulation_parameters"]
    sim["output_variable_based"] = True
    points = sim["number_of_time_pts_per_cardiac_cycle"]
    sim["number_of_time_pts_per_cardiac_cycle"] = (points - 1) * refine + 1
    sim["output_mean_only"] = False
    frame = svzerod.simulate(config)
    groups = frame.groupby("name", sort=False)
    values = {name: group["y"].to_numpy()[::refine] for name, group in groups}
    if sim.get("output_derivative"):
        values.update({f"ydot:{n}": group["ydot"].to_numpy()[::refine] for n, group in groups})
    return values


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
