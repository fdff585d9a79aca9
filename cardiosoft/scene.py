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
- any: ``cable_friction`` (capstan friction at the base holes, changes the measured force).

Every message about a bad file names the file, the key, the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from importlib import resources
from pathlib import Path

from cardiosoft.pump import Domain
from cardiosoft.units import ml_per_mmHg, mm, mmHg, mmHg_s_per_ml

__all__ = ["EFFECTS", "SCENE_NAMES", "Scene", "load_scene"]

EFFECTS = {
    "water_column": (
        "column_rise",
        "column_inertia",
        "tube_inertia",
        "tube_resistance",
        "minor_loss",
        "cable_friction",
    ),
    "windkessel3": ("valves", "preload", "cable_friction"),
}
SCENE_NAMES = ("bench-static", "bench-dynamic", "lv-systemic", "rv-pulmonary")
ACCURACY = ("fast", "default", "reference")
SHAPES = ("linear", "smoothstep", "cosine")
VALVE_KINDS = ("ideal", "smooth")


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
    valve_smoothing: float = 0.5 * mmHg
    valve_resistance: tuple[float, float] = (math.nan, math.nan)  # inlet, outlet (SI)
    cable_friction: float = 0.0
    accuracy: str = "default"
    max_beats: int = 30
    steady_tol: float = 0.01

    def has(self, effect: str) -> bool:
        return effect in self.effects

    def replace(self, **changes) -> Scene:
        """A copy with ``changes`` applied (already in SI), validated like a file."""
        return _validated(dataclasses.replace(self, **changes))


class _Reader:
    """Reads one table of a scene file, consuming keys and naming file/key in errors."""

    def __init__(self, source: str, table: dict, prefix: str = ""):
        self.source, self.table, self.prefix = source, dict(table), prefix

    def _where(self, key):
        return f"{self.source}: key '{self.prefix}{key}'"

    def sub(self, key, required=True) -> _Reader | None:
        value = self.table.pop(key, None)
        if value is None:
            if required:
                raise ValueError(f"{self._where(key)} is missing (a table)")
            return None
        if not isinstance(value, dict):
            raise ValueError(f"{self._where(key)} = {value!r} must be a table [{key}]")
        return _Reader(self.source, value, f"{self.prefix}{key}.")

    def number(
        self,
        key,
        unit,
        lo=-math.inf,
        hi=math.inf,
        *,
        default=None,
        lo_open=False,
        hi_open=False,
        scale=1.0,
    ):
        value = self.table.pop(key, default)
        allowed = (
            f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open or hi == math.inf else ']'}"
            f" {unit}"
        ).rstrip()
        if value is None:
            raise ValueError(f"{self._where(key)} is missing; allowed: a number in {allowed}")
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        if ok:
            ok = (value > lo if lo_open else value >= lo) and (
                value < hi if hi_open else value <= hi
            )
        if not ok:
            raise ValueError(f"{self._where(key)} = {value!r} {unit}: allowed {allowed}")
        return float(value) * scale

    def numbers(self, key, unit, lo, hi, *, scale=1.0):
        values = self.table.pop(key, None)
        if not isinstance(values, list) or not values:
            raise ValueError(
                f"{self._where(key)} = {values!r}: allowed a non-empty list of "
                f"numbers in [{lo:g}, {hi:g}] {unit}"
            )
        reader = _Reader(self.source, {f"{key}[{i}]": v for i, v in enumerate(values)}, self.prefix)
        return tuple(
            reader.number(f"{key}[{i}]", unit, lo, hi, scale=scale) for i in range(len(values))
        )

    def choice(self, key, choices, *, default=None):
        value = self.table.pop(key, default)
        if value not in choices:
            raise ValueError(f"{self._where(key)} = {value!r}: allowed {', '.join(choices)}")
        return value

    def text(self, key, default=""):
        value = self.table.pop(key, default)
        if not isinstance(value, str):
            raise ValueError(f"{self._where(key)} = {value!r}: allowed a string")
        return value

    def done(self):
        if self.table:
            key = sorted(self.table)[0]
            raise ValueError(f"{self._where(key)} is not a known key (value {self.table[key]!r})")


_R = mmHg_s_per_ml
_C = ml_per_mmHg
_DOMAIN = Domain()


