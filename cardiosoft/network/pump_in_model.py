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
"""

from __future__ import annotations

from dataclasses import dataclass

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from cardiosoft._validate import check_range
from cardiosoft.actuation import CablePull
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

    def __post_init__(self):
        if self.units not in UNIT_SYSTEMS:
            raise ValueError(
                f"--units {self.units!r} is not one of {', '.join(UNIT_SYSTEMS)} "
                "(the model's units: svZeroDSolver files do not state them)"
            )
        domain = Domain()
        check_range("helix parameter Omega", self.omega, "-", *domain.omega)
        check_range("cable shortening C", self.shortening, "-", *domain.shortening, lo_open=True)


class SoftPump(Block):
    """The soft pump as a chamber of a model in its own units (module docstring). Ports: inlet,
    outlet, both at the pump's pressure. State: its volume ``Vc:NAME`` (model units),
    ``dV/dt = Q_in - Q_out``; ``P = dU/dV (V, x(t); Omega)`` converted to the model's units."""

    law: PumpChamber
    pressure_unit: jnp.ndarray = eqx.field(converter=jnp.asarray)
    """Pa per model pressure unit."""
    volume_unit: jnp.ndarray = eqx.field(converter=jnp.asarray)
    """m^3 per model volume unit."""
    kind = "SoftPump"
    n_states = 1

    def state_kinds(self):
        return ("volume",)

    def internal_names(self):
        return tuple(f"{v}:{self.name}" for v in ("Vc", "pull", "cable_force"))

    def pressure(self, t, volume):
        """The pump's pressure (model units) at a volume in model units."""
        return self.law.pressure(t, volume * self.volume_unit) / self.pressure_unit

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([P[0] - self.pressure(t, x[0]), P[1] - P[0]])

    def rates(self, t, x, P, Q, steady=False):
        return jnp.stack([Q[0] - Q[1]])

    def states_from(self, values):
        return [values[f"Vc:{self.name}"]]

    def outputs(self, t, x, P, Q):
        seen = self.law.observe(t, x[0] * self.volume_unit)
        names = self.internal_names()
        return {names[0]: x[0], names[1]: seen["pull"], names[2]: seen["cable_force"]}


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
    return SoftPump(placement.chamber, tuple(ports), law, pressure_unit, volume_unit)


def pump_law(placement: PumpPlacement, period: float) -> PumpChamber:
    """The pump's chamber law (SI) for ``placement``, its pull beating at ``period`` (s)."""
    pump = load(placement.surrogate)
    stroke = placement.shortening * pump.cable_length(placement.omega)
    fractions = (placement.pull_fraction, placement.hold_fraction, placement.release_fraction)
    pull = CablePull(stroke, period, *fractions, shape=placement.shape)
    return PumpChamber(pump, placement.omega, pull, placement.onset)


def pump_beat(traces, placement: PumpPlacement, nodes) -> tuple[np.ndarray, ...]:
    """The pump's samples in ``traces`` (one model's), SI whatever the model's units: its
    pressure (Pa, at its inlet node; ``nodes``: the network's), volume (m^3), cable force (N)
    and pull (m)."""
    name = placement.chamber
    pressure_unit, volume_unit = UNIT_SYSTEMS[placement.units][:2]
    inlet = next(f"{up}:{down}" for up, down in nodes if down == name)
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
