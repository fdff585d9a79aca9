"""Sequential Monte Carlo of a block's posterior, tempered from its Laplace approximation: the
check of the mechanics and bench block, where NUTS's trees cost too much (step sizes of
0.01-0.04 in the Laplace's metric, up to 1023 gradients a step; :mod:`fit.posterior.nuts`) and
importance sampling in one step cannot be trusted (PSIS k-hat above 1,
:mod:`fit.posterior.importance`).

Adaptive tempering (Jasra et al. 2011; Chopin & Papaspiliopoulos 2020, ch. 17) over the natural
coordinates ``y`` the posterior is stated in. The particles start as draws of a Gaussian reference
``q`` (the Laplace, or a pilot run's: below) truncated to the prior's support, and pass through

    log pi_b(y) = -|z|^2 / 2 + b (-u(y) + |z|^2 / 2),      0 = b_0 < b_1 < ... < b_T = 1,

``z`` the whitened offset from the reference's centre and ``u`` the block's potential
``1/2 |r|^2``, so ``pi_0 = q`` and ``pi_1`` the posterior. Each step:

1. the next ``b`` is the largest that keeps the incremental weights' ESS at
   :data:`ESS_FRACTION` of the particles (bisection);
2. the particles are resampled by those weights (systematic);
3. they move under ``pi_b`` by Metropolis-Hastings steps, each an independent proposal from
   the Gaussian of the particles' own mean and covariance (PyMC's SMC kernel: a fresh draw
   when accepted) and then a random-walk one with that covariance scaled by ``2.38^2 / d``
   (Gelman et al. 1996), until the particles' correlation with their positions before the
   moves falls below :data:`CORRELATION_MAX` in every coordinate, at most :data:`MAX_MOVES`.

Why not gradient moves: MALA with the particles' covariance as its metric (the gradient by
forward mode: reverse mode fails inside the shooting's orbit solve) settled at a step of 0.3
and, from 128 of the block's posterior draws at ``b = 1``, left their correlation with where
they started at 0.67 after 25 rounds; these moves left it at 0.23 in the same 125 s (measured
2026-12-03).

A proposal outside the support or whose solve fails is rejected (``u`` is +inf there). The
potential is evaluated one particle at a time over a thread pool: a ``vmap``-ed batch of bench
solves runs at its slowest member's pace (the Newton shooting and its fallback are
``while_loop`` s), five times slower a particle than one at a time on two threads (measured
2026-12-03: 103 against 20 ms).

**A pilot's reference.** On the mechanics+bench block the posterior's mass lies along the
chamber's elastance-fold compliance ridge, its mean 3 Laplace sds from the mode in log E_u and
its sds there 2.7x the Laplace's; the moves carry a population along that ridge only slowly
(from the Laplace's draws at ``b = 1``, 40 rounds moved the mean of log E_u from 19.35 to 19.65
of about 19.9; differential-evolution moves (ter Braak 2006) and independent proposals from a
Student t did no better; measured 2026-12-04). So the runs that are compared start from a
reference fitted to a pilot run (from the Laplace): the Gaussian of the pilot's particles'
mean and covariance, its sds widened by :data:`REFERENCE_WIDENING`. Tempering from any
reference that covers the posterior reaches the same target (the weights correct for it), and
from one that lies where the posterior's mass is, the moves have only its shape to settle.
Measured 2026-12-04 (``python -m fit.posterior --smc``): four runs from the Laplace disagreed
(R-hat up to 1.016); four from a pilot's reference agree (R-hat at most 1.0098, 4 stages each
against the pilot's 6), and their log E_u sd (0.45) is where 60 extra rounds at ``b = 1`` had
left the widest run from the Laplace (0.41-0.45). Runs that share one pilot cannot show, by
R-hat, a bias the pilot gives all of them: ``python -m fit.posterior --smc-pilot`` makes a
pilot and a run from other seeds and compares. Measured 2026-12-04: 9 of 14 means within 2
Monte Carlo sds of the shipped runs', but the fold compliance's 4.0 MC sds apart (2.5 against
3.15 Laplace sds from the centre) and its sd 0.83 of theirs: along the ridge the pilot matters.

Several independent runs (seeded apart) are compared as chains are: ArviZ's rank-normalised
R-hat and bulk ESS over the runs' particles (as PyMC reports for its SMC), against the NUTS
criteria of :mod:`fit.posterior.nuts`.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

from fit.posterior.nuts import ESS_MIN, RHAT_MAX, SD_RATIO_TOL

PARTICLES = 256
RUNS = 4
ESS_FRACTION = 0.5
"""The incremental weights keep this share of the particles as their ESS (PyMC's threshold)."""
CORRELATION_MAX = 0.1
"""Moves stop when every coordinate's |correlation| across the particles with its values before
the moves is below this: the slowest coordinate decides. On the mechanics+bench block neither
this nor the mean over coordinates (with 12 moves at most) made four runs agree to R-hat 1.01
(1.016 and 1.018, on the chamber's elastance-fold compliance ridge; measured 2026-12-03).

With 256 particles and 14 coordinates, sampling noise alone keeps the largest |correlation| of
independent particles above 0.1 in 80 % of cases (its 95 % level is 0.18), so late stages run to
:data:`MAX_MOVES`. Stopping at that noise level instead halved the cost (68480 solves, 25 min)
but left the ridge narrower (log E_u sd 0.29 against 0.37) and the runs further apart (R-hat
1.027): a particle's correlation with its start does not show how far the population has spread
along the ridge, and the extra moves this rule forces are what spread it. Nor do 25 suffice:
80 more rounds at ``b = 1`` from 128 of the narrowest run's particles kept widening it (log E_u
sd 0.32 to 0.39, fold compliance 0.21 to 0.28, mean +0.14) and had not settled; 60 from the
widest run's kept it at 0.41-0.45 (measured 2026-12-03)."""
MAX_MOVES = 25
"""Most move rounds a stage (each two proposals a particle: one independent, one random-walk;
PyMC's SMC allows 25)."""
MAX_STAGES = 60
REFERENCE_WIDENING = 1.3
"""The compared runs' reference: the pilot's Gaussian with its sds times this, so that it covers
the posterior's tails that 256 particles leave thin (tempering from the posterior's own
Gaussian widened 1.3x took 5-7 stages on the mechanics+bench block; widened 2x, 23)."""
LAPLACE_DRAWS = 4096
"""Draws of the Laplace, truncated to the support, whose sds the SMC's are compared with
(Monte Carlo error about 1 %)."""
WORKERS = 2
"""Threads that evaluate the potential (CI's two cores: a jitted solve releases the GIL)."""


def threaded(fn, workers: int = WORKERS):
    """``fn`` of one vector -> a function of a batch (n, p) -> (n, ...), the vectors evaluated
    one at a time over ``workers`` threads."""

    def batch(points):
        with ThreadPoolExecutor(workers) as pool:
            return np.array([np.asarray(v, float) for v in pool.map(fn, points)])

    return batch


def effective_size(log_w) -> float:
    """The ESS ``1 / sum w^2`` of normalised weights ``exp(log_w)``."""
    w = np.exp(log_w - np.max(log_w))
    w /= w.sum()
    return float(1.0 / np.sum(w**2))


def next_temperature(gain, beta: float, fraction: float = ESS_FRACTION) -> float:
    """The largest ``b' <= 1`` whose incremental weights ``exp((b' - beta) gain)`` keep an ESS
    of ``fraction`` of the particles (bisection; ``gain`` is -inf where the density is zero)."""
    n = len(gain)
    if effective_size((1.0 - beta) * gain) >= fraction * n:
        return 1.0
    low, high = 0.0, 1.0 - beta
    for _ in range(60):
        mid = 0.5 * (low + high)
        if effective_size(mid * gain) >= fraction * n:
            low = mid
        else:
            high = mid
    return beta + max(low, 1e-12)


def systematic_resample(log_w, rng) -> np.ndarray:
    """Indices of a systematic resample by the weights ``exp(log_w)``."""
    w = np.exp(log_w - np.max(log_w))
    cumulative = np.cumsum(w / w.sum())
    cumulative[-1] = 1.0
    n = len(w)
    return np.searchsorted(cumulative, (rng.random() + np.arange(n)) / n)


class Stage(NamedTuple):
    beta: float
    ess_before_resample: float
    moves: int
    accept_independent: float
    accept_random_walk: float
    correlation: float
    unique: int  # distinct particles after the moves


class SmcRun(NamedTuple):
    draws: np.ndarray  # (n, p), natural coordinates, equally weighted
    stages: tuple
    evaluations: int  # bench solves
    seconds: float

    def record(self) -> dict:
        return {"stages": [s._asdict() for s in self.stages], "evaluations": self.evaluations,
                "seconds": round(self.seconds, 1)}


class SmcCheck(NamedTuple):
    """A block's Laplace against its posterior by independent SMC runs."""

    names: tuple
    laplace_sd: np.ndarray  # of its draws, truncated to the support as shipped
    smc_sd: np.ndarray
    smc_mean_shift: np.ndarray  # (SMC mean - Laplace centre) / Laplace sd
    rhat: np.ndarray  # over the runs
    ess_bulk: np.ndarray
    runs: tuple  # of SmcRun
    pilot: SmcRun | None  # whose Gaussian, widened, is the runs' reference; None: the Laplace

    @property
    def mixed(self) -> bool:
        """The runs agree (NUTS's criteria, :mod:`fit.posterior.nuts`)."""
        return bool(np.all(self.rhat < RHAT_MAX) and np.all(self.ess_bulk > ESS_MIN))

    @property
    def passed(self) -> bool:
        """The runs agree, and the Laplace's marginal sds are within
        :data:`fit.posterior.nuts.SD_RATIO_TOL` of theirs."""
        ratio = self.laplace_sd / self.smc_sd
        return self.mixed and bool(np.all(np.abs(ratio - 1) <= SD_RATIO_TOL))

    @property
    def draws(self) -> np.ndarray:
        """(runs * particles, p) natural coordinates."""
        return np.concatenate([r.draws for r in self.runs])

    def record(self) -> dict:
        return {
            "parameters": {
                n: {
                    "laplace_sd": float(self.laplace_sd[i]),
                    "smc_sd": float(self.smc_sd[i]),
                    "sd_ratio": float(self.laplace_sd[i] / self.smc_sd[i]),
                    "mean_shift_in_laplace_sd": float(self.smc_mean_shift[i]),
                    "rhat": float(self.rhat[i]),
                    "ess_bulk": float(self.ess_bulk[i]),
                }
                for i, n in enumerate(self.names)
            },
            "runs": [r.record() for r in self.runs],
            "reference": "the Laplace" if self.pilot is None else
            f"a pilot run's Gaussian, sds x {REFERENCE_WIDENING}",
            "pilot": None if self.pilot is None else self.pilot.record(),
            "mixed": self.mixed,
            "passed": self.passed,
            "criteria": f"over the runs R-hat < {RHAT_MAX}, bulk ESS > {ESS_MIN}; Laplace sd "
            f"within {SD_RATIO_TOL:.0%} of SMC's",
        }


def check(potential, centre, chol, inside, names, *, runs: int = RUNS,
          particles: int = PARTICLES, seed: int = 0, pilot: bool = True,
          progress=print) -> SmcCheck:
    """``runs`` independent :func:`run` s (seeds ``seed + 1``, ``seed + 2``, ...), compared with
    each other (R-hat, bulk ESS over the runs' particles) and with the Laplace ``N(centre, chol
    chol^T)`` (its draws truncated to the support, as shipped). With ``pilot``, a first run
    from the Laplace (seed ``seed``) whose Gaussian, widened by :data:`REFERENCE_WIDENING`, is
    the compared runs' reference (module docstring); without, they start from the Laplace."""
    import arviz as az

    from fit.posterior.laplace import Laplace, draws

    first = None
    ref_centre, ref_chol = np.asarray(centre, float), np.asarray(chol, float)
    if pilot:
        progress(f" pilot run from the Laplace, {particles} particles:")
        first = run(potential, centre, chol, inside, particles=particles, seed=seed,
                    progress=progress)
        ref_centre, ref_chol = reference(first)
    done = []
    for k in range(runs):
        progress(f" run {k + 1} of {runs}, {particles} particles:")
        done.append(run(potential, ref_centre, ref_chol, inside, particles=particles,
                        seed=seed + 1 + k, progress=progress))
    stacked = np.stack([r.draws for r in done])
    ds = az.convert_to_dataset({"theta": stacked})
    rhat = np.asarray(az.rhat(ds, method="rank")["theta"])
    bulk = np.asarray(az.ess(ds, method="bulk")["theta"])
    lap, _ = draws(Laplace(np.asarray(centre), np.asarray(chol), None, {}), LAPLACE_DRAWS,
                   seed, inside)
    lap_sd = lap.std(axis=0, ddof=1)
    flat = stacked.reshape(-1, stacked.shape[-1])
    return SmcCheck(tuple(names), lap_sd, flat.std(axis=0, ddof=1),
                    (flat.mean(axis=0) - np.asarray(centre)) / lap_sd, rhat, bulk, tuple(done),
                    first)


def piloted(potential, centre, chol, inside, *, particles: int = PARTICLES, seeds=(0, 1),
            progress=print) -> tuple[SmcRun, SmcRun]:
    """(pilot, run): a pilot :func:`run` from the Laplace ``N(centre, chol chol^T)`` (seed
    ``seeds[0]``), then a run from its :func:`reference` (seed ``seeds[1]``), as the shipped
    draws are made."""
    pilot = run(potential, centre, chol, inside, particles=particles, seed=seeds[0],
                progress=progress)
    return pilot, run(potential, *reference(pilot), inside, particles=particles, seed=seeds[1],
                      progress=progress)


def reference(pilot: SmcRun) -> tuple[np.ndarray, np.ndarray]:
    """The reference a pilot run gives the runs after it: (centre, Cholesky factor) of its
    particles' mean and covariance, the sds widened by :data:`REFERENCE_WIDENING`."""
    return (pilot.draws.mean(axis=0),
            REFERENCE_WIDENING * np.linalg.cholesky(np.cov(pilot.draws, rowvar=False)))


def run(potential, centre, chol, inside, *, particles: int = PARTICLES, seed: int = 0,
        progress=print) -> SmcRun:
    """One adaptive-tempering run (module docstring) of the density ``exp(-u)`` over the
    natural coordinates.

    ``potential``: a batch of natural points (n, p) -> (n,) potentials, +inf where the solve
    fails; ``centre``, ``chol``: the reference ``N(centre, chol chol^T)`` (the Laplace, or a
    pilot's Gaussian: :func:`check`); ``inside``: a batch
    (n, p) -> (n,) bools, the prior's support (positivity and convexity)."""
    from scipy.linalg import solve_triangular

    from fit.posterior.laplace import Laplace, draws

    start = time.perf_counter()
    rng = np.random.default_rng(seed)
    centre, chol = np.asarray(centre, float), np.asarray(chol, float)
    d = len(centre)

    def half_z2(y):
        z = solve_triangular(chol, (y - centre).T, lower=True).T
        return 0.5 * np.sum(z**2, axis=1)

    def potential_or_inf(points):
        u = np.asarray(potential(points), float)
        return np.where(np.isfinite(u), u, np.inf)

    y, _ = draws(Laplace(centre, chol, None, {}), particles, seed, inside)
    u = potential_or_inf(y)
    evaluations = particles
    # the reference's log density (up to a constant) and the log of posterior over reference
    ref = -half_z2(y)
    gain = -u - ref
    beta, stages = 0.0, []
    for _ in range(MAX_STAGES):
        if beta >= 1.0:
            break
        new_beta = next_temperature(gain, beta)
        log_inc = (new_beta - beta) * gain
        ess = effective_size(log_inc)
        beta = new_beta
        keep = systematic_resample(log_inc, rng)
        y, u, ref, gain = y[keep], u[keep], ref[keep], gain[keep]
        before = y.copy()
        accepted = np.zeros(2)
        moves, correlation = 0, 1.0
        while moves < MAX_MOVES and correlation >= CORRELATION_MAX:
            moves += 1
            mean, cov = y.mean(axis=0), np.cov(y, rowvar=False)
            factor = np.linalg.cholesky(cov + 1e-12 * np.diag(np.diag(cov)))
            for k, proposal in enumerate(("independent", "random_walk")):
                if proposal == "independent":
                    step = rng.standard_normal((particles, d)) @ factor.T
                    new = mean + step
                    # log g(y) - log g(y') of the independent proposal g = N(mean, cov)
                    w_old = solve_triangular(factor, (y - mean).T, lower=True).T
                    w_new = solve_triangular(factor, step.T, lower=True).T
                    correction = 0.5 * (np.sum(w_new**2, 1) - np.sum(w_old**2, 1))
                else:
                    new = y + (2.38 / np.sqrt(d)) * rng.standard_normal((particles, d)) @ factor.T
                    correction = np.zeros(particles)
                ok = np.asarray(inside(new), bool)
                u_new = np.full(particles, np.inf)
                if ok.any():
                    u_new[ok] = potential_or_inf(new[ok])
                    evaluations += int(ok.sum())
                ref_new = -half_z2(new)
                target_old = ref + beta * gain
                gain_new = -u_new - ref_new
                target_new = np.where(np.isfinite(u_new), ref_new + beta * gain_new, -np.inf)
                log_a = target_new - target_old + correction
                take = np.log(rng.random(particles)) < log_a
                y[take], u[take], ref[take], gain[take] = (
                    new[take], u_new[take], ref_new[take], gain_new[take])
                accepted[k] += take.mean()
            correlation = _largest_abs_correlation(before, y)
        stage = Stage(beta, ess, moves, *(accepted / moves), correlation,
                      len(np.unique(y, axis=0)))
        stages.append(stage)
        progress(f"  stage {len(stages):2d}: beta {beta:.4f}, {moves} moves, accepted "
                 f"{stage.accept_independent:.2f}/{stage.accept_random_walk:.2f} "
                 f"(independent/random walk), correlation {correlation:.2f}, "
                 f"{stage.unique} distinct, {time.perf_counter() - start:.0f} s")
    else:
        raise RuntimeError(f"tempering did not reach the posterior in {MAX_STAGES} stages "
                           f"(beta {beta:.3g})")
    return SmcRun(y, tuple(stages), evaluations, time.perf_counter() - start)


def _largest_abs_correlation(before, after) -> float:
    """The largest over coordinates of |corr(before_i, after_i)| across the particles."""
    b = before - before.mean(axis=0)
    a = after - after.mean(axis=0)
    denom = np.sqrt(np.sum(b**2, 0) * np.sum(a**2, 0))
    return float(np.max(np.abs(np.sum(a * b, 0) / np.where(denom > 0, denom, np.inf))))
