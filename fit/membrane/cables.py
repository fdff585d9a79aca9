"""The cables at rest: helices of eq. (2) on the outer surface, carried by the deformation.

See :mod:`fit.membrane` for what they measure. Lengths in m, angles in rad.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.geometry import Shell
from fit.membrane.model import Membrane, _ellipse, _mid_axes, _shell_psi, nodal_normals


class CableEmbedding(eqx.Module):
    """A curve on the outer surface, carried by the deformation as a material curve.

    Point k lies at local coordinate ``xi[k]`` of element ``element[k]``, at the reference
    distance ``offset[k]`` (m) outward along the normal, at azimuth ``angle[k]`` (rad).
    """

    element: jax.Array = eqx.field(converter=jnp.asarray)
    xi: jax.Array = eqx.field(converter=jnp.asarray)
    offset: jax.Array = eqx.field(converter=jnp.asarray)
    angle: jax.Array = eqx.field(converter=jnp.asarray)


def embed_helix(shell: Shell, n_elements: int, omega, n_points: int = 501) -> CableEmbedding:
    """The cable of eq. (2) on the outer surface (semi-axes A + w, B + w), t in [0, t0], as a
    material curve of :func:`shell_membrane`'s mesh: each point's foot on the mid-surface (the
    mid-surface point whose normal passes through it) and its distance from there."""
    a, b = _mid_axes(shell)
    t = np.linspace(0.0, float(shell.t0), n_points)
    out = _ellipse(float(shell.a), float(shell.b), t)
    psi = t.copy()
    for _ in range(50):  # Newton on (P - X(psi)) . X'(psi) = 0, from psi = t
        x, dx = _ellipse(a, b, psi), np.stack([-b * np.sin(psi), a * np.cos(psi)], -1)
        ddx = -x
        f = np.sum((out - x) * dx, -1)
        df = np.sum(-dx * dx + (out - x) * ddx, -1)
        psi = psi - f / df
    nodes = _shell_psi(shell, n_elements)
    if np.max(np.abs(f)) > 1e-12 * a * b or np.any(psi < 0) or np.any(psi > nodes[-1]):
        raise RuntimeError("the cable's points have no foot on the shell's mid-surface")
    h = nodes[1] - nodes[0]
    element = np.clip(np.floor(psi / h).astype(int), 0, n_elements - 1)
    return CableEmbedding(
        element=element,
        xi=psi / h - element,
        offset=np.linalg.norm(out - _ellipse(a, b, psi), axis=-1),
        angle=float(omega) * t,
    )


def cable_points(m: Membrane, cable: CableEmbedding, x):
    """Points (M, 3) of the cable on the outer surface of the deformed meridian ``x`` (m): the
    mid-surface point plus the reference offset times the thickness ratio 1/(lam1 lam2)."""
    e, xi = cable.element, cable.xi[:, None]
    mid = (1 - xi) * x[e] + xi * x[e + 1]
    ref = (1 - xi) * m.nodes[e] + xi * m.nodes[e + 1]
    n = nodal_normals(x)
    n = (1 - xi) * n[e] + xi * n[e + 1]
    n = n / jnp.linalg.norm(n, axis=-1, keepdims=True)
    lam1 = jnp.linalg.norm(x[e + 1] - x[e], axis=-1) / jnp.linalg.norm(
        m.nodes[e + 1] - m.nodes[e], axis=-1
    )
    lam2 = mid[:, 0] / ref[:, 0]
    rz = mid + (cable.offset / (lam1 * lam2))[:, None] * n
    return jnp.stack(
        [rz[:, 0] * jnp.cos(cable.angle), rz[:, 0] * jnp.sin(cable.angle), rz[:, 1]], -1
    )


def cable_length(m: Membrane, cable: CableEmbedding, x):
    """Length (m) of the polyline through :func:`cable_points`."""
    p = cable_points(m, cable, x)
    return jnp.sum(jnp.linalg.norm(p[1:] - p[:-1], axis=-1))
