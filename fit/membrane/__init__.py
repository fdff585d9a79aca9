"""The paper's shell inflated as an incompressible Yeoh membrane: V(P) at zero cable pull.

    python -m fit.membrane           # writes fit/data/membrane_inflation.csv (--force to overwrite)
    python -m fit.membrane --study   # prints the numbers below (~3 min on 2 cores); writes nothing

    from fit.membrane import inflate, inflation_curve
    volumes = inflate(pressures_Pa)  # m^3, the cavity at zero pull
    pressures, volumes = inflation_curve()  # Pa, m^3: 0 to 400 mmHg every 5 mmHg

The paper gives no pressure-volume curve of its shell; it gives what one needs to compute it:
the geometry (Sec. II-B: inner semi-axes A = 60 mm axial, B = 30 mm, wall w = 1.5 mm, solid
above the apex plane 50 mm over the base; :class:`cardiosoft.geometry.Shell`) and the material
(Sec. II-D: third-order Yeoh, C10 0.35944, C20 -0.14221, C30 0.261123 MPa, D_i = 0, i.e.
incompressible). This package computes that curve, the swelling branch of the chamber at zero
cable pull, as fit data (``fit/data/membrane_inflation.csv``, computed, not transcribed).

Model
-----
- An axisymmetric membrane on the shell's mid-surface (semi-axes A + w/2 = 60.75 mm and
  B + w/2 = 30.75 mm), reference thickness w; stretches lambda1 = ds/dS (meridian),
  lambda2 = r/R (hoop), lambda3 = 1/(lambda1 lambda2); W = sum_k Ck0 (I1 - 3)^k.
- The base ring is clamped (the base node fixed). The filled apex is a rigid plug, whose radius
  is fixed and which may move along the axis: the junction node keeps its r, its z is free.
- **The junction** is the mid-surface point at the apex plane's height, psi_j =
  asin(50 / 60.75) (r = 17.47 mm). The plug's lower face cuts the wall between the inner
  (16.58 mm) and the outer (18.34 mm) surface; a membrane is the wall reduced to its mid-surface,
  and 17.47 mm is where the mid-surface crosses that face, the middle of the cut. Moving the
  junction by 0.44 mm either way (to the foot of the normal through the inner or the outer
  corner) changes the swelling at 150 mmHg by -0.8 / +0.8 % (26.06 / 26.48 ml for 26.27).
- Finite elements on the reference meridian (:mod:`fit.membrane.model`): linear elements with
  nodes uniform in the ellipse angle; the reference is the polygon's surface of revolution, so
  the rest state is exactly stress-free. lambda1 = l/L is constant on an element; the hoop
  stretch r/R varies along it and is sampled at 2 Gauss points. Checked (N = 100, swelling at
  150 mmHg): 1 / 2 / 3 points give 26.26986 / 26.26884 / 26.26884 ml, so 2 points are exact to
  5e-10 and 1 point is off by 4e-5, as much as the elements' own error.
- Total potential Pi = sum_e W 2 pi R w L - P V, V the volume enclosed by the base plane, the
  surface of revolution and the plug's plane, pi dz (ra^2 + ra rb + rb^2) / 3 per element
  (exact for a polygon): the pressure acts on the mid-surface and on the plug's face.
- Newton's method on the stationarity of Pi (:mod:`fit.membrane.solver`) with the exact
  Hessian (``jax.jacfwd`` of ``jax.grad``, float64), continuation in pressure in steps of at
  most 5 mmHg from a secant predictor, a Newton step limited to 0.01 of the base radius, and
  every equilibrium checked stable (the Cholesky factor of its Hessian exists). Without the
  step limit and the check, full Newton steps along the membrane's soft zig-zag modes land on
  spurious folded equilibria. Volume control (P a Lagrange multiplier) passes limit points
  (the sphere's check); the shell's own curve has none up to 400 mmHg (dP/dV >= 2.93 mmHg/ml),
  so it is computed under pressure control.
- **The cavity is the inner surface**: the deformed mid-surface offset inward by half the
  deformed thickness, w / (2 lambda1 lambda2), along the normal (:func:`inner_volume`), closed
  by the base plane and the plug's face. Its swelling differs from the mid-surface's by -0.02,
  -0.05 and -0.04 % at 30, 150 and 250 mmHg (26.2709 vs 26.2828 ml at 150): incompressibility
  keeps the wall's volume, the integral of h dA, constant, so only a curvature term of second
  order in w remains. At rest the offset surface holds 108.51 ml (the offset of the mid-surface
  ellipsoid is not quite the inner ellipsoid, and the corners at base and plug are closed by
  straight cuts); the table therefore reports volume = the paper's 108.65 ml
  (:func:`cardiosoft.geometry.cavity_volume`) + the swelling of the inner surface.
- The membrane is taut wherever it inflates freely: the smallest principal tension is 24, 78,
  140 and 255 N/m at 30, 90, 150 and 250 mmHg (no wrinkling, so no tension-field correction).

Checks (``tests/test_membrane.py``)
-----------------------------------
1. A neo-Hookean sphere (C20 = C30 = 0, a hemisphere with symmetry conditions, the same
   element code) against P = 4 C10 (w/R)(1/lambda - 1/lambda^7), lambda 1.05-3.0 under volume
   control, past the limit point lambda = 7^(1/6): relative error 3.0e-4, 7.5e-5, 1.9e-5 with
   32, 64, 128 elements (O(h^2), flat in lambda), 3.3e-5 with the test's 96.
2. Convergence on the paper's shell, N = 200 (shipped) and 2N = 400 elements, swelling (ml):
   30 mmHg 4.4968 / 4.4970, 60: 9.1216 / 9.1219, 90: 14.1226 / 14.1229, 150: 26.2709 /
   26.2714, 250: 57.0285 / 57.0298, i.e. <= 3.7e-5 relative (volumes <= 2e-6). N = 50 / 100
   agree to 3.8e-4 (the fast test).
3. The slope at rest against linear membrane theory in closed form (statically determinate
   resultants, E = 6 C10, nu = 1/2, the volume change by Clapeyron's theorem), for a complete
   sphere (R = 30 mm) and a complete prolate spheroid of the paper's mid-surface semi-axes:
   relative errors 4.2e-5 and 5.7e-5 with 128 elements, O(h^2).

The paper's shell (N = 200; ``python -m fit.membrane --study`` prints these)
------------------------------------------------------------------------------
=========  ===========  ==========  =========  ============
P (mmHg)   swelling ml  volume ml   plug mm    max stretch
=========  ===========  ==========  =========  ============
 30          4.497       113.144     -0.110     1.0232
 60          9.122       117.768     -0.116     1.0467
 90         14.123       122.769     -0.020     1.0712
150         26.271       134.918     +0.570     1.1252
250         57.029       165.675     +3.399     1.2302
400         92.187       200.834     +7.398     1.3806
=========  ===========  ==========  =========  ============

- Slope at zero pressure: dP/dV = 6.34 mmHg/ml (linear theory on the mid-surface, N = 200;
  6.35 / 6.34 / 6.33 with 100 / 200 / 400 elements, O(h): the clamped ends are a boundary
  layer that a membrane resolves only by its mesh; -> about 6.32). The inner offset's tangent
  exactly at P = 0 does not converge (the layer's rotation is singular in linear theory), so
  the table's P = 0 row gives the mid-surface's; from 0.5 mmHg on the two agree to 1e-3
  (6.439 / 6.445 mmHg/ml at 0.5 mmHg).
- The curve first stiffens a little, to dP/dV = 6.72 mmHg/ml at 15 mmHg: the held ends do it
  (the clamped base, the plug's fixed radius), not the law; a complete spheroid of the same
  mid-surface softens from the start (3.03 to 2.84 mmHg/ml from 0 to 15 mmHg). It then
  softens (the Yeoh law's negative C20) to its softest, 2.93 mmHg/ml at 227.5 mmHg (49.5 ml
  of swelling, stretch 1.21), then stiffens (C30): 3.85 at 300 mmHg, 6.15 at 400 mmHg. The
  largest stretch, 1.38 at 400 mmHg, stays inside the 50 % strain of the material tests
  (Sec. II-D).

The cables at rest
------------------
The cables lie on the outer surface as the helices of eq. (2) (semi-axes A + w, B + w, t up
to t0 of :mod:`cardiosoft.geometry`), six of them (Sec. III-B). A helix lying on the swelling
surface lengthens. Measured at 150 mmHg on the freely inflated shell (:mod:`fit.membrane.cables`:
each point of eq. (2) is a material point of the outer surface, the mid-surface point whose
normal passes through it, carried by the deformation and offset outward by half the deformed
thickness; at rest the curve's length is eq. (3)'s to 2e-5):

=====  =======  ===============  =========  ==================
Omega  L (mm)   lengthening mm   % of L     of the stroke 0.4 L
=====  =======  ===============  =========  ==================
1        58.4       3.83            6.6          0.16
2        73.3       5.38            7.3          0.18
3        93.1       7.28            7.8          0.20
4       115.1       9.32            8.1          0.20
5       138.4      11.42            8.2          0.21
6       162.4      13.55            8.3          0.21
=====  =======  ===============  =========  ==================

On the bench (Omega = 4) a cable that followed the swelling shell at 150 mmHg would have to
lengthen by 9.3 mm, a fifth of the 46-mm stroke: not negligible. If the cables were taut at
rest and inextensible, holding their length (:func:`inflation` with ``restrain_omega``: one
Lagrange multiplier, the six tensions smeared around the circumference, the helix a material
curve that cannot slide: an upper bound of the restraint) gives, Omega = 4:

=========  ==================  ==================  ====================
P (mmHg)   swelling free (ml)  held cables (ml)    tension per cable
=========  ==================  ==================  ====================
 30           4.50                1.24                1.16 N
 90          14.12                2.89                4.05 N
150          26.27                4.38                7.20 N
=========  ==================  ==================  ====================

The held cables pull the upper shell inward: its hoop tension goes negative above z = 42.5,
40.2 and 39.5 mm up to the plug (to -46, -89, -129 N/m at 30, 90, 150 mmHg; N = 100 for the
z range), where a real wall would wrinkle and a membrane that carries no compression would
yield more. These numbers bound what a restraint
could do; whether the cables at rest are taut, slack or sliding is the bench's, not the
paper's, and this package decides nothing about it: ``inflate`` and the shipped file are the
free shell.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from cardiosoft.geometry import Shell, cavity_volume
from cardiosoft.units import mmHg
from fit.membrane.cables import CableEmbedding, cable_length, cable_points, embed_helix
from fit.membrane.model import (
    N_ELEMENTS,
    PAPER_YEOH_MPA,
    Membrane,
    Yeoh,
    enclosed_volume,
    inner_volume,
    nodal_normals,
    nodal_thickness,
    paper_yeoh,
    principal_tensions,
    shell_membrane,
    spheroid_membrane,
)
from fit.membrane.solver import MAX_STEP, Measures, State, measures, rest_state, solve

__all__ = [
    "MAX_STEP",
    "N_ELEMENTS",
    "PAPER_YEOH_MPA",
    "P_MAX_MMHG",
    "CableEmbedding",
    "Inflation",
    "Measures",
    "Membrane",
    "State",
    "Yeoh",
    "cable_length",
    "cable_points",
    "embed_helix",
    "enclosed_volume",
    "inflate",
    "inflation",
    "inflation_curve",
    "inner_volume",
    "measures",
    "nodal_normals",
    "nodal_thickness",
    "paper_yeoh",
    "principal_tensions",
    "rest_state",
    "shell_membrane",
    "solve",
    "spheroid_membrane",
]

P_MAX_MMHG = 400.0
"""Top pressure of the shipped curve (mmHg): past the softest point (~230 mmHg) into the
stiffening; the largest stretch there, 1.38, is inside the 50 % strain of the material tests."""
STEP_MMHG = 5.0
"""Pressure step of the shipped table (mmHg)."""


class Inflation(NamedTuple):
    """The shell inflated at zero cable pull (SI; arrays over the pressures)."""

    pressure: np.ndarray
    """Cavity pressure (Pa)."""
    volume: np.ndarray
    """Cavity volume (m^3): the paper's unloaded 108.6 ml plus ``swelling``."""
    swelling: np.ndarray
    """Change of the volume inside the inner surface (m^3; :func:`inner_volume`)."""
    mid_swelling: np.ndarray
    """Change of the volume inside the mid-surface (m^3), for comparison."""
    compliance: np.ndarray
    """Tangent d(volume)/dP (m^3/Pa) along the curve, by implicit differentiation; at P = 0
    the mid-surface's (module docstring: the inner offset's is singular there)."""
    plug_displacement: np.ndarray
    """Axial displacement of the plug (m), positive away from the base."""
    max_stretch: np.ndarray
    """Largest principal stretch of the wall (meridional or hoop, at the Gauss points)."""
    min_tension: np.ndarray
    """Smallest principal membrane tension (N/m); positive: taut everywhere, no wrinkles."""
    cable_tension: np.ndarray
    """Tension of one cable (N) when the cables are held at their rest length, else zero."""


