"""Design of the soft pump in a user's svZeroDSolver model (issue #40, "Tools"): the pump's
Omega and C that bring any block's metric to its target.

    cardiosoft design --scene model.json --pump-chamber LV --units si --target-sv 50
    cardiosoft design --scene model.json --pump-chamber LV --units si \\
        --target LV.stroke_volume_ml=50 --target AR_SYS.pressure_mean=9000

From Python (float64 on)::

    from cardiosoft.design.model import optimise_model
    from cardiosoft.network.pump_in_model import PumpPlacement
    result = optimise_model("model.json", PumpPlacement("LV", "si"), {"LV.stroke_volume_ml": 50})

**The metrics** are the records ``simulate --scene model.json --pump-chamber NAME`` prints,
by ``BLOCK.KEY``: the pump's (:func:`~cardiosoft.network.pump_in_model.pump_metrics`:
``NAME.stroke_volume_ml``, ``NAME.peak_force_N``, ``NAME.efficiency``, ...; ml, N, J, mmHg)
and every chamber's and vessel's (:func:`~cardiosoft.network.block_metrics.block_metrics`:
``BLOCK.stroke_volume``, ``BLOCK.pressure_mean``, ...; the model's own units), over the
periodic steady state's beat (:func:`cardiosoft.network.run.simulate` with ``steady``).

**The problem.** The free variables (``omega``, ``shortening`` or both) move in the pump's
design range (:class:`~cardiosoft.pump.Domain`), mapped to the unit box. Each target's residual
is ``(value - target) / (tolerance |target|)``: one unit is :data:`TARGET_TOLERANCE` (1 %) of
the target, and a target is reached within one unit.

**The method.** Every evaluation is one batched call of the network's solve on ``d + 1``
variants of the model (``d`` free variables): one program, compiled once.

1. a grid of :data:`GRID_LEVELS` levels per free variable, and the start design;
2. from the grid's best, :func:`scipy.optimize.least_squares` (trust-region reflective in the
   unit box), its Jacobian from forward differences of :data:`FD_STEP` taken in the same
   batched call as the point itself.

Every design evaluated is kept: a target's range over them (:attr:`ModelTarget.seen`) says,
when it is not reached, how near the pump's design range came.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time
from dataclasses import dataclass

import numpy as np

TARGET_TOLERANCE = 0.01
"""A target is reached within this fraction of its value."""
GRID_LEVELS = 4
"""Grid levels per free variable (the cell centres of the unit box)."""
FD_STEP = 1e-3
"""Forward-difference step in the unit box (its error, ~FD_STEP times the metric's curvature,
is far below a residual unit; the solve's own noise, rtol 1e-6, far below the step's change)."""
MAX_EVALUATIONS = 40
"""The most least-squares evaluations after the grid."""
FREE = ("omega", "shortening")


@dataclass(frozen=True)
class ModelTarget:
    """One target: the metric ``name`` (``BLOCK.KEY``), the value wanted and reached (None if
    the solve failed there), the residual in units of the tolerance, whether it is reached
    and the range the metric took over every design evaluated."""

    name: str
    target: float
    value: float | None
    residual: float | None
    reached: bool
    seen: tuple[float | None, float | None]


@dataclass(frozen=True)
class ModelDesign:
    """The answer: the design (``omega``, ``shortening``), its targets, whether all are
    reached, the records of its beat (:func:`~cardiosoft.network.pump_in_model.
    placed_records`), the pump's flags there, whether its solve succeeded and reached the
    periodic steady state, and the search's cost."""

    model: str
    chamber: str
    design: dict
    targets: list[ModelTarget]
    reached: bool
    records: dict
    pump_flags: list[str]
    solved: bool
    steady: bool
    evaluations: int
    seconds: float
    compile_seconds: float
    evaluated: list[tuple[float, float, list[float]]] = dataclasses.field(default_factory=list)
    """Every design solved: (Omega, C, each target's metric there, NaN where it failed)."""

    @property
    def failures(self) -> list[str]:
        """What makes the answer untrustworthy (exit 1)."""
        if not self.solved:
            return ["the solve at the design found failed"]
        if not self.steady:
            return ["the design found did not reach the periodic steady state"]
        return []

    @property
    def flags(self) -> list[str]:
        """Targets not reached (the closest design is the answer), and the pump's flags."""
        out = [
            f"{t.name}: target {t.target:g} not reached ({t.value:.4g} at the answer; "
            f"{t.seen[0]:.4g} to {t.seen[1]:.4g} over the {self.evaluations} designs solved)"
            for t in self.targets
            if not t.reached and t.value is not None
        ]
        return out + self.pump_flags

    def to_json(self) -> dict:
        """``design.json``'s record (the metrics in their records' units)."""
        return {
            "model": self.model,
            "pump_chamber": self.chamber,
            "design": self.design,
            "reached": self.reached,
            "tolerance": TARGET_TOLERANCE,
            "targets": [dataclasses.asdict(t) for t in self.targets],
            "records": self.records,
            "flags": self.flags,
            "solved": self.solved,
            "steady": self.steady,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "compile_seconds": self.compile_seconds,
        }


