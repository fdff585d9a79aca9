"""The Gauss-Newton Laplace approximation of the cut posterior, and the discrepancy's size.

**Cut posterior.** The EF law is cut from the rest (Plummer 2015, "cutting feedback"), as in
the fit: ``p(theta_ef | Table I)``, then ``p(theta_mech, theta_bench | theta_ef, quasi-static
bench, FEM, dynamic bench)``; the bench's data never move the EF law. The mechanics and the
bench's four are one block (:data:`JOINT`): the fit calibrates them one after the other, but
the dynamic SVs inform the chamber too, and cut there the chamber's flat direction (E_u, kappa
and the column, which the quasi-static data leave free) went straight into the bench's
linearised refit: the viscoelastic ratio spread over seven orders of magnitude (log sd 3.1,
measured 2026-12-03), where together the dynamic data bound it (log sd 1.0). Each block is
linearised at the fit's optimum ``theta*`` (the shipped surrogate, its rig, the bench scene's
calibrated numbers):

- ``theta_ef ~ N(theta*_ef, H_ef^-1)``, ``H_ef = J_ef^T J_ef`` of its whitened residuals;
- ``theta_rest | theta_ef ~ N(theta*_rest + B (theta_ef - theta*_ef), H_rest^-1)``, with
  ``B = -H_rest^-1 J_rest,rest^T J_rest,ef``: the linearised refit of the rest when the EF law
  moves (it is not a constant: the bench's data see EF_0 at Omega 4, C 0.4).

``theta*`` is the sequential fit's optimum, not this posterior's mode (the fit weighs its data
by its own scales): :func:`mode_offset` measures how far one Gauss-Newton step would move it,
in posterior sds, and the card records it.

The draws are ``theta* + T z``, z standard normal, T block lower-triangular; the joint
covariance is ``T T^T``. Not a ``jax.hessian`` of the loss: Gauss-Newton's ``J^T J`` is positive
definite where the Hessian is not (DESIGN.md section 3.6).

**Discrepancy.** Per output type (EF volume, SV, force, work) one scale s0, from leave-one-out
residuals: each data row left out in turn, its block refitted by one Gauss-Newton step from
``theta*`` (the linearised refit, exact for a linear model), the left-out row predicted. The
type's ``s0^2`` is the mean squared leave-one-out error less the mean measurement variance
(not below zero). The sds of the mechanics and bench rows include s0, so the sizing is iterated
to its fixed point (a few rounds). The EF block's residuals share one scale: there, s0 does not
change the leave-one-out predictions, only their spread.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from fit.posterior import blocks
from fit.posterior.blocks import Layout, Sigmas

SIZING_ROUNDS = 8
SIZING_RTOL = 1e-3  # relative change of every s0 between rounds that ends the iteration


def jacobian(fn, theta, cols: slice):
    """(fn(theta), d fn / d theta[cols]) as numpy, forward mode (the beat loop is a
    ``while_loop``, and these blocks have few parameters)."""
    theta = jnp.asarray(theta)

    def sub(x):
        return fn(theta.at[cols].set(x))

    r, jac = jax.jit(lambda x: (sub(x), jax.jacfwd(sub)(x)))(theta[cols])
    return np.asarray(r), np.asarray(jac)


def loo_errors(e, rows, sd, jac_phys, other_r, other_j):
    """Linearised leave-one-out errors of the data rows ``e`` (model - data, physical units).

    ``rows`` whitened by ``sd`` are stacked over ``other_r`` / ``other_j`` (the block's rows that
    are not left out: other data, constraints, priors); each row i is left out in turn and the
    block refitted by one Gauss-Newton step from where it is; returns the refit's error at i.
    """
    w = 1.0 / np.asarray(sd)
    jac = np.concatenate([jac_phys * w[:, None], other_j])
    r = np.concatenate([np.asarray(e) * w, other_r])
    return _left_out_errors(e, jac_phys, r, jac, rows)


def _left_out_errors(e, jac_e, r, jac, rows):
    """``e[i] + jac_e[i] @ step_i`` for each i in ``rows``: ``step_i`` the Gauss-Newton step of
    the whitened residuals ``r`` (Jacobian ``jac``) without row i, i.e. the linearised refit
    with that row left out, and ``e``, ``jac_e`` the left-out quantity and its Jacobian."""
    h, g = jac.T @ jac, jac.T @ r
    out = np.empty(len(rows))
    for k, i in enumerate(rows):
        ji = jac[i]
        step = -np.linalg.solve(h - np.outer(ji, ji), g - ji * r[i])
        out[k] = e[i] + jac_e[i] @ step
    return out


class Sizing(NamedTuple):
    """The discrepancy scales and the leave-one-out errors they came from (SI)."""

    s0: Sigmas
    loo: dict  # type -> array of leave-one-out errors
    measurement_var: dict  # type -> mean measurement variance of its rows
    rounds: int


def _s0(errors, variances):
    return float(np.sqrt(max(0.0, np.mean(np.square(errors)) - np.mean(variances))))


def size_ef(layout: Layout, d: blocks.Data, theta):
    """(s0_ef, leave-one-out EF errors): the EF block's leave-one-out on Table I."""
    cols = layout.blocks["ef"]
    residual = blocks.ef_residuals(layout, d, Sigmas(1.0, 0, 0, 0, 0))  # scale cancels here

    def ef(theta):
        from fit.pipeline import zero_pressure_ef

        return zero_pressure_ef(layout.pump(theta), d.t.t1_omega, d.t.t1_shortening)

    r, jac = jacobian(residual, theta, cols)
    model, jac_ef = jacobian(ef, theta, cols)
    e = model - d.t.t1_ef
    errors = _left_out_errors(e, jac_ef, r, jac, range(len(e)))
    return _s0(errors, [blocks.FEM_ROUNDING**2]), errors


