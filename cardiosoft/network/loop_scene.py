"""Closed-loop scenes: a TOML file (``kind = "closed_loop"``) -> a validated :class:`LoopScene`
-> the :class:`~cardiosoft.network.closed_loop.ClosedLoop` vector field.

The shipped ones (``cardiosoft/scenes/``): ``heart``, the native closed loop of Regazzoni et al.
2022 with its published defaults (``notes/closed-loop-regazzoni.md``); ``soft-lv`` and
``soft-rv``, the soft pump in place of the left or right ventricle, the rest native; ``tah``,
two soft pumps (a total artificial heart), the atria native. :func:`cardiosoft.load_scene`
reads them (it hands a closed-loop file to :func:`parse_loop_scene`).

A file has a table per chamber (``[la]``, ``[lv]``, ``[ra]``, ``[rv]``; ``type = "elastance"``
or ``"pump"``), per vessel (``[ar_sys]``, ``[ven_sys]``, ``[ar_pul]``, ``[ven_pul]``), the
``[valves]`` (``law = "regazzoni"``, the paper's, or ``"smooth"``, the project's
:class:`~cardiosoft.valves.Valve`), the rate ``[heart] bpm`` and an optional ``[solve]``.
Every number is in the user unit its key names and is checked against :data:`LOOP_KEYS` on
load; a bad one raises one ``ValueError`` naming the file, key, value, unit and range.

Numbers are addressed by a path, ``"bpm"`` or ``"<table>.<field>"`` (``"lv.omega"``,
``"ar_sys.compliance"``, SI): :func:`loop_numbers` lists a scene's, :meth:`LoopScene.with_numbers`
sets them (traced values too: the batch solve builds each member this way).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

from cardiosoft._scene_file import _Number, _Reader
from cardiosoft.actuation import BPM_RANGE, SHAPES, CablePull
from cardiosoft.network.closed_loop import CHAMBERS, DEFAULT_ENGINE, VALVES, VESSELS, ClosedLoop
from cardiosoft.network.loop_components import Activation, ElastanceChamber, PumpChamber, Vessel
from cardiosoft.pump import DEFAULT_ARTIFACT, Domain, PumpSurrogate
from cardiosoft.solve import ACCURACY_PRESETS as ACCURACY
from cardiosoft.units import ml, ml_per_mmHg, mmHg, mmHg_s2_per_ml, mmHg_s_per_ml
from cardiosoft.valves import ArctanValve, Valve

__all__ = [
    "LOOP_KEYS",
    "VALVE_LAWS",
    "ElastanceSpec",
    "LoopScene",
    "PumpSpec",
    "VesselSpec",
    "loop_circuit",
    "loop_numbers",
    "number_key",
    "parse_loop_scene",
]

VALVE_LAWS = ("regazzoni", "smooth")
"""``"regazzoni"``: :class:`~cardiosoft.valves.ArctanValve`, the paper's; ``"smooth"``:
:class:`~cardiosoft.valves.Valve` with ``kind="smooth"``, the project's own."""

_E = mmHg / ml
_R = mmHg_s_per_ml
_C = ml_per_mmHg
_L = mmHg_s2_per_ml
_DOMAIN = Domain()


@dataclasses.dataclass(frozen=True)
class ElastanceSpec:
    """A time-varying-elastance chamber
    (:class:`~cardiosoft.network.loop_components.ElastanceChamber`), SI."""

    kind: ClassVar[str] = "elastance"
    active_elastance: float
    passive_elastance: float
    rest_volume: float
    start: float
    contraction: float
    relaxation: float
    initial_volume: float


@dataclasses.dataclass(frozen=True)
class PumpSpec:
    """The soft pump as a chamber (:class:`~cardiosoft.network.loop_components.PumpChamber`): its
    design (Omega, C), the pull's shape and fractions of the period, and its onset in the period."""

    kind: ClassVar[str] = "pump"
    omega: float
    shortening: float
    pull_fraction: float
    hold_fraction: float
    release_fraction: float
    onset: float
    shape: str = "cosine"


@dataclasses.dataclass(frozen=True)
class VesselSpec:
    """An RLC vessel compartment (:class:`~cardiosoft.network.loop_components.Vessel`), SI."""

    resistance: float
    compliance: float
    inertance: float
    initial_pressure: float
    initial_flow: float


