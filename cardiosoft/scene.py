"""Scenes: what to simulate, in a TOML file with user units, validated on load.

A scene names the design (Omega, C), the actuation, the afterload (the paper's water-column
bench or a 3-element Windkessel), the effects it needs, how many beats or which steady-state
tolerance, and the accuracy preset. The shipped scenes live in ``cardiosoft/scenes/``
(``bench-static``, ``bench-dynamic``, ``lv-systemic``, ``rv-pulmonary``); ``load_scene(name)``
also takes a path to a file of your own with the same keys.

**Effects are opt-in.** An effect that is not listed is absent from the state and from the
compiled vector field (not multiplied by zero):

- water column: ``column_rise`` (the level rises as the pump ejects), ``column_inertia``
  (inertance of the column, grows with its height), ``tube_inertia``, ``tube_resistance``
  (Poiseuille), ``minor_loss`` (Borda-Carnot, ``K q|q|``);
- Windkessel: ``valves`` (inlet and outlet), ``preload`` (atrial pressure source);
- any: ``cable_friction`` (capstan friction at the base holes, changes the measured force),
  ``shell_viscoelasticity`` (the chamber stiffer to fast strokes than to slow ones, relaxing
  back to the surrogate; :class:`~cardiosoft.circuit.ShellViscoelasticity`), ``cable_slack``
  (a cable only pulls: a disk that returns faster than the shell recoils leaves the cables
  slack and the shell moving by itself; :class:`~cardiosoft.circuit.CableSlack`),
  ``wall_contact`` (a floor where the walls meet: the volume stays above zero under suction;
  :class:`~cardiosoft.circuit.WallContact`).

**The pump.** A scene's top-level ``pump`` key names the surrogate it runs
(:data:`cardiosoft.pump.SHIPPED_ARTIFACTS` or an artifact's path; default
:data:`cardiosoft.pump.DEFAULT_ARTIFACT`); ``load_scene(name, pump=...)`` (``--pump``) overrides
it. The bench's unknowns (the tube, the column, the cable friction, the shell's
viscoelasticity) are calibrated *with* a surrogate, so a scene's numbers belong to its own
``pump``; a table ``[calibration."<pump>"]``, laid out like the file, holds another pump's. A
scene that has such tables runs only the pumps it has numbers for, and says so otherwise.

Every message about a bad file names the file, the key, the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import ClassVar

import jax

from cardiosoft._scene_file import _Number, _Reader
from cardiosoft._validate import check_range
from cardiosoft.actuation import BPM_RANGE, SHAPES
from cardiosoft.circulation import BENCH_EFFECTS, AtrialSource, Bench, Windkessel3
from cardiosoft.network.loop_scene import LoopScene, parse_loop_scene
from cardiosoft.pump import DEFAULT_ARTIFACT, Domain, check_pump_name
from cardiosoft.solve import ACCURACY_PRESETS
from cardiosoft.units import ml_per_mmHg, mm, mmHg, mmHg_s_per_ml
from cardiosoft.valves import VALVE_KINDS, VALVE_SMOOTHING, Valve

__all__ = [
    "ADDABLE_EFFECTS",
    "AFTERLOADS",
    "EFFECTS",
    "LOOP_SCENE_NAMES",
    "RANGES",
    "SCENE_NAMES",
    "Scene",
    "WaterColumnAfterload",
    "Windkessel3Afterload",
    "is_closed_loop",
    "load_scene",
]

SHELL_EFFECTS = ("cable_friction", "shell_viscoelasticity", "cable_slack", "wall_contact")
"""Effects of the pump itself, allowed with any afterload."""


@dataclasses.dataclass(frozen=True)
class WaterColumnAfterload:
    """The paper's bench (section II-F): a silicone tube to an open water column.

    The members of a run differ in the column head (Pa), one per entry of the scene's
    ``afterload.pressures_mmHg``.
    """

    tag: ClassVar[str] = "water_column"
    effects: ClassVar[tuple[str, ...]] = BENCH_EFFECTS
    has_heads: ClassVar[bool] = True

    def blocks(self, scene: Scene, head) -> dict:
        """The :class:`~cardiosoft.circuit.PumpCircuit` arguments of the bench at ``head``."""
        bench = Bench.of(
            scene.column_diameter,
            head,
            scene.tube_length,
            scene.tube_diameter,
            scene.loss_coefficient,
            scene.effects,
        )
        return {"afterload": bench}


@dataclasses.dataclass(frozen=True)
class Windkessel3Afterload:
    """A 3-element Windkessel (Rp, C, Rd) behind an outlet valve, filled from an atrial source
    through an inlet valve. A run has one member; ``head`` is not used."""

    tag: ClassVar[str] = "windkessel3"
    effects: ClassVar[tuple[str, ...]] = ("valves", "preload")
    has_heads: ClassVar[bool] = False

    def blocks(self, scene: Scene, head=None) -> dict:
        """The :class:`~cardiosoft.circuit.PumpCircuit` arguments of the circulation."""
        rp, c, rd = scene.windkessel
        r_in, r_out = scene.valve_resistance
        return {
            "afterload": Windkessel3(rp, c, rd, scene.venous_pressure),
            "outlet_valve": Valve(r_out, scene.valve_kind, scene.valve_smoothing),
            "inlet_valve": Valve(r_in, scene.valve_kind, scene.valve_smoothing),
            "preload": AtrialSource(scene.preload_pressure),
        }


AFTERLOADS = {kind.tag: kind() for kind in (WaterColumnAfterload, Windkessel3Afterload)}
"""The afterloads a scene may name (``afterload.type``): a tagged union. Adding one means a
class here and its numbers in :data:`_NUMBERS` (``when=`` its tag); nothing else branches on
the type."""
EFFECTS = {tag: kind.effects + SHELL_EFFECTS for tag, kind in AFTERLOADS.items()}
"""The effects each afterload type allows."""
ADDABLE_EFFECTS = ("cable_slack", "wall_contact")
"""The effects that need no parameters of their own: a run may add them to any open-loop scene
(``--add-effect``)."""
SCENE_NAMES = ("bench-static", "bench-dynamic", "lv-systemic", "rv-pulmonary")
LOOP_SCENE_NAMES = ("heart", "soft-lv", "soft-rv", "tah")
"""The shipped closed-loop scenes (``kind = "closed_loop"``,
:mod:`cardiosoft.network.loop_scene`)."""
LOOP_KIND = "closed_loop"
"""A scene file's ``kind`` that makes it a closed loop (:func:`load_scene`)."""
ACCURACY = ACCURACY_PRESETS


