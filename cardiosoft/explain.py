"""What dominates a prediction's uncertainty, and what to measure next (issue #24, item 4).

    python -m cardiosoft.simulate --bpm 60 --uncertainty --explain

Linearised over the posterior, from its draws: every shipped draw ``theta_s`` (the fit's raw
coordinates, the posterior's ``.npz``) is solved at the scene and at the candidate measurements
(one batched solve each, :func:`cardiosoft.posterior.ensemble_run`), and the draws' joint
covariance ``C`` of parameters, predictions ``y`` and measurements ``m`` stands for the
posterior's (the ensemble Kalman filter's linearisation; Evensen 2009, ch. 9):

- the *share* of a prediction's variance that parameter i carries: the fraction removed by
  knowing theta_i exactly, ``C_yi^2 / (C_ii C_yy)``, the squared correlation over the draws
  (correlated parameters' shares need not sum to one);
- the sd *after a new measurement* ``m`` with sd ``sigma_m``: ``sqrt(C_yy - C_ym^2 / (C_mm +
  sigma_m^2))``.

Both are the Gaussian formulas (:func:`variance_shares`, :func:`sd_after`) with the draws'
covariances in place of a Jacobian's: a derivative at the fit's optimum does not describe the
draws' spread off the paper's rate. Measured 2026-12-04 at 60 bpm (256 shipped draws): one
``jax.jacfwd`` at the optimum gave the dynamic SV an sd of 38-93 ml with the Laplace's
covariance and 77-104 ml with the draws', where the draws' own SV sd is 18-25 ml; it gave the
swelling resistance 52-77 % of the peak force's variance, where its squared correlation with
the force over the draws is below 0.02; and it had a ruler on the tube cut the efficiency's sd
at 60 mmHg from 0.12 to 0.035, where over the draws it cuts 0.127 to 0.116. Where a prediction
depends nonlinearly on a measurement, the sd after is the error of the best *linear* estimate
from it, whose variance is at least the expected variance the measurement would leave: it errs
towards too little gain.

Both describe the parameters' part of the band (``<metric>_band_parameters``), not the model
discrepancy, which no measurement of theta shrinks. The candidate measurements are taken on the
paper's bench: the tube's length with a ruler, the column's bore with a caliper (neither is in
the paper), the dynamic SV and the peak force at 60 bpm (60 mmHg), and a static compliance
test of the shell (its volume at 60 mmHg with no pull). A share carries the Monte Carlo error
of a squared correlation over S draws (:data:`MIN_DRAWS`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import numpy as np

from cardiosoft.ensemble import ensemble_axes
from cardiosoft.units import ml, mm, mmHg

__all__ = [
    "MIN_DRAWS", "Explanation", "explain", "linear_over_draws", "sd_after", "variance_shares",
]

RULER_MM = 10.0
"""The tube's length measured with a ruler, fittings included: +- 10 mm (one sd)."""
CALIPER_MM = 1.0
"""The column's bore measured with a caliper, the tube's wall and its roundness included: +- 1
mm (one sd)."""
COMPLIANCE_PRESSURE_MMHG = 60.0
SHELL_VOLUME_SD_ML = 1.79
"""A static volume measured as the paper measured its static SVs: their pooled SD (Sec.
III-D, 2.6, 1.2, 1.2 ml), as the posterior card's Table II measurement."""
MEASURE_BPM, MEASURE_HEAD_MMHG = 60.0, 60.0
MIN_DRAWS = 64
"""Fewest usable draws to correlate. A share's Monte Carlo sd, ``2 rho (1 - rho^2) / sqrt(S)``,
peaks at rho^2 = 1/3 at 0.77 / sqrt(S): 0.10 at 64 draws, 0.05 at the 256 shipped."""
PREDICTIONS = {  # summary key of cardiosoft.posterior's ensemble: label
    "dynamic_sv_ml": "SV [ml]",
    "peak_force_N": "peak force [N]",
    "efficiency": "efficiency",
    "cardiac_output_l_min": "CO [l/min]",
}


