"""Fit the pump surrogate, or report on the shipped one.

    python -m fit                 # fit (~1 min on 2 cores), print the report, write surrogates/
    python -m fit --format 4      # the membrane-true surrogate, surrogates/ss950-v4
    python -m fit --report        # report on the shipped artifact, no refit
    python -m fit --report --artifact ss950-v4
    python -m fit --out DIR/NAME  # write the artifact elsewhere (NAME.eqx + NAME.json)

Run from the repository root. An existing artifact is not overwritten without --force.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def main(argv=None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)

    from cardiosoft import datasets
    from cardiosoft.files import refuse_overwrite
    from fit import fitting, pipeline, report

    parser = argparse.ArgumentParser(prog="python -m fit", description=__doc__.split("\n")[0])
    parser.add_argument(
        "--report", action="store_true", help="report on an existing artifact instead of fitting"
    )
    parser.add_argument(
        "--artifact", metavar="PATH", help="artifact for --report (default: the shipped one)"
    )
    parser.add_argument(
        "--format",
        type=int,
        choices=sorted(pipeline.RECIPES),
        default=3,
        help="3: the paper's data alone (ss950-v3); 4: the membrane inflation as data too, "
        "nothing held (ss950-v4)",
    )
    parser.add_argument(
        "--out",
        metavar="PATH",
        default=None,
        help="where to write the fitted artifact (.eqx and .json; default: "
        "surrogates/<the format's name>)",
    )
    parser.add_argument(
        "--data",
        metavar="DIR",
        default=None,
        help="folder with the paper's CSV files (default: fit/data)",
    )
    parser.add_argument("--force", action="store_true", help="overwrite an existing artifact")
    args = parser.parse_args(argv)

    try:
        data = datasets.load_paper_data(args.data)
        if args.report:
            m, card = report.artifact_metrics(args.artifact, data)
            print(report.format_report(m, data, card["rig"]))
            print("  (leave-one-out values recorded by the fit in the card)")
            return 0 if all(report.verdicts(m).values()) else 1
        recipe = pipeline.RECIPES[args.format]
        out = args.out or f"surrogates/{fitting.ARTIFACT_NAMES[args.format]}"
        out = Path(out).with_suffix(".eqx")
        refuse_overwrite(out, args.force)
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2

    start = time.perf_counter()
    model, _rig, card = fitting.fit(
        data, progress=lambda msg: print(msg, file=sys.stderr), recipe=recipe
    )
    card["fit_seconds"] = round(time.perf_counter() - start, 1)
    fitting.save_artifact(model, out, card, recipe)
    print(report.format_report(card["metrics"], data, card["rig"]))
    print(
        f"\nwrote {out} and {out.with_suffix('.json')} in {card['fit_seconds']} s", file=sys.stderr
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