@dataclasses.dataclass(frozen=True)
class LoopScene:
    """A validated closed-loop scene; quantities in SI."""

    name: str
    source: str
    description: str
    bpm: float
    la: ElastanceSpec | PumpSpec
    lv: ElastanceSpec | PumpSpec
    ra: ElastanceSpec | PumpSpec
    rv: ElastanceSpec | PumpSpec
    ar_sys: VesselSpec
    ven_sys: VesselSpec
    ar_pul: VesselSpec
    ven_pul: VesselSpec
    valve_law: str
    valve_min_resistance: float = math.nan
    valve_max_resistance: float = math.nan
    valve_resistance: float = math.nan
    valve_smoothing: float = math.nan
    accuracy: str = "default"
    max_beats: int = 300
    steady_tol: float = 0.01
    pump: str = DEFAULT_ARTIFACT  # the surrogate of every pump chamber (cardiosoft.scene)
    static: ClassVar[bool] = False

    @property
    def pumps(self) -> tuple[str, ...]:
        """The chambers that are soft pumps."""
        return tuple(c for c in CHAMBERS if getattr(self, c).kind == "pump")

    def replace(self, **changes) -> LoopScene:
        """A copy with top-level ``changes`` (SI) applied, validated like a file."""
        return _validated(dataclasses.replace(self, **changes))

    def with_numbers(self, numbers: dict) -> LoopScene:
        """A copy with the numbers at ``numbers``' paths (:func:`loop_numbers`) replaced; not
        validated (the values may be traced: check them where they enter)."""
        top = {k: v for k, v in numbers.items() if "." not in k}
        nested: dict[str, dict] = {}
        for path, value in numbers.items():
            if "." in path:
                table, field = path.split(".", 1)
                nested.setdefault(table, {})[field] = value
        parts = {t: dataclasses.replace(getattr(self, t), **f) for t, f in nested.items()}
        return dataclasses.replace(self, **top, **parts)


def loop_numbers(scene: LoopScene) -> dict[str, float]:
    """Every number of the physics of ``scene`` by path (``"bpm"``, ``"lv.omega"``, SI)."""
    out = {"bpm": scene.bpm}
    for table in (*CHAMBERS, *VESSELS):
        spec = getattr(scene, table)
        for f in dataclasses.fields(spec):
            value = getattr(spec, f.name)
            if not isinstance(value, str):
                out[f"{table}.{f.name}"] = value
    for f in (
        "valve_min_resistance",
        "valve_max_resistance",
        "valve_resistance",
        "valve_smoothing",
    ):
        out[f] = getattr(scene, f)
    return out


def loop_circuit(
    scene: LoopScene, pump: PumpSurrogate | None = None, engine: str = DEFAULT_ENGINE
) -> ClosedLoop:
    """The :class:`~cardiosoft.network.closed_loop.ClosedLoop` of ``scene`` (numbers may be traced).

    ``pump``: the surrogate of the pump chambers (required when the scene has any);
    ``engine``: :attr:`~cardiosoft.network.closed_loop.ClosedLoop.engine`.
    """
    period = 60.0 / scene.bpm
    chambers = {}
    for c in CHAMBERS:
        spec = getattr(scene, c)
        if spec.kind == "pump":
            if pump is None:
                raise ValueError(f"scene {scene.name}: chamber {c} is a soft pump; pass pump=")
            stroke = spec.shortening * pump.cable_length(spec.omega)
            pull = CablePull(
                stroke,
                period,
                spec.pull_fraction,
                spec.hold_fraction,
                spec.release_fraction,
                shape=spec.shape,
            )
            chambers[c] = PumpChamber(pump, spec.omega, pull, spec.onset)
        else:
            activation = Activation(period, spec.start, spec.contraction, spec.relaxation)
            chambers[c] = ElastanceChamber(
                spec.active_elastance,
                spec.passive_elastance,
                spec.rest_volume,
                activation,
                spec.initial_volume,
            )
    vessels = {v: Vessel(*dataclasses.astuple(getattr(scene, v))) for v in VESSELS}
    if scene.valve_law == "regazzoni":
        valve = ArctanValve(scene.valve_min_resistance, scene.valve_max_resistance)
    else:
        valve = Valve(scene.valve_resistance, "smooth", scene.valve_smoothing)
    return ClosedLoop(**chambers, **vessels, **dict.fromkeys(VALVES, valve), engine=engine)


