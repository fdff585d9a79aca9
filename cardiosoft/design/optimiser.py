"""The entry point of the design search: :func:`optimise` (the method: :mod:`cardiosoft.design`).

It validates the question (:mod:`~cardiosoft.design.problem`), evaluates the coarse grid and
refines the best candidates (:mod:`~cardiosoft.design.search`) with the compiled programs
(:mod:`~cardiosoft.design.programs`), re-simulates the answer by :func:`cardiosoft.run`
(:mod:`~cardiosoft.design.verify`) and returns a :class:`~cardiosoft.design.result.DesignResult`.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from cardiosoft.design.figure import sv_map
from cardiosoft.design.problem import DEFAULT_FREE, TOLERANCE_ML, Problem, build_problem
from cardiosoft.design.programs import Evaluator
from cardiosoft.design.result import DesignResult, TargetResult
from cardiosoft.design.search import (
    DEFAULT_STEADY,
    GRID,
    MAX_ROUNDS,
    REFINE,
    STEADY_CHOICES,
    SearchRecord,
    design_values,
    grid_points,
    rates_of,
    refine,
    residuals,
    secondary_objective,
    select_candidates,
    steady_method,
)
from cardiosoft.design.verify import pareto_trace, target_sv_of, verify_design
from cardiosoft.program_store import stored_value
from cardiosoft.pump import PumpSurrogate, load
from cardiosoft.solve import PRESETS

__all__ = ["check_method", "optimise"]


def check_method(accuracy, steady) -> None:
    """``ValueError`` unless ``accuracy`` is a solver preset (or None) and ``steady`` a method
    of :func:`cardiosoft.solve_beats`."""
    if accuracy is not None and accuracy not in PRESETS:
        raise ValueError(f"accuracy = {accuracy!r}: allowed {', '.join(PRESETS)}")
    if steady not in STEADY_CHOICES:
        raise ValueError(f"steady = {steady!r}: allowed {', '.join(STEADY_CHOICES)}")


def _check_options(problem: Problem, max_rounds, pareto, map_lattice, accuracy, steady) -> None:
    if not isinstance(max_rounds, int) or isinstance(max_rounds, bool) or max_rounds < 1:
        raise ValueError(f"max_rounds = {max_rounds!r}: allowed a whole number >= 1")
    both = {"omega", "shortening"} <= set(problem.space.names)
    if pareto and not both:
        raise ValueError("pareto: needs omega and shortening among the free variables")
    if map_lattice is not None:
        if not both:
            raise ValueError("map_lattice: needs omega and shortening among the free variables")
        if len(map_lattice) != 2 or any(int(n) < 2 for n in map_lattice):
            raise ValueError(f"map_lattice = {map_lattice!r}: allowed (n_omega, n_C), each >= 2")
    check_method(accuracy, steady)


class _Prewarm(threading.Thread):
    """The verifying run() of the start design, on a second thread: it has the final run's
    shapes, so its compile overlaps with the search's and the final run finds it compiled."""

    def __init__(self, problem: Problem, pump):
        super().__init__(daemon=True)
        self.problem, self.pump = problem, pump
        self.seconds = math.nan

    def run(self):
        begin = time.perf_counter()
        try:
            verify_design(self.problem, self.problem.start, self.pump)
        except Exception:  # reported by the real verification, if it recurs there
            pass
        self.seconds = time.perf_counter() - begin


def _grid_key(problem: Problem, accuracy, steady) -> tuple:
    """What the grid's evaluations depend on (everything but the targets' values)."""
    rates = tuple(problem.base["bpm"] if t.bpm is None else t.bpm for t in problem.targets)
    heads = problem.heads_mmHg
    return (
        problem.scene,
        problem.space,
        tuple(sorted(problem.base.items())),
        None if heads is None else tuple(heads),
        rates,
        accuracy,
        steady,
    )


def _evaluate_grid(evaluate, z_grid, key, pump):
    """((values, jac, ok) of the grid, whether they were kept from an earlier search): evaluated
    in batches of REFINE, once per :func:`_grid_key` and surrogate. A further target of the same
    scene, design space, afterloads and rates (only the targets, the objective or the tolerance
    differ) starts from them, in this process and, in a command's, from its store
    (:func:`cardiosoft.program_store.stored_value`; lv-systemic's warm design 4.2 -> 2.5 s)."""
    names = ("values", "jac", "ok")
    computed = []

    def compute():
        computed.append(True)
        grid_evals = [evaluate(z_grid[k : k + REFINE]) for k in range(0, GRID, REFINE)]
        return {n: np.concatenate([e[i] for e in grid_evals]) for i, n in enumerate(names)}

    evals = stored_value("design grid", (key, z_grid, pump), compute)
    return tuple(evals[n] for n in names), not computed


