"""NUTS on the EF block of the posterior: the shipped EF draws, and the check of its Laplace
approximation.

NumPyro's NUTS on the block's potential (:func:`potential`: ``1/2 |r(theta)|^2`` from its
whitened residuals, :mod:`fit.posterior.blocks`, with the change of variables from the natural
coordinates the posterior is stated in), differentiated in forward mode
(``forward_mode_differentiation``: the surrogate's root finds and the beat loop are
``while_loop`` s, and the blocks have 7-14 parameters), with a dense mass matrix that starts as
the Gauss-Newton covariance and is adapted in the warmup; the chains start at dispersed Laplace
draws and run one after the other (two cores: a vmapped pair would run at the slower one's
pace). A residual that is not finite (a failed root find, a draw outside the prior's
support) makes the potential +inf, never NaN. Diagnostics are ArviZ's rank-normalised split
R-hat and bulk and tail ESS (Vehtari et al. 2021) and NumPyro's divergences. The mechanics
and bench block solves the bench in every gradient; :mod:`fit.posterior.importance` checks its
Laplace instead.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

CHAINS = 4
WARMUP = 1000
SAMPLES = 2000
"""With 1000 warmup steps: R-hat <= 1.002, bulk ESS >= 1500 and no divergences on the EF block in
about 70 s (1000 samples left R-hat 1.012 on its linear rate)."""
START_SPREAD = 1.5
"""The chains start at Laplace draws with their sd scaled by this: dispersed, so that R-hat can
tell chains that have not mixed."""
TARGET_ACCEPT = 0.9
"""NumPyro's default 0.8 left divergences on the EF block (11 in 3200); 0.9 none."""
RHAT_MAX, ESS_MIN = 1.01, 400
SD_RATIO_TOL = 0.2
"""Laplace's marginal sds must be within 20 % of NUTS's (issue #24)."""


class NutsCheck(NamedTuple):
    """A block's NUTS run against its Laplace approximation."""

    names: tuple
    laplace_sd: np.ndarray
    nuts_sd: np.ndarray
    nuts_mean_shift: np.ndarray  # (NUTS mean - Laplace centre) / Laplace sd
    rhat: np.ndarray
    ess_bulk: np.ndarray
    ess_tail: np.ndarray
    divergences: int
    seconds: float
    gradient_seconds: float  # one gradient of the potential, compiled
    draws: np.ndarray  # (chains, samples, p), raw coordinates

    @property
    def mixed(self) -> bool:
        """The chains can be trusted: R-hat, bulk ESS and no divergences."""
        return bool(
            np.all(self.rhat < RHAT_MAX) and np.all(self.ess_bulk > ESS_MIN)
            and self.divergences == 0
        )

    @property
    def passed(self) -> bool:
        """Mixed, and the Laplace's marginal sds within :data:`SD_RATIO_TOL` of NUTS's."""
        ratio = self.laplace_sd / self.nuts_sd
        return self.mixed and bool(np.all(np.abs(ratio - 1) <= SD_RATIO_TOL))

    def record(self) -> dict:
        return {
            "parameters": {
                n: {
                    "laplace_sd": float(self.laplace_sd[i]),
                    "nuts_sd": float(self.nuts_sd[i]),
                    "sd_ratio": float(self.laplace_sd[i] / self.nuts_sd[i]),
                    "mean_shift_in_laplace_sd": float(self.nuts_mean_shift[i]),
                    "rhat": float(self.rhat[i]),
                    "ess_bulk": float(self.ess_bulk[i]),
                    "ess_tail": float(self.ess_tail[i]),
                }
                for i, n in enumerate(self.names)
            },
            "divergences": self.divergences,
            "seconds": round(self.seconds, 1),
            "gradient_seconds": self.gradient_seconds,
            "mixed": self.mixed,
            "passed": self.passed,
            "criteria": f"R-hat < {RHAT_MAX}, bulk ESS > {ESS_MIN}, no divergences, Laplace "
            f"sd within {SD_RATIO_TOL:.0%} of NUTS's",
        }


