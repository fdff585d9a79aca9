"""What accuracy costs in time, for every shipped scene: work-precision tables and diagrams.

    python benchmarks/work_precision.py                  # the four scenes, ~8 min on 2 CPU cores
    python benchmarks/work_precision.py --smoke          # a subset (~3 min): what the tests run
    python benchmarks/work_precision.py --scene lv-systemic --plot wp.png

``notebooks/accuracy.ipynb`` calls the functions of this file and draws the diagrams; the
notebook and the command print the same error tables (the timings differ from run to run).
Asserts nothing about time (DESIGN.md section 4). Follows ``benchmarks/accuracy.py`` (which
does the bench at 60 bpm in more depth): ``EQX_ON_ERROR=nan`` before equinox is imported,
float64, one compile per solver, then the best of repeated calls around
``jax.block_until_ready``, interleaved so that load from other processes falls on all alike.

For each dynamic scene (``bench-dynamic``, ``lv-systemic``, ``rv-pulmonary``):

- every member of the scene (the bench's three afterloads; one circulation) is solved for
  exactly :data:`BEATS` beats from rest by the public batch solve
  (``cardiosoft.solve_beats(..., save="metrics")``), so the error is that of the time
  discretisation alone, not of where a steady-state test stopped;
- the **error** of the dynamic SV (ml) and of the peak force (N) is the largest over the members
  of the difference from a tight **reference** (:data:`REFERENCE`: Dopri8 at rtol 1e-12); the
  reference's own error is bounded by its difference from a second tight solution with the
  scene's preset solver (:data:`CHECK_RTOL`);
- the solvers: Tsit5 and Dopri8 (explicit), and Kvaerno5 (implicit, the library's choice for
  valves) where the scene has valves, each over a sweep of ``rtol`` with ``atol = 1e-3 rtol``;
  the presets ``fast``, ``default``, ``reference`` as ``cardiosoft.run`` uses them (the stiff
  ones for valves); and scipy's ``solve_ivp`` (RK45, LSODA with the jitted Jacobian) on the same
  vector field (``cardiosoft.scene_circuit``), integrated piecewise between the actuation kinks,
  its metrics computed from the last beat sampled at the batch solve's sample times;
- the **time** is the steady wall time of one call for all members (compile excluded); the
  **compile** time of each compiled solve is shown apart (first call minus a steady call).
  Every diffrax setting runs with ``max_steps`` :data:`MAX_STEPS` (the ``reference`` preset's),
  so one compile per solver serves all its tolerances and the presets: ``max_steps`` bounds the
  steps; it does not change the steps taken.

For ``bench-static`` (no ODE: a root find per cable position) the presets play no part; its one
numerical setting is the pull grid, which sets the peak force (the stroke volume and the work
come from the end of the pull and the energy balance, exact to rounding).
"""

from __future__ import annotations

import os

os.environ.setdefault("EQX_ON_ERROR", "nan")  # before equinox/diffrax are imported

import argparse
import dataclasses
import itertools
import math
import textwrap
import time
import timeit
import warnings

import jax

jax.config.update("jax_enable_x64", True)

import diffrax  # noqa: E402
import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.flatten_util import ravel_pytree  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

import cardiosoft  # noqa: E402
from cardiosoft import load_pump, load_scene, preset, scene_circuit, solve_beats  # noqa: E402
from cardiosoft.batch import PULL_SAMPLES, SAMPLES_PER_BEAT, default_config  # noqa: E402
from cardiosoft.scene import SCENE_NAMES  # noqa: E402
from cardiosoft.solve import integrate, solver_name  # noqa: E402
from cardiosoft.static import column_stiffness, quasi_static_stroke  # noqa: E402
from cardiosoft.units import RHO_WATER, G, ml, mmHg  # noqa: E402
from cardiosoft.verify import STATIC_POINTS as LIBRARY_POINTS  # noqa: E402
from cardiosoft.verify import describe, fine_static, verify_run  # noqa: E402

BEATS = 10
"""Beats from rest of every dynamic solve (a run to the steady state takes 6 to 11 here)."""
RTOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
SMOKE_RTOLS = (1e-4, 1e-6, 1e-8)
ATOL_PER_RTOL = 1e-3
"""atol = 1e-3 rtol in the sweeps, as in the presets "default" and "reference"."""
MAX_STEPS = 65536
REFERENCE = ("Dopri8", 1e-12, 1e-15)
"""The tight reference: solver, rtol, atol."""
CHECK_RTOL = 1e-12
"""The reference's check: the scene's preset solver (Tsit5; Kvaerno5 with valves) at this rtol."""
SCIPY_RTOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
SMOKE_SCIPY_RTOLS = (1e-6,)
SCIPY_MAX_NFEV = 400_000
"""A scipy solve that needs more field calls than this (all members together) is stopped."""
SCIPY_CHECK = ("DOP853", 1e-12, 1e-15)
"""scipy's own tight solution, against the reference: the two methods agree (full runs only)."""
STATIC_POINTS = (26, 51, 101, 201, 401, 801, 1601, 3201)
SMOKE_STATIC_POINTS = (101, 401)
STATIC_REFERENCE_POINTS = 12801
TARGET_REL = 1e-4
"""A preset is accurate enough for a scene when the relative error of both the dynamic SV and
the peak force is at most this: a hundredth of the paper's smallest relative SD of the SV
(1.1 ml of 68.7 ml, 1.6 %), a twentieth of that of the peak force (0.2 N of 93.3 N)."""
PRESETS = ("fast", "default", "reference")
VERIFY_BPM = 60.0
VERIFY_TRUTH = (1e-11, 1e-14)
"""The acceptance check of ``--verify``: the true error of the default preset of bench-dynamic at
60 bpm, measured against the reference preset's solver at this rtol, atol."""


