"""Scalar roots that differentiate: Newton's method with the implicit function theorem."""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["implicit_scalar_root"]

NEWTON_STEPS = 40


def implicit_scalar_root(residual, start, n_steps: int = NEWTON_STEPS):
    """Root of a scalar, increasing ``residual(v)`` by Newton's method from ``start``.

    The iterations run under ``stop_gradient``; one more Newton step outside it gives the
    derivative of the root by the implicit function theorem, ``dv/dtheta = -r_theta / r_v``, in
    forward and reverse mode alike, without differentiating the loop. ``residual`` may close over
    the parameters being differentiated. A scalar needs no linear solver: a non-finite value
    propagates as NaN (for ``optax.apply_if_finite`` or a result mask) instead of raising.
    """

    def newton(v, _):
        r, dr = jax.jvp(residual, (v,), (jnp.ones_like(v),))
        return v - r / dr, None

    root, _ = jax.lax.scan(newton, jax.lax.stop_gradient(start), None, length=n_steps)
    root = jax.lax.stop_gradient(root)
    r, dr = jax.jvp(residual, (root,), (jnp.ones_like(root),))
    return root - r / jax.lax.stop_gradient(dr)
