"""Sobol indices of the 60-bpm bench's predictions against the linear shares over the draws.

    python -m fit.posterior --sobol [--base-samples 128]

``simulate --explain`` (:mod:`cardiosoft.explain`) answers linearly: squared correlations over
the posterior's draws. Here the same question is asked of the nonlinear model. Sobol indices
need independent inputs, and the posterior's parameters are correlated; the whitened
coordinates of the Gaussian with the shipped draws' mean and covariance (in the fit's raw
coordinates, where every value is admissible to the surrogate's parametrisation) are not:
``theta = mean + L z``, ``z`` standard normal, ``L L^T`` the draws' covariance. Each ``z_i`` is
one independent direction (the Cholesky ordering: the i-th parameter's spread given the ones
before it).

SALib's Saltelli sampling and Jansen estimators give first-order and total indices of the SV,
the peak force and the efficiency at 60 bpm against the 60-mmHg head; beside them the linear
index of the same ``z_i`` over the Saltelli base samples, ``corr(y, z_i)^2``, what
:mod:`cardiosoft.explain` computes over the draws. Where the linear index is the first-order
one, the response is near linear along ``z_i``; where the total indices sum to far more than
the first-order ones, the parameters interact and a linear share is a guide, not a number. All
``N (d + 2)`` samples are solved in one batched call; those that fail or miss the steady state
are counted and given the sample median (a Sobol estimate needs every sample), so a large count
makes the indices moot.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

BASE_SAMPLES = 128
BPM, HEAD_MMHG = 60.0, 60.0
OUTPUTS = ("dynamic_sv_ml", "peak_force_N", "efficiency")


class SobolCheck(NamedTuple):
    names: list
    outputs: tuple
    first: np.ndarray  # (outputs, d)
    first_conf: np.ndarray
    total: np.ndarray
    linear: np.ndarray  # (outputs, d)
    samples: int
    failed: int
    seconds: float

    def table(self, top: int = 5) -> str:
        lines = [
            f"Sobol indices on the posterior's independent coordinates z ({self.samples} "
            f"solves at {BPM:g} bpm, {HEAD_MMHG:g} mmHg; {self.failed} failed or not steady, "
            f"set to the median; {self.seconds:.0f} s) against the linear index corr(y, z_i)^2:"
        ]
        for k, out in enumerate(self.outputs):
            lines.append(f"  {out}: {'z of':28s} {'S1':>6s} {'+-':>5s} {'ST':>6s} "
                         f"{'linear':>7s}")
            for i in np.argsort(self.total[k])[::-1][:top]:
                lines.append(
                    f"    {self.names[i]:32s} {self.first[k, i]:6.2f} {self.first_conf[k, i]:5.2f} "
                    f"{self.total[k, i]:6.2f} {self.linear[k, i]:7.2f}"
                )
        return "\n".join(lines)

    def record(self) -> dict:
        return {
            "bpm": BPM, "afterload_mmHg": HEAD_MMHG, "samples": self.samples,
            "failed": self.failed, "seconds": round(self.seconds, 1),
            "coordinates": "z: theta = mean + L z, L L^T the shipped draws' covariance, raw "
            "coordinates",
            "indices": {
                out: {n: {"S1": float(self.first[k, i]), "S1_conf": float(self.first_conf[k, i]),
                          "ST": float(self.total[k, i]), "linear": float(self.linear[k, i])}
                      for i, n in enumerate(self.names)}
                for k, out in enumerate(self.outputs)
            },
        }


def run(layout, theta_draws, posterior, *, base_samples: int = BASE_SAMPLES, seed: int = 0,
        progress=print) -> SobolCheck:
    """The check (module docstring). ``layout``: :class:`fit.posterior.blocks.Layout` of the
    shipped fit; ``theta_draws``: the posterior's draws (S, p) in raw coordinates (the
    ``.npz``'s ``theta``); ``posterior``: :func:`cardiosoft.pump.load_posterior`'s."""
    from SALib.analyze import sobol as analyze
    from SALib.sample import sobol as sample

    from cardiosoft.posterior import ensemble_run
    from cardiosoft.units import mmHg
    from fit.posterior import artifact

    theta_draws = np.asarray(theta_draws, float)
    mean = theta_draws.mean(axis=0)
    lower = np.linalg.cholesky(np.cov(theta_draws, rowvar=False))
    d = len(mean)
    names = [f"z{i} ({n})" for i, n in enumerate(layout.names)]
    problem = {"num_vars": d, "names": names, "bounds": [[0.0, 1.0]] * d,
               "dists": ["norm"] * d}
    z = sample.sample(problem, base_samples, calc_second_order=False, seed=seed)
    scene = artifact.bench_scene(posterior.card["surrogate"]).replace(
        bpm=BPM, afterloads=(HEAD_MMHG * mmHg,))
    progress(f"sobol: {len(z)} samples at {BPM:g} bpm in one batched solve ...")
    start = time.perf_counter()
    ens = ensemble_run(scene, artifact.as_ensemble(layout, mean + z @ lower.T, posterior.card))
    seconds = time.perf_counter() - start
    ok = ens.ok[:, 0]
    # Saltelli's rows come in blocks of d + 2: A, A with column i from B (d of them), B
    base = np.zeros(len(z), bool)
    base[:: d + 2] = base[d + 1 :: d + 2] = True
    first, conf, total, linear = [], [], [], []
    for out in OUTPUTS:
        y = np.asarray(ens.values[out][:, 0], float)
        y = np.where(ok & np.isfinite(y), y, np.median(y[ok]))
        si = analyze.analyze(problem, y, calc_second_order=False, seed=seed)
        first.append(si["S1"])
        conf.append(si["S1_conf"])
        total.append(si["ST"])
        rows = base & ok
        linear.append([np.corrcoef(z[rows, i], y[rows])[0, 1] ** 2 for i in range(d)])
    return SobolCheck(names, OUTPUTS, np.array(first), np.array(conf), np.array(total),
                      np.array(linear), len(z), int((~ok).sum()), seconds)
