"""The closed circulation as one vector field: four chambers, four vessels, four valves.

The 12-state model of Regazzoni et al. 2022 (J. Comput. Phys. 457, 111083, section 2; the
notes' equations in ``notes/closed-loop-regazzoni.md``), in SI::

    V_LA' = Q_VEN_PUL - Q_MV        V_LV' = Q_MV - Q_AV
    V_RA' = Q_VEN_SYS - Q_TV        V_RV' = Q_TV - Q_PV
    C_AR_SYS p_AR_SYS' = Q_AV - Q_AR_SYS          L_AR_SYS Q_AR_SYS' = p_AR_SYS - p_VEN_SYS - R Q
    C_VEN_SYS p_VEN_SYS' = Q_AR_SYS - Q_VEN_SYS   L_VEN_SYS Q_VEN_SYS' = p_VEN_SYS - p_RA - R Q
    C_AR_PUL p_AR_PUL' = Q_PV - Q_AR_PUL          L_AR_PUL Q_AR_PUL' = p_AR_PUL - p_VEN_PUL - R Q
    C_VEN_PUL p_VEN_PUL' = Q_AR_PUL - Q_VEN_PUL   L_VEN_PUL Q_VEN_PUL' = p_VEN_PUL - p_LA - R Q

with the valve flows ``Q = valve(p_up - p_down)``: mitral LA -> LV, aortic LV -> AR_SYS,
tricuspid RA -> RV, pulmonary RV -> AR_PUL. Each chamber is an
:class:`~cardiosoft.network.loop_components.ElastanceChamber` or the soft pump, a
:class:`~cardiosoft.network.loop_components.PumpChamber`: a pump in place of a ventricle keeps the
rest of the
loop (filled from its atrium through the inlet valve, ejecting through the outlet valve into
the same arterial compartment).

State (a dict, SI)::

    {"la": {"volume"}, "lv": {"volume"}, "ra": {"volume"}, "rv": {"volume"},
     "ar_sys": {"pressure", "flow"}, "ven_sys": ..., "ar_pul": ..., "ven_pul": ...}

Blood volume is conserved: the chambers' volumes plus ``C p`` of each vessel
(:meth:`ClosedLoop.total_volume`).

With ``engine="network"`` the equations are solved as a
:class:`~cardiosoft.network.network.Network` of blocks: the
chambers (:class:`~cardiosoft.network.loop_blocks.LawChamber`), the vessels (svZeroDSolver's
``BloodVesselCRL``: the capacitor at the inlet, then R and L) and the valves
(:class:`~cardiosoft.network.loop_blocks.LawValve`), joined at twelve nodes. The nodes are solved
in the order :func:`~cardiosoft.network.ordering.order_nodes` finds once for this wiring
(:func:`loop_order`): each is one division, so a beat costs what the written-out field's does
(``benchmarks/engines.py``). It is the default (:data:`DEFAULT_ENGINE`): the closed loops run on
the engine that runs svZeroDSolver's models, which svZeroDSolver itself checks
(``tests/test_network.py``); ``engine="direct"`` keeps the equations written out, the second
implementation the network is tested against (``tests/test_network_loop.py``).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.network.blocks import BloodVessel
from cardiosoft.network.loop_blocks import LawChamber, LawValve
from cardiosoft.network.loop_components import (
    AbstractChamber,
    Activation,
    ElastanceChamber,
    PumpChamber,
    Vessel,
)
from cardiosoft.network.network import Network
from cardiosoft.units import ml, ml_per_mmHg, mmHg, mmHg_s2_per_ml, mmHg_s_per_ml
from cardiosoft.valves import ArctanValve, Valve

_E = mmHg / ml  # 1 mmHg/ml in Pa/m^3

__all__ = [
    "CHAMBERS",
    "DEFAULT_ENGINE",
    "ENGINES",
    "VALVES",
    "VESSELS",
    "ClosedLoop",
    "flat_state",
    "loop_order",
    "state_tree",
]

ENGINES = ("direct", "network")
"""How :class:`ClosedLoop` evaluates its equations (:attr:`ClosedLoop.engine`)."""
DEFAULT_ENGINE = "network"
"""The engine every scene runs on unless told otherwise: the closed loops
(:class:`ClosedLoop`) and the open ones (:func:`cardiosoft.batch.scene_circuit`). Measured
against the written-out fields (2026-12-07, 2 cores, ``benchmarks/README.md``): a compiled
shooting call of ``tah`` the same (0.18-0.23 against 0.20-0.26 s), a design question's first
run 3-10 % longer (soft-lv traced, tah compiled from the shipped programs); the main job with
its shipped programs the same within the machine's noise (cold 4.0-4.7 against 4.4-4.9 s,
warm 1.5-1.7 against 1.6-1.7 s), traced 0.3-0.6 s longer; each order found once a machine
(:func:`loop_order`, :func:`cardiosoft.network.bench.bench_order`)."""

CHAMBERS = ("la", "lv", "ra", "rv")
"""Left atrium, left ventricle, right atrium, right ventricle."""
VESSELS = ("ar_sys", "ven_sys", "ar_pul", "ven_pul")
"""Systemic arteries, systemic veins, pulmonary arteries, pulmonary veins."""
VALVES = {
    "mitral": ("la", "lv"),
    "aortic": ("lv", "ar_sys"),
    "tricuspid": ("ra", "rv"),
    "pulmonary": ("rv", "ar_pul"),
}
"""Each valve's upstream and downstream compartment."""
_VESSEL_PATH = {  # each vessel: (the valve or vessel that fills it, the compartment it drains to)
    "ar_sys": ("aortic", "ven_sys"),
    "ven_sys": ("ar_sys", "ra"),
    "ar_pul": ("pulmonary", "ven_pul"),
    "ven_pul": ("ar_pul", "la"),
}
_CHAMBER_PATH = {  # each chamber: (what fills it, the valve it empties through)
    "la": ("ven_pul", "mitral"),
    "lv": ("mitral", "aortic"),
    "ra": ("ven_sys", "tricuspid"),
    "rv": ("tricuspid", "pulmonary"),
}


