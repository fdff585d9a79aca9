"""What a batch solve returns, and what its two kinds share: the pump scenes'
(:func:`cardiosoft.batch.solve_beats`) and the closed loops'
(:func:`cardiosoft.network.loop_batch.solve_loop`).

:class:`BeatSolution`, the options both take (:data:`SAVE_MODES`, :data:`STEADY_METHODS`,
:func:`check_solve_options`), the members broadcast to one batch axis
(:func:`broadcast_members`) and spread over the devices (:func:`shard`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft._validate import check_range
from cardiosoft.metrics import BeatMetrics
from cardiosoft.solve import SUCCESSFUL, result_message

__all__ = [
    "GUESS_BEATS",
    "SAVE_MODES",
    "STEADY_METHODS",
    "BeatSolution",
    "broadcast_members",
    "check_solve_options",
    "shard",
    "solution",
]

SAVE_MODES = ("traces", "metrics", "state")
STEADY_METHODS = ("beats", "shooting")
"""How the periodic steady state is reached: beat after beat, or by Newton shooting."""
GUESS_BEATS = 3
"""Beats from rest before Newton shooting starts from their end."""


class BeatSolution(eqx.Module):
    """What :func:`~cardiosoft.batch.solve_beats` returns; every array has the batch axis
    first (SI).

    - ``members``: the member values, ``{"omega", "shortening", "bpm", "afterload"}`` (the
      afterload, a column head in Pa, is NaN for a Windkessel scene).
    - ``metrics``: the last beat's :class:`~cardiosoft.metrics.BeatMetrics` (None with
      ``save="state"``); a closed loop's :class:`~cardiosoft.network.loop_batch.LoopMetrics`.
    - ``traces``: with ``save="traces"``, the last beat: ``time`` (s, from 0 to the period),
      ``volume`` and the other states, and every signal of :meth:`PumpCircuit.signals`;
      ``None`` with ``save="metrics"`` or ``"state"``.
    - ``y0``: the state at the start of the last beat (SI, a dict by the state's names): on a
      steady member a point of its periodic orbit, where
      :func:`~cardiosoft.batch.solve_orbit` starts.
    - ``beats``: beats integrated; ``residual``: the cycle-to-cycle change of the last beat
      (ml, ml/s or mmHg); ``volume_drift``: the largest relative change of the total fluid
      volume; ``result``: diffrax's result code (0 successful; in words
      :func:`cardiosoft.solve.result_message`); ``num_steps``: solver steps of the last beat;
      ``newton_steps``: Newton iterations of ``steady="shooting"`` (0 otherwise).
    - ``steady_tol`` (static): the scene's tolerance ``residual`` is held to, also with a fixed
      number of beats (``fixed_beats``), which may end before the steady state.
    """

    members: dict
    metrics: BeatMetrics | None
    traces: dict | None
    y0: dict
    beats: jax.Array
    residual: jax.Array
    volume_drift: jax.Array
    result: jax.Array
    num_steps: jax.Array
    newton_steps: jax.Array
    steady_tol: float = eqx.field(static=True)
    fixed_beats: bool = eqx.field(static=True, default=False)
    max_steps: int = eqx.field(static=True, default=0)

    @property
    def succeeded(self) -> jax.Array:
        """Per member: the solver finished every beat."""
        return self.result == SUCCESSFUL

    @property
    def steady(self) -> jax.Array:
        """Per member: at its periodic steady state, the last beat's cycle-to-cycle change within
        the scene's tolerance (also when a fixed number of beats was asked for)."""
        return self.residual <= self.steady_tol

    def message(self, i: int) -> str:
        """Member ``i`` in words: ``"ok"``, not steady, or why the solver failed."""
        beats = int(self.beats[i])
        if not bool(self.succeeded[i]):
            reason = result_message(self.result[i])
            hint = ""
            if "max_steps" in reason:
                hint = (
                    f" ({self.max_steps} per beat now: run(max_steps=...), --max-steps; or a "
                    "looser accuracy preset)"
                )
            return f"solver failed in beat {beats}: {reason}{hint}"
        if not bool(self.steady[i]):
            return (
                f"not steady after {beats} beats (cycle change {float(self.residual[i]):.3g} > "
                f"{self.steady_tol:g}): a transient, not the periodic steady state"
                + ("" if self.fixed_beats else "; try steady='shooting' (--steady shooting)")
            )
        return "ok"


def broadcast_members(values: dict) -> dict:
    """Member values (scalars or 1-D arrays) as float arrays broadcast to one batch axis; a
    ``ValueError`` names the one that does not fit (also for a closed loop's members)."""
    ftype = jnp.result_type(float)
    arrays = {k: jnp.asarray(v, dtype=ftype) for k, v in values.items()}
    for k, v in arrays.items():
        if v.ndim > 1:
            raise ValueError(f"{k}: a scalar or a 1-D array of members, got shape {v.shape}")
    empty = [k for k, v in arrays.items() if v.size == 0]
    if empty:
        raise ValueError(f"{empty[0]}: the batch is empty; give at least one member")
    try:
        shape = jnp.broadcast_shapes(*(v.shape for v in arrays.values()), (1,))
    except ValueError:
        sizes = ", ".join(f"{k} {v.shape[0]}" for k, v in arrays.items() if v.ndim)
        raise ValueError(
            f"members: {sizes} values do not broadcast to one batch; give scalars or "
            "arrays of one common length"
        ) from None
    return {k: jnp.broadcast_to(v, shape) for k, v in arrays.items()}


def check_solve_options(save, steady, beats) -> None:
    """``ValueError`` unless ``save``, ``steady`` and ``beats`` are ones a batch solve takes."""
    if save not in SAVE_MODES:
        raise ValueError(f"save = {save!r}: allowed {', '.join(SAVE_MODES)}")
    if steady not in STEADY_METHODS:
        raise ValueError(f"steady = {steady!r}: allowed {', '.join(STEADY_METHODS)}")
    if beats is not None:
        if isinstance(beats, bool) or not isinstance(beats, int | np.integer):
            raise ValueError(f"beats = {beats!r}: allowed a whole number in [1, 500]")
        check_range("beats", beats, "beats", 1, 500)


def shard(tree):
    """Spread the batch over all devices when it divides evenly (one device: unchanged)."""
    devices = jax.devices()
    n = jax.tree_util.tree_leaves(tree)[0].shape[0]
    if len(devices) < 2 or n % len(devices):
        return tree
    mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
    return jax.tree_util.tree_map(lambda a: jax.device_put(a, sharding), tree)


def solution(scene, members, config, metrics, traces, out, fixed_beats) -> BeatSolution:
    return BeatSolution(
        members=members,
        metrics=metrics,
        traces=traces,
        y0=out.y0,
        beats=out.beats,
        residual=out.residual,
        volume_drift=out.volume_drift,
        result=out.result,
        num_steps=out.num_steps,
        newton_steps=out.newton_steps,
        steady_tol=float(scene.steady_tol),
        fixed_beats=fixed_beats,
        max_steps=config.max_steps,
    )
