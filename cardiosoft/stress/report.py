"""The report of a hard-case run: every outcome, a table per group, the details of each failed
and known case (with the Python that runs it alone), and one JSON record per case."""

from __future__ import annotations

import dataclasses

from cardiosoft.stress.cases import GROUPS
from cardiosoft.stress.checks import STATUSES, Outcome

__all__ = ["SuiteReport"]


@dataclasses.dataclass
class SuiteReport:
    """Every outcome, and the time each group took (s)."""

    outcomes: list[Outcome] = dataclasses.field(default_factory=list)
    times: dict[str, float] = dataclasses.field(default_factory=dict)
    energy: bool = True
    notes: list[str] = dataclasses.field(default_factory=list)

    def count(self, group: str | None = None) -> dict[str, int]:
        counts = dict.fromkeys(STATUSES, 0)
        for o in self.outcomes:
            if group is None or o.case.group == group:
                counts[o.status] += 1
        return counts

    @property
    def failures(self) -> list[Outcome]:
        return [o for o in self.outcomes if o.status == "failed"]

    @property
    def exit_code(self) -> int:
        """1 when a case failed, else 0 (known failures and flagged cases do not count; the
        command line's ``--strict`` makes a known failure count)."""
        return 1 if self.failures else 0

    def table(self) -> str:
        groups = [g for g in GROUPS if any(o.case.group == g for o in self.outcomes)]
        head = ("group", "cases", "passed", "flagged", "failed", "known", "time s")
        rows = []
        for g in [*groups, None]:
            c = self.count(g)
            t = sum(self.times.values()) if g is None else self.times.get(g, 0.0)
            rows.append((g or "total", str(sum(c.values())), *map(str, c.values()), f"{t:.1f}"))
        widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]

        def line(row):
            cells = zip(row, widths, strict=True)
            return "  ".join(x.ljust(w) if i == 0 else x.rjust(w) for i, (x, w) in enumerate(cells))

        return "\n".join([line(head), *(line(r) for r in rows)])

    def details(self) -> str:
        """Each failed and known case, what is wrong, and how to run it alone."""
        out = []
        for status in ("failed", "known"):
            for o in (o for o in self.outcomes if o.status == status):
                out.append(f"{status.upper()} {o.case.id}")
                for check, text in o.problems:
                    out.append(f"    {check}: {text}")
                for note in o.notes:
                    out.append(f"    note: {note}")
                for reason in o.known:
                    out.append(f"    known: {reason}")
                out.append(f"    run alone: {o.case.reproduce()}")
        return "\n".join(out)

    def records(self) -> list[dict]:
        """One JSON-ready record per case."""
        return [
            {
                "id": o.case.id,
                "group": o.case.group,
                "status": o.status,
                "problems": [list(p) for p in o.problems],
                "notes": list(o.notes),
                "known": list(o.known),
                "run_alone": o.case.reproduce(),
            }
            for o in self.outcomes
        ]
