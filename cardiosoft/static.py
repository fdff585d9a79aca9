"""Quasi-static strokes: the pump pulled slowly against a water column, no ODE.

At each cable pull x the cavity volume V(x) is the root of

``P_pump(V, x) = P_a + k (V_0 - V)``,   ``k = rho g / A_col``

(the column level rises by the ejected volume over its cross-section; ``k = 0`` when the rise is
not modelled). ``P_pump`` increases with V (positive chamber stiffness) and the right-hand side
decreases, so the root is unique. It is found by a fixed number of scalar Newton steps and
differentiated by the implicit function theorem (:func:`implicit_scalar_root`).

The paper's static test (section II-F) measures the stroke volume SV as the rise of the column.
The mechanical work of the pull follows from the energy balance ``dU = F dx + P dV``:

``M = U(V_end, x_end) - U(V_0, 0) + P_a SV + k SV^2 / 2``

exactly, with no quadrature of the force curve.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from cardiosoft.pump import PumpSurrogate
from cardiosoft.roots import implicit_scalar_root

__all__ = [
    "QuasiStaticStroke",
    "column_stiffness",
    "implicit_scalar_root",
    "quasi_static_stroke",
    "static_strokes",
]

def column_stiffness(column_area, rho, g) -> jax.Array:
    """k = rho g / A_col (Pa/m^3): the head rise per ejected volume."""
    return rho * g / column_area


class QuasiStaticStroke(NamedTuple):
    """A quasi-static pull (SI). Arrays are over the pull grid ``x``."""

    x: jax.Array
    """Cable pull (m)."""
    volume: jax.Array
    """Cavity volume (m^3)."""
    pressure: jax.Array
    """Chamber pressure = column pressure at the base (Pa)."""
    force: jax.Array
    """Total cable force (N)."""
    stroke_volume: jax.Array
    """Volume ejected into the column at the end of the pull (m^3)."""
    peak_force: jax.Array
    """Largest force on the grid (N)."""
    mechanical_work: jax.Array
    """Integral of F dx over the pull (J), from the energy balance."""
    hydraulic_work: jax.Array
    """Integral of P dV_out (J): P_a SV plus the work of lifting the column, k SV^2 / 2."""


def _volume_at(pump: PumpSurrogate, x, omega, afterload, k, v0):
    def residual(v):
        return pump.pressure(v, x, omega) - afterload - k * (v0 - v)

    # Start from the root without the level rise: the residual is increasing in V, so Newton
    # converges from there (the chamber law is convex in V above V_eq, concave below).
    return implicit_scalar_root(residual, pump.volume(afterload, x, omega))


def quasi_static_stroke(
    pump: PumpSurrogate, omega, stroke, afterload, k=0.0, *, n_points: int = 401
) -> QuasiStaticStroke:
    """Pull the cables slowly from 0 to ``stroke`` (m) against an afterload (Pa).

    **Arguments:**

    - ``pump``: the :class:`~cardiosoft.pump.PumpSurrogate`.
    - ``omega``: helix parameter.
    - ``stroke``: final cable pull x (m), e.g. ``C * L(Omega)``.
    - ``afterload``: column pressure at the pump base before the pull (Pa).
    - ``k``: column stiffness ``rho g / A_col`` (Pa/m^3); 0 for a level that does not rise.
    - ``n_points``: pull grid size (static), for the force curve and the peak force.

    **Returns:** a :class:`QuasiStaticStroke`.
    """
    omega = jnp.asarray(omega, dtype=float)
    afterload = jnp.asarray(afterload, dtype=float)
    v0 = pump.volume(afterload, 0.0, omega)
    x = jnp.linspace(0.0, 1.0, n_points) * stroke
    volume = jax.vmap(lambda xi: _volume_at(pump, xi, omega, afterload, k, v0))(x)
    force = jax.vmap(lambda v, xi: pump.force(v, xi, omega))(volume, x)
    sv = v0 - volume[-1]
    hydraulic = afterload * sv + 0.5 * k * sv**2
    mech = pump.energy(volume[-1], x[-1], omega) - pump.energy(v0, 0.0, omega) + hydraulic
    return QuasiStaticStroke(
        x=x,
        volume=volume,
        pressure=afterload + k * (v0 - volume),
        force=force,
        stroke_volume=sv,
        peak_force=jnp.max(force),
        mechanical_work=mech,
        hydraulic_work=hydraulic,
    )


@eqx.filter_jit
def static_strokes(
    pump: PumpSurrogate, omega, shortening, afterload, k=0.0, friction=0.0, n_points: int = 401
):
    """Quasi-static strokes of a batch (leading axis) as the bench's load cell sees them.

    ``omega``, ``shortening`` (C) and ``afterload`` (column head, Pa) are 1-D arrays of equal
    length; ``k`` the column stiffness (Pa/m^3); ``friction`` the capstan exponent mu theta of
    :class:`~cardiosoft.circuit.CableFriction` (0 without friction): a slow pull meets the
    factor ``exp(mu theta)`` on the force and so on the work. ``n_points`` (static): the pull
    grid of each stroke (:func:`quasi_static_stroke`).

    **Returns:** ``(stroke_volume m^3, peak_force N, mech_work J, efficiency, max_pressure Pa)``,
    each per member: the efficiency the paper's ``P_a SV / M``, the largest pressure of the
    stroke's grid the head plus the column's rise (what the chamber law is evaluated at, for
    the check against the surrogate's fitted range).
    """

    def one(o, c, p):
        return quasi_static_stroke(pump, o, c * pump.cable_length(o), p, k, n_points=n_points)

    out = jax.vmap(one)(omega, shortening, afterload)
    factor = jnp.exp(friction)
    force, work = factor * out.peak_force, factor * out.mechanical_work
    efficiency = afterload * out.stroke_volume / work
    return out.stroke_volume, force, work, efficiency, jnp.max(out.pressure, axis=-1)
