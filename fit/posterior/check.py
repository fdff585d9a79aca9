"""Held-out checks of the predictive bands, from the shipped posterior.

- **Table II** (experiments, never fitted): each of the nine contracted volumes
  ``V_u (1 - EF)`` against its 95 % predictive band: the EF law's draws, the EF discrepancy
  (s0 from Table I's leave-one-out) and the measurement's sd (a new measurement is predicted;
  the paper gives none, the card states the one used). Counted inside, with a Wilson interval,
  the mean interval score (Gneiting and Raftery 2007: the width plus 2/alpha times any miss,
  so that a band that covers by being wide does not pass for a good one) and the mean width,
  beside the paper's own FEM error.
- **The 30-bpm bench**: the paper's dynamic SVs (fitted: in-sample) and peak forces (not
  fitted) against the bands of the posterior's draws solved at 30 bpm, the discrepancy and the
  paper's SDs; and the model's own bands of every metric there (no measurement's sd), which
  the credibility report prints beside each comparison.
- **Table I** (the FEM the EF law is fitted to), for the credibility report: its contracted
  volumes against the draws and the EF discrepancy, with no measurement's sd (no bound).
"""

from __future__ import annotations

import json
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.units import ml

ALPHA = 0.05
NOISE_SAMPLES = 16  # discrepancy and measurement samples per draw (seeded)


def wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson's 95 % score interval of a proportion k / n."""
    p = k / n
    centre = (p + z**2 / (2 * n)) / (1 + z**2 / n)
    half = z * math.sqrt(p * (1 - p) / n + z**2 / (4 * n**2)) / (1 + z**2 / n)
    return centre - half, centre + half


def interval_score(low, high, y, alpha: float = ALPHA):
    """Gneiting and Raftery's interval score of the central (1 - alpha) band [low, high]."""
    low, high, y = (np.asarray(a, float) for a in (low, high, y))
    return (high - low) + 2 / alpha * (
        np.maximum(low - y, 0.0) + np.maximum(y - high, 0.0)
    )


class Coverage(NamedTuple):
    """Observed values against their bands (one unit)."""

    labels: list
    observed: np.ndarray
    best: np.ndarray
    low: np.ndarray
    high: np.ndarray

    @property
    def inside(self) -> np.ndarray:
        return (self.low <= self.observed) & (self.observed <= self.high)

    def summary(self) -> dict:
        k, n = int(self.inside.sum()), len(self.observed)
        lo, hi = wilson(k, n)
        return {
            "inside": k,
            "of": n,
            "wilson_95": [lo, hi],
            "mean_interval_score": float(np.mean(interval_score(self.low, self.high,
                                                                self.observed))),
            "mean_width": float(np.mean(self.high - self.low)),
        }


def _quantiles(samples):
    return np.quantile(samples, [ALPHA / 2, 1 - ALPHA / 2], axis=0)


def ensemble_map(fn, pump):
    """``fn(pump)`` for each draw of an ensemble pump (``jax.vmap`` over its drawn leaves)."""
    import equinox as eqx

    from cardiosoft.batch import ensemble_axes

    return eqx.filter_jit(jax.vmap(fn, in_axes=(ensemble_axes(pump),)))(pump)


def _zero_pressure(posterior, table, sd_ml: float, seed: int) -> Coverage:
    """A table of zero-pressure EFs (its columns omega, shortening, ef_percent) as contracted
    volumes ``V_u (1 - EF)`` (ml) against their 95 % bands: the EF law's draws and ``sd_ml``
    of normal noise (seeded)."""
    from cardiosoft.pump import load
    from fit.pipeline import zero_pressure_ef

    omega = jnp.asarray(table["omega"], float)
    c = jnp.asarray(table["shortening"], float)
    vu = float(load().unloaded_volume) / ml
    ef = np.asarray(ensemble_map(lambda p: zero_pressure_ef(p, omega, c), posterior.pump))
    best = vu * (1 - np.asarray(zero_pressure_ef(load(), omega, c)))
    volume = vu * (1 - ef)  # (S, cells)
    rng = np.random.default_rng(seed)
    samples = volume[:, None, :] + sd_ml * rng.standard_normal(
        (*volume.shape[:1], NOISE_SAMPLES, volume.shape[1])
    )
    low, high = _quantiles(samples.reshape(-1, volume.shape[1]))
    observed = vu * (1 - np.asarray(table["ef_percent"], float) / 100)
    labels = [f"Omega {o:g}, C {s:.1f}" for o, s in zip(table["omega"], table["shortening"],
                                                          strict=True)]
    return Coverage(labels, observed, best, low, high)


