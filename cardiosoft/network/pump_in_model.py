"""The soft pump in a user's svZeroDSolver model, in place of one of its chambers.

``cardiosoft simulate --scene model.json --pump-chamber LV --units mmHg`` reads the model and
puts the pump (the surrogate's chamber law at a prescribed cable pull,
:class:`~cardiosoft.network.loop_components.PumpChamber`) where its chamber ``LV`` was, between
the same nodes:
filled through the same inlet, ejecting through the same outlet. The pump is SI inside; the
model is in its own units, which svZeroDSolver files do not state, so ``--units`` says which
(:data:`UNIT_SYSTEMS`, default ``cgs``, SimVascular's). The replaced chamber's outlet inductor,
if it had one, goes with it: the pump's two nodes are at its pressure.

The pump is the paper's prototype design unless told otherwise (Omega 4, C 0.4), pulled as the
shipped ``tah`` scene pulls its pumps (:data:`PULL`), with the pull starting at the model's
t = 0. Its cable pull (m) and force (N) are output as ``pull:NAME`` and ``cable_force:NAME``, in
SI whatever the model's units; its volume keeps the chamber's name, ``Vc:NAME``.

Written by ``cardiosoft export --svzerod`` of the bench
(:mod:`cardiosoft.network.export_open_loop`), the pump also carries the shell's effects that
scene names, each absent unless given
(:class:`PumpPlacement`): the crosshead's ramp, the shell's viscoelasticity (a second state, the
dashpot's volume ``Vd:NAME``, model units) and the cables' friction in the base holes (on the
force output alone: the pull is prescribed).
"""

from __future__ import annotations

from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft._validate import check_range
from cardiosoft.actuation import CablePull
from cardiosoft.circuit import CableFriction, ShellViscoelasticity
from cardiosoft.network.block_metrics import pump_record
from cardiosoft.network.blocks import Block
from cardiosoft.network.loop_components import PumpChamber
from cardiosoft.pump import Domain, load
from cardiosoft.units import ml, mmHg

UNIT_SYSTEMS = {
    "cgs": (0.1, 1e-6, "dyn/cm^2", "ml"),
    "mmHg": (mmHg, ml, "mmHg", "ml"),
    "si": (1.0, 1.0, "Pa", "m^3"),
}
"""The model's units: (Pa per pressure unit, m^3 per volume unit, their names). Time is in
seconds and flow in volume units per second in all three."""
DEFAULT_UNITS = "cgs"
PULL = dict(shape="cosine", pull_fraction=0.35, hold_fraction=0.05, release_fraction=0.30)
"""The cable pull as a fraction of the period: the shipped ``tah`` scene's, a smooth systolic
pull over about a native ventricle's contraction (0.34 of the period), then release and rest."""
PROTOTYPE = (4.0, 0.4)
"""The paper's prototype design (Omega, C)."""
SHELL_EFFECTS = {
    "shell_viscoelasticity": {"stiffness_ratio": ("-", False), "relaxation_time_s": ("s", True)},
    "cable_friction": {"exponent": ("-", False)},
}
"""The shell's effects a ``SoftPump`` may carry: each one's numbers, as the scene files name
them, with their unit and whether their lower bound 0 is open."""
CHAMBER_VOLUMES = (1e-6, 1e-3)
"""Start volumes (m^3) a heart chamber can have, 1 ml to 1 l: a replaced chamber's start volume
outside them, in the units given, says that the model is in other units."""


