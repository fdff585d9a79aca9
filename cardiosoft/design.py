"""Design optimisation: which (Omega, C) give a target stroke volume, and at what cable force.

    python -m cardiosoft.design --target-sv 70 --afterload 90 --bpm 60
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
candidates, without derivatives (``steady="shooting"``, the default: Newton shooting on the
one-beat map, :func:`cardiosoft.solve_beats`; or ``"beats"``, beat after beat from rest), then
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
compiles faster (a fresh process about 3-5 s less). The search solves at the scene's accuracy
preset, as the verifying run does (``accuracy="fast"`` is faster; its stroke volumes differ from
the run's by up to 0.3 ml in the stiff Windkessel scenes).

``pareto=True`` also traces the designs that hit the targets across Omega (C solved for at
each of :data:`REFINE` Omegas) and reports which of them trade peak force against efficiency
(or mechanical work) without being dominated.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import dataclasses
import functools
import json
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import optax

from cardiosoft._validate import check_range
from cardiosoft.batch import (
    STEADY_METHODS,
    default_config,
    solve_beats,
    solve_orbit,
    split_scene,
)
from cardiosoft.experiment import run
from cardiosoft.pump import PumpSurrogate, load
from cardiosoft.results import RunResult
from cardiosoft.scene import RANGES, Scene, load_scene
from cardiosoft.solve import PRESETS
from cardiosoft.units import ml, mmHg

__all__ = [
    "DEFAULT_FREE",
    "FREE_VARIABLES",
    "GRID",
    "OBJECTIVES",
    "REFINE",
    "TOLERANCE_ML",
    "DesignResult",
    "ParetoPoint",
    "Target",
    "TargetResult",
    "design_optimiser",
    "main",
    "optimise",
    "plot_design",
]

FREE_VARIABLES = (
    "omega",
    "shortening",
    "bpm",
    "pull_fraction",
    "hold_fraction",
    "release_fraction",
)
"""The design variables that may be freed, in the order of ``z``."""
BOX_VARIABLES = ("omega", "shortening", "bpm")
FRACTIONS = ("pull_fraction", "hold_fraction", "release_fraction")
DEFAULT_FREE = ("omega", "shortening")
OBJECTIVES = {"peak_force": 1.0, "mech_work": 1.0, "efficiency": -1.0}
"""Secondary objectives and their sign: the first two are minimised, efficiency maximised."""
OBJECTIVE_UNITS = {"peak_force": "N", "mech_work": "J", "efficiency": ""}
TOLERANCE_ML = 0.5
"""Default tolerance on every target's stroke volume (ml)."""
GRID = 32
"""Candidates of the coarse grid (a multiple of :data:`REFINE`)."""
REFINE = 8
"""Candidates refined together: the batch of the compiled search."""
MAX_ROUNDS = 40
"""Refinement rounds at most (each one compiled call)."""
DEFAULT_STEADY = "shooting"
"""How the search reaches the periodic steady state (``solve_beats(steady=...)``)."""
METRICS = ("sv", "co", "peak_force", "mech_work", "efficiency")
"""What one evaluation returns per target, in ml, l/min, N, J and -."""
RADIUS = (1.0, 2.0, 1e-3)
"""Trust radius in z: initial, largest, and the one below which a candidate has stalled."""
_STALL_ML = 0.01
"""A round that improves a candidate's residual by less than this (ml) counts as stalled."""
_STALL_ROUNDS = 3
_LEARNING_RATE = (0.3, 0.9, 0.005)
"""Adam's learning rate for the secondary objective: initial, decay per round, final (z)."""
_GRID_LEVELS = {1: (GRID,), 2: (8, 4)}
"""Grid levels per free variable for one or two of them; more use Halton points."""
_EDGE = 1e-3
"""Where z starts, as a fraction of each range from its ends (logit(1e-3) = -6.9)."""
OUTPUT_FILES = ("design.json", "design.png")


# --------------------------------------------------------------------------------- the problem


@dataclasses.dataclass(frozen=True)
class Target:
    """One target of a design problem (user units).

    - ``sv_ml``: the target stroke volume (ml); None for a cardiac-output target.
    - ``co_l_min``: the target cardiac output (l/min); None for a stroke-volume target.
    - ``afterload_mmHg``: the column head of a water-column scene; None for a Windkessel.
    - ``bpm``: the rate (beats per minute); None when the rate is a free design variable.
    """

    sv_ml: float | None
    afterload_mmHg: float | None
    bpm: float | None
    co_l_min: float | None = None


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
      them already), ``grid_s``, ``refine_s``, ``verify_s`` (the final run()), ``prewarm_s``
      (the run() of the start design on a second thread, which compiles the verification
      meanwhile), ``prewarm_wait_s`` (how long the verification waited for
      it), ``pareto_s``, ``map_s``, ``total_s``; ``calls`` and ``call_median_s`` of the
      compiled function.
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
    def omega(self) -> float:
        return self.design["omega"]

    @property
    def shortening(self) -> float:
        return self.design["shortening"]

    def to_json(self) -> dict:
        """A JSON-ready record (user units): what ``design.json`` holds. JSON has no NaN: a
        number that could not be computed is null."""

        def clean(v):
            if isinstance(v, float) and not math.isfinite(v):
                return None
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, list | tuple):
                return [clean(x) for x in v]
            return v

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
            "targets": targets,
            "path": list(self.path),
        }
        if self.pareto is not None:
            out["pareto"] = [dataclasses.asdict(p) for p in self.pareto]
        return clean(out)


@dataclasses.dataclass(frozen=True)
class _Space:
    """The free variables and their unconstrained coordinates z (hashable: static in jit)."""

    names: tuple[str, ...]
    lo: tuple[float, ...]  # per name; box variables only (user units)
    hi: tuple[float, ...]

    def values(self, z, base: dict, xp=jnp) -> dict:
        """Design values (user units) at ``z`` (last axis: the free variables); ``base`` holds
        every variable's value when fixed."""
        out = dict(base)
        for j, name in enumerate(self.names):
            if name in BOX_VARIABLES:
                u = 1.0 / (1.0 + xp.exp(-z[..., j]))
                out[name] = self.lo[j] + (self.hi[j] - self.lo[j]) * u
        free_fractions = [j for j, n in enumerate(self.names) if n in FRACTIONS]
        if free_fractions:
            # the free fractions and the rest of the period share what the fixed ones leave
            budget = 1.0 - sum(base[f] for f in FRACTIONS if f not in self.names)
            logits = xp.stack([z[..., j] for j in free_fractions] + [0.0 * z[..., 0]], axis=-1)
            logits = logits - xp.max(logits, axis=-1, keepdims=True)
            shares = xp.exp(logits) / xp.sum(xp.exp(logits), axis=-1, keepdims=True)
            for k, j in enumerate(free_fractions):
                out[self.names[j]] = budget * shares[..., k]
        return out

    def to_z(self, design: dict, base: dict) -> np.ndarray:
        """The z of ``design`` (user units), kept :data:`_EDGE` inside every range."""
        z = np.zeros(len(self.names))
        budget = 1.0 - sum(base[f] for f in FRACTIONS if f not in self.names)
        rest = budget - sum(design[n] for n in self.names if n in FRACTIONS)
        rest = max(rest, _EDGE * budget)
        for j, name in enumerate(self.names):
            if name in BOX_VARIABLES:
                u = (design[name] - self.lo[j]) / (self.hi[j] - self.lo[j])
            else:
                u = design[name] / (design[name] + rest)
            u = float(np.clip(u, _EDGE, 1 - _EDGE))
            z[j] = math.log(u / (1 - u))
        return z


@dataclasses.dataclass(frozen=True)
class _Problem:
    scene: Scene
    targets: tuple[Target, ...]
    space: _Space
    base: dict  # user units: every FREE_VARIABLES value when fixed (the start for the free)
    start: dict
    objective: str | None
    tol: float
    kind: str  # "sv" or "co"

    @property
    def heads_mmHg(self):
        return (
            None if not self.scene.afterload.has_heads else [t.afterload_mmHg for t in self.targets]
        )


