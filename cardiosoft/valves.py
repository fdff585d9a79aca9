"""Valves: one-way couplings between a preload, the pump and an afterload (DESIGN.md 3.3).

Everything is SI: a pressure drop ``dp`` in Pa gives a flow in m^3/s; resistances in
Pa s/m^3. :class:`Valve` is the project's own (ideal diode, or a smooth passive law);
:class:`ArctanValve` the closed-loop model's of Regazzoni et al. 2022.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp

from cardiosoft._validate import _is_traced, check_positive, check_range
from cardiosoft.units import mmHg, mmHg_s_per_ml

__all__ = ["VALVE_KINDS", "VALVE_SMOOTHING", "ArctanValve", "Valve"]

_R = mmHg_s_per_ml
_INF = math.inf


VALVE_KINDS = ("ideal", "smooth")
VALVE_SMOOTHING = 0.5 * mmHg
"""Default width w (Pa) of the smooth valve law, for a :class:`Valve` and a scene's valves."""


class Valve(eqx.Module):
    """A one-way valve with forward resistance ``resistance`` R (Pa s/m^3).

    - ``kind="ideal"``: ``q = max(dp, 0) / R`` (m^3/s for dp in Pa; a diode, kinked at 0).
    - ``kind="smooth"``: ``q = dp sigmoid(dp / w) / R``, ``w = smoothing`` (Pa; default
      :data:`VALVE_SMOOTHING`, 0.5 mmHg). Chosen because it is

      - passive: ``dp q = dp^2 sigmoid(dp / w) / R >= 0`` for every dp, and q = 0 at dp = 0,
        so the valve only dissipates (with a resistance r in series, the valve's own drop
        ``dp - r q`` keeps the sign of dp: still >= 0). The earlier law
        ``w softplus(dp / w) / R`` passed ``w log 2 / R`` forward at dp = 0 (69 ml/s at w 0.5
        mmHg, R 0.005 mmHg s/ml) and forward flow against a closing dp: a negative loss;
      - close to the ideal diode: ``|q - q_ideal| <= 0.2785 w / R`` (m^3/s), the largest at
        ``|dp| = 1.2785 w``, so it converges to ``max(dp, 0) / R`` as ``w -> 0``, uniformly;
        away from 0 the gap falls as ``|dp| exp(-|dp| / w) / R``;
      - smooth (analytic) and without NaN branches (``sigmoid`` is evaluated stably).

      Its price: a closing dp lets a small backflow through (at most ``0.2785 w / R``, at
      ``dp = -1.2785 w``, vanishing exponentially beyond), and there the flow is not monotone
      in dp (slope down to ``-0.0998 / R`` at ``dp = -2.4 w``). A passive law that is smooth
      and monotone would have to be exactly 0 for every dp < 0 (not analytic), and one that
      is monotone and never 0 for dp < 0 leaks a constant backflow however closed the valve is.
    """

    resistance: jax.Array = eqx.field(converter=jnp.asarray)
    kind: str = eqx.field(static=True, default="ideal")
    smoothing: jax.Array = eqx.field(converter=jnp.asarray, default=VALVE_SMOOTHING)

    def __check_init__(self):
        if self.kind not in VALVE_KINDS:
            raise ValueError(f"valve kind = {self.kind!r} is not one of {', '.join(VALVE_KINDS)}")
        check_positive("valve resistance", self.resistance, "mmHg s/ml", scale=_R)
        check_positive("valve smoothing width", self.smoothing, "mmHg", scale=mmHg)

    def flow(self, dp, extra_resistance=0.0) -> jax.Array:
        """Forward flow (m^3/s) for a pressure drop ``dp`` (Pa) across the valve, with
        ``extra_resistance`` (Pa s/m^3, >= 0) in series. No branch can produce NaN here
        (R + extra > 0, the sigmoid is evaluated stably), so no double-where is needed.
        """
        R = self.resistance + extra_resistance
        if self.kind == "ideal":
            return jnp.maximum(dp, 0.0) / R
        return dp * jax.nn.sigmoid(dp / self.smoothing) / R


class ArctanValve(eqx.Module):
    """The valve law of Regazzoni et al. 2022 (J. Comput. Phys. 457, 111083; the closed-loop
    model's valves; ``notes/closed-loop-regazzoni.md``): a resistance switched on a log scale.

    ``q = dp / R(dp)`` (m^3/s for a drop ``dp = p_up - p_down`` in Pa), with
    ``log R = log R_min + (log R_max - log R_min) H(-dp)`` and the smooth step
    ``H(x) = 1/2 + arctan(pi k x / 2) / pi``: open (``R -> R_min``) for ``dp >> 1/k``, closed but
    leaking (``R -> R_max``) for ``dp << -1/k``.

    - ``min_resistance``, ``max_resistance``: R_min < R_max (Pa s/m^3); the paper's 0.0075 and
      75006.2 mmHg s/ml.
    - ``sharpness``: k (1/Pa); the paper's 200 per mmHg.

    Passive (``dp q = dp^2 / R >= 0``, q = 0 at dp = 0) and smooth, with no branch that can give
    NaN. Unlike :class:`Valve`'s smooth law it leaks a finite backflow however closed,
    ``|dp| / R_max`` (a closed valve against 100 mmHg: 1.3e-3 ml/s), as the paper's does.
    """

    min_resistance: jax.Array = eqx.field(converter=jnp.asarray)
    max_resistance: jax.Array = eqx.field(converter=jnp.asarray)
    sharpness: jax.Array = eqx.field(converter=jnp.asarray, default=200.0 / mmHg)

    def __check_init__(self):
        for name, value in (("minimum", self.min_resistance), ("maximum", self.max_resistance)):
            r = "Rmin" if name == "minimum" else "Rmax"
            check_positive(f"valve {name} resistance {r}", value, "mmHg s/ml", scale=_R)
        if not (_is_traced(self.min_resistance) or _is_traced(self.max_resistance)):
            lo = float(jnp.max(self.min_resistance)) / _R
            check_range(
                "valve maximum resistance Rmax",
                self.max_resistance,
                "mmHg s/ml",
                lo,
                _INF,
                lo_open=True,
                scale=_R,
            )
        check_positive("valve switch sharpness", self.sharpness, "1/mmHg", scale=1.0 / mmHg)

    def flow(self, dp) -> jax.Array:
        """Forward flow (m^3/s) for a pressure drop ``dp`` (Pa) across the valve."""
        closed = 0.5 + jnp.arctan(0.5 * jnp.pi * self.sharpness * -dp) / jnp.pi
        log_min = jnp.log(self.min_resistance)
        log_r = log_min + (jnp.log(self.max_resistance) - log_min) * closed
        return dp * jnp.exp(-log_r)