# Every numeric key of a closed-loop file: (table kind, key) -> its Scene field, unit and range.
# The ranges: the model's well-posedness (positive elastance, resistance, compliance,
# inertance), fractions of the period, and generous physiological bounds (a chamber's elastance
# up to 100 mmHg/ml, 35x the paper's largest; vessel compliances up to 1000 ml/mmHg).
# fmt: off
LOOP_KEYS: dict[str, tuple[_Number, ...]] = {
    "heart": (_Number("bpm", "bpm", "bpm", *BPM_RANGE, True),),
    "elastance": (
        _Number("active_elastance", "EA_mmHg_per_ml", "mmHg/ml", 0.0, 100.0, False, _E),
        _Number("passive_elastance", "EB_mmHg_per_ml", "mmHg/ml", 0.0, 100.0, True, _E),
        _Number("rest_volume", "V0_ml", "ml", 0.0, 500.0, False, ml),
        _Number("start", "contraction_start", "", 0.0, 1.0),
        _Number("contraction", "contraction_duration", "", 0.0, 1.0, True),
        _Number("relaxation", "relaxation_duration", "", 0.0, 1.0, True),
        _Number("initial_volume", "initial_volume_ml", "ml", 0.0, 2000.0, True, ml),
    ),
    "pump": (
        _Number("omega", "omega", "", *_DOMAIN.omega),
        _Number("shortening", "shortening", "", *_DOMAIN.shortening, True),
        _Number("pull_fraction", "pull_fraction", "", 0.0, 1.0, True),
        _Number("hold_fraction", "hold_fraction", "", 0.0, 1.0, default=0.0),
        _Number("release_fraction", "release_fraction", "", 0.0, 1.0, True),
        _Number("onset", "onset", "", 0.0, 1.0, default=0.0),
    ),
    "vessel": (
        _Number("resistance", "R_mmHg_s_per_ml", "mmHg s/ml", 0.0, 100.0, True, _R),
        _Number("compliance", "C_ml_per_mmHg", "ml/mmHg", 0.0, 1000.0, True, _C),
        _Number("inertance", "L_mmHg_s2_per_ml", "mmHg s^2/ml", 0.0, 1.0, True, _L),
        _Number("initial_pressure", "initial_pressure_mmHg", "mmHg", -50.0, 300.0, False, mmHg),
        _Number("initial_flow", "initial_flow_ml_per_s", "ml/s", -2000.0, 2000.0, False, ml,
                default=0.0),
    ),
    "regazzoni": (
        _Number("valve_min_resistance", "Rmin_mmHg_s_per_ml", "mmHg s/ml", 0.0, 10.0, True, _R),
        _Number("valve_max_resistance", "Rmax_mmHg_s_per_ml", "mmHg s/ml", 0.0, 1e7, True, _R),
    ),
    "smooth": (
        _Number("valve_resistance", "resistance_mmHg_s_per_ml", "mmHg s/ml", 0.0, 10.0, True,
                _R),
        _Number("valve_smoothing", "smoothing_mmHg", "mmHg", 0.0, 10.0, True, mmHg,
                default=0.5),
    ),
    "solve": (
        _Number("max_beats", "max_beats", "beats", 1.0, 500.0, default=300),
        _Number("steady_tol", "steady_tol", "ml or mmHg", 0.0, 10.0, default=0.01),
    ),
}
# fmt: on
_SPECS = {"elastance": ElastanceSpec, "pump": PumpSpec, "vessel": VesselSpec}


def _read_numbers(reader: _Reader, kind: str) -> dict:
    return {spec.field: reader.number(spec, spec.key) for spec in LOOP_KEYS[kind]}


def parse_loop_scene(source: str, doc: dict) -> LoopScene:
    """A :class:`LoopScene` from a parsed TOML document ``doc`` read from ``source``."""
    top = _Reader(source, doc)
    top.pop("calibration")  # a closed loop calibrates nothing per pump; any is allowed
    pump = top.text("pump", DEFAULT_ARTIFACT)
    name, description = top.text("name"), top.text("description")
    top.choice("kind", ("closed_loop",))
    fields = _read_numbers(top.sub("heart", required=True), "heart")
    for c in CHAMBERS:
        table = top.sub(c, required=True)
        kind = table.choice("type", ("elastance", "pump"))
        values = _read_numbers(table, kind)
        if kind == "pump":
            values["shape"] = table.choice("shape", SHAPES, "cosine")
        table.done()
        fields[c] = _SPECS[kind](**values)
    for v in VESSELS:
        table = top.sub(v, required=True)
        fields[v] = VesselSpec(**_read_numbers(table, "vessel"))
        table.done()
    valves = top.sub("valves", required=True)
    fields["valve_law"] = valves.choice("law", VALVE_LAWS)
    fields |= _read_numbers(valves, fields["valve_law"])
    valves.done()
    solve = top.sub("solve", required=False) or _Reader(source, {}, "solve.")
    fields["accuracy"] = solve.choice("accuracy", ACCURACY, "default")
    fields |= _read_numbers(solve, "solve")
    solve.done()
    top.done()
    fields["max_beats"] = int(fields["max_beats"])
    return _validated(
        LoopScene(name=name, source=source, description=description, pump=pump, **fields)
    )


