"""The paper's bench line as a boundary condition of an svZeroDSolver model: the extension block
``WaterColumn`` (``bc_type``), which ``cardiosoft export --svzerod bench-dynamic`` writes and the
reader (:mod:`cardiosoft.network.svzerod`) takes. svZeroDSolver itself has no such block.

It is the silicone tube into the open water column (section II-F, Fig. 5;
:class:`~cardiosoft.circulation.Bench`), the same equations as the bench scene's network block
(:class:`~cardiosoft.network.bench.AfterloadLine`): the column's volume risen above its first
level V_col (``column_volume:NAME``), and with an inertance (the tube's, the column's) the flow
q through the line, ``L(V_col) dq/dt = P - rho g h(V_col) - R q - K q|q|``. Without one the
flow is algebraic. Its ``bc_values``, named as the scene files name them, so in the units their
names say whatever the model's:

- ``head_mmHg``: the column's head at the pump's base before the pull (mmHg);
- ``column_diameter_mm``, ``tube_length_mm``, ``tube_diameter_mm`` (mm), ``loss_coefficient``
  (the Borda-Carnot K, default 1);
- ``effects``: which of the line's terms are present
  (:data:`~cardiosoft.circulation.BENCH_EFFECTS`; the rest absent);
- ``units``: the model's units (:data:`~cardiosoft.network.pump_in_model.UNIT_SYSTEMS`, default
  cgs), in which the block meets its node and holds its states.

The fluid is water (:data:`~cardiosoft.units.RHO_WATER`, :data:`~cardiosoft.units.MU_WATER`),
as in the scenes.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from cardiosoft.circulation import BENCH_EFFECTS as EFFECTS
from cardiosoft.network.blocks import Block
from cardiosoft.network.pump_in_model import DEFAULT_UNITS, UNIT_SYSTEMS
from cardiosoft.units import mm, mmHg

REQUIRED = ("head_mmHg", "column_diameter_mm", "tube_length_mm", "tube_diameter_mm", "effects")
OPTIONAL = {"loss_coefficient": 1.0, "units": DEFAULT_UNITS}


class WaterColumnLine(Block):
    """The bench's line and column in a model's units: port (inlet,), at the pump's side.
    States: ``column_volume:NAME`` and, with an inertance, the line's flow (both in the model's
    volume unit, per second for the flow). The equations are ``line``'s, in SI."""

    line: Block
    """The bench's :class:`~cardiosoft.network.bench.AfterloadLine` (SI)."""
    pressure_unit: jnp.ndarray = eqx.field(converter=jnp.asarray)
    """Pa per model pressure unit."""
    volume_unit: jnp.ndarray = eqx.field(converter=jnp.asarray)
    """m^3 per model volume unit."""
    kind = "WaterColumn"
    nonlinear = True
    vessel = True

    @property
    def n_states(self):
        return self.line.n_states

    def state_kinds(self):
        return self.line.state_kinds()

    def internal_names(self):
        return (f"column_volume:{self.name}",)

    def _si(self, x, P, Q):
        """The states and the node's unknowns in SI (each a sequence of scalars)."""
        v, p = self.volume_unit, self.pressure_unit
        return [s * v for s in x], [pressure * p for pressure in P], [q * v for q in Q]

    def residuals(self, t, x, P, Q, steady=False):
        # the line's one equation is on the flow: Q - q
        return self.line.residuals(t, *self._si(x, P, Q), steady) / self.volume_unit

    def rates(self, t, x, P, Q, steady=False):
        # the rates of a volume and of a flow: both scale with the volume unit
        return self.line.rates(t, *self._si(x, P, Q), steady) / self.volume_unit

    def states_from(self, values):
        flow = [values["Q"][0]] if self.line.has_flow else []
        return [values[f"column_volume:{self.name}"], *flow]

    def outputs(self, t, x, P, Q):
        return {f"column_volume:{self.name}": x[0]}


def water_column(name: str, values: dict, ports) -> WaterColumnLine:
    """The ``WaterColumn`` boundary condition ``name`` from its ``bc_values`` (module docstring)
    at its node (``ports``: its (inlet, outlet) nodes; it has one). Raises ``ValueError``
    naming a value it cannot take."""
    from cardiosoft.circulation import Bench
    from cardiosoft.network.bench import AfterloadLine

    given = {k: v for k, v in values.items() if not k.startswith("_")}
    unknown = sorted(set(given) - set(REQUIRED) - set(OPTIONAL))
    missing = [k for k in REQUIRED if k not in given]
    if unknown or missing:
        what = f"unknown parameter {unknown[0]!r}" if unknown else f"{missing[0]!r} is required"
        raise ValueError(f"WaterColumn {name}: {what}")
    p = {**OPTIONAL, **given}
    effects = p["effects"]
    if not isinstance(effects, list) or any(e not in EFFECTS for e in effects):
        raise ValueError(f"WaterColumn {name}: effects {effects!r} are not a list of {EFFECTS}")
    if p["units"] not in UNIT_SYSTEMS:
        units = ", ".join(UNIT_SYSTEMS)
        raise ValueError(f"WaterColumn {name}: units {p['units']!r} is not one of {units}")
    nodes = (*ports[0], *ports[1])
    if len(nodes) != 1:
        raise ValueError(f"WaterColumn {name}: connected to {len(nodes)} blocks, not 1")
    sizes = (p[k] * mm for k in ("column_diameter_mm", "tube_length_mm", "tube_diameter_mm"))
    column, length, diameter = sizes
    afterload = Bench.of(
        column, p["head_mmHg"] * mmHg, length, diameter, p["loss_coefficient"], effects
    )
    y = afterload.init()
    has_flow = afterload.line_inertance(y) is not None
    if not has_flow and afterload.line_resistance(y) is None and afterload.line_loss(y) is None:
        raise ValueError(
            f"WaterColumn {name}: the line has neither inertance, resistance nor a minor loss, "
            "so its flow is undetermined; add tube_resistance or tube_inertia to its effects"
        )
    line = AfterloadLine(name, nodes, afterload, None, tuple(y), has_flow)
    pressure_unit, volume_unit = UNIT_SYSTEMS[p["units"]][:2]
    return WaterColumnLine(name, nodes, line, pressure_unit, volume_unit)
