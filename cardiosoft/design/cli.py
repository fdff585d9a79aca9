"""The command line of the design search: ``cardiosoft design`` / ``python -m cardiosoft.design``.

It parses and prints; the numerics are :func:`cardiosoft.design.optimise`'s.
"""

from __future__ import annotations

import json
from pathlib import Path

from cardiosoft._cli import (
    add_model_options,
    add_output_options,
    add_report_options,
    add_scene_option,
    allowed,
    command_parser,
    refuse_model_options,
)
from cardiosoft.console import Console, fail, fmt, table
from cardiosoft.design.problem import (
    DEFAULT_FREE,
    FREE_VARIABLES,
    LABELS,
    OBJECTIVE_UNITS,
    OBJECTIVES,
    TOLERANCE_ML,
)
from cardiosoft.design.result import DesignResult
from cardiosoft.design.search import DEFAULT_STEADY, GRID, MAX_ROUNDS, REFINE

__all__ = ["OUTPUT_FILES", "main", "parser", "report"]

OUTPUT_FILES = ("design.json", "design.png")


def parser(prog: str | None = None):
    """The argument parser of ``cardiosoft design``."""
    p = command_parser(
        "design",
        "Find the design (helix parameter Omega, cable shortening C) whose periodic steady "
        "state hits target stroke volumes; optionally the one with the least peak force, the "
        "least mechanical work or the most efficiency among them.",
        prog=prog,
        flags="a target that no design reaches (the closest design is reported), and the "
        "verifying run's own flags",
        failure="the verifying run of the design found failed or did not reach the periodic "
        "steady state",
        output="design.json",
    )
    add_scene_option(p, static=False, loops=True)
    _target_options(p)
    _search_options(p)
    _uncertainty_options(p)
    _model_options(p)
    add_output_options(p, "design.json and design.png", plot="the figure")
    add_report_options(p)
    return p


def _target_options(p) -> None:
    p.add_argument(
        "--target-sv", type=float, nargs="+", metavar="ML", help="target stroke volume(s), ml"
    )
    p.add_argument(
        "--target-co",
        type=float,
        nargs="+",
        metavar="L_MIN",
        help="target cardiac output(s), l/min, instead of --target-sv",
    )
    p.add_argument(
        "--afterload",
        type=float,
        nargs="+",
        metavar="MMHG",
        help=f"water-column head(s), mmHg, {allowed('afterloads')}; they pair up with the "
        "targets (default: the scene's heads)",
    )
    p.add_argument(
        "--bpm",
        type=float,
        nargs="+",
        metavar="N",
        help=f"beats per minute, {allowed('bpm', '(')}; one, or one per target (default: the "
        "scene's)",
    )
    for flag, atrium in (("--lap", "left"), ("--rap", "right")):
        p.add_argument(
            flag,
            type=float,
            metavar="MMHG",
            help=f"closed-loop scenes: target mean {atrium}-atrial pressure, mmHg",
        )


def _search_options(p) -> None:
    p.add_argument(
        "--free",
        nargs="+",
        metavar="NAME",
        default=list(DEFAULT_FREE),
        help=f"free design variables among {', '.join(FREE_VARIABLES)} (default: omega shortening)",
    )
    p.add_argument(
        "--tol",
        type=float,
        default=TOLERANCE_ML,
        metavar="ML",
        help=f"tolerance on every stroke volume, ml (default {TOLERANCE_ML:g})",
    )
    p.add_argument(
        "--minimize", metavar="WHAT", help="peak_force, mech_work or none: a secondary objective"
    )
    p.add_argument("--maximize", metavar="WHAT", help="efficiency: a secondary objective")
    p.add_argument(
        "--pareto",
        action="store_true",
        help="trace the designs that hit the target and trade peak force against efficiency "
        "(against mechanical work with --minimize mech_work)",
    )
    p.add_argument(
        "--max-rounds",
        type=int,
        default=MAX_ROUNDS,
        help=f"refinement rounds (default {MAX_ROUNDS})",
    )
    p.add_argument(
        "--accuracy", metavar="PRESET", help="solver preset of the search (default: the scene's)"
    )
    p.add_argument(
        "--steady",
        default=DEFAULT_STEADY,
        metavar="METHOD",
        help="how the search finds the periodic orbits it differentiates: shooting (Newton on "
        "the one-beat map), beats (beat after beat; a lighter program, but fails where the "
        "beats ring past the scene's max_beats) or auto (the default: shooting on the "
        "water-column bench, beats on a Windkessel scene)",
    )


