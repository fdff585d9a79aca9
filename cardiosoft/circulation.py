"""Afterloads and preloads (DESIGN.md section 3.3; the bench of paper section II-F). The valves
between them and the pump are in :mod:`cardiosoft.valves`.

Everything is SI: pressures in Pa, flows in m^3/s, volumes in m^3, resistances in Pa s/m^3,
compliances in m^3/Pa, inertances in Pa s^2/m^3. Error messages use the clinical units
(mmHg s/ml, ml/mmHg, mmHg s^2/ml, mm).

Afterload protocol
------------------
An afterload is a series line (inertance L, linear resistance R, quadratic loss K) in front of a
compliant node with its own state ``y`` (a dict of scalars). For an inflow ``q`` entering at the
inlet::

    p_inlet = L(y) dq/dt + R(y) q + K(y) q |q| + node_pressure(y)        (see inlet_pressure)
    dy/dt   = node_rhs(y, q)

A term that the block does not model is ``None``, decided by static fields only: the effect is
absent from the traced computation, not multiplied by zero. ``stored_volume(y)`` is the fluid the
block holds relative to rest plus what it has drained, so that ``stored_volume(y(t)) -
stored_volume(y(0))`` equals the integral of the inflow (volume bookkeeping).

When L is present, ``q`` is the flow through the inertance and becomes a state of the composed
system: the composer solves ``L dq/dt = p_pump - R q - K q|q| - node_pressure``.

Preload protocol
----------------
``init()``, ``pressure(y)`` (Pa, the filling pressure seen by the inlet valve), ``rhs(y, q_out)``
for the flow ``q_out`` leaving towards the pump, ``stored_volume(y)`` (held relative to rest minus
what the external source supplied, so that its time derivative is ``-q_out``).
"""

from __future__ import annotations

import abc
import math

import equinox as eqx
import jax
import jax.numpy as jnp

from cardiosoft._validate import check_positive, check_range
from cardiosoft.units import (
    MU_WATER,
    RHO_WATER,
    G,
    ml_per_mmHg,
    mm,
    mmHg,
    mmHg_s2_per_ml,
    mmHg_s_per_ml,
)

__all__ = [
    "BENCH_EFFECTS",
    "AbstractAfterload",
    "AbstractPreload",
    "AtrialCompliance",
    "AtrialSource",
    "Bench",
    "Tube",
    "WaterColumn",
    "Windkessel2",
    "Windkessel3",
    "Windkessel4",
    "inlet_pressure",
]

BENCH_EFFECTS = ("column_rise", "column_inertia", "tube_inertia", "tube_resistance", "minor_loss")
"""The terms of the bench's line and column (:meth:`Bench.of`), as the scene files name them."""

_R = mmHg_s_per_ml
_C = ml_per_mmHg
_L = mmHg_s2_per_ml
_INF = math.inf


def _resistance(name, v):
    check_positive(name, v, "mmHg s/ml", scale=_R)


def _compliance(name, v):
    check_positive(name, v, "ml/mmHg", scale=_C)


def _pressure(name, v):
    check_range(name, v, "mmHg", -_INF, _INF, scale=mmHg)  # any finite value


def _add(a, b):
    """Sum of two optional series terms: None + None = None, None + x = x."""
    if a is None:
        return b
    if b is None:
        return a
    return a + b


def _zero():
    return jnp.zeros((), dtype=jnp.result_type(float))


class AbstractAfterload(eqx.Module):
    """The afterload protocol; see the module docstring."""

    @abc.abstractmethod
    def init(self) -> dict[str, jax.Array]:
        """Block state at rest (SI); may be ``{}``."""

    @abc.abstractmethod
    def node_pressure(self, y) -> jax.Array:
        """Pressure at the compliant node (Pa)."""

    @abc.abstractmethod
    def node_rhs(self, y, q) -> dict[str, jax.Array]:
        """dy/dt for an inflow ``q`` (m^3/s)."""

    @abc.abstractmethod
    def line_inertance(self, y) -> jax.Array | None:
        """Series inertance at the inlet (Pa s^2/m^3), or None when absent."""

    @abc.abstractmethod
    def line_resistance(self, y) -> jax.Array | None:
        """Linear series resistance (Pa s/m^3), or None when absent."""

    @abc.abstractmethod
    def line_loss(self, y) -> jax.Array | None:
        """K (Pa s^2/m^6) of a quadratic series drop ``K q |q|``, or None when absent."""

    @abc.abstractmethod
    def stored_volume(self, y) -> jax.Array:
        """Fluid held relative to rest plus fluid drained (m^3)."""