@dataclass(frozen=True)
class PumpPlacement:
    """Where the pump goes and how: the chamber it replaces, the model's units, its design."""

    chamber: str
    units: str = DEFAULT_UNITS
    omega: float = PROTOTYPE[0]
    shortening: float = PROTOTYPE[1]
    surrogate: str | None = None
    """A shipped surrogate's name or an artifact's path (default: the shipped default)."""
    shape: str = PULL["shape"]
    pull_fraction: float = PULL["pull_fraction"]
    hold_fraction: float = PULL["hold_fraction"]
    release_fraction: float = PULL["release_fraction"]
    onset: float = 0.0
    """The start of the pull as a fraction of the period."""
    ramp_time: float = 0.0
    """The jerk-limited ends of a ``"linear"`` pull (s;
    :class:`~cardiosoft.actuation.CablePull`)."""
    shell_viscoelasticity: dict | None = None
    """The shell's relaxation, ``{"stiffness_ratio": r, "relaxation_time_s": tau}``
    (:class:`~cardiosoft.circuit.ShellViscoelasticity`), or None."""
    cable_friction: dict | None = None
    """The cables' capstan friction, ``{"exponent": mu theta}``
    (:class:`~cardiosoft.circuit.CableFriction`), or None."""

    def __post_init__(self):
        if self.units not in UNIT_SYSTEMS:
            raise ValueError(
                f"--units {self.units!r} is not one of {', '.join(UNIT_SYSTEMS)} "
                "(the model's units: svZeroDSolver files do not state them)"
            )
        domain = Domain()
        check_range("helix parameter Omega", self.omega, "-", *domain.omega)
        check_range("cable shortening C", self.shortening, "-", *domain.shortening, lo_open=True)
        for section, keys in SHELL_EFFECTS.items():
            given = getattr(self, section)
            if given is None:
                continue
            if not isinstance(given, dict) or set(given) != set(keys):
                raise ValueError(
                    f"SoftPump {self.chamber}: {section} takes {', '.join(keys)}, not {given!r}"
                )
            for key, (unit, lo_open) in keys.items():
                check_range(f"{section}.{key}", given[key], unit, 0.0, lo_open=lo_open)

    def shell(self) -> tuple[ShellViscoelasticity | None, CableFriction | None]:
        """The shell's viscoelasticity and the cables' friction, each None unless given."""
        v, f = self.shell_viscoelasticity, self.cable_friction
        if v is not None:
            v = ShellViscoelasticity(v["stiffness_ratio"], v["relaxation_time_s"])
        return v, None if f is None else CableFriction(f["exponent"])


class SoftPump(Block):
    """The soft pump as a chamber of a model in its own units (module docstring). Ports: inlet
    and outlet, or the outlet alone (a bench's pump, filled and emptied through one port), all
    at the pump's pressure. States: its volume ``Vc:NAME`` (model units),
    ``dV/dt = Q_in - Q_out``, and with the shell's viscoelasticity the dashpot's volume
    ``Vd:NAME``; ``P = dU/dV (V, x(t); Omega)`` (plus the Maxwell branch's ``dU_v/dV``)
    converted to the model's units."""

    law: PumpChamber
    pressure_unit: jnp.ndarray = eqx.field(converter=jnp.asarray)
    """Pa per model pressure unit."""
    volume_unit: jnp.ndarray = eqx.field(converter=jnp.asarray)
    """m^3 per model volume unit."""
    viscoelasticity: ShellViscoelasticity | None = None
    friction: CableFriction | None = None
    """The cables' friction, seen by the force output only."""
    kind = "SoftPump"

    @property
    def n_states(self):
        return 1 + (self.viscoelasticity is not None)

    def state_kinds(self):
        return ("volume",) * self.n_states

    def internal_names(self):
        states = ("Vc", "Vd")[: self.n_states]
        return tuple(f"{v}:{self.name}" for v in (*states, "pull", "cable_force"))

    def _chamber(self, t):
        return self.law.pump.chamber(self.law.pull(t), self.law.omega)

    def _pressure(self, t, x):
        """The pump's pressure (model units) at the states ``x`` (model units)."""
        volume = x[0] * self.volume_unit
        chamber = self._chamber(t)
        pressure = chamber.pressure(volume)
        if self.viscoelasticity is not None:
            energy = self.viscoelasticity.energy
            pressure = pressure + jax.grad(energy, argnums=1)(
                chamber, volume, x[1] * self.volume_unit
            )
        return pressure / self.pressure_unit

    def residuals(self, t, x, P, Q, steady=False):
        pressure = self._pressure(t, x)
        return jnp.stack([P[0] - pressure, *(P[i] - P[0] for i in range(1, len(self.ports)))])

    def rates(self, t, x, P, Q, steady=False):
        inflow = Q[0] if len(self.ports) == 2 else 0.0
        rates = [inflow - Q[-1]]
        if self.viscoelasticity is not None:
            volume, relaxed = x[0] * self.volume_unit, x[1] * self.volume_unit
            rate = self.viscoelasticity.rate(self._chamber(t), volume, relaxed)
            rates.append(rate / self.volume_unit)
        return jnp.stack(rates)

    def states_from(self, values):
        return [values[name] for name in self.internal_names()[: self.n_states]]

    def outputs(self, t, x, P, Q):
        law, volume = self.law, x[0] * self.volume_unit
        seen = law.observe(t, volume)
        force = seen["cable_force"]
        if self.viscoelasticity is not None:
            energy = lambda pull: self.viscoelasticity.energy(  # noqa: E731
                law.pump.chamber(pull, law.omega), volume, x[1] * self.volume_unit
            )
            force = force + jax.grad(energy)(seen["pull"])
        if self.friction is not None:
            force = force * self.friction.factor(law.actuation.velocity(t - law.onset * law.period))
        names = self.internal_names()
        return {
            **{name: x[i] for i, name in enumerate(names[: self.n_states])},
            names[-2]: seen["pull"],
            names[-1]: force,
        }


