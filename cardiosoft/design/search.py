"""The design search: a coarse grid of candidates, then the best few refined together.

1. :func:`grid_points`: :data:`GRID` candidates (8 Omegas x 4 Cs for the default design
   variables, the start design among them), simulated in batches of :data:`REFINE`, with
   forward-mode derivatives: the buckling step (Table I's jumps) makes the landscape steep in
   places, and the grid finds the right side of it. :func:`select_candidates` keeps the
   :data:`REFINE` best (least squared residual; with a secondary objective, least objective
   after a linearised step onto the targets).
2. :func:`refine`: rounds of the optax chain (:func:`cardiosoft.design.chain.design_optimiser`)
   on those candidates together. A step is kept if it improves (the residual, or the objective
   within the targets), else it is undone and the radius shrinks. Every round is one call of
   the same compiled programs (:mod:`cardiosoft.design.programs`) on a fixed batch.
3. It stops when a candidate is within half the tolerance, or, with a secondary objective, when
   the objective stops improving; or when every candidate has stalled (an unreachable target)
   or after ``max_rounds``. A failed or unsteady solve counts as no improvement.

:class:`SearchRecord` keeps every evaluation: the best design, what was explored, the stroke
volumes seen at each target.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.design.chain import optimiser_step
from cardiosoft.design.problem import LABELS, OBJECTIVE_UNITS, OBJECTIVES, Problem
from cardiosoft.design.programs import METRICS

__all__ = [
    "DEFAULT_STEADY",
    "GRID",
    "MAX_ROUNDS",
    "RADIUS",
    "REFINE",
    "STEADY_CHOICES",
    "SearchRecord",
    "design_values",
    "grid_points",
    "halton",
    "rates_of",
    "refine",
    "residuals",
    "secondary_objective",
    "select_candidates",
    "steady_method",
]

GRID = 32
"""Candidates of the coarse grid (a multiple of :data:`REFINE`)."""
REFINE = 8
"""Candidates refined together: the batch of the compiled search."""
MAX_ROUNDS = 40
"""Refinement rounds at most (each one compiled call)."""
DEFAULT_STEADY = "auto"
"""How the search reaches the periodic steady state: ``"auto"`` (:func:`steady_method`),
``"shooting"`` or ``"beats"`` (``solve_beats(steady=...)``)."""
STEADY_CHOICES = ("auto", "shooting", "beats")


def steady_method(scene, steady: str) -> str:
    """The method ``"auto"`` stands for: Newton shooting where the afterload rings (the
    water-column bench: its column sloshes near 0.4-0.5 Hz, and at 60 bpm and 90 mmHg beat after
    beat left 8 of the 32 grid candidates unsteady after the scene's 40 beats, shooting none),
    beat after beat on the Windkessel scenes, whose valves and resistances damp the approach
    (lv-systemic and rv-pulmonary: every one of the 32 grid designs steady within 26 beats at
    60-300 bpm). Beat after beat is the lighter program: lv-systemic at 72 bpm, 40 ml from a
    fresh process took 26.6 CPU seconds against 40.4 by shooting (2 loaded cores), to the same
    design within 1e-4."""
    if steady != "auto":
        return steady
    return "shooting" if scene.afterload.has_heads else "beats"


RADIUS = (1.0, 2.0, 1e-3)
"""Trust radius in z: initial, largest, and the one below which a candidate has stalled."""
_STALL_ML = 0.01
"""A round that improves a candidate's residual by less than this (ml) counts as stalled."""
_STALL_ROUNDS = 3
_GRID_LEVELS = {1: (GRID,), 2: (8, 4)}
"""Grid levels per free variable for one or two of them; more use Halton points."""


def residuals(problem: Problem, values, jac, design_rates):
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


def secondary_objective(problem: Problem, values, jac):
    """The objective (R,) to minimise and its gradient (R, d); zeros without one."""
    if problem.objective is None:
        return np.zeros(values.shape[0]), np.zeros((values.shape[0], jac.shape[-1]))
    k = METRICS.index(problem.objective)
    sign = OBJECTIVES[problem.objective]
    return sign * values[..., k].mean(axis=1), sign * jac[..., k, :].mean(axis=1)


def halton(n: int, d: int) -> np.ndarray:
    """The first ``n`` points of the Halton sequence in d <= 6 dimensions, in [0, 1)^d."""
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


def grid_points(problem: Problem) -> np.ndarray:
    """The coarse grid in z (GRID, d): a lattice of cell centres (Halton points for more than
    two free variables), the start design in place of the point nearest to it."""
    d = len(problem.space.names)
    levels = _GRID_LEVELS.get(d)
    if levels is None:
        u = halton(GRID, d)
    else:
        axes = [(np.arange(n) + 0.5) / n for n in levels]
        u = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d)
    z = np.log(u / (1 - u))
    start = problem.space.to_z(problem.start, problem.base)
    z[np.argmin(np.sum((z - start) ** 2, axis=1))] = start
    return z