def inlet_pressure(block: AbstractAfterload, y, q, dqdt=None) -> jax.Array:
    """Inlet pressure ``L dq/dt + R q + K q|q| + node_pressure`` (Pa); absent terms are skipped.

    ``dqdt`` (m^3/s^2) is required only when the block has an inertance.
    """
    p = block.node_pressure(y)
    L = block.line_inertance(y)
    if L is not None:
        if dqdt is None:
            raise ValueError("this afterload has a series inertance: pass dqdt")
        p = p + L * dqdt
    R = block.line_resistance(y)
    if R is not None:
        p = p + R * q
    K = block.line_loss(y)
    if K is not None:
        p = p + K * q * jnp.abs(q)
    return p


class WaterColumn(AbstractAfterload):
    """The paper's open water column (section II-F, Fig. 5) fed at the pump's base.

    **Arguments:**

    - ``diameter``: inner diameter of the column (m). Not given in the paper: a scene parameter.
    - ``head``: initial afterload pressure at the pump base (Pa), ``rho g h0`` (30/60/90 mmHg).
    - ``rho``: density (kg/m^3), water by default; ``g``: gravity (m/s^2).
    - ``rise`` (static): the level rises with the ejected volume, ``h = h0 + V / A``.
      Otherwise the head stays ``rho g h0``.
    - ``inertia`` (static): the column's inertance ``rho h / A`` in series at the inlet.

    State: ``{"column_volume"}``, the volume risen above the initial level (m^3); tracked in
    both cases since it is the measured output (dynamic SV is its peak).
    """

    diameter: jax.Array = eqx.field(converter=jnp.asarray)
    head: jax.Array = eqx.field(converter=jnp.asarray)
    rho: jax.Array = eqx.field(converter=jnp.asarray, default=RHO_WATER)
    g: jax.Array = eqx.field(converter=jnp.asarray, default=G)
    rise: bool = eqx.field(static=True, default=True)
    inertia: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        check_positive("column diameter", self.diameter, "mm", scale=mm)
        check_range("column head", self.head, "mmHg", 0.0, _INF, scale=mmHg)
        check_positive("column fluid density rho", self.rho, "kg/m^3")
        check_positive("gravity g", self.g, "m/s^2")

    @property
    def area(self) -> jax.Array:
        """Cross-section of the column (m^2)."""
        return 0.25 * jnp.pi * self.diameter**2

    @property
    def h0(self) -> jax.Array:
        """Initial height of the water above the pump base (m)."""
        return self.head / (self.rho * self.g)

    def height(self, y) -> jax.Array:
        """Current height of the water above the pump base (m)."""
        if self.rise:
            return self.h0 + y["column_volume"] / self.area
        return self.h0

    def init(self):
        return {"column_volume": _zero()}

    def node_pressure(self, y):
        return self.rho * self.g * self.height(y)

    def node_rhs(self, y, q):
        return {"column_volume": q}

    def line_inertance(self, y):
        return self.rho * self.height(y) / self.area if self.inertia else None

    def line_resistance(self, y):
        return None

    def line_loss(self, y):
        return None

    def stored_volume(self, y):
        return y["column_volume"]


