"""The chamber law at one cable pull: the part of the pump's potential that holds the cavity
volume V (DESIGN.md section 3.2; the whole law and its reasons: :mod:`cardiosoft.pump`).

:meth:`cardiosoft.pump.PumpSurrogate.chamber` builds a :class:`Chamber` per pull; the vector
field of a simulation needs only its pressure, so the zero-pressure law is evaluated once per
call. SI throughout: V in m^3, pressure in Pa, energy in J.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from cardiosoft.roots import implicit_scalar_root

__all__ = ["SWELLING_WIDTH", "VOLUME_NEWTON_STEPS", "Chamber", "one_sided_ramp"]

SWELLING_WIDTH = 3e-6
"""Width (m^3, 3 ml) of the smooth onset of swelling, u(V); not fitted."""

VOLUME_NEWTON_STEPS = 12
"""Newton steps of :meth:`Chamber.volume`: the residual is nearly linear in V, and the steps
converge to round-off in 4-6 from the unswollen closed form (checked in tests/test_pump.py)."""


def _elementwise_derivative(fn, V):
    """d fn / dV of an elementwise ``fn``, in the broadcast shape of V and fn's numbers."""
    V = jnp.asarray(V, dtype=float)
    return jax.jvp(fn, (V,), (jnp.ones_like(V),))[1]


def _softplus(z):
    return jax.nn.softplus(z)


def one_sided_ramp(z) -> jax.Array:
    """``phi(z)``: 0 for z <= 0, ``z^3 - z^4 / 2`` on [0, 1], ``z - 1/2`` above (C2): a ramp
    that is exactly zero, with its slope and curvature, on one side of its onset."""
    onset = jnp.clip(z, 0.0, 1.0)
    return jnp.where(z >= 1.0, z - 0.5, onset**3 - 0.5 * onset**4)


class Chamber(eqx.Module):
    """The chamber law at one cable pull: what of U depends on the cavity volume V.

    ``U_c(V) = (E / beta^2) (cosh(beta s(V)) - 1)`` (J) with ``s = V - V_eq(V)``, the term
    ``Phi`` of the module docstring; :meth:`PumpSurrogate.chamber` builds it. The vector field
    of a simulation needs only this (its pressure), so the zero-pressure law is evaluated once
    per call.

    - ``rest_volume``: V_eq of a chamber that is not swollen (m^3): the zero-pressure volume
      of the folds at their full depth.
    - ``fold_drop``: f, the folds' share of ``-log(V_eq / V_u)`` that swelling can undo.
    - ``swelling``: k >= 0, how strongly a swollen chamber resists the folds.
    - ``unloaded_volume``: V_u (m^3): the chamber swells above it; the unit of the measure.
    - ``elastance``: E, the stiffness at zero pressure (Pa/m^3).
    - ``stiffening``: beta, how fast the chamber stiffens with distension (1/m^3).
    - ``softening``: a in [0, 1), how much a stretched membrane softens (0: the cosh law).
    - ``softening_scale``: s_a (m^3), the distension over which it softens.
    """

    rest_volume: jax.Array
    fold_drop: jax.Array
    swelling: jax.Array
    unloaded_volume: jax.Array
    elastance: jax.Array
    stiffening: jax.Array
    softening: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    softening_scale: jax.Array = eqx.field(converter=jnp.asarray, default=30e-6)

    def swelling_measure(self, V) -> jax.Array:
        """u(V) = w softplus((V - V_u) / w) / V_u >= 0 (dimensionless), w = SWELLING_WIDTH:
        how far V exceeds the unloaded cavity, smoothly, as a fraction of it."""
        w = SWELLING_WIDTH
        return w * _softplus((V - self.unloaded_volume) / w) / self.unloaded_volume

    def stretch(self, V) -> jax.Array:
        """e(V) >= 0 (m^3): how far V exceeds the unloaded cavity, the membrane's stretch.
        ``e = w phi((V - V_u) / w)`` with ``phi(z) = z^3 - z^4 / 2`` on [0, 1], 0 below and
        ``z - 1/2`` above (C2; w = SWELLING_WIDTH): exactly zero, with its slope, at and below
        V_u, so the softening leaves the shell at rest unloaded (``P(V_u, 0) = 0``)."""
        w = SWELLING_WIDTH
        return w * one_sided_ramp((V - self.unloaded_volume) / w)

    def equilibrium_volume(self, V) -> jax.Array:
        """V_eq(V) (m^3): the zero-pressure volume of the folds as deep as the chamber at
        volume V lets them be, ``V_eq0 exp(f (1 - exp(-k u(V))))`` (module docstring)."""
        return self.rest_volume * jnp.exp(
            -self.fold_drop * jnp.expm1(-self.swelling * self.swelling_measure(V))
        )

    def strain(self, V) -> jax.Array:
        """s = V - V_eq(V) (m^3): the chamber's distension from its zero-pressure volume."""
        return V - self.equilibrium_volume(V)

    def energy(self, V) -> jax.Array:
        """U_c (J) at cavity volume V (m^3): the cosh law in the distension s(V), less the
        membrane's softening in the stretch past V_u, e(V) (module docstring)."""
        beta, a, sa = self.stiffening, self.softening, self.softening_scale
        z = self.stretch(V) / sa
        log_cosh = jnp.logaddexp(z, -z) - jnp.log(2.0)
        membrane = a * sa**2 * (0.5 * z**2 - log_cosh)
        # format 3's expression as it was, so that its round-off is unchanged
        cosh_law = self.elastance / beta**2 * (jnp.cosh(beta * self.strain(V)) - 1.0)
        return cosh_law - self.elastance * membrane

    def pressure(self, V) -> jax.Array:
        """dU_c/dV (Pa), the chamber's elastic pressure: equal to dU/dV, as W does not hold V.
        Elementwise: ``V`` and the chamber's numbers may be arrays that broadcast."""
        return _elementwise_derivative(self.energy, V)

    def stiffness(self, V) -> jax.Array:
        """d2U/dV2 (Pa/m^3). ``E cosh(beta s)`` without swelling; with it, positive on the
        fitted domain by the fit's convexity constraint (``fit.fitting.check_convexity``)."""
        return _elementwise_derivative(self.pressure, V)

    def volume(self, pressure) -> jax.Array:
        """The cavity volume V (m^3) at ``pressure`` (Pa), unique where U is convex in V.

        Below V_u (no swelling, no softening), closed form: ``V = V_eq + asinh(beta P / E) /
        beta``. Above it, Newton on ``asinh(beta P(V) / E) / beta``, nearly linear in V, from
        that closed form, differentiated implicitly
        (:func:`cardiosoft.roots.implicit_scalar_root`).
        """
        beta, e = self.stiffening, self.elastance
        target = jnp.arcsinh(beta * pressure / e) / beta
        start = self.rest_volume + target

        def residual(V):
            return jnp.arcsinh(beta * self.pressure(V) / e) / beta - target

        return implicit_scalar_root(residual, start, VOLUME_NEWTON_STEPS)
