"""The public batch solve: a scene for a batch of designs and afterloads, in one compiled call.

    import cardiosoft as cs
    from cardiosoft.units import mmHg

    scene = cs.load_scene("bench-dynamic")
    out = cs.solve_beats(scene, omega=[3.0, 4.0, 5.0], afterload=90 * mmHg, save="metrics")
    out.metrics.stroke_volume      # m^3, one per member
    out.steady, out.succeeded      # can each member be trusted?

Everything above the solve goes through here: :func:`cardiosoft.run` and
:func:`cardiosoft.sweep`, the command-line tools, the bench calibration (``fit.bench``), the
benchmarks, and a researcher's own design script.

**Members.** ``omega``, ``shortening`` (C), ``bpm`` and ``afterload`` (the column head, Pa) are
scalars or 1-D arrays; they are broadcast against each other to one batch axis, and each member
is a scene that differs from ``scene`` only in them. ``None`` keeps the scene's value (for the
afterload of a water-column scene: every head of the scene). Every other number of the scene is
shared by all members; it may be a JAX array, so ``scene.replace(tube_length=L)`` with a traced
``L`` differentiates with respect to it.

**Beats.** :func:`solve_beats` builds each member's :class:`~cardiosoft.circuit.PumpCircuit`
and integrates beat after beat from rest until the cycle-to-cycle change of the state is below
the scene's ``steady_tol`` (or exactly ``beats`` beats), every member at its own pace, in one
jitted, ``vmap``-ed call sharded over ``jax.devices()``; a large batch runs as a queue on fewer
lanes, so that a member slow to settle does not hold the others
(:func:`cardiosoft.periodic.periodic_beats_batch`). Numbers are array leaves: a new design,
afterload, rate or tolerance does not recompile; a new batch size, effect or save mode does.

**Ensembles.** A ``pump`` whose fitted array leaves carry one leading axis of S draws (a
posterior, :func:`cardiosoft.pump.load_posterior`; :mod:`cardiosoft.ensemble`), and
``scene_draws`` (scene numbers per draw, e.g. the bench's calibrated tube), are one more batch
axis: every draw at every member, in the same one compiled call (draw-major on the flat batch
axis); the results have shape ``(S, M, ...)``. A draw that fails is reported in ``succeeded``
and ``message((s, i))`` like any member, never dropped.

**Save modes.** Beats are integrated saving only their end states; the last beat is integrated
once more from its start, sampled at :data:`SAMPLES_PER_BEAT` times, and its
:class:`~cardiosoft.metrics.BeatMetrics` computed from the samples. ``save="traces"`` returns
those samples too (the CLI's traces, the figures, the notebooks); ``save="metrics"`` returns
the metrics only, nothing of the beat's length (the optimiser, the sweeps); ``save="state"``
integrates no sampled beat and returns neither, only the periodic state reached (``y0``) and
whether it can be trusted (to start :func:`solve_orbit` from).

**Derivatives.** The beat loop is a ``while_loop`` whose number of beats depends on the data,
so the solve is differentiable in forward mode: ``jax.jvp`` and ``jax.jacfwd`` of any metric with
respect to the members (Omega, C, bpm, afterload) or any number of the scene. The default solver
configuration uses ``diffrax.ForwardMode`` for that reason (reverse mode, ``jax.grad``, cannot
pass the loop). The derivative is that of the discretisation taken (diffrax stops gradients
through step-size adaptation) and of the beats actually run: with a fixed number of beats it is
the exact derivative of a smooth function; at the steady state the beat count is piecewise
constant in the parameters, and the derivative agrees with finite differences of converged runs
to about the steady tolerance: measured at Omega 4, C 0.4, 60 mmHg with the default preset,
d SV / d C = 58.16 ml against central differences of independently converged runs of 57.90 to
58.16 ml (steps 1e-4 to 1e-2 in C), within 0.5 %; with the beats fixed and equal steps, to
1e-4 or better (``tests/test_batch.py``). With ``steady="shooting"`` the derivative is the
periodic orbit's itself (implicit function theorem), and :func:`solve_orbit` gives it from an
orbit found earlier without derivatives (the design search's way: two smaller compiles).

Which metrics are smooth: the mechanical and hydraulic work and the stroke work are quadratures
of the samples, smooth in every parameter; the efficiency is their ratio. The stroke volume
(EDV - ESV, the largest minus the smallest volume sample) and the peak force (the largest force
sample of the pull) are extrema over samples: their derivative is that of the extreme sample,
exact while the same sample stays the extreme and one-sided where two samples tie (a kink in the
parameter, not a jump; the samples are dense enough that it moves by one sample at a time).
"""

