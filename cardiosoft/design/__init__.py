"""Design optimisation: which (Omega, C) give a target stroke volume, and at what cable force.

    cardiosoft design --target-sv 70 --afterload 90 --bpm 60     # or python -m cardiosoft.design
    python -m cardiosoft.design --target-sv 70 --afterload 90 --bpm 60 --minimize peak_force
    python -m cardiosoft.design --target-sv 67 62 58 --afterload 30 60 90 --out results/

From Python (float64 on, as everywhere in cardiosoft)::

    from cardiosoft.design import optimise
    result = optimise("bench-dynamic", target_sv=70, afterload=90, bpm=60, minimize="peak_force")
    result.omega, result.shortening, result.reached
    result.targets[0].sv_ml          # the verifying run()'s stroke volume, ml

**The problem.** The free design variables (:data:`FREE_VARIABLES`; Omega and C by default,
the rate and the actuation fractions if freed) are tuned so that the periodic steady state of
the scene hits one or more targets (:class:`Target`): a stroke volume at an afterload of the
bench, or a stroke volume or cardiac output of a Windkessel scene, each at its rate. Several
targets share one design (the same pump at 30, 60 and 90 mmHg; the same pump at two rates) and
are solved in one vmapped call, in the least-squares sense in ml, each target's residual
reported. A cardiac-output target counts in ml too: its residual is ``SV - CO / rate``.
Optionally, among the designs that hit every target (within half the tolerance), the one with
the least peak cable force, the least mechanical work or the most efficiency is sought (mean
over the targets).

**The method.**

1. The design space is the box of :data:`cardiosoft.scene.RANGES` (Omega in [0, 6], C in
   [0, 0.65], rate in (0, 300] bpm; narrower with ``bounds=``), mapped to unconstrained
   coordinates ``z`` by a logistic function (the actuation fractions by a softmax that keeps
   pull + hold + release within the period). Bounds are never crossed and never reached.
2. A coarse grid of :data:`GRID` candidates (8 Omegas x 4 Cs for the default design
   variables, the start design among them) is simulated in batches of :data:`REFINE`, with
   forward-mode derivatives: the buckling step (Table I's jumps) makes the landscape steep in
   places, and the grid finds the right side of it. The :data:`REFINE` best (least squared
   residual; with a secondary objective, least objective after a linearised step onto the
   targets) are refined together.
3. Refinement is an optax chain (:func:`design_optimiser`): the secondary objective's gradient,
   projected onto the null space of the residuals' Jacobian, goes through Adam with a decaying
   learning rate; a Gauss-Newton step on the residuals (the pseudo-inverse of their Jacobian,
   a least-squares step in ml) is added; the sum is clipped to a trust radius. A step is kept
   if it improves (the residual, or the objective within the targets), else it is undone and
   the radius shrinks. Every round is one call of the same compiled programs on a fixed
   batch, so a problem compiles once (per number of targets and free variables) and a further
   target with the same shape reuses it.
4. It stops when a candidate is within half the tolerance (default :data:`TOLERANCE_ML`,
   0.5 ml), or, with a secondary objective, when the objective stops improving; or when
   every candidate has stalled (an unreachable target) or after ``max_rounds``. A failed or
   unsteady solve counts as no improvement: the answer is never NaN.
5. The answer is re-simulated by :func:`cardiosoft.run` at the scene's own accuracy; the
   stroke volumes, forces and ``reached`` reported are that run's. An unreachable target
   gives ``reached=False``, the closest design found and the range of stroke volumes seen at
   that target over every design evaluated (:attr:`TargetResult.reachable_sv_ml`).

**Derivatives.** Each evaluation is two compiled programs: the periodic orbits of the
candidates, without derivatives (``steady="shooting"``: Newton shooting on the one-beat map,
:func:`cardiosoft.solve_beats`; or ``"beats"``, beat after beat from rest; by default
``"auto"``, shooting on the ringing water-column bench and beats on the damped Windkessel
scenes, :func:`~cardiosoft.design.search.steady_method`), then
one beat from each orbit's start by :func:`cardiosoft.solve_orbit`, whose derivative is the
periodic steady state's by the implicit function theorem, not that of the beats from rest that
led there. Measured at Omega 4, C 0.4, 60 bpm, the search's d SV / d C and d SV / d Omega agree
with central differences (steps 1e-3 in C, 1e-2 in Omega) of runs converged beat after beat to
1e-5 ml within 0.3 % at 30 mmHg and 0.02 % at 60 and 90 mmHg (``tests/test_design.py`` holds
them to 1 %). The split is for the compile: each program is about half the size of the shooting
solve differentiated whole, and the two compile at once on two threads while the verifying
run's is traced (#13: a fresh process 25-29 s instead of 30-33 s, ``benchmarks/design.py``).
Shooting finds orbits where beats ring for longer than the scene's ``max_beats`` (the bench at
60 bpm and 90 mmHg: 32 of 32 grid candidates steady against 24 beat after beat); ``"beats"``
compiles faster and runs faster where it converges (lv-systemic at 72 bpm from a fresh
process: 26.6 CPU seconds against 40.4). The search solves at the scene's accuracy
preset, as the verifying run does (``accuracy="fast"`` is faster; its stroke volumes differ from
the run's by up to 0.3 ml in the stiff Windkessel scenes).

``pareto=True`` also traces the designs that hit the targets across Omega (C solved for at
each of :data:`REFINE` Omegas) and reports which of them trade peak force against efficiency
(or mechanical work) without being dominated.

**Where it lives.** :mod:`~cardiosoft.design.problem` (targets, free variables, the box),
:mod:`~cardiosoft.design.programs` (the two compiled programs), :mod:`~cardiosoft.design.chain`
(the optax chain), :mod:`~cardiosoft.design.search` (grid and refinement),
:mod:`~cardiosoft.design.verify` (run() of the answer, the Pareto trace),
:mod:`~cardiosoft.design.result` (records and JSON), :mod:`~cardiosoft.design.figure`,
:mod:`~cardiosoft.design.optimiser` (:func:`optimise`, which ties them together) and
:mod:`~cardiosoft.design.cli` (the command line).

**Closed loops** (``tah``, ``soft-lv``, ``soft-rv``) are designed by
:func:`~cardiosoft.design.loop.optimise_loop` (:mod:`~cardiosoft.design.loop`, its command line
:mod:`~cardiosoft.design.loop_cli`): a cardiac output with the mean atrial pressures at their
targets, ``cardiosoft design --scene tah --target-co 5 --lap 8 --rap 5``.
"""

from cardiosoft.design.chain import design_optimiser
from cardiosoft.design.cli import main
from cardiosoft.design.figure import plot_design
from cardiosoft.design.loop import LoopDesignResult, LoopTarget, optimise_loop
from cardiosoft.design.optimiser import optimise
from cardiosoft.design.problem import (
    DEFAULT_FREE,
    FREE_VARIABLES,
    OBJECTIVES,
    TOLERANCE_ML,
    Target,
)
from cardiosoft.design.result import DesignResult, ParetoPoint, TargetResult
from cardiosoft.design.search import GRID, REFINE

__all__ = [
    "DEFAULT_FREE",
    "FREE_VARIABLES",
    "GRID",
    "OBJECTIVES",
    "REFINE",
    "TOLERANCE_ML",
    "DesignResult",
    "LoopDesignResult",
    "LoopTarget",
    "ParetoPoint",
    "Target",
    "TargetResult",
    "design_optimiser",
    "main",
    "optimise",
    "optimise_loop",
    "plot_design",
]