@dataclasses.dataclass(frozen=True)
class Scene:
    """A validated scene; quantities in SI unless the name says otherwise."""

    name: str
    source: str
    description: str
    static: bool
    effects: tuple[str, ...]
    omega: float
    shortening: float
    bpm: float
    shape: str
    pull_fraction: float
    hold_fraction: float
    release_fraction: float
    afterload_type: str
    afterloads: tuple[float, ...]  # Pa: column heads (water column); empty for a Windkessel
    column_diameter: float = math.nan
    tube_length: float = math.nan
    tube_diameter: float = math.nan
    loss_coefficient: float = 1.0
    windkessel: tuple[float, float, float] = (math.nan, math.nan, math.nan)  # Rp, C, Rd (SI)
    venous_pressure: float = 0.0
    preload_pressure: float = math.nan
    valve_kind: str = "smooth"
    valve_smoothing: float = VALVE_SMOOTHING
    valve_resistance: tuple[float, float] = (math.nan, math.nan)  # inlet, outlet (SI)
    cable_friction: float = 0.0
    viscoelastic_ratio: float = 0.0
    relaxation_time: float = math.nan  # s
    ramp_time: float = 0.0  # s: the linear pull's jerk-limited ends (cardiosoft.actuation)
    accuracy: str = "default"
    max_beats: int = 30
    steady_tol: float = 0.01
    pump: str = DEFAULT_ARTIFACT  # the surrogate: a shipped name or an artifact's path
    calibrated_pumps: tuple[str, ...] = ()  # pumps the file has rig numbers for; () = any

    def has(self, effect: str) -> bool:
        return effect in self.effects

    @property
    def afterload(self) -> WaterColumnAfterload | Windkessel3Afterload:
        """The afterload's kind (:data:`AFTERLOADS`): what it allows and how it is built."""
        return AFTERLOADS[self.afterload_type]

    def replace(self, **changes) -> Scene:
        """A copy with ``changes`` applied (already in SI), validated like a file. The pump
        of a scene with calibrated rig numbers changes only through :func:`load_scene`."""
        if "pump" in changes and changes["pump"] != self.pump and self.calibrated_pumps:
            raise ValueError(
                f"pump = {changes['pump']!r}: scene {self.name}'s rig is calibrated per pump; "
                f"load it with load_scene({self.source!r}, pump=...) instead"
            )
        return _validated(dataclasses.replace(self, **changes))

    def column_heads_mmHg(self, given=None, *, action: str) -> tuple[float, ...] | None:
        """The column heads (mmHg) a request runs at: ``given`` (numbers in mmHg), else the
        scene's own, checked against :data:`RANGES`. None for an afterload without a column
        head (a Windkessel), where giving heads is a ``ValueError`` saying it has none to
        ``action`` ("set", "sweep")."""
        if not self.afterload.has_heads:
            if given is not None:
                raise ValueError(
                    f"afterload: scene {self.name} has a {self.afterload_type} afterload, which "
                    f"has no column head to {action}"
                )
            return None
        heads = tuple(float(h) / mmHg for h in self.afterloads) if given is None else given
        heads = tuple(float(h) for h in heads)
        check_range("afterload", heads, "mmHg", *RANGES["afterloads"])
        return heads


