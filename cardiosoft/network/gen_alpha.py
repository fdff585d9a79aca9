"""svZeroDSolver's own time stepping: a read model stepped as svZeroDSolver steps it, for the
same digits (issue #40, "a generalized-alpha stepper with svZeroDSolver's settings").

:func:`cardiosoft.network.run.simulate` integrates a model to the preset's tolerance: its
answer is the model's converged one, and svZeroDSolver's differs from it by that solver's
error at its step (at 100 points a beat 5-13 % on the combined heart block). A user who moves a
model over and wants svZeroDSolver's numbers steps it here instead: the generalized-alpha
scheme for first-order systems (Jansen, Whiting and Hulbert 2000) with svZeroDSolver's settings
(``src/algebra/Integrator.cpp``), at its fixed step ``T / (N - 1)``, on the unknowns
``y = (x, z)``: the blocks' states and the nodes' pressures and flows.

- ``alpha_m = (3 - rho) / (2 (1 + rho))``, ``alpha_f = 1 / (1 + rho)``,
  ``gamma = 1/2 + alpha_m - alpha_f``, ``rho`` the model's ``rho_infty`` (0.5 by default).
- A step from ``(y_n, y'_n)`` at ``t_n``: the predictor keeps ``y`` and scales ``y'`` by
  ``1 - 1/gamma``; Newton on the increment of ``y'`` solves the residuals at
  ``t_n + alpha_f dt``, ``y_n + alpha_f (y - y_n)``, ``y'_n + alpha_m (y' - y'_n)``, with
  ``y = y_n + dt y'_n + gamma dt (y' - y'_n)``.
- The residuals are the network's: ``x' - rates(t, x, z)`` and the blocks' algebraic
  equations. svZeroDSolver writes some of them as other combinations of the same unknowns (a
  capacitor as ``C dP/dt = Q_in - Q_out``): a root of one is a root of the other, and the
  scheme's update is linear, so the steps agree wherever a block's state is a linear function
  of svZeroDSolver's variables. A stenosis's capacitor pressure ``P_in - (R + S |Q_in|) Q_in``
  is not: there the digits differ by the scheme's error.
- Newton runs to convergence (svZeroDSolver stops at ``absolute_tolerance`` of its residuals,
  1e-8 by default: the iterates differ below that).
- The start is svZeroDSolver's: the model's initial values as given (not made consistent) with
  ``y' = 0``, or, with ``steady_initial``, the steady state (svZeroDSolver marches 31 steps of a
  tenth of a period towards it; they end within its Newton tolerance of it, ``y'`` decayed by
  ``|1 - 1/gamma|^31``). A model with a chamber has no steady state (its activation keeps
  time): its start-up is marched here as svZeroDSolver marches it (:func:`steady_march`), ``y``,
  ``y'`` and the internal variables where the march leaves them.

A model whose index the network reduced (:func:`~cardiosoft.network.network.reduce_index`: a
source pinning a capacitor or an inductor) is stepped on its residuals as they are, as
svZeroDSolver steps it: the scheme's Newton solves the index-2 system, and its start from the
steady state takes the nodes solved with the states.

Refused: a ``BloodVessel`` with a stenosis ahead of its capacitor (svZeroDSolver steps the
capacitor's pressure through its nodes' unknowns, a nonlinear function of them: the digits would
differ by the scheme's error, 2.4e-2 of 1 + |y| on ``pulsatileFlow_CStenosis_steadyPressure``),
the combined heart block (svZeroDSolver resets its closed valves' flows after each Newton update,
``post_solve``), ``use_cycle_to_cycle_error`` without an RCR (whose beats run until the caps
settle) and ``output_derivative``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.network.blocks import BloodVessel
from cardiosoft.network.run import Traces, node_columns
from cardiosoft.network.simulation_parameters import UnsupportedModel
from cardiosoft.network.svzerod import Model

__all__ = ["MAX_NEWTON", "NEWTON_TOLERANCE", "coefficients", "step_as_svzerod"]

MAX_NEWTON = 30
"""Newton iterations a step at most (svZeroDSolver's ``maximum_nonlinear_iterations``)."""
NEWTON_TOLERANCE = 1e-13
"""Newton stops where its last increment of ``y`` is at most this fraction of ``1 + |y|``."""
REFUSED_BLOCKS = ("ClosedLoopHeartAndPulmonary",)


def coefficients(rho: float) -> tuple[float, float, float]:
    """``(alpha_m, alpha_f, gamma)`` of the scheme with spectral radius ``rho`` at infinity."""
    alpha_m = 0.5 * (3.0 - rho) / (1.0 + rho)
    alpha_f = 1.0 / (1.0 + rho)
    return alpha_m, alpha_f, 0.5 + alpha_m - alpha_f


def _residual(net, t, y, ydot, steady):
    n = net.n_states
    x, z = y[:n], y[n:]
    return jnp.concatenate(
        [ydot[:n] - net.rates(t, x, z, steady), net.residuals(t, x, z, steady)]
    )


@eqx.filter_jit
def _steps(net, y0, ydot0, dt, n_steps: int, rho: float, steady: bool = False):
    """``n_steps`` steps of ``dt`` from ``(y0, ydot0)`` at t = 0 (``steady``: of the steady
    start-up's equations): ``y`` at every step (the start first), the last ``y'``, and whether
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
        return (y, ydot), (y, i < MAX_NEWTON)

    (_, ydot), (ys, converged) = jax.lax.scan(step, (y0, ydot0), jnp.arange(n_steps))
    return jnp.concatenate([y0[None], ys]), ydot, jnp.all(converged)


def _output_names(net) -> list[str]:
    return [k for b in net.blocks for k in b.internal_names()]


@eqx.filter_jit
def _internal(net, ys, first: dict, dt, rho: float) -> dict:
    """The blocks' internal variables at every step, as svZeroDSolver's stepping leaves them. Each
    is one of its unknowns, fixed at the stage ``t_n + alpha_f dt`` by its block's equation and
    carried to the step's end linearly: ``v_(n+1) = v_n + (g(stage) - v_n) / alpha_f``. For one
    linear in ``y`` (a capacitor's pressure) that is ``g(y_(n+1))``; for one that is not (a valve's
    status, ``(1 + tanh(...)) / 2``) it is what svZeroDSolver reports, not ``g(y_(n+1))``."""
    _, alpha_f, _ = coefficients(rho)
    n = net.n_states
    stages = ys[:-1] + alpha_f * (ys[1:] - ys[:-1])
    t_af = (jnp.arange(ys.shape[0] - 1) + alpha_f) * dt
    g = jax.vmap(net.outputs)(t_af, stages[:, :n], stages[:, n:])
    if not g:  # no internal variables (vessels and junctions alone)
        return {}

    def carry(v, g_af):
        v = jax.tree.map(lambda a, b: a + (b - a) / alpha_f, v, g_af)
        return v, v

    first = {k: first[k] for k in g}
    _, rest = jax.lax.scan(carry, first, g)
    return {k: jnp.concatenate([first[k][None], rest[k]]) for k in g}


STEADY_MARCH = (31, 10)
"""svZeroDSolver's steady start-up (``Solver::setup_initial``): 31 steps of a tenth of a period,
on the steady equations, from the initial values as given."""


def marches(net) -> bool:
    """Whether the steady start-up of ``net`` is marched here as svZeroDSolver marches it: a
    network with a block whose equations keep time in the start-up (a chamber's activation,
    :attr:`~cardiosoft.network.blocks.Block.keeps_time`), which has no steady state to solve
    for."""
    return any(b.keeps_time for b in net.blocks)


def steady_march(net, y0, rho: float):
    """svZeroDSolver's steady start-up of ``net`` from ``y0`` (:data:`STEADY_MARCH`; ``rho``:
    the model's ``rho_infty``): ``y`` at every step, the last ``y'``, and whether every
    step's Newton converged."""
    steps, parts = STEADY_MARCH
    return _steps(net, y0, jnp.zeros_like(y0), net.period / parts, steps, rho, True)


def given_start(model: Model) -> jnp.ndarray:
    """``y`` as the model's initial values give it: the states, then the nodes' pressures and
    flows (not made consistent)."""
    net, initial = model.network, model.initial
    x0 = model.initial_states()
    names = [f"{up}:{down}" for up, down in net.nodes]
    z0 = [initial[f"pressure:{n}"] for n in names] + [initial[f"flow:{n}"] for n in names]
    return jnp.concatenate([x0, jnp.asarray(z0, dtype=x0.dtype)])


def _start(model: Model):
    """svZeroDSolver's first ``(y, y')``, its internal variables there, and whether its steady
    start-up converged (None without one): the initial values as given with ``y' = 0``; the
    steady start-up marched (:func:`marches`); or the steady state solved for, ``y' = 0``."""
    net, sim = model.network, model.simulation
    y0 = given_start(model)
    given = {k: jnp.asarray(model.initial[k], y0.dtype) for k in _output_names(net)}
    if not sim.steady_initial:
        return y0, jnp.zeros_like(y0), given, None
    if marches(net):
        ys, ydot, ok = steady_march(net, y0, sim.rho_infty)
        internal = _internal(net, ys, given, net.period / STEADY_MARCH[1], sim.rho_infty)
        return ys[-1], ydot, {k: v[-1] for k, v in internal.items()}, bool(ok)
    x0, z0, ok = net.steady_solution(model.initial_states())
    return jnp.concatenate([x0, z0]), jnp.zeros_like(y0), net.outputs(0.0, x0, z0), bool(ok)


def step_as_svzerod(model: Model) -> Traces:
    """``model`` stepped as svZeroDSolver steps it (module docstring), its variables at
    svZeroDSolver's output times. Raises :class:`UnsupportedModel` for a model it refuses."""
    net, sim = model.network, model.simulation
    kinds = {b.kind for b in net.blocks}
    refused = sorted(kinds & set(REFUSED_BLOCKS))
    if refused:
        raise UnsupportedModel(
            f"--as-svzerod: block type {refused[0]!r} is not stepped as svZeroDSolver steps it "
            "(its valves' flows are reset after each Newton update)"
        )
    stenosed = [
        b.name
        for b in net.blocks
        if isinstance(b, BloodVessel) and b.resistor_first and b.has_C and b.nonlinear
    ]
    if stenosed:
        raise UnsupportedModel(
            f"--as-svzerod: vessel {stenosed[0]} has a stenosis ahead of its capacitor, whose "
            "pressure P_in - (R + S|Q_in|) Q_in svZeroDSolver steps through its nodes' "
            "unknowns; the network steps that pressure itself, a nonlinear function of them, "
            "so the digits would differ by the scheme's error"
        )
    if sim.caps or sim.derivative:
        option = "use_cycle_to_cycle_error" if sim.caps else "output_derivative"
        raise UnsupportedModel(f"--as-svzerod: simulation option {option!r} is not supported")
    y0, ydot0, first, steady_start = _start(model)
    n_steps = sim.steps_per_cycle * sim.cycles
    dt = net.period / sim.steps_per_cycle
    ys, _, converged = _steps(net, y0, ydot0, dt, n_steps, sim.rho_infty)
    n = net.n_states
    internal = _internal(net, ys, first, dt, sim.rho_infty)
    t_all = dt * np.arange(n_steps + 1)
    keep = slice(None) if sim.output_all_cycles else slice(-sim.points_per_cycle, None)
    ts, ys = t_all[keep], ys[keep]
    values = node_columns(net, ys[:, n:])
    values.update({k: v[keep] for k, v in internal.items()})
    values = {k: np.asarray(v) for k, v in values.items()}
    time = ts if sim.output_all_cycles else ts - ts[0]
    return Traces(
        np.asarray(time), values, bool(converged), steady_start, n_steps, False,
        mean_only=sim.mean_only,
    )  # fmt: skip
