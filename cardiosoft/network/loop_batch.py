"""The batch solve of a closed-loop scene: members to their periodic steady state, per-side
metrics (issue 26).

    import cardiosoft as cs
    out = cs.solve_beats("heart", bpm=[60.0, 72.0, 90.0], save="metrics")
    out.metrics.left.cardiac_output, out.metrics.right.cardiac_output   # m^3/s per member

:func:`cardiosoft.solve_beats` hands a :class:`~cardiosoft.network.loop_scene.LoopScene` to
:func:`solve_loop`, which works like it: members broadcast to one batch axis, one jitted,
``vmap``-ed call, beat after beat (or Newton shooting, ``steady="shooting"``) from the scene's
initial state until the cycle-to-cycle change is below the scene's ``steady_tol``, the last
beat sampled at :data:`LOOP_SAMPLES` equal steps, a
:class:`~cardiosoft.batch.BeatSolution` back whose ``metrics`` are :class:`LoopMetrics`.

**Members** are any numbers of the scene by path
(:func:`~cardiosoft.network.loop_scene.loop_numbers`:
``"bpm"``, ``"lv.omega"``, ``"rv.shortening"``, ``"ar_sys.resistance"``, SI), scalars or 1-D
arrays; ``bpm``, ``omega`` and ``shortening`` are shorthands (the last two set every pump of the
scene). New values never recompile.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft._validate import check_range
from cardiosoft.beat_solution import (
    GUESS_BEATS,
    BeatSolution,
    broadcast_members,
    check_solve_options,
    shard,
    solution,
)
from cardiosoft.ensemble import ensemble_size, flat_batch, unflatten
from cardiosoft.metrics import trapezoid
from cardiosoft.network.closed_loop import CHAMBERS, DEFAULT_ENGINE, VESSELS, ClosedLoop
from cardiosoft.network.loop_scene import LoopScene, loop_circuit, loop_numbers, number_key
from cardiosoft.periodic import BeatProblem, periodic_beats_batch
from cardiosoft.program_store import stored_call
from cardiosoft.pump import PumpSurrogate, load
from cardiosoft.shooting import shoot_periodic
from cardiosoft.solve import SolverConfig, preset, ran_out_of_steps

__all__ = [
    "LOOP_SAMPLES",
    "SIDES",
    "STARTED_GUESS_BEATS",
    "STIFF_SIDE_BY_SIDE",
    "LoopMetrics",
    "SideMetrics",
    "loop_config",
    "loop_members",
    "loop_metrics",
    "scene_start",
    "solve_loop",
    "stiff_batch_size",
    "stiff_loop_config",
]

LOOP_SAMPLES = 401
"""Samples of the last beat, equally spaced from 0 to the period (both ends)."""
SIDES = {
    "left": ("la", "lv", "ar_sys", "aortic"),
    "right": ("ra", "rv", "ar_pul", "pulmonary"),
}
"""Each side of the heart: its atrium, ventricle, arterial compartment and outlet valve."""


class SideMetrics(eqx.Module):
    """One side of the heart over the last beat (SI). A native side's pump fields are NaN."""

    edv: jax.Array
    """End-diastolic (largest) ventricular volume (m^3)."""
    esv: jax.Array
    """End-systolic (smallest) ventricular volume (m^3)."""
    stroke_volume: jax.Array
    """EDV - ESV (m^3)."""
    ejection_fraction: jax.Array
    """SV / EDV."""
    cardiac_output: jax.Array
    """SV / period (m^3/s)."""
    net_output: jax.Array
    """Mean flow out of the side's arterial compartment into its circulation (m^3/s): the
    cardiac output net of the valves' backflow. At the periodic steady state the same on both
    sides and equal to the mean flow through every valve (mass balance); the arterial flow is
    a state, smooth, so its mean is accurate from the samples."""
    arterial_systolic: jax.Array
    """Largest arterial pressure (Pa): aortic (left), pulmonary arterial (right)."""
    arterial_diastolic: jax.Array
    """Smallest arterial pressure (Pa)."""
    arterial_mean: jax.Array
    """Time mean of the arterial pressure over the beat (Pa)."""
    atrial_mean: jax.Array
    """Time mean of the atrial pressure (Pa)."""
    atrial_min: jax.Array
    """Smallest atrial pressure of the beat (Pa); below 0 the atrium is below its unstressed
    volume."""
    ventricle_min_pressure: jax.Array
    """Smallest ventricular (pump) pressure (Pa)."""
    ventricle_max_pressure: jax.Array
    """Largest ventricular (pump) pressure (Pa)."""
    stroke_work: jax.Array
    """Area of the ventricle's pressure-volume loop, -(closed integral of p dV) (J)."""
    peak_force: jax.Array
    """A pump's largest cable force (N); NaN for a native ventricle."""
    min_cable_force: jax.Array
    """A pump's smallest cable force (N): negative means a cable that would push; NaN native."""
    cable_work: jax.Array
    """A pump's net work of the cables over the beat, the closed integral of F dx (J); NaN
    native."""
    efficiency: jax.Array
    """A pump's stroke work over its cables' work: the hydraulic work out per mechanical work
    in; NaN native."""


