"""Compute, check or test the posterior of the shipped surrogate (fit.posterior).

    python -m fit.posterior            # compute and write surrogates/<name>-posterior.{npz,json}
    python -m fit.posterior --nuts     # NUTS on the EF block against its Laplace
    python -m fit.posterior --importance  # the mechanics+bench block by importance sampling
    python -m fit.posterior --smc      # the mechanics+bench block by tempered SMC
    python -m fit.posterior --smc-pilot  # ... from an independent pilot, against the shipped
    python -m fit.posterior --check    # Table II and the 30-bpm bench against their bands
    python -m fit.posterior --sbc      # simulation-based calibration of the EF block
    python -m fit.posterior --sbc --block mechanics+bench  # ... of the rest's Laplace
    python -m fit.posterior --sobol    # Sobol indices (SALib) against the linear shares

Run from the repository root after ``python -m fit`` and ``python -m fit.bench`` (the bench
scene's calibrated numbers are the bench block's centre). An existing posterior is not
overwritten without --force; --nuts records its result in the posterior's card.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def _print_parameters(pcard: dict) -> None:
    print("parameter                          block       centre     mean       sd  Laplace sd"
          "   (softplus(raw) where marked +, else raw; mean and sd of the draws)")
    for name, p in pcard["parameters"].items():
        mark = "+" if p["coordinate"] != "raw" else " "
        print(f"{mark} {name:32s} {p['block']:9s} {p['centre']:10.4g} {p['mean']:8.4g} "
              f"{p['sd']:8.3g} {p['laplace_sd']:10.3g}")


def _print_discrepancy(pcard: dict) -> None:
    d = pcard["discrepancy"]
    print("model discrepancy (s0 from leave-one-out; s1 far from the calibrated conditions):")
    print(
        f"  EF volume: s0 {d['ef_volume']['s0'] * 1e6:.2f} ml (Table I leave-one-out mean "
        f"|error| {pcard['table1_loo_mae_ml']['linearised']:.2f} ml linearised, "
        f"{pcard['table1_loo_mae_ml']['refitted_by_the_fit']} ml refitted by the fit)"
    )
    for kind, unit, scale in (
        ("static_sv", "ml", 1e6), ("dynamic_sv", "ml", 1e6), ("force", "N", 1.0),
        ("work", "J", 1.0),
    ):
        loo = ", ".join(f"{x * scale:+.2f}" for x in d[kind]["loo"])
        print(
            f"  {kind:10s}: s0 {d[kind]['s0'] * scale:.3g} {unit}, s1 {d[kind]['s1'] * scale:.3g} "
            f"{unit}; leave-one-out errors [{unit}] {loo}"
        )


def _record(card_path, key: str, value) -> None:
    """Write ``value`` under ``key`` into the posterior card at ``card_path`` (whole or not at
    all). The card is not hashed: the draws' .npz is."""
    from cardiosoft.files import atomic_path

    pcard = json.loads(card_path.read_text()) | {key: value}
    with atomic_path(card_path) as tmp:
        tmp.write_text(json.dumps(pcard, indent=2) + "\n")


def _nuts(args) -> int:
    import jax.numpy as jnp

    from fit.posterior import artifact, laplace, nuts

    b = artifact.Shipped(args.artifact)
    result = artifact.nuts_ef(b.layout, b.d, b.s0, b.laplace, args.seed,
                              progress=lambda m: print(m, flush=True), chains=args.chains,
                              warmup=args.warmup, samples=args.samples)
    print(f"  {'parameter':32s} {'Laplace sd':>10s} {'NUTS sd':>9s} {'ratio':>6s} "
          f"{'shift':>6s} {'R-hat':>6s} {'ESS bulk':>8s} {'tail':>6s}")
    for i, n in enumerate(result.names):
        print(
            f"  {n:32s} {result.laplace_sd[i]:10.4g} {result.nuts_sd[i]:9.4g} "
            f"{result.laplace_sd[i] / result.nuts_sd[i]:6.2f} "
            f"{result.nuts_mean_shift[i]:+6.2f} {result.rhat[i]:6.3f} "
            f"{result.ess_bulk[i]:8.0f} {result.ess_tail[i]:6.0f}"
        )
    print("  (Laplace sd: of its draws, truncated at zero; shift: NUTS's mean minus the "
          "Laplace's centre, in Laplace sds)")
    print(f"  divergences {result.divergences}; {result.seconds:.0f} s; mixing (R-hat, ESS, "
          f"divergences) {'passed' if result.mixed else 'NOT passed'}; Laplace sds within "
          f"{nuts.SD_RATIO_TOL:.0%}: {'yes' if result.passed else 'NO'}")
    record = {"ef": result.record() | _ef_predictions(b, result)}
    if args.bench_cost:
        cols = b.spans[laplace.JOINT]
        u = nuts.potential(b.residual(laplace.JOINT), b.layout.positive[cols])
        seconds = nuts.gradient_cost(u, jnp.asarray(b.centre[cols]))
        # about 10 gradients per NUTS step at this metric (measured on the EF block)
        estimate = seconds * 10 * (args.warmup + args.samples) * args.chains / 60
        print(f"{laplace.JOINT} block: one gradient {seconds:.2f} s; NUTS at these settings "
              f"would take about {estimate:.0f} min: not run")
        record[laplace.JOINT] = {"gradient_seconds": seconds, "estimated_minutes": estimate,
                                 "run": False}
    _record(b.card_path, "nuts", record)
    print(f"recorded in {b.card_path}")
    return 0 if result.passed else 1


