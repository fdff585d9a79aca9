"""What a design search returns: :class:`DesignResult`, a :class:`TargetResult` per target and
the :class:`ParetoPoint` s of a Pareto trace, with the JSON record that ``design.json`` holds.
"""

from __future__ import annotations

import dataclasses

from cardiosoft.files import json_ready
from cardiosoft.results import RunResult
from cardiosoft.scene import Scene

__all__ = ["DesignResult", "ParetoPoint", "TargetResult"]


@dataclasses.dataclass(frozen=True)
class TargetResult:
    """One target and what the verifying :func:`cardiosoft.run` gave at the design (user units).

    ``target_sv_ml`` is the stroke volume aimed at (for a cardiac-output target, the one that
    gives it at the design's rate); ``sv_ml`` and every metric are the run's; ``residual_ml``
    is ``sv_ml - target_sv_ml``; ``ok``, ``message`` and ``flags`` the run's (``flags``: what
    of its numbers is not to be trusted as it is, e.g. an extrapolated surrogate, an
    efficiency that is not meaningful and reported as NaN); ``search_sv_ml`` what the search
    itself computed there (its
    ``accuracy`` and steady-state method); ``reachable_sv_ml`` the least and largest stroke
    volume at this target over every design the search evaluated and the verifying run.
    """

    afterload_mmHg: float | None
    bpm: float
    target_sv_ml: float
    sv_ml: float
    residual_ml: float
    search_sv_ml: float
    peak_force_N: float
    mech_work_J: float
    efficiency: float
    cardiac_output_l_min: float
    static_sv_ml: float | None
    reachable_sv_ml: tuple[float, float]
    target_co_l_min: float | None
    ok: bool
    message: str
    flags: tuple[str, ...] = ()

    @property
    def where(self) -> str:
        """The target's afterload and rate, as messages name it."""
        head = "" if self.afterload_mmHg is None else f"{self.afterload_mmHg:g} mmHg, "
        return f"{head}{self.bpm:g} bpm"


@dataclasses.dataclass(frozen=True)
class ParetoPoint:
    """A design that hits the targets, with its peak force and efficiency / mechanical work
    (means over the targets, from its verifying run) and whether another one dominates it."""

    omega: float
    shortening: float
    sv_ml: tuple[float, ...]
    peak_force_N: float
    efficiency: float
    mech_work_J: float
    dominated: bool


@dataclasses.dataclass(frozen=True)
class DesignResult:
    """What :func:`optimise` returns.

    - ``design``: the design variables' values (user units), free and fixed alike;
      ``free``: the names of the free ones.
    - ``reached``: every target within ``tolerance_ml`` in the verifying run.
    - ``targets``: a :class:`TargetResult` per target, from the verifying run.
    - ``objective``, ``objective_value``: the secondary objective and its value at the design
      (mean over the targets, from the run), or None.
    - ``iterations``: refinement rounds; ``seconds``: wall time of :func:`optimise`;
      ``timings``: where it went, in s: ``trace_s`` and ``compile_s`` (tracing, and tracing
      plus XLA's compilation, of the search's two programs; 0 when this process had compiled
      them already), ``grid_s`` (the coarse grid; its evaluations are kept for a further
      target of the same scene, space, afterloads and rates), ``refine_s``, ``verify_s`` (the
      final run()), ``prewarm_s`` (the run() of the start design on a second thread, which
      compiles the verification meanwhile; NaN when the search's programs were compiled
      already, and the run()'s with them), ``prewarm_wait_s`` (how long the verification
      waited for it), ``pareto_s``, ``map_s``, ``total_s``; ``calls`` and ``call_median_s`` of
      the compiled function.
    - ``path``: the design after each accepted step of the winning candidate, from its grid
      point; ``explored``: every design evaluated (``z`` transformed, user units) with its
      stroke volumes (ml, per target) and whether its solve succeeded and was steady.
    - ``pareto``: :class:`ParetoPoint` s with ``pareto=True``, else None.
    - ``runs``: the verifying :class:`~cardiosoft.results.RunResult` s (one per rate).
    - ``message``: in words.
    - ``sv_map``: with ``map_lattice=``, the stroke volumes (ml, per target) on an (Omega, C)
      lattice, the other variables at the design: ``{"omega", "shortening", "sv_ml"}``.
    """

    scene: Scene
    design: dict
    free: tuple[str, ...]
    reached: bool
    tolerance_ml: float
    targets: tuple[TargetResult, ...]
    objective: str | None
    objective_value: float | None
    iterations: int
    seconds: float
    timings: dict
    path: tuple[dict, ...]
    explored: dict
    pareto: tuple[ParetoPoint, ...] | None
    runs: tuple[RunResult, ...]
    message: str
    sv_map: dict | None = None

    @property
    def flags(self) -> tuple[str, ...]:
        """What of the answer is not to be taken as it is, in words: a target not reached (the
        closest design is returned; :attr:`message`), and the verifying run's flags of each
        target (``"<afterload, rate>: <flag>"``). Warnings, not errors (DESIGN.md section 4)."""
        out = [] if self.reached else [self.message]
        return tuple(out + [f"{t.where}: {f}" for t in self.targets for f in t.flags])

    @property
    def failures(self) -> tuple[str, ...]:
        """The targets whose verifying run failed or did not reach the periodic steady state
        (``"<afterload, rate>: <why>"``)."""
        return tuple(f"{t.where}: {t.message}" for t in self.targets if not t.ok)

    @property
    def omega(self) -> float:
        return self.design["omega"]

    @property
    def shortening(self) -> float:
        return self.design["shortening"]

    def to_json(self) -> dict:
        """A JSON-ready record (user units): what ``design.json`` holds. JSON has no NaN: a
        number that could not be computed is null."""

        targets = [
            {
                "afterload_mmHg": t.afterload_mmHg,
                "bpm": t.bpm,
                "target_sv_ml": t.target_sv_ml,
                "target_co_l_min": t.target_co_l_min,
                "sv_ml": t.sv_ml,
                "residual_ml": t.residual_ml,
                "search_sv_ml": t.search_sv_ml,
                "static_sv_ml": t.static_sv_ml,
                "peak_force_N": t.peak_force_N,
                "mech_work_J": t.mech_work_J,
                "efficiency": t.efficiency,
                "cardiac_output_l_min": t.cardiac_output_l_min,
                "reachable_sv_ml": list(t.reachable_sv_ml),
                "ok": t.ok,
                "message": t.message,
                "flags": list(t.flags),
            }
            for t in self.targets
        ]
        out = {
            "scene": self.scene.name,
            "omega": self.omega,
            "shortening": self.shortening,
            "bpm": self.design["bpm"],
            "design": self.design,
            "free": list(self.free),
            "reached": self.reached,
            "tolerance_ml": self.tolerance_ml,
            "objective": self.objective,
            "objective_value": self.objective_value,
            "iterations": self.iterations,
            "seconds": self.seconds,
            "timings": self.timings,
            "message": self.message,
            "flags": list(self.flags),
            "failures": list(self.failures),
            "targets": targets,
            "path": list(self.path),
        }
        if self.pareto is not None:
            out["pareto"] = [dataclasses.asdict(p) for p in self.pareto]
        return json_ready(out)
