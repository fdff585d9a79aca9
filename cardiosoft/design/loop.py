"""Design of the soft pumps of a closed circulation (issue 26): which designs give a target
cardiac output with the mean atrial pressures at their targets.

    cardiosoft design --scene tah --target-co 5 --lap 8 --rap 5
    python -m cardiosoft.design --scene soft-lv --target-co 4.5 --lap 10 --free lv.shortening

From Python (float64 on)::

    from cardiosoft.design.loop import optimise_loop
    result = optimise_loop("tah", target_co=5.0, lap=8.0, rap=5.0)
    result.design, result.reached, result.targets

**The problem.** The free variables are numbers of the scene by path (``"lv.omega"``,
``"rv.shortening"``, ``"bpm"``; ``"omega"`` and ``"shortening"`` stand for every pump's),
each in a box: the pump's design range (:data:`cardiosoft.scene.RANGES`) and, for the rate,
:data:`BPM_BOX`. The residuals are weighted least squares in stated units,
``(CO - target) / CO_WEIGHT``, ``(LAP - target) / PRESSURE_WEIGHT``, ``(RAP - target) /
PRESSURE_WEIGHT``: one unit of residual is 0.1 l/min of output or 1 mmHg of mean atrial
pressure, and a target is reached within one unit (the issue's "within 1 mmHg"). At the
periodic steady state a closed loop's outputs are equal on both sides, so one output target
serves both pumps; the two atrial pressures say where the loop's blood sits.

**The method.** Every evaluation is one call of
:func:`cardiosoft.network.loop_batch.solve_loop` on a batch of ``d + 1`` members (``d`` free
variables), the periodic steady state by Newton shooting. Beat after beat from rest takes
50-150 beats on ``tah`` (the systemic veins'
compliance of 60 ml/mmHg leaves a slow mode) and stops 0.01-0.03 mmHg from the orbit in the
left-atrial pressure, a third of what a difference step changes; shooting's batches ran in
0.7-1 s against 1.9-2.5 s (measured on ``tah``'s grid). One program, compiled once:

1. a grid of :data:`GRID_LEVELS` levels per free variable (the start design among the
   candidates), evaluated ``d + 1`` at a time; the first call's Newton starts after
   :data:`GUESS_BEATS` beats from the scene's initial state (from 5, it failed on 10 of the 81
   grid designs of ``tah``), every later call's from the orbit found nearest to each member
   (:meth:`_Evaluator.nearest_starts`);
2. from the grid's best, :func:`scipy.optimize.least_squares` (trust-region reflective, in the
   unit box), its Jacobian from forward differences of step :data:`FD_STEP` (in the unit box)
   taken in the same batched call as the point itself;
3. the answer's records and flags (:func:`cardiosoft.network.loop_results.loop_member_results`) from
   the same orbit, sampled.

**What cannot be reached** is measured, not guessed: every design evaluated is kept, and for
each target the range seen over all of them is reported (:attr:`LoopTarget.seen`); for a
pump's atrial pressure that stays above its target, the pump's own filling limit: its
end-diastolic volume at the answer and the chamber's passive pressure there
(:meth:`~cardiosoft.pump.PumpSurrogate.pressure` at zero pull; the soft pump fills past its
unloaded cavity only by swelling).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import time

import numpy as np

from cardiosoft._validate import check_range
from cardiosoft.network.loop_batch import SIDES, scene_start, solve_loop
from cardiosoft.network.loop_scene import LoopScene, number_key
from cardiosoft.program_store import stored_value
from cardiosoft.scene import RANGES, load_scene
from cardiosoft.scene_tools import check_supported
from cardiosoft.units import ml, mmHg

__all__ = [
    "BPM_BOX",
    "CO_WEIGHT",
    "FD_STEP",
    "FTOL",
    "GRID_LEVELS",
    "PRESSURE_WEIGHT",
    "LoopDesignResult",
    "LoopTarget",
    "loop_free",
    "optimise_loop",
]

CO_WEIGHT = 0.1
"""l/min of cardiac output per unit of residual (2 % of 5 l/min)."""
PRESSURE_WEIGHT = 1.0
"""mmHg of mean atrial pressure per unit of residual."""
BPM_BOX = (40.0, 180.0)
"""The rate's box when it is free (bpm): the rates the closed-loop stress cases cover."""
GRID_LEVELS = (0.2, 0.5, 0.8)
"""The grid's levels, as fractions of each free variable's box; :data:`GRID_LEVELS_MANY` where
these would give more than :data:`GRID_MAX` designs (four free variables: 81)."""
GRID_LEVELS_MANY = (0.25, 0.75)
GRID_MAX = 40
GUESS_BEATS = 30
"""Beats from the scene's initial state before Newton shooting starts (module docstring)."""
MAX_NEWTON = 8
"""Newton's iterations at most (:func:`~cardiosoft.network.loop_batch.solve_loop`). Near the box's
corners it converges linearly (6-16 iterations at Omega 6, C 0.65 on the left of ``tah``), and
on some grid designs it stalls at the integrator's noise, just above its own tolerance (a tenth
of the scene's steady tolerance, 1e-3 ml or mmHg). Stopped at 8, the beats go on from its last
iterate (:func:`~cardiosoft.shooting.shoot_periodic`): at ``tah``'s answer and its difference
points, against beats to 1e-5, the largest error was 4.6e-4 mmHg with 8 as with 16 (CO 9.7e-5
against 7.6e-5 l/min), and tah's search cost 0.14 s an evaluation against 0.17 s (2026-12-07).
When the beats started from the guess instead, 16 were needed: at 8 they ended 0.02 mmHg from
the orbit."""
FD_STEP = 1e-2
"""Forward-difference step in the unit box (0.06 in Omega, 6.5e-3 in C): large enough that
a converged orbit's own error (1e-3 mmHg) is ~1e-2 of the change it makes (0.07 mmHg of LAP
per step in the left pump's C)."""
FTOL = 1e-3
"""The least squares stop when a step lowers the sum of squared residuals by less than this
fraction of it (:func:`scipy.optimize.least_squares`' ``ftol``). Where the targets cannot all
be met the answer lies in a flat valley, and how many designs the search takes there depends on
its path: on ``tah``'s 5 l/min, LAP 8, RAP 5, 47-72 over five questions 0.1 mmHg of LAP apart,
the last 30 of 72 lowering the cost by 0.6 % and moving LAP by 0.3 mmHg. At 1e-2 those five
all took 42 designs, but the same question with the rate free stopped after 63 designs at a
cost of 11.5 (LAP 10.6 mmHg at 174 bpm) where 1e-3 goes on to 6.4 in 183 (LAP 9.3 at 180 bpm):
one step's reduction is small also where the trust region has just shrunk (2026-12-07)."""
_STARTS = "start:"
"""The prefix of an evaluation's orbit starts among its observed values (``"start:la.volume"``,
SI), kept with the grid in the store so that a warm search starts from them too."""
_ATRIAL = {"lap": "left", "rap": "right"}
_LABELS = {
    "co": "cardiac output",
    "lap": "mean left-atrial pressure",
    "rap": "mean right-atrial pressure",
}
_UNITS = {"co": "l/min", "lap": "mmHg", "rap": "mmHg"}