def metric_values(records: dict[str, dict]) -> dict[str, float | None]:
    """The records (:func:`~cardiosoft.network.pump_in_model.placed_records`) flat, by
    ``BLOCK.KEY``."""
    return {f"{b}.{k}": v for b, record in records.items() for k, v in record.items()}


def metric_names(model, placement) -> list[str]:
    """Every metric a target can name (the records of a stand-in beat)."""
    from cardiosoft.network.pump_in_model import placed_records
    from cardiosoft.network.run import Traces

    n = model.simulation.points_per_cycle
    ramp = np.linspace(1.0, 2.0, n)
    stand_in = Traces(ramp, {v: ramp for v in model.variables()}, True, None, 0, False)
    with np.errstate(all="ignore"):
        return list(metric_values(placed_records(model, placement, stand_in)))


def optimise_model(
    path,
    placement,
    targets: dict[str, float],
    free=FREE,
    accuracy: str = "default",
    max_evaluations: int = MAX_EVALUATIONS,
    progress=None,
) -> ModelDesign:
    """The design of the pump ``placement`` (:class:`~cardiosoft.network.pump_in_model.
    PumpPlacement`: its chamber, the model's units, the start design and surrogate) in the
    svZeroDSolver model at ``path`` that brings each metric of ``targets`` (``{BLOCK.KEY:
    value}``, :func:`metric_names`) to its value; ``free``: the design variables searched
    (the others stay the placement's). The module docstring says how. ``ValueError`` for an
    unknown metric or free variable, or a model the pump cannot go into."""
    from scipy.optimize import least_squares

    from cardiosoft.network import read, simulate
    from cardiosoft.network.pump_in_model import placed_records, with_designs
    from cardiosoft.pump import Domain

    free = tuple(free)
    unknown = sorted(set(free) - set(FREE))
    if unknown or not free:
        raise ValueError(
            f"--free {' '.join(free) or '(none)'}: a model's pump takes {' and/or '.join(FREE)}"
        )
    if not targets:
        raise ValueError("--target: give at least one, BLOCK.KEY=VALUE (or --target-sv ML)")
    model = read(path, pump=placement)
    names = metric_names(model, placement)
    for name, value in targets.items():
        if name not in names:
            raise ValueError(
                f"--target {name}: the model has no such metric; it has {', '.join(names)}"
            )
        if not math.isfinite(value) or value == 0:
            raise ValueError(f"--target {name}={value}: a finite, non-zero value")
    domain = Domain()
    boxes = {"omega": domain.omega, "shortening": domain.shortening}
    start = {"omega": placement.omega, "shortening": placement.shortening}
    wanted = np.array(list(targets.values()))
    scale = TARGET_TOLERANCE * np.abs(wanted)
    clock = time.perf_counter()
    kept: dict[tuple, tuple[np.ndarray, dict, bool, bool]] = {}
    timings = {"compile": None}

    def design_of(u) -> dict:
        d = dict(start)
        for k, ui in zip(free, u, strict=True):
            lo, hi = boxes[k]
            d[k] = lo + (hi - lo) * float(ui)
        return d

    def evaluate(us) -> None:
        """Solve the designs ``us`` (d + 1 of them, in the unit box) in one call."""
        new = [u for u in us if tuple(u) not in kept]
        if not new:
            return
        batch = [design_of(u) for u in new]
        batch += [batch[-1]] * (len(free) + 1 - len(batch))  # one batch shape: one program
        variants = with_designs(
            model, placement, [d["omega"] for d in batch], [d["shortening"] for d in batch]
        )
        began = time.perf_counter()
        traces = simulate(model, accuracy, variants=variants, steady=True)
        if timings["compile"] is None:
            timings["compile"] = time.perf_counter() - began
        for i, u in enumerate(new):
            one = traces.variant(i)
            with np.errstate(all="ignore"):
                records = placed_records(model, placement, one)
            values = metric_values(records)
            got = np.array([np.nan if values[n] is None else values[n] for n in targets])
            ok = traces.solved and bool(traces.steady) and bool(np.all(np.isfinite(got)))
            kept[tuple(u)] = (got, records, traces.solved, ok)

    def residual(u) -> np.ndarray:
        got, _, _, ok = kept[tuple(u)]
        return (got - wanted) / scale if ok else np.full(wanted.shape, 1e3)

    def steps(u) -> list:
        out = [np.asarray(u, float)]
        for j in range(len(free)):
            e = np.zeros(len(free))
            e[j] = FD_STEP if u[j] + FD_STEP <= 1.0 else -FD_STEP
            out.append(np.asarray(u, float) + e)
        return out

    def fun(u):
        evaluate(steps(u))
        return residual(u)

    def jac(u):
        evaluate(steps(u))
        base = residual(u)
        columns = []
        for j, v in enumerate(steps(u)[1:]):
            columns.append((residual(v) - base) / (v[j] - u[j]))
        return np.stack(columns, axis=1)

    levels = (np.arange(GRID_LEVELS) + 0.5) / GRID_LEVELS
    u_start = np.array([(start[k] - boxes[k][0]) / (boxes[k][1] - boxes[k][0]) for k in free])
    grid = [np.array(p) for p in itertools.product(levels, repeat=len(free))]
    grid = [np.clip(u_start, 0.0, 1.0), *grid]
    if progress:
        progress(
            f"{model.name}: the soft pump in place of {placement.chamber}; compiling, then a "
            f"grid of {len(grid)} designs, {len(free) + 1} a call ..."
        )
    for i in range(0, len(grid), len(free) + 1):
        evaluate(grid[i : i + len(free) + 1])
    best = min(grid, key=lambda u: float(np.sum(residual(u) ** 2)))
    if progress:
        progress("least squares from the grid's best ...")
    fit = least_squares(
        fun, best, jac=jac, bounds=(0.0, 1.0), method="trf", max_nfev=max_evaluations,
        x_scale=1.0, xtol=1e-8, ftol=1e-10,
    )  # fmt: skip
    u = fit.x if tuple(fit.x) in kept else best
    evaluate(steps(u))
    got, records, solved, ok = kept[tuple(u)]
    res = residual(u)
    seen = np.array([k[0] for k in kept.values() if k[3]])
    out_targets = [
        ModelTarget(
            name, float(wanted[i]), None if not ok else float(got[i]),
            None if not ok else float(res[i]), ok and bool(abs(res[i]) <= 1.0),
            (float(np.nanmin(seen[:, i])), float(np.nanmax(seen[:, i])))
            if seen.size else (None, None),
        )
        for i, name in enumerate(targets)
    ]  # fmt: skip
    from cardiosoft.network.pump_in_model import pump_flags

    return ModelDesign(
        model=model.name,
        chamber=placement.chamber,
        design={k: float(v) for k, v in design_of(u).items()},
        targets=out_targets,
        reached=all(t.reached for t in out_targets),
        records=records,
        pump_flags=pump_flags(records[placement.chamber]) if ok else [],
        solved=bool(solved),
        steady=ok,
        evaluations=len(kept),
        seconds=time.perf_counter() - clock,
        compile_seconds=float(timings["compile"] or 0.0),
        evaluated=[
            (*(design_of(k)[v] for v in FREE), [float(x) for x in kept[k][0]]) for k in kept
        ],
    )