def table2(posterior, data, *, seed: int = 0) -> Coverage:
    """Table II's contracted volumes (ml) against their 95 % predictive bands: the draws, the
    EF discrepancy and the measurement's sd (a new measurement is predicted)."""
    card = posterior.card
    sd = math.hypot(
        card["discrepancy"]["ef_volume"]["s0"] / ml, card["sigmas"]["table2_measurement_ml"]
    )
    return _zero_pressure(posterior, data.table2_experiment, sd, seed)


def table1(posterior, data, *, seed: int = 0) -> Coverage:
    """Table I's contracted volumes (ml; the paper's FEM, which the EF law is fitted to)
    against the model's 95 % bands: the draws and the EF discrepancy, with no measurement's sd
    (a simulation does not scatter)."""
    sd = posterior.card["discrepancy"]["ef_volume"]["s0"] / ml
    return _zero_pressure(posterior, data.table1_fem, sd, seed)


class BenchCheck(NamedTuple):
    dynamic_sv: Coverage
    peak_force: Coverage
    failed: int
    bands: tuple = ()
    """Per head, the model's own 95 % predictive bands of every metric (draws and
    discrepancy, no measurement's sd: :func:`cardiosoft.posterior.predictive_bands`)."""


def bench(posterior, data, scene, *, seed: int = 0, heads=None) -> BenchCheck:
    """The 30-bpm bench's dynamic SVs (ml) and peak forces (N) against their bands: the draws
    solved as one ensemble, the discrepancy (``posterior.card``) and the paper's sd sampled.
    ``scene``: the posterior's surrogate on its calibrated bench
    (:func:`fit.posterior.artifact.bench_scene`); ``heads``: indices of the paper's afterloads to
    check (default all)."""
    from cardiosoft.batch import solve_beats
    from cardiosoft.posterior import discrepancy_sd, ensemble_run, predictive_bands
    from cardiosoft.units import mmHg

    b = data.fig10_bench
    heads = list(range(len(b["afterload_mmHg"]))) if heads is None else list(heads)
    pick = lambda a: np.asarray(a, float)[heads]  # noqa: E731
    scene = scene.replace(
        bpm=30.0, afterloads=tuple(float(p) * mmHg for p in pick(b["afterload_mmHg"]))
    )
    ens = ensemble_run(scene, posterior)
    plain = solve_beats(scene, save="metrics")
    rng = np.random.default_rng(seed)
    out = []
    for key, kind, unit, best, obs, obs_sd in (
        ("dynamic_sv_ml", "dynamic_sv", ml, np.asarray(plain.metrics.stroke_volume) / ml,
         pick(b["dynamic_sv_ml"]), pick(b["dynamic_sv_sd_ml"])),
        ("peak_force_N", "force", 1.0, np.asarray(plain.metrics.peak_force),
         pick(b["peak_force_N"]), pick(b["peak_force_sd_N"])),
    ):
        lows, highs = [], []
        for i, head in enumerate(ens.afterload_mmHg):
            sd = math.hypot(
                discrepancy_sd(posterior.card, kind, 30.0, float(head)) / unit, float(obs_sd[i])
            )
            v = ens.values[key][ens.ok[:, i], i]
            samples = v[:, None] + sd * rng.standard_normal((len(v), NOISE_SAMPLES))
            lo, hi = _quantiles(samples.ravel())
            lows.append(lo)
            highs.append(hi)
        labels = [f"{p:g} mmHg" for p in pick(b["afterload_mmHg"])]
        out.append(Coverage(labels, obs, best, np.array(lows), np.array(highs)))
    bands = tuple(predictive_bands(ens, posterior.card, seed=seed))
    return BenchCheck(*out, failed=int((~ens.ok).sum()), bands=bands)