class Linearisation(NamedTuple):
    """What the sizing and the Laplace step need of the mechanics and bench blocks at theta*,
    in physical units (the whitening is applied per round)."""

    mech_e: np.ndarray  # static SV, peak force, work: model - data (SI)
    mech_j: np.ndarray  # their Jacobians over (ef, mechanics)
    mech_fixed_r: np.ndarray
    mech_fixed_j: np.ndarray  # over (ef, mechanics)
    bench_e: np.ndarray  # dynamic SV, work: model - data (SI)
    bench_j: np.ndarray  # over all parameters
    bench_prior_r: np.ndarray
    bench_prior_j: np.ndarray  # over all parameters
    bench_outputs: blocks.BenchOutputs  # at theta* (SI), peak forces included


def linearise(layout: Layout, d: blocks.Data, scene, theta, progress=print) -> Linearisation:
    """Residuals and Jacobians of the mechanics and bench blocks at ``theta`` (forward mode)."""
    upto_mech = slice(0, layout.blocks["mechanics"].stop)
    every = slice(0, len(theta))
    t = d.t
    progress("  mechanics block: Jacobian of the quasi-static bench and FEM rows")

    def mech_rows(th):
        o = blocks.mechanics_outputs(layout, d)(th)
        return jnp.concatenate([o.static_sv, o.peak_force, o.mech_work])

    y, mech_j = jacobian(mech_rows, theta, upto_mech)
    data = np.concatenate([t.static_sv, t.peak_force, t.mech_work])
    fixed_r, fixed_j = jacobian(blocks.mechanics_fixed_rows(layout, d), theta, upto_mech)
    progress("  bench block: Jacobian of the dynamic bench at 30 bpm through diffrax")
    outputs = blocks.bench_outputs(layout, scene, t.afterload)

    def bench_rows(th):
        o = outputs(th)
        return jnp.concatenate([o.dynamic_sv, o.mech_work, o.peak_force])

    b, bench_j = jacobian(bench_rows, theta, every)
    if not np.all(np.isfinite(b)):
        raise RuntimeError("the dynamic bench at the fit's optimum did not solve or is not steady")
    n = len(t.afterload)
    idx, mu, sd = layout.prior_rows("bench")
    prior_j = np.zeros((len(idx), len(theta)))
    prior_j[np.arange(len(idx)), idx] = 1.0 / sd
    return Linearisation(
        mech_e=np.asarray(y) - data,
        mech_j=mech_j,
        mech_fixed_r=fixed_r,
        mech_fixed_j=fixed_j,
        bench_e=b[: 2 * n] - np.concatenate([d.dynamic_sv, t.mech_work]),
        bench_j=bench_j[: 2 * n],
        bench_prior_r=(np.asarray(theta)[idx] - mu) / sd,
        bench_prior_j=prior_j,
        bench_outputs=blocks.BenchOutputs(b[:n], b[n : 2 * n], b[2 * n :]),
    )


