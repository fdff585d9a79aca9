"""What dominates a prediction's uncertainty, and what to measure next (issue #24, item 4).

    python -m cardiosoft.simulate --bpm 60 --uncertainty --explain

Linearised from the posterior's Laplace approximation (``theta ~ N(theta*, Sigma)`` in the fit's
raw coordinates, the covariance shipped in the posterior's ``.npz``) and one ``jax.jacfwd`` of
the predictions through the batched solve, ``g = d prediction / d theta``:

- the *share* of a prediction's variance that parameter i carries: the fraction removed by
  knowing theta_i exactly, ``(g^T Sigma e_i)^2 / (Sigma_ii g^T Sigma g)`` (correlated parameters'
  shares need not sum to one);
- the sd *after a new measurement* with sensitivity row ``h`` (``d measurement / d theta``)
  and sd ``sigma_m``: ``sqrt(g^T (Sigma^-1 + h h^T / sigma_m^2)^-1 g)``.

Both describe the parameters' part of the band (``<metric>_band_parameters``), not the model
discrepancy, which no measurement of theta shrinks. The candidate measurements
(:data:`CANDIDATES`) are taken on the paper's bench: the tube's length with a ruler, the dynamic
SV and the peak force at 60 bpm (60 mmHg), and a static compliance test of the shell (its
volume at 60 mmHg with no pull). Linearised shares are a first answer; where the draws are far
from Gaussian (the relaxation time's) they are a guide, not a number to trust to a digit.
"""

from __future__ import annotations

import math
import re
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from cardiosoft.pump import centred_omega
from cardiosoft.units import ml, mm, mmHg

__all__ = ["CANDIDATES", "Explanation", "explain", "predictions", "raw_covariance", "rebuild"]

BENCH_FIELDS = {
    "bench.log_tube_length": "tube_length",
    "bench.log_tube_diameter": "tube_diameter",
    "bench.log_stiffness_ratio": "viscoelastic_ratio",
    "bench.log_relaxation_time": "relaxation_time",
}
"""The bench's four (logs of SI values, ``fit.bench``) and the scene fields they set."""
RULER_MM = 10.0
"""The tube's length measured with a ruler, fittings included: +- 10 mm (one sd)."""
COMPLIANCE_PRESSURE_MMHG = 60.0
SHELL_VOLUME_SD_ML = 1.79
"""A static volume measured as the paper measured its static SVs: their pooled SD (Sec.
III-D, 2.6, 1.2, 1.2 ml), as the posterior card's Table II measurement."""
MEASURE_BPM, MEASURE_HEAD_MMHG = 60.0, 60.0


def rebuild(pump, names, theta):
    """The pump and the scene numbers (SI) of raw parameters ``theta`` (names as the posterior's
    ``names``: pump fields ``f`` or ``f[i]``, ``log_column_diameter``, ``raw_cable_friction``,
    ``bench.*``, ``f(Omega o)`` for a rate ``softplus(f[0] + f[1] w)`` given by its argument at
    two Omegas; ``log_fem_pressure`` sets nothing a solve uses). The inverse of
    ``fit.posterior.blocks.Layout``'s flattening, written here because ``fit`` is not installed
    with the package."""
    leaves: dict[str, dict[int | None, jax.Array]] = {}
    at_omega: dict[str, dict[float, jax.Array]] = {}
    scene = {}
    for i, name in enumerate(names):
        by_omega = re.fullmatch(r"(\w+)\(Omega ([\d.]+)\)", name)
        if by_omega:  # a rate softplus(p0 + p1 w(Omega)) as its argument at two Omegas
            at_omega.setdefault(by_omega.group(1), {})[float(by_omega.group(2))] = theta[i]
        elif name in BENCH_FIELDS:
            scene[BENCH_FIELDS[name]] = jnp.exp(theta[i])
        elif name == "log_column_diameter":
            scene["column_diameter"] = jnp.exp(theta[i])
        elif name == "raw_cable_friction":
            scene["cable_friction"] = jax.nn.softplus(theta[i])
        elif name != "log_fem_pressure":
            m = re.fullmatch(r"(\w+)(?:\[(\d+)\])?", name)
            field, index = m.group(1), m.group(2)
            leaves.setdefault(field, {})[None if index is None else int(index)] = theta[i]
    for field, parts in at_omega.items():
        (o0, q0), (o1, q1) = sorted(parts.items())
        w0, w1 = centred_omega(o0), centred_omega(o1)
        slope = (q1 - q0) / (w1 - w0)
        leaves[field] = {0: q0 - w0 * slope, 1: slope}
    values = []
    for parts in leaves.values():
        if None in parts:
            values.append(jnp.asarray(parts[None], dtype=float))
        else:
            values.append(jnp.stack([parts[k] for k in sorted(parts)]))
    pump = eqx.tree_at(lambda p: [getattr(p, f) for f in leaves], pump, values)
    return pump, scene


