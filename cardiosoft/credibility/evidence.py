"""The report's pieces: a check (one line of the verdict table) and a section (one credibility
factor of ASME V&V 40: its text, its checks, its figures), and the store that lets a rerun reuse
a section whose inputs are unchanged.

A section is computed by a function ``(folder, quick, progress) -> Section``: ``folder`` is where
its figures go (PNG files named in :attr:`Section.figures`), ``quick`` asks for the subset that
CI runs, ``progress`` takes one line of text at a time. Its text is Markdown without a title
(the report writes the title).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

__all__ = ["BASES", "Check", "Section", "inputs_digest", "load_stored", "source_root"]

BASES = ("fitted", "held out", "verification", "no bound")
"""What a check's comparator is: data the model was fitted to, data it never saw, a
verification (an analytic solution, a second method, a peer solver, a reference solve), or a
number reported beside a comparator with no acceptance bound of its own."""


@dataclasses.dataclass(frozen=True)
class Check:
    """One line of the verdict table.

    ``target`` and ``value`` are text with their units (``"<= 1.5 ml"``, ``"1.41 ml"``);
    ``basis`` one of :data:`BASES`; ``met`` None where there is no bound to meet; ``source``
    the command that says the same (``python -m fit --report``)."""

    name: str
    target: str
    value: str
    basis: str
    met: bool | None
    source: str = ""

    def __post_init__(self):
        if self.basis not in BASES:
            raise ValueError(f"check {self.name!r}: basis {self.basis!r} is not one of {BASES}")
        if (self.met is None) != (self.basis == "no bound"):
            raise ValueError(f"check {self.name!r}: a bound is met or not exactly when it exists")


@dataclasses.dataclass(frozen=True)
class Section:
    """One credibility factor: Markdown ``text``, its ``checks`` and the ``figures`` it wrote."""

    key: str
    title: str
    text: str
    checks: tuple[Check, ...] = ()
    figures: tuple[str, ...] = ()

    def record(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_record(cls, record: dict) -> Section:
        checks = tuple(Check(**c) for c in record["checks"])
        return cls(**{**record, "checks": checks, "figures": tuple(record["figures"])})


def inputs_digest(root: Path) -> str:
    """sha256 of what every section's numbers come from: cardiosoft's and the fit's sources,
    the shipped surrogates and posteriors, the paper's data and the vendored svZeroDSolver
    cases. A rerun reuses a stored section only under the same digest."""
    digest = hashlib.sha256()
    folders = ("cardiosoft", "fit", "surrogates", "tests/data/svzerod")
    for folder in folders:
        for path in sorted((root / folder).rglob("*")):
            if path.is_file() and "__pycache__" not in path.parts:
                digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def load_stored(path: Path, digest: str) -> dict[str, Section]:
    """The sections stored at ``path`` (a report's record) under ``digest``; none otherwise."""
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if stored.get("inputs_sha256") != digest:
        return {}
    return {key: Section.from_record(r) for key, r in stored.get("sections", {}).items()}


def source_root() -> Path:
    """The source checkout this cardiosoft runs from; ``ValueError`` without one."""
    import cardiosoft

    root = Path(cardiosoft.__file__).resolve().parents[1]
    if not (root / "fit" / "report.py").is_file() or not (root / "tests").is_dir():
        raise ValueError(
            f"credibility: needs a source checkout (fit/ and tests/ beside {root / 'cardiosoft'}); "
            "this cardiosoft is installed from a wheel: clone the repository and "
            "pip install -e . there"
        )
    return root