# ----------------------------------------------------------------------------------- timing


def first_call(fn) -> float:
    """Seconds of one call (the first: compile + run)."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t0


def best_times(fns: dict, repeat: int) -> dict:
    """Steady seconds per call of each compiled function: the best of ``repeat`` samples.

    ``repeat = 1``: one call each. Otherwise each sample lasts >= 0.2 s (``timeit``'s
    autorange) and the samples of the functions are interleaved (round robin).
    """
    if repeat <= 1:
        return {key: first_call(fn) for key, fn in fns.items()}
    timers, numbers = {}, {}
    for key, fn in fns.items():
        timers[key] = timeit.Timer(lambda fn=fn: jax.block_until_ready(fn()))
        numbers[key] = timers[key].autorange()[0]
    best = dict.fromkeys(fns, math.inf)
    for _ in range(repeat):
        for key in fns:
            best[key] = min(best[key], timers[key].timeit(numbers[key]) / numbers[key])
    return best


# ----------------------------------------------------------------------------------- results


@dataclasses.dataclass
class Point:
    """One numerical setting of one scene: its error and its cost."""

    method: str  # "Tsit5", "Dopri8", "Kvaerno5", "scipy RK45", "scipy LSODA", "quasi-static"
    setting: str  # "rtol 1e-06", "preset default", "401 points", "reference", "check"
    rtol: float | None = None
    atol: float | None = None
    steps: int | None = None  # solver steps of the last beat, summed over the members
    sv: np.ndarray | None = None  # per member (ml)
    force: np.ndarray | None = None  # per member (N)
    ok: bool = True
    seconds: float = math.nan  # one call, all members, compile excluded
    sv_error: float = math.nan  # largest |dSV| over the members against the reference (ml)
    sv_rel: float = math.nan
    force_error: float = math.nan  # N
    force_rel: float = math.nan

    @property
    def kind(self) -> str:
        return "preset" if self.setting.startswith("preset") else "sweep"


@dataclasses.dataclass
class Study:
    """Work-precision of one scene (module docstring)."""

    scene: str
    members: tuple[str, ...]
    beats: int  # 0 for the static scene
    reference: str
    points: list[Point]
    compile_seconds: dict  # method -> s
    reference_error: tuple[float, float] = (math.nan, math.nan)  # (ml, N): bound of its error
    notes: list[str] = dataclasses.field(default_factory=list)

    def sweep(self, method: str) -> list[Point]:
        return [p for p in self.points if p.method == method and p.setting.startswith("rtol")]

    def preset(self, name: str) -> Point | None:
        return next((p for p in self.points if p.setting == f"preset {name}"), None)

    @property
    def methods(self) -> list[str]:
        return list(dict.fromkeys(p.method for p in self.points if p.setting.startswith("rtol")))


def score(points, ref_sv, ref_force) -> None:
    """Fill in the errors of ``points`` against the reference values (per member)."""
    for p in points:
        if p.sv is None or not p.ok:
            continue
        d_sv, d_f = np.abs(p.sv - ref_sv), np.abs(p.force - ref_force)
        p.sv_error, p.sv_rel = float(d_sv.max()), float((d_sv / np.abs(ref_sv)).max())
        p.force_error, p.force_rel = float(d_f.max()), float((d_f / np.abs(ref_force)).max())


# ----------------------------------------------------------------------------- dynamic scenes


def solver_config(scene, method: str, rtol: float, atol: float):
    """A :class:`cardiosoft.SolverConfig` of ``method`` in forward mode, as ``run()`` builds them.

    Kvaerno5 is the library's stiff preset (Newton root finder, PID 0.3/0.4); Tsit5 and Dopri8
    use the plain I controller of the non-stiff presets.
    """
    if method == "Kvaerno5":
        base = preset("default", stiff=True)
    else:
        base = dataclasses.replace(preset("default"), solver=getattr(diffrax, method)())
    return dataclasses.replace(
        base, rtol=rtol, atol=atol, max_steps=MAX_STEPS, adjoint=diffrax.ForwardMode()
    )


def preset_config(scene, name: str):
    """The configuration ``run()`` uses for ``scene`` at preset ``name`` (``max_steps`` raised)."""
    config = default_config(scene.replace(accuracy=name))
    return dataclasses.replace(config, max_steps=MAX_STEPS)


def solvers(scene, smoke: bool) -> tuple[str, ...]:
    """The solvers that make sense for ``scene``; with ``smoke``, its preset solver and Dopri8."""
    own = solver_name(default_config(scene))
    every = ("Tsit5", "Dopri8", "Kvaerno5") if scene.has("valves") else ("Tsit5", "Dopri8")
    return tuple(m for m in every if not smoke or m in (own, REFERENCE[0]))


def _beat_stats(out) -> dict:
    return {
        "sv": np.asarray(out.metrics.stroke_volume) / ml,
        "force": np.asarray(out.metrics.peak_force),
        "steps": int(np.asarray(out.num_steps).sum()),
        "ok": bool(np.all(np.asarray(out.succeeded))),
    }


def study_dynamic(name: str, *, smoke: bool = False, pump=None, repeat: int = 3) -> Study:
    scene = load_scene(name)
    pump = load_pump() if pump is None else pump
    heads = np.asarray(scene.afterloads) if scene.afterload.has_heads else None
    members = tuple(f"{h / mmHg:g} mmHg" for h in heads) if heads is not None else (scene.name,)

    def call(config):
        return lambda: solve_beats(
            scene,
            afterload=heads,
            beats=BEATS,
            save="metrics",
            pump=pump,
            config=config,
        )

    configs = {}  # (method, setting) -> config
    for method in solvers(scene, smoke):
        for rtol in SMOKE_RTOLS if smoke else RTOLS:
            atol = ATOL_PER_RTOL * rtol
            configs[method, f"rtol {rtol:.0e}"] = solver_config(scene, method, rtol, atol)
    for p in PRESETS:
        config = preset_config(scene, p)
        configs[solver_name(config), f"preset {p}"] = config
    ref_method, ref_rtol, ref_atol = REFERENCE
    configs[ref_method, "reference"] = solver_config(scene, ref_method, ref_rtol, ref_atol)
    own = solver_name(default_config(scene))
    configs[own, "check"] = solver_config(scene, own, CHECK_RTOL, CHECK_RTOL * ref_atol / ref_rtol)

    compile_seconds, points, calls = {}, [], {}
    for (method, setting), config in configs.items():
        fn = calls[method, setting] = call(config)
        if method not in compile_seconds:  # the first call of this solver compiles it
            compile_seconds[method] = first_call(fn)
        s = _beat_stats(fn())
        points.append(
            Point(
                method,
                setting,
                float(config.rtol),
                float(config.atol),
                s["steps"],
                s["sv"],
                s["force"],
                s["ok"],
            )
        )
    # a failed setting (max_steps reached) is timed once: it is slow and its time is moot
    failed = {(p.method, p.setting) for p in points if not p.ok}
    times = best_times({k: f for k, f in calls.items() if k not in failed}, repeat)
    times |= best_times({k: calls[k] for k in failed}, 1)
    for p in points:
        p.seconds = times[p.method, p.setting]
    for method in compile_seconds:  # first call minus a steady call of the same setting
        first = next(p for p in points if p.method == method)
        compile_seconds[method] = max(compile_seconds[method] - first.seconds, 0.0)

    ref = next(p for p in points if p.setting == "reference")
    check = next(p for p in points if p.setting == "check")
    if not ref.ok:
        raise RuntimeError(f"{name}: the reference solve failed")
    score(points, ref.sv, ref.force)
    study = Study(
        name,
        members,
        BEATS,
        f"{ref_method}, rtol {ref_rtol:.0e}, atol {ref_atol:.0e}",
        points,
        compile_seconds,
        (check.sv_error, check.force_error) if check.ok else (math.nan, math.nan),
    )
    study.points += scipy_points(
        scene, pump, heads, ref, SMOKE_SCIPY_RTOLS if smoke else SCIPY_RTOLS, not smoke, repeat
    )
    return study


# ----------------------------------------------------------------------------------- scipy


class _TooManyCalls(Exception):
    pass


def _save_times(period, pull_fraction) -> np.ndarray:
    """One beat's sample times, as the batch solve takes them (the first PULL_SAMPLES: the pull)."""
    t_pull = pull_fraction * period
    pull = np.linspace(0.0, 1.0, PULL_SAMPLES) * t_pull
    n_rest = SAMPLES_PER_BEAT - PULL_SAMPLES
    rest = t_pull + np.linspace(0.0, 1.0, n_rest + 1)[1:] * (period - t_pull)
    return np.concatenate([pull, rest])