class Tube(eqx.Module):
    """A rigid straight tube: a series line element, no state (DESIGN.md section 3.3).

    **Arguments:**

    - ``length``, ``diameter``: inner sizes (m). Not given in the paper: scene parameters.
    - ``rho`` (kg/m^3), ``mu`` (Pa s): the fluid, water by default.
    - ``loss_coefficient``: dimensionless Borda-Carnot K of the minor losses, >= 0; 1 (default)
      is the exit loss into a much wider column.
    - ``inertia``, ``resistance``, ``minor_loss`` (static): which terms are present.

    Terms: inertance ``rho l / A``, Poiseuille resistance ``8 mu l / (pi r^4)``, quadratic loss
    ``K_q = K rho / (2 A^2)`` so that ``dp = K_q q |q|``. The methods take an (ignored) state so
    that a tube reads like the line part of an afterload.
    """

    length: jax.Array = eqx.field(converter=jnp.asarray)
    diameter: jax.Array = eqx.field(converter=jnp.asarray)
    rho: jax.Array = eqx.field(converter=jnp.asarray, default=RHO_WATER)
    mu: jax.Array = eqx.field(converter=jnp.asarray, default=MU_WATER)
    loss_coefficient: jax.Array = eqx.field(converter=jnp.asarray, default=1.0)
    inertia: bool = eqx.field(static=True, default=True)
    resistance: bool = eqx.field(static=True, default=True)
    minor_loss: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        check_positive("tube length", self.length, "mm", scale=mm)
        check_positive("tube diameter", self.diameter, "mm", scale=mm)
        check_positive("tube fluid density rho", self.rho, "kg/m^3")
        check_positive("tube fluid viscosity mu", self.mu, "Pa s")
        check_range("tube loss coefficient K", self.loss_coefficient, "-", 0.0)

    @property
    def area(self) -> jax.Array:
        """Cross-section (m^2)."""
        return 0.25 * jnp.pi * self.diameter**2

    def line_inertance(self, y=None):
        return self.rho * self.length / self.area if self.inertia else None

    def line_resistance(self, y=None):
        if not self.resistance:
            return None
        return 8.0 * self.mu * self.length / (jnp.pi * (0.5 * self.diameter) ** 4)

    def line_loss(self, y=None):
        if not self.minor_loss:
            return None
        return self.loss_coefficient * self.rho / (2.0 * self.area**2)


class Bench(AbstractAfterload):
    """The paper's rig: a :class:`Tube` in series in front of an afterload (the water column).

    Any afterload works as ``column``; the line terms are summed, absent terms stay absent.
    """

    tube: Tube
    column: AbstractAfterload

    def init(self):
        return self.column.init()

    def node_pressure(self, y):
        return self.column.node_pressure(y)

    def node_rhs(self, y, q):
        return self.column.node_rhs(y, q)

    def line_inertance(self, y):
        return _add(self.tube.line_inertance(y), self.column.line_inertance(y))

    def line_resistance(self, y):
        return _add(self.tube.line_resistance(y), self.column.line_resistance(y))

    def line_loss(self, y):
        return _add(self.tube.line_loss(y), self.column.line_loss(y))

    def stored_volume(self, y):
        return self.column.stored_volume(y)  # a rigid tube holds a constant volume

    @classmethod
    def of(
        cls, column_diameter, head, tube_length, tube_diameter, loss_coefficient, effects
    ) -> Bench:
        """The paper's rig (SI) with those of :data:`BENCH_EFFECTS` named in ``effects``
        present, the others absent."""
        column = WaterColumn(
            column_diameter,
            head,
            rise="column_rise" in effects,
            inertia="column_inertia" in effects,
        )
        tube = Tube(
            tube_length,
            tube_diameter,
            loss_coefficient=loss_coefficient,
            inertia="tube_inertia" in effects,
            resistance="tube_resistance" in effects,
            minor_loss="minor_loss" in effects,
        )
        return cls(tube, column)


def _wk_init(p_venous):
    return {"pc": p_venous + _zero(), "drained_volume": _zero()}


def _wk_rhs(C, Rd, p_venous, y, q):
    q_out = (y["pc"] - p_venous) / Rd
    return {"pc": (q - q_out) / C, "drained_volume": q_out}


def _wk_stored(C, p_venous, y):
    return C * (y["pc"] - p_venous) + y["drained_volume"]


