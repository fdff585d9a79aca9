"""Time integration: the only module of cardiosoft that calls ``diffrax.diffeqsolve``.

Solver settings are data (:class:`SolverConfig`); :func:`preset` gives the named ones. Solves
never throw (``throw=False``): callers inspect ``sol.result`` (and mask it under ``vmap``).

Choosing (``notes/diffrax-practice.md``): Tsit5 for the smooth bench; ``preset(..., stiff=True)``
(Kvaerno5 with a Newton root finder and PID (0.3, 0.4)) when valves or tiny inertances make the
model stiff; compare ``sol.stats["num_steps"]`` before deciding. ``atol`` is absolute in SI and
shared by every state component: pressures (Pa, ~1e4) and volumes (m^3, ~1e-5) differ by nine
orders of magnitude, so for volumes ``atol`` rather than ``rtol`` usually sets the accuracy.

diffrax (and optimistix, lineax) are imported where a solve is traced, not with this module: a
command whose programs come from the program store (:mod:`cardiosoft.program_store`) never
traces one, and spares their import (0.4-0.5 s of a fresh process, issue #41). So the presets
name their solver and adjoint (:class:`SolverConfig`), and a solve's result leaves a program as
diffrax's integer code (:func:`result_code`), not as diffrax's enumeration.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.circulation import inlet_pressure
from cardiosoft.units import ml, mmHg

if TYPE_CHECKING:
    import diffrax

__all__ = [
    "ACCURACY_PRESETS",
    "PERIODIC_SCALES",
    "PRESETS",
    "QUEUE_LANES",
    "SUCCESSFUL",
    "TIGHTER",
    "BeatProblem",
    "Beats",
    "SolverConfig",
    "describe",
    "diffrax_objects",
    "in_phase",
    "integrate",
    "periodic_beats",
    "periodic_beats_batch",
    "preset",
    "queue_lanes",
    "ran_out_of_steps",
    "rerun_settings",
    "respond",
    "result_code",
    "result_code_of",
    "result_message",
    "solver_name",
]


class SolverConfig(eqx.Module):
    """Solver settings.

    **Arguments:**

    - ``solver`` (static): a diffrax solver instance, or the name of one built when a solve is
      traced: ``"Tsit5"`` (the default), ``"Kvaerno5"`` (with a Newton root finder at the
      controller's tolerances), or any other diffrax solver that takes no arguments.
    - ``rtol``, ``atol``: tolerances of the PID controller (atol in SI units of the state).
    - ``pcoeff``, ``icoeff``: PID coefficients; (0, 1) is the plain I controller.
    - ``max_steps`` (static): bound on the number of steps (sizes the checkpoint memory).
    - ``dt0``: first step (s); None picks it automatically.
    - ``fixed_steps`` (static): None for error control (the PID controller), or a number of
      equal steps over the solve's interval, without error control (still cut at ``jump_ts``).
      For checking derivatives against finite differences: with equal steps the discretisation
      is the same on both sides of the difference, so the two agree to the difference's own
      truncation error.
    - ``adjoint`` (static): diffrax adjoint, an instance or a name as ``solver``; the default
      ``"RecursiveCheckpointAdjoint"`` for reverse mode, ``"ForwardMode"`` for
      ``jax.jvp``/``jacfwd`` (least-squares fitting).
    """

    solver: Any = eqx.field(static=True, default="Tsit5")
    rtol: jax.Array = eqx.field(converter=jnp.asarray, default=1e-6)
    atol: jax.Array = eqx.field(converter=jnp.asarray, default=1e-9)
    pcoeff: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    icoeff: jax.Array = eqx.field(converter=jnp.asarray, default=1.0)
    max_steps: int = eqx.field(static=True, default=16384)
    dt0: float | None = None
    fixed_steps: int | None = eqx.field(static=True, default=None)
    adjoint: Any = eqx.field(static=True, default="RecursiveCheckpointAdjoint")


def diffrax_objects(config: SolverConfig) -> tuple:
    """``config``'s solver and adjoint as diffrax's objects, those given by name built."""
    import diffrax

    def built(field, value, kind):
        if not isinstance(value, str):
            return value
        if value == "Kvaerno5":  # the stiff preset's: Newton at the controller's tolerances
            import optimistix as optx

            newton = diffrax.with_stepsize_controller_tols(optx.Newton)()
            return diffrax.Kvaerno5(root_finder=newton)
        found = getattr(diffrax, value, None)
        if not (isinstance(found, type) and issubclass(found, kind)):
            raise ValueError(
                f"SolverConfig {field} = {value!r}: not the name of a diffrax {kind.__name__} "
                "(e.g. 'Tsit5', 'Kvaerno5'; adjoints 'RecursiveCheckpointAdjoint', 'ForwardMode')"
            )
        return found()

    return (
        built("solver", config.solver, diffrax.AbstractSolver),
        built("adjoint", config.adjoint, diffrax.AbstractAdjoint),
    )


def solver_name(config: SolverConfig) -> str:
    """The name of ``config``'s solver (``"Tsit5"``, ``"Kvaerno5"``, ...)."""
    solver = config.solver
    return solver if isinstance(solver, str) else type(solver).__name__


SUCCESSFUL = 0
"""diffrax's result code of a solve that succeeded (``RESULTS.successful``)."""


def result_code(result) -> jax.Array:
    """diffrax's result (an item of its ``RESULTS`` enumeration, or already its code) as its
    integer code: the enumeration's one array leaf."""
    (code,) = jax.tree_util.tree_leaves(result)
    return code


def result_code_of(name: str) -> int:
    """The code of diffrax's result ``name`` (``"max_steps_reached"``, ...)."""
    import diffrax

    return int(result_code(getattr(diffrax.RESULTS, name)))


def ran_out_of_steps(codes) -> np.ndarray:
    """Per member of result ``codes`` (concrete): the solver reached ``max_steps``. diffrax is
    imported only when some member did not succeed."""
    codes = np.asarray(codes)
    if np.all(codes == SUCCESSFUL):
        return np.zeros(codes.shape, dtype=bool)
    return codes == result_code_of("max_steps_reached")


def result_message(code) -> str:
    """diffrax's message for the result ``code`` (a scalar)."""
    import diffrax

    successful = diffrax.RESULTS.successful
    code = jnp.asarray(code, result_code(successful).dtype)
    item = jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(successful), [code])
    return str(diffrax.RESULTS[item]).strip()


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


