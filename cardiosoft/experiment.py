"""``run(scene, **overrides)``: the simulation behind ``python -m cardiosoft.simulate``.

A scene is built into one :class:`~cardiosoft.circuit.PumpCircuit` per afterload; the circuits
are stacked and solved in one jitted, ``vmap``-ed call (sharded over ``jax.devices()`` when
there are several), beat after beat until each reaches its periodic steady state. A member that
fails is reported by name in its record; the others are unaffected.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import math

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft._validate import check_range
from cardiosoft.actuation import CablePull
from cardiosoft.circuit import CableFriction, PumpCircuit, ShellViscoelasticity
from cardiosoft.circulation import AtrialSource, Bench, Tube, Valve, WaterColumn, Windkessel3
from cardiosoft.metrics import BeatMetrics, beat_metrics
from cardiosoft.pump import Domain, PumpSurrogate, load
from cardiosoft.scene import Scene, load_scene
from cardiosoft.solve import periodic_beats, preset
from cardiosoft.static import column_stiffness, quasi_static_stroke
from cardiosoft.units import RHO_WATER, G, bpm, ml, mmHg

__all__ = [
    "MemberResult",
    "RunResult",
    "build_circuit",
    "configure",
    "run",
    "summary_records",
    "sweep",
]

N_PULL_SAMPLES = 201
N_REST_SAMPLES = 200


@dataclasses.dataclass(frozen=True)
class MemberResult:
    """One afterload of a run. Metrics and traces are SI (see :mod:`cardiosoft.metrics`)."""

    label: str
    afterload: float | None
    """Column head (Pa) for the bench; None for a Windkessel scene."""
    ok: bool
    message: str
    beats: int
    residual: float
    """Cycle-to-cycle change of the last beat (ml, ml/s or mmHg)."""
    volume_drift: float
    """Largest relative drift of the total fluid volume over the run."""
    metrics: dict[str, float]
    """:class:`~cardiosoft.metrics.BeatMetrics` fields, plus ``static_*`` for the bench."""
    traces: dict[str, np.ndarray]
    """Last beat: time, pull, volume, pressures, flows, forces (SI)."""


@dataclasses.dataclass(frozen=True)
class RunResult:
    """What :func:`run` returns: the scene as run and one :class:`MemberResult` per afterload."""

    scene: Scene
    members: tuple[MemberResult, ...]

    @property
    def ok(self) -> bool:
        return all(m.ok for m in self.members)


def _circuit(scene: Scene, pump: PumpSurrogate, afterload) -> PumpCircuit:
    stroke = scene.shortening * pump.cable_length(scene.omega)
    actuation = CablePull(
        stroke,
        1.0 / (scene.bpm * bpm),
        scene.pull_fraction,
        scene.hold_fraction,
        scene.release_fraction,
        shape=scene.shape,
    )
    friction = CableFriction(scene.cable_friction) if scene.has("cable_friction") else None
    viscoelasticity = (
        ShellViscoelasticity(scene.viscoelastic_ratio, scene.relaxation_time)
        if scene.has("shell_viscoelasticity")
        else None
    )
    if scene.afterload_type == "water_column":
        column = WaterColumn(
            scene.column_diameter,
            afterload,
            rise=scene.has("column_rise"),
            inertia=scene.has("column_inertia"),
        )
        tube = Tube(
            scene.tube_length,
            scene.tube_diameter,
            loss_coefficient=scene.loss_coefficient,
            inertia=scene.has("tube_inertia"),
            resistance=scene.has("tube_resistance"),
            minor_loss=scene.has("minor_loss"),
        )
        return PumpCircuit(
            pump,
            scene.omega,
            actuation,
            Bench(tube, column),
            cable_friction=friction,
            viscoelasticity=viscoelasticity,
        )
    rp, c, rd = scene.windkessel
    r_in, r_out = scene.valve_resistance
    return PumpCircuit(
        pump,
        scene.omega,
        actuation,
        Windkessel3(rp, c, rd, scene.venous_pressure),
        outlet_valve=Valve(r_out, scene.valve_kind, scene.valve_smoothing),
        inlet_valve=Valve(r_in, scene.valve_kind, scene.valve_smoothing),
        preload=AtrialSource(scene.preload_pressure),
        cable_friction=friction,
        viscoelasticity=viscoelasticity,
    )


def build_circuit(scene: Scene, pump: PumpSurrogate | None = None, afterload=None):
    """The :class:`PumpCircuit` of ``scene`` (for the bench: at column head ``afterload``, Pa)."""
    pump = load() if pump is None else pump
    if scene.afterload_type == "water_column" and afterload is None:
        afterload = scene.afterloads[0]
    return _circuit(scene, pump, afterload)


def _save_times(actuation: CablePull):
    """Samples of one beat with the end of the pull on the grid (first N_PULL_SAMPLES)."""
    t_pull = actuation.pull_fraction * actuation.period
    pull = jnp.linspace(0.0, 1.0, N_PULL_SAMPLES) * t_pull
    rest = t_pull + jnp.linspace(0.0, 1.0, N_REST_SAMPLES + 1)[1:] * (actuation.period - t_pull)
    return jnp.concatenate([pull, rest])


def _reference_pressure(circuit: PumpCircuit, beats, signals):
    if circuit.preload is None:  # the bench: the column head before the pull
        return circuit.afterload.node_pressure(circuit.afterload.init())
    return jnp.mean(signals["node_pressure"])  # a Windkessel: mean afterload pressure


@eqx.filter_jit
def _simulate(circuits: PumpCircuit, max_beats: int, tol, config):
    def one(circuit: PumpCircuit):
        ts = _save_times(circuit.actuation)
        beats = periodic_beats(
            circuit,
            circuit.init(),
            circuit.actuation.period,
            ts,
            jump_ts=circuit.actuation.kink_times(1),
            total_volume=circuit.total_volume,
            max_beats=max_beats,
            tol=tol,
            config=config,
        )
        signals = jax.vmap(circuit.signals)(beats.ts, beats.ys)
        metrics = beat_metrics(
            beats.ts,
            beats.ys["volume"],
            signals,
            N_PULL_SAMPLES,
            circuit.actuation.period,
            _reference_pressure(circuit, beats, signals),
        )
        return beats, signals, metrics

    return jax.vmap(one)(circuits)


@eqx.filter_jit
def _static_strokes(pump: PumpSurrogate, omegas, strokes, afterloads, k, friction):
    out = jax.vmap(lambda o, x, p: quasi_static_stroke(pump, o, x, p, k))(
        omegas, strokes, afterloads
    )
    factor = jnp.exp(friction)
    return out.stroke_volume, factor * out.peak_force, factor * out.mechanical_work


def _stack(trees):
    """One batch from equal trees of concrete arrays (stacked by numpy: no eager XLA compiles)."""
    return jax.tree_util.tree_map(lambda *xs: jnp.asarray(np.stack(xs)), *trees)


def _shard(tree):
    """Spread the batch over all devices when it divides evenly (one CPU: unchanged)."""
    devices = jax.devices()
    n = jax.tree_util.tree_leaves(tree)[0].shape[0]
    if len(devices) < 2 or n % len(devices):
        return tree
    mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
    return jax.tree_util.tree_map(
        lambda a: jax.device_put(a, sharding) if eqx.is_array(a) else a, tree
    )


def configure(
    scene="bench-dynamic", *, omega=None, shortening=None, bpm=None, afterload=None, accuracy=None
) -> Scene:
    """The scene with the user's overrides (user units), validated; see :func:`run`."""
    scene = scene if isinstance(scene, Scene) else load_scene(scene)
    bpm_value = bpm
    changes = {}
    if omega is not None:
        check_range("omega", omega, "", *Domain().omega)
        changes["omega"] = float(omega)
    if shortening is not None:
        check_range("shortening C", shortening, "", *Domain().shortening)
        changes["shortening"] = float(shortening)
    if bpm_value is not None:
        check_range("bpm", bpm_value, "bpm", 0.0, 300.0, lo_open=True)
        changes["bpm"] = float(bpm_value)
    if afterload is not None:
        if scene.afterload_type != "water_column":
            raise ValueError(
                f"afterload: scene {scene.name} has a {scene.afterload_type} "
                "afterload; --afterload sets water-column heads"
            )
        values = tuple(float(a) for a in np.atleast_1d(afterload))
        check_range("afterload", values, "mmHg", 0.0, 150.0)
        changes["afterloads"] = tuple(v * mmHg for v in values)
    if accuracy is not None:
        if accuracy not in ("fast", "default", "reference"):
            raise ValueError(f"accuracy = {accuracy!r}: allowed fast, default, reference")
        changes["accuracy"] = accuracy
    return scene.replace(**changes) if changes else scene