_R = mmHg_s_per_ml
_C = ml_per_mmHg
_DOMAIN = Domain()


# Every numeric key of a scene file, with its allowed range: the one place ranges are written.
# Parsing converts units with it; _validated checks files and Scene.replace() alike with it.
# fmt: off
_NUMBERS = (
    # field, "section.key", unit, lo, hi, lo_open, scale; then default / index / when
    _Number("omega", "design.omega", "", *_DOMAIN.omega),
    _Number("shortening", "design.shortening", "", *_DOMAIN.shortening),
    _Number("bpm", "actuation.bpm", "bpm", *BPM_RANGE, True),
    _Number("pull_fraction", "actuation.pull_fraction", "", 0.0, 1.0, True, default=0.5),
    _Number("hold_fraction", "actuation.hold_fraction", "", 0.0, 1.0, default=0.0),
    _Number("release_fraction", "actuation.release_fraction", "", 0.0, 1.0, True, default=0.5),
    # a drive's jerk-limited start and stop (cardiosoft.actuation), linear shape only
    _Number("ramp_time", "actuation.ramp_time_s", "s", 0.0, 1.0, default=0.0),
    _Number("afterloads", "afterload.pressures_mmHg", "mmHg", 0.0, 150.0, False, mmHg,
            when="water_column"),
    _Number("column_diameter", "afterload.column_diameter_mm", "mm", 1.0, 500.0, False, mm,
            when="water_column"),
    _Number("tube_length", "afterload.tube_length_mm", "mm", 1.0, 1e4, False, mm,
            when="water_column"),
    _Number("tube_diameter", "afterload.tube_diameter_mm", "mm", 1.0, 100.0, False, mm,
            when="water_column"),
    _Number("loss_coefficient", "afterload.loss_coefficient", "", 0.0, 100.0, default=1.0,
            when="water_column"),
    _Number("windkessel", "afterload.Rp_mmHg_s_per_ml", "mmHg s/ml", 0.0, 10.0, True, _R,
            index=0, when="windkessel3"),
    # 0.01 ml/mmHg (an arterial tree ~100x stiffer than a young adult's) at the least: below,
    # the 3-element model's time constant Rp C drops under 1 ms and beat 1 ran out of steps
    _Number("windkessel", "afterload.C_ml_per_mmHg", "ml/mmHg", 0.01, 100.0, False, _C,
            index=1, when="windkessel3"),
    _Number("windkessel", "afterload.Rd_mmHg_s_per_ml", "mmHg s/ml", 0.0, 10.0, True, _R,
            index=2, when="windkessel3"),
    _Number("venous_pressure", "afterload.venous_pressure_mmHg", "mmHg", 0.0, 50.0, False,
            mmHg, default=0.0, when="windkessel3"),
    _Number("preload_pressure", "preload.pressure_mmHg", "mmHg", 0.0, 50.0, False, mmHg,
            when="effect:preload"),
    _Number("valve_smoothing", "valves.smoothing_mmHg", "mmHg", 0.0, 10.0, True, mmHg,
            default=VALVE_SMOOTHING / mmHg, when="effect:valves"),
    _Number("valve_resistance", "valves.inlet_resistance_mmHg_s_per_ml", "mmHg s/ml", 0.0,
            10.0, True, _R, index=0, when="effect:valves"),
    _Number("valve_resistance", "valves.outlet_resistance_mmHg_s_per_ml", "mmHg s/ml", 0.0,
            10.0, True, _R, index=1, when="effect:valves"),
    _Number("cable_friction", "cable_friction.exponent", "", 0.0, 3.0,
            when="effect:cable_friction"),
    _Number("viscoelastic_ratio", "shell_viscoelasticity.stiffness_ratio", "", 0.0, 20.0,
            when="effect:shell_viscoelasticity"),
    _Number("relaxation_time", "shell_viscoelasticity.relaxation_time_s", "s", 0.0, 100.0,
            True, when="effect:shell_viscoelasticity"),
    _Number("max_beats", "solve.max_beats", "beats", 1.0, 500.0, default=30),
    _Number("steady_tol", "solve.steady_tol", "ml or mmHg", 0.0, 10.0, default=0.01),
)
# fmt: on
RANGES: dict[str, tuple[float, float]] = {
    spec.field: (spec.lo, spec.hi) for spec in _NUMBERS if spec.index is None
}
"""Allowed range of each scalar number of a scene, in its user unit (:attr:`_Number.unit`):
``RANGES["bpm"]`` is (0, 300) bpm, ``RANGES["afterloads"]`` (0, 150) mmHg."""
# Text keys: (field, "section.key", allowed values, default, when).
_CHOICES = (
    ("shape", "actuation.shape", SHAPES, "linear", "always"),
    ("accuracy", "solve.accuracy", ACCURACY, "default", "always"),
    ("valve_kind", "valves.kind", VALVE_KINDS, "smooth", "effect:valves"),
)
_SECTIONS = {  # table -> when it must be present
    "design": "always",
    "actuation": "always",
    "afterload": "always",
    "preload": "effect:preload",
    "valves": "effect:valves",
    "cable_friction": "effect:cable_friction",
    "shell_viscoelasticity": "effect:shell_viscoelasticity",
    "solve": "optional",
}