def design_values(problem: Problem, z: np.ndarray) -> dict:
    """Every variable's value (user units) at each z (R, d): numpy arrays (R,)."""
    v = problem.space.values(np.asarray(z), problem.base, xp=np)
    return {k: np.broadcast_to(np.asarray(v[k], dtype=float), z.shape[:-1]) for k in v}


def rates_of(problem: Problem, z, d):
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


class SearchRecord:
    """Every evaluation of a search: designs, stroke volumes and the best so far."""

    def __init__(self, problem: Problem):
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
        designs = design_values(self.problem, z)
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


class _Assessment(NamedTuple):
    """Candidates z (R, d) as the search judges them: residuals (R, K) in ml and their
    derivatives (R, K, d), the secondary objective (R,) and its gradient (R, d), whether each
    was solved (R,) and its root-sum-square residual (R,; inf where not solved)."""

    z: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    objective: np.ndarray
    gradient: np.ndarray
    ok: np.ndarray
    rss: np.ndarray


def _assess(problem: Problem, z, values, jac, ok) -> _Assessment:
    z = np.array(z, dtype=float)
    r, j = residuals(problem, values, jac, rates_of(problem, z, z.shape[1]))
    s, g = secondary_objective(problem, values, jac)
    good = ok.all(axis=1) & np.all(np.isfinite(z), axis=1)
    rss = np.where(good, np.sqrt(np.sum(r**2, axis=1)), np.inf)
    return _Assessment(z, *(np.array(a) for a in (r, j, s, g)), good, rss)


class _Candidates:
    """The refined candidates: the step each has accepted last, its trust radius, how many
    rounds it has stalled, and its path (the z of each accepted step)."""

    def __init__(self, first: _Assessment):
        self.now = first
        n = len(first.z)
        self.radius = np.full(n, RADIUS[0])
        self.stalls = np.zeros(n, int)
        self.paths = [[first.z[i].copy()] for i in range(n)]

    def step_inputs(self):
        """(gradient, z, residual, jacobian, radius) for the optax step; zeros where unsolved."""
        a, ok = self.now, self.now.ok
        return (
            jnp.asarray(np.where(ok[:, None], a.gradient, 0.0)),
            jnp.asarray(a.z),
            jnp.asarray(np.where(ok[:, None], a.residual, 0.0)),
            jnp.asarray(np.where(ok[:, None, None], a.jacobian, 0.0)),
            jnp.asarray(self.radius),
        )

    def feasible(self, tol: float) -> np.ndarray:
        """Solved and every residual within half the tolerance."""
        return self.now.ok & (np.max(np.abs(self.now.residual), axis=1) <= 0.5 * tol)

    def accept(self, new: _Assessment, secondary: bool, tol: float) -> np.ndarray:
        """Keep the trial steps that improve (the residual; with a secondary objective, the
        objective within the targets), widen their radius, shrink the others'; returns which
        were kept."""
        now, tol_in = self.now, 0.5 * tol
        feasible_now = np.max(np.abs(now.residual), axis=1) <= tol_in
        feasible_new = np.max(np.abs(new.residual), axis=1) <= tol_in
        if secondary:
            accept = new.ok & np.where(
                feasible_now,
                feasible_new & (new.objective <= now.objective),
                feasible_new | (new.rss < now.rss),
            )
        else:
            accept = new.ok & (new.rss < now.rss)
        progress = np.where(accept, now.rss - new.rss, 0.0)
        if secondary:  # within the targets, a step is judged by the objective
            progress = np.where(accept & feasible_now, np.inf, progress)
        self.stalls = np.where(progress < _STALL_ML * tol, self.stalls + 1, 0)
        self.radius = np.where(accept, np.minimum(2 * self.radius, RADIUS[1]), self.radius / 4)
        for i in np.flatnonzero(accept):
            for field in ("z", "residual", "jacobian", "objective", "gradient", "rss"):
                getattr(now, field)[i] = getattr(new, field)[i]
            now.ok[i] = True
            self.paths[i].append(new.z[i].copy())
        return accept

    def done(self) -> np.ndarray:
        """Stalled (a radius below the smallest, or no progress for a few rounds) or unsolved."""
        return (self.radius < RADIUS[2]) | (self.stalls >= _STALL_ROUNDS) | (~self.now.ok)


