"""Command line: simulate the soft pump in a scene and print what a researcher asks first.

    python -m cardiosoft.simulate --bpm 60
    python -m cardiosoft.simulate --bpm 30 --compare-paper --out results/

Runs the ``bench-dynamic`` scene (the paper's water-column bench) at 30, 60 and 90 mmHg by
default and prints stroke volumes, peak force, mechanical work, efficiency and the beats to
steady state. ``--out DIR`` writes ``summary.json``, ``traces.csv`` and a Fig. 10-style figure.
Exit status (DESIGN.md section 4): 0 when every member is solved and at the periodic steady
state it was asked to reach, flags or not (a flag, e.g. a pump pressure outside the surrogate's
fitted range, is a ``warning:`` line and is listed under ``flags`` in ``summary.json``); 1 when
a member's solve failed or it did not reach the steady state (without ``--beats``; with
``--beats N`` a member still in a transient is a flag), or with ``--strict`` when anything is
flagged; 2 for bad input (one line, nothing written).
``--uncertainty`` also solves the surrogate's posterior draws (:mod:`cardiosoft.posterior`) in
one batched call and prints each metric's 95 % predictive band; a draw that fails is counted
and flagged, never dropped silently.
The numerics live in :func:`cardiosoft.experiment.run`; this module only parses and prints.
"""

from __future__ import annotations

import csv
import json
import sys
import time
from pathlib import Path

OUTPUT_FILES = ("summary.json", "traces.csv", "figure.png")
UNCERTAINTY_DRAWS = 48
"""Posterior draws ``--uncertainty`` solves by default: the ensemble's cost grows with them
(every draw at every afterload, the batch running to its slowest member). With 48, ``--bpm 60
--uncertainty`` takes 2.3x the plain run's wall time from a fresh process (cold compile cache;
2.45x warm) on 2 cores, within the 3x that issue #24 allows; 64 took 2.5x and 3.3x
(``benchmarks/uncertainty.py``, measured 2026-12-03)."""


