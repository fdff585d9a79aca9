"""The pump coupled to its surroundings: a vector field with only the chosen effects.

A :class:`PumpCircuit` composes the pump surrogate, the cable actuation, an afterload (the
paper's water-column bench, a Windkessel) and, optionally, valves and a preload. Its state is a
dict:

- ``"volume"``: the pump's cavity volume V (m^3), always;
- ``"flow"``: the outflow q through the outlet line (m^3/s), only when the line has an
  inertance (tube or column inertia, a Windkessel-4 inductance). Without one, q is algebraic;
- ``"afterload"``: the afterload's own state (e.g. the column's risen volume, a capacitor
  pressure);
- ``"preload"``: the preload's state, only with a preload.

Equations (SI):

- ``dV/dt = q_in - q``;
- with an inertance L: ``L dq/dt = P_pump - P_node - R q - K q|q|``;
- without: ``q`` solves ``P_pump - P_node = R q + K q|q|`` in closed form, or the valve law
  ``q = valve(P_pump - P_node) / (R_valve + R)``;
- ``q_in = valve_in(P_preload - P_pump)`` with a preload.

``P_pump = dU/dV`` of the surrogate at the prescribed cable pull x(t). Effects that are not
chosen are absent: a Python-level (static) decision removes their state and their terms from
the traced function.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from cardiosoft.actuation import CablePull
from cardiosoft.chamber import one_sided_ramp
from cardiosoft.circulation import AbstractAfterload, AbstractPreload
from cardiosoft.pump import Chamber, PumpSurrogate
from cardiosoft.roots import implicit_scalar_root
from cardiosoft.units import ml, mmHg
from cardiosoft.valves import Valve

__all__ = [
    "CableFriction",
    "CableSlack",
    "PumpCircuit",
    "ShellViscoelasticity",
    "WallContact",
    "line_acceleration",
    "line_outflow",
]

SLACK_NEWTON_STEPS = 6
"""Newton steps of :meth:`CableSlack.shell_pull`. From its start a taut root needs one; the
slackest instant of the bench at 120 bpm (60 mmHg, 6-8 mm of slack) four to reach round-off
(measured 2026-12-05: 3e-2, 8e-5, 5e-10 mm after one, two, three)."""


class CableFriction(eqx.Module):
    """Capstan friction of the cables in the base holes, seen by the load cell on the disk.

    ``F_disk = F_shell exp(mu_theta tanh(v / v_s))``: larger than the shell's force while
    pulling, smaller while releasing; the difference is dissipated. It changes the measured
    force and mechanical work, not the hydraulics (the pull is prescribed).

    - ``exponent``: mu theta (dimensionless, >= 0), fitted with the surrogate (model card).
    - ``speed_scale``: v_s (m/s) of the smooth sign; 1 mm/s.
    """

    exponent: jax.Array = eqx.field(converter=jnp.asarray)
    speed_scale: jax.Array = eqx.field(converter=jnp.asarray, default=1e-3)

    def factor(self, velocity):
        return jnp.exp(self.exponent * jnp.tanh(velocity / self.speed_scale))


class CableSlack(eqx.Module):
    """A cable only pulls: the shell's own pull, which runs ahead of the disk's when slack.

    The shell's pull coordinate ``x_s`` (m) and the disk's ``x_d`` differ by the cables'
    slack ``g = x_s - x_d >= 0``; the tension ``T = F_shell(V, x_s) >= 0`` (N, the shell being
    massless in its pull, its force is the cables'). Either the cables are taut (``g = 0``) or
    slack (``T = 0``: the shell sits where its own force vanishes, ahead of a disk that returns
    faster than it recoils). The complementarity ``g T = 0`` is smoothed (Chen-Harker-Kanzow-
    Smale) to ``(g / l)(T / F_r) = mu``: with l = 1 mm, F_r = 1 N and ``mu`` = 1e-6 it bends
    over a slack of 1 um and a tension of 1 mN. A taut cable at T newtons then has a slack of
    1e-9 / T m: the shell's pull differs from the disk's by 1e-10 m at 10 N, so a beat whose
    cables never slacken equals the one without this effect to round-off and the solver's
    tolerance. The tension is positive by construction.

    Energy: the cables work ``T dx_d/dt`` on the shell, which stores ``U(V, x_s)``; the
    difference ``T dg/dt`` is the derivative of the smoothed contact's own energy,
    ``mu l F_r log(g / l)`` (:meth:`energy`), so the account closes exactly. ``x_s`` is
    algebraic, solved in each evaluation of the vector field by Newton's method
    (:func:`cardiosoft.roots.implicit_scalar_root`, differentiable).

    - ``smoothing``: mu (dimensionless, > 0), default 1e-6.
    """

    smoothing: jax.Array = eqx.field(converter=jnp.asarray, default=1e-6)
    gap_scale = 1e-3  # l (m)
    force_scale = 1.0  # F_r (N)

    def _residual(self, xi, tension):
        """The smoothed complementarity of ``xi = g / l`` and ``tension / F_r``, zero at the
        solution; increasing in ``xi`` while taut, and while slack where the shell's force
        rises with its pull (a stable equilibrium of the free shell)."""
        t = tension / self.force_scale
        return xi + t - jnp.sqrt((xi - t) ** 2 + 4.0 * self.smoothing)

    def shell_pull(self, shell_force, disk_pull, stroke) -> tuple[jax.Array, jax.Array]:
        """``(x_s, T)``: the shell's pull (m) and the cables' tension (N) at the disk's pull
        ``disk_pull`` (m). ``shell_force(x)`` is the shell's force dU/dx (N) at pull x and the
        current volume; ``stroke`` (m) the disk's full pull, which the shell never passes.

        Newton's method on ``xi = g / l`` from ``sqrt(mu)``, the knee: taut, the residual is
        nearly linear there and the first step lands on the root; slack, the first step is
        the linearised free shell's. Each iterate is kept above a tenth of the last (the root
        is positive) and within 1 mm past the stroke.
        """
        ell = self.gap_scale
        top = (jnp.maximum(stroke - disk_pull, 0.0) + 1e-3) / ell

        def residual(xi):
            tension = shell_force(disk_pull + ell * xi)
            return self._residual(xi, tension), tension

        def safeguard(xi, step):
            return jnp.clip(step, 0.1 * xi, top)

        start = jnp.sqrt(self.smoothing) * jnp.ones_like(disk_pull)
        xi, tension = implicit_scalar_root(
            residual, start, SLACK_NEWTON_STEPS, safeguard=safeguard, has_aux=True
        )
        return disk_pull + ell * xi, tension

    def energy(self, shell_pull, disk_pull) -> jax.Array:
        """The smoothed contact's energy ``mu l F_r log(g / l)`` (J), up to a constant: its
        rate is ``T dg/dt``, the cables' work that the shell does not store."""
        gap = (shell_pull - disk_pull) / self.gap_scale
        return self.smoothing * self.gap_scale * self.force_scale * jnp.log(gap)


