"""Calibrate the bench's tube to the paper's dynamic stroke volumes (Fig. 10(a), 30 bpm).

    python -m fit.bench            # prints the calibrated tube and the TOML lines for the scene

The paper does not give the silicone tube between pump and column. Its length and diameter set
the line's inertance, Poiseuille resistance and exit loss, and so how far the moving water
overshoots after the pull: the dynamic SV. They are fitted here with optax (Adam on log-sizes)
through diffrax, the three afterloads in one vmapped solve, gradients in forward mode
(``diffrax.ForwardMode``: two parameters, and the beat loop is a ``while_loop``). The column
diameter and the cable friction come from the surrogate's fit and are not refitted.
"""

from __future__ import annotations

import sys
import time

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

STEPS = 60
LEARNING_RATE = 0.05


def calibrate(progress=print):
    from cardiosoft import datasets
    from cardiosoft.experiment import _circuit, _simulate, _stack
    from cardiosoft.pump import load
    from cardiosoft.scene import load_scene
    from cardiosoft.solve import SolverConfig

    scene = load_scene("bench-dynamic")
    bench = datasets.load_paper_data().fig10_bench
    target = jnp.asarray(bench["dynamic_sv_ml"]) * 1e-6
    sd = jnp.asarray(bench["dynamic_sv_sd_ml"]) * 1e-6
    heads = tuple(jnp.asarray(bench["afterload_mmHg"]) * 133.322387415)
    pump = load()
    circuits = _stack([_circuit(scene, pump, h) for h in heads])
    config = SolverConfig(diffrax.Tsit5(), rtol=1e-7, atol=1e-12, adjoint=diffrax.ForwardMode())

    def with_tube(log_sizes):
        length, diameter = jnp.exp(log_sizes)
        return eqx.tree_at(
            lambda c: (c.afterload.tube.length, c.afterload.tube.diameter),
            circuits,
            (jnp.full(len(heads), length), jnp.full(len(heads), diameter)),
        )

    def residuals(log_sizes):
        _, _, metrics = _simulate(with_tube(log_sizes), scene.max_beats, scene.steady_tol, config)
        return (metrics.stroke_volume - target) / sd

    residual_and_jac = jax.jit(lambda p: (residuals(p), jax.jacfwd(residuals)(p)))
    params = jnp.log(jnp.array([scene.tube_length, scene.tube_diameter]))
    optimiser = optax.adam(LEARNING_RATE)
    state = optimiser.init(params)
    best = (np.inf, params)
    for step in range(STEPS):
        r, jac = residual_and_jac(params)
        loss = float(jnp.sum(r**2))
        if loss < best[0]:
            best = (loss, params)
        if step % 10 == 0 or step == STEPS - 1:
            length, diameter = np.exp(np.asarray(params)) * 1e3
            progress(
                f"  step {step:3d}: loss {loss:8.4f}  tube {length:7.1f} mm x "
                f"{diameter:5.2f} mm  SV residuals {np.round(np.asarray(r), 2)} sd"
            )
        updates, state = optimiser.update(2.0 * jac.T @ r, state)
        params = optax.apply_updates(params, updates)
    loss, params = best
    r, _ = residual_and_jac(params)
    sv = np.asarray(r * sd + target) / 1e-6
    return np.exp(np.asarray(params)), sv, np.asarray(target) / 1e-6, loss


def main() -> int:
    jax.config.update("jax_enable_x64", True)
    start = time.perf_counter()
    (length, diameter), sv, target, loss = calibrate(progress=lambda m: print(m, file=sys.stderr))
    print(
        f"calibrated in {time.perf_counter() - start:.0f} s; loss {loss:.4f} "
        "(sum of squared SV errors in units of the paper's sd)"
    )
    print(
        "dynamic SV [ml]: model "
        + ", ".join(f"{v:.1f}" for v in sv)
        + "; paper "
        + ", ".join(f"{v:.1f}" for v in target)
    )
    print("bench-dynamic.toml, [afterload]:")
    print(f"tube_length_mm = {length * 1e3:.1f}")
    print(f"tube_diameter_mm = {diameter * 1e3:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
