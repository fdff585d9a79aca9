"""Calculation verification: a run's numerical error, estimated by running it again, tighter.

    import cardiosoft as cs

    result = cs.run("bench-dynamic", bpm=60)
    check = cs.verify_run(result)    # reruns at the reference preset
    print(check.table())             # per member and metric: run, reference, difference
    check.record()                   # JSON-ready, what `simulate --verify` adds to summary.json

In the terms of ASME V&V 40 this is *calculation verification* (how far the computed numbers
are from the exact solution of the model's equations), next to the *validation* against the
paper's measurements (how far the model is from the bench). The difference between the run and
a rerun of the same members at a much tighter setting is the estimate of the run's numerical
error; it is a good estimate when the rerun's own error is much smaller, which
``notebooks/accuracy.ipynb`` (and ``python benchmarks/work_precision.py``) measure for every
shipped scene.

What is rerun (by the scene's kind, :func:`cardiosoft.scene_tools.tools`' ``verify_rerun``; the
numbers checked are its ``verified``):

- **dynamic scenes**, open loops and closed loops alike: the same members, beats and stopping
  rule (the periodic steady state, or exactly ``beats`` beats), solved at the ``"reference"``
  preset (:func:`cardiosoft.preset`, stiff when an open loop has valves). A run that is at
  ``"reference"`` already is rerun with ``rtol`` and ``atol`` 100 times tighter still.
- **quasi-static strokes** (the ``static_*`` numbers of the bench, and the ``bench-static``
  scene): the pull grid, which sets the peak force, 10 times finer. Their stroke volume and work
  come from the end of the pull and the energy balance; the root find converges to rounding, so
  their difference is (close to) zero.

The estimate covers the discretisation in time (and the pull grid). The steady-state
iteration's error is reported beside it by every run (``steady_residual`` of
:func:`cardiosoft.summary_records`, the cycle-to-cycle change of the last beat); a rerun that
stops after a different number of beats shows it in its ``beats``.
"""

from __future__ import annotations

import dataclasses
import math
import time

from cardiosoft.files import json_ready
from cardiosoft.open_loop_tools import (  # an open loop's, named here as they always were
    STATIC_GRID_REFINEMENT,
    STATIC_POINTS,
    VERIFIED,
    fine_static,
)
from cardiosoft.pump import PumpSurrogate, load
from cardiosoft.results import RunResult
from cardiosoft.scene_tools import tools
from cardiosoft.solve import TIGHTER, describe
from cardiosoft.units import mmHg

__all__ = [
    "METRICS",
    "STATIC_GRID_REFINEMENT",
    "STATIC_POINTS",
    "TIGHTER",
    "Verification",
    "describe",
    "fine_static",
    "reference_config",
    "verify_run",
]

METRICS = VERIFIED
"""The numbers an open-loop scene's ``--verify`` checks (a closed loop's: its namespace's
``verified``): (key, name, unit)."""