@dataclasses.dataclass(frozen=True)
class LoopTarget:
    """One target and what the answer reached (user units)."""

    name: str  # "co", "lap" or "rap"
    target: float
    value: float  # at the answer
    weight: float  # user units per unit of residual
    seen: tuple[float, float]  # the range over every design evaluated to a steady orbit

    @property
    def residual(self) -> float:
        return self.value - self.target

    @property
    def reached(self) -> bool:
        return abs(self.residual) <= self.weight

    @property
    def unit(self) -> str:
        return _UNITS[self.name]


@dataclasses.dataclass(frozen=True)
class LoopDesignResult:
    """The answer of :func:`optimise_loop`."""

    scene: LoopScene  # with the design found
    design: dict  # path -> value (user units: bpm, Omega, C)
    free: tuple[str, ...]
    targets: tuple[LoopTarget, ...]
    run: object  # the answer's RunResult (records, flags, traces)
    limits: tuple[str, ...]  # why each target not reached is out of reach, measured
    evaluations: int
    seconds: float
    compile_seconds: float

    @property
    def reached(self) -> bool:
        return all(t.reached for t in self.targets)

    @property
    def failures(self) -> tuple[str, ...]:
        return tuple(m.message for m in self.run.members if not m.ok)

    @property
    def flags(self) -> tuple[str, ...]:
        unreached = tuple(
            f"{_LABELS[t.name]} {t.value:.2f} {_UNITS[t.name]}, target {t.target:g} not reached "
            f"(within {t.weight:g})"
            for t in self.targets
            if not t.reached
        )
        return unreached + self.limits + tuple(f for m in self.run.members for f in m.flags)

    def to_json(self) -> dict:
        """design.json's record (user units)."""
        from cardiosoft.network.loop_records import loop_summary_records

        return {
            "scene": self.scene.name,
            "design": self.design,
            "free": list(self.free),
            "reached": self.reached,
            "targets": [
                dataclasses.asdict(t)
                | {"residual": t.residual, "reached": t.reached, "unit": _UNITS[t.name]}
                for t in self.targets
            ],
            "limits": list(self.limits),
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "compile_seconds": self.compile_seconds,
            "run": loop_summary_records(self.run)[0],
        }