TIGHTER = 100.0
"""A run at ``"reference"`` already is verified at ``rtol`` and ``atol`` this many times tighter
(:func:`cardiosoft.verify_run`)."""


def describe(config: SolverConfig) -> str:
    """A configuration in words: solver, rtol, atol."""
    return f"{solver_name(config)}, rtol {float(config.rtol):.0e}, atol {float(config.atol):.0e}"


def rerun_settings(accuracy: str, run: SolverConfig, reference: SolverConfig) -> tuple[str, str]:
    """A run at preset ``accuracy`` (its configuration ``run``) and its verifying rerun at
    ``reference``, in words (:func:`cardiosoft.verify_run`'s ``run_setting`` and
    ``reference_setting``)."""
    which = "preset 'reference'" if accuracy != "reference" else f"{TIGHTER:g}x tighter"
    return f"preset {accuracy!r}: {describe(run)}", f"{which}: {describe(reference)}"


def preset(name: str, stiff: bool = False) -> SolverConfig:
    """The named configuration (``"fast"``, ``"default"``, ``"reference"``), built anew.

    With ``stiff=True`` the solver is ``Kvaerno5`` with a Newton root finder at the controller's
    tolerances and the PID coefficients are (0.3, 0.4).
    """
    if name not in PRESETS:
        raise ValueError(f"solver preset {name!r} is not one of {', '.join(PRESETS)}")
    if stiff:
        return SolverConfig("Kvaerno5", pcoeff=0.3, icoeff=0.4, **PRESETS[name])
    return SolverConfig("Tsit5", **PRESETS[name])


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
    import diffrax

    config = preset("default") if config is None else config
    solver, adjoint = diffrax_objects(config)
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
        solver,
        jnp.asarray(t0, dtype=ftype),
        jnp.asarray(t1, dtype=ftype),
        dt0,
        y0,
        args=args,
        saveat=saveat,
        stepsize_controller=controller,
        adjoint=adjoint,
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
    failed = result_code(result) != SUCCESSFUL
    message = "respond: the afterload solve failed; raise max_steps or loosen the tolerances"
    if isinstance(failed, jax.core.Tracer):
        return eqx.error_if(p, failed, message)
    if bool(failed):
        reason = result_message(result_code(result))
        raise RuntimeError(f"{message}: {reason} ({int(num_steps)} steps taken)")
    return p