def _ef_predictions(b, result) -> dict:
    """What the EF law's sampler changes in its predictions: Table II's bands from NUTS's draws
    (as shipped) against those from the Laplace's (truncated at zero, as
    ``--ef-sampler laplace`` would ship them)."""
    from fit.posterior import artifact, check, laplace

    ef = b.spans["ef"]
    nuts_draws = result.draws.reshape(-1, result.draws.shape[-1])
    lap = laplace.Laplace(b.natural_centre[ef], b.transform[ef, ef], None, {})
    natural, _ = laplace.draws(lap, len(nuts_draws), 0, positive=b.layout.positive[ef])
    laplace_draws = b.raw_with("ef", natural)[:, ef]
    bands = {
        name: check.table2(artifact.as_ensemble(b.layout, b.theta_with("ef", draws),
                                                b.posterior.card), b.data)
        for name, draws in (("nuts", nuts_draws), ("laplace", laplace_draws))
    }
    edges = np.abs(np.concatenate([bands["nuts"].low - bands["laplace"].low,
                                   bands["nuts"].high - bands["laplace"].high]))
    for name, cov in bands.items():
        print(check.format_coverage(f"Table II, the EF law's draws from {name}", "ml", cov))
    print(f"  band edges, NUTS's against the Laplace's: largest difference {edges.max():.2f} ml")
    return {"table2": {name: cov.summary() for name, cov in bands.items()}
            | {"largest_band_edge_difference_ml": float(edges.max())}}


def _importance(args) -> int:
    import jax.numpy as jnp

    from fit.posterior import artifact, importance, laplace

    b = artifact.Shipped(args.artifact)
    layout, cols = b.layout, b.spans[laplace.JOINT]
    potential = b.potential(laplace.JOINT)
    convex = artifact.convexity_check(layout)

    print(f"importance sampling of the {laplace.JOINT} block given the EF law at the fit "
          f"({cols.stop - cols.start} parameters, {args.importance_draws} draws):", flush=True)
    result = importance.run(
        lambda theta: potential(jnp.asarray(b.theta_with(laplace.JOINT, theta))),
        b.natural_centre[cols], b.transform[cols, cols], layout.positive[cols],
        layout.names[cols], to_raw=lambda y: b.raw_with(laplace.JOINT, y)[:, cols],
        admissible=lambda y: np.asarray(convex(b.raw_with(laplace.JOINT, y))),
        n=args.importance_draws, seed=args.seed, progress=lambda m: print(m, flush=True),
    )
    print(f"  {'parameter':32s} {'Laplace sd':>10s} {'weighted':>9s} {'ratio':>6s} {'shift':>6s}")
    for i, n in enumerate(result.names):
        print(f"  {n:32s} {result.laplace_sd[i]:10.4g} {result.weighted_sd[i]:9.4g} "
              f"{result.laplace_sd[i] / result.weighted_sd[i]:6.2f} "
              f"{result.weighted_shift[i]:+6.2f}")
    print(f"  PSIS k-hat {result.khat:.2f} ({'reliable' if result.reliable else 'NOT reliable'}: "
          f"< {importance.KHAT_RELIABLE}), ESS {result.ess:.0f} of {result.draws}, "
          f"{result.failed} failed solves; {result.seconds:.0f} s"
          + ("" if result.reliable else "; the weighted sds are no estimates: the Laplace is "
             "too far from this block's posterior for its weights to correct it"))
    _record(b.card_path, "importance", {laplace.JOINT: result.record()})
    print(f"recorded in {b.card_path}")
    return 0 if result.reliable else 1


