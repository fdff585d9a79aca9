"""The membrane: an incompressible Yeoh law on linear axisymmetric elements, and volumes.

Lengths in m, energies in J, pressures and moduli in Pa. See :mod:`fit.membrane`.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.geometry import Shell

PAPER_YEOH_MPA = (0.35944, -0.14221, 0.261123)
"""C10, C20, C30 of the paper's third-order Yeoh law (Sec. II-D), MPa; D_i = 0."""
N_ELEMENTS = 200
"""Elements of the shipped curve: N and 2N agree to 4e-5 in swelling (:mod:`fit.membrane`)."""


class Yeoh(eqx.Module):
    """Incompressible Yeoh law W = C10 (I1 - 3) + C20 (I1 - 3)^2 + C30 (I1 - 3)^3 (Pa).

    ``c10``, ``c20``, ``c30`` in Pa; neo-Hookean when C20 = C30 = 0. :func:`paper_yeoh` is the
    paper's SS950 fit.
    """

    c10: jax.Array = eqx.field(converter=jnp.asarray)
    c20: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    c30: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)

    def __call__(self, lam1, lam2):
        """Energy per reference volume (Pa) at the in-plane principal stretches; the normal
        stretch is 1 / (lam1 lam2)."""
        # I1 - 3 as a sum of terms that vanish at rest: no cancellation against 3 at small strain
        j2 = (lam1 * lam2) ** 2
        i = (lam1**2 - 1) + (lam2**2 - 1) + (1 - j2) / j2
        return i * (self.c10 + i * (self.c20 + i * self.c30))


def paper_yeoh() -> Yeoh:
    """The paper's material (Sec. II-D): C10 0.35944, C20 -0.14221, C30 0.261123 MPa."""
    return Yeoh(*(c * 1e6 for c in PAPER_YEOH_MPA))


class Membrane(eqx.Module):
    """An axisymmetric membrane: linear elements on its reference mid-surface meridian.

    - ``nodes``: reference meridian, shape (n + 1, 2), columns (r, z), m. The reference surface
      is the polygon's surface of revolution (isoparametric: stress-free at rest exactly).
    - ``fixed``: (n + 1, 2) bool, True where a coordinate keeps its reference value.
    - ``thickness``: reference wall thickness H (m).
    - ``material``: a :class:`Yeoh`.
    - ``gauss``: Gauss points per element for the hoop stretch r / R, which varies along an
      element (the meridional stretch l / L is constant on it).
    """

    nodes: jax.Array = eqx.field(converter=jnp.asarray)
    fixed: jax.Array = eqx.field(converter=jnp.asarray)
    thickness: jax.Array = eqx.field(converter=jnp.asarray)
    material: Yeoh
    gauss: int = eqx.field(static=True, default=2)

    def stretches(self, x):
        """(lambda1 (n,), lambda2 (n, g), R (n, g), L (n,)) of the deformed meridian ``x``."""
        xi = jnp.asarray(0.5 * (np.polynomial.legendre.leggauss(self.gauss)[0] + 1))
        X = self.nodes
        L = jnp.linalg.norm(X[1:] - X[:-1], axis=-1)
        l = jnp.linalg.norm(x[1:] - x[:-1], axis=-1)
        R = X[:-1, 0, None] + xi * (X[1:, 0] - X[:-1, 0])[:, None]
        r = x[:-1, 0, None] + xi * (x[1:, 0] - x[:-1, 0])[:, None]
        return l / L, r / R, R, L

    def energy(self, x):
        """Strain energy (J): sum over elements and Gauss points of W * 2 pi R H L * weight."""
        wt = jnp.asarray(0.5 * np.polynomial.legendre.leggauss(self.gauss)[1])
        lam1, lam2, R, L = self.stretches(x)
        w = self.material(lam1[:, None], lam2)
        return jnp.sum(wt * w * 2 * jnp.pi * R * self.thickness * L[:, None])


def enclosed_volume(x):
    """Volume (m^3) under the surface of revolution of the polygon ``x`` (n + 1, 2), between the
    planes through its first and last nodes: exact for a polygon, pi dz (ra^2 + ra rb + rb^2)/3
    per segment."""
    ra, rb = x[:-1, 0], x[1:, 0]
    return jnp.sum(jnp.pi * (x[1:, 1] - x[:-1, 1]) * (ra**2 + ra * rb + rb**2) / 3)


def _ellipse(a, b, psi):
    """Meridian points (r, z) = (b cos psi, a sin psi), shape (..., 2)."""
    psi = np.asarray(psi, float)
    return np.stack([b * np.cos(psi), a * np.sin(psi)], -1)


def _mid_axes(shell: Shell):
    """Semi-axes (axial, radial) of the shell's mid-surface, m: A + w/2, B + w/2."""
    return float(shell.A + shell.w / 2), float(shell.B + shell.w / 2)