def _grid_search(problem: Problem, evaluate, record: SearchRecord, z_grid, say, t0, key, pump):
    """Evaluate the coarse grid: ((values, jac, ok) of every candidate, the seconds since ``t0``
    that were not the search's compile)."""
    d = z_grid.shape[1]
    (values, jac, ok), reused = _evaluate_grid(evaluate, z_grid, key, pump)
    r, _ = residuals(problem, values, jac, rates_of(problem, z_grid, d))
    s, _ = secondary_objective(problem, values, jac)
    record.add(z_grid, values, ok, r, s)
    grid_s = time.perf_counter() - t0 - evaluate.compile_s
    n_ok = int(ok.all(axis=1).sum())
    best_grid = np.min(np.where(ok.all(axis=1), np.max(np.abs(r), axis=1), np.inf))
    say(
        f"grid: {GRID} candidates ({n_ok} solved{', kept from an earlier search' * reused}), "
        f"best max |residual| {best_grid:.3g} ml; compile {evaluate.compile_s:.1f} s, grid "
        f"{grid_s:.2f} s"
    )
    return (values, jac, ok), grid_s


def _winning_path(problem: Problem, record: SearchRecord, paths, best_z) -> tuple[dict, ...]:
    """The designs along the winning candidate's path: its grid point, each step it kept."""
    path = [best_z]
    for p in paths:
        if any(np.array_equal(q, best_z) for q in p):
            path = p[: next(k for k, q in enumerate(p) if np.array_equal(q, best_z)) + 1]
            break
    else:  # a trial step that was not kept: the path of the candidate it came from, then it
        if record.best is not None and paths:
            near = min(paths, key=lambda p: float(np.sum((p[-1] - best_z) ** 2)))
            path = [*near, best_z]
    return tuple(
        {
            k: float(v[0])
            for k, v in design_values(problem, q[None, :]).items()
            if k in problem.space.names or k in ("omega", "shortening")
        }
        for q in path
    )


def _target_results(problem: Problem, records, record: SearchRecord) -> list[TargetResult]:
    """One TargetResult per target: the verifying run's numbers, the search's SV, the range of
    SVs seen (the run's included)."""
    search = {}
    if record.best is not None:
        search = {i: float(record.best[2][i, 0]) for i in range(len(problem.targets))}
    reachable = record.reachable()
    targets = []
    for i, (t, rec) in enumerate(zip(problem.targets, records, strict=True)):
        aim = target_sv_of(problem, t, rec["bpm"])
        if rec["ok"] and math.isfinite(rec["sv_ml"]):  # the verifying run's SV was seen too
            seen = [v for v in reachable[i] if math.isfinite(v)] + [rec["sv_ml"]]
            reachable[i] = (min(seen), max(seen))
        targets.append(
            TargetResult(
                afterload_mmHg=t.afterload_mmHg,
                bpm=rec["bpm"],
                target_sv_ml=aim,
                sv_ml=rec["sv_ml"],
                residual_ml=rec["sv_ml"] - aim,
                search_sv_ml=search.get(i, math.nan),
                peak_force_N=rec["peak_force_N"],
                mech_work_J=rec["mech_work_J"],
                efficiency=rec["efficiency"],
                cardiac_output_l_min=rec["cardiac_output_l_min"],
                static_sv_ml=rec["static_sv_ml"],
                reachable_sv_ml=reachable[i],
                target_co_l_min=t.co_l_min,
                ok=rec["ok"],
                message=rec["message"],
                flags=rec["flags"],
            )
        )
    return targets


