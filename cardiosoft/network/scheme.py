"""svZeroDSolver's time-stepping scheme: the generalized-alpha step on a network's unknowns and
the steady start-up marched with it (``src/algebra/Integrator.cpp`` and
``Solver::setup_initial`` of ``SimVascular/svZeroDSolver``). The scheme, its settings and what
it reproduces are described in :mod:`cardiosoft.network.gen_alpha`, which steps whole models
with it; :func:`cardiosoft.network.run.simulate` starts a model with a chamber from its march.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

MAX_NEWTON = 30
"""Newton iterations a step at most (svZeroDSolver's ``maximum_nonlinear_iterations``)."""
NEWTON_TOLERANCE = 1e-13
"""Newton stops where its last increment of ``y`` is at most this fraction of ``1 + |y|``."""


def coefficients(rho: float) -> tuple[float, float, float]:
    """``(alpha_m, alpha_f, gamma)`` of the scheme with spectral radius ``rho`` at infinity."""
    alpha_m = 0.5 * (3.0 - rho) / (1.0 + rho)
    alpha_f = 1.0 / (1.0 + rho)
    return alpha_m, alpha_f, 0.5 + alpha_m - alpha_f


def _residual(net, t, y, ydot, steady):
    n = net.n_states
    x, z = y[:n], y[n:]
    mass, flux = net.mass_flux(t, x, z, steady)
    return jnp.concatenate([mass * ydot[:n] - flux, net.residuals(t, x, z, steady)])


@eqx.filter_jit
def steps(net, y0, ydot0, dt, n_steps: int, rho: float, steady: bool = False):
    """``n_steps`` steps of ``dt`` from ``(y0, ydot0)`` at t = 0 (``steady``: of the steady
    start-up's equations): ``y`` and ``y'`` at every step (the start first), and whether
    Newton converged at every step."""
    alpha_m, alpha_f, gamma = coefficients(rho)

    def step(carry, n):
        y_old, ydot_old = carry
        t_af = (n + alpha_f) * dt

        def advanced(ydot):  # the step's end for the rates ydot
            return y_old + dt * ydot_old + gamma * dt * (ydot - ydot_old)

        def residual(ydot):  # at the generalized mid-point; twice, as value and as aux
            y_af = y_old + alpha_f * (advanced(ydot) - y_old)
            r = _residual(net, t_af, y_af, ydot_old + alpha_m * (ydot - ydot_old), steady)
            return r, r

        def newton(state):
            i, ydot, _ = state
            jacobian, r = jax.jacfwd(residual, has_aux=True)(ydot)  # one evaluation
            delta = jnp.linalg.solve(jacobian, -r)
            return i + 1, ydot + delta, jnp.max(jnp.abs(gamma * dt * delta))

        def going(state):
            i, ydot, change = state
            scale = 1.0 + jnp.max(jnp.abs(advanced(ydot)))
            return (i < MAX_NEWTON) & (change > NEWTON_TOLERANCE * scale)

        predicted = ydot_old * (1.0 - 1.0 / gamma)  # svZeroDSolver's predictor: y kept
        start = (0, predicted, jnp.asarray(jnp.inf, dtype=y_old.dtype))
        i, ydot, _ = jax.lax.while_loop(going, newton, start)
        y = advanced(ydot)
        return (y, ydot), (y, ydot, i < MAX_NEWTON)

    _, (ys, ydots, converged) = jax.lax.scan(step, (y0, ydot0), jnp.arange(n_steps))
    first = (jnp.concatenate([y0[None], ys]), jnp.concatenate([ydot0[None], ydots]))
    return *first, jnp.all(converged)


STEADY_MARCH = (31, 10)
"""svZeroDSolver's steady start-up (``Solver::setup_initial``): 31 steps of a tenth of a period,
on the steady equations, from the initial values as given."""


def marches(net) -> bool:
    """Whether the steady start-up of ``net`` must be marched as svZeroDSolver marches it: a
    network with a block whose equations keep time in the start-up (a chamber's activation,
    :attr:`~cardiosoft.network.blocks.Block.keeps_time`), which has no steady state to solve
    for."""
    return any(b.keeps_time for b in net.blocks)


def steady_march(net, y0, rho: float):
    """svZeroDSolver's steady start-up of ``net`` from ``y0`` (:data:`STEADY_MARCH`; ``rho``:
    the model's ``rho_infty``): ``y`` and ``y'`` at every step, and whether every step's
    Newton converged."""
    count, parts = STEADY_MARCH
    return steps(net, y0, jnp.zeros_like(y0), net.period / parts, count, rho, True)


def given_start(model) -> jnp.ndarray:
    """``y`` as the model's initial values give it: the states, then the nodes' pressures and
    flows (not made consistent)."""
    net, initial = model.network, model.initial
    x0 = model.initial_states()
    names = [f"{up}:{down}" for up, down in net.nodes]
    z0 = [initial[f"pressure:{n}"] for n in names] + [initial[f"flow:{n}"] for n in names]
    return jnp.concatenate([x0, jnp.asarray(z0, dtype=x0.dtype)])