def _applies(when: str, afterload_type: str, effects) -> bool:
    if when in ("always", "optional"):
        return True
    if when.startswith("effect:"):
        return when.removeprefix("effect:") in effects
    return when == afterload_type


def _parse(source: str, doc: dict, calibrated_pumps: tuple[str, ...] = ()) -> Scene:
    top = _Reader(source, doc)
    top.pop("calibration")  # applied by select_pump
    pump = top.text("pump", DEFAULT_ARTIFACT)
    name = top.text("name")
    description = top.text("description")
    static = top.choice("kind", ("static", "dynamic")) == "static"
    # the afterload's type decides which tables and keys are required: read it first
    afterload_table = doc.get("afterload")
    afterload_table = afterload_table if isinstance(afterload_table, dict) else {}
    kind = _Reader(source, afterload_table, "afterload.").choice("type", tuple(EFFECTS))
    raw_effects = top.pop("effects", [])
    if not isinstance(raw_effects, list) or any(e not in EFFECTS[kind] for e in raw_effects):
        bad = (
            raw_effects
            if not isinstance(raw_effects, list)
            else [e for e in raw_effects if e not in EFFECTS[kind]]
        )
        raise ValueError(
            f"{source}: key 'effects' = {bad!r}: allowed for a {kind} afterload: "
            f"{', '.join(EFFECTS[kind])}"
        )
    effects = tuple(dict.fromkeys(raw_effects))
    readers = {
        section: top.sub(section, required=when != "optional" and _applies(when, kind, effects))
        or _Reader(source, {}, f"{section}.")
        for section, when in _SECTIONS.items()
    }
    readers["afterload"].pop("type")
    fields: dict = {}
    for spec in _NUMBERS:
        if _applies(spec.when, kind, effects):
            section, key = spec.key.split(".", 1)
            value = readers[section].number(spec, key)
            if spec.index is None:
                fields[spec.field] = value
            else:
                fields.setdefault(spec.field, [math.nan] * 3)[spec.index] = value
    for field, where, choices, default, when in _CHOICES:
        if _applies(when, kind, effects):
            section, key = where.split(".", 1)
            fields[field] = readers[section].choice(key, choices, default)
    for reader in readers.values():
        reader.done()
    top.done()
    fields.setdefault("afterloads", ())
    fields["windkessel"] = tuple(fields.get("windkessel", (math.nan,) * 3))
    fields["valve_resistance"] = tuple(fields.get("valve_resistance", (math.nan,) * 2)[:2])
    fields["max_beats"] = int(fields["max_beats"])
    return _validated(
        Scene(
            name=name,
            source=source,
            description=description,
            static=static,
            effects=effects,
            afterload_type=kind,
            pump=pump,
            calibrated_pumps=calibrated_pumps,
            **fields,
        )
    )