def run(
    scene="bench-dynamic",
    *,
    omega=None,
    shortening=None,
    bpm=None,
    afterload=None,
    beats=None,
    accuracy=None,
    pump: PumpSurrogate | None = None,
) -> RunResult:
    """Simulate a scene; the Python twin of ``python -m cardiosoft.simulate``.

    **Arguments** (user units; None keeps the scene's value):

    - ``scene``: a shipped scene name, a path to a scene file, or a :class:`Scene`.
    - ``omega``: helix parameter, [0, 6]; ``shortening``: C, [0, 0.65].
    - ``bpm``: beats per minute, (0, 300].
    - ``afterload``: column head(s) in mmHg, [0, 150] (water-column scenes).
    - ``beats``: run exactly this many beats instead of stopping at the steady state.
    - ``accuracy``: "fast", "default" or "reference".
    - ``pump``: a :class:`~cardiosoft.pump.PumpSurrogate` (default: the shipped one).

    **Returns:** a :class:`RunResult`. Bad input raises ``ValueError`` naming the parameter.
    """
    scene = configure(
        scene, omega=omega, shortening=shortening, bpm=bpm, afterload=afterload, accuracy=accuracy
    )
    heads = scene.afterloads if scene.afterload_type == "water_column" else (None,)
    labels = [f"{h / mmHg:g} mmHg" if h is not None else scene.name for h in heads]
    return _run_members(
        scene, [(label, scene, h) for label, h in zip(labels, heads, strict=True)], beats, pump
    )


