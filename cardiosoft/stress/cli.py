"""The command line of the hard-case suite: ``cardiosoft stress`` / ``python -m cardiosoft.stress``.

It prints a progress line per batch and one table on stdout; the suite is
:func:`cardiosoft.stress.run_suite`'s.
"""

from __future__ import annotations

import json
import time

from cardiosoft._cli import add_report_options, command_parser
from cardiosoft.console import Console
from cardiosoft.scene import LOOP_SCENE_NAMES, SCENE_NAMES
from cardiosoft.solve import ACCURACY_PRESETS
from cardiosoft.stress.cases import GRID_BPMS, GROUPS, PROPERTY_EXAMPLES, fmt
from cardiosoft.stress.loop_cases import LOOP_BPMS
from cardiosoft.stress.report import SuiteReport
from cardiosoft.stress.suite import plan, run_suite

__all__ = ["main", "parser", "report_outcomes"]


def parser(prog: str | None = None):
    """The argument parser of ``cardiosoft stress``."""
    p = command_parser(
        "stress",
        "The hard-case suite: every shipped scene at the edges of what it allows; prints one "
        "table.",
        prog=prog,
        flags="a case that fails in a way listed in cardiosoft.stress.KNOWN_FAILURES (a known "
        "bug); a case whose numbers the library flagged itself, as it should, is not one",
        failure="a case FAILED (a check does not hold)",
        output="--json",
    )
    p.add_argument("--quick", action="store_true", help="the CI subset (about a minute)")
    p.add_argument(
        "--scene",
        action="append",
        choices=SCENE_NAMES + LOOP_SCENE_NAMES,
        help="only this scene (repeat for more; default: all; the closed loops "
        f"{', '.join(LOOP_SCENE_NAMES)} run in group closed_loop only)",
    )
    p.add_argument(
        "--group",
        action="append",
        choices=GROUPS,
        help="only this group of cases (repeat for more; default: all)",
    )
    p.add_argument(
        "--preset",
        action="append",
        choices=ACCURACY_PRESETS,
        help="only this accuracy preset in the grid (repeat for more)",
    )
    p.add_argument(
        "--bpm",
        action="append",
        type=float,
        help=f"only this rate (repeat for more; default: {', '.join(map(fmt, GRID_BPMS))}; "
        f"the closed loops {', '.join(map(fmt, LOOP_BPMS))})",
    )
    p.add_argument(
        "--examples",
        type=int,
        help=f"hypothesis examples per scene structure (default: {PROPERTY_EXAMPLES}; "
        "1 with --quick)",
    )
    p.add_argument("--seed", type=int, default=14, help="hypothesis seed (default: 14)")
    p.add_argument("--json", metavar="FILE", help="write one record per case to FILE")
    add_report_options(p)
    return p


def _print_report(report: SuiteReport, seconds: float) -> None:
    print()
    print(report.table())
    details = report.details()
    if details:
        print()
        print(details)
    for note in report.notes:
        print(note)
    c = report.count()
    print(
        f"{c['failed']} failed, {c['known']} known, {c['flagged']} flagged, {c['passed']} passed "
        f"in {seconds:.0f} s"
    )


def main(argv=None, prog: str | None = None) -> int:
    """``cardiosoft stress``: returns the exit status."""
    import jax

    args = parser(prog).parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    start = time.perf_counter()
    batches = plan(
        quick=args.quick,
        scenes=args.scene,
        groups=args.group,
        presets=args.preset,
        bpms=args.bpm,
        examples=args.examples,
        seed=args.seed,
    )
    show = (lambda line: None) if args.quiet else (lambda line: print(line, flush=True))
    if args.group is None or "property" in args.group:
        try:
            import hypothesis  # noqa: F401
        except ImportError:
            show(
                "property-based cases: hypothesis is not installed (pip install -e '.[test]'); "
                "skipped"
            )
    n = sum(len(b) for b in batches)
    show(f"hard-case suite{' (quick)' if args.quick else ''}: {len(batches)} batches, {n} cases")
    report = run_suite(batches, log=show)
    if not args.quiet:
        _print_report(report, time.perf_counter() - start)
    if args.json:
        from cardiosoft.files import atomic_path

        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(report.records(), indent=1) + "\n")
    console = Console(quiet=args.quiet, strict=args.strict)
    report_outcomes(console, report)
    return console.status()


def report_outcomes(console: Console, report: SuiteReport) -> None:
    """A failed case is a failure (exit status 1); a known failure a flag (``--strict``: 1); a
    flagged case neither: the library flagged its own numbers, as the checks require."""
    for o in report.outcomes:
        if o.status in ("failed", "known"):
            what = "; ".join(f"{check}: {text}" for check, text in o.problems)
            (console.fail if o.status == "failed" else console.flag)(o.case.id, what)