class ClosedLoop(eqx.Module):
    """The closed circulation's vector field (module docstring).

    **Arguments:** the chambers ``la``, ``lv``, ``ra``, ``rv``
    (:class:`~cardiosoft.network.loop_components.AbstractChamber`: elastance chambers or pumps,
    one period for all); the vessels ``ar_sys``, ``ven_sys``, ``ar_pul``, ``ven_pul``
    (:class:`~cardiosoft.network.loop_components.Vessel`); the valves ``mitral``, ``aortic``,
    ``tricuspid``,
    ``pulmonary`` (:class:`~cardiosoft.valves.ArctanValve` or
    :class:`~cardiosoft.valves.Valve`).
    """

    la: AbstractChamber
    lv: AbstractChamber
    ra: AbstractChamber
    rv: AbstractChamber
    ar_sys: Vessel
    ven_sys: Vessel
    ar_pul: Vessel
    ven_pul: Vessel
    mitral: ArctanValve | Valve
    aortic: ArctanValve | Valve
    tricuspid: ArctanValve | Valve
    pulmonary: ArctanValve | Valve
    engine: str = eqx.field(static=True, default=DEFAULT_ENGINE)
    """``"network"`` (the default): the equations as a
    :class:`~cardiosoft.network.network.Network` of blocks (module docstring); ``"direct"``: the
    equations above written out. The two agree to round-off (``tests/test_network_loop.py``)."""

    def __check_init__(self):
        if self.engine not in ENGINES:
            raise ValueError(f"engine {self.engine!r} is not one of {', '.join(ENGINES)}")
        periods = [getattr(self, c).period for c in CHAMBERS]
        if not any(isinstance(p, jax.core.Tracer) for p in periods):
            values = np.asarray(periods, dtype=float)
            if not np.allclose(values, values[0], rtol=1e-12, atol=0.0):
                raise ValueError(
                    f"chamber periods = {', '.join(f'{v:g}' for v in values)} s: the four "
                    "chambers of a closed loop beat at one rate"
                )

    @property
    def period(self) -> jax.Array:
        """The beat period T (s)."""
        return self.lv.period

    @property
    def pumps(self) -> tuple[str, ...]:
        """The chambers that are soft pumps (static)."""
        return tuple(c for c in CHAMBERS if isinstance(getattr(self, c), PumpChamber))

    def init(self) -> dict:
        """The state at t = 0: the native chambers' and vessels' initial values; a pump filled
        at its filling chamber's pressure at t = 0 (its atrium's), at its pull at t = 0."""
        y = {v: getattr(self, v).init() for v in VESSELS}
        for c in ("la", "ra", "lv", "rv"):  # the atria first: they fill the ventricles
            chamber = getattr(self, c)
            upstream = {"lv": "la", "rv": "ra"}.get(c)
            fill = 0.0 if upstream is None else self._pressure(upstream, 0.0, y)
            y[c] = {"volume": chamber.start_volume(fill)}
        return {k: y[k] for k in (*CHAMBERS, *VESSELS)}

    def _pressure(self, name, t, y) -> jax.Array:
        if name in VESSELS:
            return y[name]["pressure"]
        return getattr(self, name).pressure(t, y[name]["volume"])

    def network(self, order: tuple | None = None) -> Network:
        """The loop as blocks joined at :data:`NODES`, its nodes solved in ``order``
        (:func:`loop_order`), or by one dense Newton when None."""

        def ports(name):
            ins = [i for i, (_, down) in enumerate(NODES) if down == name]
            return (*ins, *(i for i, (up, _) in enumerate(NODES) if up == name))

        blocks = [LawChamber(c, ports(c), getattr(self, c)) for c in CHAMBERS]
        for v in VESSELS:
            vessel = getattr(self, v)
            R, C, L = vessel.resistance, vessel.compliance, vessel.inertance
            S = jnp.zeros_like(R)
            blocks.append(BloodVessel(v, ports(v), R, C, L, S, True, True, False, False))
        blocks += [LawValve(k, ports(k), getattr(self, k)) for k in VALVES]
        return Network(tuple(blocks), NODES, 1.0, order=order)

    def _flows(self, t, y) -> tuple[dict, dict]:
        """(pressures, flows) at time t (SI): each compartment's pressure, each valve's and
        vessel's flow."""
        if self.engine == "network":
            net = self.network(loop_order())
            z = net.node_values(t, flat_state(y))
            # a compartment's pressure is its inlet node's; a valve's or vessel's flow its outlet's
            pressures = {down: z[i] for i, (_, down) in enumerate(NODES) if down not in VALVES}
            n = net.n_nodes
            flows = {up: z[n + i] for i, (up, _) in enumerate(NODES) if up not in CHAMBERS}
            return pressures, flows
        pressures = {name: self._pressure(name, t, y) for name in (*CHAMBERS, *VESSELS)}
        flows = {
            valve: getattr(self, valve).flow(pressures[up] - pressures[down])
            for valve, (up, down) in VALVES.items()
        }
        return pressures, flows | {v: y[v]["flow"] for v in VESSELS}

    def __call__(self, t, y, args=None) -> dict:
        if self.engine == "network":
            return state_tree(self.network(loop_order()).vector_field(t, flat_state(y)))
        pressures, flows = self._flows(t, y)
        dy = {
            c: {"volume": flows[fill] - flows[empty]} for c, (fill, empty) in _CHAMBER_PATH.items()
        }
        for v, (fill, drain) in _VESSEL_PATH.items():
            dy[v] = getattr(self, v).rhs(y[v], flows[fill], pressures[drain])
        return {k: dy[k] for k in (*CHAMBERS, *VESSELS)}

    def signals(self, t, y) -> dict:
        """Everything observable at time t (SI), by name: ``{c}_pressure`` and ``{c}_volume``
        of every chamber and vessel (a vessel's volume is ``C p``), ``{v}_flow`` through every
        valve and vessel, and for each pump ``{c}_pull`` (m) and ``{c}_cable_force`` (N)."""
        pressures, flows = self._flows(t, y)
        out = {f"{k}_pressure": pressures[k] for k in (*CHAMBERS, *VESSELS)}
        out |= {f"{c}_volume": y[c]["volume"] for c in CHAMBERS}
        out |= {f"{v}_volume": getattr(self, v).volume(y[v]) for v in VESSELS}
        out |= {f"{k}_flow": flows[k] for k in (*VALVES, *VESSELS)}
        for c in self.pumps:
            chamber = getattr(self, c)
            out |= {f"{c}_{k}": s for k, s in chamber.observe(t, y[c]["volume"]).items()}
        return out

    def total_volume(self, y) -> jax.Array:
        """Blood volume (m^3): the chambers' volumes plus ``C p`` of each vessel; conserved."""
        chambers = sum(y[c]["volume"] for c in CHAMBERS)
        return chambers + sum(getattr(self, v).volume(y[v]) for v in VESSELS)

    def kink_times(self) -> jax.Array:
        """Kinks of the forcing within one beat (s), sorted, from 0 to the period: every
        chamber's activation or pull phase boundaries (pass as ``jump_ts``)."""
        phases = [getattr(self, c).kink_phases() for c in CHAMBERS]
        ends = jnp.asarray([0.0, 1.0], dtype=jnp.result_type(float))
        return jnp.sort(jnp.concatenate([ends, *phases])) * self.period