def sweep(
    scene="bench-dynamic",
    designs=((4.0, 0.4),),
    *,
    bpm=None,
    afterload=None,
    beats=None,
    accuracy=None,
    pump: PumpSurrogate | None = None,
) -> RunResult:
    """Simulate several designs (Omega, C) at every afterload of a scene in one compiled call.

    ``designs`` is a sequence of ``(omega, shortening)`` pairs; the other arguments are those
    of :func:`run`. Members are labelled ``"Omega 4, C 0.4, 30 mmHg"``. Keep the designs of one
    sweep alike: the batch runs until its slowest member reaches steady state.
    """
    scene = configure(scene, bpm=bpm, afterload=afterload, accuracy=accuracy)
    heads = scene.afterloads if scene.afterload_type == "water_column" else (None,)
    variants = []
    for omega, shortening in designs:
        design = configure(scene, omega=omega, shortening=shortening)
        for h in heads:
            where = f", {h / mmHg:g} mmHg" if h is not None else ""
            variants.append((f"Omega {omega:g}, C {shortening:g}{where}", design, h))
    return _run_members(scene, variants, beats, pump)


def _solve_dynamic(scene: Scene, variants, beats, pump):
    """The beats of every (label, scene variant, afterload), in one vmapped call."""
    circuits = _shard(_stack([_circuit(v, pump, h) for _, v, h in variants]))
    config = preset(scene.accuracy, stiff=scene.has("valves"))
    max_beats, tol = (beats, 0.0) if beats is not None else (scene.max_beats, scene.steady_tol)
    return _simulate(circuits, int(max_beats), tol, config)


