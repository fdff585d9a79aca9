"""The cases of the hard-case suite: what is run (the grid, stiff afterloads, sharp valves,
preloads, long runs, shooting), as :class:`Batch` es of :class:`Case` s. A batch is one call of
the public batch solve; its members are the cases. The hypothesis draws are
:mod:`cardiosoft.stress.draws`; which batches a run takes, :func:`cardiosoft.stress.plan`."""

from __future__ import annotations

import dataclasses

from cardiosoft.scene import RANGES, Scene, load_scene
from cardiosoft.units import ml_per_mmHg, mm, mmHg, mmHg_s_per_ml

__all__ = [
    "FIELD_SCALES",
    "GRID_AFTERLOADS_MMHG",
    "GRID_BPMS",
    "GRID_OMEGAS",
    "GRID_SHORTENINGS",
    "GROUPS",
    "LONG_BEATS",
    "PRELOADS_MMHG",
    "PROPERTY_EXAMPLES",
    "QUICK_BPMS",
    "QUICK_STIFF",
    "SHARP_SMOOTHING_MMHG",
    "VALVE_RESISTANCE_RANGE",
    "WINDKESSEL_OPEN_AT_LO",
    "WINDKESSEL_RANGES",
    "Batch",
    "Case",
    "design_batch",
    "design_members",
    "dynamic_scenes",
    "grid_batches",
    "long_batches",
    "member_id",
    "preload_batches",
    "rate_batches",
    "shooting_batches",
    "stiff_batches",
    "valve_batches",
    "water_column_scenes",
    "windkessel_scenes",
]

GRID_BPMS = (10.0, 30.0, 60.0, 120.0, 180.0, 240.0, 300.0)
GRID_OMEGAS = (0.0, 0.3, 4.0, 6.0)
GRID_SHORTENINGS = (0.01, 0.4, 0.65)
GRID_AFTERLOADS_MMHG = (0.0, 150.0)
SHARP_SMOOTHING_MMHG = 0.001
PRELOADS_MMHG = (0.0, 40.0)
LONG_BEATS = 500
# The Windkessel's and the valves' numbers are tuple fields of a Scene, which RANGES does not
# list (it holds the scalar fields only): their allowed ranges, copied from the scene file's key
# table (cardiosoft/scene.py): (0, 10] mmHg s/ml for the resistances, [0.01, 100] ml/mmHg for
# C. tests/test_stress.py checks them against what Scene.replace accepts.
WINDKESSEL_RANGES = {"Rp": (0.0, 10.0), "C": (0.01, 100.0), "Rd": (0.0, 10.0)}
WINDKESSEL_OPEN_AT_LO = {"Rp": True, "C": False, "Rd": True}
VALVE_RESISTANCE_RANGE = (0.0, 10.0)  # open at 0
# SI value of the user unit RANGES gives each drawn scalar field in (RANGES' docstring).
FIELD_SCALES = {
    "column_diameter": mm,
    "tube_length": mm,
    "tube_diameter": mm,
    "loss_coefficient": 1.0,
    "cable_friction": 1.0,
    "viscoelastic_ratio": 1.0,
    "relaxation_time": 1.0,
    "venous_pressure": mmHg,
    "preload_pressure": mmHg,
    "valve_smoothing": mmHg,
}
QUICK_STIFF = ("bench-dynamic largest exit loss 60 bpm", "lv-systemic C 0.01 ml/mmHg 60 bpm")
"""The stiff batches of the quick subset (their titles)."""
QUICK_BPMS = (GRID_BPMS[0], GRID_BPMS[-1])
"""The rates the quick subset's hypothesis members are drawn from."""
PROPERTY_EXAMPLES = 4
"""Hypothesis examples per scene structure in the full suite (each one batch of members)."""


GROUPS = (
    "grid",
    "stiff",
    "valves",
    "preload",
    "long",
    "shooting",
    "property",
    "cli",
    "closed_loop",
    "models",
)
"""The groups of cases; ``closed_loop`` runs the closed-loop scenes
(:mod:`cardiosoft.stress.loop_cases`), ``models`` the pump in a closed loop written as an
svZeroDSolver model (:mod:`cardiosoft.stress.model_cases`), the others the open ones."""