def soft_pump(placement: PumpPlacement, ports, period: float, start_volume: float):
    """The :class:`SoftPump` block for ``placement`` between ``ports`` (the replaced chamber's
    nodes), beating at the model's ``period`` (s). ``start_volume``: the replaced chamber's
    initial volume (model units), checked against :data:`CHAMBER_VOLUMES`. Raises
    ``ValueError`` on a start volume that cannot be in the stated units."""
    pressure_unit, volume_unit, _, volume_name = UNIT_SYSTEMS[placement.units]
    volume = start_volume * volume_unit  # m^3
    lo, hi = CHAMBER_VOLUMES
    if not lo <= volume <= hi:
        others = [
            f"{start_volume * UNIT_SYSTEMS[u][1] / ml:.3g} ml in {u}"
            for u in UNIT_SYSTEMS
            if u != placement.units and lo <= start_volume * UNIT_SYSTEMS[u][1] <= hi
        ]
        hint = f"; it would be {' or '.join(others)}" if others else ""
        raise ValueError(
            f"Vc:{placement.chamber} = {start_volume:g} (the model's start volume) is "
            f"{volume / ml:.3g} ml in {placement.units} ({volume_name}), not a heart chamber's "
            f"({lo / ml:g} to {hi / ml:g} ml){hint}: pass the model's units with --units"
        )
    law = pump_law(placement, period)
    shell = placement.shell()
    return SoftPump(placement.chamber, tuple(ports), law, pressure_unit, volume_unit, *shell)


def pump_law(placement: PumpPlacement, period: float) -> PumpChamber:
    """The pump's chamber law (SI) for ``placement``, its pull beating at ``period`` (s)."""
    pump = load(placement.surrogate)
    stroke = placement.shortening * pump.cable_length(placement.omega)
    fractions = (placement.pull_fraction, placement.hold_fraction, placement.release_fraction)
    pull = CablePull(stroke, period, *fractions, placement.ramp_time, shape=placement.shape)
    return PumpChamber(pump, placement.omega, pull, placement.onset)


def pump_beat(traces, placement: PumpPlacement, nodes) -> tuple[np.ndarray, ...]:
    """The pump's samples in ``traces`` (one model's), SI whatever the model's units: its
    pressure (Pa, at its inlet node, or its outlet's for a pump with one port; ``nodes``: the
    network's), volume (m^3), cable force (N) and pull (m)."""
    name = placement.chamber
    pressure_unit, volume_unit = UNIT_SYSTEMS[placement.units][:2]
    touching = [node for node in nodes if name in node]
    inlet = ":".join(next((node for node in touching if node[1] == name), touching[0]))
    values = traces.values
    return (
        np.asarray(values[f"pressure:{inlet}"]) * pressure_unit,
        np.asarray(values[f"Vc:{name}"]) * volume_unit,
        np.asarray(values[f"cable_force:{name}"]),
        np.asarray(values[f"pull:{name}"]),
    )