def _as_values(name: str, value, unit: str) -> np.ndarray:
    try:
        arr = np.atleast_1d(np.asarray(value, dtype=float))
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} = {value!r}: allowed a number or a list of numbers ({unit})"
        ) from None
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} = {value!r}: allowed a number or a non-empty list ({unit})")
    return arr


def _objective(minimize, maximize) -> str | None:
    minimize = None if minimize in (None, "none") else minimize
    if minimize is not None and minimize not in ("peak_force", "mech_work"):
        raise ValueError(f"minimize = {minimize!r}: allowed peak_force, mech_work or none")
    if maximize not in (None, "none", "efficiency"):
        raise ValueError(f"maximize = {maximize!r}: allowed efficiency or none")
    maximize = None if maximize == "none" else maximize
    if minimize is not None and maximize is not None:
        raise ValueError(
            f"minimize = {minimize!r} and maximize = {maximize!r}: allowed one secondary "
            "objective at a time"
        )
    return minimize or maximize


def _problem(
    scene, target_sv, target_co, afterload, bpm, free, start, bounds, minimize, maximize, tol
) -> _Problem:
    scene = scene if isinstance(scene, Scene) else load_scene(scene)
    if scene.static:
        raise ValueError(
            f"scene = {scene.name!r} is static (no beats, no rate): use bench-dynamic or a "
            "dynamic scene"
        )
    check_range("tolerance", tol, "ml", 0.0, math.inf, lo_open=True)
    objective = _objective(minimize, maximize)
    # --- free variables and their box
    free = (free,) if isinstance(free, str) else tuple(free)
    unknown = [f for f in free if f not in FREE_VARIABLES]
    if unknown or not free or len(set(free)) != len(free):
        raise ValueError(
            f"free = {list(free)!r}: allowed distinct names among {', '.join(FREE_VARIABLES)}"
        )
    free = tuple(f for f in FREE_VARIABLES if f in free)
    bounds = dict(bounds or {})
    lo, hi = [], []
    for name in free:
        if name in FRACTIONS:
            if name in bounds:
                raise ValueError(
                    f"bounds[{name!r}]: the actuation fractions are bounded by the period "
                    "(pull + hold + release <= 1); allowed bounds for omega, shortening, bpm"
                )
            lo.append(0.0)
            hi.append(1.0)
            continue
        full = RANGES[name]
        b = bounds.pop(name, full)
        unit = "bpm" if name == "bpm" else ""
        b = _as_values(f"bounds[{name!r}]", b, unit)
        if b.size != 2 or not b[0] < b[1]:
            raise ValueError(f"bounds[{name!r}] = {list(b)}: allowed (low, high) with low < high")
        label = "shortening C" if name == "shortening" else name
        for v in b:
            check_range(
                f"bounds of {label}", v, unit, *full, lo_open=name == "bpm" and full[0] == 0.0
            )
        lo.append(float(b[0]))
        hi.append(float(b[1]))
    stray = [k for k in bounds if k not in free]
    if stray:
        raise ValueError(f"bounds[{stray[0]!r}]: not a free variable; free are {', '.join(free)}")
    # --- targets
    if (target_sv is None) == (target_co is None):
        raise ValueError("target: give target_sv (ml) or target_co (l/min), one of the two")
    kind = "sv" if target_sv is not None else "co"
    values = _as_values(
        "target_sv" if kind == "sv" else "target_co",
        target_sv if kind == "sv" else target_co,
        "ml" if kind == "sv" else "l/min",
    )
    if kind == "sv":
        check_range("target SV", values, "ml", 0.0, math.inf, hi_open=True)
    else:
        check_range("target cardiac output", values, "l/min", 0.0, math.inf, hi_open=True)
    counts = {"target_sv" if kind == "sv" else "target_co": values}
    if scene.afterload.has_heads:
        heads = _as_values("afterload", afterload, "mmHg") if afterload is not None else None
        heads = np.asarray(scene.afterloads) / mmHg if heads is None else heads
        check_range("afterload", heads, "mmHg", *RANGES["afterloads"])
        counts["afterload"] = heads
    elif afterload is not None:
        raise ValueError(
            f"afterload: scene {scene.name} has a {scene.afterload_type} afterload, which has "
            "no column head to set; give no afterload"
        )
    bpm_free = "bpm" in free
    rates = _as_values("bpm", scene.bpm if bpm is None else bpm, "bpm")
    check_range("bpm", rates, "bpm", *RANGES["bpm"], lo_open=True)
    if bpm_free and rates.size != 1:
        raise ValueError(
            f"bpm = {list(rates)}: the rate is a free variable; give one starting rate"
        )
    if not bpm_free:
        counts["bpm"] = rates
    n = max(len(v) for v in counts.values())
    bad = {k: len(v) for k, v in counts.items() if len(v) not in (1, n)}
    if bad:
        listed = ", ".join(f"{k}: {len(v)} values" for k, v in counts.items())
        raise ValueError(
            f"targets: {listed}; give one value or one per target for each (they pair up in order)"
        )
    full = {k: np.broadcast_to(v, (n,)) for k, v in counts.items()}
    targets = tuple(
        Target(
            sv_ml=float(full["target_sv"][i]) if kind == "sv" else None,
            co_l_min=float(full["target_co"][i]) if kind == "co" else None,
            afterload_mmHg=float(full["afterload"][i]) if "afterload" in full else None,
            bpm=None if bpm_free else float(full["bpm"][i]),
        )
        for i in range(n)
    )
    # --- where the search starts, and what is fixed
    base = {name: float(getattr(scene, name)) for name in FREE_VARIABLES}
    base["bpm"] = float(rates[0])
    start = dict(start or {})
    stray = [k for k in start if k not in FREE_VARIABLES]
    if stray:
        raise ValueError(f"start[{stray[0]!r}]: allowed keys {', '.join(FREE_VARIABLES)}")
    for name, value in start.items():
        unit = "bpm" if name == "bpm" else ""
        label = "shortening C" if name == "shortening" else name
        check_range(f"start {label}", value, unit, *RANGES[name], lo_open=name in ("bpm",))
    base |= {k: float(v) for k, v in start.items()}
    fixed = sum(base[f] for f in FRACTIONS if f not in free)
    if any(f in free for f in FRACTIONS) and fixed >= 1.0:
        raise ValueError(
            f"free = {list(free)}: the fixed actuation fractions already fill the period "
            f"({fixed:g}); free one of them too, or lower it"
        )
    if sum(base[f] for f in FRACTIONS) > 1 + 1e-12:
        raise ValueError("start: pull + hold + release fractions exceed 1")
    space = _Space(free, tuple(lo), tuple(hi))
    return _Problem(scene, targets, space, base, dict(base), objective, float(tol), kind)


# ------------------------------------------------------------------------------- the search


