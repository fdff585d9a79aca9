"""Round-off sensitivity of stage 2 (issue #14): where the refit tolerances of tests/test_fit.py
come from.

    python -m fit.roundoff               # spectrum at the shipped artifact, then 60 refits
    python -m fit.roundoff --refits 0    # the spectrum only (~1 min on 2 cores)
    python -m fit.roundoff --free-held   # the spectrum with the HELD parameters freed too

The spectrum: eigenvalues and the softest eigenvectors of the Gauss-Newton matrix 2 J^T J of the
stage-2 loss in the raw parameters the fit frees, at the shipped artifact. The refits: stage 2
again with the bench targets (even-numbered refits) or the stage-1 parameters (odd) multiplied by
1 + 1e-9 N(0, 1); printed are the range of each headline metric, rig value and raw parameter over
them, relative to the card for the metrics and the rig, and 1.5 times it as the tolerance.
"""

from __future__ import annotations

import argparse
import math

import numpy as np


def _names(module, fields):
    """Names of the raw parameters in ``fields``, in the order ravel_pytree flattens them."""
    import dataclasses

    out = []
    for f in (d.name for d in dataclasses.fields(module) if d.name in fields):
        n = int(np.size(getattr(module, f)))
        out += [f] if n == 1 else [f"{f}[{i}]" for i in range(n)]
    return out


def spectrum(model, rig, t, mech_fields, rig_fields):
    """(eigenvalues, eigenvectors as columns, parameter names) of 2 J^T J."""
    import equinox as eqx
    import jax
    from jax.flatten_util import ravel_pytree

    from fit import pipeline

    p, static = pipeline._split(model, mech_fields)
    r, rig_static = pipeline._split(rig, rig_fields)
    flat, unravel = ravel_pytree((p, r))

    def residual(v):
        p, r = unravel(v)
        return pipeline.all_residuals(eqx.combine(p, static), eqx.combine(r, rig_static), t)

    jac = np.asarray(jax.jit(jax.jacfwd(residual))(flat))
    w, v = np.linalg.eigh(2 * jac.T @ jac)
    return w, v, _names(model, mech_fields) + _names(rig, rig_fields)


def _up(x):
    """``x`` rounded up to 2 significant digits."""
    if x <= 0:
        return 0.0
    e = math.floor(math.log10(x)) - 1
    return round(math.ceil(x / 10**e) * 10**e, 12)


def main(argv=None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)

    import equinox as eqx
    import jax.numpy as jnp

    from cardiosoft import datasets
    from cardiosoft.pump import load, load_card
    from cardiosoft.units import mm, mmHg
    from fit import fitting, pipeline, report

    parser = argparse.ArgumentParser(
        prog="python -m fit.roundoff", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--refits", type=int, default=60, help="perturbed refits (default 60)")
    parser.add_argument("--free-held", action="store_true", help="spectrum with HELD freed too")
    args = parser.parse_args(argv)

    data = datasets.load_paper_data()
    t = pipeline.targets(data)
    shipped, card = load(), load_card()
    mech, rig_fields = pipeline.MECHANICS_FIELDS, pipeline.RIG_FIELDS
    if args.free_held:
        mech, rig_fields = (*mech, "fold_compliance"), (*rig_fields, "log_column_diameter")
    w, v, names = spectrum(shipped, fitting.rig_from_card(card), t, mech, rig_fields)
    print("2 J^T J at the shipped artifact: eigenvalues", " ".join(f"{x:.3g}" for x in w))
    print(f"  condition {w[-1] / w[0]:.3g}")
    for k in range(2):
        parts = ", ".join(
            f"{n} {x:+.2f}" for n, x in zip(names, v[:, k], strict=True) if abs(x) > 0.05
        )
        print(f"  eigenvector {k} ({w[k]:.3g}): {parts}")
    if args.refits <= 0:
        return 0

    n = len(t.t1_ef)
    start = eqx.tree_at(
        lambda m: m.three_fold_boundary,
        fitting.initial_model(),
        jnp.asarray(fitting.three_fold_boundary(data.table1_fem)),
    )
    params, static = pipeline.fit_zero_pressure_law(start, t, jnp.ones((1, n)))
    stage1 = eqx.combine(jax.tree_util.tree_map(lambda a: a[0], params), static)
    metric_keys = ("static_sv_ml", "peak_force_N", "mech_work_J")
    runs = []
    for i in range(args.refits):
        rng = np.random.default_rng(i + 1)

        def perturbed(a, rng=rng):
            return a * (1 + 1e-9 * rng.standard_normal(np.shape(a))) if eqx.is_array(a) else a

        t_i, s1 = t, stage1
        if i % 2 == 0:
            bench = ("static_sv", "peak_force", "mech_work")
            t_i = t._replace(**{k: perturbed(np.asarray(getattr(t, k))) for k in bench})
        else:
            s1 = jax.tree_util.tree_map(perturbed, stage1)
        model, rig, _ = pipeline.fit_mechanics(pipeline.mechanics_start(s1), pipeline.Rig(), t_i)
        m = report.metrics(model, rig, data)
        run = {k: np.asarray(m[k]) for k in metric_keys}
        run["cable_friction_exponent"] = np.asarray(float(rig.cable_friction))
        run["fem_pressure_mmHg"] = np.asarray(float(rig.fem_pressure / mmHg))
        run["column_diameter_mm"] = np.asarray(float(rig.column_diameter / mm))
        for f in pipeline.MECHANICS_FIELDS:
            run[f] = np.atleast_1d(np.asarray(getattr(model, f)))
        runs.append(run)
        print(f"refit {i + 1}/{args.refits}", flush=True)

    print(f"range over {len(runs)} refits, relative or raw; tolerance 1.5 x range (2 digits up):")
    for key in runs[0]:
        a = np.array([np.atleast_1d(r[key]) for r in runs])
        if key in metric_keys or key in card["rig"]:
            ref = np.atleast_1d(card["metrics"][key] if key in metric_keys else card["rig"][key])
            spread, kind = np.ptp(a, 0) / np.abs(ref), "relative"
        else:
            ref = np.atleast_1d(np.asarray(getattr(shipped, key)))
            spread, kind = np.ptp(a, 0), "raw"
        inside = bool(np.all((a.min(0) <= ref) & (ref <= a.max(0))))
        print(
            f"  {key}: range {[float(f'{x:.3g}') for x in spread]} ({kind}), tolerance "
            f"{[_up(1.5 * x) for x in spread]}; the card's value inside: {inside}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