class LoopMetrics(eqx.Module):
    """The closed loop's metrics over the last beat (SI)."""

    left: SideMetrics
    right: SideMetrics
    pulmonary_volume: jax.Array
    """Mean blood volume in the pulmonary arteries and veins (m^3)."""
    systemic_volume: jax.Array
    """Mean blood volume in the systemic arteries and veins (m^3)."""
    total_volume: jax.Array
    """Blood volume of the loop (m^3), conserved."""


def _side(loop: ClosedLoop, ts, s, side: str) -> SideMetrics:
    atrium, ventricle, artery, _ = SIDES[side]
    period = ts[-1] - ts[0]
    volume, pressure = s[f"{ventricle}_volume"], s[f"{ventricle}_pressure"]
    edv, esv = jnp.max(volume), jnp.min(volume)
    nan = jnp.full_like(edv, jnp.nan)
    if ventricle in loop.pumps:
        force, pull = s[f"{ventricle}_cable_force"], s[f"{ventricle}_pull"]
        # the largest sample by index (its derivative is that sample's; batch.py's peak force)
        pump = (force[jnp.argmax(force)], jnp.min(force), trapezoid(force, pull))
    else:
        pump = (nan, nan, nan)
    stroke_work = -trapezoid(pressure, volume)
    return SideMetrics(
        edv=edv,
        esv=esv,
        stroke_volume=edv - esv,
        ejection_fraction=(edv - esv) / edv,
        cardiac_output=(edv - esv) / period,
        net_output=trapezoid(s[f"{artery}_flow"], ts) / period,
        arterial_systolic=jnp.max(s[f"{artery}_pressure"]),
        arterial_diastolic=jnp.min(s[f"{artery}_pressure"]),
        arterial_mean=trapezoid(s[f"{artery}_pressure"], ts) / period,
        atrial_mean=trapezoid(s[f"{atrium}_pressure"], ts) / period,
        atrial_min=jnp.min(s[f"{atrium}_pressure"]),
        ventricle_min_pressure=jnp.min(pressure),
        ventricle_max_pressure=jnp.max(pressure),
        stroke_work=stroke_work,
        peak_force=pump[0],
        min_cable_force=pump[1],
        cable_work=pump[2],
        efficiency=stroke_work / pump[2],
    )


def loop_metrics(loop: ClosedLoop, ts, signals: dict) -> LoopMetrics:
    """Metrics of one beat from its :meth:`ClosedLoop.signals` at ``ts`` (0 to the period)."""
    period = ts[-1] - ts[0]

    def mean_volume(*vessels):
        return sum(trapezoid(signals[f"{v}_volume"], ts) for v in vessels) / period

    return LoopMetrics(
        left=_side(loop, ts, signals, "left"),
        right=_side(loop, ts, signals, "right"),
        pulmonary_volume=mean_volume("ar_pul", "ven_pul"),
        systemic_volume=mean_volume("ar_sys", "ven_sys"),
        total_volume=sum(signals[f"{k}_volume"][0] for k in (*CHAMBERS, *VESSELS)),
    )


def _save_times(loop: ClosedLoop):
    return jnp.linspace(0.0, 1.0, LOOP_SAMPLES) * loop.period