def _member_solve(structure, numbers, pump, config, space, steady):
    """``solve(x, bpm, head, start) -> (metrics (m, 5), (ok (m,), beats (m,), y0))`` of m
    members: design values ``x``, rates, heads (None for a Windkessel) and, with
    ``steady="orbit"``, orbit starts (:func:`cardiosoft.batch.solve_orbit`). The orbits
    themselves (``steady`` "shooting" or "beats") come without metrics (None)."""
    fractions_free = any(f in space.names for f in FRACTIONS)

    def solve(scene, x, bpm, head, start):
        common = dict(
            omega=x["omega"],
            shortening=x["shortening"],
            bpm=bpm,
            afterload=head,
            pump=pump,
            config=config,
        )
        if steady != "orbit":  # no sampled beat: the orbit's start is all it is for
            out = solve_beats(scene, steady=steady, save="state", **common)
            return None, (out.succeeded & out.steady, out.beats, out.y0)
        out = solve_orbit(scene, start, save="metrics", **common)
        m = out.metrics
        values = jnp.stack(
            [
                m.stroke_volume / ml,
                m.cardiac_output * (60.0 / (1000.0 * ml)),
                m.peak_force,
                m.mech_work,
                m.efficiency,
            ],
            axis=-1,
        )
        ok = out.succeeded & out.steady & jnp.all(jnp.isfinite(values), axis=-1)
        return values, (ok, out.beats, out.y0)

    def members(x, bpm, head, start):
        if not fractions_free:  # every member field of the batch solve: one batch
            return solve(dataclasses.replace(structure, **numbers), x, bpm, head, start)

        # the fractions are scene numbers, shared by a batch: a batch of one per member
        def one(x_m, bpm_m, head_m, start_m):
            scene = dataclasses.replace(structure, **(numbers | {f: x_m[f] for f in FRACTIONS}))
            one_head = None if head_m is None else head_m[None]
            one_start = jax.tree_util.tree_map(lambda a: a[None], start_m)
            out = solve(scene, x_m, bpm_m[None], one_head, one_start)
            return jax.tree_util.tree_map(lambda a: a[0], out)

        (size,) = jnp.broadcast_shapes(*(jnp.shape(v) for v in (*x.values(), bpm)))
        x = {name: jnp.broadcast_to(v, (size,)) for name, v in x.items()}
        return jax.vmap(one)(x, jnp.broadcast_to(bpm, (size,)), head, start)

    return members


def _member_inputs(z, base, heads, rates, space, target):
    x = space.values(z, base)
    bpm = x["bpm"] if "bpm" in space.names else rates[target]
    return x, bpm, None if heads is None else heads[target]


def _evaluate(z, base, heads, rates, numbers, pump, config, starts, *, structure, space):
    """Metrics (R, K, 5) of candidates ``z`` (R, d) at the K targets, their derivatives with
    respect to z (R, K, 5, d), and ok (R, K): one beat from ``starts``, the orbit starts of
    the R x K members (:func:`_orbits`), differentiated as the orbits
    (:func:`cardiosoft.solve_orbit`).

    One forward-mode pass over one batch: each candidate is repeated once per free variable
    (and per target), every copy moved along its own variable by the same tangent, so a
    single ``jax.jvp`` of one vmapped solve gives every column of every Jacobian. That costs
    d primal solves per candidate instead of one, and saves a vmap over the tangents, which
    would batch every while loop of the solve once more: measured, the trace and the compile
    take about half as long.
    """
    n, d = z.shape
    k = rates.shape[0]
    candidate = jnp.repeat(jnp.arange(n), d * k)
    direction = jnp.tile(jnp.repeat(jnp.arange(d), k), n)
    target = jnp.tile(jnp.arange(k), n * d)
    z_m = z[candidate]
    unit = jnp.eye(d, dtype=z.dtype)[direction]
    solve = _member_solve(structure, numbers, pump, config, space, "orbit")
    start = jax.tree_util.tree_map(lambda a: a[candidate * k + target], starts)

    def members(t):
        values, (ok, _, _) = solve(
            *_member_inputs(z_m + t[:, None] * unit, base, heads, rates, space, target), start
        )
        return values, ok

    zero = jnp.zeros(n * d * k, z.dtype)
    values, tangents, ok = jax.jvp(members, (zero,), (jnp.ones_like(zero),), has_aux=True)
    ok = ok & jnp.all(jnp.isfinite(tangents), axis=-1)
    values = values.reshape(n, d, k, -1)[:, 0]
    jac = jnp.moveaxis(tangents.reshape(n, d, k, -1), 1, -1)
    return values, jac, ok.reshape(n, d, k).all(axis=1)


def _orbits(z, base, heads, rates, numbers, pump, config, *, structure, space, steady):
    """(ok (R x K,), beats, y0) of the R x K members of candidates ``z`` (R, d) at the K
    targets: their periodic orbits (``steady``: "shooting" or "beats"), without derivatives
    (:func:`_evaluate` differentiates them)."""
    n, k = z.shape[0], rates.shape[0]
    candidate, target = jnp.repeat(jnp.arange(n), k), jnp.tile(jnp.arange(k), n)
    solve = _member_solve(structure, numbers, pump, config, space, steady)
    _, (ok, beats, y0) = solve(
        *_member_inputs(z[candidate], base, heads, rates, space, target), None
    )
    return ok, beats, y0


_EVALUATE = functools.partial(jax.jit, static_argnames=("structure", "space"))(_evaluate)
_ORBITS = functools.partial(jax.jit, static_argnames=("structure", "space", "steady"))(_orbits)


class _Evaluator:
    """The search's compiled programs for a problem's shape, and their timings.

    A call is two programs: the orbits without derivatives (:func:`_orbits`), then their
    implicit derivatives at those orbits (:func:`_evaluate`). Each is about half the size of
    the shooting solve differentiated whole, and they compile at once, on two threads: XLA
    compiles without Python's lock, so the second is traced while the first compiles (#13)."""

    _compiled: ClassVar[dict] = {}  # shared by every search of the process: no recompile
    _pending: ClassVar[dict] = {}  # traced, compiling on a thread

    def __init__(self, problem: _Problem, pump, accuracy: str | None, steady: str):
        scene = problem.scene
        if accuracy is not None and accuracy not in PRESETS:
            raise ValueError(f"accuracy = {accuracy!r}: allowed {', '.join(PRESETS)}")
        config = default_config(scene if accuracy is None else scene.replace(accuracy=accuracy))
        self.structure, self.numbers = split_scene(scene, keep_steady=True)
        self.pump, self.config, self.space, self.steady = pump, config, problem.space, steady
        ftype = jnp.result_type(float)
        self.base = {k: jnp.asarray(v, ftype) for k, v in problem.base.items()}
        heads = problem.heads_mmHg
        self.heads = None if heads is None else jnp.asarray(heads, ftype) * mmHg
        rates = [problem.base["bpm"] if t.bpm is None else t.bpm for t in problem.targets]
        self.rates = jnp.asarray(rates, ftype)
        self.compile_s = 0.0  # trace, lower and compile, until the programs are ready
        self.trace_s = 0.0  # trace and lower
        self.calls = 0
        self.call_s: list[float] = []

    def _args(self, z):
        z = jnp.asarray(z, jnp.result_type(float))
        args = (z, self.base, self.heads, self.rates, self.numbers, self.pump, self.config)
        leaves, treedef = jax.tree_util.tree_flatten(args)
        key = (
            self.structure,
            self.space,
            self.steady,
            treedef,
            tuple((np.shape(a), jnp.result_type(a)) for a in leaves),
        )
        return args, key

    def trace(self, z: np.ndarray) -> None:
        """Trace and lower for the shape of ``z`` now, each program then compiling on a thread
        of its own while the next is traced (tracing holds Python's lock, XLA does not)."""
        args, key = self._args(z)
        if key in self._compiled or key in self._pending:
            return
        start = time.perf_counter()
        static = dict(structure=self.structure, space=self.space)
        orbits = _ORBITS.lower(*args, **static, steady=self.steady)
        compiling = [_COMPILER.submit(orbits.compile)]
        starts = orbits.out_info[2]  # the shapes of the orbit starts
        compiling.append(_COMPILER.submit(_EVALUATE.lower(*args, starts, **static).compile))
        self._pending[key] = (start, compiling)
        self.trace_s += time.perf_counter() - start

    def __call__(self, z: np.ndarray):
        """(values (R, K, 5), jac (R, K, 5, d), ok (R, K), beats (R, K)) as numpy."""
        self.trace(z)
        args, key = self._args(z)
        if key not in self._compiled:
            begin, compiling = self._pending.pop(key)
            self._compiled[key] = [c.result() for c in compiling]
            self.compile_s += time.perf_counter() - begin
        start = time.perf_counter()
        orbits, derivative = self._compiled[key]
        ok_orbit, beats, y0 = orbits(*args)
        values, jac, ok = derivative(*args, y0)
        ok = np.asarray(ok) & np.asarray(ok_orbit).reshape(ok.shape)
        values, jac = np.asarray(values), np.asarray(jac)
        self.call_s.append(time.perf_counter() - start)
        self.calls += 1
        return values, jac, ok, np.asarray(beats).reshape(ok.shape)


