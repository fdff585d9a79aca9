"""One chunk of a sweep: the task a worker solves, the variables it returns per point, and what
becomes of a point (:data:`STATUS`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from cardiosoft.results import SWEEP_VARIABLES as METRIC_VARIABLES
from cardiosoft.results import flagged_members as flagged_points

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
        "that is not meaningful; in a closed loop also cardiosoft.network.loop_results."
        "loop_flags: congestion, a collapsing atrium, blood piled up on one side); the values "
        "are kept as computed",
    ),
}
VARIABLES = (*METRIC_VARIABLES, *SOLVER_VARIABLES)
"""The data variables of an open-loop scene's Dataset, each with ``units`` and ``long_name``
attributes (a closed loop's metrics are its kind's ``sweep_variables``)."""
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

    @property
    def metrics(self) -> tuple[str, ...]:
        """The names of the sweep's metric variables (its scene's kind's)."""
        from cardiosoft.scene_tools import tools

        return tuple(tools(self.scene).sweep_variables(self.scene))


_PUMPS: dict = {}


def load_pump(ref):
    """The surrogate a task names (None: the shipped one; a path), loaded once per process."""
    from cardiosoft.pump import load

    if ref is None or isinstance(ref, str):
        if ref not in _PUMPS:
            _PUMPS[ref] = load(ref)
        return _PUMPS[ref]
    return ref


def failed_result(n: int, message: str, metrics, draws: int | None = None) -> dict:
    """The result of ``n`` points of a chunk that failed with ``message`` (``metrics``: the
    names of the sweep's metric variables)."""
    out = {name: np.full(n, np.nan) for name in metrics}
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


def solve_chunk(task: Task) -> dict:
    """Solve one chunk: numpy arrays of its valid points (``error``: "" or why it failed).

    Runs on a Dask worker as well as in this process: it switches the worker's JAX to the
    caller's precision, and it never raises for a failed solve.
    """
    import jax

    if bool(jax.config.jax_enable_x64) != task.x64:
        jax.config.update("jax_enable_x64", task.x64)
    try:
        from cardiosoft.metrics import field_at
        from cardiosoft.scene_tools import solve_beats, tools
        from cardiosoft.solve import ran_out_of_steps

        kind = tools(task.scene)
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
        for name, (path, scale, _, _) in kind.sweep_variables(task.scene).items():
            result[name] = np.asarray(field_at(out.metrics, path))[:n] / scale
        finite = np.all([np.isfinite(v) for v in result.values()], axis=0)
        succeeded = np.asarray(out.succeeded)[:n]
        max_steps = ran_out_of_steps(out.result)[:n]
        steady = np.asarray(out.steady)[:n]
        status = np.select(
            [~succeeded & max_steps, ~succeeded, ~finite, ~steady],
            [MAX_STEPS, SOLVER_FAILED, NONFINITE, NOT_STEADY],
            OK,
        ).astype(np.int8)
        for name in kind.sweep_variables(task.scene):  # a failed solve leaves no number to keep
            result[name] = np.where(succeeded, result[name], np.nan)
        result |= {
            "beats": np.asarray(out.beats)[:n].astype(np.int32),
            "steady": status == OK,
            "residual": np.asarray(out.residual)[:n].astype(float),
            "volume_drift": np.asarray(out.volume_drift)[:n].astype(float),
            "num_steps": np.asarray(out.num_steps)[:n].astype(np.int32),
            "status": status,
            "flagged": kind.sweep_flags(task.scene, out.metrics, n, load_pump(task.pump).domain)
            & succeeded,
            "error": np.array(""),
        }
        if task.draws is not None:
            result |= band_result(task, members, n)
        return result
    except Exception as err:  # a failed chunk must not stop the sweep
        return failed_result(
            task.valid, f"{type(err).__name__}: {err}".splitlines()[0], task.metrics, task.draws
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
