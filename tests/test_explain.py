"""What dominates a prediction's uncertainty and what to measure next (cardiosoft.explain).

Independent sources: Gaussian conditioning written another way (the information form), and
draws of a known Gaussian, whose closed-form shares and sds the draws' estimates must reach
within their Monte Carlo error.
"""

import numpy as np
import pytest

from cardiosoft.explain import MIN_DRAWS, linear_over_draws, sd_after, variance_shares


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


def _linear_draws(size=20000, seed=5):
    """Gaussian parameters and linear functions of them: the Gaussian answers hold exactly."""
    g, cov = _problem()
    theta = np.random.default_rng(seed).multivariate_normal(np.zeros(5), cov, size=size)
    h = np.array([0.4, -1.0, 0.0, 2.0, 0.5])
    return g, cov, h, theta


# Monte Carlo tolerance of 20000 draws: a squared correlation's sd is at most
# 0.77 / sqrt(20000) = 0.0054, a variance's relative sd sqrt(2 / 20000) = 0.01; 5 sds of each.
SHARE_ATOL, SD_RTOL = 0.03, 0.025


def test_shares_and_sds_over_draws_are_the_gaussian_ones():
    """Over draws of a Gaussian and linear predictions, the shares, sds and sds after a
    measurement are the closed-form ones of the covariance the draws came from."""
    g, cov, h, theta = _linear_draws()
    predictions = {"a": theta @ g[0], "b": theta @ g[1]}
    ok = [np.ones(len(theta), bool)] * 2
    sd, shares, after, fewest = linear_over_draws(
        theta, predictions, ok, {"m": theta @ h}, {}, {"m": 0.7})
    variance, exact_shares = variance_shares(g, cov)
    np.testing.assert_allclose(sd, np.sqrt(variance), rtol=SD_RTOL)
    np.testing.assert_allclose(shares, exact_shares, atol=SHARE_ATOL)
    np.testing.assert_allclose(after["m"], sd_after(g, cov, h, 0.7), rtol=SD_RTOL)
    assert fewest == len(theta)


def test_draws_that_did_not_settle_are_left_out_of_their_prediction_only():
    """A prediction's unsettled draws (here garbage values) are left out of it, and of the
    measurement's gain where the measurement did not settle; other predictions keep them."""
    g, cov, h, theta = _linear_draws()
    a = theta @ g[0]
    broken = np.zeros(len(theta), bool)
    broken[::4] = True
    garbage = np.where(broken, 1e6 * np.random.default_rng(1).standard_normal(len(theta)), a)
    m = np.where(broken[::-1], -garbage, theta @ h)
    sd, shares, after, fewest = linear_over_draws(
        theta, {"a": garbage, "a again": a}, [~broken, np.ones(len(theta), bool)],
        {"m": m}, {"m": ~broken[::-1]}, {"m": 0.7})
    np.testing.assert_allclose(sd, np.sqrt(variance_shares(g[0], cov)[0][0]), rtol=SD_RTOL)
    np.testing.assert_allclose(shares[0], shares[1], atol=SHARE_ATOL)
    np.testing.assert_allclose(after["m"], sd_after(g[0], cov, h, 0.7)[0], rtol=SD_RTOL)
    assert fewest == (~broken).sum()


def test_too_few_settled_draws_is_an_error_naming_the_prediction():
    _, _, _, theta = _linear_draws(size=MIN_DRAWS + 10)
    ok = np.arange(len(theta)) < MIN_DRAWS - 1
    with pytest.raises(ValueError, match=f"SV at 60 mmHg: {MIN_DRAWS - 1} of"):
        linear_over_draws(theta, {"SV at 60 mmHg": theta[:, 0]}, [ok], {}, {}, {})
