"""Ensembles: a pump whose fitted leaves carry a leading axis of draws (a posterior,
:func:`cardiosoft.pump.load_posterior`), solved by :func:`cardiosoft.solve_beats` as one more
batch axis in one compiled call."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from cardiosoft.pump import PumpSurrogate

__all__ = ["ensemble_axes", "ensemble_size", "flat_batch", "unflatten"]


def ensemble_size(
    pump: PumpSurrogate, scene_draws: dict | None = None, drawable: tuple[str, ...] = ()
) -> int | None:
    """The number of draws S of an ensemble, or None for a single pump and no ``scene_draws``.

    A pump is an ensemble when some of its array leaves have one leading axis more than the
    same leaf of a single :class:`~cardiosoft.pump.PumpSurrogate` (the draws); every such axis,
    and every array of ``scene_draws`` (one value per draw), must have the same length S.
    ``ValueError`` otherwise.
    """
    sizes = {len(v) for v in _ensemble_leaves(pump) if v is not None}
    for field, values in (scene_draws or {}).items():
        if field not in drawable:
            allowed = ", ".join(drawable)
            raise ValueError(f"scene_draws: {field!r} is not a scene number; allowed {allowed}")
        if jnp.ndim(values) != 1 or len(values) == 0:
            raise ValueError(
                f"scene_draws[{field!r}]: one value per draw (a 1-D array), got shape "
                f"{jnp.shape(values)}"
            )
        sizes.add(len(values))
    if len(sizes) > 1:
        raise ValueError(
            f"ensemble: the draws disagree in number ({sorted(sizes)}); the pump's leading axes "
            "and every scene_draws array must have one length"
        )
    return sizes.pop() if sizes else None


def ensemble_axes(pump: PumpSurrogate):
    """``in_axes`` for ``jax.vmap`` over the draws of an ensemble pump: 0 on its drawn leaves,
    None on the shared ones (e.g. ``jax.vmap(f, in_axes=(ensemble_axes(p),))(p)``)."""
    return jax.tree_util.tree_unflatten(
        jax.tree_util.tree_structure(pump),
        [None if a is None else 0 for a in _ensemble_leaves(pump)],
    )


def _ensemble_leaves(pump: PumpSurrogate) -> list:
    """Per array leaf of ``pump``: the leaf if it carries a leading axis of draws, else None."""
    single = PumpSurrogate(domain=pump.domain)
    out = []
    for leaf, ref in zip(
        jax.tree_util.tree_leaves(pump), jax.tree_util.tree_leaves(single), strict=True
    ):
        extra = jnp.ndim(leaf) - jnp.ndim(ref)
        if extra not in (0, 1) or (extra == 1 and jnp.shape(leaf)[1:] != jnp.shape(ref)):
            raise ValueError(
                f"pump: an array of shape {jnp.shape(leaf)} where a single pump has "
                f"{jnp.shape(ref)}: an ensemble adds one leading axis of draws, nothing else"
            )
        out.append(leaf if extra == 1 else None)
    return out


def flat_batch(members: dict, pump: PumpSurrogate, scene_draws: dict, size: int):
    """The members of an ensemble solve on one flat axis, draw-major (index s M + i), each with
    its draw's scene numbers and pump arrays; and the pump's shared rest."""
    n = next(iter(members.values())).shape[0]
    ftype = jnp.result_type(float)
    batch = {k: jnp.tile(v, size) for k, v in members.items()}
    for field, values in scene_draws.items():
        batch[field] = jnp.repeat(jnp.asarray(values, dtype=ftype), n)
    arrays, rest = eqx.partition(pump, eqx.is_array)
    drawn = iter(_ensemble_leaves(pump))
    batch["pump"] = jax.tree_util.tree_map(
        lambda a: (
            jnp.broadcast_to(a, (size * n, *jnp.shape(a)))
            if next(drawn) is None
            else jnp.repeat(a, n, axis=0)
        ),
        arrays,
    )
    return batch, rest


def unflatten(tree, size: int):
    """Arrays of a flat ensemble batch (S M, ...) as (S, M, ...)."""
    return jax.tree_util.tree_map(lambda a: a.reshape((size, -1, *a.shape[1:])), tree)
