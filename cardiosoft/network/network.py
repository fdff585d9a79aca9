"""A network of blocks compiled into one vector field.

The unknowns are the blocks' states ``x`` (integrated by diffrax) and the nodes' pressures and
flows ``z = (P, Q)`` (algebraic). Every block contributes residuals on ``z``; together they are as
many as the unknowns of ``z`` (svZeroDSolver's count, less the internal variables that are
states here). The field solves them for ``z`` at each evaluation and returns the states' rates:

- in the solving order found when the network is built (:attr:`Network.order`,
  :mod:`cardiosoft.network.ordering`): stage by stage, most unknowns one division each (a
  pressure set by a capacitor, a flow by a valve's law at pressures already known), a coupled
  group a small dense Newton. The closed loop costs then what its written-out field costs;
- without one (a network whose index was reduced, below): one Newton step from ``z = 0`` on all
  of them, exact where the residuals are affine in ``z`` (a forward-mode Jacobian of m columns,
  m = 2 x nodes, and one dense LU solve of size m), and ``NEWTON_STEPS`` more where they are
  not (a stenosis, a valve).

Either way the steps are a fixed count, so that the field is one straight-line program whose
derivative is exact. A run checks, at its output times, that one more Newton step on all the
equations would move ``z`` by less than ``NEWTON_TOLERANCE`` relative
(:meth:`Network.newton_converged`).

The algebraic part must be uniquely solvable for ``z`` given ``x`` (an index-1 DAE). Where a
source pins a state (a capacitor on a pressure source, an inductor in series with a flow source:
index 2), :func:`reduce_index` differentiates that constraint once when the network is built;
a model still singular after that is refused. Parameters are array leaves, so a batch of
networks that differ only in their values is one ``vmap`` of the same compiled field.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.network.blocks import Block

NEWTON_STEPS = 12
"""Newton steps on a nonlinear network's node unknowns after the first, linear one. Seven
left one more step of up to 6e-7 of the pressures' range at 3 of 1,000 output times of
upstream's closedLoopHeart_singleVessel_decomposed (tanh valves of steepness 1e4 per mmHg and
a 1e5 ratio of closed to open resistance); twelve converge there."""
NEWTON_TOLERANCE = 1e-9
"""The largest relative size of one more Newton step at which a solve counts as converged."""
STEADY_NEWTON_STEPS = 30
"""Newton steps of the steady start-up (run once per model)."""


def _scalar(value, dtype):
    """An unknown as a scalar array: a literal (an unsolved zero) converted, a traced one kept."""
    return value if isinstance(value, jax.Array) else jnp.asarray(value, dtype)


def _minus(value, step):
    """``value - step``, with no subtraction traced from an unsolved (literal) zero."""
    return -step if isinstance(value, float) and value == 0.0 else value - step


class _Scalars(tuple):
    """Scalars that a block reads as an array: an integer index is the scalar itself, with no
    slice traced; a slice is their stack."""

    def __getitem__(self, i):
        if isinstance(i, slice):
            items = tuple.__getitem__(self, i)
            return jnp.stack(items) if items else jnp.zeros((0,), dtype=self.dtype)
        return tuple.__getitem__(self, i)

    @property
    def dtype(self):
        return self[0].dtype if len(self) else jnp.result_type(float)


def _given(shared, i) -> dict:
    """The keyword that passes block ``i`` its shared terms (:meth:`Network._shared`), where it
    has them."""
    return {} if shared is None or shared[i] is None else {"shared": shared[i]}


def _newton(g, w, steps, groups):
    """``steps`` Newton steps on ``g(w) = 0`` from ``w``; returns ``w`` and the size of one more
    step: as it is when ``groups`` is None, else its largest part relative to the largest
    magnitude in each group of like unknowns (``groups``: index arrays, e.g. the pressures and
    the flows), so that a flow that crosses zero is judged against the flows, not itself."""

    def step(w):
        return jnp.linalg.solve(jax.jacfwd(g)(w), g(w))

    w = jax.lax.fori_loop(0, steps, lambda _, w: w - step(w), w)
    delta = jnp.abs(step(w))
    if groups is None:
        return w, delta
    # a group all at zero (no flow anywhere) is judged against the largest unknown
    floor = 1e-12 * jnp.max(jnp.abs(w), initial=0.0) + 1e-300
    change = [
        jnp.max(delta[i]) / jnp.maximum(jnp.max(jnp.abs(w[i])), floor) for i in groups if len(i)
    ]
    return w, jnp.max(jnp.stack(change)) if change else jnp.zeros(())


class Network(eqx.Module):
    """Blocks joined at nodes. ``nodes`` (static) are the (upstream, downstream) names of each
    connection, in svZeroDSolver's order; ``period`` (static, s in the model's units of time)
    is the cardiac period."""

    blocks: tuple[Block, ...]
    nodes: tuple[tuple[str, str], ...] = eqx.field(static=True)
    period: float = eqx.field(static=True)
    reduction: tuple[tuple[float, ...], ...] | None = eqx.field(static=True, default=None)
    """An orthogonal basis of the residuals' space whose first ``n_constraints`` rows combine
    residuals into constraints on the states alone (see :func:`reduce_index`); None when
    there are none."""
    n_constraints: int = eqx.field(static=True, default=0)
    order: tuple | None = eqx.field(static=True, default=None)
    """The node equations' solving order (:func:`~cardiosoft.network.ordering.order_nodes`),
    or None: one dense Newton on all of them."""

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def n_states(self) -> int:
        return sum(b.n_states for b in self.blocks)

    @property
    def nonlinear(self) -> bool:
        return any(b.nonlinear for b in self.blocks)

    def _offsets(self):
        offsets, k = [], 0
        for b in self.blocks:
            offsets.append(k)
            k += b.n_states
        return offsets

    def _each(self, x, z):
        """(block, its states, its ports' P, its ports' Q) per block. ``z``: an array, or a list
        of scalars (:meth:`_ordered`'s, read without gathers)."""
        offsets = self._offsets()
        for i in range(len(self.blocks)):
            yield self._block(i, offsets[i], x, z)

    def _block(self, i, offset, x, z):
        """(block i, its states, its ports' P, its ports' Q); ``offset``: its first state.
        With ``z`` a list of scalars (:meth:`_ordered`), ``x`` is one too and all three are
        :class:`_Scalars`."""
        b, n = self.blocks[i], self.n_nodes
        if isinstance(z, list):
            dtype = x[0].dtype if len(x) else jnp.result_type(float)
            P = _Scalars([_scalar(z[p], dtype) for p in b.ports])
            Q = _Scalars([_scalar(z[n + p], dtype) for p in b.ports])
            return b, _Scalars(x[offset : offset + b.n_states]), P, Q
        ports = np.asarray(b.ports, dtype=int)
        return b, x[offset : offset + b.n_states], z[:n][ports], z[n:][ports]

    def residuals(self, t, x, z, steady: bool = False):
        """Every block's algebraic residuals, stacked (as many as ``z``)."""
        return jnp.concatenate(
            [b.residuals(t, xb, P, Q, steady) for b, xb, P, Q in self._each(x, z)]
        )

    def rates(self, t, x, z, steady: bool = False, shared=None):
        """Every block's state derivatives, stacked like ``x``; ``shared``: :meth:`_shared`'s."""
        parts = [
            b.rates(t, xb, P, Q, steady, **_given(shared, i))
            for i, (b, xb, P, Q) in enumerate(self._each(x, z))
        ]
        return jnp.concatenate(parts) if parts else jnp.zeros((0,))

    def _shared(self, t, x) -> list:
        """Each block's :meth:`~cardiosoft.network.blocks.Block.shared_terms` at ``(t, x)``,
        for one evaluation's residuals and rates."""
        pairs = zip(self.blocks, self._offsets(), strict=True)
        return [b.shared_terms(t, x[k : k + b.n_states]) for b, k in pairs]

    def mass_flux(self, t, x, z, steady: bool = False):
        """Every block's :meth:`~cardiosoft.network.blocks.Block.mass_flux`, stacked like
        ``x``."""
        parts = [b.mass_flux(t, xb, P, Q, steady) for b, xb, P, Q in self._each(x, z)]
        if not parts:
            return jnp.zeros((0,)), jnp.zeros((0,))
        return tuple(jnp.concatenate(column) for column in zip(*parts, strict=True))

    def _algebraic(self, t, x, z, steady):
        """The equations that fix ``z``: the residuals, where the reduction has turned the
        combinations of them that hold no node unknown into their time derivatives."""
        g = self.residuals(t, x, z, steady)
        if self.reduction is None or steady:
            return g
        basis = jnp.asarray(self.reduction, dtype=g.dtype)
        k = self.n_constraints
        rates = self.rates(t, x, z, steady)
        _, change = jax.jvp(
            lambda x_, t_: self.residuals(t_, x_, z, steady),
            (x, jnp.asarray(t, dtype=x.dtype)),
            (rates, jnp.ones((), x.dtype)),
        )
        return jnp.concatenate([basis[k:] @ g, basis[:k] @ change])

    def node_values(self, t, x, steady: bool = False):
        """The nodes' pressures and flows ``z = (P, Q)`` at states ``x``."""
        if self.order is not None and not steady:
            return self._stacked(self._ordered(t, x), x.dtype)
        z, _ = self._node_solve(t, x, steady)
        return z

    @staticmethod
    def _stacked(z: list, dtype):
        return jnp.stack([jnp.asarray(v, dtype) for v in z])

    def _ordered(self, t, x, shared=None) -> list:
        """The nodes' unknowns solved stage by stage in :attr:`order`
        (:mod:`~cardiosoft.network.ordering`), as a list of scalars (an unsolved one a literal
        zero, so that a block reads its ports without gathers): aliases copied, then a Newton
        step on the stage's unknowns, elementwise where its components are scalar;
        ``1 + NEWTON_STEPS`` steps where they are not affine in their unknowns."""
        z: list = [0.0] * (2 * self.n_nodes)
        offsets = self._offsets()
        dtype = jnp.result_type(float)
        x = list(x)  # the states as scalars too
        for stage in self.order:
            for u, v in stage.aliases:
                z[u] = z[v]
            if not stage.unknowns:
                continue

            def g(*u, stage=stage, before=tuple(z)):
                z = list(before)
                for i, value in zip(stage.unknowns, u, strict=True):
                    z[i] = value
                out = []
                for i, rows in stage.owners:
                    b, xb, P, Q = self._block(i, offsets[i], x, z)
                    r = b.residuals(t, xb, P, Q, **_given(shared, i))
                    out += [r[j] for j in rows]
                return tuple(out)

            u = tuple(_scalar(z[i], dtype) for i in stage.unknowns)
            if stage.slopes is not None:  # affine, with slopes fixed by the wiring
                r = g(*u)
                u = tuple(
                    _minus(z[i], a if c == 1.0 else a / c)
                    for i, a, c in zip(stage.unknowns, r, stage.slopes, strict=True)
                )
            for _ in range(
                0 if stage.slopes is not None else 1 if stage.affine else 1 + NEWTON_STEPS
            ):
                if stage.scalar:  # a diagonal Jacobian: one derivative along every unknown
                    r, dr = jax.jvp(g, u, tuple(jnp.ones_like(v) for v in u))
                    u = tuple(v - a / b for v, a, b in zip(u, r, dr, strict=True))
                else:

                    def stacked(w, g=g):
                        return jnp.stack(g(*(w[i] for i in range(w.shape[0]))))

                    w = jnp.stack(u)
                    step = jnp.linalg.solve(jax.jacfwd(stacked)(w), stacked(w))
                    u = tuple(v - step[i] for i, v in enumerate(u))
            for i, value in zip(stage.unknowns, u, strict=True):
                z[i] = value
        return z

    def _node_solve(self, t, x, steady=False):
        if self.order is not None and not steady:
            z = self._stacked(self._ordered(t, x), x.dtype)
            return z, jnp.abs(self._dense_step(t, x, z, steady))

        def g(z):
            return self._algebraic(t, x, z, steady)

        steps = 1 + NEWTON_STEPS * self.nonlinear
        return _newton(g, jnp.zeros(2 * self.n_nodes, dtype=x.dtype), steps, None)

    def _dense_step(self, t, x, z, steady):
        """One Newton step on all the node equations at once, from ``z``."""

        def g(z):
            return self._algebraic(t, x, z, steady)

        return jnp.linalg.solve(jax.jacfwd(g)(z), g(z))

    def _groups(self, offset):
        """Index arrays of the pressures and of the flows in ``z``, shifted by ``offset``."""
        n = self.n_nodes
        return [np.arange(n) + offset, np.arange(n, 2 * n) + offset]

    def newton_converged(self, t, x, scale) -> jnp.ndarray:
        """Whether the field's Newton on the nodes converged at ``(t, x)``: one more step moves
        the pressures and the flows by at most ``NEWTON_TOLERANCE`` times ``scale``
        (the largest pressure and flow of the run, say)."""
        delta = self._node_solve(t, x)[1]
        n = self.n_nodes
        return (jnp.max(delta[:n]) <= NEWTON_TOLERANCE * scale[0]) & (
            jnp.max(delta[n:]) <= NEWTON_TOLERANCE * scale[1]
        )

    def vector_field(self, t, x, steady: bool = False):
        """``dx/dt`` at ``(t, x)``; ``steady`` uses the steady start-up's equations."""
        if self.order is not None and not steady:
            scalars = list(x)
            shared = self._shared(t, scalars)
            return self.rates(t, scalars, self._ordered(t, scalars, shared), shared=shared)
        return self.rates(t, x, self.node_values(t, x, steady), steady)

    def outputs(self, t, x, z) -> dict:
        """The blocks' internal variables by svZeroDSolver name."""
        out = {}
        for b, xb, P, Q in self._each(x, z):
            out.update(b.outputs(t, xb, P, Q))
        return out

    def variables_and_rates(self, t, x):
        """The nodes' values ``z``, the internal variables (:meth:`outputs`), and the time
        derivative of each along the solution through ``(t, x)``: forward mode along
        ``(1, dx/dt)``, through the nodes' solve (svZeroDSolver's ``ydot``, which its
        ``output_derivative`` writes). Returns ``(z, internal), (dz/dt, d internal/dt)``."""

        def variables(t, x):
            z = self.node_values(t, x)
            return z, self.outputs(t, x, z)

        t = jnp.asarray(t, x.dtype)
        return jax.jvp(variables, (t, x), (jnp.ones_like(t), self.vector_field(t, x)))

    @eqx.filter_jit
    def consistent(self, t, x):
        """``x`` moved (least change) onto the constraints the reduction keeps: what the
        sources pin at time ``t``. A start off them would stay off by the same amount."""
        if self.reduction is None:
            return x
        basis = jnp.asarray(self.reduction, dtype=x.dtype)[: self.n_constraints]
        zeros = jnp.zeros(2 * self.n_nodes, dtype=x.dtype)

        def c(x):
            return basis @ self.residuals(t, x, zeros)

        return x - jnp.linalg.pinv(jax.jacfwd(c)(x)) @ c(x)

    @eqx.filter_jit
    def steady_state(self, x0):
        """The states with every rate zero under the steady equations: the state svZeroDSolver's
        steady start-up marches towards (``Solver::setup_initial``); and whether Newton
        converged."""
        x, _, ok = self.steady_solution(x0)
        return x, ok

    @eqx.filter_jit
    def steady_solution(self, x0):
        """``(x, z, converged)``: the states and the node values of :meth:`steady_state`, solved
        together (the nodes of a network whose index was reduced are not determined by the
        steady residuals at given states, :meth:`node_values` ``steady=True``)."""
        n = x0.shape[0]

        def g(w, _):
            x, z = w[:n], w[n:]
            return jnp.concatenate([self.rates(0.0, x, z, True), self.residuals(0.0, x, z, True)])

        w0 = jnp.concatenate([x0, jnp.zeros(2 * self.n_nodes, dtype=x0.dtype)])
        kinds = [k for b in self.blocks for k in b.state_kinds()]
        groups = [np.flatnonzero([k == kind for k in kinds]) for kind in set(kinds)]
        w, change = _newton(lambda w: g(w, None), w0, STEADY_NEWTON_STEPS, groups + self._groups(n))
        return w[:n], w[n:], change <= NEWTON_TOLERANCE


@eqx.filter_jit
def _jacobian_in_nodes(net: Network, t, x, algebraic: bool):
    z = jnp.zeros(2 * net.n_nodes, dtype=x.dtype)
    g = (
        (lambda z: net._algebraic(t, x, z, False))
        if algebraic
        else (lambda z: net.residuals(t, x, z))
    )
    return jax.jacfwd(g)(z)


def _equilibrated_svd(J):
    """``(rows, U, s)``: the SVD ``U diag(s) V^T`` of ``J`` with each row and then each column
    scaled to a largest entry of 1 (``rows``: the row scales). The residuals mix units (a
    resistance of 1e10 Pa s/m^3 beside a unit pressure coefficient), which would make a
    well-posed network look rank-deficient to an unscaled SVD."""
    rows = 1.0 / np.maximum(np.abs(J).max(axis=1), 1e-300)
    scaled = J * rows[:, None]
    scaled = scaled / np.maximum(np.abs(scaled).max(axis=0), 1e-300)[None, :]
    U, s, _ = np.linalg.svd(scaled)
    return rows, U, s


def reduce_index(net: Network, x0) -> Network:
    """``net``, with its index reduced to 1 where sources pin its states.

    A capacitor tied to a pressure source, or an inductor in series with a flow source, has a
    state that the residuals fix outright: some combination ``c = N g`` of the residuals holds
    no node unknown (``N dg/dz = 0``), so ``z`` is not determined by ``g = 0`` alone (an
    index-2 DAE). Such combinations are replaced by their time derivative,
    ``N (dg/dx dx/dt + dg/dt) = 0``, which holds node unknowns through ``dx/dt``; the
    constraint itself then holds along the solution if it holds at the start. ``N`` is the left
    null space of ``dg/dz`` at ``(0, x0)``: the combinations come from the wiring, not from
    values. Raises :class:`ValueError` when the reduced equations still leave ``z`` undetermined.
    """
    rows, U, s = _equilibrated_svd(np.asarray(_jacobian_in_nodes(net, 0.0, x0, algebraic=False)))
    rank = int(np.sum(s > s[0] * 1e-10)) if s.size else 0
    m = U.shape[0]
    if rank == m:
        return net
    # rows: first the null space's combinations, then the range's (of the equilibrated
    # residuals, so that each combines the residuals as they are)
    basis = np.concatenate([U[:, rank:].T, U[:, :rank].T]) * rows[None, :]
    reduced = Network(
        net.blocks, net.nodes, net.period, tuple(map(tuple, basis.tolist())), m - rank
    )
    _, _, s = _equilibrated_svd(np.asarray(_jacobian_in_nodes(reduced, 0.0, x0, algebraic=True)))
    if s.size and np.sum(s > s[0] * 1e-10) < m:
        raise ValueError(
            "the model's nodes are not determined by its equations, even with its sources' "
            "constraints differentiated once (a DAE of index above 2)"
        )
    return reduced