@dataclasses.dataclass(frozen=True)
class Verification:
    """What :func:`verify_run` returns: the run beside its tighter rerun, member by member.

    - ``run_setting``, ``reference_setting``: the two numerical settings in words.
    - ``seconds``: wall time of the check (the rerun, compile included).
    - ``members``: one dict per member: ``label``, ``beats`` and ``reference_beats``, and
      ``metrics``: ``{key: {"run", "reference", "difference", "relative"}}`` in the units of
      :data:`METRICS` (``difference = run - reference``, the error estimate; ``relative`` its
      size relative to ``|reference|``, NaN where that is 0).
    - ``ok``: every rerun member succeeded (and reached its steady state when the run did).
    """

    scene: str
    run_setting: str
    reference_setting: str
    seconds: float
    members: tuple[dict, ...]
    ok: bool
    metrics: tuple[tuple[str, str, str], ...] = METRICS
    """The numbers checked, (key, name, unit), in the table's order."""

    def record(self) -> dict:
        """JSON-ready (NaN as ``None``): the ``"verification"`` entry of ``summary.json``."""

        return json_ready(
            {
                "kind": "calculation verification (ASME V&V 40): the run against a tighter rerun",
                "scene": self.scene,
                "run_setting": self.run_setting,
                "reference_setting": self.reference_setting,
                "seconds": self.seconds,
                "ok": self.ok,
                "members": list(self.members),
            }
        )

    def cost(self, run_seconds: float | None = None) -> str:
        """What the check cost, in words (and against the run's own time, when given)."""
        cost = f"the check took {self.seconds:.1f} s (compile included)"
        if run_seconds:
            cost += f", {self.seconds / run_seconds:.1f}x the run's {run_seconds:.1f} s"
        return cost

    def table(self, run_seconds: float | None = None, *, timing: bool = True) -> str:
        """The check in words and one line per member and metric (what ``--verify`` prints).

        ``timing=False`` leaves out the line with the time the check took (it varies).
        """
        lines = [
            "calculation verification (ASME V&V 40): the difference from a tighter rerun "
            "estimates the run's numerical error",
            f"  run:       {self.run_setting}",
            f"  reference: {self.reference_setting}",
            *([f"  {self.cost(run_seconds)}"] if timing else []),
        ]
        if any(m["beats"] for m in self.members):  # a quasi-static run has no beats
            lines.append(
                "  beats: run "
                + "/".join(str(m["beats"]) for m in self.members)
                + ", reference "
                + "/".join(str(m["reference_beats"]) for m in self.members)
            )
        head = ("member", "metric", "unit", "run", "reference", "difference", "relative")
        rows = []
        for m in self.members:
            for key, name, unit in self.metrics:
                if key not in m["metrics"]:
                    continue
                v = m["metrics"][key]
                rel = v["relative"]
                rows.append(
                    (
                        m["label"],
                        name,
                        unit,
                        f"{v['run']:.6g}",
                        f"{v['reference']:.6g}",
                        f"{v['difference']:+.2e}",
                        "-" if rel is None or not math.isfinite(rel) else f"{rel:.1e}",
                    )
                )
        widths = [max(len(r[i]) for r in (head, *rows)) for i in range(len(head))]
        left = {0, 1, 2}
        for r in (head, *rows):
            cells = [
                c.ljust(w) if i in left else c.rjust(w)
                for i, (c, w) in enumerate(zip(r, widths, strict=True))
            ]
            lines.append("  " + "  ".join(cells))
        if not self.ok:
            lines.append("  warning: the rerun did not succeed for every member; see its beats")
        return "\n".join(lines)


def reference_config(scene):
    """The tighter setting a dynamic run of ``scene`` is checked against (module docstring)."""
    preset = tools(scene).preset
    if scene.accuracy != "reference":
        return preset(scene.replace(accuracy="reference"))
    config = preset(scene)
    return dataclasses.replace(config, rtol=config.rtol / TIGHTER, atol=config.atol / TIGHTER)


def verify_run(
    result: RunResult,
    *,
    beats: int | None = None,
    steady: str = "beats",
    pump: PumpSurrogate | None = None,
) -> Verification:
    """Rerun the members of ``result`` (a :func:`cardiosoft.run`) tighter; see the module docstring.

    ``beats`` and ``steady``: what the run was given (default: beat after beat to the steady
    state); the rerun uses the same. ``pump``: the surrogate of the run (default the shipped
    one). Raises ``ValueError`` for a result that is not a ``run()`` of its scene (as a
    ``run_designs()`` of several designs is not).
    """
    scene = result.scene
    pump = load(scene.pump) if pump is None else pump
    tool = tools(scene)
    start = time.perf_counter()
    reference, run_setting, reference_setting, succeeded = tool.verify_rerun(
        result, reference_config(scene), beats=beats, steady=steady, pump=pump
    )
    seconds = time.perf_counter() - start
    checked = tool.verified(scene)
    ran, ref = tool.summary_records(result), tool.summary_records(reference)
    members = []
    for a, b, m_run, m_ref in zip(ran, ref, result.members, reference.members, strict=True):
        metrics = {}
        for key, _, _ in checked:
            if a.get(key) is None or b.get(key) is None:
                continue
            x, y = float(a[key]), float(b[key])
            metrics[key] = {
                "run": x,
                "reference": y,
                "difference": x - y,
                "relative": abs(x - y) / abs(y) if y != 0 else math.nan,
            }
        members.append(
            {
                "label": m_run.label,
                "afterload_mmHg": None if m_run.afterload is None else m_run.afterload / mmHg,
                "beats": m_run.beats,
                "reference_beats": m_ref.beats,
                "reference_message": m_ref.message,
                "metrics": metrics,
            }
        )
    # the rerun is trusted where the run was: it succeeded (and is steady) wherever the run is
    ok = succeeded and all(
        m_ref.ok or not m_run.ok
        for m_ref, m_run in zip(reference.members, result.members, strict=True)
    )
    return Verification(
        scene.name, run_setting, reference_setting, seconds, tuple(members), ok, checked
    )
