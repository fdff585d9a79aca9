"""The blocks of a network, each in semi-explicit form: its states, and its equations on the nodes.

A node is one connection between two blocks and carries two unknowns, a pressure and a flow
(positive from the upstream block to the downstream one), as in svZeroDSolver. A block declares

- ``ports``: the nodes it touches, inlets first (static indices into the network's nodes);
- ``n_states``: its own states ``x`` (a capacitor's pressure, an inductor's flow, a volume);
- ``residuals(t, x, P, Q, steady)``: its algebraic equations on the nodes' pressures ``P`` and
  flows ``Q`` (one array each, in ``ports`` order), which must vanish;
- ``rates(t, x, P, Q, steady)``: the time derivatives of its states;
- ``states_from(values)``: its states from svZeroDSolver's initial condition (a dict of the
  block's own variables by svZeroDSolver name, see :meth:`Block.variables`);
- ``outputs(t, x, P, Q)``: its internal variables under their svZeroDSolver names.

Each block writes the same equations as svZeroDSolver's block of that type (``src/model/*.cpp``
in ``SimVascular/svZeroDSolver``): the number of its residuals equals svZeroDSolver's number of
equations for it less the internal variables it turns into states. Which elements a block has
(a capacitor, an inductor, a stenosis) is its structure and is fixed when it is read: a zero
capacitance is no capacitor, and its equation is algebraic. Parameters are array leaves.

``steady`` (static) gives the equations of svZeroDSolver's steady start-up: time tables are
replaced by the mean of their samples (``Parameter::to_steady``).

Units are the model's own: svZeroDSolver files carry none (see :mod:`cardiosoft.network`).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp


class TimeTable(eqx.Module):
    """A periodic piecewise-linear table, as svZeroDSolver's ``Parameter::get``.

    Time is folded with ``fmod(t, period)`` (not relative to the first sample), the period is
    ``times[-1] - times[0]``, and outside the samples the first or last segment is extended.
    A table of one sample is a constant.
    """

    times: jnp.ndarray
    values: jnp.ndarray

    def __init__(self, times, values):
        self.times = jnp.asarray(times, dtype=float)
        self.values = jnp.asarray(values, dtype=float)

    @property
    def period(self):
        return self.times[-1] - self.times[0]

    def __call__(self, t, steady: bool = False):
        if steady or self.values.shape[0] == 1:
            # svZeroDSolver's steady value: the mean of the samples, both ends included
            return jnp.mean(self.values)
        tau = jnp.fmod(t, self.period)
        k = jnp.clip(jnp.searchsorted(self.times, tau), 1, self.times.shape[0] - 1)
        t0, t1 = self.times[k - 1], self.times[k]
        v0, v1 = self.values[k - 1], self.values[k]
        return v0 + (v1 - v0) / (t1 - t0) * (tau - t0)


def _none(x):
    return jnp.zeros((0,), dtype=x.dtype)


class Block(eqx.Module):
    """What every block has: its name (as in the file) and its nodes (static)."""

    name: str = eqx.field(static=True)
    ports: tuple[int, ...] = eqx.field(static=True)

    n_states = 0
    nonlinear = False
    """Whether its residuals are nonlinear in the nodes' unknowns (then Newton solves them)."""
    kind = ""
    """svZeroDSolver's type name of the block, for messages and the writer."""
    keeps_time = False
    """Whether its equations keep time in svZeroDSolver's steady start-up (a chamber's
    activation): a network with one has no steady state, and its start-up is marched
    (:func:`cardiosoft.network.scheme.steady_march`)."""
    marchable = True
    """Whether svZeroDSolver's steady start-up of it is reproduced step for step
    (:meth:`mass_flux`); not the coronaries' and the combined heart's, whose ``steady``
    equations here give their steady state only."""
    vessel = False
    """Whether blood flows into it as into a vessel (a vessel, an outlet's resistance, RCR or
    coronary bed): its record is its inlet's pressure and flow
    (:mod:`cardiosoft.network.block_metrics`)."""

    def rates(self, t, x, P, Q, steady=False):
        return _none(P)

    def shared_terms(self, t, x):
        """What both its residuals and its rates need of ``(t, x)`` alone, or None. A block with
        such terms takes them as ``shared=`` in :meth:`residuals` and :meth:`rates`, and the
        network's vector field evaluates them once for both (the soft pump's chamber law:
        evaluated twice, it made the bench's field 995 equations against the written-out 591;
        once, 659)."""
        return None

    def mass_flux(self, t, x, P, Q, steady=False):
        """Its states' equations as svZeroDSolver writes them, ``m dx/dt = f``: ``(m, f)``, an
        entry a state; ``m = 1`` and ``f`` the rates unless a capacitor is switched off in the
        steady start-up (then ``m = 0``: an algebraic equation). What svZeroDSolver's scheme
        solves (:mod:`cardiosoft.network.gen_alpha`)."""
        rates = self.rates(t, x, P, Q, steady)
        return jnp.ones_like(rates), rates

    def states_from(self, values: dict) -> list[float]:
        return []

    def outputs(self, t, x, P, Q) -> dict:
        return {}

    def internal_names(self) -> tuple[str, ...]:
        """svZeroDSolver's names of the block's internal variables (``VAR:NAME``)."""
        return ()

    def state_kinds(self) -> tuple[str, ...]:
        """``"pressure"``, ``"flow"`` or ``"volume"`` per state: the state's scale."""
        return ()

    def chamber_volumes(self) -> dict[str, str]:
        """The chambers it holds, by record name, each with the name of its volume variable:
        a chamber's ``Vc:NAME`` (its record is its beat's volumes,
        :mod:`cardiosoft.network.block_metrics`)."""
        volume = f"Vc:{self.name}"
        return {self.name: volume} if volume in self.internal_names() else {}