class ScipyMember:
    """One member's vector field for ``solve_ivp``: flattened, jitted, numpy in and out."""

    def __init__(self, scene, pump, head):
        circuit = scene_circuit(scene, pump, head)
        y0, unravel = ravel_pytree(circuit.init())
        self.i_volume = int(unravel(jnp.arange(y0.size, dtype=y0.dtype))["volume"])
        self.y0 = np.asarray(y0)

        def flat(t, x):
            return ravel_pytree(circuit(t, unravel(x)))[0]

        self._f = jax.jit(flat)
        self._jac = jax.jit(jax.jacfwd(flat, argnums=1))
        self._force = jax.jit(jax.vmap(lambda t, x: circuit.signals(t, unravel(x))["cable_force"]))
        self.period = float(circuit.actuation.period)
        self.kinks = np.unique(np.asarray(circuit.actuation.kink_times(BEATS)))
        self.ts = _save_times(self.period, float(circuit.actuation.pull_fraction))
        self.nfev = 0
        self.fun(0.0, self.y0), self.jac(0.0, self.y0)  # compile
        self._force(self.ts[:PULL_SAMPLES], np.tile(self.y0, (PULL_SAMPLES, 1)))

    def fun(self, t, x):
        self.nfev += 1
        if self.nfev > SCIPY_MAX_NFEV:
            raise _TooManyCalls
        return np.asarray(self._f(t, x))

    def jac(self, t, x):
        return np.asarray(self._jac(t, x))

    def solve(self, method: str, rtol: float, atol: float):
        """``BEATS`` beats from rest: (SV ml, peak force N, steps of the last beat) or None."""
        kw = {"jac": self.jac} if method in ("LSODA", "BDF", "Radau") else {}
        self.nfev = 0
        with warnings.catch_warnings():  # RK45's trial steps on the valve scenes overflow
            warnings.simplefilter("ignore", RuntimeWarning)  # (rejected and retried: harmless)
            return self._solve(method, rtol, atol, kw)

    def _solve(self, method, rtol, atol, kw):
        y, last_steps = self.y0, 0
        start_last = (BEATS - 1) * self.period
        samples = []
        try:
            for a, b in itertools.pairwise(self.kinks):
                last = a >= start_last - 1e-12 * self.period
                sol = solve_ivp(
                    self.fun,
                    (a, b),
                    y,
                    method=method,
                    rtol=rtol,
                    atol=atol,
                    dense_output=last,
                    **kw,
                )
                if not sol.success:
                    return None
                y = sol.y[:, -1]
                if last:
                    last_steps += sol.t.size - 1
                    tau = self.ts + start_last
                    inside = (
                        (tau >= a) & (tau <= b)
                        if b >= BEATS * self.period - 1e-12
                        else ((tau >= a) & (tau < b))
                    )
                    if inside.any():
                        samples.append((tau[inside], sol.sol(tau[inside]).T))
        except _TooManyCalls:
            return None
        ts = np.concatenate([s[0] for s in samples])
        ys = np.concatenate([s[1] for s in samples])
        volume = ys[:, self.i_volume]
        force = np.asarray(self._force(ts[:PULL_SAMPLES], ys[:PULL_SAMPLES]))
        return (volume.max() - volume.min()) / ml, float(force[np.argmax(force)]), last_steps


