"""svZeroDSolver's heart blocks, in the semi-explicit form of :mod:`cardiosoft.network.blocks`.

The elastances and activations follow ``ClosedLoopHeartPulmonary.cpp`` and
``ActivationFunction.cpp`` of ``SimVascular/svZeroDSolver`` (time folded with
``fmod(t, period)``).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from cardiosoft.network.blocks import Block

FOURIER_ELASTANCE = (
    (0.283748803, 0.000000000),
    (0.031830626, -0.374299825),
    (-0.209472400, -0.018127770),
    (0.020520047, 0.073971113),
    (0.008316883, -0.047249597),
    (-0.041677660, 0.003212163),
    (0.000867323, 0.019441411),
    (-0.001675379, -0.005565534),
    (-0.011252277, 0.003401432),
    (-0.000414677, 0.008376795),
    (0.000253749, -0.000071880),
    (-0.002584966, 0.001566861),
    (0.000584752, 0.003143555),
    (0.000028502, -0.000024787),
    (0.000022961, -0.000007476),
    (0.000018735, -0.000001281),
    (0.000015573, 0.000001781),
    (0.000013133, 0.000003494),
    (0.000011199, 0.000004507),
    (0.000009634, 0.000005117),
    (0.000008343, 0.000005481),
    (0.000007265, 0.000005687),
    (0.000006354, 0.000005789),
    (0.000005575, 0.000005821),
    (0.000004903, 0.000005805),
)
"""svZeroDSolver's 25 Fourier modes (cos, sin) of the normalised ventricular elastance."""


def fourier_elastance(t_in_cycle, period):
    """The normalised ventricular elastance (unscaled, as upstream's ``Elv_i``)."""
    modes = np.asarray(FOURIER_ELASTANCE)
    k = jnp.arange(modes.shape[0])
    phase = 2.0 * jnp.pi * k * t_in_cycle / period
    return jnp.sum(modes[:, 0] * jnp.cos(phase) - modes[:, 1] * jnp.sin(phase))


def wrapping_cosine(t_in_cycle, period, Tsa, tpwave):
    """The atrial activation (upstream's ``AA``): a raised cosine of length ``Tsa`` periods that
    ends ``1/tpwave`` of a period into the beat, wrapping around the beat's start."""
    length, end = period * Tsa, period / tpwave
    first = 0.5 * (1.0 - jnp.cos(2.0 * jnp.pi * (t_in_cycle - end + length) / length))
    wrapped = 0.5 * (1.0 - jnp.cos(2.0 * jnp.pi * (t_in_cycle - end - (period - length)) / length))
    return jnp.where(
        t_in_cycle <= end,
        first,
        jnp.where((t_in_cycle >= period - length + end) & (t_in_cycle < period), wrapped, 0.0),
    )


HEART_PARAMETERS = (
    "Tsa", "tpwave", "Erv_s", "Elv_s", "iml", "imr", "Lrv_a", "Rrv_a", "Lra_v", "Rra_v",
    "Lla_v", "Rla_v", "Rlv_ao", "Llv_a", "Vrv_u", "Vlv_u", "Rpd", "Cp", "Cpa", "Kxp_ra",
    "Kxv_ra", "Emax_ra", "Vaso_ra", "Kxp_la", "Kxv_la", "Emax_la", "Vaso_la",
)  # fmt: skip
"""``ClosedLoopHeartAndPulmonary``'s parameters (all required, as upstream; ``iml`` and
``imr`` are read only by the closed-loop coronary blocks)."""

_STATES = ("V_RA", "Q_RA", "V_RV", "Q_RV", "P_pul", "V_LA", "Q_LA", "V_LV", "Q_LV")
_VALVES = ("Q_RA", "Q_RV", "Q_LA", "Q_LV")


