"""Scalar roots that differentiate: Newton's method with the implicit function theorem."""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["implicit_scalar_root"]

NEWTON_STEPS = 40


def implicit_scalar_root(
    residual, start, n_steps: int = NEWTON_STEPS, *, safeguard=None, has_aux: bool = False
):
    """Root of a scalar, increasing ``residual(v)`` by Newton's method from ``start``.

    The iterations run under ``stop_gradient``; one more Newton step outside it gives the
    derivative of the root by the implicit function theorem, ``dv/dtheta = -r_theta / r_v``, in
    forward and reverse mode alike, without differentiating the loop. ``residual`` may close over
    the parameters being differentiated. A scalar needs no linear solver: a non-finite value
    propagates as NaN (for ``optax.apply_if_finite`` or a result mask) instead of raising.

    - ``safeguard(v, v_next)``: the iterate to keep in place of a Newton step's ``v_next``
      (e.g. one kept inside the interval where the root must lie); default: the step.
    - ``has_aux``: ``residual`` returns ``(r, aux)``, aux a pytree of arrays that depend on v;
      returns ``(root, aux at the root)``, aux carried to the root along its tangent by the
      same last step, so that its derivative includes the root's.
    """
    with_aux = residual if has_aux else (lambda v: (residual(v), ()))

    def linearised(v):
        return jax.jvp(with_aux, (v,), (jnp.ones_like(v),))

    def newton(v, _):
        (r, _), (dr, _) = linearised(v)
        step = v - r / dr
        return (step if safeguard is None else safeguard(v, step)), None

    root, _ = jax.lax.scan(newton, jax.lax.stop_gradient(start), None, length=n_steps)
    root = jax.lax.stop_gradient(root)
    (r, aux), (dr, daux) = linearised(root)
    step = -r / jax.lax.stop_gradient(dr)
    if not has_aux:
        return root + step
    aux = jax.tree.map(lambda a, da: a + jax.lax.stop_gradient(da) * step, aux, daux)
    return root + step, aux
