"""The free-form chamber of the peak-force study (fit/peak_force.py), checked by other means."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

from cardiosoft.static import quasi_static_stroke
from cardiosoft.units import mm, mmHg
from fit.peak_force import N_KNOTS, FreeFormPump


@pytest.fixture(scope="module")
def pump():
    """A free-form pump with uneven laws in x, beta free."""
    rng = np.random.default_rng(0)
    stroke = 46.0 * mm
    return FreeFormPump(
        stroke,
        108.6e-6,
        ejection_rate=jnp.asarray(rng.normal(0.0, 1.0, N_KNOTS)),
        log_force=jnp.asarray(np.log(60.0) + rng.normal(0.0, 0.3, N_KNOTS)),
        log_elastance=jnp.asarray(np.log(mmHg / 0.5e-6) + rng.normal(0.0, 0.3, N_KNOTS)),
        log_stiffening=jnp.asarray(np.log(1 / 56e-6) + rng.normal(0.0, 0.3, N_KNOTS)),
    )


def test_the_exact_integral_of_a_knot_function_agrees_with_quadrature(pump):
    rate = jnp.asarray(np.random.default_rng(1).normal(0.0, 1.0, N_KNOTS))
    knots = np.asarray(pump.knots)
    for x in (0.0, 0.3 * pump.stroke, knots[7], 0.77 * pump.stroke, pump.stroke):
        expected, _ = quad(lambda s: np.interp(s, knots, rate), 0.0, x, points=knots, limit=200)
        assert float(pump._integral(rate, x)) == pytest.approx(expected, rel=1e-12, abs=1e-18)


def test_laws_start_from_the_unloaded_shell_and_the_force_is_w_prime_at_zero_pressure(pump):
    assert float(pump.ejection_fraction(0.0)) == 0.0
    assert float(pump.zero_pressure_force(0.0)) == 0.0
    ef = jax.vmap(pump.ejection_fraction)(jnp.linspace(0.0, pump.stroke, 301))
    assert np.all(np.diff(np.asarray(ef)) >= 0.0)
    for x in (5 * mm, 20 * mm, 41 * mm):
        rest = pump._chamber(x).rest_volume
        assert float(pump.pressure(rest, x)) == pytest.approx(0.0, abs=1e-9)
        assert float(pump.force(rest, x)) == pytest.approx(
            float(pump.zero_pressure_force(x)), rel=1e-10
        )


def _work_error(pump, n_points):
    """Relative gap between the stroke's work from the energy balance and its force quadrature."""
    out = quasi_static_stroke(pump, 4.0, pump.stroke, 60 * mmHg, 1e9, n_points=n_points)
    x, force = np.asarray(out.x), np.asarray(out.force)
    quadrature = np.sum(0.5 * (force[1:] + force[:-1]) * np.diff(x))
    return abs(float(out.mechanical_work) / quadrature - 1.0)


def test_a_stroke_conserves_energy(pump):
    """With E and beta constant the force is continuous (log E and log beta, piecewise linear,
    would make it jump at the knots), so the trapezoid rule is second order."""
    smooth = eqx.tree_at(
        lambda p: (p.log_elastance, p.log_stiffening),
        pump,
        (jnp.full(N_KNOTS, np.log(mmHg / 0.5e-6)), jnp.full(1, np.log(1 / 56e-6))),
    )
    assert _work_error(smooth, 1151) < 1e-6
