"""The posterior (fit.posterior), its predictive bands (cardiosoft.posterior) and their
held-out checks (issue #24).

Independent sources: closed forms of a linear-Gaussian cut posterior and exact least-squares
refits for the Laplace and leave-one-out machinery; scipy's Wilson interval; Table II (held out
of the fit) and the paper's 30-bpm bench for the bands.
"""

import json
import math
import shutil

import numpy as np
import pytest
from scipy.stats import binomtest

from cardiosoft import simulate
from cardiosoft.batch import ensemble_size
from cardiosoft.datasets import load_paper_data
from cardiosoft.posterior import EnsembleRun, discrepancy_sd, predictive_bands
from cardiosoft.pump import DEFAULT_ARTIFACT, artifact_dir, load_card, load_posterior
from cardiosoft.units import mmHg
from fit.posterior import check, laplace

HEADS = np.array([30.0, 90.0]) * mmHg
CARD = {"discrepancy": {  # a posterior card's discrepancy: s0 1, s1 2 in every type
    "distance": {"rate_bpm": 30.0, "rate_scale_bpm": 30.0, "afterload_mmHg": [30.0, 90.0],
                 "afterload_scale_mmHg": 30.0},
    **{k: {"s0": 1.0, "s1": 2.0} for k in ("static_sv", "dynamic_sv", "force", "work")},
}}


def test_bands_leave_out_and_count_failed_draws():
    """A draw that failed at a member is left out of that member's bands and counted."""
    ok = np.array([[True, True], [False, False], [True, True]])
    values = {k: np.array([[1.0, 2.0], [np.nan, np.nan], [1.5, 2.5]]) for k in (
        "dynamic_sv_ml", "peak_force_N", "mech_work_J", "efficiency", "ef",
        "cardiac_output_l_min", "edv_ml")}
    bands = predictive_bands(EnsembleRun(values, ok, 30.0, HEADS / mmHg, ["", ""]), CARD)
    assert [b["dynamic_sv_ml"].failed for b in bands] == [1, 1]
    assert [b["dynamic_sv_ml"].draws for b in bands] == [2, 2]
    assert all(math.isfinite(b["dynamic_sv_ml"].low) for b in bands)


def test_ef_band_stays_below_one():
    """EF takes the SV's discrepancy in the filling, SV / (SV + ESV) with the SV not below
    zero: a pump that empties to a positive ESV keeps every sample in [0, 1) however large
    the discrepancy (an SV's sd of 30 ml on 60 ml)."""
    sv, edv = np.full((50, 1), 60.0), np.full((50, 1), 70.0)
    values = {k: np.ones((50, 1)) for k in ("peak_force_N", "mech_work_J", "efficiency",
                                           "cardiac_output_l_min")}
    values |= {"dynamic_sv_ml": sv, "edv_ml": edv, "ef": sv / edv}
    big = json.loads(json.dumps(CARD))
    big["discrepancy"]["dynamic_sv"]["s0"] = 30e-6  # 30 ml
    band = predictive_bands(EnsembleRun(values, np.ones((50, 1), bool), 30.0, None, [""]),
                            big)[0]["ef"]
    assert 0.0 <= band.low and band.high < 1.0


def test_band_median_and_quartiles_are_the_predictive_normals():
    """Draws' SV ~ N(80, 6) ml plus a discrepancy of 8 ml (inside the calibrated conditions:
    s0 alone) is N(80, 10): the band's median and middle half are 80 and 80 -+ 6.74 ml.
    Tolerance: 5 sds of a quantile of 2000 draws (0.31 ml at a quartile)."""
    rng = np.random.default_rng(2)
    sv = rng.normal(80.0, 6.0, (2000, 1))
    values = {k: np.ones((2000, 1)) for k in ("peak_force_N", "mech_work_J", "efficiency",
                                             "cardiac_output_l_min")}
    values |= {"dynamic_sv_ml": sv, "edv_ml": sv + 50.0, "ef": sv / (sv + 50.0)}
    card = json.loads(json.dumps(CARD))
    card["discrepancy"]["dynamic_sv"] = {"s0": 8e-6, "s1": 0.0}
    band = predictive_bands(EnsembleRun(values, np.ones((2000, 1), bool), 30.0,
                                        np.array([60.0]), [""]), card)[0]["dynamic_sv_ml"]
    quartile = 10.0 * 0.6745
    assert band.median == pytest.approx(80.0, abs=1.5)
    assert band.quartiles == pytest.approx((80.0 - quartile, 80.0 + quartile), abs=1.5)
    assert band.low == pytest.approx(80.0 - 19.6, abs=2.5)  # a 2.5 % tail: 0.47 ml an sd