def _stenosis_drop(R, S, q):
    """Pressure drop of a Poiseuille resistance R plus a stenosis S |q| (both in series)."""
    return (R + S * jnp.abs(q)) * q


class BloodVessel(Block):
    """svZeroDSolver's two-element-order vessels. Ports: inlet, outlet.

    - ``BloodVessel`` (``resistor_first``): R (with a stenosis S|Q_in|) into a capacitor C to
      ground, then an inductor L (``BloodVessel.cpp``): ``P_in - (R + S|Q_in|) Q_in - P_out -
      L dQ_out/dt = 0`` and ``Q_in - Q_out - C d(P_in - (R + S|Q_in|) Q_in)/dt = 0``.
    - ``BloodVesselCRL``: the capacitor at the inlet, then R (with S|Q_out|) and L in series
      (``BloodVesselCRL.cpp``): ``Q_in - Q_out - C dP_in/dt = 0`` and
      ``P_in - (R + S|Q_out|) Q_out - P_out - L dQ_out/dt = 0``.

    States: the capacitor's pressure when C > 0, the outlet flow when L > 0.
    """

    vessel = True
    R: jnp.ndarray
    C: jnp.ndarray
    L: jnp.ndarray
    S: jnp.ndarray
    has_C: bool = eqx.field(static=True)
    has_L: bool = eqx.field(static=True)
    nonlinear: bool = eqx.field(static=True)
    """A stenosis (S != 0)."""
    resistor_first: bool = eqx.field(static=True, default=True)
    """R before the capacitor (``BloodVessel``), or after it (``BloodVesselCRL``)."""

    @property
    def kind(self):
        return "BloodVessel" if self.resistor_first else "BloodVesselCRL"

    @property
    def n_states(self):
        return int(self.has_C) + int(self.has_L)

    def state_kinds(self):
        return ("pressure",) * self.has_C + ("flow",) * self.has_L

    def _drops(self, Q):
        """The resistance's pressure drop before the capacitor and after it."""
        q = Q[0] if self.resistor_first else Q[1]
        drop = _stenosis_drop(self.R, self.S, q) if self.nonlinear else self.R * q
        return (drop, 0.0) if self.resistor_first else (0.0, drop)

    def _capacitor(self, x, P, Q):
        return x[0] if self.has_C else P[0] - self._drops(Q)[0]

    def residuals(self, t, x, P, Q, steady=False):
        before, after = self._drops(Q)
        first = P[0] - before - x[0] if self.has_C else Q[0] - Q[1]
        second = Q[1] - x[-1] if self.has_L else self._capacitor(x, P, Q) - after - P[1]
        return jnp.stack([first, second])

    def rates(self, t, x, P, Q, steady=False):
        out = []
        if self.has_C:
            out.append((Q[0] - Q[1]) / self.C)
        if self.has_L:
            out.append((self._capacitor(x, P, Q) - self._drops(Q)[1] - P[1]) / self.L)
        return jnp.stack(out) if out else _none(P)

    def states_from(self, values):
        p_in, q_in = values["P"][0], values["Q"][0]
        drop = (float(self.R) + float(self.S) * abs(q_in)) * q_in if self.resistor_first else 0.0
        return [p_in - drop] * self.has_C + [values["Q"][1]] * self.has_L


