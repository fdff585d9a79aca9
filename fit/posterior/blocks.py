"""The posterior's three blocks as whitened residual vectors: data over their stated sigmas, and
priors, so that ``1/2 |r(theta)|^2`` is the negative log posterior density of each block over
its natural coordinates (:meth:`Layout.natural`: the positive coefficients themselves where the
raw coordinate is a softplus-inverse, :data:`POSITIVE`; the raw one elsewhere).

The parameters are one flat vector ``theta`` in the fit's own raw coordinates (log, logit,
softplus-inverse; the EF law's quadratic rate as its softplus-arguments at the ends of the Omega
range, :data:`QUADRATIC_OMEGAS`), in three blocks:

- ``ef``: the EF_0 law of stage 1 (``pipeline.EF_FIELDS``, 7 numbers), on Table I;
- ``mechanics``: stage 2, the surrogate's ``pipeline.MECHANICS_FIELDS`` and the rig's
  ``pipeline.RIG_FIELDS``, and the two the fit holds (``pipeline.HELD``: the fold compliance
  kappa and the column's diameter), 10 in all, on the Fig. 10 bench (quasi-static) and the
  FEM comparisons. The held two get a prior and are sampled: the data leave them nearly free,
  and their spread is what a prediction must show;
- ``bench``: the bench calibration of ``fit.bench`` (the logs of the tube's length and diameter
  in m, the shell's viscoelastic stiffness ratio and relaxation time in s), on the dynamic SVs
  and mechanical work at 30 bpm, solved through diffrax.

Each block is conditional on the blocks before it (the fit is sequential: stage 2 holds stage 1,
the bench calibration holds the surrogate): ``r_ef(theta_ef)``, ``r_mech(theta_ef, theta_mech)``,
``r_bench(theta_ef, theta_mech, theta_bench)``. :mod:`fit.posterior.laplace` combines them as a
cut posterior (no feedback from a later block's data onto an earlier block's parameters).

**Sigmas** (stated in the posterior's card, ``STATED``):

- Table I (FEM, printed to 0.1 % EF): the rounding, 0.1 % / sqrt(12), plus the EF discrepancy
  s0 (the surrogate's leave-one-out error on Table I). The fit's soft-L1 residuals are kept: the
  whole stage-1 residual vector (cells, the longitudinal anchor, the ridge) is multiplied by
  ``EF_SCALE / sigma_ef``, so the posterior is the fit's loss at one temperature and its mode is
  the fit's optimum; the ridge becomes a normal prior of sd ``sigma_ef / REGULARISATION`` (about
  5) on each raw EF parameter, the anchor a 10 % sd scaled likewise.
- static SV and peak force: the paper's SDs (Sec. III-D) and the static SV's and force's
  discrepancy s0 in quadrature; mechanical work M = P_a SV_dyn / e: the dynamic SV's relative
  SD and the efficiency's rounding (0.0005) in quadrature, plus the work discrepancy;
- dynamic SV: the paper's SDs plus the dynamic SV's discrepancy;
- the FEM comparisons (efficiencies 0.02, ratios 10 %): the fit's own scales, stated in
  ``fit.pipeline`` as the surrogate's form error against a computed reference (no measurement
  there).

**Support.** The convexity constraint (one volume per pull and pressure: ``d2U/dV2 >=
pipeline.CONVEXITY_MARGIN E_u`` on the fit's grid, :func:`smallest_stiffness`) is the prior's
support, written as one residual that is 0 inside and +inf outside: the shipped draws are
truncated to that support, and NUTS and importance sampling see the same. The fit's own form
of it, a hinge at 1.2 times the margin with a scale of 1e-3 E_u
(``pipeline.convexity_residuals``: a margin for the fit's coarse grid), is no part of the
posterior: the fit's optimum ends on that hinge (3e-6 below it), where its one-sided wall
entered the Gauss-Newton Hessian as a two-sided one of slope 1000 and pinned the swelling
resistance's sd at 0.08 (0.55 without it); and the fifth of the draws that lie between the
margin and the hinge were charged up to 200 in potential there.

**Priors** (``PRIORS``): broad normal priors on the raw parameters of stages 2 and the bench,
each written as one more residual ``(theta - mu) / s``; the EF block's prior is the fit's ridge.
Read as densities of the natural coordinates (a positive coefficient's prior is
``N(softplus^-1(c); mu, s)`` as a function of c), so that no flat half-line of a saturated
softplus piles prior mass onto a coefficient of zero.
"""