def _shell_psi(shell: Shell, n_elements: int):
    """Nodes of the shell's mesh: uniform in the ellipse angle from the base to the junction."""
    a, _ = _mid_axes(shell)
    return np.linspace(0.0, math.asin(float(shell.apex_height) / a), n_elements + 1)


def shell_membrane(
    n_elements: int = N_ELEMENTS,
    shell: Shell | None = None,
    gauss: int = 2,
    material: Yeoh | None = None,
) -> Membrane:
    """The paper's shell (Sec. II-B) on its mid-surface, semi-axes A + w/2 and B + w/2.

    The meridian runs from the base ring (clamped: both coordinates fixed) to the junction with
    the rigid plug, the mid-surface point at the apex plane's height (radius fixed, height
    free: the plug may move along the axis). Default material: the paper's Yeoh law.
    """
    if int(n_elements) < 4:
        raise ValueError(f"n_elements = {n_elements} is outside the allowed range [4, inf)")
    shell = Shell() if shell is None else shell
    a, b = _mid_axes(shell)
    nodes = _ellipse(a, b, _shell_psi(shell, int(n_elements)))
    fixed = np.zeros_like(nodes, dtype=bool)
    fixed[0] = True
    fixed[-1, 0] = True
    material = paper_yeoh() if material is None else material
    return Membrane(nodes, fixed, float(shell.w), material, gauss)


def spheroid_membrane(a, b, thickness, material: Yeoh, n_elements: int, gauss: int = 2) -> Membrane:
    """Half of a complete spheroid (axial semi-axis ``a``, equatorial ``b``, m): the meridian
    from the equator (the symmetry plane: z fixed) to the pole (on the axis: r fixed at 0).
    Its :func:`enclosed_volume` is half the spheroid's."""
    nodes = _ellipse(a, b, np.linspace(0.0, np.pi / 2, n_elements + 1))
    nodes[-1, 0] = 0.0
    fixed = np.zeros_like(nodes, dtype=bool)
    fixed[0, 1] = True
    fixed[-1, 0] = True
    return Membrane(nodes, fixed, thickness, material, gauss)


def nodal_normals(x):
    """Outward unit normals (n + 1, 2) of the meridian at its nodes: the central chord turned
    clockwise (one-sided at the ends). The meridian runs from the base towards the axis."""
    d = jnp.concatenate([x[1:2] - x[:1], x[2:] - x[:-2], x[-1:] - x[-2:-1]])
    t = d / jnp.linalg.norm(d, axis=-1, keepdims=True)
    return jnp.stack([t[:, 1], -t[:, 0]], -1)


def nodal_thickness(m: Membrane, x):
    """Deformed thickness H / (lambda1 lambda2) at the nodes (m): lambda1 averaged over the
    adjacent elements, lambda2 = r / R (lambda1 on the axis, where both vanish)."""
    lam1 = jnp.linalg.norm(x[1:] - x[:-1], axis=-1) / jnp.linalg.norm(
        m.nodes[1:] - m.nodes[:-1], axis=-1
    )
    lam1 = jnp.concatenate([lam1[:1], 0.5 * (lam1[1:] + lam1[:-1]), lam1[-1:]])
    R = m.nodes[:, 0]
    on_axis = R <= 0
    lam2 = jnp.where(on_axis, lam1, x[:, 0] / jnp.where(on_axis, 1.0, R))
    return m.thickness / (lam1 * lam2)


def inner_volume(m: Membrane, x):
    """Cavity volume (m^3) inside the inner surface: the deformed mid-surface offset inward by
    half the deformed thickness along its normal, closed by the base plane z = z_0 and by the
    plug's plane through the last node (vertical segments join the offset ends to them)."""
    y = x - 0.5 * nodal_thickness(m, x)[:, None] * nodal_normals(x)
    base = jnp.pi * y[0, 0] ** 2 * (y[0, 1] - m.nodes[0, 1])
    top = jnp.pi * y[-1, 0] ** 2 * (x[-1, 1] - y[-1, 1])
    return enclosed_volume(y) + base + top


def principal_tensions(m: Membrane, x):
    """Membrane tensions (N/m of deformed length) at the Gauss points, (n, g) each: meridional
    and hoop, N_i = h sigma_i = H (dW/dlambda_i) / lambda_j (j the other direction)."""
    lam1, lam2, _, _ = m.stretches(x)
    lam1 = jnp.broadcast_to(lam1[:, None], lam2.shape)
    d1, d2 = jnp.vectorize(jax.grad(m.material, argnums=(0, 1)))(lam1, lam2)
    return m.thickness * d1 / lam2, m.thickness * d2 / lam1