def select_pump(source: str, doc: dict, pump=None) -> tuple[dict, tuple[str, ...]]:
    """The scene document ``doc`` as run with ``pump`` (None: the file's own ``pump``): the
    file's numbers, overlaid by the ``[calibration."<pump>"]`` table when the pump is another
    one; and the pumps the file has numbers for (none: it calibrates nothing, any pump runs).
    A scene with calibration tables refuses a pump it has no numbers for."""
    own = doc.get("pump", DEFAULT_ARTIFACT)
    pump = own if pump is None else check_pump_name(pump)
    if not isinstance(own, str):
        raise ValueError(f"{source}: key 'pump' = {own!r}: allowed a string")
    check_pump_name(own)
    calibrations = doc.get("calibration", {})
    if not isinstance(calibrations, dict) or not all(
        isinstance(t, dict) for t in calibrations.values()
    ):
        raise ValueError(
            f"{source}: key 'calibration' must hold one table per pump, "
            '[calibration."<pump>".<section>]'
        )
    calibrated = (own, *calibrations) if calibrations else ()
    if pump == own:
        return doc, calibrated
    if calibrations and pump not in calibrations:
        raise ValueError(
            f"pump = {pump!r}: scene {source} has rig numbers calibrated for "
            f"{', '.join([own, *calibrations])} only (a [calibration.\"{pump}\"] table would "
            "give them)"
        )
    merged = {k: (dict(v) if isinstance(v, dict) else v) for k, v in doc.items()}
    for section, table in calibrations.get(pump, {}).items():
        if not isinstance(table, dict) or not isinstance(merged.get(section), dict):
            raise ValueError(
                f"{source}: key 'calibration.{pump}.{section}' must be a table overriding the "
                f"scene's own [{section}]"
            )
        unknown = sorted(set(table) - set(merged[section]))
        if unknown:
            raise ValueError(
                f"{source}: key 'calibration.{pump}.{section}.{unknown[0]}' overrides no key of "
                f"[{section}]; allowed: {', '.join(sorted(merged[section]))}"
            )
        merged[section].update(table)
    merged["pump"] = pump
    return merged, calibrated