def _model_options(p) -> None:
    model = add_model_options(
        p,
        "design the soft pump in place of the model's chamber NAME (its Omega and C; --free "
        "to hold one)",
    )
    model.add_argument(
        "--target",
        action="append",
        metavar="BLOCK.KEY=VALUE",
        help="a target on any block's metric, in the metric's units (the pump's under its "
        "chamber's name: NAME.stroke_volume_ml, NAME.peak_force_N, ...; a vessel's "
        "AORTA.pressure_mean in the model's units); repeat for more. --target-sv ML stands "
        "for NAME.stroke_volume_ml=ML",
    )


def _uncertainty_options(p) -> None:
    from cardiosoft.simulate import UNCERTAINTY_DRAWS

    p.add_argument(
        "--uncertainty",
        action="store_true",
        help="report the 95 %% predictive band of each SV the design reaches (the surrogate's "
        "posterior draws plus the model discrepancy; cardiosoft.design.robust)",
    )
    p.add_argument(
        "--robust",
        action="store_true",
        help="then look for the design whose SV bands stay within --tol of every target, or "
        "say why none does",
    )
    p.add_argument(
        "--draws",
        type=int,
        default=UNCERTAINTY_DRAWS,
        metavar="N",
        help=f"with --uncertainty or --robust: the posterior's first N draws (default "
        f"{UNCERTAINTY_DRAWS})",
    )


def _band_report(result: DesignResult, bands, robust) -> str:
    """The SV each target reaches with its band; the robust search's answer."""
    rows = [
        [fmt(t.afterload_mmHg, ".0f"), fmt(t.bpm, "g"), fmt(t.target_sv_ml, ".2f"),
         fmt(t.sv_ml, ".2f"), f"[{fmt(b.low, '.2f')}, {fmt(b.high, '.2f')}]",
         f"[{fmt(b.parameter_low, '.2f')}, {fmt(b.parameter_high, '.2f')}]", str(b.failed)]
        for t, b in zip(result.targets, bands, strict=True)
    ]
    out = "\n95 % predictive bands of the SV at the design (posterior draws and the model " \
        "discrepancy; the draws alone beside)\n" + table(
            ["afterload", "bpm", "target SV", "SV", "band", "draws' band", "failed draws"],
            ["mmHg", "", "ml", "ml", "ml", "ml", ""], rows)
    if robust is not None:
        where = ("" if robust.omega is None else
                 f"Omega {robust.omega:.3f}, C {robust.shortening:.4f}: ")
        out += f"\nrobust design: {where}{robust.reason}"
    return out


def _head(result: DesignResult) -> list[str]:
    d = result.design
    head = [
        f"{result.scene.name}: Omega {d['omega']:.4f}, C {d['shortening']:.4f}"
        + "".join(f", {LABELS[k]} {d[k]:.4g}" for k in result.free if k not in DEFAULT_FREE),
        f"{'reached' if result.reached else 'NOT reached'} (tolerance {result.tolerance_ml:g} ml) "
        f"in {result.iterations} rounds, {result.seconds:.1f} s "
        f"(compile {result.timings['compile_s']:.1f} s)",
    ]
    if result.objective is not None:
        unit = OBJECTIVE_UNITS[result.objective]
        head.append(
            f"objective: {'maximise' if OBJECTIVES[result.objective] < 0 else 'minimise'} "
            f"{result.objective} -> {result.objective_value:.4g} {unit}".rstrip()
            + " (mean over the targets)"
        )
    return head


def _targetstable(result: DesignResult) -> str:
    rows = [
        [
            fmt(t.afterload_mmHg, ".0f"),
            fmt(t.bpm, "g"),
            fmt(t.target_sv_ml, ".2f"),
            fmt(t.sv_ml, ".2f"),
            fmt(t.residual_ml, "+.2f"),
            f"{fmt(t.reachable_sv_ml[0], '.1f')}-{fmt(t.reachable_sv_ml[1], '.1f')}",
            fmt(t.peak_force_N, ".1f"),
            fmt(t.mech_work_J, ".3f"),
            fmt(t.efficiency, ".3f"),
            fmt(t.cardiac_output_l_min, ".2f"),
        ]
        for t in result.targets
    ]
    return table(
        [
            "afterload",
            "bpm",
            "target SV",
            "SV",
            "residual",
            "SV seen",
            "peak force",
            "mech. work",
            "efficiency",
            "CO",
        ],
        ["mmHg", "", "ml", "ml", "ml", "ml", "N", "J", "-", "l/min"],
        rows,
    )


