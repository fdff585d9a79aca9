"""Equilibria of the membrane by Newton's method with autodiff, and continuation.

The unknowns are the nodal (r, z) of the deformed meridian, the pressure (a Lagrange multiplier
under volume control) and, with cables held at their rest length, their tension. See
:mod:`fit.membrane`.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.units import mmHg
from fit.membrane.cables import cable_length
from fit.membrane.model import Membrane, enclosed_volume, inner_volume, principal_tensions

MAX_STEP = 5 * mmHg
"""Largest pressure step of the continuation (Pa); a step whose Newton fails is halved."""


class State(NamedTuple):
    """One equilibrium: the deformed meridian ``x`` (n + 1, 2) m, the pressure (Pa) and the
    cables' total tension (N; zero without a cable restraint)."""

    x: jax.Array
    pressure: jax.Array
    cable_tension: jax.Array


def rest_state(m: Membrane) -> State:
    """The unloaded reference state."""
    return State(m.nodes, jnp.zeros(()), jnp.zeros(()))


def _scales(m: Membrane):
    """Length, force and pressure units of the nondimensional unknowns and residuals."""
    ell = jnp.max(m.nodes[:, 0])
    force = m.material.c10 * m.thickness * ell
    return ell, force, force / ell**2


def _pack(m: Membrane, cable, state: State):
    """The nondimensional unknowns (x / ell, P / p0[, T / force]) of a state."""
    ell, force, p0 = _scales(m)
    parts = [state.x.ravel() / ell, state.pressure[None] / p0]
    if cable is not None:
        parts.append(state.cable_tension[None] / force)
    return jnp.concatenate(parts)


def _unpack(m: Membrane, cable, y) -> State:
    ell, force, p0 = _scales(m)
    k = m.nodes.size
    tension = y[k + 1] * force if cable is not None else jnp.zeros(())
    return State(y[:k].reshape(m.nodes.shape) * ell, y[k] * p0, tension)


def _residual(m: Membrane, cable, y, target, volume_control):
    """Stationarity of E - P V + T (L_cable - L_rest), and the control equation (P or V given),
    and with ``cable`` = (embedding, rest length) the cable's length constraint. ``y`` holds the
    nondimensional unknowns (x / ell, P / p0[, T / force])."""
    ell, force, p0 = _scales(m)
    k = m.nodes.size
    x = y[:k].reshape(m.nodes.shape) * ell
    g = jax.grad(m.energy)(x) - y[k] * p0 * jax.grad(enclosed_volume)(x)
    extra = []
    if cable is not None:
        embedding, rest = cable
        g = g + y[k + 1] * force * jax.grad(cable_length, argnums=2)(m, embedding, x)
        extra = [(cable_length(m, embedding, x) - rest)[None] / ell]
    g = jnp.where(m.fixed, (x - m.nodes) / ell, g / force)
    ctrl = jnp.where(volume_control, (enclosed_volume(x) - target) / ell**3, y[k] - target / p0)
    return jnp.concatenate([g.ravel(), ctrl[None], *extra])


def _stable(m: Membrane, cable, jac, y, volume_control):
    """Whether the equilibrium ``y`` is a local minimum of the potential under its control: the
    Hessian of the Lagrangian on the free coordinates, plus a stiff penalty along each active
    constraint's gradient (the volume's with ``volume_control``, the cable's), is positive
    definite: its Cholesky factor exists (for a large enough penalty this is the projected
    Hessian's test)."""
    k = m.nodes.size
    free = ~m.fixed.ravel()
    mask = free[:, None] & free[None, :]
    h = jnp.where(mask, jac[:k, :k], jnp.where(jnp.eye(k, dtype=bool), 1.0, 0.0))
    grads = [jnp.where(volume_control, jac[:k, k], 0.0)]  # -dV/dx in the pressure's column
    if cable is not None:
        grads.append(jac[:k, k + 1])
    rho = 1e4 * jnp.max(jnp.abs(h))
    for a in grads:
        a = jnp.where(free, a, 0.0)
        h = h + rho * jnp.outer(a, a) / jnp.maximum(jnp.sum(a * a), 1e-300)
    return jnp.all(jnp.isfinite(jnp.linalg.cholesky(0.5 * (h + h.T))))


@eqx.filter_jit
def _newton(m: Membrane, cable, y0, target, volume_control, tol=1e-10, max_steps=60, max_move=0.01):
    """Newton's method on :func:`_residual` with the exact (autodiff) Jacobian. A step that
    would move a node by more than ``max_move`` (in units of the base radius) is shortened to
    that: a full step along the membrane's soft (zig-zag) modes can land in the basin of a
    spurious folded equilibrium. Converged when a full step is below ``tol``; the result is
    accepted only if it is stable (:func:`_stable`)."""

    def jac(y):
        return jax.jacfwd(_residual, argnums=2)(m, cable, y, target, volume_control)

    def body(c):
        y, k, _ = c
        dy = jnp.linalg.solve(jac(y), -_residual(m, cable, y, target, volume_control))
        size = jnp.max(jnp.abs(dy[: m.nodes.size]))
        return y + dy * jnp.minimum(1.0, max_move / size), k + 1, size

    y, _, step = jax.lax.while_loop(
        lambda c: (c[1] < max_steps) & (c[2] > tol), body, (y0, 0, jnp.inf)
    )
    return y, (step <= tol) & _stable(m, cable, jac(y), y, volume_control)


