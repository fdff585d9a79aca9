"""The pump surrogate: one strain-energy potential U(V, x; Omega) of the soft shell.

V is the cavity volume (m^3), x the cable pull (m; the displacement of the disk holding all
cables, ``x = C L(Omega)`` with L from eq. (3)) and Omega the helix parameter. Everything else
follows from U by automatic differentiation:

- chamber elastic pressure ``P = dU/dV`` (Pa) and total cable force ``F = dU/dx`` (N);
- ``dU = F dx + P dV``: mechanical work = stored energy + hydraulic work, so no efficiency can
  exceed one, and Maxwell's symmetry ``dF/dV = dP/dx`` holds by construction.

Structure (DESIGN.md section 3.2), built in rather than hoped for:

``U(V, x) = W(x) + Phi(V - V_eq(x, V); E(x))``

- ``V_eq(x, V) = V_u exp(-h_0(x) - f(x) exp(-k u(V)))`` is the zero-pressure volume, with
  ``V_u`` the unloaded cavity (108.6 ml, :func:`cardiosoft.geometry.cavity_volume`), ``h_0``
  what shortening alone takes and ``f`` what the folds take. Below ``V_u`` (``u = 0``) it is
  ``V_u (1 - EF_0(C, Omega))``, the zero-pressure ejection fraction being
  ``EF_0 = 1 - exp(-h)`` with

  ``h = h_0 + f``, ``h_0 = a(Omega) C + b(Omega) C^2``,
  ``f = (1 - p_3) S(Omega C) d(Omega C) + p_3 d_3``

  - ``a = a_ax + a_hel tanh(Omega / 0.3)``: before buckling, longitudinal cables (Omega = 0)
    only shorten the shell, while any helix also squeezes it. Table I has no Omega between 0
    and 1, so the switch's width (0.3) is fixed, not fitted.
  - ``S`` is a smooth step in the twist ``Omega C`` (proportional to the apex rotation, eq. 7),
    normalised to ``S = 0`` at rest: the torsional buckling, with depth
    ``d = d_0 + d_1 Omega C``. Table I's jumps between neighbouring Omega rows sit at
    ``Omega C`` of about 0.5, and past them ``h - 2C`` falls on one line in ``Omega C``.
  - ``p_3`` is the three-fold indicator (below), normalised to 0 at C = 0: a shell that folds
    into three lobes has its own depth ``d_3`` *instead of* the four-fold step.

  ``a, b, d_0, d_1, d_3 >= 0``, so ``EF_0(0) = 0`` and ``EF_0 < 1``. Every term but the three-fold
  switch is non-decreasing in C; the switch is too wherever ``d_3`` exceeds the four-fold step
  at the three-fold transition, which the fit checks on a dense grid before it writes an
  artifact (``V_eq`` decreases with x).
- **A swollen chamber resists the folds** (format 3): internal pressure stiffens a thin shell
  against torsional buckling, so the folds' depth ``f`` is scaled by ``exp(-k u(V))``, with
  ``u(V) = w softplus((V - V_u) / w) / V_u`` (w = 3 ml) a smooth, one-sided measure of how far
  the cavity exceeds its unloaded volume: a shell stretched past its rest shape is in tension,
  and tension resists the folds. The onset is not fitted: freed, ``V_ref`` went to 107.1 ml (V_u
  108.6 ml, half a width away) along the fit's flattest direction (Gauss-Newton eigenvalue 0.18
  of up to 1.3e6), where round-off would move it. By the Maxwell relation the potential guarantees,
  ``dF/dP|_x = -dV/dx|_P``: a chamber that loses less volume per millimetre of pull when
  swollen needs a force that rises more slowly with the afterload, the bend of the paper's
  peak forces with afterload (Fig. 10(d): 0.99, then 0.30 N/mmHg). No law of the separable
  form ``W(x) + Phi(V - V_eq(x))`` bends so (``fit.peak_force``). With ``k = 0`` this is format
  2. ``V_eq`` now depends on V, so the chamber's convexity in V is no longer automatic: the fit
  holds ``d2U/dV2 >= 0.1 E_u`` over the domain as a hard constraint and checks it on a dense
  grid before it writes an artifact (``fit.fitting.check_convexity``): one volume per pull and
  pressure, no hidden snap. Below ``V_u`` nothing changes, so Table I (zero pressure, cavity
  below V_u) is the same as without swelling.
- ``W(x)`` is the strain energy at zero pressure. Its force ``W'(x) = K x / (1 + (x/x_b)^2)^g``
  rises linearly, peaks near the buckling pull ``x_b = L C_b`` (the step's centre,
  ``C_b = tau / Omega``, tau the step's twist) and falls as the folds form (Fig. 10(d)): U is
  not convex in x. Under displacement control that is stable; under force control it snaps through.
- ``Phi(V; E) = (E / beta^2) (cosh(beta s) - 1) - E a (e^2 / 2 - s_a^2 log cosh(e / s_a))``
  is the chamber's elastic energy, ``s = V - V_eq(x, V)`` its distension from the zero-pressure
  volume and ``e(V) >= 0`` its stretch past the unloaded cavity (:meth:`Chamber.stretch`,
  zero with its slope at and below V_u). Where neither
  swelling nor stretch enters, ``P = (E / beta) sinh(beta s)`` and ``d2U/dV2 = E cosh(beta s) >
  0``. The second term (format 4) is the softening of an inflated membrane: a Yeoh shell grows
  more compliant as it stretches (its compliance at zero pull more than doubles from 0 to 230
  mmHg, ``fit/data/membrane_inflation.csv``) before the cosh term stiffens it. It lowers the
  stiffness by ``E a tanh^2(e / s_a)`` at most (and a term of order ``w^2 / s_a^2`` over the
  3-ml onset), so with ``0 <= a < 1`` the unfolded chamber stays convex by construction. It
  acts only past V_u: a chamber pulled below its rest shape is folded, not stretched, and its
  compliance comes from the folds (the cosh law). Format 3 has ``a = 0``: the cosh law alone,
  which only stiffens. The chamber stiffens with pressure
  (``dP/dV = sqrt(E^2 + beta^2 P^2)`` without swelling), and folding softens it,
  ``E = E_u exp(-kappa EF_0)`` (EF_0 of the unswollen chamber): the folded shell is more
  compliant (Fig. 10(a): static SV falls with afterload).
- ``U(V_u, 0) = 0`` and ``P(V_u, 0) = 0``: the unloaded shell at rest; ``P < 0`` below ``V_eq``
  (elastic recoil refills the chamber when the cables are released).

A separate smooth predictor gives the number of folds (3 or 4, Table I): three folds need few
turns and a large shortening.

Parameters are array leaves: new values never recompile. The fitted artifact lives in
``surrogates/`` (weights + JSON model card, never pickled); :func:`load` reads it.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft._validate import check_range
from cardiosoft.chamber import SWELLING_WIDTH, VOLUME_NEWTON_STEPS, Chamber
from cardiosoft.files import atomic_path, sha256
from cardiosoft.geometry import Shell, cable_length, cavity_volume
from cardiosoft.units import mmHg

__all__ = [
    "DEFAULT_ARTIFACT",
    "SHIPPED_ARTIFACTS",
    "SWELLING_WIDTH",
    "VOLUME_NEWTON_STEPS",
    "Chamber",
    "Domain",
    "PosteriorDraws",
    "PumpSurrogate",
    "artifact_dir",
    "artifact_path",
    "check_pump_name",
    "load",
    "load_posterior",
]

DEFAULT_ARTIFACT = "ss950-v3"
"""Name of the surrogate used when none is named (``surrogates/ss950-v3.eqx`` + ``.json``)."""

SHIPPED_ARTIFACTS = ("ss950-v3", "ss950-v4")
"""The surrogates shipped with the package, by name (``load("ss950-v4")``, a scene's ``pump``
key, ``--pump``): ss950-v3 (format 3) fitted to the paper's data alone; ss950-v4 (format 4)
with the shell's membrane inflation from the paper's material as data too."""

FORMAT_VERSION = 4
"""Version 4: the chamber law softens as a membrane does (a, s_a), and it is fitted to the
membrane inflation. Version 3 (still read: a = 0) has the folds' depth yield to a swollen
chamber (k). Version 2 had the same EF_0 law with the folds independent of the volume (a
separable potential); version 1 a helix-independent linear rate, a fold depth linear in C and
an additive three-fold term."""
READ_FORMAT_VERSIONS = (3, 4)
"""The format versions :func:`load` reads."""
FORMAT_4_FIELDS = ("chamber_softening", "log_softening_scale")
"""The leaves a format-3 file does not hold; it is read with their defaults (a = 0)."""

HELIX_SWITCH = 0.3
"""Omega over which the pre-buckling rate switches from longitudinal to helical (fixed)."""


class Domain(NamedTuple):
    """Where the surrogate was fitted (user units)."""

    omega: tuple[float, float] = (0.0, 6.0)
    shortening: tuple[float, float] = (0.0, 0.65)
    pressure_mmHg: tuple[float, float] = (-20.0, 150.0)


def centred_omega(omega):
    """(Omega - 3) / 2: the helix parameter centred on the fitted range, which keeps the EF
    law's raw parameters O(1)."""
    return (omega - 3.0) / 2.0