class ClosedLoopHeart(Block):
    """svZeroDSolver's ``ClosedLoopHeartAndPulmonary``: four chambers, four valves and the
    pulmonary circulation, between the inlet node (right atrium) and the outlet node (aorta,
    a capacitor ``Cpa`` to ground). Ports: inlet, outlet.

    States: the chambers' volumes, the four valves' inductor flows, the pulmonary pressure and
    the aortic pressure. The atria follow an exponential passive law blended with an active
    elastance by the activation ``AA``; the ventricles a Fourier elastance. Each valve is
    upstream's hard switch: closed while its upstream pressure is at most its downstream one
    and its flow is at most zero; a closed valve's flow holds and counts as zero (upstream
    sets it to zero after each step). As upstream, the left atrium fills with the right
    ventricle's outflow, not the pulmonary flow: blood volume is conserved only over a beat.
    """

    p: dict
    period: float = eqx.field(static=True)
    kind = "ClosedLoopHeartAndPulmonary"
    marchable = False
    n_states = len(_STATES) + 1

    def state_kinds(self):
        kinds = {"V": "volume", "Q": "flow", "P": "pressure"}
        return (*(kinds[s[0]] for s in _STATES), "pressure")

    def internal_names(self):
        names = ("V_RA", "Q_RA", "P_RV", "V_RV", "Q_RV", "P_pul", "P_LA", "V_LA", "Q_LA")
        return tuple(f"{n}:{self.name}" for n in (*names, "P_LV", "V_LV", "Q_LV"))

    def chamber_volumes(self):
        return {f"{self.name}:{c}": f"V_{c}:{self.name}" for c in ("RA", "RV", "LA", "LV")}

    def _chambers(self, t, x, P):
        """Every pressure and each valve's open flag (1.0 or 0.0) at ``(t, x)``."""
        p = self.p
        s = dict(zip(_STATES, x, strict=False))
        tau = jnp.fmod(t, self.period)
        active = wrapping_cosine(tau, self.period, p["Tsa"], p["tpwave"])
        elastance = fourier_elastance(tau, self.period)

        def atrium(V, side):
            passive = p[f"Kxp_{side}"] * (jnp.exp((V - p[f"Vaso_{side}"]) * p[f"Kxv_{side}"]) - 1.0)
            return active * p[f"Emax_{side}"] * (V - p[f"Vaso_{side}"]) + (1.0 - active) * passive

        pressure = {
            "RA": atrium(s["V_RA"], "ra"),
            "RV": elastance * p["Erv_s"] * (s["V_RV"] - p["Vrv_u"]),
            "pul": s["P_pul"],
            "LA": atrium(s["V_LA"], "la"),
            "LV": elastance * p["Elv_s"] * (s["V_LV"] - p["Vlv_u"]),
            "ao": x[-1],
        }
        chain = (("RA", "RV"), ("RV", "pul"), ("LA", "LV"), ("LV", "ao"))
        is_open = {
            q: jnp.where((pressure[a] <= pressure[b]) & (s[q] <= 0.0), 0.0, 1.0)
            for q, (a, b) in zip(_VALVES, chain, strict=True)
        }
        return s, pressure, is_open

    def residuals(self, t, x, P, Q, steady=False):
        _, pressure, _ = self._chambers(t, x, P)
        return jnp.stack([P[0] - pressure["RA"], P[1] - pressure["ao"]])

    def rates(self, t, x, P, Q, steady=False):
        p = self.p
        s, pr, v = self._chambers(t, x, P)
        flow = {q: v[q] * s[q] for q in _VALVES}

        def inductor(q, up, down, R, L):
            return v[q] * (pr[up] - pr[down] - p[R] * s[q]) / p[L]

        return jnp.stack(
            [
                Q[0] - flow["Q_RA"],
                inductor("Q_RA", "RA", "RV", "Rra_v", "Lra_v"),
                flow["Q_RA"] - flow["Q_RV"],
                inductor("Q_RV", "RV", "pul", "Rrv_a", "Lrv_a"),
                (flow["Q_RV"] - (pr["pul"] - pr["LA"]) / p["Rpd"]) / p["Cp"],
                flow["Q_RV"] - flow["Q_LA"],  # upstream's: the RV's outflow fills the LA
                inductor("Q_LA", "LA", "LV", "Rla_v", "Lla_v"),
                flow["Q_LA"] - flow["Q_LV"],
                inductor("Q_LV", "LV", "ao", "Rlv_ao", "Llv_a"),
                (flow["Q_LV"] - Q[1]) / p["Cpa"],
            ]
        )

    def states_from(self, values):
        n = self.name
        return [values[f"{s}:{n}"] for s in _STATES] + [values["P"][1]]

    def outputs(self, t, x, P, Q):
        s, pr, v = self._chambers(t, x, P)
        out = {f"{k}:{self.name}": s[k] for k in ("V_RA", "V_RV", "P_pul", "V_LA", "V_LV")}
        out.update({f"{q}:{self.name}": v[q] * s[q] for q in _VALVES})
        out.update({f"P_{c}:{self.name}": pr[c] for c in ("RV", "LA", "LV")})
        return out


