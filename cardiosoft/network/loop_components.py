"""Blocks of the closed circulation: heart chambers and vessel compartments (issue 26).

The native heart is the lumped model of Regazzoni et al. 2022 ("A cardiac electromechanical
model coupled with a lumped-parameter model for closed-loop blood circulation", J. Comput. Phys.
457, 111083; equations and defaults in ``notes/closed-loop-regazzoni.md``): four
time-varying-elastance chambers, four RLC vessel compartments and four valves (the valve law is
:class:`cardiosoft.valves.ArctanValve`). The soft pump takes the place of a ventricle as a
:class:`PumpChamber`. :class:`cardiosoft.network.closed_loop.ClosedLoop` composes them.

Everything is SI: volumes m^3, pressures Pa, flows m^3/s, elastances Pa/m^3, resistances
Pa s/m^3, compliances m^3/Pa, inertances Pa s^2/m^3, times s. Messages use the clinical units.

Chamber protocol (:class:`AbstractChamber`): ``pressure(t, V)`` (Pa), ``start_volume(p)`` (the
volume at t = 0 of a chamber filled at pressure p), ``kink_phases()`` (where in the beat its
forcing has kinks, fractions of the period, for the solver's ``jump_ts``), ``observe(t, V)``
(what else it shows: a pump's pull and cable force) and ``period``.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp

from cardiosoft._validate import _is_traced, check_positive, check_range
from cardiosoft.actuation import CablePull
from cardiosoft.pump import PumpSurrogate
from cardiosoft.units import ml, ml_per_mmHg, mmHg, mmHg_s2_per_ml, mmHg_s_per_ml

__all__ = [
    "AbstractChamber",
    "Activation",
    "ElastanceChamber",
    "PumpChamber",
    "Vessel",
]

_E = mmHg / ml  # 1 mmHg/ml in Pa/m^3


class Activation(eqx.Module):
    """The cosine activation a(t) in [0, 1] of Regazzoni et al. 2022 (section 2.2; the
    ``time_varying_elastance`` of the first author's code).

    With ``tau = (t - t_C) mod T`` and ``tau_r = (t - t_C - T_C) mod T``::

        a(t) = 1/2 (1 - cos(pi tau / T_C))      for tau < T_C      (contraction)
             + 1/2 (1 + cos(pi tau_r / T_R))    for tau_r < T_R    (relaxation)

    clipped to [0, 1]. a and da/dt are continuous; d2a/dt2 jumps at ``t_C``, ``t_C + T_C`` and
    ``t_C + T_C + T_R`` (:meth:`kink_phases`).

    - ``period``: T (s), > 0.
    - ``start``: t_C / T, in [0, 1); ``contraction``: T_C / T and ``relaxation``: T_R / T, in
      (0, 1] with ``contraction + relaxation <= 1`` (the next contraction starts after this
      relaxation ends).
    """

    period: jax.Array = eqx.field(converter=jnp.asarray)
    start: jax.Array = eqx.field(converter=jnp.asarray)
    contraction: jax.Array = eqx.field(converter=jnp.asarray)
    relaxation: jax.Array = eqx.field(converter=jnp.asarray)

    def __check_init__(self):
        check_positive("activation period", self.period, "s")
        check_range("contraction start t_C / T", self.start, "-", 0.0, 1.0, hi_open=True)
        check_range("contraction duration T_C / T", self.contraction, "-", 0.0, 1.0, lo_open=True)
        check_range("relaxation duration T_R / T", self.relaxation, "-", 0.0, 1.0, lo_open=True)
        if not (_is_traced(self.contraction) or _is_traced(self.relaxation)):
            total = self.contraction + self.relaxation
            check_range("contraction + relaxation durations T_C / T + T_R / T", total, "-", 0, 1)

    def __call__(self, t) -> jax.Array:
        """a(t) (dimensionless)."""
        T = self.period
        t_c, t_r = self.contraction * T, self.relaxation * T
        tau = jnp.mod(t - self.start * T, T)
        tau_r = jnp.mod(tau - t_c, T)
        rising = jnp.where(tau < t_c, 0.5 * (1.0 - jnp.cos(jnp.pi * tau / t_c)), 0.0)
        falling = jnp.where(tau_r < t_r, 0.5 * (1.0 + jnp.cos(jnp.pi * tau_r / t_r)), 0.0)
        return jnp.clip(rising + falling, 0.0, 1.0)

    def kink_phases(self) -> jax.Array:
        """Start of contraction, of relaxation, end of relaxation: phases of the beat in [0, 1)."""
        ends = jnp.cumsum(jnp.stack([self.start, self.contraction, self.relaxation]))
        return jnp.mod(ends, 1.0)


class AbstractChamber(eqx.Module):
    """The chamber protocol; see the module docstring."""

    @abc.abstractmethod
    def pressure(self, t, volume) -> jax.Array:
        """Chamber pressure (Pa) at time t (s) and volume (m^3)."""

    @abc.abstractmethod
    def start_volume(self, fill_pressure) -> jax.Array:
        """The volume at t = 0 (m^3) of the chamber filled at ``fill_pressure`` (Pa)."""

    @abc.abstractmethod
    def kink_phases(self) -> jax.Array:
        """Kinks of the chamber's forcing in time, as phases of the beat in [0, 1]."""

    @abc.abstractmethod
    def observe(self, t, volume) -> dict[str, jax.Array]:
        """Further signals at time t (SI), ``{}`` for none."""

    @property
    @abc.abstractmethod
    def period(self) -> jax.Array:
        """The beat period (s)."""


class ElastanceChamber(AbstractChamber):
    """A time-varying-elastance chamber, ``p = E(t) (V - V_0)``, ``E(t) = E_B + E_A a(t)``
    (Regazzoni et al. 2022, section 2.2; the notes' "chamber c").

    - ``active_elastance``: E_A (Pa/m^3), >= 0; ``passive_elastance``: E_B (Pa/m^3), > 0.
    - ``rest_volume``: V_0 (m^3), >= 0, the unstressed volume.
    - ``activation``: an :class:`Activation`.
    - ``initial_volume``: the volume at t = 0 (m^3), > 0 (the notes' initial state).
    """

    active_elastance: jax.Array = eqx.field(converter=jnp.asarray)
    passive_elastance: jax.Array = eqx.field(converter=jnp.asarray)
    rest_volume: jax.Array = eqx.field(converter=jnp.asarray)
    activation: Activation
    initial_volume: jax.Array = eqx.field(converter=jnp.asarray)

    def __check_init__(self):
        check_range("active elastance E_A", self.active_elastance, "mmHg/ml", 0.0, scale=_E)
        check_positive("passive elastance E_B", self.passive_elastance, "mmHg/ml", scale=_E)
        check_range("unstressed volume V_0", self.rest_volume, "ml", 0.0, scale=ml)
        check_positive("initial chamber volume", self.initial_volume, "ml", scale=ml)

    @property
    def period(self) -> jax.Array:
        return self.activation.period

    def elastance(self, t) -> jax.Array:
        """E(t) (Pa/m^3)."""
        return self.passive_elastance + self.active_elastance * self.activation(t)

    def pressure(self, t, volume) -> jax.Array:
        return self.elastance(t) * (volume - self.rest_volume)

    def start_volume(self, fill_pressure) -> jax.Array:
        """:attr:`initial_volume`: the native chambers start where the paper's state does."""
        return self.initial_volume

    def kink_phases(self) -> jax.Array:
        return self.activation.kink_phases()

    def observe(self, t, volume) -> dict[str, jax.Array]:
        return {}


class PumpChamber(AbstractChamber):
    """The soft pump as a heart chamber: the surrogate's chamber law at the prescribed pull.

    ``p = dU/dV (V, x(t); Omega)`` (:meth:`PumpSurrogate.chamber`), the cable force
    ``F = dU/dx`` (:meth:`PumpSurrogate.force`). The pull starts at ``onset`` of the period:
    ``x(t) = actuation(t - onset T)``; t = 0 is the native ventricles' onset of contraction,
    so the atria contract before the pull at ``onset = 0`` as before a native ventricle. No
    shell effect (cable friction, viscoelasticity) is modelled here: the chamber is the
    surrogate's relaxed law, the cables ideal.

    - ``pump``: the :class:`~cardiosoft.pump.PumpSurrogate`; ``omega``: its helix parameter.
    - ``actuation``: the cable pull, a :class:`~cardiosoft.actuation.CablePull` (its period is
      the beat's).
    - ``onset``: the start of the pull as a fraction of the period, in [0, 1).
    """

    pump: PumpSurrogate
    omega: jax.Array = eqx.field(converter=jnp.asarray)
    actuation: CablePull
    onset: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)

    def __check_init__(self):
        check_range("helix parameter Omega", self.omega, "-", *self.pump.domain.omega)
        check_range("pull onset / T", self.onset, "-", 0.0, 1.0, hi_open=True)

    @property
    def period(self) -> jax.Array:
        return self.actuation.period

    def pull(self, t) -> jax.Array:
        """Cable pull x(t) (m)."""
        return self.actuation(t - self.onset * self.period)

    def pressure(self, t, volume) -> jax.Array:
        return self.pump.chamber(self.pull(t), self.omega).pressure(volume)

    def start_volume(self, fill_pressure) -> jax.Array:
        """The pump's volume at its pull at t = 0, filled at ``fill_pressure`` (Pa)."""
        return self.pump.volume(fill_pressure, self.pull(0.0), self.omega)

    def kink_phases(self) -> jax.Array:
        phases = self.actuation.kink_times(1) / self.period
        return jnp.mod(phases + self.onset, 1.0)

    def observe(self, t, volume) -> dict[str, jax.Array]:
        """The pull x (m) and the total cable force dU/dx (N)."""
        x = self.pull(t)
        return {"pull": x, "cable_force": self.pump.force(volume, x, self.omega)}


