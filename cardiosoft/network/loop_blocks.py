"""cardiosoft's own blocks of the closed loop, in the semi-explicit form of
:mod:`cardiosoft.network.blocks`: a chamber whose pressure law is the soft pump's or a native
elastance chamber's, and a valve whose flow law is the scene's (SI, as the laws are).
"""

from __future__ import annotations

import jax.numpy as jnp

from cardiosoft.network.blocks import Block
from cardiosoft.network.loop_components import AbstractChamber
from cardiosoft.valves import ArctanValve, Valve


class LawChamber(Block):
    """A chamber with the pressure law ``law.pressure(t, V)``
    (:class:`~cardiosoft.network.loop_components.AbstractChamber`: the soft pump at its pull,
    or a time-varying elastance). Ports: inlet, outlet, both at the chamber's pressure. State:
    the volume V (m^3), ``dV/dt = Q_in - Q_out``."""

    law: AbstractChamber
    kind = "Chamber"
    n_states = 1

    def state_kinds(self):
        return ("volume",)

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([P[0] - self.law.pressure(t, x[0]), P[1] - P[0]])

    def rates(self, t, x, P, Q, steady=False):
        return jnp.stack([Q[0] - Q[1]])


class LawValve(Block):
    """A valve with the flow law ``law.flow(P_in - P_out)`` (:class:`~cardiosoft.valves.
    ArctanValve` or :class:`~cardiosoft.valves.Valve`). Ports: inlet, outlet; no state. Its
    equations are affine in the flow at given pressures, so a network that sets the pressures
    first solves them in one step (:mod:`cardiosoft.network.ordering`)."""

    law: ArctanValve | Valve
    kind = "Valve"
    nonlinear = True

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([Q[0] - self.law.flow(P[0] - P[1]), Q[1] - Q[0]])