def _softplus(z):
    return jax.nn.softplus(z)


def _inverse_softplus(y: float) -> float:
    return float(np.log(np.expm1(y)))


BUCKLING_ONSET = (0.45, 0.15)
"""Twist Omega C at the centre of the buckling step, and the step's width. Not fitted: the fit
(``fit.pipeline``) holds them here. Table I's jumps between Omega rows place the onset at
Omega C of about 0.5; over the grid onset {0.35, ..., 0.6} x width {0.05, 0.1, 0.15, 0.2}
these values gave the smallest leave-one-out error on Table I."""


class PumpSurrogate(eqx.Module):
    """The soft pump's strain-energy potential U(V, x; Omega) (module docstring).

    All methods take and return SI values: V in m^3, x in m, pressure in Pa, force in N,
    energy in J. ``omega`` is the helix parameter (dimensionless). Raw parameters are
    unconstrained reals; positivity comes from ``softplus``/``exp`` so that any parameter value is
    a valid pump and fitting needs no constraints.

    Arguments are checked against :attr:`domain` only by the methods that take user-facing
    quantities (``ejection_fraction``, ``folds``, :meth:`check`); the energy and its derivatives
    are pure functions for use inside ``jit``/``vmap``/``grad``.
    """

    shell: Shell = eqx.field(default_factory=Shell)
    # zero-pressure volume law, EF_0(C, Omega)
    ef_linear: jax.Array = eqx.field(converter=jnp.asarray, default=(0.0, 0.4))
    ef_quadratic: jax.Array = eqx.field(converter=jnp.asarray, default=(1.4, 1.4))
    buckling_twist: jax.Array = eqx.field(
        converter=jnp.asarray, default=_inverse_softplus(BUCKLING_ONSET[0])
    )
    buckling_width: jax.Array = eqx.field(
        converter=jnp.asarray, default=_inverse_softplus(BUCKLING_ONSET[1])
    )
    fold_depth: jax.Array = eqx.field(converter=jnp.asarray, default=(0.5, 0.0))
    three_fold_depth: jax.Array = eqx.field(converter=jnp.asarray, default=-2.0)
    # zero-pressure force law, W'(x)
    log_stiffness: jax.Array = eqx.field(converter=jnp.asarray, default=(8.0, 0.0))
    softening_exponent: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    # chamber pressure-volume law
    log_chamber_elastance: jax.Array = eqx.field(converter=jnp.asarray, default=22.0)
    fold_compliance: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    log_stiffening: jax.Array = eqx.field(converter=jnp.asarray, default=11.0)
    # format 4: a = r^2 / (1 + r^2) in [0, 1) (r = 0: the cosh law) and log s_a [m^3]
    chamber_softening: jax.Array = eqx.field(converter=jnp.asarray, default=0.0)
    log_softening_scale: jax.Array = eqx.field(converter=jnp.asarray, default=np.log(30e-6))
    # a chamber swollen past V_u resists the folds: k = softplus(.)
    swelling_resistance: jax.Array = eqx.field(converter=jnp.asarray, default=-20.0)
    # fold-count predictor: boundary in (Omega, C) and transition widths
    three_fold_boundary: jax.Array = eqx.field(converter=jnp.asarray, default=(1.5, 0.35))
    three_fold_width: jax.Array = eqx.field(converter=jnp.asarray, default=(0.1, 0.02))
    domain: Domain = eqx.field(static=True, default=Domain())

    # ----------------------------------------------------------------------------- geometry
    @property
    def unloaded_volume(self) -> jax.Array:
        """V_u: the cavity of the unloaded shell (m^3), 108.6 ml for the paper's shell."""
        return cavity_volume(self.shell)

    def cable_length(self, omega) -> jax.Array:
        """L(Omega) (m), eq. (3)."""
        return cable_length(self.shell, omega)

    # ------------------------------------------------------------------------ volume law
    def _log_volume_drops(self, shortening, omega):
        """(h_0, f): ``-log(V_eq / V_u)`` split into what shortening alone takes (h_0, the
        terms in a and b) and what the folds take (f, the buckling step or the three-fold
        depth); EF_0 = 1 - exp(-(h_0 + f)) for a chamber that is not swollen."""
        w = centred_omega(omega)
        helix = jnp.tanh(omega / HELIX_SWITCH)
        a = _softplus(self.ef_linear[0]) + _softplus(self.ef_linear[1]) * helix
        b = _softplus(self.ef_quadratic[0] + self.ef_quadratic[1] * w)
        tau = _softplus(self.buckling_twist)
        width = _softplus(self.buckling_width)
        twist = omega * shortening
        step = jax.nn.sigmoid((twist - tau) / width) - jax.nn.sigmoid(-tau / width)
        depth = _softplus(self.fold_depth[0]) + _softplus(self.fold_depth[1]) * twist
        # normalised like the buckling step, so that EF_0 is exactly 0 at C = 0 for every Omega
        three = self.three_fold_probability(omega, shortening) - self.three_fold_probability(
            omega, jnp.zeros_like(shortening)
        )
        folding = (1.0 - three) * step * depth + three * _softplus(self.three_fold_depth)
        return a * shortening + b * shortening**2, folding

    @property
    def swelling(self) -> jax.Array:
        """k >= 0: how strongly a swollen chamber resists the folds (module docstring)."""
        return _softplus(self.swelling_resistance)

    def chamber(self, x, omega) -> Chamber:
        """The chamber law at cable pull x (m): V_eq, its swelling, E(x) and beta."""
        shortening_drop, fold_drop = self._log_volume_drops(x / self.cable_length(omega), omega)
        ef0 = -jnp.expm1(-(shortening_drop + fold_drop))
        # folding softens the chamber: E = E_u exp(-kappa EF_0)
        elastance = jnp.exp(self.log_chamber_elastance - _softplus(self.fold_compliance) * ef0)
        return Chamber(
            rest_volume=self.unloaded_volume * (1.0 - ef0),
            fold_drop=fold_drop,
            swelling=self.swelling,
            unloaded_volume=self.unloaded_volume,
            elastance=elastance,
            stiffening=jnp.exp(self.log_stiffening),
            softening=self.softening,
            softening_scale=jnp.exp(self.log_softening_scale),
        )

    @property
    def softening(self) -> jax.Array:
        """a = r^2 / (1 + r^2) in [0, 1): the chamber's membrane softening (format 4)."""
        r2 = self.chamber_softening**2
        return r2 / (1.0 + r2)

    def zero_pressure_volume(self, x, omega) -> jax.Array:
        """V_eq(x; Omega) (m^3): the cavity volume at zero pressure for a cable pull x (m)."""
        return self.volume(jnp.zeros_like(jnp.asarray(x, dtype=float)), x, omega)

    # ------------------------------------------------------------------------- the potential
    def _buckling_shortening_ratio(self, c, omega):
        """(C / C_b)^2 with C_b = tau / Omega, written without dividing by Omega (Omega = 0 ok)."""
        return (c * omega / _softplus(self.buckling_twist)) ** 2

    def _shell_energy(self, x, omega):
        """W(x; Omega) (J): zero-pressure strain energy; W' = K x / (1 + (x/x_b)^2)^g."""
        length = self.cable_length(omega)
        k = jnp.exp(self.log_stiffness[0] + self.log_stiffness[1] * (omega - 4.0) / 4.0)
        g = _softplus(self.softening_exponent) + 0.5
        r = self._buckling_shortening_ratio(x / length, omega)  # (x / x_b)^2
        # x_b^2 = x^2 / r; W = K x_b^2 / (2 (1 - g)) ((1 + r)^(1 - g) - 1), written through
        # x^2 * phi(r) with phi(r) = ((1 + r)^(1 - g) - 1) / (r (1 - g)), smooth at r = 0 and
        # at g = 1 (where it is log1p(r) / r).
        one_minus_g = 1.0 - g
        safe_r = jnp.where(r > 1e-12, r, 1.0)
        log1p_r = jnp.log1p(safe_r)
        z = one_minus_g * log1p_r
        safe_z = jnp.where(jnp.abs(z) > 1e-12, z, 1.0)
        phi_big = jnp.where(jnp.abs(z) > 1e-12, jnp.expm1(safe_z) / safe_z, 1.0 + 0.5 * z)
        phi = jnp.where(r > 1e-12, phi_big * log1p_r / safe_r, 1.0 - 0.5 * g * r)
        return 0.5 * k * x**2 * phi

    def chamber_elastance(self, x, omega):
        """E (Pa/m^3): chamber stiffness at zero pressure, softened as the shell folds."""
        return self.chamber(x, omega).elastance

    def energy(self, V, x, omega) -> jax.Array:
        """U(V, x; Omega) (J): strain energy of the shell at cavity volume V (m^3), pull x (m)."""
        return self._shell_energy(x, omega) + self.chamber(x, omega).energy(V)

    def pressure(self, V, x, omega) -> jax.Array:
        """Chamber elastic pressure dU/dV (Pa), by autodiff of the V-dependent part of U."""
        return self.chamber(x, omega).pressure(V)

    def force(self, V, x, omega) -> jax.Array:
        """Total cable force dU/dx (N), on all cables together."""
        return jax.grad(self.energy, argnums=1)(V, x, omega)

    def stiffness(self, V, x, omega) -> jax.Array:
        """Chamber stiffness d2U/dV2 (Pa/m^3), positive on the fitted domain (fit's check)."""
        return self.chamber(x, omega).stiffness(V)

    def volume(self, pressure, x, omega) -> jax.Array:
        """The cavity volume (m^3) at chamber pressure ``pressure`` (Pa) and pull x (m), unique
        where U is convex in V (:meth:`Chamber.volume`)."""
        return self.chamber(x, omega).volume(pressure)

    def zero_pressure_force(self, x, omega) -> jax.Array:
        """Cable force (N) at zero chamber pressure: W'(x)."""
        return jax.grad(self._shell_energy)(x, omega)

    # ------------------------------------------------------------------ user-facing summaries
    def check(self, omega=None, shortening=None, pressure=None, *, extrapolate=False) -> bool:
        """Check user inputs against the fitted domain.

        Returns ``True`` when every given value is inside :attr:`domain`. Outside it, raise a
        ``ValueError`` naming the parameter, unless ``extrapolate=True``: then return ``False``
        (the caller flags the result as an extrapolation). Non-finite values always raise.
        """
        d = self.domain
        checks = [
            ("helix parameter Omega", omega, "-", d.omega, 1.0, (0.0, np.inf)),
            ("shortening C", shortening, "-", d.shortening, 1.0, (0.0, 1.0)),
            ("pressure", pressure, "mmHg", d.pressure_mmHg, mmHg, (-np.inf, np.inf)),
        ]
        inside = True
        for name, value, unit, (lo, hi), scale, (hard_lo, hard_hi) in checks:
            if value is None:
                continue
            # physically impossible values always raise
            check_range(name, value, unit, hard_lo, hard_hi, hi_open=hard_hi == 1.0, scale=scale)
            try:
                check_range(f"{name} (fitted domain)", value, unit, lo, hi, scale=scale)
            except ValueError:
                if not extrapolate:
                    raise
                inside = False
        return inside

    def ejection_fraction(self, omega, shortening, pressure=0.0, *, extrapolate=False):
        """EF = 1 - V(P, C L) / V_u (dimensionless), the volume drop at chamber pressure P (Pa).

        At ``pressure = 0`` this is Table I's quantity (as a fraction, not percent). Raises outside
        the fitted domain unless ``extrapolate=True``.
        """
        self.check(omega, shortening, pressure, extrapolate=extrapolate)
        omega = jnp.asarray(omega, dtype=float)
        x = shortening * self.cable_length(omega)
        volume = self.volume(jnp.asarray(pressure, dtype=float), x, omega)
        return 1.0 - volume / self.unloaded_volume

    def three_fold_probability(self, omega, shortening) -> jax.Array:
        """Smooth indicator (0..1) that the shell folds into three lobes rather than four."""
        (omega_c, c_c), (w_o, w_c) = self.three_fold_boundary, self.three_fold_width
        return jax.nn.sigmoid((omega_c - omega) / w_o) * jax.nn.sigmoid((shortening - c_c) / w_c)

    def folds(self, omega, shortening, *, extrapolate=False) -> jax.Array:
        """Predicted number of folds (3 or 4) of the contracted shell (Table I)."""
        self.check(omega, shortening, extrapolate=extrapolate)
        p3 = self.three_fold_probability(jnp.asarray(omega, float), jnp.asarray(shortening, float))
        return jnp.where(p3 > 0.5, 3, 4)


