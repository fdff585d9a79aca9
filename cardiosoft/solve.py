"""Time integration: the only module of cardiosoft that calls ``diffrax.diffeqsolve``.

Solver settings are data (:class:`SolverConfig`); :func:`preset` gives the named ones. Solves
never throw (``throw=False``): callers inspect ``sol.result`` (and mask it under ``vmap``).

Choosing (``notes/diffrax-practice.md``): Tsit5 for the smooth bench; ``preset(..., stiff=True)``
(Kvaerno5 with a Newton root finder and PID (0.3, 0.4)) when valves or tiny inertances make the
model stiff; compare ``sol.stats["num_steps"]`` before deciding. ``atol`` is absolute in SI and
shared by every state component: pressures (Pa, ~1e4) and volumes (m^3, ~1e-5) differ by nine
orders of magnitude, so for volumes ``atol`` rather than ``rtol`` usually sets the accuracy.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from cardiosoft.circulation import inlet_pressure
from cardiosoft.units import ml, mmHg

__all__ = [
    "ACCURACY_PRESETS",
    "PERIODIC_SCALES",
    "PRESETS",
    "Beats",
    "SolverConfig",
    "integrate",
    "orbit_beat",
    "periodic_beats",
    "preset",
    "respond",
    "shoot_periodic",
]


class SolverConfig(eqx.Module):
    """Solver settings.

    **Arguments:**

    - ``solver`` (static): a diffrax solver instance; default ``Tsit5()``.
    - ``rtol``, ``atol``: tolerances of the PID controller (atol in SI units of the state).
    - ``pcoeff``, ``icoeff``: PID coefficients; (0, 1) is the plain I controller.
    - ``max_steps`` (static): bound on the number of steps (sizes the checkpoint memory).
    - ``dt0``: first step (s); None picks it automatically.
    - ``fixed_steps`` (static): None for error control (the PID controller), or a number of
      equal steps over the solve's interval, without error control (still cut at ``jump_ts``).
      For checking derivatives against finite differences: with equal steps the discretisation
      is the same on both sides of the difference, so the two agree to the difference's own
      truncation error.
    - ``adjoint`` (static): diffrax adjoint; the default checkpointed one for reverse mode,
      ``diffrax.ForwardMode()`` for ``jax.jvp``/``jacfwd`` (least-squares fitting).
    """

    solver: diffrax.AbstractSolver = eqx.field(static=True, default_factory=diffrax.Tsit5)
    rtol: jax.Array = eqx.field(converter=jnp.asarray, default=1e-6)
    atol: jax.Array = eqx.field(converter=jnp.asarray, default=1e-9)
    pcoeff: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    icoeff: jax.Array = eqx.field(converter=jnp.asarray, default=1.0)
    max_steps: int = eqx.field(static=True, default=16384)
    dt0: float | None = None
    fixed_steps: int | None = eqx.field(static=True, default=None)
    adjoint: diffrax.AbstractAdjoint = eqx.field(
        static=True, default_factory=diffrax.RecursiveCheckpointAdjoint
    )


PRESETS: dict[str, dict] = {
    "fast": dict(rtol=1e-4, atol=1e-8),
    "default": dict(rtol=1e-6, atol=1e-9),
    "reference": dict(rtol=1e-10, atol=1e-13, max_steps=65536),
}
"""Named non-stiff configurations, as :class:`SolverConfig` arguments with the ``Tsit5`` solver;
:func:`preset` builds them (plain numbers here: no JAX array is built at import time, so float64
can be switched on after ``import cardiosoft``).

