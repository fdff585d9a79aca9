"""The credibility report's applicability section (cardiosoft.credibility.applicability), in
its quick form (8 posterior draws, the bench at 30 and 60 bpm; about a minute on 2 cores)."""

import re

import pytest

from cardiosoft.credibility.applicability import FIGURE, MEASURED_BPM, applicability
from cardiosoft.credibility.evidence import BASES


@pytest.fixture(scope="module")
def section(tmp_path_factory):
    folder = tmp_path_factory.mktemp("applicability")
    return folder, applicability(folder, quick=True, progress=lambda m: None)


def _widths(section, name):
    """The band widths (one per head) of the check named ``name``: ``"13.1, 11.8 ml at ..."``."""
    (check,) = [c for c in section.checks if c.name == name]
    assert check.basis == "no bound" and check.met is None
    return [float(w) for w in re.match(r"([\d., ]+) (ml|N) at", check.value)[1].split(", ")]


@pytest.mark.parametrize("metric", ["dynamic SV", "peak force"])
def test_band_is_wider_at_an_unmeasured_rate(section, metric):
    # measured on the shipped posterior: SV 13.1/11.8/14.2 ml at 30 bpm against 66.5/89.1/110.9
    # at 60; force 36.7/31.3/37.1 N against 54.4/138.3/105.1 (8 draws)
    _, s = section
    measured = _widths(s, f"{metric} 95 % band width, bench at {MEASURED_BPM:g} bpm (measured)")
    away = _widths(s, f"{metric} 95 % band width, bench at 60 bpm (not measured)")
    assert len(measured) == len(away) == 3  # the paper's three heads
    for head_measured, head_away in zip(measured, away, strict=True):
        assert head_away > head_measured


def test_figure_is_written(section):
    folder, s = section
    assert s.figures == (FIGURE,)
    path = folder / FIGURE
    assert path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"]({FIGURE})" in s.text


def test_30_bpm_bands_hold_the_papers_fitted_means(section):
    _, s = section
    cover = [c for c in s.checks if c.met is not None]
    assert [c.name for c in cover] == [
        "the 30-bpm bench bands hold the paper's dynamic SVs",
        "the 30-bpm bench bands hold the paper's peak forces",
    ]
    for check in cover:
        assert check.basis == "fitted" and check.basis in BASES  # fitted data: not held out
        assert check.met is True and check.value.startswith("3 of 3")


def test_section_shape(section):
    _, s = section
    assert (s.key, s.title) == ("applicability", "Applicability")
    assert not s.text.startswith("#")  # the report writes the title
    assert "outside" in s.text and "inside" in s.text