from __future__ import annotations

import dataclasses
import math
import os

import equinox as eqx
import jax
import jax.numpy as jnp

from cardiosoft import ensemble as _ensemble
from cardiosoft._validate import check_range
from cardiosoft.actuation import CablePull
from cardiosoft.beat_solution import (
    GUESS_BEATS,
    SAVE_MODES,
    STEADY_METHODS,
    BeatSolution,
    broadcast_members,
    check_solve_options,
)
from cardiosoft.beat_solution import shard as _shard
from cardiosoft.beat_solution import solution as _solution
from cardiosoft.circuit import (
    CableFriction,
    CableSlack,
    PumpCircuit,
    ShellViscoelasticity,
    WallContact,
)
from cardiosoft.ensemble import ensemble_axes, flat_batch, unflatten
from cardiosoft.metrics import beat_metrics, trapezoid
from cardiosoft.network.bench import DEFAULT_ENGINE, ENGINES, BenchNetwork
from cardiosoft.periodic import BeatProblem, periodic_beats_batch
from cardiosoft.program_store import stored_call
from cardiosoft.pump import PumpSurrogate, load
from cardiosoft.scene import RANGES, Scene, load_scene
from cardiosoft.shooting import orbit_beat, shoot_periodic
from cardiosoft.solve import SolverConfig, preset
from cardiosoft.static import column_stiffness, static_strokes
from cardiosoft.units import RHO_WATER, G, bpm, mmHg

__all__ = [
    "SAMPLES_PER_BEAT",
    "SAVE_MODES",
    "STEADY_METHODS",
    "BeatSolution",
    "StaticSolution",
    "default_config",
    "ensemble_axes",
    "ensemble_size",
    "scene_circuit",
    "solve_beats",
    "solve_orbit",
    "solve_static",
]

PULL_SAMPLES = 201
"""Samples of the pull phase; the force curve, peak force and mechanical work use them."""
SAMPLES_PER_BEAT = PULL_SAMPLES + 200
"""Samples of one beat: the pull phase (its end on the grid), then 200 over the rest."""
MEMBER_FIELDS = ("omega", "shortening", "bpm", "afterload")
"""What may differ between the members of one batch."""
# Scene fields that are numbers (or tuples of numbers) of the physics: array leaves of the solve.
SCENE_NUMBERS = (
    "omega",
    "shortening",
    "bpm",
    "pull_fraction",
    "hold_fraction",
    "release_fraction",
    "column_diameter",
    "tube_length",
    "tube_diameter",
    "loss_coefficient",
    "windkessel",
    "venous_pressure",
    "preload_pressure",
    "valve_smoothing",
    "valve_resistance",
    "cable_friction",
    "viscoelastic_ratio",
    "relaxation_time",
    "ramp_time",
)


def ensemble_size(pump: PumpSurrogate, scene_draws: dict | None = None) -> int | None:
    """The number of draws S of an ensemble pump (and ``scene_draws``), or None for a single
    pump (:func:`cardiosoft.ensemble.ensemble_size`; the scene numbers that may vary between
    draws are :data:`SCENE_NUMBERS` but the members')."""
    drawable = tuple(f for f in SCENE_NUMBERS if f not in MEMBER_FIELDS)
    return _ensemble.ensemble_size(pump, scene_draws, drawable)


