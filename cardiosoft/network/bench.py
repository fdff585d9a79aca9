"""The open-loop scenes (the bench's water column, a Windkessel) as a network of blocks.

A :class:`~cardiosoft.circuit.PumpCircuit` evaluated as a :class:`~cardiosoft.network.network.
Network`: the same equations, the same states, in the semi-explicit block form of
:mod:`cardiosoft.network.blocks` (issue #40, "one network"). Its blocks, SI:

- :class:`ShellPump`: the soft pump with its shell's effects (cable slack, wall contact, the
  shell's viscoelasticity), the law of :meth:`PumpCircuit.pump_pressure`;
- :class:`AfterloadLine`: an afterload (:mod:`cardiosoft.circulation`: the water column behind
  the bench's tube, a Windkessel) with its inlet line and, optionally, the outlet valve;
- :class:`PreloadSource`: a preload (an atrial source or compliance), with the inlet valve a
  :class:`~cardiosoft.network.loop_blocks.LawValve` between it and the pump.

They are joined at one node (pump -> afterload), or three with a preload (preload -> inlet
valve -> pump -> afterload). The nodes are solved in an order found once per structure
(:func:`bench_order`, on a stand-in network): the pump's and the preload's pressures, then the
flows. Each evaluation is then the written-out field's work plus the order's bookkeeping.

:class:`BenchNetwork` answers what the batch solve asks of a circuit (``init``, the vector
field, ``signals``, ``power``, ``total_volume``, ...). Its states' rates and the pressures and
flows of its signals come from the network; the pull, the forces and the energy account's rates
are the circuit's own (:meth:`PumpCircuit.power`, which no block holds yet).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.circuit import PumpCircuit, line_acceleration, line_outflow
from cardiosoft.circulation import AbstractAfterload, AbstractPreload, WaterColumn, Windkessel3
from cardiosoft.network.blocks import Block
from cardiosoft.network.closed_loop import DEFAULT_ENGINE, ENGINES
from cardiosoft.network.loop_blocks import LawValve
from cardiosoft.network.network import Network
from cardiosoft.units import ml, mmHg, mmHg_s_per_ml
from cardiosoft.valves import Valve

__all__ = [
    "DEFAULT_ENGINE", "ENGINES", "AfterloadLine", "BenchNetwork", "PreloadSource", "ShellPump",
    "bench_order",
]  # fmt: skip


def _state_kind(key: str) -> str:
    """A state's scale by its name: ``pc``, ``pa`` are pressures, the rest volumes."""
    return "pressure" if key in ("pc", "pa") else "volume"


class ShellPump(Block):
    """The soft pump in its shell: ports (inlet,) outlet, both at the cavity's pressure.

    States: the cavity volume V (m^3) and, with the shell's viscoelasticity, the dashpot's
    volume s_v (m^3). ``dV/dt = Q_in - Q_out``; ``ds_v/dt`` as
    :meth:`~cardiosoft.circuit.ShellViscoelasticity.rate`. The pressure law is
    ``shell.pump_pressure`` (:meth:`~cardiosoft.circuit.PumpCircuit.pump_pressure`, which
    reads the pump's side of the circuit only), whose chamber law the dashpot's rate reads
    too (:meth:`shared_terms`)."""

    shell: PumpCircuit
    kind = "SoftPump"

    @property
    def n_states(self):
        return 1 + (self.shell.viscoelasticity is not None)

    def state_kinds(self):
        return ("volume",) * self.n_states

    def _state(self, x) -> dict:
        y = {"volume": x[0]}
        if self.shell.viscoelasticity is not None:
            y["relaxation"] = x[1]
        return y

    def shared_terms(self, t, x) -> dict:
        """The pump's side (:meth:`~cardiosoft.circuit.PumpCircuit.pump_pressure`): the
        cavity's pressure for the residuals, the chamber law for the dashpot's rate."""
        return self.shell.pump_pressure(t, self._state(x))

    def residuals(self, t, x, P, Q, steady=False, shared=None):
        pressure = (self.shared_terms(t, x) if shared is None else shared)["pump_pressure"]
        if len(self.ports) == 1:
            return jnp.stack([P[0] - pressure])
        return jnp.stack([P[0] - pressure, P[1] - P[0]])

    def rates(self, t, x, P, Q, steady=False, shared=None):
        inflow = Q[0] if len(self.ports) == 2 else 0.0
        rates = [inflow - Q[len(self.ports) - 1]]
        if self.shell.viscoelasticity is not None:
            chamber = (self.shared_terms(t, x) if shared is None else shared)["chamber"]
            rates.append(self.shell.viscoelasticity.rate(chamber, x[0], x[1]))
        return jnp.stack(rates)


