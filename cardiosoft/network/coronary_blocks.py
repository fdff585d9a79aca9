"""svZeroDSolver's coronary boundary conditions, in the semi-explicit form of
:mod:`cardiosoft.network.blocks`.

The circuit (Kim et al. 2010, as upstream draws it): from the inlet, a small-artery resistance
``Ra`` to a capacitor ``Ca`` to ground (pressure ``P_a``), a microvascular resistance ``Ram``
to the intramyocardial capacitor ``Cim`` (pressure ``P_cim`` on one plate, the
intramyocardial pressure ``Pim`` on the other; its charge is the intramyocardial volume
``V_im``), then a venous resistance ``Rv`` to the venous pressure. With ``Q_am`` the flow
through ``Ram``:

    P_in - Ra Q_in = P_a,      Ca dP_a/dt = Q_in - Q_am,      P_a - P_cim = Ram Q_am,
    dV_im/dt = Q_am - Q_v,     P_cim - P_venous = Rv Q_v.

- ``CORONARY`` and ``CORONARY_VAR_RES`` (``OpenLoopCoronaryBC.cpp``,
  ``OpenLoopCoronaryVarResBC.cpp``): one port; the venous pressure is ``P_v``; ``V_im`` counts
  from the start: ``V_im = Cim (P_cim - Pim(t)) - Cim (P_Cim_0 - Pim_0)``, with upstream's
  start-up offsets (``setup_initial_state_dependent_params``) ``Pim_0`` the value of ``Pim``
  then and ``P_Cim_0 = P_a - Ram(0) (Q_in - Ca dP_a/dt)`` at the start state.
- ``ClosedLoopCoronaryLeft``/``Right`` (``ClosedLoopCoronaryBC.cpp``): two ports, the outlet's
  pressure is the venous one (the heart's inlet junction); ``V_im = Cim (P_cim - Pim)`` with
  ``Pim = iml P_LV`` (left) or ``imr P_RV`` (right) of the ``ClosedLoopHeartAndPulmonary``
  block ``CLH``. A block sees only its own states, so the coronaries and the heart are one
  block here, :class:`HeartAndCoronaries` (:func:`join_coronaries`).

Units are the model's own (pressure, flow, volume, time: e.g. dyn/cm^2, ml/s, ml, s).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from cardiosoft.network.blocks import Block, TimeTable
from cardiosoft.network.heart_blocks import ClosedLoopHeart

OPEN_LOOP_CORONARY = {
    "CORONARY": ("Ra1", "Rv1", "Ca", "Cc", "Pim", "P_v", "Ra2"),
    "CORONARY_VAR_RES": (
        "Ra1", "Rv1", "Ca", "Cc", "Pim", "P_v", "Ra2_min", "Ra2_max", "T_vc", "T_vr",
    ),
}  # fmt: skip
"""svZeroDSolver's parameters of the open-loop coronaries (all required; ``Pim`` a time table
with ``t``; ``closed_loop_outlet`` is accepted and, as upstream, unused). ``Ra1`` is Ra,
``Ra2`` Ram, ``Rv1`` Rv, ``Cc`` Cim."""
CLOSED_LOOP_CORONARY = {"ClosedLoopCoronaryLeft": "LV", "ClosedLoopCoronaryRight": "RV"}
"""svZeroDSolver's closed-loop coronaries and the ventricle whose pressure is their ``Pim``."""
CORONARIES = {
    **OPEN_LOOP_CORONARY,
    **dict.fromkeys(CLOSED_LOOP_CORONARY, ("Ra", "Ram", "Rv", "Ca", "Cim")),
}
"""Every coronary type and its parameters."""


def _check(where: str, values: dict, positive=(), nonnegative=(), real=()) -> None:
    """Raise ValueError naming the first parameter that is not a number in its range."""
    for key in (*positive, *nonnegative, *real):
        value = values[key]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{where}: parameter {key!r} must be a number, not {value!r}")
        if key in real:
            continue
        if value < 0 or (value == 0 and key in positive):
            bound = "> 0" if key in positive else ">= 0"
            raise ValueError(f"{where}: parameter {key!r} = {value:g} must be {bound}")


class ConstantResistance(eqx.Module):
    """``CORONARY``'s microvascular resistance: the constant ``Ra2``."""

    R: jnp.ndarray = eqx.field(converter=jnp.asarray)
    kind = "CORONARY"

    def __call__(self, t):
        return self.R