class Explanation(NamedTuple):
    """Per prediction (label): its sd over the draws, the variance shares, and the sd after
    each candidate measurement (user units); ``draws``: the fewest draws any prediction was
    correlated over, of ``total``."""

    names: tuple
    labels: list
    sd: np.ndarray
    shares: np.ndarray  # (predictions, parameters)
    after: dict  # candidate -> (predictions,) sd after measuring it
    candidates: dict  # candidate -> sd of the measurement, in words
    draws: int
    total: int

    def table(self, top: int = 3) -> str:
        error = 0.77 / math.sqrt(self.draws)  # a share's Monte Carlo sd, at most (MIN_DRAWS)
        lines = [f"what dominates each prediction's parameter uncertainty (share of its "
                 f"variance removed by knowing the parameter, linear over at least {self.draws} "
                 f"of {self.total} posterior draws, +- up to {error:.2f}):"]
        for k, label in enumerate(self.labels):
            order = np.argsort(self.shares[k])[::-1][:top]
            parts = ", ".join(f"{self.names[i]} {100 * self.shares[k, i]:.1f} %" for i in order)
            lines.append(f"  {label:38s} sd {self.sd[k]:.3g}: {parts}")
        lines.append("sd after one more measurement (" + "; ".join(
            f"{c}: {why}" for c, why in self.candidates.items()) + "):")
        head = f"  {'prediction':38s} {'now':>8s}" + "".join(f" {c:>16s}" for c in self.after)
        lines.append(head)
        for k, label in enumerate(self.labels):
            lines.append(f"  {label:38s} {self.sd[k]:8.3g}" + "".join(
                f" {self.after[c][k]:16.3g}" for c in self.after))
        return "\n".join(lines)

    def record(self) -> dict:
        return {
            "method": "the posterior draws' joint covariance of parameters, predictions and "
            "measurements (ensemble Kalman linearisation)",
            "fewest_draws": self.draws,
            "total_draws": self.total,
            "predictions": {
                label: {
                    "sd_parameters": float(self.sd[k]),
                    "shares": {n: float(self.shares[k, i]) for i, n in enumerate(self.names)},
                    "sd_after": {c: float(v[k]) for c, v in self.after.items()},
                }
                for k, label in enumerate(self.labels)
            },
            "candidates": self.candidates,
        }


def explain(scene, posterior, progress=print) -> Explanation:
    """The variance shares of ``scene``'s SV, peak force, efficiency (and, off the bench,
    cardiac output) per member, and their sd after each candidate measurement (module
    docstring). ``posterior``: :class:`cardiosoft.pump.PosteriorDraws`, all of whose draws are
    solved (at least :data:`MIN_DRAWS` usable)."""
    from cardiosoft.posterior import discrepancy_sd, ensemble_run
    from cardiosoft.pump import artifact_dir
    from cardiosoft.scene import load_scene

    size = len(next(iter(posterior.scene_draws.values())))
    with np.load(artifact_dir() / posterior.card["file"], allow_pickle=False) as f:
        names = tuple(str(n) for n in f["names"])
        theta = np.asarray(f["theta"][:size], float)  # the draws' raw coordinates, in order
    progress(f"explain: {size} posterior draws at the scene, in one batched solve ...")
    ens = ensemble_run(scene, posterior)
    progress(f"explain: {size} draws at the candidate measurements (the bench at "
             f"{MEASURE_BPM:g} bpm, {MEASURE_HEAD_MMHG:g} mmHg; the shell at rest) ...")
    bench = load_scene("bench-dynamic").replace(
        bpm=MEASURE_BPM, afterloads=(MEASURE_HEAD_MMHG * mmHg,)
    )
    measured = ensemble_run(bench, posterior)
    shell = jax.vmap(
        lambda p: p.volume(COMPLIANCE_PRESSURE_MMHG * mmHg, 0.0, 4.0),
        in_axes=(ensemble_axes(posterior.pump),),
    )(posterior.pump)

    labels, columns, settled = [], [], []
    heads = scene.afterloads if scene.afterload.has_heads else [None]
    for key, kind in PREDICTIONS.items():
        if key == "cardiac_output_l_min" and scene.afterload.has_heads:
            continue  # the bench's output is its SV at the rate: nothing new
        for i, head in enumerate(heads):
            where = f"{head / mmHg:.0f} mmHg" if head is not None else scene.name
            labels.append(f"{kind} at {scene.bpm:g} bpm, {where}")
            columns.append(ens.values[key][:, i])
            settled.append(ens.ok[:, i])
    length, bore = names.index("bench.log_tube_length"), names.index("log_column_diameter")
    candidates = {  # the measured quantity per draw, in the unit of its sd
        "tube length": theta[:, length],
        "column bore": theta[:, bore],
        "SV at 60 bpm": measured.values["dynamic_sv_ml"][:, 0],
        "shell compliance": np.asarray(shell) / ml,
        "force at 60 bpm": measured.values["peak_force_N"][:, 0],
    }
    sv_sd = math.hypot(2.0, discrepancy_sd(posterior.card, "dynamic_sv", MEASURE_BPM,
                                           MEASURE_HEAD_MMHG) / ml)
    force_sd = math.hypot(3.0, discrepancy_sd(posterior.card, "force", MEASURE_BPM,
                                              MEASURE_HEAD_MMHG))
    # a length's sd in the log coordinate: relative to the draws' median length
    noise = {
        "tube length": RULER_MM * mm / float(np.exp(np.median(theta[:, length]))),
        "column bore": CALIPER_MM * mm / float(np.exp(np.median(theta[:, bore]))),
        "SV at 60 bpm": sv_sd,
        "shell compliance": SHELL_VOLUME_SD_ML,
        "force at 60 bpm": force_sd,
    }
    why = {
        "tube length": f"ruler +- {RULER_MM:g} mm",
        "column bore": f"caliper +- {CALIPER_MM:g} mm",
        "SV at 60 bpm": f"+- {sv_sd:.1f} ml (2 ml and the discrepancy at 60 bpm)",
        "shell compliance": f"V at {COMPLIANCE_PRESSURE_MMHG:g} mmHg, no pull, "
        f"+- {SHELL_VOLUME_SD_ML} ml",
        "force at 60 bpm": f"+- {force_sd:.1f} N (3 N and the discrepancy at 60 bpm)",
    }

    measurable = {"SV at 60 bpm": measured.ok[:, 0], "force at 60 bpm": measured.ok[:, 0]}
    sd, shares, after, fewest = linear_over_draws(
        theta, dict(zip(labels, columns, strict=True)), settled, candidates, measurable, noise
    )
    return Explanation(names, labels, sd, shares, after, why, fewest, size)