def _run_members(scene: Scene, variants, beats, pump) -> RunResult:
    """Solve every (label, scene variant, afterload) in one vmapped call."""
    if beats is not None:
        check_range("beats", beats, "beats", 1, 500)
    pump = load() if pump is None else pump
    labels = [label for label, _, _ in variants]
    heads = [h for _, _, h in variants]

    static_strokes = None
    if scene.afterload_type == "water_column":
        k = (
            column_stiffness(0.25 * math.pi * scene.column_diameter**2, RHO_WATER, G)
            if scene.has("column_rise")
            else 0.0
        )
        friction = scene.cable_friction if scene.has("cable_friction") else 0.0
        omegas = jnp.asarray([v.omega for _, v, _ in variants])
        strokes = jnp.asarray([v.shortening for _, v, _ in variants]) * pump.cable_length(omegas)

        def static_strokes():
            out = _static_strokes(pump, omegas, strokes, jnp.asarray(heads), k, friction)
            return [np.asarray(a) for a in out]

    if scene.static:
        static = static_strokes()
        members = tuple(
            MemberResult(
                label, h, True, "quasi-static", 0, 0.0, 0.0, _static_metrics(static, i, h), {}
            )
            for i, (label, h) in enumerate(zip(labels, heads, strict=True))
        )
        return RunResult(scene, members)

    if static_strokes is None:
        static, dynamic = None, _solve_dynamic(scene, variants, beats, pump)
    else:
        # Compiling the dynamic solve takes seconds; the quasi-static strokes compile on a second
        # thread meanwhile (JAX traces and compiles thread-safely).
        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            pending = pool.submit(static_strokes)
            dynamic = _solve_dynamic(scene, variants, beats, pump)
            static = pending.result()

    out, signals, metrics = dynamic
    codes = np.asarray(out.result._value)
    members = []
    for i, (label, h) in enumerate(zip(labels, heads, strict=True)):
        code = int(codes[i])
        ok = code == int(diffrax.RESULTS.successful._value)
        m = {f.name: float(getattr(metrics, f.name)[i]) for f in dataclasses.fields(BeatMetrics)}
        if static is not None:
            m |= _static_metrics(static, i, h)
        n_beats = int(out.beats[i])
        residual = float(out.residual[i])
        converged = beats is not None or residual <= scene.steady_tol
        if not ok:
            message = f"solver failed in beat {n_beats}: {_result_message(code)}"
        elif not converged:
            message = (
                f"not steady after {n_beats} beats (cycle change {residual:.3g} > "
                f"{scene.steady_tol:g})"
            )
        else:
            message = "ok"
        traces = {"time": np.asarray(out.ts[i]), "volume": np.asarray(out.ys["volume"][i])}
        traces |= {k: np.asarray(v[i]) for k, v in signals.items()}
        if "column_volume" in out.ys["afterload"]:
            traces["column_volume"] = np.asarray(out.ys["afterload"]["column_volume"][i])
        if "relaxation" in out.ys:
            traces["relaxation"] = np.asarray(out.ys["relaxation"][i])
        members.append(
            MemberResult(
                label,
                h,
                ok and converged,
                message,
                n_beats,
                residual,
                float(out.volume_drift[i]),
                m,
                traces,
            )
        )
    return RunResult(scene, tuple(members))


def _result_message(code: int) -> str:
    """diffrax's message for a result code (its table is not public API; fall back to the code)."""
    table = getattr(diffrax.RESULTS, "_index_to_message", None)
    try:
        return str(table[code]).strip() or f"diffrax result code {code}"
    except (TypeError, IndexError, KeyError):
        return f"diffrax result code {code}"


def _static_metrics(static, i, head) -> dict[str, float]:
    sv, force, work = (float(a[i]) for a in static)
    return {
        "static_stroke_volume": sv,
        "static_peak_force": force,
        "static_mech_work": work,
        "static_efficiency": head * sv / work,
    }


def summary_records(result: RunResult) -> list[dict]:
    """One JSON-ready record per member, in user units (``summary.json``)."""
    records = []
    for m in result.members:
        x = m.metrics
        dynamic = not result.scene.static
        records.append(
            {
                "label": m.label,
                "afterload_mmHg": None if m.afterload is None else m.afterload / mmHg,
                "static_sv_ml": x.get("static_stroke_volume", math.nan) / ml,
                "dynamic_sv_ml": x["stroke_volume"] / ml if dynamic else None,
                "peak_force_N": x["peak_force"] if dynamic else x["static_peak_force"],
                "mech_work_J": x["mech_work"] if dynamic else x["static_mech_work"],
                "efficiency": x["efficiency"] if dynamic else x["static_efficiency"],
                "ef": x["ejection_fraction"] if dynamic else None,
                "edv_ml": x["edv"] / ml if dynamic else None,
                "esv_ml": x["esv"] / ml if dynamic else None,
                "cardiac_output_l_min": x["cardiac_output"] / ml * 60 / 1000 if dynamic else None,
                "beats": m.beats,
                "steady_residual": m.residual,
                "volume_drift": m.volume_drift,
                "ok": m.ok,
                "message": m.message,
            }
        )
    return records