# --------------------------------------------------------------------------------- artifacts
def artifact_dir() -> Path:
    """The folder holding the shipped surrogates, after an editable or a regular install."""
    packaged = resources.files("cardiosoft") / "_surrogates"
    if packaged.is_dir():
        return Path(str(packaged))
    repo = Path(__file__).resolve().parent.parent / "surrogates"
    if repo.is_dir():
        return repo
    raise FileNotFoundError(
        "no surrogates folder found: expected the package data cardiosoft/_surrogates or "
        f"{repo} in a source checkout"
    )


def save(model: PumpSurrogate, path, card: dict, format_version: int = FORMAT_VERSION) -> None:
    """Write ``model`` to ``path`` (``.eqx``, equinox leaf serialisation) and its card (``.json``).

    The card gets the format version and the sha256 of the weights file; a format-3 file holds
    no membrane softening (:data:`FORMAT_4_FIELDS`), which must then be a = 0. Both files are
    written whole (temporary file + rename).
    """
    if format_version not in READ_FORMAT_VERSIONS:
        raise ValueError(f"format_version = {format_version}: allowed {READ_FORMAT_VERSIONS}")
    if format_version < 4:
        if float(model.softening) != 0.0:
            raise ValueError("a format-3 surrogate has no membrane softening (a must be 0)")
        model = eqx.tree_at(
            lambda m: [getattr(m, f) for f in FORMAT_4_FIELDS], model, replace_fn=lambda _: None
        )
    path = Path(path).with_suffix(".eqx")
    with atomic_path(path) as tmp:
        eqx.tree_serialise_leaves(tmp, model)
        digest = sha256(tmp)
    card = {
        **card,
        "format_version": format_version,
        "weights_file": path.name,
        "weights_sha256": digest,
    }
    with atomic_path(path.with_suffix(".json")) as tmp:
        tmp.write_text(json.dumps(card, indent=2) + "\n")