def _paretotable(result: DesignResult) -> str:
    rows = [
        [
            f"{p.omega:.3f}",
            f"{p.shortening:.4f}",
            " ".join(f"{v:.2f}" for v in p.sv_ml),
            f"{p.peak_force_N:.1f}",
            f"{p.efficiency:.4f}",
            f"{p.mech_work_J:.3f}",
            "" if p.dominated else "*",
        ]
        for p in result.pareto
    ]
    out = "\n\nPareto trace (designs hitting the targets; * = not dominated)\n" + table(
        ["Omega", "C", "SV", "peak force", "efficiency", "mech. work", "front"],
        ["", "", "ml", "N", "-", "J", ""],
        rows,
    )
    if not result.pareto:
        out += "\n(no design on the trace hit the targets)"
    return out


def report(result: DesignResult) -> str:
    """What the command prints: the design, then a row per target (and the Pareto trace)."""
    out = "\n".join(_head(result)) + "\n" + _targetstable(result)
    if result.pareto is not None:
        out += _paretotable(result)
    return out


def _arguments(args) -> dict:
    """``optimise()``'s keyword arguments from the command line, checked as far as they can be
    without a solve (``ValueError`` otherwise)."""
    from cardiosoft._validate import check_range

    if args.target_sv is None and args.target_co is None:
        raise ValueError("--target-sv: missing; give the target stroke volume(s) in ml")
    if args.target_sv is not None and args.target_co is not None:
        raise ValueError("--target-sv and --target-co: give one of the two")
    targets = args.target_sv if args.target_sv is not None else args.target_co
    flag = "--target-sv" if args.target_sv is not None else "--target-co"
    for other, values in (("--afterload", args.afterload), ("--bpm", args.bpm)):
        if values is not None and len(values) not in (1, len(targets)) and len(targets) != 1:
            raise ValueError(
                f"{flag}: {len(targets)} values and {other}: {len(values)} values; give "
                f"one {other[2:]} or one per target (they pair up in order)"
            )
    if (
        args.afterload is not None
        and args.bpm is not None
        and len(targets) == 1
        and len(args.afterload) > 1
        and len(args.bpm) > 1
        and len(args.afterload) != len(args.bpm)
    ):
        raise ValueError(
            f"--afterload: {len(args.afterload)} values and --bpm: {len(args.bpm)} values; "
            "give one or the same number of each"
        )
    check_range("--max-rounds", args.max_rounds, "rounds", 1, 1000)
    if args.pareto and not {"omega", "shortening"} <= set(args.free):
        raise ValueError("--pareto: needs omega and shortening among --free")
    return dict(
        target_sv=args.target_sv,
        target_co=args.target_co,
        afterload=args.afterload,
        bpm=None if args.bpm is None else (args.bpm[0] if len(args.bpm) == 1 else args.bpm),
        free=args.free,
        tol=args.tol,
        minimize=args.minimize,
        maximize=args.maximize,
        pareto=args.pareto,
        max_rounds=args.max_rounds,
        accuracy=args.accuracy,
        steady=args.steady,
    )


def _check(scene, kwargs) -> None:
    """Everything ``optimise()`` would refuse, before it compiles anything."""
    from cardiosoft.design.optimiser import check_method
    from cardiosoft.design.problem import build_problem

    problem_args = ("target_sv", "target_co", "afterload", "bpm", "free", "tol")
    build_problem(
        scene,
        **{k: kwargs[k] for k in problem_args},
        start=None,
        bounds=None,
        minimize=kwargs["minimize"],
        maximize=kwargs["maximize"],
    )
    check_method(kwargs["accuracy"], kwargs["steady"])


def _write(
    out_dir: Path, result: DesignResult, plot: bool, console: Console, extra=None
) -> None:
    """design.json (the result, the exit status) and the figure, moved into place together."""
    from cardiosoft.design.figure import plot_design
    from cardiosoft.files import write_together

    record = result.to_json() | (extra or {}) | {"exit_status": console.status()}
    with write_together(out_dir) as staging:
        (staging / "design.json").write_text(json.dumps(record, indent=2, allow_nan=False) + "\n")
        if plot:
            plot_design(result, staging / "design.png")
    for name in OUTPUT_FILES[: 1 + plot]:
        console.say(f"wrote {out_dir / name}")