@dataclasses.dataclass(frozen=True)
class Case:
    """One member of one batch, with everything needed to run it again (SI in ``changes``)."""

    id: str
    group: str
    scene: str
    """The shipped scene the case starts from."""
    changes: tuple[tuple[str, object], ...]
    """``Scene.replace`` arguments (SI), the accuracy preset included."""
    omega: float
    shortening: float
    bpm: float | None
    """None for a quasi-static stroke."""
    afterload_mmHg: float | None
    """The column head; None for a Windkessel scene."""
    beats: int | None = None
    steady: str = "beats"

    def reproduce(self) -> str:
        """Python that runs this case alone."""
        changes = ", ".join(f"{k}={v!r}" for k, v in self.changes)
        scene = f"cs.load_scene({self.scene!r})" + (f".replace({changes})" if changes else "")
        head = "" if self.afterload_mmHg is None else f", afterload={self.afterload_mmHg!r} * mmHg"
        if self.bpm is None:
            call = (
                f"cs.solve_static({scene}, omega={self.omega!r}, "
                f"shortening={self.shortening!r}{head})"
            )
        else:
            beats = "" if self.beats is None else f", beats={self.beats}"
            steady = "" if self.steady == "beats" else f", steady={self.steady!r}"
            call = (
                f"cs.solve_beats({scene}, omega={self.omega!r}, shortening={self.shortening!r}, "
                f"bpm={self.bpm!r}{head}{beats}{steady}, save='metrics')"
            )
        return "from cardiosoft.units import mmHg; " + call


@dataclasses.dataclass(frozen=True)
class Batch:
    """One call of the batch solve: a scene (a shipped one with ``changes``) and its members."""

    group: str
    title: str
    scene: str
    omega: tuple[float, ...]
    shortening: tuple[float, ...]
    bpm: tuple[float, ...] | None
    """Per member; None for the static scene."""
    afterload_mmHg: tuple[float, ...] | None
    """Per member; None for a Windkessel scene."""
    ids: tuple[str, ...]
    changes: tuple[tuple[str, object], ...] = ()
    beats: int | None = None
    steady: str = "beats"
    cli: bool = False
    """Also run the first design of the batch through the command line (group ``cli``)."""

    def __len__(self) -> int:
        return len(self.ids)

    def cases(self) -> list[Case]:
        heads = self.afterload_mmHg or (None,) * len(self)
        bpms = self.bpm or (None,) * len(self)
        return [
            Case(
                self.ids[i],
                self.group,
                self.scene,
                self.changes,
                self.omega[i],
                self.shortening[i],
                bpms[i],
                heads[i],
                self.beats,
                self.steady,
            )
            for i in range(len(self))
        ]

    def build_scene(self) -> Scene:
        scene = load_scene(self.scene)
        return scene.replace(**dict(self.changes)) if self.changes else scene


def fmt(v) -> str:
    """A number as case ids and titles write it."""
    return f"{v:g}"


def design_members(scene: Scene):
    """(omega, C, head or None) of the grid's design corners, at each column head."""
    heads = GRID_AFTERLOADS_MMHG if scene.afterload.has_heads else (None,)
    return [(o, c, h) for o in GRID_OMEGAS for c in GRID_SHORTENINGS for h in heads]


def member_id(prefix: str, omega, c, head) -> str:
    where = "" if head is None else f",{fmt(head)}mmHg"
    return f"{prefix}/Omega={fmt(omega)},C={fmt(c)}{where}"


def design_batch(
    group, scene_name, title, prefix, *, bpm, changes=(), beats=None, steady="beats", cli=False
) -> Batch:
    """The grid's design corners (at both heads for a water column) as one batch."""
    scene = load_scene(scene_name)
    members = design_members(scene)
    has_heads = scene.afterload.has_heads
    return Batch(
        group=group,
        title=title,
        scene=scene_name,
        omega=tuple(m[0] for m in members),
        shortening=tuple(m[1] for m in members),
        bpm=None if scene.static else (float(bpm),) * len(members),
        afterload_mmHg=tuple(m[2] for m in members) if has_heads else None,
        ids=tuple(member_id(prefix, *m) for m in members),
        changes=tuple(changes),
        beats=beats,
        steady=steady,
        cli=cli,
    )


def accuracy_change(preset: str) -> tuple[tuple[str, object], ...]:
    return (("accuracy", preset),)


def dynamic_scenes(scenes) -> list[str]:
    return [s for s in scenes if not load_scene(s).static]


def windkessel_scenes(scenes) -> list[str]:
    return [s for s in dynamic_scenes(scenes) if not load_scene(s).afterload.has_heads]


def water_column_scenes(scenes) -> list[str]:
    return [s for s in dynamic_scenes(scenes) if load_scene(s).afterload.has_heads]


def grid_batches(scenes, presets, bpms, cli_at=None) -> list[Batch]:
    """The grid: per dynamic scene, preset and rate one batch of the design corners; the static
    scene one batch. ``cli_at``: (preset, bpm) whose batch is also checked through the CLI."""
    out = []
    for name in scenes:
        if load_scene(name).static:
            out.append(
                design_batch(
                    "grid",
                    name,
                    f"{name} (quasi-static)",
                    f"grid/{name}",
                    bpm=None,
                    cli=cli_at is not None,
                )
            )
            continue
        for preset in presets:
            for bpm in bpms:
                out.append(
                    design_batch(
                        "grid",
                        name,
                        f"{name} {preset} {fmt(bpm)} bpm",
                        f"grid/{name}/{preset}/{fmt(bpm)}bpm",
                        bpm=bpm,
                        changes=accuracy_change(preset),
                        cli=cli_at == (preset, bpm),
                    )
                )
    return out