class FlowSource(Block):
    """svZeroDSolver's ``FLOW`` boundary condition: the node's flow is ``Q(t)``."""

    Q: TimeTable
    kind = "FLOW"

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([Q[0] - self.Q(t, steady)])


class PressureSource(Block):
    """svZeroDSolver's ``PRESSURE`` boundary condition: the node's pressure is ``P(t)``."""

    P: TimeTable
    kind = "PRESSURE"

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([P[0] - self.P(t, steady)])


class Resistance(Block):
    """svZeroDSolver's ``RESISTANCE`` boundary condition: ``P = R Q + Pd``."""

    R: TimeTable
    Pd: TimeTable
    vessel = True
    kind = "RESISTANCE"

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([P[0] - self.R(t, steady) * Q[0] - self.Pd(t, steady)])


class RCR(Block):
    """svZeroDSolver's ``RCR`` boundary condition (``WindkesselBC.cpp``): Rp, then a capacitor C
    and Rd in parallel to the distal pressure Pd. State: the capacitor's pressure
    (``pressure_c:NAME``): ``C dP_c/dt = Q - (P_c - Pd)/Rd``.

    svZeroDSolver's steady start-up switches C off; its steady state is the same.
    """

    Rp: TimeTable
    C: TimeTable
    Rd: TimeTable
    Pd: TimeTable
    vessel = True
    kind = "RCR"
    n_states = 1

    def state_kinds(self):
        return ("pressure",)

    def internal_names(self):
        return (f"pressure_c:{self.name}",)

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([P[0] - self.Rp(t, steady) * Q[0] - x[0]])

    def rates(self, t, x, P, Q, steady=False):
        outflow = (x[0] - self.Pd(t, steady)) / self.Rd(t, steady)
        return jnp.stack([(Q[0] - outflow) / self.C(t, steady)])

    def mass_flux(self, t, x, P, Q, steady=False):
        flux = Q[0] - (x[0] - self.Pd(t, steady)) / self.Rd(t, steady)
        # svZeroDSolver's start-up switches C off (Model::to_steady)
        mass = jnp.zeros_like(flux) if steady else self.C(t) + jnp.zeros_like(flux)
        return jnp.stack([mass]), jnp.stack([flux])

    def states_from(self, values):
        return [values[f"pressure_c:{self.name}"]]

    def outputs(self, t, x, P, Q):
        return {f"pressure_c:{self.name}": x[0]}


class ClosedLoopRCR(Block):
    """svZeroDSolver's ``ClosedLoopRCR`` (``ClosedLoopRCRBC.cpp``): Rp, a capacitor C to ground
    (state ``P_c:NAME``), then Rd to its outlet node. Ports: inlet, outlet."""

    Rp: jnp.ndarray
    C: jnp.ndarray
    Rd: jnp.ndarray
    vessel = True
    kind = "ClosedLoopRCR"
    n_states = 1

    def state_kinds(self):
        return ("pressure",)

    def internal_names(self):
        return (f"P_c:{self.name}",)

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([P[0] - self.Rp * Q[0] - x[0], x[0] - P[1] - self.Rd * Q[1]])

    def rates(self, t, x, P, Q, steady=False):
        return jnp.stack([(Q[0] - Q[1]) / self.C])

    def mass_flux(self, t, x, P, Q, steady=False):
        flux = Q[0] - Q[1]
        # svZeroDSolver's start-up switches C off (Model::to_steady)
        mass = jnp.zeros_like(flux) if steady else self.C + jnp.zeros_like(flux)
        return jnp.stack([mass]), jnp.stack([flux])

    def states_from(self, values):
        return [values[f"P_c:{self.name}"]]

    def outputs(self, t, x, P, Q):
        return {f"P_c:{self.name}": x[0]}