class CyclicResistance(eqx.Module):
    """``CORONARY_VAR_RES``'s microvascular resistance (``OpenLoopCoronaryVarResBC::get_Ram``):
    ``sqrt(Ram) = sqrt(Ra2_min) + (sqrt(Ra2_max) - sqrt(Ra2_min)) e(t)``, with ``e`` rising as
    ``(1 - cos(pi t / T_vc)) / 2`` over ``T_vc``, falling as ``(1 + cos(pi (t - T_vc) / T_vr))
    / 2`` over ``T_vr``, then 0, with ``t`` folded into the model's period (static)."""

    R_min: jnp.ndarray = eqx.field(converter=jnp.asarray)
    R_max: jnp.ndarray = eqx.field(converter=jnp.asarray)
    T_vc: jnp.ndarray = eqx.field(converter=jnp.asarray)
    T_vr: jnp.ndarray = eqx.field(converter=jnp.asarray)
    period: float = eqx.field(static=True)
    kind = "CORONARY_VAR_RES"

    def __call__(self, t):
        tau = jnp.fmod(t, self.period)
        rising = 0.5 * (1.0 - jnp.cos(jnp.pi * tau / self.T_vc))
        falling = 0.5 * (1.0 + jnp.cos(jnp.pi * (tau - self.T_vc) / self.T_vr))
        e = jnp.where(
            tau <= self.T_vc, rising, jnp.where(tau <= self.T_vc + self.T_vr, falling, 0.0)
        )
        low, high = jnp.sqrt(self.R_min), jnp.sqrt(self.R_max)
        return (low + (high - low) * e) ** 2


class OpenLoopCoronary(Block):
    """svZeroDSolver's ``CORONARY`` and ``CORONARY_VAR_RES`` boundary conditions (see the
    module). One port. States: ``P_a`` (pressure), ``V_im`` (``volume_im:NAME``) and the
    start-up offset ``P_Cim_0 - Pim_0`` (pressure, constant in time), so that
    ``P_cim = V_im / Cim + Pim(t) + P_Cim_0 - Pim_0``.

    The steady start-up (upstream's ``steady`` equations, ``P_in = (Ra + Ram(0) + Rv) Q_in +
    P_v`` and ``V_im = 0``, with ``Pim`` the mean of its samples) fixes the offset at its
    steady state, where ``dP_a/dt = 0``: ``P_Cim_0 - Pim_0 = P_a - Ram(0) Q_in - mean(Pim)``.
    A start from ``initial_condition`` fixes it there, with ``Pim(0)`` and ``dP_a/dt = 0``
    (upstream's rates there are ``initial_condition_d``'s, refused with such a start).
    """

    Ra: jnp.ndarray
    Rv: jnp.ndarray
    Ca: jnp.ndarray
    Cim: jnp.ndarray
    Pim: TimeTable
    Pv: jnp.ndarray
    Ram: ConstantResistance | CyclicResistance
    vessel = True
    n_states = 3
    marchable = False

    @property
    def kind(self):
        return self.Ram.kind

    def state_kinds(self):
        return ("pressure", "volume", "pressure")

    def internal_names(self):
        return (f"volume_im:{self.name}",)

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([P[0] - self.Ra * Q[0] - x[0]])

    def rates(self, t, x, P, Q, steady=False):
        if steady:  # rates that vanish where upstream's steady equations hold
            R0 = self.Ram(0.0)
            return jnp.stack(
                [
                    (Q[0] - (x[0] - self.Pv) / (R0 + self.Rv)) / self.Ca,
                    -x[1] / (self.Cim * self.Rv),
                    x[0] - R0 * Q[0] - self.Pim(t, True) - x[2],
                ]
            )
        p_cim = x[1] / self.Cim + self.Pim(t) + x[2]
        q_am = (x[0] - p_cim) / self.Ram(t)
        outflow = (p_cim - self.Pv) / self.Rv
        return jnp.stack([(Q[0] - q_am) / self.Ca, q_am - outflow, jnp.zeros_like(q_am)])

    def states_from(self, values):
        p_in, q_in = values["P"][0], values["Q"][0]
        p_a = p_in - float(self.Ra) * q_in
        offset = p_a - float(self.Ram(0.0)) * q_in - float(self.Pim(0.0))
        return [p_a, values[f"volume_im:{self.name}"], offset]

    def outputs(self, t, x, P, Q):
        return {f"volume_im:{self.name}": x[1]}