def _verdict(problem: Problem, targets, found: str) -> tuple[bool, float | None, str]:
    """(reached, the secondary objective's value at the design, the message)."""
    reached = all(t.ok and abs(t.residual_ml) <= problem.tol for t in targets)
    objective_value = None
    if problem.objective is not None:
        key = {"peak_force": "peak_force_N", "mech_work": "mech_work_J"}.get(
            problem.objective, problem.objective
        )
        objective_value = float(np.mean([getattr(t, key) for t in targets]))
    if reached:
        message = f"every target within {problem.tol:g} ml"
    else:
        worst = max(targets, key=lambda t: abs(t.residual_ml))
        lo, hi = worst.reachable_sv_ml
        message = (
            f"not reached: {worst.sv_ml:.2f} ml against {worst.target_sv_ml:.2f} ml"
            + (f" at {worst.afterload_mmHg:g} mmHg" if worst.afterload_mmHg is not None else "")
            + f"; stroke volumes seen there {lo:.1f} to {hi:.1f} ml; the closest design is "
            "returned"
        )
        if not all(t.ok for t in targets):
            message += "; the verifying run: " + "; ".join(t.message for t in targets if not t.ok)
    if found:
        message = f"{found}; {message}"
    return reached, objective_value, message


def optimise(
    scene="bench-dynamic",
    target_sv=None,
    *,
    target_co=None,
    afterload=None,
    bpm=None,
    free=DEFAULT_FREE,
    start=None,
    bounds=None,
    minimize=None,
    maximize=None,
    tol: float = TOLERANCE_ML,
    pareto: bool = False,
    accuracy: str | None = None,
    steady: str = DEFAULT_STEADY,
    max_rounds: int = MAX_ROUNDS,
    map_lattice: tuple[int, int] | None = None,
    progress=None,
    pump: PumpSurrogate | None = None,
) -> DesignResult:
    """Find a design of ``scene`` whose periodic steady state hits the targets.

    **Arguments** (user units):

    - ``scene``: a shipped scene's name, a scene file or a :class:`~cardiosoft.scene.Scene`.
    - ``target_sv``: target stroke volume(s), ml (>= 0); or ``target_co``: cardiac output(s),
      l/min. One of the two.
    - ``afterload``: column head(s) in mmHg of a water-column scene (default: the scene's);
      none for a Windkessel scene. ``bpm``: rate(s), default the scene's. Targets, afterloads
      and rates pair up in order; each is one value or one per target.
    - ``free``: the free design variables (:data:`FREE_VARIABLES`), default Omega and C.
    - ``start``: ``{name: value}`` to start from (default: the scene's design); the values of
      variables that are not free are kept fixed at it.
    - ``bounds``: ``{name: (low, high)}`` narrowing the range of Omega, C or the rate
      (default: :data:`cardiosoft.scene.RANGES`).
    - ``minimize``: ``"peak_force"`` or ``"mech_work"``; ``maximize``: ``"efficiency"``: a
      secondary objective among the designs that hit the targets (mean over the targets).
    - ``tol``: tolerance on every target's stroke volume, ml (default 0.5).
    - ``pareto``: also trace the designs that hit the targets across Omega (module docstring);
      they trade peak force against efficiency, or against mechanical work with
      ``minimize="mech_work"``.
    - ``accuracy``: the solver preset of the search (default: the scene's, as the verifying
      run uses; ``"fast"`` is faster and less accurate). ``steady``: how the search finds the
      periodic orbits, ``"shooting"`` or ``"beats"`` (:func:`cardiosoft.solve_beats`), or
      ``"auto"`` (the default: shooting on the water-column bench, beats on a Windkessel
      scene; :func:`cardiosoft.design.search.steady_method`).
    - ``max_rounds``: refinement rounds at most. ``map_lattice``: ``(n_omega, n_C)``, also
      map the stroke volume on that lattice for the figure (:attr:`DesignResult.sv_map`).
      ``progress``: a callable that receives one
      line per round (default: silent). ``pump``: a surrogate (default: the shipped one).

    **Returns:** a :class:`DesignResult`. Bad input raises ``ValueError`` naming the parameter,
    its value, unit and allowed range. An unreachable target is not an error: ``reached`` is
    False and the closest design is returned.
    """
    start_time = time.perf_counter()
    problem = build_problem(
        scene, target_sv, target_co, afterload, bpm, free, start, bounds, minimize, maximize, tol
    )
    _check_options(problem, max_rounds, pareto, map_lattice, accuracy, steady)
    say = progress if progress is not None else (lambda line: None)
    pump = load(problem.scene.pump) if pump is None else pump
    steady = steady_method(problem.scene, steady)
    evaluate = Evaluator(problem, pump, accuracy, steady)
    record = SearchRecord(problem)
    seconds: dict = {}
    rounds, paths, warmer = _search(
        problem, evaluate, record, say, max_rounds, _grid_key(problem, accuracy, steady), seconds
    )
    if record.best is None:
        best_z = problem.space.to_z(problem.start, problem.base)
        found = "no candidate solved; the start design is returned"
    else:
        best_z, found = record.best[1], ""
    design = {k: float(v[0]) for k, v in design_values(problem, best_z[None, :]).items()}
    # 3. verification by the ordinary run() path, once the prewarm has compiled it
    t2 = time.perf_counter()
    if warmer.ident is not None:  # started
        warmer.join()
    seconds["prewarm_wait_s"] = time.perf_counter() - t2
    t2 = time.perf_counter()
    records, runs = verify_design(problem, design, pump)
    seconds["verify_s"] = time.perf_counter() - t2
    targets = _target_results(problem, records, record)
    reached, objective_value, message = _verdict(problem, targets, found)
    front, lattice = None, None
    seconds["pareto_s"] = seconds["map_s"] = 0.0
    if pareto:
        t3 = time.perf_counter()
        trade = "mech_work" if problem.objective == "mech_work" else "efficiency"
        front = pareto_trace(problem, evaluate, record, design, trade, say, max_rounds, pump)
        seconds["pareto_s"] = time.perf_counter() - t3
    if map_lattice is not None:
        t4 = time.perf_counter()
        lattice = sv_map(problem, evaluate, design, tuple(int(n) for n in map_lattice))
        seconds["map_s"] = time.perf_counter() - t4
    total = time.perf_counter() - start_time
    return DesignResult(
        scene=problem.scene,
        design=design,
        free=problem.space.names,
        reached=reached,
        tolerance_ml=problem.tol,
        targets=tuple(targets),
        objective=problem.objective,
        objective_value=objective_value,
        iterations=rounds,
        seconds=total,
        timings=_timings(evaluate, warmer, seconds, total),
        path=_winning_path(problem, record, paths, best_z),
        explored=record.explored(),
        pareto=front,
        runs=tuple(runs),
        message=message,
        sv_map=lattice,
    )


