"""The credibility report's validation section (cardiosoft.credibility.validation): its verdicts
on the posterior's bands are what ``python -m fit.posterior --check`` recorded, and each
comparison's band is the one of its own point (issue #42)."""

import json
import re
from pathlib import Path

import pytest

from cardiosoft.credibility.validation import posterior_checks, validation
from cardiosoft.pump import artifact_path
from fit.posterior import artifact

TABLE2_BOUND = 8
"""Issue #24's bound: at least 8 of Table II's 9 experiments inside their bands."""


def _recorded() -> dict:
    """What ``fit.posterior --check`` recorded in the shipped posterior's card."""
    _, card = artifact.posterior_paths(artifact_path(None))
    return json.loads(Path(card).read_text())["checks"]


def _coverage(value: str) -> tuple[int, int, float]:
    """(inside, of, mean width) of a coverage check's value."""
    found = re.match(r"(\d+) of (\d+) \(Wilson 95 %: [\d.]+-[\d.]+; mean width ([\d.]+)\)", value)
    return int(found[1]), int(found[2]), float(found[3])


def _same(check, summary, bound):
    inside, of, width = _coverage(check.value)
    assert (inside, of) == (summary["inside"], summary["of"]), (check, summary)
    # the width is printed to 3 significant digits: the report rounds, nothing else
    assert width == pytest.approx(summary["mean_width"], rel=5e-3), (check, summary)
    assert check.met is (None if bound is None else summary["inside"] >= bound), check


def test_the_report_says_what_fit_posterior_check_recorded():
    """Table II's bands are recomputed by the report (the same draws, noise and seed as
    ``--check``): its count and width must be what ``--check`` recorded, and its verdict
    issue #24's bound on that count. The --quick report reads the bench and the
    leave-one-afterload-out checks from the card: they must say what the card says."""
    recorded = _recorded()
    checks = {c.name: c for c in posterior_checks(True, lambda m: None).checks}
    _same(checks["Table II (experiments) inside the 95 % bands"], recorded["table2"],
          TABLE2_BOUND)  # fmt: skip
    n = recorded["bench_dynamic_sv"]["of"]
    _same(checks["30-bpm bench dynamic SV inside the 95 % bands"],
          recorded["bench_dynamic_sv"], n)  # fmt: skip
    _same(checks["30-bpm bench peak force inside the 95 % bands"],
          recorded["bench_peak_force"], n)  # fmt: skip
    _same(checks["leave one afterload out: dynamic SV inside"],
          recorded["leave_one_afterload_out_dynamic_sv"], None)  # fmt: skip


@pytest.fixture(scope="module")
def full_section(tmp_path_factory):
    return validation(tmp_path_factory.mktemp("validation"), False, lambda m: None)


@pytest.mark.slow  # the full section: the posterior's 256 draws on the bench, about 2 min
def test_the_full_report_recomputes_what_fit_posterior_check_recorded(full_section):
    recorded = _recorded()
    checks = {c.name: c for c in full_section.checks}
    n = recorded["bench_dynamic_sv"]["of"]
    _same(checks["30-bpm bench dynamic SV inside the 95 % bands"],
          recorded["bench_dynamic_sv"], n)  # fmt: skip
    _same(checks["30-bpm bench peak force inside the 95 % bands"],
          recorded["bench_peak_force"], n)  # fmt: skip


@pytest.mark.slow
def test_each_comparison_of_fig10_has_the_band_of_its_own_point(full_section):
    """Every Fig. 10 line with a band (static and dynamic SV, peak force, efficiency, at each
    head) holds the model's own value at that point: the fit's optimum lies well inside the
    posterior's 95 % band (measured: at least 0.2 of the band's width from its nearest edge).
    A band of another head or another metric misses it (the static SV's bands at 30 and
    90 mmHg, [64.7, 70.4] and [53.1, 58.6] ml, do not overlap)."""
    rows = [line.split(" | ") for line in full_section.text.splitlines()
            if line.startswith("| Fig. 10") and "| [" in line]  # fmt: skip
    assert len(rows) == 12, full_section.text  # 4 metrics x 3 heads
    for row in rows:
        model = float(row[3].split()[0])
        low, high = (float(x) for x in row[4].strip("[]").split(", "))
        assert low < model < high, row
