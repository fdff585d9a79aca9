"""``run()`` and ``run_designs()``: a scene simulated as ``python -m cardiosoft.simulate`` does.

Both are thin: they apply the user's overrides (user units) to the scene, hand the members to
the public batch solve (:func:`cardiosoft.batch.solve_beats`, and
:func:`cardiosoft.batch.solve_static` for the bench's quasi-static strokes) and label the
records (:mod:`cardiosoft.results`).
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from cardiosoft._validate import check_range
from cardiosoft.pump import PumpSurrogate, check_pump_name
from cardiosoft.results import RunResult
from cardiosoft.scene import Scene, load_scene
from cardiosoft.scene_tools import check_supported, tools
from cardiosoft.units import mmHg

__all__ = ["configure", "run", "run_designs"]


def configure(
    scene="bench-dynamic",
    *,
    omega=None,
    shortening=None,
    bpm=None,
    afterload=None,
    accuracy=None,
    pump: str | None = None,
    effects=(),
) -> Scene:
    """The scene with the user's overrides (user units), validated; see :func:`run`."""
    if isinstance(scene, str | os.PathLike):
        scene = load_scene(scene, pump=pump)
    elif pump is not None and pump != scene.pump:
        scene = scene.replace(pump=check_pump_name(pump))
    scene = _add_effects(scene, effects)
    return tools(scene).configure(
        scene, omega=omega, shortening=shortening, bpm=bpm, afterload=afterload, accuracy=accuracy
    )


def _add_effects(scene, effects):
    """``scene`` with ``effects`` switched on besides its own (:data:`ADDABLE_EFFECTS`)."""
    effects = tuple(effects)
    if not effects:
        return scene
    allowed = tools(scene).addable_effects(scene)
    for effect in effects:
        if effect not in allowed:
            raise ValueError(
                f"effect = {effect!r}: scene {scene.name} can add {', '.join(allowed) or 'none'}; "
                "the other effects need their parameters: list them in a scene file"
            )
    return scene.replace(effects=tuple(dict.fromkeys(scene.effects + effects)))


def run(
    scene="bench-dynamic",
    *,
    omega=None,
    shortening=None,
    bpm=None,
    afterload=None,
    beats=None,
    accuracy=None,
    steady="beats",
    energy=False,
    max_steps=None,
    pump: PumpSurrogate | None = None,
    effects=(),
) -> RunResult:
    """Simulate a scene; the Python twin of ``python -m cardiosoft.simulate``.

    **Arguments** (user units; None keeps the scene's value):

    - ``scene``: a shipped scene name, a path to a scene file, or a :class:`Scene`; a
      closed-loop scene (``heart``, ``soft-lv``, ``soft-rv``, ``tah``) is run by
      :func:`cardiosoft.network.loop_results.run_loop` (``omega`` and ``shortening`` set every
      pump).
    - ``omega``: helix parameter, [0, 6]; ``shortening``: C, [0, 0.65].
    - ``bpm``: beats per minute, (0, 300].
    - ``afterload``: column head(s) in mmHg, [0, 150] (water-column scenes).
    - ``beats``: run exactly this many beats instead of stopping at the steady state.
    - ``accuracy``: "fast", "default" or "reference".
    - ``steady``: "beats" (beat after beat) or "shooting" (Newton shooting on the one-beat map,
      robust at high rates); see :func:`cardiosoft.batch.solve_beats`.
    - ``energy``: keep each beat's energy account; adds ``energy_efficiency`` (work delivered
      past the outlet over work put in, in [0, 1] at any rate) and ``energy_residual``.
    - ``max_steps``: the most solver steps per beat, [100, 10^7] (default: the preset's, 16384
      or 65536 for "reference"); a stiff case that runs out of steps says so.
    - ``pump``: a :class:`~cardiosoft.pump.PumpSurrogate` (default: the shipped one).
    - ``effects``: effects to switch on besides the scene's own, of those that need no
      parameters (:data:`~cardiosoft.scene.ADDABLE_EFFECTS`), e.g. ``("cable_slack",)``.

    **Returns:** a :class:`~cardiosoft.results.RunResult`, one member per afterload. Each member
    says whether it can be trusted: ``ok`` (solved, at its periodic steady state) and ``flags``
    (outside the surrogate's fitted range, a cable that would push, a metric not meaningful).
    Bad input raises ``ValueError`` naming the parameter.
    """
    scene = configure(
        scene,
        omega=omega,
        shortening=shortening,
        bpm=bpm,
        afterload=afterload,
        accuracy=accuracy,
        effects=effects,
    )
    config = None
    if max_steps is not None:
        if isinstance(max_steps, bool) or not isinstance(max_steps, int | np.integer):
            raise ValueError(f"max_steps = {max_steps!r}: allowed a whole number in [100, 1e7]")
        check_range("max_steps", max_steps, "steps", 100, 1e7)
        config = dataclasses.replace(tools(scene).preset(scene), max_steps=int(max_steps))
    kind = tools(scene)
    return kind.run(scene, beats=beats, steady=steady, energy=energy, config=config, pump=pump)


def run_designs(
    scene="bench-dynamic",
    designs=((4.0, 0.4),),
    *,
    bpm=None,
    afterload=None,
    beats=None,
    accuracy=None,
    steady="beats",
    pump: PumpSurrogate | None = None,
) -> RunResult:
    """Simulate several designs (Omega, C) at every afterload of a scene in one compiled call.

    ``designs`` is a non-empty sequence of ``(omega, shortening)`` pairs; the other arguments
    are those of :func:`run`. Members are labelled ``"Omega 4, C 0.4, 30 mmHg"``. Keep the
    designs of one sweep alike: the batch runs until its slowest member reaches steady state.
    """
    scene = configure(scene, bpm=bpm, afterload=afterload, accuracy=accuracy)
    check_supported(scene, "designs", "designs")
    designs = [tuple(d) for d in designs]
    if not designs or any(len(d) != 2 for d in designs):
        raise ValueError(
            f"designs = {designs!r}: allowed a non-empty sequence of (omega, shortening) pairs"
        )
    for omega, shortening in designs:
        configure(scene, omega=omega, shortening=shortening)  # validates each design
    kind = tools(scene)
    has_heads = kind.column_heads(scene, None, "set") is not None
    heads = scene.afterloads if has_heads else (None,)
    labels, omegas, shortenings, members_heads = [], [], [], []
    for omega, shortening in designs:
        for h in heads:
            where = f", {h / mmHg:g} mmHg" if h is not None else ""
            labels.append(f"Omega {omega:g}, C {shortening:g}{where}")
            omegas.append(float(omega))
            shortenings.append(float(shortening))
            members_heads.append(h)
    members = {"omega": np.asarray(omegas), "shortening": np.asarray(shortenings)}
    if has_heads:
        members["afterload"] = np.asarray(members_heads)
    return kind.simulate_members(scene, labels, members, beats, steady, pump)
