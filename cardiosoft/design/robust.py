"""The stroke volumes a design reaches, with their 95 % predictive bands; the robust design.

    cardiosoft design --target-sv 70 --afterload 60 --bpm 60 --uncertainty   # the SV's band
    cardiosoft design --target-sv 70 --afterload 60 --bpm 60 --robust        # a design whose
                                                                             # band stays in tol

A design hits its targets for the shipped surrogate; the posterior's draws
(:func:`cardiosoft.pump.load_posterior`) and the model discrepancy say how far the real pump may
be from them (:mod:`cardiosoft.posterior`). ``--robust`` looks for the design (Omega, C) whose SV
band stays within the tolerance of every target: first against the floor the discrepancy alone
sets (its band is at least ``2 x 1.96 sd`` wide whatever the design; wider than twice the
tolerance, no design can be robust, and it says so without solving), then over a grid of
:data:`GRID` x :data:`GRID` designs around the one found, all draws at all designs and targets
in one batched solve per rate.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from cardiosoft.units import ml, mmHg

__all__ = ["GRID", "SPAN", "RobustResult", "robust_design", "sv_bands"]

GRID = 5
"""Designs per axis of the robust search's grid."""
SPAN = (0.5, 0.05)
"""Half-widths of the grid around the design found: Omega, C (clipped to the fitted domain)."""
Z95 = 1.959963984540054


def sv_bands(scene, omega, shortening, targets, posterior) -> np.ndarray:
    """The SV's predictive bands (:class:`cardiosoft.posterior.Band`, ml) of each design
    ``(omega[d], shortening[d])`` at each target (``DesignResult.targets``: afterload, bpm):
    an object array ``(designs, targets)``."""
    from cardiosoft.posterior import ensemble_run, predictive_bands

    omega, shortening = np.atleast_1d(omega), np.atleast_1d(shortening)
    n_designs = len(omega)
    out = np.empty((n_designs, len(targets)), dtype=object)
    for bpm in sorted({t.bpm for t in targets}):
        which = [k for k, t in enumerate(targets) if t.bpm == bpm]
        heads = scene.afterload.has_heads
        n = len(which) if heads else 1
        members = dict(omega=np.repeat(omega, n), shortening=np.repeat(shortening, n))
        if heads:
            members["afterload"] = np.tile([targets[k].afterload_mmHg * mmHg for k in which],
                                           n_designs)
        ens = ensemble_run(scene.replace(bpm=bpm), posterior, **members)
        bands = predictive_bands(ens, posterior.card)
        for d in range(n_designs):
            for j, k in enumerate(which):
                out[d, k] = bands[d * n + (j if heads else 0)]["dynamic_sv_ml"]
    return out


class RobustResult(NamedTuple):
    """The robust search's answer: the design (None where no search was worth running), its
    worst band edge's distance from a target (ml), whether that is within the tolerance, and
    why (in words, with the numbers)."""

    omega: float | None
    shortening: float | None
    worst_ml: float | None
    within: bool
    reason: str
    bands: list  # per target: [low, high] ml at the design, or []

    def record(self) -> dict:
        return self._asdict()


def discrepancy_floor_ml(card: dict, targets, scene) -> np.ndarray:
    """Per target, the half-width (ml) of the band the SV discrepancy alone gives."""
    from cardiosoft.posterior import discrepancy_sd

    return np.array([
        Z95 * discrepancy_sd(card, "dynamic_sv", t.bpm,
                             t.afterload_mmHg if scene.afterload.has_heads else None) / ml
        for t in targets
    ])


def robust_design(scene, result, posterior, progress=print) -> RobustResult:
    """The design whose SV bands stay within ``result.tolerance_ml`` of every target (module
    docstring), searched around ``result.design``."""
    from cardiosoft.pump import load

    tol, targets = result.tolerance_ml, result.targets
    floor = discrepancy_floor_ml(posterior.card, targets, scene)
    if np.max(floor) > tol:
        k = int(np.argmax(floor))
        return RobustResult(
            None, None, None, False,
            f"no design can be: the model discrepancy alone gives the SV a 95 % band of +- "
            f"{floor[k]:.2f} ml at {targets[k].where}, wider than the tolerance +- {tol:g} ml "
            "(a wider --tol, or a smaller discrepancy: more data at this rate and afterload)",
            [],
        )
    domain = load().domain
    (o_lo, o_hi), (c_lo, c_hi) = domain.omega, domain.shortening
    o0, c0 = result.design["omega"], result.design["shortening"]
    omegas = np.clip(np.linspace(o0 - SPAN[0], o0 + SPAN[0], GRID), o_lo, o_hi)
    cs = np.clip(np.linspace(c0 - SPAN[1], c0 + SPAN[1], GRID), c_lo, c_hi)
    grid_o, grid_c = (a.ravel() for a in np.meshgrid(omegas, cs, indexing="ij"))
    progress(f"robust: {len(grid_o)} designs around Omega {o0:.3f}, C {c0:.4f}, every "
             "posterior draw at every target ...")
    bands = sv_bands(scene, grid_o, grid_c, targets, posterior)
    target_sv = np.array([t.target_sv_ml for t in targets])
    low = np.array([[b.low for b in row] for row in bands], dtype=float)
    high = np.array([[b.high for b in row] for row in bands], dtype=float)
    worst = np.max(np.maximum(np.abs(low - target_sv), np.abs(high - target_sv)), axis=1)
    worst = np.where(np.isfinite(worst), worst, np.inf)
    best = int(np.argmin(worst))
    within = bool(worst[best] <= tol)
    reason = (
        f"the band stays within +- {tol:g} ml of every target" if within else
        f"none of the {len(grid_o)} designs keeps its band within +- {tol:g} ml: the closest "
        f"misses by {worst[best] - tol:.2f} ml at its worst band edge"
    )
    return RobustResult(
        float(grid_o[best]), float(grid_c[best]), float(worst[best]), within, reason,
        [[float(low[best, k]), float(high[best, k])] for k in range(len(targets))],
    )