def loop_free(scene: LoopScene, free) -> tuple[str, ...]:
    """The free variables as paths of ``scene``: ``"omega"`` and ``"shortening"`` stand for
    every pump's, in the order lv, rv; ``ValueError`` naming anything else."""
    if not scene.pumps:
        raise ValueError(f"scene = {scene.name!r} has no soft pump to design")
    free = (free,) if isinstance(free, str) else tuple(free)
    paths = []
    for name in free:
        if name in ("omega", "shortening"):
            paths += [f"{p}.{name}" for p in sorted(scene.pumps)]
            continue
        table, _, field = name.partition(".")
        if name != "bpm" and (table not in scene.pumps or field not in ("omega", "shortening")):
            allowed = ["omega", "shortening", "bpm"]
            allowed += [f"{p}.{f}" for p in sorted(scene.pumps) for f in ("omega", "shortening")]
            raise ValueError(f"free = {name!r}: allowed {', '.join(allowed)} on scene {scene.name}")
        paths.append(name)
    if not paths or len(set(paths)) != len(paths):
        raise ValueError(f"free = {list(free)!r}: allowed distinct names, at least one")
    return tuple(paths)


def _box(path: str) -> tuple[float, float]:
    if path == "bpm":
        return BPM_BOX
    return RANGES[path.partition(".")[2]]


def _targets(target_co, lap, rap) -> dict:
    """{name: value} of the targets, validated (user units). An atrium of a native side is a
    target too: the pumps set where the loop's blood sits."""
    out = {}
    for name, value, lo, hi in (
        ("co", target_co, 0.0, 20.0),
        ("lap", lap, -5.0, 40.0),
        ("rap", rap, -5.0, 40.0),
    ):
        if value is None:
            continue
        value = float(value)
        check_range(_LABELS[name], value, _UNITS[name], lo, hi, lo_open=name == "co")
        out[name] = value
    if "co" not in out:
        raise ValueError("target_co: missing; give the target cardiac output in l/min")
    return out