def solve(
    m: Membrane, targets, volume_control: bool = False, cable=None, max_step: float | None = None
) -> list[State]:
    """Equilibria at increasing ``targets`` by continuation from the reference state.

    - ``targets``: pressures (Pa) or, with ``volume_control``, enclosed mid-surface volumes
      (m^3; P becomes a Lagrange multiplier: limit points are passed).
    - ``cable``: None, or (``CableEmbedding``, rest length m): the cables keep that length
      (their tension is a Lagrange multiplier, smeared around the circumference).
    - ``max_step``: the largest step between solves (default: :data:`MAX_STEP` for pressures,
      none for volumes); a step whose Newton fails is halved, up to 20 times.

    Each solve starts from a secant prediction through the two previous solutions. Raises
    ``RuntimeError`` where no stable equilibrium is found (e.g. past a limit point under
    pressure control).
    """
    targets = np.asarray(targets, float)
    start = float(enclosed_volume(m.nodes)) if volume_control else 0.0
    if np.any(np.diff(targets) < 0) or np.any(targets < start):
        what = "enclosed volumes" if volume_control else "pressures"
        raise ValueError(f"targets: {what} must not decrease and start at {start:.6g} or above")
    if max_step is None and not volume_control:
        max_step = MAX_STEP
    history = [(start, _pack(m, cable, rest_state(m)))]
    out = []
    for target in targets:
        while history[-1][0] < target:
            t0, y0 = history[-1]
            step = target - t0 if max_step is None else min(target - t0, max_step)
            for _ in range(21):
                t1 = target if step >= target - t0 else t0 + step
                guess = y0
                if len(history) > 1:
                    tp, yp = history[-2]
                    guess = y0 + (y0 - yp) * (t1 - t0) / (t0 - tp)
                y1, ok = _newton(m, cable, guess, jnp.asarray(t1), volume_control)
                if bool(ok):
                    break
                step /= 2
            else:
                raise RuntimeError(f"no stable equilibrium found beyond {t0:.6g} towards {t1:.6g}")
            history = [history[-1], (t1, y1)]
        out.append(_unpack(m, cable, history[-1][1]))
    return out


class Measures(NamedTuple):
    """Scalars of one equilibrium (SI)."""

    inner_volume: jax.Array
    """Inside the inner surface (m^3), :func:`inner_volume`."""
    mid_volume: jax.Array
    """Inside the mid-surface (m^3), :func:`enclosed_volume`."""
    inner_compliance: jax.Array
    """Tangent d(inner_volume)/dP (m^3/Pa) along the pressure-controlled path."""
    mid_compliance: jax.Array
    """Tangent d(mid_volume)/dP (m^3/Pa)."""
    plug_displacement: jax.Array
    """Axial displacement of the meridian's last node (m)."""
    max_stretch: jax.Array
    """Largest principal stretch (meridional or hoop) at the Gauss points."""
    min_tension: jax.Array
    """Smallest principal membrane tension (N/m) at the Gauss points."""


@eqx.filter_jit
def measures(m: Membrane, state: State, cable=None) -> Measures:
    """The :class:`Measures` of an equilibrium under pressure control (``cable`` as in
    :func:`solve`); the compliances by implicit differentiation of the equilibrium."""
    ell, _, _ = _scales(m)
    y = _pack(m, cable, state)

    def residual(y, p):
        return _residual(m, cable, y, p, False)

    # the equilibrium's derivative: J dy/dP = -dr/dP
    dy = jnp.linalg.solve(
        jax.jacfwd(residual)(y, state.pressure), -jax.jacfwd(residual, argnums=1)(y, state.pressure)
    )
    dx = dy[: m.nodes.size].reshape(m.nodes.shape) * ell
    lam1, lam2, _, _ = m.stretches(state.x)
    return Measures(
        inner_volume(m, state.x),
        enclosed_volume(state.x),
        jnp.sum(jax.grad(inner_volume, argnums=1)(m, state.x) * dx),
        jnp.sum(jax.grad(enclosed_volume)(state.x) * dx),
        state.x[-1, 1] - m.nodes[-1, 1],
        jnp.maximum(jnp.max(lam1), jnp.max(lam2)),
        jnp.minimum(*(jnp.min(t) for t in principal_tensions(m, state.x))),
    )