class WallContact(eqx.Module):
    """The shell's walls meet: a floor under the cavity volume.

    The surrogate's chamber law holds the volume only through its fitted pressures (-20 to
    150 mmHg); sucked harder, as a fast beat's column can do, it lets the volume fall through
    zero. Below ``onset`` the walls press together: ``U_w = E_w e^2 / 2`` with ``e`` the
    one-sided depth ``w phi((onset - V) / w)`` (``phi``: :func:`cardiosoft.chamber.one_sided_ramp`,
    C2; w = ``onset``), so the floor is exactly absent, with its pressure and stiffness, at and
    above ``onset``: a beat that never comes near it is unchanged to the last bit. It adds
    ``dU_w/dV`` (< 0, it pushes the walls apart) to the chamber pressure and
    ``U_w`` to the stored energy; not the cable force (it does not depend on the pull).

    - ``onset``: where the walls begin to touch (m^3), default 2 ml: a film of about 0.2 mm
      over the cavity's ~110 cm^2 of wall (a half-ellipsoid of semi-axes 60 and 30 mm),
      which the folds of a 1.5-mm wall cannot press out. The contact stiffens from zero
      there to ``stiffness`` at V = 0 (where it pushes back with ``stiffness onset / 2``).
    - ``stiffness``: E_w (Pa/m^3), default 1000 mmHg/ml, 500 times the unloaded chamber's
      (ss950-v3's 2 mmHg/ml): stiff enough that the water hammer of the bench at 120 bpm
      when the walls meet (700 mmHg of suction at 30 mmHg) leaves the volume above zero, soft
      enough that an explicit solver steps through the contact (it rings with the inertance
      of the bench's tube and column, 1.2e6 Pa s^2/m^3, at about 50 Hz).
    """

    onset: jax.Array = eqx.field(converter=jnp.asarray, default=2 * ml)
    stiffness: jax.Array = eqx.field(converter=jnp.asarray, default=1000 * mmHg / ml)

    def energy(self, volume) -> jax.Array:
        """U_w (J) at cavity volume ``volume`` (m^3)."""
        depth = self.onset * one_sided_ramp((self.onset - volume) / self.onset)
        return 0.5 * self.stiffness * depth**2

    def pressure(self, volume) -> jax.Array:
        """dU_w/dV (Pa), <= 0."""
        volume = jnp.asarray(volume, dtype=float)
        return jax.jvp(self.energy, (volume,), (jnp.ones_like(volume),))[1]