def _mech_sds(d, s0):
    sds = blocks.mechanics_sds(d, s0)
    return np.concatenate([sds.static_sv, sds.peak_force, sds.mech_work])


def _bench_sds(d, s0):
    return np.concatenate(blocks.bench_sds(d, s0))


TYPES = ("static_sv", "dynamic_sv", "force", "work")


def size_discrepancy(layout: Layout, d: blocks.Data, lin: Linearisation, s0_ef: float) -> Sizing:
    """Iterate the static and dynamic SV, force and work scales to their fixed point (module
    docstring)."""
    n = len(d.t.afterload)
    mech = layout.blocks["mechanics"]
    bench = layout.blocks["bench"]
    variances = {
        "static_sv": d.static_sv_sd**2,
        "dynamic_sv": d.dynamic_sv_sd**2,
        "force": d.peak_force_sd**2,
        "work": np.concatenate([d.mech_work_sd, d.mech_work_sd]) ** 2,
    }
    s0 = Sigmas(s0_ef, 0.0, 0.0, 0.0, 0.0)
    rounds = 0
    while rounds < SIZING_ROUNDS:
        rounds += 1
        m = loo_errors(
            lin.mech_e, range(3 * n), _mech_sds(d, s0), lin.mech_j[:, mech],
            lin.mech_fixed_r, lin.mech_fixed_j[:, mech],
        )
        b = loo_errors(
            lin.bench_e, range(2 * n), _bench_sds(d, s0), lin.bench_j[:, bench],
            lin.bench_prior_r, lin.bench_prior_j[:, bench],
        )
        types = {
            "static_sv": m[:n],
            "dynamic_sv": b[:n],
            "force": m[n : 2 * n],
            "work": np.concatenate([m[2 * n :], b[n:]]),
        }
        new = Sigmas(s0_ef, *(_s0(types[k], variances[k]) for k in TYPES))
        done = np.allclose(new, s0, rtol=SIZING_RTOL, atol=0.0)
        s0 = new
        if done:
            break
    return Sizing(s0, types, {k: float(np.mean(v)) for k, v in variances.items()}, rounds)


class Laplace(NamedTuple):
    """The cut posterior's Gaussian: centre, the transform T (draws = centre + T z) and the
    joint covariance ``T T^T``; per block its conditional covariance given the blocks before."""

    centre: np.ndarray
    transform: np.ndarray
    covariance: np.ndarray
    conditional: dict  # block -> (p_b, p_b) covariance given the earlier blocks


def _cholesky_inverse(h):
    """(H^-1, its Cholesky factor L, L L^T = H^-1) of a positive definite H."""
    cov = np.linalg.inv(h)
    cov = 0.5 * (cov + cov.T)
    return cov, np.linalg.cholesky(cov)


def cut_laplace(centre, jacobians, spans, names=None) -> Laplace:
    """The Laplace approximation of a cut posterior whose blocks ``spans`` (consecutive
    slices of ``centre``) are each conditional on the blocks before them.

    ``jacobians[k]``: the whitened Jacobian of block k's residuals over the parameters
    ``0 .. spans[k].stop`` (the earlier blocks' and its own). Block k given the earlier ones:
    ``N(centre_k + B_k (theta_< - centre_<), H_k^-1)``, ``H_k = J_kk^T J_kk`` and
    ``B_k = -H_k^-1 J_kk^T J_k<``, the linearised refit of block k as the earlier ones move.
    """
    p = len(centre)
    transform = np.zeros((p, p))
    conditional = {}
    for k, (jac, own) in enumerate(zip(jacobians, spans, strict=True)):
        before = slice(0, own.start)
        j_own = jac[:, own]
        cov, chol = _cholesky_inverse(j_own.T @ j_own)
        if own.start > 0:
            coupling = -cov @ j_own.T @ jac[:, before]
            transform[own, before] = coupling @ transform[before, before]
        transform[own, own] = chol
        conditional[k if names is None else names[k]] = cov
    return Laplace(np.asarray(centre), transform, transform @ transform.T, conditional)