_COMPILER = concurrent.futures.ThreadPoolExecutor(max_workers=2, thread_name_prefix="compile")
"""XLA compiles the search's two programs here, each on a thread of its own."""


def _project_secondary() -> optax.GradientTransformationExtraArgs:
    """The objective's gradient minus its part that would change the residuals."""

    def update(updates, state, params=None, *, jacobian, mask, **extra):
        del params, extra
        jac = jacobian * mask
        null = jnp.eye(jac.shape[1], dtype=jac.dtype) - jnp.linalg.pinv(jac) @ jac
        return null @ (updates * mask), state

    return optax.GradientTransformationExtraArgs(lambda params: optax.EmptyState(), update)


def _gauss_newton_step() -> optax.GradientTransformationExtraArgs:
    """Adds the least-squares (Gauss-Newton) step on the residuals: ``-J^+ r``."""

    def update(updates, state, params=None, *, residual, jacobian, mask, **extra):
        del params, extra
        step = -jnp.linalg.pinv(jacobian * mask) @ residual
        return updates + step * mask, state

    return optax.GradientTransformationExtraArgs(lambda params: optax.EmptyState(), update)


def _trust_region() -> optax.GradientTransformationExtraArgs:
    """Clips the step to the candidate's trust radius (in z)."""

    def update(updates, state, params=None, *, radius, **extra):
        del params, extra
        norm = jnp.sqrt(jnp.sum(updates**2))
        return updates * jnp.minimum(1.0, radius / jnp.maximum(norm, 1e-300)), state

    return optax.GradientTransformationExtraArgs(lambda params: optax.EmptyState(), update)


def design_optimiser() -> optax.GradientTransformationExtraArgs:
    """The refinement step as an optax chain (module docstring, step 3).

    ``update(objective_gradient, state, z, residual=r, jacobian=J, mask=m, radius=rho)`` for
    one candidate: ``r`` (K,) the residuals in ml, ``J`` (K, d) their derivatives in z, ``m``
    (d,) 1 for the variables that may move, ``rho`` the trust radius. The gradient of the
    secondary objective (zeros without one) is projected onto the null space of ``J`` and
    scaled by Adam with a decaying learning rate; the Gauss-Newton step ``-J^+ r`` is added;
    the sum is clipped to ``rho``.
    """
    first, decay, last = _LEARNING_RATE
    schedule = optax.exponential_decay(first, 1, decay, end_value=last)
    return optax.chain(
        _project_secondary(),
        optax.scale_by_adam(),
        optax.scale_by_learning_rate(schedule),
        _gauss_newton_step(),
        _trust_region(),
    )


@functools.cache
def _optimiser_step():
    opt = design_optimiser()

    def step(gradient, state, z, residual, jacobian, mask, radius):
        updates, state = opt.update(
            gradient, state, z, residual=residual, jacobian=jacobian, mask=mask, radius=radius
        )
        return z + updates, state

    return opt, jax.jit(jax.vmap(step))


def _residuals(problem: _Problem, values, jac, design_rates):
    """Residuals (R, K) in ml and their derivatives (R, K, d): SV - target, or for a cardiac
    output target SV - CO_target / rate (the SV that gives the target output)."""
    sv, dsv = values[..., 0], jac[..., 0, :]
    if problem.kind == "sv":
        target = np.array([t.sv_ml for t in problem.targets])
        return sv - target, dsv
    co = np.array([t.co_l_min for t in problem.targets])
    rate, drate = design_rates  # (R, K) bpm and its derivative (R, K, d)
    target = co * 1000.0 / rate
    return sv - target, dsv + (co * 1000.0 / rate**2)[..., None] * drate


def _secondary(problem: _Problem, values, jac):
    """The objective (R,) to minimise and its gradient (R, d); zeros without one."""
    if problem.objective is None:
        return np.zeros(values.shape[0]), np.zeros((values.shape[0], jac.shape[-1]))
    k = METRICS.index(problem.objective)
    sign = OBJECTIVES[problem.objective]
    return sign * values[..., k].mean(axis=1), sign * jac[..., k, :].mean(axis=1)


def _halton(n: int, d: int) -> np.ndarray:
    primes = (2, 3, 5, 7, 11, 13)[:d]
    out = np.zeros((n, d))
    for j, p in enumerate(primes):
        for i in range(n):
            f, k, x = 1.0, i + 1, 0.0
            while k:
                f /= p
                x += f * (k % p)
                k //= p
            out[i, j] = x
    return out


def _grid(problem: _Problem) -> np.ndarray:
    """The coarse grid in z (GRID, d): a lattice of cell centres (Halton points for more than
    two free variables), the start design in place of the point nearest to it."""
    d = len(problem.space.names)
    levels = _GRID_LEVELS.get(d)
    if levels is None:
        u = _halton(GRID, d)
    else:
        axes = [(np.arange(n) + 0.5) / n for n in levels]
        u = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d)
    z = np.log(u / (1 - u))
    start = problem.space.to_z(problem.start, problem.base)
    z[np.argmin(np.sum((z - start) ** 2, axis=1))] = start
    return z


def _design_values(problem: _Problem, z: np.ndarray) -> dict:
    """Every variable's value (user units) at each z (R, d): numpy arrays (R,)."""
    v = problem.space.values(np.asarray(z), problem.base, xp=np)
    return {k: np.broadcast_to(np.asarray(v[k], dtype=float), z.shape[:-1]) for k in v}


def _rates(problem: _Problem, z, d):
    """The rate of every candidate at every target (R, K) and its derivative (R, K, d)."""
    n = len(problem.targets)
    if "bpm" not in problem.space.names:
        rate = np.array([t.bpm for t in problem.targets], dtype=float)
        return np.broadcast_to(rate, (z.shape[0], n)), np.zeros((z.shape[0], n, d))
    j = problem.space.names.index("bpm")
    lo, hi = problem.space.lo[j], problem.space.hi[j]
    u = 1.0 / (1.0 + np.exp(-z[:, j]))
    rate = np.repeat((lo + (hi - lo) * u)[:, None], n, axis=1)
    drate = np.zeros((z.shape[0], n, d))
    drate[:, :, j] = ((hi - lo) * u * (1 - u))[:, None]
    return rate, drate


class _Record:
    """Every evaluation of a search: designs, stroke volumes and the best so far."""

    def __init__(self, problem: _Problem):
        self.problem = problem
        self.z, self.sv, self.ok = [], [], []
        self.best = None  # (key, z, values, residual)

    def add(self, z, values, ok, residual, objective):
        self.z.append(np.asarray(z))
        self.sv.append(values[..., 0])
        self.ok.append(ok.all(axis=1))
        good = ok.all(axis=1)
        rss = np.sum(residual**2, axis=1)
        feasible = np.max(np.abs(residual), axis=1) <= 0.5 * self.problem.tol
        for i in np.flatnonzero(good):
            if self.problem.objective is not None and feasible[i]:
                key = (0, objective[i])
            else:
                key = (1, rss[i])
            if self.best is None or key < self.best[0]:
                self.best = (key, np.asarray(z[i]), values[i], residual[i])

    def explored(self) -> dict:
        z = np.concatenate(self.z) if self.z else np.zeros((0, len(self.problem.space.names)))
        designs = _design_values(self.problem, z)
        return {
            **{k: designs[k] for k in self.problem.space.names},
            "omega": designs["omega"],
            "shortening": designs["shortening"],
            "sv_ml": np.concatenate(self.sv) if self.sv else np.zeros((0, 0)),
            "ok": np.concatenate(self.ok) if self.ok else np.zeros(0, bool),
        }

    def reachable(self) -> list[tuple[float, float]]:
        sv = np.concatenate(self.sv)[np.concatenate(self.ok)]
        if sv.size == 0:
            return [(math.nan, math.nan)] * len(self.problem.targets)
        return [(float(lo), float(hi)) for lo, hi in zip(sv.min(0), sv.max(0), strict=True)]


