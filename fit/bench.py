"""Calibrate the bench's unknowns to the paper's dynamic measurements (Fig. 10, 30 bpm).

    python -m fit.bench                # prints the calibrated rig and the TOML lines for the scene
    python -m fit.bench --peak-forces  # the same fit with the paper's peak forces as targets too

The paper gives neither the silicone tube between pump and column nor the shell's rate
dependence. Four unknowns are fitted here with optax (Adam on their logarithms) through diffrax,
the three afterloads in one vmapped solve, gradients in forward mode (``diffrax.ForwardMode``:
four parameters, and the beat loop is a ``while_loop``):

- the tube's length and diameter: its inertance, Poiseuille resistance and exit loss;
- the shell's viscoelasticity (``cardiosoft.circuit.ShellViscoelasticity``): how much stiffer
  the chamber is to a 1-s stroke than to a static one, and how fast it relaxes.

They are fitted to the six dynamic measurements of the same runs: the dynamic SVs (in units of
the paper's sd) and the mechanical work of the pull, M = P_a SV / e (section II-F; residuals in
units of 2 % of M, about the SVs' relative sd). Peak forces are not used: they validate. The
column diameter and the cable friction come from the surrogate's fit and are not refitted.

The calibration starts from the scene's values and takes a fixed 150 Adam steps. On the format-3
surrogate (ss950-v3; started from the ss950-v2 calibration, 124.6 x 18.94 mm, r 0.136, tau
0.387 s) it gave 276.3 x 19.09 mm, r 0.227, tau 2.25 s, loss 1.81. The data leave a flat valley
along the tube's length and tau (measured 2026-12-02 on a first ss950-v3 candidate, with the
swelling's onset fitted): 320 steps went from 274.6 mm, tau 1.76 s, loss 2.37 on to 319.5 mm,
tau 2.49 s, loss 2.26, every residual moving by less than 0.1 of its unit. Neither end of the
valley can be held: with the tube held at 124.6 mm the best loss was 26 (the 90-mmHg dynamic SV
6 sd low: the column's inertia is what lifts the dynamic SVs above the static ones), with tau
held at 0.387 s 2.61 with a 400-mm tube. The tube's inertance puts the column's sloshing near
0.4-0.5 Hz, so beyond 30 bpm the bench rings: at 60 bpm the pump pressure swings to 167-212
mmHg at 60 and 90 mmHg heads, outside the surrogate's fitted range (flagged).

The crosshead's ramp time (``actuation.ramp_time_s``) is held at the scene's value: ss950-v4's
bench holds 50 ms, the median of its prior (``fit.posterior.blocks.PRIORS``), with the tube and
viscoelasticity calibrated at 0 ms (the ideal crosshead). Recalibrated with the ramp
(2026-12-05, 150 steps from those numbers) the loss fell only from 4.36 to 1.46 while the tube
drifted along the valley to a 52-mm bore, past its prior's 13-29 mm, and a 15-ms relaxation:
the point calibration has no prior to stop it, so it is not used, and the posterior, which has
them, samples all five.

``--peak-forces`` adds the three peak forces (residuals in units of 2 % of the force) to see
whether the bench's unknowns could bring them within 5 %. On ss950-v2 (2026-12-01) they did
not (10.6 % at best); on ss950-v3 the calibration without them already gives 6.2 %. The
calibrated forces are printed, and the TOML lines are for that fit, not the shipped one.
"""

from __future__ import annotations

import sys
import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optax

STEPS = 150
LEARNING_RATE = 0.05
WORK_SCALE = 0.02  # residual unit of the mechanical work, relative
FORCE_SCALE = 0.02  # residual unit of the peak force with --peak-forces, relative
NAMES = ("tube_length_mm", "tube_diameter_mm", "stiffness_ratio", "relaxation_time_s")


def surrogate_rig(pump_name=None) -> dict:
    """The rig numbers fitted with the surrogate (its card's ``rig``), as a bench scene's
    keys: the column's diameter and the cable friction."""
    from cardiosoft.pump import load_card

    rig = load_card(pump_name)["rig"]
    return {
        "column_diameter_mm": rig["column_diameter_mm"],
        "exponent": rig["cable_friction_exponent"],
    }