NODES = (
    ("ven_pul", "la"), ("la", "mitral"), ("mitral", "lv"), ("lv", "aortic"),
    ("aortic", "ar_sys"), ("ar_sys", "ven_sys"), ("ven_sys", "ra"), ("ra", "tricuspid"),
    ("tricuspid", "rv"), ("rv", "pulmonary"), ("pulmonary", "ar_pul"), ("ar_pul", "ven_pul"),
)  # fmt: skip
"""The loop's connections (upstream, downstream), around from the pulmonary veins."""


def flat_state(y) -> jax.Array:
    """The state dict as the network's state vector: the chambers' volumes, then each
    vessel's pressure and flow."""
    vessels = [jnp.stack([y[v]["pressure"], y[v]["flow"]]) for v in VESSELS]
    return jnp.concatenate([jnp.stack([y[c]["volume"] for c in CHAMBERS]), *vessels])


def state_tree(x) -> dict:
    """The inverse of :func:`flat_state`."""
    out = {c: {"volume": x[i]} for i, c in enumerate(CHAMBERS)}
    for j, v in enumerate(VESSELS):
        out[v] = {"pressure": x[4 + 2 * j], "flow": x[5 + 2 * j]}
    return {k: out[k] for k in (*CHAMBERS, *VESSELS)}