class ShellViscoelasticity(eqx.Module):
    """Relaxation of the silicone shell: a standard linear solid on the chamber's volume.

    The surrogate's chamber law is the relaxed (equilibrium) response. In parallel with it sits a
    Maxwell branch: a spring of stiffness ``r E(x)`` (``E`` the surrogate's zero-pressure chamber
    elastance, Pa/m^3) in series with a dashpot, with energy
    ``U_v = r E(x) (V - V_eq(x) - s_v)^2 / 2`` and the dashpot's volume ``s_v`` relaxing as
    ``ds_v/dt = (V - V_eq(x) - s_v) / tau``. A fast stroke meets a chamber ``1 + r`` times
    stiffer than a slow one; held, it creeps back to the surrogate in a time ``tau``. The branch
    adds ``dU_v/dV`` to the chamber pressure and ``dU_v/dx`` to the cable force, and dissipates
    ``r E (V - V_eq - s_v)^2 / tau >= 0``.

    - ``stiffness_ratio``: r (dimensionless, >= 0).
    - ``relaxation_time``: tau (s, > 0).
    """

    stiffness_ratio: jax.Array = eqx.field(converter=jnp.asarray)
    relaxation_time: jax.Array = eqx.field(converter=jnp.asarray)

    def strain(self, chamber: Chamber, volume, relaxed):
        """V - V_eq(x) - s_v (m^3): the Maxwell spring's stretch, at the pull of ``chamber``.

        V_eq is the unswollen chamber's (``Chamber.rest_volume``): the branch does not see the
        folds yield to swelling. Measured 2026-12-02: with the swollen chamber's distension
        instead (``Chamber.strain``), the bench calibration (``python -m fit.bench``) reached a
        loss of 2.21 against 1.81, with the relaxation time running off (to 12 s) on the way.
        """
        return volume - chamber.rest_volume - relaxed

    def energy(self, chamber: Chamber, volume, relaxed):
        """U_v (J)."""
        stiffness = self.stiffness_ratio * chamber.elastance
        return 0.5 * stiffness * self.strain(chamber, volume, relaxed) ** 2

    def rest_state(self, chamber: Chamber, volume):
        """The relaxed dashpot volume s_v = V - V_eq(x) (m^3): the spring unstretched."""
        return self.strain(chamber, volume, 0.0)

    def rate(self, chamber: Chamber, volume, relaxed):
        """ds_v/dt (m^3/s)."""
        return self.strain(chamber, volume, relaxed) / self.relaxation_time

    def dissipation(self, chamber: Chamber, volume, relaxed):
        """Power lost in the dashpot (W), ``r E (V - V_eq - s_v)^2 / tau >= 0``."""
        stiffness = self.stiffness_ratio * chamber.elastance
        return stiffness * self.strain(chamber, volume, relaxed) ** 2 / self.relaxation_time


def line_outflow(afterload: AbstractAfterload, valve: Valve | None, ya, drop) -> jax.Array:
    """The outflow (m^3/s) of a line without inertance at pressure drop ``drop`` (Pa) from the
    pump to the afterload's node: through ``valve`` and the line's resistance in series, or
    the root of ``R q + K q|q| = drop``. ``ya``: the afterload's state."""
    r = afterload.line_resistance(ya)
    if valve is not None:
        return valve.flow(drop, 0.0 if r is None else r)
    k = afterload.line_loss(ya)
    if k is None:
        return drop / r
    # R q + K q|q| = drop: the root of the quadratic, in the form without cancellation
    r = jnp.zeros_like(drop) if r is None else r
    return 2.0 * drop / (r + jnp.sqrt(r**2 + 4.0 * k * jnp.abs(drop)))