def scene_circuit(
    scene: Scene,
    pump: PumpSurrogate,
    afterload=None,
    *,
    energy: bool = False,
    engine: str = DEFAULT_ENGINE,
) -> PumpCircuit | BenchNetwork:
    """The :class:`PumpCircuit` of one member of ``scene``, with only the scene's effects.

    ``afterload`` is the column head (Pa) of a water-column scene (default: its first) and is
    ignored by a Windkessel scene. ``energy``: keep the energy account
    (:meth:`PumpCircuit.power`). ``engine``: ``"network"`` (the default,
    :data:`~cardiosoft.network.closed_loop.DEFAULT_ENGINE`), the equations as a network of
    blocks (:class:`~cardiosoft.network.bench.BenchNetwork`); ``"direct"``, the circuit's
    equations written out, the second implementation it is tested against. Numbers may be
    traced (this runs inside the batch solve).
    """
    if engine not in ENGINES:
        raise ValueError(f"engine = {engine!r} is not one of {', '.join(ENGINES)}")
    stroke = scene.shortening * pump.cable_length(scene.omega)
    actuation = CablePull(
        stroke,
        1.0 / (scene.bpm * bpm),
        scene.pull_fraction,
        scene.hold_fraction,
        scene.release_fraction,
        ramp_time=scene.ramp_time,
        shape=scene.shape,
    )
    friction = CableFriction(scene.cable_friction) if scene.has("cable_friction") else None
    viscoelasticity = (
        ShellViscoelasticity(scene.viscoelastic_ratio, scene.relaxation_time)
        if scene.has("shell_viscoelasticity")
        else None
    )
    circuit = PumpCircuit(
        pump,
        scene.omega,
        actuation,
        **scene.afterload.blocks(scene, _head(scene) if afterload is None else afterload),
        cable_friction=friction,
        viscoelasticity=viscoelasticity,
        cable_slack=CableSlack() if scene.has("cable_slack") else None,
        wall_contact=WallContact() if scene.has("wall_contact") else None,
        energy=energy,
    )
    return circuit if engine == "direct" else BenchNetwork(circuit)


def _head(scene: Scene):
    """The first column head of a water-column scene; None (unused) for a Windkessel."""
    return scene.afterloads[0] if scene.afterload.has_heads else None


def default_config(scene: Scene) -> SolverConfig:
    """The scene's accuracy preset, stiff when it has valves, in forward mode (module docstring)."""
    config = preset(scene.accuracy, stiff=scene.has("valves"))
    return dataclasses.replace(config, adjoint="ForwardMode")


def _members(scene: Scene, omega, shortening, bpm_value, afterload) -> dict:
    """The member values, validated where concrete, broadcast to one batch axis."""
    if scene.afterload.has_heads:
        if afterload is None:
            afterload = jnp.asarray(scene.afterloads)
        check_range("afterload", afterload, "mmHg", *RANGES["afterloads"], scale=mmHg)
    elif afterload is not None:
        raise ValueError(
            f"afterload: scene {scene.name} has a {scene.afterload_type} afterload, which "
            "has no column head to set"
        )
    else:
        afterload = jnp.nan
    values = {
        "omega": scene.omega if omega is None else omega,
        "shortening": scene.shortening if shortening is None else shortening,
        "bpm": scene.bpm if bpm_value is None else bpm_value,
        "afterload": afterload,
    }
    check_range("omega", values["omega"], "", *RANGES["omega"])
    check_range("shortening C", values["shortening"], "", *RANGES["shortening"])
    check_range("bpm", values["bpm"], "bpm", *RANGES["bpm"], lo_open=True)
    return broadcast_members(values)


def split_scene(scene: Scene, *, keep_steady: bool = False):
    """(structure, numbers): the hashable, static part of ``scene`` and its numbers as arrays.

    What the circuit's structure does not depend on is blanked: a scene of another name or
    accuracy, with the same effects, reuses the compiled solve. ``keep_steady`` keeps
    ``max_beats`` and ``steady_tol`` (for a caller that rebuilds the scene and passes it to
    :func:`solve_beats`)."""
    ftype = jnp.result_type(float)
    numbers = {f: jnp.asarray(getattr(scene, f), dtype=ftype) for f in SCENE_NUMBERS}
    steady = {} if keep_steady else dict(max_beats=0, steady_tol=0.0)
    structure = dataclasses.replace(
        scene,
        **dict.fromkeys(SCENE_NUMBERS),
        **dict.fromkeys(("name", "source", "description", "accuracy"), ""),
        afterloads=(),
        **steady,
    )
    return structure, numbers