def load_card(path=None) -> dict:
    """The JSON model card of the surrogate at ``path`` (default: the shipped one)."""
    weights = artifact_path(path)
    return json.loads(weights.with_suffix(".json").read_text())


def artifact_path(path=None) -> Path:
    """The weights file (``.eqx``) of the surrogate ``path``: a shipped name
    (:data:`SHIPPED_ARTIFACTS`), or the path of its ``.eqx`` or ``.json`` (default: the
    :data:`DEFAULT_ARTIFACT`)."""
    if path is None:
        path = DEFAULT_ARTIFACT
    if str(path) in SHIPPED_ARTIFACTS:
        return artifact_dir() / f"{path}.eqx"
    path = Path(path)
    return path if path.suffix == ".eqx" else path.with_suffix(".eqx")


def check_pump_name(name) -> str:
    """``name`` if it names a shipped surrogate or an existing artifact file; a
    ``ValueError`` naming the allowed values otherwise (a CLI's ``--pump``, a scene's key)."""
    if str(name) in SHIPPED_ARTIFACTS or artifact_path(name).is_file():
        return str(name)
    raise ValueError(
        f"pump = {str(name)!r}: allowed a shipped surrogate ({', '.join(SHIPPED_ARTIFACTS)}) "
        "or the path of a surrogate's .eqx or .json file"
    )


