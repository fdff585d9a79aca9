"""Our network next to svZeroDSolver on its closed-loop heart case, at equal accuracy.

    python benchmarks/svzerod_heart.py [--variants 1000] [--loop 1000]   # ~10 min on 2 cores
    python benchmarks/svzerod_heart.py --loop 100 --figure docs/figures/wp_heart.png  # the site

The case is upstream's ``closedLoopHeart_singleVessel`` (``tests/data/svzerod/``): the combined
heart block, an aorta and a closed-loop RCR, 10 beats from its initial condition. Its converged
answer is ``svzerod`` at 256 points a step of the case (25,600 points a beat). The error of a
solve is the largest deviation, over the last beat's samples, of any pressure or volume from
that answer, relative to the variable's largest magnitude (valve flows are left out: a closed
valve's flow is 0 here and its inductor's drift in svzerod, see ``tests/test_network.py``).

Prints:

1. the work-precision table of both solvers (and its diagram, ``--figure``, by default
   ``work_precision_svzerod_heart.png`` in the current folder):
   ``svzerod`` at 1, 2, 4, ... times the case's points a beat, ours at a range of rtol, each
   with its error and its wall time per run (warm: compiled, in-process; the best of 3);
2. the wall time per beat of one model at an error of 1e-4, each solver at the cheapest
   setting that reaches it;
3. the wall time of ``--variants`` parameter variants (Elv_s, Erv_s, Rlv_ao and the RCR's Rd
   each scaled by a factor in [0.9, 1.1]): ours in one batched call (its compile reported
   apart), ``svzerod`` in a loop at the setting that reaches 1e-4 (``--loop`` of them timed, the
   rest extrapolated and said so), and the ratio.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402

from cardiosoft import network  # noqa: E402

CASE = Path(__file__).resolve().parent.parent / "tests" / "data" / "svzerod"
CASE = CASE / "closedLoopHeart_singleVessel.json"
TARGET = 1e-4
REFERENCE_REFINEMENT = 256


def compared(names):
    return [n for n in names if not (n.startswith("Q_") and n.endswith(":CLH"))]


def error(values: dict, reference: dict) -> float:
    return max(
        float(np.max(np.abs(values[k] - reference[k])) / np.max(np.abs(reference[k])))
        for k in compared(reference)
    )


def best_of(f, repeat=3):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - start)
    return min(times), out


def variant_networks(net, factors):
    """The network with Elv_s, Erv_s, Rlv_ao and the RCR's Rd scaled by ``factors`` (n x 4)."""
    heart = next(i for i, b in enumerate(net.blocks) if b.kind == "ClosedLoopHeartAndPulmonary")
    rcr = next(i for i, b in enumerate(net.blocks) if b.kind == "ClosedLoopRCR")

    def one(f):
        p = dict(net.blocks[heart].p)
        p["Elv_s"], p["Erv_s"], p["Rlv_ao"] = (
            p["Elv_s"] * f[0],
            p["Erv_s"] * f[1],
            p["Rlv_ao"] * f[2],
        )
        out = eqx.tree_at(lambda n: n.blocks[heart].p, net, p)
        return eqx.tree_at(lambda n: n.blocks[rcr].Rd, out, net.blocks[rcr].Rd * f[3])

    return jax.vmap(one)(factors)


def variant_config(config: dict, f) -> dict:
    config = json.loads(json.dumps(config))
    heart = config["closed_loop_blocks"][0]["parameters"]
    heart["Elv_s"] *= f[0]
    heart["Erv_s"] *= f[1]
    heart["Rlv_ao"] *= f[2]
    config["boundary_conditions"][0]["bc_values"]["Rd"] *= f[3]
    return config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", type=int, default=1000)
    parser.add_argument("--loop", type=int, default=1000, help="svzerod runs to time")
    parser.add_argument(
        "--figure", default="work_precision_svzerod_heart.png", help="the diagram's file"
    )
    args = parser.parse_args()
    config = json.loads(CASE.read_text())
    beats = config["simulation_parameters"]["number_of_cardiac_cycles"]
    model = network.read(config, "closedLoopHeart_singleVessel")
    print(f"reference: svzerod at {REFERENCE_REFINEMENT}x the case's points a beat ...")
    reference = network.run_svzerod(config, REFERENCE_REFINEMENT)

    print("\nwork-precision (wall time per run of 10 beats, warm, best of 3)")
    print(f"{'solver':10s} {'setting':>14s} {'error':>10s} {'time (s)':>10s}")
    svz_rows, our_rows = [], []
    for refine in (1, 2, 4, 8, 16, 32, 64):
        seconds, values = best_of(lambda r=refine: network.run_svzerod(config, r))
        svz_rows.append((refine, error(values, reference), seconds))
        setting = f"{refine * 99 + 1} pts/beat"
        print(f"{'svzerod':10s} {setting:>14s} {svz_rows[-1][1]:10.2e} {seconds:10.4f}")
    for rtol in (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        network.simulate(model, rtol=rtol)  # compile
        seconds, traces = best_of(lambda r=rtol: network.simulate(model, rtol=r))
        our_rows.append((rtol, error(traces.values, reference), seconds))
        print(f"{'ours':10s} {f'rtol {rtol:g}':>14s} {our_rows[-1][1]:10.2e} {seconds:10.4f}")
    plot(svz_rows, our_rows, Path(args.figure))

    svz_at = next(r for r in svz_rows if r[1] <= TARGET)
    ours_at = next(r for r in our_rows if r[1] <= TARGET)
    print(f"\none model at an error of {TARGET:g}, wall time per beat:")
    print(f"  svzerod {svz_at[2] / beats * 1e3:.2f} ms ({svz_at[0] * 99 + 1} points a beat)")
    print(f"  ours    {ours_at[2] / beats * 1e3:.2f} ms (rtol {ours_at[0]:g})")

    n = args.variants
    factors = np.random.default_rng(0).uniform(0.9, 1.1, size=(n, 4))
    nets = variant_networks(model.network, factors)
    start = time.perf_counter()
    traces = network.simulate(model, rtol=ours_at[0], variants=nets)
    first = time.perf_counter() - start
    ours_seconds, traces = best_of(
        lambda: network.simulate(model, rtol=ours_at[0], variants=nets), 1
    )
    loop = min(args.loop, n)
    start = time.perf_counter()
    for f in factors[:loop]:
        network.run_svzerod(variant_config(config, f), svz_at[0])
    svz_seconds = (time.perf_counter() - start) * n / loop
    print(f"\n{n} variants at an error of {TARGET:g} (all solved: {traces.solved}):")
    print(
        f"  ours, one batched call: {ours_seconds:.2f} s (first call, with compile: {first:.1f} s)"
    )
    note = "" if loop == n else f" ({loop} timed, extrapolated)"
    print(f"  svzerod, a loop:        {svz_seconds:.2f} s{note}")
    print(f"  ratio svzerod / ours:   {svz_seconds / ours_seconds:.1f}")


def plot(svz_rows, our_rows, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 4))
    for rows, label in ((svz_rows, "svzerod (fixed step)"), (our_rows, "cardiosoft (adaptive)")):
        ax.loglog([r[2] for r in rows], [r[1] for r in rows], "o-", label=label)
    ax.axhline(TARGET, color="grey", lw=0.8, ls="--")
    ax.set_xlabel("wall time per run of 10 beats (s)")
    ax.set_ylabel("error (max over pressures and volumes, relative)")
    ax.set_title("closedLoopHeart_singleVessel")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