class _Evaluator:
    """Batched evaluations of the loop at points of the unit box: one compiled program."""

    def __init__(self, scene: LoopScene, free, pump):
        self.scene, self.free, self.pump = scene, free, pump
        self.lo = np.array([_box(p)[0] for p in free])
        self.hi = np.array([_box(p)[1] for p in free])
        self.batch = len(free) + 1
        self.points: list[tuple[dict, dict]] = []  # (design, observed) of every steady orbit
        self.starts: list[tuple[np.ndarray, dict]] = []  # (unit-box point, its orbit's start)
        self.count = 0
        self.compile_seconds = 0.0

    def values(self, x) -> np.ndarray:
        return self.lo + (self.hi - self.lo) * np.asarray(x)

    def solve(self, xs: np.ndarray):
        """The orbits at points ``xs`` (rows, at most ``batch``) of the unit box, each started
        from the nearest orbit found so far (:meth:`nearest_starts`): (solution, observed
        {name: values} per row, with the orbits' starts under :data:`_STARTS` keys)."""
        n = len(xs)
        padded = np.concatenate([xs, np.repeat(xs[-1:], self.batch - n, axis=0)])
        vals = self.values(padded)
        members = {p: vals[:, j] for j, p in enumerate(self.free)}
        t0 = time.perf_counter()
        out = solve_loop(
            self.scene,
            members=members,
            save="traces",
            steady="shooting",
            pump=self.pump,
            guess_beats=GUESS_BEATS,
            max_newton=MAX_NEWTON,
            start=self.nearest_starts(padded),
        )
        if self.count == 0:
            self.compile_seconds = time.perf_counter() - t0
        m = out.metrics
        observed = {
            "co": np.asarray(m.left.net_output) / ml * 60 / 1000,
            "lap": np.asarray(m.left.atrial_mean) / mmHg,
            "rap": np.asarray(m.right.atrial_mean) / mmHg,
        } | {
            f"{_STARTS}{part}.{name}": np.asarray(v)
            for part, values in out.y0.items()
            for name, v in values.items()
        }
        ok = np.asarray(out.succeeded) & np.asarray(out.steady)
        observed = {k: np.where(ok, v, np.nan)[:n] for k, v in observed.items()}
        self.keep(xs, observed, ok[:n])
        self.count += n
        return out, observed

    def nearest_starts(self, xs) -> dict:
        """Per point of ``xs``: the start of the steady orbit kept nearest to it in the unit
        box, or NaN (the scene's initial state) before there is one. A step of the search
        moves the orbit little, so from its neighbour's Newton needs no guess beats and 1-8
        iterations: with the grid kept, soft-lv's search (5 calls) took 1.3 s against 2.1 s
        from the scene's initial state, tah's (72 designs) 4.1 s against 10.3 s, to the same
        cost (2026-12-08)."""
        start = scene_start(len(xs))
        if not self.starts:
            return start
        kept = np.array([x for x, _ in self.starts])
        near = np.argmin(np.linalg.norm(np.asarray(xs)[:, None] - kept[None], axis=-1), axis=1)
        return {
            part: {name: np.array([self.starts[i][1][f"{part}.{name}"] for i in near])
                   for name in values}
            for part, values in start.items()
        }  # fmt: skip

    def keep(self, xs, observed: dict, steady=None) -> None:
        """Keep the ``steady`` orbits (default: the finite rows of ``observed``) at points
        ``xs``: the designs seen, from which a target out of reach is explained
        (:func:`_limits`), and their orbits' starts (:data:`_STARTS` keys)."""
        vals = self.values(xs)
        if steady is None:
            steady = np.all([np.isfinite(v) for v in observed.values()], axis=0)
        starts = {k[len(_STARTS) :]: v for k, v in observed.items() if k.startswith(_STARTS)}
        for i in np.flatnonzero(steady):
            design = {p: float(vals[i, j]) for j, p in enumerate(self.free)}
            found = {k: float(v[i]) for k, v in observed.items() if not k.startswith(_STARTS)}
            self.points.append((design, found))
            if starts:
                start = {k: float(v[i]) for k, v in starts.items()}
                self.starts.append((np.asarray(xs[i]), start))


def _residuals(observed: dict, targets: dict) -> np.ndarray:
    """Rows: points; columns: the weighted residuals in the order of ``targets``."""
    weights = {"co": CO_WEIGHT, "lap": PRESSURE_WEIGHT, "rap": PRESSURE_WEIGHT}
    return np.stack([(observed[k] - v) / weights[k] for k, v in targets.items()], axis=-1)


def _levels(d: int) -> tuple[float, ...]:
    return GRID_LEVELS if len(GRID_LEVELS) ** d <= GRID_MAX else GRID_LEVELS_MANY