def potential(residual, positive=None):
    """The negative log posterior over the raw coordinates x that NUTS moves in: ``1/2 |r|^2``
    (the density over the natural coordinates, :data:`fit.posterior.blocks.POSITIVE`) minus
    the log of the change of variables, ``log sigmoid(x_i)`` for each ``positive`` x_i (the
    softplus-inverse of its coefficient); +inf where r is not finite."""
    positive = jnp.zeros((), bool) if positive is None else jnp.asarray(positive)

    def u(x):
        r = residual(x)
        value = 0.5 * jnp.sum(r**2) - jnp.sum(jnp.where(positive, jax.nn.log_sigmoid(x), 0.0))
        return jnp.where(jnp.all(jnp.isfinite(r)), value, jnp.inf)

    return u


def gradient_cost(u, x0) -> float:
    """Seconds of one compiled forward-mode gradient of ``u`` at ``x0`` (best of three)."""
    grad = jax.jit(jax.jacfwd(u))
    jax.block_until_ready(grad(x0))
    best = np.inf
    for _ in range(3):
        start = time.perf_counter()
        jax.block_until_ready(grad(x0))
        best = min(best, time.perf_counter() - start)
    return float(best)


def run(
    residual, centre, covariance, names, *, positive=None, chains=CHAINS, warmup=WARMUP,
    samples=SAMPLES, seed=0, target_accept=TARGET_ACCEPT, progress=print, compare=None,
) -> NutsCheck:
    """NUTS on the :func:`potential` of ``residual`` (a function of the block's raw
    parameters, ``positive`` marking the softplus-inverses), started near ``centre`` with
    ``covariance`` (the Laplace approximation, linearised in raw coordinates) as its metric.

    ``compare``: ``(to, centre, sd)``: compare the marginals in other coordinates, ``to`` mapping
    a batch of draws there, ``centre`` and ``sd`` the Laplace's in them (default: these)."""
    import arviz as az
    from numpyro.infer import MCMC, NUTS

    centre = jnp.asarray(centre)
    covariance = np.asarray(covariance)
    u = potential(residual, positive)
    seconds_per_gradient = gradient_cost(u, centre)
    progress(f"  one gradient: {seconds_per_gradient * 1e3:.1f} ms (compiled, forward mode)")
    kernel = NUTS(
        potential_fn=u,
        inverse_mass_matrix=jnp.asarray(covariance),
        dense_mass=True,
        forward_mode_differentiation=True,
        target_accept_prob=target_accept,
    )
    mcmc = MCMC(
        kernel, num_warmup=warmup, num_samples=samples, num_chains=chains,
        chain_method="sequential", progress_bar=False,
    )
    chol = np.linalg.cholesky(covariance)
    z = np.random.default_rng(seed).standard_normal((chains, len(centre)))
    init = np.asarray(centre) + START_SPREAD * z @ chol.T
    start = time.perf_counter()
    # NumPyro takes one chain's start unbatched
    start_at = jnp.asarray(init[0] if chains == 1 else init)
    mcmc.run(jax.random.PRNGKey(seed), init_params=start_at, extra_fields=("diverging",))
    draws = np.asarray(jax.block_until_ready(mcmc.get_samples(group_by_chain=True)))
    seconds = time.perf_counter() - start
    diverging = int(np.sum(np.asarray(mcmc.get_extra_fields()["diverging"])))
    ds = az.convert_to_dataset({"theta": draws})
    rhat = np.asarray(az.rhat(ds, method="rank")["theta"])
    bulk = np.asarray(az.ess(ds, method="bulk")["theta"])
    tail = np.asarray(az.ess(ds, method="tail")["theta"])
    to, centre_c, lap_sd = compare or (
        (lambda a: a), np.asarray(centre), np.sqrt(np.diag(covariance))
    )
    flat = to(draws.reshape(-1, draws.shape[-1]))
    return NutsCheck(
        tuple(names),
        np.asarray(lap_sd),
        flat.std(axis=0, ddof=1),
        (flat.mean(axis=0) - np.asarray(centre_c)) / lap_sd,
        rhat,
        bulk,
        tail,
        diverging,
        seconds,
        seconds_per_gradient,
        draws,
    )
