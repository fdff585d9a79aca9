"""Compute the posterior from the shipped fit and write it beside the surrogate.

``surrogates/<name>-posterior.npz`` holds the draws (numpy arrays only, read with
``allow_pickle=False``): ``theta`` (S, p) in the fit's raw coordinates with ``names`` (p,),
``centre`` and ``transform`` of the Laplace approximation, ``pump.<field>`` (S, ...) the
surrogate's fitted leaves per draw, ``scene.<field>`` (S,) the rig per draw in SI (column
diameter, cable friction, the bench's tube and viscoelasticity) and ``centre.<field>`` the
values they are centred on. ``<name>-posterior.json`` says how they were computed (blocks,
sigmas, priors, discrepancy, checks) and records the draws' and the weights' sha256; the
surrogate's own card records the draws' sha256 too (:func:`fit.fitting.record_posterior`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft import datasets
from cardiosoft.files import atomic_path, sha256
from cardiosoft.pump import POSTERIOR_FORMAT_VERSION, load, load_card
from cardiosoft.scene import load_scene
from cardiosoft.units import ml, mmHg
from fit import fitting, pipeline
from fit.posterior import blocks, laplace, nuts, smc

DRAWS = 256
SEED = 0
TABLE2_MEASUREMENT_ML = float(np.sqrt(np.mean(np.square([2.6, 1.2, 1.2]))))
"""The measurement sd (ml) of one Table II volume, which the paper does not give: its own
repeatability of a measured volume, the pooled SD of the static SV triplicates (Sec. III-D:
2.6, 1.2, 1.2 ml), 1.79 ml. Used only where a new measurement is predicted (the held-out
check)."""
RATE_BPM, RATE_SCALE_BPM = 30.0, 30.0
AFTERLOAD_SCALE_MMHG = 30.0
"""The discrepancy grows with the distance from the calibrated conditions, in units of the
bench's rate (30 bpm: a doubled rate is one unit away) and of the spacing of its heads (30
mmHg) beyond their range (30-90 mmHg)."""
SCENE = "bench-dynamic"


def bench_scene(surrogate=None):
    """The calibrated bench (:data:`SCENE`) of the surrogate ``surrogate`` (its card's name, or
    the artifact's path; None: the shipped default), with that pump's rig numbers (the scene's
    ``[calibration."<pump>"]`` tables)."""
    return load_scene(SCENE, pump=load_card(surrogate)["name"])


def posterior_paths(weights: Path) -> tuple[Path, Path]:
    """(draws .npz, card .json) beside the surrogate's weights."""
    stem = weights.with_suffix("").name + "-posterior"
    return weights.parent / f"{stem}.npz", weights.parent / f"{stem}.json"


def _scene_values(layout: blocks.Layout, theta: np.ndarray) -> dict[str, np.ndarray]:
    """The rig's scene numbers (SI) of each row of ``theta``."""
    rigs = jax.vmap(layout.rig)(jnp.asarray(theta))
    tube = np.exp(np.asarray(theta)[..., layout.blocks["bench"]])
    out = {
        "column_diameter": np.asarray(rigs.column_diameter),
        "cable_friction": np.asarray(rigs.cable_friction),
    }
    for k, field in enumerate(layout.bench_scene_fields):
        out[field] = tube[..., k]
    return out


def _far_scales(lin: laplace.Linearisation, layout, d: blocks.Data, static_loo):
    """s1 per type (SI). For the dynamic types the RMS over the bench's heads of what its
    dynamics add at 30 bpm, the whole correction a calibration at one rate absorbs (the
    paper's measured dynamic minus static SV; the model's dynamic minus quasi-static peak force
    and work). For the static SV, which no rate changes, the RMS of its leave-one-out errors:
    what a head left out of the calibration costs."""
    static = blocks.mechanics_outputs(layout, d)(jnp.asarray(layout.centre))
    rms = lambda a: float(np.sqrt(np.mean(np.square(a))))  # noqa: E731
    return {
        "static_sv": rms(static_loo),
        "dynamic_sv": rms(d.dynamic_sv - d.t.static_sv),
        "force": rms(np.asarray(lin.bench_outputs.peak_force) - np.asarray(static.peak_force)),
        "work": rms(np.asarray(lin.bench_outputs.mech_work) - np.asarray(static.mech_work)),
    }


def convexity_check(layout: blocks.Layout):
    """A batch of draws (m, p) -> whether each lies in the prior's support
    (:func:`fit.posterior.blocks.smallest_stiffness`: one volume per pull and pressure on the
    fit's grid; an artifact must pass it on a denser grid)."""
    smallest = jax.jit(jax.vmap(blocks.smallest_stiffness(layout)))
    return lambda theta: np.asarray(smallest(jnp.asarray(theta))) >= pipeline.CONVEXITY_MARGIN


class LinearisedFit(NamedTuple):
    """The shipped fit linearised at its optimum, and the discrepancy sized there."""

    model: object
    card: dict
    scene: object
    data: object
    d: blocks.Data
    layout: blocks.Layout
    lin: laplace.Linearisation
    sizing: laplace.Sizing
    s0_ef: float
    ef_loo: np.ndarray


def linearised_fit(path=None, progress=print) -> LinearisedFit:
    """Jacobians of every block at the fit's optimum (forward mode, the dynamic bench through
    diffrax) and the discrepancy's leave-one-out sizing: what the Laplace and the checks need."""
    model, card = load(path), load_card(path)
    rig = fitting.rig_from_card(card)
    scene = bench_scene(card["name"])
    data = datasets.load_paper_data()
    d = blocks.training_data(data)
    layout = blocks.Layout(model, rig, scene)
    theta = jnp.asarray(layout.centre)
    progress("EF block: leave-one-out on Table I (linearised refits)")
    s0_ef, ef_loo = laplace.size_ef(layout, d, theta)
    lin = laplace.linearise(layout, d, scene, theta, progress=progress)
    progress("discrepancy: leave-one-out of the bench rows, iterated to its fixed point")
    sizing = laplace.size_discrepancy(layout, d, lin, s0_ef)
    return LinearisedFit(model, card, scene, data, d, layout, lin, sizing, s0_ef, ef_loo)


def sample(layout: blocks.Layout, lap: laplace.Laplace, n: int, seed: int, ef_draws=None,
           joint_draws=None):
    """``n`` draws (n, p) in the fit's raw coordinates, truncated to the prior's support
    (positive coefficients, :func:`convexity_check`), and the fraction of proposals accepted.

    ``ef_draws``: (m >= n, p_ef) raw draws of the EF block from elsewhere (NUTS), in an order
    to take them in; the later blocks are drawn from ``lap``'s conditional given each
    (:func:`fit.posterior.laplace.conditional_draws`). ``joint_draws``: (k, p_joint) natural
    draws of the mechanics+bench block given the EF law at its centre (SMC's), in the
    conditional's place, moved with each EF draw by its linearised refit. Else every block
    from ``lap``."""
    convex = convexity_check(layout)
    positive = layout.positive
    ef = layout.blocks["ef"]

    def admissible(natural):  # of positive draws
        return convex(layout.raw(natural))

    if ef_draws is None and joint_draws is None:
        natural_draws, accepted = laplace.draws(lap, n, seed, admissible, positive)
        return layout.raw(natural_draws), accepted
    if ef_draws is None:  # the EF law's Laplace, a pool as large as the draws' rejection allows
        marginal = laplace.Laplace(lap.centre[ef], lap.transform[ef, ef], None, {})
        natural_ef, _ = laplace.draws(marginal, laplace.MAX_DRAW_ROUNDS * n, seed,
                                      positive=positive[ef])
    else:
        natural_ef = layout.natural(ef_draws, ef)
    natural_draws, accepted = laplace.conditional_draws(lap, ef, natural_ef, n, seed,
                                                        admissible, positive, joint_draws)
    return layout.raw(natural_draws), accepted


def shuffled(run: smc.SmcRun, seed: int) -> np.ndarray:
    """An SMC run's particles in a seeded random order, as :func:`sample` pairs them with the
    EF draws: resampling leaves copies side by side, and shuffled the pairing is random."""
    return np.random.default_rng(seed).permutation(run.draws)


def joint_raw(layout: blocks.Layout, natural) -> np.ndarray:
    """Full raw parameter vectors (n, p) from the mechanics+bench block's natural coordinates
    (n, p_joint), the EF law at the fit's optimum."""
    cols = laplace._spans(layout)[1]
    theta = np.tile(np.asarray(layout.centre, float), (len(natural), 1))
    theta[:, cols] = layout.raw(natural, cols)
    return theta


def joint_target(layout: blocks.Layout, d: blocks.Data, s0: blocks.Sigmas, scene, keep=None):
    """The mechanics+bench block's posterior given the EF law at the fit's optimum, as
    :mod:`fit.posterior.smc` takes it: (potential of a batch of the block's natural
    coordinates, one bench solve each over threads; the prior's support of such a batch).

    The bench's periodic state by Newton shooting: the orbit itself, where beat after beat stops
    at the scene's steady tolerance (the potentials differ by a median 5e-4 and at most 0.19
    over 64 Laplace draws), at about half the cost."""
    cols = laplace._spans(layout)[1]
    full = blocks.joint_residuals(layout, d, s0, scene, steady="shooting", keep=keep)
    potential = jax.jit(lambda theta: 0.5 * jnp.sum(full(theta) ** 2))
    convex = convexity_check(layout)
    positive = layout.positive[cols]

    def inside(natural):
        ok = np.all((natural > 0) | ~positive, axis=1)
        ok[ok] = convex(joint_raw(layout, natural[ok]))
        return ok

    return (lambda natural: smc.threaded(potential)(joint_raw(layout, natural))), inside


def nuts_ef(layout: blocks.Layout, d: blocks.Data, s0: blocks.Sigmas, lap: laplace.Laplace,
            seed: int, progress=print, *, chains=nuts.CHAINS, warmup=nuts.WARMUP,
            samples=nuts.SAMPLES) -> nuts.NutsCheck:
    """NUTS on the EF block (:mod:`fit.posterior.nuts`: its Laplace as the start and metric),
    the other blocks at the fit's optimum."""
    cols = layout.blocks["ef"]
    centre = layout.centre
    full = blocks.ef_residuals(layout, d, s0)
    natural_cov = lap.conditional["ef"]
    slope = layout.natural_slope(centre)[cols]
    positive = layout.positive[cols]
    progress(f"NUTS on the EF block ({chains} chains x ({warmup} warmup + {samples}))")
    return nuts.run(
        lambda x: full(jnp.asarray(centre).at[cols].set(x)), centre[cols],
        natural_cov / np.outer(slope, slope), layout.names[cols], positive=positive,
        chains=chains, warmup=warmup, samples=samples, seed=seed, progress=progress,
        compare=(lambda a: layout.natural(a, cols), lap.centre[cols],
                 laplace.truncated_sd(lap.centre[cols], np.linalg.cholesky(natural_cov),
                                      positive)),
    )


def draw_pool(run: nuts.NutsCheck, n: int, seed: int) -> np.ndarray:
    """Every chain's draws (m, p) of ``run``, first ``n`` evenly thinned ones, then the rest in
    a seeded random order: a pool to take draws from where the prior's support rejects some."""
    flat = run.draws.reshape(-1, run.draws.shape[-1])
    first = np.unique(np.linspace(0, len(flat) - 1, n).round().astype(int))
    rest = np.setdiff1d(np.arange(len(flat)), first)
    return flat[np.concatenate([first, np.random.default_rng(seed).permutation(rest)])]


def as_ensemble(layout: blocks.Layout, theta_draws: np.ndarray, card: dict):
    """Draws (S, p) in raw coordinates as :class:`cardiosoft.pump.PosteriorDraws` (the pump's
    fitted leaves with a leading axis, the rig per draw), ``card`` its posterior card."""
    from cardiosoft.pump import PosteriorDraws

    pumps = jax.vmap(layout.pump)(jnp.asarray(theta_draws))
    fields = (*pipeline.EF_FIELDS, *blocks.MECHANICS)  # as load_posterior: the drawn leaves only
    pump = eqx.tree_at(
        lambda m: [getattr(m, f) for f in fields],
        layout.fitted_model,
        [getattr(pumps, f) for f in fields],
    )
    centre = {f: float(v[0]) for f, v in _scene_values(layout, layout.centre[None]).items()}
    return PosteriorDraws(pump, _scene_values(layout, theta_draws), centre, card)


def discrepancy_card(fit: LinearisedFit) -> dict:
    """The posterior card's ``discrepancy`` entry (``{"discrepancy": ...}``): per output type
    s0 from the leave-one-out sizing, s1 far from the calibrated conditions, and the law."""
    d, sizing, layout, lin = fit.d, fit.sizing, fit.layout, fit.lin
    vu_ml = float(fit.model.unloaded_volume) / ml
    s0_ef, ef_loo = fit.s0_ef, fit.ef_loo
    s1 = _far_scales(lin, layout, d, sizing.loo["static_sv"])
    discrepancy = {
        "ef_volume": {"s0": s0_ef * vu_ml * ml, "loo_ml": (ef_loo * vu_ml).tolist()},
        **{
            k: {
                "s0": getattr(sizing.s0, k),
                "s1": s1[k],
                "loo": sizing.loo[k].tolist(),
                "measurement_var": sizing.measurement_var[k],
            }
            for k in laplace.TYPES
        },
        "units": "SI: m^3 (ef_volume, static_sv, dynamic_sv), N (force), J (work)",
        "static_sv_note": "a quasi-static pull has no rate: its d counts the afterload only",
        "sizing_rounds": sizing.rounds,
        "distance": {
            "rate_bpm": RATE_BPM,
            "rate_scale_bpm": RATE_SCALE_BPM,
            "afterload_mmHg": [float(np.min(d.t.afterload / mmHg)),
                               float(np.max(d.t.afterload / mmHg))],
            "afterload_scale_mmHg": AFTERLOAD_SCALE_MMHG,
        },
        "law": "sd^2 = s0^2 + s1^2 (1 - exp(-d^2)), d^2 = ((bpm - rate) / rate_scale)^2 + "
        "(distance of the head from the calibrated range / afterload_scale)^2; s0 from "
        "linearised leave-one-out errors (the mean squared error less the mean measurement "
        "variance), s1 the RMS of what the bench's dynamics add to the quasi-static values "
        "at 30 bpm",
    }
    return {"discrepancy": discrepancy}


EF_SAMPLERS = ("nuts", "laplace")
JOINT_SAMPLERS = ("smc", "laplace")


def compute(path=None, *, n_draws: int = DRAWS, seed: int = SEED, ef_sampler: str = "nuts",
            joint_sampler: str = "smc", progress=print):
    """The posterior of the surrogate at ``path`` (default: the shipped one) and the bench
    scene: ``(arrays for the .npz, the posterior card, the Layout, the Laplace)``.

    ``ef_sampler``: ``"nuts"`` draws the EF block with NUTS (its Laplace is not close to it:
    the card's ``nuts`` record) and raises if the chains did not mix; ``"laplace"`` draws it
    from the Laplace (seconds instead of minutes). ``joint_sampler``: ``"smc"`` draws the
    mechanics+bench block by tempered SMC given the EF law at its centre (a pilot run from its
    Laplace, then a run from the pilot's Gaussian, about 25 min on 2 cores: its Laplace is not
    close to it either, the card's ``smc`` and ``sbc_joint`` records), moved with each EF draw
    by the Laplace's linearised refit; ``"laplace"`` from the Laplace's conditional (seconds)."""
    if ef_sampler not in EF_SAMPLERS:
        raise ValueError(f"ef_sampler {ef_sampler!r}: one of {EF_SAMPLERS}")
    if joint_sampler not in JOINT_SAMPLERS:
        raise ValueError(f"joint_sampler {joint_sampler!r}: one of {JOINT_SAMPLERS}")
    fit = linearised_fit(path, progress)
    model, card, scene, data, d, layout, lin, sizing = (
        fit.model, fit.card, fit.scene, fit.data, fit.d, fit.layout, fit.lin, fit.sizing
    )
    s0_ef, ef_loo = fit.s0_ef, fit.ef_loo
    theta = jnp.asarray(layout.centre)
    vu_ml = float(model.unloaded_volume) / ml
    progress("Laplace: the cut posterior's Gauss-Newton covariance")
    lap = laplace.laplace(layout, d, lin, sizing.s0, theta)
    ef_draws, ef_run = None, None
    if ef_sampler == "nuts":
        ef_run = nuts_ef(layout, d, sizing.s0, lap, seed, progress)
        ef_draws = draw_pool(ef_run, n_draws, seed)
        if not ef_run.mixed:
            raise RuntimeError(
                "NUTS on the EF block did not mix (R-hat, bulk ESS or divergences: "
                f"{ef_run.record()['criteria']}); no posterior written"
            )
    joint_draws, joint_run = None, None
    if joint_sampler == "smc":
        cols = laplace._spans(layout)[1]
        progress(f"tempered SMC of the {laplace.JOINT} block ({n_draws} particles): a pilot "
                 "from the Laplace, then the draws from the pilot's Gaussian")
        potential, inside = joint_target(layout, d, sizing.s0, scene)
        joint_pilot, joint_run = smc.piloted(potential, lap.centre[cols],
                                             lap.transform[cols, cols], inside,
                                             particles=n_draws, seeds=(seed, seed + 1),
                                             progress=progress)
        joint_draws = shuffled(joint_run, seed)
    theta_draws, accepted = sample(layout, lap, n_draws, seed, ef_draws, joint_draws)
    pumps = jax.vmap(layout.pump)(jnp.asarray(theta_draws))
    arrays = {
        "names": np.asarray(layout.names),
        "theta": theta_draws,
        "centre": np.asarray(theta),
        "natural_centre": lap.centre,
        "transform": lap.transform,
        "positive": layout.positive,
    }
    for f in (*pipeline.EF_FIELDS, *blocks.MECHANICS):
        arrays[f"pump.{f}"] = np.asarray(getattr(pumps, f))
    for f, v in _scene_values(layout, theta_draws).items():
        arrays[f"scene.{f}"] = v
    for f, v in _scene_values(layout, np.asarray(theta)[None]).items():
        arrays[f"centre.{f}"] = np.asarray(v[0])
    mismatch = {
        f: (float(getattr(scene, f)), float(arrays[f"centre.{f}"]))
        for f in ("column_diameter", "cable_friction")
        if not np.isclose(float(getattr(scene, f)), float(arrays[f"centre.{f}"]), rtol=1e-4)
    }
    if mismatch:
        progress(
            f"warning: the scene {SCENE} does not hold the card's rig {mismatch} (scene, card): "
            "its draws are centred on the card's; update the scene"
        )
    laplace_sd = np.sqrt(np.diag(lap.covariance))  # natural coordinates, not truncated
    natural_draws = layout.natural(theta_draws)
    offset = laplace.mode_offset(layout, d, lin, sizing.s0)
    pcard = {
        "format_version": POSTERIOR_FORMAT_VERSION,
        "surrogate": card["name"],
        "weights_sha256": card["weights_sha256"],
        "data_sha256": data.hashes(),
        "scene": SCENE,
        "draws": n_draws,
        "seed": seed,
        "accepted": accepted,
        "support": "draws whose surrogate is convex enough in V (d2U/dV2 >= "
        f"{pipeline.CONVEXITY_MARGIN} E_u on the fit's grid) are kept: the Gaussian truncated "
        "to the prior's support by rejection; 'accepted' is the fraction kept",
        "method": (
            "the EF block by NUTS (fit.posterior.nuts: NumPyro, forward mode, the Laplace as "
            "start and metric; 'ef_nuts' below), evenly thinned to the draws (the chains' "
            "other draws, in a seeded order, replacing those the support rejects); "
            if ef_run is not None else "the EF block from its Laplace approximation; "
        ) + (
            "the mechanics+bench block by tempered SMC (fit.posterior.smc: from the Gaussian "
            "of a pilot run from its Laplace, given the EF law at the fit's optimum; 'joint_smc'"
            " below), each particle moved with"
            " its EF draw by the Laplace's linearised refit (fit.posterior.laplace); "
            if joint_run is not None else
            "the mechanics+bench block from the Gauss-Newton Laplace approximation of the cut "
            "posterior (fit.posterior.laplace) given each EF draw; "
        ) + (
            "the Laplace at the fit's optimum: the shipped weights, the card's rig and the "
            "bench scene's calibrated numbers; numpy's default generator. The posterior is a "
            "density over the natural coordinates (the positive coefficients themselves, the EF"
            " law's quadratic rate at Omega 0 and 6), its priors functions of them"
        ),
        "ef_nuts": None if ef_run is None else ef_run.record(),
        "joint_smc": None if joint_run is None else
        joint_run.record() | {"pilot": joint_pilot.record()},
        "independence": (
            "a cut posterior: Table I informs only the EF law; the mechanics and the bench's four"
            " are one block conditional on it (its linearised refit as the EF law moves), "
            "informed by the quasi-static and the dynamic bench and the FEM comparisons; no bench"
            " data move the EF law. The paper's mechanical work M (a dynamic measurement, P_a "
            "SV_dyn / e at 30 bpm) enters once, as the dynamic bench's work (the fit's stage 2 "
            "also fits the quasi-static work to it; here that would count it twice). Held and not"
            " sampled: the buckling step's onset and width (pump.BUCKLING_ONSET, chosen by leave-"
            "one-out over a grid), the three-fold boundary (its fold data) and the column's loss "
            "coefficient (1, Borda-Carnot). The two the fit holds (fold compliance kappa, column "
            "diameter) are sampled here under their priors."
        ),
        "parameters": {
            n: {
                "block": layout.block_of(i),
                "coordinate": "softplus(raw)" if layout.positive[i] else "raw",
                "centre": float(lap.centre[i]),
                "mean": float(np.mean(natural_draws[:, i])),
                "sd": float(np.std(natural_draws[:, i], ddof=1)),
                "laplace_sd": float(laplace_sd[i]),
                "draws_sd_raw": float(np.std(theta_draws[:, i], ddof=1)),
                "prior": list(blocks.PRIORS[n][:2]) if n in blocks.PRIORS else None,
                "prior_reason": blocks.PRIORS[n][2] if n in blocks.PRIORS else None,
            }
            for i, n in enumerate(layout.names)
        },
        "sigmas": {
            "table1": "sqrt(rounding^2 + s0_ef^2), rounding 0.1 % / sqrt(12) EF; the fit's "
            "soft-L1 residuals, its ridge and its longitudinal anchor scaled alike "
            f"(factor EF_SCALE / sigma = {pipeline.EF_SCALE / blocks.ef_sigma(s0_ef):.4g})",
            "static_sv_sd_ml": (d.static_sv_sd / ml).tolist(),
            "dynamic_sv_sd_ml": (d.dynamic_sv_sd / ml).tolist(),
            "peak_force_sd_N": d.peak_force_sd.tolist(),
            "mech_work_sd_J": d.mech_work_sd.tolist(),
            "mech_work_note": "M = P_a SV_dyn / e: the dynamic SV's relative SD and the "
            "efficiency's rounding (0.0005) in quadrature",
            "measured": "the paper's SDs (Sec. III-D) and the type's s0 in quadrature",
            "fem": "the fit's own scales (fit.pipeline): efficiencies 0.02, work ratios 10 %",
            "table2_measurement_ml": TABLE2_MEASUREMENT_ML,
            "table2_measurement_note": TABLE2_MEASUREMENT_NOTE,
        },
        "discrepancy": discrepancy_card(fit)["discrepancy"],
        "table1_loo_mae_ml": {
            "linearised": float(np.mean(np.abs(ef_loo)) * vu_ml),
            "refitted_by_the_fit": card.get("metrics", {}).get("table1_loo_mae_ml"),
        },
        "scene_mismatch": mismatch,
        "mode_offset_sd": {
            "note": "one Gauss-Newton step of the mechanics+bench block from the fit's optimum "
            "(the EF law held), in units of its conditional posterior sd (raw coordinates): "
            "the draws are centred on the shipped fit, whose weights are its own, not on this "
            "posterior's mode",
            **{
                n: float(v)
                for n, v in zip(layout.names[laplace._spans(layout)[1]], offset, strict=True)
            },
        },
    }
    return arrays, pcard, layout, lap


TABLE2_MEASUREMENT_NOTE = (
    "not in the paper: its own repeatability of a measured volume, the pooled SD of the static "
    "SV triplicates (2.6, 1.2, 1.2 ml); added only to predict a new measurement"
)


LAPLACE_RECORDS = ("nuts", "importance", "smc", "sbc_ef", "sbc_joint")
"""The posterior card's records that check the Laplace approximation and not the shipped
draws: ``--nuts``, ``--importance``, ``--smc`` and ``--sbc``'s. ``checks`` (``--check``),
``sobol`` (``--sobol``) and ``smc_pilot`` (``--smc-pilot``) are the shipped draws' and are not
among them."""


def carried_records(old_card: dict, old_arrays, arrays: dict) -> dict:
    """The :data:`LAPLACE_RECORDS` of ``old_card`` that a recomputation keeps: all of them where
    its Laplace (``centre``, ``natural_centre``, ``transform`` of the .npz) is the old one to
    1e-6 relative (the same fit, recomputed: what they checked has not moved), none else."""
    same = all(
        np.shape(old_arrays[k]) == np.shape(arrays[k])
        and np.allclose(old_arrays[k], arrays[k], rtol=1e-6, atol=1e-12)
        for k in ("centre", "natural_centre", "transform")
    )
    return {k: old_card[k] for k in LAPLACE_RECORDS if same and k in old_card}


def write(path, arrays: dict, pcard: dict) -> tuple[Path, Path]:
    """Write the draws and the posterior card beside the surrogate at ``path`` (default: the
    shipped one) and record the draws' sha256 in the surrogate's card."""
    from cardiosoft.pump import artifact_path

    weights = artifact_path(path)
    npz, js = posterior_paths(weights)
    with atomic_path(npz) as tmp:
        np.savez(tmp, **arrays)
        digest = sha256(tmp)
    pcard = {**pcard, "file": npz.name, "sha256": digest}
    with atomic_path(js) as tmp:
        tmp.write_text(json.dumps(pcard, indent=2) + "\n")
    fitting.record_posterior(weights, {"file": npz.name, "card": js.name, "sha256": digest})
    return npz, js


class Shipped:
    """The shipped posterior's blocks as NUTS and importance sampling see them: the layout, the
    Laplace (centre, natural centre, Cholesky factor) and each block's whitened residuals."""

    def __init__(self, path):
        from cardiosoft.pump import artifact_path, load_posterior

        self.posterior = post = load_posterior(path)
        self.npz, self.card_path = posterior_paths(artifact_path(path))
        with np.load(self.npz, allow_pickle=False) as f:
            self.centre, self.natural_centre = f["centre"], f["natural_centre"]
            self.transform = f["transform"]
        model, card = load(path), load_card(path)
        self.scene = scene = bench_scene(card["name"])
        self.layout = layout = blocks.Layout(model, fitting.rig_from_card(card), scene)
        if not np.allclose(layout.centre, self.centre, rtol=0, atol=1e-12):
            raise ValueError(f"{self.npz}: centred elsewhere than the current fit and scene; "
                             "recompute")
        self.data = datasets.load_paper_data()
        self.d = d = blocks.training_data(self.data)
        dis = post.card["discrepancy"]
        s0 = blocks.Sigmas(
            dis["ef_volume"]["s0"] / float(model.unloaded_volume),
            *(dis[k]["s0"] for k in ("static_sv", "dynamic_sv", "force", "work")),
        )
        self.s0 = s0
        self.spans = dict(zip(("ef", laplace.JOINT), laplace._spans(layout), strict=True))
        t = self.transform
        self.laplace = laplace.Laplace(
            self.natural_centre, t, t @ t.T,
            {block: t[cols, cols] @ t[cols, cols].T for block, cols in self.spans.items()},
        )
        self.residuals = {
            "ef": blocks.ef_residuals(layout, d, s0),
            laplace.JOINT: blocks.joint_residuals(layout, d, s0, scene),
        }

    def residual(self, block):
        """The block's residuals as a function of its own parameters (the others at the
        centre)."""
        cols, full = self.spans[block], self.residuals[block]
        return lambda x: full(jnp.asarray(self.centre).at[cols].set(x))

    def potential(self, block):
        """Full raw vectors (n, p) -> the block's potentials ``1/2 |r|^2`` (n,), one compiled,
        batched call (a failed solve gives a value that is not finite)."""
        full = self.residuals[block]
        return jax.jit(jax.vmap(lambda t: 0.5 * jnp.sum(full(t) ** 2)))

    def raw_with(self, block, natural):
        """Full raw vectors (n, p) from ``block``'s natural coordinates (n, p_block), the rest
        at the Laplace's natural centre."""
        full = np.tile(self.natural_centre, (len(natural), 1))
        full[:, self.spans[block]] = natural
        return self.layout.raw(full)

    def theta_with(self, block, x):
        """Full raw parameter vectors (n, p): the centre with ``block``'s columns set to x."""
        theta = np.tile(self.centre, (len(x), 1))
        theta[:, self.spans[block]] = x
        return theta
