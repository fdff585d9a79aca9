"""The credibility report (issue #42, ``cardiosoft credibility``): the verdict table says what
each check says, a section is reused only under unchanged inputs, bad input writes nothing.

The sections' own numbers are checked where they are computed: the fit's verdicts against
``python -m fit --report`` (tests/test_fit.py), the code verification and the applicability in
their own files; here, sections made up for the test stand for them, so the report's logic is
checked in a second, not in minutes. The whole quick report runs in the slow suite.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import pytest

from cardiosoft.credibility.cli import main
from cardiosoft.credibility.evidence import Check, Section
from cardiosoft.credibility.report import compute, factors

CALLS = []


def _made_up(folder: Path, quick: bool, progress) -> Section:
    """A section with a bound met, a bound not met, a number without a bound and a figure."""
    CALLS.append(quick)
    (folder / "made-up.png").write_bytes(b"\x89PNG made up")
    checks = (
        Check("order of convergence", "5 +- 0.5", "4.9", "verification", True, "a command"),
        Check("mean |error|", "<= 1 ml", "1.4 ml", "held out", False),
        Check("band width", "no bound", "12 ml", "no bound", None),
    )
    return Section("made_up", "Made up", "Text of the section.", checks, ("made-up.png",))


def _root(tmp_path: Path, source: str = "x = 1\n") -> Path:
    """A stand-in checkout: what the inputs' digest reads."""
    root = tmp_path / "checkout"
    (root / "cardiosoft").mkdir(parents=True, exist_ok=True)
    (root / "cardiosoft" / "module.py").write_text(source)
    return root


def _compute(tmp_path, root, store):
    work = Path(tempfile.mkdtemp(dir=tmp_path))
    return compute(root, quick=True, store=store, workdir=work, progress=lambda m: None,
                   sections=[("made_up", _made_up)])  # fmt: skip


@pytest.fixture(autouse=True)
def _calls():
    CALLS.clear()


def test_the_verdict_table_counts_the_bounds_and_names_what_is_not_met(tmp_path):
    report = _compute(tmp_path, _root(tmp_path), store=None)
    page = report.page()
    assert "**1 of 2 acceptance bounds met**; not met: mean |error|." in page
    assert [c.name for c in report.failed] == ["mean |error|"]
    table = page.split("## Verdict\n", 1)[1].split("\n## ", 1)[0]
    rows = table.strip().splitlines()[2:]
    assert len(rows) == 3
    assert "| Made up | mean \\|error\\| | <= 1 ml | 1.4 ml | held out | **NOT MET** |" in rows[1]
    assert rows[2].count(" - |") == 1  # no bound: no verdict
    assert "## Made up\n\nText of the section." in page


def test_a_section_is_reused_under_the_same_inputs_and_recomputed_when_they_change(tmp_path):
    store = tmp_path / "store"
    root = _root(tmp_path)
    first = _compute(tmp_path, root, store)
    again = _compute(tmp_path, root, store)
    assert CALLS == [True] and again.reused == ("Made up",) and not first.reused
    assert again.sections == first.sections
    assert (again.figures / "made-up.png").read_bytes() == b"\x89PNG made up"

    _root(tmp_path, "x = 2\n")  # an input changed: the stored section is not trusted
    changed = _compute(tmp_path, root, store)
    assert CALLS == [True, True] and not changed.reused


def test_a_check_says_its_basis_and_has_a_verdict_exactly_when_it_has_a_bound():
    with pytest.raises(ValueError, match="basis"):
        Check("x", "<= 1", "0.5", "measured", True)
    with pytest.raises(ValueError, match="bound"):
        Check("x", "<= 1", "0.5", "held out", None)
    with pytest.raises(ValueError, match="bound"):
        Check("x", "none", "0.5", "no bound", True)


def test_the_report_has_the_factors_of_vv40_in_order():
    assert [key for key, _ in factors()] == [
        "context_of_use", "code_verification", "calculation_verification", "validation",
        "applicability",
    ]  # fmt: skip


def test_an_existing_report_is_not_overwritten(tmp_path, capsys):
    (tmp_path / "index.md").write_text("an earlier report\n")
    assert main(["--quick", "--out", str(tmp_path)]) == 2
    assert "--force" in capsys.readouterr().err
    assert (tmp_path / "index.md").read_text() == "an earlier report\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["index.md"]


@pytest.mark.slow
def test_the_quick_report_end_to_end(tmp_path):
    """``cardiosoft credibility --quick --out DIR``: every factor computed, the page and the
    evidence written together, the exit status 1 exactly when a bound is not met."""
    out = tmp_path / "report"
    status = main(["--quick", "--no-reuse", "--out", str(out), "--quiet"])
    evidence = json.loads((out / "evidence.json").read_text())
    assert list(evidence["sections"]) == [key for key, _ in factors()]
    checks = [c for s in evidence["sections"].values() for c in s["checks"]]
    assert len(checks) >= 20
    assert status == (1 if any(c["met"] is False for c in checks) else 0)
    page = (out / "index.md").read_text()
    for s in evidence["sections"].values():
        assert f"## {s['title']}" in page
        for figure in s["figures"]:
            assert (out / figure).is_file() and f"({figure})" in page