class Windkessel2(AbstractAfterload):
    """Two-element Windkessel: compliance ``C`` drained through ``R`` to ``p_venous``.

    ``C dpc/dt = q - (pc - p_venous) / R``; inlet pressure = pc. Defaults: the systemic values
    of DESIGN.md with R = Rp + Rd = 1.1 mmHg s/ml, C = 1.3 ml/mmHg (stored in SI).

    State: ``{"pc", "drained_volume"}`` (Pa, m^3); at rest pc = p_venous.
    """

    R: jax.Array = eqx.field(converter=jnp.asarray, default=1.1 * _R)
    C: jax.Array = eqx.field(converter=jnp.asarray, default=1.3 * _C)
    p_venous: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)

    def __check_init__(self):
        _resistance("Windkessel resistance R", self.R)
        _compliance("Windkessel compliance C", self.C)
        _pressure("venous pressure p_venous", self.p_venous)

    def init(self):
        return _wk_init(self.p_venous)

    def node_pressure(self, y):
        return y["pc"]

    def node_rhs(self, y, q):
        return _wk_rhs(self.C, self.R, self.p_venous, y, q)

    def line_inertance(self, y):
        return None

    def line_resistance(self, y):
        return None

    def line_loss(self, y):
        return None

    def stored_volume(self, y):
        return _wk_stored(self.C, self.p_venous, y)


class Windkessel3(AbstractAfterload):
    """Three-element Windkessel: ``Rp`` in series, then ``C`` drained through ``Rd``.

    Inlet pressure = Rp q + pc; ``C dpc/dt = q - (pc - p_venous) / Rd``. Defaults: systemic,
    Rp 0.05 mmHg s/ml, C 1.3 ml/mmHg, Rd 1.05 mmHg s/ml (DESIGN.md section 3.3), stored in SI;
    see :meth:`systemic` and :meth:`pulmonary`.

    State: ``{"pc", "drained_volume"}`` (Pa, m^3); at rest pc = p_venous.
    """

    Rp: jax.Array = eqx.field(converter=jnp.asarray, default=0.05 * _R)
    C: jax.Array = eqx.field(converter=jnp.asarray, default=1.3 * _C)
    Rd: jax.Array = eqx.field(converter=jnp.asarray, default=1.05 * _R)
    p_venous: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)

    def __check_init__(self):
        _resistance("Windkessel proximal resistance Rp", self.Rp)
        _compliance("Windkessel compliance C", self.C)
        _resistance("Windkessel distal resistance Rd", self.Rd)
        _pressure("venous pressure p_venous", self.p_venous)

    @classmethod
    def systemic(cls, p_venous=0.0) -> Windkessel3:
        """Rp 0.05 mmHg s/ml, C 1.3 ml/mmHg, Rd 1.05 mmHg s/ml."""
        return cls(0.05 * _R, 1.3 * _C, 1.05 * _R, p_venous)

    @classmethod
    def pulmonary(cls, p_venous=0.0) -> Windkessel3:
        """Rp 0.012 mmHg s/ml, C 4 ml/mmHg, Rd 0.3 mmHg s/ml."""
        return cls(0.012 * _R, 4.0 * _C, 0.3 * _R, p_venous)

    def init(self):
        return _wk_init(self.p_venous)

    def node_pressure(self, y):
        return y["pc"]

    def node_rhs(self, y, q):
        return _wk_rhs(self.C, self.Rd, self.p_venous, y, q)

    def line_inertance(self, y):
        return None

    def line_resistance(self, y):
        return self.Rp

    def line_loss(self, y):
        return None

    def stored_volume(self, y):
        return _wk_stored(self.C, self.p_venous, y)