def open_loop_coronary(kind: str, name: str, p: dict, ports, period: float) -> OpenLoopCoronary:
    """The block of a ``CORONARY`` or ``CORONARY_VAR_RES`` entry: ``p`` its parameters (``Pim``
    a :class:`TimeTable`), ``ports`` its (inlet, outlet) node indices, ``period`` the model's.
    Raises ValueError (naming the block) for a wiring or a value it cannot take."""
    where = f"{kind} {name}"
    nodes = (*ports[0], *ports[1])
    if len(nodes) != 1:
        raise ValueError(f"{where}: connected to {len(nodes)} blocks, not 1")
    if kind == "CORONARY":
        _check(where, p, ("Ra2", "Rv1", "Ca", "Cc"), ("Ra1",))
        Ram = ConstantResistance(float(p["Ra2"]))
    else:
        _check(where, p, ("Ra2_min", "Ra2_max", "T_vc", "T_vr", "Rv1", "Ca", "Cc"), ("Ra1",))
        values = (float(p[k]) for k in ("Ra2_min", "Ra2_max", "T_vc", "T_vr"))
        Ram = CyclicResistance(*values, period=float(period))
    _check(where, p, real=("P_v",))
    R = {k: jnp.asarray(float(p[k])) for k in ("Ra1", "Rv1", "Ca", "Cc", "P_v")}
    return OpenLoopCoronary(
        name, nodes, R["Ra1"], R["Rv1"], R["Ca"], R["Cc"], p["Pim"], R["P_v"], Ram
    )


class ClosedLoopCoronary(eqx.Module):
    """svZeroDSolver's ``ClosedLoopCoronaryLeft``/``Right`` (see the module): not a block of its
    own, its ``Pim`` being the heart's ventricle pressure; :class:`HeartAndCoronaries` holds
    it. Ports: inlet, outlet (the heart's inlet junction). States: ``P_a`` and ``V_im``.
    Residuals ``P_in - Ra Q_in - P_a`` and ``P_out + Rv Q_out - V_im / Cim - Pim``."""

    name: str = eqx.field(static=True)
    ports: tuple[int, ...] = eqx.field(static=True)
    Ra: jnp.ndarray
    Ram: jnp.ndarray
    Rv: jnp.ndarray
    Ca: jnp.ndarray
    Cim: jnp.ndarray
    ventricle: str = eqx.field(static=True)
    """``"LV"`` (``Pim = iml P_LV``) or ``"RV"`` (``Pim = imr P_RV``)."""
    n_states = 2

    @property
    def kind(self):
        return "ClosedLoopCoronaryLeft" if self.ventricle == "LV" else "ClosedLoopCoronaryRight"

    def pim(self, heart: ClosedLoopHeart, pressures: dict):
        scale = heart.p["iml"] if self.ventricle == "LV" else heart.p["imr"]
        return scale * pressures[self.ventricle]

    def residuals(self, x, P, Q, pim):
        return jnp.stack(
            [P[0] - self.Ra * Q[0] - x[0], P[1] + self.Rv * Q[1] - x[1] / self.Cim - pim]
        )

    def rates(self, x, P, Q, pim):
        q_am = (x[0] - x[1] / self.Cim - pim) / self.Ram
        return jnp.stack([(Q[0] - q_am) / self.Ca, q_am - Q[1]])

    def states_from(self, values):
        return [values["P"][0] - float(self.Ra) * values["Q"][0], values[f"volume_im:{self.name}"]]


def closed_loop_coronary(kind: str, name: str, p: dict, ports) -> ClosedLoopCoronary:
    """The coronary of a ``ClosedLoopCoronaryLeft``/``Right`` entry; ``ports``: its (inlet,
    outlet) node indices. Raises ValueError (naming it) for a wiring or a value it cannot
    take."""
    where = f"{kind} {name}"
    ins, outs = ports
    if len(outs) != 1:  # upstream's coronaries look the heart up, and flow into its inlet
        raise ValueError(
            f"{where}: needs the ClosedLoopHeartAndPulmonary block (closed_loop_blocks), "
            "whose inlet junction is its outlet and whose ventricle pressure its Pim"
        )
    if len(ins) != 1:
        raise ValueError(f"{where}: needs one inlet connection, has {len(ins)}")
    _check(where, p, ("Ram", "Rv", "Ca", "Cim"), ("Ra",))
    R = {k: jnp.asarray(float(p[k])) for k in CORONARIES[kind]}
    return ClosedLoopCoronary(name, (ins[0], outs[0]), **R, ventricle=CLOSED_LOOP_CORONARY[kind])


