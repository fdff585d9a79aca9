"""The periodic steady state by Newton shooting on the one-beat map, and the orbit's implicit
derivative: the beats themselves are integrated by :mod:`cardiosoft.solve` (the one module that
calls ``diffrax.diffeqsolve``) through :mod:`cardiosoft.periodic`'s beat; this module only asks
for one beat at a time.

:func:`shoot_periodic` finds the periodic state of a scene's vector field (``steady="shooting"``
of :func:`cardiosoft.batch.solve_beats`); :func:`orbit_beat` integrates one beat from a periodic
state with the derivative of the orbit taken implicitly at that state (the design search's
derivative program).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp

from cardiosoft.periodic import (
    ACCUMULATORS,
    PERIODIC_SCALES,
    Beats,
    _cycle_residual,
    _finite_or_failed,
    _one_beat,
    _phases,
    periodic_beats,
)
from cardiosoft.solve import SUCCESSFUL, SolverConfig, preset

__all__ = ["orbit_beat", "shoot_periodic"]


def shoot_periodic(
    field,
    y0,
    period,
    ts,
    *,
    jump_ts,
    total_volume,
    closed: bool,
    guess_beats: int,
    max_beats: int,
    tol,
    config: SolverConfig | None = None,
    observe: Callable[[jax.Array, dict], Any] | None = None,
    max_newton: int = 8,
) -> Beats:
    """The periodic steady state by Newton shooting on the one-beat map, then its last beat.

    1. ``guess_beats`` beats from ``y0`` (beat after beat; fewer if already steady): the guess.
    2. Newton's method (:func:`_newton`) on ``u -> Phi(u) - u``, ``Phi`` the state one
       beat later, in the periodic states of :data:`PERIODIC_SCALES` divided by their scales
       (ml, ml/s, mmHg); its Jacobian comes from forward-mode derivatives of the beat (a 2-5
       dimensional state; 11 in a closed loop). ``closed``: the circuit conserves its total
       fluid volume (no preload), so the orbits form a family, one per total; the first state
       named ``volume`` (the pump's; a closed loop's left atrium's) is then eliminated,
       ``V = total_volume(y0) - (total_volume(y) - V)``. Accumulators
       (:data:`ACCUMULATORS`) are bookkeeping, read by nothing but the volume check: with a
       preload (an open circuit, whose total the orbit does not fix) the first is re-based so
       that the total volume is that of ``y0``. Left at its guessed value, Newton's move of the
       pump volume and the Windkessel pressure showed as a volume drift of up to 0.78
       (relative; lv-systemic and rv-pulmonary at 240-300 bpm), now ~1e-15.
    3. From the orbit (where Newton stopped short of its tolerance, from its iterate that one
       beat changes least, the guess's end among them), beat
       after beat as in :func:`periodic_beats` until the cycle-to-cycle change is below
       ``tol``, at most ``max_beats``: at a converged orbit that is two beats (the steady
       test); otherwise beat after beat is the fallback, and ``residual`` says how it ended.
       The last beat is then integrated once more with its samples, by :func:`orbit_beat`;
       with ``ts`` None it is not, and ``y0``, the orbit's start, is what carries the orbit's
       derivative.

    **Derivatives** (``jax.jvp``/``jacfwd`` of anything downstream) are the periodic orbit's,
    ``dy*/dtheta = -(dPhi/dy - I)^-1 dPhi/dtheta`` (implicit function theorem), taken at the
    last beat's start: at Newton's root when it converged, where the fallback's beats ended
    when it did not (there the beats before it were measured wrong in sign: -663 against 175.7
    ml per unit C on the ringing bench, ``tests/test_batch.py``). Steps 1-3 run on inputs cut
    from differentiation; only :func:`orbit_beat` carries tangents (tracing tangents through
    every beat took about 40 % more tracing, #13).

    ``beats`` counts the beats of steps 1 and 3; ``newton_steps`` the iterations of step 2 (each
    costs about one beat per state component more). The arguments are those of
    :func:`periodic_beats`.
    """
    config = preset("default") if config is None else config
    v_ref = total_volume(y0)
    field_f, y0_f, period_f, jump_ts_f, v_ref_f = _frozen((field, y0, period, jump_ts, v_ref))
    beats = dict(jump_ts=jump_ts_f, total_volume=total_volume, tol=tol, config=config)
    guess = periodic_beats(field_f, y0_f, period_f, None, max_beats=guess_beats, **beats)
    unknowns = _Unknowns(guess.y_end, closed, total_volume)

    def beat_map(u):
        y = unknowns.state(u, v_ref_f)
        return unknowns.of(_beat_end(field_f, period_f, y, jump_ts_f, config)) - u

    # Newton's own tolerance, in the scaled units: well inside the steady tolerance
    start, newton_steps = _newton(
        beat_map, unknowns.of(guess.y_end), atol=0.1 * tol + 1e-9, rtol=1e-8,
        max_steps=max_newton,
    )  # fmt: skip
    final = periodic_beats(
        field_f, unknowns.state(start, v_ref_f), period_f, None, max_beats=max_beats, **beats
    )
    drift = jnp.maximum(guess.volume_drift, final.volume_drift)
    result = jnp.where(guess.result == SUCCESSFUL, final.result, guess.result)
    beats = guess.beats + final.beats
    if ts is None:  # the orbit's start only, its derivative the orbit's
        orbit = (field, final.y0, period, jump_ts, total_volume, v_ref, closed, config)
        y_start, _, _ = _orbit(*orbit)
        return Beats(
            ts, None, y_start, final.y_end, beats, final.residual, drift, result, jnp.array(0),
            newton_steps,
        )
    last = orbit_beat(
        field, final.y0, period, ts, jump_ts=jump_ts, total_volume=total_volume, v_ref=v_ref,
        closed=closed, config=config, observe=observe,
    )
    return Beats(
        ts, last.observed, last.y0, final.y_end, beats, final.residual,
        jnp.maximum(drift, last.volume_drift),
        jnp.where(result == SUCCESSFUL, last.result, result),
        last.num_steps, newton_steps,
    )


def orbit_beat(
    field,
    y_start,
    period,
    ts,
    *,
    jump_ts,
    total_volume,
    v_ref,
    closed: bool,
    config: SolverConfig | None = None,
    observe: Callable[[jax.Array, dict], Any] | None = None,
) -> Beats:
    """One beat from ``y_start``, a point of the periodic orbit, differentiated as the orbit.

    The value is the beat from ``y_start`` sampled at ``ts`` (its last entry the period): what
    ``observe`` sees, its end, its cycle-to-cycle change ``residual`` (how far ``y_start`` is
    from the orbit: compare it with the steady tolerance). The derivative is not that of one beat
    from a fixed start: ``y_start``'s own derivative is ignored, and the start moves with the
    parameters as the orbit does, ``-(dPhi/du - I)^-1 dPhi/dtheta`` in the unknowns ``u`` of
    :func:`shoot_periodic`, evaluated at ``y_start`` (implicit function theorem). Nothing of it
    is computed without differentiation.

    ``v_ref`` is the total fluid volume (m^3) the orbit holds: that of the state the beats
    started from (it depends on the parameters: the pump's rest volume, the column's head).
    ``closed`` and the other arguments are those of :func:`shoot_periodic`.

    Where ``dPhi/du - I`` is singular or not finite (no isolated orbit there), the derivatives
    are NaN. They are computed with the beat itself, inside one custom derivative rule: no NaN
    reaches the derivative of a stiff solver's linear solve (whose checks raise), and one batched
    solve gives the beat's derivatives along the unknowns and along the parameters at once.
    """
    config = preset("default") if config is None else config
    y, ys, (result, steps) = _orbit(
        field, y_start, period, jump_ts, total_volume, v_ref, closed, config, _phases(ts, period)
    )
    observed = ys if observe is None else observe(ts, ys)
    y_end = jax.tree_util.tree_map(lambda a: a[-1], ys)
    drift = jnp.abs(total_volume(y_end) - v_ref) / jnp.abs(v_ref)
    return Beats(
        ts, observed, y, y_end, jnp.array(1), _cycle_residual(y, y_end), drift,
        _finite_or_failed(ys, result), steps, jnp.array(0),
    )


def _orbit(field, y_start, period, jump_ts, total_volume, v_ref, closed, config, save_s=None):
    """``(y, ys, (result, steps))``: ``y_start`` and, with phases ``save_s``, the beat from it
    sampled there (else None), both differentiated as the orbit through ``y_start``
    (:func:`orbit_beat`)."""
    y_fixed = _frozen(y_start)
    unknowns = _Unknowns(y_fixed, closed, total_volume)
    live = (field, period, jump_ts, v_ref, save_s)

    def beat(u, live):
        field, period, jump_ts, v_ref, save_s = live
        sol = _one_beat(field, period, unknowns.state(u, v_ref), save_s, jump_ts, config)
        y_end = jax.tree_util.tree_map(lambda a: a[-1], sol.ys)
        samples = None if save_s is None else sol.ys
        return (unknowns.of(y_end) - u, samples), (sol.result, sol.stats["num_steps"])

    u = unknowns.of(y_fixed)
    u, ys, aux = _on_orbit(u, live, eqx.filter_closure_convert(beat, u, live))
    return unknowns.state(u, v_ref), ys, aux


@eqx.filter_custom_jvp
def _on_orbit(u, live, beat):
    """``(u, samples, aux)`` of ``beat(u, live) = ((G(u), samples), aux)``, ``G(u) = Phi(u) -
    u``. Differentiated, ``u`` moves as the root of ``G`` through it (implicit function
    theorem) and the samples with it; both derivatives are NaN where ``dG/du`` is singular."""
    (_, samples), aux = beat(u, live)
    return u, samples, aux


@_on_orbit.def_jvp
def _on_orbit_jvp(primals, tangents):
    u, live, beat = primals
    _, t_live, _ = tangents  # u's own tangent is ignored; beat closes over frozen values
    unperturbed = jax.tree_util.tree_map(lambda t: t is None, t_live, is_leaf=_is_none)
    if all(jax.tree_util.tree_leaves(unperturbed)):
        out = _on_orbit(u, live, beat)
        return out, jax.tree_util.tree_map(lambda _: None, out)
    fixed, diff = eqx.partition(live, unperturbed, is_leaf=_is_none)
    n = u.shape[0]

    def moved(u, diff):
        return beat(u, eqx.combine(diff, fixed))

    # The beat and its derivatives along each unknown and along the inputs' tangent: one
    # batched solve. Directions 0..n-1 move u, direction n the inputs; the primal outputs do
    # not depend on the directions (so an outer vmap, as jax.jacfwd's, leaves them unbatched).
    t_us = jnp.concatenate([jnp.eye(n, dtype=u.dtype), jnp.zeros((1, n), u.dtype)])
    t_diffs = jax.tree_util.tree_map(
        lambda t: jnp.concatenate([jnp.zeros((n, *jnp.shape(t)), t.dtype), t[None]]), t_live
    )
    (_, samples), (t_g, t_samples), aux = jax.vmap(
        lambda tu, td: jax.jvp(moved, (u, diff), (tu, td), has_aux=True),
        out_axes=(None, 0, None),
    )(t_us, t_diffs)
    t_u = -jnp.linalg.solve(t_g[:n].T, t_g[n])
    t_u = jnp.where(jnp.all(jnp.isfinite(t_u)), t_u, jnp.nan)
    t_samples = jax.tree_util.tree_map(
        lambda t: t[n] + jnp.tensordot(t_u, t[:n], axes=1), t_samples
    )
    return (u, samples, aux), (t_u, t_samples, jax.tree_util.tree_map(lambda _: None, aux))


def _is_none(x) -> bool:
    return x is None


class _Unknowns:
    """The unknowns of the one-beat map: the periodic states of a template state ``y`` divided
    by their scales (:data:`PERIODIC_SCALES`), and back (:func:`shoot_periodic`, step 2)."""

    def __init__(self, y: dict, closed: bool, total_volume):
        flat, self.treedef = jax.tree_util.tree_flatten_with_path(y)
        names = [path[-1].key for path, _ in flat]
        # closed: the first leaf named "volume" (the pump's; a closed loop's left atrium) is
        # eliminated, held by the total (total_volume is affine in it with slope 1)
        self.eliminated = names.index("volume") if closed else None
        self.unknown = [
            i for i, name in enumerate(names) if name in PERIODIC_SCALES and i != self.eliminated
        ]
        self.scales = jnp.asarray([PERIODIC_SCALES[names[i]] for i in self.unknown])
        self.template = [leaf for _, leaf in flat]
        self.closed, self.total_volume = closed, total_volume
        # the accumulator re-based in an open circuit (total_volume is affine in it, slope +-1)
        self.rebase = (
            None if closed else next((i for i, n in enumerate(names) if n in ACCUMULATORS), None)
        )

    def of(self, y: dict) -> jax.Array:
        leaves = jax.tree_util.tree_leaves(y)
        return jnp.stack([leaves[i] for i in self.unknown]) / self.scales

    def state(self, u: jax.Array, v_ref) -> dict:
        """The state of unknowns ``u`` holding the total volume ``v_ref`` (m^3)."""
        leaves = list(self.template)
        for k, i in enumerate(self.unknown):
            leaves[i] = u[k] * self.scales[k]
        if self.closed:
            i = self.eliminated
            leaves[i] = jnp.zeros_like(leaves[i])
            others = self.total_volume(jax.tree_util.tree_unflatten(self.treedef, leaves))
            leaves[i] = v_ref - others
        y = jax.tree_util.tree_unflatten(self.treedef, leaves)
        if self.closed or self.rebase is None:
            return y

        def with_leaf(a):
            return jax.tree_util.tree_unflatten(
                self.treedef, [*leaves[: self.rebase], a, *leaves[self.rebase + 1 :]]
            )

        acc = leaves[self.rebase]
        total, slope = jax.jvp(
            lambda a: self.total_volume(with_leaf(a)), (acc,), (jnp.ones_like(acc),)
        )
        return with_leaf(acc + (v_ref - total) / slope)


def _newton(residual, u0, *, atol, rtol, max_steps: int):
    """Newton's method on ``residual(u) = 0`` from ``u0``: (where the beats go on from,
    iterations). Each iteration takes the residual and its Jacobian from one
    forward-mode pass (``jax.jacfwd``, the residual as its aux), so each beat is integrated
    once, with its tangents. (``optimistix.root_find`` linearises the beat map instead:
    JAX integrates the beat once for the value and again inside the linear map, and its
    answer's residual took one more beat; the design's program was 25,569 jaxpr equations.)

    Converged as optimistix's Cauchy test: the residual within ``atol`` and the step within
    ``atol + rtol |u|`` (the largest component; the step is taken). Where it does not
    converge in ``max_steps`` (the beat map is smooth only to the integrator's tolerance:
    Newton can stall just above its tolerance, on tah's design grid at 1.1e-3 against 1e-3),
    the iterate of least residual, the last one among them, much nearer the orbit than the
    guess: the beats start there (2 to the steady test, where from the guess they took
    80-100)."""

    def value_and_jacobian(u):
        jac, value = jax.jacfwd(lambda v: (lambda r: (r, r))(residual(v)), has_aux=True)(u)
        return value, jac

    def running(carry):
        steps, _, _, _, stop, _ = carry
        return (steps < max_steps) & ~stop

    def iteration(carry):
        steps, u, best, least, _, _ = carry
        value, jac = value_and_jacobian(u)
        size = jnp.max(jnp.abs(value))
        better = size < least  # False for a NaN
        step = jnp.linalg.solve(jac, value)
        new = u - step
        small = jnp.max(jnp.abs(step) / (atol + rtol * jnp.abs(new))) < 1
        converged = (size < atol) & small
        finite = jnp.all(jnp.isfinite(new))
        return (
            steps + 1, jnp.where(finite, new, u), jnp.where(better, u, best),
            jnp.where(better, size, least), converged | ~finite, converged,
        )  # fmt: skip

    inf = jnp.array(jnp.inf, u0.dtype)
    carry = (jnp.array(0), u0, u0, inf, jnp.array(False), jnp.array(False))
    steps, u, best, least, _, converged = jax.lax.while_loop(running, iteration, carry)
    # stopped by max_steps: the last step is not yet measured, and may be the one that
    # landed (one step from far off on a linear map); one beat, without tangents, says
    last = jnp.max(jnp.abs(residual(u))) < least
    return jnp.where(converged | last, u, best), steps


def _beat_end(field, period, y, jump_ts, config):
    """The state one beat after ``y``."""
    sol = _one_beat(field, period, y, None, jump_ts, config)
    return jax.tree_util.tree_map(lambda a: a[-1], sol.ys)


def _frozen(tree):
    """``tree`` with its arrays cut from differentiation (``lax.stop_gradient``)."""
    return jax.tree_util.tree_map(
        lambda a: jax.lax.stop_gradient(a) if eqx.is_array(a) else a, tree
    )