PERIODIC_SCALES = {
    "volume": ml,
    "flow": ml,  # per s
    "column_volume": ml,
    "relaxation": ml,  # the shell dashpot's volume
    "pc": mmHg,
    "pa": mmHg,
    "pressure": mmHg,  # a vessel compartment's (cardiosoft.network.loop_components.Vessel)
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
    """The last beat's change (by default the largest change of a periodic state: ml, ml/s or
    mmHg)."""
    volume_drift: jax.Array
    """Largest |total volume - initial total| at any beat's end, relative to the first."""
    result: jax.Array
    """diffrax's result code of the last solve (:data:`SUCCESSFUL` unless a beat failed;
    :func:`result_message`)."""
    num_steps: jax.Array
    """Solver steps of the last beat."""
    newton_steps: jax.Array
    """Newton iterations of :func:`cardiosoft.shooting.shoot_periodic` (0 beat after beat)."""


def in_phase(s, y, args):
    """dy/ds = T f(s T, y): the vector field ``f`` in the phase s = t / T of a beat of period T
    (``args``: ``(f, T)``; ``f(t, y, None)`` as diffrax calls a field): every beat is integrated
    in it, over s in [0, 1]."""
    field, period = args
    return jax.tree_util.tree_map(lambda d: period * d, field(s * period, y, None))


def _one_beat(field, period, y, save_ts, jump_ts, config):
    # Integrated in the beat's phase s = t / period over [0, 1]: with constant ends, diffrax's
    # end-of-interval bookkeeping (t1 minus 100 ULP, ~1500 HLO ops per member) folds away at
    # compile time, while the period stays an array leaf (a new bpm does not recompile).
    return integrate(
        in_phase, y, 0.0, 1.0, args=(field, period), ts=save_ts,
        jump_ts=None if jump_ts is None else jump_ts / period, config=config,
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
    # Returns the result's code (:func:`result_code`), as :class:`Beats` holds it.
    leaves = jax.tree_util.tree_leaves(states)
    finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in leaves]))
    code = result_code(result)
    return jnp.where((code == SUCCESSFUL) & ~finite, result_code_of("internal_error"), code)


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
    change: Callable[[Any, Any], jax.Array] | None = None,
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
      ``[0, period]`` (None: none); ``total_volume``: ``y -> m^3`` for the conservation check
      (None: no check, ``volume_drift`` 0).
    - ``max_beats`` (static): the most beats; with ``tol = 0`` exactly that many are run.
    - ``tol``: steady-state tolerance in the units of ``change``.
    - ``change``: ``(y_start, y_end) -> scalar``, a beat's change; by default the largest
      change of a named periodic state in the units of :data:`PERIODIC_SCALES`.
    - ``config``: a :class:`SolverConfig`.
    - ``observe``: ``(ts, ys) -> pytree``, applied to the last beat's states at ``ts``
      (:attr:`Beats.observed`); ``None`` keeps the states themselves. The beats before it are
      integrated without samples (only their end states), the last once more from its start.

    Runs in one ``lax.while_loop``: jit it once, ``vmap`` it over parameters, and every element
    stops at its own steady state (the batch runs until the slowest is done; a large batch
    whose members need very different numbers of beats is better served by
    :func:`periodic_beats_batch`). A failed beat stops its element and is reported in
    ``result``; nothing is raised.
    """
    problem = BeatProblem(field, y0, period, ts, jump_ts, total_volume, observe)
    return _run_one(_BeatLoop.of(max_beats, tol, config, change), problem)


class BeatProblem(NamedTuple):
    """One member's beat-after-beat problem: the arguments of :func:`periodic_beats` that
    belong to the member (``total_volume`` and ``observe`` may be None, as there)."""

    field: Any
    y0: Any
    period: Any
    ts: Any
    jump_ts: Any
    total_volume: Any
    observe: Any = None


class _BeatLoop(NamedTuple):
    """The beat loop of :func:`periodic_beats` in pieces, so that :func:`periodic_beats_batch`
    can run it member by member on a few lanes. A member's carry is
    ``(y, beats, residual, previous residual, drift, result code, beat's start, total volume
    at the start)``."""

    max_beats: int
    tol: Any
    config: SolverConfig
    change: Callable

    @classmethod
    def of(cls, max_beats, tol, config, change) -> _BeatLoop:
        """The loop with :func:`periodic_beats`'s defaults filled in (config, change)."""
        config = preset("default") if config is None else config
        return cls(max_beats, tol, config, _cycle_residual if change is None else change)

    def start(self, p: BeatProblem):
        import diffrax

        ftype = jnp.result_type(float)
        inf = jnp.array(jnp.inf, ftype)
        v_ref = jnp.ones((), ftype) if p.total_volume is None else p.total_volume(p.y0)
        return (p.y0, jnp.array(0), inf, inf, jnp.zeros((), ftype),
                result_code(diffrax.RESULTS.successful), p.y0, v_ref)

    # Beat after beat saving only each beat's end (interpolating the samples of every beat was
    # measured as half to three quarters of the cost: benchmarks/sweep_throughput.py); the
    # last beat is then integrated once more from its start, the same steps, with its samples.
    def step(self, p: BeatProblem, carry):
        y, beats, residual, _, drift, _, _, v_ref = carry
        sol = _one_beat(p.field, p.period, y, None, p.jump_ts, self.config)
        y_end = jax.tree_util.tree_map(lambda a: a[-1], sol.ys)
        if p.total_volume is not None:
            drift = jnp.maximum(drift, jnp.abs(p.total_volume(y_end) - v_ref) / jnp.abs(v_ref))
        code = result_code(sol.result)
        return y_end, beats + 1, self.change(y, y_end), residual, drift, code, y, v_ref

    def running(self, carry):
        _, beats, residual, previous, _, code, _, _ = carry
        ok = code == SUCCESSFUL
        return ok & (beats < self.max_beats) & (jnp.maximum(residual, previous) > self.tol)

    def finish(self, p: BeatProblem, carry) -> Beats:
        y_end, beats, residual, _, drift, code, y_start, _ = carry
        if p.ts is None:
            observed, steps, code = None, jnp.array(0), _finite_or_failed(y_end, code)
        else:
            last = _one_beat(p.field, p.period, y_start, _phases(p.ts, p.period), p.jump_ts,
                             self.config)
            observed = last.ys if p.observe is None else p.observe(p.ts, last.ys)
            code, steps = _finite_or_failed(last.ys, code), last.stats["num_steps"]
        return Beats(p.ts, observed, y_start, y_end, beats, residual, drift, code, steps,
                     jnp.array(0))