class AfterloadLine(Block):
    """An afterload behind its inlet line: port (inlet,), at the pump's pressure.

    States: the afterload's own (``keys``, in its state's order) and, when the line has an
    inertance L, its flow q (m^3/s): ``L dq/dt = P_in - P_node - R q - K q|q|``
    (:func:`~cardiosoft.circuit.line_acceleration`). Without one the flow is algebraic: through
    the valve and R in series, or the root of ``R q + K q|q| = P_in - P_node``
    (:func:`~cardiosoft.circuit.line_outflow`), written as ``Q - q(P)``: affine in the flow."""

    afterload: AbstractAfterload
    valve: Valve | None
    keys: tuple[str, ...] = eqx.field(static=True)
    has_flow: bool = eqx.field(static=True)
    kind = "Afterload"
    nonlinear = True

    @property
    def n_states(self):
        return len(self.keys) + self.has_flow

    def state_kinds(self):
        return (*map(_state_kind, self.keys), *("flow",) * self.has_flow)

    def _state(self, x):
        return {k: x[i] for i, k in enumerate(self.keys)}

    def residuals(self, t, x, P, Q, steady=False):
        ya = self._state(x)
        if self.has_flow:
            return jnp.stack([Q[0] - x[len(self.keys)]])
        drop = P[0] - self.afterload.node_pressure(ya)
        return jnp.stack([Q[0] - line_outflow(self.afterload, self.valve, ya, drop)])

    def rates(self, t, x, P, Q, steady=False):
        ya = self._state(x)
        rhs = self.afterload.node_rhs(ya, Q[0])
        rates = [rhs[k] for k in self.keys]
        if self.has_flow:
            drop = P[0] - self.afterload.node_pressure(ya)
            rates.append(line_acceleration(self.afterload, ya, x[len(self.keys)], drop))
        return jnp.stack(rates)


class PreloadSource(Block):
    """A preload (:class:`~cardiosoft.circulation.AbstractPreload`): port (outlet,), at its
    pressure. States: its own (``keys``, in its state's order), driven by its outflow."""

    preload: AbstractPreload
    keys: tuple[str, ...] = eqx.field(static=True)
    kind = "Preload"

    @property
    def n_states(self):
        return len(self.keys)

    def state_kinds(self):
        return tuple(map(_state_kind, self.keys))

    def _state(self, x):
        return {k: x[i] for i, k in enumerate(self.keys)}

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([P[0] - self.preload.pressure(self._state(x))])

    def rates(self, t, x, P, Q, steady=False):
        rhs = self.preload.rhs(self._state(x), Q[0])
        return jnp.stack([rhs[k] for k in self.keys])


NODES = {
    False: (("pump", "afterload"),),
    True: (("preload", "inlet_valve"), ("inlet_valve", "pump"), ("pump", "afterload")),
}
"""The open loop's connections (upstream, downstream), without and with a preload."""


def _ports(nodes, name) -> tuple[int, ...]:
    ins = [i for i, (_, down) in enumerate(nodes) if down == name]
    return (*ins, *(i for i, (up, _) in enumerate(nodes) if up == name))


def _network(circuit, afterload_keys, preload_keys, has_flow, order=None) -> Network:
    """The blocks of ``circuit`` (a :class:`PumpCircuit`, or the stand-in's) joined at
    :data:`NODES`."""
    nodes = NODES[circuit.preload is not None]
    blocks = [
        ShellPump("pump", _ports(nodes, "pump"), circuit),
        AfterloadLine(
            "afterload",
            _ports(nodes, "afterload"),
            circuit.afterload,
            circuit.outlet_valve,
            afterload_keys,
            has_flow,
        ),
    ]
    if circuit.preload is not None:
        blocks += [
            PreloadSource("preload", _ports(nodes, "preload"), circuit.preload, preload_keys),
            LawValve("inlet_valve", _ports(nodes, "inlet_valve"), circuit.inlet_valve),
        ]
    return Network(tuple(blocks), nodes, 1.0, order=order)


class _StandInShell(eqx.Module):
    """A linear chamber (2 mmHg/ml about 50 ml) in place of the pump: the order depends on
    which unknowns each equation holds, not on the pump's law."""

    afterload: AbstractAfterload
    preload: AbstractPreload | None
    inlet_valve: Valve | None
    outlet_valve: Valve | None = None
    viscoelasticity: None = None

    def pump_pressure(self, t, y):
        return {"pump_pressure": 2.0 * mmHg / ml * (y["volume"] - 50.0 * ml)}