def _refine(
    problem, evaluate, record, z0, evals, mask, max_rounds, say, label="round", every=False
):
    """Refine the candidates z0 (R, d), already evaluated (``evals``); returns (rounds, paths).

    Without a secondary objective it stops when one candidate hits the targets, or with
    ``every`` when each one has hit them or stalled."""
    opt, step = _optimiser_step()
    n, d = z0.shape
    secondary = problem.objective is not None and mask.sum() > 0
    tol_in = 0.5 * problem.tol
    z_acc = np.array(z0, dtype=float)
    values, jac, ok = evals
    rates = _rates(problem, z_acc, d)
    r_acc, j_acc = (np.array(a) for a in _residuals(problem, values, jac, rates))
    s_acc, g_acc = (np.array(a) for a in _secondary(problem, values, jac))
    ok_acc = ok.all(axis=1)
    rss_acc = np.where(ok_acc, np.sqrt(np.sum(r_acc**2, axis=1)), np.inf)
    radius = np.full(n, RADIUS[0])
    stalls = np.zeros(n, int)
    state = jax.vmap(opt.init)(jnp.asarray(z_acc))
    masks = jnp.asarray(np.broadcast_to(mask, (n, d)), dtype=jnp.result_type(float))
    paths = [[z_acc[i].copy()] for i in range(n)]
    best_objective = math.inf
    quiet_rounds = 0
    rounds = 0
    for rounds in range(1, max_rounds + 1):
        t0 = time.perf_counter()
        trial, state = step(
            jnp.asarray(np.where(ok_acc[:, None], g_acc, 0.0)),
            state,
            jnp.asarray(z_acc),
            jnp.asarray(np.where(ok_acc[:, None], r_acc, 0.0)),
            jnp.asarray(np.where(ok_acc[:, None, None], j_acc, 0.0)),
            masks,
            jnp.asarray(radius),
        )
        trial = np.asarray(trial)
        values, jac, ok, _ = evaluate(trial)
        rates = _rates(problem, trial, d)
        r_new, j_new = _residuals(problem, values, jac, rates)
        s_new, g_new = _secondary(problem, values, jac)
        ok_new = ok.all(axis=1) & np.all(np.isfinite(trial), axis=1)
        record.add(trial, values, ok, r_new, s_new)
        rss_new = np.where(ok_new, np.sqrt(np.sum(r_new**2, axis=1)), np.inf)
        feas_acc = np.max(np.abs(r_acc), axis=1) <= tol_in
        feas_new = np.max(np.abs(r_new), axis=1) <= tol_in
        if secondary:
            accept = ok_new & np.where(
                feas_acc, feas_new & (s_new <= s_acc), feas_new | (rss_new < rss_acc)
            )
        else:
            accept = ok_new & (rss_new < rss_acc)
        progress = np.where(accept, rss_acc - rss_new, 0.0)
        if secondary:
            progress = np.where(accept & feas_acc, np.inf, progress)  # judged by the objective
        stalls = np.where(progress < _STALL_ML * problem.tol, stalls + 1, 0)
        radius = np.where(accept, np.minimum(2 * radius, RADIUS[1]), radius / 4)
        for i in np.flatnonzero(accept):
            z_acc[i], r_acc[i], j_acc[i] = trial[i], r_new[i], j_new[i]
            s_acc[i], g_acc[i], rss_acc[i], ok_acc[i] = s_new[i], g_new[i], rss_new[i], True
            paths[i].append(trial[i].copy())
        feasible = ok_acc & (np.max(np.abs(r_acc), axis=1) <= tol_in)
        done = (radius < RADIUS[2]) | (stalls >= _STALL_ROUNDS) | (~ok_acc)
        if secondary and feasible.any():
            current = float(np.min(s_acc[feasible]))
            improved = current < best_objective - 1e-4 * abs(best_objective)
            quiet_rounds = 0 if improved else quiet_rounds + 1
            best_objective = min(best_objective, current)
        i = (
            int(np.argmin(np.where(feasible, s_acc, np.inf)))
            if secondary and feasible.any()
            else (int(np.argmin(rss_acc)))
        )
        x = _design_values(problem, z_acc[i : i + 1])
        where = ", ".join(f"{_LABELS[k]} {x[k][0]:.4g}" for k in problem.space.names)
        line = f"{label} {rounds:2d}: max |residual| {np.max(np.abs(r_acc[i])):7.3f} ml at {where}"
        if problem.objective is not None:
            sign = OBJECTIVES[problem.objective]
            line += (
                f"; {problem.objective} {sign * s_acc[i]:.4g} {OBJECTIVE_UNITS[problem.objective]}"
            )
        line += f"; {int(accept.sum())}/{n} steps kept ({time.perf_counter() - t0:.2f} s)"
        say(line)
        if not secondary and (np.all(feasible | done) if every else feasible.any()):
            break
        if secondary and feasible.any() and quiet_rounds >= 2 * _STALL_ROUNDS:
            break
        if np.all(done | (secondary & feasible & (radius < 4 * RADIUS[2]))):
            break
    return rounds, paths


_LABELS = {
    "omega": "Omega",
    "shortening": "C",
    "bpm": "bpm",
    "pull_fraction": "pull",
    "hold_fraction": "hold",
    "release_fraction": "release",
}


def _select(problem, z, values, jac, ok, count):
    """The ``count`` best grid candidates (indices)."""
    d = z.shape[1]
    r, j = _residuals(problem, values, jac, _rates(problem, z, d))
    rss = np.where(ok.all(axis=1), np.sum(r**2, axis=1), np.inf)
    if problem.objective is None:
        return np.argsort(rss, kind="stable")[:count]
    s, g = _secondary(problem, values, jac)
    predicted = np.full(len(z), np.inf)
    for i in range(len(z)):
        if not np.isfinite(rss[i]):
            continue
        dz = -np.linalg.pinv(j[i]) @ r[i]
        if np.sqrt(np.sum(dz**2)) <= 2 * RADIUS[1]:  # the targets are near: rank by objective
            predicted[i] = s[i] + g[i] @ dz
    order = np.lexsort((rss, predicted))  # by predicted objective, then by residual
    return order[:count]


# ------------------------------------------------------------------------------ verification


def _verify(problem: _Problem, design: dict, pump) -> tuple[list[dict], list[RunResult]]:
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


def _target_sv(problem: _Problem, target: Target, rate: float) -> float:
    return target.sv_ml if target.sv_ml is not None else target.co_l_min * 1000.0 / rate