ACTIVATIONS = {
    "half_cosine": ("t_active", "t_twitch"),
    "piecewise_cosine": ("contract_start", "relax_start", "contract_duration", "relax_duration"),
    "two_hill": ("t_shift", "tau_1", "tau_2", "m1", "m2"),
    "fourier": (),
    "wrapping_cosine": ("Tsa", "tpwave"),
}
"""svZeroDSolver's activation functions of a chamber and their parameters
(``ActivationFunction.cpp``)."""


def _two_hill_raw(t, p):
    g1 = (t / p["tau_1"]) ** p["m1"]
    g2 = (t / p["tau_2"]) ** p["m2"]
    return g1 / (1.0 + g1) / (1.0 + g2)


class Activation(eqx.Module):
    """A chamber's activation in [0, 1] over the beat, as upstream computes it. ``scale`` and
    ``offset`` (static) normalise ``two_hill`` and ``fourier`` as upstream does, from samples
    of one beat (every 1e-5 s; 10,000 a beat)."""

    kind: str = eqx.field(static=True)
    p: dict
    period: float = eqx.field(static=True)
    scale: float = eqx.field(static=True, default=1.0)
    offset: float = eqx.field(static=True, default=0.0)

    @classmethod
    def build(cls, kind: str, p: dict, period: float) -> Activation:
        p = {k: float(v) for k, v in p.items()}
        if kind == "two_hill":
            samples = np.arange(0.0, period, 1e-5)
            return cls(kind, p, period, 1.0 / float(np.max(_two_hill_raw(samples, p))))
        if kind == "fourier":
            modes = np.asarray(FOURIER_ELASTANCE)
            phase = 2.0 * np.pi * np.outer(np.arange(10000) / 10000, np.arange(len(modes)))
            raw = np.cos(phase) @ modes[:, 0] - np.sin(phase) @ modes[:, 1]
            low, high = float(raw.min()), float(raw.max())
            return cls(kind, p, period, 1.0 / ((high - low) or 1.0), low)
        return cls(kind, p, period)

    def __call__(self, t):
        p, T = self.p, self.period
        tau = jnp.fmod(t, T)
        if self.kind == "half_cosine":
            since = jnp.where(tau >= p["t_active"], tau - p["t_active"], 0.0)
            rising = 0.5 - 0.5 * jnp.cos(2.0 * jnp.pi * since / p["t_twitch"])
            return jnp.where(since <= p["t_twitch"], rising, 0.0)
        if self.kind == "piecewise_cosine":
            c = jnp.fmod(t - p["contract_start"], T)
            r = jnp.fmod(t - p["relax_start"], T)
            contracting = 0.5 * (1.0 - jnp.cos(jnp.pi * c / p["contract_duration"]))
            relaxing = 0.5 * (1.0 + jnp.cos(jnp.pi * r / p["relax_duration"]))
            relax = jnp.where((r >= 0.0) & (r < p["relax_duration"]), relaxing, 0.0)
            return jnp.where((c >= 0.0) & (c < p["contract_duration"]), contracting, relax)
        if self.kind == "two_hill":
            shifted = jnp.fmod(tau - p["t_shift"], T)
            shifted = jnp.where(shifted >= 0.0, shifted, shifted + T)
            return self.scale * _two_hill_raw(shifted, p)
        if self.kind == "fourier":
            return (fourier_elastance(tau, T) - self.offset) * self.scale
        return wrapping_cosine(tau, T, p["Tsa"], p["tpwave"])