from __future__ import annotations

from typing import NamedTuple

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from cardiosoft.pump import centred_omega
from cardiosoft.units import mm, mmHg
from fit import pipeline

BLOCKS = ("ef", "mechanics", "bench")
MECHANICS = (*pipeline.MECHANICS_FIELDS, "fold_compliance")
"""The surrogate's parameters in the mechanics block: the fitted ones and the held kappa."""
RIG = ("log_column_diameter", *pipeline.RIG_FIELDS)
"""The rig's parameters in the mechanics block: the held column diameter and the fitted ones."""
BENCH_FIELDS = {
    "bench.log_tube_length": "tube_length",
    "bench.log_tube_diameter": "tube_diameter",
    "bench.log_stiffness_ratio": "viscoelastic_ratio",
    "bench.log_relaxation_time": "relaxation_time",
}
"""The bench calibration's four, as logs of SI values (``fit.bench.NAMES`` in m, -, s), and the
scene fields they set."""
RAMP_FIELD = {"bench.log_ramp_time": "ramp_time"}
"""The crosshead's ramp time (s), a rig unknown of the bench block wherever the calibrated bench
has a crosshead that accelerates (its ``actuation.ramp_time_s`` > 0): sampled from its prior
(:data:`PRIORS`) and the dynamic SVs and work, never fitted to the peak forces (issue #39)."""
FEM_ROUNDING = 0.001 / np.sqrt(12.0)
"""Table I prints EF to 0.1 %: a uniform rounding error of sd 0.1 % / sqrt(12) (fraction)."""
EFFICIENCY_ROUNDING = 0.0005
"""The paper prints the efficiencies to three decimals (Sec. III-D)."""
BENCH_RTOL, BENCH_ATOL = 1e-7, 1e-12  # fit.bench's solver tolerances, so that its optimum holds


def _softplus_inverse(y: float) -> float:
    return float(np.log(np.expm1(y)))


PRIORS: dict[str, tuple[float, float, str]] = {
    "log_stiffness[0]": (
        float(np.log(5e3)), float(np.log(10.0)),
        "log K [N/m]: an order of magnitude about a zero-pressure force peaking near 50 N",
    ),
    "log_stiffness[1]": (0.0, 1.0, "slope of log K in (Omega - 4)/4: K within e-fold per unit"),
    "softening_exponent": (0.0, 3.0, "softplus-inverse of g - 0.5: g from 0.5 to ~4"),
    "log_chamber_elastance": (
        float(np.log(7.0 * mmHg / 1e-6)), float(np.log(10.0)),
        "log E_u [Pa/m^3]: an order of magnitude about 7 mmHg/ml (the shell's inflation)",
    ),
    "fold_compliance": (
        _softplus_inverse(1.0), 2.0,
        "softplus-inverse of kappa (the folded chamber's elastance E_u exp(-kappa EF_0)): "
        "kappa from ~0 to ~3, held at 0.81 by the fit",
    ),
    "log_stiffening": (
        float(np.log(1 / 10e-6)), float(np.log(10.0)),
        "log beta [1/m^3]: stiffening over 1-100 ml",
    ),
    "swelling_resistance": (0.0, 3.0, "softplus-inverse of k: k from ~0 to ~3"),
    "log_column_diameter": (
        float(np.log(45 * mm)), float(np.log(2.0)),
        "log of the column's bore [m]: a laboratory tube of 20-90 mm, held at 43.4 mm by the fit",
    ),
    "raw_cable_friction": (
        _softplus_inverse(0.5), 1.5,
        "softplus-inverse of mu theta: cables over the base holes' edges, mu 0.1-0.5, theta ~pi/2",
    ),
    "log_fem_pressure": (
        float(np.log(60 * mmHg)), float(np.log(2.0)),
        "log of the FEM efficiencies' pressure [Pa]: physiological, 30-120 mmHg",
    ),
    "bench.log_tube_length": (
        float(np.log(0.3)), float(np.log(3.0)), "silicone tube from pump to column: 0.1-0.9 m"
    ),
    "bench.log_tube_diameter": (
        float(np.log(19e-3)), float(np.log(1.5)), "its bore: 13-29 mm, the pump base's outlet"
    ),
    "bench.log_stiffness_ratio": (
        float(np.log(0.2)), float(np.log(3.0)), "silicone's rate stiffening: 7-60 %"
    ),
    "bench.log_relaxation_time": (
        float(np.log(1.0)), float(np.log(5.0)), "its relaxation time: 0.2-5 s"
    ),
    "bench.log_ramp_time": (
        float(np.log(0.05)), float(np.log(10.0)) / 2.0,
        "log t_r [s], the crosshead's jerk-limited start and stop: 5-500 ms at 2 sd. Neither "
        "the paper (3000 mm/min, Sec. II-F) nor the INSTRON 5965's public data give an "
        "acceleration. 5 ms is a servo velocity loop of ~100 Hz; 500 ms is half the 1-s pull, "
        "past which it never runs at the stated speed. Peak accelerations pi v / (2 t_r): "
        "0.16-16 m/s^2",
    ),
}
"""Normal priors (mean, sd, why) on the raw parameters of the mechanics and bench blocks."""