def laplace(
    layout: Layout, d: blocks.Data, lin: Linearisation, s0: Sigmas, theta, keep=None
) -> Laplace:
    """The cut posterior's Laplace approximation at ``theta`` with the discrepancy ``s0``, in
    the layout's natural coordinates (:meth:`Layout.natural`: the positive coefficients
    themselves where the raw coordinate is a softplus-inverse, else the raw one).

    ``keep``: which of the bench's afterloads keep their rows (bools; default all). Without
    some, the second block is refitted by one Gauss-Newton step from ``theta`` (the EF law
    held) and the approximation centred there: the posterior had those data never been seen
    (the leave-one-afterload-out check, :func:`fit.posterior.check.leave_one_afterload_out`).
    """
    theta = np.asarray(theta, float)
    if keep is not None and not np.all(keep):
        r, jac = joint_rows(layout, d, lin, s0, keep)
        own = _spans(layout)[1]
        step = -np.linalg.solve(jac[:, own].T @ jac[:, own], jac[:, own].T @ r)
        theta = theta.copy()
        theta[own] += step  # the linearised refit; the Jacobians stay theta*'s
    slope = layout.natural_slope(theta)
    lap = _laplace_raw(layout, d, lin, s0, theta, 1.0 / slope, keep)
    return lap._replace(centre=layout.natural(theta))


JOINT = "mechanics+bench"
"""The second block of the cut posterior: the mechanics and the bench's four together."""


def joint_rows(layout: Layout, d: blocks.Data, lin: Linearisation, s0: Sigmas, keep=None):
    """(whitened residuals, their Jacobian over every parameter) of the second block: the
    mechanics rows (quasi-static SVs and peak forces, the support, FEM, priors), then the bench
    rows (dynamic SVs and works, priors). The paper's work M is one measurement: it enters as
    the dynamic work only (the fit's stage 2 fits the quasi-static work to it too). ``keep``:
    which afterloads keep their four data rows (bools; default all)."""
    p = lin.bench_j.shape[1]
    n = len(d.t.afterload)
    keep = np.ones(n, bool) if keep is None else np.asarray(keep, bool)
    rows = np.concatenate([keep, keep, np.zeros(n, bool)])  # static SV, force; no static work
    bench_rows = np.concatenate([keep, keep])  # dynamic SV, work
    w_mech, w_bench = 1.0 / _mech_sds(d, s0)[rows], 1.0 / _bench_sds(d, s0)[bench_rows]
    mech_j = np.concatenate([lin.mech_j[rows] * w_mech[:, None], lin.mech_fixed_j])
    mech_j = np.pad(mech_j, ((0, 0), (0, p - mech_j.shape[1])))  # no bench columns
    jac = np.concatenate(
        [mech_j, lin.bench_j[bench_rows] * w_bench[:, None], lin.bench_prior_j]
    )
    r = np.concatenate(
        [
            lin.mech_e[rows] * w_mech,
            lin.mech_fixed_r,
            lin.bench_e[bench_rows] * w_bench,
            lin.bench_prior_r,
        ]
    )
    return r, jac


def _spans(layout: Layout):
    ef = layout.blocks["ef"]
    return [ef, slice(ef.stop, layout.blocks["bench"].stop)]


def mode_offset(layout: Layout, d: blocks.Data, lin: Linearisation, s0: Sigmas) -> np.ndarray:
    """One Gauss-Newton step of the second block from ``theta*`` (the EF law held), in units of
    its conditional posterior sd (raw coordinates): how far this posterior's mode lies from the
    fit's optimum it is centred on."""
    r, jac = joint_rows(layout, d, lin, s0)
    own = _spans(layout)[1]
    h = jac[:, own].T @ jac[:, own]
    step = -np.linalg.solve(h, jac[:, own].T @ r)
    return step / np.sqrt(np.diag(np.linalg.inv(h)))


def _laplace_raw(layout, d, lin, s0, theta, column_scale, keep=None) -> Laplace:
    _, j_ef = jacobian(blocks.ef_residuals(layout, d, s0), theta, layout.blocks["ef"])
    _, j_rest = joint_rows(layout, d, lin, s0, keep)
    jacobians = [j * column_scale[: j.shape[1]] for j in (j_ef, j_rest)]
    return cut_laplace(theta, jacobians, _spans(layout), ("ef", JOINT))


MAX_DRAW_ROUNDS = 50