def test_cut_laplace_is_the_linear_gaussian_cut_posterior():
    """For linear residuals the cut posterior is Gaussian in closed form: theta_a ~ N(., (A^T
    A)^-1); theta_b's refit given theta_a is lstsq(B2, y - B1 theta_a), linear in theta_a, plus
    N(0, (B2^T B2)^-1). Checked against numpy's least squares, not the normal equations."""
    rng = np.random.default_rng(1)
    a, b1, b2 = rng.normal(size=(6, 2)), rng.normal(size=(5, 2)), rng.normal(size=(5, 3))
    lap = laplace.cut_laplace(np.zeros(5), [a, np.hstack([b1, b2])],
                              [slice(0, 2), slice(2, 5)])
    cov_a = np.linalg.inv(a.T @ a)
    gain = np.linalg.lstsq(b2, -b1, rcond=None)[0]  # d theta_b* / d theta_a
    expected = np.zeros((5, 5))
    expected[:2, :2] = cov_a
    expected[2:, :2] = gain @ cov_a
    expected[:2, 2:] = expected[2:, :2].T
    expected[2:, 2:] = gain @ cov_a @ gain.T + np.linalg.inv(b2.T @ b2)
    np.testing.assert_allclose(lap.covariance, expected, rtol=1e-10, atol=1e-12)


def test_conditional_draws_follow_the_cut_posterior_given_the_first_block():
    """Given theta_a (drawn elsewhere, e.g. by NUTS), theta_b ~ N(lstsq refit given theta_a,
    (B2^T B2)^-1) for linear residuals: the draws' mean within 4 standard errors and their
    covariance within 10 % (4000 draws: the sd's relative error is 1.1 %); a draw outside the
    support is replaced with the pool's next row, whose theta_a it takes."""
    rng = np.random.default_rng(1)
    a, b1, b2 = rng.normal(size=(6, 2)), rng.normal(size=(5, 2)), rng.normal(size=(5, 3))
    lap = laplace.cut_laplace(np.zeros(5), [a, np.hstack([b1, b2])],
                              [slice(0, 2), slice(2, 5)])
    given = np.array([0.7, -0.3])
    n = 4000
    out, accepted = laplace.conditional_draws(lap, slice(0, 2), np.tile(given, (n, 1)), n, 5)
    assert accepted == 1.0 and np.all(out[:, :2] == given)
    mean = np.linalg.lstsq(b2, -b1 @ given, rcond=None)[0]
    cov = np.linalg.inv(b2.T @ b2)
    se = np.sqrt(np.diag(cov) / n)
    assert np.all(np.abs(out[:, 2:].mean(axis=0) - mean) <= 4 * se)
    np.testing.assert_allclose(np.cov(out[:, 2:].T), cov, rtol=0.1, atol=0.1 * cov.max())
    pool = np.repeat(np.array([[0.7, -0.3], [-0.7, 0.3]]), 50, axis=0)[rng.permutation(100)]
    kept, accepted = laplace.conditional_draws(lap, slice(0, 2), pool, 20, 5,
                                               lambda y: y[:, 0] > 0)
    assert np.all(kept[:, 0] == 0.7) and len(kept) == 20 and accepted < 1.0