def raw_covariance(arrays) -> np.ndarray:
    """The Laplace covariance in raw coordinates: the natural one (``transform`` T, ``T T^T``)
    mapped back through d raw / d natural = 1 / sigmoid(raw) where the coordinate is a
    softplus (``positive``), linearised at the centre."""
    t = np.asarray(arrays["transform"])
    slope = np.where(arrays["positive"], 1.0 / (1.0 + np.exp(-np.asarray(arrays["centre"]))), 1.0)
    return (t @ t.T) / np.outer(slope, slope)


class Explanation(NamedTuple):
    """Per prediction (label -> value): its sd from the parameters, the variance shares, and
    the sd after each candidate measurement (user units)."""

    names: tuple
    labels: list
    values: np.ndarray
    sd: np.ndarray
    shares: np.ndarray  # (predictions, parameters)
    after: dict  # candidate -> (predictions,) sd after measuring it
    candidates: dict  # candidate -> sd of the measurement, in words

    def table(self, top: int = 3) -> str:
        lines = ["what dominates each prediction's parameter uncertainty (linearised; share of "
                 "its variance removed by knowing the parameter):"]
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
            "method": "linearised: Laplace covariance and jax.jacfwd of the predictions",
            "predictions": {
                label: {
                    "value": float(self.values[k]),
                    "sd_parameters": float(self.sd[k]),
                    "shares": {n: float(self.shares[k, i]) for i, n in enumerate(self.names)},
                    "sd_after": {c: float(v[k]) for c, v in self.after.items()},
                }
                for k, label in enumerate(self.labels)
            },
            "candidates": self.candidates,
        }


CANDIDATES = ("tube length", "SV at 60 bpm", "shell compliance", "force at 60 bpm")


def _matching(scene, centre: dict) -> set:
    """The rig's fields that ``scene`` shares with the calibrated bench (its value is the
    posterior's centre): only those take theta's values."""
    from cardiosoft.posterior import SCENE_MATCH_RTOL

    return {
        f for f, c in centre.items()
        if math.isclose(float(getattr(scene, f)), c, rel_tol=SCENE_MATCH_RTOL)
    }


def predictions(scene, pump0, names, centre_values):
    """``theta -> (4, M)``: the scene's SV (ml), peak force (N), efficiency and cardiac output
    (l/min) per member, for raw parameters ``theta`` (:func:`rebuild`); the rig's numbers take
    theta's values where ``scene`` holds the calibrated ones (``centre_values``, SI)."""
    from cardiosoft.batch import solve_beats

    shared = _matching(scene, centre_values)

    def f(theta):
        pump, values = rebuild(pump0, names, theta)
        s = scene.replace(**{k: v for k, v in values.items() if k in shared})
        m = solve_beats(s, save="metrics", pump=pump).metrics
        return jnp.stack([
            m.stroke_volume / ml, m.peak_force, m.efficiency, m.cardiac_output / ml * 60 / 1000
        ])

    return f


