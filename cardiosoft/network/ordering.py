"""The nodes' equations put in solving order: one small solve after another instead of one dense
Newton on all of them.

Most lumped circulations are causal: each node's pressure is set by one block (a capacitor's
state, a chamber's law) and each flow by one other (an inductor's state, a valve's law at the
pressures already known). Their node equations are then triangular after a permutation, and a
solve of them one by one costs what a hand-written vector field costs. Where some equations are
coupled (a resistor loop, a junction between algebraic resistances) they form one block of the
permutation that is solved together.

:func:`order_nodes` finds that permutation once, when the network is built, from which unknowns
each residual holds (the sparsity of ``dg/dz`` at random points):

1. a perfect matching of residuals to unknowns (each residual solved for one unknown), of
   least cost where a residual costs more for an unknown it is not affine in (a tanh or
   piecewise valve is solved for its flow, at pressures already known, not for a pressure);
2. the strongly connected components of the graph "unknown -> the unknowns its residual
   holds" (scipy's), grouped into stages in topological order (:class:`graphlib.
   TopologicalSorter`): a stage's components need only earlier stages;
3. for each component, whether its residuals are affine in its own unknowns (their Jacobian
   unchanged when only those move, at random points): one Newton step from anywhere is then
   exact; otherwise its stage takes ``NEWTON_STEPS`` more.

Each stage evaluates the blocks that own its rows once, with one forward-mode derivative. A
stage of one-unknown components is an elementwise division, with no LU (the closed loop's four
stages: the pressures and the vessels' flows, each chamber's outlet pressure, the valves'
inflows, their outflows); only a stage with coupled unknowns solves a small dense system.

A run of an svZeroDSolver model still checks the nodes against the whole set of equations at
its output times (:meth:`Network.newton_converged`), so that an order built on a mistaken
sparsity would be caught.
"""

from __future__ import annotations

import graphlib
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, min_weight_full_bipartite_matching

SPARSITY_POINTS = 3
"""Random points at which the residuals' sparsity and the components' affinity are sampled: a
coincidental zero at one is not one at all of them."""


@dataclass(frozen=True)
class Stage:
    """One stage of the solving order: unknowns (indices into ``z``) that depend only on earlier
    stages' and on each other within their component. ``owners``: per block index, its local
    residual rows, in the unknowns' order; ``scalar``: every component has one unknown (the
    stage's Jacobian in its unknowns is then diagonal); ``affine``: every component's rows are
    affine in its own unknowns (one Newton step is exact); ``aliases``: (u, v) pairs of
    unknowns that a residual ``c (z_u - z_v)`` sets equal (a chamber's two pressures, a valve's
    two flows), copied without evaluating their block."""

    unknowns: tuple[int, ...]
    owners: tuple[tuple[int, tuple[int, ...]], ...]
    scalar: bool
    affine: bool
    aliases: tuple[tuple[int, int], ...] = ()
    slopes: tuple[float, ...] | None = None
    """Each row's derivative in its unknown where every one is a constant of the wiring (the
    same at every sampled point and for randomly scaled parameters, like the 1 of
    ``P - law(V)``): the step is then a division by it, with no derivative traced."""


def _points(net, x0, t, n, rng):
    """Random (t, x, z) about the start: each state scaled by a factor in [0.5, 1.5] (a zero
    state by a unit normal), the nodes' unknowns unit normals."""
    x0 = np.asarray(x0, dtype=float)
    for _ in range(n):
        scale = rng.uniform(0.5, 1.5, x0.shape)
        x = np.where(x0 != 0, x0 * scale, rng.standard_normal(x0.shape))
        z = rng.standard_normal(2 * net.n_nodes)
        yield jnp.asarray(t + rng.uniform(0.0, net.period)), jnp.asarray(x), jnp.asarray(z)


def stored_order(net, x0) -> tuple[Stage, ...] | None:
    """:func:`order_nodes` of ``net`` from ``x0``, kept in a command's program store
    (:func:`cardiosoft.program_store.stored_value`): a model read again by a later process is
    not ordered again (0.9 s of the 3.3 s of a warm run of ``closedLoopHeart_singleVessel``)."""
    from cardiosoft.program_store import stored_value

    def encode(stages):
        if stages is None:
            return None
        return [
            {
                "unknowns": [int(u) for u in s.unknowns],
                "owners": [[int(b), [int(r) for r in rows]] for b, rows in s.owners],
                "scalar": bool(s.scalar),
                "affine": bool(s.affine),
                "aliases": [[int(u), int(v)] for u, v in s.aliases],
                "slopes": None if s.slopes is None else [float(x) for x in s.slopes],
            }
            for s in stages
        ]

    def decode(stages):
        if stages is None:
            return None
        return tuple(
            Stage(
                tuple(s["unknowns"]),
                tuple((b, tuple(rows)) for b, rows in s["owners"]),
                s["scalar"],
                s["affine"],
                tuple((u, v) for u, v in s["aliases"]),
                None if s["slopes"] is None else tuple(s["slopes"]),
            )
            for s in stages
        )

    return stored_value("order_nodes", (net, x0), lambda: order_nodes(net, x0), encode, decode)