@eqx.filter_jit
def _solve(
    structure,
    numbers,
    pump,
    members,
    max_beats: int,
    tol,
    config,
    save,
    steady,
    guess,
    newton,
    engine,
):
    def build(member):
        # an ensemble's member carries its own draw of the pump's arrays (pump: the rest)
        values = {k: v for k, v in member.items() if k != "pump"}
        own = pump if "pump" not in member else eqx.combine(member["pump"], pump)
        values.pop("start", None)
        loop = loop_circuit(structure.with_numbers(numbers | values), own, engine)
        return loop, None if save == "state" else _save_times(loop)

    def problem(member) -> BeatProblem:
        loop, ts = build(member)

        def observe(ts, ys):
            signals = jax.vmap(loop.signals)(ts, ys)
            return loop_metrics(loop, ts, signals)

        y0 = loop.init() if "start" not in member else started(loop, member["start"])
        return BeatProblem(
            loop, y0, loop.period, ts, loop.kink_times(), loop.total_volume,
            None if save == "traces" else observe,
        )

    def report(member, out):
        if save != "traces":
            return out.observed, None  # the metrics, or None without a sampled beat
        loop, ts = build(member)
        signals = jax.vmap(loop.signals)(ts, out.observed)
        return loop_metrics(loop, ts, signals), {"time": ts, **signals}

    def shoot(member):
        p = problem(member)
        guess_beats = min(guess, max_beats)
        if "start" in member:  # a member given a start is near its orbit already
            given = jnp.any(~jnp.isnan(jnp.stack(jax.tree.leaves(member["start"]))))
            guess_beats = jnp.where(given, min(STARTED_GUESS_BEATS, guess_beats), guess_beats)
        return shoot_periodic(
            p.field, p.y0, p.period, p.ts, jump_ts=p.jump_ts, total_volume=p.total_volume,
            closed=True, guess_beats=guess_beats, max_beats=max_beats, tol=tol,
            config=config, observe=p.observe, max_newton=newton,
        )

    if steady == "shooting":
        out = jax.vmap(shoot)(members)
    else:  # every member at its own pace (periodic.periodic_beats_batch)
        out = periodic_beats_batch(problem, members, max_beats=max_beats, tol=tol, config=config)
    metrics, traces = jax.vmap(report)(members, out)
    return metrics, traces, out


def started(loop: ClosedLoop, start: dict) -> dict:
    """``loop``'s initial state with the given ``start`` in place of its values (a NaN keeps
    the loop's own), holding the loop's own total blood volume: its orbits form a family, one
    per total (:func:`~cardiosoft.shooting.shoot_periodic`), so the left atrium, the volume the
    shooting eliminates, takes the difference. The total depends on the initial volumes and
    pressures and the compliances, not on a pump's design: another design's orbit in the same
    loop leaves no difference, one from a loop of other numbers does."""
    own = loop.init()
    y = jax.tree.map(lambda mine, given: jnp.where(jnp.isnan(given), mine, given), own, start)
    gap = loop.total_volume(own) - loop.total_volume(y)
    first = CHAMBERS[0]
    return y | {first: {**y[first], "volume": y[first]["volume"] + gap}}


STARTED_GUESS_BEATS = 2
"""Beats before Newton starts, for a member given a ``start`` (:func:`solve_loop`): from a
nearby design's orbit the slow venous mode still changes a beat by more than the steady
tolerance, so the guess would run all of its beats, where Newton needs none of them."""


def scene_start(n: int) -> dict:
    """A :func:`solve_loop` ``start`` of ``n`` members that keeps the scene's initial state
    (every value NaN), in the layout of :meth:`ClosedLoop.init`."""
    nan = np.full(n, np.nan)
    return {c: {"volume": nan} for c in CHAMBERS} | {
        v: {"pressure": nan, "flow": nan} for v in VESSELS
    }


def _start_states(start: dict, n: int) -> dict:
    """``start`` (:func:`solve_loop`) as float arrays of ``n`` members, laid out as
    :func:`scene_start`'s."""
    layout = scene_start(n)
    if jax.tree.structure(start) != jax.tree.structure(layout):
        parts = {part: list(states) for part, states in layout.items()}
        raise ValueError(f"start: a state needs the parts {list(parts)} with {parts}")
    ftype = jnp.result_type(float)
    try:
        return jax.tree.map(lambda a: jnp.broadcast_to(jnp.asarray(a, ftype), (n,)), start)
    except ValueError as err:
        raise ValueError(f"start: every value one per member ({n}): {err}") from None


def _split(scene: LoopScene):
    """(structure, numbers): ``scene`` with its numbers as float64 arrays beside it; the
    structure keeps the rest (chamber kinds, valve law, shapes), hashable and static."""
    ftype = jnp.result_type(float)
    numbers = {k: jnp.asarray(v, dtype=ftype) for k, v in loop_numbers(scene).items()}
    blank = dataclasses.replace(
        scene, name="", source="", description="", accuracy="", max_beats=0, steady_tol=0.0
    )
    return blank.with_numbers(dict.fromkeys(numbers)), numbers


