"""Command line: simulate the soft pump in a scene and print what a researcher asks first.

    python -m cardiosoft.simulate --bpm 60
    python -m cardiosoft.simulate --bpm 30 --compare-paper --out results/

Runs the ``bench-dynamic`` scene (the paper's water-column bench) at 30, 60 and 90 mmHg by
default and prints stroke volumes, peak force, mechanical work, efficiency and the beats to
steady state. ``--out DIR`` writes ``summary.json``, ``traces.csv`` and a Fig. 10-style figure.
Exit status: 0 when every member is solved, at its periodic steady state and inside the
surrogate's fitted range; 1 when the table is printed but some member is not (a warning line
each says why); 2 for bad input.
The numerics live in :func:`cardiosoft.experiment.run`; this module only parses and prints.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from pathlib import Path

OUTPUT_FILES = ("summary.json", "traces.csv", "figure.png")


def _parser() -> argparse.ArgumentParser:
    from cardiosoft.scene import ACCURACY, LOOP_SCENE_NAMES, RANGES, SCENE_NAMES

    def allowed(field, left="["):
        lo, hi = RANGES[field]
        return f"{left}{lo:g}, {hi:g}]"

    p = argparse.ArgumentParser(
        prog="python -m cardiosoft.simulate",
        description="Simulate the cable-driven soft pump beating against an afterload.",
    )
    p.add_argument(
        "--scene",
        default="bench-dynamic",
        help=f"shipped scene ({', '.join(SCENE_NAMES)}; closed loops: "
        f"{', '.join(LOOP_SCENE_NAMES)}) or a scene .toml file (default: bench-dynamic)",
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
        default="beats",
        help="reach the periodic steady state beat after beat (default) or by Newton shooting "
        "on the one-beat map (robust at high rates; compiles longer)",
    )
    p.add_argument(
        "--max-steps",
        type=int,
        metavar="N",
        help="most solver steps per beat, [100, 1e7] (default: the preset's)",
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
    p.add_argument("--out", metavar="DIR", help="write summary.json, traces.csv, figure.png")
    p.add_argument("--no-plot", action="store_true", help="with --out: skip the figure")
    p.add_argument(
        "--verify",
        action="store_true",
        help="rerun at the reference preset and print each metric's difference, the run's "
        "numerical error estimate (calculation verification); recorded in summary.json",
    )
    p.add_argument("--force", action="store_true", help="overwrite existing files in --out")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def _fmt(value, spec):
    return (
        "-"
        if value is None or (isinstance(value, float) and math.isnan(value))
        else format(value, spec)
    )


# (header, unit, summary record key, format): one spec per table, so that headers, units and
# cells cannot drift apart. The paper's rows reuse the bench spec with the same keys.
_BENCH_COLUMNS = (
    ("afterload", "mmHg", "afterload_mmHg", ".0f"),
    ("static SV", "ml", "static_sv_ml", ".1f"),
    ("dynamic SV", "ml", "dynamic_sv_ml", ".1f"),
    ("peak force", "N", "peak_force_N", ".1f"),
    ("mech. work", "J", "mech_work_J", ".2f"),
    ("efficiency", "-", "efficiency", ".3f"),
    ("EF", "-", "ef", ".2f"),
    ("beats", "", "beats", "d"),
)
_CIRCULATION_COLUMNS = (
    ("scene", "", "label", "s"),
    ("SV", "ml", "dynamic_sv_ml", ".1f"),
    ("EDV", "ml", "edv_ml", ".1f"),
    ("ESV", "ml", "esv_ml", ".1f"),
    ("EF", "-", "ef", ".2f"),
    ("CO", "l/min", "cardiac_output_l_min", ".2f"),
    ("peak force", "N", "peak_force_N", ".1f"),
    ("mech. work", "J", "mech_work_J", ".2f"),
    ("beats", "", "beats", "d"),
)


def _is_loop(scene) -> bool:
    from cardiosoft.loop_scene import LoopScene

    return isinstance(scene, LoopScene)


def _design(scene) -> dict:
    """The design of the summary: Omega and C, or each pump's of a closed loop."""
    if not _is_loop(scene):
        return {"omega": scene.omega, "shortening": scene.shortening}
    pumps = {c: getattr(scene, c) for c in scene.pumps}
    return {"pumps": {c: {"omega": p.omega, "shortening": p.shortening} for c, p in pumps.items()}}


def _heading(scene) -> str:
    if not _is_loop(scene):
        return f"{scene.name} at {scene.bpm:g} bpm, Omega {scene.omega:g}, C {scene.shortening:g}"
    pumps = [
        f"{c.upper()} pump Omega {getattr(scene, c).omega:g}, C {getattr(scene, c).shortening:g}"
        for c in scene.pumps
    ]
    return ", ".join([f"{scene.name} (closed loop) at {scene.bpm:g} bpm", *pumps])


