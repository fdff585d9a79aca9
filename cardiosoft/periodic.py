"""Beat after beat to the periodic steady state: :func:`periodic_beats` for one member (or a
``vmap`` of members side by side), :func:`periodic_beats_batch` for a large batch run as a
queue. Each beat is one :func:`cardiosoft.solve.integrate` (the module that calls diffrax) in
the beat's phase; :mod:`cardiosoft.shooting` finds the same orbit by Newton's method.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.solve import (
    SUCCESSFUL,
    SolverConfig,
    integrate,
    preset,
    result_code,
    result_code_of,
)  # fmt: skip
from cardiosoft.units import ml, mmHg

__all__ = [
    "ACCUMULATORS",
    "PERIODIC_SCALES",
    "QUEUE_LANES",
    "BeatProblem",
    "Beats",
    "in_phase",
    "periodic_beats",
    "periodic_beats_batch",
    "queue_lanes",
]


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
