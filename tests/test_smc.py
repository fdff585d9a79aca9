"""Tempered SMC (fit.posterior.smc), the check of the mechanics and bench block's Laplace
(issue #24), on targets whose moments are known in closed form: a Gaussian truncated at zero
(scipy's truncnorm), reached from a reference that is too wide and centred elsewhere, directly
and after a pilot run."""

import math

import numpy as np
import pytest
from scipy.stats import truncnorm

from fit.posterior import smc

MEAN, SD = np.array([0.3, -1.0]), np.array([0.5, 0.25])
"""The target: independent Gaussians, the first truncated to y > 0 (the prior's support)."""


def _target_potential(y):
    return 0.5 * np.sum(((y - MEAN) / SD) ** 2, axis=1)


def _inside(y):
    return y[:, 0] > 0


def _exact():
    a = (0.0 - MEAN[0]) / SD[0]
    first = truncnorm(a, np.inf, loc=MEAN[0], scale=SD[0])
    return np.array([first.mean(), MEAN[1]]), np.array([first.std(), SD[1]])


def test_next_temperature_keeps_the_ess_fraction():
    """The next temperature leaves the incremental weights an ESS of half the particles (to
    the bisection's resolution), and jumps to 1 where the whole step keeps more."""
    gain = np.random.default_rng(0).normal(0.0, 3.0, 500)
    beta = smc.next_temperature(gain, 0.2)
    assert 0.2 < beta < 1.0
    assert smc.effective_size((beta - 0.2) * gain) == pytest.approx(250, rel=1e-6)
    assert smc.next_temperature(1e-3 * gain, 0.2) == 1.0


def test_systematic_resample_keeps_each_particle_its_share():
    """Each index appears floor or ceil of n times its weight (systematic resampling)."""
    rng = np.random.default_rng(1)
    w = rng.exponential(size=40)
    w /= w.sum()
    counts = np.bincount(smc.systematic_resample(np.log(w), rng), minlength=40)
    assert np.all(np.abs(counts - 40 * w) < 1)


def test_smc_reaches_a_truncated_gaussian_from_a_wide_laplace():
    """From N(0, 1.5^2 I) truncated to the support (k-hat territory for importance sampling:
    the target's second sd is 6x narrower and 4 of its sds off centre), the runs' means and sds
    match the closed form within 4 Monte Carlo standard errors of the runs' bulk ESS (sd /
    sqrt(ESS) for a mean, sd / sqrt(2 ESS) for an sd), and the runs agree (R-hat < 1.01).
    Proposals outside the support are rejected, never solved."""
    calls = []

    def potential(y):
        assert np.all(_inside(y)), "a point outside the support was evaluated"
        calls.append(len(y))
        return _target_potential(y)

    result = smc.check(potential, np.zeros(2), 1.5 * np.eye(2), _inside, ("a", "b"), runs=4,
                       particles=400, seed=2, progress=lambda m: None)
    mean, sd = _exact()
    draws = result.draws
    ess = result.ess_bulk
    assert result.mixed, result.record()
    assert np.all(np.abs(draws.mean(axis=0) - mean) <= 4 * sd / np.sqrt(ess))
    assert np.all(np.abs(draws.std(axis=0, ddof=1) - sd) <= 4 * sd / np.sqrt(2 * ess))
    assert sum(r.evaluations for r in (result.pilot, *result.runs)) == sum(calls)
    assert all(r.stages[-1].beta == 1.0 for r in result.runs)


def test_runs_after_a_pilot_start_where_the_posterior_is():
    """The compared runs start from the pilot's Gaussian (widened 1.3x), not from the wide,
    misplaced Laplace: the pilot needs several stages of tempering (3 with this seed), each run
    after it 1 (the weights from a reference that covers the target keep half their ESS in one
    step); without the pilot the runs need several, as the pilot did."""
    kwargs = dict(runs=2, particles=400, seed=2, progress=lambda m: None)
    with_pilot = smc.check(_target_potential, np.zeros(2), 1.5 * np.eye(2), _inside, ("a", "b"),
                           **kwargs)
    assert len(with_pilot.pilot.stages) >= 2
    assert [len(r.stages) for r in with_pilot.runs] == [1, 1]
    assert with_pilot.record()["reference"].startswith("a pilot run's Gaussian")
    without = smc.check(_target_potential, np.zeros(2), 1.5 * np.eye(2), _inside, ("a", "b"),
                        pilot=False, **kwargs)
    assert without.pilot is None
    assert all(len(r.stages) >= 2 for r in without.runs)


def test_smc_rejects_failed_solves():
    """A potential that is NaN (a failed solve) on part of the support: no particle ends
    there, and the rest of the target is still reached (its mean within 4 standard errors)."""

    def potential(y):
        return np.where(y[:, 1] > -0.9, np.nan, _target_potential(y))

    run = smc.run(potential, np.zeros(2), 1.5 * np.eye(2), _inside, particles=400, seed=3,
                  progress=lambda m: None)
    assert np.all(run.draws[:, 1] <= -0.9)
    b = truncnorm(-np.inf, (-0.9 - MEAN[1]) / SD[1], loc=MEAN[1], scale=SD[1])
    assert abs(run.draws[:, 1].mean() - b.mean()) <= 4 * b.std() / math.sqrt(len(run.draws) / 4)


@pytest.mark.parametrize("argv", [["--pilot-seed", "0"], ["--particles", "8"]])
def test_smc_pilot_refuses_the_shipped_seed_and_too_few_particles(argv, capsys):
    """``--smc-pilot`` checks the shipped draws against a pilot of other seeds: their own seed
    would compare them with themselves. Refused before anything runs, exit 2."""
    from fit.posterior.__main__ import main

    assert main(["--smc-pilot", *argv]) == 2
    assert "--pilot-seed" in capsys.readouterr().err