def _search(problem: Problem, evaluate, record, say, max_rounds, key, seconds: dict):
    """The coarse grid, then the best few refined together: (rounds, paths, the prewarm
    thread). The verifying run() is compiled meanwhile on a second thread, unless this process
    ran a search of this shape before (its run() is compiled then too)."""
    # The search's tracing first, alone: two threads tracing at once share Python's lock and
    # took longer than one after the other (measured, #13); the prewarm's tracing then runs
    # while XLA compiles the search.
    t0 = time.perf_counter()
    z_grid = grid_points(problem)
    warm = evaluate.compiled(z_grid[:REFINE])
    evaluate.trace(z_grid[:REFINE])
    warmer = _Prewarm(problem, evaluate.pump)
    if not warm:
        warmer.start()
    (values, jac, ok), seconds["grid_s"] = _grid_search(
        problem, evaluate, record, z_grid, say, t0, key, evaluate.pump
    )
    chosen = select_candidates(problem, z_grid, values, jac, ok, REFINE)
    t1 = time.perf_counter()
    evals = (values[chosen], jac[chosen], ok[chosen])
    mask = np.ones(z_grid.shape[1])
    rounds, paths = refine(problem, evaluate, record, z_grid[chosen], evals, mask, max_rounds, say)
    seconds["refine_s"] = time.perf_counter() - t1
    return rounds, paths, warmer


def _timings(evaluate, warmer, seconds: dict, total: float) -> dict:
    """Where the time of :func:`optimise` went (:attr:`DesignResult.timings`)."""
    calls = sorted(evaluate.call_s)
    return {
        "compile_s": evaluate.compile_s,
        "trace_s": evaluate.trace_s,
        "grid_s": seconds["grid_s"],
        "refine_s": seconds["refine_s"],
        "verify_s": seconds["verify_s"],
        "prewarm_s": warmer.seconds,
        "prewarm_wait_s": seconds["prewarm_wait_s"],
        "pareto_s": seconds["pareto_s"],
        "map_s": seconds["map_s"],
        "total_s": total,
        "calls": evaluate.calls,
        "call_median_s": calls[len(calls) // 2] if calls else math.nan,
    }
