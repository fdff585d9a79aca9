"""The command line of design-space sweeps: ``cardiosoft sweep`` / ``python -m cardiosoft.sweep``.

It parses and prints; the sweep is :func:`cardiosoft.sweep.design_sweep`'s.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from cardiosoft._cli import (
    add_model_options,
    add_output_options,
    add_report_options,
    add_scene_option,
    command_parser,
    refuse_model_options,
    values_argument,
)
from cardiosoft.console import Console, fail
from cardiosoft.scene import load_scene
from cardiosoft.sweep.chunk import NOT_STEADY, STATUS
from cardiosoft.sweep.maps import map_keys, panels_of
from cardiosoft.sweep.plan import DEFAULT_CHUNK
from cardiosoft.sweep.runner import design_sweep
from cardiosoft.sweep.store import PARTIAL

__all__ = ["main", "parser", "report_points", "summary"]


def parser(prog: str | None = None):
    """The argument parser of ``cardiosoft sweep``."""
    from cardiosoft.scene import ACCURACY

    p = command_parser(
        "sweep",
        "Design-space maps: simulate every point of a grid of designs (Omega x C), "
        "afterloads and rates to its periodic steady state, keeping metrics only; write an "
        "xarray Dataset (sweep.nc) and heat maps.",
        prog=prog,
        flags="points stopped after --beats N before the steady state",
        failure="a point failed, or did not reach the periodic steady state it was run to",
        output="sweep.nc ('steady', 'status')",
    )
    add_scene_option(
        p, static=False, loops=True, models="with --pump-chamber: the pump swept in its place"
    )
    p.add_argument("--omega", required=True, metavar="START:STOP:N", help="helix parameter grid")
    p.add_argument(
        "--shortening", required=True, metavar="START:STOP:N", help="cable shortening C grid"
    )
    p.add_argument(
        "--afterload",
        nargs="+",
        metavar="MMHG",
        help="water-column heads in mmHg (default: the scene's); START:STOP:N allowed too",
    )
    p.add_argument(
        "--bpm", nargs="+", metavar="BPM", help="beats per minute (default: the scene's)"
    )
    p.add_argument("--beats", type=int, help="run exactly this many beats (default: until steady)")
    p.add_argument("--accuracy", choices=ACCURACY, help="solver preset (default: the scene's)")
    p.add_argument(
        "--chunk",
        type=int,
        default=DEFAULT_CHUNK,
        metavar="N",
        help=f"points per chunk, one compiled batch (default {DEFAULT_CHUNK})",
    )
    p.add_argument(
        "--workers", type=int, metavar="N", help="start a local Dask cluster of N processes"
    )
    p.add_argument(
        "--scheduler", metavar="ADDRESS", help="use the running Dask scheduler at ADDRESS"
    )
    p.add_argument("--resume", action="store_true", help="continue the unfinished sweep in --out")
    p.add_argument(
        "--uncertainty",
        action="store_true",
        help="also solve the surrogate's posterior draws at every point and add each metric's "
        "95 %% predictive band as <metric>_band_low/_high (draws x points per chunk)",
    )
    p.add_argument(
        "--draws",
        type=int,
        default=16,
        metavar="N",
        help="with --uncertainty: the posterior's first N draws (default 16: a sweep solves "
        "N times its points)",
    )
    add_model_options(p, "sweep the soft pump's design in place of the model's chamber NAME")
    add_output_options(p, "DIR/sweep.nc and DIR/map-*.png")
    p.add_argument("--no-maps", action="store_true", help="with --out: skip the figures")
    add_report_options(p)
    return p


NOT_FOR_MODELS = ("afterload", "bpm", "beats", "workers", "scheduler", "resume", "uncertainty")
"""Options of ``sweep`` an svZeroDSolver model does not take (:mod:`cardiosoft.sweep.model`)."""


def _model_sweep(args, console: Console):
    """The sweep of the pump in the model ``args.scene`` (:func:`cardiosoft.sweep.model.
    model_sweep`): its Dataset. ``ValueError`` for what a model's sweep does not take."""
    from cardiosoft.network import UnsupportedModel
    from cardiosoft.network.pump_in_model import DEFAULT_UNITS, PumpPlacement
    from cardiosoft.sweep.model import model_sweep

    for option in NOT_FOR_MODELS:
        if getattr(args, option) not in (None, False):
            raise ValueError(
                f"--{option}: not taken on an svZeroDSolver model (its pump is swept over Omega "
                "x C at the model's own rate and heads, to its periodic steady state, in this "
                "process)"
            )
    if args.pump_chamber is None:
        raise ValueError(
            "--pump-chamber: missing; name the model's chamber the soft pump takes the place of"
        )
    placement = PumpPlacement(args.pump_chamber, args.units or DEFAULT_UNITS, surrogate=args.pump)
    try:
        return model_sweep(
            args.scene, placement, omega=args.omega, shortening=args.shortening,
            accuracy=args.accuracy or "default", chunk=args.chunk, out=args.out,
            force=args.force, maps=not args.no_maps, progress=not args.quiet, log=console.say,
        )  # fmt: skip
    except UnsupportedModel as err:
        raise ValueError(f"--scene {args.scene}: {err}") from None


def _best(cut, name: str, coords) -> str:
    """The steady point of one map with the largest ``name``, as text."""
    steady_mask = cut["steady"].values
    values = cut[name].values
    note = ""
    if steady_mask.sum():
        values = np.where(steady_mask, values, np.nan)
    elif np.isfinite(values).any():
        note = " (no point steady)"
    if not np.isfinite(values).any():
        return "-"
    i, j = np.unravel_index(np.nanargmax(values), values.shape)
    return f"{values[i, j]:.3f} at ({coords['omega'][i]:g}, {coords['shortening'][j]:g}){note}"


