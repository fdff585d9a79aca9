"""Importance sampling of a block's posterior with its Laplace approximation as the proposal:
the second method where NUTS costs too much (the mechanics and bench block solves the bench in
every gradient, :mod:`fit.posterior.nuts`).

Draws ``y`` of the Laplace (natural coordinates, truncated to the prior's support) are weighted
by the posterior's density over the proposal's, both over the natural coordinates the posterior
is stated in (:data:`fit.posterior.blocks.POSITIVE`):

    log w = -u(y) + |z|^2 / 2

with ``u`` the block's potential ``1/2 |r|^2`` and ``z`` the draw's whitened offset. The weights
are Pareto-smoothed (PSIS, Vehtari et al. 2024, ArviZ's ``psislw``): its shape ``k-hat`` says
whether they can be trusted (below 0.7) and so whether the Laplace is close to the posterior;
the weighted moments then estimate the posterior's. A draw whose solve fails weighs nothing and
is counted.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

DRAWS = 256
"""Draws of ``--importance``: one bench solve each (about 0.4 s on 2 cores)."""
KHAT_RELIABLE = 0.7
"""PSIS's threshold: above it the importance estimates are not reliable (Vehtari et al. 2024)."""


class ImportanceCheck(NamedTuple):
    """A block's Laplace against its posterior by importance sampling."""

    names: tuple
    laplace_sd: np.ndarray  # natural coordinates
    weighted_sd: np.ndarray
    weighted_shift: np.ndarray  # (weighted mean - Laplace centre) / Laplace sd
    khat: float
    ess: float  # of the smoothed weights, 1 / sum w^2
    draws: int
    failed: int  # draws whose potential is not finite (a failed solve)
    seconds: float

    @property
    def reliable(self) -> bool:
        return self.khat < KHAT_RELIABLE

    def record(self) -> dict:
        return {
            "parameters": {
                n: {
                    "laplace_sd": float(self.laplace_sd[i]),
                    "weighted_sd": float(self.weighted_sd[i]),
                    "sd_ratio": float(self.laplace_sd[i] / self.weighted_sd[i]),
                    "mean_shift_in_laplace_sd": float(self.weighted_shift[i]),
                }
                for i, n in enumerate(self.names)
            },
            "khat": self.khat,
            "ess": self.ess,
            "draws": self.draws,
            "failed": self.failed,
            "seconds": round(self.seconds, 1),
            "reliable": self.reliable,
            "criterion": f"PSIS k-hat < {KHAT_RELIABLE}: the Laplace is close enough to the "
            "posterior for the weights to correct it",
        }


def log_weights(u, u_centre, z) -> np.ndarray:
    """The log importance weights (module docstring), -inf where ``u`` is not finite.

    ``u``: (n,) potentials of the draws, ``u_centre`` the centre's (a constant that keeps the
    numbers small), ``z``: (n, p) the draws' whitened offsets."""
    lw = -(np.asarray(u) - u_centre) + 0.5 * np.sum(np.asarray(z) ** 2, axis=1)
    return np.where(np.isfinite(lw), lw, -np.inf)


def run(potential, centre, chol, positive, names, *, to_raw, admissible=None, n=DRAWS, seed=0,
        progress=print) -> ImportanceCheck:
    """Importance sampling of the density ``exp(-potential)`` over the natural coordinates with
    the Gaussian ``N(centre, chol chol^T)`` there as the proposal.

    ``potential``: a batch of raw draws (m, p) -> (m,) potentials (the block's ``1/2 |r|^2``,
    +inf or NaN where the solve failed); ``to_raw``: natural -> raw coordinates (a batch);
    ``positive``: (p,) bools, coordinates that must be > 0; ``admissible``: natural batch (of
    positive draws) -> bools, the rest of the prior's support (the proposal is truncated to
    both by rejection, as the shipped draws are: :func:`fit.posterior.laplace.draws`)."""
    import arviz as az
    from scipy.linalg import solve_triangular

    from fit.posterior.laplace import Laplace, draws

    centre, chol = np.asarray(centre, float), np.asarray(chol, float)
    y, _ = draws(Laplace(centre, chol, chol @ chol.T, {}), n, seed, admissible, positive)
    z = solve_triangular(chol, (y - centre).T, lower=True).T
    start = time.perf_counter()
    progress(f"  {n} draws of the Laplace, their potential (one batched solve each)")
    # the centre in the same batch: one compiled call, not a second one for a batch of one
    u = np.asarray(potential(to_raw(np.concatenate([centre[None], y]))), float)
    u_centre, u = float(u[0]), u[1:]
    seconds = time.perf_counter() - start
    lw = log_weights(u, u_centre, z)
    failed = int(np.sum(~np.isfinite(lw)))
    smoothed, khat = az.psislw(lw - np.max(lw))
    w = np.exp(smoothed)
    w /= w.sum()
    mean = w @ y
    sd = np.sqrt(w @ (y - mean) ** 2)
    lap_sd = np.sqrt(np.sum(chol**2, axis=1))
    return ImportanceCheck(
        tuple(names), lap_sd, sd, (mean - centre) / lap_sd, float(khat),
        float(1.0 / np.sum(w**2)), n, failed, seconds,
    )