def _print_bench(check, bench, sv_title: str, force_title: str) -> None:
    print(check.format_coverage(sv_title, "ml", bench.dynamic_sv))
    print(check.format_coverage(force_title, "N", bench.peak_force))
    print(f"  draws that failed, missed the steady state or emptied the pump: {bench.failed}")


def _smc(args) -> int:
    from fit.posterior import artifact, laplace, smc

    b = artifact.Shipped(args.artifact)
    layout, cols = b.layout, b.spans[laplace.JOINT]
    potential, inside = artifact.joint_target(layout, b.d, b.s0, b.scene)
    print(f"tempered SMC of the {laplace.JOINT} block given the EF law at the fit "
          f"({cols.stop - cols.start} parameters, {args.runs} runs of {args.particles} "
          "particles):", flush=True)
    result = smc.check(
        potential, b.natural_centre[cols], b.transform[cols, cols], inside, layout.names[cols],
        runs=args.runs, particles=args.particles, seed=args.seed,
        progress=lambda m: print(m, flush=True),
    )
    print(f"  {'parameter':32s} {'Laplace sd':>10s} {'SMC sd':>9s} {'ratio':>6s} "
          f"{'shift':>6s} {'R-hat':>6s} {'ESS bulk':>8s}")
    for i, n in enumerate(result.names):
        print(f"  {n:32s} {result.laplace_sd[i]:10.4g} {result.smc_sd[i]:9.4g} "
              f"{result.laplace_sd[i] / result.smc_sd[i]:6.2f} "
              f"{result.smc_mean_shift[i]:+6.2f} {result.rhat[i]:6.3f} "
              f"{result.ess_bulk[i]:8.0f}")
    print("  (natural coordinates; Laplace sd: of its draws truncated to the support; shift: "
          "SMC's mean minus the Laplace's centre, in Laplace sds)")
    seconds = sum(r.seconds for r in result.runs)
    solves = sum(r.evaluations for r in result.runs)
    print(f"  {solves} bench solves, {seconds:.0f} s; the runs agree (R-hat, ESS): "
          f"{'yes' if result.mixed else 'NO'}; Laplace sds within {smc.SD_RATIO_TOL:.0%}: "
          f"{'yes' if result.passed else 'NO'}")
    record = result.record() | _bench_bands(b, result, inside)
    _record(b.card_path, "smc", {laplace.JOINT: record})
    print(f"recorded in {b.card_path}")
    return 0 if result.passed else 1


def _bench_bands(b, result, inside) -> dict:
    """What the block's sampler changes in its predictions: the 30-bpm bench's dynamic SV and
    peak force, 95 % of the draws (no discrepancy), from SMC's draws and from as many of the
    Laplace's, truncated to the support ``inside`` (:func:`fit.posterior.artifact.joint_target`)."""
    import jax
    import jax.numpy as jnp

    from cardiosoft.units import ml, mmHg
    from fit.posterior import blocks, laplace, smc

    cols = b.spans[laplace.JOINT]
    outputs = blocks.bench_outputs(b.layout, b.scene, b.d.t.afterload, steady="shooting")

    @jax.jit
    def one(theta):
        o = outputs(theta)
        return jnp.concatenate([o.dynamic_sv / ml, o.peak_force])

    smc_draws = result.draws
    lap = laplace.Laplace(b.natural_centre[cols], b.transform[cols, cols], None, {})
    lap_draws, _ = laplace.draws(lap, len(smc_draws), 0, inside)
    heads = [f"{h / mmHg:.0f}" for h in np.asarray(b.d.t.afterload)]
    bands = {}
    for name, natural in (("smc", smc_draws), ("laplace", lap_draws)):
        out = smc.threaded(one)(b.raw_with(laplace.JOINT, natural))
        ok = np.all(np.isfinite(out), axis=1)
        bands[name] = (np.percentile(out[ok], [2.5, 97.5], axis=0), int(np.sum(~ok)))
    k = len(heads)
    record = {}
    for j, (what, unit) in enumerate((("dynamic_sv", "ml"), ("peak_force", "N"))):
        for i, h in enumerate(heads):
            s, lp = bands["smc"][0][:, j * k + i], bands["laplace"][0][:, j * k + i]
            print(f"  30 bpm, {h} mmHg, {what}: SMC [{s[0]:.1f}, {s[1]:.1f}] {unit}, Laplace "
                  f"[{lp[0]:.1f}, {lp[1]:.1f}] {unit}")
            record[f"{what}_{h}mmHg_{unit}"] = {"smc": s.tolist(), "laplace": lp.tolist()}
    print(f"  failed solves: SMC {bands['smc'][1]}, Laplace {bands['laplace'][1]} of "
          f"{len(smc_draws)} each")
    return {"bench_30bpm_bands": record
            | {"failed": {n: v[1] for n, v in bands.items()}, "draws": len(smc_draws)}}