def parser(prog: str | None = None):
    """The argument parser of ``cardiosoft simulate``."""
    from cardiosoft._cli import (
        add_model_options,
        add_output_options,
        add_report_options,
        add_scene_option,
        allowed,
        command_parser,
    )
    from cardiosoft.scene import ACCURACY

    p = command_parser(
        "simulate",
        "Simulate the cable-driven soft pump beating against an afterload.",
        prog=prog,
        flags="pump pressures outside the surrogate's fitted range, a cable that would push, "
        "a pump volume below zero, an efficiency that is not meaningful, a transient after "
        "--beats N",
        failure="a member's solve failed or it did not reach the periodic steady state",
        output="summary.json",
    )
    add_scene_option(
        p,
        loops=True,
        models="run as svZeroDSolver runs it; --out writes traces.csv under its variable names",
    )
    p.add_argument(
        "--bpm", type=float, help=f"beats per minute, {allowed('bpm', '(')} (default: the scene's)"
    )
    p.add_argument("--omega", type=float, help=f"helix parameter Omega, {allowed('omega')}")
    p.add_argument("--shortening", type=float, help=f"cable shortening C, {allowed('shortening')}")
    p.add_argument(
        "--afterload",
        type=float,
        nargs="+",
        metavar="MMHG",
        help=f"water-column head(s) at the pump base in mmHg, {allowed('afterloads')}",
    )
    p.add_argument("--beats", type=int, help="run exactly this many beats (default: until steady)")
    p.add_argument(
        "--steady",
        choices=("beats", "shooting"),
        nargs="?",
        const="beats",
        help="reach the periodic steady state beat after beat (beats, the default) or by "
        "Newton shooting on the one-beat map (robust at high rates; compiles longer); an "
        "svZeroDSolver model runs its own number_of_cardiac_cycles unless --steady is given",
    )
    p.add_argument(
        "--max-steps",
        type=int,
        metavar="N",
        help="most solver steps per beat, [100, 1e7] (default: the preset's)",
    )
    p.add_argument(
        "--add-effect",
        action="append",
        default=[],
        metavar="NAME",
        help="switch on an effect besides the scene's own: cable_slack (a cable only pulls: at "
        "high rates the disk returns faster than the shell recoils), wall_contact (a floor "
        "where the shell's walls meet, the volume kept above zero); repeatable",
    )
    p.add_argument(
        "--energy",
        action="store_true",
        help="keep each beat's energy account: summary.json gets energy_efficiency (work "
        "delivered past the outlet / work put in) and the account's closing error",
    )
    p.add_argument(
        "--accuracy",
        choices=ACCURACY,
        help="solver preset (default: the scene's)",
    )
    p.add_argument(
        "--compare-paper",
        action="store_true",
        help="print the paper's 30-bpm bench values (Fig. 10) beside the model's",
    )
    p.add_argument(
        "--verify",
        action="store_true",
        help="rerun at the reference preset and print each metric's difference, the run's "
        "numerical error estimate (calculation verification); recorded in summary.json",
    )
    p.add_argument(
        "--uncertainty",
        action="store_true",
        help="also solve the surrogate's posterior draws (cardiosoft.pump.load_posterior) in "
        "one batched call and print each metric's 95 %% predictive band (draws plus model "
        "discrepancy); summary.json gets <metric>_band: [low, high] and <metric>_median, the "
        "figure the bands",
    )
    p.add_argument(
        "--draws",
        type=int,
        default=UNCERTAINTY_DRAWS,
        metavar="N",
        help=f"with --uncertainty: solve the posterior's first N draws (default "
        f"{UNCERTAINTY_DRAWS}; the artifact holds 256)",
    )
    p.add_argument(
        "--explain",
        action="store_true",
        help="with --uncertainty: which parameters dominate each metric's band, and how far "
        "one more measurement (tube length, column bore, SV or force at 60 bpm, shell "
        "compliance) would narrow it (linear over all the posterior's draws: two batched "
        "solves of them, about a minute more)",
    )
    models = add_model_options(
        p,
        "put the soft pump (--omega, --shortening, --pump; default the prototype) in place of "
        "the model's chamber NAME",
    )
    models.add_argument(
        "--as-svzerod",
        action="store_const",
        const=True,
        help="step the model as svZeroDSolver steps it (its generalized-alpha scheme at its "
        "own step) for svZeroDSolver's digits, not the converged answer",
    )
    add_output_options(p, "summary.json, traces.csv, figure.png", plot="the figure")
    add_report_options(p)
    return p


def _paper_values():
    from cardiosoft import datasets
    from cardiosoft.units import mmHg

    b = datasets.load_paper_data().fig10_bench
    return {
        float(b["afterload_mmHg"][i]): {
            "static_sv_ml": float(b["static_sv_ml"][i]),
            "dynamic_sv_ml": float(b["dynamic_sv_ml"][i]),
            "peak_force_N": float(b["peak_force_N"][i]),
            "efficiency": float(b["efficiency"][i]),
            "mech_work_J": float(
                b["afterload_mmHg"][i] * mmHg * b["dynamic_sv_ml"][i] * 1e-6 / b["efficiency"][i]
            ),
        }
        for i in range(len(b))
    }


def _write_traces(path: Path, result) -> None:
    from cardiosoft.scene_tools import tools

    columns = tools(result.scene).trace_columns(result)
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["member", *[c[0] for c in columns]])
        for m in result.members:
            n = len(m.traces.get("time", []))
            for k in range(n):
                writer.writerow(
                    [
                        m.label,
                        *[
                            f"{m.traces[key][k] / scale:.8g}" if key in m.traces else ""
                            for _, key, scale in columns
                        ],
                    ]
                )