def pump_metrics(traces, placement: PumpPlacement, nodes) -> dict:
    """The pump's beat from ``traces`` (the reported samples, one whole beat; ``nodes``: the
    network's, to find its inlet): :func:`~cardiosoft.network.block_metrics.pump_record`."""
    return pump_record(*pump_beat(traces, placement, nodes))


def pump_flags(metrics: dict) -> list[str]:
    """What not to take as it is: a pump pressure outside the surrogate's fitted range, a
    cable that would push (a negative force)."""
    lo, hi = Domain().pressure_mmHg
    out = []
    if metrics["min_pressure_mmHg"] < lo or metrics["max_pressure_mmHg"] > hi:
        out.append(
            f"pump pressure {metrics['min_pressure_mmHg']:.1f} to "
            f"{metrics['max_pressure_mmHg']:.1f} mmHg leaves the surrogate's fitted range "
            f"({lo:g} to {hi:g} mmHg): extrapolated"
        )
    if metrics["min_force_N"] < 0:
        out.append(f"cable force down to {metrics['min_force_N']:.2f} N: a cable that would push")
    return out


def placed_records(model, placement: PumpPlacement, traces) -> dict[str, dict]:
    """``{BLOCK: record}`` of one model's ``traces`` with the pump placed (its last beat is
    taken): the pump's record (:func:`pump_metrics`, under its chamber's name; the chamber's
    record in the model's units joins it), then every chamber's and vessel's
    (:func:`~cardiosoft.network.block_metrics.block_metrics`)."""
    from cardiosoft.network.block_metrics import block_metrics

    beat = traces.last_beat(model.simulation.points_per_cycle)
    net = model.network
    records = {placement.chamber: pump_metrics(beat, placement, net.nodes)}
    for name, record in block_metrics(net, beat).items():
        records[name] = {**record, **records.get(name, {})}
    return records


def pump_index(network, placement: PumpPlacement) -> int:
    """The index of the placed pump's block among ``network.blocks``."""
    return next(
        i
        for i, b in enumerate(network.blocks)
        if isinstance(b, SoftPump) and b.name == placement.chamber
    )


def with_designs(model, placement: PumpPlacement, omegas, shortenings):
    """The model's network once per design (``omegas``, ``shortenings``: arrays of Omega and
    C), the placed pump's helix and stroke set to each (its pull's timing stays): a batch of
    networks for :func:`cardiosoft.network.run.simulate`'s ``variants``, one program for any
    designs."""
    import jax

    net, index = model.network, pump_index(model.network, placement)

    def one(omega, shortening):
        law = net.blocks[index].law
        stroke = shortening * law.pump.cable_length(omega)
        return eqx.tree_at(
            lambda n: (n.blocks[index].law.omega, n.blocks[index].law.actuation.stroke),
            net,
            (omega, stroke),
        )

    return jax.vmap(one)(jnp.asarray(omegas, float), jnp.asarray(shortenings, float))


def with_pump_draws(model, placement: PumpPlacement, pump):
    """The model's network once per draw of the ensemble surrogate ``pump`` (a posterior's,
    :func:`cardiosoft.pump.load_posterior`: its drawn leaves carry a leading axis), the
    placed pump's surrogate replaced by each draw: a batch of networks for
    :func:`cardiosoft.network.run.simulate`'s ``variants``. The pull stays the placement's."""
    import jax

    from cardiosoft.ensemble import ensemble_axes

    net, index = model.network, pump_index(model.network, placement)

    def one(draw):
        return eqx.tree_at(lambda n: n.blocks[index].law.pump, net, draw)

    return jax.vmap(one, in_axes=(ensemble_axes(pump),))(pump)