def explain(scene, posterior, progress=print) -> Explanation:
    """The variance shares of ``scene``'s SV, peak force, efficiency and cardiac output per
    member, and their sd after each candidate measurement (module docstring).
    ``posterior``: :class:`cardiosoft.pump.PosteriorDraws`."""
    from cardiosoft.posterior import discrepancy_sd
    from cardiosoft.pump import artifact_dir, load
    from cardiosoft.scene import load_scene

    with np.load(artifact_dir() / posterior.card["file"], allow_pickle=False) as f:
        arrays = {k: f[k] for k in ("names", "centre", "transform", "positive")}
    names = tuple(str(n) for n in arrays["names"])
    theta = jnp.asarray(arrays["centre"])
    cov = raw_covariance(arrays)
    pump0 = load()
    progress("explain: d prediction / d theta (jax.jacfwd through the batched solve) ...")
    predict = predictions(scene, pump0, names, posterior.scene_centre)
    # one forward-mode pass gives the values beside the Jacobian (aux): no second solve
    jac, values = jax.jit(jax.jacfwd(lambda t: (y := predict(t), y), has_aux=True))(theta)
    values, jac = np.asarray(values), np.asarray(jac)  # (4, M), (4, M, p)
    kinds = ["SV [ml]", "peak force [N]", "efficiency", "CO [l/min]"]
    heads = scene.afterloads if scene.afterload.has_heads else [None]
    labels, rows, vals = [], [], []
    for k, kind in enumerate(kinds):
        if kind.startswith("CO") and scene.afterload.has_heads:
            continue  # the bench's output is its SV at the rate: nothing new
        for i, head in enumerate(heads):
            where = f"{head / mmHg:.0f} mmHg" if head is not None else scene.name
            labels.append(f"{kind} at {scene.bpm:g} bpm, {where}")
            rows.append(jac[k, i])
            vals.append(values[k, i])
    g = np.array(rows)

    progress("explain: the candidate measurements' sensitivities (the bench at 60 bpm, the "
             "shell at rest) ...")
    bench = load_scene("bench-dynamic").replace(
        bpm=MEASURE_BPM, afterloads=(MEASURE_HEAD_MMHG * mmHg,)
    )
    b_jac = jax.jit(jax.jacfwd(predictions(bench, pump0, names, posterior.scene_centre)))(theta)

    def shell_volume(t):
        pump, _ = rebuild(pump0, names, t)
        return pump.volume(COMPLIANCE_PRESSURE_MMHG * mmHg, 0.0, 4.0) / ml

    v_jac = np.asarray(jax.jacfwd(shell_volume)(theta))
    card = posterior.card
    sv_sd = math.hypot(2.0, discrepancy_sd(card, "dynamic_sv", MEASURE_BPM,
                                           MEASURE_HEAD_MMHG) / ml)
    force_sd = math.hypot(3.0, discrepancy_sd(card, "force", MEASURE_BPM, MEASURE_HEAD_MMHG))
    length = np.zeros(len(names))
    length[names.index("bench.log_tube_length")] = 1.0
    ruler = RULER_MM * mm / float(np.exp(theta[names.index("bench.log_tube_length")]))
    measurements = {
        "tube length": (length, ruler),
        "SV at 60 bpm": (np.asarray(b_jac)[0, 0], sv_sd),
        "shell compliance": (v_jac, SHELL_VOLUME_SD_ML),
        "force at 60 bpm": (np.asarray(b_jac)[1, 0], force_sd),
    }
    why = {
        "tube length": f"ruler +- {RULER_MM:g} mm",
        "SV at 60 bpm": f"+- {sv_sd:.1f} ml (2 ml and the discrepancy at 60 bpm)",
        "shell compliance": f"V at {COMPLIANCE_PRESSURE_MMHG:g} mmHg, no pull, "
        f"+- {SHELL_VOLUME_SD_ML} ml",
        "force at 60 bpm": f"+- {force_sd:.1f} N (3 N and the discrepancy at 60 bpm)",
    }
    variance, shares = variance_shares(g, cov)
    after = {c: sd_after(g, cov, h, sd) for c, (h, sd) in measurements.items()}
    return Explanation(names, labels, np.array(vals), np.sqrt(variance), shares, after, why)


def variance_shares(g, cov):
    """(variance ``g^T Sigma g`` per row of ``g``, shares (rows, parameters)): the fraction of
    each row's variance removed by knowing parameter i exactly (module docstring)."""
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