def scipy_points(scene, pump, heads, ref: Point, rtols, check: bool, repeat: int) -> list[Point]:
    """RK45 and LSODA over ``rtols`` (and DOP853 tight when ``check``), every member in turn."""
    # a Windkessel scene ignores the head; scene_circuit(scene, pump) would index its empty
    # afterloads, so a head is passed all the same
    members = [ScipyMember(scene, pump, h) for h in (heads if heads is not None else [0.0])]
    runs = [("RK45", r, ATOL_PER_RTOL * r) for r in rtols]
    runs += [("LSODA", r, ATOL_PER_RTOL * r) for r in rtols]
    if check:
        runs.append(SCIPY_CHECK)
    points = []
    for method, rtol, atol in runs:

        def once(method=method, rtol=rtol, atol=atol):
            return [m.solve(method, rtol, atol) for m in members]

        t0 = time.perf_counter()
        out = once()
        seconds = time.perf_counter() - t0
        ok = all(o is not None for o in out)
        if ok and repeat > 1 and seconds < 2.0:  # the best of a few, when they are quick
            seconds = min([seconds, *(first_call(once) for _ in range(repeat - 1))])
        setting = "check" if (method, rtol, atol) == SCIPY_CHECK else f"rtol {rtol:.0e}"
        points.append(
            Point(
                f"scipy {method}",
                setting,
                rtol,
                atol,
                sum(o[2] for o in out) if ok else None,
                np.array([o[0] for o in out]) if ok else None,
                np.array([o[1] for o in out]) if ok else None,
                ok,
                seconds,
            )
        )
    score(points, ref.sv, ref.force)
    return points


# ------------------------------------------------------------------------------ static scene


@eqx.filter_jit
def _static_curves(pump, omega, strokes, heads, k, n_points: int):
    """Quasi-static pulls of the members on ``n_points``: (SV m^3, force curve N per point)."""

    def one(stroke, head):
        out = quasi_static_stroke(pump, omega, stroke, head, k, n_points=n_points)
        return out.stroke_volume, out.force

    return jax.vmap(one)(strokes, heads)