def loop_members(scene: LoopScene, members: dict) -> dict:
    """The member values ``{path: values}`` (SI) of ``scene``, checked against their ranges
    where concrete (``ValueError`` naming the path), broadcast to one batch axis (the scene's
    rate, one member, when there are none)."""
    for path, values in members.items():
        key = number_key(scene, path)  # raises for a path the scene does not have
        if not isinstance(values, jax.core.Tracer):
            check_range(
                path,
                np.asarray(values, dtype=float),
                key.unit,
                key.lo,
                key.hi,
                lo_open=key.lo_open,
                scale=key.scale,
            )
    return broadcast_members(members or {"bpm": scene.bpm})


def solve_loop(
    scene: LoopScene,
    *,
    members: dict | None = None,
    bpm=None,
    omega=None,
    shortening=None,
    beats: int | None = None,
    save: str = "traces",
    steady: str = "beats",
    pump: PumpSurrogate | None = None,
    config: SolverConfig | None = None,
    guess_beats: int = GUESS_BEATS,
    max_newton: int = 8,
    engine: str = DEFAULT_ENGINE,
    start: dict | None = None,
) -> BeatSolution:
    """Simulate a batch of members of a closed-loop scene to their periodic steady state.

    **Arguments:**

    - ``scene``: a :class:`~cardiosoft.network.loop_scene.LoopScene`.
    - ``members``: ``{path: values}`` (module docstring); ``bpm`` (beats per minute),
      ``omega`` and ``shortening`` (every pump's design) are shorthands for ``"bpm"`` and
      ``"<pump>.omega"``, ``"<pump>.shortening"``.
    - ``beats``: exactly this many beats, in [1, 500] (default: until steady, at most the
      scene's ``max_beats``).
    - ``save``: ``"traces"`` (the last beat's signals, :meth:`ClosedLoop.signals`, with
      ``time``), ``"metrics"`` or ``"state"`` (:data:`~cardiosoft.batch.SAVE_MODES`).
    - ``steady``: ``"beats"`` or ``"shooting"`` (Newton on the one-beat map, the total blood
      volume held; :func:`cardiosoft.shooting.shoot_periodic`).
    - ``pump``: the surrogate of the pump chambers (default the shipped one); an *ensemble*
      (a leading axis of S draws on some of its arrays, :func:`cardiosoft.pump.load_posterior`)
      solves every draw at every member in the same call, and every array of the result has
      the shape ``(S, M, ...)`` (:mod:`cardiosoft.batch`'s ensembles).
    - ``config``: a :class:`~cardiosoft.solve.SolverConfig`; default the scene's accuracy
      preset with Tsit5 in forward mode (:func:`loop_config`), and for the members that run
      out of its steps the implicit Kvaerno5 (:func:`stiff_loop_config`), solved again (in a
      batch of :func:`stiff_batch_size`).
    - ``guess_beats``: with ``steady="shooting"``, the beats from the scene's initial state
      before Newton starts (default :data:`~cardiosoft.beat_solution.GUESS_BEATS`). Far from the
      shipped designs a closed loop's slow venous mode needs more: from 5, Newton failed on 10
      of 81 grid designs of ``tah`` and fell back to beats (each such batch 30 times slower);
      from 30, on 3 (``cardiosoft.design.loop``).
    - ``max_newton``: Newton's iterations at most, then beat after beat. The arctan valves
      (a 1e7 ratio of closed to open resistance) make the one-beat map nearly kinked: near the
      design box's corners Newton converges linearly, in 6-16 iterations on ``tah`` (Omega 6,
      C 0.65 on the left).
    - ``engine``: ``"network"`` (default) or ``"direct"``
      (:attr:`~cardiosoft.network.closed_loop.ClosedLoop.engine`).
    - ``start``: the members' states at the first beat's start, a dict like
      :attr:`~cardiosoft.batch.BeatSolution`'s ``y0`` with the batch axis on every leaf (SI), in
      place of the scene's initial state; a NaN keeps the scene's value, and the left atrium's
      volume keeps each member's own total blood volume (:func:`started`). From a nearby
      design's orbit the beats are steady after two (``cardiosoft.design.loop``).

    **Returns:** a :class:`~cardiosoft.batch.BeatSolution` whose ``metrics`` are
    :class:`LoopMetrics`; nothing is raised for a member that fails or is not steady.
    """
    check_solve_options(save, steady, beats)
    members = dict(members or {})
    if bpm is not None:
        members["bpm"] = bpm
    for name, value in (("omega", omega), ("shortening", shortening)):
        if value is None:
            continue
        if not scene.pumps:
            raise ValueError(f"{name}: scene {scene.name} has no soft pump to design")
        members |= {f"{c}.{name}": value for c in scene.pumps}
    members = loop_members(scene, members)
    if start is not None:
        start = _start_states(start, next(iter(members.values())).shape[0])
    pump = load(scene.pump) if pump is None and scene.pumps else pump
    chosen = config
    config = loop_config(scene) if config is None else config
    max_beats, tol = (int(beats), 0.0) if beats is not None else (scene.max_beats, scene.steady_tol)
    structure, numbers = _split(scene)
    method = "beats" if beats is not None else steady

    size = None if pump is None else ensemble_size(pump)
    batch, shared = members, pump
    if size is not None:  # every draw at every member, on one flat axis
        batch, shared = flat_batch(members, pump, {}, size)
        start = None if start is None else jax.tree.map(lambda a: jnp.tile(a, size), start)
    if start is not None:
        batch = batch | {"start": start}

    def solve(batch, config):
        return stored_call(
            _solve,
            structure,
            numbers,
            shared,
            shard(batch),
            max_beats,
            tol,
            config,
            save,
            method,
            int(guess_beats),
            int(max_newton),
            engine,
        )

    solved = solve(batch, config)
    out_of_steps = ran_out_of_steps(solved[2].result)
    ran_out = np.flatnonzero(out_of_steps)
    if chosen is None and ran_out.size:
        # the members (or draws) the explicit solver ran out of steps on are stiff: solve them
        # again, implicitly, repeated to a batch size that many counts share
        picked = np.resize(ran_out, stiff_batch_size(ran_out.size, len(out_of_steps)))
        again = solve(jax.tree.map(lambda a: a[picked], batch), stiff_loop_config(scene))
        again = jax.tree.map(lambda b: jnp.asarray(b)[: ran_out.size], again)
        solved = jax.tree.map(lambda a, b: jnp.asarray(a).at[ran_out].set(b), solved, again)
    if size is not None:
        solved = unflatten(solved, size)
    return solution(scene, members, config, *solved, beats is not None)