def _save_times(actuation: CablePull):
    """Samples of one beat with the end of the pull on the grid (the first PULL_SAMPLES)."""
    t_pull = actuation.pull_fraction * actuation.period
    pull = jnp.linspace(0.0, 1.0, PULL_SAMPLES) * t_pull
    n_rest = SAMPLES_PER_BEAT - PULL_SAMPLES
    rest = t_pull + jnp.linspace(0.0, 1.0, n_rest + 1)[1:] * (actuation.period - t_pull)
    return jnp.concatenate([pull, rest])


def _metrics(circuit: PumpCircuit, ts, ys):
    """The beat's signals and metrics from its saved states."""
    signals = jax.vmap(circuit.signals)(ts, ys)
    if circuit.preload is None:  # the bench: P_a is the column head before the pull
        reference = circuit.afterload.node_pressure(circuit.afterload.init())
    else:  # a Windkessel: the afterload pressure's mean over time (the samples are denser
        # in the pull than after it, so not their plain mean)
        reference = trapezoid(signals["node_pressure"], ts) / (ts[-1] - ts[0])
    energy = None
    if circuit.energy:
        first, last = (jax.tree_util.tree_map(lambda a, i=i: a[i], ys) for i in (0, -1))
        terms = {k: v[-1] - v[0] for k, v in ys["energy"].items()}
        start = circuit.stored_energy(ts[0], first)
        energy = (terms, circuit.stored_energy(ts[-1], last) - start, start)
    metrics = beat_metrics(
        ts, ys["volume"], signals, PULL_SAMPLES, circuit.actuation.period, reference, energy
    )
    return signals, metrics


@eqx.filter_jit
def _solve(
    structure, numbers, pump, members, max_beats: int, tol, config, save, steady, energy, engine
):
    def build(member):
        values = {k: v for k, v in member.items() if k not in ("afterload", "start", "pump")}
        scene = dataclasses.replace(structure, **(numbers | values))
        # an ensemble's member carries its own draw of the pump's arrays (pump: the rest)
        own = pump if "pump" not in member else eqx.combine(member["pump"], pump)
        circuit = scene_circuit(scene, own, member["afterload"], energy=energy, engine=engine)
        ts = None if save == "state" else _save_times(circuit.actuation)
        observe = None if save == "traces" else (lambda ts, ys: _metrics(circuit, ts, ys)[1])
        return circuit, ts, observe

    def problem(member) -> BeatProblem:
        circuit, ts, observe = build(member)
        return BeatProblem(
            circuit, circuit.init(), circuit.actuation.period, ts,
            circuit.actuation.kink_times(1), circuit.total_volume, observe,
        )

    def report(member, out):
        if save != "traces":
            return out.observed, None  # the metrics, or None without a sampled beat
        circuit, ts, _ = build(member)
        signals, metrics = _metrics(circuit, ts, out.observed)
        return metrics, {"time": ts, **_flat_states(out.observed), **signals}

    def orbit_or_shooting(member):
        p = problem(member)
        common = dict(total_volume=p.total_volume, config=config, observe=p.observe)
        if steady == "orbit":
            init = p.y0
            # a start that is not finite (a failed member's) begins at rest instead: its beat
            # is then far from periodic, and the member reported not steady
            leaves = jax.tree_util.tree_leaves(member["start"])
            finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(a)) for a in leaves]))
            start = jax.tree_util.tree_map(
                lambda a, b: jnp.where(finite, a, b), member["start"], init
            )
            out = orbit_beat(
                p.field, start, p.period, p.ts, jump_ts=p.jump_ts,
                v_ref=p.total_volume(init), closed=p.field.preload is None, **common,
            )
        else:  # shooting
            out = shoot_periodic(
                p.field, p.y0, p.period, p.ts, closed=p.field.preload is None,
                guess_beats=min(GUESS_BEATS, max_beats), jump_ts=p.jump_ts,
                max_beats=max_beats, tol=tol, **common,
            )
        return out

    if steady == "beats":  # every member at its own pace (periodic.periodic_beats_batch)
        out = periodic_beats_batch(problem, members, max_beats=max_beats, tol=tol, config=config)
    else:
        out = jax.vmap(orbit_or_shooting)(members)
    metrics, traces = jax.vmap(report)(members, out)
    return metrics, traces, out


