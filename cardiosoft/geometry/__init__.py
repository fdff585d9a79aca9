"""The paper's geometrical model of the shell and its helical cables (section II-C, eqs. 1-7).

All lengths are in m and angles in rad. Every function is pure JAX: it can be ``jit``-ed,
``vmap``-ed over designs and differentiated with respect to the shell sizes, the helix
parameter ``omega`` (Omega) and the shortening ``C``. The contracted helix parameter ``t_f`` comes
from a Newton root find whose derivative is given by the implicit function theorem
(``optimistix.root_find`` with its default ``ImplicitAdjoint``), not by unrolled iterations.

Reading of ``t0`` (where each cable ends on the apex)
-----------------------------------------------------
The paper prints ``t0 = arcsin(((A + w) - d) / (A + w))`` with "apex height d", and section
III-B states ``d = 10 mm``. Read with d = 10 mm (the inner apex height A - 50 mm), the model gives
``|dz| = 20.3 mm`` and ``|dalpha| = 105.7 deg`` at Omega = 4, C = 0.4, not the boundary
conditions ``19.8 mm`` and ``99.8 deg`` that the paper says its geometrical model produced for
analysis A3. The helix lies on the *outer* surface (eq. 2, semi-axes ``A + w`` and ``B + w``) and
the cables end on the rigid apex part, whose plane is 50 mm above the base. Measured on the outer
surface, the apex height is ``d = (A + w) - 50 mm = 11.5 mm`` and ``t0 = arcsin(50 mm / (A + w))``:
the helix ends exactly on the apex plane, ``z0 = 50 mm``. This reading reproduces
``|dz| = 19.77 mm`` and ``|dalpha| = 99.82 deg``, the paper's 19.8 mm and 99.8 deg to the digits
printed, and it is the one used here.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft._validate import check_positive, check_range
from cardiosoft.units import mm

__all__ = [
    "ApexMotion",
    "Shell",
    "apex_motion",
    "apex_motion_table",
    "arc_length",
    "cable_length",
    "cable_pull",
    "cavity_volume",
    "helix",
]

# Gauss-Legendre nodes on [-1, 1]: the arc-length integrand of eq. (3) is smooth (analytic) on
# [0, t0], so 48 nodes integrate it to float64 round-off for any Omega in the domain.
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(48)


class Shell(eqx.Module):
    """Semi-ellipsoidal silicone shell (section II-B, Fig. 2).

    **Arguments** (all in m; defaults are the paper's prototype):

    - ``A``: inner semi-major axis (along the pump's axis z), 60 mm.
    - ``B``: inner semi-minor axis (radius at the base), 30 mm.
    - ``w``: wall thickness, 1.5 mm.
    - ``apex_height``: height of the apex plane above the base plane, 50 mm. Above it the shell is
      solid; the cavity and the cables end there.
    """

    A: jax.Array = eqx.field(converter=jnp.asarray, default=60 * mm)
    B: jax.Array = eqx.field(converter=jnp.asarray, default=30 * mm)
    w: jax.Array = eqx.field(converter=jnp.asarray, default=1.5 * mm)
    apex_height: jax.Array = eqx.field(converter=jnp.asarray, default=50 * mm)

    def __check_init__(self):
        check_positive("shell semi-major axis A", self.A, "mm", scale=mm)
        check_positive("shell semi-minor axis B", self.B, "mm", scale=mm)
        check_positive("shell wall thickness w", self.w, "mm", scale=mm)
        if not isinstance(self.A, jax.core.Tracer):
            check_range(
                "shell apex height",
                self.apex_height,
                "mm",
                0.0,
                float(self.A) / mm,
                lo_open=True,
                hi_open=True,
                scale=mm,
            )

    @property
    def a(self) -> jax.Array:
        """Outer semi-major axis ``A + w`` (m), on which the cables lie (eq. 1)."""
        return self.A + self.w

    @property
    def b(self) -> jax.Array:
        """Outer semi-minor axis ``B + w`` (m) (eq. 1)."""
        return self.B + self.w

    @property
    def t0(self) -> jax.Array:
        """Helix parameter where the cables reach the apex plane (rad); see the module docstring."""
        return jnp.arcsin(self.apex_height / self.a)


def cavity_volume(shell: Shell) -> jax.Array:
    """Inner cavity volume up to the apex plane (m^3): ``pi B^2 (h - h^3 / (3 A^2))``.

    The inner surface is the semi-ellipsoid with semi-axes B, B, A; h is the apex height. For the
    paper's shell this is 108.6 ml (section II-F).
    """
    h = shell.apex_height
    return jnp.pi * shell.B**2 * (h - h**3 / (3 * shell.A**2))


def helix(shell: Shell, omega, t) -> jax.Array:
    """Point of the elliptical helix at parameter ``t`` (eq. 2), shape ``(..., 3)`` in m."""
    t = jnp.asarray(t)
    r = shell.b * jnp.cos(t)
    return jnp.stack([r * jnp.cos(omega * t), r * jnp.sin(omega * t), shell.a * jnp.sin(t)], -1)


def _speed(shell: Shell, omega, t):
    """|d helix / dt|, the integrand of eqs. (3)-(4) (m/rad)."""
    return jnp.sqrt(
        (shell.b * jnp.sin(t)) ** 2 + (shell.a**2 + (shell.b * omega) ** 2) * jnp.cos(t) ** 2
    )


def arc_length(shell: Shell, omega, t) -> jax.Array:
    """Helix arc length from the base (t = 0) to parameter ``t`` (m), eqs. (3)-(4)."""
    t = jnp.asarray(t)
    omega = jnp.asarray(omega)[..., None]
    s = 0.5 * t[..., None] * (1.0 + jnp.asarray(_GL_NODES))  # nodes mapped to [0, t]
    return 0.5 * t * jnp.sum(jnp.asarray(_GL_WEIGHTS) * _speed(shell, omega, s), -1)


@jax.jit  # called eagerly when scenes are built: one compiled kernel, not ~30 eager ops
def cable_length(shell: Shell, omega) -> jax.Array:
    """Rest length L(Omega) of one cable between base and apex (m), eq. (3)."""
    return arc_length(shell, omega, shell.t0)


def cable_pull(shell: Shell, omega, shortening) -> jax.Array:
    """Cable pull x = C L(Omega) (m): the displacement of the disk holding the cables."""
    return shortening * cable_length(shell, omega)


class ApexMotion(NamedTuple):
    """Result of :func:`apex_motion` (SI)."""

    cable_length: jax.Array
    """Rest cable length L (m), eq. (3)."""
    t0: jax.Array
    """Helix parameter of the apex at rest (rad)."""
    tf: jax.Array
    """Helix parameter of the apex after contraction (rad), root of eq. (4)."""
    dz: jax.Array
    """Axial translation of the apex z_f - z_0 (m), eq. (6); negative: towards the base."""
    dalpha: jax.Array
    """Rotation of the apex Omega (t_f - t_0) (rad), eq. (7); negative for a pull."""


def _solve_tf(shell: Shell, omega, shortening):
    import optimistix as optx  # where it is traced: a stored program spares the import (#41)

    target = (1.0 - shortening) * cable_length(shell, omega)

    def residual(t, _):
        return arc_length(shell, omega, t) - target

    # The arc length is strictly increasing in t (its derivative is the speed, >= b > 0), so
    # Newton from the linear guess converges in a few steps on the whole domain C in [0, 1).
    sol = optx.root_find(
        residual,
        optx.Newton(rtol=1e-13, atol=1e-15),
        (1.0 - shortening) * shell.t0,
        max_steps=64,
        throw=False,
    )
    return sol.value


def apex_motion(shell: Shell, omega, shortening) -> ApexMotion:
    """Apex translation and rotation for a cable shortening ``C = (L - l) / L`` (eqs. 3-7).

    **Arguments:**

    - ``shell``: the :class:`Shell`.
    - ``omega``: helix parameter Omega >= 0 (``n = Omega / 4`` turns), dimensionless.
    - ``shortening``: C in [0, 1), dimensionless.

    **Returns:** an :class:`ApexMotion`. For the paper's shell at Omega = 4, C = 0.4:
    ``dz = -19.8 mm`` and ``dalpha = -99.8 deg`` (analysis A3 of section II-D).

    Arguments are checked eagerly when they are concrete values; inside ``jit``/``vmap`` they are
    not, so check them at the edge (or call this function once outside).
    """
    check_range("helix parameter Omega", omega, "-", 0.0)
    check_range("shortening C", shortening, "-", 0.0, 1.0, hi_open=True)
    omega = jnp.asarray(omega, dtype=float)
    shortening = jnp.asarray(shortening, dtype=float)
    t0 = shell.t0
    # vectorize: one scalar root find per (Omega, C) pair, also for broadcast array inputs
    tf = jnp.vectorize(lambda o, c: _solve_tf(shell, o, c))(omega, shortening)
    return ApexMotion(
        cable_length=cable_length(shell, omega),
        t0=t0,
        tf=tf,
        dz=shell.a * (jnp.sin(tf) - jnp.sin(t0)),
        dalpha=omega * (tf - t0),
    )


def apex_motion_table(shell: Shell, omegas, shortenings):
    """|dz| (mm) and |dalpha| (deg) on the grid shortenings x omegas (Fig. 7(a)), as numpy."""
    grid_o, grid_c = np.meshgrid(np.asarray(omegas, float), np.asarray(shortenings, float))
    motion = jax.jit(jax.vmap(jax.vmap(lambda o, c: apex_motion(shell, o, c))))(grid_o, grid_c)
    return np.abs(np.asarray(motion.dz)) / mm, np.degrees(np.abs(np.asarray(motion.dalpha)))