def line_acceleration(afterload: AbstractAfterload, ya, flow, drop) -> jax.Array:
    """dq/dt (m^3/s^2) of a line with inertance L carrying ``flow`` q (m^3/s) at pressure drop
    ``drop`` (Pa) from the pump to the afterload's node: ``L dq/dt = drop - R q - K q|q|``."""
    r = afterload.line_resistance(ya)
    if r is not None:
        drop = drop - r * flow
    k = afterload.line_loss(ya)
    if k is not None:
        drop = drop - k * flow * jnp.abs(flow)
    return drop / afterload.line_inertance(ya)


class PumpCircuit(eqx.Module):
    """The pump's vector field; see the module docstring.

    **Arguments:**

    - ``pump``: the :class:`~cardiosoft.pump.PumpSurrogate`; ``omega``: its helix parameter.
    - ``actuation``: the prescribed cable pull x(t), a :class:`~cardiosoft.actuation.CablePull`.
    - ``afterload``: an :class:`~cardiosoft.circulation.AbstractAfterload`.
    - ``outlet_valve``, ``inlet_valve``: :class:`~cardiosoft.valves.Valve` or None.
    - ``preload``: an :class:`~cardiosoft.circulation.AbstractPreload` or None (needs an inlet
      valve).
    - ``cable_friction``: a :class:`CableFriction` or None.
    - ``viscoelasticity``: a :class:`ShellViscoelasticity` or None.
    - ``cable_slack``: a :class:`CableSlack` or None (the shell's pull is then the disk's).
    - ``wall_contact``: a :class:`WallContact` or None (no floor under the volume).
    - ``energy`` (static): keep the energy account as states (:meth:`power`): the work done by
      the cables and by the atrium, delivered past the outlet, and lost to friction, the
      shell's viscosity and the valves, integrated by the solver with the rest (J). Off by
      default: the cable force then stays out of the vector field, which is several times
      cheaper to evaluate without it.
    """

    pump: PumpSurrogate
    omega: jax.Array = eqx.field(converter=jnp.asarray)
    actuation: CablePull
    afterload: AbstractAfterload
    outlet_valve: Valve | None = None
    inlet_valve: Valve | None = None
    preload: AbstractPreload | None = None
    cable_friction: CableFriction | None = None
    viscoelasticity: ShellViscoelasticity | None = None
    cable_slack: CableSlack | None = None
    wall_contact: WallContact | None = None
    energy: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        if (self.preload is None) != (self.inlet_valve is None):
            raise ValueError("a preload needs an inlet valve, and an inlet valve needs a preload")
        y = self.afterload.init()
        inertia = self.afterload.line_inertance(y) is not None
        if inertia and self.outlet_valve is not None:
            raise ValueError(
                "an outlet valve in series with an inertance is not supported: drop the "
                "inertance effects (or the Windkessel-4 inductance) or the outlet valve"
            )
        if (
            not inertia
            and self.outlet_valve is None
            and (self.afterload.line_resistance(y) is None and self.afterload.line_loss(y) is None)
        ):
            raise ValueError(
                "the outlet line has neither inertance, resistance nor a valve: the outflow is "
                "undetermined; add tube_resistance or tube_inertia, or use a static scene"
            )

    @property
    def has_flow_state(self) -> bool:
        """Whether the outflow is a state (the line has an inertance); static."""
        return self.afterload.line_inertance(self.afterload.init()) is not None

    def init(self) -> dict:
        """Rest state: no pull, the pump filled at the preload (or afterload) pressure."""
        ya = self.afterload.init()
        y = {"afterload": ya}
        if self.preload is not None:
            y["preload"] = self.preload.init()
            p_fill = self.preload.pressure(y["preload"])
        else:
            p_fill = self.afterload.node_pressure(ya)
        y["volume"] = self.pump.volume(p_fill, self.actuation(0.0), self.omega)
        if self.has_flow_state:
            y["flow"] = jnp.zeros_like(y["volume"])
        if self.viscoelasticity is not None:
            chamber = self.pump.chamber(self.actuation(0.0), self.omega)
            y["relaxation"] = self.viscoelasticity.rest_state(chamber, y["volume"])
        if self.energy:
            terms = self.power(0.0, y)
            y["energy"] = {k: jnp.zeros_like(v) for k, v in terms.items()}
        return y

    def _shell_force(self, y, pull):
        """The shell's force dU/dx (N) at pull ``pull`` (m) and the volume of state ``y``."""

        def volume_energy(pull):
            """The chamber's energy, and the viscoelastic branch's, at this volume (J).

            With W'(x) this gives the shell's force dU/dx, the chamber law evaluated once.
            """
            chamber = self.pump.chamber(pull, self.omega)
            energy = chamber.energy(y["volume"])
            if self.viscoelasticity is not None:
                energy = energy + self.viscoelasticity.energy(chamber, y["volume"], y["relaxation"])
            return energy

        return self.pump.zero_pressure_force(pull, self.omega) + jax.grad(volume_energy)(pull)

    def _shell_pull(self, t, y) -> dict:
        """The disk's pull x_d(t) (m) and, with slack cables, the shell's own and the tension."""
        x = self.actuation(t)
        if self.cable_slack is None:
            return {"pull": x}
        shell_pull, tension = self.cable_slack.shell_pull(
            lambda pull: self._shell_force(y, pull), x, self.actuation.stroke
        )
        return {"pull": x, "shell_pull": shell_pull, "shell_force": tension}

    def _chamber(self, t, y):
        """The pulls (:meth:`_shell_pull`) and the chamber law at the shell's pull."""
        pulls = self._shell_pull(t, y)
        return pulls, self.pump.chamber(pulls.get("shell_pull", pulls["pull"]), self.omega)

    def pump_pressure(self, t, y) -> dict:
        """The pump's side at time t (SI): the disk's pull (and, with slack cables, the shell's
        own and the tension), the chamber law at the shell's pull (``chamber``) and the
        cavity's pressure with the shell's effects (``pump_pressure``, Pa). Reads only
        ``y["volume"]`` and ``y["relaxation"]``: the law of the network's pump block
        (:class:`cardiosoft.network.bench.ShellPump`)."""
        out, chamber = self._chamber(t, y)
        volume = y["volume"]
        p_pump = chamber.pressure(volume)
        if self.wall_contact is not None:
            p_pump = p_pump + self.wall_contact.pressure(volume)
        if self.viscoelasticity is not None:
            p_pump = p_pump + jax.grad(self.viscoelasticity.energy, argnums=1)(
                chamber, volume, y["relaxation"]
            )
        return out | {"chamber": chamber, "pump_pressure": p_pump}

    def _hydraulics(self, t, y) -> dict:
        """Pull, chamber law, pressures and flows at time t (SI): all the vector field needs."""
        out = self.pump_pressure(t, y)
        ya = y["afterload"]
        p_pump = out["pump_pressure"]
        p_node = self.afterload.node_pressure(ya)
        if self.has_flow_state:
            q_out = y["flow"]
        else:
            q_out = line_outflow(self.afterload, self.outlet_valve, ya, p_pump - p_node)
        out |= {"node_pressure": p_node, "outflow": q_out}
        if self.preload is not None:
            p_pre = self.preload.pressure(y["preload"])
            out["preload_pressure"] = p_pre
            out["inflow"] = self.inlet_valve.flow(p_pre - p_pump)
        return out

    def signals(self, t, y) -> dict:
        """Everything observable at time t (SI): pull, pressures, flows, forces."""
        out = self._hydraulics(t, y)
        del out["chamber"]
        return out | self._forces(t, y, out)

    def _forces(self, t, y, hydraulics: dict) -> dict:
        """The shell's force dU/dx and the cable force the load cell reads (N)."""
        force = hydraulics.get("shell_force")
        if force is None:
            force = self._shell_force(y, hydraulics["pull"])
        out = {"shell_force": force}
        if self.cable_friction is not None:
            force = force * self.cable_friction.factor(self.actuation.velocity(t))
        out["cable_force"] = force
        return out

    def power(self, t, y, hydraulics: dict | None = None) -> dict:
        """The energy account's rates at time t (W), each term present only with its effect.

        - ``cable_in``: F_cable dx/dt, the work of the cables on the disk;
        - ``atrium_in``: P_preload q_in, the work of the filling source (with a preload);
        - ``delivered``: P_outlet q_out, the work done on the fluid past the outlet (valve):
          the afterload's, including its line (the bench's tube, a Windkessel's Rp);
        - ``friction``: (F_cable - F_shell) dx/dt, lost at the base holes;
        - ``viscous``: the shell dashpot's loss (:meth:`ShellViscoelasticity.dissipation`);
        - ``valves``: (P_pump - P_outlet) q_out + (P_preload - P_pump) q_in.

        ``cable_in + atrium_in = delivered + friction + viscous + valves + dU/dt``, U the
        shell's strain energy (:meth:`stored_energy`): ``dU = F_shell dx + P_pump dV``.
        """
        s = self._hydraulics(t, y) if hydraulics is None else hydraulics
        forces = self._forces(t, y, s)
        speed = self.actuation.velocity(t)
        q_out, p_pump = s["outflow"], s["pump_pressure"]
        out = {"cable_in": forces["cable_force"] * speed}
        if self.outlet_valve is None:
            p_outlet = p_pump  # no valve: the pump's pressure drives the line itself
        else:  # past the valve: the line's resistance and the node (no inertance with a valve)
            r = self.afterload.line_resistance(y["afterload"])
            p_outlet = s["node_pressure"] + (0.0 if r is None else r * q_out)
        out["delivered"] = p_outlet * q_out
        if self.preload is not None:
            out["atrium_in"] = s["preload_pressure"] * s["inflow"]
        if self.cable_friction is not None:
            out["friction"] = (forces["cable_force"] - forces["shell_force"]) * speed
        if self.viscoelasticity is not None:
            out["viscous"] = self.viscoelasticity.dissipation(
                s["chamber"], y["volume"], y["relaxation"]
            )
        if self.outlet_valve is not None:
            valves = (p_pump - p_outlet) * q_out
            if self.preload is not None:
                valves = valves + (s["preload_pressure"] - p_pump) * s["inflow"]
            out["valves"] = valves
        return out

    def stored_energy(self, t, y) -> jax.Array:
        """The shell's strain energy U(V, x) plus the dashpot spring's (J) at time t, with
        slack cables the smoothed contact's (:meth:`CableSlack.energy`), with the floor the
        walls' (:meth:`WallContact.energy`)."""
        pulls = self._shell_pull(t, y)
        x = pulls.get("shell_pull", pulls["pull"])
        energy = self.pump.energy(y["volume"], x, self.omega)
        if self.viscoelasticity is not None:
            chamber = self.pump.chamber(x, self.omega)
            energy = energy + self.viscoelasticity.energy(chamber, y["volume"], y["relaxation"])
        if self.cable_slack is not None:
            energy = energy + self.cable_slack.energy(x, pulls["pull"])
        if self.wall_contact is not None:
            energy = energy + self.wall_contact.energy(y["volume"])
        return energy

    def __call__(self, t, y, args=None) -> dict:
        s = self._hydraulics(t, y)
        q_in = s.get("inflow", 0.0)
        dy = {
            "volume": q_in - s["outflow"],
            "afterload": self.afterload.node_rhs(y["afterload"], s["outflow"]),
        }
        if self.preload is not None:
            dy["preload"] = self.preload.rhs(y["preload"], q_in)
        if self.viscoelasticity is not None:
            dy["relaxation"] = self.viscoelasticity.rate(s["chamber"], y["volume"], y["relaxation"])
        if self.has_flow_state:
            drop = s["pump_pressure"] - s["node_pressure"]
            dy["flow"] = line_acceleration(self.afterload, y["afterload"], y["flow"], drop)
        if self.energy:
            dy["energy"] = self.power(t, y, s)
        return dy

    def total_volume(self, y) -> jax.Array:
        """Pump + afterload + preload volume bookkeeping (m^3); constant in time."""
        total = y["volume"] + self.afterload.stored_volume(y["afterload"])
        if self.preload is not None:
            total = total + self.preload.stored_volume(y["preload"])
        return total
