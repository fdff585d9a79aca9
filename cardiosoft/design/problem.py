"""The design problem: its targets, its free variables and the box they live in.

:func:`build_problem` validates what :func:`cardiosoft.design.optimise` is asked (every bad
input is one ``ValueError`` naming the parameter, its value, unit and allowed range) and returns
a :class:`Problem`: the scene, the :class:`Target` s, the :class:`DesignSpace` of the free
variables (mapped to unconstrained coordinates ``z``), the fixed values and the secondary
objective. Nothing here solves anything.
"""

from __future__ import annotations

import dataclasses
import math
import os

import jax.numpy as jnp
import numpy as np

from cardiosoft._validate import check_range
from cardiosoft.scene import RANGES, Scene, load_scene
from cardiosoft.scene_tools import check_supported

__all__ = [
    "BOX_VARIABLES",
    "DEFAULT_FREE",
    "EDGE",
    "FRACTIONS",
    "FREE_VARIABLES",
    "LABELS",
    "OBJECTIVES",
    "OBJECTIVE_UNITS",
    "TOLERANCE_ML",
    "DesignSpace",
    "Problem",
    "Target",
    "as_values",
    "build_problem",
    "objective_choice",
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
EDGE = 1e-3
"""Where z starts, as a fraction of each range from its ends (logit(1e-3) = -6.9)."""
LABELS = {
    "omega": "Omega",
    "shortening": "C",
    "bpm": "bpm",
    "pull_fraction": "pull",
    "hold_fraction": "hold",
    "release_fraction": "release",
}
"""How each design variable is printed."""


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
class DesignSpace:
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
        """The z of ``design`` (user units), kept :data:`EDGE` inside every range."""
        z = np.zeros(len(self.names))
        budget = 1.0 - sum(base[f] for f in FRACTIONS if f not in self.names)
        rest = budget - sum(design[n] for n in self.names if n in FRACTIONS)
        rest = max(rest, EDGE * budget)
        for j, name in enumerate(self.names):
            if name in BOX_VARIABLES:
                u = (design[name] - self.lo[j]) / (self.hi[j] - self.lo[j])
            else:
                u = design[name] / (design[name] + rest)
            u = float(np.clip(u, EDGE, 1 - EDGE))
            z[j] = math.log(u / (1 - u))
        return z


@dataclasses.dataclass(frozen=True)
class Problem:
    """A validated design problem (:func:`build_problem`)."""

    scene: Scene
    targets: tuple[Target, ...]
    space: DesignSpace
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


def as_values(name: str, value, unit: str) -> np.ndarray:
    """``value`` as a non-empty 1-d float array; ``ValueError`` naming ``name`` otherwise."""
    try:
        arr = np.atleast_1d(np.asarray(value, dtype=float))
    except (TypeError, ValueError):
        raise ValueError(
            f"{name} = {value!r}: allowed a number or a list of numbers ({unit})"
        ) from None
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} = {value!r}: allowed a number or a non-empty list ({unit})")
    return arr


def objective_choice(minimize, maximize) -> str | None:
    """The secondary objective named by ``minimize`` / ``maximize`` (None: none)."""
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


def _free_space(free, bounds) -> DesignSpace:
    """The free variables, in the order of :data:`FREE_VARIABLES`, and their box."""
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
        b = as_values(f"bounds[{name!r}]", b, unit)
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
    return DesignSpace(free, tuple(lo), tuple(hi))


def _targets(scene: Scene, target_sv, target_co, afterload, bpm, bpm_free: bool):
    """(kind, targets, rates): the targets paired up with their afterloads and rates."""
    if (target_sv is None) == (target_co is None):
        raise ValueError("target: give target_sv (ml) or target_co (l/min), one of the two")
    kind = "sv" if target_sv is not None else "co"
    values = as_values(
        "target_sv" if kind == "sv" else "target_co",
        target_sv if kind == "sv" else target_co,
        "ml" if kind == "sv" else "l/min",
    )
    if kind == "sv":
        check_range("target SV", values, "ml", 0.0, math.inf, hi_open=True)
    else:
        check_range("target cardiac output", values, "l/min", 0.0, math.inf, hi_open=True)
    counts = {"target_sv" if kind == "sv" else "target_co": values}
    given = as_values("afterload", afterload, "mmHg") if afterload is not None else None
    heads = scene.column_heads_mmHg(given, action="set")
    if heads is not None:
        counts["afterload"] = np.asarray(heads)
    rates = as_values("bpm", scene.bpm if bpm is None else bpm, "bpm")
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
    return kind, targets, rates


def _base_values(scene: Scene, rates, start, free) -> dict:
    """Every design variable's value (user units): the scene's, the first rate, ``start``."""
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
    return base


def build_problem(
    scene, target_sv, target_co, afterload, bpm, free, start, bounds, minimize, maximize, tol
) -> Problem:
    """Validate a design question (the arguments of :func:`cardiosoft.design.optimise`)."""
    scene = load_scene(scene) if isinstance(scene, str | os.PathLike) else scene
    check_supported(scene, "pump_design", "optimise")
    if scene.static:
        raise ValueError(
            f"scene = {scene.name!r} is static (no beats, no rate): use bench-dynamic or a "
            "dynamic scene"
        )
    check_range("tolerance", tol, "ml", 0.0, math.inf, lo_open=True)
    objective = objective_choice(minimize, maximize)
    space = _free_space(free, bounds)
    kind, targets, rates = _targets(
        scene, target_sv, target_co, afterload, bpm, "bpm" in space.names
    )
    base = _base_values(scene, rates, start, space.names)
    return Problem(scene, targets, space, base, dict(base), objective, float(tol), kind)