def _table(records, scene, paper) -> str:
    if _is_loop(scene):
        from cardiosoft.loop_records import loop_table

        return loop_table(records)
    columns = _BENCH_COLUMNS if scene.afterload.has_heads else _CIRCULATION_COLUMNS
    head = [c[0] for c in columns]
    units = [c[1] for c in columns]
    rows = []
    for r in records:
        rows.append([_fmt(r.get(key), fmt) for _, _, key, fmt in columns])
        if paper is not None and r.get("afterload_mmHg") in paper:
            p = {**paper[r["afterload_mmHg"]], "afterload_mmHg": None}
            rows.append(["  paper", *[_fmt(p.get(key), fmt) for _, _, key, fmt in columns[1:]]])
    widths = [max(len(x) for x in col) for col in zip(head, units, *rows, strict=True)]
    line = "  ".join
    out = [
        line(h.rjust(w) for h, w in zip(head, widths, strict=True)),
        line(u.rjust(w) for u, w in zip(units, widths, strict=True)),
    ]
    out += [line(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in rows]
    return "\n".join(out)


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


def _write_outputs(out_dir: Path, result, records, plot: bool, extra=None) -> list[Path]:
    """Write every file to a staging folder first, then move them all into place."""
    import shutil
    import tempfile

    from cardiosoft.units import ml, mm, mmHg

    out_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=out_dir, prefix=".staging-"))
    try:
        (staging / "summary.json").write_text(
            json.dumps(
                {
                    "scene": result.scene.name,
                    "bpm": result.scene.bpm,
                    **_design(result.scene),
                    "records": records,
                    **(extra or {}),
                },
                indent=2,
            )
            + "\n"
        )
        columns = [
            ("time_s", "time", 1.0),
            ("pull_mm", "pull", mm),
            ("volume_ml", "volume", ml),
            ("pump_pressure_mmHg", "pump_pressure", mmHg),
            ("afterload_pressure_mmHg", "node_pressure", mmHg),
            ("outflow_ml_per_s", "outflow", ml),
            ("cable_force_N", "cable_force", 1.0),
            ("column_volume_ml", "column_volume", ml),
        ]
        if _is_loop(result.scene):
            from cardiosoft.loop_records import loop_trace_columns

            columns = loop_trace_columns(result.members[0].traces)
        with open(staging / "traces.csv", "w", newline="") as f:
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
        written = ["summary.json", "traces.csv"]
        if plot:
            from cardiosoft.plots import plot_closed_loop, plot_fig10

            draw = plot_closed_loop if _is_loop(result.scene) else plot_fig10
            draw(result, staging / "figure.png")
            written.append("figure.png")
        targets = [out_dir / name for name in written]
        for name, target in zip(written, targets, strict=True):
            (staging / name).replace(target)
        return targets
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    from cardiosoft._cli import fail
    from cardiosoft._validate import check_range
    from cardiosoft.experiment import configure, run
    from cardiosoft.files import check_writable_folder, refuse_overwrite
    from cardiosoft.results import summary_records

    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr))
    try:
        out_dir = Path(args.out) if args.out else None
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
        )
        if args.beats is not None:
            check_range("beats", args.beats, "beats", 1, 500)
        loop = _is_loop(scene)
        if args.compare_paper and (loop or not scene.afterload.has_heads):
            raise ValueError(f"--compare-paper: scene {scene.name} is not the paper's bench")
        if args.verify and loop:
            raise ValueError(f"--verify: not available for a closed-loop scene ({scene.name}) yet")
        what = (
            "quasi-static pull, one root find per cable position"
            if scene.static
            else "compiling, then solving beat by beat to the periodic steady state"
        )
        n = 1 if loop else max(1, len(scene.afterloads))
        say(f"{scene.name}: {n} afterload(s), {scene.bpm:g} bpm; {what} ...")
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
    say(f"done in {run_seconds:.1f} s")
    records = summary_records(result)
    if not args.quiet:
        paper = _paper_values() if args.compare_paper else None
        print(_heading(result.scene) + ("   (paper: 30 bpm)" if paper is not None else ""))
        print(_table(records, result.scene, paper))
        for m in result.members:
            if not m.ok:
                print(f"warning: {m.label}: {m.message}", file=sys.stderr)
            for what in m.flags:
                print(f"warning: {m.label}: {what}", file=sys.stderr)
    extra = None
    if args.verify:
        from cardiosoft.verify import verify_run

        say("verifying: rerunning tighter (the reference preset; a finer pull grid) ...")
        check = verify_run(result, beats=args.beats, steady=args.steady)
        extra = {"verification": check.record()}
        if not args.quiet:
            print(check.table(run_seconds=run_seconds))
    if out_dir is not None:
        try:
            written = _write_outputs(out_dir, result, records, not args.no_plot, extra)
        except OSError as err:  # checked before the run; the system can still refuse
            return fail(ValueError(f"--out {out_dir}: {err.strerror or err}; nothing written"))
        for path in written:
            say(f"wrote {path}")
    # 1: printed, but some member is not to be trusted as it is (module docstring)
    return 0 if result.ok and not result.flagged else 1


if __name__ == "__main__":
    # The main job's time is start-up: the solve takes ~30 ms after seconds of compiling it.
    # LLVM's optimisation of the generated CPU code is about 2 s of those and buys nothing for
    # one solve (results agree to 1e-13). Set here, not in main(), so that it stays with this
    # process; an XLA_FLAGS of the user's own is left as it is.
    os.environ.setdefault("XLA_FLAGS", "--xla_backend_optimization_level=0")
    from cardiosoft._cli import use_compile_cache

    use_compile_cache()  # the next process loads what this one compiles
    raise SystemExit(main())
