"""The credibility report: its sections computed (or reused), and written as one Markdown page
with its figures and the evidence as JSON.

A section is reused from a stored run when everything its numbers come from is unchanged
(:func:`~cardiosoft.credibility.evidence.inputs_digest`): the store is a folder beside the
compile cache (``~/.cache/cardiosoft/credibility``): the last report of each subset (full,
quick), its sections under the digest of their inputs, and its figures.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import shutil
import time
from pathlib import Path

from cardiosoft.credibility.evidence import Check, Section, inputs_digest, load_stored

__all__ = ["Report", "compute", "factors", "verdict_table"]

PAGE = "index.md"
EVIDENCE = "evidence.json"


def factors():
    """(key, function) of each section, in the report's order (V&V 40's credibility
    factors). Imported here: each pulls in what it computes with."""
    from cardiosoft.credibility.applicability import applicability
    from cardiosoft.credibility.calculation_verification import calculation_verification
    from cardiosoft.credibility.code_verification import code_verification
    from cardiosoft.credibility.context import context_of_use
    from cardiosoft.credibility.validation import validation

    return (
        ("context_of_use", context_of_use),
        ("code_verification", code_verification),
        ("calculation_verification", calculation_verification),
        ("validation", validation),
        ("applicability", applicability),
    )


@dataclasses.dataclass(frozen=True)
class Report:
    """The computed sections, where their figures are, and which were reused."""

    sections: tuple[Section, ...]
    figures: Path
    digest: str
    quick: bool
    reused: tuple[str, ...]

    @property
    def checks(self) -> list[tuple[str, Check]]:
        return [(s.title, c) for s in self.sections for c in s.checks]

    @property
    def failed(self) -> list[Check]:
        """The checks whose acceptance bound is not met."""
        return [c for _, c in self.checks if c.met is False]

    def page(self) -> str:
        """The report as Markdown: the verdict table on top, then each section."""
        bounded = [c for _, c in self.checks if c.met is not None]
        met = sum(c.met for c in bounded)
        today = datetime.date.today().isoformat()
        head = [
            "# Credibility report",
            "",
            f"Written by `cardiosoft credibility{' --quick' if self.quick else ''}` on "
            f"{today}, in the structure of ASME V&V 40 (2018) and the FDA's 2023 guidance on "
            "computational modelling: the contexts of use, then the evidence by credibility "
            f"factor. **{met} of {len(bounded)} acceptance bounds met**"
            + (f"; not met: {', '.join(c.name for c in self.failed)}." if self.failed else ".")
            + f" Inputs sha256 `{self.digest[:12]}`"
            + (f"; sections reused from a stored run: {', '.join(self.reused)}." if self.reused
               else "."),
            "",
            "## Verdict",
            "",
            verdict_table(self.checks),
        ]  # fmt: skip
        body = []
        for s in self.sections:
            body += ["", f"## {s.title}", "", s.text]
        return "\n".join(head + body) + "\n"

    def record(self) -> dict:
        return {
            "inputs_sha256": self.digest,
            "quick": self.quick,
            "sections": {s.key: s.record() for s in self.sections},
        }


def verdict_table(checks: list[tuple[str, Check]]) -> str:
    """One line per check: factor, check, target, value, fitted or held out, verdict, and the
    command that says the same."""
    verdict = {True: "met", False: "**NOT MET**", None: "-"}
    rows = [
        "| factor | check | target | value | basis | verdict | also says it |",
        "|---|---|---|---|---|---|---|",
    ]
    for factor, c in checks:
        cells = [factor, c.name, c.target, c.value, c.basis, verdict[c.met]]
        cells.append(f"`{c.source}`" if c.source else "")
        rows.append("| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |")
    return "\n".join(rows)


def compute(
    root: Path, *, quick: bool, store: Path | None, workdir: Path, progress, sections=None
) -> Report:
    """Compute each section (or reuse it from ``store`` under the same inputs), its figures
    written to ``workdir``; ``root``: the source checkout (its ``fit/`` and ``tests/``);
    ``sections``: (key, function) pairs, default :func:`factors`."""
    digest = inputs_digest(root)
    name = "quick" if quick else "full"
    stored = {} if store is None else load_stored(store / f"{name}.json", digest)
    done, reused = [], []
    for key, compute_section in factors() if sections is None else sections:
        section = stored.get(key)
        if section is not None and all((store / name / f).is_file() for f in section.figures):
            for f in section.figures:
                shutil.copy2(store / name / f, workdir / f)
            reused.append(section.title)
            progress(f"{section.title}: reused (inputs unchanged)")
        else:
            start = time.perf_counter()
            section = compute_section(workdir, quick, progress)
            progress(f"{section.title}: {time.perf_counter() - start:.0f} s")
        done.append(section)
    report = Report(tuple(done), workdir, digest, quick, tuple(reused))
    if store is not None:
        _remember(report, store / f"{name}.json", store / name)
    return report


def _remember(report: Report, path: Path, figures: Path) -> None:
    """Store the report's sections and figures for a rerun; a store that cannot be written
    only costs the rerun its time."""
    from cardiosoft.files import atomic_path

    try:
        figures.mkdir(parents=True, exist_ok=True)
        for s in report.sections:
            for f in s.figures:
                shutil.copy2(report.figures / f, figures / f)
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(report.record(), indent=1))
    except OSError as err:
        print(f"warning: credibility store {path.parent}: {err}")
