"""Predictive bands: the posterior's draws carried through one batched solve, plus the model
discrepancy (DESIGN.md section 3.6).

    import cardiosoft as cs
    from cardiosoft.posterior import ensemble_run, predictive_bands

    posterior = cs.pump.load_posterior()
    ens = ensemble_run(cs.load_scene("bench-dynamic").replace(bpm=60), posterior)
    bands = predictive_bands(ens, posterior.card)    # per member: {metric: Band}

A prediction is ``y = f(theta, x) + delta(x)``: ``theta`` the posterior's draws (the surrogate's
fitted parameters and the rig, :func:`cardiosoft.pump.load_posterior`), carried through one
compiled, batched solve (:func:`cardiosoft.batch.solve_beats` with an ensemble); ``delta`` the
model discrepancy of the metric's output type (static SV and dynamic SV in ml, force in N,
work in J), a normal error
whose sd grows away from the calibrated conditions:

``sd^2 = s0^2 + s1^2 (1 - exp(-d^2))``, ``d^2 = ((bpm - 30) / 30)^2 + (a / 30 mmHg)^2``

with ``a`` the afterload's distance from the calibrated heads' range (30-90 mmHg; a Windkessel
afterload is far from every calibrated condition: ``d`` infinite); the static SV's ``d`` has
no rate term (a quasi-static pull has no rate). ``s0``, ``s1`` and the scales
are the posterior card's (``discrepancy``; ``python -m fit.posterior`` sizes them). The band is
the central 95 % of the samples, sampled, not linearised. Measurement noise is not in it: it
predicts the quantity, not one more measurement of it.

Efficiency (``P_a SV / M``), EF (``SV / EDV``, the SV's discrepancy taken in the filling:
``SV / (SV + ESV)``) and cardiac output (``SV x rate``) take the discrepancy of their SV
and work (an SV sample below zero is zero); the pump's SV (the paper's dynamic SV on the
bench), the efficiency, EF and output share one SV discrepancy per sample, the static SV has
its own.

A draw whose solve fails or misses the steady state, or whose pump empties below zero volume
(ESV < 0: its surrogate extrapolated to a stroke no pump delivers), is left out of the band and
counted (``Band.failed``); nothing is dropped silently.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from cardiosoft.units import ml, mmHg

__all__ = [
    "BAND",
    "Band",
    "EnsembleRun",
    "band",
    "discrepancy_sd",
    "ensemble_run",
    "first_draws",
    "predictive_bands",
]

BAND = 0.95
"""The central probability of a printed band."""
ENSEMBLE_MAX_BEATS = 300
"""Beats an ensemble member may take to its steady state. The draws of the shell's relaxation
time reach tens of seconds (its posterior is its prior, log sd 1.6), whose transients outlast a
scene's own ``max_beats``: on the shipped posterior at 30 bpm, 63 of 256 draws were not steady
after 40 beats; at 60 bpm, 5 of 64 after 150 and none after 300 (measured 2026-12-03; Newton
shooting reached them too, at 10-25 times the cost)."""
NOISE_SAMPLES = 16
"""Discrepancy samples per draw (seeded): the band's quantiles are taken over draws x these."""
SCENE_MATCH_RTOL = 1e-3
"""A scene number within this (relative) of the posterior's centre is the calibrated bench's
(scene files round to 4-5 digits), and gets the draws."""
METRICS = {
    # summary-record key: (discrepancy type, user unit) of cardiosoft.results.summary_records
    "static_sv_ml": ("static_sv", ml),
    "dynamic_sv_ml": ("dynamic_sv", ml),
    "peak_force_N": ("force", 1.0),
    "mech_work_J": ("work", 1.0),
    "efficiency": (None, 1.0),
    "ef": (None, 1.0),
    "cardiac_output_l_min": (None, 1.0),
}
"""The metrics that get a band, as ``simulate`` names them."""


class EnsembleRun(NamedTuple):
    """The draws' values of each metric, ``(S, M)`` in user units (:data:`METRICS`), whether
    each (draw, member) is usable, and the members' rate and afterload."""

    values: dict
    ok: np.ndarray
    bpm: np.ndarray  # per member (or one for all)
    afterload_mmHg: np.ndarray | None
    messages: list  # per member: the first failed draw's message, or ""


