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
  ``y' = 0``, or, with ``steady_initial``, its steady start-up marched as svZeroDSolver marches
  it (:func:`steady_march`: 31 steps of a tenth of a period on the steady equations, an RCR's
  capacitor switched off), ``y``, ``y'`` and the internal variables where the march leaves
  them. A coronary's or the combined heart's start-up is not reproduced step for step (their
  steady equations here give their steady state only): there the steady state is solved for,
  with ``y' = 0`` (svZeroDSolver's march ends within its Newton tolerance of it, ``y'`` decayed
  by ``|1 - 1/gamma|^31``).
- ``output_derivative``: every variable's ``y'`` as the scheme leaves it, ``ydot:NAME``.

A model whose index the network reduced (:func:`~cardiosoft.network.network.reduce_index`: a
source pinning a capacitor or an inductor) is stepped on its residuals as they are, as
svZeroDSolver steps it: the scheme's Newton solves the index-2 system, and its start from the
steady state takes the nodes solved with the states.

Refused: a ``BloodVessel`` with a stenosis ahead of its capacitor (svZeroDSolver steps the
capacitor's pressure through its nodes' unknowns, a nonlinear function of them: the digits would
differ by the scheme's error, 2.4e-2 of 1 + |y| on ``pulsatileFlow_CStenosis_steadyPressure``),
the combined heart block (svZeroDSolver resets its closed valves' flows after each Newton update,
``post_solve``), ``use_cycle_to_cycle_error`` without an RCR (whose beats run until the caps
settle) and ``output_derivative`` after a start-up solved for, not marched.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.network.blocks import BloodVessel
from cardiosoft.network.run import Traces, node_columns
from cardiosoft.network.scheme import (
    MAX_NEWTON,
    NEWTON_TOLERANCE,
    STEADY_MARCH,
    coefficients,
    given_start,
    marches,
    steady_march,
    steps,
)
from cardiosoft.network.simulation_parameters import UnsupportedModel
from cardiosoft.network.svzerod import Model

__all__ = [
    "MAX_NEWTON", "NEWTON_TOLERANCE", "STEADY_MARCH", "coefficients", "steady_march",
    "step_as_svzerod",
]  # fmt: skip

REFUSED_BLOCKS = ("ClosedLoopHeartAndPulmonary",)


def _output_names(net) -> list[str]:
    return [k for b in net.blocks for k in b.internal_names()]


@eqx.filter_jit
def _internal(net, ys, first: dict, first_rates: dict, dt, rho: float):
    """The blocks' internal variables at every step, as svZeroDSolver's stepping leaves them, and
    their rates. Each is one of its unknowns, fixed at the stage ``t_n + alpha_f dt`` by its
    block's equation and carried to the step's end linearly: ``v_(n+1) = v_n + (g(stage) - v_n)
    / alpha_f``. For one linear in ``y`` (a capacitor's pressure) that is ``g(y_(n+1))``; for one
    that is not (a valve's status, ``(1 + tanh(...)) / 2``) it is what svZeroDSolver reports, not
    ``g(y_(n+1))``. Its rate follows the scheme's update, ``v_(n+1) = v_n + dt v'_n + gamma dt
    (v'_(n+1) - v'_n)``, from ``first_rates``."""
    _, alpha_f, gamma = coefficients(rho)
    n = net.n_states
    stages = ys[:-1] + alpha_f * (ys[1:] - ys[:-1])
    t_af = (jnp.arange(ys.shape[0] - 1) + alpha_f) * dt
    g = jax.vmap(net.outputs)(t_af, stages[:, :n], stages[:, n:])
    if not g:  # no internal variables (vessels and junctions alone)
        return {}, {}

    def carry(state, g_af):
        v, vdot = state
        new = v + (g_af - v) / alpha_f
        new_rate = vdot + (new - v - dt * vdot) / (gamma * dt)
        return (new, new_rate), (new, new_rate)

    out = {}, {}
    for k in g:
        _, (values, rates) = jax.lax.scan(carry, (first[k], first_rates[k]), g[k])
        out[0][k] = jnp.concatenate([first[k][None], values])
        out[1][k] = jnp.concatenate([first_rates[k][None], rates])
    return out


def _start(model: Model):
    """svZeroDSolver's first ``y`` and ``y'``, its internal variables and their rates there,
    and how the steady start-up went (None without one; else whether it converged and whether
    it was marched). From the initial values as given with zero rates; with ``steady_initial``,
    svZeroDSolver's march (:func:`steady_march`) wherever every block's start-up is reproduced
    (:attr:`~cardiosoft.network.blocks.Block.marchable`) or must be (:func:`marches`), else the
    steady state solved for, with zero rates (a coronary, the combined heart)."""
    net, sim = model.network, model.simulation
    y0 = given_start(model)
    given = {k: jnp.asarray(model.initial[k], y0.dtype) for k in _output_names(net)}
    still = {k: jnp.zeros_like(v) for k, v in given.items()}
    if not sim.steady_initial:
        return y0, jnp.zeros_like(y0), given, still, None
    if marches(net) or all(b.marchable for b in net.blocks):
        ys, ydots, ok = steady_march(net, y0, sim.rho_infty)
        dt = net.period / STEADY_MARCH[1]
        internal, rates = _internal(net, ys, given, still, dt, sim.rho_infty)
        last = {k: v[-1] for k, v in internal.items()}
        return ys[-1], ydots[-1], last, {k: v[-1] for k, v in rates.items()}, (bool(ok), True)
    x0, z0, ok = net.steady_solution(model.initial_states())
    y = jnp.concatenate([x0, z0])
    return y, jnp.zeros_like(y), net.outputs(0.0, x0, z0), still, (bool(ok), False)


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
    if sim.caps:
        raise UnsupportedModel(
            "--as-svzerod: simulation option 'use_cycle_to_cycle_error' is not supported"
        )
    y0, ydot0, first, first_rates, start = _start(model)
    if sim.derivative and start is not None and not start[1]:
        raise UnsupportedModel(
            "--as-svzerod: simulation option 'output_derivative' with the steady start-up of a "
            "coronary or the combined heart, which is solved for here, not marched: the rates "
            "it starts from would not be svZeroDSolver's"
        )
    n_steps = sim.steps_per_cycle * sim.cycles
    dt = net.period / sim.steps_per_cycle
    ys, ydots, converged = steps(net, y0, ydot0, dt, n_steps, sim.rho_infty)
    n = net.n_states
    internal, rates = _internal(net, ys, first, first_rates, dt, sim.rho_infty)
    t_all = dt * np.arange(n_steps + 1)
    keep = slice(None) if sim.output_all_cycles else slice(-sim.points_per_cycle, None)
    ts = t_all[keep]
    values = node_columns(net, ys[keep, n:])
    values.update({k: v[keep] for k, v in internal.items()})
    if sim.derivative:  # svZeroDSolver's ydot of every variable, its scheme's
        values.update({f"ydot:{k}": v for k, v in node_columns(net, ydots[keep, n:]).items()})
        values.update({f"ydot:{k}": v[keep] for k, v in rates.items()})
    values = {k: np.asarray(v) for k, v in values.items()}
    time = ts if sim.output_all_cycles else ts - ts[0]
    return Traces(
        np.asarray(time), values, bool(converged), None if start is None else start[0],
        n_steps, False,
        mean_only=sim.mean_only,
    )  # fmt: skip