def inflation(
    pressures,
    n_elements: int = N_ELEMENTS,
    shell: Shell | None = None,
    restrain_omega: float | None = None,
    n_cables: int = 6,
) -> Inflation:
    """Inflate the paper's shell (:func:`shell_membrane`) to ``pressures`` (Pa, >= 0, any order).

    ``restrain_omega``: hold ``n_cables`` helices of this Omega (eq. 2, on the outer surface) at
    their rest length, as taut inextensible cables would (their tension smeared around the
    circumference; an upper bound of the restraint). None: the shell inflates freely.
    """
    pressures = _check_pressures(pressures)
    if restrain_omega is not None and not 0 <= restrain_omega <= 50:
        raise ValueError(
            f"restrain_omega = {restrain_omega:g} is outside the allowed range [0, 50]"
        )
    if int(n_cables) < 1:
        raise ValueError(f"n_cables = {n_cables} is outside the allowed range [1, inf)")
    shell = Shell() if shell is None else shell
    m = shell_membrane(n_elements, shell)
    cable = None
    if restrain_omega is not None:
        embedding = embed_helix(shell, n_elements, restrain_omega)
        cable = (embedding, cable_length(m, embedding, m.nodes))
    order = np.argsort(pressures)
    states = [None] * len(pressures)
    for i, s in zip(order, solve(m, pressures[order], cable=cable), strict=True):
        states[i] = s
    rest = measures(m, rest_state(m), cable)
    c = Measures(*np.array([[float(v) for v in measures(m, s, cable)] for s in states]).T)
    swelling = c.inner_volume - float(rest.inner_volume)
    pressure = np.array([float(s.pressure) for s in states])
    return Inflation(
        pressure=pressure,
        volume=float(cavity_volume(shell)) + swelling,
        swelling=swelling,
        mid_swelling=c.mid_volume - float(rest.mid_volume),
        compliance=np.where(pressure > 0, c.inner_compliance, c.mid_compliance),
        plug_displacement=c.plug_displacement,
        max_stretch=c.max_stretch,
        min_tension=c.min_tension,
        cable_tension=np.array([float(s.cable_tension) / n_cables for s in states]),
    )


def inflate(pressures, n_elements: int = N_ELEMENTS, shell: Shell | None = None) -> np.ndarray:
    """Cavity volumes (m^3) of the freely inflated shell at ``pressures`` (Pa): V(P) at zero
    pull, from the paper's unloaded 108.6 ml (:func:`cardiosoft.geometry.cavity_volume`)."""
    return inflation(pressures, n_elements, shell).volume


def inflation_curve(
    p_max: float = P_MAX_MMHG * mmHg, step: float = STEP_MMHG * mmHg, n_elements: int = N_ELEMENTS
) -> tuple[np.ndarray, np.ndarray]:
    """The curve (pressures Pa, cavity volumes m^3) from 0 to ``p_max`` every ``step``."""
    pressures = np.arange(0.0, p_max + 0.5 * step, step)
    return pressures, inflate(pressures, n_elements)


def _check_pressures(pressures) -> np.ndarray:
    p = np.atleast_1d(np.asarray(pressures, float))
    bad = p[~np.isfinite(p) | (p < 0) | (p > 2000 * mmHg)]
    if bad.size:
        raise ValueError(
            f"pressure = {bad[0] / mmHg:.6g} mmHg is outside the allowed range [0, 2000] mmHg"
        )
    return p
