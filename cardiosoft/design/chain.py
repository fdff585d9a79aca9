"""The refinement step of the design search as an optax chain (:func:`design_optimiser`).

The secondary objective's gradient, projected onto the null space of the residuals' Jacobian,
goes through Adam with a decaying learning rate; a Gauss-Newton step on the residuals (the
pseudo-inverse of their Jacobian, a least-squares step in ml) is added; the sum is clipped to a
trust radius.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import optax

__all__ = [
    "design_optimiser",
    "gauss_newton_step",
    "optimiser_step",
    "project_secondary",
    "trust_region",
]

_LEARNING_RATE = (0.3, 0.9, 0.005)
"""Adam's learning rate for the secondary objective: initial, decay per round, final (z)."""


def project_secondary() -> optax.GradientTransformationExtraArgs:
    """The objective's gradient minus its part that would change the residuals."""

    def update(updates, state, params=None, *, jacobian, mask, **extra):
        del params, extra
        jac = jacobian * mask
        null = jnp.eye(jac.shape[1], dtype=jac.dtype) - jnp.linalg.pinv(jac) @ jac
        return null @ (updates * mask), state

    return optax.GradientTransformationExtraArgs(lambda params: optax.EmptyState(), update)


def gauss_newton_step() -> optax.GradientTransformationExtraArgs:
    """Adds the least-squares (Gauss-Newton) step on the residuals: ``-J^+ r``."""

    def update(updates, state, params=None, *, residual, jacobian, mask, **extra):
        del params, extra
        step = -jnp.linalg.pinv(jacobian * mask) @ residual
        return updates + step * mask, state

    return optax.GradientTransformationExtraArgs(lambda params: optax.EmptyState(), update)


def trust_region() -> optax.GradientTransformationExtraArgs:
    """Clips the step to the candidate's trust radius (in z)."""

    def update(updates, state, params=None, *, radius, **extra):
        del params, extra
        norm = jnp.sqrt(jnp.sum(updates**2))
        return updates * jnp.minimum(1.0, radius / jnp.maximum(norm, 1e-300)), state

    return optax.GradientTransformationExtraArgs(lambda params: optax.EmptyState(), update)


def design_optimiser() -> optax.GradientTransformationExtraArgs:
    """The refinement step as an optax chain (:mod:`cardiosoft.design`, the method, step 3).

    ``update(objective_gradient, state, z, residual=r, jacobian=J, mask=m, radius=rho)`` for
    one candidate: ``r`` (K,) the residuals in ml, ``J`` (K, d) their derivatives in z, ``m``
    (d,) 1 for the variables that may move, ``rho`` the trust radius. The gradient of the
    secondary objective (zeros without one) is projected onto the null space of ``J`` and
    scaled by Adam with a decaying learning rate; the Gauss-Newton step ``-J^+ r`` is added;
    the sum is clipped to ``rho``.
    """
    first, decay, last = _LEARNING_RATE
    schedule = optax.exponential_decay(first, 1, decay, end_value=last)
    return optax.chain(
        project_secondary(),
        optax.scale_by_adam(),
        optax.scale_by_learning_rate(schedule),
        gauss_newton_step(),
        trust_region(),
    )


@functools.cache
def optimiser_step():
    opt = design_optimiser()

    def step(gradient, state, z, residual, jacobian, mask, radius):
        updates, state = opt.update(
            gradient, state, z, residual=residual, jacobian=jacobian, mask=mask, radius=radius
        )
        return z + updates, state

    return opt, jax.jit(jax.vmap(step))