def _flat_states(ys: dict) -> dict:
    """The state's leaves by their own names (``volume``, ``column_volume``, ``relaxation``...)."""
    flat, _ = jax.tree_util.tree_flatten_with_path(ys)
    return {path[-1].key: leaf for path, leaf in flat}


def solve_beats(
    scene="bench-dynamic",
    *,
    omega=None,
    shortening=None,
    bpm=None,
    afterload=None,
    beats: int | None = None,
    save: str = "traces",
    steady: str = "beats",
    energy: bool = False,
    pump: PumpSurrogate | None = None,
    config: SolverConfig | None = None,
    scene_draws: dict | None = None,
    engine: str = DEFAULT_ENGINE,
) -> BeatSolution:
    """Simulate a batch of members of ``scene`` to their periodic steady state (module docstring).

    **Arguments:**

    - ``scene``: an open-loop :class:`~cardiosoft.scene.Scene`, a shipped scene's name or a
      scene file. :func:`cardiosoft.solve_beats` (:func:`cardiosoft.scene_tools.solve_beats`)
      takes a closed loop too.
    - ``omega``, ``shortening``: the design (dimensionless); ``bpm``: beats per minute;
      ``afterload``: column head (Pa) of a water-column scene. Scalars or 1-D arrays, broadcast
      to one batch axis; ``None`` keeps the scene's value(s).
    - ``beats``: run exactly this many beats, in [1, 500] (default: until steady, at most the
      scene's ``max_beats``).
    - ``save``: ``"traces"``, ``"metrics"`` or ``"state"`` (:data:`SAVE_MODES`).
    - ``steady``: ``"beats"``, beat after beat from rest until the cycle-to-cycle change is
      below the scene's ``steady_tol``; or ``"shooting"``, :data:`GUESS_BEATS` beats, then
      Newton's method on the one-beat map (:func:`cardiosoft.shooting.shoot_periodic`), whose
      derivative is that of the periodic orbit itself (implicit function theorem), with beat
      after beat as the fallback. Ignored with a fixed number of ``beats``.
    - ``energy``: keep the energy account of every beat (:meth:`PumpCircuit.power`); the
      metrics then hold ``work_in``, ``work_delivered``, ``work_lost``, ``stored_change``,
      ``energy_residual`` and ``energy_efficiency``. It puts the cable force into the vector
      field: slower, and the added states change the adaptive steps (to within tolerance).
    - ``pump``: a :class:`~cardiosoft.pump.PumpSurrogate`; default the shipped one. An
      *ensemble* (:func:`cardiosoft.pump.load_posterior`: a leading axis of S draws on some of
      its array leaves) is one more batch axis (module docstring, "Ensembles").
    - ``config``: a :class:`~cardiosoft.solve.SolverConfig`; default :func:`default_config`.
    - ``scene_draws``: scene numbers that differ between the ensemble's draws, ``{field: (S,)
      array}`` (SI; fields of :data:`SCENE_NUMBERS` that are not members), e.g. the bench's
      calibrated tube per draw; with a single pump, an ensemble of the scene's numbers alone.
    - ``engine``: ``"network"`` (default), the scene as a network of blocks, or ``"direct"``,
      its equations written out (:func:`scene_circuit`); the two agree to the solver's
      tolerance.

    **Returns:** a :class:`BeatSolution`. Nothing is raised for a member that fails or is not
    steady: see ``succeeded``, ``steady`` and ``message(i)``. Bad input raises ``ValueError``.
    With an ensemble, every array but ``members`` has the shape ``(S, M, ...)`` (draws, then
    members), and ``message((s, i))`` speaks of draw s of member i.
    """
    scene = load_scene(scene) if isinstance(scene, str | os.PathLike) else scene
    if not isinstance(scene, Scene):  # the one batch solve of any scene is above this layer
        raise TypeError(
            f"scene {scene.name}: batch.solve_beats solves an open-loop scene; "
            "cardiosoft.solve_beats takes any scene"
        )
    if scene.static:
        raise ValueError(f"scene {scene.name} is static: use solve_static")
    check_solve_options(save, steady, beats)
    members = _members(scene, omega, shortening, bpm, afterload)
    pump = load(scene.pump) if pump is None else pump
    config = default_config(scene) if config is None else config
    max_beats, tol = (int(beats), 0.0) if beats is not None else (scene.max_beats, scene.steady_tol)
    structure, numbers = split_scene(scene)
    method = "beats" if beats is not None else steady
    size = ensemble_size(pump, scene_draws)
    batch, shared = members, pump
    if size is not None:
        batch, shared = flat_batch(members, pump, scene_draws or {}, size)
    metrics, traces, out = stored_call(
        _solve,
        structure,
        numbers,
        shared,
        _shard(batch),
        max_beats,
        tol,
        config,
        save,
        method,
        energy,
        engine,
    )
    if size is not None:
        metrics, traces, out = unflatten((metrics, traces, out), size)
    return _solution(scene, members, config, metrics, traces, out, beats is not None)