def _pareto(problem, evaluate, record, design, trade, say, max_rounds, pump):
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
    _refine_rounds, paths = _refine(
        searched, evaluate, record, z, (values, jac, ok), mask, max_rounds, say, "pareto", True
    )
    finals = np.array([p[-1] for p in paths])
    designs = _design_values(problem, finals)
    points = []
    for i in range(len(finals)):
        candidate = {k: float(designs[k][i]) for k in designs}
        records, _ = _verify(problem, candidate, pump)
        hit = all(
            r["ok"] and abs(r["sv_ml"] - _target_sv(problem, t, r["bpm"])) <= problem.tol
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


# ------------------------------------------------------------------------------- the entry


def _check_method(accuracy, steady) -> None:
    if accuracy is not None and accuracy not in PRESETS:
        raise ValueError(f"accuracy = {accuracy!r}: allowed {', '.join(PRESETS)}")
    if steady not in STEADY_METHODS:
        raise ValueError(f"steady = {steady!r}: allowed {', '.join(STEADY_METHODS)}")


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
      run uses; ``"fast"`` is faster and less accurate). ``steady``: ``"shooting"`` or
      ``"beats"`` (:func:`cardiosoft.solve_beats`).
    - ``max_rounds``: refinement rounds at most. ``map_lattice``: ``(n_omega, n_C)``, also
      map the stroke volume on that lattice for the figure (:attr:`DesignResult.sv_map`).
      ``progress``: a callable that receives one
      line per round (default: silent). ``pump``: a surrogate (default: the shipped one).

    **Returns:** a :class:`DesignResult`. Bad input raises ``ValueError`` naming the parameter,
    its value, unit and allowed range. An unreachable target is not an error: ``reached`` is
    False and the closest design is returned.
    """
    start_time = time.perf_counter()
    problem = _problem(
        scene, target_sv, target_co, afterload, bpm, free, start, bounds, minimize, maximize, tol
    )
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
    _check_method(accuracy, steady)
    say = progress if progress is not None else (lambda line: None)
    pump = load() if pump is None else pump
    evaluate = _Evaluator(problem, pump, accuracy, steady)
    record = _Record(problem)

    # The verifying run() compiles while the search does (same shapes, the start design): its
    # compile overlaps with the search's, and the final run finds it compiled.
    warm: dict = {}

    def prewarm():
        begin = time.perf_counter()
        try:
            warm["records"], _ = _verify(problem, problem.start, pump)
        except Exception as err:  # reported by the real verification, if it recurs there
            warm["error"] = err
        warm["seconds"] = time.perf_counter() - begin

    # The search's tracing first, alone: two threads tracing at once share Python's lock and
    # took longer than one after the other (measured, #13); the prewarm's tracing then runs
    # while XLA compiles the search.
    t0 = time.perf_counter()
    z_grid = _grid(problem)
    evaluate.trace(z_grid[:REFINE])
    warmer = threading.Thread(target=prewarm, daemon=True)
    warmer.start()

    # 1. the coarse grid, in batches of REFINE
    d = z_grid.shape[1]
    grid_evals = [evaluate(z_grid[k : k + REFINE]) for k in range(0, GRID, REFINE)]
    values = np.concatenate([e[0] for e in grid_evals])
    jac = np.concatenate([e[1] for e in grid_evals])
    ok = np.concatenate([e[2] for e in grid_evals])
    r, _ = _residuals(problem, values, jac, _rates(problem, z_grid, d))
    s, _ = _secondary(problem, values, jac)
    record.add(z_grid, values, ok, r, s)
    grid_s = time.perf_counter() - t0 - evaluate.compile_s
    n_ok = int(ok.all(axis=1).sum())
    best_grid = np.min(np.where(ok.all(axis=1), np.max(np.abs(r), axis=1), np.inf))
    say(
        f"grid: {GRID} candidates ({n_ok} solved), best max |residual| {best_grid:.3g} ml; "
        f"compile {evaluate.compile_s:.1f} s, grid {grid_s:.2f} s"
    )

    # 2. refine the best few together
    chosen = _select(problem, z_grid, values, jac, ok, REFINE)
    t1 = time.perf_counter()
    mask = np.ones(d)
    rounds, paths = _refine(
        problem,
        evaluate,
        record,
        z_grid[chosen],
        (values[chosen], jac[chosen], ok[chosen]),
        mask,
        max_rounds,
        say,
    )
    refine_s = time.perf_counter() - t1
    if record.best is None:
        best_z = problem.space.to_z(problem.start, problem.base)
        found = "no candidate solved; the start design is returned"
    else:
        best_z = record.best[1]
        found = ""
    design = {k: float(v[0]) for k, v in _design_values(problem, best_z[None, :]).items()}
    # the path of the winning candidate (its grid point, then each step it kept)
    path = [best_z]
    for p in paths:
        if any(np.array_equal(q, best_z) for q in p):
            path = p[: next(k for k, q in enumerate(p) if np.array_equal(q, best_z)) + 1]
            break
    else:  # a trial step that was not kept: the path of the candidate it came from, then it
        if record.best is not None and paths:
            near = min(paths, key=lambda p: float(np.sum((p[-1] - best_z) ** 2)))
            path = [*near, best_z]
    path_designs = tuple(
        {
            k: float(v[0])
            for k, v in _design_values(problem, q[None, :]).items()
            if k in problem.space.names or k in ("omega", "shortening")
        }
        for q in path
    )

    # 3. verification by the ordinary run() path
    t2 = time.perf_counter()
    warmer.join()
    wait_s = time.perf_counter() - t2
    t2 = time.perf_counter()
    records, runs = _verify(problem, design, pump)
    verify_s = time.perf_counter() - t2
    search = {}
    if record.best is not None:
        search = {i: float(record.best[2][i, 0]) for i in range(len(problem.targets))}
    reachable = record.reachable()
    targets = []
    for i, (t, rec) in enumerate(zip(problem.targets, records, strict=True)):
        aim = _target_sv(problem, t, rec["bpm"])
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

    front = None
    pareto_s = 0.0
    if pareto:
        t3 = time.perf_counter()
        trade = "mech_work" if problem.objective == "mech_work" else "efficiency"
        front = _pareto(problem, evaluate, record, design, trade, say, max_rounds, pump)
        pareto_s = time.perf_counter() - t3

    lattice = None
    map_s = 0.0
    if map_lattice is not None:
        t4 = time.perf_counter()
        lattice = _sv_map(problem, evaluate, design, tuple(int(n) for n in map_lattice))
        map_s = time.perf_counter() - t4

    seconds = time.perf_counter() - start_time
    calls = sorted(evaluate.call_s)
    timings = {
        "compile_s": evaluate.compile_s,
        "trace_s": evaluate.trace_s,
        "grid_s": grid_s,
        "refine_s": refine_s,
        "verify_s": verify_s,
        "prewarm_s": warm.get("seconds", math.nan),
        "prewarm_wait_s": wait_s,
        "pareto_s": pareto_s,
        "map_s": map_s,
        "total_s": seconds,
        "calls": evaluate.calls,
        "call_median_s": calls[len(calls) // 2] if calls else math.nan,
    }
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
        seconds=seconds,
        timings=timings,
        path=path_designs,
        explored=record.explored(),
        pareto=front,
        runs=tuple(runs),
        message=message,
        sv_map=lattice,
    )


# ----------------------------------------------------------------------------------- figure


def plot_design(result: DesignResult, path=None):
    """The search over a map of stroke volume in the (Omega, C) plane, Table I's designs marked.

    The map is the result's :attr:`~DesignResult.sv_map` (``optimise(..., map_lattice=...)``),
    else interpolated from the designs the search evaluated; it is that of the first target.
    A second panel shows the Pareto trace when the result has one. With ``path`` (png, pdf or
    svg) the figure is written there, off-screen, and closed; without, it is returned (a
    notebook shows it).
    """
    from cardiosoft.datasets import load_paper_data
    from cardiosoft.files import atomic_path
    from cardiosoft.plots import check_figure_path

    fmt = None if path is None else check_figure_path(path)
    panels = 2 if result.pareto else 1
    size = (6.2 * panels, 5)
    if path is None:  # pyplot's figure: a notebook shows it
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, panels, figsize=size, constrained_layout=True)
    else:  # off-screen, whatever pyplot's backend is
        from matplotlib.figure import Figure

        fig = Figure(figsize=size, layout="constrained")
        axes = fig.subplots(1, panels)
    axes = np.atleast_1d(axes)
    ax = axes[0]
    target = result.targets[0]
    contour = result.sv_map
    if contour is not None:
        om, c = np.meshgrid(contour["omega"], contour["shortening"], indexing="ij")
        sv = contour["sv_ml"][..., 0]
        filled = ax.contourf(om, c, sv, levels=16, cmap="viridis")
        ax.contour(om, c, sv, levels=[target.target_sv_ml], colors="w", linewidths=2)
    else:
        e = result.explored
        good = e["ok"]
        filled = ax.tricontourf(
            e["omega"][good], e["shortening"][good], e["sv_ml"][good, 0], levels=16, cmap="viridis"
        )
        ax.tricontour(
            e["omega"][good],
            e["shortening"][good],
            e["sv_ml"][good, 0],
            levels=[target.target_sv_ml],
            colors="w",
            linewidths=2,
        )
    where = f" at {target.afterload_mmHg:g} mmHg" if target.afterload_mmHg is not None else ""
    fig.colorbar(filled, ax=ax, label=f"stroke volume{where}, {target.bpm:g} bpm [ml]")
    table1 = load_paper_data().table1_fem
    ax.plot(table1["omega"], table1["shortening"], "k+", ms=8, label="paper Table I (FEM sweep)")
    e = result.explored
    ax.plot(e["omega"], e["shortening"], ".", color="0.85", ms=3, label="designs evaluated")
    p_om = [p["omega"] for p in result.path]
    p_c = [p["shortening"] for p in result.path]
    ax.plot(p_om, p_c, "o-", color="tab:red", ms=4, label="optimiser path")
    ax.plot(p_om[:1], p_c[:1], "s", color="tab:red", ms=7)
    ax.plot(
        [result.omega],
        [result.shortening],
        "*",
        color="tab:orange",
        ms=16,
        mec="k",
        label=f"design: Omega {result.omega:.3f}, C {result.shortening:.3f}",
    )
    if result.pareto:
        front = [p for p in result.pareto if not p.dominated]
        ax.plot(
            [p.omega for p in result.pareto],
            [p.shortening for p in result.pareto],
            "D",
            mfc="none",
            mec="tab:cyan",
            label="designs hitting the target (Pareto trace)",
        )
        ax.plot([p.omega for p in front], [p.shortening for p in front], "D", color="tab:cyan")
    ax.set(xlabel="helix parameter Omega [-]", ylabel="cable shortening C [-]")
    ax.set_title(
        f"{result.scene.name}: target {target.target_sv_ml:.1f} ml{where}"
        + ("" if result.reached else " (not reached)"),
        fontsize=10,
    )
    ax.legend(fontsize=7, loc="lower right")
    if result.pareto:
        ax2 = axes[1]
        trade = "mech_work" if result.objective == "mech_work" else "efficiency"
        key = "mech_work_J" if trade == "mech_work" else "efficiency"
        pts = sorted(result.pareto, key=lambda p: p.peak_force_N)
        for p in pts:
            ax2.plot(
                p.peak_force_N, getattr(p, key), "o", color="0.6" if p.dominated else "tab:cyan"
            )
            ax2.annotate(f"{p.omega:.2f}", (p.peak_force_N, getattr(p, key)), fontsize=7)
        front = [p for p in pts if not p.dominated]
        ax2.plot(
            [p.peak_force_N for p in front],
            [getattr(p, key) for p in front],
            "-",
            color="tab:cyan",
            label="non-dominated (labels: Omega)",
        )
        ax2.set(
            xlabel="peak cable force (mean over targets) [N]",
            ylabel="efficiency [-]" if trade == "efficiency" else "mechanical work [J]",
        )
        ax2.set_title("designs that hit the target: force against " + trade, fontsize=10)
        ax2.legend(fontsize=7)
    if path is None:
        return fig
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=fmt, dpi=110)
    return None


def _sv_map(problem, evaluate, design, lattice) -> dict:
    """Stroke volumes (ml, search accuracy) on an (Omega, C) lattice over the bounds, the other
    variables at ``design``; for the figure. Batches of :data:`REFINE` (the compiled shape)."""
    names = problem.space.names
    n_omega, n_c = lattice
    axes = {}
    for name, n in (("omega", n_omega), ("shortening", n_c)):
        j = names.index(name)
        lo, hi = problem.space.lo[j], problem.space.hi[j]
        axes[name] = lo + (hi - lo) * np.linspace(0.01, 0.99, n)
    om, c = np.meshgrid(axes["omega"], axes["shortening"], indexing="ij")
    z = np.array(
        [
            problem.space.to_z(design | {"omega": float(a), "shortening": float(b)}, problem.base)
            for a, b in zip(om.ravel(), c.ravel(), strict=True)
        ]
    )
    pad = (-len(z)) % REFINE
    z = np.concatenate([z, np.repeat(z[-1:], pad, axis=0)])
    sv = []
    for k in range(0, len(z), REFINE):
        values, _, ok, _ = evaluate(z[k : k + REFINE])
        sv.append(np.where(ok, values[..., 0], np.nan))
    sv = np.concatenate(sv)[: om.size].reshape(n_omega, n_c, -1)
    return {"omega": axes["omega"], "shortening": axes["shortening"], "sv_ml": sv}


# ------------------------------------------------------------------------------ command line


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are one line and exit status 2, like every other bad input."""

    def error(self, message):
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(2)


