"""Run a read svZeroDSolver model: its beats from its initial condition, as svZeroDSolver defines
them, and its variables at svZeroDSolver's output times.

svZeroDSolver steps a fixed step of ``T / (N - 1)`` (N points a beat) with a generalized-alpha
scheme; here diffrax's adaptive solver integrates the states to the preset's tolerance and is
read out at the same times, so the answer is the model's converged one, not the scheme's.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.network.scheme import given_start, marches, steady_march
from cardiosoft.network.svzerod import Model
from cardiosoft.periodic import periodic_beats
from cardiosoft.program_store import stored_call
from cardiosoft.solve import PRESETS, SUCCESSFUL, SolverConfig, integrate, preset, result_code


@dataclass(frozen=True)
class Traces:
    """svZeroDSolver's variables at its output times.

    - ``time``: s (in the model's units); reset to 0 at the last beat's start unless every
      beat is output, as svZeroDSolver does;
    - ``values``: each variable by its svZeroDSolver name (``pressure:UP:DOWN``,
      ``flow:UP:DOWN``, ``pressure_c:NAME``, ...), in the model's units; with the model's
      ``output_derivative``, then each one's time derivative as ``ydot:NAME`` (its units per
      the model's unit of time);
    - ``mean_only``: the model's ``output_mean_only``: :meth:`write_csv` writes each
      variable's mean (:meth:`means`), not its samples;
    - ``solved``: the time integration reached the end, and the nodes' Newton converged at
      every output time; ``steady_start``: the steady start-up's
      Newton converged (None when the model starts from its initial condition);
    - ``steps``: the integrator's accepted steps, ``stiff``: whether the implicit solver was
      needed (the explicit one ran out of steps);
    - ``steady``: with :func:`simulate`'s ``steady``, whether the periodic steady state was
      reached (None when the model's own beats were run), after ``beats`` beats (the reported
      one included), the last one's cycle-to-cycle change ``residual`` (the largest state's
      change over its tolerance; at most 1 when steady). A model's own
      ``use_cycle_to_cycle_error`` without an RCR fills them too: whether its caps settled,
      the beats run in all, and the caps' largest change over its bound.

    A batch of variants (:func:`simulate`'s ``variants``) puts the variants' axis first in every
    ``values`` array; the flags hold for all of them and ``steps`` is the most any took.
    """

    time: np.ndarray
    values: dict
    solved: bool
    steady_start: bool | None
    steps: int
    stiff: bool
    steady: bool | None = None
    beats: int | None = None
    residual: float | None = None
    mean_only: bool = False

    def means(self) -> dict:
        """Each variable's mean over the output samples, as svZeroDSolver's ``output_mean_only``
        takes it: the samples' arithmetic mean, both ends of a beat included (not the time
        mean, :func:`~cardiosoft.network.block_metrics.time_mean`)."""
        return {k: np.mean(v, axis=-1) for k, v in self.values.items()}

    def variant(self, i: int) -> Traces:
        """Variant ``i`` of a batch (:func:`simulate`'s ``variants``) as one model's traces (the
        flags stay the batch's)."""
        return dataclasses.replace(self, values={k: v[i] for k, v in self.values.items()})

    def last_beat(self, points: int) -> Traces:
        """The last ``points`` samples (the model's points a beat: its last beat, whether or not
        every beat was output), time from 0."""
        if self.time.shape[0] == points:
            return self
        values = {k: v[..., -points:] for k, v in self.values.items()}
        time = self.time[-points:] - self.time[-points]
        return dataclasses.replace(self, time=time, values=values)

    def write_csv(self, path) -> None:
        """``time`` and one column per variable, as ``path`` (written whole or not at all); with
        ``mean_only``, one row of :meth:`means` and an empty ``time``, as svZeroDSolver leaves
        it."""
        from cardiosoft.files import atomic_path

        names = list(self.values)
        if self.mean_only:
            means = self.means()
            table = [["", *(f"{means[n]:.10g}" for n in names)]]
        else:
            table = np.column_stack([self.time, *(self.values[n] for n in names)])
        with atomic_path(path) as tmp:
            np.savetxt(
                tmp,
                table,
                delimiter=",",
                header=",".join(["time", *names]),
                comments="",
                fmt="%s" if self.mean_only else "%.10g",
            )


def _tolerances(net, x0, z0, rtol):
    """Absolute tolerances per state: ``rtol`` times the largest magnitude of its kind (pressure,
    flow, volume) at the start, so that a state near zero is not asked for digits it has not."""
    n = net.n_nodes
    scale = {
        "pressure": float(jnp.max(jnp.abs(z0[:n]), initial=0.0)),
        "flow": float(jnp.max(jnp.abs(z0[n:]), initial=0.0)),
        "volume": 0.0,
    }
    kinds = [k for b in net.blocks for k in b.state_kinds()]
    for k, v in zip(kinds, np.abs(np.asarray(x0)), strict=True):
        scale[k] = max(scale[k], float(v))
    return jnp.asarray([rtol * (scale[k] or 1.0) for k in kinds])


def _jump_times(net, t_end):
    """The time tables' samples over the run: kinks of the forcing the controller steps to."""
    knots = []
    for leaf in jax.tree_util.tree_leaves(net, is_leaf=lambda v: hasattr(v, "times")):
        if hasattr(leaf, "times") and leaf.times.shape[0] > 1:
            period = float(leaf.period)
            base = np.mod(np.asarray(leaf.times), period)
            cycles = np.arange(int(np.ceil(t_end / period)) + 1) * period
            knots.append((cycles[:, None] + base[None, :]).ravel())
    if not knots:
        return None
    knots = np.unique(np.concatenate(knots))
    knots = knots[(knots > 0) & (knots < t_end)]
    return jnp.asarray(knots) if knots.size else None  # diffrax takes no empty jump_ts


STEADY_TOLERANCE = 1000.0
"""With ``steady``, a beat is steady when no state changes over it by more than this many times
its integration tolerance (``rtol`` times the largest magnitude of its kind; preset "default":
1e-3 of it). The integration's own error sets a floor under a beat's change: once at its cycle,
the combined heart block (``ClosedLoopHeartAndPulmonary``) still moves its states by 170-350
times their tolerance a beat (median 250 on ``closedLoopHeart_singleVessel``, 280 with the
coronaries; measured over beats 20-60), where the decomposed heart and the open networks move
by less than 1."""
STEADY_MAX_BEATS = 1000
"""With ``steady``, the most beats run before the run is reported as not steady."""


def simulate(
    model: Model,
    accuracy: str = "default",
    *,
    rtol=None,
    variants=None,
    steady: bool = False,
    max_beats: int | None = None,
) -> Traces:
    """Run ``model`` for its number of beats and return its variables at svZeroDSolver's output
    times.

    - ``accuracy``: a solver preset (``cardiosoft.solve.PRESETS``); ``rtol`` overrides its
      relative tolerance (the absolute ones follow it, see ``_tolerances``).
    - ``steady``: run beat after beat to the periodic steady state instead of the model's
      ``number_of_cardiac_cycles`` (:data:`STEADY_TOLERANCE`, at most ``max_beats`` beats,
      default :data:`STEADY_MAX_BEATS`) and report the steady beat (time from 0,
      ``output_all_cycles`` notwithstanding).
    - ``variants``: ``model.network`` with a leading batch axis on its parameters (built, say,
      by ``jax.vmap`` over ``eqx.tree_at``): all of them are solved in one compiled, vectorised
      call. Every array of the result then has that axis first; ``solved`` and
      ``steady_start`` hold for all variants (each is the worst of them).
    """
    if accuracy not in PRESETS:
        raise ValueError(f"accuracy {accuracy!r} is not one of {', '.join(PRESETS)}")
    if not jax.config.jax_enable_x64:  # a float32 run could only ever report itself unsolved
        raise ValueError(
            "cardiosoft.network.simulate needs float64: the nodes' Newton stops at 1e-9 of "
            "each scale, which float32 cannot reach; call "
            "jax.config.update('jax_enable_x64', True) first"
        )
    sim = model.simulation
    net = model.network if variants is None else variants

    def each(f, *axes):  # f over the variants, or f itself for one network
        return f if variants is None else eqx.filter_vmap(f, in_axes=axes)

    def each_stored(jitted, *axes):  # likewise, one network's program from a command's store
        return functools.partial(stored_call, jitted) if variants is None else each(jitted, *axes)

    x0 = model.initial_states()
    steady_start = None
    if sim.steady_initial and marches(model.network):  # svZeroDSolver's march, as it goes
        ys, _, ok = each(steady_march, 0, None, None)(net, given_start(model), sim.rho_infty)
        x0 = ys[..., -1, : x0.shape[0]]
        steady_start = bool(jnp.all(ok))
    elif sim.steady_initial:
        x0, ok = each(_steady_state, 0, None)(net, x0)
        steady_start = bool(jnp.all(ok))
    x0 = each(_consistent, 0, 0 if sim.steady_initial else None)(net, x0)
    cycles, output_all = (1, False) if steady else (sim.cycles, sim.output_all_cycles)
    caps = () if steady else sim.caps
    if caps and variants is not None:
        raise ValueError("use_cycle_to_cycle_error runs one model, not a batch of variants")
    dt = model.network.period / sim.steps_per_cycle
    t_all = dt * np.arange(sim.steps_per_cycle * cycles + 1)
    kept = sim.points_per_cycle + sim.steps_per_cycle * bool(caps)  # caps: the last two beats
    ts = t_all if output_all else t_all[-kept:]
    ts = jnp.asarray(ts)
    periodic = dict(steady=None, beats=None, residual=None)
    if model.network.n_states == 0:
        zs, internal, converged = each(_read_out, 0, None, 0, None)(
            net, ts, jnp.zeros((ts.shape[0], 0)), sim.derivative
        )
        steps, stiff, solved = 0, False, True
        if steady:  # nothing to settle: every beat is the same
            periodic = dict(steady=True, beats=1, residual=0.0)
    else:
        rtol = PRESETS[accuracy]["rtol"] if rtol is None else rtol
        first, x_start = model.network, model.initial_states()
        atol = _tolerances(first, x_start, _start_nodes(first, x_start), rtol)
        jumps = _jump_times(first, t_all[-1])
        for stiff in (False, True):
            base = preset(accuracy, stiff=stiff)
            # the preset's step budget is a beat's: a run of many beats gets it for each
            budget = base.max_steps * cycles
            config = SolverConfig(base.solver, rtol, atol, base.pcoeff, base.icoeff, budget)
            x_first, started = x0, True
            if steady:
                x_first, beats, residual, result = each_stored(_steady_beats, 0, 0, *[None] * 4)(
                    net, x0, float(t_all[-1]), jumps, config, max_beats or STEADY_MAX_BEATS
                )
                started = bool(jnp.all(result == SUCCESSFUL))
                residual = float(jnp.max(residual))
                periodic = dict(steady=started and residual <= 1.0, beats=int(jnp.max(beats)))
                periodic["residual"] = residual
            zs, internal, converged, result, steps, x_end = each_stored(_run, 0, 0, *[None] * 5)(
                net, x_first, float(t_all[-1]), ts, jumps, config, sim.derivative
            )
            solved = started and bool(jnp.all(result == SUCCESSFUL))
            if solved:
                break
        steps = int(jnp.max(steps))
        if caps and solved:
            zs, internal, converged, ts, periodic, more = _until_caps_settle(
                model, x_end, (zs, internal, converged, ts), dt, config, base.max_steps
            )
            solved, steps = periodic["steady"] is not None, steps + more
    solved = solved and bool(jnp.all(converged))
    values = node_columns(model.network, zs)
    values.update(internal)  # with the derivative, its ydot: columns last
    values = {k: np.asarray(v) for k, v in values.items()}
    if caps and not output_all:  # the last beat alone
        values = {k: v[-sim.points_per_cycle :] for k, v in values.items()}
        ts = ts[-sim.points_per_cycle :]
    time = ts if sim.output_all_cycles else ts - ts[0]
    return Traces(
        np.asarray(time), values, solved, steady_start, steps, stiff, **periodic,
        mean_only=sim.mean_only,
    )  # fmt: skip


def node_columns(net, zs, prefix: str = "") -> dict:
    """Each node's pressure and flow in ``zs`` (nodes last) by svZeroDSolver's name."""
    n, columns = net.n_nodes, {}
    for i, (up, down) in enumerate(net.nodes):
        columns[f"{prefix}pressure:{up}:{down}"] = zs[..., i]
        columns[f"{prefix}flow:{up}:{down}"] = zs[..., n + i]
    return columns


def _caps_change(zs, caps, n, steps, error) -> float:
    """svZeroDSolver's ``check_vessel_cap_convergence`` on the last two beats of ``zs``: the
    largest change of a cap's mean flow or mean pressure over a beat's ``steps + 1`` samples
    (both ends, as svZeroDSolver averages them), relative to the earlier beat's, over
    ``error``. Settled at most 1; a 0 / 0 (NaN) passes, as upstream."""
    window = np.asarray(zs[-(2 * steps + 1) :])
    columns = [c for i in caps for c in (n + i, i)]
    before, last = window[: steps + 1, columns].mean(0), window[steps:, columns].mean(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        change = np.abs((last - before) / before) / error
    return float(np.max(np.nan_to_num(change, nan=0.0), initial=0.0))


def _until_caps_settle(model, x_end, run, dt, config, beat_steps):
    """``use_cycle_to_cycle_error`` without an RCR (:attr:`~cardiosoft.network.
    simulation_parameters.Simulation.cycle_error`): after the model's beats (``run``: their
    nodes, internal variables, Newton's flag and output times, the last two beats at least),
    one beat more at a time from ``x_end`` until the caps settle, at most
    :data:`STEADY_MAX_BEATS` more. Returns the run extended by those beats (every beat kept
    only with ``output_all_cycles``, else the last two), the periodic record (``steady`` None
    when a beat failed; ``beats`` all that ran) and the steps they took."""
    sim, net = model.simulation, model.network
    steps, n = sim.steps_per_cycle, net.n_nodes
    caps = [net.nodes.index(tuple(c.split(":"))) for c in sim.caps]
    zs, internal, converged, ts = run
    beat = jnp.asarray(dt * np.arange(steps + 1))
    jumps = _jump_times(net, float(beat[-1]))
    config = dataclasses.replace(config, max_steps=beat_steps)
    extra, taken = 0, 0
    change = _caps_change(zs, caps, n, steps, sim.cycle_error)
    while change > 1.0 and extra < STEADY_MAX_BEATS:
        z1, i1, c1, result, s1, x_end = _run(
            net, x_end, float(beat[-1]), beat, jumps, config, sim.derivative
        )
        if not bool(result == SUCCESSFUL):
            record = dict(steady=None, beats=sim.cycles + extra + 1, residual=None)
            return zs, internal, converged, ts, record, taken
        kept = slice(None) if sim.output_all_cycles else slice(-(2 * steps + 1), None)
        zs = jnp.concatenate([zs, z1[1:]])[kept]
        internal = {k: jnp.concatenate([v, i1[k][1:]])[kept] for k, v in internal.items()}
        converged, ts = converged & c1, jnp.concatenate([ts, ts[-1] + beat[1:]])[kept]
        extra, taken = extra + 1, taken + int(s1)
        change = _caps_change(zs, caps, n, steps, sim.cycle_error)
    record = dict(steady=change <= 1.0, beats=sim.cycles + extra, residual=change)
    return zs, internal, converged, ts, record, taken


@eqx.filter_jit
def _steady_beats(net, x0, period, jumps, config, max_beats):
    """Beat after beat from ``x0`` (:func:`cardiosoft.periodic.periodic_beats`) until two beats in a
    row change no state by more than :data:`STEADY_TOLERANCE` times its tolerance
    (``config.atol``). Returns the state at the start of the last beat, the beats run (that one
    included), its change over that tolerance, and diffrax's result."""
    tolerance = STEADY_TOLERANCE * config.atol
    out = periodic_beats(
        lambda t, x, _: net.vector_field(t, x), x0, period, None, jump_ts=jumps,
        total_volume=None, max_beats=max_beats, tol=1.0, config=config,
        change=lambda start, end: jnp.max(jnp.abs(end - start) / tolerance),
    )  # fmt: skip
    return out.y0, out.beats, out.residual, out.result


@eqx.filter_jit
def _start_nodes(net, x0):
    return net.node_values(0.0, x0)


def _steady_state(net, x0):
    return net.steady_state(x0)


def _consistent(net, x0):
    return net.consistent(0.0, x0)


RATE_LAG = 1e-10
"""With ``output_derivative``, the rates are read this fraction of a period before each output
time: at a time table's sample, where the output times usually fall, a table's slope jumps,
and the rate from the past is the one svZeroDSolver's stepping reports there (``ydot``); at
the output time itself, rounding in ``t`` would pick the side. The states' own rates move by
about 1e-10 of themselves over the lag."""


@eqx.filter_jit
def _read_out(net, ts, xs, derivative: bool):
    """The nodes' values, the internal variables and whether Newton converged, at ``ts``; with
    ``derivative``, the internal variables are followed by every variable's time derivative
    (``ydot:NAME``: the nodes', then the internal ones')."""
    zs = jax.vmap(net.node_values)(ts, xs)
    internal = jax.vmap(net.outputs)(ts, xs, zs)
    if derivative:
        before = ts - RATE_LAG * net.period
        _, (z_rates, rates) = jax.vmap(net.variables_and_rates)(before, xs)
        internal.update(node_columns(net, z_rates, "ydot:"))
        internal.update({f"ydot:{k}": v for k, v in rates.items()})
    n = net.n_nodes
    scale = jnp.stack([jnp.max(jnp.abs(zs[:, :n])), jnp.max(jnp.abs(zs[:, n:]))])
    converged = jax.vmap(net.newton_converged, in_axes=(0, 0, None))(ts, xs, scale)
    return zs, internal, jnp.all(converged)


def _field(t, x, net):
    return net.vector_field(t, x)


@eqx.filter_jit
def _run(net, x0, t_end, ts, jumps, config, derivative: bool):
    """The network's states from ``x0`` at t = 0 to ``t_end``, read out at ``ts``
    (:func:`_read_out`)."""
    sol = integrate(_field, x0, 0.0, t_end, args=net, ts=ts, jump_ts=jumps, config=config)
    steps = sol.stats["num_accepted_steps"]
    return (*_read_out(net, ts, sol.ys, derivative), result_code(sol.result), steps, sol.ys[-1])