STIFF_SIDE_BY_SIDE = 8
"""A batch of at most this many members solves its stiff ones again at its own size
(:func:`stiff_batch_size`)."""


def stiff_batch_size(stiff: int, members: int) -> int:
    """How many members :func:`solve_loop` solves implicitly when ``stiff`` of its ``members``
    ran out of the explicit solver's steps (the stiff ones repeated to that size). Each batch
    size is a program to trace and compile: on ``tah`` near 180 bpm, 52-55 s each, where
    solving one member takes 2.1 s and six 4.5 s. So a small batch (a design's calls, of 2-6
    members) takes them at its own size, one program for any count, and a larger one at the
    next power of two."""
    if members <= STIFF_SIDE_BY_SIDE:
        return members
    return min(members, 1 << (stiff - 1).bit_length())


def stiff_loop_config(scene: LoopScene) -> SolverConfig:
    """The scene's accuracy preset with the implicit Kvaerno5, in forward mode: what
    :func:`solve_loop` takes for the members the explicit :func:`loop_config` runs out of steps
    on (near the design box's corners at 120-180 bpm, a pump's valves make the loop stiff)."""
    return dataclasses.replace(preset(scene.accuracy, stiff=True), adjoint="ForwardMode")


def loop_config(scene: LoopScene) -> SolverConfig:
    """The scene's accuracy preset with Tsit5, in forward mode (``jax.jacfwd`` through the beat
    loop, as :func:`cardiosoft.batch.default_config`).

    Tsit5, not the stiff preset that the pump scenes' valves get: on ``heart`` at the default
    preset, 178 steps a beat (31 rejected) against Kvaerno5's 78 (8), but 0.24 s against 0.76 s
    for 30 beats and a third of the compile time (measured 2026-12, two busy cores)."""
    return dataclasses.replace(preset(scene.accuracy), adjoint="ForwardMode")
