"""Simulation-based calibration of the posterior's blocks (Talts et al. 2018).

    python -m fit.posterior --sbc [--replicates N]                       # the EF block
    python -m fit.posterior --sbc --block mechanics+bench [--replicates N]

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
is Gaussian, so small departures in the tails are expected.

**The mechanics and bench block** (:func:`run_joint`): a refit through diffrax per replicate
would take minutes, so the replicate's posterior is the block's Laplace at a linearised refit
(what ``--joint-sampler laplace`` ships; the shipped draws are SMC's, a run per replicate would
take 25 min): the truth drawn from the Laplace of the block (given the EF law at the
fit's optimum, truncated to the prior's support), new data drawn from the *nonlinear* model at
the truth (every whitened row ``r`` reads ``r(theta) - r(truth) - eps``, ``eps`` standard
normal: the quasi-static and 30-bpm bench rows, the FEM comparisons and the priors'
pseudo-observations; the support row has no noise), one Gauss-Newton step from the optimum with
the optimum's Jacobian (as the leave-one-afterload-out check refits), and the Laplace there.
Where the rows are linear in the raw coordinates over the posterior's width, the truth's ranks
would be uniform whatever the truths are (a Gaussian likelihood and flat priors: the priors are
data here), but for the Laplace's own two liberties: it is Gaussian in the natural coordinates
(a softplus of the raw one for the positive coefficients) and truncated to the prior's support.
A control run with the rows replaced by their linearisation at the optimum (no solves) measures
those two alone; what the model's rows add beyond it is what their curvature costs, which
tempered SMC (:mod:`fit.posterior.smc`) shows from the other side. The held-out quantities are the
predictions the posterior serves (:data:`JOINT_PREDICTIONS`): the bench's SV and peak force at
60 bpm, 60 mmHg, noise-free, solved for the truth and for every draw.
"""

from __future__ import annotations

import functools
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
JOINT_REPLICATES = 200
"""Replicates of :func:`run_joint` (each 1 + :data:`JOINT_DRAWS` bench solves at 60 bpm;
100 took 4.4 min on 2 cores)."""
JOINT_DRAWS = 110
"""Draws solved per replicate of :func:`run_joint`: the first :data:`DRAWS` that solve and
settle rank the truth's prediction (fewer: that rank is not counted, and said)."""
JOINT_PREDICTIONS = (60.0, 60.0)
"""(bpm, mmHg): the held-out bench of :func:`run_joint`, the main job's middle head."""


class SbcResult(NamedTuple):
    """Ranks (replicates, quantities) of the truth among the draws (NaN where a prediction
    could not be ranked: its solve failed), the quantities' names, each quantity's chi-square
    p-value of uniform ranks and 95 % interval coverage over the ranked replicates, the
    replicates redrawn because their refit failed, and the block's name."""

    names: list
    ranks: np.ndarray
    p_values: np.ndarray
    coverage: np.ndarray
    failed: int
    block: str = "the EF block"

    @property
    def ranked(self) -> np.ndarray:
        """Replicates that ranked each quantity."""
        return np.sum(np.isfinite(self.ranks), axis=0)

    @property
    def mean_rank(self) -> np.ndarray:
        """The truth's mean rank over the replicates, as a fraction of the draws (0.5 when
        unbiased; above: the posterior sits below the truth)."""
        return np.nanmean(self.ranks, axis=0) / (DRAWS + 1)

    @property
    def coverage_50(self) -> np.ndarray:
        """How often the truth falls in the central 50 % (above 0.5: too wide; below: too
        narrow)."""
        return _fraction((self.ranks >= 25) & (self.ranks < 75), self.ranks)

    def table(self) -> str:
        from fit.posterior.check import wilson

        n = len(self.ranks)
        lines = [
            f"simulation-based calibration of {self.block}: {n} replicates, {DRAWS} draws each "
            f"({self.failed} refits failed and were redrawn)",
            f"  {'quantity':28s} {'ranked':>6s} {'p (uniform)':>11s} {'mean rank':>9s} "
            f"{'50 % cov.':>9s} {'95 % cov.':>9s}  Wilson 95 %",
        ]
        for i, name in enumerate(self.names):
            m = int(self.ranked[i])
            lo, hi = wilson(round(float(self.coverage[i]) * m), m)
            lines.append(
                f"  {name:28s} {m:6d} {self.p_values[i]:11.3f} {self.mean_rank[i]:9.2f} "
                f"{self.coverage_50[i]:9.2f} {self.coverage[i]:9.2f}  {lo:.2f}-{hi:.2f}"
            )
        return "\n".join(lines)

    def record(self) -> dict:
        """Per quantity: the p-value, mean rank and coverages, for the posterior card."""
        return {n: {"ranked": int(self.ranked[i]), "p_uniform": float(self.p_values[i]),
                    "mean_rank": float(self.mean_rank[i]),
                    "coverage_50": float(self.coverage_50[i]),
                    "coverage_95": float(self.coverage[i])}
                for i, n in enumerate(self.names)}


