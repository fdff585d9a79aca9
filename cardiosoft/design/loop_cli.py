"""``cardiosoft design`` on a closed-loop scene (``tah``, ``soft-lv``, ``soft-rv``): the
arguments it takes, what it prints and writes. The numerics are
:func:`cardiosoft.design.loop.optimise_loop`'s; :func:`cardiosoft.design.cli.main` hands a
closed-loop scene here.
"""

from __future__ import annotations

import json
from pathlib import Path

from cardiosoft.console import Console, fail, fmt, table
from cardiosoft.design.problem import DEFAULT_FREE, TOLERANCE_ML

__all__ = ["loop_arguments", "loop_report", "refuse_options", "run_loop_design"]


def refuse_options(args, flags, why: str) -> None:
    """``ValueError`` naming the first of ``flags`` (``design``'s options, as typed; ``--steady
    shooting`` for that method) given on the command line, and ``why`` it is not taken."""
    given = {
        "--target-sv": args.target_sv is not None,
        "--target-co": args.target_co is not None,
        "--afterload": args.afterload is not None,
        "--bpm": args.bpm is not None,
        "--lap": args.lap is not None,
        "--rap": args.rap is not None,
        "--minimize": args.minimize not in (None, "none"),
        "--maximize": args.maximize not in (None, "none"),
        "--pareto": args.pareto,
        "--tol": args.tol != TOLERANCE_ML,
        "--uncertainty": args.uncertainty,
        "--robust": args.robust,
        "--steady shooting": args.steady == "shooting",
    }
    for flag in flags:
        if given[flag]:
            raise ValueError(f"{flag}: {why}")


def loop_arguments(args) -> dict:
    """:func:`~cardiosoft.design.loop.optimise_loop`'s keyword arguments from the command
    line; ``ValueError`` for what a closed loop does not take."""
    refuse_options(
        args,
        ("--target-sv", "--afterload", "--minimize", "--maximize", "--pareto", "--tol",
         "--uncertainty", "--robust"),
        "not taken on a closed-loop scene (its targets are --target-co, --lap, --rap, "
        "reached within 0.1 l/min and 1 mmHg)",
    )  # fmt: skip
    if args.target_co is None:
        raise ValueError(
            "--target-co: missing; a closed loop is designed for its cardiac output (l/min), "
            "with --lap and --rap (mmHg) optional"
        )
    if len(args.target_co) != 1:
        raise ValueError(f"--target-co: {len(args.target_co)} values; a closed loop takes one")
    if args.bpm is not None and len(args.bpm) != 1:
        raise ValueError(f"--bpm: {len(args.bpm)} values; a closed loop beats at one rate")
    free = DEFAULT_FREE if args.free is None else args.free
    return dict(
        target_co=args.target_co[0],
        lap=args.lap,
        rap=args.rap,
        free=free,
        max_evaluations=args.max_rounds,
    )


def loop_report(result) -> str:
    """What the command prints: the design, a row per target, then the answer's run."""
    from cardiosoft.network.loop_records import loop_summary_records, loop_table

    design = ", ".join(f"{p} {v:.4g}" for p, v in result.design.items())
    head = [
        f"{result.scene.name}: {design}",
        f"{'reached' if result.reached else 'NOT reached'} after {result.evaluations} designs "
        f"evaluated, {result.seconds:.1f} s (compile {result.compile_seconds:.1f} s)",
    ]
    rows = [
        [
            t.name,
            t.unit,
            f"{t.target:g}",
            fmt(t.value, ".2f"),
            fmt(t.residual, "+.2f"),
            f"{t.weight:g}",
            f"{fmt(t.seen[0], '.2f')}-{fmt(t.seen[1], '.2f')}",
            "yes" if t.reached else "no",
        ]
        for t in result.targets
    ]
    targets = table(
        ["target", "unit", "wanted", "reached", "residual", "within", "seen", "ok"],
        [""] * 8,
        rows,
    )
    return "\n".join(head) + "\n" + targets + "\n\n" + loop_table(loop_summary_records(result.run))


def _write(out_dir: Path, result, plot: bool, console: Console) -> None:
    """design.json (the result, the exit status) and the figure, moved into place together."""
    from cardiosoft.files import write_together
    from cardiosoft.plots import plot_closed_loop

    record = result.to_json() | {"exit_status": console.status()}
    names = ["design.json"] + (["design.png"] if plot else [])
    with write_together(out_dir) as staging:
        (staging / "design.json").write_text(json.dumps(record, indent=2, allow_nan=False) + "\n")
        if plot:
            plot_closed_loop(result.run, staging / "design.png")
    for name in names:
        console.say(f"wrote {out_dir / name}")


def run_loop_design(scene, args, out_dir: Path | None, console: Console) -> int:
    """The closed-loop design from parsed arguments: returns the exit status."""
    from cardiosoft.design.loop import optimise_loop

    try:
        kwargs = loop_arguments(args)
        if args.bpm is not None:
            from cardiosoft.network.loop_results import configure_loop

            scene = configure_loop(scene, bpm=args.bpm[0])
        if args.accuracy is not None:
            scene = scene.replace(accuracy=args.accuracy)
        result = optimise_loop(scene, **kwargs, progress=console.say)
    except ValueError as err:
        return fail(err)
    return console.conclude(
        result,
        None if args.quiet else loop_report(result),
        None if out_dir is None else lambda: _write(out_dir, result, not args.no_plot, console),
    )