POSITIVE = (
    "ef_linear",
    "ef_quadratic",
    "fold_depth",
    "three_fold_depth",
    "softening_exponent",
    "fold_compliance",
    "swelling_resistance",
    "raw_cable_friction",
)
"""Raw parameters that are softplus-inverses of one positive coefficient each (the EF law's
rates and depths, g - 1/2, kappa, k, mu theta). Near zero their raw coordinate is flat (the
softplus saturates): a density stated over it would put the whole flat half-line's prior mass
on a coefficient of about zero. The posterior is therefore stated over the coefficients
themselves (the natural coordinates, :meth:`Layout.natural`), its priors being functions of
them, and the Laplace approximation is taken there, truncated at zero
(:mod:`fit.posterior.laplace`). The EF law's quadratic rate ``b(Omega) = softplus(p0 + p1 w)``
enters as its values at the ends of the fitted Omega range (:data:`QUADRATIC_OMEGAS`)."""
QUADRATIC_OMEGAS = (0.0, 6.0)
"""Where the EF law's quadratic rate b(Omega) is a coordinate of the posterior: the fitted
range's ends (``Domain.omega``); ``p0 + p1 w`` at them determines (p0, p1)."""


class Sigmas(NamedTuple):
    """The discrepancy scales s0 per output type (SI: EF as a fraction, m^3, N, J). The static
    SV (a slow pull, the surrogate alone) and the dynamic SV (the column's rise at 30 bpm, the
    bench's calibrated tube and viscoelasticity too) are two types: the model reaches them by
    different mechanisms."""

    ef: float
    static_sv: float
    dynamic_sv: float
    force: float
    work: float


def _names(module, fields, prefix=""):
    import dataclasses

    out = []
    for f in (d.name for d in dataclasses.fields(module) if d.name in fields):
        n = int(np.size(getattr(module, f)))
        out += [f"{prefix}{f}"] if n == 1 else [f"{prefix}{f}[{i}]" for i in range(n)]
    return out