def _checked_card(card_path: Path, data_path: Path, versions, what: str) -> dict:
    """The JSON card at ``card_path``, once it and ``data_path`` exist and its format version
    is one of ``versions`` (``FileNotFoundError``, ``ValueError`` otherwise)."""
    for p in (data_path, card_path):
        if not p.is_file():
            raise FileNotFoundError(f"{what} file {p} not found")
    card = json.loads(card_path.read_text())
    if card.get("format_version") not in versions:
        raise ValueError(
            f"{card_path}: format_version {card.get('format_version')!r} is not supported "
            f"(this cardiosoft reads {', '.join(map(str, versions))})"
        )
    return card


def load(path=None) -> PumpSurrogate:
    """Load a fitted :class:`PumpSurrogate`: the shipped default, or the artifact at ``path``.

    ``path`` names the weights (``.eqx``) or the card (``.json``); the two sit side by side. The
    card's format version and the weights' sha256 are checked; nothing is ever unpickled.
    """
    weights = artifact_path(path)
    card = _checked_card(weights.with_suffix(".json"), weights, READ_FORMAT_VERSIONS, "surrogate")
    digest = sha256(weights)
    if digest != card.get("weights_sha256"):
        raise ValueError(
            f"{weights}: sha256 {digest} does not match the card's {card.get('weights_sha256')}; "
            "the weights were changed after the fit"
        )
    skeleton = PumpSurrogate(domain=Domain(**{k: tuple(v) for k, v in card["domain"].items()}))
    # Deserialise into a float64 skeleton when x64 is on, float32 otherwise.
    skeleton = jax.tree_util.tree_map(
        lambda a: jnp.asarray(a, dtype=float) if eqx.is_array(a) else a, skeleton
    )
    if card["format_version"] >= 4:
        return eqx.tree_deserialise_leaves(weights, skeleton)
    # a format-3 file holds every leaf but the membrane softening's: read the others, then
    # put the defaults back (a = 0, the cosh law the file was fitted with)
    defaults = [getattr(skeleton, f) for f in FORMAT_4_FIELDS]
    older = eqx.tree_at(
        lambda m: [getattr(m, f) for f in FORMAT_4_FIELDS], skeleton, replace_fn=lambda _: None
    )
    model = eqx.tree_deserialise_leaves(weights, older)
    return eqx.tree_at(
        lambda m: [getattr(m, f) for f in FORMAT_4_FIELDS],
        model,
        defaults,
        is_leaf=lambda x: x is None,
    )