def test_conditional_draws_move_a_pool_of_the_later_blocks_with_the_first():
    """``rest_pool``: draws of theta_b given theta_a at its centre (SMC's) stand in for the
    conditional's Gaussian and move with theta_a by the linearised refit. For linear residuals
    that is exact: a pool drawn from N(0, (B2^T B2)^-1) about the centre's refit gives, at a
    given theta_a, the closed-form mean and covariance (4 standard errors, 10 %); the pool's
    rows are taken in turn."""
    rng = np.random.default_rng(1)
    a, b1, b2 = rng.normal(size=(6, 2)), rng.normal(size=(5, 2)), rng.normal(size=(5, 3))
    lap = laplace.cut_laplace(np.zeros(5), [a, np.hstack([b1, b2])],
                              [slice(0, 2), slice(2, 5)])
    cov = np.linalg.inv(b2.T @ b2)
    n = 4000
    rest_pool = rng.multivariate_normal(np.zeros(3), cov, size=n // 2)  # used twice over
    given = np.array([0.7, -0.3])
    out, accepted = laplace.conditional_draws(lap, slice(0, 2), np.tile(given, (n, 1)), n, 5,
                                              rest_pool=rest_pool)
    mean = np.linalg.lstsq(b2, -b1 @ given, rcond=None)[0]
    assert accepted == 1.0
    np.testing.assert_allclose(out[: n // 2, 2:] - mean, rest_pool, atol=1e-12)
    np.testing.assert_allclose(out[n // 2:, 2:], out[: n // 2, 2:], atol=1e-12)
    se = np.sqrt(np.diag(cov) / (n // 2))
    assert np.all(np.abs(out[:, 2:].mean(axis=0) - mean) <= 4 * se)
    np.testing.assert_allclose(np.cov(out[:, 2:].T), cov, rtol=0.1, atol=0.1 * cov.max())


def test_linearised_leave_one_out_is_exact_for_a_linear_model():
    """One Gauss-Newton step without row i is the exact refit of a linear model: the left-out
    errors equal those of least-squares refits without each row."""
    rng = np.random.default_rng(2)
    x, y = rng.normal(size=(8, 3)), rng.normal(size=8)
    sd = rng.uniform(0.5, 2.0, size=8)
    prior_j, prior_r = 0.3 * np.eye(3), np.zeros(3)  # theta = 0: a prior row pulls to 0
    errors = laplace.loo_errors(-y, range(8), sd, x, prior_r, prior_j)
    for i in range(8):
        keep = np.arange(8) != i
        lhs = np.vstack([x[keep] / sd[keep, None], prior_j])
        rhs = np.concatenate([y[keep] / sd[keep], np.zeros(3)])
        theta = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        assert math.isclose(errors[i], x[i] @ theta - y[i], rel_tol=1e-9, abs_tol=1e-12)


def _softplus_inverse(y):
    return y + np.log(-np.expm1(-y))


def test_importance_weights_are_flat_where_the_laplace_is_exact():
    """A posterior Gaussian over the natural coordinates (y = softplus(theta) for the first, x
    for the second), the coordinates it is stated in: a Laplace with its exact mean and sd gets
    equal weights, so ESS = n."""
    from fit.posterior import importance

    mean, sd = np.array([3.0, -1.0]), np.array([0.4, 2.0])
    positive = np.array([True, False])

    def potential(theta):
        y = np.column_stack([np.logaddexp(0.0, theta[:, 0]), theta[:, 1]])
        return 0.5 * np.sum(((y - mean) / sd) ** 2, axis=1)

    to_raw = lambda y: np.column_stack([_softplus_inverse(y[:, 0]), y[:, 1]])  # noqa: E731
    result = importance.run(potential, mean, np.diag(sd), positive, ("y", "x"), to_raw=to_raw,
                            n=400, seed=3, progress=lambda m: None)
    assert result.ess == pytest.approx(400, rel=1e-9)
    assert result.failed == 0
    np.testing.assert_allclose(result.weighted_shift, 0.0, atol=4 / math.sqrt(400))  # 4 SE


def test_importance_sampling_finds_a_narrower_posterior_and_counts_failures():
    """A posterior N(0, 0.5^2) seen through a Laplace of sd 1: the weighted sd is 0.5 within
    its Monte Carlo error (3 / sqrt(2 ESS) relative), PSIS trusts the weights (k-hat < 0.7);
    draws whose potential is NaN (a failed solve) weigh nothing and are counted."""
    from fit.posterior import importance

    def potential(theta):
        u = 0.5 * (theta[:, 0] / 0.5) ** 2
        return np.where(theta[:, 0] > 2.5, np.nan, u)  # beyond 5 target sd: "failed"

    result = importance.run(potential, np.zeros(1), np.eye(1), np.array([False]), ("x",),
                            to_raw=lambda y: y, n=4000, seed=4, progress=lambda m: None)
    assert result.reliable
    assert result.weighted_sd[0] == pytest.approx(0.5, rel=3 / math.sqrt(2 * result.ess))
    assert 0 < result.failed < 40  # P(x > 2.5) = 0.6 % of 4000


def test_a_recomputation_keeps_only_the_unchanged_laplaces_records():
    """``python -m fit.posterior --force`` keeps the records that check the Laplace (NUTS, SMC,
    SBC, ...) where the recomputed Laplace is the old one, drops them where it moved, and never
    keeps ``checks``: those are the old draws'."""
    from fit.posterior import artifact

    rng = np.random.default_rng(0)
    old = {"centre": rng.normal(size=3), "natural_centre": rng.normal(size=3),
           "transform": np.tril(rng.normal(size=(3, 3)))}
    card = {"smc": {"mixed": True}, "sbc_joint": {"replicates": 200}, "checks": {"x": 1},
            "draws": 256}
    same = {k: v * (1 + 1e-9) for k, v in old.items()}  # recomputed: round-off only
    assert artifact.carried_records(card, old, same) == {"smc": {"mixed": True},
                                                         "sbc_joint": {"replicates": 200}}
    moved = dict(same, transform=old["transform"] * 1.01)
    assert artifact.carried_records(card, old, moved) == {}


@pytest.mark.parametrize("k", [9, 8, 5])
def test_wilson_interval_matches_scipy(k):
    lo, hi = check.wilson(k, 9)
    ci = binomtest(k, 9).proportion_ci(method="wilson")
    assert math.isclose(lo, ci.low, abs_tol=1e-9) and math.isclose(hi, ci.high, abs_tol=1e-9)


def test_interval_score_charges_misses():
    """Gneiting and Raftery's score: the width inside; the width plus 2/alpha times the miss
    outside (alpha 0.05: 40 per unit)."""
    np.testing.assert_allclose(check.interval_score([0, 0, 0], [2, 2, 2], [1, 3, -0.5]),
                               [2.0, 2.0 + 40.0, 2.0 + 20.0])


def test_discrepancy_grows_away_from_the_calibrated_conditions():
    card = CARD
    assert discrepancy_sd(card, "force", 30.0, 60.0) == pytest.approx(1.0)
    one = math.sqrt(1 + 4 * (1 - math.exp(-1)))
    assert discrepancy_sd(card, "force", 60.0, 60.0) == pytest.approx(one)  # a rate away
    assert discrepancy_sd(card, "force", 30.0, 120.0) == pytest.approx(one)  # a head away
    assert discrepancy_sd(card, "force", 30.0, None) == pytest.approx(math.sqrt(5))
    assert discrepancy_sd(card, "static_sv", 120.0, 60.0) == pytest.approx(1.0)  # no rate


def test_load_posterior_checks_its_hashes(tmp_path):
    """The shipped posterior loads as an ensemble; a changed draw or draws computed for other
    weights are refused."""
    post = load_posterior()
    size = ensemble_size(post.pump, post.scene_draws)
    assert size == post.card["draws"]
    assert set(post.scene_draws) == set(post.scene_centre)
    src = artifact_dir()
    card = load_card()
    weights = tmp_path / f"{DEFAULT_ARTIFACT}.eqx"
    for name in (f"{DEFAULT_ARTIFACT}.eqx", f"{DEFAULT_ARTIFACT}.json", card["posterior"]["file"],
                 card["posterior"]["card"]):
        shutil.copy(src / name, tmp_path / name)
    load_posterior(weights)
    npz = tmp_path / card["posterior"]["file"]
    with np.load(npz) as f:
        arrays = dict(f)
    arrays["theta"] = arrays["theta"] + 1e-12
    np.savez(npz, **arrays)
    with pytest.raises(ValueError, match="sha256"):
        load_posterior(weights)
    shutil.copy(src / card["posterior"]["file"], npz)
    pcard = tmp_path / card["posterior"]["card"]
    other = json.loads(pcard.read_text()) | {"weights_sha256": "0" * 64}
    pcard.write_text(json.dumps(other))
    with pytest.raises(ValueError, match="not for"):
        load_posterior(weights)


def test_table2_held_out_inside_their_bands():
    """Issue #24: at least 8 of Table II's 9 experiments (never fitted) inside their 95 %
    predictive bands. Loose on purpose: 9 experiments at nominal 95 % cover all 9 with
    probability 0.63 and at least 8 with 0.93; Monte Carlo moves a band edge by ~0.3 ml."""
    cov = check.table2(load_posterior(), load_paper_data())
    assert cov.inside.sum() >= 8


def test_simulate_uncertainty_refuses_a_closed_loop(tmp_path, capsys):
    status = simulate.main(["--scene", "heart", "--uncertainty", "--out", str(tmp_path / "o")])
    assert status == 2
    assert "--uncertainty" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_simulate_uncertainty_refuses_draws_out_of_range(tmp_path, capsys):
    status = simulate.main(["--uncertainty", "--draws", "1", "--out", str(tmp_path / "o")])
    assert status == 2
    assert "draws = 1" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_simulate_uncertainty_writes_bands(tmp_path, capsys):
    """``simulate --uncertainty`` (4 draws, 30 bpm, fixed beats) prints and writes each metric's
    band, with the draws' own (narrower: no discrepancy) beside it; the figure is written."""
    out = tmp_path / "o"
    status = simulate.main(["--bpm", "30", "--beats", "2", "--uncertainty", "--draws", "4",
                            "--out", str(out)])
    assert status == 0
    assert "95 % predictive bands" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["uncertainty"]["draws"] == 4
    for r in summary["records"]:
        for key in ("static_sv_ml", "dynamic_sv_ml", "peak_force_N", "mech_work_J", "ef"):
            lo, hi = r[f"{key}_band"]
            plo, phi = r[f"{key}_band_parameters"]
            assert lo < hi and lo <= plo <= phi <= hi
            assert lo <= r[f"{key}_median"] <= hi
    assert (out / "figure.png").is_file()


def test_posterior_density_has_the_draws_support():
    """The posterior's density and its draws share one support (fit.posterior.blocks,
    "Support"): a surrogate convex enough in V (d2U/dV2 >= CONVEXITY_MARGIN E_u on the fit's
    grid) is charged nothing for its convexity, even between the margin and the fit's own
    hinge at 1.2 times it (where a fifth of the draws lie), and one that is not has the density
    zero (+inf residual). Draws of the shipped Laplace, untruncated, supply both kinds."""
    import jax
    import jax.numpy as jnp

    from fit import pipeline
    from fit.posterior import artifact, blocks

    b = artifact.Shipped(None)
    rows = jax.jit(jax.vmap(blocks.mechanics_fixed_rows(b.layout, b.d)))
    smallest = jax.jit(jax.vmap(blocks.smallest_stiffness(b.layout)))
    natural, _ = laplace.draws(b.laplace, 64, 0, positive=b.layout.positive)
    theta = jnp.asarray(b.layout.raw(natural))
    m = np.asarray(smallest(theta))
    between = (m >= pipeline.CONVEXITY_MARGIN) & (m < pipeline.CONVEXITY_FIT_MARGIN)
    outside = m < pipeline.CONVEXITY_MARGIN
    assert between.any() and outside.any()
    r = np.asarray(rows(theta))
    n_fem_and_priors = 4 + len(b.layout.prior_rows("mechanics")[0])
    support = r[:, : r.shape[1] - n_fem_and_priors]
    assert np.all(support[between] == 0.0)
    assert np.all(np.isinf(support[outside]).any(axis=1))
    assert np.all(np.isfinite(r[~outside]))


@pytest.mark.parametrize("pump", ["ss950-v3", "ss950-v4"])
def test_each_pump_s_posterior_stands_on_its_own_calibrated_bench(pump):
    """A surrogate's posterior is centred on the bench calibrated with it (the scene's
    ``[calibration."<pump>"]`` table): ss950-v4's on its 101.7-mm tube and a crosshead with a
    50-ms ramp, which enters its bench block as a fifth rig unknown with its prior
    (``bench.log_ramp_time``, 5-500 ms at 2 sd) and sets the scene's ramp from theta;
    ss950-v3's ideal crosshead (no ramp) has four."""
    import jax.numpy as jnp

    from cardiosoft.pump import load
    from cardiosoft.scene import load_scene
    from fit import fitting
    from fit.posterior import artifact, blocks

    scene = artifact.bench_scene(pump)
    assert scene == load_scene("bench-dynamic", pump=pump)
    layout = blocks.Layout(load(pump), fitting.rig_from_card(load_card(pump)), scene)
    bench = layout.blocks["bench"]
    ramp = pump == "ss950-v4"
    assert ("bench.log_ramp_time" in layout.names) == ramp
    assert bench.stop - bench.start == 4 + ramp
    idx, mu, sd = layout.prior_rows("bench")
    assert list(idx) == list(range(bench.start, bench.stop))
    if ramp:
        assert (scene.tube_length, scene.ramp_time) == pytest.approx((0.1017, 0.05))
        assert np.exp(mu[-1] + np.array([-2, 2]) * sd[-1]) == pytest.approx([0.005, 0.5])
        theta = np.array(layout.centre)
        theta[bench.stop - 1] = np.log(0.2)
        at = blocks.bench_scene_at(scene, layout, jnp.asarray(theta))
        assert float(at.ramp_time) == pytest.approx(0.2)
        assert float(at.tube_length) == pytest.approx(scene.tube_length)


@pytest.mark.slow
def test_leaving_an_afterload_out_drops_its_four_rows():
    """The leave-one-afterload-out posterior's residuals (``joint_residuals(keep=...)``) are
    the whole block's with exactly the left-out head's static SV, peak force, dynamic SV and
    work set to 0: the support, the FEM rows and the priors stay. Checked against the rows'
    values at the fit's optimum, where none of the four is 0."""
    import jax
    import jax.numpy as jnp

    from cardiosoft.scene import load_scene
    from fit.posterior import artifact, blocks

    b = artifact.Shipped(None)
    scene = load_scene(artifact.SCENE)
    keep = np.array([True, False, True])
    full = blocks.joint_residuals(b.layout, b.d, b.s0, scene)
    left = blocks.joint_residuals(b.layout, b.d, b.s0, scene, keep=keep)
    r, r_left = (np.asarray(x) for x in jax.jit(lambda t: (full(t), left(t)))(
        jnp.asarray(b.centre)))
    n_fixed = 1 + len(blocks.FEM_ROWS) + len(b.layout.prior_rows("mechanics")[0])
    dropped = np.array([1, 4, 6 + n_fixed + 1, 6 + n_fixed + 4])  # the middle head's four
    assert np.all(r[dropped] != 0.0) and np.all(r_left[dropped] == 0.0)
    np.testing.assert_array_equal(np.delete(r_left, dropped), np.delete(r, dropped))


@pytest.fixture(scope="module")
def bench_30():
    from fit.posterior import artifact

    post = load_posterior()
    return check.bench(post, load_paper_data(), artifact.bench_scene(post.card["surrogate"]))


@pytest.mark.slow
def test_bench_at_30_bpm_inside_its_bands(bench_30):
    """Issue #24: the paper's dynamic SVs (fitted) and peak forces (not fitted) at 30 bpm inside
    their 95 % bands."""
    assert bench_30.dynamic_sv.inside.all() and bench_30.peak_force.inside.all()


@pytest.mark.slow
def test_bench_at_30_bpm_leaves_out_at_most_2_percent(bench_30):
    """At most 2 % of the (draw, head) pairs left out of the 30-bpm bands (2 of 768 with SMC's
    draws of the mechanics+bench block, 2026-12-04; 6 with the Laplace's; 20 while the
    posterior charged the fit's convexity hinge, which pinned the swelling resistance and sent
    the linearised refit where the chamber swells to 140-190 ml)."""
    assert bench_30.failed <= 0.02 * 3 * load_posterior().card["draws"]


@pytest.mark.slow
def test_posterior_recomputes_to_the_shipped_draws():
    """``python -m fit.posterior`` is reproducible (about 30 min: NUTS and two SMC runs):
    recomputed with the card's seed, each parameter's draws have the shipped mean and sd to
    within their Monte Carlo error, not bit for bit (another CPU's NUTS chains are other chains;
    the convexity rejection may flip a draw at its edge). Each set is taken as S effective
    draws: the EF draws are thinned from chains whose autocorrelation time is well under the
    thinning step (bulk ESS > 1500 of 8000), the mechanics+bench block's are one SMC run's
    particles, whose bulk ESS the ``--smc`` check measured (853 over four runs of 256: S 213);
    4 standard errors of a difference of two such estimates, sd sqrt(2 / S) for the means and
    sd sqrt(1 / S) for the sds (42 comparisons: a false alarm about once in 300)."""
    from fit.posterior import artifact

    post = load_posterior()
    arrays, pcard, _, _ = artifact.compute(n_draws=post.card["draws"], seed=post.card["seed"],
                                           progress=lambda m: None)
    with np.load(artifact_dir() / post.card["file"]) as f:
        shipped = f["theta"]
    smc_check = post.card["smc"]["mechanics+bench"]
    ess = min(p["ess_bulk"] for p in smc_check["parameters"].values()) / len(smc_check["runs"])
    new, n = arrays["theta"], min(len(shipped), ess)
    sd = shipped.std(axis=0, ddof=1)
    assert np.all(np.abs(new.mean(axis=0) - shipped.mean(axis=0)) <= 4 * sd * np.sqrt(2 / n))
    assert np.all(np.abs(new.std(axis=0, ddof=1) - sd) <= 4 * sd * np.sqrt(1 / n))
    assert pcard["ef_nuts"]["mixed"]
    for kind in laplace.TYPES:
        assert pcard["discrepancy"][kind]["s0"] == pytest.approx(
            post.card["discrepancy"][kind]["s0"], rel=1e-3, abs=1e-12)


@pytest.fixture(scope="module")
def ef_nuts():
    """NUTS on the EF block as ``python -m fit.posterior`` runs it (nothing written)."""
    from fit.posterior.artifact import Shipped, nuts_ef

    b = Shipped(None)
    return nuts_ef(b.layout, b.d, b.s0, b.laplace, seed=0, progress=lambda m: None)


@pytest.mark.slow
def test_nuts_on_the_ef_block_mixes(ef_nuts):
    """The shipped EF draws' chains: R-hat < 1.01, bulk ESS > 400, no divergences (issue #24;
    ArviZ's rank-normalised diagnostics). Without the change of variables to the natural
    coordinates the chains stuck on the plateaus where a softplus saturates (R-hat 1.06, bulk
    ESS 85 at 4 x 4000)."""
    assert ef_nuts.mixed, ef_nuts.record()


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue #24: the EF law's posterior is not Gaussian: the "
                   "Laplace's marginal sds (truncated at zero) are 0.50-0.94 of NUTS's (mixed), "
                   "off by more than 20 % for both linear rates, the quadratic rate at Omega 0 "
                   "and the three-fold depth (measured 2026-12-03); the shipped EF draws are "
                   "NUTS's")
def test_laplace_sds_within_20_percent_of_nuts_on_the_ef_block(ef_nuts):
    """The Laplace's marginal sds (of its draws, truncated at zero) within 20 % of NUTS's."""
    assert ef_nuts.passed, ef_nuts.record()


@pytest.mark.slow
def test_simulate_explain_records_shares_and_measurements(tmp_path):
    """``--uncertainty --explain``: each prediction's shares lie in [0, 1] and no measurement
    widens its band (a measurement only adds information)."""
    out = tmp_path / "o"
    assert simulate.main(["--bpm", "60", "--uncertainty", "--draws", "4", "--explain",
                          "--no-plot", "--out", str(out), "--quiet"]) in (0,)
    explained = json.loads((out / "summary.json").read_text())["uncertainty"]["explain"]
    assert len(explained["predictions"]) == 9  # SV, force, efficiency at three heads
    for p in explained["predictions"].values():
        assert all(0.0 <= s <= 1.0 + 1e-9 for s in p["shares"].values())
        assert all(v <= p["sd_parameters"] * (1 + 1e-9) for v in p["sd_after"].values())


SBC_REPLICATES = 60


@pytest.fixture(scope="module")
def ef_sbc():
    """Simulation-based calibration of the EF block (fit.posterior.sbc), 60 replicates."""
    from cardiosoft.pump import artifact_path, load, load_card
    from cardiosoft.scene import load_scene
    from fit import fitting
    from fit.posterior import artifact, blocks, sbc

    post = load_posterior()
    npz, _ = artifact.posterior_paths(artifact_path())
    layout = blocks.Layout(load(), fitting.rig_from_card(load_card()),
                           load_scene(artifact.SCENE))
    cols = layout.blocks["ef"]
    with np.load(npz) as f:
        lap_ef = (f["natural_centre"][cols], f["transform"][cols, cols])
    data = load_paper_data()
    s0 = blocks.Sigmas(post.card["discrepancy"]["ef_volume"]["s0"]
                       / float(load().unloaded_volume), 0.0, 0.0, 0.0, 0.0)
    return sbc.run(layout, blocks.training_data(data), s0, lap_ef, data,
                   replicates=SBC_REPLICATES, seed=1, progress=lambda m: None)


def _undercovered(result, names):
    """The quantities whose 95 % intervals cover the truth at a rate whose Wilson interval
    stays below 0.95."""
    return [name for name, cov, n in zip(result.names, result.coverage, result.ranked,
                                         strict=True)
            if name in names and check.wilson(round(float(cov) * n), int(n))[1] < 0.95]


@pytest.mark.slow
def test_sbc_of_the_ef_block_does_not_undercover(ef_sbc):
    """SBC of the EF block: for each parameter but the quadratic coefficients (next test) and
    each of Table II's held-out EF_0, the 95 % intervals cover the truth at a rate whose Wilson
    interval reaches 0.95 (an under-dispersed posterior fails this; the ranks' uniformity is
    reported by ``python -m fit.posterior --sbc``, not asserted: the Laplace's shape is not the
    soft-L1 posterior's)."""
    names = [n for n in ef_sbc.names if not n.startswith("ef_quadratic")]
    assert _undercovered(ef_sbc, names) == []


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue #24: the Laplace is too narrow along the EF law's "
                   "quadratic rate (NUTS finds the sds of its values at Omega 0 and 6 1.6x and "
                   "1.1x the truncated Laplace's); python -m fit.posterior --sbc, 200 replicates: "
                   "its value at Omega 6 covers 0.91 (Wilson 0.86-0.94), at Omega 0 0.92 "
                   "(0.87-0.95), measured 2026-12-03")
def test_sbc_of_the_ef_quadratic_coefficients_does_not_undercover(ef_sbc):
    assert _undercovered(ef_sbc, [n for n in ef_sbc.names if n.startswith("ef_quadratic")]) == []