class Layout:
    """The flat parameter vector: names, blocks, centre (the fit's optimum) and how to rebuild
    the surrogate, the rig and the bench's four (five with the crosshead's ramp,
    :data:`RAMP_FIELD`) from it."""

    def __init__(self, model, rig, bench_scene):
        ef, self._ef_static = pipeline._split(model, pipeline.EF_FIELDS)
        mech, _ = pipeline._split(model, MECHANICS)
        self._mech_static = pipeline._split(model, MECHANICS)[1]
        rig_params, self._rig_static = pipeline._split(rig, RIG)
        self.fitted_model, self.fitted_rig = model, rig
        flat_ef, self._unravel_ef = ravel_pytree(ef)
        flat_mech, self._unravel_mech = ravel_pytree((mech, rig_params))
        ef_names = _names(model, pipeline.EF_FIELDS)
        # the quadratic rate's (p0, p1) as its softplus-arguments at QUADRATIC_OMEGAS: a linear
        # map, so that b at either end is one positive coordinate
        quadratic = [ef_names.index(f"ef_quadratic[{i}]") for i in range(2)]
        w = np.array([centred_omega(o) for o in QUADRATIC_OMEGAS])
        self._to_layout = np.eye(len(ef_names))
        self._to_layout[np.ix_(quadratic, quadratic)] = np.stack([np.ones(2), w], axis=1)
        self._from_layout = np.linalg.inv(self._to_layout)
        for i, o in zip(quadratic, QUADRATIC_OMEGAS, strict=True):
            ef_names[i] = f"ef_quadratic(Omega {o:g})"
        flat_ef = self._to_layout @ np.asarray(flat_ef)
        fields = BENCH_FIELDS | (RAMP_FIELD if float(bench_scene.ramp_time) > 0.0 else {})
        self.bench_names, self.bench_scene_fields = tuple(fields), tuple(fields.values())
        bench = np.log(np.array([float(getattr(bench_scene, f)) for f in fields.values()]))
        self.centre = np.concatenate([flat_ef, np.asarray(flat_mech), bench])
        n_ef, n_mech = flat_ef.size, flat_mech.size
        self.blocks = {
            "ef": slice(0, n_ef),
            "mechanics": slice(n_ef, n_ef + n_mech),
            "bench": slice(n_ef + n_mech, n_ef + n_mech + bench.size),
        }
        self.names = tuple(
            ef_names
            + _names(model, MECHANICS)
            + _names(rig, RIG)
            + list(self.bench_names)
        )

    @property
    def positive(self) -> np.ndarray:
        """Which parameters are softplus-inverses of positive coefficients (:data:`POSITIVE`)."""
        return np.array([n.split("[")[0].split("(")[0] in POSITIVE for n in self.names])

    def natural(self, theta, cols=None):
        """The Laplace's coordinates: ``softplus(theta)`` where :attr:`positive`, else theta.
        ``cols``: ``theta`` holds only these columns (a block's slice; default all)."""
        theta = np.asarray(theta, float)
        return np.where(self._positive(cols), np.logaddexp(0.0, theta), theta)

    def raw(self, natural, cols=None):
        """The inverse of :meth:`natural` (its positive coordinates must be > 0)."""
        natural = np.asarray(natural, float)
        with np.errstate(invalid="ignore", divide="ignore"):  # where() evaluates both sides
            inverse = natural + np.log(-np.expm1(-natural))
        return np.where(self._positive(cols), inverse, natural)

    def natural_slope(self, theta, cols=None):
        """d natural / d theta: ``sigmoid(theta)`` where :attr:`positive`, else 1."""
        theta = np.asarray(theta, float)
        return np.where(self._positive(cols), 1.0 / (1.0 + np.exp(-theta)), 1.0)

    def _positive(self, cols):
        return self.positive if cols is None else self.positive[cols]

    def pump(self, theta):
        """The surrogate whose EF and mechanics parameters are ``theta``'s."""
        ef = self._unravel_ef(jnp.asarray(self._from_layout) @ theta[self.blocks["ef"]])
        mech, _ = self._unravel_mech(theta[self.blocks["mechanics"]])
        model = eqx.combine(ef, self._ef_static)
        fields = MECHANICS
        return eqx.tree_at(
            lambda m: [getattr(m, f) for f in fields], model, [getattr(mech, f) for f in fields]
        )

    def rig(self, theta) -> pipeline.Rig:
        _, rig = self._unravel_mech(theta[self.blocks["mechanics"]])
        return eqx.combine(rig, self._rig_static)

    def prior_rows(self, block: str):
        """(indices into theta, means, sds) of the block's normal priors."""
        idx = [i for i, n in enumerate(self.names) if n in PRIORS and self.block_of(i) == block]
        mu = np.array([PRIORS[self.names[i]][0] for i in idx])
        sd = np.array([PRIORS[self.names[i]][1] for i in idx])
        return np.array(idx, dtype=int), mu, sd

    def block_of(self, i: int) -> str:
        return next(b for b, s in self.blocks.items() if s.start <= i < s.stop)


class Data(NamedTuple):
    """The training data with their measurement sds (SI)."""

    t: pipeline.Targets
    static_sv_sd: np.ndarray  # m^3
    peak_force_sd: np.ndarray  # N
    mech_work_sd: np.ndarray  # J
    dynamic_sv: np.ndarray  # m^3
    dynamic_sv_sd: np.ndarray  # m^3


def training_data(data) -> Data:
    """The targets of the fit and the paper's SDs (Sec. III-D) in SI."""
    t = pipeline.targets(data)
    b = data.fig10_bench
    dyn = np.asarray(b["dynamic_sv_ml"], float) * 1e-6
    dyn_sd = np.asarray(b["dynamic_sv_sd_ml"], float) * 1e-6
    e = np.asarray(b["efficiency"], float)
    work_rel = np.sqrt((dyn_sd / dyn) ** 2 + (EFFICIENCY_ROUNDING / e) ** 2)
    return Data(
        t=t,
        static_sv_sd=np.asarray(t.static_sv_sd, float),
        peak_force_sd=np.asarray(b["peak_force_sd_N"], float),
        mech_work_sd=work_rel * t.mech_work,
        dynamic_sv=dyn,
        dynamic_sv_sd=dyn_sd,
    )


