"""Sobol indices of the 60-bpm bench's predictions against the linearised variance shares.

    python -m fit.posterior --sobol [--base-samples 128]

``simulate --explain`` (:mod:`cardiosoft.explain`) linearises: one ``jax.jacfwd`` and the
Laplace covariance. Here the same question is asked of the nonlinear model. Sobol indices need
independent inputs, and the posterior's parameters are correlated; its whitened coordinates are
not: ``theta = theta* + L z`` with ``z`` standard normal and ``L`` the Laplace's transform in
the fit's raw coordinates (the natural one mapped back at the centre, so that every sample is
admissible to the surrogate's parametrisation). Each ``z_i`` is one independent direction of the
posterior (its Cholesky ordering: the i-th parameter's spread given the ones before it).

SALib's Saltelli sampling and Jansen estimators give first-order and total indices of the SV,
the peak force and the efficiency at 60 bpm against the 60-mmHg head; beside them the linearised
first-order index of the same ``z_i``, ``(g^T L e_i)^2 / (g^T L L^T g)``. Where the two agree the
linearised shares of ``--explain`` can be read as they are; where they do not, the model is far
from linear over the posterior and the Sobol numbers hold. All ``N (d + 2)`` samples are solved
in one batched call; those that fail or miss the steady state are counted and given the
sample median (a Sobol estimate needs every sample), so a large count makes the indices moot.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
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
            f"set to the median; {self.seconds:.0f} s) against the linearised index:"
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
            "coordinates": "z: theta = theta* + L z, L the Laplace transform in raw coordinates",
            "indices": {
                out: {n: {"S1": float(self.first[k, i]), "S1_conf": float(self.first_conf[k, i]),
                          "ST": float(self.total[k, i]), "linear": float(self.linear[k, i])}
                      for i, n in enumerate(self.names)}
                for k, out in enumerate(self.outputs)
            },
        }


def run(layout, arrays: dict, posterior, *, base_samples: int = BASE_SAMPLES, seed: int = 0,
        progress=print) -> SobolCheck:
    """The check (module docstring). ``layout``: :class:`fit.posterior.blocks.Layout` of the
    shipped fit; ``arrays``: the posterior's ``.npz`` (``centre``, ``transform``,
    ``positive``); ``posterior``: :func:`cardiosoft.pump.load_posterior`'s."""
    from SALib.analyze import sobol as analyze
    from SALib.sample import sobol as sample

    from cardiosoft.explain import predictions
    from cardiosoft.posterior import ensemble_run
    from cardiosoft.scene import load_scene
    from cardiosoft.units import mmHg
    from fit.posterior import artifact

    centre = np.asarray(arrays["centre"], float)
    slope = layout.natural_slope(centre)
    transform = np.asarray(arrays["transform"]) / slope[:, None]  # raw coordinates
    d = len(centre)
    names = [f"z{i} ({n})" for i, n in enumerate(layout.names)]
    problem = {"num_vars": d, "names": names, "bounds": [[0.0, 1.0]] * d,
               "dists": ["norm"] * d}
    z = sample.sample(problem, base_samples, calc_second_order=False, seed=seed)
    theta = centre + z @ transform.T
    scene = load_scene("bench-dynamic").replace(bpm=BPM, afterloads=(HEAD_MMHG * mmHg,))
    progress(f"sobol: {len(z)} posterior samples at {BPM:g} bpm in one batched solve ...")
    start = time.perf_counter()
    ens = ensemble_run(scene, artifact.as_ensemble(layout, theta, posterior.card))
    seconds = time.perf_counter() - start
    ok = ens.ok[:, 0]
    first, conf, total = [], [], []
    for out in OUTPUTS:
        y = np.asarray(ens.values[out][:, 0], float)
        y = np.where(ok & np.isfinite(y), y, np.median(y[ok]))
        si = analyze.analyze(problem, y, calc_second_order=False, seed=seed)
        first.append(si["S1"])
        conf.append(si["S1_conf"])
        total.append(si["ST"])
    progress("sobol: the linearised indices (one jax.jacfwd at the centre) ...")
    predict = predictions(scene, layout.fitted_model, list(layout.names), posterior.scene_centre)
    g = np.asarray(jax.jit(jax.jacfwd(predict))(jnp.asarray(centre)))[:3, 0]  # SV, F, e
    gl = g @ transform
    linear = gl**2 / np.sum(gl**2, axis=1, keepdims=True)
    return SobolCheck(names, OUTPUTS, np.array(first), np.array(conf), np.array(total),
                      linear, len(z), int((~ok).sum()), seconds)