def solve_orbit(
    scene,
    start: dict,
    *,
    omega=None,
    shortening=None,
    bpm=None,
    afterload=None,
    save: str = "traces",
    energy: bool = False,
    pump: PumpSurrogate | None = None,
    config: SolverConfig | None = None,
    engine: str = DEFAULT_ENGINE,
) -> BeatSolution:
    """One beat of each member from ``start``, a point of its periodic orbit, differentiated as
    the orbit.

    ``start`` is the ``y0`` of a steady :class:`BeatSolution` of the same members (the same
    scene, ``energy`` setting and batch). The value is that one beat, as :func:`solve_beats`
    samples it; ``residual`` is its cycle-to-cycle change, so ``steady`` says whether ``start``
    was on the orbit. The derivative (``jax.jvp``, ``jax.jacfwd``) is the periodic steady
    state's, by the implicit function theorem at ``start``
    (:func:`cardiosoft.shooting.orbit_beat`), whatever ``start``'s own derivative: at a converged
    orbit that of ``solve_beats(steady="shooting")``. Finding the orbits without derivatives,
    then differentiating them here, compiles two smaller programs instead of one larger one
    (the design search does so, #13). A start that is not finite begins at rest instead (that
    member is then not steady). The other arguments are those of :func:`solve_beats`.
    """
    scene = load_scene(scene) if isinstance(scene, str | os.PathLike) else scene
    if scene.static:
        raise ValueError(f"scene {scene.name} is static: it has no orbit")
    if save not in ("traces", "metrics"):
        raise ValueError(f"save = {save!r}: allowed traces, metrics")
    pump = load(scene.pump) if pump is None else pump
    config = default_config(scene) if config is None else config
    members = _members(scene, omega, shortening, bpm, afterload)
    head = members["afterload"][0]
    states = jax.eval_shape(lambda: scene_circuit(scene, pump, head, energy=energy).init())
    if not isinstance(start, dict):
        raise ValueError(f"start: a dict of states (the y0 of solve_beats), got {type(start)}")
    if jax.tree_util.tree_structure(start) != jax.tree_util.tree_structure(states):
        raise ValueError(
            f"start: states {_names(start)} do not match the states {_names(states)} of scene "
            f"{scene.name} with energy={energy}: give the y0 of its solve_beats"
        )
    sizes = {jnp.shape(a)[:1] for a in jax.tree_util.tree_leaves(start)}
    if len(sizes) != 1 or any(jnp.ndim(a) != 1 for a in jax.tree_util.tree_leaves(start)):
        raise ValueError("start: one 1-D array per state, one entry per member (a y0)")
    (shape,) = sizes
    try:
        members = {k: jnp.broadcast_to(v, shape) for k, v in members.items()}
    except ValueError:
        raise ValueError(
            f"start: {shape[0]} members, but the members given are "
            f"{next(iter(members.values())).shape[0]}"
        ) from None
    structure, numbers = split_scene(scene)
    batch = _shard({**members, "start": start})
    metrics, traces, out = stored_call(
        _solve, structure, numbers, pump, batch, 1, 0.0, config, save, "orbit", energy, engine
    )
    return _solution(scene, members, config, metrics, traces, out, True)