@functools.cache
def loop_order() -> tuple:
    """The solving order of the loop's node equations. It depends on the wiring alone (every
    chamber law gives the pressure of its two nodes, every valve law the flow through it), so
    it is found once, on a stand-in loop (elastance chambers and arctan valves at
    physiological values), and serves every closed loop: pumps and the smooth valve law have
    the same equations' structure (``tests/test_network_loop.py`` checks ``tah``'s). A
    command keeps it in its store (:func:`~cardiosoft.network.ordering.stored_order`): finding
    it takes 1-2 s, once a machine."""
    from cardiosoft.network.ordering import stored_order

    with jax.ensure_compile_time_eval():  # first asked for while a solve is being traced
        x0 = np.asarray([100.0 * ml] * 4 + [20.0 * mmHg, 0.0] * 4)  # the stand-in's start
        return stored_order(_stand_in().network(), x0)


def _stand_in() -> ClosedLoop:
    """A closed loop with concrete values: each chamber 2 mmHg/ml active, 0.1 passive, 5 ml
    unstressed, 100 ml at the start; each vessel 0.1 mmHg s/ml, 1 ml/mmHg, 1e-3 mmHg s^2/ml,
    at 20 mmHg; the published valves (0.0075 and 75006.2 mmHg s/ml)."""
    activation = Activation(1.0, 0.0, 0.3, 0.2)
    chamber = ElastanceChamber(2.0 * _E, 0.1 * _E, 5.0 * ml, activation, 100.0 * ml)
    vessel = Vessel(0.1 * mmHg_s_per_ml, ml_per_mmHg, 1e-3 * mmHg_s2_per_ml, 20.0 * mmHg)
    valve = ArctanValve(0.0075 * mmHg_s_per_ml, 75006.2 * mmHg_s_per_ml)
    return ClosedLoop(
        **dict.fromkeys(CHAMBERS, chamber),
        **dict.fromkeys(VESSELS, vessel),
        **dict.fromkeys(VALVES, valve),
    )