class Windkessel4(AbstractAfterload):
    """Four-element Windkessel, inertance ``L`` in series at the inlet (the "series" variant).

    Inlet pressure = L dq/dt + Rp q + pc; ``C dpc/dt = q - (pc - p_venous) / Rd``. All of
    ``Rp`` (Pa s/m^3), ``C`` (m^3/Pa), ``Rd`` (Pa s/m^3), ``L`` (Pa s^2/m^3) are required.

    State: ``{"pc", "drained_volume"}`` (Pa, m^3); at rest pc = p_venous.
    """

    Rp: jax.Array = eqx.field(converter=jnp.asarray)
    C: jax.Array = eqx.field(converter=jnp.asarray)
    Rd: jax.Array = eqx.field(converter=jnp.asarray)
    L: jax.Array = eqx.field(converter=jnp.asarray)
    p_venous: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)

    def __check_init__(self):
        _resistance("Windkessel proximal resistance Rp", self.Rp)
        _compliance("Windkessel compliance C", self.C)
        _resistance("Windkessel distal resistance Rd", self.Rd)
        check_positive("Windkessel inertance L", self.L, "mmHg s^2/ml", scale=_L)
        _pressure("venous pressure p_venous", self.p_venous)

    def init(self):
        return _wk_init(self.p_venous)

    def node_pressure(self, y):
        return y["pc"]

    def node_rhs(self, y, q):
        return _wk_rhs(self.C, self.Rd, self.p_venous, y, q)

    def line_inertance(self, y):
        return self.L

    def line_resistance(self, y):
        return self.Rp

    def line_loss(self, y):
        return None

    def stored_volume(self, y):
        return _wk_stored(self.C, self.p_venous, y)


class AbstractPreload(eqx.Module):
    """The preload protocol; see the module docstring."""

    @abc.abstractmethod
    def init(self) -> dict[str, jax.Array]:
        """State at rest (SI)."""

    @abc.abstractmethod
    def pressure(self, y) -> jax.Array:
        """Filling pressure (Pa)."""

    @abc.abstractmethod
    def rhs(self, y, q_out) -> dict[str, jax.Array]:
        """dy/dt for a flow ``q_out`` (m^3/s) leaving towards the pump."""

    @abc.abstractmethod
    def stored_volume(self, y) -> jax.Array:
        """Held relative to rest minus supplied (m^3); its rate is ``-q_out``."""


class AtrialSource(AbstractPreload):
    """A constant filling pressure ``pressure`` (Pa), stored as the field ``p_atrial`` (the
    name ``pressure`` is the protocol's method).

    State: ``{"supplied_volume"}``, the volume it has delivered (m^3).
    """

    p_atrial: jax.Array

    def __init__(self, pressure):
        self.p_atrial = jnp.asarray(pressure)

    def __check_init__(self):
        _pressure("atrial pressure", self.p_atrial)

    def init(self):
        return {"supplied_volume": _zero()}

    def pressure(self, y):
        return self.p_atrial

    def rhs(self, y, q_out):
        return {"supplied_volume": q_out}

    def stored_volume(self, y):
        return -y["supplied_volume"]


class AtrialCompliance(AbstractPreload):
    """A compliance ``C`` (m^3/Pa) filled from ``p_venous`` (Pa) through ``R_venous`` (Pa s/m^3).

    ``C dpa/dt = (p_venous - pa) / R_venous - q_out``. State: ``{"pa", "supplied_volume"}``
    (Pa, m^3; the latter is what the venous side delivered); at rest pa = p_venous.
    """

    C: jax.Array = eqx.field(converter=jnp.asarray)
    p_venous: jax.Array = eqx.field(converter=jnp.asarray)
    R_venous: jax.Array = eqx.field(converter=jnp.asarray)

    def __check_init__(self):
        _compliance("atrial compliance C", self.C)
        _pressure("venous pressure p_venous", self.p_venous)
        _resistance("venous resistance R_venous", self.R_venous)

    def init(self):
        return {"pa": self.p_venous + _zero(), "supplied_volume": _zero()}

    def pressure(self, y):
        return y["pa"]

    def rhs(self, y, q_out):
        q_in = (self.p_venous - y["pa"]) / self.R_venous
        return {"pa": (q_in - q_out) / self.C, "supplied_volume": q_in}

    def stored_volume(self, y):
        return self.C * (y["pa"] - self.p_venous) - y["supplied_volume"]