def _inside(batch, positive, admissible):
    """Which draws of ``batch`` (m, p) lie in the prior's support: > 0 where ``positive``,
    and ``admissible`` (a function of the draws the positivity keeps)."""
    inside = np.ones(len(batch), bool) if positive is None else np.all(
        (batch > 0) | ~np.asarray(positive, bool), axis=1)
    if admissible is not None:
        inside[inside] = np.asarray(admissible(batch[inside]), bool)
    return inside


def conditional_draws(lap: Laplace, given: slice, pool, n: int, seed: int, admissible=None,
                      positive=None, rest_pool=None):
    """``n`` draws (n, p) whose leading block ``given`` comes from ``pool`` (m, p_given), rows
    taken in order, in its natural coordinates, and whose later blocks come from the cut
    Laplace's conditional given it (the linearised refit as the given block moves, and its own
    covariance); and the fraction of proposals accepted.

    ``rest_pool`` (k, p_rest): draws of the later blocks given the leading block at its centre
    (SMC's, :mod:`fit.posterior.smc`), taken in turn (cyclically) in place of the conditional's
    Gaussian; the linearised refit still moves them with the given block.

    ``admissible``, ``positive`` as in :func:`draws`: a whole draw outside the prior's support
    is rejected and the pool's next row proposed, so the support truncates the joint
    distribution as it does the Laplace's."""
    pool = np.asarray(pool, float)
    rest = slice(given.stop, len(lap.centre))
    t = lap.transform
    rng = np.random.default_rng(seed)
    kept, proposed = [], 0
    while len(kept) < n and proposed < len(pool):
        values = pool[proposed:proposed + n - len(kept)]
        z_given = np.linalg.solve(t[given, given], (values - lap.centre[given]).T).T
        if rest_pool is None:
            spread = (rng.standard_normal((len(values), rest.stop - rest.start))
                      @ t[rest, rest].T)
        else:
            rows = np.arange(proposed, proposed + len(values)) % len(rest_pool)
            spread = np.asarray(rest_pool, float)[rows] - lap.centre[rest]
        proposed += len(values)
        batch = np.empty((len(values), len(lap.centre)))
        batch[:, given] = values
        batch[:, rest] = lap.centre[rest] + z_given @ t[rest, given].T + spread
        kept += list(batch[_inside(batch, positive, admissible)])
    if len(kept) < n:
        raise RuntimeError(
            f"only {len(kept)} of {proposed} draws inside the prior's support: {n} wanted; "
            "draw a larger pool"
        )
    return np.asarray(kept), n / proposed


def draws(lap: Laplace, n: int, seed: int, admissible=None, positive=None):
    """``n`` draws (n, p) of the Laplace approximation, seeded (numpy's default generator),
    and the fraction of proposals accepted.

    The Gaussian is truncated to the prior's support by rejection, proposals drawn in batches
    of n until n are accepted: ``positive`` (p,) bools, coordinates that must be > 0 (the
    positive coefficients); ``admissible`` a function of a batch of draws (m, p) -> (m,)
    bools, the rest of the support (the surrogate's convexity constraint).
    """
    rng = np.random.default_rng(seed)
    kept, proposed = [], 0
    for _ in range(MAX_DRAW_ROUNDS):
        batch = lap.centre + rng.standard_normal((n, len(lap.centre))) @ lap.transform.T
        proposed += n
        kept += list(batch[_inside(batch, positive, admissible)])
        if len(kept) >= n:
            return np.asarray(kept[:n]), n / proposed
    raise RuntimeError(
        f"the Laplace approximation put {len(kept)} of {proposed} draws inside the prior's "
        "support: it is no approximation of this posterior"
    )


TRUNCATED_SD_DRAWS = 4096


def truncated_sd(centre, chol, positive, seed: int = 0) -> np.ndarray:
    """The marginal sds of ``N(centre, chol chol^T)`` truncated to ``y_i > 0`` where
    ``positive``: the Laplace's sds as its draws have them, from
    :data:`TRUNCATED_SD_DRAWS` draws (Monte Carlo error about 1 %)."""
    lap = Laplace(np.asarray(centre), np.asarray(chol), None, {})
    y, _ = draws(lap, TRUNCATED_SD_DRAWS, seed, positive=positive)
    return y.std(axis=0, ddof=1)