def _parser() -> argparse.ArgumentParser:
    from cardiosoft.scene import SCENE_NAMES

    def allowed(field, left="["):
        lo, hi = RANGES[field]
        return f"{left}{lo:g}, {hi:g}]"

    p = _Parser(
        prog="python -m cardiosoft.design",
        description="Find the design (helix parameter Omega, cable shortening C) whose periodic "
        "steady state hits target stroke volumes; optionally the one with the least peak force, "
        "the least mechanical work or the most efficiency among them.",
    )
    p.add_argument(
        "--scene",
        default="bench-dynamic",
        help=f"shipped scene ({', '.join(SCENE_NAMES)}) or a scene .toml file "
        "(default: bench-dynamic)",
    )
    p.add_argument(
        "--target-sv", type=float, nargs="+", metavar="ML", help="target stroke volume(s), ml"
    )
    p.add_argument(
        "--target-co",
        type=float,
        nargs="+",
        metavar="L_MIN",
        help="target cardiac output(s), l/min, instead of --target-sv",
    )
    p.add_argument(
        "--afterload",
        type=float,
        nargs="+",
        metavar="MMHG",
        help=f"water-column head(s), mmHg, {allowed('afterloads')}; they pair up with the "
        "targets (default: the scene's heads)",
    )
    p.add_argument(
        "--bpm",
        type=float,
        nargs="+",
        metavar="N",
        help=f"beats per minute, {allowed('bpm', '(')}; one, or one per target (default: the "
        "scene's)",
    )
    p.add_argument(
        "--free",
        nargs="+",
        metavar="NAME",
        default=list(DEFAULT_FREE),
        help=f"free design variables among {', '.join(FREE_VARIABLES)} (default: omega shortening)",
    )
    p.add_argument(
        "--tol",
        type=float,
        default=TOLERANCE_ML,
        metavar="ML",
        help=f"tolerance on every stroke volume, ml (default {TOLERANCE_ML:g})",
    )
    p.add_argument(
        "--minimize", metavar="WHAT", help="peak_force, mech_work or none: a secondary objective"
    )
    p.add_argument("--maximize", metavar="WHAT", help="efficiency: a secondary objective")
    p.add_argument(
        "--pareto",
        action="store_true",
        help="trace the designs that hit the target and trade peak force against efficiency "
        "(against mechanical work with --minimize mech_work)",
    )
    p.add_argument(
        "--max-rounds",
        type=int,
        default=MAX_ROUNDS,
        help=f"refinement rounds (default {MAX_ROUNDS})",
    )
    p.add_argument(
        "--accuracy", metavar="PRESET", help="solver preset of the search (default: the scene's)"
    )
    p.add_argument(
        "--steady",
        default=DEFAULT_STEADY,
        metavar="METHOD",
        help="how the search finds the periodic orbits it differentiates: shooting (Newton on "
        "the one-beat map; the default) or beats (beat after beat; compiles faster, fails where "
        "the beats ring past the scene's max_beats)",
    )
    p.add_argument("--out", metavar="DIR", help="write design.json and design.png there")
    p.add_argument("--no-plot", action="store_true", help="with --out: skip the figure")
    p.add_argument("--force", action="store_true", help="overwrite existing files in --out")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def _fmt(value, spec) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return format(value, spec)