QUEUE_LANES = 16
"""The fewest lanes of :func:`periodic_beats_batch`'s queue (with one per eight members in a
larger batch); a batch of at most twice this many members is solved side by side."""


def queue_lanes(members: int) -> int:
    """How many members :func:`periodic_beats_batch` solves side by side in a batch of
    ``members``: all of them in a small batch, else :data:`QUEUE_LANES` or one in eight."""
    if members <= 2 * QUEUE_LANES:
        return members
    return max(QUEUE_LANES, -(-members // 8))


def periodic_beats_batch(
    problem: Callable[[Any], BeatProblem],
    members,
    *,
    max_beats: int,
    tol,
    config: SolverConfig | None = None,
    change: Callable[[Any, Any], jax.Array] | None = None,
) -> Beats:
    """:func:`periodic_beats` of every member of a batch: ``members`` a pytree of arrays with a
    leading member axis, ``problem(member)`` one member's :class:`BeatProblem` (traced, so
    built from the member's arrays); the rest as :func:`periodic_beats`. Each member's beats
    are the same as :func:`periodic_beats` gives it alone.

    Why not ``vmap(periodic_beats)``: a batched ``while_loop`` integrates every member until the
    slowest is steady. In the posterior's ensemble at 60 bpm (48 draws x 3 heads) the members
    need 17-194 beats and two never settle (300, the most): side by side, all 144 ran 300
    beats, 7x the beats the members needed. So a batch of more than ``2 QUEUE_LANES``
    members runs as a queue on :func:`queue_lanes` lanes: each lane integrates its member's
    next beat, and a lane whose member is steady, failed or out of beats stores it and takes
    the next member waiting. One compiled loop; a lane left without a member integrates the
    last member from its start again (a beat of ordinary cost) and keeps nothing of it. With
    ``tol = 0`` (a number: every member runs ``max_beats``) the members run side by side. A
    batch sharded over several devices (:func:`cardiosoft.beat_solution.shard`, the sweeps')
    runs a queue on each device.
    """
    loop = _BeatLoop.of(max_beats, tol, config, change)
    n = jax.tree_util.tree_leaves(members)[0].shape[0]
    devices = jax.devices()
    sharded = len(devices) > 1 and n % len(devices) == 0  # as beat_solution.shard spreads it
    share = n // len(devices) if sharded else n
    fixed = isinstance(tol, int | float) and tol == 0  # every member runs max_beats
    if fixed or queue_lanes(share) >= share:
        return jax.vmap(lambda m: _run_one(loop, problem(m)))(members)
    if not sharded:
        return _queue(loop, problem, members)
    mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
    spec = jax.sharding.PartitionSpec("batch")
    # check_vma off: the queue's lane bookkeeping starts the same on every device (not varying
    # over the batch axis) and becomes the device's own in the loop, which the check refuses
    return jax.shard_map(
        partial(_queue, loop, problem), mesh=mesh, in_specs=spec, out_specs=spec,
        check_vma=False,
    )(members)


def _queue(loop: _BeatLoop, problem, members) -> Beats:
    """The members on :func:`queue_lanes` lanes, each lane taking the next member waiting when
    its own is done (:func:`periodic_beats_batch`)."""
    n = jax.tree_util.tree_leaves(members)[0].shape[0]
    lanes = queue_lanes(n)

    def take(tree, index):
        return jax.tree_util.tree_map(lambda a: a[jnp.minimum(index, n - 1)], tree)

    starts = jax.vmap(lambda m: loop.start(problem(m)))(members)
    lane_step = jax.vmap(lambda m, c: loop.step(problem(m), c))
    lane_running = jax.vmap(loop.running)

    def body(state):
        store, slots, carry, waiting = state
        live = slots < n
        stepped = lane_step(take(members, slots), carry)
        carry = _where_lanes(live & lane_running(carry), stepped, carry)
        done = live & ~lane_running(carry)
        kept = jnp.where(done, slots, n)  # index n: dropped
        store = jax.tree_util.tree_map(
            lambda s, c: s.at[kept].set(c, mode="drop"), store, carry
        )
        queued = waiting + jnp.cumsum(done) - 1
        slots = jnp.where(done, jnp.minimum(queued, n), slots)
        carry = _where_lanes(done, take(starts, slots), carry)
        return store, slots, carry, waiting + jnp.sum(done)

    first = jnp.arange(lanes)
    state = (starts, first, take(starts, first), jnp.array(lanes))
    store, *_ = jax.lax.while_loop(lambda s: jnp.any(s[1] < n), body, state)
    return jax.vmap(lambda m, c: loop.finish(problem(m), c))(members, store)


def _run_one(loop: _BeatLoop, p: BeatProblem) -> Beats:
    carry = jax.lax.while_loop(loop.running, partial(loop.step, p), loop.start(p))
    return loop.finish(p, carry)


def _where_lanes(mask, a, b):
    """``a`` on the lanes where ``mask`` (leading axis) holds, ``b`` elsewhere."""
    return jax.tree_util.tree_map(
        lambda x, y: jnp.where(mask.reshape(mask.shape + (1,) * (x.ndim - 1)), x, y), a, b
    )