def _write_outputs(out_dir: Path, result, records, plot: bool, extra=None) -> list[Path]:
    """summary.json, traces.csv and the figure, all moved into place together or none."""
    from cardiosoft.files import write_together
    from cardiosoft.scene_tools import tools

    written = ["summary.json", "traces.csv"] + (["figure.png"] if plot else [])
    summary = {
        "scene": result.scene.name,
        "pump": result.scene.pump,
        "bpm": result.scene.bpm,
        **tools(result.scene).design(result.scene),
        "records": records,
        **(extra or {}),
    }
    with write_together(out_dir) as staging:
        (staging / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        _write_traces(staging / "traces.csv", result)
        if plot:
            tools(result.scene).plot(result, staging / "figure.png", records)
    return [out_dir / name for name in written]


def _configure(args, out_dir):
    """The scene of the run, everything checked before it (``ValueError`` otherwise)."""
    from cardiosoft._validate import check_range
    from cardiosoft.experiment import configure
    from cardiosoft.files import check_writable_folder, refuse_overwrite
    from cardiosoft.scene_tools import check_supported

    if out_dir is not None:
        check_writable_folder(out_dir)
        for name in OUTPUT_FILES:
            refuse_overwrite(out_dir / name, args.force)
    scene = configure(
        args.scene,
        omega=args.omega,
        shortening=args.shortening,
        bpm=args.bpm,
        afterload=args.afterload,
        accuracy=args.accuracy,
        pump=args.pump,
        effects=args.add_effect,
    )
    if args.beats is not None:
        check_range("beats", args.beats, "beats", 1, 500)
    for what in ("compare_paper", "verify", "uncertainty"):
        if getattr(args, what):
            check_supported(scene, what, "--" + what.replace("_", "-"))
    if args.explain and not args.uncertainty:
        raise ValueError("--explain: explains the bands of --uncertainty; give both")
    if args.explain:
        check_supported(scene, "bench_bands", "--explain")
    return scene


def _print_table(result, records, compare_paper: bool) -> None:
    paper = _paper_values() if compare_paper else None
    from cardiosoft.scene_tools import tools

    kind = tools(result.scene)
    print(kind.heading(result.scene) + ("   (paper: 30 bpm)" if paper is not None else ""))
    print(kind.table(result.scene, records, paper))


def _uncertainty(args, scene, records, console, posterior) -> dict:
    """Solve the posterior's draws, add ``<metric>_band`` (and ``<metric>_band_parameters``,
    the draws alone, and ``<metric>_median``, the predictive samples') to each record, flag
    failed draws; returns summary.json's ``uncertainty`` entry."""
    from cardiosoft.posterior import BAND

    console.say(
        f"uncertainty: {len(next(iter(posterior.scene_draws.values())))} posterior draws x "
        f"{len(records)} member(s) in one batched solve ..."
    )
    start = time.perf_counter()
    from cardiosoft.scene_tools import tools

    kind = tools(scene)
    bands, messages, draws, about = kind.uncertainty(
        scene, posterior, beats=args.beats, steady=args.steady
    )
    failed = []
    for record, member_bands, message in zip(records, bands, messages, strict=True):
        for key, band in member_bands.items():
            record[f"{key}_band"] = _finite([band.low, band.high])
            record[f"{key}_band_parameters"] = _finite([band.parameter_low, band.parameter_high])
            # the best estimate is the fit's optimum, which need not be typical of the draws
            record[f"{key}_median"] = _finite([band.median])[0]
        n_failed = next(iter(member_bands.values())).failed
        record["band_failed_draws"] = n_failed
        failed.append(n_failed)
        if n_failed:
            console.flag(
                record["label"],
                f"{n_failed} of {draws} posterior draws failed, missed the steady "
                f"state or emptied the pump below zero volume, and are left out of its bands "
                f"(the first: {message})",
            )
    console.say(f"done in {time.perf_counter() - start:.1f} s")
    return {
        "band": BAND,
        "draws": draws,
        "failed_draws": failed,
        "posterior": posterior.card["file"],
        "posterior_sha256": posterior.card["sha256"],
        **about,
    }


def _finite(values):
    import math

    return [v if math.isfinite(v) else None for v in values]


def main(argv=None, prog: str | None = None) -> int:
    """``cardiosoft simulate``: returns the exit status (module docstring)."""
    args = parser(prog).parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    from cardiosoft.console import Console, fail, report_members
    from cardiosoft.experiment import run
    from cardiosoft.scene_tools import summary_records, tools

    console = Console(quiet=args.quiet, strict=args.strict)
    if args.scene.endswith(".json"):  # an svZeroDSolver model: the network's own run
        from cardiosoft.network.cli import simulate_model

        return simulate_model(args, console)
    from cardiosoft._cli import refuse_model_options

    try:
        refuse_model_options(args, own=("as_svzerod",))
    except ValueError as err:
        return fail(err)
    args.steady = args.steady or "beats"  # a scene always runs to its periodic steady state
    out_dir = Path(args.out) if args.out else None
    posterior = every_draw = None
    try:
        scene = _configure(args, out_dir)
        if args.uncertainty:
            from cardiosoft.posterior import first_draws
            from cardiosoft.pump import load_posterior

            every_draw = load_posterior(scene.pump)  # --explain correlates them all
            posterior = first_draws(every_draw, args.draws)
        what = (
            "quasi-static pull, one root find per cable position"
            if scene.static
            else "compiling, then solving beat by beat to the periodic steady state"
        )
        n = tools(scene).member_count(scene)
        console.say(f"{scene.name}: {n} afterload(s), {scene.bpm:g} bpm; {what} ...")
        start = time.perf_counter()
        result = run(
            scene,
            beats=args.beats,
            steady=args.steady,
            energy=args.energy,
            max_steps=args.max_steps,
        )
    except (ValueError, FileNotFoundError) as err:
        return fail(err)
    run_seconds = time.perf_counter() - start
    console.say(f"done in {run_seconds:.1f} s")
    records = summary_records(result)
    uncertainty = None
    if posterior is not None:
        uncertainty = _uncertainty(args, scene, records, console, posterior)
    if not args.quiet:
        _print_table(result, records, args.compare_paper)
        if uncertainty is not None:
            print(
                f"95 % predictive bands ({uncertainty['draws']} draws; {uncertainty['holds']}; "
                "--out: summary.json has the draws' own bands too)"
            )
            print(tools(result.scene).table(result.scene, records, bands=True))
    if args.explain:
        from cardiosoft.explain import explain

        try:  # every draw: correlations need more than --draws' default
            explanation = explain(scene, every_draw, progress=console.say)
        except ValueError as err:  # too few draws settled to correlate: a failed solve
            console.fail("--explain", str(err))
        else:
            uncertainty["explain"] = explanation.record()
            if not args.quiet:
                print(explanation.table())
    report_members(console, result.members, steady_asked=args.beats is None)
    extra = console.record()
    if uncertainty is not None:
        extra["uncertainty"] = uncertainty
    if args.verify:
        from cardiosoft.verify import verify_run

        console.say("verifying: rerunning tighter (the reference preset; a finer pull grid) ...")
        check = verify_run(result, beats=args.beats, steady=args.steady)
        extra["verification"] = check.record()
        if not args.quiet:
            print(check.table(run_seconds=run_seconds))
    if out_dir is not None:
        try:
            written = _write_outputs(out_dir, result, records, not args.no_plot, extra)
        except OSError as err:  # checked before the run; the system can still refuse
            return fail(ValueError(f"--out {out_dir}: {err.strerror or err}; nothing written"))
        for path in written:
            console.say(f"wrote {path}")
    return console.status()


if __name__ == "__main__":
    from cardiosoft._cli import prepare_process

    prepare_process("simulate", sys.argv[1:])  # XLA's optimisation level, the compile cache
    raise SystemExit(main())