"reference" uses Tsit5, not Dopri8: output at ``ts`` is interpolated, and diffrax's Dopri8
interpolant was measured 300x less accurate there (relative error 8e-9 against 3e-11 for Tsit5
on an RC decay at rtol 1e-10), although Dopri8 is more accurate at its own steps.
"""

ACCURACY_PRESETS: tuple[str, ...] = tuple(PRESETS)
"""The names of the presets, ``("fast", "default", "reference")``: the accuracy a scene asks for."""


def preset(name: str, stiff: bool = False) -> SolverConfig:
    """The named configuration (``"fast"``, ``"default"``, ``"reference"``), built anew.

    With ``stiff=True`` the solver is ``Kvaerno5`` with a Newton root finder at the controller's
    tolerances and the PID coefficients are (0.3, 0.4).
    """
    if name not in PRESETS:
        raise ValueError(f"solver preset {name!r} is not one of {', '.join(PRESETS)}")
    if stiff:
        solver = diffrax.Kvaerno5(root_finder=diffrax.with_stepsize_controller_tols(optx.Newton)())
        return SolverConfig(solver, pcoeff=0.3, icoeff=0.4, **PRESETS[name])
    return SolverConfig(diffrax.Tsit5(), **PRESETS[name])


def integrate(
    vector_field,
    y0,
    t0,
    t1,
    *,
    args=None,
    ts=None,
    jump_ts=None,
    config=None,
    dense=False,
    max_step=None,
) -> diffrax.Solution:
    """Solve ``dy/dt = vector_field(t, y, args)`` from ``t0`` to ``t1``.

    **Arguments:**

    - ``vector_field``: ``(t, y, args) -> dy/dt`` with the pytree structure of ``y0``. Pass
      parameters through ``args`` (or make it a Module), not by closure, to avoid recompiles.
    - ``y0``: any pytree of arrays (e.g. a dict of scalars).
    - ``ts``: save times (interpolated); None saves ``t1`` only.
    - ``jump_ts``: known kinks/jumps of the forcing in time (e.g. ``CablePull.kink_times``),
      stepped to exactly through ``ClipStepSizeController``.
    - ``config``: a :class:`SolverConfig`, ``preset("default")`` when None.
    - ``dense``: keep the dense interpolant (``sol.evaluate``).
    - ``max_step``: the longest step (same unit as t), None for no cap. Error control cannot
      see forcing that falls entirely between two steps: cap the step below the shortest
      feature of a forcing whose kinks are not passed as ``jump_ts``.

    **Returns:** the ``diffrax.Solution``; never throws, check ``sol.result``.
    """
    config = preset("default") if config is None else config
    dt0 = config.dt0
    if config.fixed_steps is None:
        controller = diffrax.PIDController(
            rtol=config.rtol,
            atol=config.atol,
            pcoeff=config.pcoeff,
            icoeff=config.icoeff,
            dtmax=max_step,
        )
    else:
        # equal steps that may still be cut at jump_ts (ClipStepSizeController needs an adaptive
        # controller): tolerances no error can reach, every step as long as dtmax allows
        dt0 = (jnp.asarray(t1) - jnp.asarray(t0)) / config.fixed_steps
        controller = diffrax.PIDController(rtol=1e30, atol=1e30, dtmax=dt0)
    if jump_ts is not None:
        controller = diffrax.ClipStepSizeController(controller, jump_ts=jump_ts)
    ftype = jnp.result_type(float)
    saveat = (
        diffrax.SaveAt(t1=True, dense=dense)
        if ts is None
        else diffrax.SaveAt(ts=jnp.asarray(ts, dtype=ftype), dense=dense)
    )
    return diffrax.diffeqsolve(
        diffrax.ODETerm(vector_field),
        config.solver,
        jnp.asarray(t0, dtype=ftype),
        jnp.asarray(t1, dtype=ftype),
        dt0,
        y0,
        args=args,
        saveat=saveat,
        stepsize_controller=controller,
        adjoint=config.adjoint,
        max_steps=config.max_steps,
        throw=False,
    )


def _afterload_field(t, y, args):
    block, inflow = args
    return block.node_rhs(y, inflow(t))


@eqx.filter_jit
def _respond(block, inflow, ts, y0, config, jump_ts, max_step):
    sol = integrate(
        _afterload_field,
        y0,
        0.0,
        ts[-1],
        args=(block, inflow),
        ts=ts,
        jump_ts=jump_ts,
        config=config,
        max_step=max_step,
    )

    def pressure(t, y):
        q, dqdt = jax.jvp(inflow, (t,), (jnp.ones_like(t),))
        return inlet_pressure(block, y, q, dqdt)

    return jax.vmap(pressure)(ts, sol.ys), sol.result, sol.stats["num_steps"]


def respond(
    block, inflow, ts, y0=None, config=None, *, jump_ts=None, max_step="auto"
) -> jax.Array:
    """Inlet pressure (Pa) of an afterload driven standalone by a prescribed inflow.

    **Arguments:**

    - ``block``: an :class:`~cardiosoft.circulation.AbstractAfterload`.
    - ``inflow``: a JAX function ``q(t)`` (m^3/s); dq/dt comes from ``jax.jvp``. Make it an
      ``eqx.Module`` with array fields (or a module-level function) so that a new inflow
      does not recompile.
    - ``ts``: increasing output times (s), ``ts[-1] > 0``; the solve runs from t = 0.
    - ``y0``: initial block state; ``block.init()`` (rest) when None.
    - ``config``: a :class:`SolverConfig` (``preset("default")`` when None); ``jump_ts``:
      kinks of ``inflow`` (s).
    - ``max_step``: the longest solver step (s). ``"auto"`` (the default): the shortest
      interval of ``ts`` without ``jump_ts``, no cap with them. Error control only sees the
      inflow where it steps: a pulse that falls between two steps would vanish without a word,
      so without the kinks the step is kept as fine as the output grid (a pulse the grid
      resolves is resolved). ``None``: no cap.

    **Returns:** the inlet pressure at ``ts``. Raises ``RuntimeError`` if the solve failed, or
    an equinox runtime error when called under ``jit``.
    """
    ts = jnp.asarray(ts, dtype=jnp.result_type(float))
    y0 = block.init() if y0 is None else y0
    config = preset("default") if config is None else config
    if isinstance(max_step, str):
        if max_step != "auto":
            raise ValueError(f"max_step = {max_step!r}: allowed 'auto', None or a step in s")
        gaps = jnp.diff(jnp.concatenate([jnp.zeros(1, ts.dtype), ts]))
        max_step = None if jump_ts is not None else jnp.min(jnp.where(gaps > 0, gaps, jnp.inf))
    p, result, num_steps = _respond(block, inflow, ts, y0, config, jump_ts, max_step)
    failed = result != diffrax.RESULTS.successful
    message = "respond: the afterload solve failed; raise max_steps or loosen the tolerances"
    if isinstance(failed, jax.core.Tracer):
        return eqx.error_if(p, failed, message)
    if bool(failed):
        reason = diffrax.RESULTS[result]
        raise RuntimeError(f"{message}: {reason} ({int(num_steps)} steps taken)")
    return p


PERIODIC_SCALES = {
    "volume": ml,
    "flow": ml,  # per s
    "column_volume": ml,
    "relaxation": ml,  # the shell dashpot's volume
    "pc": mmHg,
    "pa": mmHg,
    "pressure": mmHg,  # a vessel compartment's (cardiosoft.heart.Vessel)
}
"""State leaves compared from beat to beat, with the unit of the steady-state tolerance (ml,
ml/s, mmHg). Accumulators (``supplied_volume``, ``drained_volume``) grow every beat and are not
compared."""
ACCUMULATORS = frozenset({"supplied_volume", "drained_volume"})


def _cycle_residual(y_start, y_end):
    worst = jnp.zeros(())
    flat, _ = jax.tree_util.tree_flatten_with_path(y_start)
    ends = jax.tree_util.tree_leaves(y_end)
    for (path, a), b in zip(flat, ends, strict=True):
        name = path[-1].key
        if name in ACCUMULATORS or path[0].key == "energy":  # growing, not periodic
            continue
        if name not in PERIODIC_SCALES:
            raise KeyError(f"state {jax.tree_util.keystr(path)} has no periodicity scale")
        worst = jnp.maximum(worst, jnp.abs(b - a) / PERIODIC_SCALES[name])
    return worst


class Beats(eqx.Module):
    """Result of :func:`periodic_beats` (SI)."""

    ts: jax.Array
    """Save times of a beat, from 0 to the period (s)."""
    observed: Any
    """What ``observe`` returned for the last beat: by default the state at ``ts`` (leaves with
    a leading time axis)."""
    y0: dict
    """State at the start of the last beat."""
    y_end: dict
    """State at the end of the last beat."""
    beats: jax.Array
    """Number of beats integrated."""
    residual: jax.Array
    """Largest change of a periodic state over the last beat (ml, ml/s or mmHg)."""
    volume_drift: jax.Array
    """Largest |total volume - initial total| at any beat's end, relative to the first."""
    result: diffrax.RESULTS
    """diffrax's result of the last solve (``successful`` unless a beat failed)."""
    num_steps: jax.Array
    """Solver steps of the last beat."""
    newton_steps: jax.Array
    """Newton iterations of :func:`shoot_periodic` (0 beat after beat)."""