def _fraction(hit, ranks):
    """Per column, the share of the ranked (finite) replicates where ``hit``."""
    return np.sum(hit & np.isfinite(ranks), axis=0) / np.sum(np.isfinite(ranks), axis=0)


def summarise(names, ranks, failed: int, block: str = "the EF block") -> SbcResult:
    """Chi-square p-values of uniform ranks over :data:`BINS` bins and the 95 % intervals'
    coverage, per quantity, over the replicates that ranked it."""
    ranks = np.asarray(ranks, float)
    edges = np.linspace(0, DRAWS + 1, BINS + 1)
    p_values = np.array([
        stats.chisquare(np.histogram(col[np.isfinite(col)], bins=edges)[0]).pvalue
        for col in ranks.T
    ])
    lo, hi = 0.025 * (DRAWS + 1), 0.975 * (DRAWS + 1)
    return SbcResult(list(names), ranks, p_values, _fraction((ranks >= lo) & (ranks < hi), ranks),
                     failed, block)


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
    return summarise(names, ranks, failed)


def linearised(truth_law: laplace.Laplace, inside, residuals, jacobian, optimum, natural, slope,
               noisy, predictions, *, replicates: int, seed: int = 0, progress=print):
    """The SBC of a block's Laplace at a linearised refit (module docstring), on any model.

    ``truth_law``: where the truths come from (natural coordinates), truncated to ``inside``
    (a batch (n, p) -> (n,) bools); ``residuals``: a batch of natural points (n, p) -> their
    whitened rows (n, m), not finite where the model fails; ``jacobian`` (m, p): the rows'
    Jacobian over the raw coordinates at ``optimum`` (raw, (p,)); ``natural``, ``slope``: raw
    -> natural coordinates and their derivative; ``noisy`` (m,) bools: the rows that hold a
    datum; ``predictions``: a batch of natural points -> (n, q) held-out quantities (not finite
    where they fail), or None. Returns (ranks (replicates, p + q), replicates redrawn)."""
    rng = np.random.default_rng(seed)
    r_star = residuals(natural(optimum)[None])[0]
    gram = jacobian.T @ jacobian
    ranks, failed = [], 0
    while len(ranks) < replicates:
        truth = laplace.draws(truth_law, 1, int(rng.integers(2**31)), admissible=inside)[0][0]
        r_truth = residuals(truth[None])[0]
        if not np.all(np.isfinite(r_truth)):
            failed += 1  # the truth's own model does not solve: no data to draw
            continue
        r_new = r_star - r_truth - noisy * rng.standard_normal(len(r_star))
        refit = optimum - np.linalg.solve(gram, jacobian.T @ r_new)  # one Gauss-Newton step
        j_natural = jacobian / slope(refit)
        _, chol = laplace._cholesky_inverse(j_natural.T @ j_natural)
        lap = laplace.Laplace(natural(refit), chol, None, {})
        try:
            draws, _ = laplace.draws(lap, JOINT_DRAWS, int(rng.integers(2**31)),
                                     admissible=inside)
        except RuntimeError:
            failed += 1  # the refit's Laplace lies outside the support
            continue
        rank = np.sum(draws[:DRAWS] < truth, axis=0).astype(float)
        if predictions is not None:
            solved = predictions(np.vstack([truth, draws]))
            truth_q, draw_q = solved[0], solved[1:]
            settled = draw_q[np.all(np.isfinite(draw_q), axis=1)][:DRAWS]
            rank_q = np.sum(settled < truth_q, axis=0).astype(float)
            rank_q[(len(settled) < DRAWS) | ~np.isfinite(truth_q)] = np.nan
            rank = np.concatenate([rank, rank_q])
        ranks.append(rank)
        if len(ranks) % 10 == 0:
            progress(f"  {len(ranks)} of {replicates} replicates")
    return np.array(ranks), failed


