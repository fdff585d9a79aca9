"""``cardiosoft.solve``: what the integrator does with forcing it cannot see coming."""

import equinox as eqx
import jax
import jax.numpy as jnp
import pytest

from cardiosoft.circulation import Windkessel3
from cardiosoft.solve import respond
from cardiosoft.units import mmHg

PERIOD, EJECTION, SV = 0.8, 0.3, 70e-6  # s, s, m^3
RP, C, RD = 6.67e6, 1.5e-8, 1.33e8  # Pa s/m^3, m^3/Pa, Pa s/m^3


class HalfSine(eqx.Module):
    """A half-sine ejection of volume ``sv`` over ``ejection`` s, once per ``period``."""

    sv: jax.Array
    period: jax.Array
    ejection: jax.Array

    def __call__(self, t):
        tau = jnp.mod(t, self.period)
        peak = self.sv * jnp.pi / (2 * self.ejection)
        return jnp.where(tau < self.ejection, peak * jnp.sin(jnp.pi * tau / self.ejection), 0.0)


@pytest.mark.parametrize("with_kinks", [False, True])
def test_a_pulse_between_two_steps_does_not_vanish(with_kinks):
    """Mean inlet pressure of a 3-element Windkessel at its periodic steady state: the
    capacitor passes no net flow over a period, so it is mean(q) (Rp + Rd) = 91.7 mmHg whatever
    the pulse's shape. Without a step cap and without the kinks, the solver stepped over whole
    pulses: 4.5 mmHg. Averaged over the last 5 of 20 periods, the transient (time constant
    Rd C = 2 s) has decayed to e^-6 of its start, and the samples (every 8 ms) average the
    pulse to ~0.1 %: 1 % holds with room."""
    ts = jnp.linspace(0.0, 20 * PERIOD, 2001)[1:]
    kinks = jnp.sort(jnp.concatenate([jnp.arange(21) * PERIOD, jnp.arange(20) * PERIOD + EJECTION]))
    q = HalfSine(jnp.asarray(SV), jnp.asarray(PERIOD), jnp.asarray(EJECTION))
    p = respond(Windkessel3(RP, C, RD), q, ts, jump_ts=kinks if with_kinks else None)
    mean = float(jnp.mean(p[ts > 15 * PERIOD]))
    expected = SV / PERIOD * (RP + RD)
    assert mean == pytest.approx(expected, rel=1e-2), (mean / mmHg, expected / mmHg)


def test_the_step_cap_can_be_lifted_and_then_pulses_are_lost():
    """The cap is what keeps them: without it (max_step=None) the same run is far off."""
    ts = jnp.linspace(0.0, 20 * PERIOD, 2001)[1:]
    q = HalfSine(jnp.asarray(SV), jnp.asarray(PERIOD), jnp.asarray(EJECTION))
    p = respond(Windkessel3(RP, C, RD), q, ts, max_step=None)
    mean = float(jnp.mean(p[ts > 15 * PERIOD]))
    assert mean < 0.5 * SV / PERIOD * (RP + RD)