def _in_phase(s, y, args):
    """dy/ds = T f(s T, y): the vector field ``f`` in the phase s = t / T of a beat of period T."""
    field, period = args
    return jax.tree_util.tree_map(lambda d: period * d, field(s * period, y, None))


def _one_beat(field, period, y, save_ts, jump_ts, config):
    # Integrated in the beat's phase s = t / period over [0, 1]: with constant ends, diffrax's
    # end-of-interval bookkeeping (t1 minus 100 ULP, ~1500 HLO ops per member) folds away at
    # compile time, while the period stays an array leaf (a new bpm does not recompile).
    return integrate(
        _in_phase, y, 0.0, 1.0, args=(field, period), ts=save_ts, jump_ts=jump_ts / period,
        config=config,
    )


def _phases(ts, period):
    """Save times ``ts`` (s) as phases of the beat in [0, 1]: ts[-1] / period can round to
    1 + 1 ULP, past the solve's end, so they are clipped."""
    return jnp.clip(ts / period, 0.0, 1.0)


def _finite_or_failed(states, result):
    # A state that is not finite after a successful solve is a broken invariant, never a
    # result: diffrax checks the save times with a host callback that raises, which the CLIs
    # resolve to NaN instead so that their compile can be cached (cardiosoft._cli); diffrax then
    # leaves every sample at inf and still reports success.
    leaves = jax.tree_util.tree_leaves(states)
    finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in leaves]))
    return diffrax.RESULTS.where(
        diffrax.is_successful(result) & ~finite, diffrax.RESULTS.internal_error, result
    )