def study_static(name: str, *, smoke: bool = False, pump=None, repeat: int = 3) -> Study:
    """The quasi-static scene: the peak force's error against the pull grid.

    The quasi-static volume at a cable position is a root find there, whatever the grid, and
    every grid studied is a subset of the reference grid (its points minus 1 divide
    ``STATIC_REFERENCE_POINTS - 1``). So one solve on the reference grid gives the peak force on
    every grid (the largest force on its points) and the errors do not depend on ``smoke``. The
    time of each grid is that of the library's solve on it (:func:`cardiosoft.verify.fine_static`,
    one compile per grid), measured only without ``smoke``.
    """
    scene = load_scene(name)
    pump = load_pump() if pump is None else pump
    heads = np.asarray(scene.afterloads)
    members = tuple(f"{h / mmHg:g} mmHg" for h in heads)
    n_ref = STATIC_REFERENCE_POINTS
    grids = [*(SMOKE_STATIC_POINTS if smoke else STATIC_POINTS), n_ref]
    assert all((n_ref - 1) % (n - 1) == 0 for n in grids), "grids must nest in the reference"
    k = column_stiffness(0.25 * np.pi * scene.column_diameter**2, RHO_WATER, G)
    friction = np.exp(scene.cable_friction) if scene.has("cable_friction") else 1.0
    stroke = scene.shortening * pump.cable_length(scene.omega)
    strokes = jnp.full(heads.shape, stroke)
    sv, force = _static_curves(pump, scene.omega, strokes, jnp.asarray(heads), k, n_ref)
    sv, force = np.asarray(sv) / ml, friction * np.asarray(force)

    def peak(n):
        return force[:, :: (n_ref - 1) // (n - 1)].max(axis=1)

    points = [
        Point(
            "quasi-static",
            "reference" if n == n_ref else f"{n} points",
            steps=n,
            sv=sv,
            force=peak(n),
        )
        for n in grids
    ]
    compile_seconds = {}
    if not smoke:  # the library's solve on each grid: one compile each
        calls = {n: (lambda n=n: fine_static(scene, pump, heads, n)) for n in grids}
        for n in grids:
            compile_seconds[f"{n} points"] = first_call(calls[n])
        times = best_times(calls, repeat)
        for p, n in zip(points, grids, strict=True):
            p.seconds = times[n]
            compile_seconds[f"{n} points"] = max(compile_seconds[f"{n} points"] - p.seconds, 0.0)
    ref = points[-1]
    score(points, ref.sv, ref.force)
    # the reference's error: the grid error of a smooth peak falls as 1/n^2; bounded by the
    # grid of half its points
    half = peak((n_ref - 1) // 2 + 1)
    study = Study(
        name,
        members,
        0,
        f"quasi-static pull on {n_ref} points",
        points,
        compile_seconds,
        (0.0, float(np.abs(half - ref.force).max())),
    )
    study.notes.append(
        "no ODE: the presets play no part; the stroke volume and the work come from the end of "
        "the pull and the energy balance, so only the peak force depends on the pull grid "
        f"(the library's is {LIBRARY_POINTS} points)"
    )
    return study


def study(name: str, *, smoke: bool = False, pump=None, repeat: int | None = None) -> Study:
    """The work-precision study of one shipped scene (module docstring)."""
    repeat = (1 if smoke else 3) if repeat is None else repeat
    if load_scene(name).static:
        return study_static(name, smoke=smoke, pump=pump, repeat=repeat)
    return study_dynamic(name, smoke=smoke, pump=pump, repeat=repeat)


# ------------------------------------------------------------------------- recommendation


def recommend(s: Study) -> tuple[str, str]:
    """(preset, why): the cheapest preset whose SV and peak-force errors are within TARGET_REL.

    Cheapest by the presets' order (fast, default, reference: tighter tolerances, more steps),
    so the choice does not depend on timings.
    """
    if s.beats == 0:
        p = next(p for p in s.points if p.setting == f"{LIBRARY_POINTS} points")
        return (
            "any (no ODE)",
            f"the presets play no part; the library's pull grid of {LIBRARY_POINTS} "
            f"points gives the peak force within {p.force_error:.1e} N "
            f"({p.force_rel:.0e} relative) and the static SV exactly",
        )
    for name in PRESETS:
        p = s.preset(name)
        if p.ok and p.sv_rel <= TARGET_REL and p.force_rel <= TARGET_REL:
            break
    else:
        return "none", f"no preset reaches {TARGET_REL:.0e} relative error"
    why = [
        f"{name} ({p.method}, rtol {p.rtol:.0e}): SV within {p.sv_error:.1e} ml "
        f"({p.sv_rel:.0e}), peak force within {p.force_error:.1e} N ({p.force_rel:.0e})"
    ]
    for cheaper in PRESETS[: PRESETS.index(name)]:
        c = s.preset(cheaper)
        why.append(
            f"{cheaper} is not enough: "
            + (
                "it fails"
                if not c.ok
                else f"SV {c.sv_error:.1e} ml ({c.sv_rel:.0e}), "
                f"peak force {c.force_error:.1e} N ({c.force_rel:.0e})"
            )
        )
    return name, "; ".join(why)


# ----------------------------------------------------------------------------------- tables


def _e(x, spec=".1e") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def error_table(studies) -> str:
    """Errors and steps of every setting of every scene: deterministic (no timings).

    One line per setting, each naming its scene and method, so that any line can be compared
    on its own (the notebook test compares a smoke run's lines with the stored full run's).
    """
    head = (
        f"{'scene':<14} {'method':<12} {'setting':<16} {'rtol':>6} {'atol':>6} {'steps':>6} "
        f"{'|dSV| ml':>9} {'rel':>8} {'|dF| N':>9} {'rel':>8}"
    )
    lines = [head]
    for s in studies:
        for p in s.points:
            if p.setting == "reference":
                continue
            cells = f"{p.rtol:>6.0e} {p.atol:>6.0e}" if p.rtol is not None else f"{'-':>6} {'-':>6}"
            errors = (
                f"{_e(p.sv_error):>9} {_e(p.sv_rel):>8} {_e(p.force_error):>9} {_e(p.force_rel):>8}"
                if p.ok
                else f"{'failed':>9}"
            )
            lines.append(
                f"{s.scene:<14} {p.method:<12} {p.setting:<16} {cells} "
                f"{_e(p.steps, 'd'):>6} {errors}"
            )
    return "\n".join(lines)


def reference_table(studies) -> str:
    """Each scene's reference and the bound of its own error (deterministic)."""
    lines = []
    for s in studies:
        d_sv, d_f = s.reference_error
        what = (
            f"against the scene's preset solver at rtol {CHECK_RTOL:.0e}"
            if s.beats
            else "against half its points"
        )
        lines.append(
            f"{s.scene:<14} reference {s.reference}"
            + (f", {s.beats} beats from rest" if s.beats else "")
            + f"; members {', '.join(s.members)}; its error: |dSV| {_e(d_sv)} ml, "
            f"|dF| {_e(d_f)} N ({what})"
        )
        lines += [f"{s.scene:<14} note: {n}" for n in s.notes]
    return "\n".join(lines)


def timing_table(studies) -> str:
    """Compile and run times (vary from run to run and machine to machine)."""
    lines = [f"{'scene':<14} {'method':<12} {'setting':<16} {'run ms':>9} {'/default':>9}"]
    for s in studies:
        default = s.preset("default")
        for p in s.points:
            ratio = p.seconds / default.seconds if default is not None else math.nan
            lines.append(
                f"{s.scene:<14} {p.method:<12} {p.setting:<16} {_e(1e3 * p.seconds, '.2f'):>9} "
                f"{_e(ratio, '.2f'):>9}"
            )
    lines.append("compile (first call minus a steady call), s:")
    for s in studies:
        lines.append(
            f"{s.scene:<14} " + ", ".join(f"{k} {v:.1f}" for k, v in s.compile_seconds.items())
        )
    return "\n".join(lines)


def recommendation_table(studies) -> str:
    """Which preset each scene should default to, and why (deterministic)."""
    lines = [
        f"target: relative error of the dynamic SV and of the peak force <= {TARGET_REL:.0e}, "
        f"after {BEATS} beats from rest; the cheapest preset that reaches it:"
    ]
    for s in studies:
        name, why = recommend(s)
        shipped = load_scene(s.scene).accuracy
        lines.append(f"{s.scene:<14} {name:<10} (shipped: {shipped}) {why}")
    return "\n".join(lines)


def fastest_table(studies) -> str:
    """Per scene, the fastest setting that reaches TARGET_REL (timings: varies)."""
    lines = []
    for s in studies:
        good = [
            p
            for p in s.points
            if p.ok
            and p.sv_rel <= TARGET_REL
            and p.force_rel <= TARGET_REL
            and p.setting not in ("reference", "check")
            and math.isfinite(p.seconds)
        ]
        if not good:
            timed = any(math.isfinite(p.seconds) for p in s.points)
            what = "nothing reaches the target" if timed else "not timed"
            lines.append(f"{s.scene:<14} {what}")
            continue
        best = min(good, key=lambda p: p.seconds)
        lines.append(
            f"{s.scene:<14} fastest within the target: {best.method} {best.setting} "
            f"({1e3 * best.seconds:.1f} ms, SV {_e(best.sv_error)} ml, F {_e(best.force_error)} N)"
        )
        scipy = [p for p in good if p.method.startswith("scipy")]
        if scipy and not best.method.startswith("scipy"):
            other = min(scipy, key=lambda p: p.seconds)
            lines.append(
                f"{s.scene:<14}   scipy's fastest within it: {other.method} {other.setting} "
                f"({1e3 * other.seconds:.1f} ms, {other.seconds / best.seconds:.1f}x)"
            )
    return "\n".join(lines)


# --------------------------------------------------------------------------------- diagrams


STYLE = {
    "Tsit5": ("C0", "o", "-"),
    "Dopri8": ("C1", "s", "-"),
    "Kvaerno5": ("C2", "D", "-"),
    "scipy RK45": ("C3", "v", "--"),
    "scipy LSODA": ("C4", "^", "--"),
    "quasi-static": ("C0", "o", "-"),
}


def plot_study(s: Study, axes) -> None:
    """Work-precision diagram of one scene on two axes: |dSV| and |dF| against run time."""
    from matplotlib.ticker import NullFormatter

    keys = (("sv_error", "dynamic SV", "ml"), ("force_error", "peak force", "N"))
    if s.beats == 0:
        keys = (("force_error", "peak force (quasi-static)", "N"),) * 2
    for ax, (key, what, unit) in zip(axes, keys, strict=True):
        for method in dict.fromkeys(p.method for p in s.points):
            pts = [
                p
                for p in s.points
                if p.method == method
                and p.ok
                and p.setting not in ("reference", "check")
                and not p.setting.startswith("preset")
                and getattr(p, key) > 0
            ]
            if not pts:
                continue
            color, marker, ls = STYLE.get(method, ("k", "x", "-"))
            ax.loglog(
                [p.seconds for p in pts],
                [getattr(p, key) for p in pts],
                marker=marker,
                ls=ls,
                color=color,
                label=method if s.beats else "pull grid (points)",
                ms=4,
            )
            if s.beats == 0:
                for p in pts:
                    ax.annotate(
                        p.setting.split()[0],
                        (p.seconds, getattr(p, key)),
                        fontsize=7,
                        xytext=(3, 3),
                        textcoords="offset points",
                    )
        for name in PRESETS:
            p = s.preset(name)
            if p is None or not p.ok or getattr(p, key) <= 0:
                continue
            ax.loglog(p.seconds, getattr(p, key), "*", color="k", ms=11, mfc="none")
            ax.annotate(
                name,
                (p.seconds, getattr(p, key)),
                fontsize=8,
                xytext=(5, -10),
                textcoords="offset points",
            )
        floor = s.reference_error[0 if key == "sv_error" else 1]
        if math.isfinite(floor) and floor > 0:
            ax.axhline(floor, color="0.5", ls=":", lw=1, label="reference's own error")
        failed = [p for p in s.points if not p.ok]
        title = f"{s.scene}: {what}"
        if failed:
            title += f" ({len(failed)} failed, not shown)"
        ax.set(xlabel="wall time of one call, all members [s]", ylabel=f"|error| [{unit}]")
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.xaxis.set_minor_formatter(NullFormatter())
    axes[0].legend(fontsize=7)
    if s.beats == 0:
        axes[1].axis("off")
        axes[1].text(0.0, 0.5, "\n".join(textwrap.wrap(s.notes[0], 50)), fontsize=9, va="center")


# ------------------------------------------------------------------------- explicit stalls


def stall_diagnosis(name: str, method: str = "Tsit5", rtol: float = 1e-6, pump=None) -> dict:
    """Where an explicit solver stops on a valve scene, and why: beat by beat from rest.

    Integrates the scene's one member beat by beat, as the batch solve does (each beat in its
    phase over [0, 1], the kinks as ``jump_ts``), with at most 4096 steps a beat; at the first
    beat that fails, takes the state at the last time it reached and tries one step of the
    solver from there, of several sizes: is its error estimate finite?
    """
    pump = load_pump() if pump is None else pump
    scene = load_scene(name)
    circuit = scene_circuit(scene, pump, 0.0)  # a Windkessel scene ignores the head
    period = circuit.actuation.period
    config = dataclasses.replace(
        solver_config(scene, method, rtol, ATOL_PER_RTOL * rtol), max_steps=4096
    )

    def field(s, y, args):
        return jax.tree_util.tree_map(lambda d: period * d, circuit(s * period, y))

    ts = jnp.linspace(0.0, 1.0, 2001)
    y = circuit.init()
    steps = []
    for beat in range(1, BEATS + 1):
        sol = integrate(
            field,
            y,
            0.0,
            1.0,
            ts=ts,
            jump_ts=circuit.actuation.kink_times(1) / period,
            config=config,
        )
        steps.append(int(sol.stats["num_steps"]))
        if not diffrax.is_successful(sol.result):
            volume = np.asarray(sol.ys["volume"])
            i = int(np.flatnonzero(np.isfinite(volume))[-1])
            y_i = jax.tree_util.tree_map(lambda a, i=i: a[i], sol.ys)
            term = diffrax.ODETerm(field)
            trials = []
            for dt in (1e-3, 1e-2, 3e-2, 1e-1, 3e-1):
                s0 = ts[i]
                state = config.solver.init(term, s0, s0 + dt, y_i, None)
                _, y_err, _, _, _ = config.solver.step(
                    term, s0, s0 + dt, y_i, None, state, made_jump=False
                )
                leaves = jax.tree_util.tree_leaves(y_err)
                trials.append((dt, bool(all(np.all(np.isfinite(a)) for a in leaves))))
            return {
                "scene": name,
                "setting": f"{method}, rtol {rtol:.0e}",
                "failed_beat": beat,
                "steps": steps,
                "rejected": int(sol.stats["num_rejected_steps"]),
                "phase": float(ts[i]),
                "pull_mm": float(circuit.actuation(ts[i] * period)) / 1e-3,
                "trials": trials,
            }
        y = jax.tree_util.tree_map(lambda a: a[-1], sol.ys)
    return {
        "scene": name,
        "setting": f"{method}, rtol {rtol:.0e}",
        "failed_beat": None,
        "steps": steps,
    }


def stall_text(d: dict) -> str:
    if d["failed_beat"] is None:
        return f"{d['scene']}, {d['setting']}: no beat failed (steps {d['steps']})"
    finite = ", ".join(f"{dt:g}: {'finite' if ok else 'NOT finite'}" for dt, ok in d["trials"])
    before = (
        f"beats 1-{d['failed_beat'] - 1} take {'/'.join(map(str, d['steps'][:-1]))} steps; "
        if d["failed_beat"] > 1
        else ""
    )
    return (
        f"{d['scene']}, {d['setting']}: {before}beat {d['failed_beat']} reaches phase "
        f"{d['phase']:.3f} (pull {d['pull_mm']:.1f} mm), then spends its 4096 steps there, "
        f"{d['rejected']} of them rejected. One step from that state, by size (phase): {finite}"
    )


# ------------------------------------------------------------------ the acceptance of --verify


def verify_check(pump=None) -> dict:
    """``--verify``'s estimate against the true error, bench-dynamic at 60 bpm, default preset.

    The true error: the run's metrics against the same steady-state run with the reference
    preset's solver at :data:`VERIFY_TRUTH` (rtol 1e-11). Returns both per member (ml) and the
    seconds of the run and of the check.
    """
    pump = load_pump() if pump is None else pump
    t0 = time.perf_counter()
    result = cardiosoft.run("bench-dynamic", bpm=VERIFY_BPM, pump=pump)
    run_seconds = time.perf_counter() - t0
    check = verify_run(result, pump=pump)
    scene = result.scene
    config = default_config(scene.replace(accuracy="reference"))
    config = dataclasses.replace(config, rtol=VERIFY_TRUTH[0], atol=VERIFY_TRUTH[1])
    truth = solve_beats(scene, pump=pump, config=config)
    true_sv = np.asarray(truth.metrics.stroke_volume) / ml
    rows = []
    for i, (m, v) in enumerate(zip(result.members, check.members, strict=True)):
        run_sv = m.metrics["stroke_volume"] / ml
        rows.append(
            {
                "member": m.label,
                "estimate": v["metrics"]["dynamic_sv_ml"]["difference"],
                "true": run_sv - float(true_sv[i]),
                "beats": (m.beats, v["reference_beats"], int(truth.beats[i])),
            }
        )
    return {
        "rows": rows,
        "run": describe(default_config(scene)),
        "reference": check.reference_setting,
        "truth": describe(config),
        "run_seconds": run_seconds,
        "check_seconds": check.seconds,
        "check": check,
    }


def verify_table(v: dict) -> str:
    """The acceptance of ``--verify`` in one table (deterministic; no timings)."""
    lines = [
        f"bench-dynamic at {VERIFY_BPM:g} bpm, the run at {v['run']}",
        f"--verify's estimate: the difference from {v['reference']}",
        f"true error: the difference from {v['truth']} (the same steady-state stopping)",
        f"{'member':<8} {'estimate ml':>12} {'true ml':>12} {'ratio':>7} "
        f"{'beats run/ref/true':>19}",
    ]
    for r in v["rows"]:
        ratio = abs(r["estimate"]) / abs(r["true"]) if r["true"] else math.inf
        lines.append(
            f"{r['member']:<8} {r['estimate']:>+12.2e} {r['true']:>+12.2e} {ratio:>7.2f} "
            f"{'/'.join(map(str, r['beats'])):>19}"
        )
    return "\n".join(lines)


def verify_ratios(v: dict) -> np.ndarray:
    return np.array([abs(r["estimate"]) / abs(r["true"]) for r in v["rows"]])


# -------------------------------------------------------------------------------------- main


def header() -> str:
    import equinox
    import scipy

    return (
        f"machine: os.cpu_count() = {os.cpu_count()}, jax.devices() = {jax.devices()}, "
        f"float64 = {jax.config.jax_enable_x64}, load average {os.getloadavg()[0]:.2f}\n"
        f"jax {jax.__version__}, diffrax {diffrax.__version__}, equinox {equinox.__version__}, "
        f"scipy {scipy.__version__}, cardiosoft {cardiosoft.__version__}"
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python benchmarks/work_precision.py",
        description="Work-precision of the shipped scenes: error of the dynamic SV and peak "
        "force against wall time, per solver, preset and tolerance.",
    )
    p.add_argument("--scene", action="append", choices=SCENE_NAMES, help="(repeatable)")
    p.add_argument("--smoke", action="store_true", help="a subset: fewer solvers, tolerances")
    p.add_argument("--no-verify", action="store_true", help="skip the --verify acceptance check")
    p.add_argument("--plot", metavar="PNG", help="also draw the diagrams to this file")
    args = p.parse_args(argv)
    t_start = time.perf_counter()
    print(header())
    pump = load_pump()
    studies = []
    for name in args.scene or SCENE_NAMES:
        print(f"... {name}", flush=True)
        studies.append(study(name, smoke=args.smoke, pump=pump))
    print("\nreferences")
    print(reference_table(studies))
    print("\nerrors (largest over the members) and solver steps of the last beat")
    print(error_table(studies))
    print("\nwall time (one call, all members; compile excluded)")
    print(timing_table(studies))
    print("\nrecommended presets")
    print(recommendation_table(studies))
    print(fastest_table(studies))
    if not args.no_verify:
        print("\n--verify: its estimate against the true error")
        v = verify_check(pump)
        print(verify_table(v))
        print(
            f"the run took {v['run_seconds']:.1f} s, the check {v['check_seconds']:.1f} s "
            "(both compile included)"
        )
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(len(studies), 2, figsize=(10, 3.6 * len(studies)), squeeze=False)
        for s, ax in zip(studies, axes, strict=True):
            plot_study(s, ax)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=100)
        print(f"wrote {args.plot}")
    print(f"\ntotal wall time {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