def run_joint(fit, *, replicates: int = JOINT_REPLICATES, seed: int = 0,
              progress=print) -> tuple[SbcResult, SbcResult]:
    """The SBC of the mechanics and bench block's Laplace (module docstring): its parameters
    (natural coordinates) and :data:`JOINT_PREDICTIONS`' SV and peak force; and its control,
    the same with the block's rows replaced by their linearisation at the optimum (what the
    Laplace assumes, in the raw coordinates its Gauss-Newton step takes): what is left off
    there comes from the support and the positive coefficients' coordinates, the rest of the
    departure from the model's curvature. ``fit``:
    :func:`fit.posterior.artifact.linearised_fit`."""
    from cardiosoft.units import mmHg
    from fit.posterior import artifact, smc

    layout, d, s0 = fit.layout, fit.d, fit.sizing.s0
    own = laplace._spans(layout)[1]
    centre = np.asarray(layout.centre, float)
    shipped = laplace.laplace(layout, d, fit.lin, s0, centre)
    truth_law = laplace.Laplace(shipped.centre[own],
                                np.linalg.cholesky(shipped.conditional[laplace.JOINT]), None, {})
    _, inside = artifact.joint_target(layout, d, s0, fit.scene)
    rows = smc.threaded(jax.jit(
        blocks.joint_residuals(layout, d, s0, fit.scene, steady="shooting")))
    bpm, head = JOINT_PREDICTIONS
    outputs = blocks.bench_outputs(layout, fit.scene.replace(bpm=bpm), jnp.array([head * mmHg]),
                                   steady="shooting")

    def prediction(theta):
        o = outputs(theta)
        return jnp.stack([o.dynamic_sv[0], o.peak_force[0]])

    solve = smc.threaded(jax.jit(prediction))

    full = functools.partial(artifact.joint_raw, layout)

    r_star, jac = laplace.joint_rows(layout, d, fit.lin, s0)
    jac = jac[:, own]
    noisy = np.ones(len(jac), bool)
    noisy[2 * len(d.t.afterload)] = False  # mechanics_fixed_rows' first: the support, no datum
    common = (centre[own], lambda x: layout.natural(x, own),
              lambda x: layout.natural_slope(x, own), noisy)
    progress(f"  the model's rows: {replicates} replicates, each {JOINT_DRAWS + 1} bench "
             f"solves at {bpm:g} bpm")
    ranks, failed = linearised(truth_law, inside, lambda y: rows(full(y)), jac, *common,
                               lambda y: solve(full(y)), replicates=replicates, seed=seed,
                               progress=progress)
    names = [*layout.names[own], f"SV at {bpm:g} bpm, {head:g} mmHg",
             f"peak force at {bpm:g} bpm, {head:g} mmHg"]
    progress("  the control: the rows linearised at the optimum, no solves")
    ranks_c, failed_c = linearised(
        truth_law, inside, lambda y: r_star + (layout.raw(y, own) - centre[own]) @ jac.T, jac,
        *common, None, replicates=replicates, seed=seed, progress=progress)
    return (summarise(names, ranks, failed, "the mechanics+bench block's Laplace"),
            summarise(names[: len(jac.T)], ranks_c, failed_c,
                      "the same Laplace, the rows linearised (control)"))
