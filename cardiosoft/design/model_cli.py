"""``cardiosoft design --scene model.json --pump-chamber NAME``: the soft pump's design in a
user's svZeroDSolver model (:mod:`cardiosoft.design.model`): the arguments it takes, what it
prints and writes. :func:`cardiosoft.design.cli.main` hands a ``.json`` scene here.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from cardiosoft.console import Console, fail, fmt, table
from cardiosoft.design.loop_cli import refuse_options

__all__ = ["model_arguments", "model_report", "run_model_design"]

def _target(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not sep or not name or not math.isfinite(number):
        raise ValueError(
            f"--target {text!r}: give BLOCK.KEY=VALUE, a metric and its target in the metric's "
            "units (LV.stroke_volume_ml=50, AR_SYS.pressure_mean=9000)"
        )
    return name, number


def model_arguments(args) -> dict:
    """:func:`~cardiosoft.design.model.optimise_model`'s keyword arguments from the command
    line; ``ValueError`` for what a model's design does not take."""
    from cardiosoft.network.pump_in_model import DEFAULT_UNITS, PumpPlacement

    refuse_options(
        args,
        ("--target-co", "--afterload", "--bpm", "--lap", "--rap", "--minimize", "--maximize",
         "--pareto", "--tol", "--uncertainty", "--robust", "--steady shooting"),
        "not taken on an svZeroDSolver model (its pump is designed at the model's periodic "
        "steady state for --target BLOCK.KEY=VALUE or --target-sv, each reached within 1 %)",
    )  # fmt: skip
    if args.pump_chamber is None:
        raise ValueError(
            "--pump-chamber: missing; name the model's chamber the soft pump takes the place of"
        )
    if args.target_sv is not None and len(args.target_sv) != 1:
        raise ValueError(f"--target-sv: {len(args.target_sv)} values; a model's pump takes one")
    targets = dict(_target(t) for t in args.target or [])
    if args.target_sv is not None:
        targets[f"{args.pump_chamber}.stroke_volume_ml"] = args.target_sv[0]
    placement = PumpPlacement(
        args.pump_chamber, args.units or DEFAULT_UNITS, surrogate=getattr(args, "pump", None)
    )
    return dict(
        placement=placement,
        targets=targets,
        free=tuple(args.free),
        accuracy=args.accuracy or "default",
        max_evaluations=args.max_rounds,
    )


def model_report(result) -> str:
    """What the command prints: the design, a row per target, then the pump's beat."""
    d = result.design
    head = [
        f"{result.model}: soft pump in place of {result.chamber}, Omega {d['omega']:.4f}, "
        f"C {d['shortening']:.4f}",
        f"{'reached' if result.reached else 'NOT reached'} (within 1 % of each target) after "
        f"{result.evaluations} designs solved, {result.seconds:.1f} s "
        f"(compile {result.compile_seconds:.1f} s)",
    ]
    rows = [
        [t.name, f"{t.target:g}", fmt(t.value, ".4g"), fmt(t.residual, "+.2f"),
         f"{fmt(t.seen[0], '.4g')} to {fmt(t.seen[1], '.4g')}", "yes" if t.reached else "no"]
        for t in result.targets
    ]  # fmt: skip
    targets = table(
        ["target", "wanted", "reached", "residual (1 %)", "seen", "ok"], [""] * 6, rows
    )
    pump = result.records.get(result.chamber, {})
    beat = (
        f"pump at the design: SV {fmt(pump.get('stroke_volume_ml'), '.1f')} ml, "
        f"EF {fmt(pump.get('ejection_fraction'), '.2f')}, peak cable force "
        f"{fmt(pump.get('peak_force_N'), '.1f')} N, efficiency {fmt(pump.get('efficiency'), '.2f')}"
    )
    return "\n".join(head) + "\n" + targets + "\n" + beat


def _plot(result, path: Path) -> None:
    """The designs solved in (Omega, C), coloured by the first target's metric, the answer
    starred: where in the pump's design range the target lies."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    target = result.targets[0]
    omega, shortening, values = zip(*result.evaluated, strict=True)
    metric = np.array([v[0] for v in values])
    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    dots = ax.scatter(omega, shortening, c=metric, cmap="viridis", s=28)
    fig.colorbar(dots, ax=ax, label=target.name)
    ax.plot(result.design["omega"], result.design["shortening"], "r*", ms=14, label="design")
    ax.set(xlabel="helix parameter Omega", ylabel="cable shortening C",
           title=f"{result.model}: {target.name} = {target.target:g}")  # fmt: skip
    ax.legend(loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _write(out_dir: Path, result, plot: bool, console: Console) -> None:
    """design.json (the result, the exit status) and the figure, moved into place together."""
    from cardiosoft.files import write_together

    record = result.to_json() | {"exit_status": console.status()}
    names = ["design.json"] + (["design.png"] if plot else [])
    with write_together(out_dir) as staging:
        (staging / "design.json").write_text(json.dumps(record, indent=2) + "\n")
        if plot:
            _plot(result, staging / "design.png")
    for name in names:
        console.say(f"wrote {out_dir / name}")


def run_model_design(args, out_dir: Path | None, console: Console) -> int:
    """The design of the pump in the model ``args.scene``: returns the exit status."""
    from cardiosoft.design.model import optimise_model
    from cardiosoft.network import UnsupportedModel

    try:
        kwargs = model_arguments(args)
        result = optimise_model(args.scene, **kwargs, progress=console.say)
    except (ValueError, UnsupportedModel, OSError) as err:
        return fail(ValueError(f"--scene {args.scene}: {err}"))
    return console.conclude(
        result,
        None if args.quiet else model_report(result),
        None if out_dir is None else lambda: _write(out_dir, result, not args.no_plot, console),
    )
