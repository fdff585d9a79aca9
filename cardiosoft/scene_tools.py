"""What the tools do with a scene, by its kind: the one place that knows the kinds of scene.

Each kind answers the same questions through its own namespace: :mod:`cardiosoft.open_loop_tools`
for an open-loop :class:`~cardiosoft.scene.Scene` (the pump with a water column or a
Windkessel), :mod:`cardiosoft.network.closed_loop_tools` for a closed loop
(:class:`~cardiosoft.network.loop_scene.LoopScene`); the first lists the names. The tools
(:func:`cardiosoft.run`, ``simulate``, ``design``, ``export``, the posterior's ensemble) ask
:func:`tools` and never branch on the kind of scene; a new kind of scene registers its namespace
in :data:`TOOLS`. Until issue #40 makes every scene one network, there are two.
"""

from __future__ import annotations

import os

from cardiosoft import open_loop_tools
from cardiosoft.network import closed_loop_tools
from cardiosoft.network.loop_scene import LoopScene
from cardiosoft.scene import Scene, load_scene

__all__ = ["TOOLS", "check_supported", "solve_beats", "summary_records", "tools"]

TOOLS = {Scene: open_loop_tools, LoopScene: closed_loop_tools}
"""Each kind of scene and its namespace."""


def tools(scene):
    """The namespace of what the tools do with ``scene``'s kind (:data:`TOOLS`)."""
    try:
        return TOOLS[type(scene)]
    except KeyError:
        raise TypeError(f"{scene!r} is not a scene (load one with load_scene)") from None


def check_supported(scene, what: str, option: str) -> None:
    """Raise ``ValueError`` naming ``option`` when ``scene`` cannot do ``what`` (one of
    :data:`cardiosoft.open_loop_tools.ABILITIES`), saying why."""
    reason = tools(scene).unsupported(scene, what)
    if reason is not None:
        raise ValueError(f"{option}: scene {scene.name} {reason}")


def solve_beats(scene="bench-dynamic", **options):
    """Simulate a batch of members of any scene (a scene, a shipped scene's name or a scene
    file) to their periodic steady state: :func:`cardiosoft.batch.solve_beats` of an open-loop
    scene, :func:`cardiosoft.network.loop_batch.solve_loop` of a closed loop (``omega`` and
    ``shortening`` setting every pump; metrics
    :class:`~cardiosoft.network.loop_batch.LoopMetrics`). ``options`` are those of
    :func:`cardiosoft.batch.solve_beats`."""
    scene = load_scene(scene) if isinstance(scene, str | os.PathLike) else scene
    return tools(scene).solve_beats(scene, **options)


def summary_records(result) -> list[dict]:
    """One JSON-ready record per member of a :class:`~cardiosoft.results.RunResult`, in user
    units (``summary.json``), as the scene's kind writes them."""
    return tools(result.scene).summary_records(result)