def _table(header, units, rows) -> str:
    widths = [max(len(x) for x in col) for col in zip(header, units, *rows, strict=True)]
    line = "  ".join
    out = [
        line(h.rjust(w) for h, w in zip(header, widths, strict=True)),
        line(u.rjust(w) for u, w in zip(units, widths, strict=True)),
    ]
    out += [line(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in rows]
    return "\n".join(out)


def _report(result: DesignResult) -> str:
    d = result.design
    head = [
        f"{result.scene.name}: Omega {d['omega']:.4f}, C {d['shortening']:.4f}"
        + "".join(f", {_LABELS[k]} {d[k]:.4g}" for k in result.free if k not in DEFAULT_FREE),
        f"{'reached' if result.reached else 'NOT reached'} (tolerance {result.tolerance_ml:g} ml) "
        f"in {result.iterations} rounds, {result.seconds:.1f} s "
        f"(compile {result.timings['compile_s']:.1f} s)",
    ]
    if result.objective is not None:
        unit = OBJECTIVE_UNITS[result.objective]
        head.append(
            f"objective: {'maximise' if OBJECTIVES[result.objective] < 0 else 'minimise'} "
            f"{result.objective} -> {result.objective_value:.4g} {unit}".rstrip()
            + " (mean over the targets)"
        )
    rows = []
    for t in result.targets:
        rows.append(
            [
                _fmt(t.afterload_mmHg, ".0f"),
                _fmt(t.bpm, "g"),
                _fmt(t.target_sv_ml, ".2f"),
                _fmt(t.sv_ml, ".2f"),
                _fmt(t.residual_ml, "+.2f"),
                f"{_fmt(t.reachable_sv_ml[0], '.1f')}-{_fmt(t.reachable_sv_ml[1], '.1f')}",
                _fmt(t.peak_force_N, ".1f"),
                _fmt(t.mech_work_J, ".3f"),
                _fmt(t.efficiency, ".3f"),
                _fmt(t.cardiac_output_l_min, ".2f"),
            ]
        )
    table = _table(
        [
            "afterload",
            "bpm",
            "target SV",
            "SV",
            "residual",
            "SV seen",
            "peak force",
            "mech. work",
            "efficiency",
            "CO",
        ],
        ["mmHg", "", "ml", "ml", "ml", "ml", "N", "J", "-", "l/min"],
        rows,
    )
    out = "\n".join(head) + "\n" + table
    if result.pareto is not None:
        rows = [
            [
                f"{p.omega:.3f}",
                f"{p.shortening:.4f}",
                " ".join(f"{v:.2f}" for v in p.sv_ml),
                f"{p.peak_force_N:.1f}",
                f"{p.efficiency:.4f}",
                f"{p.mech_work_J:.3f}",
                "" if p.dominated else "*",
            ]
            for p in result.pareto
        ]
        out += "\n\nPareto trace (designs hitting the targets; * = not dominated)\n" + _table(
            ["Omega", "C", "SV", "peak force", "efficiency", "mech. work", "front"],
            ["", "", "ml", "N", "-", "J", ""],
            rows,
        )
        if not result.pareto:
            out += "\n(no design on the trace hit the targets)"
    return out


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    from cardiosoft._cli import fail
    from cardiosoft.files import atomic_path, refuse_overwrite

    say = (lambda line: None) if args.quiet else (lambda line: print(line, file=sys.stderr))
    try:
        out_dir = Path(args.out) if args.out else None
        if out_dir is not None:
            if out_dir.exists() and not out_dir.is_dir():
                raise ValueError(f"--out {out_dir} exists and is not a folder")
            for name in OUTPUT_FILES:
                refuse_overwrite(out_dir / name, args.force)
        if args.target_sv is None and args.target_co is None:
            raise ValueError("--target-sv: missing; give the target stroke volume(s) in ml")
        if args.target_sv is not None and args.target_co is not None:
            raise ValueError("--target-sv and --target-co: give one of the two")
        targets = args.target_sv if args.target_sv is not None else args.target_co
        flag = "--target-sv" if args.target_sv is not None else "--target-co"
        for other, values in (("--afterload", args.afterload), ("--bpm", args.bpm)):
            if values is not None and len(values) not in (1, len(targets)) and len(targets) != 1:
                raise ValueError(
                    f"{flag}: {len(targets)} values and {other}: {len(values)} values; give "
                    f"one {other[2:]} or one per target (they pair up in order)"
                )
        if (
            args.afterload is not None
            and args.bpm is not None
            and len(targets) == 1
            and len(args.afterload) > 1
            and len(args.bpm) > 1
            and len(args.afterload) != len(args.bpm)
        ):
            raise ValueError(
                f"--afterload: {len(args.afterload)} values and --bpm: {len(args.bpm)} values; "
                "give one or the same number of each"
            )
        check_range("--max-rounds", args.max_rounds, "rounds", 1, 1000)
        kwargs = dict(
            target_sv=args.target_sv,
            target_co=args.target_co,
            afterload=args.afterload,
            bpm=None if args.bpm is None else (args.bpm[0] if len(args.bpm) == 1 else args.bpm),
            free=args.free,
            tol=args.tol,
            minimize=args.minimize,
            maximize=args.maximize,
            pareto=args.pareto,
            max_rounds=args.max_rounds,
            accuracy=args.accuracy,
            steady=args.steady,
        )
        scene = load_scene(args.scene)
        _problem(
            scene,
            **{k: kwargs[k] for k in ("target_sv", "target_co", "afterload", "bpm", "free", "tol")},
            start=None,
            bounds=None,
            minimize=args.minimize,
            maximize=args.maximize,
        )
        if args.pareto and not {"omega", "shortening"} <= set(args.free):
            raise ValueError("--pareto: needs omega and shortening among --free")
        _check_method(args.accuracy, args.steady)
    except (ValueError, FileNotFoundError) as err:
        return fail(err)
    plot = out_dir is not None and not args.no_plot
    say(
        f"{scene.name}: {len(targets)} target(s); compiling the search, then a "
        f"grid of {GRID} candidates and refinement rounds of {REFINE} ..."
    )
    try:
        result = optimise(
            scene,
            **kwargs,
            map_lattice=(12, 8) if plot else None,
            progress=say,
        )
    except ValueError as err:  # a problem only the search could see
        return fail(err)
    if not args.quiet:
        print(_report(result))
        if not result.reached:
            print(f"warning: {result.message}", file=sys.stderr)
        for t in result.targets:
            for flag in t.flags:
                where = f"{t.afterload_mmHg:g} mmHg" if t.afterload_mmHg is not None else "target"
                print(f"warning: {where}, {t.bpm:g} bpm: {flag}", file=sys.stderr)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        with atomic_path(out_dir / "design.json") as tmp:
            tmp.write_text(json.dumps(result.to_json(), indent=2, allow_nan=False) + "\n")
        say(f"wrote {out_dir / 'design.json'}")
        if plot:
            plot_design(result, out_dir / "design.png")
            say(f"wrote {out_dir / 'design.png'}")
    return 0 if result.reached else 3


if __name__ == "__main__":
    # From a fresh process most of the time is compiling the search's programs and the
    # verifying run(). XLA's optimisation level 0 (as simulate uses) compiles them in about a
    # third less CPU time than level 1; the compiled code runs about 3x slower (~0.15 s against
    # 0.05 s a call on the bench), which a search of a few to tens of calls hardly notices. An
    # XLA_FLAGS of the user's own is left as it is.
    os.environ.setdefault("XLA_FLAGS", "--xla_backend_optimization_level=0")
    from cardiosoft._cli import use_compile_cache

    use_compile_cache()  # the next process loads what this one compiles
    raise SystemExit(main())