class HeartAndCoronaries(Block):
    """The ``ClosedLoopHeartAndPulmonary`` block ``CLH`` with the closed-loop coronaries that
    read its ventricles' pressures. Ports: the heart's two, then each coronary's two. States:
    the heart's, then each coronary's."""

    heart: ClosedLoopHeart
    coronaries: tuple[ClosedLoopCoronary, ...]
    kind = "ClosedLoopHeartAndPulmonary"
    marchable = False

    @property
    def n_states(self):
        return self.heart.n_states + sum(c.n_states for c in self.coronaries)

    def state_kinds(self):
        return (*self.heart.state_kinds(), *(("pressure", "volume") * len(self.coronaries)))

    def chamber_volumes(self):
        return self.heart.chamber_volumes()

    def internal_names(self):
        return (*self.heart.internal_names(), *(f"volume_im:{c.name}" for c in self.coronaries))

    def _parts(self, t, x, P, Q):
        """The heart's (x, P, Q), and per coronary (coronary, x, P, Q, Pim)."""
        h = self.heart.n_states
        heart = (x[:h], P[:2], Q[:2])
        _, pressures, _ = self.heart._chambers(t, heart[0], heart[1])
        parts = []
        for i, c in enumerate(self.coronaries):
            s, n = slice(h + 2 * i, h + 2 * i + 2), slice(2 + 2 * i, 4 + 2 * i)
            parts.append((c, x[s], P[n], Q[n], c.pim(self.heart, pressures)))
        return heart, parts

    def residuals(self, t, x, P, Q, steady=False):
        heart, parts = self._parts(t, x, P, Q)
        own = [c.residuals(xc, Pc, Qc, pim) for c, xc, Pc, Qc, pim in parts]
        return jnp.concatenate([self.heart.residuals(t, *heart, steady), *own])

    def rates(self, t, x, P, Q, steady=False):
        heart, parts = self._parts(t, x, P, Q)
        own = [c.rates(xc, Pc, Qc, pim) for c, xc, Pc, Qc, pim in parts]
        return jnp.concatenate([self.heart.rates(t, *heart, steady), *own])

    def states_from(self, values):
        out = self.heart.states_from({**values, "P": values["P"][:2], "Q": values["Q"][:2]})
        for i, c in enumerate(self.coronaries):
            n = slice(2 + 2 * i, 4 + 2 * i)
            out += c.states_from({**values, "P": values["P"][n], "Q": values["Q"][n]})
        return out

    def outputs(self, t, x, P, Q):
        heart, parts = self._parts(t, x, P, Q)
        out = self.heart.outputs(t, *heart)
        out.update({f"volume_im:{c.name}": xc[1] for c, xc, *_ in parts})
        return out


def coronary(kind: str, name: str, p: dict, ports, clock: dict):
    """The block (open loop) or the part of the heart block (closed loop) of a coronary entry
    of type ``kind``: ``p`` its parameters, ``ports`` its (inlet, outlet) node indices,
    ``clock["period"]`` the model's period."""
    if kind in OPEN_LOOP_CORONARY:
        return open_loop_coronary(kind, name, p, ports, clock["period"])
    return closed_loop_coronary(kind, name, p, ports)


def join_coronaries(blocks: list, start_rates: bool = False) -> list:
    """``blocks`` with the closed-loop coronaries moved into the heart ``CLH`` (one
    :class:`HeartAndCoronaries` in the heart's place; a coronary has its outlet only where
    the heart is, :func:`closed_loop_coronary`). Raises ValueError for an open-loop coronary
    with ``start_rates`` (a start from ``initial_condition`` with
    ``initial_condition_d``: upstream's offset ``P_Cim_0`` would take ``dP_a/dt`` from them;
    the states here have no given rates)."""
    for b in blocks:
        if start_rates and isinstance(b, OpenLoopCoronary):
            raise ValueError(
                f"{b.kind} {b.name} with initial_condition_d and no steady_initial: its "
                "start-up offset from the given rates is not supported"
            )
    coronaries = tuple(b for b in blocks if isinstance(b, ClosedLoopCoronary))
    if not coronaries:
        return blocks
    hearts = [i for i, b in enumerate(blocks) if isinstance(b, ClosedLoopHeart)]
    heart = blocks[hearts[0]]
    ports = heart.ports + tuple(p for c in coronaries for p in c.ports)
    joined = HeartAndCoronaries(heart.name, ports, heart, coronaries)
    return [
        joined if i == hearts[0] else b
        for i, b in enumerate(blocks)
        if not isinstance(b, ClosedLoopCoronary)
    ]