PILOT_SEED = 10
"""--smc-pilot's default seed (its pilot; its run the next): apart from the shipped draws' 0, 1."""
PILOT_RATES_BPM = (30.0, 60.0)


def _smc_pilot(args) -> int:
    """Runs that share one pilot cannot show by R-hat a bias that pilot gives all of them
    (:mod:`fit.posterior.smc`): a pilot and a run made as the shipped draws are, from other
    seeds, compared with the card's ``smc`` record (the shipped pilot's runs) per parameter,
    and the bench's bands at 30 and 60 bpm from draws built as the shipped ones are, beside
    theirs. Recorded in the card as ``smc_pilot``."""
    from cardiosoft.posterior import ensemble_run, predictive_bands
    from cardiosoft.units import mmHg
    from fit.posterior import artifact, laplace, smc

    b = artifact.Shipped(args.artifact)
    layout, cols = b.layout, b.spans[laplace.JOINT]
    shipped = json.loads(b.card_path.read_text())["smc"][laplace.JOINT]["parameters"]
    potential, inside = artifact.joint_target(layout, b.d, b.s0, b.scene)
    seeds = (args.pilot_seed, args.pilot_seed + 1)
    print(f"tempered SMC of the {laplace.JOINT} block from an independent pilot (seeds "
          f"{seeds[0]}, {seeds[1]}; the shipped draws': 0, 1), {args.particles} particles:",
          flush=True)
    _, run = smc.piloted(potential, b.natural_centre[cols], b.transform[cols, cols], inside,
                         particles=args.particles, seeds=seeds,
                         progress=lambda m: print(m, flush=True))
    # Monte Carlo sd of a difference of means: the shipped runs' bulk ESS, and for this one
    # run the ESS of one of theirs (a quarter), scaled by its particles
    print(f"  {'parameter':28s} {'sd':>8s} {'shipped':>8s} {'shift':>6s} {'shipped':>8s} "
          f"{'difference':>10s}   (natural coordinates; shift: mean minus the Laplace's "
          "centre, in Laplace sds; difference in Monte Carlo sds)")
    parameters = {}
    for i, name in enumerate(layout.names[cols]):
        r, x = shipped[name], run.draws[:, i]
        shift = (x.mean() - b.natural_centre[cols][i]) / r["laplace_sd"]
        ess = r["ess_bulk"] / smc.RUNS * args.particles / smc.PARTICLES
        error = np.hypot(r["smc_sd"] / np.sqrt(r["ess_bulk"]),
                         x.std(ddof=1) / np.sqrt(ess)) / r["laplace_sd"]
        difference = (shift - r["mean_shift_in_laplace_sd"]) / error
        parameters[name] = {"sd": float(x.std(ddof=1)), "shipped_sd": r["smc_sd"],
                            "shift": float(shift), "shipped_shift": r["mean_shift_in_laplace_sd"],
                            "difference_mc_sd": float(difference)}
        print(f"  {name:28s} {x.std(ddof=1):8.4g} {r['smc_sd']:8.4g} {shift:+6.2f} "
              f"{r['mean_shift_in_laplace_sd']:+8.2f} {difference:+10.1f}")
    # the draws as the shipped ones are made, this run in the shipped run's place; the shipped
    # EF draws are reused, as the support rejects some of their pairings
    with np.load(b.npz, allow_pickle=False) as f:
        theta = f["theta"]
    ef = layout.blocks["ef"]
    lap = laplace.Laplace(b.natural_centre, b.transform, None, {})
    pool = np.tile(theta[:, ef], (laplace.MAX_DRAW_ROUNDS, 1))
    theta_new, _ = artifact.sample(layout, lap, len(theta), seeds[0], pool,
                                   artifact.shuffled(run, seeds[0]))
    draws = {"shipped": b.posterior,
             "pilot": artifact.as_ensemble(layout, theta_new, b.posterior.card)}
    bands = {}
    for bpm in PILOT_RATES_BPM:
        scene = b.scene.replace(bpm=bpm)
        per = {who: predictive_bands(ensemble_run(scene, post), post.card)
               for who, post in draws.items()}
        for i, head in enumerate(scene.afterloads):
            where = f"{bpm:g} bpm, {head / mmHg:.0f} mmHg"
            for key in ("dynamic_sv_ml", "peak_force_N"):
                row = {who: {"band": [v[i][key].low, v[i][key].high],
                             "median": v[i][key].median, "failed": v[i][key].failed}
                       for who, v in per.items()}
                bands[f"{key} at {where}"] = row
                print(f"  {key} at {where}:".ljust(36)
                      + "   ".join(f"{who} [{r['band'][0]:.1f}, {r['band'][1]:.1f}] median "
                                   f"{r['median']:.1f} ({r['failed']} failed)"
                                   for who, r in row.items()), flush=True)
    record = {"seeds": list(seeds), "particles": args.particles,
              "evaluations": run.evaluations, "seconds": round(run.seconds, 1),
              "parameters": parameters, "bands": bands,
              "note": "95 % predictive bands (draws and discrepancy), as simulate --uncertainty "
              "prints them, from the shipped draws and from draws built as they are with this "
              "pilot's run in their run's place"}
    _record(b.card_path, "smc_pilot", record)
    print(f"recorded in {b.card_path}")
    return 0


