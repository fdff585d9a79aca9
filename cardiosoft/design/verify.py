"""Every design answer re-simulated by :func:`cardiosoft.run`, and the Pareto trace.

:func:`verify_design` runs a design through the ordinary :func:`cardiosoft.run` path at the
scene's own accuracy (one run per rate); the stroke volumes, forces and ``reached`` that
:func:`cardiosoft.design.optimise` reports are that run's. :func:`pareto_trace` solves for C at
each of :data:`~cardiosoft.design.search.REFINE` Omegas so that the targets are hit, verifies
each, and marks which trade peak force against efficiency (or mechanical work) without being
dominated.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from cardiosoft.design.problem import FRACTIONS, Problem, Target
from cardiosoft.design.result import ParetoPoint
from cardiosoft.design.search import REFINE, design_values, refine
from cardiosoft.experiment import run
from cardiosoft.results import RunResult
from cardiosoft.units import ml

__all__ = ["pareto_trace", "target_sv_of", "verify_design"]


def verify_design(problem: Problem, design: dict, pump) -> tuple[list[dict], list[RunResult]]:
    """Run the design through :func:`cardiosoft.run`: one run per rate, every target's record."""
    scene = problem.scene
    fractions = {f: design[f] for f in FRACTIONS if f in problem.space.names}
    if fractions:
        scene = scene.replace(**fractions)
    groups: dict[float, list[int]] = {}
    for i, t in enumerate(problem.targets):
        groups.setdefault(design["bpm"] if t.bpm is None else t.bpm, []).append(i)
    records: list[dict] = [{} for _ in problem.targets]
    runs = []
    for rate, members in groups.items():
        heads = None
        if scene.afterload.has_heads:
            heads = [problem.targets[i].afterload_mmHg for i in members]
        result = run(
            scene,
            omega=design["omega"],
            shortening=design["shortening"],
            bpm=rate,
            afterload=heads,
            pump=pump,
        )
        runs.append(result)
        for k, i in enumerate(members):
            m = result.members[k if heads is not None else 0]
            x = m.metrics
            records[i] = {
                "bpm": rate,
                "sv_ml": x["stroke_volume"] / ml,
                "peak_force_N": x["peak_force"],
                "mech_work_J": x["mech_work"],
                "efficiency": x["efficiency"],
                "cardiac_output_l_min": x["cardiac_output"] * 60.0 / (1000.0 * ml),
                "static_sv_ml": (
                    x["static_stroke_volume"] / ml if "static_stroke_volume" in x else None
                ),
                "ok": m.ok,
                "message": m.message,
                "flags": tuple(getattr(m, "flags", ())),
            }
    return records, runs


def target_sv_of(problem: Problem, target: Target, rate: float) -> float:
    """The stroke volume aimed at (ml); for a cardiac-output target, the one giving it at
    ``rate``."""
    return target.sv_ml if target.sv_ml is not None else target.co_l_min * 1000.0 / rate


def pareto_trace(problem, evaluate, record, design, trade, say, max_rounds, pump):
    """Designs that hit the targets across Omega (C solved for at each), verified by run()."""
    names = problem.space.names
    j_omega = names.index("omega")
    mask = np.array([1.0 if n == "shortening" else 0.0 for n in names])
    lo, hi = problem.space.lo[j_omega], problem.space.hi[j_omega]
    omegas = lo + (hi - lo) * (np.arange(REFINE) + 0.5) / REFINE
    omegas[np.argmin(np.abs(omegas - design["omega"]))] = design["omega"]
    z = np.array([problem.space.to_z(design | {"omega": float(w)}, problem.base) for w in omegas])
    values, jac, ok, _ = evaluate(z)
    searched = dataclasses.replace(problem, objective=None)
    _rounds, paths = refine(
        searched, evaluate, record, z, (values, jac, ok), mask, max_rounds, say, "pareto", True
    )
    finals = np.array([p[-1] for p in paths])
    designs = design_values(problem, finals)
    points = []
    for i in range(len(finals)):
        candidate = {k: float(designs[k][i]) for k in designs}
        records, _ = verify_design(problem, candidate, pump)
        hit = all(
            r["ok"] and abs(r["sv_ml"] - target_sv_of(problem, t, r["bpm"])) <= problem.tol
            for r, t in zip(records, problem.targets, strict=True)
        )
        if hit:
            points.append(
                {
                    "omega": candidate["omega"],
                    "shortening": candidate["shortening"],
                    "sv_ml": tuple(r["sv_ml"] for r in records),
                    "peak_force_N": float(np.mean([r["peak_force_N"] for r in records])),
                    "efficiency": float(np.mean([r["efficiency"] for r in records])),
                    "mech_work_J": float(np.mean([r["mech_work_J"] for r in records])),
                }
            )
    # non-dominated: less force, and more efficiency (or less mechanical work)
    second = (lambda p: -p["efficiency"]) if trade == "efficiency" else (lambda p: p["mech_work_J"])
    out = []
    for p in points:
        dominated = any(
            q["peak_force_N"] <= p["peak_force_N"]
            and second(q) <= second(p)
            and (q["peak_force_N"] < p["peak_force_N"] or second(q) < second(p))
            for q in points
        )
        out.append(ParetoPoint(**p, dominated=dominated))
    return tuple(sorted(out, key=lambda p: p.omega))