def _check(source: str, where: str, spec: _Number, value) -> None:
    if not isinstance(value, float | int) or isinstance(value, bool):
        return  # a traced value: checked where it entered
    u = value / spec.scale
    inside = math.isfinite(u) and (u > spec.lo if spec.lo_open else u >= spec.lo) and u <= spec.hi
    if not inside:
        raise ValueError(
            f"{source}: key '{where}' = {u:g} {spec.unit}".rstrip() + f": allowed {spec.allowed()}"
        )


def _validated(scene: LoopScene) -> LoopScene:
    """Check every number of ``scene`` against :data:`LOOP_KEYS` and the structural rules."""
    src = scene.source
    _check(src, "heart.bpm", LOOP_KEYS["heart"][0], scene.bpm)
    for table in (*CHAMBERS, *VESSELS):
        spec = getattr(scene, table)
        kind = "vessel" if table in VESSELS else spec.kind
        for key in LOOP_KEYS[kind]:
            _check(src, f"{table}.{key.key}", key, getattr(spec, key.field))
        if kind == "elastance" and _concrete(spec.contraction, spec.relaxation):
            if spec.contraction + spec.relaxation > 1.0 + 1e-12:
                raise ValueError(
                    f"{src}: keys '{table}.contraction_duration' + '{table}.relaxation_duration' "
                    f"= {spec.contraction + spec.relaxation:g}: allowed at most 1 (a period)"
                )
        if kind == "pump":
            total = spec.pull_fraction + spec.hold_fraction + spec.release_fraction
            if _concrete(total) and total > 1.0 + 1e-12:
                raise ValueError(
                    f"{src}: {table} pull + hold + release fractions = {total:g}: allowed at most 1"
                )
    if scene.valve_law not in VALVE_LAWS:
        raise ValueError(
            f"{src}: key 'valves.law' = {scene.valve_law!r}: allowed {', '.join(VALVE_LAWS)}"
        )
    for key in LOOP_KEYS[scene.valve_law]:
        _check(src, f"valves.{key.key}", key, getattr(scene, key.field))
    lo, hi = scene.valve_min_resistance, scene.valve_max_resistance
    if scene.valve_law == "regazzoni" and _concrete(lo, hi) and not hi > lo:
        raise ValueError(
            f"{src}: key 'valves.Rmax_mmHg_s_per_ml' = {hi / _R:g} mmHg s/ml: allowed above "
            f"Rmin = {lo / _R:g} mmHg s/ml"
        )
    for key in LOOP_KEYS["solve"]:
        _check(src, f"solve.{key.key}", key, getattr(scene, key.field))
    if scene.accuracy not in ACCURACY:
        raise ValueError(
            f"{src}: key 'solve.accuracy' = {scene.accuracy!r}: allowed {', '.join(ACCURACY)}"
        )
    return scene


def _concrete(*values) -> bool:
    return all(isinstance(v, float | int) for v in values)


def number_key(scene: LoopScene, path: str) -> _Number:
    """The key (unit, range) of the number at ``path`` of ``scene`` (:func:`loop_numbers`)."""
    table, _, field = path.partition(".")
    if path == "bpm":
        kind, field = "heart", path
    elif table in CHAMBERS:
        kind = getattr(scene, table).kind
    elif table in VESSELS:
        kind = "vessel"
    else:
        kind, field = scene.valve_law, path
    for spec in LOOP_KEYS[kind]:
        if spec.field == field:
            return spec
    raise ValueError(
        f"{path!r} is not a number of scene {scene.name}; allowed: "
        f"{', '.join(k for k in loop_numbers(scene) if _is_set(scene, k))}"
    )


def _is_set(scene: LoopScene, path: str) -> bool:
    value = loop_numbers(scene)[path]
    return not (isinstance(value, float) and math.isnan(value))