def _check(args) -> int:
    from cardiosoft import datasets
    from cardiosoft.pump import artifact_path, load_card, load_posterior
    from fit.posterior import artifact, check

    post = load_posterior(args.artifact)
    data = datasets.load_paper_data()
    t2 = check.table2(post, data, seed=args.seed)
    fem = load_card(args.artifact)["metrics"]["table2_paper_fem_mae_ml"]
    print(check.format_coverage(
        "Table II (held out): contracted volume V_u (1 - EF) [ml] against the 95 % predictive "
        "band (draws, EF discrepancy, measurement sd)", "ml", t2,
        f" (the paper's FEM misses these by {fem:.2f} ml on average)",
    ))
    print()
    b = check.bench(post, data, artifact.bench_scene(post.card["surrogate"]), seed=args.seed)
    _print_bench(check, b, "30-bpm bench: dynamic SV [ml] (fitted) against the 95 % band "
                 "(draws, discrepancy, the paper's sd)",
                 "30-bpm bench: peak force [N] (not fitted) against the 95 % band")
    print()
    fit = artifact.linearised_fit(args.artifact, progress=lambda m: print(m, file=sys.stderr))
    loao_sampler = "smc" if post.card.get("joint_smc") else "laplace"  # as the shipped draws
    loao = check.leave_one_afterload_out(
        fit, seed=args.seed, joint_sampler=loao_sampler,
        progress=lambda m: print(m, file=sys.stderr, flush=True),
    )
    _print_bench(check, loao, "leave one afterload out: the left-out dynamic SV [ml] against "
                 "the band of the posterior without its four rows",
                 "leave one afterload out: the left-out peak force [N]")
    _, js = artifact.posterior_paths(artifact_path(args.artifact))
    _record(js, "checks", {
        "seed": args.seed,
        "table2": t2.summary(),
        "bench_dynamic_sv": b.dynamic_sv.summary(),
        "bench_peak_force": b.peak_force.summary(),
        "bench_failed_draws": b.failed,
        "leave_one_afterload_out_dynamic_sv": loao.dynamic_sv.summary(),
        "leave_one_afterload_out_peak_force": loao.peak_force.summary(),
        "leave_one_afterload_out_failed_draws": loao.failed,
        "leave_one_afterload_out_joint_sampler": loao_sampler,
    })
    print(f"recorded in {js}")
    return 0


