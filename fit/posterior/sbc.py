"""Simulation-based calibration of the EF block's posterior (Talts et al. 2018).

    python -m fit.posterior --sbc [--replicates 100]

Each replicate draws "true" EF-law parameters from the shipped Laplace approximation of the EF
block, simulates Table I from them (the surrogate's EF_0 at Table I's designs plus Gaussian
noise of the block's stated sd, rounding and discrepancy), refits the block from the shipped
optimum by Levenberg-Marquardt as the fit does (one start), recomputes its Laplace
approximation there in the posterior's own coordinates (:func:`fit.posterior.laplace.
cut_laplace`, positive coefficients truncated at zero) and ranks the truth among
:data:`DRAWS` draws: each parameter, and the EF_0 of Table II's nine held-out designs (the
quantity, noise-free). If the machinery is right, every rank is uniform over the replicates;
a chi-square test over :data:`BINS` bins says how far from it each is, and the 95 % intervals'
coverage is counted with a Wilson interval.

It checks the machinery (the residuals' whitening, the Gauss-Newton covariance, the
coordinates, the sampling) on the block whose model is cheap, not the model itself: the
synthetic data come from the surrogate. The likelihood is the fit's soft-L1 one while the noise
is Gaussian, so small departures in the tails are expected; the mechanics and bench block
(every replicate would refit through diffrax, about a minute each on 2 cores) is not run.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from scipy import stats

from fit.pipeline import zero_pressure_ef
from fit.posterior import blocks, laplace

DRAWS = 99
"""Posterior draws per replicate: ranks 0..99, 100 possible values."""
BINS = 10
REPLICATES = 200
LM_STEPS = 200


class SbcResult(NamedTuple):
    """Ranks (replicates, quantities) of the truth among the draws, the quantities' names,
    each quantity's chi-square p-value of uniform ranks and 95 % interval coverage."""

    names: list
    ranks: np.ndarray
    p_values: np.ndarray
    coverage: np.ndarray
    failed: int

    @property
    def mean_rank(self) -> np.ndarray:
        """The truth's mean rank over the replicates, as a fraction of the draws (0.5 when
        unbiased; above: the posterior sits below the truth)."""
        return self.ranks.mean(axis=0) / (DRAWS + 1)

    @property
    def coverage_50(self) -> np.ndarray:
        """How often the truth falls in the central 50 % (above 0.5: too wide; below: too
        narrow)."""
        return np.mean((self.ranks >= 25) & (self.ranks < 75), axis=0)

    def table(self) -> str:
        from fit.posterior.check import wilson

        n = len(self.ranks)
        lines = [
            f"simulation-based calibration of the EF block: {n} replicates, {DRAWS} draws each "
            f"({self.failed} refits failed and were redrawn)",
            f"  {'quantity':28s} {'p (uniform)':>11s} {'mean rank':>9s} {'50 % cov.':>9s} "
            f"{'95 % cov.':>9s}  Wilson 95 %",
        ]
        for i, name in enumerate(self.names):
            k = round(float(self.coverage[i]) * n)
            lo, hi = wilson(k, n)
            lines.append(
                f"  {name:28s} {self.p_values[i]:11.3f} {self.mean_rank[i]:9.2f} "
                f"{self.coverage_50[i]:9.2f} {self.coverage[i]:9.2f}  {lo:.2f}-{hi:.2f}"
            )
        return "\n".join(lines)


def run(layout: blocks.Layout, d: blocks.Data, s0: blocks.Sigmas, lap_ef, data, *,
        replicates: int = REPLICATES, seed: int = 0, progress=print) -> SbcResult:
    """The SBC of the EF block (module docstring). ``lap_ef``: ``(centre, transform)`` of the
    shipped EF block in natural coordinates; ``data``: the paper's data (Table II's designs)."""
    cols = layout.blocks["ef"]
    centre = np.asarray(layout.centre, float)
    positive = layout.positive[cols]
    sigma = blocks.ef_sigma(s0.ef)
    t2 = data.table2_experiment
    held = (jnp.asarray(t2["omega"], float), jnp.asarray(t2["shortening"], float))
    rng = np.random.default_rng(seed)

    def with_ef(theta_ef):
        return jnp.asarray(centre).at[cols].set(theta_ef)

    def table1(theta_ef):
        return zero_pressure_ef(layout.pump(with_ef(theta_ef)), d.t.t1_omega, d.t.t1_shortening)

    def table2(theta_ef):
        return zero_pressure_ef(layout.pump(with_ef(theta_ef)), *held)

    @jax.jit
    def refit_and_jacobian(synthetic):
        data_k = d._replace(t=d.t._replace(t1_ef=synthetic))
        residual = blocks.ef_residuals(layout, data_k, s0)
        fn = lambda x, _: residual(with_ef(x))  # noqa: E731
        sol = optx.least_squares(fn, optx.LevenbergMarquardt(rtol=1e-9, atol=1e-9),
                                 jnp.asarray(centre[cols]), max_steps=LM_STEPS, throw=False)
        jac = jax.jacfwd(lambda x: fn(x, None))(sol.value)
        return sol.value, jac, sol.result == optx.RESULTS.successful

    table2_draws = jax.jit(jax.vmap(table2))
    names = [*layout.names[cols], *(f"EF_0 Omega {o:g}, C {c:.1f}" for o, c in
                                    zip(t2["omega"], t2["shortening"], strict=True))]
    ranks, failed = [], 0
    lap_centre, lap_transform = lap_ef
    while len(ranks) < replicates:
        z = rng.standard_normal(len(lap_centre))
        truth_natural = lap_centre + lap_transform @ z
        if np.any(truth_natural[positive] <= 0):
            continue  # outside the prior's support: not a draw of the shipped posterior
        truth = layout.raw(truth_natural, cols)
        synthetic = np.asarray(table1(truth)) + sigma * rng.standard_normal(len(d.t.t1_ef))
        fitted, jac, ok = refit_and_jacobian(jnp.asarray(synthetic))
        if not bool(ok):
            failed += 1
            continue
        fitted, jac = np.asarray(fitted), np.asarray(jac)
        slope = layout.natural_slope(fitted, cols)
        lap = laplace.cut_laplace(layout.natural(fitted, cols), [jac / slope],
                                  [slice(0, len(fitted))])
        draws, _ = laplace.draws(lap, DRAWS, int(rng.integers(2**31)), positive=positive)
        draws_raw = layout.raw(draws, cols)
        quantities = np.concatenate([draws, np.asarray(table2_draws(jnp.asarray(draws_raw)))],
                                    axis=1)
        true_q = np.concatenate([truth_natural, np.asarray(table2(truth))])
        ranks.append(np.sum(quantities < true_q, axis=0))
        if len(ranks) % 10 == 0:
            progress(f"  {len(ranks)} of {replicates} replicates")
    ranks = np.array(ranks)
    edges = np.linspace(0, DRAWS + 1, BINS + 1)
    p_values = np.array([
        stats.chisquare(np.histogram(ranks[:, i], bins=edges)[0]).pvalue
        for i in range(ranks.shape[1])
    ])
    lo, hi = 0.025 * (DRAWS + 1), 0.975 * (DRAWS + 1)
    coverage = np.mean((ranks >= lo) & (ranks < hi), axis=0)
    return SbcResult(names, ranks, p_values, coverage, failed)