def rate_batches(group, name, label, tag, bpms, **options) -> list[Batch]:
    """The design corners of scene ``name`` (``options``: of :func:`design_batch`) at each rate:
    batches titled ``"<name> <label> <bpm> bpm"``, their cases
    ``"<group>/<name>/<tag><bpm>bpm/..."``."""
    return [
        design_batch(
            group,
            name,
            f"{name} {label} {fmt(bpm)} bpm",
            f"{group}/{name}/{tag}{fmt(bpm)}bpm",
            bpm=bpm,
            **options,
        )
        for bpm in bpms
    ]


def _stiff_variants(name, column_min, tube_max, tube_narrow, loss_max, r_max, valve_max):
    """{label: scene changes} of the stiffest afterloads of scene ``name``."""
    if load_scene(name).afterload.has_heads:
        return {
            "narrowest column": (("column_diameter", column_min),),
            "longest narrowest tube": (("tube_length", tube_max), ("tube_diameter", tube_narrow)),
            "largest exit loss": (("loss_coefficient", loss_max),),
            "all stiff": (
                ("column_diameter", column_min),
                ("tube_length", tube_max),
                ("tube_diameter", tube_narrow),
                ("loss_coefficient", loss_max),
            ),
        }
    rp, c, rd = load_scene(name).windkessel
    c_min = WINDKESSEL_RANGES["C"][0]
    return {
        "resistances max": (
            ("windkessel", (r_max, c, r_max)),
            ("valve_resistance", (valve_max, valve_max)),
        ),
        f"C {fmt(c_min)} ml/mmHg": (("windkessel", (rp, c_min * ml_per_mmHg, rd)),),
        f"C {fmt(c_min)} ml/mmHg, resistances max": (
            ("windkessel", (r_max, c_min * ml_per_mmHg, r_max)),
            ("valve_resistance", (valve_max, valve_max)),
        ),
    }


def stiff_batches(scenes, bpms) -> list[Batch]:
    """The stiffest afterloads the scene files allow (module docstring)."""
    limits = (
        RANGES["column_diameter"][0] * mm,
        RANGES["tube_length"][1] * mm,
        RANGES["tube_diameter"][0] * mm,
        RANGES["loss_coefficient"][1],
        max(WINDKESSEL_RANGES["Rp"][1], WINDKESSEL_RANGES["Rd"][1]) * mmHg_s_per_ml,
        VALVE_RESISTANCE_RANGE[1] * mmHg_s_per_ml,
    )
    out = []
    for name in water_column_scenes(scenes) + windkessel_scenes(scenes):
        heads = load_scene(name).afterload.has_heads
        for label, changes in _stiff_variants(name, *limits).items():
            if heads:
                tag = label.replace(" ", "-")
            else:
                tag = label.replace(" ", "").replace(",", "-").replace("/", "per")
            out += rate_batches("stiff", name, label, f"{tag}/", bpms, changes=changes)
    return out


def valve_batches(scenes, bpms, ideal=True) -> list[Batch]:
    """Sharp valves: the smoothing down to :data:`SHARP_SMOOTHING_MMHG`, and ideal diodes."""
    out = []
    for name in windkessel_scenes(scenes):
        variants = {"smoothing 0.001 mmHg": (("valve_smoothing", SHARP_SMOOTHING_MMHG * mmHg),)}
        if ideal:
            variants["ideal"] = (("valve_kind", "ideal"),)
        for label, changes in variants.items():
            tag = label.replace(" ", "")
            out += rate_batches("valves", name, f"valves {label}", f"{tag}/", bpms, changes=changes)
    return out


def preload_batches(scenes, bpms) -> list[Batch]:
    """Atrial pressures of :data:`PRELOADS_MMHG`."""
    return [
        batch
        for name in windkessel_scenes(scenes)
        for p in PRELOADS_MMHG
        for batch in rate_batches(
            "preload",
            name,
            f"preload {fmt(p)} mmHg",
            f"{fmt(p)}mmHg/",
            bpms,
            changes=(("preload_pressure", p * mmHg),),
        )
    ]


def long_batches(scenes, bpms) -> list[Batch]:
    """:data:`LONG_BEATS` beats exactly."""
    label, tag = f"{LONG_BEATS} beats", f"{LONG_BEATS}beats/"
    return [
        batch
        for name in dynamic_scenes(scenes)
        for batch in rate_batches("long", name, label, tag, bpms, beats=LONG_BEATS)
    ]


def shooting_batches(scenes, bpms) -> list[Batch]:
    """The periodic steady state by Newton shooting."""
    return [
        batch
        for name in dynamic_scenes(scenes)
        for batch in rate_batches("shooting", name, "shooting", "", bpms, steady="shooting")
    ]