def _grid(ev: _Evaluator, start_x, targets) -> tuple[np.ndarray, bool]:
    """The grid's best point (least sum of squared residuals) in the unit box, and whether the
    grid's orbits were kept from an earlier search. They depend on the scene, the free
    variables, the start and the surrogate, not on the targets: a later question of other
    targets starts from them, in this process and, in a command's, from its store
    (:func:`cardiosoft.program_store.stored_value`; ``tah``'s warm design 10.4 -> 8.1 s)."""
    levels = itertools.product(_levels(len(ev.free)), repeat=len(ev.free))
    points = np.array([np.asarray(start_x), *levels])
    computed = []

    def compute() -> dict:
        computed.append(True)
        calls = [ev.solve(points[i : i + ev.batch])[1] for i in range(0, len(points), ev.batch)]
        return {k: np.concatenate([c[k] for c in calls]) for k in calls[0]}

    material = (ev.scene, ev.free, ev.pump, points, GUESS_BEATS, MAX_NEWTON, "orbit starts")
    observed = stored_value("closed-loop design grid", material, compute)
    if not computed:  # evaluated all the same, by an earlier search: seen and counted
        ev.keep(points, observed)
        ev.count += len(points)
    cost = np.sum(_residuals(observed, targets) ** 2, axis=-1)
    cost = np.where(np.isfinite(cost), cost, math.inf)
    return points[int(np.argmin(cost))], not computed


def _refine(ev: _Evaluator, x0, targets, max_evaluations: int):
    """Trust-region least squares from ``x0``; the Jacobian of each point from the same call.
    Returns the answer and its solved call (its first row), or None where the answer was
    never evaluated."""
    from scipy.optimize import least_squares

    cache: dict[bytes, tuple[np.ndarray, np.ndarray, object]] = {}

    def at(x):
        key = np.asarray(x).tobytes()
        if key not in cache:
            # step inwards at the upper face, so every point stays in the box
            steps = np.where(x + FD_STEP <= 1.0, FD_STEP, -FD_STEP)
            xs = np.vstack([x, x + np.diag(steps)])
            out, observed = ev.solve(xs)
            r = _residuals(observed, targets)
            r = np.where(np.isfinite(r), r, 1e6)  # a failed orbit: far from every target
            cache[key] = (r[0], ((r[1:] - r[0]) / steps[:, None]).T, (out, observed))
        return cache[key]

    fit = least_squares(
        lambda x: at(x)[0],
        x0,
        jac=lambda x: at(x)[1],
        bounds=(0.0, 1.0),
        method="trf",
        max_nfev=max_evaluations,
        xtol=1e-4,
        ftol=FTOL,
    )
    solved = cache.get(np.asarray(fit.x).tobytes())
    return fit.x, None if solved is None else solved[2]


def _design_text(values: dict) -> str:
    return ", ".join(f"{p} {v:.4g}" for p, v in values.items())


def _limits(ev: _Evaluator, run, found: dict, pump) -> tuple[str, ...]:
    """Why each target not reached is out of reach, measured: the best seen over every
    design evaluated, and where an atrial pressure stays high, the pump's own filling."""
    out = []
    n = len(ev.points)
    for name, t in found.items():
        if t.reached:
            continue
        if t.seen[0] <= t.target <= t.seen[1]:
            out.append(
                f"{_LABELS[name]}: seen on both sides of {t.target:g} {_UNITS[name]} "
                f"({t.seen[0]:.2f}-{t.seen[1]:.2f} over {n} steady designs), but not by a "
                "design that also meets the other targets: the answer is the least-squares "
                "compromise"
            )
            continue
        values = np.array([obs[name] for _, obs in ev.points])
        low = t.value > t.target  # the target lies below what was reached
        i = int(np.nanargmin(values) if low else np.nanargmax(values))
        design, obs = ev.points[i]
        out.append(
            f"{_LABELS[name]}: the {'lowest' if low else 'highest'} over {n} steady designs "
            f"is {values[i]:.2f} {_UNITS[name]} ({_design_text(design)}; cardiac "
            f"output there {obs['co']:.2f} l/min)"
        )
        side = _ATRIAL.get(name)
        chamber = SIDES[side][1] if side else None
        if low and chamber in run.scene.pumps:
            x = run.members[0].metrics
            omega = getattr(run.scene, chamber).omega
            vu = float(pump.unloaded_volume) / ml
            edv, esv = x[f"{side}_edv"], x[f"{side}_esv"]
            passive = float(pump.pressure(edv, 0.0, omega)) / mmHg
            out.append(
                f"the {side} pump ejects from EDV {edv / ml:.1f} to ESV {esv / ml:.1f} ml; it "
                f"fills past its unloaded cavity ({vu:.1f} ml) only by swelling, its chamber's "
                f"passive pressure {passive:.1f} mmHg at that EDV: a stroke this size needs "
                "that filling pressure at the end of diastole"
            )
    return tuple(out)