def calibrate(progress=print, peak_forces: bool = False, pump_name=None, steps: int = STEPS):
    """Returns (rig values in the units of NAMES, model SV ml, M J, peak force N, targets, loss).

    ``peak_forces``: fit the paper's peak forces too (module docstring). ``pump_name``: the
    surrogate (default: the shipped default). The column and the cable friction are the
    surrogate's own (its card); the calibration starts from the scene's numbers for that pump
    where it has them, else from its own.
    """
    from cardiosoft import datasets
    from cardiosoft.batch import solve_beats
    from cardiosoft.pump import load
    from cardiosoft.scene import load_scene
    from cardiosoft.solve import SolverConfig
    from cardiosoft.units import mm, mmHg

    try:
        scene = load_scene("bench-dynamic", pump=pump_name)
    except ValueError:  # no numbers for this pump yet: start from the scene's own
        scene = load_scene("bench-dynamic")
    own = surrogate_rig(pump_name)
    scene = scene.replace(
        column_diameter=own["column_diameter_mm"] * mm, cable_friction=own["exponent"]
    )
    bench = datasets.load_paper_data().fig10_bench
    sv_target = jnp.asarray(bench["dynamic_sv_ml"]) * 1e-6
    sv_sd = jnp.asarray(bench["dynamic_sv_sd_ml"]) * 1e-6
    heads = jnp.asarray(bench["afterload_mmHg"]) * mmHg
    work_target = heads * sv_target / jnp.asarray(bench["efficiency"])
    force_target = jnp.asarray(bench["peak_force_N"])
    pump = load(pump_name)
    config = SolverConfig(diffrax.Tsit5(), rtol=1e-7, atol=1e-12, adjoint=diffrax.ForwardMode())

    def outputs(log_rig):
        length, diameter, ratio, tau = jnp.exp(log_rig)
        rig = scene.replace(
            tube_length=length,
            tube_diameter=diameter,
            viscoelastic_ratio=ratio,
            relaxation_time=tau,
        )
        out = solve_beats(rig, afterload=heads, save="metrics", pump=pump, config=config)
        return out.metrics.stroke_volume, out.metrics.mech_work, out.metrics.peak_force

    def residuals(log_rig):
        sv, work, force = outputs(log_rig)
        r = [(sv - sv_target) / sv_sd, (work - work_target) / (WORK_SCALE * work_target)]
        if peak_forces:
            r.append((force - force_target) / (FORCE_SCALE * force_target))
        return jnp.concatenate(r)

    residual_and_jac = jax.jit(lambda p: (residuals(p), jax.jacfwd(residuals)(p)))
    start = (scene.tube_length, scene.tube_diameter)
    start += (scene.viscoelastic_ratio, scene.relaxation_time)
    params = jnp.log(jnp.array(start))
    optimiser = optax.adam(LEARNING_RATE)
    state = optimiser.init(params)
    best = (np.inf, params)
    for step in range(steps):
        r, jac = residual_and_jac(params)
        loss = float(jnp.sum(r**2))
        if loss < best[0]:
            best = (loss, params)
        if step % 10 == 0 or step == steps - 1:
            rig = np.exp(np.asarray(params)) * np.array([1e3, 1e3, 1.0, 1.0])
            progress(
                f"  step {step:3d}: loss {loss:8.4f}  tube {rig[0]:6.1f} x {rig[1]:5.2f} mm, "
                f"r {rig[2]:5.2f}, tau {rig[3]:6.2f} s  residuals {np.round(np.asarray(r), 2)}"
            )
        updates, state = optimiser.update(2.0 * jac.T @ r, state)
        params = optax.apply_updates(params, updates)
    loss, params = best
    sv, work, force = jax.jit(outputs)(params)
    rig = np.exp(np.asarray(params)) * np.array([1e3, 1e3, 1.0, 1.0])
    targets = (np.asarray(sv_target) / 1e-6, np.asarray(work_target), np.asarray(force_target))
    return rig, np.asarray(sv) / 1e-6, np.asarray(work), np.asarray(force), targets, loss


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m fit.bench", description=__doc__.split("\n")[0])
    parser.add_argument(
        "--peak-forces", action="store_true", help="fit the paper's peak forces too (a check)"
    )
    parser.add_argument(
        "--pump", metavar="NAME", help="the surrogate to calibrate with (default: the default)"
    )
    parser.add_argument(
        "--steps", type=int, default=STEPS, help=f"Adam steps (default {STEPS})"
    )
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    from cardiosoft.scene import load_scene

    start = time.perf_counter()
    rig, sv, work, force, (sv_target, work_target, force_target), loss = calibrate(
        progress=lambda m: print(m, file=sys.stderr),
        peak_forces=args.peak_forces,
        pump_name=args.pump,
        steps=args.steps,
    )
    units = f"SV in the paper's sd, M in {WORK_SCALE:.0%} of M"
    if args.peak_forces:
        units += f", peak force in {FORCE_SCALE:.0%} of it"
    print(
        f"calibrated in {time.perf_counter() - start:.0f} s; loss {loss:.4f} (sum of squared "
        f"residuals: {units})"
    )
    for name, model, paper, unit in (
        ("dynamic SV", sv, sv_target, "ml"),
        ("mech. work M", work, work_target, "J"),
        ("peak force", force, force_target, "N"),
    ):
        print(
            f"{name} [{unit}]: model {', '.join(f'{v:.2f}' for v in model)}; "
            f"paper {', '.join(f'{v:.2f}' for v in paper)}"
        )
    print(f"peak force, worst relative error: {np.max(np.abs(force / force_target - 1)):.3f}")
    own = surrogate_rig(args.pump)
    where = "" if args.pump is None else f'calibration."{args.pump}".'
    print(f"bench-dynamic.toml{' (a table of its own for this pump)' if where else ''}:")
    ramp = float(load_scene("bench-dynamic", pump=args.pump).ramp_time)
    if ramp > 0.0:
        print(f"[{where}actuation]")
        print(f"ramp_time_s = {ramp:g}  # held, not calibrated (fit.posterior samples it)")
    print(f"[{where}afterload]")
    print(f"column_diameter_mm = {own['column_diameter_mm']:.2f}  # the surrogate's card")
    print(f"tube_length_mm = {rig[0]:.1f}")
    print(f"tube_diameter_mm = {rig[1]:.3f}")
    print(f"[{where}cable_friction]")
    print(f"exponent = {own['exponent']:.4f}  # the surrogate's card")
    print(f"[{where}shell_viscoelasticity]")
    print(f"stiffness_ratio = {rig[2]:.3f}")
    print(f"relaxation_time_s = {rig[3]:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