LOAO_DRAWS = 64
"""Draws of each leave-one-afterload-out posterior."""


def leave_one_afterload_out(fit, *, n_draws: int = LOAO_DRAWS, seed: int = 0,
                            joint_sampler: str = "laplace", progress=print) -> BenchCheck:
    """Each of the paper's three afterloads left out in turn: its four data rows (static SV, peak
    force, dynamic SV, work) dropped from the mechanics and bench block, the block refitted by
    one Gauss-Newton step and its Laplace recomputed (:func:`fit.posterior.laplace.laplace` with
    ``keep``), ``n_draws`` drawn and solved at the left-out afterload, its dynamic SV and peak
    force predicted. ``joint_sampler``: the block drawn as the shipped posterior draws it: by
    tempered SMC (``"smc"``, :func:`fit.posterior.artifact.joint_target` without the rows: a
    pilot from that Laplace, then a run from the pilot's Gaussian, as
    :func:`fit.posterior.artifact.compute` draws it) or from the Laplace itself. The
    discrepancy keeps its sizes (they saw every row), but the left-out head is now outside the
    calibrated range of the other two where it is an end one (30 or 90 mmHg): its band grows as
    a prediction's would. ``fit``: :func:`fit.posterior.artifact.linearised_fit`."""
    from fit.posterior import artifact, laplace, smc

    n = len(fit.d.t.afterload)
    cols = laplace._spans(fit.layout)[1]
    heads = np.asarray(fit.data.fig10_bench["afterload_mmHg"], float)
    parts = []
    failed = 0
    for i in range(n):
        keep = np.arange(n) != i
        progress(f"  leave out {heads[i]:g} mmHg: refit, Laplace, {n_draws} draws "
                 f"({joint_sampler}) at 30 bpm")
        lap = laplace.laplace(fit.layout, fit.d, fit.lin, fit.sizing.s0, fit.layout.centre,
                              keep=keep)
        joint_draws = None
        if joint_sampler == "smc":
            potential, inside = artifact.joint_target(fit.layout, fit.d, fit.sizing.s0,
                                                      fit.scene, keep)
            _, run = smc.piloted(potential, lap.centre[cols], lap.transform[cols, cols], inside,
                                 particles=n_draws, seeds=(seed + i, seed + n + i),
                                 progress=progress)
            joint_draws = artifact.shuffled(run, seed + i)
        theta, _ = artifact.sample(fit.layout, lap, n_draws, seed + i, None, joint_draws)
        card = json.loads(json.dumps(artifact.discrepancy_card(fit)))
        card["discrepancy"]["distance"]["afterload_mmHg"] = [
            float(heads[keep].min()), float(heads[keep].max())
        ]
        posterior = artifact.as_ensemble(fit.layout, theta, card)
        parts.append(bench(posterior, fit.data, fit.scene, seed=seed, heads=[i]))
        failed += parts[-1].failed
    def join(kind):
        covs = [getattr(part, kind) for part in parts]
        labels = [label for c in covs for label in c.labels]
        return Coverage(labels, *(np.concatenate([getattr(c, f) for c in covs])
                                  for f in Coverage._fields[1:]))

    return BenchCheck(join("dynamic_sv"), join("peak_force"), failed)


def format_coverage(title: str, unit: str, cov: Coverage, extra: str = "") -> str:
    s = cov.summary()
    lines = [title, f"  {'':18s} {'observed':>9s} {'model':>8s}   95 % band [{unit}]"]
    for i, label in enumerate(cov.labels):
        mark = "" if cov.inside[i] else "   OUTSIDE"
        lines.append(
            f"  {label:18s} {cov.observed[i]:9.2f} {cov.best[i]:8.2f}   "
            f"[{cov.low[i]:.2f}, {cov.high[i]:.2f}]{mark}"
        )
    lines.append(
        f"  inside: {s['inside']} of {s['of']} (Wilson 95 %: {s['wilson_95'][0]:.2f}-"
        f"{s['wilson_95'][1]:.2f}); mean interval score {s['mean_interval_score']:.2f} {unit}; "
        f"mean band width {s['mean_width']:.2f} {unit}{extra}"
    )
    return "\n".join(lines)