CHAMBER_PARAMETERS = {
    "ChamberElastanceInductor": ("Emax", "Emin", "Vrd", "Vrs", "Impedance"),
    "ChamberElastanceInductorExponential": ("Emax", "Kxp", "Kxv", "Vaso", "Impedance"),
    "LinearElastanceChamber": ("Emax", "Epass", "Vrest"),
}
"""svZeroDSolver's chambers with an activation, and their parameters."""


class Chamber(Block):
    """svZeroDSolver's chambers (``ChamberElastanceInductor.cpp`` and its ``Exponential``
    variant, ``LinearElastanceChamber.cpp``). Ports: inlet, outlet. States: the volume
    ``Vc:NAME`` and, with an ``Impedance`` (inductance) > 0, the outflow.

    Pressure at the inlet, with the activation ``a(t)``:

    - ``ChamberElastanceInductor``: ``E (Vc - Vrest)``, ``E = Emin + (Emax - Emin) a``,
      ``Vrest = Vrs + (1 - a) (Vrd - Vrs)``;
    - ``...Exponential``: ``a Emax (Vc - Vaso) + (1 - a) Kxp (exp(Kxv (Vc - Vaso)) - 1)``;
    - ``LinearElastanceChamber``: ``(Epass + Emax a) (Vc - Vrest)``, no inductor.

    ``dVc/dt = Q_in - Q_out``; ``L dQ_out/dt = P_in - P_out`` (``P_in = P_out`` without one).
    """

    p: dict
    activation: Activation
    law: str = eqx.field(static=True)
    has_L: bool = eqx.field(static=True)
    keeps_time = True

    @property
    def kind(self):
        return self.law

    @property
    def n_states(self):
        return 1 + int(self.has_L)

    def state_kinds(self):
        return ("volume",) + ("flow",) * self.has_L

    def internal_names(self):
        return (f"Vc:{self.name}",)

    def pressure(self, t, volume):
        p, a = self.p, self.activation(t)
        if self.law == "ChamberElastanceInductor":
            rest = p["Vrs"] + (1.0 - a) * (p["Vrd"] - p["Vrs"])
            return (p["Emin"] + (p["Emax"] - p["Emin"]) * a) * (volume - rest)
        if self.law == "ChamberElastanceInductorExponential":
            passive = p["Kxp"] * (jnp.exp(p["Kxv"] * (volume - p["Vaso"])) - 1.0)
            return a * p["Emax"] * (volume - p["Vaso"]) + (1.0 - a) * passive
        return (p["Epass"] + p["Emax"] * a) * (volume - p["Vrest"])

    def residuals(self, t, x, P, Q, steady=False):
        second = Q[1] - x[1] if self.has_L else P[0] - P[1]
        return jnp.stack([P[0] - self.pressure(t, x[0]), second])

    def rates(self, t, x, P, Q, steady=False):
        volume = Q[0] - Q[1]
        if self.has_L:
            return jnp.stack([volume, (P[0] - P[1]) / self.p["Impedance"]])
        return jnp.stack([volume])

    def states_from(self, values):
        return [values[f"Vc:{self.name}"]] + [values["Q"][1]] * self.has_L

    def outputs(self, t, x, P, Q):
        return {f"Vc:{self.name}": x[0]}


SPHERE_PARAMETERS = (
    "rho", "thick0", "radius0", "W1", "W2", "eta", "sigma_max", "alpha_max", "alpha_min",
    "tsys", "tdias", "steepness",
)  # fmt: skip
"""``ChamberSphere``'s parameters, in upstream's order (``ChamberSphere.h``)."""