def order_nodes(net, x0, seed: int = 0) -> tuple[Stage, ...] | None:
    """The solving order of ``net``'s node equations, or None when there is none to exploit
    (a network whose index :func:`~cardiosoft.network.network.reduce_index` reduced: its
    equations are combinations of every block's). Raises :class:`ValueError` when no residual
    can be matched to some unknown (a structurally singular network)."""
    if net.reduction is not None:
        return None
    rng = np.random.default_rng(seed)
    m = 2 * net.n_nodes
    jac = _jacobian(net)
    pattern, linear = _edges(net, x0, rng)
    # each residual solved for an unknown it is affine in wherever the wiring allows: a valve's
    # law for its flow, not for a pressure it switches on
    cost = np.where(pattern, np.where(linear, 1.0, 1.0 + m), 0.0)
    try:
        rows, cols = min_weight_full_bipartite_matching(sp.csr_matrix(cost))
    except ValueError:
        raise ValueError(
            "the model's nodes are not determined by its equations: some residual cannot be "
            "solved for any unknown"
        ) from None
    match = np.empty(m, dtype=int)
    match[rows] = cols
    # row r is solved for unknown match[r]; unknown u needs the unknowns its row holds
    row_of = np.empty(m, dtype=int)
    row_of[match] = np.arange(m)
    needs = pattern[row_of]  # needs[u, v]: u's row holds v
    n_comp, label = connected_components(sp.csr_matrix(needs), directed=True, connection="strong")
    sorter = graphlib.TopologicalSorter({c: set() for c in range(n_comp)})
    for u, v in zip(*np.nonzero(needs), strict=True):
        if label[u] != label[v]:
            sorter.add(int(label[u]), int(label[v]))
    components = [[int(u) for u in np.flatnonzero(label == c)] for c in range(n_comp)]
    affine = _affine(net, x0, [([row_of[u] for u in c], c) for c in components], rng)
    owner = _row_owners(net, x0)
    # a copy of an unknown solved in an earlier component (not one coupled with it)
    single = {c[0] for c in components if len(c) == 1}
    alias = {
        u: v
        for u, v in _aliases(jac, net, x0, pattern, match, rng).items()
        if u in single and label[u] != label[v]
    }
    slope = _constant_slopes(net, x0, match, rng)
    stages = []
    sorter.prepare()
    while sorter.is_active():  # the components whose predecessors are solved, stage by stage
        ready = sorted(sorter.get_ready())
        sorter.done(*ready)
        copied = [c for c in ready if components[c][0] in alias]
        copies = tuple((components[c][0], alias[components[c][0]]) for c in copied)
        ready = [c for c in ready if c not in copied]
        grouped: dict[int, list[int]] = {}  # rows of one block together
        for c in ready:
            for u in components[c]:
                grouped.setdefault(owner[row_of[u]][0], []).append(int(row_of[u]))
        owners = tuple((b, tuple(owner[r][1] for r in rows)) for b, rows in grouped.items())
        unknowns = tuple(int(match[r]) for rows in grouped.values() for r in rows)
        scalar = all(len(components[c]) == 1 for c in ready)
        flag = all(affine[c] for c in ready)
        rows = [r for group in grouped.values() for r in group]
        given = scalar and flag and all(r in slope for r in rows)
        steps = tuple(slope[r] for r in rows) if given else None
        stages.append(Stage(unknowns, owners, scalar, flag, copies, steps))
    return tuple(stages)


def _constant_slopes(net, x0, match, rng) -> dict[int, float]:
    """``{row: dg_row/dz_u}`` for the rows whose derivative in their matched unknown u is one
    number at every sampled point, with the network's parameters each scaled by a random
    factor in [0.5, 1.5] at each point: a constant of the wiring, not of the values."""
    m = 2 * net.n_nodes
    seen: dict[int, float] = {}
    varying: set[int] = set()
    for t, x, z in _points(net, x0, 0.0, SPARSITY_POINTS, rng):
        scaled = jax.tree.map(
            lambda a: a * rng.uniform(0.5, 1.5) if eqx.is_inexact_array(a) else a, net
        )
        J = np.asarray(_jacobians(scaled, t, x, jnp.asarray(_padded(np.asarray(z)[None])))[0][0])
        for r in range(m):
            value = float(J[r, match[r]])
            if not np.isfinite(value) or value == 0 or seen.setdefault(r, value) != value:
                varying.add(r)
    return {r: v for r, v in seen.items() if r not in varying}


def _aliases(jac, net, x0, pattern, match, rng) -> dict[int, int]:
    """``{u: v}``: the unknowns whose matched residual is ``c (z_u - z_v)`` with a constant c at
    every sampled point (exactly: no other term)."""
    candidates = {}
    for r in range(pattern.shape[0]):
        held = np.flatnonzero(pattern[r])
        if len(held) == 2:
            u = int(match[r])
            candidates[u] = (r, int(held[held != u][0]))
    for t, x, z in _points(net, x0, 0.0, SPARSITY_POINTS, rng):
        (J, g), zz = jax.tree.map(np.asarray, jac(t, x, z)), np.asarray(z)
        for u, (r, v) in list(candidates.items()):
            c = J[r, u]
            if not (J[r, v] == -c and c != 0 and g[r] == c * (zz[u] - zz[v])):
                del candidates[u]
    return {u: v for u, (_, v) in candidates.items()}


