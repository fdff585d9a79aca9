"""Hypothesis' draws of the hard-case suite (group ``property``): the scene's numbers
(actuation fractions, the bench's column, tube, loss, friction and viscoelasticity; the
Windkessel, venous and atrial pressures, valves) and each member's Omega, C, bpm and column head
over their whole allowed ranges (:data:`cardiosoft.scene.RANGES`), edges and odd values
included. Each draw is a :class:`~cardiosoft.stress.cases.Batch` as large as the grid's batches
of its scene, so that it compiles nothing new."""

from __future__ import annotations

from cardiosoft.scene import RANGES, Scene, load_scene
from cardiosoft.stress.cases import (
    FIELD_SCALES,
    VALVE_RESISTANCE_RANGE,
    WINDKESSEL_OPEN_AT_LO,
    WINDKESSEL_RANGES,
    Batch,
    design_members,
    water_column_scenes,
    windkessel_scenes,
)
from cardiosoft.units import ml_per_mmHg, mmHg_s_per_ml

__all__ = ["property_batches"]


def _lo_open(scene: Scene, field: str, scale: float) -> bool:
    """Whether the lower end of ``RANGES[field]`` is excluded: ``Scene.replace`` refuses it."""
    try:
        scene.replace(**{field: RANGES[field][0] * scale})
    except ValueError:
        return True
    return False


def _ranged(st, scene: Scene, field: str):
    """A strategy of SI values over the field's whole allowed range."""
    lo, hi = RANGES[field]
    scale = FIELD_SCALES[field]
    return _floats(st, lo, hi, _lo_open(scene, field, scale), scale)


def _floats(st, lo, hi, lo_open=False, scale=1.0):
    """Floats in [lo, hi] (user unit; (lo, hi] if ``lo_open``) as SI values. Subnormal floats
    are left out, and so is a positive value that the unit's scale turns into 0."""
    values = st.floats(lo, hi, exclude_min=lo_open, allow_subnormal=False)
    if scale == 1.0:
        return values
    return values.map(lambda v: v * scale).filter(lambda v: v > 0 or not lo_open)


def _open_floats(st, lo_hi, scale=1.0):
    return _floats(st, *lo_hi, True, scale)


def _draw_batch(data, st, base: Scene, title: str, size: int, numbers: bool, bpms) -> Batch:
    """One example: the scene's numbers (``numbers``; else the shipped scene's), then ``size``
    members (Omega, C, bpm, column head), all over their whole allowed ranges (the rate over
    ``bpms`` when given)."""
    changes = {}
    fields = []
    if numbers and not base.static:
        # the actuation's fractions: pull and release in (0, 1], hold >= 0, their sum at most 1
        no_subnormal = dict(allow_subnormal=False)
        pull = data.draw(st.floats(0.0, 1.0, exclude_min=True, exclude_max=True, **no_subnormal))
        release = data.draw(st.floats(0.0, 1.0 - pull, exclude_min=True, **no_subnormal))
        hold = data.draw(st.floats(0.0, (1.0 - pull) - release, **no_subnormal))
        changes |= {"pull_fraction": pull, "release_fraction": release, "hold_fraction": hold}
    if numbers and base.afterload.has_heads:
        fields = ["column_diameter", "tube_length", "tube_diameter"]
        fields += [] if base.static else ["loss_coefficient"]
    elif numbers:
        fields = ["venous_pressure", "preload_pressure", "valve_smoothing"]
        changes["windkessel"] = tuple(
            data.draw(_floats(st, *WINDKESSEL_RANGES[k], WINDKESSEL_OPEN_AT_LO[k], s))
            for k, s in (("Rp", mmHg_s_per_ml), ("C", ml_per_mmHg), ("Rd", mmHg_s_per_ml))
        )
        changes["valve_resistance"] = tuple(
            data.draw(_floats(st, *VALVE_RESISTANCE_RANGE, True, mmHg_s_per_ml)) for _ in "io"
        )
    for effect, names in (
        ("cable_friction", ["cable_friction"]),
        ("shell_viscoelasticity", ["viscoelastic_ratio", "relaxation_time"]),
    ):
        if numbers and base.has(effect):
            fields += names
    for field in fields:
        changes[field] = data.draw(_ranged(st, base, field))
    members = []
    for _ in range(size):
        member = {
            "omega": _floats(st, *RANGES["omega"]),
            "shortening": _floats(st, *RANGES["shortening"]),
        }
        if not base.static:
            # (0, 300]: open at 0 (documented)
            member["bpm"] = _floats(st, *RANGES["bpm"], True) if bpms is None else st.floats(*bpms)
        if base.afterload.has_heads:
            member["afterload"] = _floats(st, *RANGES["afterloads"])
        members.append({k: data.draw(s) for k, s in member.items()})
    prefix = f"property/{base.name}/{title.replace(' ', '-')}"
    return Batch(
        group="property",
        title=f"{base.name} hypothesis {title}",
        scene=base.name,
        omega=tuple(m["omega"] for m in members),
        shortening=tuple(m["shortening"] for m in members),
        bpm=None if base.static else tuple(m["bpm"] for m in members),
        afterload_mmHg=tuple(m["afterload"] for m in members) if base.afterload.has_heads else None,
        ids=tuple(
            f"{prefix}/member{j}:"
            + ",".join(f"{'C' if k == 'shortening' else k}={v!r}" for k, v in m.items())
            for j, m in enumerate(members)
        ),
        changes=tuple(changes.items()),
    )


def property_batches(
    scenes, examples: int, seed: int, skip_minimal: bool = False, numbers: bool = True, bpms=None
) -> list[Batch]:
    """``examples`` hypothesis draws per scene structure (the static bench, a water column, a
    Windkessel), each one batch of as many members as the grid's batches of that scene (no new
    compile). ``numbers``: draw the scene's numbers too (else only the members). ``bpms``: the
    rates' range (default: the whole allowed one).

    Hypothesis draws the minimal example first: every number at the low end of its range
    (2.2e-308 for a range open at 0). ``skip_minimal`` leaves it out."""
    try:
        from hypothesis import HealthCheck, Phase, given, settings
        from hypothesis import seed as fix_seed
        from hypothesis import strategies as st
    except ImportError:  # a test extra: pip install -e ".[test]"
        return []
    static = [s for s in scenes if load_scene(s).static]
    bases = [
        load_scene(k[0])
        for k in (static, water_column_scenes(scenes), windkessel_scenes(scenes))
        if k
    ]
    what = "example" if numbers else "members example"

    def draws(base: Scene) -> list[Batch]:
        size = len(design_members(base))
        drawn: list[Batch] = []

        @fix_seed(seed)
        @settings(
            max_examples=examples + skip_minimal,
            database=None,
            deadline=None,
            phases=(Phase.generate,),
            suppress_health_check=list(HealthCheck),
        )
        @given(st.data())
        def collect(data):
            title = f"{what} {len(drawn)}"
            drawn.append(_draw_batch(data, st, base, title, size, numbers, bpms))

        collect()
        return drawn[int(skip_minimal) :][:examples]

    return [b for base in bases for b in (draws(base) if examples > 0 else [])]
