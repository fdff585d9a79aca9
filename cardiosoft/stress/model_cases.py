"""The hard cases of the soft pump in an svZeroDSolver model (group ``models``, issue #40's
"stress works on any network"): a shipped closed loop written as an svZeroDSolver model
(:func:`cardiosoft.network.export.to_svzerod`, in mmHg), read back with the pump in place of
one of its chambers (``--pump-chamber``), at the grid's design corners
(:data:`~cardiosoft.stress.GRID_OMEGAS` x :data:`~cardiosoft.stress.GRID_SHORTENINGS`), all
of one chamber's in one batched call of the network's solve to the periodic steady state.

Checks per case (:func:`check_model_member`): the solve succeeded and settled; every number of
every record finite; the pump's volumes positive, its EF in [0, 1], its cable force never
negative unless the pump's flags say so; and the pump's energy balance: the surrogate's chamber
is a potential, so over a periodic beat the cables' work equals the stroke work, within what the
beat's samples leave (:func:`balance_allowance`, :data:`BALANCE_TOL`)."""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np

from cardiosoft.network.block_metrics import closed_integral
from cardiosoft.stress.cases import GRID_OMEGAS, GRID_SHORTENINGS, fmt

__all__ = [
    "BALANCE_TOL",
    "MODEL_PLACES",
    "ModelBatch",
    "ModelCase",
    "balance_allowance",
    "check_model_member",
    "model_batches",
]

MODEL_PLACES = (("heart", "lv"), ("heart", "rv"))
"""(shipped closed loop, chamber): where the pump goes. The native ``heart``'s ventricles: the
pump at the corners, filled and emptied by a native circulation."""
BALANCE_TOL = 2.0
"""The pump's stroke work may differ from its cables' work by this many times the beat's own
allowance (:func:`balance_allowance`): Richardson's factor of safety, as the comparisons with
svzerod take twice their estimate."""


def balance_allowance(pressure, volume, force, pull) -> float:
    """What one beat's samples (SI, both ends of the beat) leave of the pump's energy balance
    (J). Over a closed beat the stroke work and the cables' work are equal, the chamber being a
    potential U(V, x); the reported beat closes only to the steady rule, which leaves
    ``U(end) - U(start)``, bounded by max|p| |dV| + max|F| |dx| over the beat; and each closed
    integral is a trapezoid over the samples, whose error the same rule over every other sample
    estimates (second order: a third of their difference)."""
    p, v, f, x = (np.asarray(a, dtype=float) for a in (pressure, volume, force, pull))
    open_ends = np.max(np.abs(p)) * abs(v[-1] - v[0]) + np.max(np.abs(f)) * abs(x[-1] - x[0])

    def quadrature(y, z):
        return abs(closed_integral(y, z) - closed_integral(y[::2], z[::2])) / 3.0

    return float(open_ends + quadrature(p, v) + quadrature(f, x))


@dataclasses.dataclass(frozen=True)
class ModelCase:
    """One design of the pump in one model."""

    id: str
    group: str
    scene: str
    chamber: str
    omega: float
    shortening: float

    def reproduce(self) -> str:
        """Python that runs this case alone."""
        return (
            "from cardiosoft.network import read, simulate; "
            "from cardiosoft.network.export import to_svzerod; "
            "from cardiosoft.network.pump_in_model import PumpPlacement; "
            f"config = to_svzerod(cs.load_scene({self.scene!r}), units='mmHg', beats=3); "
            f"simulate(read(config, pump=PumpPlacement({self.chamber!r}, 'mmHg', "
            f"{self.omega!r}, {self.shortening!r})), steady=True)"
        )


@dataclasses.dataclass(frozen=True)
class ModelBatch:
    """One batched call: the pump in ``scene``'s chamber ``chamber``, at the designs."""

    group: str
    title: str
    scene: str
    chamber: str
    designs: tuple[tuple[float, float], ...]
    cli: ClassVar[bool] = False

    def __len__(self) -> int:
        return len(self.designs)

    def build_scene(self):
        """The shipped closed loop the model is written from."""
        from cardiosoft.scene import load_scene

        return load_scene(self.scene)

    def cases(self) -> list[ModelCase]:
        return [
            ModelCase(
                f"models/{self.scene}:{self.chamber}/Omega={fmt(o)},C={fmt(c)}",
                self.group, self.scene, self.chamber, o, c,
            )
            for o, c in self.designs
        ]  # fmt: skip


def model_batches(scenes, quick: bool = False) -> list[ModelBatch]:
    """The group's batches for the shipped ``scenes`` named (those of :data:`MODEL_PLACES`);
    ``quick``: the left ventricle at two corners only, the strongest (Omega 6, C 0.65) and a
    weak one whose stroke is nearly nothing (Omega 0.3, C 0.01)."""
    corners = tuple((o, c) for o in GRID_OMEGAS for c in GRID_SHORTENINGS)
    if quick:
        corners = ((GRID_OMEGAS[-1], GRID_SHORTENINGS[-1]), (GRID_OMEGAS[1], GRID_SHORTENINGS[0]))
    places = [(s, c) for s, c in MODEL_PLACES if s in scenes]
    if quick:
        places = places[:1]
    return [
        ModelBatch("models", f"{s} as an svZeroDSolver model, the pump in {c}", s, c, corners)
        for s, c in places
    ]


def check_model_member(
    records: dict, chamber: str, solved: bool, steady: bool, flags, allowance: float
):
    """The problems ``[(check, what)]`` of one case's records (the module docstring);
    ``allowance``: the beat's :func:`balance_allowance` (J)."""
    problems = []
    if not solved:
        return [("solve", "the solve failed or the nodes' Newton did not converge")]
    if not steady:
        problems.append(("steady", "not at the periodic steady state"))
    for block, record in records.items():
        for key, v in record.items():
            if v is not None and not math.isfinite(v):
                problems.append(("finite", f"{block}.{key} = {v}"))
    pump = records[chamber]
    if not pump["esv_ml"] > 0:
        problems.append(("physical", f"end-systolic volume {pump['esv_ml']:.4g} ml <= 0"))
    if not 0.0 <= pump["ejection_fraction"] <= 1.0:
        problems.append(("physical", f"EF {pump['ejection_fraction']:.4g} outside [0, 1]"))
    pushes = any("push" in f for f in flags)
    if pump["min_force_N"] < 0 and not pushes:
        problems.append(("physical", f"cable force {pump['min_force_N']:.4g} N, not flagged"))
    work, stroke = pump["cable_work_J"], pump["stroke_work_J"]
    if abs(work - stroke) > BALANCE_TOL * allowance:
        problems.append(
            ("energy", f"stroke work {stroke:.5g} J against the cables' {work:.5g} J, "
             f"{abs(work - stroke):.3g} apart where the beat allows {allowance:.3g}")
        )  # fmt: skip
    return problems
