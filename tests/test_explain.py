"""What dominates a prediction's uncertainty and what to measure next (cardiosoft.explain).

Independent sources: Gaussian conditioning written another way (the information form), and the
shipped surrogate and bench scene for the parameter map.
"""

import jax.numpy as jnp
import numpy as np
import pytest

from cardiosoft.explain import rebuild, sd_after, variance_shares
from cardiosoft.pump import artifact_dir, load, load_posterior
from cardiosoft.scene import load_scene


def _problem(seed=3, p=5):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(p, p))
    return rng.normal(size=(2, p)), a @ a.T + 0.1 * np.eye(p)


def test_sd_after_is_the_information_form():
    """The rank-one update equals ``sqrt(g^T (Sigma^-1 + h h^T / s^2)^-1 g)``."""
    g, cov = _problem()
    h = np.random.default_rng(4).normal(size=5)
    direct = np.sqrt(np.einsum("kp,pq,kq->k", g, np.linalg.inv(
        np.linalg.inv(cov) + np.outer(h, h) / 0.3**2), g))
    np.testing.assert_allclose(sd_after(g, cov, h, 0.3), direct, rtol=1e-10)


@pytest.mark.parametrize("i", [0, 2, 4])
def test_a_share_is_the_variance_an_exact_measurement_removes(i):
    """Measuring parameter i exactly leaves the variance ``(1 - share_i)`` times what it was."""
    g, cov = _problem()
    variance, shares = variance_shares(g, cov)
    e = np.eye(5)[i]
    np.testing.assert_allclose(sd_after(g, cov, e, 1e-9) ** 2, variance * (1 - shares[:, i]),
                               rtol=1e-6)


def test_rebuild_at_the_centre_is_the_shipped_pump_and_bench():
    """The posterior's raw centre maps back onto the shipped surrogate and the bench scene's
    calibrated numbers (which the scene file rounds to 4-5 digits)."""
    post = load_posterior()
    with np.load(artifact_dir() / post.card["file"]) as f:
        names, centre = [str(n) for n in f["names"]], jnp.asarray(f["centre"])
    pump, values = rebuild(load(), names, centre)
    shipped = load()
    for field in ("ef_linear", "log_stiffness", "fold_compliance", "log_chamber_elastance"):
        np.testing.assert_array_equal(getattr(pump, field), getattr(shipped, field))
    # the quadratic rate comes back from its arguments at two Omegas: a 2x2 solve, to round-off
    np.testing.assert_allclose(pump.ef_quadratic, shipped.ef_quadratic, rtol=1e-12, atol=1e-14)
    scene = load_scene("bench-dynamic")
    for field, value in values.items():
        assert float(value) == pytest.approx(float(getattr(scene, field)), rel=1e-3), field