def ef_sigma(s0_ef: float) -> float:
    """The EF residuals' sd (fraction): Table I's rounding and the discrepancy."""
    return float(np.sqrt(FEM_ROUNDING**2 + s0_ef**2))


def ef_residuals(layout: Layout, d: Data, s0: Sigmas):
    """r_ef(theta): the fit's stage-1 residuals (soft-L1 Table I cells, anchor, ridge) times
    ``EF_SCALE / sigma_ef`` (module docstring)."""
    scale = pipeline.EF_SCALE / ef_sigma(s0.ef)
    ones = jnp.ones(len(d.t.t1_ef))

    def residual(theta):
        return pipeline.ef_residuals(layout.pump(theta), d.t, ones) * scale

    return residual


class MechanicsOutputs(NamedTuple):
    """What the mechanics block predicts of its data (SI), before whitening."""

    static_sv: jax.Array
    peak_force: jax.Array
    mech_work: jax.Array


def mechanics_outputs(layout: Layout, d: Data):
    """theta -> the quasi-static bench's SVs, peak forces and works (the rows that get a
    discrepancy)."""

    def outputs(theta):
        b = pipeline.bench_prediction(layout.pump(theta), layout.rig(theta), d.t.afterload)
        return MechanicsOutputs(b.static_sv, b.peak_force, b.mech_work)

    return outputs


def smallest_stiffness(layout: Layout):
    """theta -> the smallest ``d2U/dV2 / E_u`` of its surrogate on the fit's grid
    (``pipeline.CONVEXITY_FIT_GRID``): inside the prior's support where it is at least
    ``pipeline.CONVEXITY_MARGIN`` (module docstring, "Support")."""
    n_omega, n_c, n_v = pipeline.CONVEXITY_FIT_GRID
    dom = layout.fitted_model.domain
    omegas, cs = jnp.linspace(*dom.omega, n_omega), jnp.linspace(*dom.shortening, n_c)
    return lambda theta: jnp.min(pipeline.stiffness_grid(layout.pump(theta), omegas, cs, n_v))


FEM_ROWS = ("efficiency_helical", "efficiency_longitudinal", "mech_ratio", "hydraulic_ratio")
"""The FEM comparisons among :func:`mechanics_fixed_rows`, in their order."""


def mechanics_fixed_rows(layout: Layout, d: Data):
    """theta -> the mechanics block's rows whose sigmas do not depend on the discrepancy: the
    support (0 inside, +inf outside; module docstring), the FEM comparisons (the fit's own
    scales), and the priors."""
    t = d.t
    idx, mu, sd = layout.prior_rows("mechanics")
    smallest = smallest_stiffness(layout)

    def rows(theta):
        model, rig = layout.pump(theta), layout.rig(theta)
        fem = pipeline.fem_prediction(model, rig)
        inside = smallest(theta) >= pipeline.CONVEXITY_MARGIN
        return jnp.concatenate(
            [
                jnp.where(inside, 0.0, jnp.inf)[None],
                jnp.stack(  # FEM_ROWS
                    [
                        (fem.efficiency_helical - t.fem_efficiency_helical) / 0.02,
                        (fem.efficiency_longitudinal - t.fem_efficiency_longitudinal) / 0.02,
                        (fem.mech_ratio - t.fem_mech_ratio) / (0.1 * t.fem_mech_ratio),
                        (fem.hydraulic_ratio - t.fem_hydraulic_ratio)
                        / (0.1 * t.fem_hydraulic_ratio),
                    ]
                ),
                (theta[idx] - mu) / sd,
            ]
        )

    return rows


def mechanics_sds(d: Data, s0: Sigmas) -> MechanicsOutputs:
    """The sds (SI) of the mechanics block's bench rows: measurement and discrepancy."""
    return MechanicsOutputs(
        np.sqrt(d.static_sv_sd**2 + s0.static_sv**2),
        np.sqrt(d.peak_force_sd**2 + s0.force**2),
        np.sqrt(d.mech_work_sd**2 + s0.work**2),
    )


