"""The closed-loop cases of the hard-case suite (group ``closed_loop``, issue #26): the shipped
closed-loop scenes (:data:`cardiosoft.scene.LOOP_SCENE_NAMES`) over the rates
:data:`LOOP_BPMS` and, with a soft pump, the design corners, as :class:`LoopBatch` es of
:class:`LoopCase` s. A batch is one call of :func:`cardiosoft.network.loop_batch.solve_loop`, its
members
sets of the scene's numbers by path (``"bpm"``, ``"lv.omega"``, ...); every batch of one scene
sets the same paths and, but for the quick subset's, has the same size, so that each scene
structure compiles one program."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from cardiosoft.network.loop_scene import LoopScene
from cardiosoft.scene import load_scene
from cardiosoft.stress.cases import GRID_OMEGAS, GRID_SHORTENINGS, fmt

__all__ = [
    "LOOP_BPMS",
    "QUICK_LOOP_BPMS",
    "LoopBatch",
    "LoopCase",
    "design_corners",
    "loop_batches",
    "loop_member_id",
    "opposite_corner",
    "quick_loop_batches",
]

LOOP_BPMS = (40.0, 60.0, 72.0, 90.0, 120.0, 150.0, 180.0)
"""The closed loops' rates: a resting to an exercising heart (issue #26)."""
QUICK_LOOP_BPMS = (60.0, 180.0)
"""The quick subset's rates; its two-pump scene's opposite corners run at the faster one."""


@dataclasses.dataclass(frozen=True)
class LoopCase:
    """One member of one closed-loop batch: the scene's numbers it sets (SI), by path."""

    id: str
    group: str
    scene: str
    numbers: tuple[tuple[str, float], ...]

    @property
    def bpm(self) -> float:
        return dict(self.numbers)["bpm"]

    @property
    def shortening(self) -> float | None:
        """The smallest shortening C of the member's pumps; None for a native heart (what a
        :class:`~cardiosoft.stress.checks.KnownFailure` 's ``max_shortening`` compares)."""
        values = [v for k, v in self.numbers if k.endswith(".shortening")]
        return min(values) if values else None

    def reproduce(self) -> str:
        """Python that runs this case alone."""
        members = ", ".join(f"{k!r}: {v!r}" for k, v in self.numbers)
        return (
            "from cardiosoft.network.loop_batch import solve_loop; "
            f"solve_loop(cs.load_scene({self.scene!r}), members={{{members}}}, save='metrics')"
        )


@dataclasses.dataclass(frozen=True)
class LoopBatch:
    """One call of :func:`~cardiosoft.network.loop_batch.solve_loop`: a shipped closed-loop scene
    and its members."""

    group: str
    title: str
    scene: str
    numbers: tuple[tuple[str, tuple[float, ...]], ...]
    """Per path, the members' values (SI)."""
    ids: tuple[str, ...]
    cli: ClassVar[bool] = False
    """A closed loop is not run through the command line by the suite."""

    def __len__(self) -> int:
        return len(self.ids)

    def members(self) -> dict[str, tuple[float, ...]]:
        """``solve_loop`` 's ``members``."""
        return dict(self.numbers)

    def cases(self) -> list[LoopCase]:
        return [
            LoopCase(self.ids[i], self.group, self.scene, tuple((k, v[i]) for k, v in self.numbers))
            for i in range(len(self))
        ]

    def build_scene(self) -> LoopScene:
        return load_scene(self.scene)


def design_corners() -> list[tuple[float, float]]:
    """(Omega, C) of the grid's design corners (:data:`~cardiosoft.stress.GRID_OMEGAS` x
    :data:`~cardiosoft.stress.GRID_SHORTENINGS`)."""
    return [(o, c) for o in GRID_OMEGAS for c in GRID_SHORTENINGS]


def opposite_corner(omega: float, c: float) -> tuple[float, float]:
    """The corner across the grid: the smallest Omega for the largest, C likewise."""
    return (
        GRID_OMEGAS[-1 - GRID_OMEGAS.index(omega)],
        GRID_SHORTENINGS[-1 - GRID_SHORTENINGS.index(c)],
    )