class Vessel(eqx.Module):
    """A compliant vessel compartment with resistance and inertance (RLC): a compliance C at
    pressure p, drained through R in series with L (Regazzoni et al. 2022, section 2.3)::

        C dp/dt = q_in - q          L dq/dt = p - p_downstream - R q

    The compartment holds ``C p`` of blood (no unstressed volume, as in the paper).

    - ``resistance``: R (Pa s/m^3), ``compliance``: C (m^3/Pa), ``inertance``: L (Pa s^2/m^3),
      all > 0.
    - ``initial_pressure`` (Pa), ``initial_flow`` (m^3/s): the state at t = 0.

    State: ``{"pressure", "flow"}`` (Pa, m^3/s), the flow leaving it.
    """

    resistance: jax.Array = eqx.field(converter=jnp.asarray)
    compliance: jax.Array = eqx.field(converter=jnp.asarray)
    inertance: jax.Array = eqx.field(converter=jnp.asarray)
    initial_pressure: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    initial_flow: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)

    def __check_init__(self):
        check_positive("vessel resistance R", self.resistance, "mmHg s/ml", scale=mmHg_s_per_ml)
        check_positive("vessel compliance C", self.compliance, "ml/mmHg", scale=ml_per_mmHg)
        check_positive("vessel inertance L", self.inertance, "mmHg s^2/ml", scale=mmHg_s2_per_ml)
        check_range("initial vessel pressure", self.initial_pressure, "mmHg", scale=mmHg)
        check_range("initial vessel flow", self.initial_flow, "ml/s", scale=ml)

    def init(self) -> dict[str, jax.Array]:
        ftype = jnp.result_type(float)
        return {
            "pressure": jnp.asarray(self.initial_pressure, ftype),
            "flow": jnp.asarray(self.initial_flow, ftype),
        }

    def rhs(self, y, inflow, downstream_pressure) -> dict[str, jax.Array]:
        """dy/dt for an ``inflow`` (m^3/s) and the pressure it drains into (Pa)."""
        drop = y["pressure"] - downstream_pressure - self.resistance * y["flow"]
        return {
            "pressure": (inflow - y["flow"]) / self.compliance,
            "flow": drop / self.inertance,
        }

    def volume(self, y) -> jax.Array:
        """Blood held, ``C p`` (m^3)."""
        return self.compliance * y["pressure"]