def summary(ds) -> str:
    """Per afterload and bpm: steady points, the ranges of the maps' first and third panels
    (stroke volume and peak force) and the best design by the second (efficiency; a closed
    loop's cardiac output)."""
    (sv_name, _, _), (best_name, _, _), (force_name, _, _) = panels_of(ds)
    lines = [
        f"afterload    bpm  steady      SV ml     peak F N   best {best_name} at (Omega, C)",
    ]
    coords = {d: tuple(np.asarray(ds[d]).tolist()) for d in ds.dims}
    for head, rate in map_keys(coords):
        sel = {"bpm": rate} | ({} if head is None else {"afterload_mmHg": head})
        cut = ds[[sv_name, force_name, best_name, "steady"]].sel(sel).load()
        sv, force = cut[sv_name].values, cut[force_name].values
        steady = int(cut["steady"].values.sum())
        best = _best(cut, best_name, coords)
        sv_range, f_range = _value_range(sv), _value_range(force)
        head_txt = "-" if head is None else f"{head:g} mmHg"
        lines.append(
            f"{head_txt:>9}  {rate:5g}  {steady:6d}  {sv_range:>11}  {f_range:>11}   {best}"
        )
    return "\n".join(lines)


def _value_range(values) -> str:
    """``"low-high"`` of the finite ``values``; ``"-"`` when none is (every point failed:
    numpy's nanmin would warn of an all-NaN slice)."""
    finite = np.asarray(values)[np.isfinite(values)]
    return f"{finite.min():5.1f}-{finite.max():5.1f}" if finite.size else "-"


def _check(args) -> None:
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers {args.workers}: allowed a whole number >= 1")
    if args.workers is not None and args.scheduler is not None:
        raise ValueError("--workers and --scheduler: give one of them")
    if args.resume and not args.out:
        raise ValueError("--resume needs --out DIR, the folder of the unfinished sweep")
    if args.chunk < 1:
        raise ValueError(f"--chunk {args.chunk}: allowed a whole number of points >= 1")


def main(argv=None, prog: str | None = None) -> int:
    """``cardiosoft sweep``: returns the exit status."""
    import jax

    args = parser(prog).parse_args(argv)
    jax.config.update("jax_enable_x64", True)

    console = Console(quiet=args.quiet, strict=args.strict)
    model = args.scene.endswith(".json")  # an svZeroDSolver model, with the pump in it
    try:
        _check(args)
        if not model:
            refuse_model_options(args)
        ds = _model_sweep(args, console) if model else _scene_sweep(args, console)
    except (ValueError, FileNotFoundError) as err:
        return fail(err)
    except KeyboardInterrupt:
        where = (
            f"; rerun with --resume to continue ({Path(args.out) / PARTIAL})"
            if args.out and not model
            else ""
        )
        print(f"interrupted{where}", file=sys.stderr)
        return 130
    if not args.quiet:
        print(summary(ds))
    report_points(console, ds, fixed_beats=args.beats is not None)
    ds.close()
    return console.status()


def _scene_sweep(args, console: Console):
    """The sweep of a scene (:func:`cardiosoft.sweep.design_sweep`): its Dataset."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Dask's notes on ports and memory are not errors
        return design_sweep(
            args.scene if args.pump is None else load_scene(args.scene, pump=args.pump),
            omega=args.omega,
            shortening=args.shortening,
            afterload=values_argument(args.afterload),
            bpm=values_argument(args.bpm),
            beats=args.beats,
            accuracy=args.accuracy,
            out=args.out,
            chunk=args.chunk,
            workers=args.workers,
            scheduler=args.scheduler,
            resume=args.resume,
            force=args.force,
            maps=not args.no_maps,
            progress=not args.quiet,
            uncertainty=args.draws if args.uncertainty else None,
            log=console.say,
        )


def report_points(console: Console, ds, fixed_beats: bool) -> None:
    """Points that failed or missed the steady state (a failure; with ``--beats N`` a point
    still in a transient is a flag), and points whose numbers are flagged."""
    status = np.asarray(ds["status"]).ravel()
    counts = np.bincount(status, minlength=len(STATUS))
    total = status.size
    failing = [
        k for k in range(1, len(STATUS)) if counts[k] and (k != NOT_STEADY or not fixed_beats)
    ]
    if failing:
        detail = ", ".join(f"{counts[k]} {STATUS[k]}" for k in failing)
        console.fail("", f"{sum(counts[k] for k in failing)} of {total} points ({detail})")
    if fixed_beats and counts[NOT_STEADY]:
        console.flag(
            "",
            f"{counts[NOT_STEADY]} of {total} points not steady after --beats "
            f"{int(ds.attrs['max_beats'])} (a transient; 'steady' false in the Dataset)",
        )
    if "band_failed_draws" in ds:
        failed = np.asarray(ds["band_failed_draws"])
        if failed.sum():
            console.flag(
                "",
                f"{int((failed > 0).sum())} of {total} points have posterior draws that failed, "
                f"missed the steady state or emptied the pump ({int(failed.sum())} in all), left "
                "out of their bands ('band_failed_draws' in the Dataset)",
            )
    flagged = int(np.asarray(ds["flagged"]).sum())
    if flagged:
        console.flag(
            "",
            f"{flagged} of {total} points flagged: a pump pressure outside the surrogate's fitted "
            "range, a cable that would push or an efficiency that is not meaningful; in a closed "
            "loop also congestion, a collapsing atrium or blood piled up on one side ('flagged' "
            "in the Dataset)",
        )