def _names(states) -> str:
    return ", ".join(sorted(_flat_states(states)))


class StaticSolution(eqx.Module):
    """What :func:`solve_static` returns: quasi-static pulls against the column (SI, per member).

    The force and work are the load cell's (cable friction included when the scene has it);
    ``efficiency`` is the paper's ``P_a SV / M``; ``max_pressure`` the stroke's largest chamber
    pressure (Pa), the head plus the column's rise, which :func:`cardiosoft.results.flags`
    holds against the surrogate's fitted pressures.
    """

    members: dict
    stroke_volume: jax.Array
    peak_force: jax.Array
    mech_work: jax.Array
    efficiency: jax.Array
    max_pressure: jax.Array


def solve_static(
    scene="bench-static",
    *,
    omega=None,
    shortening=None,
    afterload=None,
    pump: PumpSurrogate | None = None,
    n_points: int = 401,
    scene_draws: dict | None = None,
) -> StaticSolution:
    """Quasi-static strokes of a water-column scene's members (no ODE; :mod:`cardiosoft.static`).

    The arguments are those of :func:`solve_beats`; the rate plays no part. Any water-column
    scene works, dynamic ones too (the paper's static SV beside the dynamic one). ``n_points``:
    the pull grid of each stroke (its peak force is the largest of them). An ensemble (``pump``
    with draws, ``scene_draws``: of these strokes only ``column_diameter`` and
    ``cable_friction`` matter) gives arrays of shape ``(S, M)``.
    """
    scene = load_scene(scene) if isinstance(scene, str | os.PathLike) else scene
    if not scene.afterload.has_heads:
        raise ValueError(f"scene {scene.name}: quasi-static strokes need a water-column afterload")
    members = _members(scene, omega, shortening, None, afterload)
    pump = load(scene.pump) if pump is None else pump
    size = ensemble_size(pump, scene_draws)
    draws = scene_draws or {}
    diameter = draws.get("column_diameter", scene.column_diameter)
    area = 0.25 * math.pi * jnp.asarray(diameter) ** 2
    k = column_stiffness(area, RHO_WATER, G) if scene.has("column_rise") else jnp.zeros(())
    friction = draws.get("cable_friction", scene.cable_friction)
    friction = jnp.asarray(friction if scene.has("cable_friction") else 0.0)
    args = (members["omega"], members["shortening"], members["afterload"])
    if size is None:
        strokes = stored_call(static_strokes, pump, *args, k, friction, n_points)
        return StaticSolution(members, *strokes)

    k, friction = (jnp.broadcast_to(v, (size,)) for v in (k, friction))
    strokes = stored_call(_ensemble_strokes, pump, ensemble_axes(pump), args, k, friction, n_points)
    return StaticSolution(members, *strokes)


@eqx.filter_jit
def _ensemble_strokes(pump, axes, args, k, friction, n_points: int):
    """:func:`static_strokes` of each draw of an ensemble ``pump`` (``axes``: its leaves' draw
    axes), one compiled program (a command stores it: :mod:`cardiosoft.program_store`)."""

    def one(p, k, friction):
        return static_strokes(p, *args, k, friction, n_points)

    return jax.vmap(one, in_axes=(axes, 0, 0))(pump, k, friction)