class ChamberSphere(Block):
    """svZeroDSolver's spherical chamber (``ChamberSphere.cpp``; Caruel et al. 2013, eq. 13a-b,
    with the active stress of Pfaller et al. 2019, eq. 12-16): a thin spherical shell of
    reference radius ``r0`` and thickness ``d0`` whose wall moves. Ports: inlet, outlet, at one
    pressure. States: the radial displacement r, its velocity v, the active stress tau and the
    volume change V (``radius:NAME``, ``velo:NAME``, ``tau:NAME``, ``volume:NAME``); the
    spherical stress S (``stress:NAME``) is algebraic. With ``R = r0 + r``:

    - momentum: ``rho d0 dv/dt = R (P_out R - S d0) / r0^2``;
    - stress: ``S = tau + 2 (v eta (2 r0^12 + R^12) + 2 R^5 (R^6 - r0^6) (W1 r0^2 + W2 R^2))
      / (r0^2 R^11)``;
    - ``dr/dt = v``, ``dV/dt = 4 pi R^2 v``, ``Q_in - Q_out = dV/dt``, ``P_in = P_out``;
    - active stress: ``dtau/dt = -|a| tau + sigma_max max(a, 0)``, ``a = f alpha_max + (1 - f)
      alpha_min``, ``f = (1 + tanh((t - tsys) / steepness)) (1 - tanh((t - tdias) /
      steepness)) / 4``, t folded with ``fmod(t, period)``.

    Upstream's stress equation takes ``dr/dt`` from the scheme where this takes v: the two are
    one by ``dr/dt = v`` at every solution. Its ``volume`` is the change from its start, so it
    has no chamber record (an ejection fraction needs the volume itself).
    """

    p: dict
    period: jnp.ndarray = eqx.field(converter=jnp.asarray)
    kind = "ChamberSphere"
    n_states = 4
    nonlinear = True
    keeps_time = True

    def state_kinds(self):
        return ("volume", "flow", "pressure", "volume")

    def internal_names(self):
        return tuple(f"{v}:{self.name}" for v in ("radius", "velo", "stress", "tau", "volume"))

    def stress(self, x):
        """The spherical stress S (the model's units) at the states ``x``."""
        p = self.p
        r0 = p["radius0"]
        big = r0 + x[0]
        viscous = x[1] * p["eta"] * (2.0 * r0**12 + big**12)
        elastic = 2.0 * big**5 * (big**6 - r0**6) * (p["W1"] * r0**2 + p["W2"] * big**2)
        return x[2] + 2.0 * (viscous + elastic) / (r0**2 * big**11)

    def activation(self, t):
        """``(|a|, max(a, 0))`` at time t."""
        p = self.p
        tau = jnp.fmod(t, self.period)
        rising = 0.5 * (1.0 + jnp.tanh((tau - p["tsys"]) / p["steepness"]))
        falling = 0.5 * (1.0 - jnp.tanh((tau - p["tdias"]) / p["steepness"]))
        f = rising * falling
        a = p["alpha_max"] * f + p["alpha_min"] * (1.0 - f)
        return jnp.abs(a), jnp.maximum(a, 0.0)

    def _volume_rate(self, x):
        return 4.0 * jnp.pi * (self.p["radius0"] + x[0]) ** 2 * x[1]

    def residuals(self, t, x, P, Q, steady=False):
        return jnp.stack([P[0] - P[1], Q[0] - Q[1] - self._volume_rate(x)])

    def rates(self, t, x, P, Q, steady=False):
        p = self.p
        big = p["radius0"] + x[0]
        momentum = big * (P[1] * big - self.stress(x) * p["thick0"]) / p["radius0"] ** 2
        a, a_plus = self.activation(t)
        return jnp.stack(
            [
                x[1],
                momentum / (p["rho"] * p["thick0"]),
                -a * x[2] + p["sigma_max"] * a_plus,
                self._volume_rate(x),
            ]
        )

    def states_from(self, values):
        return [values[f"{v}:{self.name}"] for v in ("radius", "velo", "tau", "volume")]

    def outputs(self, t, x, P, Q):
        names = self.internal_names()
        values = (x[0], x[1], self.stress(x), x[2], x[3])
        return dict(zip(names, values, strict=True))