def linear_over_draws(theta, predictions: dict, settled: list, candidates: dict,
                      measurable: dict, noise: dict):
    """The module docstring's linear answer from draws: ``theta`` (S, p), each prediction's
    values (label -> (S,)) and which draws settled for it (``settled``, (S,) bools per
    prediction), each candidate measurement's values (S,), where it settled (``measurable``;
    everywhere if absent) and its sd (``noise``, the values' unit). Returns (sd (n,), shares
    (n, p), {candidate: sd after (n,)}, the fewest draws a prediction was taken over).

    Each prediction is taken over the draws usable for it, as its band is; a measurement's gain
    (the fraction of that variance it removes) over the draws usable for both."""
    size, p = theta.shape
    sd = np.empty(len(predictions))
    shares = np.empty((len(predictions), p))
    after = {c: np.empty(len(predictions)) for c in candidates}
    fewest = size
    for k, ((label, y), ok) in enumerate(zip(predictions.items(), settled, strict=True)):
        rows = ok & np.isfinite(y)
        fewest = min(fewest, int(rows.sum()))
        if rows.sum() < MIN_DRAWS:
            raise ValueError(
                f"{label}: {rows.sum()} of {size} posterior draws solved and settled; at "
                f"least {MIN_DRAWS} are needed to correlate them with the parameters"
            )
        cov = np.cov(np.column_stack([theta[rows], y[rows]]), rowvar=False)
        variance, share = variance_shares(np.eye(p + 1)[p], cov)
        sd[k], shares[k] = np.sqrt(variance[0]), share[0, :p]
        for c, m in candidates.items():
            both = rows & measurable.get(c, True) & np.isfinite(m)
            pair = np.cov(y[both], m[both])
            kept = sd_after([1.0, 0.0], pair, np.array([0.0, 1.0]), noise[c])[0]
            after[c][k] = sd[k] * kept / np.sqrt(pair[0, 0])
    return sd, shares, after, fewest


def variance_shares(g, cov):
    """(variance ``g^T Sigma g`` per row of ``g``, shares (rows, coordinates)): the fraction of
    each row's variance removed by knowing coordinate i exactly (module docstring)."""
    g, cov = np.atleast_2d(g), np.asarray(cov)
    variance = np.einsum("kp,pq,kq->k", g, cov, g)
    return variance, (g @ cov) ** 2 / (np.diag(cov)[None, :] * variance[:, None])


def sd_after(g, cov, h, sd):
    """The sd of each row of ``g`` after one measurement of sensitivity ``h`` and sd ``sd``:
    ``sqrt(g^T (Sigma^-1 + h h^T / sd^2)^-1 g)``, written as the rank-one (Kalman) update of
    Sigma, which needs no inverse of a near-singular Sigma."""
    g, cov, h = np.atleast_2d(g), np.asarray(cov), np.asarray(h)
    gain = cov @ h / (h @ cov @ h + sd**2)
    post = cov - np.outer(gain, h @ cov)
    return np.sqrt(np.einsum("kp,pq,kq->k", g, post, g))
