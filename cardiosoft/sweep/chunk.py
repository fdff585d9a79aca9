"""One chunk of a sweep: the task a worker solves, the variables it returns per point, and what
becomes of a point (:data:`STATUS`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from cardiosoft.units import ml

__all__ = [
    "BAND_VARIABLES",
    "CHUNK_FAILED",
    "MAX_STEPS",
    "METRIC_VARIABLES",
    "NONFINITE",
    "NOT_STEADY",
    "OK",
    "SOLVER_FAILED",
    "SOLVER_VARIABLES",
    "STATUS",
    "VARIABLES",
    "Task",
    "failed_result",
    "flagged_points",
    "load_pump",
    "solve_chunk",
]

STATUS = ("ok", "not_steady", "max_steps_reached", "nonfinite", "solver_failed", "chunk_failed")
"""The values of the ``status`` variable (its ``flag_meanings``): 0 ok; 1 the solver finished
but the cycle-to-cycle change is above the scene's tolerance; 2 the step limit was hit; 3 the
solver finished with a NaN or infinite metric; 4 another solver failure; 5 the chunk raised
or its worker was lost (the chunk's message is in the Dataset's ``failed_chunks`` attribute)."""
OK, NOT_STEADY, MAX_STEPS, NONFINITE, SOLVER_FAILED, CHUNK_FAILED = range(len(STATUS))

# name: (BeatMetrics field, scale to the unit, unit, long name). The five the issue asks for
# first; every one is in the last beat of the member.
METRIC_VARIABLES = {
    "stroke_volume_ml": (
        "stroke_volume",
        ml,
        "ml",
        "stroke volume EDV - ESV (the bench: the peak column rise, the paper's dynamic SV)",
    ),
    "ejection_fraction": ("ejection_fraction", 1.0, "1", "ejection fraction SV / EDV"),
    "peak_force_N": ("peak_force", 1.0, "N", "largest measured cable force during the pull"),
    "mech_work_J": (
        "mech_work",
        1.0,
        "J",
        "mechanical work: the cable force integrated over the pull (the paper's M)",
    ),
    "efficiency": ("efficiency", 1.0, "1", "the paper's efficiency P_a SV / M"),
    "hydraulic_work_J": ("hydraulic_work_paper", 1.0, "J", "the paper's hydraulic work P_a SV"),
    "stroke_work_J": ("stroke_work", 1.0, "J", "area of the pressure-volume loop"),
    "edv_ml": ("edv", ml, "ml", "end-diastolic (largest) pump volume"),
    "esv_ml": ("esv", ml, "ml", "end-systolic (smallest) pump volume"),
    "cardiac_output_l_min": (
        "cardiac_output",
        1000 * ml / 60.0,
        "l/min",
        "cardiac output SV / period",
    ),
}
SOLVER_VARIABLES = {
    "beats": ("i4", "1", "beats integrated"),
    "steady": (
        "bool",
        "1",
        "at the periodic steady state (the last beat's cycle-to-cycle change within the "
        "attribute steady_tol, also with a fixed number of beats), the solver successful and "
        "every metric finite",
    ),
    "residual": (
        "f8",
        "1",
        "largest cycle-to-cycle change of a periodic state over the last beat, each state in "
        "its own unit (ml, ml/s or mmHg), held to the attribute steady_tol",
    ),
    "volume_drift": ("f8", "1", "largest relative drift of the total fluid volume"),
    "num_steps": ("i4", "1", "solver steps of the last beat"),
    "status": ("i1", "1", "what became of the point: " + ", ".join(STATUS)),
    "flagged": (
        "bool",
        "1",
        "a number of the point is not to be taken as it is (cardiosoft.results.flags: the pump "
        "pressure outside the surrogate's fitted range, a cable that would push, an efficiency "
        "that is not meaningful); the values are kept as computed",
    ),
}
VARIABLES = (*METRIC_VARIABLES, *SOLVER_VARIABLES)
"""The data variables of the Dataset, each with ``units`` and ``long_name`` attributes."""
BAND_VARIABLES = {
    "stroke_volume_ml": "dynamic_sv_ml",
    "ejection_fraction": "ef",
    "peak_force_N": "peak_force_N",
    "mech_work_J": "mech_work_J",
    "efficiency": "efficiency",
    "cardiac_output_l_min": "cardiac_output_l_min",
}
"""With ``uncertainty``: the metrics that get ``<name>_band_low`` and ``<name>_band_high`` (the
95 % predictive band, :func:`cardiosoft.posterior.predictive_bands`' key beside), and the
variable ``band_failed_draws`` (posterior draws that failed, missed the steady state or emptied
the pump below zero volume at the point, left out of its bands)."""


def band_names() -> list[str]:
    """The band variables' names, in order."""
    return [f"{name}_band_{edge}" for name in BAND_VARIABLES for edge in ("low", "high")]


@dataclasses.dataclass(frozen=True)
class Task:
    """Everything a worker needs to solve one chunk (picklable, small)."""

    index: int
    scene: object
    members: dict
    valid: int
    beats: int | None
    pump: object
    x64: bool
    draws: int | None = None  # posterior draws per point (uncertainty), or None


_PUMPS: dict = {}


def load_pump(ref):
    """The surrogate a task names (None: the shipped one; a path), loaded once per process."""
    from cardiosoft.pump import load

    if ref is None or isinstance(ref, str):
        if ref not in _PUMPS:
            _PUMPS[ref] = load(ref)
        return _PUMPS[ref]
    return ref


def failed_result(n: int, message: str, draws: int | None = None) -> dict:
    """The result of ``n`` points of a chunk that failed with ``message``."""
    out = {name: np.full(n, np.nan) for name in METRIC_VARIABLES}
    if draws is not None:
        out |= {name: np.full(n, np.nan) for name in band_names()}
        out["band_failed_draws"] = np.full(n, draws, np.int32)
    out |= {
        "beats": np.zeros(n, np.int32),
        "steady": np.zeros(n, bool),
        "residual": np.full(n, np.nan),
        "volume_drift": np.full(n, np.nan),
        "num_steps": np.zeros(n, np.int32),
        "status": np.full(n, CHUNK_FAILED, np.int8),
        "flagged": np.zeros(n, bool),
        "error": np.array(message),
    }
    return out


def flagged_points(metrics, n: int, domain) -> np.ndarray:
    """Whether :func:`cardiosoft.results.flags` flags each of the first ``n`` members of a batch
    solve's :class:`~cardiosoft.metrics.BeatMetrics` (on a copy: nothing is changed)."""
    from cardiosoft.results import flags

    fields = {
        f.name: np.asarray(getattr(metrics, f.name))[:n]
        for f in dataclasses.fields(metrics)
        if getattr(metrics, f.name) is not None
    }
    return np.array(
        [bool(flags({k: float(v[i]) for k, v in fields.items()}, domain)) for i in range(n)],
        dtype=bool,
    )


def solve_chunk(task: Task) -> dict:
    """Solve one chunk: numpy arrays of its valid points (``error``: "" or why it failed).

    Runs on a Dask worker as well as in this process: it switches the worker's JAX to the
    caller's precision, and it never raises for a failed solve.
    """
    import jax

    if bool(jax.config.jax_enable_x64) != task.x64:
        jax.config.update("jax_enable_x64", task.x64)
    try:
        import diffrax

        from cardiosoft.batch import solve_beats

        n = task.valid
        members = dict(task.members)
        devices = len(jax.devices())
        size = len(next(iter(members.values())))
        if size % devices:  # shard evenly over the worker's devices: pad once more
            pad = devices - size % devices
            members = {k: np.concatenate([v, np.repeat(v[-1:], pad)]) for k, v in members.items()}
        out = solve_beats(
            task.scene,
            **members,
            beats=task.beats,
            save="metrics",
            pump=load_pump(task.pump),
        )
        out = jax.block_until_ready(out)
        result = {}
        for name, (field, scale, _, _) in METRIC_VARIABLES.items():
            result[name] = np.asarray(getattr(out.metrics, field))[:n] / scale
        finite = np.all([np.isfinite(v) for v in result.values()], axis=0)
        succeeded = np.asarray(out.succeeded)[:n]
        max_steps = np.asarray(out.result == diffrax.RESULTS.max_steps_reached)[:n]
        steady = np.asarray(out.steady)[:n]
        status = np.select(
            [~succeeded & max_steps, ~succeeded, ~finite, ~steady],
            [MAX_STEPS, SOLVER_FAILED, NONFINITE, NOT_STEADY],
            OK,
        ).astype(np.int8)
        for name in METRIC_VARIABLES:  # a failed solve leaves no number worth keeping
            result[name] = np.where(succeeded, result[name], np.nan)
        result |= {
            "beats": np.asarray(out.beats)[:n].astype(np.int32),
            "steady": status == OK,
            "residual": np.asarray(out.residual)[:n].astype(float),
            "volume_drift": np.asarray(out.volume_drift)[:n].astype(float),
            "num_steps": np.asarray(out.num_steps)[:n].astype(np.int32),
            "status": status,
            "flagged": flagged_points(out.metrics, n, load_pump(task.pump).domain) & succeeded,
            "error": np.array(""),
        }
        if task.draws is not None:
            result |= band_result(task, members, n)
        return result
    except Exception as err:  # a failed chunk must not stop the sweep
        return failed_result(
            task.valid, f"{type(err).__name__}: {err}".splitlines()[0], task.draws
        )


_POSTERIORS: dict = {}


def band_result(task: Task, members: dict, n: int) -> dict:
    """The chunk's points' predictive bands: the posterior's first ``task.draws`` draws solved
    at every point in one batched call (:func:`cardiosoft.posterior.ensemble_run`)."""
    from cardiosoft.posterior import ensemble_run, first_draws, predictive_bands
    from cardiosoft.pump import load_posterior

    if task.draws not in _POSTERIORS:
        _POSTERIORS[task.draws] = first_draws(load_posterior(), task.draws)
    posterior = _POSTERIORS[task.draws]
    ens = ensemble_run(task.scene, posterior, beats=task.beats, **members)
    bands = predictive_bands(ens, posterior.card)[:n]
    out = {}
    for name, key in BAND_VARIABLES.items():
        out[f"{name}_band_low"] = np.array([b[key].low for b in bands])
        out[f"{name}_band_high"] = np.array([b[key].high for b in bands])
    out["band_failed_draws"] = np.array([b["dynamic_sv_ml"].failed for b in bands], np.int32)
    return out