def _round_line(problem, candidates, feasible, secondary, label, rounds, kept, seconds) -> str:
    """The progress line of one round: the best candidate so far."""
    now = candidates.now
    i = (
        int(np.argmin(np.where(feasible, now.objective, np.inf)))
        if secondary and feasible.any()
        else (int(np.argmin(now.rss)))
    )
    x = design_values(problem, now.z[i : i + 1])
    where = ", ".join(f"{LABELS[k]} {x[k][0]:.4g}" for k in problem.space.names)
    worst = np.max(np.abs(now.residual[i]))
    line = f"{label} {rounds:2d}: max |residual| {worst:7.3f} ml at {where}"
    if problem.objective is not None:
        sign = OBJECTIVES[problem.objective]
        line += (
            f"; {problem.objective} {sign * now.objective[i]:.4g} "
            f"{OBJECTIVE_UNITS[problem.objective]}"
        )
    return line + f"; {int(kept.sum())}/{len(now.z)} steps kept ({seconds:.2f} s)"


def refine(problem, evaluate, record, z0, evals, mask, max_rounds, say, label="round", every=False):
    """Refine the candidates z0 (R, d), already evaluated (``evals``); returns (rounds, paths).

    Without a secondary objective it stops when one candidate hits the targets, or with
    ``every`` when each one has hit them or stalled."""
    opt, step = optimiser_step()
    n, d = z0.shape
    secondary = problem.objective is not None and mask.sum() > 0
    candidates = _Candidates(_assess(problem, z0, *evals))
    state = jax.vmap(opt.init)(jnp.asarray(candidates.now.z))
    masks = jnp.asarray(np.broadcast_to(mask, (n, d)), dtype=jnp.result_type(float))
    best_objective = math.inf
    quiet_rounds = 0
    rounds = 0
    for rounds in range(1, max_rounds + 1):
        t0 = time.perf_counter()
        gradient, z, residual, jacobian, radius = candidates.step_inputs()
        trial, state = step(gradient, state, z, residual, jacobian, masks, radius)
        values, jac, ok, _ = evaluate(np.asarray(trial))
        new = _assess(problem, trial, values, jac, ok)
        record.add(new.z, values, ok, new.residual, new.objective)
        kept = candidates.accept(new, secondary, problem.tol)
        feasible = candidates.feasible(problem.tol)
        done = candidates.done()
        if secondary and feasible.any():
            current = float(np.min(candidates.now.objective[feasible]))
            improved = current < best_objective - 1e-4 * abs(best_objective)
            quiet_rounds = 0 if improved else quiet_rounds + 1
            best_objective = min(best_objective, current)
        seconds = time.perf_counter() - t0
        say(_round_line(problem, candidates, feasible, secondary, label, rounds, kept, seconds))
        if not secondary and (np.all(feasible | done) if every else feasible.any()):
            break
        if secondary and feasible.any() and quiet_rounds >= 2 * _STALL_ROUNDS:
            break
        if np.all(done | (secondary & feasible & (candidates.radius < 4 * RADIUS[2]))):
            break
    return rounds, candidates.paths


def select_candidates(problem, z, values, jac, ok, count):
    """The ``count`` best grid candidates (indices)."""
    d = z.shape[1]
    r, j = residuals(problem, values, jac, rates_of(problem, z, d))
    rss = np.where(ok.all(axis=1), np.sum(r**2, axis=1), np.inf)
    if problem.objective is None:
        return np.argsort(rss, kind="stable")[:count]
    s, g = secondary_objective(problem, values, jac)
    predicted = np.full(len(z), np.inf)
    for i in range(len(z)):
        if not np.isfinite(rss[i]):
            continue
        dz = -np.linalg.pinv(j[i]) @ r[i]
        if np.sqrt(np.sum(dz**2)) <= 2 * RADIUS[1]:  # the targets are near: rank by objective
            predicted[i] = s[i] + g[i] @ dz
    order = np.lexsort((rss, predicted))  # by predicted objective, then by residual
    return order[:count]