def _validated(scene: Scene) -> Scene:
    """Check every value of ``scene`` against :data:`_NUMBERS` and the structural rules."""
    where = f"{scene.source}:"
    if scene.afterload_type not in EFFECTS:
        raise ValueError(
            f"{where} key 'afterload.type' = {scene.afterload_type!r}: allowed {', '.join(EFFECTS)}"
        )
    bad = [e for e in scene.effects if e not in EFFECTS[scene.afterload_type]]
    if bad:
        raise ValueError(
            f"{where} key 'effects' = {bad!r}: allowed for a "
            f"{scene.afterload_type} afterload: "
            f"{', '.join(EFFECTS[scene.afterload_type])}"
        )
    for spec in _NUMBERS:
        if not _applies(spec.when, scene.afterload_type, scene.effects):
            continue
        value = getattr(scene, spec.field)
        value = value[spec.index] if spec.index is not None else value
        listed = isinstance(value, tuple)
        for i, v in enumerate(value if listed else (value,)):
            if isinstance(v, jax.core.Tracer):
                continue  # a value being differentiated: checked where it entered
            u = v / spec.scale
            inside = (
                math.isfinite(u)
                and (u > spec.lo if spec.lo_open else u >= spec.lo)
                and u <= spec.hi
            )
            if not inside:
                key = f"{spec.key}[{i}]" if listed else spec.key
                raise ValueError(
                    f"{where} key '{key}' = {u:g} {spec.unit}".rstrip()
                    + f": allowed {spec.allowed()}"
                )
    if scene.afterload.has_heads and not scene.afterloads:
        raise ValueError(
            f"{where} key 'afterload.pressures_mmHg' is empty: allowed a non-empty "
            "list of numbers in [0, 150] mmHg"
        )
    for field, key, choices, _, when in _CHOICES:
        if (
            _applies(when, scene.afterload_type, scene.effects)
            and getattr(scene, field) not in choices
        ):
            raise ValueError(
                f"{where} key '{key}' = {getattr(scene, field)!r}: allowed {', '.join(choices)}"
            )
    timing = (scene.ramp_time, scene.bpm, scene.pull_fraction, scene.release_fraction)
    concrete = not any(isinstance(v, jax.core.Tracer) for v in timing)
    if concrete and scene.ramp_time > 0 and scene.shape != "linear":
        raise ValueError(
            f"{where} key 'actuation.ramp_time_s' = {scene.ramp_time:g} s: allowed only with "
            f"shape = 'linear' (the {scene.shape} shape already starts and stops at rest)"
        )
    phases = min(scene.pull_fraction, scene.release_fraction)
    shortest = phases / scene.bpm * 60.0 if concrete else 0.0  # s
    if concrete and scene.ramp_time > 0.5 * shortest:
        raise ValueError(
            f"{where} key 'actuation.ramp_time_s' = {scene.ramp_time:g} s: allowed at most half "
            f"the shortest phase, {0.5 * shortest:g} s"
        )
    total = scene.pull_fraction + scene.hold_fraction + scene.release_fraction
    if total > 1 + 1e-12:
        raise ValueError(
            f"{where} actuation fractions pull + hold + release = {total:g}: allowed at most 1"
        )
    if (
        scene.afterload_type == "windkessel3"
        and not scene.static
        and ("valves" not in scene.effects or "preload" not in scene.effects)
    ):
        raise ValueError(
            f"{where} a Windkessel scene needs the effects 'valves' and 'preload' "
            "(the pump fills from the atrium through the inlet valve)"
        )
    if scene.static and not scene.afterload.has_heads:
        raise ValueError(f"{where} a static scene needs a water_column afterload")
    return scene


def load_scene(name_or_path, pump=None) -> Scene | LoopScene:
    """A shipped scene by name (:data:`SCENE_NAMES`, :data:`LOOP_SCENE_NAMES`) or a scene file
    by path; a closed-loop file (``kind = "closed_loop"``) gives a
    :class:`~cardiosoft.network.loop_scene.LoopScene`. ``pump`` runs another surrogate than the
    file's own (module docstring: a scene calibrated per pump needs its numbers for it)."""
    text_name = str(name_or_path)
    if text_name in SCENE_NAMES + LOOP_SCENE_NAMES:
        path = resources.files("cardiosoft") / "scenes" / f"{text_name}.toml"
        source, text = text_name, path.read_text()
    else:
        path = Path(text_name)
        if not path.is_file():
            raise ValueError(
                f"scene = {text_name!r}: allowed a shipped scene "
                f"({', '.join(SCENE_NAMES + LOOP_SCENE_NAMES)}) "
                "or the path of a .toml scene file"
            )
        source, text = str(path), path.read_text()
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"{source}: not valid TOML: {err}") from None
    doc, calibrated = select_pump(source, doc, pump)
    if doc.get("kind") == LOOP_KIND:
        return parse_loop_scene(source, doc)
    return _parse(source, doc, calibrated)


def is_closed_loop(name_or_path) -> bool:
    """Whether ``name_or_path`` names a closed loop, without loading it: a shipped one
    (:data:`LOOP_SCENE_NAMES`) or a TOML file of ``kind = "closed_loop"``. False for anything
    unreadable, which :func:`load_scene` then refuses with the reason."""
    if str(name_or_path) in LOOP_SCENE_NAMES:
        return True
    try:
        return tomllib.loads(Path(name_or_path).read_text()).get("kind") == LOOP_KIND
    except (OSError, ValueError):  # tomllib's and the text's decoding errors are ValueErrors
        return False