def joint_residuals(layout: Layout, d: Data, s0: Sigmas, scene, steady: str = "beats",
                    keep=None):
    """r(theta) of the mechanics and bench block (:data:`fit.posterior.laplace.JOINT`): the
    quasi-static SVs and peak forces over their sds, :func:`mechanics_fixed_rows`, then
    :func:`bench_residuals`. The paper's work M enters once, as the dynamic work.

    ``steady``: how the bench's periodic state is reached (:func:`cardiosoft.batch.solve_beats`);
    ``keep``: which afterloads keep their four data rows (bools; default all), the others read
    0 whatever their solve gave (the leave-one-afterload-out check)."""
    outputs, fixed = mechanics_outputs(layout, d), mechanics_fixed_rows(layout, d)
    bench = bench_residuals(layout, d, s0, scene, steady)
    sds = mechanics_sds(d, s0)
    t = d.t

    def residual(theta):
        o = outputs(theta)
        return jnp.concatenate(
            [
                (o.static_sv - t.static_sv) / sds.static_sv,
                (o.peak_force - t.peak_force) / sds.peak_force,
                fixed(theta),
                bench(theta),
            ]
        )

    if keep is None or np.all(keep):
        return residual
    keep = np.asarray(keep, bool)
    others = [len(layout.prior_rows(block)[0]) for block in ("mechanics", "bench")]
    mask = np.concatenate([keep, keep, np.ones(1 + len(FEM_ROWS) + others[0], bool), keep, keep,
                           np.ones(others[1], bool)])
    return lambda theta: jnp.where(mask, residual(theta), 0.0)


class BenchOutputs(NamedTuple):
    """The dynamic bench at 30 bpm (SI): the paper's dynamic SV (the pump's EDV - ESV), the
    mechanical work of the pull and the peak force (not fitted: validation)."""

    dynamic_sv: jax.Array
    mech_work: jax.Array
    peak_force: jax.Array


def bench_scene_at(scene, layout: Layout, theta):
    """The bench scene with theta's tube, viscoelasticity, column and cable friction."""
    tube = jnp.exp(theta[layout.blocks["bench"]])
    rig = layout.rig(theta)
    return scene.replace(
        **dict(zip(layout.bench_scene_fields, tube, strict=True)),
        column_diameter=rig.column_diameter,
        cable_friction=rig.cable_friction,
    )


def bench_config():
    """fit.bench's solver: Tsit5 at rtol 1e-7, forward-mode derivatives."""
    from cardiosoft.solve import SolverConfig

    return SolverConfig(
        diffrax.Tsit5(), rtol=BENCH_RTOL, atol=BENCH_ATOL, adjoint=diffrax.ForwardMode()
    )


def bench_outputs(layout: Layout, scene, heads, steady: str = "beats"):
    """theta -> :class:`BenchOutputs` at the column heads (Pa), one batched solve."""
    from cardiosoft.batch import solve_beats
    from cardiosoft.posterior import ENSEMBLE_MAX_BEATS

    config = bench_config()
    # a draw with a slow shell (relaxation times of tens of seconds) needs more beats to its
    # steady state than the scene allows; cut off, it would read as a failed solve and weigh
    # nothing in the posterior's importance weights or NUTS. The optimum stops where it did.
    scene = scene.replace(max_beats=max(scene.max_beats, ENSEMBLE_MAX_BEATS))

    def outputs(theta):
        out = solve_beats(
            bench_scene_at(scene, layout, theta),
            afterload=heads,
            save="metrics",
            pump=layout.pump(theta),
            config=config,
            steady=steady,
        )
        m = out.metrics
        ok = out.succeeded & out.steady
        bad = jnp.where(ok, 0.0, jnp.nan)  # a failed solve must not pass for a number
        return BenchOutputs(m.stroke_volume + bad, m.mech_work + bad, m.peak_force + bad)

    return outputs


def bench_sds(d: Data, s0: Sigmas):
    """(dynamic SV sd, work sd) of the bench rows (SI): measurement and discrepancy."""
    return (
        np.sqrt(d.dynamic_sv_sd**2 + s0.dynamic_sv**2),
        np.sqrt(d.mech_work_sd**2 + s0.work**2),
    )


def bench_residuals(layout: Layout, d: Data, s0: Sigmas, scene, steady: str = "beats"):
    """r_bench(theta): dynamic SVs and works over their sds, then the bench priors."""
    outputs = bench_outputs(layout, scene, d.t.afterload, steady)
    sv_sd, work_sd = bench_sds(d, s0)
    idx, mu, sd = layout.prior_rows("bench")

    def residual(theta):
        o = outputs(theta)
        return jnp.concatenate(
            [
                (o.dynamic_sv - d.dynamic_sv) / sv_sd,
                (o.mech_work - d.t.mech_work) / work_sd,
                (theta[idx] - mu) / sd,
            ]
        )

    return residual