def _sbc(args) -> int:
    from cardiosoft.pump import artifact_path
    from fit.posterior import artifact, sbc

    progress = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    _, js = artifact.posterior_paths(artifact_path(args.artifact))
    start = time.perf_counter()
    control = None
    if args.block == "ef":
        replicates = args.replicates or sbc.REPLICATES
        result = _sbc_ef(args, replicates, progress)
    else:
        replicates = args.replicates or sbc.JOINT_REPLICATES
        result, control = sbc.run_joint(
            artifact.linearised_fit(args.artifact, progress=progress), replicates=replicates,
            seed=args.seed, progress=progress)
    print(result.table())
    record = {
        "replicates": replicates, "draws": sbc.DRAWS, "seed": args.seed,
        "seconds": round(time.perf_counter() - start, 1), "failed_refits": result.failed,
        "quantities": result.record(),
    }
    if control is not None:
        print(control.table())
        record["control_linearised_rows"] = {"failed_refits": control.failed,
                                             "quantities": control.record()}
    _record(js, "sbc_ef" if args.block == "ef" else "sbc_joint", record)
    print(f"recorded in {js}")
    return 0


def _sbc_ef(args, replicates: int, progress):
    from cardiosoft import datasets
    from cardiosoft.pump import artifact_path, load, load_card, load_posterior
    from fit import fitting
    from fit.posterior import artifact, blocks, sbc

    post = load_posterior(args.artifact)
    npz, _ = artifact.posterior_paths(artifact_path(args.artifact))
    model, card = load(args.artifact), load_card(args.artifact)
    layout = blocks.Layout(model, fitting.rig_from_card(card),
                           artifact.bench_scene(args.artifact))
    cols = layout.blocks["ef"]
    with np.load(npz, allow_pickle=False) as f:
        lap_ef = (f["natural_centre"][cols], f["transform"][cols, cols])
    data = datasets.load_paper_data()
    s0 = blocks.Sigmas(post.card["discrepancy"]["ef_volume"]["s0"]
                       / float(model.unloaded_volume), 0.0, 0.0, 0.0, 0.0)
    return sbc.run(layout, blocks.training_data(data), s0, lap_ef, data,
                   replicates=replicates, seed=args.seed, progress=progress)


def _sobol(args) -> int:
    from cardiosoft.pump import artifact_path, load, load_card, load_posterior
    from fit import fitting
    from fit.posterior import artifact, blocks, sobol

    post = load_posterior(args.artifact)
    npz, js = artifact.posterior_paths(artifact_path(args.artifact))
    layout = blocks.Layout(load(args.artifact), fitting.rig_from_card(load_card(args.artifact)),
                           artifact.bench_scene(args.artifact))
    with np.load(npz, allow_pickle=False) as f:
        theta = f["theta"]
    result = sobol.run(layout, theta, post, base_samples=args.base_samples, seed=args.seed,
                       progress=lambda m: print(m, file=sys.stderr, flush=True))
    print(result.table())
    _record(js, "sobol", result.record())
    print(f"recorded in {js}")
    return 0