def _jacobian(net):
    """``(t, x, z) -> (dg/dz, g)`` at one point."""

    def at(t, x, z):
        J, g = _jacobians(net, t, x, jnp.broadcast_to(z, (2 * net.n_nodes + 1, z.shape[0])))
        return J[0], g[0]

    return at


def _row_owners(net, x0) -> list[tuple[int, int]]:
    """(block index, row within the block) of each residual row (traced once, not run)."""

    def counts(net, x, z):
        return [b.residuals(0.0, xb, P, Q) for b, xb, P, Q in net._each(x, z)]

    z = jax.ShapeDtypeStruct((2 * net.n_nodes,), jnp.result_type(float))
    shapes = eqx.filter_eval_shape(counts, net, jnp.asarray(x0, dtype=float), z)
    return [(i, k) for i, shape in enumerate(shapes) for k in range(shape.shape[0])]


def _moves_are_linear(J, g, zs, unknowns) -> np.ndarray:
    """Per residual row: whether moving ``unknowns`` from ``zs[0]`` to ``zs[1]`` changed the
    residual by exactly its linear prediction and left its Jacobian in them unchanged (``J``,
    ``g``: at the two points). Curvature fails the second test, a jump (a valve that switches
    its resistance on the sign of a pressure drop) the first."""
    step = zs[1][unknowns] - zs[0][unknowns]
    predicted = J[0][:, unknowns] @ step
    scale = np.maximum(np.abs(g[0]), np.abs(g[1])) + np.abs(predicted)
    values = np.abs(g[1] - g[0] - predicted) <= 1e-9 * scale
    slopes = np.all(np.isclose(J[1][:, unknowns], J[0][:, unknowns], rtol=1e-12, atol=0.0), axis=1)
    return values & slopes


def _edges(net, x0, rng) -> tuple[np.ndarray, np.ndarray]:
    """``(pattern, linear)``: which unknowns each residual holds (its Jacobian nonzero at some
    sampled point), and whether it is affine in each of them (:func:`_moves_are_linear` at
    every point, moving that unknown alone)."""
    m = 2 * net.n_nodes
    pattern = np.zeros((m, m), dtype=bool)
    linear = np.ones((m, m), dtype=bool)
    for t, x, z in _points(net, x0, 0.0, SPARSITY_POINTS, rng):
        moved = np.repeat(np.asarray(z)[None], m + 1, axis=0)  # row 0: as is; row u + 1: u moved
        moved[np.arange(1, m + 1), np.arange(m)] = rng.standard_normal(m)
        J, g = (np.asarray(a) for a in _jacobians(net, t, x, jnp.asarray(moved)))
        pattern |= J[0] != 0
        for u in range(m):
            pair = [0, u + 1]
            linear[:, u] &= _moves_are_linear(J[pair], g[pair], moved[pair], [u])
    return pattern, linear


def _affine(net, x0, components, rng) -> list[bool]:
    """Whether each component's rows are affine in its own unknowns (:func:`_moves_are_linear`
    at each sampled point, moving the component's unknowns together)."""
    affine = [True] * len(components)
    for t, x, z in _points(net, x0, 0.0, SPARSITY_POINTS, rng):
        moved = np.repeat(np.asarray(z)[None], len(components) + 1, axis=0)  # row 0: as is
        for i, (_, unknowns) in enumerate(components):
            moved[i + 1, unknowns] = rng.standard_normal(len(unknowns))
        J, g = (np.asarray(a) for a in _jacobians(net, t, x, jnp.asarray(_padded(moved))))
        for i, (rows, unknowns) in enumerate(components):
            pair = [0, i + 1]
            linear = _moves_are_linear(J[pair], g[pair], moved[pair], unknowns)
            affine[i] &= bool(np.all(linear[rows]))
    return affine


def _padded(zs):
    """``zs`` with its last row repeated to ``zs.shape[1] + 1`` rows (at most one per component
    and one more): every call of :func:`_jacobians` has one shape, one compile."""
    rows = zs.shape[1] + 1
    return np.concatenate([zs, np.repeat(zs[-1:], rows - zs.shape[0], axis=0)])


@eqx.filter_jit
def _jacobians(net, t, x, zs):
    """``(dg/dz, g)`` at each of the unknowns ``zs`` (a leading axis). The network is an
    argument, not a constant of the program: under ``jax.ensure_compile_time_eval``
    (:func:`~cardiosoft.network.closed_loop.loop_order`) its constants would otherwise be
    folded eagerly, one small compile per operation."""

    def g(z):
        return net.residuals(t, x, z)

    return jax.vmap(lambda z: (jax.jacfwd(g)(z), g(z)))(zs)