def _member(pumps, bpm: float, designs) -> dict[str, float]:
    """The numbers of one member: its rate and each pump's (Omega, C), in the order of
    ``pumps``. Every pump's design is set, also when it is the scene's own, so that every batch
    of the scene passes the same paths (one compiled program)."""
    out = {"bpm": float(bpm)}
    for pump, (omega, c) in zip(pumps, designs, strict=True):
        out |= {f"{pump}.omega": float(omega), f"{pump}.shortening": float(c)}
    return out


def loop_member_id(group: str, scene: str, member: dict[str, float]) -> str:
    """``"<group>/<scene>/<bpm>bpm"``, then each pump's design: ``"/lv:Omega=4,C=0.4"``."""
    pumps = [k.split(".")[0] for k in member if k.endswith(".omega")]
    designs = ";".join(
        f"{p}:Omega={fmt(member[f'{p}.omega'])},C={fmt(member[f'{p}.shortening'])}" for p in pumps
    )
    return f"{group}/{scene}/{fmt(member['bpm'])}bpm" + (f"/{designs}" if designs else "")


def _batch(group: str, scene: str, title: str, members: list[dict[str, float]]) -> LoopBatch:
    return LoopBatch(
        group=group,
        title=title,
        scene=scene,
        numbers=tuple((k, tuple(m[k] for m in members)) for k in members[0]),
        ids=tuple(loop_member_id(group, scene, m) for m in members),
    )


def _rate_label(bpms) -> str:
    return f"{', '.join(fmt(b) for b in bpms)} bpm"


def loop_batches(scenes, bpms, group: str = "closed_loop") -> list[LoopBatch]:
    """The full group: a native loop at every rate in one batch; a scene with soft pumps, per
    rate, one batch of the design corners (every pump at the same corner) and, with two pumps,
    one of opposite corners (left at a corner, right at the one across the grid: left weak and
    right strong, and the reverse, among them). The scenes' own design, the paper's prototype
    (Omega 4, C 0.4), is a corner, so each scene also runs at every rate as shipped."""
    out = []
    for name in scenes:
        pumps = load_scene(name).pumps
        if not pumps:
            members = [_member((), bpm, ()) for bpm in bpms]
            out.append(_batch(group, name, f"{name} {_rate_label(bpms)}", members))
            continue
        for bpm in bpms:
            same = [_member(pumps, bpm, [corner] * len(pumps)) for corner in design_corners()]
            out.append(_batch(group, name, f"{name} corners {fmt(bpm)} bpm", same))
            if len(pumps) == 2:
                across = [
                    _member(pumps, bpm, (corner, opposite_corner(*corner)))
                    for corner in design_corners()
                ]
                title = f"{name} opposite corners {fmt(bpm)} bpm"
                out.append(_batch(group, name, title, across))
    return out


def quick_loop_batches(scenes, group: str = "closed_loop") -> list[LoopBatch]:
    """The quick subset: a native loop and a two-pump scene, one batch each, at
    :data:`QUICK_LOOP_BPMS` (the pumps at the scene's own design); the two-pump scene also at
    the extreme opposite corners at the faster rate (left weakest, Omega and C smallest, with
    right strongest, and the reverse). The one-pump scenes, each its own compiled program, are
    the full group's."""
    out = []
    for name in scenes:
        scene = load_scene(name)
        pumps = scene.pumps
        if len(pumps) == 1:
            continue
        own = [(getattr(scene, p).omega, getattr(scene, p).shortening) for p in pumps]
        members = [_member(pumps, bpm, own) for bpm in QUICK_LOOP_BPMS]
        title = f"{name} {_rate_label(QUICK_LOOP_BPMS)}"
        if len(pumps) == 2:
            weak, strong = design_corners()[0], design_corners()[-1]
            fast = QUICK_LOOP_BPMS[-1]
            members += [_member(pumps, fast, d) for d in ((weak, strong), (strong, weak))]
            title += f", opposite corners at {fmt(fast)} bpm"
        out.append(_batch(group, name, title, members))
    return out