def main(argv=None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    from cardiosoft.files import refuse_overwrite
    from cardiosoft.pump import artifact_path
    from fit.posterior import artifact, importance, laplace, nuts, sbc, smc

    parser = argparse.ArgumentParser(
        prog="python -m fit.posterior", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--artifact", metavar="PATH", help="surrogate (default: the shipped one)")
    parser.add_argument("--draws", type=int, default=artifact.DRAWS, help="number of draws")
    parser.add_argument("--seed", type=int, default=artifact.SEED, help="seed of the draws")
    parser.add_argument("--force", action="store_true", help="overwrite an existing posterior")
    parser.add_argument("--ef-sampler", choices=artifact.EF_SAMPLERS, default="nuts",
                        help="how the EF block is drawn (default nuts, about 2 min; laplace: "
                        "seconds, not close to the posterior)")
    parser.add_argument("--joint-sampler", choices=artifact.JOINT_SAMPLERS, default="smc",
                        help="how the mechanics+bench block is drawn (default smc: tempered "
                        "SMC, the --smc check's sampler, about 25 min; laplace: seconds, not "
                        "close to the posterior)")
    parser.add_argument("--nuts", action="store_true",
                        help="NUTS on the EF block against its Laplace (fit.posterior.nuts)")
    parser.add_argument("--chains", type=int, default=nuts.CHAINS)
    parser.add_argument("--warmup", type=int, default=nuts.WARMUP)
    parser.add_argument("--samples", type=int, default=nuts.SAMPLES)
    parser.add_argument("--bench-cost", action="store_true",
                        help="with --nuts: time the mechanics+bench block's gradient and "
                        "estimate its NUTS run")
    parser.add_argument("--importance", action="store_true",
                        help="importance sampling (PSIS) of the mechanics+bench block with its "
                        "Laplace as the proposal (fit.posterior.importance)")
    parser.add_argument("--importance-draws", type=int, default=importance.DRAWS,
                        help="draws for --importance (one bench solve each)")
    parser.add_argument("--smc", action="store_true",
                        help="tempered SMC of the mechanics+bench block against its Laplace "
                        "(fit.posterior.smc)")
    parser.add_argument("--smc-pilot", action="store_true",
                        help="an SMC run of the mechanics+bench block from an independent "
                        "pilot against the shipped draws: parameters and the bench's bands")
    parser.add_argument("--pilot-seed", type=int, default=PILOT_SEED,
                        help=f"--smc-pilot's pilot seed (its run the next; default {PILOT_SEED})")
    parser.add_argument("--runs", type=int, default=smc.RUNS, help="independent runs of --smc")
    parser.add_argument("--particles", type=int, default=smc.PARTICLES,
                        help="particles of each --smc run (each stage's moves solve the bench "
                        "for every particle)")
    parser.add_argument("--check", action="store_true", help="held-out checks of the bands")
    parser.add_argument("--sbc", action="store_true",
                        help="simulation-based calibration of a block (fit.posterior.sbc)")
    parser.add_argument("--block", choices=("ef", laplace.JOINT), default="ef",
                        help="the block --sbc calibrates (default: ef)")
    parser.add_argument("--replicates", type=int,
                        help=f"replicates for --sbc (default {sbc.REPLICATES} for ef, "
                        f"{sbc.JOINT_REPLICATES} for {laplace.JOINT})")
    parser.add_argument("--sobol", action="store_true",
                        help="Sobol indices (SALib) of the 60-bpm bench against the linear "
                        "shares of --explain (fit.posterior.sobol)")
    parser.add_argument("--base-samples", type=int, default=128,
                        help="Saltelli base samples N for --sobol (N (d + 2) solves)")
    args = parser.parse_args(argv)
    try:
        if args.nuts:
            return _nuts(args)
        if args.importance:
            return _importance(args)
        if args.smc:
            if args.runs < 2 or args.particles < 16:
                raise ValueError(f"--runs {args.runs}, --particles {args.particles}: at least 2 "
                                 "runs (they are compared) of 16 particles")
            return _smc(args)
        if args.smc_pilot:
            if args.pilot_seed in (0, 1) or args.particles < 16:
                raise ValueError(f"--pilot-seed {args.pilot_seed}, --particles "
                                 f"{args.particles}: a seed other than the shipped draws' 0 "
                                 "and 1, and at least 16 particles")
            return _smc_pilot(args)
        if args.check:
            return _check(args)
        if args.sbc:
            if args.replicates is not None and args.replicates < 2:
                raise ValueError(f"--replicates {args.replicates}: at least 2")
            return _sbc(args)
        if args.sobol:
            return _sobol(args)
        if args.draws < 2:
            raise ValueError(f"--draws {args.draws}: at least 2")
        npz, js = artifact.posterior_paths(artifact_path(args.artifact))
        refuse_overwrite(npz, args.force)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    old = None  # the posterior being replaced: its Laplace's records may carry over
    if npz.exists() and js.exists():
        with np.load(npz, allow_pickle=False) as f:
            old = (json.loads(js.read_text()), {k: f[k] for k in f.files})
    start = time.perf_counter()
    try:
        arrays, pcard, _, _ = artifact.compute(
            args.artifact, n_draws=args.draws, seed=args.seed, ef_sampler=args.ef_sampler,
            joint_sampler=args.joint_sampler,
            progress=lambda m: print(m, file=sys.stderr, flush=True),
        )
    except RuntimeError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    pcard["seconds"] = round(time.perf_counter() - start, 1)
    if old is not None:
        kept = artifact.carried_records(*old, arrays)
        pcard |= kept
        print(f"kept the unchanged Laplace's records: {', '.join(kept) or 'none'}",
              file=sys.stderr)
    npz, js = artifact.write(args.artifact, arrays, pcard)
    _print_parameters(pcard)
    _print_discrepancy(pcard)
    print(f"wrote {npz} and {js} in {pcard['seconds']} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