class Band(NamedTuple):
    """A metric's 95 % predictive band (user units): ``low``/``high`` with the discrepancy,
    ``parameter_low``/``parameter_high`` from the draws alone; ``failed`` draws left out of
    ``draws``; the predictive samples' ``median`` and middle half (``quartiles``): off the
    calibrated conditions the fit's optimum need not be typical of them."""

    low: float
    high: float
    parameter_low: float
    parameter_high: float
    failed: int
    draws: int
    median: float = math.nan
    quartiles: tuple = (math.nan, math.nan)


def discrepancy_sd(card: dict, kind: str, bpm: float, afterload_mmHg: float | None) -> float:
    """The discrepancy's sd (SI) of output type ``kind`` ("static_sv", "dynamic_sv", "force",
    "work") at a rate
    (bpm) and column head (mmHg; None for an afterload that is not the bench's column)."""
    d = card["discrepancy"]
    where = d["distance"]
    # a quasi-static stroke has no rate
    rate = 0.0 if kind == "static_sv" else (bpm - where["rate_bpm"]) / where["rate_scale_bpm"]
    if afterload_mmHg is None or not math.isfinite(afterload_mmHg):
        return float(np.hypot(d[kind]["s0"], d[kind]["s1"]))
    lo, hi = where["afterload_mmHg"]
    excess = max(0.0, lo - afterload_mmHg, afterload_mmHg - hi) / where["afterload_scale_mmHg"]
    grow = -math.expm1(-(rate**2 + excess**2))
    return float(math.sqrt(d[kind]["s0"] ** 2 + d[kind]["s1"] ** 2 * grow))


def first_draws(posterior, n: int):
    """The posterior's first ``n`` draws (they are independent: a smaller sample of the same
    posterior), as :class:`cardiosoft.pump.PosteriorDraws`."""
    import equinox as eqx
    import jax

    from cardiosoft.batch import ensemble_axes

    total = len(next(iter(posterior.scene_draws.values())))
    if not 2 <= n <= total:
        raise ValueError(f"draws = {n}: allowed 2 to {total} (the posterior's draws)")
    axes = ensemble_axes(posterior.pump)
    drawn = jax.tree_util.tree_map(lambda a, ax: a[:n] if ax == 0 else a, posterior.pump, axes,
                                   is_leaf=lambda x: x is None)
    pump = eqx.combine(drawn)
    scene = {k: v[:n] for k, v in posterior.scene_draws.items()}
    return posterior._replace(pump=pump, scene_draws=scene)


def _scene_draws(scene, posterior) -> dict:
    """The rig's draws for the numbers ``scene`` shares with the calibrated bench: a scene
    whose value differs from the posterior's centre keeps its own (it is not the paper's
    rig, and its value is taken as known)."""
    out = {}
    for field, values in posterior.scene_draws.items():
        centre = posterior.scene_centre[field]
        if math.isclose(float(getattr(scene, field)), centre, rel_tol=SCENE_MATCH_RTOL):
            out[field] = values
    return out


def ensemble_run(
    scene, posterior, *, omega=None, shortening=None, afterload=None, bpm=None, beats=None,
    steady="beats", config=None,
) -> EnsembleRun:
    """Solve every draw of ``posterior`` (:class:`cardiosoft.pump.PosteriorDraws`) at every
    member of ``scene`` (its afterloads; or ``omega``, ``shortening``, ``afterload`` (Pa),
    ``bpm`` as members, broadcast as in :func:`cardiosoft.batch.solve_beats`) in one batched
    call, and the quasi-static strokes of a water-column scene likewise. ``beats``, ``steady`` and
    ``config`` as in :func:`cardiosoft.batch.solve_beats`; beat after beat, the draws get at
    least :data:`ENSEMBLE_MAX_BEATS` beats to reach their steady state."""
    # an open-loop, dynamic scene: batch.solve_beats refuses any other by name (the tools check
    # first: scene_tools' "uncertainty" and "bench_bands", which sit above this module)
    from cardiosoft.batch import solve_beats, solve_static

    draws = _scene_draws(scene, posterior)
    scene = scene.replace(max_beats=max(scene.max_beats, ENSEMBLE_MAX_BEATS))
    members = dict(omega=omega, shortening=shortening, afterload=afterload)
    out = solve_beats(
        scene, save="metrics", pump=posterior.pump, scene_draws=draws, beats=beats,
        steady=steady, config=config, bpm=bpm, **members,
    )
    m = out.metrics
    solved = np.asarray(out.succeeded) & (np.asarray(out.steady) | (beats is not None))
    # a draw whose pump empties below zero volume delivers a stroke no pump can: outside the
    # model (its surrogate extrapolates to V < 0), not a number to put in a band
    esv_ml = np.asarray(m.esv) / ml
    ok = solved & ~(esv_ml < 0.0)
    values = {
        "dynamic_sv_ml": np.asarray(m.stroke_volume) / ml,
        "peak_force_N": np.asarray(m.peak_force),
        "mech_work_J": np.asarray(m.mech_work),
        "efficiency": np.asarray(m.efficiency),
        "ef": np.asarray(m.ejection_fraction),
        "cardiac_output_l_min": np.asarray(m.cardiac_output) / ml * 60 / 1000,
        "edv_ml": np.asarray(m.edv) / ml,  # for EF's discrepancy; no band of its own
    }
    heads = None
    if scene.afterload.has_heads:
        static = solve_static(scene, pump=posterior.pump, scene_draws=draws, **members)
        values["static_sv_ml"] = np.asarray(static.stroke_volume) / ml
        heads = np.asarray(out.members["afterload"]) / mmHg
    messages = []
    for i in range(ok.shape[1]):
        bad = np.flatnonzero(~ok[:, i])
        if not bad.size:
            messages.append("")
        elif solved[bad[0], i]:
            messages.append(f"the pump's volume falls to {esv_ml[bad[0], i]:.1f} ml, below zero: "
                            "the draw is outside the model")
        else:
            messages.append(out.message((int(bad[0]), i)))
    return EnsembleRun(values, ok, np.asarray(out.members["bpm"], float), heads, messages)