class ValveTanh(Block):
    """svZeroDSolver's ``ValveTanh``: a resistance that moves from ``Rmin`` (open) to ``Rmax``
    (closed) along ``tanh(steepness (P_out - P_in))``. Ports: inlet, outlet. Its internal
    variable ``valve_status:NAME`` is ``(1 + tanh(steepness (P_out - P_in))) / 2``, as upstream."""

    Rmax: jnp.ndarray
    Rmin: jnp.ndarray
    steepness: jnp.ndarray
    kind = "ValveTanh"
    nonlinear = True

    def internal_names(self):
        return (f"valve_status:{self.name}",)

    def residuals(self, t, x, P, Q, steady=False):
        closing = jnp.tanh(self.steepness * (P[1] - P[0]))
        R = 0.5 * (self.Rmax + self.Rmin) + 0.5 * (self.Rmax - self.Rmin) * closing
        return jnp.stack([P[0] - P[1] - R * Q[0], Q[0] - Q[1]])

    def outputs(self, t, x, P, Q):
        status = 0.5 * (1.0 + jnp.tanh(self.steepness * (P[1] - P[0])))
        return {f"valve_status:{self.name}": status}


class PiecewiseValve(Block):
    """svZeroDSolver's ``PiecewiseValve``: ``Rmin`` while the upstream pressure is above the
    downstream one, else ``Rmax``. Ports: inlet, outlet."""

    Rmax: jnp.ndarray
    Rmin: jnp.ndarray
    kind = "PiecewiseValve"
    nonlinear = True

    def residuals(self, t, x, P, Q, steady=False):
        R = jnp.where(P[1] < P[0], self.Rmin, self.Rmax)
        return jnp.stack([P[0] - P[1] - R * Q[0], Q[0] - Q[1]])


class BloodVesselRC(Block):
    """svZeroDSolver's ``BloodVesselRC`` (``BloodVesselRC.cpp``): a capacitor ``Cp`` at the
    inlet (state) and ``Rpd`` to the outlet, with the outflow equal to the inflow, as upstream:
    ``Cp dP_in/dt = Q_in - (P_in - P_out) / Rpd``, ``Q_out = Q_in``."""

    Rpd: jnp.ndarray
    Cp: jnp.ndarray
    vessel = True
    kind = "BloodVesselRC"
    n_states = 1

    def state_kinds(self):
        return ("pressure",)

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([P[0] - x[0], Q[0] - Q[1]])

    def rates(self, t, x, P, Q, steady=False):
        return jnp.stack([(Q[0] - (x[0] - P[1]) / self.Rpd) / self.Cp])

    def states_from(self, values):
        return [values["P"][0]]


class Junction(Block):
    """svZeroDSolver's ``NORMAL_JUNCTION``: one pressure on every port, and the inflows equal the
    outflows. ``n_in`` (static) ports are inlets."""

    n_in: int = eqx.field(static=True)
    kind = "NORMAL_JUNCTION"

    def residuals(self, t, x, P, Q, steady=False):
        balance = jnp.sum(Q[: self.n_in]) - jnp.sum(Q[self.n_in :])
        return jnp.concatenate([P[0] - P[1:], balance[None]])


class VesselJunction(Block):
    """svZeroDSolver's ``BloodVesselJunction``: one inlet; to each outlet i a resistance R_i with a
    stenosis S_i |Q_i| and an inductor L_i (a state when L_i > 0)."""

    R: jnp.ndarray
    L: jnp.ndarray
    S: jnp.ndarray
    has_L: tuple[bool, ...] = eqx.field(static=True)
    nonlinear: bool = eqx.field(static=True)
    """A stenosis on some branch (S_i != 0)."""
    kind = "BloodVesselJunction"

    @property
    def n_states(self):
        return sum(self.has_L)

    def state_kinds(self):
        return ("flow",) * self.n_states

    def _branches(self):
        """(outlet index, state index or None) per branch."""
        k = 0
        for i, inductive in enumerate(self.has_L):
            yield i, (k if inductive else None)
            k += inductive

    def residuals(self, t, x, P, Q, steady=False):
        out = [Q[0] - jnp.sum(Q[1:])]
        for i, k in self._branches():
            if k is None:
                out.append(P[0] - P[i + 1] - _stenosis_drop(self.R[i], self.S[i], Q[i + 1]))
            else:
                out.append(Q[i + 1] - x[k])
        return jnp.stack(out)

    def rates(self, t, x, P, Q, steady=False):
        out = [
            (P[0] - P[i + 1] - _stenosis_drop(self.R[i], self.S[i], x[k])) / self.L[i]
            for i, k in self._branches()
            if k is not None
        ]
        return jnp.stack(out) if out else _none(P)

    def states_from(self, values):
        return [values["Q"][i + 1] for i, k in self._branches() if k is not None]