def optimise_loop(
    scene="tah",
    *,
    target_co,
    lap=None,
    rap=None,
    free=("omega", "shortening"),
    start: dict | None = None,
    max_evaluations: int = 25,
    pump=None,
    progress=None,
) -> LoopDesignResult:
    """Design the soft pumps of a closed-loop scene (module docstring).

    - ``target_co``: cardiac output (l/min); ``lap``, ``rap``: mean left- and right-atrial
      pressures (mmHg), each optional.
    - ``free``: the free variables (:func:`loop_free`); ``start``: their starting values by
      path (default the scene's).
    - ``max_evaluations``: the least-squares iterations at most (each one batched call).
    """
    from cardiosoft.network.loop_results import loop_member_results
    from cardiosoft.pump import load
    from cardiosoft.results import RunResult

    t0 = time.perf_counter()
    say = progress or (lambda _msg: None)
    scene = load_scene(scene) if isinstance(scene, str | os.PathLike) else scene
    check_supported(scene, "loop_design", "optimise_loop")
    free = loop_free(scene, free)
    targets = _targets(target_co, lap, rap)
    check_range("max_evaluations", max_evaluations, "calls", 1, 1000)
    stray = [k for k in (start or {}) if k not in free]
    if stray:
        raise ValueError(f"start[{stray[0]!r}]: not a free variable; free are {', '.join(free)}")
    numbers = {p: _current(scene, p) for p in free} | dict(start or {})
    for p in free:
        number_key(scene, p)
        lo, hi = _box(p)
        check_range(f"start {p}", numbers[p], "bpm" if p == "bpm" else "", lo, hi)
    pump = load(scene.pump) if pump is None else pump
    ev = _Evaluator(scene, free, pump)
    start_x = np.clip((np.array([numbers[p] for p in free]) - ev.lo) / (ev.hi - ev.lo), 0, 1)
    say(
        f"{scene.name}: grid of {len(_levels(len(free))) ** len(free) + 1} designs, "
        f"{ev.batch} per call (compiling first) ..."
    )
    x, kept = _grid(ev, start_x, targets)
    if kept:
        say("the grid's orbits kept from an earlier search")
    say(f"refining (trust-region least squares, {ev.batch} members a call) ...")
    x, solved = _refine(ev, x, targets, max_evaluations)
    # the answer's orbit is that of the call that evaluated it (its first row), not solved again
    out, observed = ev.solve(x[None]) if solved is None else solved
    design = {p: float(v) for p, v in zip(free, ev.values(x), strict=True)}
    answer = scene.with_numbers(design)
    members = loop_member_results(answer, [answer.name], _first(out), pump.domain)
    run = RunResult(answer, members)
    found = {
        k: LoopTarget(
            k,
            v,
            float(observed[k][0]),
            CO_WEIGHT if k == "co" else PRESSURE_WEIGHT,
            _seen(ev, k),
        )
        for k, v in targets.items()
    }
    limits = _limits(ev, run, found, pump)
    return LoopDesignResult(
        answer,
        design,
        free,
        tuple(found.values()),
        run,
        limits,
        ev.count,
        time.perf_counter() - t0,
        ev.compile_seconds,
    )


def _seen(ev: _Evaluator, name: str) -> tuple[float, float]:
    values = [obs[name] for _, obs in ev.points]
    return (min(values, default=math.nan), max(values, default=math.nan))


def _current(scene: LoopScene, path: str) -> float:
    from cardiosoft.network.loop_scene import loop_numbers

    return float(loop_numbers(scene)[path])


def _first(solution):
    """``solution`` cut to its first member (the padded batch's answer)."""
    import jax

    return jax.tree_util.tree_map(
        lambda a: a[:1] if hasattr(a, "shape") and getattr(a, "ndim", 0) > 0 else a, solution
    )