@functools.cache
def bench_order(has_preload: bool, has_flow: bool) -> tuple:
    """The solving order of an open loop's node equations. It depends on the wiring alone (the
    pump's and the preload's laws give pressures, the line and the valve flows), so it is found
    once per structure, on a stand-in (a linear chamber; the bench's column with its inertia,
    or a three-element Windkessel, its line a resistance; an atrial source of 10 mmHg), and
    serves every circuit of that structure (``tests/test_network_bench.py`` checks it against
    the dense Newton). A command keeps it in its store
    (:func:`~cardiosoft.network.ordering.stored_order`), as the closed loop's."""
    from cardiosoft.circulation import AtrialSource
    from cardiosoft.network.ordering import stored_order

    with jax.ensure_compile_time_eval():  # first asked for while a solve is being traced
        afterload = WaterColumn(0.02, 60.0 * mmHg) if has_flow else Windkessel3.systemic()
        preload = AtrialSource(10.0 * mmHg) if has_preload else None
        valve = Valve(0.005 * mmHg_s_per_ml) if has_preload else None
        shell = _StandInShell(afterload, preload, valve)
        keys = tuple(afterload.init())
        pre_keys = tuple(preload.init()) if has_preload else ()
        net = _network(shell, keys, pre_keys, has_flow)
        y_a = [1.0 * ml] * len(keys)
        x0 = np.asarray([60.0 * ml, *y_a, *[0.0] * has_flow, *[1.0 * ml] * len(pre_keys)])
        return stored_order(net, x0)


class BenchNetwork(eqx.Module):
    """A :class:`~cardiosoft.circuit.PumpCircuit` whose vector field is its network's (module
    docstring). The state is the circuit's dict; the energy account, when kept, is not a
    network state and comes from :meth:`PumpCircuit.power`."""

    circuit: PumpCircuit

    @property
    def actuation(self):
        return self.circuit.actuation

    @property
    def afterload(self):
        return self.circuit.afterload

    @property
    def preload(self):
        return self.circuit.preload

    @property
    def energy(self) -> bool:
        return self.circuit.energy

    def init(self) -> dict:
        return self.circuit.init()

    def total_volume(self, y) -> jax.Array:
        return self.circuit.total_volume(y)

    def stored_energy(self, t, y) -> jax.Array:
        return self.circuit.stored_energy(t, y)

    def power(self, t, y) -> dict:
        return self.circuit.power(t, y)

    def _keys(self, y) -> tuple[tuple[str, ...], tuple[str, ...]]:
        return tuple(y["afterload"]), tuple(y.get("preload", {}))

    def network(self, y, ordered: bool = True) -> Network:
        """The circuit's blocks for the state dict ``y``'s keys, their nodes solved in
        :func:`bench_order`'s order (``ordered``) or by one dense Newton."""
        keys, pre_keys = self._keys(y)
        c = self.circuit
        order = bench_order(c.preload is not None, c.has_flow_state) if ordered else None
        return _network(c, keys, pre_keys, c.has_flow_state, order)

    def flat_state(self, y) -> jax.Array:
        """The state dict as the network's state vector, block by block: the pump's volume
        (and dashpot), the afterload's states (and the line's flow), the preload's."""
        keys, pre_keys = self._keys(y)
        parts = [y["volume"]]
        if self.circuit.viscoelasticity is not None:
            parts.append(y["relaxation"])
        parts += [y["afterload"][k] for k in keys]
        if self.circuit.has_flow_state:
            parts.append(y["flow"])
        parts += [y["preload"][k] for k in pre_keys]
        return jnp.stack(parts)

    def state_tree(self, x, y) -> dict:
        """The inverse of :meth:`flat_state`, in the key order of the state dict ``y``."""
        keys, pre_keys = self._keys(y)
        out, i = {"volume": x[0]}, 1
        if self.circuit.viscoelasticity is not None:
            out["relaxation"], i = x[1], 2
        out["afterload"] = {k: x[i + j] for j, k in enumerate(keys)}
        i += len(keys)
        if self.circuit.has_flow_state:
            out["flow"], i = x[i], i + 1
        if pre_keys:
            out["preload"] = {k: x[i + j] for j, k in enumerate(pre_keys)}
        return {k: out[k] for k in y if k in out}

    def __call__(self, t, y, args=None) -> dict:
        x = self.flat_state(y)
        dy = self.state_tree(self.network(y).vector_field(t, x), y)
        if self.energy:
            dy["energy"] = self.circuit.power(t, y)
        return dy

    def signals(self, t, y) -> dict:
        """The circuit's signals, with the pump's and the preload's pressures and the flows
        taken from the network's nodes."""
        out = self.circuit.signals(t, y)
        net = self.network(y)
        z = net.node_values(t, self.flat_state(y))
        n, last = net.n_nodes, net.n_nodes - 1
        out["pump_pressure"], out["outflow"] = z[last], z[n + last]
        if self.preload is not None:
            out["preload_pressure"], out["inflow"] = z[0], z[n + 1]
        return out