def predictive_bands(ens: EnsembleRun, card: dict, *, seed: int = 0) -> list[dict]:
    """Per member, ``{metric: Band}`` for each metric of :data:`METRICS` the run has (module
    docstring); the discrepancy is sampled (``NOISE_SAMPLES`` per draw, ``seed``)."""
    rng = np.random.default_rng(seed)
    n_draws, n_members = ens.ok.shape
    out = []
    rates = np.broadcast_to(np.asarray(ens.bpm, float), (n_members,))
    with np.errstate(invalid="ignore"):  # a failed draw's NaN: left out of its band
        for i in range(n_members):
            head = None if ens.afterload_mmHg is None else float(ens.afterload_mmHg[i])
            ok = ens.ok[:, i]
            kinds = ("static_sv", "dynamic_sv", "force", "work")
            z = {k: rng.standard_normal((n_draws, NOISE_SAMPLES)) for k in kinds}
            sd = {k: discrepancy_sd(card, k, float(rates[i]), head) for k in kinds}
            v = {k: a[:, i, None] for k, a in ens.values.items()}
            # the pump's SV and what follows from it; a stroke volume is not negative
            sv = np.maximum(v["dynamic_sv_ml"] + z["dynamic_sv"] * sd["dynamic_sv"] / ml, 0.0)
            relative_sv = sv / v["dynamic_sv_ml"]
            work = v["mech_work_J"] + z["work"] * sd["work"]
            esv = v["edv_ml"] - v["dynamic_sv_ml"]
            sampled = {
                "dynamic_sv_ml": sv,
                "peak_force_N": v["peak_force_N"] + z["force"] * sd["force"],
                "mech_work_J": work,
                "efficiency": v["efficiency"] * relative_sv * v["mech_work_J"] / work,
                # the SV's discrepancy taken in the filling (EDV), the folded ESV the pump's own:
                # EF = SV / (SV + ESV) stays in [0, 1)
                "ef": sv / (sv + esv),
                "cardiac_output_l_min": v["cardiac_output_l_min"] * relative_sv,
            }
            if "static_sv_ml" in v:
                sampled["static_sv_ml"] = v["static_sv_ml"] + z["static_sv"] * sd["static_sv"] / ml
            failed = int((~ok).sum())
            out.append(
                {key: band(x[ok], ens.values[key][ok, i], failed) for key, x in sampled.items()}
            )
    return out


def band(samples, draws, failed: int) -> Band:
    """The :data:`BAND` band of ``samples`` (the predictive ones; their median and quartiles
    too) and of ``draws`` (the draws' own values), the ``failed`` draws left out of both."""
    if samples.size == 0:
        return Band(math.nan, math.nan, math.nan, math.nan, failed, 0)
    lo_q, hi_q = 0.5 - BAND / 2, 0.5 + BAND / 2
    lo, q1, median, q3, hi = (float(q) for q in np.quantile(samples, [lo_q, 0.25, 0.5, 0.75, hi_q]))
    draws_lo, draws_hi = (float(q) for q in np.quantile(draws, [lo_q, hi_q]))
    return Band(lo, hi, draws_lo, draws_hi, failed, int(draws.size), median, (q1, q3))