POSTERIOR_FORMAT_VERSION = 1
"""Version of the posterior artifact (``surrogates/<name>-posterior.npz`` + ``.json``)."""


class PosteriorDraws(NamedTuple):
    """The posterior of a fitted surrogate as one ensemble (:func:`load_posterior`).

    - ``pump``: one :class:`PumpSurrogate` whose fitted array leaves carry a leading axis of S
      draws (the others are the artifact's); ``cardiosoft.solve_beats(..., pump=pump,
      scene_draws=scene_draws)`` solves all draws in one call.
    - ``scene_draws``: the rig per draw, ``{scene field: (S,) array}`` in SI: the column's
      diameter and the cable friction (fitted with the surrogate) and the bench's calibrated
      tube and shell viscoelasticity (``fit.bench``).
    - ``scene_centre``: the values those draws are centred on (SI): the model card's rig and the
      bench scene's calibrated numbers when the posterior was computed.
    - ``card``: the posterior's JSON card: how it was computed, the sigmas and priors, the
      model discrepancy per output type, the checks.
    """

    pump: PumpSurrogate
    scene_draws: dict
    scene_centre: dict
    card: dict


def load_posterior(path=None) -> PosteriorDraws:
    """The posterior draws of the surrogate at ``path`` (default: the shipped one).

    The surrogate's model card names the posterior (its ``posterior`` entry, written by
    ``python -m fit.posterior``); the draws' sha256 must match the card's and the posterior
    card's, and the posterior must have been computed for these very weights. Nothing is
    unpickled (``numpy.load(..., allow_pickle=False)``).
    """
    weights = artifact_path(path)
    card = load_card(weights)
    entry = card.get("posterior")
    if entry is None:
        raise FileNotFoundError(
            f"{weights.with_suffix('.json')}: no posterior recorded for this surrogate; "
            "compute one with python -m fit.posterior"
        )
    draws_path, card_path = weights.parent / entry["file"], weights.parent / entry["card"]
    posterior = _checked_card(card_path, draws_path, (POSTERIOR_FORMAT_VERSION,), "posterior")
    digest = sha256(draws_path)
    if not digest == entry["sha256"] == posterior.get("sha256"):
        raise ValueError(
            f"{draws_path}: sha256 {digest} does not match the model card's {entry['sha256']} "
            f"and the posterior card's {posterior.get('sha256')}; the draws were changed"
        )
    if posterior.get("weights_sha256") != card["weights_sha256"]:
        raise ValueError(
            f"{card_path}: computed for weights {posterior.get('weights_sha256')}, not for "
            f"{weights} ({card['weights_sha256']}); recompute with python -m fit.posterior"
        )
    pump = load(weights)
    with np.load(draws_path, allow_pickle=False) as f:
        fields = [k.removeprefix("pump.") for k in f.files if k.startswith("pump.")]
        arrays = [jnp.asarray(f[f"pump.{k}"], dtype=float) for k in fields]
        scene = {
            k.removeprefix("scene."): np.asarray(f[k], float)
            for k in f.files
            if k.startswith("scene.")
        }
        centre = {
            k.removeprefix("centre."): float(f[k]) for k in f.files if k.startswith("centre.")
        }
    for name, a in zip(fields, arrays, strict=True):
        single = jnp.shape(getattr(pump, name))
        if a.ndim != len(single) + 1 or a.shape[1:] != single:
            raise ValueError(
                f"{draws_path}: pump.{name} has shape {a.shape}, not (draws, *{single})"
            )
    pump = eqx.tree_at(lambda m: [getattr(m, k) for k in fields], pump, arrays)
    return PosteriorDraws(pump, scene, centre, posterior)