def main(argv=None, prog: str | None = None) -> int:
    """``cardiosoft design``: returns the exit status."""
    import jax

    args = parser(prog).parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    from cardiosoft.files import refuse_overwrite
    from cardiosoft.scene import load_scene
    from cardiosoft.scene_tools import tools

    console = Console(quiet=args.quiet, strict=args.strict)
    model = args.scene.endswith(".json")  # an svZeroDSolver model, with the pump in it
    try:
        out_dir = Path(args.out) if args.out else None
        if out_dir is not None:
            if out_dir.exists() and not out_dir.is_dir():
                raise ValueError(f"--out {out_dir} exists and is not a folder")
            for name in OUTPUT_FILES:
                refuse_overwrite(out_dir / name, args.force)
        if not model:
            refuse_model_options(args, own=("target",))
        if model:
            from cardiosoft.design.model_cli import run_model_design

            return run_model_design(args, out_dir, console)
        scene = load_scene(args.scene, pump=args.pump)
    except (ValueError, FileNotFoundError) as err:
        return fail(err)
    if tools(scene).unsupported(scene, "pump_design") is None:
        return run_pump_design(scene, args, out_dir, console)
    from cardiosoft.design.loop_cli import run_loop_design  # a closed loop: its pumps

    return run_loop_design(scene, args, out_dir, console)


def run_pump_design(scene, args, out_dir: Path | None, console: Console) -> int:
    """The pump's design in an open-loop scene from parsed arguments: returns the exit
    status (the closed loop's: :func:`cardiosoft.design.loop_cli.run_loop_design`)."""
    from cardiosoft.design.optimiser import optimise

    try:
        for flag, value in (("--lap", args.lap), ("--rap", args.rap)):
            if value is not None:
                raise ValueError(f"{flag}: only a closed-loop scene has atria; {scene.name} not")
        kwargs = _arguments(args)
        _check(scene, kwargs)
        posterior = None
        if args.uncertainty or args.robust:
            from cardiosoft.posterior import first_draws
            from cardiosoft.pump import load_posterior

            posterior = first_draws(load_posterior(scene.pump), args.draws)
    except (ValueError, FileNotFoundError) as err:
        return fail(err)
    plot = out_dir is not None and not args.no_plot
    n = len(args.target_sv if args.target_sv is not None else args.target_co)
    console.say(
        f"{scene.name}: {n} target(s); compiling the search, then a "
        f"grid of {GRID} candidates and refinement rounds of {REFINE} ..."
    )
    try:
        result = optimise(
            scene, **kwargs, map_lattice=(12, 8) if plot else None, progress=console.say
        )
    except ValueError as err:  # a problem only the search could see
        return fail(err)
    text = None if args.quiet else report(result)
    extra = None
    if posterior is not None:
        text, extra = _uncertainty(scene, result, posterior, args.robust, text, console)
    return console.conclude(
        result,
        text,
        None if out_dir is None else lambda: _write(out_dir, result, plot, console, extra),
    )


def _uncertainty(scene, result, posterior, robust: bool, text, console):
    """The design's SV bands (and the robust search): the report's text and design.json's
    ``uncertainty`` entry; a robust design that does not exist, and failed draws, flagged."""
    from cardiosoft.design.robust import robust_design, sv_bands

    console.say("uncertainty: every posterior draw at the design's targets ...")
    d = result.design
    bands = list(sv_bands(scene, d["omega"], d["shortening"], result.targets, posterior)[0])
    found = robust_design(scene, result, posterior, console.say) if robust else None
    for t, b in zip(result.targets, bands, strict=True):
        if b.failed:
            console.flag(t.where, f"{b.failed} of {b.failed + b.draws} posterior draws failed, "
                         "missed the steady state or emptied the pump below zero volume, and are "
                         "left out of the SV's band")
    if found is not None and not found.within:
        console.flag("robust design", found.reason)
    record = {
        "uncertainty": {
            "draws": int(bands[0].draws + bands[0].failed),
            "sv_band_ml": [[b.low, b.high] for b in bands],
            "sv_band_parameters_ml": [[b.parameter_low, b.parameter_high] for b in bands],
            "failed_draws": [b.failed for b in bands],
            "robust": None if found is None else found.record(),
        }
    }
    if text is not None:
        text += "\n" + _band_report(result, bands, found)
    return text, record