def periodic_beats(
    field,
    y0,
    period,
    ts,
    *,
    jump_ts,
    total_volume,
    max_beats: int,
    tol,
    config: SolverConfig | None = None,
    observe: Callable[[jax.Array, dict], Any] | None = None,
) -> Beats:
    """Integrate beat after beat until the cycle-to-cycle change is below ``tol`` in two
    beats in a row.

    One beat is not enough: an approach to the cycle that oscillates (a ringing water column,
    a slow shell relaxation) passes through a small change between two large ones. On the
    calibrated bench at 30 bpm and 90 mmHg one beat's change of 0.002 ml was followed by 0.019
    ml (measured 2026-12-02); the returned ``residual`` is the last beat's change.

    **Arguments:**

    - ``field``: the vector field, periodic in t with ``period`` (s); each beat runs over
      ``[0, period]`` from the previous beat's end state.
    - ``ts``: save times of a beat, increasing from 0, the last one equal to ``period``; None
      integrates no sampled last beat (``observed`` is None, ``num_steps`` 0).
    - ``y0``: the state at the start of the first beat; ``jump_ts``: kinks of the forcing in
      ``[0, period]``; ``total_volume``: ``y -> m^3`` for the conservation check.
    - ``max_beats`` (static): the most beats; with ``tol = 0`` exactly that many are run.
    - ``tol``: steady-state tolerance in the units of :data:`PERIODIC_SCALES`.
    - ``config``: a :class:`SolverConfig`.
    - ``observe``: ``(ts, ys) -> pytree``, applied to the last beat's states at ``ts``
      (:attr:`Beats.observed`); ``None`` keeps the states themselves. The beats before it are
      integrated without samples (only their end states), the last once more from its start.

    Runs in one ``lax.while_loop``: jit it once, ``vmap`` it over parameters, and every element
    stops at its own steady state (the batch runs until the slowest is done). A failed beat
    stops its element and is reported in ``result``; nothing is raised.
    """
    config = preset("default") if config is None else config
    ftype = jnp.result_type(float)
    v_ref = total_volume(y0)

    # Beat after beat saving only each beat's end (interpolating the samples of every beat was
    # measured as half to three quarters of the cost: benchmarks/sweep_throughput.py); the
    # last beat is then integrated once more from its start, the same steps, with its samples.
    def body(carry):
        y, beats, residual, _, drift, _, _ = carry
        sol = _one_beat(field, period, y, None, jump_ts, config)
        y_end = jax.tree_util.tree_map(lambda a: a[-1], sol.ys)
        drift = jnp.maximum(drift, jnp.abs(total_volume(y_end) - v_ref) / jnp.abs(v_ref))
        return y_end, beats + 1, _cycle_residual(y, y_end), residual, drift, sol.result, y

    def cond(carry):
        _, beats, residual, previous, _, result, _ = carry
        ok = result == diffrax.RESULTS.successful
        return ok & (beats < max_beats) & (jnp.maximum(residual, previous) > tol)

    inf = jnp.array(jnp.inf, ftype)
    carry = (y0, jnp.array(0), inf, inf, jnp.zeros((), ftype), diffrax.RESULTS.successful, y0)
    y_end, beats, residual, _, drift, result, y_start = jax.lax.while_loop(cond, body, carry)
    if ts is None:
        observed, steps, result = None, jnp.array(0), _finite_or_failed(y_end, result)
    else:
        last = _one_beat(field, period, y_start, _phases(ts, period), jump_ts, config)
        observed = last.ys if observe is None else observe(ts, last.ys)
        result, steps = _finite_or_failed(last.ys, result), last.stats["num_steps"]
    return Beats(ts, observed, y_start, y_end, beats, residual, drift, result, steps, jnp.array(0))


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
    2. Newton's method (``optimistix.root_find``) on ``u -> Phi(u) - u``, ``Phi`` the state one
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
    3. From the orbit (or, if Newton failed, from the guess), beat after beat as in
       :func:`periodic_beats` until the cycle-to-cycle change is below ``tol``, at most
       ``max_beats``: at a converged orbit that is two beats (the steady test); otherwise beat
       after beat is the fallback, and ``residual`` says how it ended. The last beat is then
       integrated once more with its samples, by :func:`orbit_beat`; with ``ts`` None it is
       not, and ``y0``, the orbit's start, is what carries the orbit's derivative.

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

    def beat_map(u, args):
        y = unknowns.state(u, v_ref_f)
        return unknowns.of(_beat_end(field_f, period_f, y, jump_ts_f, config)) - u

    # Newton's own tolerance, in the scaled units: well inside the steady tolerance
    newton = optx.Newton(rtol=1e-8, atol=0.1 * tol + 1e-9)
    u0 = unknowns.of(guess.y_end)
    root = optx.root_find(beat_map, newton, u0, max_steps=max_newton, throw=False)
    converged = optx.RESULTS.successful == root.result
    finite = jnp.all(jnp.isfinite(root.value))
    start = jnp.where(converged & finite, root.value, u0)
    final = periodic_beats(
        field_f, unknowns.state(start, v_ref_f), period_f, None, max_beats=max_beats, **beats
    )
    drift = jnp.maximum(guess.volume_drift, final.volume_drift)
    result = diffrax.RESULTS.where(diffrax.is_successful(guess.result), final.result, guess.result)
    beats = guess.beats + final.beats
    newton_steps = root.stats["num_steps"]
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
        diffrax.RESULTS.where(diffrax.is_successful(result), last.result, result),
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


def _beat_end(field, period, y, jump_ts, config):
    """The state one beat after ``y``."""
    sol = _one_beat(field, period, y, None, jump_ts, config)
    return jax.tree_util.tree_map(lambda a: a[-1], sol.ys)


def _frozen(tree):
    """``tree`` with its arrays cut from differentiation (``lax.stop_gradient``)."""
    return jax.tree_util.tree_map(
        lambda a: jax.lax.stop_gradient(a) if eqx.is_array(a) else a, tree
    )