def _parse(source: str, doc: dict) -> Scene:
    top = _Reader(source, doc)
    name = top.text("name")
    description = top.text("description")
    static = top.choice("kind", ("static", "dynamic")) == "static"
    design = top.sub("design")
    omega = design.number("omega", "", *_DOMAIN.omega)
    shortening = design.number("shortening", "", *_DOMAIN.shortening)
    design.done()
    act = top.sub("actuation")
    fields = {
        "bpm": act.number("bpm", "bpm", 0.0, 300.0, lo_open=True),
        "shape": act.choice("shape", SHAPES, default="linear"),
        "pull_fraction": act.number("pull_fraction", "", 0.0, 1.0, default=0.5, lo_open=True),
        "hold_fraction": act.number("hold_fraction", "", 0.0, 1.0, default=0.0),
        "release_fraction": act.number("release_fraction", "", 0.0, 1.0, default=0.5, lo_open=True),
    }
    act.done()
    after = top.sub("afterload")
    kind = after.choice("type", tuple(EFFECTS))
    raw_effects = top.table.pop("effects", [])
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
    if kind == "water_column":
        fields |= {
            "afterloads": after.numbers("pressures_mmHg", "mmHg", 0.0, 150.0, scale=mmHg),
            "column_diameter": after.number("column_diameter_mm", "mm", 1.0, 500.0, scale=mm),
            "tube_length": after.number("tube_length_mm", "mm", 1.0, 1e4, scale=mm),
            "tube_diameter": after.number("tube_diameter_mm", "mm", 1.0, 100.0, scale=mm),
            "loss_coefficient": after.number("loss_coefficient", "", 0.0, 100.0, default=1.0),
        }
    else:
        fields |= {
            "afterloads": (),
            "windkessel": (
                after.number("Rp_mmHg_s_per_ml", "mmHg s/ml", 0.0, 10.0, lo_open=True, scale=_R),
                after.number("C_ml_per_mmHg", "ml/mmHg", 0.0, 100.0, lo_open=True, scale=_C),
                after.number("Rd_mmHg_s_per_ml", "mmHg s/ml", 0.0, 10.0, lo_open=True, scale=_R),
            ),
            "venous_pressure": after.number(
                "venous_pressure_mmHg", "mmHg", 0.0, 50.0, default=0.0, scale=mmHg
            ),
        }
    after.done()
    preload = top.sub("preload", required="preload" in effects)
    if preload is not None:
        fields["preload_pressure"] = preload.number("pressure_mmHg", "mmHg", 0.0, 50.0, scale=mmHg)
        preload.done()
    valves = top.sub("valves", required="valves" in effects)
    if valves is not None:
        fields["valve_kind"] = valves.choice("kind", VALVE_KINDS, default="smooth")
        fields["valve_smoothing"] = valves.number(
            "smoothing_mmHg", "mmHg", 0.0, 10.0, default=0.5, lo_open=True, scale=mmHg
        )
        fields["valve_resistance"] = (
            valves.number(
                "inlet_resistance_mmHg_s_per_ml", "mmHg s/ml", 0.0, 10.0, lo_open=True, scale=_R
            ),
            valves.number(
                "outlet_resistance_mmHg_s_per_ml", "mmHg s/ml", 0.0, 10.0, lo_open=True, scale=_R
            ),
        )
        valves.done()
    friction = top.sub("cable_friction", required="cable_friction" in effects)
    if friction is not None:
        fields["cable_friction"] = friction.number("exponent", "", 0.0, 3.0)
        friction.done()
    solve = top.sub("solve", required=False) or _Reader(source, {}, "solve.")
    fields |= {
        "accuracy": solve.choice("accuracy", ACCURACY, default="default"),
        "max_beats": int(solve.number("max_beats", "beats", 1, 500, default=30)),
        "steady_tol": solve.number("steady_tol", "ml or mmHg", 0.0, 10.0, default=0.01),
    }
    solve.done()
    top.done()
    return _validated(
        Scene(
            name=name,
            source=source,
            description=description,
            static=static,
            effects=effects,
            omega=omega,
            shortening=shortening,
            afterload_type=kind,
            **fields,
        )
    )


def _validated(scene: Scene) -> Scene:
    where = f"{scene.source}:"
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
    if scene.static and scene.afterload_type != "water_column":
        raise ValueError(f"{where} a static scene needs a water_column afterload")
    return scene


def load_scene(name_or_path) -> Scene:
    """A shipped scene by name (:data:`SCENE_NAMES`) or a scene file by path."""
    text_name = str(name_or_path)
    if text_name in SCENE_NAMES:
        path = resources.files("cardiosoft") / "scenes" / f"{text_name}.toml"
        source, text = text_name, path.read_text()
    else:
        path = Path(text_name)
        if not path.is_file():
            raise ValueError(
                f"scene = {text_name!r}: allowed a shipped scene ({', '.join(SCENE_NAMES)}) "
                "or the path of a .toml scene file"
            )
        source, text = str(path), path.read_text()
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"{source}: not valid TOML: {err}") from None
    return _parse(source, doc)
