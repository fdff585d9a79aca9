"""The command line of the credibility report: ``cardiosoft credibility`` /
``python -m cardiosoft.credibility``.

    cardiosoft credibility --out docs/credibility --force   # the site's page, ~10 min on 2 cores
    cardiosoft credibility --quick --out report/            # the subset CI runs

It runs from a source checkout (the evidence lives in its ``fit/`` and ``tests/`` too) and
writes ``index.md`` (the report), its figures and ``evidence.json`` (every section's text and
checks) into ``--out``, all or none. Exit status: 0 when every acceptance bound is met, 1 when
one is not or a section could not be computed, 2 for bad input.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

from cardiosoft._cli import add_output_options, command_parser

__all__ = ["main", "parser"]

def parser(prog: str | None = None):
    """The argument parser of ``cardiosoft credibility``."""
    p = command_parser(
        "credibility",
        "Recompute the project's credibility evidence (ASME V&V 40: context of use, code and "
        "calculation verification, validation, applicability) and write it as one report.",
        prog=prog,
        flags="checks without an acceptance bound are reported, never flagged",
        failure="an acceptance bound is not met, or a section could not be computed",
        output="evidence.json",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="the subset CI runs (about a minute): the posterior's bench bands and the "
        "hard-case suite read from their stored runs, fewer draws, the test files not rerun",
    )
    p.add_argument(
        "--no-reuse",
        action="store_true",
        help="recompute every section, even one stored under unchanged inputs",
    )
    add_output_options(p, "index.md, its figures and evidence.json")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def main(argv=None, prog: str | None = None) -> int:
    """``cardiosoft credibility``: returns the exit status (module docstring)."""
    args = parser(prog).parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    from cardiosoft._cli import compile_cache_folder
    from cardiosoft.console import fail
    from cardiosoft.credibility.evidence import source_root
    from cardiosoft.credibility.report import EVIDENCE, PAGE, compute
    from cardiosoft.files import check_writable_folder, refuse_overwrite, write_together

    out = Path(args.out) if args.out else None
    try:
        root = source_root()
        if out is not None:
            for name in (PAGE, EVIDENCE):
                refuse_overwrite(out / name, args.force)
            check_writable_folder(out)
    except ValueError as err:
        return fail(err)
    if str(root) not in sys.path:  # the fit's evidence: fit/ at the checkout's root
        sys.path.insert(0, str(root))
    cache = compile_cache_folder()
    store = None if args.no_reuse or cache is None else cache.parent / "credibility"
    start = time.perf_counter()

    def progress(line: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - start:5.0f} s] {line}", file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory() as workdir:
        try:
            report = compute(
                root, quick=args.quick, store=store, workdir=Path(workdir), progress=progress
            )
        except Exception as err:  # a section that cannot be computed: no report, exit 1
            print(f"error: credibility: {type(err).__name__}: {err}", file=sys.stderr)
            return 1
        page = report.page()
        if out is not None:
            with write_together(out) as staging:
                for s in report.sections:
                    for f in s.figures:
                        (staging / f).write_bytes((Path(workdir) / f).read_bytes())
                (staging / PAGE).write_text(page)
                (staging / EVIDENCE).write_text(json.dumps(report.record(), indent=1))
            progress(f"wrote {out / PAGE}")
    if not args.quiet:
        print(page.split("\n## Verdict\n", 1)[1].split("\n## ", 1)[0].strip())
    for check in report.failed:
        print(f"not met: {check.name}: {check.value} (target {check.target})", file=sys.stderr)
    return 1 if report.failed else 0
